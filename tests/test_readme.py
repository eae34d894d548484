"""The README a newcomer follows: its tour works on a fresh `make run` (the ids it uses
exist, the port it tells a user to change is the one `mebm serve` reads, its alert-id
line answers in words before there is an alert and acknowledges the alert once there is
one); it stays short and for users (development detail lives in docs/), explains its
terms through the glossary, and every link it (and the glossary and performance pages)
gives leads to a file and heading that exist."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from api.service.config.loading import load_settings
from tests.waiting import poll

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
LINK = re.compile(r"\]\(([^)\s]+)\)")


def flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def test_the_tour_acknowledges_an_alert_taken_from_the_list_not_a_guessed_id():
    assert not re.search(r"/alerts/\d+/ack", README)
    listing = README.index("/api/v1/alerts?state=active' \\")
    ack = README.index("/api/v1/alerts/$A/ack")
    assert listing < ack and '["items"]' in README[listing:ack]


def test_the_demo_has_the_machine_and_axis_the_tour_names_and_the_port_variable_it_gives():
    demo = load_settings(env={})
    assert [name for name, _ in demo.machines] == ["demo-vmc"] and [(a.machine, a.settings.spec.name) for a in demo.axes] == [("demo-vmc", "y")]
    assert "one machine (`demo-vmc`, id 1) with one axis (`y`, id 1)" in flat(README)
    assert "`MEBM_PORT=8080 make run`" in README
    assert load_settings(env={"MEBM_PORT": "8080"}).port == 8080


def tour_lines() -> str:
    """The tour's key lines and its alert-id and acknowledge lines, as the README gives them."""
    lines = README.splitlines()
    keys = [ln for ln in lines if ln.startswith(("K=$(", "OPERATE=$("))]
    start = next(i for i, ln in enumerate(lines) if ln.startswith("A=$("))
    end = next(i for i in range(start, len(lines)) if lines[i].rstrip().endswith("fi"))
    return "\n".join(keys + lines[start:end + 1]) + "\n"


@pytest.fixture
def service(tmp_path):
    from tests.api.ui.conftest import UiServer

    if shutil.which("curl") is None:  # the README's tour is curl's
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("curl is not installed; CI=true requires the README's tour")
        pytest.skip("curl is not installed (apt-get install curl)")

    srv = UiServer(tmp_path / "service")
    yield srv
    srv.close()


def run_tour(srv, cwd: Path) -> subprocess.CompletedProcess:
    script = tour_lines().replace("http://127.0.0.1:8000", srv.url)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    return subprocess.run(["bash", "-c", script], cwd=cwd, env=env, capture_output=True, text=True, timeout=60)


def test_the_alert_id_line_says_there_is_no_alert_yet_then_acknowledges_the_one_the_alarm_raised(service, tmp_path):
    from storage.db import results_repo, session_scope

    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "demo-keys.json").write_text(
        json.dumps({"read": service.keys["read"], "operate": service.keys["operate"]}), encoding="utf-8")
    before = run_tour(service, tmp_path)
    assert before.returncode == 0 and "Traceback" not in before.stderr, before.stderr
    assert "no active alert yet" in before.stdout

    service.measure(200.0)
    service.measure(250.0)  # past the limit: ALARM, an active alert
    after = run_tour(service, tmp_path)
    assert after.returncode == 0 and "no active alert yet" not in after.stdout, after.stderr
    answer = json.loads(after.stdout)

    def acknowledged():
        with session_scope(service.svc.factory) as s:
            _, alerts = results_repo.list_alerts(s, "active")
        return [(a.id, a.acknowledged_by) for a in alerts]

    assert poll(lambda: acknowledged() == [(answer["id"], "ui-operate")], 10.0), acknowledged()


def test_the_readme_is_short_and_for_users():
    assert len(README.splitlines()) <= 250
    for pattern, what in ((r"(?i)\bseeds? \d+", "a tuning or benchmark seed"), (r"(?i)busy loops", "the suite's load test"),
                          (r"\btests/", "a test path"), (r"storage\.db", "a storage internal")):
        found = re.findall(pattern, README)
        assert not found, f"{what} in the README ({found}): it belongs in docs/"


def test_the_readme_links_the_glossary_and_cites_the_paper_by_title():
    assert "(docs/glossary.md)" in README
    assert "*Manufacturing-error-based maintenance for high-precision machine tools*" in flat(README)
    glossary = (ROOT / "docs" / "glossary.md").read_text(encoding="utf-8")
    for term in ("Guard band", "k = 2", "Utility day", "Digital twin", "TPDO", "SYNC", "EDS/DCF", "CiA 402", "HAL",
                 "halsampler", "e_p", "v_u", "v_300", "v_2π", "GUM", "EN 13306"):
        assert term.lower() in glossary.lower(), term


def slug(heading: str) -> str:
    """A heading's anchor as GitHub makes it."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


@pytest.mark.parametrize("doc", ["README.md", "docs/glossary.md", "docs/performance.md"])
def test_every_relative_link_leads_to_a_file_and_heading_that_exist(doc):
    path = ROOT / doc
    for target in LINK.findall(path.read_text(encoding="utf-8")):
        if re.match(r"[a-z]+:", target):
            continue
        file, _, anchor = target.partition("#")
        dest = (path.parent / file).resolve() if file else path
        assert dest.exists(), f"{doc}: {target}"
        if anchor:
            headings = re.findall(r"^#+ (.+)$", dest.read_text(encoding="utf-8"), flags=re.M)
            assert anchor in {slug(h) for h in headings}, f"{doc}: {target}"
