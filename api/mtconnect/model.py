"""The MTConnect device model of mebm and the observations of one axis' status.

Each machine is a ``Device``; each monitored axis a ``Linear`` component under it, with
these DataItems (lengths in MILLIMETER: MTConnect has no micrometre unit, 183.4 µm is
0.1834):

| id | category | type | value (REST status field) |
|---|---|---|---|
| ``a<N>_backlash`` | SAMPLE | DISPLACEMENT, statistic AVERAGE | b̄ (``backlash_mean_um``) |
| ``a<N>_backlash_u`` | SAMPLE | x:BACKLASH_UNCERTAINTY | U(b̄), k = 2 (``backlash_mean_uncertainty_um``) |
| ``a<N>_backlash_limit`` | SAMPLE | x:BACKLASH_LIMIT | ``backlash_limit_um`` |
| ``a<N>_restore_below`` | SAMPLE | x:RESTORE_BELOW | the repair target ``restore_below_um`` |
| ``a<N>_tbe_<task>`` | SAMPLE | x:TRANSIENT_BACKLASH_ERROR | ``tasks[].tbe_um`` |
| ``a<N>_temp`` | SAMPLE | TEMPERATURE (CELSIUS) | ``temperature_c`` |
| ``a<N>_cycle_time`` | EVENT | x:LAST_CYCLE_TIME | ``last_cycle_at`` |
| ``a<N>_cycle_status`` | EVENT | x:LAST_CYCLE_STATUS | ``last_cycle_status`` |
| ``a<N>_work_order`` | EVENT | x:MAINTENANCE_ORDER | the active work order, ``STATE:ID:KIND`` or ``NONE`` |
| ``a<N>_backlash_cond`` | CONDITION | DISPLACEMENT | ``state`` / ``message`` |
| ``a<N>_circle_g`` | SAMPLE | x:CIRCULAR_DEVIATION | G of the newest circular test (``circular_test.circular_deviation_um``) |
| ``a<N>_circle_g_u`` | SAMPLE | x:CIRCLE_UNCERTAINTY | U(G), k = 2 |
| ``a<N>_circle_h`` | SAMPLE | x:CIRCULAR_HYSTERESIS | H (``circular_test.hysteresis_um``) |
| ``a<N>_circle_h_u`` | SAMPLE | x:CIRCLE_UNCERTAINTY | U(H), k = 2 |
| ``a<N>_circle_spike`` | SAMPLE | x:REVERSAL_SPIKE | the axis' largest reversal spike, the measured TBE (``circular_test.spike_um``) |
| ``a<N>_circle_spike_u`` | SAMPLE | x:CIRCLE_UNCERTAINTY | U(spike), k = 2 |
| ``a<N>_circle_agreement`` | EVENT | x:CIRCLE_AGREEMENT | the spikes against Eq. 8 at b̄: agree, larger, smaller (``circular_test.agreement``) |

The condition is Normal (OK), Warning (WARNING), Fault (ALARM) or Unavailable (UNKNOWN);
its ``nativeCode`` is the state as REST says it and its text the status message. The
circular test's observations carry the test's time and are UNAVAILABLE until the axis has
one (api.service.circles.axis_summary).
"""

from __future__ import annotations

import math
import re
import uuid
from dataclasses import dataclass
from datetime import datetime, timezone
from urllib.parse import urlsplit

from api.service.circles import axis_summary
from api.service.status import AxisStatus, state_and_message

X_NS = "urn:mebm:MTConnectStreams:2.4"  # the x: extension namespace of the streams
X_DEVICES_NS = "urn:mebm:MTConnectDevices:2.4"  # ...declared in the probe, whose x: types name it
CONDITION_LEVEL = {"OK": "Normal", "WARNING": "Warning", "ALARM": "Fault", "UNKNOWN": "Unavailable"}


@dataclass(frozen=True)
class DataItem:
    id: str
    category: str  # SAMPLE, EVENT or CONDITION
    type: str  # DISPLACEMENT, x:BACKLASH_LIMIT...
    element: str  # the observation's element in the streams: Displacement, x:BacklashLimit
    name: str | None = None
    units: str | None = None
    statistic: str | None = None
    description: str = ""


@dataclass(frozen=True)
class Component:
    """One axis: a ``Linear`` component."""

    id: str
    name: str
    axis_id: int
    data_items: tuple[DataItem, ...]


@dataclass(frozen=True)
class Device:
    """One machine."""

    id: str
    name: str
    uuid: str
    data_items: tuple[DataItem, ...]
    components: tuple[Component, ...]


@dataclass(frozen=True)
class Value:
    """One observed value: ``value`` None is UNAVAILABLE. For a condition, ``level`` is
    Normal/Warning/Fault/Unavailable, ``value`` the message and ``native_code`` the state."""

    data_item: DataItem
    timestamp: datetime
    value: float | str | None
    level: str | None = None
    native_code: str | None = None
    condition_id: str | None = None


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "_"


def device_uuid(machine: str, instance: str) -> str:
    """Stable across restarts and unique across installations: derived from the
    installation's name (api.service.installation) and the machine's, so two plants'
    ``vmc-1`` are two devices to one MES."""
    return str(uuid.uuid5(uuid.NAMESPACE_URL, f"urn:mebm:{instance}:machine:{machine}"))


def device_for(machine_id: int, machine: str, components: tuple[Component, ...], instance: str) -> Device:
    avail = DataItem(f"m{machine_id}_avail", "EVENT", "AVAILABILITY", "Availability", name="avail")
    return Device(f"m{machine_id}", machine, device_uuid(machine, instance), (avail,), components)


def component_for(st: AxisStatus) -> Component:
    """The Linear component of an axis, with one TBE DataItem per current machining task."""
    a = f"a{st.axis.id}"
    items = [
        DataItem(f"{a}_backlash", "SAMPLE", "DISPLACEMENT", "Displacement", name="backlash_mean",
                 units="MILLIMETER", statistic="AVERAGE", description="mean backlash b̄ of the last good measurement"),
        DataItem(f"{a}_backlash_u", "SAMPLE", "x:BACKLASH_UNCERTAINTY", "x:BacklashUncertainty",
                 name="backlash_mean_uncertainty", units="MILLIMETER",
                 description="expanded (k = 2) uncertainty of b̄"),
        DataItem(f"{a}_backlash_limit", "SAMPLE", "x:BACKLASH_LIMIT", "x:BacklashLimit", name="backlash_limit",
                 units="MILLIMETER", description="the backlash at which the binding task's TBE reaches its tolerance"),
        DataItem(f"{a}_restore_below", "SAMPLE", "x:RESTORE_BELOW", "x:RestoreBelow", name="restore_below",
                 units="MILLIMETER", description="the repair target: the warning level in backlash (the backlash "
                                                 "limit times the warning fraction), so that the repaired axis does "
                                                 "not warn again at once"),
    ]
    seen = set()
    for task in st.axis.tasks:
        slug = _slug(task.name)
        while slug in seen:
            slug += "_"
        seen.add(slug)
        items.append(DataItem(f"{a}_tbe_{slug}", "SAMPLE", "x:TRANSIENT_BACKLASH_ERROR", "x:TransientBacklashError",
                              name=task.name, units="MILLIMETER",
                              description=f"TBE of the task {task.name!r} (tolerance {task.tolerance_um:g} µm)"))
    items += [
        DataItem(f"{a}_temp", "SAMPLE", "TEMPERATURE", "Temperature", name="temperature", units="CELSIUS",
                 description="temperature at the last good measurement"),
        DataItem(f"{a}_cycle_time", "EVENT", "x:LAST_CYCLE_TIME", "x:LastCycleTime", name="last_cycle_time",
                 description="when the last measurement cycle ended"),
        DataItem(f"{a}_cycle_status", "EVENT", "x:LAST_CYCLE_STATUS", "x:LastCycleStatus", name="last_cycle_status",
                 description="ok, failed, interrupted, queued or running"),
        DataItem(f"{a}_work_order", "EVENT", "x:MAINTENANCE_ORDER", "x:MaintenanceOrder", name="work_order",
                 description="the active work order as STATE:ID:KIND, or NONE"),
    ]
    items += _circle_items(a)
    items.append(DataItem(f"{a}_backlash_cond", "CONDITION", "DISPLACEMENT", "", name="maintenance",
                          description="the maintenance state: Normal (OK), Warning, Fault (ALARM), Unavailable (UNKNOWN)"))
    return Component(a, st.axis.name, st.axis.id, tuple(items))


def _circle_items(a: str) -> list[DataItem]:
    """The newest circular test (ISO 230-4) of a plane with the axis, beside its TBE."""
    def u(key: str, of: str) -> DataItem:
        return DataItem(f"{a}_circle_{key}_u", "SAMPLE", "x:CIRCLE_UNCERTAINTY", "x:CircleUncertainty",
                        name=f"{of}_uncertainty", units="MILLIMETER", description=f"expanded (k = 2) uncertainty of {of}")

    return [
        DataItem(f"{a}_circle_g", "SAMPLE", "x:CIRCULAR_DEVIATION", "x:CircularDeviation", name="circular_deviation",
                 units="MILLIMETER", description="circular deviation G (ISO 230-4, least-squares centre) of the "
                                                 "newest circular test"),
        u("g", "circular_deviation"),
        DataItem(f"{a}_circle_h", "SAMPLE", "x:CIRCULAR_HYSTERESIS", "x:CircularHysteresis", name="circular_hysteresis",
                 units="MILLIMETER", description="circular hysteresis H (ISO 230-4) between the two directions"),
        u("h", "circular_hysteresis"),
        DataItem(f"{a}_circle_spike", "SAMPLE", "x:REVERSAL_SPIKE", "x:ReversalSpike", name="reversal_spike",
                 units="MILLIMETER", description="the axis' largest reversal spike in the newest circular test: "
                                                 "its measured TBE"),
        u("spike", "reversal_spike"),
        DataItem(f"{a}_circle_agreement", "EVENT", "x:CIRCLE_AGREEMENT", "x:CircleAgreement", name="circle_agreement",
                 description="the spikes against Eq. 8's TBE at b̄: agree, larger or smaller"),
    ]


_CIRCLE_FIELDS = {"circle_g": "circular_deviation_um", "circle_g_u": "circular_deviation_uncertainty_um",
                  "circle_h": "hysteresis_um", "circle_h_u": "hysteresis_uncertainty_um",
                  "circle_spike": "spike_um", "circle_spike_u": "spike_uncertainty_um"}


def _utc(t: datetime | None) -> datetime | None:
    if t is None:
        return None
    return t.replace(tzinfo=timezone.utc) if t.tzinfo is None else t.astimezone(timezone.utc)


def _mm(um: float | None) -> float | None:
    # to 0.1 nm: 183.4 µm is 0.1834, not 0.18340000000000001
    return None if um is None or not math.isfinite(um) else round(um / 1000.0, 7)


# an IPv4 address, a bracketed IPv6 one, or a host name with a port: what a connection failure names
_ADDRESS = re.compile(r"\b\d{1,3}(?:\.\d{1,3}){3}(?::\d+)?\b|\[[0-9A-Fa-f:.]+\](?::\d+)?"
                      r"|\b(?:localhost|[A-Za-z0-9-]+(?:\.[A-Za-z0-9-]+)+):\d{2,5}\b")


def public_message(message: str, controller_url: str | None) -> str:
    """``message`` without the controller's address: the agent answers anyone on the shop
    network, and a failure text ("connection to 10.0.4.21:502 refused") would map the
    controllers behind it. The REST status (behind a key) keeps the whole text."""
    if controller_url:
        parts = urlsplit(controller_url)
        for piece in (controller_url, parts.netloc, parts.hostname, parts.path if parts.scheme.endswith("rtu") else ""):
            if piece and len(piece) > 1:
                message = message.replace(piece, "the controller")
    return _ADDRESS.sub("the controller", message)


def values_for(st: AxisStatus, comp: Component, now: datetime) -> list[Value]:
    """The value of each of ``comp``'s DataItems in the status ``st``; measured values carry
    the measurement's time, the cycle events the cycle's time."""
    latest, d = st.latest, st.decision
    measured_at = _utc(latest.measured_at) if latest is not None else None
    cycle_at = _utc(st.last_cycle_at)
    t_meas = measured_at or now
    rt = latest.round_trip if latest is not None else None
    tbe = {x.task.name: x.tbe_um for x in d.assessments} if d is not None else {}
    state, message = state_and_message(st)
    message = public_message(message, st.axis.settings.controller_url)
    circle = axis_summary(st.circle, st.axis.name)
    t_circle = _utc(circle["measured_at"]) if circle else now
    out = []
    for di in comp.data_items:
        suffix = di.id[len(comp.id) + 1:]
        if suffix == "backlash":
            v = _mm(rt.backlash.mean_um) if rt is not None else None
        elif suffix == "backlash_u":
            v = _mm(rt.backlash_mean_uncertainty_um) if rt is not None and rt.budgets else None
        elif suffix == "backlash_limit":
            v = _mm(d.backlash_limit_um) if d is not None else None
        elif suffix == "restore_below":
            target = d.repair_target if d is not None else None
            v = _mm(target.restore_below_um) if target is not None else None
        elif suffix.startswith("tbe_"):
            v = _mm(tbe.get(di.name))
        elif suffix == "temp":
            v = latest.temperature_c if latest is not None else None
        elif suffix == "cycle_time":
            out.append(Value(di, cycle_at or now, iso(cycle_at) if cycle_at else None))
            continue
        elif suffix == "cycle_status":
            out.append(Value(di, cycle_at or now, st.last_cycle_status))
            continue
        elif suffix == "work_order":
            o = st.work_order
            out.append(Value(di, _utc(o.transitions[-1].at) if o is not None and o.transitions else now,
                             f"{o.state.upper()}:{o.id}:{o.kind}" if o is not None else "NONE"))
            continue
        elif suffix in _CIRCLE_FIELDS:
            out.append(Value(di, t_circle, _mm(circle[_CIRCLE_FIELDS[suffix]]) if circle else None))
            continue
        elif suffix == "circle_agreement":
            out.append(Value(di, t_circle, circle["agreement"] if circle else None))
            continue
        elif suffix == "backlash_cond":
            c_state, c_message, c_at = state, message, measured_at or cycle_at or now
            if (st.active_alert_id is not None and circle and circle.get("state") in ("WARNING", "ALARM")
                    and state not in ("WARNING", "ALARM")):
                # the active alert is the circular test's (the round trip's decision does not
                # raise one): the condition is the direct measurement's
                c_state, c_at = circle["state"], t_circle
                c_message = (f"circular test {circle['id']}: reversal spike {circle['spike_um']:.1f} µm on task "
                             f"{circle['task']} ({circle['state']})")
            cid = f"alert-{st.active_alert_id}" if st.active_alert_id is not None else f"{comp.id}-{c_state.lower()}"
            out.append(Value(di, c_at, c_message, level=CONDITION_LEVEL[c_state], native_code=c_state,
                             condition_id=cid))
            continue
        else:  # pragma: no cover - every DataItem of component_for is handled above
            raise AssertionError(di.id)
        out.append(Value(di, t_meas, v))
    return out


def iso(t: datetime) -> str:
    """ISO 8601 UTC with a Z, as MTConnect timestamps are written."""
    t = _utc(t)
    return t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
