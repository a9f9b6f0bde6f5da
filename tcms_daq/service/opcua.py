"""The bench over OPC UA for the plant's MES (``tcms serve --opcua-port N``), after the companion specifications
(asyncua, imported only when the server starts; the types are built in code: :mod:`tcms_daq.service.opcua_model`).

Address space (``Machinery:`` ``http://opcfoundation.org/UA/Machinery/``, ``DI:`` ``http://opcfoundation.org/UA/DI/``,
``Result:`` ``http://opcfoundation.org/UA/Machinery/Result/``, the bench's own nodes in ``urn:tcms-daq:bench:<id>``)::

    Objects/Machinery:Machines/<bench id>              a TorsionTestBenchType (OPC 40001-1 machine)
        DI:Identification (HasAddIn)                   MachineIdentificationType: Manufacturer, Model, SerialNumber,
                                                       ProductInstanceUri, SoftwareRevision, DeviceClass [, Location]
        Machinery:MachineryBuildingBlocks              HasAddIn Identification, MachineryItemState, MachineryOperationMode
            MachineryItemState/CurrentState (+ Id)     NotAvailable | OutOfService | NotExecuting | Executing
            MachineryOperationMode/CurrentState (+ Id) Processing while the bench serves tests
        State, Phase, ActiveRunId                      the service's run state (strings)
        Torque, Angle                                  live (10 Hz), AnalogUnitType Doubles with EngineeringUnits
        Result:ResultManagement                        OPC 40001-101 ResultManagementType
            GetLatestResult(Timeout) -> (ResultHandle, Result, Error)
            GetResultById(ResultId, Timeout) -> (ResultHandle, Result, Error)   Bad_NotFound for an unknown id
            Result:Results/LatestResult                ResultType (ResultDataType: ResultMetaData with ResultId,
                                                       ResultState, CreationTime, ProcessingTimes, PartId = serial
                                                       number, ProductId = reducer, ResultEvaluation; ResultContent:
                                                       the identity and full results as JSON), and as variables:
                TorsionalRigidity, LostMotion, Backlash   Doubles with EngineeringUnits, each with ExpandedUncertainty
                                                          (same unit, NaN: U not stated), CoverageFactor and Text
                                                          (a turning test's: NaN, "—")
                Quantities                                the result's typed quantities, made anew for each result
                                                          (opcua_model.result_quantities: a turning test's results
                                                          per direction and speed, its TE lines' amplitudes), each
                                                          as those three: EngineeringUnits, ExpandedUncertainty,
                                                          CoverageFactor, Text
                SerialNumber, Reducer, Method, Verdict    Method: the test method; Verdict: a ResultEvaluationEnum
                                                       ResultContent: the identity and full results as JSON, then
                                                       each quantity as a ResultQuantityDataType (Name, Value,
                                                       ExpandedUncertainty, CoverageFactor, EngineeringUnits, Text)

A run that ends with results raises a ``TorsionTestResultReadyEventType`` (a Result:ResultReadyEventType with
Result, SerialNumber, Reducer, Verdict) with the Server object as notifier (and the bench and ResultManagement
objects: Server -HasNotifier-> bench -HasEventSource-> ResultManagement), one event id for all three.

Security (``[opcua]``): Basic256Sha256 with SignAndEncrypt and Sign (None only when configured) with a server
certificate made on the first start and kept in ``<data dir>/opcua/``; users with scrypt password hashes
(``tcms opcua-user``), anonymous clients only when ``anonymous = true``; the bind address is ``host`` (loopback by
default). The server runs in its own thread and event loop (acquisition and the web service never wait on it) and
registers with no discovery server (asyncua sends no multicast).
"""

from __future__ import annotations

import asyncio
import importlib.util
import json
import logging
import math
import os
import socket
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from tcms_daq import __version__
from tcms_daq.config.models import OpcUaSection
from tcms_daq.errors import TcmsError
from tcms_daq.extras import missing_extra_message
from tcms_daq.identity import HEADLINES
from tcms_daq.service import opcua_model as model
from tcms_daq.service.passwords import verify_password
from tcms_daq.store import RunQuery, Store, StoredRun

VALUE_PERIOD_S = 0.1
STATUS_PERIOD_S = 1.0
FINAL = ("completed", "aborted", "failed", "interrupted")
#: ModelChangeStructureDataType verbs (OPC 10000-3 §9.32.1: a bit mask)
MODEL_CHANGE_REFERENCE_ADDED, MODEL_CHANGE_REFERENCE_DELETED = 4, 8
ACTIVE = ("queued", "running")
CERT_DIRNAME = "opcua"
CERT_FILE, KEY_FILE = "server-cert.der", "server-key.pem"
CERT_DAYS = 5 * 365
#: the stiffness test's result variables under LatestResult: (results key, browse name)
QUANTITIES = model.STIFFNESS_QUANTITIES
MISSING_ASYNCUA = missing_extra_message("plant", "the OPC UA server")


_ua = model._ua


class OpcUaError(TcmsError):
    """The OPC UA server could not start (asyncua missing, port in use, no client could connect …)."""


def asyncua_available() -> bool:
    return importlib.util.find_spec("asyncua") is not None


def check_config(config: OpcUaSection, data_dir: Path | None) -> None:
    """OpcUaError (one line) when a server would serve nobody: asyncua missing, or no way to sign in."""
    if not asyncua_available():
        raise OpcUaError(MISSING_ASYNCUA)
    if not config.users and not config.anonymous:
        raise OpcUaError("OPC UA: no client could connect: [opcua] has no users and anonymous = false (add a user "
                         "with `tcms opcua-user NAME` to [opcua.users], or set anonymous = true)")
    if any(m != "None" for m in config.security_modes) and data_dir is None:
        raise OpcUaError("OPC UA: message security needs a data directory for the server certificate")


def result_json(record: StoredRun) -> str:
    """The JSON text a result's ResultContent carries: the identity plus the full results."""
    doc = {**record.identity(), "full_results": record.results}
    return json.dumps(doc, allow_nan=False, default=str)


def _simulated(record: StoredRun) -> bool | None:
    """Whether the run's instruments were the in-process simulated bench (None: not recorded)."""
    instruments = (record.config_snapshot or {}).get("instruments")
    if not isinstance(instruments, Mapping) or not instruments:
        return None
    return all(isinstance(c, Mapping) and c.get("driver") == "virtual" for c in instruments.values())


def ensure_certificate(directory: Path, application_uri: str, hosts: list[str]) -> tuple[Path, Path]:
    """The server's certificate (DER) and private key (PEM, mode 0600) in ``directory``, made on the first start
    and again only when missing, expired or made for another application URI. (cert, key)."""
    from asyncua.crypto import cert_gen, uacrypto
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding

    directory.mkdir(parents=True, exist_ok=True)
    cert_path, key_path = directory / CERT_FILE, directory / KEY_FILE
    if cert_path.is_file() and key_path.is_file():
        cert = x509.load_der_x509_certificate(cert_path.read_bytes())
        uris = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value.get_values_for_type(
            x509.UniformResourceIdentifier)
        from datetime import UTC, datetime

        if application_uri in uris and cert.not_valid_after_utc > datetime.now(UTC):
            return cert_path, key_path
    key = cert_gen.generate_private_key()
    names: list[x509.GeneralName] = [x509.UniformResourceIdentifier(application_uri)]
    import ipaddress

    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    cert = cert_gen.generate_self_signed_app_certificate(
        key, f"TCMS-DAQ {application_uri}", {"organizationName": "TCMS-DAQ"}, names,
        extended=[x509.oid.ExtendedKeyUsageOID.SERVER_AUTH, x509.oid.ExtendedKeyUsageOID.CLIENT_AUTH],
        days=CERT_DAYS)
    descriptor = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(descriptor, "wb") as f:
        f.write(cert_gen.dump_private_key_as_pem(key))
    cert_path.write_bytes(cert.public_bytes(encoding=Encoding.DER))
    uacrypto.check_certificate(cert, application_uri)  # logs what a client may object to
    return cert_path, key_path


class _Users:
    """asyncua's user manager: named users with password hashes; anonymous clients only when allowed."""

    def __init__(self, users: Mapping[str, str], anonymous: bool):
        self.users = dict(users)
        self.anonymous = anonymous

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> Any:
        from asyncua.crypto.permission_rules import User, UserRole

        if username is None:
            return User(role=UserRole.User, name="anonymous") if self.anonymous else None
        hashed = self.users.get(username)
        if hashed is None or password is None or not verify_password(password, hashed):
            return None
        return User(role=UserRole.User, name=username)


async def announce_model_change(generator: Any, folder: Any) -> None:
    """A GeneralModelChangeEvent (OPC 10000-3 §9.32) through ``generator`` (the Server object's): ``folder``'s
    references to its children were deleted and added (verbs ReferenceAdded | ReferenceDeleted)."""
    ua = _ua()

    change = ua.ModelChangeStructureDataType(Affected=folder.nodeid, AffectedType=ua.NodeId(ua.ObjectIds.FolderType),
                                             Verb=MODEL_CHANGE_REFERENCE_ADDED | MODEL_CHANGE_REFERENCE_DELETED)
    event = generator.event
    # the type's field is a structure asyncua cannot wrap by its DataType NodeId: declared as what it is encoded as
    event.add_property("Changes", [change], ua.VariantType.ExtensionObject)
    event.SourceNode = folder.nodeid
    event.SourceName = (await folder.read_browse_name()).Name
    event.Severity = 1
    event.Message = ua.LocalizedText("the folder's children were replaced")
    await generator.trigger()


class _QuantityNodes:
    """The bench's AnalogUnitType nodes (a Double with its EngineeringUnits) and typed results (that value with its
    ExpandedUncertainty in the same unit, CoverageFactor and Text), made under the bench's namespace (``node_id``:
    path → NodeId) and kept in the bridge's map of nodes by path."""

    def __init__(self, node_id: Callable[[str], Any], ns_bench: int, nodes: dict[str, Any]):
        self.node_id = node_id
        self.ns_bench = ns_bench
        self.nodes = nodes

    async def analog(self, parent: Any, path: str, name: str, unit: model.Unit) -> Any:
        """An AnalogUnitType Double (NaN until written) with its EngineeringUnits."""
        ua = _ua()

        node = await model.add_variable(parent, self.node_id(path), ua.QualifiedName(name, self.ns_bench),
                                        ua.Variant(math.nan, ua.VariantType.Double), ua.NodeId(ua.ObjectIds.Double),
                                        ua.NodeId(ua.ObjectIds.AnalogUnitType))
        await node.add_property(self.node_id(path + ".EngineeringUnits"), ua.QualifiedName("EngineeringUnits", 0),
                                ua.Variant(model.eu_information(unit), ua.VariantType.ExtensionObject),
                                datatype=ua.NodeId(ua.ObjectIds.EUInformation))
        self.nodes[path] = node
        return node

    async def quantity(self, parent: Any, path: str, name: str, unit: model.Unit) -> Any:
        """An AnalogUnitType result with its ExpandedUncertainty (same unit), CoverageFactor and Text."""
        ua = _ua()

        quantity = await self.analog(parent, path, name, unit)
        await self.analog(quantity, f"{path}.ExpandedUncertainty", "ExpandedUncertainty", unit)
        for child, kind, value in (("CoverageFactor", ua.ObjectIds.Double, math.nan), ("Text", ua.ObjectIds.String, "")):
            variant = ua.Variant(value, ua.VariantType.Double if kind == ua.ObjectIds.Double else ua.VariantType.String)
            self.nodes[f"{path}.{child}"] = await model.add_variable(
                quantity, self.node_id(f"{path}.{child}"), ua.QualifiedName(child, self.ns_bench), variant,
                ua.NodeId(kind))
        return quantity

    async def write(self, path: str, q: model.ResultQuantity | None) -> None:
        """The result at ``path`` written from ``q`` (None: NaN and "—")."""
        ua = _ua()

        double, string = ua.VariantType.Double, ua.VariantType.String
        for node, value, kind in (
                (self.nodes[path], math.nan if q is None else q.value, double),
                (self.nodes[f"{path}.ExpandedUncertainty"], math.nan if q is None else q.expanded, double),
                (self.nodes[f"{path}.CoverageFactor"], math.nan if q is None else q.k, double),
                (self.nodes[f"{path}.Text"], "—" if q is None else q.text, string)):
            await node.write_value(ua.Variant(value, kind))


class OpcUaBridge:
    """An asyncua server in its own thread, fed from the service (events, live batches) and the store."""

    def __init__(self, store: Store, bench_id: str, bench_name: str, port: int, *,
                 config: OpcUaSection | None = None, data_dir: Path | None = None,
                 nameplate: Mapping[str, Any] | None = None,
                 bench_connected: Callable[[], bool | None] | None = None):
        self.store = store
        self.bench_id = bench_id
        self.bench_name = bench_name
        self.port = port
        self.config = config or OpcUaSection()
        self.host = self.config.host
        self.data_dir = data_dir
        self.nameplate = dict(nameplate or {})
        self.bench_connected = bench_connected
        self.application_uri = f"urn:tcms-daq:bench:{bench_id}"
        self.endpoint = self._endpoint_url(port)
        self._latest_columns: Mapping[str, np.ndarray] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stopping: asyncio.Event | None = None
        self._error: BaseException | None = None
        self.server: Any = None
        self.results_published = 0
        self._nodes: dict[str, Any] = {}
        self._active = False
        self._connected: bool | None = True

    def _endpoint_url(self, port: int) -> str:
        host = socket.gethostname() if self.host in ("0.0.0.0", "::", "") else self.host
        return f"opc.tcp://{f'[{host}]' if ':' in host else host}:{port}/tcms/"

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

    def check(self) -> None:
        check_config(self.config, self.data_dir)

    def start(self, timeout_s: float = 60.0) -> None:
        """Start the server thread; returns once it listens (OpcUaError, one line, when it cannot)."""
        self.check()
        self._thread = threading.Thread(target=self._run, name="tcms-opcua", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise OpcUaError(f"OPC UA server on {self.endpoint} did not start within {timeout_s:g} s")
        if self._error is not None:
            raise OpcUaError(f"OPC UA server on {self.host} port {self.port}: {self._error}") from None

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
        from asyncua import Server

        ua = _ua()

        self._loop = asyncio.get_running_loop()
        self._stopping = asyncio.Event()
        if self.port == 0:  # any free port, chosen before the endpoint descriptions are made (they name it)
            family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
            with socket.socket(family) as probe:
                probe.bind((self.host, 0))
                self.port = int(probe.getsockname()[1])
        self.endpoint = self._endpoint_url(self.port)
        users: Any = _Users(self.config.users, self.config.anonymous)  # asyncua's UserManager protocol
        server = Server(user_manager=users)
        await server.init()
        server.set_endpoint(self.endpoint)
        server.socket_address = (self.host, self.port)
        server.set_server_name(f"TCMS-DAQ bench {self.bench_name}")
        server.product_uri = "urn:tcms-daq"
        server.manufacturer_name = "TCMS-DAQ"
        await server.set_application_uri(self.application_uri)
        policies = {"SignAndEncrypt": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
                    "Sign": ua.SecurityPolicyType.Basic256Sha256_Sign, "None": ua.SecurityPolicyType.NoSecurity}
        server.set_security_policy([policies[m] for m in self.config.security_modes])
        if any(m != "None" for m in self.config.security_modes):
            assert self.data_dir is not None  # check()
            hosts = sorted({socket.gethostname(), "localhost", self.host} - {"0.0.0.0", "::", ""})
            cert, key = await asyncio.to_thread(ensure_certificate, self.data_dir / CERT_DIRNAME,
                                                self.application_uri, hosts)
            await server.load_certificate(str(cert))
            await server.load_private_key(str(key))
        tokens = ([ua.UserNameIdentityToken] if self.config.users else []) + (
            [ua.AnonymousIdentityToken] if self.config.anonymous else [])
        server.set_identity_tokens(tokens)
        self.ns, self.types = await model.build_types(server, self.application_uri)
        self._quantities = _QuantityNodes(self._id, self.ns.bench, self._nodes)
        await self._build(server)
        await self._load_latest()
        try:
            await server.start()
        except OSError as exc:
            raise OpcUaError(exc.strerror or str(exc)) from None
        self.server = server
        self._ready.set()
        try:
            next_status = 0.0
            while not self._stopping.is_set():
                await self._publish_values()
                if self._loop.time() >= next_status:
                    next_status = self._loop.time() + STATUS_PERIOD_S
                    await self._poll_bench()
                try:
                    await asyncio.wait_for(self._stopping.wait(), VALUE_PERIOD_S)
                except TimeoutError:
                    pass
            await self._set_item_state("NotAvailable")
        finally:
            await server.stop()

    # -- the address space -----------------------------------------------------------------------------------
    def _id(self, path: str) -> Any:
        ua = _ua()

        return ua.NodeId(f"{self.bench_id}.{path}" if path else self.bench_id, self.ns.bench)

    async def _relink(self, parent: Any, child: Any, old: int, new: int) -> None:
        await parent.delete_reference(child.nodeid, old, forward=True, bidirectional=True)
        await parent.add_reference(child.nodeid, new)

    async def _state_machine(self, parent: Any, path: str, name: str, type_id: int, states: Mapping[str, Any]
                             ) -> None:
        ua = _ua()

        machine = await parent.add_object(self._id(path), ua.QualifiedName(name, self.ns.machinery),
                                          objecttype=ua.NodeId(type_id, self.ns.machinery),
                                          instantiate_optional=False)
        current = await machine.get_child("0:CurrentState")
        self._nodes[path] = (current, await current.get_child("0:Id"), states)

    async def _build(self, server: Any) -> None:
        ua = _ua()

        ns, types = self.ns, self.types
        machines = await server.nodes.objects.add_folder(ua.NodeId(model.MACHINES, ns.machinery),
                                                         ua.QualifiedName("Machines", ns.machinery))
        bench = await machines.add_object(self._id(""), ua.QualifiedName(self.bench_id, ns.bench),
                                          objecttype=types["TorsionTestBenchType"].nodeid)
        await bench.write_attribute(ua.AttributeIds.DisplayName,
                                    ua.DataValue(ua.Variant(ua.LocalizedText(self.bench_name), ua.VariantType.LocalizedText)))
        self._nodes["bench"] = bench

        identification = await bench.add_object(self._id("Identification"), ua.QualifiedName("Identification", ns.di),
                                                objecttype=types["MachineIdentificationType"].nodeid)
        await self._relink(bench, identification, ua.ObjectIds.HasComponent, ua.ObjectIds.HasAddIn)
        plate = self.nameplate
        text = ua.VariantType.LocalizedText
        fields: list[tuple[str, int, Any, Any]] = [
            ("Manufacturer", ns.di, ua.LocalizedText(plate.get("manufacturer") or "not stated"), text),
            ("Model", ns.di, ua.LocalizedText(plate.get("model") or "TCMS-DAQ torsion test bench"), text),
            ("SerialNumber", ns.di, str(plate.get("serial_number") or self.bench_id), ua.VariantType.String),
            ("ProductInstanceUri", ns.di, str(plate.get("product_instance_uri") or self.application_uri),
             ua.VariantType.String),
            ("SoftwareRevision", ns.di, __version__, ua.VariantType.String),
            ("DeviceClass", ns.di, "torsional characteristic test bench", ua.VariantType.String)]
        if plate.get("location"):
            fields.append(("Location", ns.machinery, str(plate["location"]), ua.VariantType.String))
        for name, name_ns, value, kind in fields:
            await identification.add_property(self._id(f"Identification.{name}"), ua.QualifiedName(name, name_ns),
                                              ua.Variant(value, kind))

        blocks = await bench.add_object(self._id("MachineryBuildingBlocks"),
                                        ua.QualifiedName("MachineryBuildingBlocks", ns.machinery),
                                        objecttype=ua.NodeId(ua.ObjectIds.FolderType))
        await blocks.add_reference(identification.nodeid, ua.ObjectIds.HasAddIn)
        await self._state_machine(blocks, "MachineryItemState", "MachineryItemState", model.MACHINERY_ITEM_STATE_TYPE,
                                  types["item_states"])
        await self._state_machine(blocks, "MachineryOperationMode", "MachineryOperationMode",
                                  model.MACHINERY_OPERATION_MODE_TYPE, types["mode_states"])
        for path in ("MachineryItemState", "MachineryOperationMode"):
            child = server.get_node(self._id(path))
            await self._relink(blocks, child, ua.ObjectIds.Organizes, ua.ObjectIds.HasAddIn)
        await self._set_state("MachineryOperationMode", "Processing")
        await self._set_item_state("NotExecuting")

        for name, value in (("State", "idle"), ("Phase", ""), ("ActiveRunId", "")):
            self._nodes[name] = await model.add_variable(bench, self._id(name), ua.QualifiedName(name, ns.bench),
                                                         ua.Variant(value, ua.VariantType.String),
                                                         ua.NodeId(ua.ObjectIds.String))
        await self._quantities.analog(bench, "Torque", "Torque", model.NEWTON_METRE)
        await self._quantities.analog(bench, "Angle", "Angle", model.ARCSEC)

        manager = await bench.add_object(self._id("ResultManagement"), ua.QualifiedName("ResultManagement", ns.result),
                                         objecttype=types["ResultManagementType"].nodeid)
        results = await manager.add_object(self._id("ResultManagement.Results"), ua.QualifiedName("Results", ns.result),
                                           objecttype=ua.NodeId(ua.ObjectIds.FolderType))
        latest = await model.add_result_variable(
            results, types, ua.QualifiedName("LatestResult", ns.bench), model.empty_result(),
            (self._id("LatestResult"), self._id("LatestResult.ResultMetaData"),
             self._id("LatestResult.ResultMetaData.ResultId")))
        self._nodes["LatestResult"] = latest
        self._nodes["LatestResult.ResultMetaData"] = server.get_node(self._id("LatestResult.ResultMetaData"))
        self._nodes["LatestResult.ResultMetaData.ResultId"] = server.get_node(
            self._id("LatestResult.ResultMetaData.ResultId"))
        for key, name in QUANTITIES:
            await self._quantities.quantity(latest, f"LatestResult.{name}", name,
                                 model.UNITS_OF[next(h.unit for h in HEADLINES if h.key == key)])
        self._nodes["LatestResult.Quantities"] = await latest.add_object(
            self._id("LatestResult.Quantities"), ua.QualifiedName("Quantities", ns.bench),
            objecttype=ua.NodeId(ua.ObjectIds.FolderType))
        self._quantity_nodes: list[Any] = []
        for name in ("SerialNumber", "Reducer", "Method"):
            self._nodes[f"LatestResult.{name}"] = await model.add_variable(
                latest, self._id(f"LatestResult.{name}"), ua.QualifiedName(name, ns.bench),
                ua.Variant("", ua.VariantType.String), ua.NodeId(ua.ObjectIds.String))
        self._nodes["LatestResult.Verdict"] = await model.add_variable(
            latest, self._id("LatestResult.Verdict"), ua.QualifiedName("Verdict", ns.bench),
            ua.Variant(0, ua.VariantType.Int32), ua.NodeId(model.RESULT_EVALUATION_ENUM, ns.result))

        timeout = self._argument("Timeout", ua.NodeId(ua.ObjectIds.Int32),
                                 "a hint how long the client needs the result, ms (not used: results stay stored)")
        outputs = [self._argument("ResultHandle", ua.NodeId(ua.ObjectIds.Handle), "always 0 (no handles kept)"),
                   self._argument("Result", types["ResultDataType"].nodeid, "the result with its metadata"),
                   self._argument("Error", ua.NodeId(ua.ObjectIds.Int32), "0: OK")]
        await manager.add_method(self._id("ResultManagement.GetLatestResult"),
                                 ua.QualifiedName("GetLatestResult", ns.result), self._get_latest, [timeout], outputs)
        await manager.add_method(self._id("ResultManagement.GetResultById"),
                                 ua.QualifiedName("GetResultById", ns.result), self._get_by_id,
                                 [self._argument("ResultId", ua.NodeId(ua.ObjectIds.TrimmedString),
                                                 "the result's id (the run id)"), timeout], outputs)

        # events: the Server object is the notifier (Server -HasNotifier-> bench -HasEventSource-> ResultManagement)
        server_node = server.get_node(ua.NodeId(ua.ObjectIds.Server))
        await server_node.add_reference(bench.nodeid, ua.ObjectIds.HasNotifier)
        await bench.add_reference(manager.nodeid, ua.ObjectIds.HasEventSource)
        for node in (bench, manager):
            await node.set_event_notifier([ua.EventNotifier.SubscribeToEvents])
        self._event = await server.get_event_generator(types["TorsionTestResultReadyEventType"], ua.ObjectIds.Server)
        self._event.event.SourceNode = manager.nodeid
        self._event.event.SourceName = "ResultManagement"
        self._notifiers = [bench.nodeid, manager.nodeid]
        # LatestResult/Quantities is remade for each result: a GeneralModelChangeEvent tells a client to browse again
        self._model_change = await server.get_event_generator(ua.ObjectIds.GeneralModelChangeEventType,
                                                              ua.ObjectIds.Server)

    @staticmethod
    def _argument(name: str, datatype: Any, text: str) -> Any:
        ua = _ua()

        arg = ua.Argument()
        arg.Name, arg.DataType, arg.ValueRank = name, datatype, -1
        arg.Description = ua.LocalizedText(text)
        return arg

    # -- methods ---------------------------------------------------------------------------------------------
    def _answer(self, value: Any) -> list[Any]:
        ua = _ua()

        return [ua.Variant(0, ua.VariantType.UInt32), ua.Variant(value, ua.VariantType.ExtensionObject),
                ua.Variant(0, ua.VariantType.Int32)]

    async def _get_latest(self, parent: Any, timeout: Any = None) -> Any:
        ua = _ua()

        value = await self._nodes["LatestResult"].read_value()
        if value.ResultMetaData.ResultId in ("", "NA"):
            return ua.StatusCode(ua.StatusCodes.BadNotFound)
        return self._answer(value)

    async def _get_by_id(self, parent: Any, result_id: Any = None, timeout: Any = None) -> Any:
        ua = _ua()

        wanted = result_id.Value if isinstance(result_id, ua.Variant) else result_id
        if not isinstance(wanted, str) or not wanted or len(wanted) > 200:
            return ua.StatusCode(ua.StatusCodes.BadInvalidArgument)
        record = await asyncio.to_thread(self.store.get_run, wanted)
        if record is None or record.results is None:
            return ua.StatusCode(ua.StatusCodes.BadNotFound)
        return self._answer(self._result(record))

    # -- updates ---------------------------------------------------------------------------------------------
    async def _write(self, node: Any, value: Any, kind: Any) -> None:
        ua = _ua()

        await node.write_value(ua.Variant(value, kind))

    async def _set_state(self, path: str, state: str) -> None:
        ua = _ua()

        current, state_id, states = self._nodes[path]
        await self._write(current, ua.LocalizedText(state, "en"), ua.VariantType.LocalizedText)
        await self._write(state_id, states[state].nodeid, ua.VariantType.NodeId)

    async def _set_item_state(self, state: str | None = None) -> None:
        """MachineryItemState: Executing while a test is queued or running, OutOfService when the bench reports it
        is not connected, NotExecuting otherwise (NotAvailable is written on the way down)."""
        if state is None:
            state = "Executing" if self._active else "OutOfService" if self._connected is False else "NotExecuting"
        await self._set_state("MachineryItemState", state)

    async def _poll_bench(self) -> None:
        if self.bench_connected is None:
            return
        try:
            connected = await asyncio.to_thread(self.bench_connected)
        except Exception:  # a status that cannot be read says nothing about the connection
            return
        if connected != self._connected:
            self._connected = connected
            await self._set_item_state()

    async def _publish_values(self) -> None:
        ua = _ua()

        cols = self._latest_columns
        if cols is None:
            return
        for name, key in (("Torque", "torque_nm"), ("Angle", "angle_arcsec")):
            values = cols.get(key)
            if values is not None and len(values):
                await self._write(self._nodes[name], float(values[-1]), ua.VariantType.Double)

    def _handle_event(self, event: dict) -> None:
        asyncio.get_running_loop().create_task(self._apply_event(event))

    async def _apply_event(self, event: dict) -> None:
        ua = _ua()

        string = ua.VariantType.String
        if event["type"] == "test_phase":
            await self._write(self._nodes["Phase"], str(event.get("phase", "")), string)
            return
        status = str(event.get("status", ""))
        run_id = str(event.get("id", ""))
        await self._write(self._nodes["State"], status, string)
        await self._write(self._nodes["ActiveRunId"], "" if status in FINAL else run_id, string)
        self._active = status in ACTIVE
        await self._set_item_state()
        if status in FINAL:
            await self._write(self._nodes["Phase"], "", string)
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

    def _result(self, record: StoredRun) -> Any:
        return model.result_value(record.identity(), record.summary()["finished_at"], result_json(record),
                                  _simulated(record), model.result_quantities(record.results))

    async def _set_quantities(self, typed: list[model.ResultQuantity]) -> None:
        """LatestResult/Quantities: the previous result's quantities deleted, this one's made (a turning test's
        differ in number and name from one result to the next)."""
        if self._quantity_nodes:
            await self.server.delete_nodes(self._quantity_nodes, recursive=True)
        self._quantity_nodes = []
        folder = self._nodes["LatestResult.Quantities"]
        for q in typed:
            path = f"LatestResult.Quantities.{q.name}"
            self._quantity_nodes.append(await self._quantities.quantity(folder, path, q.name, q.unit))
            await self._quantities.write(path, q)
        if self.server is not None:  # listening: a model change before it is not announced
            await announce_model_change(self._model_change, folder)

    async def _set_latest(self, record: StoredRun) -> None:
        ua = _ua()

        ident = record.identity()
        value = self._result(record)
        string = ua.VariantType.String
        typed = {q.name: q for q in model.result_quantities(record.results)}
        for _, name in QUANTITIES:  # a turning test's result has none of them: NaN, "—"
            await self._quantities.write(f"LatestResult.{name}", typed.get(name))
        await self._set_quantities(list(typed.values()))
        await self._write(self._nodes["LatestResult.SerialNumber"], str(ident.get("serial_number") or ""), string)
        await self._write(self._nodes["LatestResult.Reducer"], str(ident.get("reducer") or ""), string)
        await self._write(self._nodes["LatestResult.Method"], str((ident.get("method") or {}).get("kind") or ""),
                          string)
        await self._write(self._nodes["LatestResult.Verdict"],
                          model.EVALUATION.get(str(ident.get("verdict")), 0), ua.VariantType.Int32)
        await self._write(self._nodes["LatestResult.ResultMetaData"], value.ResultMetaData,
                          ua.VariantType.ExtensionObject)
        await self._write(self._nodes["LatestResult.ResultMetaData.ResultId"], record.id, string)
        # last: a reader that sees the new result sees its values
        await self._write(self._nodes["LatestResult"], value, ua.VariantType.ExtensionObject)

    async def _announce(self, record: StoredRun) -> None:
        """ResultReady with the Server object as notifier, and the same event from the bench and ResultManagement
        (one event id)."""
        ua = _ua()

        ident = record.identity()
        value = self._result(record)
        event = self._event.event
        extension = ua.VariantType.ExtensionObject
        event.add_variable("Result", value, extension)
        event.add_variable("Result/ResultMetaData", value.ResultMetaData, extension)
        event.add_variable("Result/ResultMetaData/ResultId", record.id, ua.VariantType.String)
        for name, key in (("SerialNumber", "serial_number"), ("Reducer", "reducer"), ("Verdict", "verdict")):
            event.add_property(name, str(ident.get(key) or ""), ua.VariantType.String)
        event.Severity = 100
        event.Message = ua.LocalizedText(f"result of run {record.id} ready ({ident.get('verdict') or 'no verdict'})")
        await self._event.trigger()  # the Server object (EventId and times set here)
        service = self.server.iserver.subscription_service  # the same event again for the other notifiers
        try:
            for node_id in self._notifiers:
                event.emitting_node = node_id
                await service.trigger_event(event)
        finally:
            event.emitting_node = ua.NodeId(ua.ObjectIds.Server)
        self.results_published += 1
