"""The CANopen wire (canopen on python-can).

- :mod:`acquisition.canopen.driver`: :class:`CanopenDriver`, active with mebm's objects
  (mebm is the NMT master and the SYNC producer; the drive plays a programmed round trip);
- :mod:`acquisition.canopen.cia402`: active through the standard CiA 402 objects;
- :mod:`acquisition.canopen.listen`: listen-only beside a CNC master, sending no frame;
- :mod:`acquisition.canopen.objects`: the objects mebm uses, the object dictionary, the PDO
  codec (docs/canopen-objects.md);
- :mod:`acquisition.canopen.mapping`: where a drive's TPDO carries the two positions (from
  the configuration or an EDS/DCF);
- :mod:`acquisition.canopen.sync_matcher`: which SYNC a TPDO answers, from bus timestamps;
- :mod:`acquisition.canopen.url`: ``canopen://`` URLs and ``[machines.axes.canopen]`` tables.
"""
