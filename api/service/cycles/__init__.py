"""Measurement cycles in the service, from schedule to stored result.

- :mod:`api.service.cycles.scheduler`: per-axis schedules and the per-axis cycle queue;
- :mod:`api.service.cycles.leases`: the fleet scheduler, several workers on one database;
- :mod:`api.service.cycles.runner`: one cycle on an axis' controller, in a worker process
  where it can run there (:class:`CycleProcesses`);
- :mod:`api.service.cycles.executor`: one cycle from request to stored result, and the
  on-disk spool;
- :mod:`api.service.cycles.folders`: where an axis' raw runs live, and whose a folder is.
"""
