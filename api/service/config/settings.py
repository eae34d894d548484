"""Service settings: what the service runs with, as frozen dataclasses, and the embedded
defaults.

Without a configuration file the defaults describe the demo: SQLite under ./data, the
built-in simulated Modbus controller, and the seed paper's Y axis measured every 60 s.
Reading them from a TOML file and the environment is :mod:`api.service.config.loading`;
what an admin may change at run time, :mod:`api.service.config.input`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from core.dataset import AxisSpec
from core.errors import InputError
from core.tbe import MachiningTask
from storage.db import AxisSettings, Schedule, sqlite_url
from storage.retention import RetentionPolicy

SIM_CONTROLLER = "sim"


class ConfigError(InputError):
    """The configuration file or an environment override is invalid; says which option."""


@dataclass(frozen=True)
class SimulatorSettings:
    """The built-in simulated controller (used by axes whose controller is ``sim``).

    The shop temperature swings sinusoidally; the backlash follows it with
    ``backlash_um_per_k`` (the paper found b̄ tracks temperature, r = 0.94)."""

    time_scale: float = 10.0
    servo_rate_hz: float = 400.0
    backlash_um_at_20c: float = 226.0
    backlash_um_per_k: float = 2.0
    temperature_mean_c: float = 21.0
    temperature_amplitude_c: float = 6.0
    temperature_period_s: float = 900.0
    cyclic_error_um: float = 4.0
    # wear: b̄ grows by wear_um_per_day per utility day, the simulated clock
    # making utility_days_per_s of them each second; a recorded repair restores it
    wear_um_per_day: float = 0.0
    utility_days_per_s: float = 1.0 / 86400.0


@dataclass(frozen=True)
class MaintenanceSettings:
    """``[maintenance]``: work orders, the verification of repairs, the managers' summary."""

    enabled: bool = True
    horizon_days: float = 30.0  # WARNING opens a condition-based order when the prognosis dates the limit within this
    verify_at: str = "now"  # when a repair's verification cycle runs: "now", or "HH:MM" (UTC, the next such time)
    fixed_interval_days: float = 90.0  # the fixed maintenance plan the summary compares against


@dataclass(frozen=True)
class LimitSettings:
    """What one client can make the service do (``[limits]``)."""

    max_body_bytes: int = 1_000_000  # larger request bodies: 413 before they are read, key or no key
    # ...except a posted or imported circular test's: its samples (a LinuxCNC recording at the servo
    # rate is some 40,000, 1.5 MB of JSON); 32 MB is about 800,000 samples
    max_circle_body_bytes: int = 32_000_000
    max_header_bytes: int = 65536  # a request line and header fields larger in all: 431, the rest unread
    max_headers: int = 100  # more header fields: 431
    header_timeout_s: float = 10.0  # a request head not complete this long after its first byte: 408, closed
    triggers_per_minute: float = 6.0  # manual measurements per key (a token bucket)...
    trigger_burst: int = 3  # ...of which this many at once
    auth_failures_per_minute: float = 10.0  # failed authentications per client address and key prefix...
    auth_failure_burst: int = 20  # ...before they are answered 429 for a while (a valid key never is)
    auth_address_failures_per_minute: float = 60.0  # failed authentications per client address, any key...
    auth_address_failure_burst: int = 100  # ...before that address' failures are answered 429 for a while
    allow_link_local_controllers: bool = False  # 169.254.x.x / fe80:: controllers (cloud metadata lives there)
    gap_diagnoses_pending: int = 2  # gap diagnoses waiting or running at once; more are refused (429)
    gap_diagnosis_timeout_s: float = 900.0  # a gap diagnosis running longer is stopped, and says so
    gap_diagnosis_nice: int = 10  # the diagnosis' worker process runs this much below the service (0-19)
    plot_renders: int = 2  # figures drawn at once (1-16), each on a worker thread of its own...
    plot_queue: int = 16  # ...and this many waiting (0-1000, holding no thread); more are answered 429
    plot_window_step_s: float = 3600.0  # a figure's since is rounded down to this step (1-86400): one cache entry


@dataclass(frozen=True)
class AxisConfig:
    machine: str
    settings: AxisSettings


@dataclass(frozen=True)
class MqttSettings:
    """``[mqtt]``: publish the status and alerts to a broker (None: off)."""

    url: str | None = None  # mqtt://[user:password@]host[:port]
    topic_prefix: str = "mebm"
    outbox_max: int = 1000  # alert messages kept while the broker is away


@dataclass(frozen=True)
class WebhookSettings:
    """``[webhooks]``: POST alert and work-order changes, signed per Standard Webhooks.
    Messages are kept in the database until delivered: ``max_attempts`` tries with
    back-off, then ``failed`` until an admin re-queues them."""

    urls: tuple[str, ...] = ()
    secret: str | None = None  # whsec_<base64>
    timeout_s: float = 5.0
    max_attempts: int = 5
    log_max: int = 200  # the in-memory log of attempts
    keep_delivered_days: float = 7.0  # delivered messages are purged after this
    max_failed: int = 10000  # failed messages kept beyond this: the oldest are deleted (logged, counted)


DEFAULT_OPCUA_ENDPOINT = "opc.tcp://127.0.0.1:4840/mebm/"


@dataclass(frozen=True)
class OpcuaSettings:
    """``[opcua]``: an OPC UA server with the axes' status (read-only for every user).

    Anonymous sessions are allowed unless a username is configured (then only that user,
    unless ``anonymous = true`` says otherwise). Without a certificate the only security
    policy is None: the password then travels in clear, so keep such an endpoint on a
    trusted network or configure ``certificate`` and ``private_key`` (Basic256Sha256).
    With ``trusted_certificates`` (a folder), a client's certificate must be trusted
    (directly or by its CA) to open a signed channel, and a session on such a channel, or
    one presenting a trusted certificate as its identity, is a (read-only) user even when
    anonymous sessions are off."""

    enabled: bool = False
    endpoint: str = DEFAULT_OPCUA_ENDPOINT  # opc.tcp://host:port/path (port 0: a free one)
    anonymous: bool = True
    username: str | None = None
    password: str | None = None  # or MEBM_OPCUA_PASSWORD
    certificate: Path | None = None  # PEM or DER server certificate: adds Basic256Sha256 Sign(AndEncrypt)
    private_key: Path | None = None
    trusted_certificates: Path | None = None  # folder of trusted client certificates (or their CAs)


@dataclass(frozen=True)
class MtconnectSettings:
    """``[mtconnect]``: an MTConnect agent (2.4, read-only) under ``/mtconnect`` on the API's port."""

    enabled: bool = True
    require_key: bool = False  # agents are usually open on the shop network; True: any valid key (X-API-Key)
    buffer_size: int = 131072  # observations kept for /sample (the ring buffer)
    sender: str | None = None  # the Header's sender; None: this host's name
    shdr_port: int | None = None  # an SHDR adapter port for a site's own agent (7878 by convention); None: off
    shdr_host: str = "127.0.0.1"


@dataclass(frozen=True)
class WorkerSettings:
    """``[worker]``: this process as one worker of a fleet on a PostgreSQL database
    (docs/fleet.md). ``axes``: the ``machine/axis`` patterns (shell-style, ``site-a-*/*``)
    of the axes it can reach; None: any. ``lease_s``: how long an axis stays owned by a
    worker that stopped renewing (the takeover delay after a crash or a network cut)."""

    name: str | None = None  # None: <host>-<pid>
    axes: tuple[str, ...] | None = None
    lease_s: float = 30.0
    tick_s: float | None = None  # heartbeat/claim period; None: min(2 s, lease_s / 6)

    @property
    def period_s(self) -> float:
        return self.tick_s if self.tick_s is not None else min(2.0, self.lease_s / 6.0)


@dataclass(frozen=True)
class Settings:
    # this installation's name on MQTT, MTConnect and OPC UA ([service] instance, MEBM_INSTANCE);
    # None: drawn once and kept in the data folder (api.service.installation)
    instance: str | None = None
    host: str = "127.0.0.1"
    port: int = 8000
    data_dir: Path = Path("data")
    database_url: str | None = None
    min_free_disk_mb: float = 500.0  # below this much free disk under data_dir: /healthz degraded, no new cycle
    # a file of this size kept under <data_dir>/spool, released when the disk is full so
    # that a finished cycle can still be spooled (0: none)
    spool_reserve_mb: float = 16.0
    # spool slots: files of spool_slot_mb each kept under <data_dir>/spool, into which a
    # finished cycle's spool file is written in place when the disk has no room left (even
    # after the reserve was released): one slot per cycle, refilled once there is room
    spool_slots: int = 4
    spool_slot_mb: float = 1.0
    # the folder a register profile named in an axis' controller URL (``profile=NAME``) is
    # read from; None: ``<data_dir>/profiles``
    profiles_dir: Path | None = None
    bootstrap_admin_key: str | None = None
    demo_keys: bool = True
    scheduler_enabled: bool = True
    catch_up_missed: bool = True
    spool_retry_s: float = 30.0
    # cycles run in up to this many worker processes (api.service.cycles.runner.CycleProcesses); 0: on
    # the scheduler's threads (the library's default; `mebm serve` uses 2, default_settings)
    cycle_processes: int = 0
    machines: tuple[tuple[str, str], ...] = ()  # (name, description)
    axes: tuple[AxisConfig, ...] = ()
    simulator: SimulatorSettings = field(default_factory=SimulatorSettings)
    log_level: str = "info"
    limits: LimitSettings = field(default_factory=LimitSettings)
    retention: RetentionPolicy = field(default_factory=RetentionPolicy)
    retention_interval_s: float = 3600.0
    mqtt: MqttSettings = field(default_factory=MqttSettings)
    webhooks: WebhookSettings = field(default_factory=WebhookSettings)
    opcua: OpcuaSettings = field(default_factory=OpcuaSettings)
    mtconnect: MtconnectSettings = field(default_factory=MtconnectSettings)
    maintenance: MaintenanceSettings = field(default_factory=MaintenanceSettings)
    worker: WorkerSettings = field(default_factory=WorkerSettings)
    status_max_age_s: float = 30.0  # a status is recomputed at least this often (others' measurements)
    # reverse proxies (addresses or CIDRs) whose X-Forwarded-For names the client; from any
    # other peer the header is ignored
    trusted_proxies: tuple[str, ...] = ()

    @property
    def db_url(self) -> str:
        return self.database_url or sqlite_url(self.data_dir)

    @property
    def profiles_path(self) -> Path:
        """Where ``profile=NAME`` in a controller URL is looked up."""
        return self.profiles_dir if self.profiles_dir is not None else self.data_dir / "profiles"

    @property
    def uses_simulator(self) -> bool:
        return any(a.settings.controller_url == SIM_CONTROLLER for a in self.axes)


DEMO_MACHINE = "demo-vmc"
DEFAULT_MQTT_URL = "mqtt://127.0.0.1:1883"  # `make run` publishes to a local broker, if one listens
DEMO_TASK = MachiningTask("circle R200 F200", "circle", feed_mm_min=200.0, gain_per_s=10.0, tolerance_um=45.0,
                          radius_mm=200.0)


def demo_axis(*, travel_mm: tuple[float, float] = (0.0, 1000.0), controller_url: str = SIM_CONTROLLER,
              interval_s: float = 60.0) -> AxisConfig:
    """The seed paper's Y axis (Table 1, Section 5), on the simulated controller unless
    ``controller_url`` names another; a shorter ``travel_mm`` makes a shorter round trip."""
    spec = AxisSpec("y", transmission_mm_per_rev=6.857, screw_lead_mm=16.0, position_gain_per_s=10.0,
                    travel_mm=travel_mm)
    return AxisConfig(DEMO_MACHINE, AxisSettings(
        spec=spec, controller_url=controller_url, measure_feed_mm_min=3000.0, measure_acceleration_mm_s2=500.0,
        warning_fraction=0.9, schedule=Schedule(interval_s=interval_s), tasks=(DEMO_TASK,),
    ))


# `make run`'s demo chain wears: b̄ starts OK near 192 µm (190 µm at 20 °C, the shop 21 ± 2 °C), grows
# 4 µm per utility day with a utility day every 15 s, so the axis is WARNING after about a minute and ALARM
# (about 239 µm) after about three; `mebm maintenance repair` restores it (docs/maintenance.md)
DEMO_SIMULATOR = SimulatorSettings(backlash_um_at_20c=190.0, temperature_amplitude_c=2.0, wear_um_per_day=4.0,
                                   utility_days_per_s=1.0 / 15.0)


def default_settings() -> Settings:
    return Settings(machines=((DEMO_MACHINE, "demo: the seed paper's Y axis on a simulated controller"),),
                    axes=(demo_axis(),), mqtt=MqttSettings(url=DEFAULT_MQTT_URL),
                    opcua=OpcuaSettings(enabled=True), simulator=DEMO_SIMULATOR, cycle_processes=2)

