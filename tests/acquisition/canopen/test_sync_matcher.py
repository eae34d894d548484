"""SyncMatcher: pairing TPDOs with SYNCs on bus timestamps, for late, lost, duplicated and reordered frames."""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.canopen.sync_matcher import SyncMatcher, sync_counter_byte
from core.errors import InputError

PERIOD_S = 0.001
WINDOW_S = 0.0005


def _syncs(m: SyncMatcher, n: int, t0: float = 100.0, first_k: int = 1) -> list[float]:
    times = [t0 + i * PERIOD_S for i in range(n)]
    for i, t in enumerate(times):
        m.sync(first_k + i, t)
    return times


def test_each_frame_pairs_with_the_sync_it_answers():
    m = SyncMatcher(WINDOW_S)
    times = _syncs(m, 5)
    got = [m.frame(t + 0.0002, payload=i) for i, t in enumerate(times)]
    assert got == [(1, 0), (2, 1), (3, 2), (4, 3), (5, 4)]
    assert (m.matched, m.late, m.duplicates) == (5, 0, 0)


def test_a_lost_frame_leaves_a_gap_and_never_shifts_the_next():
    m = SyncMatcher(WINDOW_S)
    times = _syncs(m, 5)
    got = [m.frame(times[i] + 0.0001)[0] for i in (0, 1, 3, 4)]  # the answer to SYNC 3 was lost
    assert got == [1, 2, 4, 5]
    assert m.late == 0 and m.duplicates == 0


def test_a_frame_later_than_its_window_is_counted_not_given_to_the_next_sync():
    m = SyncMatcher(WINDOW_S)
    times = _syncs(m, 3)
    assert m.frame(times[0] + 0.0007) is None  # after the window, before SYNC 2: not attributable
    assert m.late == 1
    assert m.frame(times[1] + 0.0001)[0] == 2


def test_a_duplicated_frame_is_counted_and_dropped():
    m = SyncMatcher(WINDOW_S)
    times = _syncs(m, 2)
    assert m.frame(times[0] + 0.0001, "a") == (1, "a")
    assert m.frame(times[0] + 0.0002, "a again") is None
    assert m.duplicates == 1 and m.matched == 1


def test_frames_arriving_out_of_order_pair_by_their_timestamps():
    m = SyncMatcher(WINDOW_S)
    times = _syncs(m, 6)
    order = [1, 0, 3, 2, 5, 4]  # each pair swapped on the way to the driver
    got = {m.frame(times[i] + 0.0003, payload=i)[0]: i for i in order}
    assert got == {k + 1: k for k in range(6)}


def test_a_frame_older_than_every_sync_kept_is_late():
    m = SyncMatcher(WINDOW_S, history=4)
    times = _syncs(m, 10)
    assert m.frame(times[2] + 0.0001) is None and m.late == 1  # SYNC 3 already left the history
    assert m.frame(times[9] + 0.0001)[0] == 10


def test_a_frame_before_any_sync_is_late():
    m = SyncMatcher(WINDOW_S)
    assert m.frame(5.0) is None and m.late == 1


def test_pairing_by_sync_counter_is_exact_whatever_the_delay():
    m = SyncMatcher(WINDOW_S)
    times = _syncs(m, 300, first_k=230)  # the counter wraps 240 -> 1 inside
    # each frame arrives 7 periods late, far outside the window: the counter still pairs it
    for i in (0, 5, 11, 12, 200):
        k = 230 + i
        assert m.frame(times[i] + 7 * PERIOD_S, counter=sync_counter_byte(k))[0] == k
    assert m.frame(times[12] + 7 * PERIOD_S, counter=sync_counter_byte(242)) is None  # answered already
    assert m.duplicates == 1
    assert m.frame(times[0], counter=0) is None  # not a CiA 301 counter value


def test_sync_counter_runs_1_to_240():
    assert [sync_counter_byte(k) for k in (1, 240, 241, 480, 481)] == [1, 240, 1, 240, 1]


def test_syncs_must_go_forward():
    m = SyncMatcher(WINDOW_S)
    m.sync(5, 1.0)
    with pytest.raises(InputError, match="SYNC 5"):
        m.sync(5, 1.1)
    with pytest.raises(InputError, match="not after"):
        m.sync(6, 0.9)


def test_jittered_delayed_lossy_shuffled_stream_loses_nothing_that_arrived():
    rng = np.random.default_rng(7)
    n = 2000
    m = SyncMatcher(WINDOW_S, history=n)
    times = _syncs(m, n)
    sent = rng.random(n) > 0.02  # 2 % of the answers never sent
    delay = 0.0001 + rng.uniform(0.0, 0.0003, n)  # within the window
    frames = [(times[i] + delay[i], i + 1) for i in range(n) if sent[i]]
    frames += [frames[j] for j in rng.choice(len(frames), 20, replace=False)]  # duplicates
    order = np.argsort(np.arange(len(frames)) + rng.uniform(0, 8, len(frames)))  # local reordering
    paired = {}
    for j in order:
        t, k_true = frames[j]
        got = m.frame(t, payload=k_true)
        if got is not None:
            paired[got[0]] = got[1]
    assert all(k == v for k, v in paired.items())  # never paired with the wrong SYNC
    assert set(paired) == {i + 1 for i in range(n) if sent[i]}  # everything that arrived is kept
    assert m.duplicates == 20 and m.late == 0
    assert n - len(paired) == int((~sent).sum())  # and every lost one is a gap


def test_a_sync_echo_moves_the_window_to_the_bus_time():
    m = SyncMatcher(WINDOW_S)
    m.sync(1, 100.0)  # recorded just before sending; the host then stalled 0.4 ms
    m.sync(2, 100.001)
    assert m.restamp(1, 100.0004)
    assert m.frame(100.0008)[0] == 1  # 0.8 ms after the send time, 0.4 ms after the wire time
    assert not m.restamp(2, 99.9)  # never before the previous SYNC
    assert not m.restamp(9, 100.0)  # not a SYNC it has
