"""The mebm service: configuration, measurement cycles, scheduler and the demo machine.

It wires acquisition (drivers, simulated controllers) into storage (database and
dataset folders); the REST API (``api.rest``) reads through it.
"""
