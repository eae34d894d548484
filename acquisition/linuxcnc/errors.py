"""How a LinuxCNC cycle fails beyond the shared kinds (:mod:`acquisition.errors`).

A LinuxCNC that is not running, or stops mid-trace, is a
:class:`~acquisition.errors.ControllerConnectionError`; a sampler overrun (halsampler's
``overrun``) is a :class:`~acquisition.errors.LostSamplesError`. The kinds below are
LinuxCNC's own states and configuration, each with what to do about it.
"""

from __future__ import annotations

from acquisition.errors import AcquisitionError


class EstopError(AcquisitionError):
    """LinuxCNC is in emergency stop (before the round trip, or it went there during it).
    mebm never resets an e-stop: the operator does, at the machine."""

    reason_code = "estop"


class MachineOffError(AcquisitionError):
    """LinuxCNC is out of e-stop but the machine is off (before the round trip, or it was
    switched off during it). mebm never switches a machine on."""

    reason_code = "machine_off"


class HalPinError(AcquisitionError, LookupError):
    """A HAL pin the configuration names does not exist, or the sampler does not record it
    (the sampler lines of docs/controllers.md are missing or net other signals)."""

    reason_code = "hal_pin"

    def __init__(self, message: str, *, pin: str):
        self.pin = pin
        super().__init__(message)
