"""Moves of the output between positions: never under torque; an abort during a move halts it, ramps to zero and
disables; the next test after it runs normally. In-process simulated bench (simulated clock)."""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import pytest
from tcms_daq.drivers.base import CommandRejected

from tcms_daq.acquisition import TestRun, compose_bench
from tcms_daq.acquisition.fanout import EventMessage
from tcms_daq.config import load_bench_config
from tcms_daq.procedure import continuous_profile
from tcms_daq.procedure.plan import Plan, Stage


def _bench():
    cfg = load_bench_config()
    return compose_bench(cfg, config_dir=Path(cfg.source_path).parent)


@contextmanager
def _enabled_loader(bench):
    """The bench connected and its loader enabled, for commands by hand; yields (loader, virtual bench)."""
    bench.connect()
    try:
        bench.loader.enable()
        yield bench.loader, bench.loader.bench
    finally:
        bench.close()


def test_no_move_under_torque():
    with _enabled_loader(_bench()) as (loader, vbench):
        loader.set_torque(200.0, 2000.0)
        vbench.advance(0.5)
        with pytest.raises(CommandRejected, match="no move under torque"):
            loader.move_to(90.0, 30.0)
        assert loader.status().position_deg == pytest.approx(0.0) and not loader.status().moving
        loader.set_torque(0.0, 2000.0)
        vbench.advance(0.5)
        loader.move_to(90.0, 30.0)
        vbench.advance(1.0)
        st = loader.status()
        assert st.moving and 25.0 < st.position_deg < 35.0  # 30 °/s for 1 s
        assert abs(st.torque_actual_nm) < 1.0
        vbench.advance(3.0)
        st = loader.status()
        assert not st.moving and st.position_deg == pytest.approx(90.0)


def test_abort_during_a_move_then_the_next_test():
    bench = _bench()
    profile = continuous_profile(300.0, 300.0, cycles=1)
    plan = Plan("positions", (Stage(0, profile, 0.0), Stage(1, profile, 180.0)), move_velocity_deg_per_s=2.0)
    run = TestRun(bench, plan, reducer_torque_limit_nm=1200.0)
    vbench = bench.loader.bench
    moved: list[float] = []

    def abort_mid_move() -> None:
        moved.append(vbench.output_position()[0])
        run.abort("operator abort during the move")

    # the first stage takes ~6 s of torque loops; the 180° move at 2 °/s takes 90 s: abort 30 s after the start
    vbench.at(30.0, abort_mid_move)
    record = run.run()
    assert record.state == "aborted" and record.reason == "operator abort during the move"
    assert 5.0 < moved[0] < 175.0  # the abort came while the output was moving
    assert record.loader_final["state"] == "SWITCH ON DISABLED"
    position, moving = vbench.output_position()
    assert not moving and position == pytest.approx(moved[0], abs=1.0)  # halted where it was, not at 180°
    assert abs(record.samples.torque_nm[-50:]).max() < 5.0
    assert any("moved from" in note for note in record.notes)

    # the next test on the same bench: at the position where the move stopped, runs and completes
    nxt = TestRun(bench, continuous_profile(300.0, 300.0, cycles=1), reducer_torque_limit_nm=1200.0).run()
    assert nxt.state == "completed", nxt.reason


def test_the_eta_starts_from_where_the_output_is():
    """The output left at 90° by an earlier test: the first ETA includes the 90° move back to the first position
    (45 s at 2 °/s), not the plan's assumed start at 0°."""
    bench = _bench()
    with _enabled_loader(bench) as (loader, vbench):
        loader.move_to(90.0, 30.0)
        vbench.advance(4.0)
        assert loader.status().position_deg == pytest.approx(90.0)
        loader.disable()
    profile = continuous_profile(300.0, 300.0, cycles=1)
    plan = Plan("positions", (Stage(0, profile, 0.0), Stage(1, profile, 30.0)), move_velocity_deg_per_s=2.0)
    progress: list[dict] = []

    def keep(msg) -> None:
        if isinstance(msg, EventMessage) and msg.event == "progress":
            progress.append(msg.details)

    record = TestRun(bench, plan, reducer_torque_limit_nm=1200.0, subscribers=[keep]).run()
    assert record.state == "completed", record.reason
    from_90 = replace(plan, start_position_deg=90.0).duration_s()
    assert from_90 - plan.duration_s() == pytest.approx(45.0)
    assert progress[0]["eta_s"] == pytest.approx(from_90)
    assert progress[0]["eta_s"] + progress[0]["elapsed_s"] == pytest.approx(progress[-1]["elapsed_s"], rel=0.1)
