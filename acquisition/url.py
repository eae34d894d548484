"""Controller URLs: ``modbus://HOST[:PORT][?mode=trace|latched|separate&device_id=N]`` and
``canopen://INTERFACE/CHANNEL?node=N[&mode=listen-only|active-cia402|active-mebm&rate_hz=R&window_ms=W&...]``
(:mod:`acquisition.canopen_url`; any other query key, e.g. ``bitrate`` or ``port``, is passed to the python-can bus).
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
        from acquisition.canopen_url import driver_from_canopen_url

        return driver_from_canopen_url(url, **kwargs)
    raise InputError(f"controller URL {url!r}: scheme must be modbus:// or canopen://")
