"""The mebm service: configuration, measurement cycles, maintenance, figures and the demo machine.

It wires acquisition (drivers, simulated controllers) into storage (database and
dataset folders); the REST API (``api.rest``) and the other interfaces read through it.
Grouped by theme: ``config/`` (settings, loading, input), ``cycles/`` (scheduler, leases,
runner, executor, folders), ``maintenance/`` (loop, input), ``figures/`` (axis, plots,
prognosis, cache, process); ``service.Service`` starts and stops them as one.
"""
