"""The bench over OPC UA for the plant's MES (``tcms serve --opcua-port N``), with asyncua.

Address space (namespace ``urn:tcms-daq:bench:<id>``), after OPC 40001-101 (Machinery Result Transfer) where it is
practical for one bench::

    Objects/Bench                     BenchId, BenchName, State, Phase, ActiveRunId, TorqueNm, AngleArcsec
    Objects/Bench/ResultManagement    GetLatestResult() -> (RunId, Result, Error)
                                      GetResultById(RunId) -> (Result, Error)
                                      emits ResultReadyEventType (RunId, SerialNumber, Verdict, Reducer)
    Objects/Bench/ResultManagement/LatestResult
                                      RunId, Reducer, SerialNumber, BenchId, Operator, StartTime, Status, Verdict,
                                      RigidityNmPerArcmin, LostMotionArcsec, BacklashArcsec and their expanded
                                      uncertainties …ExpandedU (NaN: U not stated), …Text ("value ± U (k = …)"),
                                      ResultJson (the whole identity, :func:`tcms_daq.identity.run_identity`)

``Result`` is that JSON text; ``Error`` is 0 (found) or 1 (no such result). Variables are read-only; the methods
read only. The server runs in its own thread and event loop (acquisition and the web service never wait on
it), listens on ``opc.tcp://127.0.0.1:N`` only, with security policy None (loopback only), and announces itself
nowhere (no discovery-server registration; asyncua does no multicast). It follows the service through the event
hub (test states and phases) and the live batches (the last torque and angle, published 10 times a second).
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
from collections.abc import Mapping
from typing import Any

import numpy as np

from tcms_daq.errors import TcmsError
from tcms_daq.identity import HEADLINES
from tcms_daq.store import RunQuery, Store, StoredRun

NAMESPACE = "urn:tcms-daq:bench:"
VALUE_PERIOD_S = 0.1
FINAL = ("completed", "aborted", "failed", "interrupted")


class OpcUaError(TcmsError):
    """The OPC UA server could not start (port in use …)."""


def result_json(record: StoredRun) -> str:
    """The JSON text ``GetLatestResult`` / ``GetResultById`` answer: the identity plus the full results."""
    doc = {**record.identity(), "full_results": record.results}
    return json.dumps(doc, allow_nan=False, default=str)


class OpcUaBridge:
    """An asyncua server in its own thread, fed from the service (events, live batches) and the store."""

    def __init__(self, store: Store, bench_id: str, bench_name: str, port: int):
        self.store = store
        self.bench_id = bench_id
        self.bench_name = bench_name
        self.port = port
        self.endpoint = f"opc.tcp://127.0.0.1:{port}/tcms/"
        self._latest_columns: Mapping[str, np.ndarray] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stopping: asyncio.Event | None = None
        self._error: BaseException | None = None
        self.server: Any = None
        self.results_published = 0
        self._nodes: dict[str, Any] = {}

    # -- called from the service's threads ---------------------------------------------------------------------
    def live(self, columns: Mapping[str, np.ndarray]) -> None:
        """A live batch (acquisition thread): only its reference is kept; the server samples it 10 times a second."""
        self._latest_columns = columns

    def on_event(self, event: dict) -> None:
        """An event of the service's hub (any thread): handed to the server's loop."""
        loop = self._loop
        if loop is not None and not loop.is_closed() and event.get("type") in ("test_state", "test_phase"):
            try:
                loop.call_soon_threadsafe(self._handle_event, event)
            except RuntimeError:  # the loop is closing
                pass

    def start(self, timeout_s: float = 60.0) -> None:
        """Start the server thread; returns once it listens (OpcUaError, one line, when it cannot)."""
        self._thread = threading.Thread(target=self._run, name="tcms-opcua", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise OpcUaError(f"OPC UA server on {self.endpoint} did not start within {timeout_s:g} s")
        if self._error is not None:
            raise OpcUaError(f"OPC UA server on port {self.port}: {self._error}") from None

    def stop(self) -> None:
        loop, stopping = self._loop, self._stopping
        if loop is not None and stopping is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stopping.set)
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(15.0)

    # -- the server's own thread -------------------------------------------------------------------------------
    def _run(self) -> None:
        logging.getLogger("asyncua").setLevel(logging.ERROR)
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # reported by start() (if it happened before the server listened)
            self._error = exc
            self._ready.set()

    async def _main(self) -> None:
        from asyncua import Server, ua

        self._loop = asyncio.get_running_loop()
        self._stopping = asyncio.Event()
        if self.port == 0:  # any free port, chosen before the endpoint descriptions are made (they name it)
            import socket

            with socket.socket() as probe:
                probe.bind(("127.0.0.1", 0))
                self.port = int(probe.getsockname()[1])
            self.endpoint = f"opc.tcp://127.0.0.1:{self.port}/tcms/"
        server = Server()
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name(f"TCMS-DAQ bench {self.bench_name}")
        await server.set_application_uri(f"urn:tcms-daq:{self.bench_id}")
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        await self._build(server)
        await self._load_latest()
        try:
            await server.start()
        except OSError as exc:
            raise OpcUaError(exc.strerror or str(exc)) from None
        self.server = server
        self._ready.set()
        try:
            while not self._stopping.is_set():
                await self._publish_values()
                try:
                    await asyncio.wait_for(self._stopping.wait(), VALUE_PERIOD_S)
                except TimeoutError:
                    pass
        finally:
            await server.stop()

    async def _build(self, server: Any) -> None:
        from asyncua import ua

        idx = await server.register_namespace(NAMESPACE + self.bench_id)
        nodes = self._nodes

        async def var(parent: Any, name: str, value: Any, kind: Any) -> Any:
            node = await parent.add_variable(idx, name, ua.Variant(value, kind))
            nodes[name] = node
            return node

        bench = await server.nodes.objects.add_object(idx, "Bench")
        await var(bench, "BenchId", self.bench_id, ua.VariantType.String)
        await var(bench, "BenchName", self.bench_name, ua.VariantType.String)
        for name in ("State", "Phase", "ActiveRunId"):
            await var(bench, name, "idle" if name == "State" else "", ua.VariantType.String)
        for name in ("TorqueNm", "AngleArcsec"):
            await var(bench, name, math.nan, ua.VariantType.Double)
        manager = await bench.add_object(idx, "ResultManagement")
        latest = await manager.add_object(idx, "LatestResult")
        self._nodes["__latest"] = latest
        for name in ("RunId", "Reducer", "SerialNumber", "ResultBenchId", "Operator", "StartTime", "Status",
                     "Verdict", "ResultJson"):
            await var(latest, name, "", ua.VariantType.String)
        for h in HEADLINES:
            await var(latest, h.browse_name, math.nan, ua.VariantType.Double)
            await var(latest, h.browse_name + "ExpandedU", math.nan, ua.VariantType.Double)
            await var(latest, h.browse_name + "Text", "", ua.VariantType.String)
        event_type = await server.create_custom_event_type(
            idx, "ResultReadyEventType", ua.ObjectIds.BaseEventType,
            [("RunId", ua.VariantType.String), ("SerialNumber", ua.VariantType.String),
             ("Reducer", ua.VariantType.String), ("Verdict", ua.VariantType.String)])
        self._event = await server.get_event_generator(event_type, manager)
        string, int32 = ua.VariantType.String, ua.VariantType.Int32

        def argument(name: str, kind: Any, text: str) -> Any:
            arg = ua.Argument()
            arg.Name, arg.DataType, arg.ValueRank = name, ua.NodeId(kind.value), -1
            arg.Description = ua.LocalizedText(text)
            return arg

        result_arg = argument("Result", string, "the result as JSON (identity, headline results ± U, full results)")
        error_arg = argument("Error", int32, "0: found; 1: no such result")
        await manager.add_method(idx, "GetLatestResult", self._get_latest, [],
                                 [argument("RunId", string, "the run id"), result_arg, error_arg])
        await manager.add_method(idx, "GetResultById", self._get_by_id, [argument("RunId", string, "a run id")],
                                 [result_arg, error_arg])

    # -- methods ---------------------------------------------------------------------------------------------
    async def _get_latest(self, parent: Any) -> list[Any]:
        from asyncua import ua

        run_id = await self._nodes["RunId"].read_value()
        if not run_id:
            return [ua.Variant("", ua.VariantType.String), ua.Variant("", ua.VariantType.String),
                    ua.Variant(1, ua.VariantType.Int32)]
        text = await self._nodes["ResultJson"].read_value()
        return [ua.Variant(run_id, ua.VariantType.String), ua.Variant(text, ua.VariantType.String),
                ua.Variant(0, ua.VariantType.Int32)]

    async def _get_by_id(self, parent: Any, run_id: Any) -> list[Any]:
        from asyncua import ua

        wanted = run_id.Value if isinstance(run_id, ua.Variant) else run_id
        record = await asyncio.to_thread(self.store.get_run, str(wanted)) if isinstance(wanted, str) else None
        if record is None or record.results is None:
            return [ua.Variant("", ua.VariantType.String), ua.Variant(1, ua.VariantType.Int32)]
        return [ua.Variant(result_json(record), ua.VariantType.String), ua.Variant(0, ua.VariantType.Int32)]

    # -- updates ---------------------------------------------------------------------------------------------
    async def _write(self, name: str, value: Any) -> None:
        from asyncua import ua

        node = self._nodes[name]
        kind = ua.VariantType.Double if isinstance(value, float) else ua.VariantType.String
        await node.write_value(ua.Variant(value, kind))

    async def _publish_values(self) -> None:
        cols = self._latest_columns
        if cols is None:
            return
        for name, key in (("TorqueNm", "torque_nm"), ("AngleArcsec", "angle_arcsec")):
            values = cols.get(key)
            if values is not None and len(values):
                await self._write(name, float(values[-1]))

    def _handle_event(self, event: dict) -> None:
        asyncio.get_running_loop().create_task(self._apply_event(event))

    async def _apply_event(self, event: dict) -> None:
        if event["type"] == "test_phase":
            await self._write("Phase", str(event.get("phase", "")))
            return
        status = str(event.get("status", ""))
        await self._write("State", status)
        run_id = str(event.get("id", ""))
        await self._write("ActiveRunId", "" if status in FINAL else run_id)
        if status in FINAL:
            await self._write("Phase", "")
            record = await asyncio.to_thread(self.store.get_run, run_id)
            if record is not None and record.results is not None:
                await self._set_latest(record)
                await self._announce(record)

    async def _load_latest(self) -> None:
        found = await asyncio.to_thread(self.store.list_runs, 1, 0, RunQuery(bench=self.bench_id, status="completed"))
        if found:
            record = await asyncio.to_thread(self.store.get_run, found[0].id)
            if record is not None:
                await self._set_latest(record)

    async def _set_latest(self, record: StoredRun) -> None:
        ident = record.identity()
        for name, key in (("Reducer", "reducer"), ("SerialNumber", "serial_number"), ("ResultBenchId", "bench_id"),
                          ("Operator", "operator"), ("StartTime", "started_at"), ("Status", "status"),
                          ("Verdict", "verdict")):
            await self._write(name, str(ident.get(key) or ""))
        for h in HEADLINES:
            entry = ident["results"][h.key]
            await self._write(h.browse_name, math.nan if entry["value"] is None else float(entry["value"]))
            await self._write(h.browse_name + "ExpandedU", math.nan if entry["U"] is None else float(entry["U"]))
            await self._write(h.browse_name + "Text", entry["text"])
        await self._write("ResultJson", result_json(record))
        await self._write("RunId", record.id)  # last: a reader that sees the id sees its values

    async def _announce(self, record: StoredRun) -> None:
        from asyncua import ua

        ident = record.identity()
        event = self._event.event
        event.RunId = record.id
        event.SerialNumber = str(ident.get("serial_number") or "")
        event.Reducer = str(ident.get("reducer") or "")
        event.Verdict = str(ident.get("verdict") or "")
        event.Severity = 100
        event.Message = ua.LocalizedText(f"result of run {record.id} ready ({event.Verdict or 'no verdict'})")
        await self._event.trigger()
        self.results_published += 1
