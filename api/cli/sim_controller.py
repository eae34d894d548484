"""``mebm sim-controller modbus|canopen|linuxcnc``: a simulated controller whose axis is the
digital twin (``modbus``, ``canopen``), or LinuxCNC itself running a simulated machine with
a backlash between motor and table (``linuxcnc``, :mod:`acquisition.linuxcnc.sim`).

Runs until interrupted (or ``--duration-s``). Prints one line with the address to use
as ``mebm measure --controller``.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
import time

import numpy as np

from core.errors import InputError


def _add_axis_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("simulated axis (the digital twin)")
    g.add_argument("--axis", default="y", help="axis name (default y)")
    g.add_argument("--backlash-um", type=float, default=120.0, help="backlash width b (µm), default 120")
    g.add_argument("--transmission-mm-per-rev", type=float, default=6.857, help="k_a (mm/rev), default 6.857")
    g.add_argument("--screw-lead-mm", type=float, default=16.0, help="ball-screw lead (mm), default 16")
    g.add_argument("--position-gain-per-s", type=float, default=10.0, help="K = k_a k_p (1/s), default 10")
    g.add_argument("--temperature-c", type=float, default=20.0, help="machine temperature (degC)")
    g.add_argument("--effect", action="append", default=[], metavar="CATEGORY:key=value,...",
                   help="a core.sim effect, e.g. cyclic_error:periods_mm=16,amplitudes_um=3 (repeatable)")
    g.add_argument("--fault", action="append", default=[], metavar="KIND:key=value,...",
                   help="inject a fault: stuck, jump, lost, emcy, drop, slow, exception, refuse "
                        "(see acquisition.sim.faults), e.g. emcy:at=0.5,code=0x7305")
    g.add_argument("--servo-rate-hz", type=float, default=1000.0, help="servo (latch) rate, default 1000")
    g.add_argument("--counts-per-rev", type=int, default=131072, help="motor encoder counts/rev")
    g.add_argument("--table-nm-per-count", type=int, default=10, help="linear encoder resolution (nm)")
    g.add_argument("--seed", type=int, default=0, help="seed of the twin's encoder noise")
    g.add_argument("--duration-s", type=float, default=None, help="stop after this many seconds (default: run until Ctrl-C)")
    g.add_argument("--wear-um-per-day", type=float, default=0.0,
                   help="the backlash grows this much per utility day (default 0: no wear); "
                        "`mebm sim-controller repair` restores it")
    g.add_argument("--utility-days-per-s", type=float, default=1.0 / 86400.0,
                   help="utility days per second of the simulator's clock (default: real time; 1: a day a second)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim-controller", help="run a simulated Modbus TCP controller, CANopen drive or LinuxCNC machine")
    sp = p.add_subparsers(dest="protocol", metavar="PROTOCOL")
    sp.required = True
    m = sp.add_parser("modbus", help="simulated controller on Modbus TCP (register map mebm-modbus/1)")
    m.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    m.add_argument("--port", type=int, default=5020, help="TCP port (0: a free one), default 5020")
    m.add_argument("--time-scale", type=float, default=1.0, help="run the axis X times faster than real time")
    m.add_argument("--ring-records", type=int, default=2000,
                   help="trace buffer size in samples (20..10906), default 2000 (2 s at 1 kHz)")
    _add_axis_options(m)
    m.set_defaults(func=run)
    c = sp.add_parser("canopen", help="simulated CiA 402 drive on a python-can bus (SYNC-clocked)")
    c.add_argument("--interface", default="udp_multicast",
                   help="python-can interface: udp_multicast (reachable from other processes, default) or virtual")
    c.add_argument("--channel", default="239.74.163.2", help="python-can channel (default 239.74.163.2)")
    c.add_argument("--node", type=int, default=5, help="CANopen node id (default 5)")
    c.add_argument("--bus-option", action="append", default=[], metavar="KEY=VALUE",
                   help="python-can bus option, e.g. port=43114 for udp_multicast (repeatable)")
    c.add_argument("--reply-delay-ms", type=float, default=0.1,
                   help="delay of each TPDO after its SYNC, ms (default 0.1)")
    c.add_argument("--reply-jitter-ms", type=float, default=0.2,
                   help="uniform jitter added to that delay, 0..this many ms (default 0.2); a reply that would "
                        "miss the synchronous window (0x1007) is discarded, as CiA 301 says")
    _add_axis_options(c)
    c.set_defaults(func=run)
    x = sp.add_parser("linuxcnc", help="LinuxCNC (linuxcnc-uspace) running mebm's simulated machine: pid loop, "
                                        "servo thread and sampler are LinuxCNC's, the feed axes with backlash are HAL")
    x.add_argument("--loop", choices=("semi", "full"), default="semi",
                   help="pid closed on the motor encoder (semi, default) or on the linear scale (full)")
    x.add_argument("--backlash-um", type=float, default=120.0, help="backlash between motor and table (µm), default 120")
    x.add_argument("--p-gain-per-s", type=float, default=30.0, help="pid P, the position loop gain K (1/s), default 30")
    x.add_argument("--ff1", type=float, default=0.0, help="pid FF1 (velocity feed-forward), default 0")
    x.add_argument("--drive-tau-s", type=float, default=0.0, help="drive velocity loop time constant (s), default 0")
    x.add_argument("--scale-resolution-um", type=float, default=0.001,
                   help="linear scales' resolution (µm), their reading rounded to it; default 0.001")
    x.add_argument("--port", type=int, default=5007, help="linuxcncrsh port, default 5007")
    x.add_argument("--comp-file", default=None,
                   help="a LinuxCNC compensation table for joints 0 and 1 (mebm export-comp --format linuxcnc)")
    x.add_argument("--comp-type", type=int, choices=(0, 1), default=1, help="its COMP_FILE_TYPE, default 1")
    x.add_argument("--user", default=None,
                   help="the account LinuxCNC runs as when mebm runs as root (rtapi_app refuses root)")
    x.add_argument("--run-dir", default=None, help="where the configuration is written (default: a new temporary one)")
    x.add_argument("--duration-s", type=float, default=None, help="stop after this many seconds (default: until Ctrl-C)")
    x.set_defaults(func=run_linuxcnc)
    r = sp.add_parser("repair", help="repair a running simulated Modbus controller: its wear back to zero")
    r.add_argument("controller", help="the simulator's address, modbus://HOST:PORT")
    r.set_defaults(func=repair)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def run_linuxcnc(a: argparse.Namespace) -> int:
    """Start LinuxCNC on the simulated machine, power it on (it is a simulation) and wait."""
    from acquisition.linuxcnc.sim import LinuxcncSim, SimSettings

    sim = LinuxcncSim(SimSettings(backlash_um=a.backlash_um, loop=a.loop, p_gain_per_s=a.p_gain_per_s, ff1=a.ff1,
                                  drive_tau_s=a.drive_tau_s, scale_resolution_um=a.scale_resolution_um,
                                  port=a.port, comp_file=a.comp_file,
                                  comp_type=a.comp_type), run_dir=a.run_dir, user=a.user)
    # LinuxCNC runs in a session of its own (a Ctrl-C in the terminal does not reach it), so
    # it is stopped here: on Ctrl-C, and on SIGTERM (a service manager, `timeout`, `kill`),
    # also while it is starting, or it would run on without anyone to stop it
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        sim.start()
        sim.power_on()
        print(f"LinuxCNC running mebm's simulated machine ({a.loop}-closed, b = {a.backlash_um:g} µm, "
              f"P = {a.p_gain_per_s:g}/s, FF1 = {a.ff1:g}; configuration in {sim.run_dir}); "
              f"mebm measure --controller '{sim.url}' records the round trips it runs, "
              "add &trigger=active to have mebm run them; mebm circle measure --url "
              f"'linuxcnc://127.0.0.1:{a.port}?sampler=2' --radius-mm R --feed-mm-min F --resolution-um "
              f"{a.scale_resolution_um:g} --out FILE.json runs a circular test of X and Y", flush=True)
        deadline = time.monotonic() + (a.duration_s if a.duration_s is not None else float("inf"))
        while time.monotonic() < deadline and sim.proc is not None and sim.proc.poll() is None:
            time.sleep(min(0.5, max(deadline - time.monotonic(), 0.0)))
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second SIGTERM must not cut the shutdown short
        sim.stop()
    return 0


def build_twin(a: argparse.Namespace):
    from acquisition.sim.twin import CoreSimTwin
    from core.sim import AxisModel, Effects, parse_effect

    effects = {}
    for text in a.effect:
        cat, eff = parse_effect(text)
        if cat in effects:
            raise InputError(f"--effect {cat} given twice")
        effects[cat] = eff
    model = AxisModel(name=a.axis.lower(), transmission_mm_per_rev=a.transmission_mm_per_rev,
                      screw_lead_mm=a.screw_lead_mm, position_gain_per_s=a.position_gain_per_s,
                      backlash_um=a.backlash_um, effects=Effects(**effects))
    twin = CoreSimTwin(model, temperature_c=a.temperature_c, rng=np.random.default_rng(a.seed))
    twin.warm_up()
    return _with_wear(twin, a)


def _with_wear(twin, a: argparse.Namespace):
    """The twin with wear (acquisition.sim.wear) when ``--wear-um-per-day`` is given."""
    if not a.wear_um_per_day:
        return twin
    from acquisition.sim.wear import Wear, WearingTwin

    return WearingTwin(twin, Wear(a.wear_um_per_day, a.utility_days_per_s))


def _wear_note(a: argparse.Namespace) -> str:
    if not a.wear_um_per_day:
        return ""
    return (f", wearing {a.wear_um_per_day:g} µm per utility day, {a.utility_days_per_s * 86400:g} utility days "
            f"per day; `mebm sim-controller repair` restores it")


def repair(a: argparse.Namespace) -> int:
    """Write the simulator's repair register (acquisition.sim.modbus.wear) and print the wear it read before."""
    from urllib.parse import urlsplit

    from pymodbus.client import ModbusTcpClient

    from acquisition.sim.modbus.wear import REPAIR_REG, WEAR_WORDS
    from acquisition.sim.wear import REPAIR_MAGIC

    u = urlsplit(a.controller)
    if u.scheme != "modbus" or not u.hostname:
        raise InputError(f"controller (={a.controller!r}) must be modbus://HOST:PORT")
    client = ModbusTcpClient(u.hostname, port=u.port or 502, timeout=3)
    if not client.connect():
        raise InputError(f"no simulated controller answers at {a.controller}")
    try:
        before = client.read_holding_registers(REPAIR_REG, count=WEAR_WORDS)
        w = client.write_register(REPAIR_REG, REPAIR_MAGIC)
        if before.isError() or w.isError():
            raise InputError(f"{a.controller} refused the repair (no wear simulated there?): {w}")
        regs = before.registers
        print(f"repaired {a.controller}: wear {((regs[2] << 16) | regs[3]) / 100:.2f} µm removed "
              f"(repair {regs[1] + 1})", flush=True)
    finally:
        client.close()
    return 0


def run(a: argparse.Namespace) -> int:
    from acquisition.scale import EncoderScale
    from acquisition.sim.faults import parse_fault

    for name in ("pymodbus", "canopen", "can"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    faults = [parse_fault(f) for f in a.fault]
    scale = EncoderScale(counts_per_rev=a.counts_per_rev, table_nm_per_count=a.table_nm_per_count)
    twin = build_twin(a)
    if a.protocol == "modbus":
        return asyncio.run(_serve_modbus(a, twin, scale, faults))
    return _serve_canopen(a, twin, scale, faults)


async def _serve_modbus(a, twin, scale, faults) -> int:
    from acquisition.sim.axis import SimAxis
    from acquisition.sim.modbus.server import SimModbusController

    if not 20 <= a.ring_records <= (65536 - 100) // 6:
        raise InputError(f"--ring-records (={a.ring_records}) must be in 20..{(65536 - 100) // 6}")
    axis = SimAxis(twin, servo_rate_hz=a.servo_rate_hz, time_scale=a.time_scale, scale=scale, faults=faults,
                   ring_records=a.ring_records)
    sim = SimModbusController(axis, host=a.host, port=a.port)
    try:
        port = await sim.start()
    except OSError as exc:
        raise InputError(f"cannot listen on {a.host}:{a.port}: {exc.strerror or exc}") from exc
    print(f"simulated controller listening on modbus://{a.host}:{port} "
          f"(axis {a.axis}, b = {a.backlash_um:g} µm, time scale {a.time_scale:g}{_wear_note(a)}); "
          f"mebm measure --controller sim://{a.host}:{port} starts its round trips", flush=True)
    try:
        if a.duration_s is not None:
            await asyncio.sleep(a.duration_s)
        else:
            await asyncio.Event().wait()
    finally:
        await sim.stop()
    return 0


def _serve_canopen(a, twin, scale, faults) -> int:
    from acquisition.sim.canopen.drive import SimCanopenDrive

    bus_kwargs = {}
    for opt in a.bus_option:
        key, eq, val = opt.partition("=")
        if not eq:
            raise InputError(f"--bus-option {opt!r} must be KEY=VALUE")
        bus_kwargs[key.strip()] = int(val) if val.strip().lstrip("-").isdigit() else val.strip()
    drive = SimCanopenDrive(twin, node_id=a.node, channel=a.channel, interface=a.interface,
                            servo_rate_hz=a.servo_rate_hz, scale=scale, faults=faults, bus_kwargs=bus_kwargs,
                            reply_delay_s=a.reply_delay_ms / 1000.0, reply_jitter_s=a.reply_jitter_ms / 1000.0,
                            rng=np.random.default_rng(a.seed))
    try:
        drive.start()
    except Exception as exc:  # noqa: BLE001 - python-can raises many kinds on a bad interface
        raise InputError(f"cannot open CAN interface {a.interface!r} channel {a.channel!r}: {exc}") from exc
    print(f"simulated drive on canopen://{a.interface}/{a.channel}?node={a.node} "
          f"(axis {a.axis}, b = {a.backlash_um:g} µm{_wear_note(a)})", flush=True)
    try:
        deadline = time.monotonic() + (a.duration_s if a.duration_s is not None else float("inf"))
        while time.monotonic() < deadline:
            time.sleep(min(0.5, max(deadline - time.monotonic(), 0.0)))
    finally:
        drive.stop()
    sys.stdout.flush()
    return 0
