"""Controller URLs: ``modbus://HOST[:PORT][?mode=trace|latched|separate&device_id=N]`` and
``canopen://INTERFACE/CHANNEL?node=N[&rate_hz=R&window_ms=W&time_scale=X&<bus option>=V...]``
(any other query key, e.g. ``bitrate`` or ``port``, is passed to the python-can bus).
"""

from __future__ import annotations

from urllib.parse import parse_qs, urlsplit

from core.errors import InputError


def driver_from_url(url: str, **kwargs):
    """A :class:`~acquisition.driver.ControllerDriver` for ``url``; ``kwargs`` go to the driver
    (``timeout_s``, ``retries``, ...)."""
    parts = urlsplit(url)
    q = {k: v[-1] for k, v in parse_qs(parts.query).items()}

    def num(key, cast, default):
        if key not in q:
            return default
        try:
            return cast(q[key])
        except ValueError:
            raise InputError(f"controller URL {url!r}: {key} (={q[key]!r}) must be a number") from None

    if parts.scheme == "modbus":
        from acquisition.modbus import ModbusDriver

        if not parts.hostname:
            raise InputError(f"controller URL {url!r} needs a host: modbus://HOST:PORT")
        try:
            port = parts.port or 502
        except ValueError:
            raise InputError(f"controller URL {url!r}: the port must be a number 1..65535") from None
        return ModbusDriver(parts.hostname, port, device_id=num("device_id", int, 1), mode=q.get("mode", "trace"),
                            **kwargs)
    if parts.scheme == "canopen":
        from acquisition.canopen import CanopenDriver

        channel = parts.path.lstrip("/")
        if not parts.netloc or not channel:
            raise InputError(f"controller URL {url!r} must be canopen://INTERFACE/CHANNEL?node=N "
                             "(e.g. canopen://socketcan/can0?node=5, canopen://virtual/sim?node=5)")
        if "node" not in q:
            raise InputError(f"controller URL {url!r} needs ?node=N (the drive's CANopen node id)")
        known = {"node", "rate_hz", "time_scale", "window_ms"}
        bus_kwargs = {}
        for key, val in q.items():  # anything else is a python-can bus option (bitrate, port, ...)
            if key not in known:
                bus_kwargs[key] = int(val) if val.lstrip("-").isdigit() else val
        return CanopenDriver(channel, num("node", int, 0), interface=parts.netloc,
                             sync_rate_hz=num("rate_hz", float, 250.0), time_scale=num("time_scale", float, 1.0),
                             bus_kwargs=bus_kwargs,
                             sync_window_s=num("window_ms", float, 0.0) / 1000.0 or None, **kwargs)
    raise InputError(f"controller URL {url!r}: scheme must be modbus:// or canopen://")
