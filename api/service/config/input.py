"""What an admin may configure (machines, axes, machining tasks, schedules), validated
once for every writer: the REST API's request bodies (``api.rest.schemas`` re-exports
these models) and the dashboard's forms (``api.ui``) both validate with these models and
build the stored settings with the functions below, so a value refused by one is refused
by the other with the same message. The TOML file (:mod:`api.service.config.loading`) is read at
start-up with its own option names; an axis' controller URL from it is completed and checked
here (:func:`with_modbus_profile`, :func:`checked_canopen_controller`, :func:`with_trigger`).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Literal
from urllib.parse import urlencode, urlsplit

from pydantic import BaseModel, ConfigDict, Field, model_validator

from api.service.config.settings import SIM_CONTROLLER, ConfigError
from core.criteria.uncertainty import (
    DEFAULT_SCALE_ACCURACY_UM,
    DEFAULT_SCALE_ACCURACY_UM_PER_M,
    DEFAULT_THERMOMETER_CLASS,
    STEEL_EXPANSION_PER_K,
    Instruments,
)
from core.dataset import AxisSpec
from core.errors import InputError, MebmError
from core.tbe import MachiningTask
from storage.db import AxisSettings, Schedule


class In(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class MachineIn(In):
    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9][A-Za-z0-9 ._-]*$")
    description: str = Field("", max_length=2000)


class TaskIn(In):
    """A machining task. ``circle`` needs ``radius_mm``; ``line`` needs ``angle_deg``
    (to the reversely engaged axis, -90..90)."""

    name: str = Field(min_length=1, max_length=100, pattern=r"\S", description="not blank")
    profile: Literal["circle", "line"]
    feed_mm_min: float = Field(ge=0.1, le=100000)
    tolerance_um: float = Field(ge=0.01, le=10000)
    radius_mm: float | None = Field(None, ge=0.01, le=100000)
    angle_deg: float | None = Field(None, gt=-90, lt=90)

    @model_validator(mode="after")
    def _shape(self):
        if self.profile == "circle" and self.radius_mm is None:
            raise ValueError("radius_mm is required for a circle task")
        if self.profile == "line" and self.angle_deg is None:
            raise ValueError("angle_deg is required for a line task")
        return self


class TasksIn(In):
    tasks: list[TaskIn] = Field(min_length=1, max_length=50)



class ScheduleIn(In):
    """Every ``interval_s`` seconds or on a 5-field cron expression (UTC); not both.
    Neither (or ``enabled: false``): manual cycles only."""

    interval_s: float | None = Field(None, ge=1, le=1e8)
    cron: str | None = Field(None, min_length=9, max_length=120)
    enabled: bool = True

    @model_validator(mode="after")
    def _one(self):
        if self.interval_s is not None and self.cron is not None:
            raise ValueError("give interval_s or cron, not both")
        return self



MAX_TRAVEL_MM = 100_000.0  # 100 m: beyond the largest gantry
MAX_PROGRAM_MIN = 60.0  # one measurement round trip: an hour at most


def link_local_problem(url: str) -> str | None:
    """Why a controller URL points at a link-local address (169.254.0.0/16, fe80::/10:
    where cloud metadata services live), or None. Only literal addresses are checked."""
    import ipaddress
    from urllib.parse import urlsplit

    try:
        host = urlsplit(url).hostname or ""
        addr = ipaddress.ip_address(host)
    except ValueError:
        return None
    if addr.is_link_local:
        return (f"controller_url (={url!r}) points at the link-local address {addr}; set "
                "limits.allow_link_local_controllers = true if the controller really is there")
    return None


class AxisIn(In):
    name: str = Field(min_length=1, max_length=20, pattern=r"^[a-z][a-z0-9_]*$")
    transmission_mm_per_rev: float = Field(ge=0.001, le=10000)
    screw_lead_mm: float = Field(ge=0.001, le=10000)
    position_gain_per_s: float = Field(ge=0.01, le=10000)
    travel_mm: tuple[float, float]
    controller_url: str = Field(min_length=3, max_length=300, pattern=r"^(sim|modbus://.+|modbus\+rtu://.+|sim://.+|canopen://.+)$")
    measure_feed_mm_min: float = Field(2000.0, ge=0.1, le=100000)
    measure_acceleration_mm_s2: float = Field(500.0, ge=0.1, le=100000)
    warning_fraction: float = Field(0.9, ge=0.01, le=1)
    decision_rule: Literal["simple", "guarded"] = Field(
        "guarded", description="ISO 14253-1: 'guarded' needs TBE ± U clear of a threshold to call it")
    worst_case_temperature_c: float = Field(
        30.0, ge=-50, le=100, description="the shop temperature the prognosis' date is computed for")
    scale_accuracy_um: float = Field(
        DEFAULT_SCALE_ACCURACY_UM, gt=0, le=1000, description="the linear scale's short-range accuracy, ± µm")
    scale_accuracy_um_per_m: float = Field(
        DEFAULT_SCALE_ACCURACY_UM_PER_M, gt=0, le=1000, description="the linear scale's accuracy class, ± µm per metre")
    thermometer_class: Literal["AA", "A", "B", "C"] = Field(
        DEFAULT_THERMOMETER_CLASS, description="IEC 60751 class of the Pt100 thermometer")
    thermal_expansion_per_k: float = Field(
        STEEL_EXPANSION_PER_K, gt=0, le=1e-4, description="the axis' thermal expansion coefficient, 1/K")
    schedule: ScheduleIn = Field(default_factory=ScheduleIn)
    tasks: list[TaskIn] = Field(default_factory=list, max_length=50)

    @model_validator(mode="after")
    def _travel(self):
        a, b = self.travel_mm
        if not (abs(a) <= MAX_TRAVEL_MM and abs(b) <= MAX_TRAVEL_MM and b - a >= 10):
            raise ValueError(f"travel_mm (={[a, b]}) must be [start, end] with end - start >= 10 mm and "
                             f"|start|, |end| <= {MAX_TRAVEL_MM:g} mm")
        round_trip_min = 2 * (b - a) / self.measure_feed_mm_min
        if round_trip_min > MAX_PROGRAM_MIN:
            raise ValueError(f"measure_feed_mm_min (={self.measure_feed_mm_min:g}) over travel_mm (={[a, b]}) makes a "
                             f"measurement program of {round_trip_min:.0f} min; at most {MAX_PROGRAM_MIN:g} min")
        return self


def machining_tasks(body: list[TaskIn], gain_per_s: float) -> tuple[MachiningTask, ...]:
    """The tasks of an axis with position gain ``gain_per_s``; a tolerance the model cannot
    map to a backlash limit is refused now, not at the next cycle (``tasks[i]: ...``)."""
    tasks = []
    for i, t in enumerate(body):
        try:
            task = MachiningTask(name=t.name, profile=t.profile, feed_mm_min=t.feed_mm_min, gain_per_s=gain_per_s,
                                 tolerance_um=t.tolerance_um, radius_mm=t.radius_mm, angle_deg=t.angle_deg)
            task.backlash_limit_um()
        except MebmError as exc:
            raise type(exc)(f"tasks[{i}]: {exc}") from exc
        tasks.append(task)
    return tuple(tasks)


def schedule_of(body: ScheduleIn) -> Schedule:
    """The schedule; a cron expression the scheduler cannot read is refused here."""
    sch = Schedule(body.interval_s, body.cron, body.enabled)
    if sch.cron is not None:
        from api.service.config.schedule import make_trigger

        make_trigger(sch)
    return sch


# controller URL options that name a file, read from the profiles folder ([storage] profiles_dir)
# when the URL comes from the API or the dashboard: a Modbus register profile, a CANopen EDS/DCF
FILE_OPTIONS = ("profile", "eds")


def _named_files(url: str) -> list[tuple[str, str]]:
    """The (option, value) of every file named in the URL's query (the built-in profile is none)."""
    from urllib.parse import parse_qs

    from acquisition.modbus.profile import BUILTIN

    query = parse_qs(urlsplit(url).query, keep_blank_values=True)
    return [(key, v) for key in FILE_OPTIONS for v in query.get(key, []) if not (key == "profile" and v == BUILTIN)]


def check_profile_name(url: str) -> None:
    """A file named in a controller URL sent to the API (a register profile ``profile=``, a
    CANopen EDS/DCF ``eds=``) is a plain file name inside the profiles folder (``[storage]
    profiles_dir``): no folder, no absolute path, no ``..``; the file is then read as a
    regular file of bounded size (:mod:`acquisition.files`). Absolute paths are for the
    configuration file (``modbus_profile``, an axis' ``canopen`` table), which the operator writes."""
    for key, name in _named_files(url):
        if not name or "/" in name or "\\" in name or name.startswith(".") or "\0" in name:
            raise InputError(f"controller_url: {key} (={name[:100]!r}) must be a file name, without a folder, "
                             "an absolute path or '..': a file in the profiles folder ([storage] profiles_dir)")


def resolve_profile(url: str, profiles_dir: Path) -> str:
    """``url`` with a bare ``profile=NAME`` or ``eds=NAME`` replaced by ``profiles_dir/NAME``
    (what the drivers open); a URL without one, or whose file is a path (written in the
    configuration file by the operator), is returned as it is."""
    bare = {(k, n) for k, n in _named_files(url) if n and "/" not in n and "\\" not in n}
    if not bare:
        return url
    from urllib.parse import parse_qsl, urlencode

    head, _, rest = url.partition("?")  # not urlunsplit: it drops the empty authority of modbus+rtu:///dev/…
    query, hash_, fragment = rest.partition("#")
    pairs = [(k, str(Path(profiles_dir) / v) if (k, v) in bare else v)
             for k, v in parse_qsl(query, keep_blank_values=True)]
    return f"{head}?{urlencode(pairs, safe='/:')}{hash_}{fragment}"


def check_controller_url(url: str, profiles_dir: Path) -> None:
    """Refuse a controller URL whose options a cycle would refuse (unknown option, trigger,
    passive settings, device id, serial line, a register profile that does not load from
    ``profiles_dir``, a CANopen mapping), as a 422 naming it, when the axis is created
    rather than at its first cycle. Builds the driver without connecting (drivers connect
    when a cycle opens them)."""
    if url == "sim":  # the embedded simulator: no driver of its own
        return
    check_profile_name(url)
    from acquisition.url import driver_from_url

    try:
        driver_from_url(resolve_profile(url, profiles_dir))
    except MebmError as exc:
        raise InputError(f"controller_url: {exc}") from exc


def axis_settings(body: AxisIn, *, allow_link_local: bool, profiles_dir: Path) -> AxisSettings:
    """The stored settings of a new axis (``allow_link_local``: limits.allow_link_local_controllers;
    ``profiles_dir``: where a ``profile=NAME`` of its controller URL is read from)."""
    problem = link_local_problem(body.controller_url)
    if problem and not allow_link_local:
        raise InputError(problem)
    check_controller_url(body.controller_url, profiles_dir)
    try:
        spec = AxisSpec(body.name, body.transmission_mm_per_rev, body.screw_lead_mm, body.position_gain_per_s,
                        tuple(body.travel_mm))
    except MebmError as exc:
        raise type(exc)(str(exc)) from exc
    return AxisSettings(
        spec=spec, controller_url=body.controller_url, measure_feed_mm_min=body.measure_feed_mm_min,
        measure_acceleration_mm_s2=body.measure_acceleration_mm_s2, warning_fraction=body.warning_fraction,
        decision_rule=body.decision_rule, worst_case_temperature_c=body.worst_case_temperature_c,
        schedule=schedule_of(body.schedule), tasks=machining_tasks(body.tasks, body.position_gain_per_s),
        instruments=Instruments(scale_accuracy_um=body.scale_accuracy_um,
                                scale_accuracy_um_per_m=body.scale_accuracy_um_per_m,
                                thermometer_class=body.thermometer_class,
                                thermal_expansion_per_k=body.thermal_expansion_per_k),
    )


# -- the controller URL of an axis in the configuration file ---------------------------------


def with_modbus_profile(controller: str, path: str | None, where: str) -> str:
    """``modbus_profile`` (``path``): the register profile file of a Modbus controller
    (docs/controllers.md), validated now and carried in the controller URL (``profile=``) to
    the driver."""
    from acquisition.modbus.profile import BUILTIN, load_profile
    from acquisition.trigger import query_of

    if path is None or path == BUILTIN:
        return controller
    if not controller.startswith(("modbus://", "modbus+rtu://")):
        raise ConfigError(f"{where}.modbus_profile needs a modbus:// or modbus+rtu:// controller (={controller!r})")
    if "profile" in query_of(controller):
        raise ConfigError(f"{where}: the profile is given twice (modbus_profile and the controller URL's profile=)")
    try:
        load_profile(path)
    except InputError as exc:
        raise ConfigError(f"{where}.modbus_profile: {exc}") from exc
    sep = "&" if "?" in controller else "?"
    return f"{controller}{sep}{urlencode({'profile': str(Path(path).resolve())})}"


def checked_canopen_controller(controller: str, table: Mapping | None, given: str | None, where: str) -> str:
    """An axis' CANopen controller, checked now: its ``[machines.axes.canopen]`` ``table`` (mode,
    node, EDS or mapping; folded into the stored URL, over ``given``, the axis' ``controller``)
    or a ``canopen://`` URL (acquisition/canopen/url.py)."""
    from acquisition.canopen.url import driver_from_canopen_url, url_from_table

    try:
        if table is not None:
            if not isinstance(table, Mapping):
                raise ConfigError(f"{where}.canopen must be a table")
            return url_from_table(table, given if given and given != SIM_CONTROLLER else None, f"{where}.canopen")
        if controller.startswith("canopen://"):
            driver_from_canopen_url(controller, where=f"{where}.controller (={controller!r}):")
    except ConfigError:
        raise
    except InputError as exc:
        raise ConfigError(str(exc)) from exc
    return controller


def with_trigger(controller: str, trigger: str | None, passive: Mapping[str, str], spec: AxisSpec,
                 where: str) -> str:
    """The controller URL with the axis' ``trigger`` (``active``, ``passive`` or None) and
    ``passive`` settings (query values) in its query (where the drivers read them, and where
    they are stored with the axis), checked now: a driver is made for the URL (no connection)
    and its detection settings for the axis."""
    from acquisition.trigger import default_trigger, query_of
    from acquisition.url import driver_from_url

    if controller == SIM_CONTROLLER:
        if trigger == "passive" or passive:
            raise ConfigError(f"{where}: the built-in simulator ('sim') has no CNC to start a round trip: it is "
                              "always active (for passive mode, point controller at a controller the CNC drives)")
        return controller
    in_url = query_of(controller).get("trigger")
    effective = trigger or in_url or default_trigger(controller)
    if trigger is not None and in_url not in (None, trigger):
        raise ConfigError(f"{where}: trigger = {trigger!r} contradicts the controller URL's "
                          f"trigger={in_url}")
    if passive and effective != "passive":
        raise ConfigError(f"{where}.passive applies to trigger = 'passive' only (this axis is {effective})")
    query = dict(passive)
    if trigger is not None:
        query = {"trigger": trigger, **query}
    url = controller
    if query:
        sep = "&" if urlsplit(controller).query else "?"
        url = controller + sep + "&".join(f"{k}={v}" for k, v in query.items())
    try:
        driver_from_url(url).detector_settings(spec)
    except InputError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    return url
