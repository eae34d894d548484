"""TraceAssembler: counter continuity, gaps, duplicates, in order, without a wire."""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.modbus import register_map as mm
from acquisition.errors import LostSamplesError, ProtocolError
from acquisition.driver.trace_assembler import TraceAssembler
from acquisition.types import SampleBlock


def block(counters, *, skew_s=0.0) -> SampleBlock:
    c = np.asarray(counters, dtype=np.int64)
    return SampleBlock(c, c * 0.001, c * 0.01, skew_s=skew_s)


def test_consecutive_blocks_assemble_in_order_with_nothing_lost():
    a = TraceAssembler(continuous=True, first_counter=100)
    a.add(block(range(100, 120)))
    a.add(SampleBlock.empty())
    a.add(block(range(120, 125)))
    time_s, counter, motor, table = a.arrays(1000.0)
    assert counter.tolist() == list(range(100, 125)) and a.lost_samples == 0 and a.samples == 25
    assert np.allclose(time_s, np.arange(25) / 1000.0) and table[-1] == pytest.approx(1.24)


def test_a_gap_is_counted_and_fails_past_the_tolerance():
    a = TraceAssembler(continuous=True, max_lost_samples=5, first_counter=0)
    a.add(block(range(0, 10)))
    a.add(block(range(13, 20)))  # 10, 11, 12 lost
    assert a.lost_samples == 3
    with pytest.raises(LostSamplesError) as err:
        a.add(block([23, 24]))  # 3 more: 6 > 5
    assert err.value.lost_samples == 6 and err.value.first_missing == 20
    assert "counter jumps from 19 to 23" in str(err.value)


def test_samples_missing_before_the_first_one_are_lost_too():
    a = TraceAssembler(continuous=True, max_lost_samples=10, first_counter=50)
    a.add(block(range(52, 60)))  # the wire's first sample is 50: 50 and 51 never arrived
    assert a.lost_samples == 2


def test_a_late_block_on_a_continuous_wire_is_refused():
    a = TraceAssembler(continuous=True, first_counter=0)
    a.add(block(range(0, 20)))
    with pytest.raises(ProtocolError, match="backwards or repeated"):
        a.add(block(range(10, 15)))  # arrived after newer samples


def test_a_duplicated_block_on_a_continuous_wire_is_refused():
    a = TraceAssembler(continuous=True, first_counter=0)
    a.add(block(range(0, 20)))
    with pytest.raises(ProtocolError, match=r"\(19 after 19\)"):
        a.add(block(range(19, 25)))


def test_a_torn_block_is_refused_where_it_goes_back():
    a = TraceAssembler(continuous=True, first_counter=0)
    with pytest.raises(ProtocolError, match=r"\(-80 after 4\)"):
        a.add(block([0, 1, 2, 3, 4, -80, 6]))  # a record of the previous lap inside the block


def test_a_lapped_reader_shows_as_one_gap_of_the_overwritten_records():
    # ring of 100: the reader read up to 29, then found records from 131 on
    a = TraceAssembler(continuous=True, max_lost_samples=10**6, first_counter=0)
    a.add(block(range(0, 30)))
    a.add(block(range(131, 231)))
    assert a.lost_samples == 101
    assert int(np.sum(np.diff(a.arrays(1000.0)[1]) - 1)) == a.lost_samples


def test_a_trace_across_the_u32_counter_wrap_is_continuous():
    # the codec unwraps against the counter it expects; the assembler sees no seam
    top = 2**32 - 5
    raw = [(top + i) % 2**32 for i in range(12)]
    a = TraceAssembler(continuous=True, first_counter=top)
    a.add(block(mm.unwrap_u32(raw[:6], top)))
    a.add(block(mm.unwrap_u32(raw[6:], top + 6)))
    assert a.lost_samples == 0 and a.arrays(1000.0)[1].tolist() == list(range(top, top + 12))


def test_polled_wires_drop_samples_read_twice_and_count_them():
    a = TraceAssembler(continuous=False)
    assert a.add(block([10]))[0].tolist() == [10]
    assert a.add(block([10]))[0].size == 0  # the same latched cycle polled again
    assert a.add(block([9]))[0].size == 0  # a late reply
    a.add(block([14, 14, 17]))
    assert a.arrays(500.0)[1].tolist() == [10, 14, 17]
    assert a.duplicates == 3 and a.lost_samples == 0  # skipped cycles are no loss when polling


def test_skew_is_the_worst_of_the_blocks_that_carried_samples():
    a = TraceAssembler(continuous=False)
    a.add(block([1], skew_s=0.002))
    a.add(block([2], skew_s=0.001))
    a.add(SampleBlock(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0), skew_s=0.5))
    assert a.skew_s == 0.002
