"""CANopen controller URLs and ``[machines.axes.canopen]`` tables: the mode and what it needs.

``canopen://INTERFACE/CHANNEL?node=N[&mode=...&<option>=V...]``; any key not known here
(``bitrate``, ``port``, ...) is passed to the python-can bus. Modes (docs/canopen-objects.md):

- ``listen-only``: beside a CNC master; mebm sends no frame. Needs the PDO mapping:
  ``eds=PATH`` (an EDS or DCF), or ``tpdo_cob_id``, ``motor_offset_bytes``,
  ``table_offset_bytes`` (``motor_type``/``table_type`` i32 by default), ``counts_per_rev``,
  ``table_nm_per_count`` (the node's TPDO1 of mebm's objects when none is given),
  ``max_lost_samples``. The round trip is found passively (``trigger=passive`` and the
  detection keys of :mod:`acquisition.trigger`).
- ``active-cia402``: mebm is the NMT master and SYNC producer and commands the drive
  through CiA 402 Profile Position (a drive on a bench). ``table_nm_per_count`` unless
  the drive has 0x2005.
- ``active-mebm``: as above through mebm's objects 0x2000-0x2006 (the simulated drive's).

``mode`` and ``trigger`` (:mod:`acquisition.trigger`) agree: ``listen-only`` is the passive
mode, the two others are active. Without ``mode``, the trigger decides: passive (the
default for any bus but the in-process ``virtual`` one) is ``listen-only``, active is
``active-mebm``; a ``mode`` that contradicts an explicit ``trigger`` is refused.
"""

from __future__ import annotations

from collections.abc import Mapping
from urllib.parse import quote, urlsplit

from acquisition.trigger import TRIGGER_KEYS, query_of, trigger_kwargs
from core.errors import InputError

MODES = ("listen-only", "active-cia402", "active-mebm")
_COMMON = {"node", "mode", "rate_hz", "window_ms", "time_scale"}
_MAPPING = {"eds", "tpdo_cob_id", "sync_cob_id", "motor_offset_bytes", "table_offset_bytes", "motor_type",
            "table_type", "counts_per_rev", "table_nm_per_count", "max_lost_samples"}  # listen-only keys
_TABLE_KEYS = {"interface", "channel", "bus"} | _COMMON | _MAPPING


def _trigger_keys() -> set[str]:
    return set(TRIGGER_KEYS)


def mode_for(trigger: str) -> str:
    """The CANopen mode a trigger means when the URL names none."""
    return "listen-only" if trigger == "passive" else "active-mebm"


def _num(field: str, raw, cast):
    if isinstance(raw, bool):
        raise InputError(f"{field} (={raw!r}) must be a number")
    if isinstance(raw, (int, float)) and cast is float:
        return float(raw)
    if isinstance(raw, int) and cast is int:
        return raw
    try:
        return cast(raw, 0) if cast is int else cast(raw)
    except (TypeError, ValueError):
        raise InputError(f"{field} (={raw!r}) must be {'an integer' if cast is int else 'a number'}") from None


def _at(where: str, msg: str) -> str:
    return f"{where}{msg}" if where.endswith(".") else f"{where} {msg}"


def driver_from_canopen_url(url: str, *, where: str | None = None, **kwargs):
    """The driver for a ``canopen://`` URL (see the module docstring); errors name the key,
    after ``where`` (default: the URL; ``machines[0].axes[0].canopen.`` for a table)."""
    where = where or f"controller URL {url!r}:"
    try:
        return _driver(url, where, **kwargs)
    except InputError as exc:
        msg = str(exc)
        if msg.startswith("controller URL"):
            raise
        raise InputError(_at(where, msg)) from exc


def _driver(url: str, where: str, **kwargs):
    parts = urlsplit(url)
    q = query_of(url)
    channel = parts.path.lstrip("/")
    if not parts.netloc or not channel:
        raise InputError(f"controller URL {url!r} must be canopen://INTERFACE/CHANNEL?node=N "
                         "(e.g. canopen://socketcan/can0?node=5, canopen://virtual/sim?node=5)")
    if "node" not in q:
        raise InputError(f"controller URL {url!r} needs ?node=N (the drive's CANopen node id)")
    interface = parts.netloc
    explicit_trigger = kwargs.get("trigger", q.get("trigger"))
    mode = q.get("mode")
    if mode is not None and mode not in MODES:
        raise InputError(f"mode (={mode!r}) must be one of {', '.join(MODES)}")
    tq = dict(q)
    if mode is not None:
        wanted = "passive" if mode == "listen-only" else "active"
        if explicit_trigger is not None and explicit_trigger != wanted:
            raise InputError(f"mode (={mode}) is {wanted}: it contradicts trigger={explicit_trigger} (listen-only "
                             "is the passive mode, active-cia402 and active-mebm are active)")
        tq["trigger"] = wanted
    elif explicit_trigger is not None:
        tq["trigger"] = explicit_trigger
    kwargs = {**kwargs, **trigger_kwargs(url, tq)}  # trigger, running_flag, passive settings
    mode = mode or mode_for(kwargs["trigger"])
    node = _num(f"node", q["node"], int)
    if not 1 <= node <= 127:
        raise InputError(f"node (={node}) must be a CANopen node id 1..127")
    bus_kwargs = {}
    for key, val in q.items():  # anything else is a python-can bus option (bitrate, port, ...)
        if key not in _COMMON | _MAPPING | _trigger_keys():
            bus_kwargs[key] = int(val) if val.lstrip("-").isdigit() else val
    rate = _num(f"rate_hz", q["rate_hz"], float) if "rate_hz" in q else None
    window_s = _num(f"window_ms", q["window_ms"], float) / 1000.0 if "window_ms" in q else None
    time_scale = _num(f"time_scale", q.get("time_scale", 1.0), float)
    if mode == "listen-only":
        from acquisition.canopen.listen import CanopenListenDriver

        if "max_lost_samples" in q:
            kwargs["max_lost_samples"] = _num("max_lost_samples", q["max_lost_samples"], int)
        return CanopenListenDriver(channel, node, mapping=listen_mapping(q, node, where), interface=interface,
                                   sync_rate_hz=rate, time_scale=time_scale, window_s=window_s,
                                   bus_kwargs=bus_kwargs, **kwargs)
    stray = sorted(set(q) & (_MAPPING - {"table_nm_per_count"}))
    if stray:
        raise InputError(f"{', '.join(stray)} only apply to mode=listen-only (mode is {mode})")
    common = dict(interface=interface, sync_rate_hz=rate or 250.0, time_scale=time_scale, bus_kwargs=bus_kwargs,
                  sync_window_s=window_s)
    if mode == "active-cia402":
        from acquisition.canopen.cia402 import CanopenCia402Driver

        nm = _num(f"table_nm_per_count", q["table_nm_per_count"], float) if "table_nm_per_count" in q else None
        return CanopenCia402Driver(channel, node, table_nm_per_count=nm, **common, **kwargs)
    if "table_nm_per_count" in q:
        raise InputError(f"table_nm_per_count does not apply to mode=active-mebm (read from 0x2005)")
    from acquisition.canopen.driver import CanopenDriver

    return CanopenDriver(channel, node, **common, **kwargs)


def listen_mapping(q: Mapping[str, str], node: int, where: str):
    """The listen-only PDO mapping from URL keys: ``eds`` (overridable scale), or the keys one by one."""
    from acquisition.canopen.mapping import PdoField, default_mapping, mapping_from_eds, pdo_type

    def num(key, cast):
        return _num(f"{key}", q[key], cast) if key in q else None

    scale = {k: num(k, float) for k in ("counts_per_rev", "table_nm_per_count") if k in q}
    if "eds" in q:
        given = sorted(set(q) & {"tpdo_cob_id", "motor_offset_bytes", "table_offset_bytes", "motor_type",
                                 "table_type", "sync_cob_id"})
        if given:
            raise InputError(f"eds and {', '.join(given)} both give the PDO mapping: give one")
        return mapping_from_eds(q["eds"], node, **scale)
    kw = dict(scale)
    if "tpdo_cob_id" in q:
        kw["tpdo_cob_id"] = num("tpdo_cob_id", int)
    if "sync_cob_id" in q:
        kw["sync_cob_id"] = num("sync_cob_id", int)
    for name in ("motor", "table"):
        off = num(f"{name}_offset_bytes", int)
        fmt = pdo_type(f"{name}_type", q[f"{name}_type"]) if f"{name}_type" in q else "l"
        if off is not None or f"{name}_type" in q:
            kw[name] = PdoField(off if off is not None else (0 if name == "motor" else 4), fmt)
    return default_mapping(node, **kw)


def url_from_table(table: Mapping, controller: str | None, where: str) -> str:
    """The controller URL for an axis' ``[machines.axes.canopen]`` table (``where`` names it).

    ``interface`` and ``channel`` come from the table or from ``controller``
    (``canopen://INTERFACE/CHANNEL``); ``bus`` is a table of python-can options."""
    unknown = sorted(set(table) - _TABLE_KEYS)
    if unknown:
        raise InputError(f"{where}.{unknown[0]}: unknown option (known: {', '.join(sorted(_TABLE_KEYS))})")
    interface, channel = table.get("interface"), table.get("channel")
    base_q: dict[str, str] = {}
    if controller:
        parts = urlsplit(controller)
        if parts.scheme != "canopen":
            raise InputError(f"{where}: the axis' controller (={controller!r}) must be canopen://... or left out")
        interface = interface or parts.netloc
        channel = channel or parts.path.lstrip("/")
        base_q = query_of(controller)
    for key, val in (("interface", interface), ("channel", channel)):
        if not isinstance(val, str) or not val:
            raise InputError(f"{where}.{key} is needed (or controller = \"canopen://INTERFACE/CHANNEL\")")
    if "node" not in table and "node" not in base_q:
        raise InputError(f"{where}.node is needed (the drive's CANopen node id)")
    mode = table.get("mode", base_q.get("mode"))
    if mode is not None and mode not in MODES:
        raise InputError(f"{where}.mode (={mode!r}) must be one of {', '.join(MODES)}")
    q = dict(base_q)
    for key in sorted(set(table) - {"interface", "channel", "bus"}):
        val = table[key]
        if isinstance(val, bool) or not isinstance(val, (str, int, float)):
            raise InputError(f"{where}.{key} (={val!r}) must be a string or a number")
        q[key] = str(val)
    bus = table.get("bus", {})
    if not isinstance(bus, Mapping):
        raise InputError(f"{where}.bus must be a table of python-can bus options")
    for key, val in bus.items():
        q[key] = str(val)
    query = "&".join(f"{k}={quote(str(v), safe='/.:-_')}" for k, v in q.items())
    url = f"canopen://{interface}/{channel}?{query}"
    driver_from_canopen_url(url, where=f"{where}.")  # every field checked now (the EDS read, the mapping)
    return url
