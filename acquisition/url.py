"""Controller URLs: ``modbus://HOST[:PORT][?mode=trace|latched|separate&device_id=N&profile=FILE.toml]``,
``modbus+rtu:///dev/ttyUSB0[?baudrate=19200&parity=N|E|O&stopbits=1|2&bytesize=8&device_id=N&profile=...]`` and
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

    if parts.scheme in ("modbus", "modbus+rtu"):
        from acquisition.modbus import ModbusDriver
        from acquisition.modbus_profile import BUILTIN, RegisterProfile, load_profile

        known = {"device_id", "mode", "profile", *(_SERIAL if parts.scheme == "modbus+rtu" else ())}
        unknown = sorted(set(q) - known)
        if unknown:
            raise InputError(f"controller URL {url!r}: unknown option(s) {unknown} (allowed: {sorted(known)})")
        device_id = num("device_id", int, 1)
        if not 0 <= device_id <= 247:
            raise InputError(f"controller URL {url!r}: device_id (={device_id}) must be 0..247")
        if parts.scheme == "modbus":
            if not parts.hostname:
                raise InputError(f"controller URL {url!r} needs a host: modbus://HOST:PORT")
            try:
                host, port = parts.hostname, parts.port or 502
            except ValueError:
                raise InputError(f"controller URL {url!r}: the port must be a number 1..65535") from None
            serial = None
        else:
            host, port = parts.path, 0
            if parts.netloc or not host.startswith("/"):
                raise InputError(f"controller URL {url!r} must be modbus+rtu:///dev/DEVICE?baudrate=...")
            serial = dict(baudrate=num("baudrate", int, 19200), parity=q.get("parity", "N").upper(),
                          stopbits=num("stopbits", int, 1), bytesize=num("bytesize", int, 8))
            if serial["parity"] not in ("N", "E", "O"):
                raise InputError(f"controller URL {url!r}: parity (={q['parity']!r}) must be N, E or O")
            if serial["stopbits"] not in (1, 2) or serial["bytesize"] not in (7, 8) or serial["baudrate"] <= 0:
                raise InputError(f"controller URL {url!r}: stopbits must be 1 or 2, bytesize 7 or 8, baudrate > 0")
        profile = kwargs.pop("profile", None) or q.get("profile", BUILTIN)
        if isinstance(profile, str) and profile != BUILTIN:
            profile = load_profile(profile)
        if isinstance(profile, RegisterProfile):
            from acquisition.modbus_polled import ProfileModbusDriver

            if "mode" in q:
                raise InputError(f"controller URL {url!r}: mode= is for mebm-modbus/1; a profile's mode follows "
                                 f"its layout ({profile.mode})")
            return ProfileModbusDriver(host, port, profile=profile, device_id=device_id, serial=serial, **kwargs)
        return ModbusDriver(host, port, device_id=device_id, mode=q.get("mode", "trace"), serial=serial, **kwargs)
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
    raise InputError(f"controller URL {url!r}: scheme must be modbus://, modbus+rtu:// or canopen://")


_SERIAL = ("baudrate", "parity", "stopbits", "bytesize")
