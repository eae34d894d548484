"""Every number of the configuration has its bounds and every name its alphabet: a value
outside them is refused at load, in one line naming the key, the value and the range."""

from __future__ import annotations

import tomllib

import pytest

from api.service.config.bounds import BOUNDS, check_bounds
from api.service.config.loading import load_settings, parse_settings
from api.service.config.settings import ConfigError, Settings, default_settings

AXIS = """
[[machines]]
name = "{machine}"
[[machines.axes]]
name = "{axis}"
transmission_mm_per_rev = 6.857
screw_lead_mm = 16
position_gain_per_s = 10
travel_mm = [0, 500]
{extra}
"""


def _refused(text: str) -> str:
    with pytest.raises(ConfigError) as err:
        parse_settings(tomllib.loads(text))
    return str(err.value)


@pytest.mark.parametrize("text, message", [
    ("[scheduler]\nspool_retry_s = -1", "scheduler.spool_retry_s (=-1.0) must be 0.1..86400 s"),
    ("[scheduler]\nspool_retry_s = 0", "scheduler.spool_retry_s (=0.0) must be 0.1..86400 s"),
    ("[limits]\ngap_diagnosis_timeout_s = 1e308", "limits.gap_diagnosis_timeout_s (=1e+308) must be 1..604800 s"),
    ("[server]\nstatus_max_age_s = 1e300", "server.status_max_age_s (=1e+300) must be 0.1..86400 s"),
    ("[worker]\nlease_s = 0.001", "worker.lease_s (=0.001) must be 1..86400 s"),
    ("[webhooks]\ntimeout_s = 1e9", "webhooks.timeout_s (=1000000000.0) must be 0.1..300 s"),
    ("[retention]\ninterval_s = 1e12", "retention.interval_s (=1000000000000.0) must be 1..31536000 s"),
    ("[simulator]\nservo_rate_hz = 1e9", "simulator.servo_rate_hz (=1000000000.0) must be 1..100000 Hz"),
    ("[limits]\nmax_header_bytes = 10", "limits.max_header_bytes (=10) must be 1024..16777216 bytes"),
])
def test_a_number_out_of_bounds_is_refused_naming_key_value_and_range(text, message):
    assert _refused(text) == message


@pytest.mark.parametrize("machine, axis, extra, message", [
    ("m", "Ä/../z", "", "machines[0].axes[0].name (='Ä/../z') must be lower-case letters a-z, digits and _"),
    ("x/Notification", "y", "", "machines[0].name (='x/Notification') must be letters A-Z a-z, digits, space"),
    ("m", "y", "schedule_interval_s = 5e8",
     "machines[0].axes[0].schedule_interval_s (=500000000.0) must be 1..100000000 s"),
    ("m", "y", "measure_feed_mm_min = 1e300",
     "machines[0].axes[0].measure_feed_mm_min (=1e+300) must be 0.1..100000 mm/min"),
    ("m", "y", '[[machines.axes.tasks]]\nname = "c"\nprofile = "circle"\nradius_mm = 1e9\nfeed_mm_min = 200\n'
               "tolerance_um = 45", "machines[0].axes[0].tasks[0].radius_mm (=1000000000.0) must be 0.01..100000 mm"),
])
def test_an_axis_out_of_its_alphabet_or_bounds_is_refused_as_rest_would(machine, axis, extra, message):
    assert _refused(AXIS.format(machine=machine, axis=axis, extra=extra)).startswith(message)


def test_a_name_within_its_alphabet_and_numbers_within_bounds_load(tmp_path):
    path = tmp_path / "mebm.toml"
    path.write_text(AXIS.format(machine="vmc 850.a_b-c", axis="y_2", extra="schedule_interval_s = 3600")
                    + "\n[scheduler]\nspool_retry_s = 0.1\n[limits]\ngap_diagnosis_timeout_s = 604800\n")
    s = load_settings(path, env={})
    assert s.machines[0][0] == "vmc 850.a_b-c" and s.axes[0].settings.spec.name == "y_2"
    assert (s.spool_retry_s, s.limits.gap_diagnosis_timeout_s) == (0.1, 604800.0)


def test_an_environment_override_is_bounded_too():
    with pytest.raises(ConfigError, match=r"server.port \(=70000\) must be 0..65535"):
        load_settings(None, env={"MEBM_PORT": "70000"})


def test_the_defaults_are_within_every_bound():
    for settings in (Settings(), default_settings()):
        assert check_bounds(settings) is settings
    assert len({b.key for b, _ in BOUNDS}) == len(BOUNDS)


def test_docs_operations_lists_every_bound_with_its_range():
    from pathlib import Path

    text = (Path(__file__).resolve().parents[4] / "docs" / "operations.md").read_text(encoding="utf-8")
    rows = {line.split("|")[1].strip(" `"): line for line in text.splitlines() if line.startswith("| `")}
    missing = [b.key for b, _ in BOUNDS if b.key not in rows or f"| {b.range}" not in rows[b.key]]
    assert missing == []
