"""The agent: the device model and the observation buffer, kept current from the
service's events.

``start()`` subscribes to the event hub (its own bounded queue and thread, like every
interface); ``seed()``, once the service has started, puts every axis' status from the
database into the buffer, so ``/current`` is right after a restart. Then each
``measurement_stored``, ``cycle_failed`` and ``alert_changed`` recomputes that axis'
status (the same :class:`~api.service.status.StatusCache` the REST status reads) and
appends the values that changed; ``axis_changed`` (an axis created, its tasks or
schedule set through the API) updates the device model at once (``deviceModelChangeTime``).
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from dataclasses import replace
from pathlib import Path

from api.mtconnect.buffer import ObservationBuffer, Window
from api.mtconnect.documents import Header
from api.mtconnect.model import Component, Device, Value, component_for, device_for, values_for
from api.service.config.settings import MtconnectSettings
from api.service.events import Event
from storage.db import StorageError, config_repo, session_scope, utcnow

log = logging.getLogger("mebm.mtconnect")
INSTANCE_FILE = "mtconnect-instance-id"  # in the data folder


class MTConnectAgent:
    def __init__(self, service, settings: MtconnectSettings):
        self.service = service
        self.settings = settings
        self.sender = settings.sender or socket.gethostname() or "mebm"
        self.instance_id = int(time.time())  # a new instance: clients know the sequences started again
        self.buffer = ObservationBuffer(settings.buffer_size)
        self.model_changed_at = utcnow()
        self._machines: dict[int, tuple[str, dict[int, Component]]] = {}  # machine id -> name, axis id -> Linear
        self._lock = threading.RLock()
        self._seeded = False
        self.subscription = None
        self.shdr = None

    # -- life cycle ----------------------------------------------------------------------------------
    def start(self) -> None:
        """Subscribe to the service's events (before the service starts cycles); open the
        SHDR port if configured (:class:`~core.errors.InputError` if it cannot listen)."""
        if self.settings.shdr_port is not None:
            from api.mtconnect.shdr import ShdrAdapter
            from core.errors import InputError

            try:
                self.shdr = ShdrAdapter(self.buffer, self.settings.shdr_host, self.settings.shdr_port)
            except OSError as exc:
                raise InputError(f"mtconnect.shdr_port: cannot listen on {self.settings.shdr_host}:"
                                 f"{self.settings.shdr_port}: {exc.strerror}") from exc
        self.subscription = self.service.events.subscribe("mtconnect", self.handle)

    def seed(self) -> None:
        """Every configured axis' current status into the buffer (once; the service must be started)."""
        with self._lock:
            if self._seeded:
                return
            self.instance_id = self._next_instance_id()
            now = utcnow()
            try:
                with session_scope(self.service.factory) as s:
                    axes = config_repo.list_axes(s)
            except StorageError as exc:  # the next event tries again; the API starts meanwhile
                log.warning("MTConnect agent not seeded yet: %s", exc)
                return
            for axis in axes:
                try:
                    self._update(self.service.status.get(axis.id), now, seed=True)
                except StorageError as exc:
                    log.warning("MTConnect: axis %s not seeded (%s); it appears at its next cycle", axis.id, exc)
            self._seeded = True
            log.info("MTConnect agent seeded: %d device(s), sequences %d..%d", len(self._machines),
                     *self.buffer.bounds()[:2])

    def _next_instance_id(self) -> int:
        """The start time in seconds, but always above the last start's (kept in the data
        folder): a restart within a second still tells clients the sequences began anew."""
        path = Path(self.service.settings.data_dir) / INSTANCE_FILE
        new = int(time.time())
        try:
            last = int(path.read_text().strip()) if path.is_file() else 0
            new = max(new, last + 1)
            path.write_text(f"{new}\n")
        except (OSError, ValueError) as exc:
            log.warning("MTConnect instanceId from the clock only (%s: %s)", path, exc)
        return new

    def close(self) -> None:
        if self.shdr is not None:
            self.shdr.close()
            self.shdr = None
        if self.subscription is not None:
            self.service.events.unsubscribe(self.subscription)
            self.subscription = None

    # -- events --------------------------------------------------------------------------------------
    def handle(self, ev: Event) -> None:
        if ev.kind not in ("measurement_stored", "cycle_failed", "alert_changed", "axis_changed", "work_order_changed",
                           "circular_test_stored"):
            return
        if not self._seeded:
            self.seed()  # reads this event's cycle too (events follow the commit)
            return
        st = self.service.status.get(ev.axis_id)  # outside the lock: requests never wait on the database
        with self._lock:
            self._update(st, utcnow())

    def _update(self, st, now, *, seed: bool = False) -> None:
        a = st.axis
        name, comps = self._machines.get(a.machine_id, (a.machine_name, {}))
        device_new = a.machine_id not in self._machines
        comp = component_for(st)
        if comps.get(a.id) != comp or name != a.machine_name:
            comps = dict(comps)
            comps[a.id] = comp
            self._machines[a.machine_id] = (a.machine_name, comps)
            if not seed:
                self.model_changed_at = now
        dev = self._device(a.machine_id)
        if device_new:
            self.buffer.add(dev.id, dev.id, [Value(dev.data_items[0], now, "AVAILABLE")])
        self.buffer.add(dev.id, comp.id, values_for(st, comp, now))

    # -- reading -------------------------------------------------------------------------------------
    def _device(self, machine_id: int) -> Device:
        name, comps = self._machines[machine_id]
        return device_for(machine_id, name, tuple(comps[k] for k in sorted(comps)), self.service.instance)

    def devices(self, name: str | None = None) -> list[Device] | None:
        """All devices, or the one named ``name`` (by name or uuid); None if there is none such."""
        with self._lock:
            devs = [self._device(m) for m in sorted(self._machines)]
        if name is None:
            return devs
        devs = [d for d in devs if name in (d.name, d.uuid)]
        return devs or None

    def header(self) -> Header:
        return Header(sender=self.sender, instance_id=self.instance_id, buffer_size=self.buffer.size,
                      device_model_change_time=self.model_changed_at, creation_time=utcnow())

    def current(self, devices: list[Device]) -> Window:
        return self.only(self.buffer.current(), devices)

    @staticmethod
    def only(w: Window, devices: list[Device]) -> Window:
        """``w`` without the observations of DataItems not in ``devices`` (another device's,
        or of a task since removed): a client finds every dataItemId in the probe."""
        wanted = {di.id for d in devices for di in d.data_items}
        wanted |= {di.id for d in devices for c in d.components for di in c.data_items}
        return replace(w, observations=tuple(o for o in w.observations if o.v.data_item.id in wanted))
