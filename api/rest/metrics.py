"""Prometheus metrics, computed from the database at scrape time (they survive restarts
and agree with what the API reports). One registry per app, no global state."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from datetime import timedelta

import numpy as np

from api.service.cycles.leases import FleetScheduler, workers_overview
from storage.db import StorageError, leases, results_repo, session_scope, utcnow
from storage.retention import folder_bytes


class ServiceCollector:
    def __init__(self, service):
        self.service = service

    def collect(self):
        yield from self._health()
        up = GaugeMetricFamily("mebm_database_up", "1 when the database answers")
        try:
            with session_scope(self.service.factory) as s:
                snap = results_repo.metrics_snapshot(s)
            up.add_metric([], 1.0)
        except StorageError:
            up.add_metric([], 0.0)
            yield up
            return
        yield up
        cycles = CounterMetricFamily("mebm_cycles", "Measurement cycles by axis and final status",
                                     labels=["axis_id", "status"])
        failed = CounterMetricFamily("mebm_cycles_failed", "Cycles that failed or were interrupted",
                                     labels=["axis_id"])
        per_axis_failed: dict[int, int] = {}
        for (axis_id, status), n in sorted(snap["cycles"].items()):
            cycles.add_metric([str(axis_id), status], float(n))
            if status in ("failed", "interrupted"):
                per_axis_failed[axis_id] = per_axis_failed.get(axis_id, 0) + n
        for axis_id, n in sorted(per_axis_failed.items()):
            failed.add_metric([str(axis_id)], float(n))
        yield cycles
        yield failed
        last = GaugeMetricFamily("mebm_last_success_timestamp_seconds",
                                 "Unix time of the last good measurement per axis", labels=["axis_id"])
        for axis_id, t in sorted(snap["last_success"].items()):
            last.add_metric([str(axis_id)], t.timestamp())
        yield last
        alerts = GaugeMetricFamily("mebm_active_alerts", "Active (not cleared) alerts", labels=["axis_id"])
        total = 0
        for axis_id, n in sorted(snap["active_alerts"].items()):
            alerts.add_metric([str(axis_id)], float(n))
            total += n
        yield alerts
        tot = GaugeMetricFamily("mebm_active_alerts_total", "Active alerts over all axes")
        tot.add_metric([], float(total))
        yield tot
        lost = CounterMetricFamily("mebm_raw_runs_lost", "Cycles whose raw run could not be kept anywhere",
                                   labels=["axis_id"])
        for axis_id, n in sorted(snap.get("raw_runs_lost", {}).items()):
            lost.add_metric([str(axis_id)], float(n))
        yield lost
        disk = GaugeMetricFamily("mebm_dataset_bytes", "Bytes of raw runs on disk per axis (all its dataset folders)",
                                 labels=["axis_id"])
        for axis_id, axis in sorted(self.service.executor._axes.items()):
            disk.add_metric([str(axis_id)], float(sum(folder_bytes(f) for f in self.service.axis_folders(axis))))
        yield disk
        spooled = GaugeMetricFamily("mebm_spooled_cycles", "Cycles kept on disk waiting for the database")
        ex = self.service.executor
        spooled.add_metric([], float(len(ex.pending()) + len(ex.unsaved)))
        yield spooled
        yield from self._fleet()

    def _fleet(self):
        """Leases held and takeovers per worker, lateness of scheduled cycles."""
        try:
            workers = workers_overview(self.service)
            late_rows = []
            if isinstance(self.service.scheduler, FleetScheduler):
                with session_scope(self.service.factory) as s:
                    late_rows = leases.lateness(s, utcnow() - timedelta(hours=1))
        except StorageError:
            return
        held = GaugeMetricFamily("mebm_worker_leases_held", "Axes whose lease each live worker holds",
                                 labels=["worker"])
        taken = CounterMetricFamily("mebm_lease_takeovers", "Axes a worker took over from a worker whose lease "
                                    "had expired", labels=["worker"])
        live = GaugeMetricFamily("mebm_workers_live", "Workers whose heartbeat is younger than their lease")
        for w in workers:
            if w["live"]:
                held.add_metric([w["name"]], float(len(w["axes"])))
            taken.add_metric([w["name"]], float(w["takeovers"]))
        live.add_metric([], float(sum(1 for w in workers if w["live"])))
        yield held
        yield taken
        yield live
        last = GaugeMetricFamily("mebm_cycle_lateness_seconds", "Start minus due time of the axis' last scheduled "
                                 "cycle (last hour)", labels=["axis_id"])
        for axis_id, late_s in sorted(dict(late_rows).items()):
            last.add_metric([str(axis_id)], late_s)
        yield last
        p95 = GaugeMetricFamily("mebm_cycle_lateness_p95_seconds", "95th percentile of the lateness of the "
                                "scheduled cycles started in the last hour (due time to start)")
        if late_rows:
            p95.add_metric([], float(np.percentile([v for _, v in late_rows], 95)))
        yield p95


    def _health(self):
        rep = self.service.health.report()
        healthy = GaugeMetricFamily("mebm_healthy", "1 when /healthz is ok; 0 when degraded (see mebm_degraded)")
        healthy.add_metric([], 1.0 if rep.ok else 0.0)
        yield healthy
        degraded = GaugeMetricFamily("mebm_degraded", "1 per reason the service is degraded", labels=["reason"])
        for reason in rep.problems:
            degraded.add_metric([reason], 1.0)
        yield degraded
        writable = GaugeMetricFamily("mebm_database_writable", "1 when a write to the database succeeds")
        writable.add_metric([], 1.0 if rep.database == "ok" else 0.0)
        yield writable
        folder = GaugeMetricFamily("mebm_data_dir_writable", "1 when the data folders take a new file")
        folder.add_metric([], 1.0 if rep.data_dir_writable else 0.0)
        yield folder
        if rep.free_disk_bytes is not None:
            free = GaugeMetricFamily("mebm_disk_free_bytes", "Free disk under the data folder")
            free.add_metric([], float(rep.free_disk_bytes))
            yield free
        floor = GaugeMetricFamily("mebm_disk_free_floor_bytes", "Configured floor of free disk (degraded below)")
        floor.add_metric([], float(rep.min_free_disk_bytes))
        yield floor


def make_registry(service) -> CollectorRegistry:
    reg = CollectorRegistry(auto_describe=False)
    reg.register(ServiceCollector(service))
    return reg


def render(registry: CollectorRegistry) -> bytes:
    return generate_latest(registry)
