"""Maintenance in the service: the loop (:mod:`api.service.maintenance.loop`: orders opened by
the measured error, repairs recorded by people, the measurement that verifies them) and what a
person sends to it, validated once for every writer (:mod:`api.service.maintenance.input`)."""
