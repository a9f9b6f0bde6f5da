"""The OPC UA companion-specification types the bench needs, built in code, and the results as Result Transfer
values (asyncua; imported lazily: this module is imported only when the OPC UA server starts).

No nodeset file is read: each type is created with its specification's namespace URI, browse name and NodeId.

* OPC 10000-100 Devices (DI, ``http://opcfoundation.org/UA/DI/``): ``FunctionalGroupType`` (i=1005), the
  supertype of the Machinery identification; the browse names ``Identification``, ``Manufacturer``, ``Model``,
  ``SerialNumber``, ``ProductInstanceUri``, ``SoftwareRevision``, ``DeviceClass``.
* OPC 40001-1 Machinery (``http://opcfoundation.org/UA/Machinery/``): the ``Machines`` folder (i=1001),
  ``MachineryItemIdentificationType`` (i=1004), ``MachineIdentificationType`` (i=1012),
  ``MachineryItemState_StateMachineType`` (i=1002: NotAvailable 0, OutOfService 1, NotExecuting 2, Executing 3)
  and ``MachineryOperationModeStateMachineType`` (i=1008: None 0, Maintenance 1, Setup 2, Processing 3), each
  with its states and transitions (the specification's numbers).
* OPC 40001-101 Machinery Result Transfer (``http://opcfoundation.org/UA/Machinery/Result/``):
  ``ResultEvaluationEnum`` (i=3002), ``ProcessingTimesDataType`` (i=3006), ``ResultMetaDataType`` (i=3007) and
  ``ResultDataType`` (i=3008) with their binary encodings (i=5003, 5005, 5008) and the specification's fields in
  its order (so their binary encoding is the specification's), ``ResultType`` (i=2001), ``ResultManagementType``
  (i=1004) and the abstract ``ResultReadyEventType`` (i=1002).
* This program's types (``urn:tcms-daq:types``): ``TorsionTestBenchType``, the concrete
  ``TorsionTestResultReadyEventType`` (a ResultReadyEventType with the serial number, reducer and verdict) and
  ``ResultQuantityDataType`` (a result's typed value: Name, Value, ExpandedUncertainty, CoverageFactor,
  EngineeringUnits, Text): a result's ResultContent holds its identity and full results as JSON, then each of its
  quantities as one of these (:func:`result_quantities`: the stiffness test's headlines, a turning test's results
  per direction and speed and its transmission-error lines).

Quantities carry ``EngineeringUnits`` (EUInformation, UNECE Recommendation 20 codes; the unit id is the code's
ASCII bytes as an integer, -1 where Rec. 20 has no code, as for N·m/arcmin).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

DI_URI = "http://opcfoundation.org/UA/DI/"
MACHINERY_URI = "http://opcfoundation.org/UA/Machinery/"
RESULT_URI = "http://opcfoundation.org/UA/Machinery/Result/"
TYPES_URI = "urn:tcms-daq:types"
UNECE_URI = "http://www.opcfoundation.org/UA/units/un/cefact"


def _ua() -> Any:
    """asyncua's ``ua`` module, imported when the server starts (typed Any: its NewType integers would ask for a
    cast at every NodeId and StatusCode)."""
    from asyncua import ua

    return ua

# -- NodeIds of the specifications (numeric, in their namespaces) ------------------------------------------------
DI_FUNCTIONAL_GROUP_TYPE = 1005
MACHINES = 1001
MACHINERY_ITEM_STATE_TYPE = 1002
MACHINERY_ITEM_IDENTIFICATION_TYPE = 1004
MACHINERY_OPERATION_MODE_TYPE = 1008
MACHINE_IDENTIFICATION_TYPE = 1012
RESULT_READY_EVENT_TYPE = 1002
RESULT_MANAGEMENT_TYPE = 1004
RESULT_TYPE = 2001
RESULT_EVALUATION_ENUM = 3002
PROCESSING_TIMES_TYPE, PROCESSING_TIMES_ENCODING = 3006, 5003
RESULT_META_DATA_TYPE, RESULT_META_DATA_ENCODING = 3007, 5005
RESULT_DATA_TYPE, RESULT_DATA_ENCODING = 3008, 5008

#: (state, StateNumber, NodeId of the state in the type, NodeId of its StateNumber) — OPC 40001-1 12.2
ITEM_STATES = (("NotAvailable", 0, 5005, 6039), ("OutOfService", 1, 5004, 6038), ("NotExecuting", 2, 5007, 6041),
               ("Executing", 3, 5006, 6040))
#: (transition, TransitionNumber, NodeId, NodeId of its TransitionNumber) — OPC 40001-1 12.2
ITEM_TRANSITIONS = (
    ("FromNotAvailableToOutOfService", 0, 5008, 6042), ("FromNotAvailableToExecuting", 1, 5010, 6044),
    ("FromNotAvailableToNotExecuting", 2, 5009, 6043), ("FromOutOfServiceToNotAvailable", 3, 5012, 6046),
    ("FromOutOfServiceToExecuting", 4, 5014, 6048), ("FromOutOfServiceToNotExecuting", 5, 5013, 6047),
    ("FromExecutingToNotAvailable", 6, 5020, 6054), ("FromExecutingToOutOfService", 7, 5021, 6055),
    ("FromExecutingToNotExecuting", 8, 5022, 6056), ("FromNotExecutingToNotAvailable", 9, 5016, 6050),
    ("FromNotExecutingToOutOfService", 10, 5017, 6051), ("FromNotExecutingToExecuting", 11, 5018, 6052),
    ("FromNotAvailableToNotAvailable", 12, 5011, 6045), ("FromOutOfServiceToOutOfService", 13, 5015, 6049),
    ("FromExecutingToExecuting", 14, 5023, 6057), ("FromNotExecutingToNotExecuting", 15, 5019, 6053))
#: OPC 40001-1 13.2
MODE_STATES = (("None", 0, 5024, 6059), ("Maintenance", 1, 5025, 6060), ("Setup", 2, 5027, 6062),
               ("Processing", 3, 5026, 6061))
MODE_TRANSITIONS = (
    ("FromNoneToMaintenance", 0, 5028, 6063), ("FromNoneToProcessing", 1, 5030, 6065),
    ("FromNoneToSetup", 2, 5029, 6064), ("FromMaintenanceToNone", 3, 5032, 6067),
    ("FromMaintenanceToProcessing", 4, 5034, 6069), ("FromMaintenanceToSetup", 5, 5033, 6068),
    ("FromProcessingToNone", 6, 5040, 6075), ("FromProcessingToMaintenance", 7, 5041, 6076),
    ("FromProcessingToSetup", 8, 5042, 6077), ("FromSetupToNone", 9, 5036, 6071),
    ("FromSetupToMaintenance", 10, 5037, 6072), ("FromSetupToProcessing", 11, 5038, 6073),
    ("FromNoneToNone", 12, 5031, 6066), ("FromMaintenanceToMaintenance", 13, 5035, 6070),
    ("FromProcessingToProcessing", 14, 5043, 6078), ("FromSetupToSetup", 15, 5039, 6074))

#: ResultEvaluationEnum of a decision (ISO 14253-1): OK, NotOK, NotDecidable; Undefined without one
EVALUATION = {"pass": 1, "fail": 2, "undecided": 3}
#: ResultState (Int32) of a run's status: 1 Completed, 2 Processing, 3 Aborted, 4 Failed (0 Undefined)
RESULT_STATE = {"completed": 1, "queued": 2, "running": 2, "aborted": 3, "failed": 4, "interrupted": 4}


@dataclass(frozen=True)
class Unit:
    """An engineering unit: UNECE Rec. 20 common code ('' when it has none), symbol and name."""

    code: str
    symbol: str
    name: str

    @property
    def unit_id(self) -> int:
        """OPC 10000-8 5.6.3: the common code's ASCII bytes as one integer (-1: no code)."""
        return int.from_bytes(self.code.encode("ascii"), "big") if self.code else -1


NEWTON_METRE = Unit("NU", "N·m", "newton metre")
ARCSEC = Unit("D62", "″", "second [unit of angle]")
RIGIDITY = Unit("", "N·m/arcmin", "newton metre per minute of arc (no UNECE Rec. 20 code)")
ONE = Unit("C62", "1", "one (a ratio: 1 = 100 %)")
UNITS_OF = {"N·m/arcmin": RIGIDITY, "arcsec": ARCSEC, "N·m": NEWTON_METRE, "1": ONE}
#: the stiffness test's headline results under LatestResult: (results key, browse name)
STIFFNESS_QUANTITIES = (("rigidity_nm_per_arcmin", "TorsionalRigidity"), ("lost_motion_arcsec", "LostMotion"),
                        ("backlash_arcsec", "Backlash"))


@dataclass(frozen=True)
class ResultQuantity:
    """One typed result: its browse name, its value and expanded uncertainty U (in ``unit``; NaN: not evaluated or
    U not stated), its coverage factor k, its unit and its text ("21.8 ± 3.8″ (k = 1.96)")."""

    name: str
    value: float
    expanded: float
    k: float
    unit: Unit
    text: str


def result_quantities(results: Mapping[str, Any] | None) -> list[ResultQuantity]:
    """A run's results as typed quantities: the stiffness test's rigidity, lost motion and backlash; a turning
    test's results (``method_views.quantities``: the headline, each direction, each speed) and, for the
    transmission error, each line's amplitude (``TeOrder_<order>_Amplitude``, its text naming the component)."""
    from tcms_daq.analysis.rounding import with_uncertainty
    from tcms_daq.identity import HEADLINES, uncertainty_entry
    from tcms_daq.service.method_views import method_of, quantities, te_lines

    res = results or {}

    def one(name: str, value: Any, entry: Mapping[str, Any] | None, unit: str, prefix: str = "") -> ResultQuantity:
        number = number_or_nan(value)
        text = with_uncertainty(number, entry, "" if unit == "1" else unit) if math.isfinite(number) else "—"
        return ResultQuantity(name, number, number_or_nan((entry or {}).get("U")),
                              number_or_nan((entry or {}).get("k")), UNITS_OF[unit], prefix + text)

    if method_of(res) is None:
        units = {h.key: h.unit for h in HEADLINES}
        return [one(name, res.get(key), uncertainty_entry(res, key), units[key]) for key, name in STIFFNESS_QUANTITIES]
    out = [one(q.browse_name, res.get(q.key), uncertainty_entry(res, q.key), q.unit) for q in quantities(res)]
    for line in te_lines(res):
        out.append(one(f"TeOrder_{line['order']:g}_Amplitude", line["amplitude_arcsec"], line["uncertainty"], "arcsec",
                       f"order {line['order']:g} ({line['component'] or 'no component'}): "))
    return out


@dataclass
class Namespaces:
    """The namespace indices of the server."""

    di: int
    machinery: int
    result: int
    types: int
    bench: int


def eu_information(unit: Unit) -> Any:
    ua = _ua()

    return ua.EUInformation(NamespaceUri=UNECE_URI, UnitId=unit.unit_id, DisplayName=ua.LocalizedText(unit.symbol),
                            Description=ua.LocalizedText(unit.name))


# -- building the types ----------------------------------------------------------------------------------------------
async def _object_type(parent: Any, ns: int, numeric: int, name: str, abstract: bool = False) -> Any:
    ua = _ua()

    node = await parent.add_object_type(ua.NodeId(numeric, ns), ua.QualifiedName(name, ns))
    if abstract:
        await node.write_attribute(ua.AttributeIds.IsAbstract, ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)))
    return node


async def _numbered(machine: Any, ns: int, name: str, node_id: int, type_id: int, number_name: str, number: int,
                    number_id: int) -> Any:
    """A StateType or TransitionType object of a state machine type, with its number property, at the
    specification's NodeIds (made directly: instantiating the type would number its property itself)."""
    ua = _ua()

    node = await machine.add_object(ua.NodeId(node_id, ns), ua.QualifiedName(name, ns))
    await node.delete_reference(ua.NodeId(ua.ObjectIds.BaseObjectType), ua.ObjectIds.HasTypeDefinition,
                                forward=True, bidirectional=False)
    await node.add_reference(ua.NodeId(type_id), ua.ObjectIds.HasTypeDefinition, bidirectional=False)
    await node.add_property(ua.NodeId(number_id, ns), ua.QualifiedName(number_name, 0),
                            ua.Variant(number, ua.VariantType.UInt32))
    return node


async def _state_machine_type(server: Any, ns: int, numeric: int, name: str,
                              states: tuple[tuple[str, int, int, int], ...],
                              transitions: tuple[tuple[str, int, int, int], ...]) -> dict[str, Any]:
    """A FiniteStateMachineType subtype with its StateType objects (StateNumber) and TransitionType objects
    (TransitionNumber, FromState, ToState); the state nodes by name."""
    ua = _ua()

    base = server.get_node(ua.NodeId(ua.ObjectIds.FiniteStateMachineType))
    machine = await _object_type(base, ns, numeric, name)
    nodes = {}
    for state, number, node_id, number_id in states:
        nodes[state] = await _numbered(machine, ns, state, node_id, ua.ObjectIds.StateType, "StateNumber", number,
                                       number_id)
    for transition, number, node_id, number_id in transitions:
        node = await _numbered(machine, ns, transition, node_id, ua.ObjectIds.TransitionType, "TransitionNumber",
                               number, number_id)
        origin, target = transition.removeprefix("From").split("To", 1)
        await node.add_reference(nodes[origin].nodeid, ua.ObjectIds.FromState)
        await node.add_reference(nodes[target].nodeid, ua.ObjectIds.ToState)
    return nodes


async def _structure(server: Any, ns: int, numeric: int | str, encoding: int | str, name: str, fields: list[Any]
                     ) -> Any:
    """A structured DataType with its Default Binary encoding at the specification's NodeIds (asyncua's
    ``new_struct`` would number the encoding itself)."""
    ua = _ua()
    from asyncua.common.manage_nodes import create_data_type, create_encoding

    dtype = await create_data_type(server.nodes.base_structure_type, ua.NodeId(numeric, ns), ua.QualifiedName(name, ns))
    enc = await create_encoding(dtype, ua.NodeId(encoding, ns), ua.QualifiedName("Default Binary", 0))
    definition = ua.StructureDefinition()
    definition.BaseDataType = server.nodes.base_structure_type.nodeid
    definition.StructureType = (ua.StructureType.StructureWithOptionalFields if any(f.IsOptional for f in fields)
                                else ua.StructureType.Structure)
    definition.Fields = fields
    definition.DefaultEncodingId = enc.nodeid
    await dtype.write_data_type_definition(definition)
    return dtype


async def build_types(server: Any, bench_uri: str) -> tuple[Namespaces, dict[str, Any]]:
    """Register the namespaces and create every type; (namespaces, type nodes by name)."""
    ua = _ua()
    from asyncua.common.structures104 import new_enum, new_struct_field

    ns = Namespaces(di=await server.register_namespace(DI_URI), machinery=await server.register_namespace(MACHINERY_URI),
                    result=await server.register_namespace(RESULT_URI), types=await server.register_namespace(TYPES_URI),
                    bench=await server.register_namespace(bench_uri))
    types: dict[str, Any] = {}
    base_object = server.get_node(ua.NodeId(ua.ObjectIds.BaseObjectType))
    group = await _object_type(base_object, ns.di, DI_FUNCTIONAL_GROUP_TYPE, "FunctionalGroupType")
    item_identification = await _object_type(group, ns.machinery, MACHINERY_ITEM_IDENTIFICATION_TYPE,
                                             "MachineryItemIdentificationType", abstract=True)
    types["MachineIdentificationType"] = await _object_type(item_identification, ns.machinery,
                                                            MACHINE_IDENTIFICATION_TYPE, "MachineIdentificationType")
    types["item_states"] = await _state_machine_type(server, ns.machinery, MACHINERY_ITEM_STATE_TYPE,
                                                     "MachineryItemState_StateMachineType", ITEM_STATES,
                                                     ITEM_TRANSITIONS)
    types["mode_states"] = await _state_machine_type(server, ns.machinery, MACHINERY_OPERATION_MODE_TYPE,
                                                     "MachineryOperationModeStateMachineType", MODE_STATES,
                                                     MODE_TRANSITIONS)

    # Result Transfer: the data types, in the specification's field order
    evaluation = await new_enum(server, ua.NodeId(RESULT_EVALUATION_ENUM, ns.result),
                                ua.QualifiedName("ResultEvaluationEnum", ns.result),
                                ["Undefined", "OK", "NotOK", "NotDecidable"])
    utc, duration = ua.NodeId(ua.ObjectIds.UtcTime), ua.NodeId(ua.ObjectIds.Duration)
    trimmed = ua.NodeId(ua.ObjectIds.TrimmedString)
    times = await _structure(server, ns.result, PROCESSING_TIMES_TYPE, PROCESSING_TIMES_ENCODING,
                             "ProcessingTimesDataType", [
                                 new_struct_field("StartTime", utc), new_struct_field("EndTime", utc),
                                 new_struct_field("AcquisitionDuration", duration, optional=True),
                                 new_struct_field("ProcessingDuration", duration, optional=True)])
    optional_ids = ("StepId", "PartId", "ExternalRecipeId", "InternalRecipeId", "ProductId",
                    "ExternalConfigurationId", "InternalConfigurationId", "JobId")
    meta = await _structure(server, ns.result, RESULT_META_DATA_TYPE, RESULT_META_DATA_ENCODING,
                            "ResultMetaDataType", [
                                new_struct_field("ResultId", trimmed),
                                *(new_struct_field(f, ua.VariantType.Boolean, optional=True)
                                  for f in ("HasTransferableDataOnFile", "IsPartial", "IsSimulated")),
                                new_struct_field("ResultState", ua.VariantType.Int32, optional=True),
                                *(new_struct_field(f, trimmed, optional=True) for f in optional_ids),
                                new_struct_field("CreationTime", utc, optional=True),
                                new_struct_field("ProcessingTimes", times, optional=True),
                                new_struct_field("ResultUri", ua.NodeId(ua.ObjectIds.UriString), array=True,
                                                 optional=True),
                                new_struct_field("ResultEvaluation", evaluation, optional=True),
                                new_struct_field("ResultEvaluationCode", ua.VariantType.Int64, optional=True),
                                new_struct_field("ResultEvaluationDetails", ua.VariantType.LocalizedText,
                                                 optional=True),
                                new_struct_field("FileFormat", ua.VariantType.String, array=True, optional=True)])
    data = await _structure(server, ns.result, RESULT_DATA_TYPE, RESULT_DATA_ENCODING, "ResultDataType", [
        new_struct_field("ResultMetaData", meta),
        new_struct_field("ResultContent", ua.NodeId(ua.ObjectIds.BaseDataType), array=True)])
    ns_types = ns.types
    types["ResultQuantityDataType"] = await _structure(
        server, ns_types, "ResultQuantityDataType", "ResultQuantityDataType.DefaultBinary", "ResultQuantityDataType", [
            new_struct_field("Name", ua.VariantType.String), new_struct_field("Value", ua.VariantType.Double),
            new_struct_field("ExpandedUncertainty", ua.VariantType.Double),
            new_struct_field("CoverageFactor", ua.VariantType.Double),
            new_struct_field("EngineeringUnits", ua.NodeId(ua.ObjectIds.EUInformation)),
            new_struct_field("Text", ua.VariantType.String)])
    await server.load_data_type_definitions()  # the Python classes of the structures (ua.ResultDataType …)
    types.update(ResultMetaDataType=meta, ResultDataType=data)

    # ResultType (a variable type) and the abstract ResultReadyEventType with its Result
    base_variable = server.get_node(ua.NodeId(ua.ObjectIds.BaseDataVariableType))
    result_type = await base_variable.add_variable_type(ua.NodeId(RESULT_TYPE, ns.result),
                                                        ua.QualifiedName("ResultType", ns.result), data.nodeid)
    types["ResultType"] = result_type
    base_event = server.get_node(ua.NodeId(ua.ObjectIds.BaseEventType))
    ready = await _object_type(base_event, ns.result, RESULT_READY_EVENT_TYPE, "ResultReadyEventType", abstract=True)
    await add_result_variable(ready, types, ua.QualifiedName("Result", ns.result), empty_result(),
                              (ua.NodeId(6032, ns.result), ua.NodeId(6033, ns.result), ua.NodeId(6034, ns.result)))
    types["ResultReadyEventType"] = ready
    types["ResultManagementType"] = await _object_type(base_object, ns.result, RESULT_MANAGEMENT_TYPE,
                                                       "ResultManagementType")
    await types["ResultManagementType"].add_reference(ready.nodeid, ua.ObjectIds.GeneratesEvent)

    # this program's types
    types["TorsionTestBenchType"] = await base_object.add_object_type(
        ua.NodeId("TorsionTestBenchType", ns.types), ua.QualifiedName("TorsionTestBenchType", ns.types))
    event = await ready.add_object_type(ua.NodeId("TorsionTestResultReadyEventType", ns.types),
                                        ua.QualifiedName("TorsionTestResultReadyEventType", ns.types))
    for name in EVENT_FIELDS:
        await event.add_property(ua.NodeId(f"TorsionTestResultReadyEventType.{name}", ns.types),
                                 ua.QualifiedName(name, ns.types), ua.Variant("", ua.VariantType.String))
    types["TorsionTestResultReadyEventType"] = event
    return ns, types


#: the fields the bench's ResultReady event adds to the specification's (strings)
EVENT_FIELDS = ("SerialNumber", "Reducer", "Verdict")


async def add_result_variable(parent: Any, types: Mapping[str, Any], qname: Any, value: Any,
                              ids: tuple[Any, Any, Any]) -> Any:
    """A ResultType variable under ``parent`` holding ``value`` (a ResultDataType), with its ResultMetaData and
    that one's ResultId as structured components; ``ids``: the three NodeIds."""
    ua = _ua()

    result_ns = types["ResultType"].nodeid.NamespaceIndex
    result = await add_variable(parent, ids[0], qname, ua.Variant(value, ua.VariantType.ExtensionObject),
                                types["ResultDataType"].nodeid, types["ResultType"].nodeid)
    meta = await add_variable(result, ids[1], ua.QualifiedName("ResultMetaData", result_ns),
                              ua.Variant(value.ResultMetaData, ua.VariantType.ExtensionObject),
                              types["ResultMetaDataType"].nodeid, reference=ua.ObjectIds.HasStructuredComponent)
    await add_variable(meta, ids[2], ua.QualifiedName("ResultId", result_ns),
                       ua.Variant(value.ResultMetaData.ResultId, ua.VariantType.String),
                       ua.NodeId(ua.ObjectIds.TrimmedString), reference=ua.ObjectIds.HasStructuredComponent)
    return result


async def add_variable(parent: Any, node_id: Any, qname: Any, variant: Any, datatype: Any,
                       type_definition: Any = None, reference: int | None = None) -> Any:
    """A read-only variable under ``parent`` (by HasComponent, or ``reference``) with ``type_definition``
    (default BaseDataVariableType)."""
    ua = _ua()

    node = await parent.add_variable(node_id, qname, variant, datatype=datatype)
    if type_definition is not None:
        await node.delete_reference(ua.NodeId(ua.ObjectIds.BaseDataVariableType), ua.ObjectIds.HasTypeDefinition,
                                    forward=True, bidirectional=False)
        await node.add_reference(type_definition, ua.ObjectIds.HasTypeDefinition, bidirectional=False)
    if reference is not None:
        await parent.delete_reference(node.nodeid, ua.ObjectIds.HasComponent, forward=True, bidirectional=True)
        await parent.add_reference(node.nodeid, reference)
    return node


# -- values ----------------------------------------------------------------------------------------------------------
def empty_result() -> Any:
    """A ResultDataType with no result (ResultId "NA", as the specification asks of a system without one)."""
    ua = _ua()

    return ua.ResultDataType(ResultMetaData=ua.ResultMetaDataType(ResultId="NA", ResultState=0), ResultContent=[])


def _utc(iso: str | None) -> datetime | None:
    if not iso:
        return None
    parsed = datetime.fromisoformat(iso)
    return parsed if parsed.tzinfo is not None else parsed.replace(tzinfo=UTC)


def quantity_value(q: ResultQuantity) -> Any:
    """A typed result as a ResultQuantityDataType (the server's class, made by load_data_type_definitions)."""
    ua = _ua()

    return ua.ResultQuantityDataType(Name=q.name, Value=q.value, ExpandedUncertainty=q.expanded,
                                     CoverageFactor=q.k, EngineeringUnits=eu_information(q.unit), Text=q.text)


def result_value(identity: Mapping[str, Any], finished_at_iso: str | None, content_json: str,
                 simulated: bool | None, typed: list[ResultQuantity] | None = None) -> Any:
    """A run as a ResultDataType: its metadata (id, state, times, the reducer as ProductId, the serial number as
    PartId, the test method as InternalRecipeId, compensation and bench model versions as InternalConfigurationId,
    the verdict as ResultEvaluation); in ResultContent its whole identity with the full results as one JSON string,
    then each of ``typed`` as a ResultQuantityDataType."""
    ua = _ua()

    started, finished = _utc(identity.get("started_at")), _utc(finished_at_iso)
    verdict = identity.get("verdict")
    meta = ua.ResultMetaDataType(
        ResultId=str(identity["run_id"]),
        IsSimulated=simulated,
        ResultState=RESULT_STATE.get(str(identity.get("status")), 0),
        PartId=identity.get("serial_number") or None,
        ProductId=identity.get("reducer") or None,
        InternalConfigurationId=(f"compensation {identity.get('compensation_version')}, bench model "
                                 f"{identity.get('bench_model_version')}"),
        ExternalRecipeId=identity.get("plan") or None,
        InternalRecipeId=str((identity.get("method") or {}).get("kind") or "") or None,
        CreationTime=finished or started,
        ProcessingTimes=ua.ProcessingTimesDataType(StartTime=started, EndTime=finished or started)
        if started is not None else None,
        ResultEvaluation=ua.ResultEvaluationEnum(EVALUATION.get(str(verdict), 0)),
        ResultEvaluationDetails=ua.LocalizedText(str(verdict) if verdict else "no verdict", "en"),
    )
    content = [ua.Variant(content_json, ua.VariantType.String)] + [
        ua.Variant(quantity_value(q), ua.VariantType.ExtensionObject) for q in typed or []]
    return ua.ResultDataType(ResultMetaData=meta, ResultContent=content)


def number_or_nan(value: Any) -> float:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value) \
        else math.nan
