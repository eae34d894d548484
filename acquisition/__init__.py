"""Acquisition: drivers for Modbus TCP and CANopen controllers, simulated controllers, the cycle.

- ``acquisition.driver.base.ControllerDriver``: the base class that owns the measurement loop
  (idle check, start, drain, abort on failure), composed of ``retry.RetryPolicy`` (every
  exchange), ``trace_assembler.TraceAssembler`` (counter continuity, gaps, duplicates),
  ``encoder_monitor.EncoderMonitor`` (stuck/jumping/glitching encoders) and a fresh
  ``acquisition_cycle.AcquisitionCycle`` per cycle; ``acquisition.modbus.driver.ModbusDriver``
  (with its register map, ``modbus_map``) and ``acquisition.canopen.driver.CanopenDriver``
  implement only their wire. See docs/acquisition.md.
- ``acquisition.modbus.profile``: Modbus register profiles (where a PLC keeps the positions,
  their types, byte/word orders, scales; validated with errors naming the field) and
  ``acquisition.modbus.polled.ProfileModbusDriver``, which polls them (one PDU when it can,
  else separate reads with the skew reported); its ``poll()`` reads one sample now.
- ``acquisition.measurement.run_cycle`` / ``run_cycle_async``: one measurement cycle ->
  ``CycleResult`` (ok/failed with a reason, trace, criteria, decision, uncertainty).
- ``acquisition.url.driver_from_url``: ``modbus://HOST:PORT[?profile=P.toml]``,
  ``modbus+rtu:///dev/DEVICE?baudrate=N`` / ``canopen://INTERFACE/CHANNEL?node=N``.
- ``acquisition.sim``: simulated controllers backed by the digital twin, with fault injection.
- ``acquisition.errors``: the acquisition subtree of ``core.errors.MebmError``.

Imports ``core`` only (never ``storage`` or ``api``); submodules import their wire
libraries (pymodbus, python-can, canopen) so this package stays cheap to import.
"""
