"""The layering `api -> acquisition | storage -> core` is a checked fact (import-linter)."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("core", "acquisition", "storage", "api")


def _lint(cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; lint_imports_command()",
         "--no-cache"],
        cwd=cwd, capture_output=True, text=True, timeout=120, env={"PYTHONPATH": str(cwd), "PATH": "/usr/bin:/bin"},
    )


def test_contracts_are_kept():
    res = _lint(ROOT)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "0 broken" in res.stdout


def _copy_tree(tmp_path: Path) -> Path:
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    return tmp_path


def test_core_importing_a_database_library_breaks_the_contract(tmp_path):
    tree = _copy_tree(tmp_path)
    with open(tree / "core" / "kinematics.py", "a") as fh:
        fh.write("\nimport sqlite3  # noqa\n")
    res = _lint(tree)
    assert res.returncode != 0
    assert "core is pure numerics" in res.stdout and "BROKEN" in res.stdout


def test_storage_importing_acquisition_breaks_the_contract(tmp_path):
    tree = _copy_tree(tmp_path)
    with open(tree / "storage" / "dataset.py", "a") as fh:
        fh.write("\nimport acquisition  # noqa\n")
    res = _lint(tree)
    assert res.returncode != 0
    assert "BROKEN" in res.stdout


def test_mtconnect_importing_rest_or_mqtt_breaks_the_contracts(tmp_path):
    tree = _copy_tree(tmp_path)
    with open(tree / "api" / "mtconnect" / "model.py", "a") as fh:
        fh.write("\nimport api.rest.convert  # noqa\nimport api.mqtt  # noqa\n")
    res = _lint(tree)
    assert res.returncode != 0
    assert "Event interfaces (MQTT, webhooks, OPC UA, MTConnect) do not import each other BROKEN" in res.stdout
    assert "Event interfaces depend on the service, not on REST or the CLI BROKEN" in res.stdout
