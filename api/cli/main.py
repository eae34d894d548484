"""Entry point of the ``mebm`` command."""

from __future__ import annotations

import argparse
import importlib
import sys

from core.errors import MebmError

# Command-group modules under api.cli; each defines register(subparsers).
COMMAND_MODULES = ("tbe", "analyze", "demo", "sim", "measure", "sim_controller", "serve", "keys", "gap")

EXIT_USAGE = 2
EXIT_FAILED = 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mebm",
        description="Manufacturing-error-based maintenance: backlash, lead criteria and TBE of feed drives.",
    )
    parser.add_argument("--debug", action="store_true", help="show a full traceback on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"api.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"api.cli.{name}":
                continue  # command group not built yet
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = args.func(args)
    except MebmError as exc:
        if args.debug:
            raise
        print(f"mebm {args.command}: error: {exc}", file=sys.stderr)
        return getattr(exc, "exit_code", EXIT_FAILED)
    except BrokenPipeError:  # output piped into `head` and closed: not an error of ours
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print(f"mebm {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - last line of defence: one line, not a traceback
        if args.debug:
            raise
        print(
            f"mebm {args.command}: internal error: {type(exc).__name__}: {exc} (run with --debug for the traceback)",
            file=sys.stderr,
        )
        return EXIT_FAILED
    return int(code or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
