"""Service configuration: a TOML file (docs/configuration.md) over the embedded defaults
(:mod:`api.service.config.settings`), then environment overrides (MEBM_DATABASE_URL,
MEBM_DATA_DIR, MEBM_BOOTSTRAP_ADMIN_KEY, MEBM_HOST, MEBM_PORT, MEBM_MQTT_URL,
MEBM_WEBHOOK_SECRET, MEBM_OPCUA_ENDPOINT, MEBM_OPCUA_PASSWORD, MEBM_WORKER_*).

Every option is checked here, and an error names it (:class:`ConfigError`); an axis'
controller URL is completed and checked by :mod:`api.service.config.input`, as the REST
API's and the dashboard's are.
"""

from __future__ import annotations

import base64
import binascii
import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from urllib.parse import urlsplit

from acquisition.files import MIB, FileRefused, read_regular
from api.service.config.bounds import check_axis, check_axis_name, check_bounds, keys_of
from api.service.installation import check_instance
from api.service.config.input import checked_canopen_controller, resolve_profile, with_modbus_profile, with_trigger
from api.service.config.settings import (
    DEMO_SIMULATOR,
    SIM_CONTROLLER,
    AxisConfig,
    ConfigError,
    LimitSettings,
    MaintenanceSettings,
    MqttSettings,
    MtconnectSettings,
    OpcuaSettings,
    Settings,
    SimulatorSettings,
    WebhookSettings,
    WorkerSettings,
    default_settings,
)
from core.criteria.uncertainty import Instruments
from core.dataset import AxisSpec
from core.errors import InputError
from core.tbe import MachiningTask
from storage.db import AxisSettings, Schedule
from storage.db.names import collision, collision_message

MAX_CONFIG_BYTES = MIB  # a configuration file larger than this is not one (a device, a log named by mistake)
# the top-level tables of the configuration file
TABLES = {"server", "storage", "auth", "scheduler", "simulator", "machines", "logging", "limits", "retention", "mqtt",
        "webhooks", "opcua", "mtconnect", "maintenance", "worker", "uncertainty", "service"}
# the instruments of the uncertainty budget: [uncertainty] for every axis, the same keys in an
# axis' table for that axis (core.criteria.uncertainty.Instruments)
INSTRUMENT_KEYS = {"scale_accuracy_um": float, "scale_accuracy_um_per_m": float, "thermometer_class": str,
                   "thermal_expansion_per_k": float}


def _instruments(table: Mapping, base: Instruments, where: str) -> Instruments:
    given = {k: _get(table, k, kind, where) for k, kind in INSTRUMENT_KEYS.items() if k in table}
    if not given:
        return base
    try:
        return replace(base, **given)
    except InputError as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def _get(table: Mapping, key: str, kind, where: str, default=None):
    if key not in table:
        return default
    v = table[key]
    if kind is float and isinstance(v, int) and not isinstance(v, bool):
        v = float(v)
    if not isinstance(v, kind) or (kind is int and isinstance(v, bool)):
        raise ConfigError(f"{where}.{key} (={v!r}) must be {kind.__name__}")
    if kind is float and not math.isfinite(v):
        raise ConfigError(f"{where}.{key} (={v!r}) must be finite")
    return v


def _unknown(table: Mapping, allowed: set[str], where: str) -> None:
    extra = sorted(set(table) - allowed)
    if extra:
        raise ConfigError(f"{where}: unknown option(s) {extra} (allowed: {sorted(allowed)})")


def _task(t: Mapping, gain: float, where: str) -> MachiningTask:
    _unknown(t, {"name", "profile", "radius_mm", "angle_deg", "feed_mm_min", "tolerance_um"}, where)
    try:
        return MachiningTask(
            name=_get(t, "name", str, where) or "", profile=_get(t, "profile", str, where, "circle"),
            feed_mm_min=_get(t, "feed_mm_min", float, where, float("nan")), gain_per_s=gain,
            tolerance_um=_get(t, "tolerance_um", float, where, float("nan")),
            radius_mm=_get(t, "radius_mm", float, where), angle_deg=_get(t, "angle_deg", float, where),
        )
    except ConfigError:
        raise
    except InputError as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def _axis(a: Mapping, machine: str, where: str, instruments: Instruments = Instruments()) -> AxisConfig:
    allowed = set(INSTRUMENT_KEYS) | {
               "name", "transmission_mm_per_rev", "screw_lead_mm", "position_gain_per_s", "travel_mm",
               "controller", "measure_feed_mm_min", "measure_acceleration_mm_s2", "warning_fraction",
                "decision_rule", "worst_case_temperature_c", "schedule_interval_s", "schedule_cron", "schedule_enabled", "tasks",
                "modbus_profile", "trigger", "passive", "canopen"}
    _unknown(a, allowed, where)
    travel = a.get("travel_mm")
    if not (isinstance(travel, list) and len(travel) == 2 and all(isinstance(x, (int, float)) for x in travel)):
        raise ConfigError(f"{where}.travel_mm (={travel!r}) must be [start, end] in mm")
    try:
        spec = AxisSpec(
            name=_get(a, "name", str, where, ""), transmission_mm_per_rev=_get(a, "transmission_mm_per_rev", float, where),
            screw_lead_mm=_get(a, "screw_lead_mm", float, where),
            position_gain_per_s=_get(a, "position_gain_per_s", float, where),
            travel_mm=(float(travel[0]), float(travel[1])),
        )
        if not spec.name:
            raise ConfigError(f"{where}.name must be given")
        check_axis_name(spec.name, where)
        schedule = Schedule(_get(a, "schedule_interval_s", float, where), _get(a, "schedule_cron", str, where),
                            _get(a, "schedule_enabled", bool, where, True))
    except ConfigError:
        raise
    except InputError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    tasks = tuple(_task(t, spec.position_gain_per_s, f"{where}.tasks[{i}]") for i, t in enumerate(a.get("tasks", [])))
    controller = _get(a, "controller", str, where, SIM_CONTROLLER)
    if controller != SIM_CONTROLLER and not controller.startswith(("modbus://", "modbus+rtu://", "sim://", "canopen://")):
        raise ConfigError(f"{where}.controller (={controller!r}) must be 'sim', modbus://host:port, "
                          "modbus+rtu:///dev/DEVICE, sim://host:port or canopen://...")
    controller = with_modbus_profile(controller, _get(a, "modbus_profile", str, where), where)
    # a profile named in this file's URL is the operator's path, relative to where the service
    # starts (as modbus_profile): stored absolute, so the profiles folder is not looked in
    controller = resolve_profile(controller, Path.cwd())
    controller = checked_canopen_controller(controller, a.get("canopen"), a.get("controller"), where)
    controller = resolve_profile(controller, Path.cwd())  # and an EDS named in the axis' canopen table
    trigger = _get(a, "trigger", str, where)
    if trigger is not None and trigger not in ("active", "passive"):
        raise ConfigError(f"{where}.trigger (={trigger!r}) must be 'active' (mebm starts the round trip) or "
                          "'passive' (the CNC runs it, mebm records)")
    controller = with_trigger(controller, trigger, _passive_query(a, where), spec, where)
    st = AxisSettings(
        spec=spec, controller_url=controller,
        measure_feed_mm_min=_get(a, "measure_feed_mm_min", float, where, 2000.0),
        measure_acceleration_mm_s2=_get(a, "measure_acceleration_mm_s2", float, where, 500.0),
        warning_fraction=_get(a, "warning_fraction", float, where, 0.9), schedule=schedule, tasks=tasks,
        decision_rule=_get(a, "decision_rule", str, where, "guarded"),
        worst_case_temperature_c=_get(a, "worst_case_temperature_c", float, where, 30.0),
        instruments=_instruments(a, instruments, where),
    )
    if not -50.0 <= st.worst_case_temperature_c <= 100.0:
        raise ConfigError(f"{where}.worst_case_temperature_c (={st.worst_case_temperature_c}) must be within -50..100 °C")
    if st.decision_rule not in ("simple", "guarded"):
        raise ConfigError(f"{where}.decision_rule (={st.decision_rule!r}) must be 'simple' or 'guarded'")
    if not st.measure_feed_mm_min > 0 or not st.measure_acceleration_mm_s2 > 0:
        raise ConfigError(f"{where}: measure_feed_mm_min and measure_acceleration_mm_s2 must be > 0")
    if not 0 < st.warning_fraction <= 1:
        raise ConfigError(f"{where}.warning_fraction (={st.warning_fraction}) must be in (0, 1]")
    return check_axis(AxisConfig(machine, st), where)


def _passive_query(a: Mapping, where: str) -> dict[str, str]:
    """An axis' ``passive`` table (the detection settings of a passive round trip) as the
    controller URL's query values."""
    from acquisition.trigger import PASSIVE_KEYS

    passive = a.get("passive")
    if passive is not None and not isinstance(passive, Mapping):
        raise ConfigError(f"{where}.passive must be a table of detection settings")
    passive = dict(passive or {})
    _unknown(passive, {*PASSIVE_KEYS, "running_flag"}, f"{where}.passive")
    query = {}
    for key in passive:
        if key == "running_flag":
            query[key] = "1" if _get(passive, key, bool, f"{where}.passive") else "0"
        else:
            query[key] = repr(_get(passive, key, float, f"{where}.passive"))
    return query


def parse_settings(doc: Mapping, *, base: Settings | None = None) -> Settings:
    """Settings from a parsed TOML document; options absent keep the defaults."""
    base = base or Settings()
    _unknown(doc, TABLES, "config")
    service = doc.get("service", {})
    _unknown(service, {"instance"}, "service")
    instance = _get(service, "instance", str, "service", base.instance)
    if instance is not None:
        check_instance(instance, "service.instance")
    server = doc.get("server", {})
    _unknown(server, {"host", "port", "status_max_age_s", "trusted_proxies"}, "server")
    storage = doc.get("storage", {})
    _unknown(storage, {"data_dir", "database_url", "min_free_disk_mb", "spool_reserve_mb", "spool_slots",
                       "spool_slot_mb", "profiles_dir"}, "storage")
    auth = doc.get("auth", {})
    _unknown(auth, {"bootstrap_admin_key", "demo_keys"}, "auth")
    sched = doc.get("scheduler", {})
    _unknown(sched, {"enabled", "catch_up_missed", "spool_retry_s", "cycle_processes"}, "scheduler")
    cycle_processes = _get(sched, "cycle_processes", int, "scheduler", base.cycle_processes)
    if not 0 <= cycle_processes <= 64:
        raise ConfigError(f"scheduler.cycle_processes (={cycle_processes}) must be 0..64 (0: cycles run in the "
                          "service's own process)")
    sim = doc.get("simulator", {})
    sim_fields = set(SimulatorSettings.__dataclass_fields__)
    _unknown(sim, sim_fields, "simulator")
    logging_ = doc.get("logging", {})
    _unknown(logging_, {"level"}, "logging")
    limits = _limits(doc.get("limits", {}), base.limits)
    ret = doc.get("retention", {})
    _unknown(ret, {"keep_last_runs", "keep_around_events", "max_runs", "interval_s"}, "retention")
    try:
        retention = replace(base.retention, **{k: _get(ret, k, int, "retention") for k in ret if k != "interval_s"})
    except InputError as exc:
        raise ConfigError(str(exc)) from exc
    retention_interval_s = _get(ret, "interval_s", float, "retention", base.retention_interval_s)
    if not retention_interval_s > 0:
        raise ConfigError(f"retention.interval_s (={retention_interval_s}) must be > 0")
    port = _get(server, "port", int, "server", base.port)
    if not 0 <= port <= 65535:
        raise ConfigError(f"server.port (={port}) must be 0..65535 (0: a free port)")
    # the demo's wearing chain belongs to the demo machine: a file with machines of its own starts from the plain simulator
    sim_base = SimulatorSettings() if "machines" in doc and base.simulator == DEMO_SIMULATOR else base.simulator
    simulator = replace(sim_base, **{k: _get(sim, k, float, "simulator") for k in sim})
    if simulator.wear_um_per_day < 0:
        raise ConfigError(f"simulator.wear_um_per_day (={simulator.wear_um_per_day}) must be >= 0")
    for k in ("time_scale", "servo_rate_hz", "temperature_period_s", "utility_days_per_s"):
        if not getattr(simulator, k) > 0:
            raise ConfigError(f"simulator.{k} (={getattr(simulator, k)}) must be > 0")
    unc = doc.get("uncertainty", {})
    _unknown(unc, set(INSTRUMENT_KEYS), "uncertainty")
    instruments = _instruments(unc, Instruments(), "uncertainty")
    machines, axes = base.machines, base.axes
    if unc:
        axes = tuple(replace(a, settings=replace(a.settings, instruments=_instruments(unc, a.settings.instruments,
                                                                                      "uncertainty")))
                     for a in axes)
    if "machines" in doc:
        machines, axes = [], []
        for i, m in enumerate(doc["machines"]):
            where = f"machines[{i}]"
            _unknown(m, {"name", "description", "axes"}, where)
            name = _get(m, "name", str, where, "")
            if not name:
                raise ConfigError(f"{where}.name must be given")
            other = collision(name, (n for n, _ in machines))
            if other is not None:
                raise ConfigError(f"{where}.name: " + collision_message("machine", name, other))
            machines.append((name, _get(m, "description", str, where, "")))
            for j, a in enumerate(m.get("axes", [])):
                axis = _axis(a, name, f"{where}.axes[{j}]", instruments)
                other = collision(axis.settings.spec.name, (x.settings.spec.name for x in axes if x.machine == name))
                if other is not None:
                    raise ConfigError(f"{where}.axes[{j}].name: "
                                      + collision_message("axis", axis.settings.spec.name, other))
                axes.append(axis)
        machines, axes = tuple(machines), tuple(axes)
    data_dir = _get(storage, "data_dir", str, "storage")
    profiles_dir = _get(storage, "profiles_dir", str, "storage")
    min_free_disk_mb = _get(storage, "min_free_disk_mb", float, "storage", base.min_free_disk_mb)
    if min_free_disk_mb < 0:
        raise ConfigError(f"storage.min_free_disk_mb (={min_free_disk_mb}) must be >= 0")
    spool_reserve_mb = _get(storage, "spool_reserve_mb", float, "storage", base.spool_reserve_mb)
    if spool_reserve_mb < 0:
        raise ConfigError(f"storage.spool_reserve_mb (={spool_reserve_mb}) must be >= 0")
    spool_slots = _get(storage, "spool_slots", int, "storage", base.spool_slots)
    if not 0 <= spool_slots <= 64:
        raise ConfigError(f"storage.spool_slots (={spool_slots}) must be 0..64 (0: none; each keeps one cycle "
                          "finished on a full disk)")
    spool_slot_mb = _get(storage, "spool_slot_mb", float, "storage", base.spool_slot_mb)
    if not 0.01 <= spool_slot_mb <= 64:
        raise ConfigError(f"storage.spool_slot_mb (={spool_slot_mb}) must be 0.01..64 (a cycle's spool file with "
                          "its raw trace is a few hundred kB)")
    return check_bounds(replace(
        base, instance=instance,
        host=_get(server, "host", str, "server", base.host), port=port,
        data_dir=Path(data_dir) if data_dir else base.data_dir,
        database_url=_get(storage, "database_url", str, "storage", base.database_url) or None,
        min_free_disk_mb=min_free_disk_mb, spool_reserve_mb=spool_reserve_mb, spool_slots=spool_slots,
        spool_slot_mb=spool_slot_mb,
        profiles_dir=Path(profiles_dir) if profiles_dir else base.profiles_dir,
        bootstrap_admin_key=_get(auth, "bootstrap_admin_key", str, "auth", base.bootstrap_admin_key) or None,
        demo_keys=_get(auth, "demo_keys", bool, "auth", base.demo_keys),
        scheduler_enabled=_get(sched, "enabled", bool, "scheduler", base.scheduler_enabled),
        catch_up_missed=_get(sched, "catch_up_missed", bool, "scheduler", base.catch_up_missed),
        spool_retry_s=_get(sched, "spool_retry_s", float, "scheduler", base.spool_retry_s),
        cycle_processes=cycle_processes,
        machines=machines, axes=axes, simulator=simulator,
        log_level=_get(logging_, "level", str, "logging", base.log_level), limits=limits,
        retention=retention, retention_interval_s=retention_interval_s,
        mqtt=_mqtt(doc.get("mqtt"), base.mqtt), webhooks=_webhooks(doc.get("webhooks"), base.webhooks),
        opcua=_opcua(doc.get("opcua"), base.opcua),
        mtconnect=_mtconnect(doc.get("mtconnect"), base.mtconnect),
        maintenance=_maintenance(doc.get("maintenance"), base.maintenance),
        worker=_worker(doc.get("worker"), base.worker),
        status_max_age_s=_positive(_get(server, "status_max_age_s", float, "server", base.status_max_age_s),
                                   "server.status_max_age_s"),
        trusted_proxies=_trusted_proxies(server, base.trusted_proxies),
    ), keys_of(doc))


def _trusted_proxies(server: Mapping, base: tuple[str, ...]) -> tuple[str, ...]:
    if "trusted_proxies" not in server:
        return base
    value = server["trusted_proxies"]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"server.trusted_proxies (={value!r}) must be a list of addresses or CIDRs, "
                          "e.g. [\"127.0.0.1\", \"10.0.0.0/8\"]")
    import ipaddress

    for v in value:
        try:
            ipaddress.ip_network(v.strip(), strict=False)
        except ValueError:
            raise ConfigError(f"server.trusted_proxies: {v!r} is not an IP address or CIDR "
                              "(host names and \"*\" are not accepted)") from None
    return tuple(v.strip() for v in value)


def _maintenance(table: Mapping | None, base: MaintenanceSettings) -> MaintenanceSettings:
    if table is None:
        return base
    _unknown(table, {"enabled", "horizon_days", "verify_at", "fixed_interval_days"}, "maintenance")
    out = MaintenanceSettings(
        enabled=_get(table, "enabled", bool, "maintenance", base.enabled),
        horizon_days=_get(table, "horizon_days", float, "maintenance", base.horizon_days),
        verify_at=_get(table, "verify_at", str, "maintenance", base.verify_at),
        fixed_interval_days=_get(table, "fixed_interval_days", float, "maintenance", base.fixed_interval_days))
    check_maintenance(out)
    return out


def check_maintenance(m: MaintenanceSettings) -> None:
    if not m.horizon_days >= 0:
        raise ConfigError(f"maintenance.horizon_days (={m.horizon_days}) must be >= 0")
    if not m.fixed_interval_days > 0:
        raise ConfigError(f"maintenance.fixed_interval_days (={m.fixed_interval_days}) must be > 0")
    if m.verify_at != "now":
        hh, sep, mm = m.verify_at.partition(":")
        if not (sep and hh.isdigit() and mm.isdigit() and int(hh) < 24 and int(mm) < 60):
            raise ConfigError(f"maintenance.verify_at (={m.verify_at!r}) must be \"now\" or \"HH:MM\" (UTC)")


def _positive(v: float, where: str) -> float:
    if not v > 0:
        raise ConfigError(f"{where} (={v}) must be > 0")
    return v


def _patterns(v, where: str) -> tuple[str, ...]:
    if isinstance(v, str):
        v = [p.strip() for p in v.split(",") if p.strip()]
    if not isinstance(v, list) or not v or not all(isinstance(p, str) and p.count("/") == 1 for p in v):
        raise ConfigError(f"{where} (={v!r}) must be a non-empty list of 'machine/axis' patterns "
                          "(shell-style: 'site-a-*/*', 'vmc-7/x')")
    return tuple(v)


def _worker(table: Mapping | None, base: WorkerSettings) -> WorkerSettings:
    if table is None:
        return base
    _unknown(table, {"name", "axes", "lease_s", "tick_s"}, "worker")
    axes = _patterns(table["axes"], "worker.axes") if "axes" in table else base.axes
    lease_s = _positive(_get(table, "lease_s", float, "worker", base.lease_s), "worker.lease_s")
    tick_s = _get(table, "tick_s", float, "worker", base.tick_s)
    if tick_s is not None and not 0 < tick_s <= lease_s / 3:
        raise ConfigError(f"worker.tick_s (={tick_s}) must be > 0 and at most lease_s / 3 (={lease_s / 3:g}): "
                          "a lease must survive a missed heartbeat")
    name = _get(table, "name", str, "worker", base.name) or None
    return replace(base, name=name, axes=axes, lease_s=lease_s, tick_s=tick_s)


def _mqtt(table: Mapping | None, base: MqttSettings) -> MqttSettings:
    if table is None:
        return base
    _unknown(table, {"url", "topic_prefix", "outbox_max"}, "mqtt")
    out = MqttSettings(url=_get(table, "url", str, "mqtt", base.url) or None,
                       topic_prefix=_get(table, "topic_prefix", str, "mqtt", base.topic_prefix),
                       outbox_max=_get(table, "outbox_max", int, "mqtt", base.outbox_max))  # fmt: skip
    check_mqtt(out, "mqtt")
    return out


def check_mqtt(m: MqttSettings, where: str) -> None:
    if m.url is not None:
        u = urlsplit(m.url)
        if u.scheme not in ("mqtt", "mqtts") or not u.hostname:
            raise ConfigError(f"{where}.url (={m.url!r}) must be mqtt://host[:port] or mqtts://host[:port]")
        try:
            u.port
        except ValueError as exc:
            raise ConfigError(f"{where}.url (={m.url!r}): {exc}") from exc
    if not m.topic_prefix or any(c in m.topic_prefix for c in "+#") or m.topic_prefix.startswith("/"):
        raise ConfigError(f"{where}.topic_prefix (={m.topic_prefix!r}) must be a plain topic level (no + # or leading /)")
    if m.outbox_max < 1:
        raise ConfigError(f"{where}.outbox_max (={m.outbox_max}) must be >= 1")


def _opcua(table: Mapping | None, base: OpcuaSettings) -> OpcuaSettings:
    if table is None:
        return base
    _unknown(table, {"enabled", "endpoint", "anonymous", "username", "password", "certificate", "private_key",
                     "trusted_certificates"}, "opcua")  # fmt: skip
    username = _get(table, "username", str, "opcua", base.username) or None
    cert, key = _get(table, "certificate", str, "opcua"), _get(table, "private_key", str, "opcua")
    trusted = _get(table, "trusted_certificates", str, "opcua")
    out = OpcuaSettings(
        enabled=_get(table, "enabled", bool, "opcua", base.enabled),
        endpoint=_get(table, "endpoint", str, "opcua", base.endpoint),
        anonymous=_get(table, "anonymous", bool, "opcua", username is None),
        username=username, password=_get(table, "password", str, "opcua", base.password) or None,
        certificate=Path(cert) if cert else base.certificate, private_key=Path(key) if key else base.private_key,
        trusted_certificates=Path(trusted) if trusted else base.trusted_certificates,
    )
    check_opcua(out, "opcua", complete=False)  # the password may still come from the environment
    return out


def check_opcua(o: OpcuaSettings, where: str, complete: bool = True) -> None:
    u = urlsplit(o.endpoint)
    if u.scheme != "opc.tcp" or not u.hostname:
        raise ConfigError(f"{where}.endpoint (={o.endpoint!r}) must be opc.tcp://host:port/path")
    try:
        u.port
    except ValueError as exc:
        raise ConfigError(f"{where}.endpoint (={o.endpoint!r}): {exc}") from exc
    if o.password is not None and o.username is None:
        raise ConfigError(f"{where}: a password needs a username")
    if complete and o.username is not None and o.password is None:
        raise ConfigError(f"{where}.username (={o.username!r}) needs a password (opcua.password or "
                          "MEBM_OPCUA_PASSWORD)")  # fmt: skip
    if not o.anonymous and o.username is None and o.trusted_certificates is None:
        raise ConfigError(f"{where}: anonymous = false needs a username and password or trusted_certificates "
                          "(nobody could connect)")  # fmt: skip
    if (o.certificate is None) != (o.private_key is None):
        raise ConfigError(f"{where}: certificate and private_key go together")
    for name in ("certificate", "private_key"):
        p = getattr(o, name)
        if p is not None and not p.is_file():
            raise ConfigError(f"{where}.{name} (={str(p)!r}) is not a file")
    if o.trusted_certificates is not None:
        if o.certificate is None:
            raise ConfigError(f"{where}.trusted_certificates needs the server's certificate and private_key "
                              "(client certificates are only seen on signed channels)")  # fmt: skip
        if not o.trusted_certificates.is_dir():
            raise ConfigError(f"{where}.trusted_certificates (={str(o.trusted_certificates)!r}) is not a folder")


def _mtconnect(table: Mapping | None, base: MtconnectSettings) -> MtconnectSettings:
    if table is None:
        return base
    _unknown(table, {"enabled", "require_key", "buffer_size", "sender", "shdr_port", "shdr_host"}, "mtconnect")
    out = MtconnectSettings(enabled=_get(table, "enabled", bool, "mtconnect", base.enabled),
                            require_key=_get(table, "require_key", bool, "mtconnect", base.require_key),
                            buffer_size=_get(table, "buffer_size", int, "mtconnect", base.buffer_size),
                            sender=_get(table, "sender", str, "mtconnect", base.sender) or None,
                            shdr_port=_get(table, "shdr_port", int, "mtconnect", base.shdr_port),
                            shdr_host=_get(table, "shdr_host", str, "mtconnect", base.shdr_host))  # fmt: skip
    if out.shdr_port is not None and not 0 <= out.shdr_port <= 65535:
        raise ConfigError(f"mtconnect.shdr_port (={out.shdr_port}) must be 0..65535 (0: a free port)")
    if not 1 <= out.buffer_size <= 10_000_000:
        raise ConfigError(f"mtconnect.buffer_size (={out.buffer_size}) must be 1..10000000 observations")
    return out


def _webhooks(table: Mapping | None, base: WebhookSettings) -> WebhookSettings:
    if table is None:
        return base
    _unknown(table, {"urls", "secret", "timeout_s", "max_attempts", "log_max", "keep_delivered_days", "max_failed"},
             "webhooks")
    urls = table.get("urls", list(base.urls))
    if not isinstance(urls, list) or not all(isinstance(u, str) for u in urls):
        raise ConfigError("webhooks.urls must be a list of http(s) URLs")
    for u in urls:
        if urlsplit(u).scheme not in ("http", "https") or not urlsplit(u).hostname:
            raise ConfigError(f"webhooks.urls: {u!r} is not an http(s) URL")
    out = WebhookSettings(urls=tuple(urls), secret=_get(table, "secret", str, "webhooks", base.secret) or None,
                          timeout_s=_get(table, "timeout_s", float, "webhooks", base.timeout_s),
                          max_attempts=_get(table, "max_attempts", int, "webhooks", base.max_attempts),
                          log_max=_get(table, "log_max", int, "webhooks", base.log_max),
                          keep_delivered_days=_get(table, "keep_delivered_days", float, "webhooks",
                                                   base.keep_delivered_days),
                          max_failed=_get(table, "max_failed", int, "webhooks", base.max_failed))  # fmt: skip
    check_webhooks(out, "webhooks")
    return out


def check_webhooks(w: WebhookSettings, where: str) -> None:
    if w.urls and not w.secret:
        raise ConfigError(f"{where}.secret must be set when {where}.urls is (receivers verify the signature): "
                          "whsec_ followed by base64 of 24-64 random bytes")  # fmt: skip
    if w.secret is not None:
        try:
            key = base64.b64decode(w.secret.removeprefix("whsec_"), validate=True)
        except (ValueError, binascii.Error) as exc:
            raise ConfigError(f"{where}.secret must be whsec_ followed by base64") from exc
        if len(key) < 16:
            raise ConfigError(f"{where}.secret is {len(key)} bytes; use at least 16 (24-64 random bytes)")
    if not (w.timeout_s > 0 and w.keep_delivered_days > 0) or min(w.max_attempts, w.log_max, w.max_failed) < 1:
        raise ConfigError(f"{where}: timeout_s and keep_delivered_days must be > 0, "
                          "max_attempts, log_max and max_failed >= 1")


def _limits(table: Mapping, base: LimitSettings) -> LimitSettings:
    kinds = {"max_body_bytes": int, "max_circle_body_bytes": int, "max_header_bytes": int, "max_headers": int, "header_timeout_s": float,
             "triggers_per_minute": float, "trigger_burst": int,
             "auth_failures_per_minute": float, "auth_failure_burst": int,
             "auth_address_failures_per_minute": float, "auth_address_failure_burst": int,
             "allow_link_local_controllers": bool, "gap_diagnoses_pending": int, "gap_diagnosis_timeout_s": float,
             "gap_diagnosis_nice": int, "plot_renders": int, "plot_queue": int, "plot_window_step_s": float}
    _unknown(table, set(kinds), "limits")
    out = replace(base, **{k: _get(table, k, kinds[k], "limits") for k in table})
    for k in kinds:
        if kinds[k] is bool or k in ("gap_diagnosis_nice", "plot_renders", "plot_queue", "plot_window_step_s"):
            continue
        if not getattr(out, k) > 0:
            raise ConfigError(f"limits.{k} (={getattr(out, k)}) must be > 0")
    if not 0 <= out.gap_diagnosis_nice <= 19:
        raise ConfigError(f"limits.gap_diagnosis_nice (={out.gap_diagnosis_nice}) must be 0..19 (0: the service's own priority)")
    if not 1 <= out.plot_renders <= 16:
        raise ConfigError(f"limits.plot_renders (={out.plot_renders}) must be 1..16 (figures drawn at once)")
    if not 0 <= out.plot_queue <= 1000:
        raise ConfigError(f"limits.plot_queue (={out.plot_queue}) must be 0..1000 (figures waiting to be drawn; "
                          "more are answered 429)")
    if not 1 <= out.plot_window_step_s <= 86400:
        raise ConfigError(f"limits.plot_window_step_s (={out.plot_window_step_s}) must be 1..86400 (the step a "
                          "figure's since is rounded down to)")
    return out


def apply_env(settings: Settings, env: Mapping[str, str] | None = None) -> Settings:
    env = os.environ if env is None else env
    out = settings
    if env.get("MEBM_DATA_DIR"):
        out = replace(out, data_dir=Path(env["MEBM_DATA_DIR"]))
    if env.get("MEBM_DATABASE_URL"):
        out = replace(out, database_url=env["MEBM_DATABASE_URL"])
    if env.get("MEBM_BOOTSTRAP_ADMIN_KEY"):
        out = replace(out, bootstrap_admin_key=env["MEBM_BOOTSTRAP_ADMIN_KEY"])
    if "MEBM_MQTT_URL" in env:  # empty: off
        out = replace(out, mqtt=replace(out.mqtt, url=env["MEBM_MQTT_URL"] or None))
        check_mqtt(out.mqtt, "MEBM_MQTT_URL")
    if env.get("MEBM_WEBHOOK_SECRET"):
        out = replace(out, webhooks=replace(out.webhooks, secret=env["MEBM_WEBHOOK_SECRET"]))
        check_webhooks(out.webhooks, "MEBM_WEBHOOK_SECRET")
    if "MEBM_OPCUA_ENDPOINT" in env:  # empty: off
        ep = env["MEBM_OPCUA_ENDPOINT"]
        out = replace(out, opcua=replace(out.opcua, enabled=bool(ep), endpoint=ep or out.opcua.endpoint))
    if env.get("MEBM_OPCUA_PASSWORD"):
        out = replace(out, opcua=replace(out.opcua, password=env["MEBM_OPCUA_PASSWORD"]))
    if out.opcua.enabled:
        check_opcua(out.opcua, "opcua")
    if env.get("MEBM_WORKER_NAME"):
        out = replace(out, worker=replace(out.worker, name=env["MEBM_WORKER_NAME"]))
    if env.get("MEBM_WORKER_AXES"):
        out = replace(out, worker=replace(out.worker, axes=_patterns(env["MEBM_WORKER_AXES"], "MEBM_WORKER_AXES")))
    if env.get("MEBM_WORKER_LEASE_S"):
        try:
            lease = float(env["MEBM_WORKER_LEASE_S"])
        except ValueError as exc:
            raise ConfigError(f"MEBM_WORKER_LEASE_S (={env['MEBM_WORKER_LEASE_S']!r}) must be a number") from exc
        out = replace(out, worker=replace(out.worker, lease_s=_positive(lease, "MEBM_WORKER_LEASE_S")))
    if env.get("MEBM_INSTANCE"):
        out = replace(out, instance=check_instance(env["MEBM_INSTANCE"], "MEBM_INSTANCE"))
    if env.get("MEBM_HOST"):
        out = replace(out, host=env["MEBM_HOST"])
    if env.get("MEBM_PORT"):
        try:
            out = replace(out, port=int(env["MEBM_PORT"]))
        except ValueError as exc:
            raise ConfigError(f"MEBM_PORT (={env['MEBM_PORT']!r}) must be an integer") from exc
    return out


def load_settings(path: str | os.PathLike | None = None, env: Mapping[str, str] | None = None) -> Settings:
    """Embedded defaults, then the TOML file (if any), then the environment."""
    settings = default_settings()
    if path is not None:
        p = Path(path)
        try:
            doc = tomllib.loads(read_regular(p, MAX_CONFIG_BYTES, "config file").decode("utf-8"))
        except FileRefused as exc:
            if not p.exists():
                raise ConfigError(f"config file {p} not found") from exc
            raise ConfigError(str(exc)) from exc
        except UnicodeDecodeError as exc:
            raise ConfigError(f"config file {p}: not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config file {p}: {exc}") from exc
        settings = parse_settings(doc, base=settings)
    return check_bounds(apply_env(settings, env))
