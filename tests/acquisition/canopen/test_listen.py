"""CANopen listen-only in-process (python-can's virtual bus): mapping from EDS/DCF, URL and
configuration, SYNC numbering, the no-send guard, and passive round trips with a CNC master."""

from __future__ import annotations

import contextlib
import itertools
import threading
import time
from pathlib import Path

import can
import numpy as np
import pytest

from acquisition.canopen import objects as co
from acquisition.canopen.driver import CanopenDriver
from acquisition.canopen.cia402 import CanopenCia402Driver
from acquisition.canopen.listen import CanopenListenDriver, ListenOnlyBusError, SyncListener, ListenOnlyBus
from acquisition.canopen.mapping import ListenMapping, PdoField, default_mapping, mapping_from_eds
from acquisition.canopen.url import driver_from_canopen_url
from acquisition.url import driver_from_url
from acquisition.measurement import run_cycle
from acquisition.sim.canopen import eds as sim_eds
from acquisition.sim.canopen.drive import SimCanopenDrive
from acquisition.sim.canopen.cnc_master import CncMaster
from acquisition.sim.twin import KinematicTwin
from acquisition.types import RoundTripProgram
from api.service.config.loading import parse_settings
from api.service.config.settings import ConfigError
from core.errors import InputError
from tests.acquisition.conftest import AXIS, PROGRAM

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = ROOT / "examples" / "canopen"
EDS = EXAMPLES / sim_eds.EDS_NAME
DCF = EXAMPLES / sim_eds.DCF_NAME
_channels = itertools.count()


# -- the mapping ------------------------------------------------------------------------------------
def test_shipped_eds_and_dcf_are_what_the_simulated_drive_offers(tmp_path):
    written = sim_eds.write_files(tmp_path)
    for p in written:
        assert (EXAMPLES / p.name).read_text() == p.read_text(), f"regenerate: python -m acquisition.sim.canopen.eds {EXAMPLES}"


def test_mapping_from_the_eds_resolves_the_node_id_and_reads_the_scale():
    m = mapping_from_eds(EDS, 9)
    assert m.tpdo_cob_id == 0x189 and m.sync_cob_id == 0x80
    assert m.motor == PdoField(0, "l") and m.table == PdoField(4, "l")
    assert m.counts_per_rev == 131072 and m.table_nm_per_count == 10
    assert m.sync_period_s is None and m.window_s is None  # an EDS does not know this bus' cycle
    assert m.decode(co.encode_tpdo1(-5, 7)) == (-5, 7)


def test_mapping_from_the_dcf_takes_the_configured_values():
    m = mapping_from_eds(DCF, sim_eds.DCF_NODE)
    assert m.tpdo_cob_id == 0x180 + sim_eds.DCF_NODE
    assert m.sync_period_s == pytest.approx(sim_eds.DCF_PERIOD_US * 1e-6)
    assert m.window_s == pytest.approx(sim_eds.DCF_WINDOW_US * 1e-6)


def _edit(text: str, section: str, key: str, value: str) -> str:
    head, _, rest = text.partition(f"[{section}]\n")
    body, sep, tail = rest.partition("\n[")
    lines = [f"{key}={value}" if ln.startswith(f"{key}=") else ln for ln in body.splitlines()]
    return head + f"[{section}]\n" + "\n".join(lines) + sep + tail


def test_a_tpdo_mapped_elsewhere_in_the_file_is_found(tmp_path):
    # TPDO1 maps something else; TPDO2 (the table first, then the motor) is the one to listen to
    text = _edit(EDS.read_text(), "1A00sub2", "DefaultValue", "0x60630020")
    tpdo2 = ("[1801]\nParameterName=TPDO2 communication\nObjectType=0x9\nSubNumber=3\n\n"
             "[1801sub0]\nParameterName=entries\nObjectType=0x7\nDataType=0x0005\nAccessType=ro\nDefaultValue=2\n\n"
             "[1801sub1]\nParameterName=COB-ID\nObjectType=0x7\nDataType=0x0007\nAccessType=rw\n"
             "DefaultValue=$NODEID+0x280\n\n"
             "[1801sub2]\nParameterName=Type\nObjectType=0x7\nDataType=0x0005\nAccessType=rw\nDefaultValue=1\n\n"
             "[1A01]\nParameterName=TPDO2 mapping\nObjectType=0x9\nSubNumber=3\n\n"
             "[1A01sub0]\nParameterName=entries\nObjectType=0x7\nDataType=0x0005\nAccessType=rw\nDefaultValue=2\n\n"
             "[1A01sub1]\nParameterName=m1\nObjectType=0x7\nDataType=0x0007\nAccessType=rw\n"
             "DefaultValue=0x60E40120\n\n"
             "[1A01sub2]\nParameterName=m2\nObjectType=0x7\nDataType=0x0007\nAccessType=rw\n"
             "DefaultValue=0x60640020\n\n")
    p = tmp_path / "tpdo2.eds"
    p.write_text(text.replace("[2000]", tpdo2 + "[2000]", 1))
    m = mapping_from_eds(p, 5)
    assert m.tpdo_cob_id == 0x285
    assert m.table == PdoField(0, "l") and m.motor == PdoField(4, "l")


@pytest.mark.parametrize("section,key,value,message", [
    ("1A00sub2", "DefaultValue", "0x60630020", "no TPDO maps both 0x6064"),
    ("1800sub2", "DefaultValue", "254", "not synchronous"),
    ("1800sub1", "DefaultValue", "0x80000185", "bit 31"),
    ("608Fsub1", "DefaultValue", "0", "counts_per_rev"),
])
def test_a_file_whose_mapping_cannot_be_listened_to_is_refused_with_the_reason(tmp_path, section, key, value,
                                                                                 message):
    p = tmp_path / "bad.eds"
    p.write_text(_edit(EDS.read_text(), section, key, value))
    with pytest.raises(InputError, match=message):
        mapping_from_eds(p, 5)


def test_a_file_that_is_no_eds_is_refused(tmp_path):
    p = tmp_path / "notes.eds"
    p.write_text("this is not an EDS\n")
    with pytest.raises(InputError, match="eds .* not a readable EDS/DCF"):
        mapping_from_eds(p, 5)


@pytest.mark.parametrize("kw,field", [
    (dict(tpdo_cob_id=0x800), "tpdo_cob_id"),
    (dict(tpdo_cob_id=0x80), "sync_cob_id"),
    (dict(motor=PdoField(2, "l")), "overlap"),
    (dict(table=PdoField(6, "l")), "table_offset_bytes"),
    (dict(motor=PdoField(0, "f")), "motor_type"),
    (dict(counts_per_rev=0.0), "counts_per_rev"),
    (dict(table_nm_per_count=float("nan")), "table_nm_per_count"),
])
def test_a_bad_mapping_names_its_field(kw, field):
    with pytest.raises(InputError, match=field):
        default_mapping(5, **kw)


# -- URL and configuration ---------------------------------------------------------------------------
def test_the_url_chooses_the_mode_and_listen_only_is_the_default_on_a_real_bus():
    assert isinstance(driver_from_canopen_url("canopen://socketcan/can0?node=5"), CanopenListenDriver)
    assert isinstance(driver_from_canopen_url("canopen://udp_multicast/239.0.0.1?node=5"), CanopenListenDriver)
    assert type(driver_from_canopen_url("canopen://virtual/sim?node=5")) is CanopenDriver  # a simulator: active
    assert type(driver_from_canopen_url("canopen://socketcan/can0?node=5&trigger=active")) is CanopenDriver
    d = driver_from_url("canopen://socketcan/can0?node=5&trigger=passive&start_timeout_s=30")
    assert isinstance(d, CanopenListenDriver) and d.trigger == "passive" and d.passive == {"start_timeout_s": 30.0}
    assert type(driver_from_canopen_url("canopen://socketcan/can0?node=5&mode=active-mebm")) is CanopenDriver
    d = driver_from_canopen_url("canopen://socketcan/can0?node=5&mode=active-cia402&table_nm_per_count=5")
    assert isinstance(d, CanopenCia402Driver) and d.table_nm_per_count == 5
    d = driver_from_canopen_url(f"canopen://pcan/PCAN_USBBUS1?node=7&eds={DCF}&bitrate=500000")
    assert d.wire.sync_rate_hz == pytest.approx(500.0) and d.wire.bus_kwargs == {"bitrate": 500000}
    d = driver_from_canopen_url("canopen://socketcan/can0?node=5&tpdo_cob_id=0x285&table_offset_bytes=2"
                                "&table_type=i16&motor_offset_bytes=4")
    assert d.wire.mapping.tpdo_cob_id == 0x285 and d.wire.mapping.table == PdoField(2, "h")


@pytest.mark.parametrize("query,field", [
    ("mode=listen", "mode"),
    ("mode=listen-only&trigger=active", "contradicts trigger=active"),
    ("mode=active-cia402&trigger=passive", "contradicts trigger=passive"),
    ("mode=active-mebm&start_timeout_s=5", "trigger=passive only"),
    ("mode=active-mebm&eds=x.eds", "eds"),
    ("eds=/no/such.eds", "eds"),
    ("tpdo_cob_id=abc", "tpdo_cob_id"),
    (f"eds={EDS}&tpdo_cob_id=0x185", "eds and tpdo_cob_id"),
    ("table_type=f32", "table_type"),
])
def test_a_bad_url_names_the_key(query, field):
    with pytest.raises(InputError, match=field):
        driver_from_canopen_url(f"canopen://socketcan/can0?node=5&{query}")


AXIS_DOC = dict(name="y", transmission_mm_per_rev=6.857, screw_lead_mm=16, position_gain_per_s=10,
                travel_mm=[0, 100])


def _settings(axis: dict):
    return parse_settings({"machines": [{"name": "m", "axes": [dict(AXIS_DOC, **axis)]}]})


def test_the_configuration_table_becomes_the_controller_url():
    s = _settings({"canopen": {"interface": "socketcan", "channel": "can0", "mode": "listen-only", "node": 7,
                               "eds": str(DCF), "bus": {"bitrate": 500000}}})
    url = s.axes[0].settings.controller_url
    d = driver_from_canopen_url(url)
    assert isinstance(d, CanopenListenDriver) and d.wire.mapping.tpdo_cob_id == 0x187
    assert d.wire.bus_kwargs == {"bitrate": 500000}


@pytest.mark.parametrize("table,field", [
    ({"mode": "listen"}, "canopen.mode"),
    ({"tpdo_cob_id": 0x987}, "canopen.tpdo_cob_id"),
    ({"eds": "/no/such.dcf"}, "canopen.eds"),
    ({"colour": "red"}, "canopen.colour"),
    ({"mode": "active-cia402", "table_nm_per_count": 0}, "canopen.table_nm_per_count"),
    ({"motor_offset_bytes": 2}, "canopen.motor_offset_bytes"),
])
def test_a_bad_configuration_table_is_refused_at_load_naming_the_field(table, field):
    doc = {"interface": "socketcan", "channel": "can0", "node": 7, **table}
    with pytest.raises(ConfigError, match=rf"machines\[0\]\.axes\[0\]\.{field}"):
        _settings({"canopen": doc})


def test_a_bad_canopen_url_in_the_configuration_is_refused_at_load():
    with pytest.raises(ConfigError, match=r"axes\[0\]\.controller .*mode"):
        _settings({"controller": "canopen://socketcan/can0?node=5&mode=bogus"})


# -- SYNC numbering and the no-send guard ------------------------------------------------------------
def _msg(cob, data, t):
    return can.Message(arbitration_id=cob, is_extended_id=False, data=data, timestamp=t)


def test_a_sync_this_host_missed_is_a_counter_gap_and_its_tpdo_is_not_given_to_another():
    li = SyncListener(default_mapping(5), wall_period_s=0.004, window_s=0.002)
    k_of = {}
    for k in (1, 2, 4, 5):  # SYNC 3 never heard; its TPDO arrives (outside the window of SYNC 2)
        li(_msg(0x80, [k], 1 + k * 0.004))
        k_of[k] = li.k
    li(_msg(0x185, co.encode_tpdo1(1, 1), 1.0045))
    li(_msg(0x185, co.encode_tpdo1(2, 2), 1.0085))
    li(_msg(0x185, co.encode_tpdo1(3, 3), 1.0125))  # SYNC 3's answer: 4.5 ms after SYNC 2 -> late
    li(_msg(0x185, co.encode_tpdo1(5, 5), 1.0205))
    assert k_of == {1: 1, 2: 2, 4: 4, 5: 5} and li.syncs_missed == 1
    assert [f[0] for f in li.frames] == [1, 2, 5] and li.stats()["late"] == 1


def test_without_a_sync_counter_the_spacing_numbers_the_syncs():
    li = SyncListener(default_mapping(5), wall_period_s=0.004)
    for t in (1.0, 1.004, 1.008, 1.016, 1.020):  # one SYNC missing at 1.012 s
        li(_msg(0x80, [], t))
    assert li.k == 6 and li.syncs_missed == 1


def test_the_listen_only_bus_refuses_to_send():
    bus = ListenOnlyBus(can.Bus(interface="virtual", channel=f"guard-{next(_channels)}"))
    try:
        with pytest.raises(ListenOnlyBusError, match="refused to send CAN frame 0x080"):
            bus.send(_msg(0x80, [], 0.0))
        assert bus.sends_refused == 1
    finally:
        bus.shutdown()


def test_listen_only_cannot_start_or_acknowledge_and_its_status_asks_nothing():
    import asyncio

    d = driver_from_canopen_url("canopen://socketcan/can0?node=5")
    for make in (lambda: d._start(PROGRAM), d._acknowledge):
        with pytest.raises(Exception, match="listen-only: mebm cannot"):
            asyncio.run(make())
    st = asyncio.run(d._read_status())  # no bus is even open: nothing could have been sent
    assert d.wire.bus is None and np.isnan(st.temperature_c)


# -- passive round trips beside a CNC master (in-process) ----------------------------------------------
@contextlib.contextmanager
def _bench(**drive_kw):
    channel = f"listen-{next(_channels)}"
    drive = SimCanopenDrive(KinematicTwin(backlash_um=120.0, position_gain_per_s=30.0), node_id=5, channel=channel,
                            rng=np.random.default_rng(1), **drive_kw)
    drive.start()
    try:
        yield channel, drive
    finally:
        drive.stop()


def _listener(channel, start_timeout_s=30.0):
    return driver_from_url(f"canopen://virtual/{channel}?node=5&mode=listen-only&eds={EDS}&rate_hz=500"
                           f"&time_scale=2&start_timeout_s={start_timeout_s}&max_duration_s=30", timeout_s=5.0,
                           max_lost_samples=50)


def _master_in_thread(channel, program, **kw):
    out = {}

    def go():
        time.sleep(0.3)  # mebm listens first
        out.update(CncMaster(5, interface="virtual", channel=channel, sync_rate_hz=500.0, time_scale=2.0)
                   .run_round_trip(program, **kw))

    th = threading.Thread(target=go, daemon=True)
    th.start()
    return th, out


def test_listen_only_measures_a_round_trip_a_cnc_master_commanded():
    with _bench() as (channel, drive):
        d = _listener(channel)
        th, master = _master_in_thread(channel, PROGRAM)
        r = run_cycle(d, AXIS, PROGRAM)
        th.join(30)
    assert r.ok, r.reason
    assert r.result.backlash_mean_um == pytest.approx(120.0, abs=1.0)
    assert d.sends_refused == 0 and drive.axis.cycles_started == 0  # the master moved it, not mebm
    assert r.trace.servo_rate_hz == pytest.approx(500.0)
    assert np.all(np.diff(r.trace.counter) >= 1) and r.trace.lost_samples == int(np.sum(np.diff(r.trace.counter) - 1))
    assert master["syncs_sent"] > len(r.trace)


def test_no_round_trip_within_the_time_out_is_a_typed_failure_and_no_measurement():
    short = RoundTripProgram(0.0, 2.0, 1000.0, acceleration_mm_s2=500.0, dwell_s=0.1)  # a 2 mm jog
    with _bench() as (channel, _drive):
        d = _listener(channel, start_timeout_s=1.5)
        th, _ = _master_in_thread(channel, short, rest_after_s=3.0)
        r = run_cycle(d, AXIS, PROGRAM)
        th.join(30)
    assert not r.ok and r.reason_code == "no_round_trip", r.reason
    assert r.result is None and r.trace is None


def test_an_emcy_the_drive_sends_while_mebm_listens_fails_the_cycle_with_its_code():
    with _bench() as (channel, drive):
        d = _listener(channel)
        th, _ = _master_in_thread(channel, PROGRAM)
        timer = threading.Timer(1.0, drive.node.emcy.send, (0x7305, 0x01))  # incremental sensor 1 fault
        timer.start()
        r = run_cycle(d, AXIS, PROGRAM)
        th.join(30)
        timer.cancel()
    assert not r.ok and r.reason_code == "device_fault" and "0x7305" in r.reason, r.reason
    assert r.result is None


def test_listen_only_with_no_master_on_the_bus_says_so():
    with _bench() as (channel, _drive):
        d = _listener(channel)
        d.timeout_s = 0.3
        r = run_cycle(d, AXIS, PROGRAM)
    assert not r.ok and r.reason_code == "timeout" and "no SYNC" in r.reason, r.reason


def test_listen_only_on_a_mapping_that_does_not_match_the_drive_says_so():
    with _bench() as (channel, _drive):
        d = driver_from_canopen_url(f"canopen://virtual/{channel}?node=6&mode=listen-only&rate_hz=500"
                                    "&time_scale=2", timeout_s=5.0)  # SYNC comes within it, even on a busy host
        th, _ = _master_in_thread(channel, PROGRAM)
        r = run_cycle(d, AXIS, PROGRAM)
        th.join(30)
    assert not r.ok and r.reason_code == "timeout" and "no TPDO 0x186" in r.reason, r.reason


def test_mapping_dataclass_is_frozen():
    m = default_mapping(5)
    with pytest.raises(Exception):
        m.tpdo_cob_id = 1  # type: ignore[misc]
    assert isinstance(m, ListenMapping)
