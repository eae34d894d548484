"""One exception tree for the whole product.

Every error a user can cause or meet derives from :class:`MebmError`; stdlib
co-bases let callers catch them the usual way (``ValueError``, ``TimeoutError``).
Layers above core subclass these; only ``api/`` maps them to HTTP codes.
"""

from __future__ import annotations


class MebmError(Exception):
    """Root of every error raised by mebm."""


class InputError(MebmError, ValueError):
    """A value given to mebm is invalid (out of range, NaN, wrong shape)."""


class DatasetError(InputError):
    """A dataset (folder, dataset.json or run CSV) is malformed.

    ``source`` names the file (and row where known) so a technician can open it.
    """

    def __init__(self, message: str, *, source: str | None = None, row: int | None = None):
        self.source = source
        self.row = row
        where = ""
        if source is not None:
            where = f"{source}" + (f", row {row}" if row is not None else "") + ": "
        super().__init__(where + message)


class TraceError(InputError):
    """A measured round trip cannot be analysed (single stroke, motor still, too short...)."""


class OutlierError(TraceError):
    """Too many samples of a trace are glitches to clean them away (a faulty encoder?)."""


class ModelDomainError(InputError):
    """A question the model cannot answer (tolerance unreachable, outside validity)."""


class NotFittedError(MebmError, RuntimeError):
    """An estimator was used before ``fit()``."""


def _number(name: str, value) -> float:
    if isinstance(value, (str, bytes)) or value is None:
        raise InputError(f"{name} (={value!r}) must be a number")
    try:
        return float(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} (={value!r}) must be a number") from exc


def require_positive(name: str, value: float) -> float:
    """Return ``value`` as float, or raise :class:`InputError` naming it."""
    v = _number(name, value)
    if not v > 0 or v != v or v == float("inf"):
        raise InputError(f"{name} (={value}) must be a finite number > 0")
    return v


def require_finite(name: str, value: float) -> float:
    v = _number(name, value)
    if v != v or v in (float("inf"), float("-inf")):
        raise InputError(f"{name} (={value}) must be finite")
    return v
