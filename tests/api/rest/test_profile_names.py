"""A register profile named in a controller URL sent to the API is a plain file name: a
device, an absolute path or a way out of the folder is refused with 422 at once, and the
refusal quotes no file."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.api.rest.conftest import hdr

EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "modbus-profiles"

V1 = "/api/v1"
BODY = {"name": "p", "transmission_mm_per_rev": 10, "screw_lead_mm": 10, "position_gain_per_s": 20,
        "travel_mm": [0, 500],
        "tasks": [{"name": "c", "profile": "circle", "radius_mm": 50, "feed_mm_min": 1000, "tolerance_um": 20}]}


@pytest.mark.parametrize("profile", ["/dev/zero", "/etc/passwd", "../x", "..%2Fx", "sub/x.toml", "%2Fdev%2Fzero"])
def test_a_profile_path_is_refused(app_env, profile):
    client, _, keys, _ = app_env
    h = hdr(keys["admin"])
    machine_id = client.get(f"{V1}/machines", headers=h).json()[0]["id"]
    r = client.post(f"{V1}/machines/{machine_id}/axes", headers=h,
                    json={**BODY, "controller_url": f"modbus://10.0.0.5:502?profile={profile}"})
    assert r.status_code == 422 and "must be a file name" in r.json()["detail"], r.text
    assert "root:" not in r.text


def test_a_profile_name_that_is_not_there_is_refused_naming_it(app_env):
    client, _, keys, _ = app_env
    h = hdr(keys["admin"])
    machine_id = client.get(f"{V1}/machines", headers=h).json()[0]["id"]
    r = client.post(f"{V1}/machines/{machine_id}/axes", headers=h,
                    json={**BODY, "controller_url": "modbus://10.0.0.5:502?profile=no-such-profile.toml"})
    assert r.status_code == 422 and "no-such-profile.toml" in r.json()["detail"] and "cannot read" in r.text


def test_a_profile_name_is_read_from_the_profiles_folder_not_the_working_directory(app_env, tmp_path,
                                                                                      monkeypatch):
    client, svc, keys, _ = app_env
    h = hdr(keys["admin"])
    machine_id = client.get(f"{V1}/machines", headers=h).json()[0]["id"]
    text = (EXAMPLES / "drive-int32-input-separate.toml").read_text()
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    (cwd / "plc-y.toml").write_text(text)
    monkeypatch.chdir(cwd)  # a file of that name beside the service is not the profiles folder
    url = "modbus://10.0.0.5:502?profile=plc-y.toml"
    r = client.post(f"{V1}/machines/{machine_id}/axes", headers=h, json={**BODY, "controller_url": url})
    assert r.status_code == 422 and "plc-y.toml" in r.json()["detail"], r.text
    folder = svc.settings.profiles_path
    assert folder == svc.settings.data_dir / "profiles"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "plc-y.toml").write_text(text)
    r = client.post(f"{V1}/machines/{machine_id}/axes", headers=h, json={**BODY, "controller_url": url})
    assert r.status_code == 201, r.text
    assert r.json()["controller_url"] == url  # stored as given: the folder is the service's setting


CANOPEN = "canopen://socketcan/can0?node=7&mode=listen-only&trigger=passive"
EDS_EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "canopen" / "mebm-sim-drive.eds"


@pytest.mark.parametrize("eds", ["/dev/zero", "/etc/passwd", "../x.eds", "sub/x.eds", "%2Fetc%2Fpasswd"])
def test_an_eds_path_is_refused_as_a_profile_path_is(app_env, eds):
    client, _, keys, _ = app_env
    h = hdr(keys["admin"])
    machine_id = client.get(f"{V1}/machines", headers=h).json()[0]["id"]
    r = client.post(f"{V1}/machines/{machine_id}/axes", headers=h,
                    json={**BODY, "tasks": [], "controller_url": f"{CANOPEN}&eds={eds}"})
    assert r.status_code == 422 and "eds (=" in r.json()["detail"] and "must be a file name" in r.text, r.text
    assert "root:" not in r.text


def test_an_eds_name_is_read_from_the_profiles_folder(app_env, tmp_path, monkeypatch):
    client, svc, keys, _ = app_env
    h = hdr(keys["admin"])
    machine_id = client.get(f"{V1}/machines", headers=h).json()[0]["id"]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "drive.eds").write_bytes(EDS_EXAMPLE.read_bytes())  # beside the service: not looked at
    url = f"{CANOPEN}&eds=drive.eds"
    r = client.post(f"{V1}/machines/{machine_id}/axes", headers=h, json={**BODY, "tasks": [], "controller_url": url})
    assert r.status_code == 422 and "drive.eds" in r.json()["detail"], r.text
    folder = svc.settings.profiles_path
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "drive.eds").write_bytes(EDS_EXAMPLE.read_bytes())
    r = client.post(f"{V1}/machines/{machine_id}/axes", headers=h, json={**BODY, "tasks": [], "controller_url": url})
    assert r.status_code == 201, r.text
    assert r.json()["controller_url"] == url
