"""The simulated CANopen side: ``SimCanopenDrive`` (:mod:`acquisition.sim.canopen.drive`), its CiA 402
position control (:mod:`acquisition.sim.canopen.cia402`), a CNC master run as its own process
(:mod:`acquisition.sim.canopen.cnc_master`) and the drive's EDS/DCF files (:mod:`acquisition.sim.canopen.eds`)."""
