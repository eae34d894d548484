"""Acquisition: drivers for Modbus TCP and CANopen controllers, simulated controllers, the cycle.

- ``acquisition.driver.ControllerDriver``: the base class that owns the measurement loop
  (idle check, start, drain, timeouts and bounded retries, abort on failure, counter
  continuity, stuck/jumping encoders); ``acquisition.modbus.ModbusDriver`` and
  ``acquisition.canopen.CanopenDriver`` implement only their wire.
- ``acquisition.cycle.run_cycle`` / ``run_cycle_async``: one measurement cycle ->
  ``CycleResult`` (ok/failed with a reason, trace, criteria, decision, uncertainty).
- ``acquisition.url.driver_from_url``: ``modbus://HOST:PORT`` / ``canopen://INTERFACE/CHANNEL?node=N``.
- ``acquisition.sim``: simulated controllers backed by the digital twin, with fault injection.
- ``acquisition.errors``: the acquisition subtree of ``core.errors.MebmError``.

Imports ``core`` only (never ``storage`` or ``api``); submodules import their wire
libraries (pymodbus, python-can, canopen) so this package stays cheap to import.
"""
