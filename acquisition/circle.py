"""A circular test (ISO 230-4) measured with the CNC's own encoders: the two axes of a plane
run a full circle in each direction, and the table (linear scale) positions give the radial
deviation along it (:func:`core.circle.pass_from_positions`).

Two machines can run one:

- **LinuxCNC** (``linuxcnc://HOST[:PORT]?sampler=N``): mebm writes the circle as a program
  (:func:`circle_gcode`) and records it with :func:`acquisition.linuxcnc.contour.record_contour`,
  whose six-pin sampler latches both axes' motor, scale and command in one servo period.
  Each direction is its own program: from the centre out along the start's radius (so
  every recording starts the same way, whatever ran before), a dwell, then one arc of
  ``lead_in_deg + 360 + lead_out_deg`` degrees (a G2/G3 with ``P``: full turns plus the
  rest, so no block boundary and no planner stop lies on the circle). The data arc is the
  360° after the lead-in (:func:`data_arc`): the start from rest, where one axis reverses as
  the arc begins, is outside it (the lead-in lasts at least a second, many times the position
  loop's time constant 1/K), and so is the stop at the end.
- **the simulated two-axis machine** (``sim:?backlash_um=120&gain_per_s=30...``):
  :func:`core.circle.simulate.simulated_test` with those parameters (core/sim's twin of a
  feed drive traces the circle).

Modbus and CANopen drivers read one axis' round trip and cannot record a two-axis circle
(docs/controllers.md): their URLs are refused naming ``mebm circle import``.

Failures are typed (:mod:`acquisition.errors`): e-stop and machine off before or during the
circle, samples the sampler's FIFO dropped, an arc that does not close its 360°
(:class:`~acquisition.errors.IncompleteCircleError`).
"""

from __future__ import annotations

import asyncio
import math
import os
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from urllib.parse import parse_qsl, urlsplit

import numpy as np

from acquisition.errors import AcquisitionError, IncompleteCircleError, LostSamplesError, ProtocolError
from core.circle import DIRECTIONS, CircularTest, Instrument, pass_from_positions
from core.errors import InputError, require_finite, require_positive

PLANE_AXES = "xyz"
#: G-code plane of each pair of axes, and the pair in which that plane's G3 turns
#: counter-clockwise (RS274/NGC: G17 X->Y, G18 Z->X, G19 Y->Z).
GCODE_PLANES = {frozenset("xy"): ("G17", ("x", "y")), frozenset("xz"): ("G18", ("z", "x")),
                frozenset("yz"): ("G19", ("y", "z"))}
CENTRE_WORDS = {"x": "I", "y": "J", "z": "K"}
#: The LinuxCNC circle URL's keys.
LINUXCNC_KEYS = ("sampler", "program_dir")
#: The simulated machine's keys and defaults (the LinuxCNC simulated machine's: b 120 µm,
#: K 30/s, 1 µm scales).
SIM_DEFAULTS = {"backlash_um": "120", "gain_per_s": "30", "resolution_um": "1", "noise_um": "0", "seed": "0"}


MIN_LEAD_IN_DEG = 20.0


def lead_in_deg(start_deg: float, direction: str, min_deg: float) -> float:
    """The arc before the data arc: at least ``min_deg``, extended so that the data arc starts
    midway between two quadrant points (45° from each), where no reversal spike straddles its
    two ends."""
    s = 1.0 if direction == "ccw" else -1.0
    first = start_deg + s * min_deg
    data_start = first + ((45.0 - first) % 90.0) if s > 0 else first - ((first - 45.0) % 90.0)
    return s * (data_start - start_deg)


@dataclass(frozen=True)
class CircleProgram:
    """The circle a CNC runs for the test, in the plane ``(first, second)`` (first axis = 0°,
    counter-clockwise positive): radius, feed, centre in the program's work coordinates
    (G54), the start angle (midway between two quadrant points), ``lead_in_s`` of arc at
    the feed before the 360° of data (at least 20°, see :attr:`lead_in_deg`) and
    ``lead_out_deg`` after it."""

    radius_mm: float
    feed_mm_min: float
    plane: tuple[str, str] = ("x", "y")
    centre_mm: tuple[float, float] = (0.0, 0.0)
    start_deg: float = -45.0
    lead_in_s: float = 1.0
    lead_out_deg: float = 25.0
    dwell_s: float = 0.5

    def __post_init__(self) -> None:
        require_positive("radius_mm", self.radius_mm)
        require_positive("feed_mm_min", self.feed_mm_min)
        plane = check_plane(self.plane)
        object.__setattr__(self, "plane", plane)
        for i, c in enumerate(self.centre_mm):
            require_finite(f"centre_mm[{i}]", c)
        if require_finite("start_deg", self.start_deg) % 90.0 != 45.0:
            raise InputError(f"start_deg (={self.start_deg}) must lie midway between two quadrant points (45° + "
                             "a multiple of 90°, e.g. -45)")
        if not 0.0 <= require_finite("lead_in_s", self.lead_in_s) <= 60.0:
            raise InputError(f"lead_in_s (={self.lead_in_s}) must be 0..60 s")
        if not 5.0 <= require_finite("lead_out_deg", self.lead_out_deg) < 90.0:
            raise InputError(f"lead_out_deg (={self.lead_out_deg}) must be 5..90°")
        if not 0.1 <= self.dwell_s <= 10.0:
            raise InputError(f"dwell_s (={self.dwell_s}) must be 0.1..10 s")

    @property
    def lead_in_deg(self) -> float:
        """The arc the lead-in runs: ``lead_in_s`` at the feed, at least 20°, rounded up to a
        multiple of 90° (the start lies midway between quadrant points, and so does the data
        arc's start)."""
        arc_deg = math.degrees(self.feed_mm_min / 60.0 / self.radius_mm * self.lead_in_s)
        return lead_in_deg(self.start_deg, "ccw", max(MIN_LEAD_IN_DEG, arc_deg))

    @property
    def sweep_deg(self) -> float:
        """The arc the program runs: lead-in, 360° of data, lead-out."""
        return self.lead_in_deg + 360.0 + self.lead_out_deg

    @property
    def turns(self) -> int:
        """The arc's P word: its full turns plus the part turn to its end point."""
        return 2 + int((self.lead_in_deg + self.lead_out_deg) // 360.0)


def check_plane(plane) -> tuple[str, str]:
    """``plane`` as two distinct axis letters of X, Y, Z, lower case (``"xy"`` or ``("x", "y")``)."""
    letters = tuple(str(a).strip().lower() for a in plane) if not isinstance(plane, str) else tuple(plane.lower())
    if len(letters) != 2 or letters[0] == letters[1] or any(a not in PLANE_AXES for a in letters):
        raise InputError(f"plane (={plane!r}) must be two different axes of x, y, z, the first at 0° (e.g. xy)")
    return letters  # type: ignore[return-value]


def check_directions(directions) -> tuple[str, ...]:
    dirs = tuple(str(d).strip().lower() for d in directions)
    if not dirs or any(d not in DIRECTIONS for d in dirs) or len(set(dirs)) != len(dirs):
        raise InputError(f"directions (={list(directions)}) must be one or both of {list(DIRECTIONS)}, each once")
    return dirs


def circle_gcode(program: CircleProgram, direction: str) -> str:
    """The program of one direction: G21 G90 G61 G54 in the plane's G17/G18/G19; to the
    centre, out along the start's radius, a dwell, one arc of ``program.sweep_deg`` (its
    ``P`` word: the full turns and the part turn to the end point), a dwell, M2."""
    if direction not in DIRECTIONS:
        raise InputError(f"direction (={direction!r}) must be one of {list(DIRECTIONS)}")
    first, second = program.plane
    gplane, ccw_pair = GCODE_PLANES[frozenset(program.plane)]
    turns_ccw = (direction == "ccw") == (ccw_pair == (first, second))
    sign = 1.0 if direction == "ccw" else -1.0
    r, (c1, c2), f = program.radius_mm, program.centre_mm, program.feed_mm_min
    a0 = math.radians(program.start_deg)
    a1 = a0 + sign * math.radians(program.sweep_deg - 360.0)
    s1, s2 = c1 + r * math.cos(a0), c2 + r * math.sin(a0)
    e1, e2 = c1 + r * math.cos(a1), c2 + r * math.sin(a1)
    L1, L2 = first.upper(), second.upper()
    w1, w2 = CENTRE_WORDS[first], CENTRE_WORDS[second]
    return (f"(mebm circular test, {direction}, R {r:g} mm, F {f:g} mm/min)\n"
            f"G21 G90 {gplane} G61 G54\nG1 {L1}{c1:.6f} {L2}{c2:.6f} F{f:g}\nG4 P0.3\n"
            f"G1 {L1}{s1:.6f} {L2}{s2:.6f}\nG4 P{program.dwell_s:.3f}\n"
            f"{'G3' if turns_ccw else 'G2'} {L1}{e1:.6f} {L2}{e2:.6f} {w1}{c1 - s1:.6f} {w2}{c2 - s2:.6f} "
            f"P{program.turns} F{f:g}\n"
            f"G4 P0.3\nM2\n")


@dataclass(frozen=True)
class DataArc:
    """The 360° of a recording that the test analyses: the table positions of both axes
    over it (``first_mm``, ``second_mm``), and the circle's centre in the recording's
    (machine) coordinates, read from the command."""

    first_mm: np.ndarray
    second_mm: np.ndarray
    centre_mm: tuple[float, float]
    swept_deg: float  # how far the command ran along the arc in all


def data_arc(command_mm: tuple[np.ndarray, np.ndarray], table_mm: tuple[np.ndarray, np.ndarray],
             program: CircleProgram, direction: str, src: str = "the recording") -> DataArc:
    """The data arc of a recording of :func:`circle_gcode`: from where the command has run
    ``lead_in_deg`` along the arc to 360° further. The arc's start is the end of the dwell
    at the start point (the command's first rest there); the centre is the start point
    less the start's radius (work offsets need not be known)."""
    xc, yc = (np.asarray(a, dtype=float) for a in command_mm)
    x, y = (np.asarray(a, dtype=float) for a in table_mm)
    r = program.radius_mm
    a0 = math.radians(program.start_deg)
    # the centre and the start point: two consecutive rests of the command (at rest it
    # repeats exactly), the second the start's radius out from the first
    still = np.flatnonzero((np.abs(np.diff(xc)) < 1e-9) & (np.abs(np.diff(yc)) < 1e-9))
    rests = [s for s in (np.split(still, np.flatnonzero(np.diff(still) > 1) + 1) if still.size else []) if s.size >= 20]
    out = np.array([math.cos(a0), math.sin(a0)]) * r
    pair = next(((c, s) for c, s in zip(rests, rests[1:])
                 if np.hypot(xc[s[0]] - xc[c[0]] - out[0], yc[s[0]] - yc[c[0]] - out[1]) < 1e-3), None)
    if pair is None:
        radial = [(c, s) for c, s in zip(rests, rests[1:])
                  if abs(np.hypot(xc[s[0]] - xc[c[0]], yc[s[0]] - yc[c[0]]) - r) < 1e-3]
        if not radial:  # no rest one radius out from another: the program did not get that far
            raise IncompleteCircleError(f"{src}: the command does not rest at the circle's centre and then at its "
                                        "start point: not a recording of mebm's circle program, or cut short")
        raise ProtocolError(f"{src}: the commanded positions do not come out from the centre to the start at "
                            f"{program.start_deg:g}° in the plane {''.join(program.plane)}: does the sampler record "
                            f"the first axis ({program.plane[0]}) on pins 0..2 and the second ({program.plane[1]}) on "
                            "pins 3..5?")
    centre_rest, start_rest = pair
    centre = (float(xc[centre_rest[0]]), float(yc[centre_rest[0]]))
    i0 = int(start_rest[-1]) + 1  # the arc begins as the command leaves the start point
    dx, dy = xc[i0:] - centre[0], yc[i0:] - centre[1]
    sign = 1.0 if direction == "ccw" else -1.0
    progress = sign * np.degrees(np.unwrap(np.arctan2(dy, dx) - a0))
    on_arc = np.abs(np.hypot(dx, dy) - r) < 1e-3
    swept = float(progress[on_arc].max()) if on_arc.any() else 0.0
    if swept < -1.0 or (on_arc.any() and float(progress[on_arc].min()) < -1.0):
        raise ProtocolError(f"{src}: the command turned the other way than {direction} in the plane "
                            f"{''.join(program.plane)}: the sampler's axes are swapped (pins 0..2 must be "
                            f"{program.plane[0]}, 3..5 {program.plane[1]})")
    end = program.lead_in_deg + 360.0
    if swept < end:
        raise IncompleteCircleError(f"{src}: the {direction} arc does not close: the command ran "
                                    f"{max(swept, 0.0):.1f}° "
                                    f"of the {program.sweep_deg:g}° programmed, and the data arc needs "
                                    f"{program.lead_in_deg:g}° + 360° (the program was stopped or aborted)")
    idx = np.flatnonzero((progress >= program.lead_in_deg) & (progress < end))
    if not np.all(on_arc[idx]) or np.any(np.diff(idx) != 1):
        raise ProtocolError(f"{src}: the command leaves the circle of radius {r:g} mm within the data arc")
    idx = idx + i0
    return DataArc(x[idx], y[idx], centre, swept)


def _linuxcnc_options(url: str) -> tuple[str, int, dict]:
    parts = urlsplit(url)
    q = dict(parse_qsl(parts.query, keep_blank_values=True))
    unknown = sorted(set(q) - set(LINUXCNC_KEYS))
    if unknown:
        raise InputError(f"circle URL {url!r}: unknown option(s) {unknown}; a circle reads the six-pin sampler of both "
                         f"axes and takes {list(LINUXCNC_KEYS)} (e.g. linuxcnc://127.0.0.1:5007?sampler=2)")
    if not parts.hostname:
        raise InputError(f"circle URL {url!r} needs a host: linuxcnc://HOST:PORT (linuxcncrsh)")
    try:
        port = parts.port or 5007
    except ValueError:
        raise InputError(f"circle URL {url!r}: the port must be a number 1..65535") from None
    try:
        sampler = int(q.get("sampler", "2"))
    except ValueError:
        raise InputError(f"circle URL {url!r}: sampler (={q['sampler']!r}) must be a sampler number 0..15") from None
    if not 0 <= sampler <= 15:
        raise InputError(f"circle URL {url!r}: sampler (={sampler}) must be a sampler number 0..15")
    return parts.hostname, port, {"sampler": sampler, "program_dir": q.get("program_dir") or None}


async def _ready(host: str, port: int, timeout_s: float) -> None:
    """E-stop and machine off before the circle are typed errors (and nothing is sent);
    else LinuxCNC is put in AUTO mode for the program."""
    from acquisition.linuxcnc.rsh import RshClient

    await _check_state(host, port, timeout_s)
    rsh = RshClient(host, port, timeout_s=timeout_s)
    await rsh.open(enable=True)
    try:
        await rsh.set("mode auto")
    except ProtocolError as exc:
        raise ProtocolError(f"{exc}: LinuxCNC is busy (a program or MDI command running) or another linuxcncrsh "
                            "session has taken control since (one enabled session at a time)") from exc
    finally:
        await rsh.close()


async def _check_state(host: str, port: int, timeout_s: float) -> None:
    from acquisition.linuxcnc.errors import EstopError, MachineOffError
    from acquisition.linuxcnc.rsh import RshClient

    rsh = RshClient(host, port, timeout_s=timeout_s)
    await rsh.open()
    try:
        machine = (await rsh.get("machine"))[0].upper() == "ON"
        estop = (await rsh.get("estop"))[0].upper() == "ON"
        for _ in range(3):  # an e-stop passes through machine off before task reports it
            if machine or estop:
                break
            await asyncio.sleep(0.05)
            estop = (await rsh.get("estop"))[0].upper() == "ON"
    finally:
        await rsh.close()
    where = f"LinuxCNC at {host}:{port}"
    if estop:
        raise EstopError(f"{where} is in E-STOP: the operator resets it at the machine; mebm never does")
    if not machine:
        raise MachineOffError(f"{where} has the machine OFF: the operator switches it on; mebm never does")


async def _abort(host: str, port: int, timeout_s: float) -> bool:
    """Abort the program mebm started; False when LinuxCNC cannot be reached or refuses."""
    from acquisition.linuxcnc.rsh import RshClient

    rsh = RshClient(host, port, timeout_s=timeout_s)
    try:
        await rsh.open(enable=True)
        await rsh.set("abort")
        return True
    except AcquisitionError:
        return False
    finally:
        await rsh.close()


def _check_sampler(sampler: int) -> None:
    """The sampler records six pins (both axes' motor, scale, command)."""
    from acquisition.linuxcnc import hal
    from acquisition.linuxcnc.errors import HalPinError

    try:
        hal.show_pin(f"sampler.{sampler}.pin.5")
    except HalPinError:
        raise HalPinError(f"HAL has no sampler.{sampler}.pin.5: a circle needs a sampler of six pins (cfg=ffffff: "
                          "the first axis' motor, scale, command, then the second's; docs/controllers.md), named "
                          "by sampler= in the URL", pin=f"sampler.{sampler}.pin.5") from None
    try:
        hal.show_pin(f"sampler.{sampler}.pin.6")
    except HalPinError:
        return
    raise HalPinError(f"sampler.{sampler} records more than six pins: a circle reads one of exactly six "
                      "(cfg=ffffff)", pin=f"sampler.{sampler}.pin.6")


def measure_linuxcnc(url: str, program: CircleProgram, directions=DIRECTIONS, *, resolution_um: float,
                     accuracy_um: float = 0.0, timeout_s: float = 2.0, temperature_c: float | None = None,
                     utility_day: float | None = None) -> CircularTest:
    """Run and record ``program`` on LinuxCNC in each of ``directions``; ``resolution_um``
    is the linear scales' (LinuxCNC does not know it)."""
    from acquisition.linuxcnc.contour import record_contour
    from acquisition.linuxcnc.errors import EstopError, MachineOffError

    host, port, opts = _linuxcnc_options(url)
    dirs = check_directions(directions)
    require_positive("resolution_um", resolution_um)
    folder = Path(opts["program_dir"] or tempfile.gettempdir())
    passes = []
    for direction in dirs:
        asyncio.run(_ready(host, port, timeout_s))
        _check_sampler(opts["sampler"])
        path = folder / f"mebm-circle-{direction}-{os.getpid()}.ngc"
        path.write_text(circle_gcode(program, direction))
        path.chmod(0o644)  # LinuxCNC may run as another user
        try:
            turn_s = program.sweep_deg / 360.0 * 2 * math.pi * program.radius_mm / (program.feed_mm_min / 60.0)
            rec = record_contour(host, port, str(path), sampler=opts["sampler"], timeout_s=timeout_s,
                                 max_duration_s=2.0 * turn_s + 30.0)
        except AcquisitionError as exc:
            # mebm started the motion: it stops it (an e-stop or a machine off has already)
            if isinstance(exc, (EstopError, MachineOffError)) or not asyncio.run(_abort(host, port, timeout_s)):
                raise
            if isinstance(exc, LostSamplesError):
                raise LostSamplesError(f"{exc}: abort sent", lost_samples=exc.lost_samples) from exc
            raise
        except KeyboardInterrupt:
            asyncio.run(_abort(host, port, timeout_s))
            raise
        finally:
            path.unlink(missing_ok=True)
        if len(rec) < 100:
            raise IncompleteCircleError(f"sampler.{opts['sampler']} recorded {len(rec)} samples of the {direction} "
                                        "circle")
        arc = data_arc(rec.command_mm, rec.table_mm, program, direction, f"the {direction} circle on {url}")
        passes.append(pass_from_positions(arc.first_mm, arc.second_mm, radius_mm=program.radius_mm,
                                          centre_mm=arc.centre_mm, direction=direction))
    instrument = Instrument("encoders", float(resolution_um), float(accuracy_um),
                            f"linear scales {resolution_um:g} µm (LinuxCNC sampler)")
    return CircularTest(program.radius_mm, program.feed_mm_min, program.plane, tuple(passes), instrument,
                        temperature_c=temperature_c, utility_day=utility_day, source=f"measured: {url}")


def sim_options(url: str) -> dict:
    """The simulated machine's parameters from ``sim:?key=value&...`` (defaults: SIM_DEFAULTS);
    ``backlash_um`` is one value for both axes or two (``120,80``)."""
    parts = urlsplit(url)
    if parts.netloc:
        raise InputError(f"circle URL {url!r}: sim://HOST:PORT is the simulated Modbus controller (one axis), "
                         "which cannot run a circle; the simulated two-axis machine is sim: "
                         "(e.g. sim:?backlash_um=120&gain_per_s=30)")
    q = dict(parse_qsl(parts.query, keep_blank_values=True))
    unknown = sorted(set(q) - set(SIM_DEFAULTS))
    if unknown:
        raise InputError(f"circle URL {url!r}: unknown option(s) {unknown} (the simulated machine takes "
                         f"{sorted(SIM_DEFAULTS)})")
    q = {**SIM_DEFAULTS, **q}
    try:
        b = tuple(float(v) for v in q["backlash_um"].split(","))
        out = {"gain_per_s": float(q["gain_per_s"]), "resolution_um": float(q["resolution_um"]),
               "noise_um": float(q["noise_um"]), "seed": int(q["seed"])}
    except ValueError:
        raise InputError(f"circle URL {url!r}: backlash_um, gain_per_s, resolution_um, noise_um must be numbers "
                         "(backlash_um one or two: 120 or 120,80) and seed an integer") from None
    if len(b) == 1:
        b = (b[0], b[0])
    if len(b) != 2 or any(not (math.isfinite(v) and v >= 0) for v in b):
        raise InputError(f"circle URL {url!r}: backlash_um (={q['backlash_um']!r}) must be one or two numbers >= 0")
    out["backlash_um"] = b
    require_positive("gain_per_s", out["gain_per_s"])
    if not (math.isfinite(out["resolution_um"]) and out["resolution_um"] >= 0):
        raise InputError(f"circle URL {url!r}: resolution_um (={q['resolution_um']}) must be >= 0")
    if not (math.isfinite(out["noise_um"]) and out["noise_um"] >= 0):
        raise InputError(f"circle URL {url!r}: noise_um (={q['noise_um']}) must be >= 0")
    return out


def measure_sim(url: str, program: CircleProgram, directions=DIRECTIONS, *, temperature_c: float | None = None,
                utility_day: float | None = None) -> CircularTest:
    """The circular test of the simulated two-axis machine (:func:`core.circle.simulate.simulated_test`)."""
    from core.circle.simulate import simulated_test

    o = sim_options(url)
    test = simulated_test(radius_mm=program.radius_mm, feed_mm_min=program.feed_mm_min, gain_per_s=o["gain_per_s"],
                          backlash_um=o["backlash_um"], noise_um=o["noise_um"], resolution_um=o["resolution_um"],
                          directions=check_directions(directions), plane=program.plane, temperature_c=temperature_c,
                          seed=o["seed"])
    what = test.source.removeprefix("simulated: ")
    return replace(test, utility_day=utility_day, source=f"simulated: {url} ({what})")


def measure_circle(url: str, program: CircleProgram, directions=DIRECTIONS, *, resolution_um: float | None = None,
                   accuracy_um: float = 0.0, temperature_c: float | None = None,
                   utility_day: float | None = None, timeout_s: float = 2.0) -> CircularTest:
    """A circular test on the machine ``url`` names (``linuxcnc://...`` or ``sim:...``)."""
    scheme = urlsplit(url).scheme
    if scheme == "sim":
        return measure_sim(url, program, directions, temperature_c=temperature_c, utility_day=utility_day)
    if scheme == "linuxcnc":
        if resolution_um is None:
            raise InputError("the linear scales' resolution is needed for the radial reading's uncertainty and "
                             "LinuxCNC does not know it: give --resolution-um (e.g. 1 for 1 µm scales; the scale's "
                             "data sheet)")
        return measure_linuxcnc(url, program, directions, resolution_um=resolution_um, accuracy_um=accuracy_um,
                                timeout_s=timeout_s, temperature_c=temperature_c, utility_day=utility_day)
    if scheme in ("modbus", "modbus+rtu", "canopen"):
        raise InputError(f"{scheme}:// reads one axis' round trip and cannot record a two-axis circle "
                         "(docs/controllers.md): export the circular test from its instrument (a ballbar) or the "
                         "CNC's trace tool and import it: mebm circle import FILE --profile P.toml")
    raise InputError(f"circle URL {url!r}: must be linuxcnc://HOST:PORT?sampler=N (LinuxCNC) or sim: (the "
                     "simulated two-axis machine)")
