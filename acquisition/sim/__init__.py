"""Simulated controllers backed by the digital twin, split by wire as the drivers are.

Shared by both wires: :mod:`acquisition.sim.axis` (``SimAxis``: the controller's clock,
latched sample and trace buffer), :mod:`acquisition.sim.twin` (``CoreSimTwin``,
``KinematicTwin``), :mod:`acquisition.sim.wear` (wear and repair) and
:mod:`acquisition.sim.faults` (fault injection).

- :mod:`acquisition.sim.modbus`: ``SimModbusController`` (a pymodbus server of
  ``mebm-modbus/1``) and ``SimProfileController`` (a register profile's layout);
- :mod:`acquisition.sim.canopen`: ``SimCanopenDrive`` (a canopen LocalNode), its CiA 402
  motion, the CNC master played by another process, and the drive's EDS/DCF files.
"""
