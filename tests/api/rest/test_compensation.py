"""GET /axes/{id}/compensation: the last measurement's raw run as a controller table."""

from __future__ import annotations

import numpy as np

from storage.db import config_repo, session_scope
from tests.api.rest.conftest import hdr
from tests.api.rest.test_api import V1, run_cycle
from tests.api.service.comp_twin import read_linuxcnc


def test_no_measurement_is_404(app_env):
    client, _svc, keys, axis_id = app_env
    r = client.get(f"{V1}/axes/{axis_id}/compensation?format=linuxcnc", headers=hdr(keys["read"]))
    assert r.status_code == 404 and "measurement" in r.json()["detail"]


def test_last_measurement_as_a_linuxcnc_table_then_409_once_its_run_is_gone(app_env):
    client, svc, keys, axis_id = app_env
    cycle = run_cycle(client, svc, keys, axis_id)
    r = client.get(f"{V1}/axes/{axis_id}/compensation?format=linuxcnc&comp_type=1&joint=0",
                   headers=hdr(keys["read"]))
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith("text/plain")
    assert 'filename="vmc-850_' in r.headers["content-disposition"] and r.headers["content-disposition"].endswith(
        '_linuxcnc_type1.comp"')
    assert r.headers["x-measurement-id"] == str(cycle["measurement"]["id"])
    nom, fwd, rev = read_linuxcnc(r.text, 1)
    assert 2 < nom.size <= 256 and np.all(np.diff(nom) > 0)
    # the fake runner's trace: a play of 200 µm and a 2 µm cyclic lead error of period 16 mm
    cyclic = 2.0 * np.sin(2 * np.pi * nom / 16.0)
    assert np.max(np.abs((rev - fwd) - 200.0)) < 0.5
    mid = 0.5 * (fwd + rev) - cyclic
    assert np.ptp(mid) < 0.5  # the table follows the lead error up to one constant (its zero)
    assert "mean backlash b = 200.0" in r.text and "BACKLASH is ignored" in r.text

    # the raw run removed (retention, a hand): nothing to build a table from
    with session_scope(svc.factory) as s:
        folder = svc.executor.dataset_folder(config_repo.get_axis(s, axis_id))
    for f in folder.glob("rt_*.csv*"):
        f.unlink()
    r = client.get(f"{V1}/axes/{axis_id}/compensation?format=csv", headers=hdr(keys["read"]))
    assert r.status_code == 409, r.text
    assert "raw run rt_" in r.json()["detail"] and "no longer in the dataset folder" in r.json()["detail"]
