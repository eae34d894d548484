"""The README's tour works on a fresh `make run`: the ids it uses exist, the port it
tells a user to change is the one `mebm serve` reads."""

from __future__ import annotations

import re
from pathlib import Path

from api.service.config.loading import load_settings

README = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")


def test_the_tour_acknowledges_an_alert_taken_from_the_list_not_a_guessed_id():
    assert not re.search(r"/alerts/\d+/ack", README)
    listing = README.index("/api/v1/alerts?state=active' \\")
    ack = README.index("/api/v1/alerts/$A/ack")
    assert listing < ack and '["items"][0]["id"]' in README[listing:ack]


def test_the_demo_has_the_machine_and_axis_the_tour_names_and_the_port_variable_it_gives():
    demo = load_settings(env={})
    assert [name for name, _ in demo.machines] == ["demo-vmc"] and [(a.machine, a.settings.spec.name) for a in demo.axes] == [("demo-vmc", "y")]
    assert "one machine (`demo-vmc`, id 1) with one\naxis (`y`, id 1)" in README
    assert "`MEBM_PORT=8080 make run`" in README
    assert load_settings(env={"MEBM_PORT": "8080"}).port == 8080
