"""The OPC UA server on its own thread and event loop, fed by the service's events.

``start()`` blocks until the server listens (or could not: the port taken, a bad
certificate), seeds every configured axis from the database and subscribes to the
event hub. It never raises for a server that cannot start: it logs the reason, keeps it
in ``error`` and the service goes on measuring without OPC UA. Each event is turned into
values on the hub's consumer thread (database reads) and written on the server's loop.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import threading
from urllib.parse import urlsplit, urlunsplit

from asyncua import Server, ua
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

from api.opcua.access import ReadOnlyRuleset, Users
from api.opcua.nodes import AddressSpace, namespace_uri
from api.opcua.values import axis_values
from api.service.config.settings import OpcuaSettings
from api.service.events import Event
from storage.db import config_repo, session_scope

log = logging.getLogger("mebm.opcua")
START_TIMEOUT_S = 60.0
CALL_TIMEOUT_S = 30.0


class _DeniedIsInfo(logging.Filter):
    """asyncua logs every refused request of a client at ERROR ("sending service fault
    response: ... (BadUserAccessDenied)"); a read-only server refuses writes by design, so
    a client that tries one is an INFO line, not an error of the service."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.WARNING and "AccessDenied" in record.getMessage():
            record.levelno, record.levelname = logging.INFO, "INFO"
        return True


_DENIED_IS_INFO = _DeniedIsInfo()


class OpcuaServer:
    def __init__(self, service, settings: OpcuaSettings):
        self.service = service
        self.settings = settings
        self.endpoint = settings.endpoint  # the port filled in once listening (port 0)
        self.running = False
        self.error: str | None = None
        self.updates = 0
        self.subscription = None
        self._server: Server | None = None
        self._space: AddressSpace | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._started = threading.Event()
        self._abandoned = False

    # -- life cycle ------------------------------------------------------------------------------
    def start(self) -> bool:
        """Start listening, seed the address space, subscribe; False (``error`` says why) if
        the server could not start."""
        logging.getLogger("asyncua.server.uaprocessor").addFilter(_DENIED_IS_INFO)  # once: a filter is kept once
        self._thread = threading.Thread(target=self._run, name="mebm-opcua", daemon=True)
        self._thread.start()
        if not self._started.wait(START_TIMEOUT_S):
            self._abandoned = True  # the thread stops the server if it starts after all
            self.error = f"did not start within {START_TIMEOUT_S:g} s"
        if self.error is not None:
            log.error("OPC UA server NOT started on %s: %s; the service goes on without OPC UA",
                      self.settings.endpoint, self.error)  # fmt: skip
            self._stop_loop()
            return False
        self.subscription = self.service.events.subscribe("opcua", self.handle)
        try:
            with session_scope(self.service.factory) as s:
                axis_ids = [a.id for a in config_repo.list_axes(s)]
        except Exception:  # noqa: BLE001 - the next measurement fills in what seeding missed
            log.exception("OPC UA: seeding the address space from the database failed")
            axis_ids = []
        for axis_id in axis_ids:  # one axis that cannot be shown leaves the others shown
            try:
                self.update(axis_id)
            except Exception:  # noqa: BLE001 - the next measurement of that axis tries again
                log.exception("OPC UA: axis %d could not be added to the address space", axis_id)
        log.info("OPC UA server listening on %s", self.endpoint)
        return True

    def _run(self) -> None:
        loop = self._loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._start())
        except Exception as exc:  # noqa: BLE001 - reported by start(), the service goes on
            self.error = _reason(exc)
            loop.run_until_complete(self._quiet_stop())
        if self._abandoned and self.error is None:
            self.running = False
            loop.run_until_complete(self._quiet_stop())
        self._started.set()
        if self.error is None and not self._abandoned:
            loop.run_forever()
        loop.close()

    async def _start(self) -> None:
        st = self.settings
        _probe_port(st.endpoint)  # fail in a millisecond, not after building the address space
        trust = None
        if st.trusted_certificates is not None:
            trust = TrustStore([st.trusted_certificates], [])
            await trust.load()
        users = Users(st, trust)
        srv = Server(user_manager=users)
        await srv.init()
        srv.set_endpoint(st.endpoint)
        srv.set_server_name("mebm: backlash and TBE of machine-tool feed axes")
        await srv.set_application_uri("urn:mebm:server")
        policies = security_policies(st)
        if st.certificate is not None:
            await srv.load_certificate(str(st.certificate))
            await srv.load_private_key(str(st.private_key))
        srv.set_security_policy(policies, permission_ruleset=ReadOnlyRuleset())
        if trust is not None:  # a client certificate must be trusted (directly or by its CA) for a channel
            srv.set_certificate_validator(CertificateValidator(
                CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT, trust))
        srv.set_identity_tokens(users.identity_tokens())
        srv.allow_remote_admin(False)
        idx = await srv.register_namespace(namespace_uri(self.service.instance))
        self._server = srv
        self._space = AddressSpace(srv, idx)
        await self._space.build()
        await srv.start()
        port = srv.bserver.port
        u = urlsplit(st.endpoint)
        host = f"[{u.hostname}]" if ":" in u.hostname else u.hostname
        self.endpoint = urlunsplit((u.scheme, f"{host}:{port}", u.path, u.query, u.fragment))
        self.running = True

    async def _quiet_stop(self) -> None:
        if self._server is not None:
            try:
                await self._server.stop()
            except Exception:  # noqa: BLE001 - a half-started server: nothing more to free
                log.debug("OPC UA stop after a failed start", exc_info=True)

    def _stop_loop(self) -> None:
        if self._loop is not None and self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
        if self._thread is not None:
            self._thread.join(10)

    def close(self) -> None:
        if self.subscription is not None:
            self.service.events.unsubscribe(self.subscription)
            self.subscription = None
        if self.running and self._loop is not None:
            try:
                asyncio.run_coroutine_threadsafe(self._server.stop(), self._loop).result(CALL_TIMEOUT_S)
            except Exception:  # noqa: BLE001 - stopping anyway
                log.warning("OPC UA server did not stop cleanly", exc_info=True)
        self.running = False
        self._stop_loop()

    # -- values ----------------------------------------------------------------------------------
    def update(self, axis_id: int) -> None:
        """Read the axis' status (on the calling thread) and write it into the address space."""
        values = axis_values(self.service, axis_id)
        asyncio.run_coroutine_threadsafe(self._space.apply(values), self._loop).result(CALL_TIMEOUT_S)
        self.updates += 1

    def handle(self, ev: Event) -> None:
        if self.running:
            self.update(ev.axis_id)

    def describe(self) -> dict:
        """For /interfaces and the banner."""
        st = self.settings
        return {"endpoint": self.endpoint, "running": self.running, "error": self.error,
                "anonymous": st.anonymous, "username": st.username is not None,
                "trusted_certificates": st.trusted_certificates is not None,
                "security_policies": [p.name for p in security_policies(st)],
                "updates": self.updates}  # fmt: skip


def security_policies(st: OpcuaSettings) -> list[ua.SecurityPolicyType]:
    """None, plus Basic256Sha256 with a server certificate; with trusted client
    certificates only the signed ones: on a None channel the client's certificate is
    not proven (it need not hold the key), so it could not be trusted there."""
    signed = [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt, ua.SecurityPolicyType.Basic256Sha256_Sign]
    if st.trusted_certificates is not None:
        return signed
    return [ua.SecurityPolicyType.NoSecurity] + (signed if st.certificate is not None else [])


def _probe_port(endpoint: str) -> None:
    """OSError if the endpoint's port is taken (asyncio's server binds the same way, with
    SO_REUSEADDR; the real bind later still reports a port taken in between)."""
    u = urlsplit(endpoint)
    if not u.port:
        return
    for family, kind, proto, _, addr in socket.getaddrinfo(u.hostname, u.port, type=socket.SOCK_STREAM):
        with socket.socket(family, kind, proto) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(addr)


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.errno is not None:
        return f"cannot listen ({exc.strerror or exc}); is another OPC UA server on the port?"
    return f"{type(exc).__name__}: {exc}"
