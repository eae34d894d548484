"""A register profile named in a controller URL (``profile=NAME``) is read from the
service's profiles folder: the URL the drivers get, the cycle's and the check's alike."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from api.service.config.loading import load_settings
from api.service.config.input import resolve_profile
from api.service.cycles.runner import DriverRunner
from core.errors import InputError

FOLDER = Path("/srv/mebm/profiles")


@pytest.mark.parametrize("url, expected", [
    ("modbus://10.0.0.5:502?profile=plc-y.toml&mode=trace", "modbus://10.0.0.5:502?profile=/srv/mebm/profiles/plc-y.toml&mode=trace"),
    ("modbus+rtu:///dev/ttyUSB0?baudrate=38400&parity=E&profile=a.toml",
     "modbus+rtu:///dev/ttyUSB0?baudrate=38400&parity=E&profile=/srv/mebm/profiles/a.toml"),
    ("modbus://h:502?profile=/etc/mebm/x.toml", "modbus://h:502?profile=/etc/mebm/x.toml"),  # the config file's path
    ("modbus://h:502?profile=mebm-modbus/1", "modbus://h:502?profile=mebm-modbus/1"),  # the built-in map
    ("modbus://h:502", "modbus://h:502"),
    ("canopen://socketcan/can0?node=3", "canopen://socketcan/can0?node=3"),
])  # fmt: skip
def test_a_bare_profile_name_is_resolved_in_the_profiles_folder(url, expected):
    assert resolve_profile(url, FOLDER) == expected


def test_the_cycle_opens_the_profile_in_the_folder():
    seen = []

    def factory(url):
        seen.append(url)
        raise InputError("no controller here")

    out = DriverRunner(factory, profiles_dir=FOLDER)(SimpleNamespace(id=1, settings=None), "modbus://h?profile=p.toml")
    assert seen == ["modbus://h?profile=/srv/mebm/profiles/p.toml"]
    assert not out.ok and "no controller here" in out.reason


def test_the_folder_is_a_setting_under_storage(tmp_path):
    cfg = tmp_path / "mebm.toml"
    cfg.write_text(f'[storage]\ndata_dir = "{tmp_path / "d"}"\n')
    assert load_settings(cfg, env={}).profiles_path == tmp_path / "d" / "profiles"
    cfg.write_text(f'[storage]\ndata_dir = "{tmp_path / "d"}"\nprofiles_dir = "{tmp_path / "p"}"\n')
    assert load_settings(cfg, env={}).profiles_path == tmp_path / "p"


def test_a_profile_named_in_the_configuration_file_is_the_operators_path(tmp_path, monkeypatch):
    profile = Path(__file__).resolve().parents[4] / "examples" / "modbus-profiles" / "drive-int32-input-separate.toml"
    (tmp_path / "plc-y.toml").write_text(profile.read_text())
    monkeypatch.chdir(tmp_path)  # where the service is started
    cfg = tmp_path / "mebm.toml"
    cfg.write_text(f'[storage]\ndata_dir = "{tmp_path / "d"}"\n[[machines]]\nname = "m"\n[[machines.axes]]\n'
                   'name = "y"\ntransmission_mm_per_rev = 10\nscrew_lead_mm = 10\nposition_gain_per_s = 20\n'
                   'travel_mm = [0, 500]\ncontroller = "modbus://10.0.0.5:502?profile=plc-y.toml"\n')
    (axis,) = load_settings(cfg, env={}).axes
    url = axis.settings.controller_url
    assert f"profile={tmp_path / 'plc-y.toml'}" in url  # stored absolute: the profiles folder is not looked in
    assert resolve_profile(url, FOLDER) == url
