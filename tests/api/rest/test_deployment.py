"""docker-compose.yml and the Dockerfile cannot be run here (no container engine):
parse them and check every service's image build context, Dockerfile, command and
configuration exist and make sense."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from api.cli.main import build_parser
from api.service.config.loading import apply_env, parse_settings

yaml = pytest.importorskip("yaml")
ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def compose():
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def test_every_service_has_an_image_or_a_build_context(compose):
    assert set(compose["services"]) == {"db", "simulator", "mebm", "mebm-2"}
    for name, svc in compose["services"].items():
        if "build" in svc:
            ctx = ROOT / svc["build"]["context"]
            assert ctx.is_dir(), name
            assert (ctx / svc["build"].get("dockerfile", "Dockerfile")).is_file(), name
        else:
            assert svc["image"].startswith("postgres:"), name


def test_commands_are_real_mebm_commands(compose):
    parser = build_parser()
    for name in ("simulator", "mebm", "mebm-2"):
        cmd = compose["services"][name]["command"]
        assert cmd[0] == "mebm"
        args = parser.parse_args(cmd[1:])  # raises SystemExit on an unknown command or option
        assert callable(args.func), name


def test_dockerfile_copies_what_the_service_needs_and_runs_mebm_serve():
    text = (ROOT / "Dockerfile").read_text()
    for path in ("core", "acquisition", "storage", "api", "pyproject.toml", "alembic.ini"):
        assert f"COPY {path}" in text or f" {path} " in text, path
        assert (ROOT / path).exists(), path
    cmd = [ln for ln in text.splitlines() if ln.startswith("CMD")][-1]
    assert "serve" in cmd and "/healthz" in text


def test_service_config_parses_and_points_at_the_simulator_container(compose):
    content = compose["configs"]["mebm_config"]["content"]
    settings = parse_settings(tomllib.loads(content))
    (axis,) = settings.axes
    assert axis.settings.controller_url == "sim://simulator:5020"
    sim_cmd = compose["services"]["simulator"]["command"]
    assert sim_cmd[sim_cmd.index("--port") + 1] == "5020"
    env = compose["services"]["mebm"]["environment"]
    assert env["MEBM_DATABASE_URL"].startswith("postgresql://") and "@db:5432/" in env["MEBM_DATABASE_URL"]
    assert compose["services"]["mebm"]["depends_on"]["db"]["condition"] == "service_healthy"


def test_two_workers_share_the_database_under_their_own_names(compose):
    """docs/fleet.md: a fleet of two workers on the one PostgreSQL database."""
    one, two = (compose["services"][n] for n in ("mebm", "mebm-2"))
    assert one["environment"]["MEBM_DATABASE_URL"] == two["environment"]["MEBM_DATABASE_URL"]
    assert one["environment"]["MEBM_WORKER_NAME"] != two["environment"]["MEBM_WORKER_NAME"]
    assert one["volumes"] != two["volumes"]  # each worker its own data folder (raw runs, spool)
    assert two["depends_on"]["db"]["condition"] == "service_healthy"
    env = {k: str(v) for k, v in two["environment"].items()}
    assert apply_env(parse_settings({}), env).worker.lease_s == 30.0


def test_every_service_has_a_health_check_of_its_own(compose):
    services = compose["services"]
    for name, svc in services.items():
        assert "healthcheck" in svc, name
    sim = " ".join(services["simulator"]["healthcheck"]["test"])
    assert "/healthz" not in sim and "5020" in sim  # the simulator serves Modbus, not the REST API
    assert "/healthz" in " ".join(services["mebm"]["healthcheck"]["test"])


def test_dockerfile_installs_dependencies_before_copying_the_code():
    lines = (ROOT / "Dockerfile").read_text().splitlines()
    first_code = min(i for i, ln in enumerate(lines) if ln.startswith(("COPY core", "COPY api")))
    deps = next(i for i, ln in enumerate(lines) if "pip install -r" in ln)
    assert deps < first_code
    ignored = (ROOT / ".dockerignore").read_text().split()
    assert ".venv" in ignored and ".git" in ignored
