"""The ``mebm`` entry point: every command registered explicitly, imported only when run."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from api.cli.main import COMMANDS, build_parser, main


def test_every_listed_command_registers_itself_with_the_listed_help():
    parser = build_parser()  # imports every command module: a renamed one fails here
    sub = next(a for a in parser._actions if a.dest == "command")
    helps = {a.dest: a.help for a in sub._choices_actions}
    assert list(sub.choices) == [c.name for c in COMMANDS]
    for cmd in COMMANDS:
        assert helps[cmd.name] == cmd.help, cmd.name  # `mebm --help` shows what the module says


def test_help_imports_no_command_module():
    code = ("import sys, json\nfrom api.cli.main import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith(('api.cli.', 'numpy', 'scipy')))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    loaded = json.loads(out.strip().splitlines()[-1])
    assert loaded == ["api.cli.main"]


def test_running_one_command_imports_only_that_command():
    code = ("import sys, json\nfrom api.cli.main import main\ntry:\n    main(['tbe', '--help'])\n"
            "except SystemExit:\n    pass\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('api.cli.'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    loaded = set(json.loads(out.strip().splitlines()[-1]))
    assert "api.cli.tbe" in loaded
    assert not loaded & {c.module for c in COMMANDS if c.name != "tbe"}


def test_an_unknown_command_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["no-such-command"])
    assert exc.value.code == 2 and "invalid choice" in capsys.readouterr().err


def test_every_router_module_is_mounted():
    import pkgutil

    from api.rest.app import ROUTERS
    from api.rest.routers import __path__ as routers_path

    modules = {m.name for m in pkgutil.iter_modules(routers_path)} - {"health"}
    assert {r.__name__.rsplit(".", 1)[-1] for r in ROUTERS} == modules
