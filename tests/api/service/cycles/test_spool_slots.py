"""Spool slots and the loss ledger on an ordinary folder: cycles finishing at once on a
full disk each get a slot of their own (never two in one), written in place and renamed to
their spool file; the ones that find none leave one ledger record each. The full-disk
path end to end (a real small tmpfs, kills and restarts): tests/api/rest/test_full_disk.py."""

from __future__ import annotations

import json
import threading

from api.service.cycles.executor import LEDGER_RECORD_BYTES, CycleExecutor


def _doc(i: int) -> dict:
    return {"uuid": f"cycle-{i}", "axis_id": 1, "trigger": "schedule", "requested_by": None, "status": "ok",
            "requested_at": "2026-01-01T00:00:00+00:00", "started_at": "2026-01-01T00:00:01+00:00",
            "finished_at": "2026-01-01T00:01:00+00:00", "failure_reason": "storage_full: the disk was full",
            "tasks": [], "padding": "x" * (300 + i)}


def test_cycles_finishing_at_once_get_a_slot_each_and_the_rest_a_ledger_record(tmp_path):
    ex = CycleExecutor(None, tmp_path, None, None, slots=3, slot_bytes=4096)
    assert ex.ensure_reserve() and ex.free_slots() == 3 and ex.reserve_ok()
    start = threading.Barrier(8)
    got: dict[int, object] = {}

    def finish(i: int) -> None:
        start.wait(10)
        got[i] = ex._write_into_slot(_doc(i))

    threads = [threading.Thread(target=finish, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    kept = {i: p for i, p in got.items() if p is not None}
    assert len(kept) == 3 and ex.free_slots() == 0
    for i, path in kept.items():  # each a whole spool file of its own cycle, no byte of another
        assert path.name == f"cycle-{i}.json" and json.loads(path.read_text()) == _doc(i)
    records = {d["uuid"] for _, d in ex._ledger_records()}
    assert records == {f"cycle-{i}" for i in got if i not in kept}  # every other one: its record
    assert (tmp_path / "spool" / ".ledger").stat().st_size % LEDGER_RECORD_BYTES == 0


def test_a_spool_file_larger_than_a_slot_is_kept_without_its_trace_and_says_so(tmp_path):
    ex = CycleExecutor(None, tmp_path, None, None, slots=1, slot_bytes=2048)
    assert ex.ensure_reserve()
    doc = {**_doc(0), "raw_run_lost": "not written to the dataset folder", "trace": {"time_s": "A" * 5000}}
    path = ex._write_into_slot(doc)
    kept = json.loads(path.read_text())
    assert "trace" not in kept and "did not fit a spool slot" in kept["raw_run_lost"]
    assert kept["uuid"] == "cycle-0" and kept["status"] == "ok"
