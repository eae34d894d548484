"""Modbus controller URLs: ``modbus://HOST[:PORT][?mode=trace|latched|separate&device_id=N&profile=FILE.toml]``,
``modbus+rtu:///dev/ttyUSB0[?baudrate=19200&parity=N|E|O&stopbits=1|2&bytesize=8&device_id=N&profile=...]``
and ``sim://HOST[:PORT][?...]`` (mebm's own simulated Modbus controller, ``mebm sim-controller
modbus``). Each also takes the trigger keys of :mod:`acquisition.trigger`.

Reached through :func:`acquisition.url.driver_from_url`, which checks the characters of any URL
and hands it here by its scheme.
"""

from __future__ import annotations

import ipaddress
import re
from urllib.parse import urlsplit

from acquisition.trigger import TRIGGER_KEYS, query_number, query_of, trigger_kwargs
from core.errors import InputError

SCHEMES = ("modbus", "modbus+rtu", "sim")


def driver_from_modbus_url(url: str, **kwargs):
    """A :class:`~acquisition.modbus.driver.ModbusDriver` (mebm-modbus/1) or, with a register
    profile, a :class:`~acquisition.modbus.polled.ProfileModbusDriver` for ``url``; ``kwargs``
    go to the driver (``timeout_s``, ``retries``, ``profile``, ...)."""
    parts = urlsplit(url)
    if parts.scheme not in SCHEMES:
        raise InputError(f"controller URL {url!r}: scheme must be modbus://, modbus+rtu:// or sim://")
    q = query_of(url)
    kwargs = {**trigger_kwargs(url, q), **kwargs}

    def num(key, cast, default):
        return query_number(url, q, key, cast, default)

    from acquisition.modbus.driver import ModbusDriver
    from acquisition.modbus.profile import BUILTIN, RegisterProfile, load_profile

    known = {"device_id", "mode", "profile", *(_SERIAL if parts.scheme == "modbus+rtu" else ())}
    unknown = sorted(set(q) - known)
    if unknown:
        raise InputError(f"controller URL {url!r}: unknown option(s) {unknown} (allowed: {sorted(known | set(TRIGGER_KEYS))})")
    device_id = num("device_id", int, 1)
    if not 0 <= device_id <= 247:
        raise InputError(f"controller URL {url!r}: device_id (={device_id}) must be 0..247")
    if parts.scheme in ("modbus", "sim"):
        if not parts.hostname:
            raise InputError(f"controller URL {url!r} needs a host: {parts.scheme}://HOST:PORT")
        try:
            host, port = parts.hostname, parts.port or 502
        except ValueError:
            raise InputError(f"controller URL {url!r}: the port must be a number 1..65535") from None
        if not _is_host(host):
            raise InputError(f"controller URL {url!r}: {host!r} is neither an IP address nor a host name "
                             "(letters, digits, '-' and '.')")
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
        from acquisition.modbus.polled import ProfileModbusDriver

        if "mode" in q:
            raise InputError(f"controller URL {url!r}: mode= is for mebm-modbus/1; a profile's mode follows "
                             f"its layout ({profile.mode})")
        return ProfileModbusDriver(host, port, profile=profile, device_id=device_id, serial=serial, **kwargs)
    return ModbusDriver(host, port, device_id=device_id, mode=q.get("mode", "trace"), serial=serial, **kwargs)


_SERIAL = ("baudrate", "parity", "stopbits", "bytesize")
_LABEL = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?")


def _is_host(host: str) -> bool:
    """An IP address or a DNS host name (RFC 1123 labels)."""
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        pass
    name = host[:-1] if host.endswith(".") else host
    return 0 < len(name) <= 253 and all(_LABEL.fullmatch(label) for label in name.split("."))
