"""Who starts a round trip, from a controller URL (acquisition.trigger): shared by every
scheme's parser, so the CANopen parser needs nothing of the Modbus one."""

import subprocess
import sys

import pytest

from acquisition.trigger import default_trigger, trigger_kwargs
from core.errors import InputError


def test_a_simulator_is_active_and_any_other_controller_passive():
    assert default_trigger("sim://127.0.0.1:5020") == "active"
    assert default_trigger("canopen://virtual/sim?node=5") == "active"
    assert default_trigger("modbus://10.0.0.5:502") == "passive"
    assert default_trigger("canopen://socketcan/can0?node=5") == "passive"


def test_the_trigger_keys_are_taken_out_of_the_query_and_the_rest_left():
    q = {"trigger": "passive", "running_flag": "yes", "rest_s": "0.5", "node": "5"}
    assert trigger_kwargs("modbus://h", q) == {"trigger": "passive", "running_flag": True, "passive": {"rest_s": 0.5}}
    assert q == {"node": "5"}


@pytest.mark.parametrize(("query", "said"), [
    ({"trigger": "sometimes"}, "must be active or passive"),
    ({"running_flag": "maybe"}, "must be 0 or 1"),
    ({"rest_s": "long"}, "must be a number"),
    ({"trigger": "active", "rest_s": "1"}, "apply to trigger=passive only"),
])  # fmt: skip
def test_a_bad_trigger_setting_is_an_input_error_that_names_it(query, said):
    with pytest.raises(InputError, match=said):
        trigger_kwargs("modbus://h", dict(query))


def test_the_canopen_url_parser_does_not_import_the_modbus_one():
    code = "import sys, acquisition.canopen.url; print('acquisition.url' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
