"""``mebm serve [--config FILE]``: the REST API, the scheduler and (for axes whose
controller is ``sim``, as in the embedded demo) the built-in simulated controller."""

from __future__ import annotations

import argparse
import json
import logging
import signal
import socket
import sys
from dataclasses import replace
from pathlib import Path

from api.service.config.loading import load_settings
from api.service.installation import installation_name
from api.service.secret_files import ADMIN_KEY_FILE, DEMO_KEYS_FILE, SIGN_IN_LINK_FILE, secret_path, write_secret_file


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve", help="run the service: REST API, scheduled measurements, simulated demo controller",
                       description="Run the mebm service. Without --config: SQLite under ./data (MEBM_DATA_DIR), "
                                   "the demo machine on a built-in simulated controller. Secrets (the demo "
                                   "keys, the dashboard's sign-in link) go to mode-600 files of the data "
                                   "directory, stdout says where; --show-keys prints them too.")
    p.add_argument("--config", type=Path, help="TOML configuration file (docs/configuration.md)")
    p.add_argument("--host", help="listen address (default 127.0.0.1; env MEBM_HOST)")
    p.add_argument("--port", type=int, help="listen port, 0 for a free one (default 8000; env MEBM_PORT)")
    p.add_argument("--data-dir", type=Path, help="data directory (default ./data; env MEBM_DATA_DIR)")
    p.add_argument("--no-scheduler", action="store_true", help="serve the API only: no scheduled cycles")
    p.add_argument("--show-keys", action="store_true",
                   help="also print the demo keys created and the sign-in link (for an operator at a terminal: "
                        "stdout of a service usually ends in a journal)")
    p.set_defaults(func=_serve)


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    # proto must be IPPROTO_TCP: asyncio only sets TCP_NODELAY on such sockets, and without
    # it every response waits ~40 ms for a delayed ACK (Nagle) on keep-alive connections.
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        from core.errors import InputError

        raise InputError(f"cannot listen on {host}:{port}: {exc.strerror} (try --port 0 for a free port)") from exc
    sock.listen(2048)
    sock.set_inheritable(True)
    return sock


def demo_read_key(settings, report) -> str | None:
    """The demo read key: created by this start, else the one kept in demo-keys.json."""
    if report.demo_keys.get("read"):
        return report.demo_keys["read"]
    path = secret_path(settings.data_dir, settings.database_url, DEMO_KEYS_FILE)
    try:
        kept = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}
    except (OSError, ValueError):
        return None
    key = kept.get("read") if isinstance(kept, dict) else None
    return key if isinstance(key, str) else None


def opcua_line(settings, opcua) -> str:
    o = settings.opcua
    if not o.enabled:
        return "OPC UA: off ([opcua] enabled)"
    if opcua is None or not opcua.running:
        why = opcua.error if opcua is not None else "not started"
        return f"OPC UA: NOT running on {o.endpoint}: {why} (the service goes on without it)"
    who = " + ".join((["anonymous"] if o.anonymous else []) + ([f"user {o.username!r}"] if o.username else [])
                     + (["certificate users"] if o.trusted_certificates else [])) + " read-only"
    sec = "Basic256Sha256 only, trusted client certificates" if o.trusted_certificates else \
        "None" + (", Basic256Sha256" if o.certificate else "")
    return f"OPC UA: {opcua.endpoint}  ({who}; security {sec}; Objects/Machines/<machine>/<axis>/BacklashMean)"


def banner(settings, report, url: str, opcua=None, sign_in_url: str | None = None, *, show_keys: bool = False,
           sign_in_file: Path | None = None, sign_in_error: str | None = None) -> str:
    """The start banner. It names the files that hold secrets and prints no secret, unless
    ``show_keys`` (``mebm serve --show-keys``): then the demo keys this start created and
    the sign-in link are printed as well."""
    data = Path(settings.data_dir)
    if sign_in_url and show_keys:
        sign_in = f"  (one-time sign-in link for the demo read key, valid 10 min: {sign_in_url})"
    elif sign_in_url and sign_in_file is not None:
        sign_in = f"  (one-time sign-in link for the demo read key, valid 10 min, in {sign_in_file})"
    elif sign_in_error:
        sign_in = f"  (no sign-in link: {sign_in_error}; sign in with an access key)"
    else:
        sign_in = "  (sign in with an access key)"
    lines = [f"mebm service on {url}  (API {url}/api/v1, OpenAPI docs {url}/docs)",
             f"dashboard: {url}/ui/" + sign_in,
             f"database: {report.database}"]
    if getattr(report, "waiting_for_room", None):
        lines.append(f"WAITING FOR DISK: {report.waiting_for_room}; until then /healthz says so and every "
                     "request that needs the database answers 503")
    if getattr(report, "worker", None):
        lines.append(report.worker)
    if report.replayed:
        lines.append(f"stored {report.replayed} cycle(s) kept on disk during a database outage")
    if report.interrupted:
        lines.append(f"{report.interrupted} cycle(s) interrupted by the last stop were closed")
    for line in (*getattr(report, "not_stored", ()), *getattr(report, "lost", ())):
        lines.append(line)
    for line in getattr(report, "folders_moved_aside", ()):
        lines.append(f"{line} (nothing deleted; what to do with it: docs/operations.md, "
                     "'Dataset folders and their owner')")
    for axis_id, sim_url in report.simulators.items():
        lines.append(f"axis {axis_id}: built-in simulated controller on {sim_url}")
    m = settings.mqtt
    lines.append(f"MQTT: {_redact_url(m.url)}, topics {m.topic_prefix}/{installation_name(settings)}/<machine>/<axis>/"
                 "status|alerts" if m.url
                 else "MQTT: off ([mqtt] url or MEBM_MQTT_URL)")  # fmt: skip
    lines.append(opcua_line(settings, opcua))
    w = settings.webhooks
    lines.append(f"webhooks: {len(w.urls)} receiver(s)" if w.urls else "webhooks: off ([webhooks] urls)")
    mc = settings.mtconnect
    lines.append(f"MTConnect agent: {url}/mtconnect/probe, /current, /sample"
                 + (" (any API key)" if mc.require_key else " (open, read-only)") if mc.enabled
                 else "MTConnect: off ([mtconnect] enabled)")  # fmt: skip
    if mc.enabled and mc.shdr_port is not None:
        lines.append(f"MTConnect SHDR adapter: {mc.shdr_host}:{mc.shdr_port} (device file: {url}/mtconnect/probe)")
    kept_at = secret_path(data, settings.database_url, DEMO_KEYS_FILE)  # this database's files
    admin_at = secret_path(data, settings.database_url, ADMIN_KEY_FILE)
    if report.demo_keys:  # only the keys created by this start
        k = report.demo_keys
        files = [f"read and operate in {kept_at}"] if ("read" in k or "operate" in k) else []
        files += [f"admin in {admin_at}"] if "admin" in k else []
        if show_keys:
            lines.append(f"demo keys created (shown this once; {', '.join(files)}, mode 600):")
            labels = {"read": "read (MES):", "operate": "operate:", "admin": "admin:"}
            lines += [f"  {labels[r]:<12} {k[r]}" for r in ("read", "operate", "admin") if r in k]
        else:
            lines.append(f"demo keys created: {', '.join(files)} (mode 600; --show-keys prints them)")
        if "read" in k:
            # without --show-keys the examples name the key $K, set from the file
            header = f"'X-API-Key: {k['read']}'" if show_keys else '"X-API-Key: $K"'
            where = "" if show_keys else f"; K: the read key in {kept_at}"
            lines += [
                f"try (the first measurement arrives within a minute{where}):",
                f"  curl -H {header} {url}/api/v1/axes/1/status",
                f"  curl -H {header} '{url}/api/v1/alerts?state=active'",
                f"  open {url}/api/v1/axes/1/plots/backlash_trend.png (with the key header) for Fig. 10",
            ]
    if "admin" not in report.demo_keys and admin_at.is_file():
        lines.append(f"the demo admin key is in {admin_at}: keep it somewhere safe and delete the file")
    if report.bootstrap_admin:
        lines.append(f"bootstrap admin key registered as {report.bootstrap_admin!r}")
    return "\n".join(lines)


def sign_in_link(settings, report, url: str, sessions) -> tuple[str | None, Path | None, str | None]:
    """The one-time sign-in link for the demo read key, written to ``<data_dir>/sign-in-link``
    (mode 600; ``sign-in-link.<tag>`` for a database other than the default one). Returns (link, its file, why it could not be written). The link carries a
    one-time token, never the key; the dashboard keeps the token hashed."""
    read_key = demo_read_key(settings, report) if settings.demo_keys else None
    if not read_key:
        return None, None, None
    from storage.db import StorageError

    try:
        link = f"{url}/ui/sign-in/{sessions.issue_link(read_key)}"
    except StorageError as exc:  # the database is not open yet (a full disk): sign in with a key later
        return None, None, f"no database yet ({exc})"
    path = secret_path(settings.data_dir, settings.database_url, SIGN_IN_LINK_FILE, claim=True)
    try:
        write_secret_file(path, link + "\n")
    except OSError as exc:
        return link, None, f"cannot write {path}: {exc.strerror or exc}"
    return link, path, None


SWITCH_INTERVAL_S = 0.001


def uvicorn_config(app, settings):
    """The uvicorn configuration ``mebm serve`` runs ``app`` with.

    ``proxy_headers=False``: the app itself trusts ``X-Forwarded-For`` from
    ``[server] trusted_proxies`` only (api.rest.proxies); uvicorn's own handling would
    trust 127.0.0.1 and the ``FORWARDED_ALLOW_IPS`` environment, and hide the TCP peer.
    The HTTP protocol bounds the request head: ``[limits] max_header_bytes``,
    ``max_headers`` and ``header_timeout_s`` (api.rest.header_limits)."""
    import uvicorn

    from api.rest.header_limits import bounded_head_protocol

    lim = settings.limits
    return uvicorn.Config(app, log_level=settings.log_level, access_log=False, timeout_graceful_shutdown=10,
                          proxy_headers=False, forwarded_allow_ips=[],
                          http=bounded_head_protocol(lim.max_header_bytes, lim.max_headers, lim.header_timeout_s))


def _serve(a: argparse.Namespace) -> int:
    import uvicorn

    from api.rest import create_app
    from api.service.figures.process import PlotProcess
    from api.service.service import Service

    # The service's threads (cycles, the in-process simulator, the event publishers) are
    # CPU-bound Python at times; a request thread waits for the interpreter lock up to the
    # switch interval at every hand-off. 1 ms instead of CPython's 5 ms: in a hand-off test
    # beside two CPU-bound threads (load 13), median 33.8 -> 6.2 ms, p99 248 -> 46 ms.
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    settings = load_settings(a.config)
    if a.host:
        settings = replace(settings, host=a.host)
    if a.port is not None:
        settings = replace(settings, port=a.port)
    if a.data_dir:
        settings = replace(settings, data_dir=a.data_dir)
    if a.no_scheduler:
        settings = replace(settings, scheduler_enabled=False)
    logging.basicConfig(level=settings.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("apscheduler").setLevel(logging.WARNING)  # one line per job run is noise
    logging.getLogger("asyncua").setLevel(logging.WARNING)  # a line per session and request otherwise
    sock = _bind(settings.host, settings.port)
    port = sock.getsockname()[1]
    service = Service(settings)
    opcua = None
    try:
        report = service.start()
        if settings.opcua.enabled:  # before the banner, which says whether it listens
            from api.opcua import OpcuaServer

            opcua = OpcuaServer(service, settings.opcua)
            opcua.start()  # logs and goes on when it cannot listen
        host = settings.host if settings.host not in ("0.0.0.0", "::") else "127.0.0.1"
        url = f"http://{host}:{port}"
        app = create_app(settings, service=service, opcua=opcua)
        link, link_file, link_error = sign_in_link(settings, report, url, app.state.ui.sessions)
        print(banner(settings, report, url, opcua, sign_in_url=link, show_keys=a.show_keys, sign_in_file=link_file,
                     sign_in_error=link_error), flush=True)
        server = uvicorn.Server(uvicorn_config(app, settings))
        # uvicorn re-raises SIGTERM after its graceful shutdown, with the handler it found: the
        # default one would end the process before `finally` stops the service (a fleet worker
        # would keep its leases for lease_s and leave its cycles running); this one exits cleanly
        signal.signal(signal.SIGTERM, _exit_on_sigterm)
        server.run(sockets=[sock])
    finally:
        if opcua is not None:
            opcua.close()
        service.stop()
        # the figure process is the interpreter's (shared by in-process restarts); this one ends now
        PlotProcess.shared().close()
        sock.close()
    sys.stdout.flush()
    return 0


def _exit_on_sigterm(signum, frame) -> None:
    raise SystemExit(0)


def _redact_url(url: str) -> str:
    """``url`` without its password (a broker URL may carry one)."""
    from urllib.parse import urlsplit, urlunsplit

    u = urlsplit(url)
    if u.password is None:
        return url
    host = u.hostname + (f":{u.port}" if u.port else "")
    return urlunsplit((u.scheme, f"{u.username}:***@{host}", u.path, u.query, u.fragment))
