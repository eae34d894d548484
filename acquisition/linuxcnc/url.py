"""``linuxcnc://HOST[:PORT]?joint=N&motor_pin=PIN&scale_pin=PIN[&...]``: the LinuxCNC driver.

HOST:PORT is linuxcncrsh (default port 5007); the HAL is this computer's (halcmd,
halsampler), so mebm runs on the LinuxCNC computer. Keys:

- ``joint`` (default 0): the measured joint; ``axis`` its coordinate letter (trivkins:
  X, Y, Z... by joint number), for the active round trip's G-code;
- ``motor_pin``, ``scale_pin`` (required): the HAL pins of the motor-side feedback and
  of the linear scale; ``command_pin`` (default ``joint.N.pos-cmd``): the commanded
  position. The sampler must record them in that order (docs/controllers.md);
- ``sampler`` (default 0): the sampler's FIFO number (``halsampler -c``);
- ``motor_units``: ``mm`` (default: the motor encoder in joint units) or ``rev``;
- ``program_dir``: where an active round trip's ``.ngc`` is written;
- ``trigger`` (default passive) and the passive detection keys (:mod:`acquisition.trigger`).
"""

from __future__ import annotations

from urllib.parse import urlsplit

from acquisition.trigger import TRIGGER_KEYS, query_number, query_of, trigger_kwargs
from core.errors import InputError

KEYS = ("joint", "axis", "motor_pin", "scale_pin", "command_pin", "sampler", "motor_units", "program_dir")


def driver_from_linuxcnc_url(url: str, **kwargs):
    """A :class:`~acquisition.linuxcnc.driver.LinuxcncDriver` for ``url``; ``kwargs`` go to
    the driver (``timeout_s``, ``retries``, ...) and win over the URL."""
    from acquisition.linuxcnc.driver import LinuxcncDriver

    parts = urlsplit(url)
    if parts.scheme != "linuxcnc":
        raise InputError(f"controller URL {url!r}: scheme must be linuxcnc://")
    q = query_of(url)
    kwargs = {**trigger_kwargs(url, q), **kwargs}
    unknown = sorted(set(q) - set(KEYS))
    if unknown:
        raise InputError(f"controller URL {url!r}: unknown option(s) {unknown} (allowed: "
                         f"{sorted(set(KEYS) | set(TRIGGER_KEYS))})")
    if not parts.hostname:
        raise InputError(f"controller URL {url!r} needs a host: linuxcnc://HOST:PORT (linuxcncrsh)")
    try:
        port = parts.port or 5007
    except ValueError:
        raise InputError(f"controller URL {url!r}: the port must be a number 1..65535") from None
    for key in ("motor_pin", "scale_pin"):
        if not q.get(key):
            raise InputError(f"controller URL {url!r}: {key}= is required (the HAL pin the sampler records; "
                             "docs/controllers.md)")

    def integer(key: str, default: int) -> int:
        return query_number(url, q, key, int, default)

    return LinuxcncDriver(parts.hostname, port, joint=integer("joint", 0), motor_pin=q["motor_pin"],
                          scale_pin=q["scale_pin"], command_pin=q.get("command_pin") or None,
                          sampler=integer("sampler", 0), motor_units=q.get("motor_units", "mm"),
                          axis_letter=q.get("axis") or None, program_dir=q.get("program_dir") or None, **kwargs)
