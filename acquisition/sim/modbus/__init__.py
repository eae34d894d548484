"""Simulated Modbus controllers: ``SimModbusController`` (:mod:`acquisition.sim.modbus.server`,
register map ``mebm-modbus/1``), ``SimProfileController`` (:mod:`acquisition.sim.modbus.profile_server`,
a register profile's layout), both served from a loop thread (:mod:`acquisition.sim.modbus.loop_thread`)."""
