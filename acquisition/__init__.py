"""Acquisition: drivers for Modbus and CANopen controllers, simulated controllers, the measurement.

One package per wire, the driver loop in one, the simulators split the same way:

- ``acquisition.driver``: ``base.ControllerDriver``, the base class that owns the measurement
  loop (idle check, start, drain, abort on failure), composed of ``retry.RetryPolicy`` (every
  exchange), ``trace_assembler.TraceAssembler`` (counter continuity, gaps, duplicates),
  ``encoder_monitor.EncoderMonitor`` (stuck/jumping/glitching encoders) and a fresh
  ``cycle_state.AcquisitionCycle`` per cycle; ``round_trip_detector`` finds a round trip mebm
  did not command. See docs/acquisition.md.
- ``acquisition.modbus``: ``driver.ModbusDriver`` (register map ``mebm-modbus/1``,
  ``register_map``), register profiles (``profile``: where a PLC keeps the positions, their
  types, byte/word orders, scales) and ``polled.ProfileModbusDriver``, which polls them.
- ``acquisition.canopen``: ``driver.CanopenDriver`` (mebm's objects), ``cia402`` (standard
  CiA 402 objects), ``listen`` (listen-only beside a CNC master), ``objects``, ``mapping``,
  ``sync_matcher``.
- ``acquisition.url.driver_from_url``: the table of URL schemes; each wire package parses its
  own URLs (``modbus.url``, ``canopen.url``); ``acquisition.trigger``: active or passive, for
  every scheme.
- ``acquisition.measurement.run_cycle`` / ``run_cycle_async``: one measurement cycle ->
  ``CycleResult`` (ok/failed with a reason, trace, criteria, decision, uncertainty).
- ``acquisition.sim``: simulated controllers backed by the digital twin, with fault injection
  (``sim.modbus``, ``sim.canopen``).
- ``acquisition.errors``: the acquisition subtree of ``core.errors.MebmError``;
  ``acquisition.types``, ``acquisition.scale``: shared by every wire.
- ``acquisition.trace_import``: controller scope traces (CSV) into mebm runs.

Imports ``core`` only (never ``storage`` or ``api``); the wire packages do not import each
other; submodules import their wire libraries (pymodbus, python-can, canopen) so this package
stays cheap to import.
"""
