"""What a controller URL says of how a cycle starts: active (mebm starts the round trip) or
passive (mebm waits for the CNC's own program), and the passive settings.

Shared by every URL scheme's parser (:mod:`acquisition.modbus.url`, :mod:`acquisition.canopen.url`,
:mod:`acquisition.linuxcnc.url`), so none imports another for it; so are :func:`query_of`, the
one reading of a URL's query, and :func:`query_number`.
"""

from __future__ import annotations

from urllib.parse import parse_qs, urlsplit

from core.errors import InputError

PASSIVE_KEYS = ("start_timeout_s", "max_duration_s", "rest_band_mm", "rest_s", "min_stroke_mm",
                "return_tolerance_mm", "pre_roll_s", "flag_margin_s")
TRIGGER_KEYS = ("trigger", "running_flag", *PASSIVE_KEYS)


def query_of(url: str) -> dict[str, str]:
    """A controller URL's query, one value per key: the last one given (keys without a value
    are left out), as every scheme's parser and the configuration read it."""
    return {k: v[-1] for k, v in parse_qs(urlsplit(url).query).items()}


def query_number(url: str, q: dict[str, str], key: str, cast: type, default):
    """The query's ``key`` as ``cast`` (``int`` or ``float``), ``default`` when it is not
    given; an :class:`~core.errors.InputError` naming the URL and the key when it is no number."""
    if key not in q:
        return default
    try:
        return cast(q[key])
    except ValueError:
        kind = "an integer" if cast is int else "a number"
        raise InputError(f"controller URL {url!r}: {key} (={q[key]!r}) must be {kind}") from None


def is_simulator_url(url: str) -> bool:
    """A controller that can only be a simulation: ``sim://``, or CANopen on the in-process bus."""
    return urlsplit(url).scheme == "sim" or needs_callers_process(url)


def needs_callers_process(url: str) -> bool:
    """A controller reachable only from the process that created it: CANopen on python-can's
    in-process ``virtual`` bus (a cycle on it cannot run in a worker process)."""
    parts = urlsplit(url)
    return parts.scheme == "canopen" and parts.netloc == "virtual"


def default_trigger(url: str) -> str:
    """``active`` for a simulator, ``passive`` for any other controller."""
    return "active" if is_simulator_url(url) else "passive"


def trigger_kwargs(url: str, q: dict[str, str]) -> dict:
    """The driver's ``trigger``/``running_flag``/``passive`` arguments from the URL's query."""
    trigger = q.pop("trigger", None) or default_trigger(url)
    if trigger not in ("active", "passive"):
        raise InputError(f"controller URL {url!r}: trigger (={trigger!r}) must be active or passive")
    out: dict = {"trigger": trigger}
    if "running_flag" in q:
        flag = q.pop("running_flag").lower()
        if flag not in ("0", "1", "true", "false", "yes", "no", "on", "off"):
            raise InputError(f"controller URL {url!r}: running_flag (={flag!r}) must be 0 or 1")
        out["running_flag"] = flag in ("1", "true", "yes", "on")
    passive = {}
    for key in PASSIVE_KEYS:
        if key in q:
            raw = q.pop(key)
            try:
                passive[key] = float(raw)
            except ValueError:
                raise InputError(f"controller URL {url!r}: {key} (={raw!r}) must be a number") from None
    if passive:
        if trigger != "passive":
            raise InputError(f"controller URL {url!r}: {sorted(passive)} apply to trigger=passive only")
        out["passive"] = passive
    return out
