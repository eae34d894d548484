"""The driver loop and its parts, shared by every wire.

- :mod:`acquisition.driver.base`: :class:`ControllerDriver`, the base class that owns the
  measurement loop (idle check, start, drain, abort on failure); a wire package implements
  only its exchanges (:class:`BlockingLinkDriver` for a wire whose library blocks);
- :mod:`acquisition.driver.retry`: how every exchange is retried, boundedly;
- :mod:`acquisition.driver.trace_assembler`: counter continuity, gaps, duplicates;
- :mod:`acquisition.driver.encoder_monitor`: stuck, jumping and glitching encoders;
- :mod:`acquisition.driver.cycle_state`: everything one acquisition cycle knows, made fresh
  for each cycle;
- :mod:`acquisition.driver.round_trip_detector`: the round trip found in a stream mebm did
  not command (passive mode).
"""
