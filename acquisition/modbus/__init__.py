"""The Modbus wire (pymodbus), TCP and RTU.

- :mod:`acquisition.modbus.driver`: :class:`ModbusDriver`, for controllers that speak mebm's
  register map ``mebm-modbus/1``;
- :mod:`acquisition.modbus.register_map`: that map's addresses and word codecs
  (docs/register-map.md);
- :mod:`acquisition.modbus.profile`: register profiles, where another controller keeps the
  values mebm needs (docs/controllers.md);
- :mod:`acquisition.modbus.polled`: :class:`ProfileModbusDriver`, which polls a profile's
  values;
- :mod:`acquisition.modbus.url`: ``modbus://``, ``modbus+rtu://`` and ``sim://`` URLs.
"""
