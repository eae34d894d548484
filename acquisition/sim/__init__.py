"""Simulated controllers backed by the digital twin: ``SimAxis`` (the controller's clock,
latched sample and trace buffer), ``SimModbusController`` (pymodbus server),
``SimCanopenDrive`` (canopen LocalNode), twins (``CoreSimTwin``, ``KinematicTwin``) and
fault injection (``faults``)."""
