"""Acquisition errors: every way a measurement cycle can fail, as one subtree of MebmError.

Faults on the wire are normal events, not bugs: each class says what a technician
should look at, and carries its ``reason_code`` (the stable short code the service,
metrics and tests use; ``code`` is taken: the Modbus exception or EMCY code). stdlib co-bases let callers catch them the usual way
(``ConnectionError``, ``TimeoutError``). Foreign exceptions (pymodbus, python-can,
canopen) are translated at the driver boundary with ``raise ... from``.
"""

from __future__ import annotations

from core.errors import MebmError


class AcquisitionError(MebmError):
    """A measurement cycle could not acquire a trustworthy trace."""

    reason_code = "acquisition"
    #: Whether retrying the same operation may succeed (timeouts, dropped links).
    transient = False


class ControllerConnectionError(AcquisitionError, ConnectionError):
    """The controller cannot be reached, refused the connection or dropped it."""

    reason_code = "connection"
    transient = True


class ControllerTimeoutError(AcquisitionError, TimeoutError):
    """The controller did not answer within the configured timeout."""

    reason_code = "timeout"
    transient = True


class ProtocolError(AcquisitionError):
    """The controller answered, but with an error or something we do not understand.

    ``code`` is the Modbus exception code or the SDO abort code when there is one.
    """

    reason_code = "protocol"

    def __init__(self, message: str, *, code: int | None = None):
        self.code = code
        super().__init__(message)


class DeviceBusyError(ProtocolError):
    """The controller answered that it cannot serve the request now but may shortly
    (Modbus exception 5 acknowledge, 6 device busy): the same request is retried."""

    reason_code = "device_busy"
    transient = True


class TransientProtocolError(ProtocolError):
    """An error reply the protocol says may pass (Modbus exception 4 server device failure,
    11 gateway target did not respond): retried; if it persists, the cycle fails with
    ``protocol``."""

    reason_code = "protocol_transient"
    transient = True


class DeviceFaultError(AcquisitionError):
    """The controller or drive reported a fault (CANopen EMCY, Modbus fault register).

    ``code`` is the 16-bit error code (CiA 301/402 EMCY code).
    """

    reason_code = "device_fault"

    def __init__(self, message: str, *, code: int):
        self.code = int(code)
        super().__init__(f"{message} (error code 0x{self.code:04X})")


class LostSamplesError(AcquisitionError):
    """The sample counter has a gap: samples were lost and will not be interpolated."""

    reason_code = "lost_samples"

    def __init__(self, message: str, *, lost_samples: int, first_missing: int | None = None):
        self.lost_samples = int(lost_samples)
        self.first_missing = first_missing
        super().__init__(message)


class EncoderFaultError(AcquisitionError):
    """An encoder value is implausible: stuck while the axis moves, or jumping."""

    reason_code = "encoder_fault"

    def __init__(self, message: str, *, encoder: str):
        self.encoder = encoder
        super().__init__(message)


class DriverMisuseError(MebmError, RuntimeError):
    """A driver was used the wrong way by the program calling it (a bug there, not a fault of
    the machine): ``acquire()`` inside a running event loop, two cycles at once on one driver."""


class AxisBusyError(AcquisitionError):
    """The axis is not idle (moving, faulted or in another program): the cycle was not started."""

    reason_code = "axis_busy"


class IncompleteTraceError(AcquisitionError):
    """The acquired trace does not cover the programmed round trip (stroke missing, travel short)."""

    reason_code = "incomplete_trace"


class IncompleteCircleError(IncompleteTraceError):
    """A circular test's recording does not close its circle: the arc ran short of the 360°
    the test analyses (the program was stopped or aborted), or the recording holds no circle."""

    reason_code = "incomplete_circle"


class NoRoundTripSeen(AcquisitionError):
    """Passive mode: the CNC ran no round trip while mebm listened (``waited_s``). Nothing
    was measured: start the round-trip program at the CNC within the time-out."""

    reason_code = "no_round_trip"

    def __init__(self, message: str, *, waited_s: float):
        self.waited_s = float(waited_s)
        super().__init__(message)


class RoundTripTooLong(AcquisitionError):
    """Passive mode: a round trip took longer than the configured ``max_duration_s``
    (a feed hold, a slower program than configured, or motion that was not the round trip)."""

    reason_code = "round_trip_too_long"


class IncompleteRoundTrip(AcquisitionError):
    """Passive mode: a round trip started (left rest, reached the minimum stroke) but never
    came back to rest at its start: stopped short, or the program ended elsewhere."""

    reason_code = "incomplete_round_trip"
