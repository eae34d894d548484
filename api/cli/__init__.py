"""The ``mebm`` command line. Each command group lives in its own module and
registers itself through ``register(subparsers)``; ``main`` maps every
:class:`core.errors.MebmError` to one clear line and a non-zero exit code."""

from api.cli.main import main

__all__ = ["main"]
