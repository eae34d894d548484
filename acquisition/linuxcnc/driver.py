"""mebm's LinuxCNC driver: both encoders of a joint latched in the same servo period by a
``sampler`` on the servo thread, read through ``halsampler``; state and (when told to) the
round trip through linuxcncrsh.

The user's HAL adds the sampler lines of docs/controllers.md: ``sampler.N.pin.0`` the
motor-side feedback, ``.pin.1`` the linear scale, ``.pin.2`` the commanded position. At
connection the driver checks that those pins net the same signals as the pins the URL
names (``motor_pin``, ``scale_pin``, ``command_pin``), reads the servo period of the
thread that runs the sampler, and starts ``halsampler``; the FIFO's backlog is read with
the sampler disabled and thrown away, so the first sample kept is of the present servo
period, and from then on every sample number is one servo period.

Passive by default: the CNC runs the round trip (its program, its operator) and
:class:`~acquisition.driver.round_trip_detector.RoundTripDetector` cuts it from the positions;
mebm's session is not even enabled (linuxcncrsh refuses every ``set`` on it). Active only
when configured (``trigger=active``): mebm writes the round trip as an ``.ngc`` program
(machine coordinates, ``G53``), positions the axis at its start by MDI if it is not there,
runs the program in AUTO mode and aborts it on any failure.

Every failure is typed: LinuxCNC not running or stopped mid-trace
(:class:`~acquisition.errors.ControllerConnectionError`), e-stop and machine off
(:class:`~acquisition.linuxcnc.errors.EstopError`, :class:`MachineOffError`), a missing
or unsampled pin (:class:`~acquisition.linuxcnc.errors.HalPinError`), a sampler overrun
(:class:`~acquisition.errors.LostSamplesError`: halsampler's ``overrun``; the count is the
sampler's ``overruns`` pin; the sample numbers do not advance over dropped samples, so no
overrun is ever tolerated).
"""

from __future__ import annotations

import asyncio
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from acquisition.driver.base import ControllerDriver
from acquisition.errors import ControllerConnectionError, ControllerTimeoutError, LostSamplesError, ProtocolError
from acquisition.linuxcnc import hal
from acquisition.linuxcnc.errors import EstopError, HalPinError, MachineOffError
from acquisition.linuxcnc.rsh import RshClient
from acquisition.types import AxisState, ControllerStatus, RoundTripProgram, SampleBlock
from core.errors import InputError

AXIS_LETTERS = "XYZABCUVW"
#: Columns of the sampler, in order.
COLUMNS = ("motor", "scale", "command")
#: How often the state (e-stop, machine, program) is read while samples are drained.
STATUS_INTERVAL_S = 0.1


class LinuxcncDriver(ControllerDriver):
    """One joint of a LinuxCNC machine. ``motor_units``: ``mm`` (the motor encoder scaled to
    joint units, as a HAL encoder usually is; divided by the axis' transmission) or
    ``rev``. ``axis_letter``: the coordinate the joint moves (trivkins: X for joint 0, ...).
    ``program_dir``: where the active round trip's ``.ngc`` is written (LinuxCNC must be
    able to read it)."""

    protocol = "linuxcnc"
    mode = "trace"  # every servo period, numbered by the sampler: a gap is a lost sample
    latched = True  # one sampler function call reads all pins in the same servo period
    continuous = True
    supports_passive = True
    has_running_flag = False
    connect_exchanges = 4  # the linuxcncrsh hello and HAL set-up (halcmd, halsampler's backlog)

    def __init__(self, host: str, port: int = 5007, *, joint: int = 0, motor_pin: str, scale_pin: str,
                 command_pin: str | None = None, sampler: int = 0, motor_units: str = "mm",
                 axis_letter: str | None = None, program_dir: str | None = None, **kwargs):
        kwargs.setdefault("timeout_s", 2.0)
        kwargs.setdefault("trigger", "passive")
        super().__init__(**kwargs)
        if not 0 <= int(joint) <= 15:
            raise InputError(f"joint (={joint}) must be a LinuxCNC joint number 0..15")
        if not 0 <= int(sampler) <= 15:
            raise InputError(f"sampler (={sampler}) must be a sampler FIFO number 0..15")
        if motor_units not in ("mm", "rev"):
            raise InputError(f"motor_units (={motor_units!r}) must be mm or rev")
        for name, pin in (("motor_pin", motor_pin), ("scale_pin", scale_pin), ("command_pin", command_pin)):
            if pin is not None and (not pin or any(c.isspace() for c in pin)):
                raise InputError(f"{name} (={pin!r}) must be a HAL pin name")
        self.host, self.port, self.joint, self.sampler_channel = host, int(port), int(joint), int(sampler)
        self.motor_pin, self.scale_pin = motor_pin, scale_pin
        self.command_pin = command_pin or f"joint.{self.joint}.pos-cmd"
        self.motor_units = motor_units
        letter = (axis_letter or (AXIS_LETTERS[self.joint] if self.joint < len(AXIS_LETTERS) else "")).upper()
        if len(letter) != 1 or letter not in AXIS_LETTERS:
            raise InputError(f"axis_letter (={axis_letter!r}) must be one of {', '.join(AXIS_LETTERS)}")
        self.axis_letter = letter
        self.program_dir = program_dir
        self.rsh: RshClient | None = None
        self.sampler: hal.HalSampler | None = None
        self.session: hal.SamplerSession | None = None
        self._program_path: Path | None = None  # the active round trip's .ngc, removed after the cycle
        self._t_status = 0.0
        self._seen_running = False
        self._t_run = 0.0
        self._commands: list[np.ndarray] = []
        self.last_command_mm = np.zeros(0)  # the commanded position beside the last trace's samples
        self._links = 0  # links opened (a trace is read on one link)
        self.samples_read = 0  # samples handed to the cycle under way (the tests wait on it)

    def describe(self) -> str:
        return f"linuxcnc://{self.host}:{self.port}?joint={self.joint}"

    @property
    def sampler_pid(self) -> int | None:
        """The process id of the running halsampler (None between cycles)."""
        return self.sampler.pid if self.sampler is not None else None

    # -- the link -------------------------------------------------------------------------------
    async def _connect(self) -> None:
        cycle = self._cycle
        self._links += 1
        if cycle is not None and not cycle.ever_connected:
            self._commands = []
            self.samples_read = 0
        self.rsh = RshClient(self.host, self.port, timeout_s=self.timeout_s)
        await self.rsh.open(enable=self.trigger == "active")
        await asyncio.to_thread(self._open_sampler)

    def _open_sampler(self) -> None:
        n = self.sampler_channel
        for col, pin in enumerate((self.motor_pin, self.scale_pin, self.command_pin)):
            src = hal.show_pin(pin)
            try:
                dst = hal.show_pin(f"sampler.{n}.pin.{col}")
            except HalPinError:
                raise HalPinError(f"HAL has no sampler.{n}.pin.{col}: load the sampler with cfg=fff on the servo "
                                  "thread (docs/controllers.md, LinuxCNC)", pin=f"sampler.{n}.pin.{col}") from None
            if src.signal is None or src.signal != dst.signal:
                raise HalPinError(
                    f"sampler.{n}.pin.{col} ({COLUMNS[col]}) records signal {dst.signal or 'none'}, but {pin} is on "
                    f"{src.signal or 'no signal'}: net {pin} to sampler.{n}.pin.{col} (docs/controllers.md)", pin=pin)
        self.servo_rate_hz = 1.0 / hal.thread_period_s(f"sampler.{n}")
        self.session = hal.SamplerSession(n, len(COLUMNS))
        try:
            self.session.open(self.timeout_s)
        finally:
            self.sampler = self.session.reader

    async def _close(self) -> None:
        if self._cycle is None or not self._cycle.started:
            self._forget_program()  # the round trip ran to its end
        session, self.session, self.sampler = self.session, None, None
        if session is not None:
            await asyncio.to_thread(session.close)
        if self.rsh is not None:
            await self.rsh.close()
            self.rsh = None

    # -- state --------------------------------------------------------------------------------
    async def _state(self) -> tuple[bool, bool, str]:
        rsh = self._rsh()
        # machine first: an e-stop between the two reads then shows as the e-stop it is
        machine = (await rsh.get("machine"))[0].upper() == "ON"
        estop = (await rsh.get("estop"))[0].upper() == "ON"
        for _ in range(3):  # an e-stop passes through machine off before task reports it
            if machine or estop:
                break
            await asyncio.sleep(0.05)
            estop = (await rsh.get("estop"))[0].upper() == "ON"
        program = (await rsh.get("program_status"))[0].upper()
        return estop, machine, program

    def _rsh(self) -> RshClient:
        if self.rsh is None or not self.rsh.is_open:
            raise ControllerConnectionError(f"not connected to {self.describe()}")
        return self.rsh

    async def _read_status(self) -> ControllerStatus:
        estop, machine, program = await self._state()
        self._raise_for(estop, machine, "")
        state = AxisState.RUNNING if program in ("RUNNING", "PAUSED") else AxisState.IDLE
        return ControllerStatus(state, 0, float("nan"), self.servo_rate_hz)

    def _raise_for(self, estop: bool, machine: bool, when: str) -> None:
        if estop:
            raise EstopError(f"LinuxCNC at {self.describe()} is in E-STOP{when}: the operator resets it at the "
                             "machine; mebm never does")
        if not machine:
            raise MachineOffError(f"LinuxCNC at {self.describe()} has the machine OFF{when}: the operator switches "
                                  "it on; mebm never does")

    # -- active round trip ----------------------------------------------------------------------
    def round_trip_gcode(self, program: RoundTripProgram) -> str:
        """The round trip as a LinuxCNC program, in machine coordinates (G53), exact stop."""
        a, f = self.axis_letter, program.feed_mm_min
        dwell = f"G4 P{program.dwell_s:.3f}\n" if program.dwell_s > 0 else ""
        return (f"(mebm round trip, joint {self.joint})\nG21 G90 G61\n{dwell}"
                f"G53 G1 {a}{program.end_mm:.4f} F{f:.1f}\n{dwell}"
                f"G53 G1 {a}{program.start_mm:.4f} F{f:.1f}\n{dwell}M2\n")

    async def _start(self, program: RoundTripProgram) -> int | None:
        try:
            return await self._run_program(program)
        except ProtocolError:
            # a refused command: because of the machine's state (e-stop, off)? say so
            estop, machine, _ = await self._state()
            self._raise_for(estop, machine, " while mebm started the round trip")
            raise

    async def _run_program(self, program: RoundTripProgram) -> int | None:
        rsh = self._rsh()
        idx = AXIS_LETTERS.index(self.axis_letter)
        here = float((await rsh.get("abs_cmd_pos"))[idx])
        if abs(here - program.start_mm) > 1e-4:  # to the start first, by MDI, outside the trace
            await rsh.set("mode mdi")
            await rsh.set(f"mdi G53 G1 {self.axis_letter}{program.start_mm:.4f} F{program.feed_mm_min:.1f}")
            end = time.monotonic() + 2.0 * abs(here - program.start_mm) / program.speed_mm_s + 5.0
            while abs(float((await rsh.get("abs_cmd_pos"))[idx]) - program.start_mm) > 1e-4:
                estop, machine, _ = await self._state()
                self._raise_for(estop, machine, " while mebm positioned the axis at the round trip's start")
                if time.monotonic() > end:
                    raise ControllerTimeoutError(f"the axis did not reach the round trip's start "
                                                 f"{program.start_mm:g} mm")
                await asyncio.sleep(0.02)
        path = self._write_program(program)
        await rsh.set("mode auto")
        await rsh.set(f"open {path}")
        self.sampler.take()  # the trace begins with the program
        self._commands = []
        self.samples_read = 0
        self._seen_running = False
        self._t_run = time.monotonic()
        await rsh.set("run")
        return None

    def _write_program(self, program: RoundTripProgram) -> str:
        folder = Path(self.program_dir or tempfile.gettempdir())
        path = folder / f"mebm-round-trip-j{self.joint}-{os.getpid()}.ngc"
        path.write_text(self.round_trip_gcode(program))
        path.chmod(0o644)  # LinuxCNC may run as another user
        self._program_path = path
        return str(path)

    def _forget_program(self) -> None:
        if self._program_path is not None:
            self._program_path.unlink(missing_ok=True)
            self._program_path = None

    async def _abort(self) -> None:
        if self.rsh is not None and self.rsh.enabled:
            try:
                await self.rsh.set("abort")
                self._forget_program()
            except ProtocolError:
                estop, machine, _ = await self._state()
                if not (estop or not machine):
                    raise  # refused on a running machine
                self._forget_program()  # an e-stop or a machine off has stopped the axis already

    async def _acknowledge(self) -> None:
        return None  # LinuxCNC's states need the operator (e-stop, machine on): _read_status raises for them

    # -- samples --------------------------------------------------------------------------------
    async def _samples(self, finished: bool = False) -> SampleBlock:
        """The samples halsampler printed since the last call. The sampler's ``overruns`` pin
        is read after them: a sample written after a drop is in hand only once the drop is
        counted there (halsampler's ``overrun`` line may come later than the samples)."""
        s = self.sampler
        if s is None:
            raise ControllerConnectionError(f"not connected to {self.describe()}")
        cycle = self._cycle
        if cycle is not None and cycle.wire is not None and cycle.wire != self._links:
            # samples were drained on a link that was lost: those of the outage are gone for good
            raise LostSamplesError(f"the link to {self.describe()} was lost mid-trace: the samples while it was "
                                   "down are not in the trace", lost_samples=1)
        tags, vals = s.take()
        eof = s.eof
        if not eof:
            lost = await asyncio.to_thread(self.session.dropped)
            if lost:
                raise LostSamplesError(
                    f"sampler.{self.sampler_channel} dropped {lost} sample(s) so far (FIFO full): halsampler did not "
                    "keep up (a busy host, or a FIFO too small: depth= in the sampler line)", lost_samples=lost)
        elif not tags.size:
            raise ControllerConnectionError(f"halsampler ended ({s.stderr.strip() or 'HAL gone'}): LinuxCNC stopped "
                                            "mid-trace")
        if s.bad_lines:
            raise ProtocolError(f"halsampler printed {s.bad_lines} line(s) that are not {len(COLUMNS)} numbers: the "
                                f"sampler's cfg must be fff (motor, scale, command)")
        if not tags.size:
            return SampleBlock.empty(finished)
        motor = vals[:, 0] if self.motor_units == "rev" else vals[:, 0] / self.cycle.axis.transmission_mm_per_rev
        if cycle is not None:
            cycle.wire = self._links  # the link the trace is read on
        self._commands.append(vals[:, 2])
        self.samples_read += int(tags.size)
        return SampleBlock(tags, motor, vals[:, 1], finished=finished, time_s=tags / self.servo_rate_hz)

    async def _poll_state(self, when: str) -> str | None:
        """The program state every ``STATUS_INTERVAL_S`` (None between reads); e-stop and machine off raise."""
        now = time.monotonic()
        if now - self._t_status < STATUS_INTERVAL_S:
            return None
        self._t_status = now
        estop, machine, program = await self._state()
        self._raise_for(estop, machine, when)
        return program

    async def _drain(self) -> SampleBlock:
        """Samples and the program's state, together every ``STATUS_INTERVAL_S``."""
        program = await self._poll_state(" during the round trip")
        if program is None:
            return SampleBlock.empty()
        finished = False
        if program in ("RUNNING", "PAUSED"):
            self._seen_running = True
        elif self._seen_running:
            finished = True  # the program ended (its last dwell is in the trace)
        elif time.monotonic() - self._t_run > 3.0:
            raise ProtocolError(f"LinuxCNC at {self.describe()} did not run the round-trip program "
                                f"(program status {program})")
        block = await self._samples(finished)
        if finished:
            self.last_command_mm = np.concatenate(self._commands) if self._commands else np.zeros(0)
        return block

    async def _passive_drain(self) -> SampleBlock:
        if await self._poll_state(" while mebm listened for a round trip") is None:
            return SampleBlock.empty()
        return await self._samples()
