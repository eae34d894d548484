"""The axis page renders the sections other features register (api/ui/panels.py)."""

from __future__ import annotations

import re

from fastapi.testclient import TestClient

from api.rest import create_app
from api.ui import panels
from api.ui.routes import templates
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, make_settings


def test_a_registered_panel_is_on_the_axis_page(tmp_path, monkeypatch):
    from jinja2 import ChoiceLoader, DictLoader

    monkeypatch.setattr(panels, "AXIS_PANELS", [])
    monkeypatch.setattr(templates.env, "loader", ChoiceLoader([
        templates.env.loader, DictLoader({"_axis_test.html": '<section id="p">{{ panel.n }} for {{ axis.name }}, '
                                                               '{{ who.key.role }}</section>'})]))
    panels.register_axis_panel(panels.AxisPanel(
        "_axis_test.html", lambda svc, s, axis_id: {"n": len(config_repo.get_axis(s, axis_id).tasks)}))
    app = create_app(make_settings(f"sqlite:///{tmp_path}/m.sqlite3", tmp_path, scheduler_enabled=False),
                     runner=FakeRunner())
    with TestClient(app) as c:
        with session_scope(app.state.service.factory) as s:
            _, secret = config_repo.create_key(s, "r", "read")
            axis = config_repo.list_axes(s)[0]
        form = c.get("/ui/sign-in")
        csrf = re.search(r'name="csrf" value="([^"]+)"', form.text).group(1)
        assert c.post("/ui/sign-in", data={"key": secret, "csrf": csrf}).status_code == 200
        html = c.get(f"/ui/axes/{axis.id}").text
    assert f'<section id="p">{len(axis.tasks)} for {axis.name}, read</section>' in html
