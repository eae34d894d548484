"""Entry point of the ``mebm`` command."""

from __future__ import annotations

import argparse
import importlib
import sys
from dataclasses import dataclass

from core.errors import MebmError

EXIT_USAGE = 2
EXIT_FAILED = 1


@dataclass(frozen=True)
class CommandGroup:
    """One ``mebm`` command: its module under api.cli (which defines ``register(subparsers)``)
    and the one-line help shown by ``mebm --help`` without importing that module."""

    name: str
    module: str
    help: str


# Every command, registered explicitly: a module renamed or missing is an ImportError the
# first time the command (or the test that builds them all) runs, never a dropped command.
# Modules are imported only for the command being run, so `mebm --help` stays fast.
COMMANDS: tuple[CommandGroup, ...] = (
    CommandGroup("tbe", "api.cli.tbe", "transient backlash error of a task (Eqs. 7-11) and its backlash limit"),
    CommandGroup("analyze", "api.cli.analyze", "backlash b(x) and ISO 3408-3 lead criteria of a dataset's round trips"),
    CommandGroup("demo", "api.cli.demo", "analyse a simulated round trip of the paper's Y axis and give the verdict"),
    CommandGroup("sim", "api.cli.sim", "simulate a feed drive (the digital twin) and write a dataset run"),
    CommandGroup("measure", "api.cli.measure", "measure an axis' backlash and lead criteria on the machine"),
    CommandGroup("sim-controller", "api.cli.sim_controller", "run a simulated Modbus TCP controller, CANopen drive or LinuxCNC machine"),
    CommandGroup("serve", "api.cli.serve",
                 "run the service: REST API, scheduled measurements, simulated demo controller"),
    CommandGroup("keys", "api.cli.keys", "create, list and revoke API keys"),
    CommandGroup("maintenance", "api.cli.maintenance",
                 "work orders, repairs and the maintenance summary of a running service"),
    CommandGroup("gap", "api.cli.gap", "where and why the nominal model misses a machine (sim-to-real gap)"),
    CommandGroup("import", "api.cli.import_trace", "a controller's scope trace (CSV) into a mebm dataset run"),
    CommandGroup("circle", "api.cli.circle", "circular tests (ISO 230-4): measure, import, analyze"),
    CommandGroup("export-comp", "api.cli.export_comp",
                 "a round trip as the controller's compensation table (LinuxCNC, Beckhoff/ISG, CSV)"),
)


def _selected(argv: list[str]) -> str | None:
    """The command named on the command line (the first word that is not an option)."""
    for word in argv:
        if not word.startswith("-"):
            return word
    return None


def build_parser(argv: list[str] | None = None, *, all_commands: bool = True) -> argparse.ArgumentParser:
    """The ``mebm`` parser. With ``all_commands=False`` only the command named in ``argv``
    is imported and fully registered; the others are listed by name and help only."""
    parser = argparse.ArgumentParser(
        prog="mebm",
        description="Manufacturing-error-based maintenance: backlash, lead criteria and TBE of feed drives.",
    )
    parser.add_argument("--debug", action="store_true", help="show a full traceback on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    wanted = None if all_commands else _selected(list(argv or []))
    for cmd in COMMANDS:
        if all_commands or cmd.name == wanted:
            module = importlib.import_module(cmd.module)
            module.register(sub)
            if cmd.name not in sub.choices:
                raise RuntimeError(f"{cmd.module}.register() did not add the command {cmd.name!r}")
        else:
            sub.add_parser(cmd.name, help=cmd.help, add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv, all_commands=False)
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
