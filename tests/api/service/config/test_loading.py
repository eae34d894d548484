"""Configuration: embedded defaults, the TOML file, environment overrides, errors that
name the option; and the ``mebm keys`` commands."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from api.cli.main import main
from api.service.config.loading import load_settings
from api.service.config.settings import ConfigError
from storage.db import config_repo, make_engine, make_session_factory, session_scope

FULL = """
[server]
host = "0.0.0.0"
port = 9000
trusted_proxies = ["10.0.0.2", "fd00::/8"]
[limits]
max_header_bytes = 32768
max_headers = 50
auth_address_failures_per_minute = 30
auth_address_failure_burst = 40
gap_diagnoses_pending = 3
gap_diagnosis_timeout_s = 300
gap_diagnosis_nice = 0
[storage]
data_dir = "/var/lib/mebm"
database_url = "postgresql://mebm@db/mebm"
[auth]
bootstrap_admin_key = "0123456789abcdef0123"
demo_keys = false
[scheduler]
enabled = true
catch_up_missed = false
spool_retry_s = 10
[simulator]
time_scale = 5
servo_rate_hz = 500
backlash_um_at_20c = 200
backlash_um_per_k = 1.5
temperature_mean_c = 18
temperature_amplitude_c = 4
temperature_period_s = 3600
cyclic_error_um = 2
[logging]
level = "warning"
[[machines]]
name = "vmc-850"
description = "hall 2"
  [[machines.axes]]
  name = "y"
  transmission_mm_per_rev = 6.857
  screw_lead_mm = 16
  position_gain_per_s = 10
  travel_mm = [0, 1000]
  controller = "modbus://10.0.0.7:502?mode=latched"
  measure_feed_mm_min = 2000
  measure_acceleration_mm_s2 = 400
  warning_fraction = 0.85
  schedule_cron = "0 6 * * *"
    [[machines.axes.tasks]]
    name = "bore R200"
    profile = "circle"
    radius_mm = 200
    feed_mm_min = 200
    tolerance_um = 45
    [[machines.axes.tasks]]
    name = "chamfer"
    profile = "line"
    angle_deg = 45
    feed_mm_min = 1000
    tolerance_um = 100
"""


def test_defaults_are_the_demo():
    s = load_settings(None, env={})
    assert s.db_url.startswith("sqlite:///") and s.db_url.endswith("data/mebm.sqlite3")
    (axis,) = s.axes
    assert axis.settings.controller_url == "sim" and s.uses_simulator
    assert axis.settings.spec.transmission_mm_per_rev == 6.857 and axis.settings.spec.position_gain_per_s == 10
    (task,) = axis.settings.tasks
    assert (task.radius_mm, task.feed_mm_min, task.tolerance_um) == (200, 200, 45)
    assert task.backlash_limit_um() == pytest.approx(236.0, abs=0.1)


def test_every_option_is_read(tmp_path):
    p = tmp_path / "mebm.toml"
    p.write_text(FULL)
    s = load_settings(p, env={})
    assert (s.host, s.port, s.data_dir, s.database_url) == ("0.0.0.0", 9000, Path("/var/lib/mebm"),
                                                          "postgresql://mebm@db/mebm")
    assert s.bootstrap_admin_key == "0123456789abcdef0123" and s.demo_keys is False
    assert s.trusted_proxies == ("10.0.0.2", "fd00::/8")
    lim = s.limits
    assert (lim.max_header_bytes, lim.max_headers, lim.auth_address_failures_per_minute,
            lim.auth_address_failure_burst) == (32768, 50, 30, 40)
    assert (lim.gap_diagnoses_pending, lim.gap_diagnosis_timeout_s, lim.gap_diagnosis_nice) == (3, 300.0, 0)
    assert load_settings(None, env={}).limits.gap_diagnosis_nice == 10  # below the service by default
    assert (s.catch_up_missed, s.spool_retry_s, s.log_level) == (False, 10, "warning")
    assert s.simulator.time_scale == 5 and s.simulator.temperature_period_s == 3600
    (axis,) = s.axes
    st = axis.settings
    assert st.schedule.cron == "0 6 * * *" and st.warning_fraction == 0.85 and st.measure_acceleration_mm_s2 == 400
    assert [t.profile for t in st.tasks] == ["circle", "line"] and st.tasks[1].gain_per_s == 10
    assert not s.uses_simulator


def test_environment_overrides_the_file(tmp_path):
    p = tmp_path / "mebm.toml"
    p.write_text(FULL)
    env = {"MEBM_DATABASE_URL": "sqlite:////tmp/x.sqlite3", "MEBM_DATA_DIR": "/srv/mebm", "MEBM_PORT": "0",
           "MEBM_HOST": "127.0.0.1", "MEBM_BOOTSTRAP_ADMIN_KEY": "k" * 20}
    s = load_settings(p, env=env)
    assert (s.database_url, s.data_dir, s.port, s.host, s.bootstrap_admin_key) == (
        "sqlite:////tmp/x.sqlite3", Path("/srv/mebm"), 0, "127.0.0.1", "k" * 20)


AXIS = ("[[machines]]\nname='m'\n[[machines.axes]]\nname='y'\ntransmission_mm_per_rev=1\nscrew_lead_mm=1\n"
        "position_gain_per_s=1\ntravel_mm=[0, 10]\n")


def test_instruments_default_to_a_glass_scale_and_a_class_b_pt100_and_are_set_per_axis(tmp_path):
    (demo,) = load_settings(None, env={}).axes
    assert demo.settings.instruments.to_dict() == {"scale_accuracy_um": 1.0, "scale_accuracy_um_per_m": 5.0,
                                                   "thermometer_class": "B", "thermal_expansion_per_k": 11.5e-6}
    p = tmp_path / "mebm.toml"
    p.write_text("[uncertainty]\nscale_accuracy_um = 2\nthermometer_class = 'A'\n" + AXIS
                 + "scale_accuracy_um_per_m = 3\n[[machines.axes]]\nname='z'\ntransmission_mm_per_rev=1\n"
                   "screw_lead_mm=1\nposition_gain_per_s=1\ntravel_mm=[0, 10]\nthermometer_class = 'AA'\n")
    y, z = load_settings(p, env={}).axes
    assert (y.settings.instruments.scale_accuracy_um, y.settings.instruments.scale_accuracy_um_per_m,
            y.settings.instruments.thermometer_class) == (2.0, 3.0, "A")
    assert (z.settings.instruments.scale_accuracy_um, z.settings.instruments.scale_accuracy_um_per_m,
            z.settings.instruments.thermometer_class) == (2.0, 5.0, "AA")
    # [uncertainty] alone applies to the demo axis
    p.write_text("[uncertainty]\nthermal_expansion_per_k = 10.5e-6\n")
    (demo,) = load_settings(p, env={}).axes
    assert demo.settings.instruments.thermal_expansion_per_k == 10.5e-6


@pytest.mark.parametrize("text, where", [
    ("[uncertainty]\nscale_accuracy_um = 0", "uncertainty: scale_accuracy_um"),
    ("[uncertainty]\nthermometer_class = 'D'", "thermometer_class"),
    ("[uncertainty]\nscale_accuracy = 1", "uncertainty: unknown"),
    (AXIS + "thermal_expansion_per_k = -1e-6\n", "machines[0].axes[0]: thermal_expansion_per_k"),
    (AXIS + "scale_accuracy_um = 'x'\n", "machines[0].axes[0].scale_accuracy_um"),
])
def test_instrument_errors_name_the_option(tmp_path, text, where):
    p = tmp_path / "mebm.toml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=where.replace(".", r"\.").replace("[", r"\[").replace("]", r"\]")):
        load_settings(p, env={})


@pytest.mark.parametrize("text, where", [
    ("[server]\nport = 'x'", "server.port"),
    ("[server]\nprt = 1", "prt"),
    ("[[machines]]\nname='m'\n[[machines.axes]]\nname='y'\ntransmission_mm_per_rev=1\nscrew_lead_mm=1\n"
     "position_gain_per_s=1\ntravel_mm=[0]\n", "travel_mm"),
    ("[[machines]]\nname='m'\n[[machines.axes]]\nname='y'\ntransmission_mm_per_rev=1\nscrew_lead_mm=1\n"
     "position_gain_per_s=1\ntravel_mm=[0, 10]\ncontroller='ftp://x'\n", "controller"),
    ("[[machines]]\nname='m'\n[[machines.axes]]\nname='y'\ntransmission_mm_per_rev=1\nscrew_lead_mm=1\n"
     "position_gain_per_s=1\ntravel_mm=[0, 10]\n[[machines.axes.tasks]]\nname='c'\nprofile='circle'\n"
     "feed_mm_min=100\ntolerance_um=5\n", "radius_mm"),
    ("not toml =", "mebm.toml"),
    ("[limits]\ngap_diagnosis_nice = 20", "limits.gap_diagnosis_nice"),
    ("[limits]\ngap_diagnosis_nice = -1", "limits.gap_diagnosis_nice"),
])
def test_errors_name_the_option(tmp_path, text, where):
    p = tmp_path / "mebm.toml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=where.replace(".", r"\.")):
        load_settings(p, env={})


def test_keys_cli_writes_a_created_secret_to_a_mode_600_file_and_prints_only_where(tmp_path, capsys, monkeypatch):
    url = f"sqlite:///{tmp_path}/k.sqlite3"
    monkeypatch.setenv("MEBM_DATABASE_URL", url)
    monkeypatch.setenv("MEBM_DATA_DIR", str(tmp_path / "data"))
    assert main(["keys", "create", "--role", "operate", "--name", "cell-3"]) == 0
    out = capsys.readouterr().out
    assert main(["keys", "create", "--role", "read", "--json"]) == 0
    as_json = json.loads(capsys.readouterr().out)
    assert "key" not in as_json and Path(as_json["key_file"]) == tmp_path / "data" / "keys" / f"{as_json['id']}.key"
    eng = make_engine(url)
    try:
        with session_scope(make_session_factory(eng)) as s:
            rec = config_repo.find_key(s, "cell-3")
            path = tmp_path / "data" / "keys" / f"{rec.id}.key"
            assert str(path) in out and "mebm_" not in out
            secret = path.read_text().strip()
            assert config_repo.authenticate(s, secret).name == "cell-3"
            assert config_repo.authenticate(s, Path(as_json["key_file"]).read_text().strip()).role == "read"
        assert path.stat().st_mode & 0o777 == 0o600 and path.parent.stat().st_mode & 0o777 == 0o700
    finally:
        eng.dispose()


def test_keys_cli_create_list_revoke(tmp_path, capsys, monkeypatch):
    url = f"sqlite:///{tmp_path}/k.sqlite3"
    monkeypatch.setenv("MEBM_DATABASE_URL", url)
    monkeypatch.setenv("MEBM_DATA_DIR", str(tmp_path / "data"))
    assert main(["keys", "create", "--role", "read", "--name", "mes", "--json", "--show-keys"]) == 0
    created = json.loads(capsys.readouterr().out)
    assert created["role"] == "read" and created["key"].startswith("mebm_")
    assert not (tmp_path / "data" / "keys").exists()  # printed, so written nowhere
    assert main(["keys", "list", "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)
    assert row["name"] == "mes" and "key" not in row
    assert main(["keys", "revoke", "mes"]) == 0
    eng = make_engine(url)
    with session_scope(make_session_factory(eng)) as s:
        assert config_repo.authenticate(s, created["key"]) is None
    eng.dispose()
