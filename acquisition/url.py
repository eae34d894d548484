"""Controller URLs: which wire package makes the driver for a URL's scheme.

A table of schemes, as python-can keeps one of its bus backends: each scheme names the
module of its wire package that parses its own URLs and the function that makes the
driver. The module is imported only when a URL of its scheme is opened, so ``mebm --help``
loads no wire library and no wire package imports another.

- ``modbus://``, ``modbus+rtu://``, ``sim://`` (mebm's own simulated Modbus controller,
  ``mebm sim-controller modbus``): :mod:`acquisition.modbus.url`;
- ``canopen://INTERFACE/CHANNEL?node=N[&mode=listen-only|active-cia402|active-mebm&...]``:
  :mod:`acquisition.canopen.url` (any other query key, e.g. ``bitrate`` or ``port``, is
  passed to the python-can bus);
- ``linuxcnc://HOST[:PORT]?joint=N&motor_pin=PIN&scale_pin=PIN``: :mod:`acquisition.linuxcnc.url`.

A new wire is a package under ``acquisition/`` with a ``url`` module, and one row here.

Every scheme also takes who starts the round trip, ``trigger=active|passive`` (docs/controllers.md,
"Passive and active round trips"), and for passive mode ``running_flag=0|1`` and the detection
settings (``start_timeout_s``, ``max_duration_s``, ``rest_band_mm``, ``rest_s``, ``min_stroke_mm``,
``return_tolerance_mm``, ``pre_roll_s``, ``flag_margin_s``): :mod:`acquisition.trigger`, shared
by every scheme's parser. Without ``trigger`` a simulator (``sim://``, or CANopen on python-can's
in-process ``virtual`` bus) is active and any other controller passive: mebm moves an axis only
where it was told to, or where nothing can move.
"""

from __future__ import annotations

import importlib
from urllib.parse import urlsplit

from core.errors import InputError

# scheme -> (module, function): the function takes the URL and the driver's keyword arguments
SCHEMES: dict[str, tuple[str, str]] = {
    "modbus": ("acquisition.modbus.url", "driver_from_modbus_url"),
    "modbus+rtu": ("acquisition.modbus.url", "driver_from_modbus_url"),
    "sim": ("acquisition.modbus.url", "driver_from_modbus_url"),
    "canopen": ("acquisition.canopen.url", "driver_from_canopen_url"),
    "linuxcnc": ("acquisition.linuxcnc.url", "driver_from_linuxcnc_url"),
}


def driver_from_url(url: str, **kwargs):
    """A :class:`~acquisition.driver.base.ControllerDriver` for ``url``; ``kwargs`` go to the driver
    (``timeout_s``, ``retries``, ...)."""
    bad = next((c for c in url if c.isspace() or ord(c) < 32 or ord(c) == 127), None)
    if bad is not None:
        raise InputError(f"controller URL {url!r}: contains {'a space' if bad == ' ' else repr(bad)}; "
                         "percent-encode it (%20) or remove it")
    scheme = urlsplit(url).scheme
    if scheme not in SCHEMES:
        names = [f"{s}://" for s in SCHEMES]
        raise InputError(f"controller URL {url!r}: scheme must be {', '.join(names[:-1])} or {names[-1]}")
    module, function = SCHEMES[scheme]
    return getattr(importlib.import_module(module), function)(url, **kwargs)
