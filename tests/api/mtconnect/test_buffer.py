"""The agent's ring buffer: sequence numbers, bounds, the window /sample serves."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from api.mtconnect.buffer import ObservationBuffer, OutOfRangeError
from api.mtconnect.model import DataItem, Value

T0 = datetime(2026, 11, 25, tzinfo=timezone.utc)
DI = DataItem("a1_backlash", "SAMPLE", "DISPLACEMENT", "Displacement", units="MILLIMETER")


def _values(n: int, start: int = 0) -> list[Value]:
    return [Value(DI, T0 + timedelta(seconds=i), 0.1 + i / 1000) for i in range(start, start + n)]


def test_sequences_count_from_one_and_the_ring_keeps_the_newest():
    buf = ObservationBuffer(4)
    assert buf.bounds() == (1, 0, 1)  # empty: first = next, last = next - 1
    for v in _values(6):
        buf.add("m1", "a1", [v])
    assert buf.bounds() == (3, 6, 7)  # 1 and 2 fell out of the ring
    w = buf.sample(None, 100)
    assert [o.sequence for o in w.observations] == [3, 4, 5, 6] and w.next == 7
    w = buf.sample(4, 2)
    assert [o.sequence for o in w.observations] == [4, 5] and (w.first, w.last, w.next) == (3, 6, 6)
    assert buf.sample(7, 10).observations == () and buf.sample(7, 10).next == 7  # from = next: nothing yet
    with pytest.raises(OutOfRangeError, match="greater than or equal to 3"):
        buf.sample(2, 1)
    with pytest.raises(OutOfRangeError):
        buf.sample(8, 1)
    # current: the newest of each DataItem, whatever the ring lost
    assert [o.sequence for o in buf.current().observations] == [6]


def test_an_unchanged_value_is_not_observed_again():
    buf = ObservationBuffer(10)
    (v,) = _values(1)
    assert buf.add("m1", "a1", [v]) == 1
    assert buf.add("m1", "a1", [v]) == 0  # same value, same timestamp: a duplicate
    assert buf.add("m1", "a1", [v], only_changed=False) == 1
    assert buf.add("m1", "a1", _values(1, start=1)) == 1  # a new measurement, even of the same size
    assert buf.bounds() == (1, 3, 4)
    later = T0 + timedelta(hours=1)
    gone = Value(DI, T0, None)
    assert buf.add("m1", "a1", [gone]) == 1
    assert buf.add("m1", "a1", [Value(DI, later, None)]) == 0  # still UNAVAILABLE: nothing new
    cond = DataItem("a1_cond", "CONDITION", "DISPLACEMENT", "")
    normal = Value(cond, T0, "OK: ...", level="Normal", native_code="OK")
    assert buf.add("m1", "a1", [normal]) == 1
    assert buf.add("m1", "a1", [Value(cond, later, "OK: ...", level="Normal", native_code="OK")]) == 0
    assert buf.add("m1", "a1", [Value(cond, later, "WARNING: ...", level="Warning", native_code="WARNING")]) == 1


def test_a_buffer_of_no_size_is_refused():
    with pytest.raises(ValueError, match="buffer size"):
        ObservationBuffer(0)
