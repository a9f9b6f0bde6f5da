"""OPC UA for the plant: an asyncua client reads the bench's state and the latest result (with expanded
uncertainties), receives ResultReady, calls GetLatestResult / GetResultById; the server listens on 127.0.0.1 only
and registers with no discovery server."""

from __future__ import annotations

import asyncio
import json
import math

import httpx
import pytest
from asyncua import Client, ua
from svc_helpers import TOKEN, ScriptedRunner, results_with_uncertainty, serve

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 200, "cycles": 1, "rate_nm_per_s": 400,
           "serial_number": "SN-OPC-1", "operator": "Ada"}


class Collector:
    """asyncua subscription handler: keeps every event's fields."""

    def __init__(self) -> None:
        self.events: list[dict] = []
        self.states: list[str] = []
        self.arrived = asyncio.Event()

    def event_notification(self, event) -> None:
        self.events.append({k: v.Value for k, v in event.get_event_props_as_fields_dict().items()})
        self.arrived.set()

    def datachange_notification(self, node, value, data) -> None:
        self.states.append(value)


async def _wait(predicate, timeout_s: float = 30.0) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while not await predicate():
        assert loop.time() < deadline, "condition not met in time"
        await asyncio.sleep(0.05)


@pytest.mark.timeout(180)
async def test_client_reads_latest_result_and_receives_result_ready(settings_factory):
    runner = ScriptedRunner(bench_name="Line 5 bench", bench_id="line-5", speed=5.0,
                            results=results_with_uncertainty())
    with serve(settings_factory(opcua_port=0), runner=runner) as server:
        bridge = server.app.state.opcua
        assert bridge.endpoint.startswith("opc.tcp://127.0.0.1:") and bridge.port > 0
        # bound to loopback only, registered nowhere
        sockets = bridge.server.bserver._server.sockets
        assert sockets and all(s.getsockname()[0] == "127.0.0.1" for s in sockets)
        assert bridge.server._discovery_clients == {}

        async with Client(bridge.endpoint, timeout=20) as client:
            ns = await client.get_namespace_index("urn:tcms-daq:bench:line-5")
            bench = await client.nodes.objects.get_child(f"{ns}:Bench")
            manager = await bench.get_child(f"{ns}:ResultManagement")
            latest = await manager.get_child(f"{ns}:LatestResult")

            async def value(node, name):
                return await (await node.get_child(f"{ns}:{name}")).read_value()

            assert await value(bench, "BenchId") == "line-5" and await value(bench, "State") == "idle"
            await _wait(lambda: _finite(value(bench, "TorqueNm")))  # the live torque moves in
            run_id, text, error = await manager.call_method(f"{ns}:GetLatestResult")
            assert (run_id, text, error) == ("", "", 1)
            for endpoint in await client.get_endpoints():
                assert endpoint.EndpointUrl == bridge.endpoint
                assert endpoint.SecurityMode == ua.MessageSecurityMode.None_

            collector = Collector()
            subscription = await client.create_subscription(50, collector)
            event_type = await client.nodes.base_event_type.get_child(f"{ns}:ResultReadyEventType")
            await subscription.subscribe_events(manager, event_type)
            await subscription.subscribe_data_change(await bench.get_child(f"{ns}:State"))

            async with httpx.AsyncClient(base_url=server.base, headers={"Authorization": f"Bearer {TOKEN}"},
                                         timeout=20) as http:
                new_id = (await http.post("/api/tests", json=REQUEST)).json()["id"]
                await asyncio.wait_for(collector.arrived.wait(), 60)
                assert (await http.get(f"/api/tests/{new_id}")).json()["status"] == "completed"

            states = collector.states  # the State variable's changes, as a subscribed client saw them
            assert states[0] == "idle" and "running" in states and states.index("running") < states.index("completed")
            event = collector.events[0]
            assert event["RunId"] == new_id and event["SerialNumber"] == "SN-OPC-1"
            assert event["Verdict"] == "pass" and event["Reducer"] == "RV-110E"
            assert await value(latest, "RunId") == new_id and await value(latest, "SerialNumber") == "SN-OPC-1"
            assert await value(latest, "ResultBenchId") == "line-5" and await value(latest, "Verdict") == "pass"
            assert await value(latest, "RigidityNmPerArcmin") == pytest.approx(293.94)
            assert await value(latest, "RigidityNmPerArcminExpandedU") == pytest.approx(2.05 * 1.1219512)
            assert await value(latest, "LostMotionArcsecExpandedU") == pytest.approx(0.82)
            assert await value(latest, "BacklashArcsecText") == "18.6 ± 1.2″ (k = 2.00)"
            assert await value(bench, "State") == "completed" and await value(bench, "ActiveRunId") == ""

            run_id, text, error = await manager.call_method(f"{ns}:GetLatestResult")
            doc = json.loads(text)
            assert (run_id, error) == (new_id, 0) and doc["serial_number"] == "SN-OPC-1"
            assert doc["results"]["rigidity_nm_per_arcmin"]["U"] == pytest.approx(2.3)
            text, error = await manager.call_method(f"{ns}:GetResultById", ua.Variant(new_id, ua.VariantType.String))
            assert error == 0 and json.loads(text)["run_id"] == new_id
            assert await manager.call_method(f"{ns}:GetResultById", "no-such-run") == ["", 1]

            # a result without uncertainty keys: U not stated (NaN), and its event too
            runner.results = {"rigidity_nm_per_arcmin": 300.5, "verdict": {"passed": False, "checks": {}}}
            collector.arrived.clear()
            async with httpx.AsyncClient(base_url=server.base, headers={"Authorization": f"Bearer {TOKEN}"},
                                         timeout=20) as http:
                old_id = (await http.post("/api/tests", json={**REQUEST, "serial_number": "SN-2"})).json()["id"]
            await asyncio.wait_for(collector.arrived.wait(), 60)
            assert collector.events[-1]["RunId"] == old_id and collector.events[-1]["Verdict"] == "fail"
            assert await value(latest, "RigidityNmPerArcmin") == pytest.approx(300.5)
            assert math.isnan(await value(latest, "RigidityNmPerArcminExpandedU"))
            assert await value(latest, "RigidityNmPerArcminText") == "300.5 N·m/arcmin (U not stated)"
            await subscription.delete()
    assert bridge.results_published == 2


async def _finite(awaitable) -> bool:
    v = await awaitable
    return isinstance(v, float) and math.isfinite(v)
