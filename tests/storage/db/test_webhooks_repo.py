"""Webhook messages kept until delivered (storage/db/webhooks_repo.py), on SQLite and
PostgreSQL: each receiver's messages go out in order, a claim is held by one sender only,
a dead sender's claim runs out and another takes the message, failed messages stay until
re-queued, and the table stays bounded."""

from __future__ import annotations

import threading
from datetime import datetime, timedelta, timezone

import pytest

from storage.db import make_session_factory, session_scope, webhooks_repo as wr
from storage.db.webhooks_repo import NewMessage

T0 = datetime(2026, 3, 1, 8, 0, tzinfo=timezone.utc)
A, B = "http://mes-a/hook", "http://mes-b/hook"


@pytest.fixture
def factory(engine):
    return make_session_factory(engine)


def put(factory, *specs, at=T0):
    with session_scope(factory) as s:
        wr.enqueue(s, [NewMessage(f"msg_{name}", url, "alert.raised", 1, f'{{"n":"{name}"}}', at)
                       for name, url in specs])


def claim(factory, sender, now, claim_s=60.0, limit=20):
    with session_scope(factory) as s:
        return [m.msg_id for m in wr.claim_due(s, sender, now, claim_s, limit)]


def attempt(factory, msg_id, now, *, ok, retry_s=None):
    with session_scope(factory) as s:
        (m,) = [m for m in wr.list_messages(s) if m.msg_id == msg_id]
        return wr.record_attempt(s, m.id, now, status=200 if ok else 503, error=None if ok else "HTTP 503",
                                 delivered=ok, retry_at=None if retry_s is None else now + timedelta(seconds=retry_s))


def test_each_receiver_gets_its_messages_in_order_and_a_claim_is_one_senders(factory):
    put(factory, ("a1", A), ("a2", A), ("b1", B), ("a3", A))
    assert claim(factory, "s1", T0) == ["msg_a1", "msg_b1"]  # the head of each receiver's queue
    assert claim(factory, "s2", T0) == []  # both claimed; a2 waits behind a1
    assert attempt(factory, "msg_a1", T0, ok=False, retry_s=4.0) == wr.PENDING
    with session_scope(factory) as s:  # b1, claimed by s1 until T0 + 60 s; a2 behind a1 does not count
        assert wr.next_due(s) == T0 + timedelta(seconds=4)
    assert claim(factory, "s1", T0 + timedelta(seconds=1)) == []  # a1 backs off, a2 still behind it
    assert claim(factory, "s1", T0 + timedelta(seconds=5)) == ["msg_a1"]
    assert attempt(factory, "msg_a1", T0 + timedelta(seconds=5), ok=True) == wr.DELIVERED
    assert claim(factory, "s1", T0 + timedelta(seconds=5)) == ["msg_a2"]
    # s1 dies holding b1 and a2: once their claims run out another sender takes them
    assert claim(factory, "s2", T0 + timedelta(seconds=30)) == []
    assert claim(factory, "s2", T0 + timedelta(seconds=70)) == ["msg_a2", "msg_b1"]
    with session_scope(factory) as s:
        (a1,) = wr.list_messages(s, state=wr.DELIVERED)
        assert (a1.msg_id, a1.attempts, a1.last_status) == ("msg_a1", 2, 200)


def test_a_receivers_queue_waits_for_its_head_so_a_sender_does_not_spin(factory):
    put(factory, ("a1", A), ("a2", A), ("a3", A))  # a2, a3 due at once on their own
    claim(factory, "s1", T0)
    attempt(factory, "msg_a1", T0, ok=False, retry_s=8.0)
    with session_scope(factory) as s:
        assert wr.next_due(s) == T0 + timedelta(seconds=8)  # not T0: a sender sleeps until then


def test_a_message_that_used_every_attempt_is_kept_failed_until_requeued_and_no_longer_blocks(factory):
    put(factory, ("a1", A), ("a2", A))
    claim(factory, "s1", T0)
    assert attempt(factory, "msg_a1", T0, ok=False) == wr.FAILED
    assert claim(factory, "s1", T0) == ["msg_a2"]  # a failed message holds nothing back
    attempt(factory, "msg_a2", T0, ok=True)
    with session_scope(factory) as s:
        assert wr.counts(s) == {"pending": 0, "delivered": 1, "failed": 1}
        (f,) = wr.list_messages(s, state=wr.FAILED)
        assert (f.msg_id, f.last_status, f.last_error, f.attempts) == ("msg_a1", 503, "HTTP 503", 1)
        assert wr.next_due(s) is None
        assert wr.requeue_failed(s, T0 + timedelta(hours=1)) == 1
        assert wr.next_due(s) == T0 + timedelta(hours=1)
    assert claim(factory, "s1", T0 + timedelta(hours=1)) == ["msg_a1"]  # the same webhook-id again
    with session_scope(factory) as s:
        assert wr.list_messages(s, state=wr.PENDING)[0].attempts == 0


def test_delivered_messages_are_purged_after_a_while_and_failed_ones_beyond_the_bound(factory):
    put(factory, *[(f"a{i}", A) for i in range(5)])
    for i in range(5):
        claim(factory, "s1", T0)
        attempt(factory, f"msg_a{i}", T0 + timedelta(days=i), ok=i >= 3)  # a0-a2 failed, a3-a4 delivered
    with session_scope(factory) as s:
        gone, dropped = wr.purge(s, T0 + timedelta(days=4, hours=1), keep_delivered_s=86400.0, max_failed=2)
        assert (gone, dropped) == (1, 1)  # a3 (delivered 1 d 1 h ago) and a0 (the oldest failed)
        assert sorted(m.msg_id for m in wr.list_messages(s)) == ["msg_a1", "msg_a2", "msg_a4"]


def test_two_senders_claiming_at_once_never_take_the_same_message(factory):
    urls = [f"http://mes-{i}/hook" for i in range(40)]
    put(factory, *[(f"m{i}", u) for i, u in enumerate(urls)])
    taken: dict[str, list[str]] = {"s1": [], "s2": []}
    go = threading.Barrier(2)

    def sender(name):
        go.wait()
        while got := claim(factory, name, T0, limit=3):
            taken[name] += got

    threads = [threading.Thread(target=sender, args=(n,)) for n in taken]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not set(taken["s1"]) & set(taken["s2"])
    assert sorted(taken["s1"] + taken["s2"]) == sorted(f"msg_m{i}" for i in range(40))
