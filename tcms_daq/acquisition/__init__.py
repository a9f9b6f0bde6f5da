"""Acquisition: a bench composed from config, the acquisition loop, subscribers, the test procedure and its
interlocks (DESIGN §6).

Typical use::

    bench = bench_from_file("config/bench-sim.toml")
    run = run_test(bench, segments, subscribers=[on_message])   # a thread
    record = run.join()                                          # RunRecord: state, reason, samples, evaluation
"""

from tcms_daq.acquisition.bench import Bench, bench_from_file, compose_bench, read_bench_config
from tcms_daq.acquisition.clock import Clock, MonotonicClock, SimulatedClock
from tcms_daq.acquisition.fanout import DataMessage, EventMessage, FanOut, Subscription
from tcms_daq.acquisition.interlocks import InterlockLimits, Trip
from tcms_daq.acquisition.loop import AbortRequested, AcquisitionLoop, InterlockTripped
from tcms_daq.acquisition.record import FINAL_STATES, RunRecord, StateChange
from tcms_daq.acquisition.testrun import (
    ProcedureError,
    ProcedureOptions,
    ProfileRejected,
    Segment,
    TestRun,
    run_test,
)

__all__ = [
    "AbortRequested",
    "AcquisitionLoop",
    "Bench",
    "Clock",
    "DataMessage",
    "EventMessage",
    "FINAL_STATES",
    "FanOut",
    "InterlockLimits",
    "InterlockTripped",
    "MonotonicClock",
    "ProcedureError",
    "ProcedureOptions",
    "ProfileRejected",
    "RunRecord",
    "Segment",
    "SimulatedClock",
    "StateChange",
    "Subscription",
    "TestRun",
    "Trip",
    "bench_from_file",
    "compose_bench",
    "read_bench_config",
    "run_test",
]
