"""The address space: Objects/Machines/<machine>/<axis>/{BacklashMean, ...} and an
OPC 40501-style Notification/Prognoses list per machine. Runs on the server's loop.

Every variable is read-only (AccessLevel and UserAccessLevel CurrentRead only). The
micrometre values are AnalogItemType with EngineeringUnits per OPC UA Part 8 (UNECE
Recommendation 20 common code ``4H``, micrometre)."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone

from asyncua import Server, ua

from api.opcua.values import AxisValues

NAMESPACE_URI = "urn:mebm"  # the namespace of an installation is this, a colon and its name (namespace_uri)
UNECE_URI = "http://www.opcfoundation.org/UA/units/un/cefact"
EU_RANGE_UM = (0.0, 1000.0)  # the EURange AnalogItemType requires: the range of normal operation
READ = ua.AccessLevel.CurrentRead.mask


def unece_unit_id(code: str) -> int:
    """Part 8 5.6.3: the UnitId is the common code's characters, 8 bits each, big-endian."""
    uid = 0
    for c in code.strip():
        uid = (uid << 8) | ord(c)
    return uid


MICROMETRE = ua.EUInformation(NamespaceUri=UNECE_URI, UnitId=unece_unit_id("4H"),
                              DisplayName=ua.LocalizedText("µm"), Description=ua.LocalizedText("micrometre"))


def namespace_uri(instance: str) -> str:
    """The namespace of the installation ``instance`` (api.service.installation): two
    installations' servers never offer one node id for two machines to one client."""
    return f"{NAMESPACE_URI}:{instance}"


def segment(name: str) -> str:
    """A machine's or a task's name as one segment of a string NodeId: ``/`` and ``%`` are
    escaped, so a name that reads like a path (``x/Notification``) names a node of its own
    and never one the address space uses for something else."""
    return name.replace("%", "%25").replace("/", "%2F")


def _dv(value, vtype: ua.VariantType, source: datetime | None = None) -> ua.DataValue:
    """A DataValue; a missing value is BadWaitingForInitialData (no measurement gives it yet)."""
    now = datetime.now(timezone.utc)
    if value is None:
        return ua.DataValue(ua.Variant(), StatusCode=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData),
                            ServerTimestamp=now)  # fmt: skip
    return ua.DataValue(ua.Variant(value, vtype), SourceTimestamp=source or now, ServerTimestamp=now)


@dataclass
class AxisNodes:
    obj: object
    backlash: object
    uncertainty: object
    limit: object
    restore_below: object
    state: object
    message: object
    measured_at: object
    tbe_folder: object
    circle: dict  # the CircularTest folder's variables: circular_test key -> (variable, type)
    tbe: dict = field(default_factory=dict)  # task name -> variable


# the CircularTest folder of an axis: (circular_test key, browse name, type, description)
CIRCLE_VARIABLES = (
    ("circular_deviation_um", "CircularDeviation", ua.VariantType.Double,
     "circular deviation G (ISO 230-4, least-squares centre) of the newest circular test, µm"),
    ("circular_deviation_uncertainty_um", "CircularDeviationUncertainty", ua.VariantType.Double,
     "expanded (k = 2) uncertainty of G, µm"),
    ("hysteresis_um", "CircularHysteresis", ua.VariantType.Double,
     "circular hysteresis H (ISO 230-4) between the two directions, µm"),
    ("hysteresis_uncertainty_um", "CircularHysteresisUncertainty", ua.VariantType.Double,
     "expanded (k = 2) uncertainty of H, µm"),
    ("spike_um", "ReversalSpike", ua.VariantType.Double,
     "the axis' largest reversal spike: its measured TBE, µm"),
    ("spike_uncertainty_um", "ReversalSpikeUncertainty", ua.VariantType.Double,
     "expanded (k = 2) uncertainty of the spike, µm"),
    ("agreement", "Agreement", ua.VariantType.String,
     "the spikes against Eq. 8's TBE at b̄: agree, larger or smaller (null: no b̄ to compare)"),
    ("measured_at", "MeasuredAt", ua.VariantType.DateTime, "time of the newest circular test (UTC)"),
)


@dataclass
class MachineNodes:
    obj: object
    prognoses: object
    entries: dict = field(default_factory=dict)  # axis id -> prognosis object


class AddressSpace:
    def __init__(self, server: Server, idx: int):
        self.server = server
        self.idx = idx
        self.machines_folder = None
        self.machines: dict[str, MachineNodes] = {}
        self.axes: dict[int, AxisNodes] = {}

    def _id(self, s: str) -> ua.NodeId:
        return ua.NodeId(s, self.idx)

    def _qn(self, name: str) -> ua.QualifiedName:
        return ua.QualifiedName(name, self.idx)

    async def build(self) -> None:
        self.machines_folder = await self.server.nodes.objects.add_folder(self._id("Machines"), self._qn("Machines"))

    async def _variable(self, parent, sid: str, name: str, vtype: ua.VariantType, description: str,
                        analog: bool = False):  # fmt: skip
        item = ua.AddNodesItem()
        item.RequestedNewNodeId = self._id(sid)
        item.BrowseName = self._qn(name)
        item.NodeClass = ua.NodeClass.Variable
        item.ParentNodeId = parent.nodeid
        item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasComponent)
        item.TypeDefinition = ua.NodeId(ua.ObjectIds.AnalogItemType if analog else ua.ObjectIds.BaseDataVariableType)
        attrs = ua.VariableAttributes()
        attrs.DisplayName = ua.LocalizedText(name)
        attrs.Description = ua.LocalizedText(description)
        attrs.DataType = ua.NodeId(getattr(ua.ObjectIds, vtype.name))
        attrs.ValueRank = ua.ValueRank.Scalar
        attrs.Value = ua.Variant()  # null until the first measurement
        attrs.AccessLevel = attrs.UserAccessLevel = READ
        attrs.WriteMask = attrs.UserWriteMask = 0
        attrs.Historizing = False
        item.NodeAttributes = attrs
        (res,) = await parent.session.add_nodes([item])
        res.StatusCode.check()
        node = self.server.get_node(res.AddedNodeId)
        if analog:
            await node.add_property(self._id(f"{sid}/EngineeringUnits"), ua.QualifiedName("EngineeringUnits", 0),
                                    MICROMETRE, datatype=ua.NodeId(ua.ObjectIds.EUInformation))
            await node.add_property(self._id(f"{sid}/EURange"), ua.QualifiedName("EURange", 0),
                                    ua.Range(Low=EU_RANGE_UM[0], High=EU_RANGE_UM[1]), datatype=ua.NodeId(ua.ObjectIds.Range))
        await self.server.write_attribute_value(node.nodeid, _dv(None, vtype))
        return node

    async def _machine(self, name: str) -> MachineNodes:
        m = self.machines.get(name)
        if m is None:
            base = f"Machines/{segment(name)}"
            obj = await self.machines_folder.add_object(self._id(base), self._qn(name))
            notification = await obj.add_folder(self._id(f"{base}/Notification"), self._qn("Notification"))
            prognoses = await notification.add_folder(self._id(f"{base}/Notification/Prognoses"), self._qn("Prognoses"))
            m = self.machines[name] = MachineNodes(obj, prognoses)
        return m

    async def _axis(self, v: AxisValues) -> AxisNodes:
        a = self.axes.get(v.axis_id)
        if a is None:
            m = await self._machine(v.machine)
            base = f"Axes/{v.axis_id}"
            obj = await m.obj.add_object(self._id(base), self._qn(v.axis))
            D, S = ua.VariantType.Double, ua.VariantType.String  # noqa: N806
            a = self.axes[v.axis_id] = AxisNodes(
                obj=obj,
                backlash=await self._variable(obj, f"{base}/BacklashMean", "BacklashMean", D,
                                              "mean backlash b̄ of the last good measurement, µm", analog=True),
                uncertainty=await self._variable(obj, f"{base}/BacklashMeanUncertainty", "BacklashMeanUncertainty", D,
                                                 "expanded (k = 2) uncertainty of b̄, µm", analog=True),
                limit=await self._variable(obj, f"{base}/BacklashLimit", "BacklashLimit", D,
                                           "largest b̄ at which every task's TBE stays within tolerance, µm",
                                           analog=True),
                restore_below=await self._variable(
                    obj, f"{base}/RestoreBelow", "RestoreBelow", D,
                    "the b̄ a repair must restore the chain below: the warning level, BacklashLimit times the "
                    "axis' warning fraction, so that the repaired axis does not warn again at once, µm", analog=True),
                state=await self._variable(obj, f"{base}/State", "State", S, "OK, WARNING, ALARM or UNKNOWN"),
                message=await self._variable(obj, f"{base}/Message", "Message", S, "the state, explained"),
                measured_at=await self._variable(obj, f"{base}/MeasuredAt", "MeasuredAt", ua.VariantType.DateTime,
                                                 "time of the last good measurement (UTC)"),
                tbe_folder=await obj.add_folder(self._id(f"{base}/TBE"), self._qn("TBE")),
                circle=await self._circle(obj, base),
            )  # fmt: skip
        return a

    async def _circle(self, obj, base: str) -> dict:
        """The axis' newest circular test (ISO 230-4), beside the TBE folder."""
        folder = await obj.add_folder(self._id(f"{base}/CircularTest"), self._qn("CircularTest"))
        out = {}
        for key, name, vtype, description in CIRCLE_VARIABLES:
            analog = vtype is ua.VariantType.Double
            out[key] = (await self._variable(folder, f"{base}/CircularTest/{name}", name, vtype, description,
                                             analog=analog), vtype)
        return out

    async def _tasks(self, a: AxisNodes, v: AxisValues) -> None:
        names = {t.name for t in v.tasks}
        for gone in [n for n in a.tbe if n not in names]:  # a task removed through the API
            await self.server.delete_nodes([a.tbe.pop(gone)], recursive=True)
        for t in v.tasks:
            node = a.tbe.get(t.name)
            if node is None:
                sid = f"Axes/{v.axis_id}/TBE/{segment(t.name)}"
                node = a.tbe[t.name] = await self._variable(
                    a.tbe_folder, sid, t.name, ua.VariantType.Double,
                    f"transient backlash error of task {t.name!r} at the measured b̄, µm", analog=True)
                await node.add_property(self._id(f"{sid}/Tolerance"), self._qn("Tolerance"), t.tolerance_um,
                                        ua.VariantType.Double)
            await self.server.write_attribute_value(node.nodeid, _dv(t.tbe_um, ua.VariantType.Double, v.measured_at))

    async def _prognosis(self, v: AxisValues) -> None:
        m = await self._machine(v.machine)
        entry = m.entries.get(v.axis_id)
        if v.predicted_time is None:
            if entry is not None:
                await self.server.delete_nodes([m.entries.pop(v.axis_id)], recursive=True)
            return
        activity = ua.LocalizedText(
            f"axis {v.axis}: restore the backlash below {v.restore_below_um:.1f} µm ({v.restore_below_explanation})"
            if v.restore_below_um is not None else f"axis {v.axis}: restore the backlash")
        sid = f"Machines/{segment(v.machine)}/Notification/Prognoses/{v.axis_id}"
        props = (("PredictedTime", v.predicted_time, ua.VariantType.DateTime),  # as 40501's PrognosisType
                 ("Activity", activity, ua.VariantType.LocalizedText),  # as its MaintenancePrognosisType
                 ("Source", v.prediction_source, ua.VariantType.String))  # fmt: skip
        if entry is None:
            entry = m.entries[v.axis_id] = await m.prognoses.add_object(self._id(sid), self._qn(f"{v.axis}Backlash"))
            for name, val, vt in props:
                await entry.add_property(self._id(f"{sid}/{name}"), self._qn(name), val, vt)
        else:
            for name, val, vt in props:
                await self.server.write_attribute_value(self._id(f"{sid}/{name}"), _dv(val, vt))

    async def apply(self, v: AxisValues) -> None:
        a = await self._axis(v)
        D = ua.VariantType.Double  # noqa: N806
        w = self.server.write_attribute_value
        await w(a.backlash.nodeid, _dv(v.backlash_mean_um, D, v.measured_at))
        await w(a.uncertainty.nodeid, _dv(v.backlash_mean_uncertainty_um, D, v.measured_at))
        await w(a.limit.nodeid, _dv(v.backlash_limit_um, D, v.measured_at))
        await w(a.restore_below.nodeid, _dv(v.restore_below_um, D, v.measured_at))
        await w(a.state.nodeid, _dv(v.state, ua.VariantType.String))
        await w(a.message.nodeid, _dv(v.message, ua.VariantType.String))
        await w(a.measured_at.nodeid, _dv(v.measured_at, ua.VariantType.DateTime))
        await self._tasks(a, v)
        c = v.circle
        t = c["measured_at"] if c else None
        for key, (node, vtype) in a.circle.items():
            await w(node.nodeid, _dv(c.get(key) if c else None, vtype, t if key != "measured_at" else None))
        await self._prognosis(v)
