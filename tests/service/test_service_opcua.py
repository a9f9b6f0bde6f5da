"""OPC UA for the plant's MES, read by an independent asyncua client as an MES would: the bench is a machine after
OPC 40001-1 (Machines/<bench>/Identification, MachineryItemState Executing during a test and NotExecuting after),
its results after OPC 40001-101 (typed Doubles with EngineeringUnits and their U, ResultMetaData with the verdict as
ResultEvaluationEnum, GetLatestResult / GetResultById with a Bad status for an unknown id, ResultReady on a
subscription to the Server object), over Basic256Sha256 SignAndEncrypt with a user and password."""

from __future__ import annotations

import asyncio
import math
import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from asyncua import Client, ua
from asyncua.crypto import cert_gen
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from cryptography import x509
from svc_helpers import TOKEN, ScriptedRunner, results_with_uncertainty, serve

from tcms_daq.config.models import OpcUaSection
from tcms_daq.service.opcua import OpcUaBridge, OpcUaError
from tcms_daq.service.passwords import hash_password

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 200, "cycles": 1, "rate_nm_per_s": 400,
           "serial_number": "SN-OPC-1", "operator": "Ada"}
MACHINERY = "http://opcfoundation.org/UA/Machinery/"
DI = "http://opcfoundation.org/UA/DI/"
RESULT = "http://opcfoundation.org/UA/Machinery/Result/"
UNECE = "http://www.opcfoundation.org/UA/units/un/cefact"
PASSWORD = "mes-password-1"
CLIENT_URI = "urn:tcms-daq:test:mes-client"


@pytest.fixture(scope="module")
def client_certificate(tmp_path_factory) -> tuple[Path, Path]:
    """The MES client's own application certificate (message security needs one on both sides)."""
    directory = tmp_path_factory.mktemp("mes")
    cert, key = directory / "client.der", directory / "client.pem"
    asyncio.run(cert_gen.setup_self_signed_certificate(
        key, cert, CLIENT_URI, "localhost", [x509.oid.ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "mes"}))
    return cert, key


def _opcua(**kw) -> OpcUaSection:
    return OpcUaSection(**{"users": {"mes": hash_password(PASSWORD)}, **kw})


async def _client(endpoint: str, certificate: tuple[Path, Path] | None, user: str | None = "mes",
                  password: str = PASSWORD, mode=ua.MessageSecurityMode.SignAndEncrypt) -> Client:
    client = Client(endpoint, timeout=20)
    client.application_uri = CLIENT_URI
    if certificate is not None:
        await client.set_security(SecurityPolicyBasic256Sha256, str(certificate[0]), str(certificate[1]), mode=mode)
    if user is not None:
        client.set_user(user)
        client.set_password(password)
    return client


class Collector:
    """asyncua subscription handler: keeps every event and every data change."""

    def __init__(self) -> None:
        self.events: list = []
        self.states: list[str] = []
        self.arrived = asyncio.Event()

    def event_notification(self, event) -> None:
        self.events.append(event)
        self.arrived.set()

    def datachange_notification(self, node, value, data) -> None:
        self.states.append(value.Text)


async def _until(predicate, timeout_s: float = 60.0):
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while not (value := await predicate()):
        assert loop.time() < deadline, "condition not met in time"
        await asyncio.sleep(0.02)
    return value


@pytest.mark.timeout(240)
async def test_an_mes_reads_the_machine_its_state_and_typed_results_and_receives_result_ready(
        settings_factory, client_certificate):
    runner = ScriptedRunner(bench_name="Line 5 bench", bench_id="line-5", speed=2.0,
                            results=results_with_uncertainty())
    with serve(settings_factory(opcua_port=0, opcua=_opcua()), runner=runner) as server:
        bridge = server.app.state.opcua
        assert bridge.endpoint.startswith("opc.tcp://127.0.0.1:") and bridge.port > 0
        sockets = bridge.server.bserver._server.sockets  # bound to loopback only (the default), registered nowhere
        assert sockets and all(s.getsockname()[0] == "127.0.0.1" for s in sockets)
        assert bridge.server._discovery_clients == {}

        client = await _client(bridge.endpoint, client_certificate)
        async with client:
            endpoints = await client.get_endpoints()
            assert {(e.SecurityPolicyUri.rsplit("#", 1)[1], e.SecurityMode) for e in endpoints} == {
                ("Basic256Sha256", ua.MessageSecurityMode.SignAndEncrypt),
                ("Basic256Sha256", ua.MessageSecurityMode.Sign)}  # no endpoint without security
            assert {t.TokenType for e in endpoints for t in e.UserIdentityTokens} == {ua.UserTokenType.UserName}
            await client.load_data_type_definitions()
            machinery, di, result_ns = [await client.get_namespace_index(u) for u in (MACHINERY, DI, RESULT)]
            bench_ns = await client.get_namespace_index("urn:tcms-daq:bench:line-5")

            # Machines/<bench>/Identification (OPC 40001-1)
            machines = await client.nodes.objects.get_child(f"{machinery}:Machines")
            assert (await machines.read_type_definition()) == ua.NodeId(ua.ObjectIds.FolderType)
            bench = await machines.get_child(f"{bench_ns}:line-5")
            assert (await bench.read_display_name()).Text == "Line 5 bench"
            identification = await bench.get_child(f"{di}:Identification")
            assert await identification.read_type_definition() == ua.NodeId(1012, machinery)  # MachineIdentificationType
            values = {name: await (await identification.get_child(f"{di}:{name}")).read_value()
                      for name in ("Manufacturer", "Model", "SerialNumber", "ProductInstanceUri")}
            assert values["SerialNumber"] == "line-5" and values["ProductInstanceUri"] == "urn:tcms-daq:bench:line-5"
            assert isinstance(values["Manufacturer"], ua.LocalizedText) and values["Model"].Text

            blocks = await bench.get_child(f"{machinery}:MachineryBuildingBlocks")
            item_state = await blocks.get_child(f"{machinery}:MachineryItemState")
            assert await item_state.read_type_definition() == ua.NodeId(1002, machinery)
            current = await item_state.get_child("0:CurrentState")
            assert (await current.read_value()).Text == "NotExecuting"
            state_id = await (await current.get_child("0:Id")).read_value()
            assert state_id == ua.NodeId(5007, machinery)  # the NotExecuting state of the type
            mode = await (await blocks.get_child([f"{machinery}:MachineryOperationMode", "0:CurrentState"])).read_value()
            assert mode.Text == "Processing"

            collector = Collector()
            subscription = await client.create_subscription(20, collector)
            ready_type = client.get_node(ua.NodeId(1002, result_ns))  # Result:ResultReadyEventType (abstract)
            await subscription.subscribe_events(client.nodes.server, ready_type)  # the Server object as notifier
            await subscription.subscribe_data_change(current)
            # the bench's own event type (with serial number, reducer, verdict) on the bench object
            types_ns = await client.get_namespace_index("urn:tcms-daq:types")
            bench_events = Collector()
            own = await client.create_subscription(20, bench_events)
            await own.subscribe_events(bench, client.get_node(ua.NodeId("TorsionTestResultReadyEventType", types_ns)))

            async with httpx.AsyncClient(base_url=server.base, headers={"Authorization": f"Bearer {TOKEN}"},
                                         timeout=20) as http:
                new_id = (await http.post("/api/tests", json=REQUEST)).json()["id"]
                # read during the test, as an MES polls
                await _until(lambda: _text_is(current, "Executing"))
                await asyncio.wait_for(collector.arrived.wait(), 120)
                assert (await http.get(f"/api/tests/{new_id}")).json()["status"] == "completed"
            await _until(lambda: _text_is(current, "NotExecuting"))
            states = collector.states
            assert states[0] == "NotExecuting" and "Executing" in states
            assert states.index("Executing") < len(states) - 1 - states[::-1].index("NotExecuting")

            event = collector.events[0]
            assert event.EventType == ua.NodeId("TorsionTestResultReadyEventType", types_ns)
            assert getattr(event, "Result/ResultMetaData/ResultId") == new_id
            assert event.SourceName == "ResultManagement"
            await asyncio.wait_for(bench_events.arrived.wait(), 30)
            own_event = bench_events.events[0]
            assert own_event.EventId == event.EventId  # one event, reported by each notifier
            assert own_event.SerialNumber == "SN-OPC-1" and own_event.Verdict == "pass"
            assert own_event.Reducer == "RV-110E"
            meta = event.Result.ResultMetaData
            assert meta.ResultId == new_id and meta.ResultEvaluation == 1 and meta.ResultState == 1  # OK, Completed
            assert meta.PartId == "SN-OPC-1" and meta.ProductId == "RV-110E"
            assert meta.ProcessingTimes.StartTime <= meta.ProcessingTimes.EndTime

            # the latest result: typed Doubles with EngineeringUnits and their U
            manager = await bench.get_child(f"{result_ns}:ResultManagement")
            latest = await manager.get_child([f"{result_ns}:Results", f"{bench_ns}:LatestResult"])
            rigidity = await latest.get_child(f"{bench_ns}:TorsionalRigidity")
            assert await rigidity.read_data_type() == ua.NodeId(ua.ObjectIds.Double)
            assert await rigidity.read_type_definition() == ua.NodeId(ua.ObjectIds.AnalogUnitType)
            value = await rigidity.read_value()
            assert isinstance(value, float) and value == pytest.approx(293.94)
            units = await (await rigidity.get_child("0:EngineeringUnits")).read_value()
            assert units.NamespaceUri == UNECE and units.DisplayName.Text == "N·m/arcmin" and units.UnitId == -1
            u = await rigidity.get_child(f"{bench_ns}:ExpandedUncertainty")
            assert await u.read_value() == pytest.approx(2.05 * 1.1219512)
            assert (await (await u.get_child("0:EngineeringUnits")).read_value()).DisplayName.Text == "N·m/arcmin"
            assert await (await rigidity.get_child(f"{bench_ns}:CoverageFactor")).read_value() == pytest.approx(2.05)
            lost = await latest.get_child(f"{bench_ns}:LostMotion")
            assert (await (await lost.get_child("0:EngineeringUnits")).read_value()).UnitId == int.from_bytes(b"D62",
                                                                                                               "big")
            assert await (await lost.get_child(f"{bench_ns}:ExpandedUncertainty")).read_value() == pytest.approx(0.82)
            verdict = await latest.get_child(f"{bench_ns}:Verdict")
            assert await verdict.read_value() == 1 and await verdict.read_data_type() == ua.NodeId(3002, result_ns)
            whole = await latest.read_value()
            assert whole.ResultMetaData.ResultId == new_id and '"serial_number": "SN-OPC-1"' in whole.ResultContent[0].Value

            # the methods; a Bad status for an unknown id
            handle, found, error = await manager.call_method(f"{result_ns}:GetLatestResult",
                                                             ua.Variant(0, ua.VariantType.Int32))
            assert (handle, error) == (0, 0) and found.ResultMetaData.ResultId == new_id
            _, by_id, _ = await manager.call_method(f"{result_ns}:GetResultById", ua.Variant(new_id, ua.VariantType.String),
                                                    ua.Variant(0, ua.VariantType.Int32))
            assert by_id.ResultMetaData.ResultId == new_id and by_id.ResultMetaData.ResultEvaluation == 1
            with pytest.raises(ua.UaStatusCodeError) as bad:
                await manager.call_method(f"{result_ns}:GetResultById", ua.Variant("no-such-run", ua.VariantType.String),
                                          ua.Variant(0, ua.VariantType.Int32))
            assert bad.value.code == ua.StatusCodes.BadNotFound
            with pytest.raises(ua.UaStatusCodeError) as wrong:
                await manager.call_method(f"{result_ns}:GetResultById", ua.Variant(7, ua.VariantType.Int32),
                                          ua.Variant(0, ua.VariantType.Int32))
            assert wrong.value.code == ua.StatusCodes.BadInvalidArgument

            # a result without uncertainty keys: U not stated (NaN), the verdict NotOK
            runner.results = {"rigidity_nm_per_arcmin": 300.5, "verdict": {"passed": False, "checks": {}}}
            collector.arrived.clear()
            async with httpx.AsyncClient(base_url=server.base, headers={"Authorization": f"Bearer {TOKEN}"},
                                         timeout=20) as http:
                old_id = (await http.post("/api/tests", json={**REQUEST, "serial_number": "SN-2"})).json()["id"]
            await asyncio.wait_for(collector.arrived.wait(), 120)
            last = collector.events[-1]
            assert last.Result.ResultMetaData.ResultId == old_id and last.Result.ResultMetaData.ResultEvaluation == 2
            assert await rigidity.read_value() == pytest.approx(300.5) and math.isnan(await u.read_value())
            assert await verdict.read_value() == 2
            await subscription.delete()
            await own.delete()
    assert bridge.results_published == 2


async def _text_is(node, text: str) -> bool:
    return (await node.read_value()).Text == text


@pytest.mark.timeout(180)
async def test_only_named_users_over_secure_channels_and_the_certificate_is_kept(settings_factory, tmp_path,
                                                                                  client_certificate):
    settings = settings_factory(opcua_port=0, opcua=_opcua(host="127.0.0.2"))
    with serve(settings, runner=ScriptedRunner(bench_id="line-6")) as server:
        bridge = server.app.state.opcua
        assert bridge.endpoint.startswith("opc.tcp://127.0.0.2:")  # the configured bind address
        assert all(s.getsockname()[0] == "127.0.0.2" for s in bridge.server.bserver._server.sockets)
        for user, password, mode in ((None, PASSWORD, ua.MessageSecurityMode.SignAndEncrypt),  # anonymous: off
                                     ("mes", "wrong-password", ua.MessageSecurityMode.SignAndEncrypt),
                                     ("nobody", PASSWORD, ua.MessageSecurityMode.Sign)):
            client = await _client(bridge.endpoint, client_certificate, user, password, mode)
            with pytest.raises(ua.UaStatusCodeError):
                await client.connect()
            await client.disconnect()
        with pytest.raises(ua.UaError):  # no endpoint without security
            async with await _client(bridge.endpoint, None):
                pass
        signed = await _client(bridge.endpoint, client_certificate, mode=ua.MessageSecurityMode.Sign)
        async with signed:
            assert await signed.nodes.server.read_browse_name() == ua.QualifiedName("Server", 0)
    cert = settings.data_dir / "opcua" / "server-cert.der"
    key = settings.data_dir / "opcua" / "server-key.pem"
    assert stat.S_IMODE(os.stat(key).st_mode) == 0o600
    first = cert.read_bytes()
    with serve(settings, runner=ScriptedRunner(bench_id="line-6")):
        pass
    assert cert.read_bytes() == first  # made on the first start, kept after


@pytest.mark.timeout(120)
async def test_anonymous_without_security_only_when_configured(settings_factory):
    settings = settings_factory(opcua_port=0, opcua=OpcUaSection(security_modes=["None"], anonymous=True))
    with serve(settings, runner=ScriptedRunner(bench_id="line-7")) as server:
        async with Client(server.app.state.opcua.endpoint, timeout=20) as client:
            ns = await client.get_namespace_index(MACHINERY)
            assert await client.nodes.objects.get_child(f"{ns}:Machines")


def test_a_server_nobody_could_use_and_a_missing_asyncua_are_one_line_errors(tmp_path, monkeypatch):
    from tcms_daq.store import open_store

    with open_store(None, tmp_path, bench_id="b", bench_name="b") as store:
        nobody = OpcUaBridge(store, "b", "b", 0, config=OpcUaSection(), data_dir=tmp_path)
        with pytest.raises(OpcUaError, match=r"no client could connect: \[opcua\] has no users"):
            nobody.start()
        monkeypatch.setattr("tcms_daq.service.opcua.asyncua_available", lambda: False)
        with pytest.raises(OpcUaError, match=re.escape("OPC UA server needs the optional [plant] dependencies")):
            OpcUaBridge(store, "b", "b", 0, config=_opcua(), data_dir=tmp_path).start()


def test_opcua_user_prints_a_hash_line_and_serve_refuses_a_server_nobody_could_use(tmp_path):
    import tomllib

    from tcms_daq.service.passwords import verify_password

    done = subprocess.run([sys.executable, "-m", "tcms_daq.cli", "opcua-user", "mes"], input="a-long-password\n",
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    line = done.stdout.strip()
    assert "a-long-password" not in line and verify_password("a-long-password", tomllib.loads(line)["mes"])
    short = subprocess.run([sys.executable, "-m", "tcms_daq.cli", "opcua-user", "mes"], input="short\n",
                           capture_output=True, text=True, timeout=60)
    assert short.returncode == 2 and short.stderr.count("\n") == 1 and "at least 8" in short.stderr
    serve_cli = subprocess.run([sys.executable, "-m", "tcms_daq.cli", "serve", "--opcua-port", "0", "--port", "0",
                                "--data-dir", str(tmp_path / "data")], capture_output=True, text=True, timeout=120)
    assert serve_cli.returncode == 2 and serve_cli.stderr.startswith("tcms: error: OPC UA: no client could connect")
    assert serve_cli.stderr.count("\n") == 1
