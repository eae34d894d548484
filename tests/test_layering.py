"""The layering `api -> acquisition | storage -> core` is a checked fact (import-linter), and
every module imports on its own, whatever was imported before it (no import cycle)."""

import random
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


def _lint_with(tmp_path: Path, module: str, line: str) -> subprocess.CompletedProcess:
    """import-linter on a copy of the tree in which ``module`` (a path) ends with ``line``."""
    tree = _copy_tree(tmp_path)
    (tree / module).write_text((tree / module).read_text() + f"\n{line}  # noqa\n")
    return _lint(tree)


def test_a_wire_package_importing_another_breaks_the_contract(tmp_path):
    res = _lint_with(tmp_path, "acquisition/modbus/register_map.py", "import acquisition.canopen.objects")
    assert res.returncode != 0 and "Wire packages (Modbus, CANopen, LinuxCNC) do not import each other BROKEN" in res.stdout


def _modules() -> list[str]:
    """Every module of the four packages, but ``__main__`` (it runs the CLI) and the
    migration scripts (alembic runs them, with its own context)."""
    out = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
            if rel.name == "__main__" or parts[:2] == ("storage", "migrations"):
                continue
            out.append(".".join(parts))
    return out


def test_every_module_imports_in_a_fresh_interpreter_in_any_order():
    modules = _modules()
    assert "acquisition.modbus.driver" in modules and "api.service.config.settings" in modules
    code = "import importlib, sys\nfor m in sys.argv[1:]:\n    importlib.import_module(m)\n"
    procs = []
    for seed in (1, 2):  # two orders, each in its own interpreter, at once
        order = modules[:]
        random.Random(seed).shuffle(order)
        procs.append(subprocess.Popen([sys.executable, "-c", code, *order], cwd=ROOT, stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True))
    for p in procs:
        _, err = p.communicate(timeout=120)
        assert p.returncode == 0, err[-2000:]


def _private_imports(root: Path) -> list[str]:
    """Every ``from X import _name`` of a project module, in the product, tests and benchmarks:
    what another module uses is public and says what it is."""
    import ast

    out = []
    for pkg in (*PACKAGES, "tests", "benchmarks"):
        for path in sorted((root / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                        and node.module.split(".")[0] in (*PACKAGES, "tests"):
                    out += [f"{path.relative_to(root)}:{node.lineno} {node.module}.{a.name}" for a in node.names
                            if a.name.startswith("_") and not a.name.startswith("__")]
    return out


def test_no_private_name_is_imported_across_modules(tmp_path):
    assert _private_imports(ROOT) == []
    # and the check sees one when there is one
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_x.py").write_text("from core.gap.diagnose import _hidden\n")
    assert _private_imports(tmp_path) == ["tests/test_x.py:1 core.gap.diagnose._hidden"]


def _import_circles(graph, package: str) -> list[list[str]]:
    """Every import circle among the modules of ``package`` (strongly connected components
    of two modules or more, Tarjan's), each sorted."""
    modules = sorted(m for m in graph.modules if m == package or m.startswith(package + "."))
    inside = set(modules)
    edges = {m: sorted(graph.find_modules_directly_imported_by(m) & inside) for m in modules}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for m in modules:
        if m not in index:
            visit(m)
    return circles


def test_the_service_has_no_import_circle():
    import grimp

    graph = grimp.build_graph("api", cache_dir=None)
    assert _import_circles(graph, "api.service") == []
    # and the check sees one when there is one: the configuration importing the scheduler again
    graph.add_import(importer="api.service.config.input", imported="api.service.cycles.scheduler")
    circles = _import_circles(graph, "api.service")
    assert len(circles) == 1 and {"api.service.config.input", "api.service.cycles.scheduler"} <= set(circles[0])
