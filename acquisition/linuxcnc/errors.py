"""How a LinuxCNC cycle fails beyond the shared kinds (:mod:`acquisition.errors`).

A LinuxCNC that is not running, or stops mid-trace, is a
:class:`~acquisition.errors.ControllerConnectionError`; a sampler overrun (halsampler's
``overrun``) is a :class:`~acquisition.errors.LostSamplesError`. The kinds below are
LinuxCNC's own states and configuration, each with what to do about it.
"""

from __future__ import annotations

from acquisition.errors import AcquisitionError, ProtocolError


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


class CommandRefusedError(ProtocolError):
    """linuxcncrsh refused a ``set`` on mebm's enabled session, and asking it why (``get
    enable``, ``get machine``, ``get estop``) and sending the command once more did not help.
    ``estop``, ``machine_on``, ``enabled``: the state found after the refusal (``estop`` is
    None when the machine was on: it was not asked)."""

    reason_code = "command_refused"

    def __init__(self, message: str, *, command: str, estop: bool | None, machine_on: bool, enabled: bool):
        self.command, self.estop, self.machine_on, self.enabled = command, estop, machine_on, enabled
        super().__init__(message)
