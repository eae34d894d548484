"""CiA 402 position control for the simulated drive: device state machine, Profile Position
(0x6060 = 1) and Cyclic Synchronous Position (0x6060 = 8), stepped once per SYNC.

The drive's own objects (0x2000-0x2006) play a precomputed twin round trip; a drive
commanded through CiA 402 must instead follow set-points as they come, so here the axis
is the :class:`~acquisition.sim.twin.KinematicTwin`'s (first-order position loop, play
of width b, cyclic lead error) stepped one communication cycle at a time from the
demand position. Same equations, so the same round trip gives the same backlash.

Position user units are encoder increments (position factor 1): 0x607A, 0x6064 and
0x6067 in increments, 0x6081 in increments/s, 0x6083/0x6084 in increments/s².
Simplifications, said plainly: a new PP set-point is accepted only once the previous
one is reached (no blending, bit 5 "change set immediately" is not honoured); relative
moves (bit 6) are not supported; quick stop disables the drive at once.
"""

from __future__ import annotations

import math

from acquisition.canopen import objects as co
from acquisition.scale import EncoderScale
from core.errors import InputError

SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
READY_TO_SWITCH_ON = "READY TO SWITCH ON"
SWITCHED_ON = "SWITCHED ON"
OPERATION_ENABLED = "OPERATION ENABLED"
FAULT = "FAULT"

_STATUS_BITS = {
    SWITCH_ON_DISABLED: co.SW_SWITCH_ON_DISABLED,
    READY_TO_SWITCH_ON: co.SW_READY_TO_SWITCH_ON | co.SW_QUICK_STOP,
    SWITCHED_ON: co.SW_READY_TO_SWITCH_ON | co.SW_SWITCHED_ON | co.SW_QUICK_STOP | co.SW_VOLTAGE_ENABLED,
    OPERATION_ENABLED: (co.SW_READY_TO_SWITCH_ON | co.SW_SWITCHED_ON | co.SW_OPERATION_ENABLED | co.SW_QUICK_STOP
                        | co.SW_VOLTAGE_ENABLED),
    FAULT: co.SW_FAULT,
}


class PositionFollower:
    """The kinematic twin's axis, one step at a time: nut follows the command through a
    first-order loop (gain K), the table through the play (width b), plus a cyclic error."""

    def __init__(self, *, k_a_mm_per_rev: float, gain_per_s: float, backlash_mm: float, cyclic_mm: float = 0.0,
                 lead_mm: float = 16.0, nut_mm: float = 0.0, side: float = -1.0):
        self.k_a = k_a_mm_per_rev
        self.gain_per_s = gain_per_s
        self.h = backlash_mm / 2.0
        self.cyclic_mm, self.lead_mm = cyclic_mm, lead_mm
        self.nut_mm = nut_mm
        self.x_mm = nut_mm - side * self.h  # table before the cyclic error

    @classmethod
    def from_twin(cls, twin, motor_rev: float, table_mm: float) -> "PositionFollower":
        """From a :class:`KinematicTwin` (its own equations), or a :class:`CoreSimTwin`'s nominal
        model (k_a, K, b only: the core twin's other effects are not stepped here)."""
        if all(hasattr(twin, n) for n in ("k_a", "gain_per_s", "backlash_mm", "cyclic_mm", "lead_mm", "_side")):
            kw = dict(k_a_mm_per_rev=twin.k_a, gain_per_s=twin.gain_per_s, backlash_mm=twin.backlash_mm,
                      cyclic_mm=twin.cyclic_mm, lead_mm=twin.lead_mm, side=twin._side)
        elif hasattr(twin, "model") and hasattr(twin.model, "backlash_um"):
            m = twin.model
            kw = dict(k_a_mm_per_rev=m.transmission_mm_per_rev, gain_per_s=m.position_gain_per_s,
                      backlash_mm=m.backlash_um * 1e-3, lead_mm=m.screw_lead_mm,
                      side=1.0 if getattr(twin, "_side", "negative") == "positive" else -1.0)
        else:
            raise InputError(f"CiA 402 motion in the simulated drive needs a KinematicTwin or a CoreSimTwin, "
                             f"not {type(twin).__name__}")
        f = cls(nut_mm=motor_rev * kw["k_a_mm_per_rev"], **kw)
        if math.isfinite(table_mm) and abs(table_mm - f.nut_mm) <= f.h:
            f.x_mm = table_mm  # keep where the table really is within the play
        return f

    def step(self, command_mm: float, dt_s: float) -> tuple[float, float]:
        alpha = 1.0 - math.exp(-self.gain_per_s * dt_s)
        self.nut_mm += alpha * (command_mm - self.nut_mm)
        self.x_mm = min(max(self.x_mm, self.nut_mm - self.h), self.nut_mm + self.h)
        return self.position()

    def position(self) -> tuple[float, float]:
        table = self.x_mm + self.cyclic_mm * math.sin(2 * math.pi * self.x_mm / self.lead_mm)
        return self.nut_mm / self.k_a, table


class TrapezoidMove:
    """Trapezoidal (or triangular) move from rest to rest, ``s(t)`` in increments."""

    def __init__(self, p0: float, p1: float, v: float, a: float, d: float):
        self.p0, self.sign, dist = p0, (1.0 if p1 >= p0 else -1.0), abs(p1 - p0)
        if v <= 0 or a <= 0 or d <= 0:
            raise InputError(f"profile velocity (={v}), acceleration (={a}) and deceleration (={d}) must be > 0")
        if v * v / (2 * a) + v * v / (2 * d) > dist:  # never reaches the profile velocity
            v = math.sqrt(2 * dist * a * d / (a + d))
        self.v, self.a, self.d, self.dist = v, a, d, dist
        self.t_a, self.t_d = v / a, v / d
        self.t_c = max(dist - v * v / (2 * a) - v * v / (2 * d), 0.0) / v if v > 0 else 0.0
        self.duration_s = self.t_a + self.t_c + self.t_d if dist > 0 else 0.0

    def at(self, t: float) -> float:
        if t >= self.duration_s:
            s = self.dist
        elif t < self.t_a:
            s = 0.5 * self.a * t * t
        elif t < self.t_a + self.t_c:
            s = 0.5 * self.v * self.t_a + self.v * (t - self.t_a)
        else:
            r = self.duration_s - t
            s = self.dist - 0.5 * self.d * r * r
        return self.p0 + self.sign * s


class Cia402Motion:
    """Device control, PP and CSP of one simulated drive (driven from its SDO and SYNC callbacks)."""

    def __init__(self, twin, scale: EncoderScale):
        self.twin, self.scale = twin, scale
        self.state = SWITCH_ON_DISABLED
        self.controlword = 0
        self.mode = 0
        self.target = 0  # 0x607A (SDO, or RPDO in CSP), increments
        self.velocity = self.acceleration = self.deceleration = 0
        self.window = 200  # 0x6067
        self.follower: PositionFollower | None = None
        self.engaged = False  # positions come from here since CiA 402 first enabled operation
        self.demand = 0.0  # position demand, increments
        self._pending_csp: int | None = None  # RPDO target, applied on the next SYNC
        self._move: TrapezoidMove | None = None
        self._move_t = 0.0
        self._ack = False
        self.moves = 0  # PP set-points accepted
        self.csp_targets = 0  # CSP targets applied

    # -- inputs -----------------------------------------------------------------------------------
    def write(self, index: int, value: int, hold: tuple[float, float]) -> None:
        """An SDO (or RPDO) write to a CiA 402 object; ``hold``: positions (rev, mm) before engaging."""
        if index == co.CONTROLWORD:
            self._controlword(int(value), hold)
        elif index == co.MODES_OF_OPERATION:
            self.mode = int(value)
            self._move = None
        elif index == co.TARGET_POSITION:
            self.target = int(value)
        elif index == co.PROFILE_VELOCITY:
            self.velocity = int(value)
        elif index == co.PROFILE_ACCELERATION:
            self.acceleration = int(value)
        elif index == co.PROFILE_DECELERATION:
            self.deceleration = int(value)
        elif index == co.POSITION_WINDOW:
            self.window = int(value)

    def rpdo(self, controlword: int, target: int, hold: tuple[float, float]) -> None:
        """RPDO1 from a CNC master: the controlword now, the target on the next SYNC (CSP)."""
        self._controlword(controlword, hold)
        if self.mode == co.MODE_CYCLIC_SYNC_POSITION:
            self._pending_csp = int(target)
        else:
            self.target = int(target)

    def _controlword(self, cw: int, hold: tuple[float, float]) -> None:
        prev, self.controlword = self.controlword, cw
        st = self.state
        if st == FAULT:
            if cw & co.CW_FAULT_RESET and not prev & co.CW_FAULT_RESET:
                self.state = SWITCH_ON_DISABLED
            return
        if cw & 0x02 == 0:  # disable voltage
            self.state = SWITCH_ON_DISABLED
        elif cw & 0x04 == 0:  # quick stop (simplified: stop and disable at once)
            self.state = SWITCH_ON_DISABLED
        elif cw & 0x8F == co.CW_ENABLE_OPERATION and st in (SWITCHED_ON, OPERATION_ENABLED):
            if st != OPERATION_ENABLED:
                self._enable(hold)
        elif cw & 0x8F == co.CW_SWITCH_ON and st in (READY_TO_SWITCH_ON, OPERATION_ENABLED):
            self.state = SWITCHED_ON
        elif cw & 0x87 == co.CW_SHUTDOWN:
            self.state = READY_TO_SWITCH_ON
        if self.state != OPERATION_ENABLED:
            self._move = None
            self._ack = False
            return
        if self.mode == co.MODE_PROFILE_POSITION:
            new = cw & co.CW_NEW_SETPOINT and not prev & co.CW_NEW_SETPOINT
            done = self._move is None or self._move_t >= self._move.duration_s
            if new and done:
                self._move = TrapezoidMove(self.demand, float(self.target), float(self.velocity), float(self.acceleration),
                                   float(self.deceleration or self.acceleration))
                self._move_t = 0.0
                self._ack = True
                self.moves += 1
            elif not cw & co.CW_NEW_SETPOINT:
                self._ack = False

    def _enable(self, hold: tuple[float, float]) -> None:
        if self.follower is None or not self.engaged:
            self.follower = PositionFollower.from_twin(self.twin, *hold)
        self.engaged = True
        self.state = OPERATION_ENABLED
        self.demand = float(self.scale.motor_counts(self.follower.position()[0]))
        self.target = int(self.demand)
        self._pending_csp = None

    def release(self) -> None:
        """The drive's own round-trip program took over (0x2001 START)."""
        self.engaged = False
        self.state = SWITCH_ON_DISABLED
        self._move = None

    # -- one communication cycle -------------------------------------------------------------------
    def step(self, dt_s: float) -> tuple[float, float]:
        """Advance one SYNC period; the positions (rev, mm) latched at this SYNC."""
        f = self.follower
        if self.state == OPERATION_ENABLED:
            if self.mode == co.MODE_CYCLIC_SYNC_POSITION and self._pending_csp is not None:
                self.demand = float(self._pending_csp)
                self._pending_csp = None
                self.csp_targets += 1
            elif self.mode == co.MODE_PROFILE_POSITION and self._move is not None:
                self._move_t += dt_s
                self.demand = self._move.at(self._move_t)
        command_mm = self.demand / self.scale.counts_per_rev * f.k_a
        return f.step(command_mm, dt_s)

    def statusword(self) -> int:
        sw = _STATUS_BITS[self.state]
        if self.state != OPERATION_ENABLED:
            return sw
        if self.mode == co.MODE_PROFILE_POSITION:
            actual = float(self.scale.motor_counts(self.follower.position()[0]))
            moving = self._move is not None and self._move_t < self._move.duration_s
            if not moving and abs(actual - self.target) <= self.window:
                sw |= co.SW_TARGET_REACHED
            if self._ack:
                sw |= co.SW_SETPOINT_ACK
        elif self.mode == co.MODE_CYCLIC_SYNC_POSITION:
            sw |= co.SW_SETPOINT_ACK  # drive follows the command value
        return sw
