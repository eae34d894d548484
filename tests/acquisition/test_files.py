"""Files a user names are read only as regular files of bounded size: a FIFO, /dev/zero, a
folder or a file beyond the reader's bound is refused at once, naming the file, by every
reader of such files (register and trace-import profiles, traces, EDS/DCF, the service's
configuration)."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from acquisition.canopen.mapping import mapping_from_eds
from acquisition.files import FileRefused, open_regular, read_regular
from acquisition.modbus.profile import load_profile
from acquisition.trace_import import ColumnSpec, TraceProfile, read_trace
from api.cli.import_trace import load_trace_profile
from api.service.config.loading import load_settings
from core.errors import InputError

EDS = Path(__file__).resolve().parents[2] / "examples" / "canopen" / "mebm-sim-drive.eds"


@pytest.fixture
def fifo(tmp_path) -> Path:
    path = tmp_path / "named.eds"  # a suffix the readers accept: only the kind of file refuses it
    os.mkfifo(path)
    return path


def _refused_without_waiting(read, path) -> str:
    """What ``read(path)`` raised; it runs in a thread so that a reader that blocked on the
    file (a FIFO without a writer) would fail the test, not hang the suite."""
    out: dict = {}

    def go():
        try:
            read(path)
            out["error"] = None
        except InputError as exc:
            out["error"] = str(exc)

    t = threading.Thread(target=go, daemon=True)
    t.start()
    t.join(60)
    assert "error" in out, f"reading {path} did not return (blocked on it?)"
    assert out["error"] is not None, f"{path} was read"
    return out["error"]


def test_a_regular_file_within_the_bound_is_read(tmp_path):
    f = tmp_path / "ok.txt"
    f.write_bytes(b"x" * 100)
    assert read_regular(f, 100, "test file") == b"x" * 100
    with open_regular(f, 100, "test file", encoding="utf-8", newline="") as fh:
        assert fh.read() == "x" * 100


@pytest.mark.parametrize("kind", ["fifo", "/dev/zero", "folder", "too large", "missing"])
def test_the_helper_refuses_what_is_not_a_bounded_regular_file(tmp_path, fifo, kind):
    path = {"fifo": fifo, "/dev/zero": Path("/dev/zero"), "folder": tmp_path, "too large": tmp_path / "big",
            "missing": tmp_path / "none"}[kind]
    if kind == "too large":
        path.write_bytes(b"x" * 101)
    message = _refused_without_waiting(lambda p: read_regular(p, 100, "test file"), path)
    assert message.startswith(f"test file {path}: ")
    expected = {"fifo": "not a regular file", "/dev/zero": "not a regular file", "folder": "not a regular file",
                "too large": "101 bytes, larger than the 100 bytes", "missing": "cannot be read"}[kind]
    assert expected in message
    with pytest.raises(FileRefused):
        read_regular(tmp_path / "none", 100, "test file")


TRACE_PROFILE = TraceProfile(columns=(ColumnSpec("time_s", "t", "s"),))
READERS = {
    "register profile": load_profile,
    "trace-import profile": lambda p: load_trace_profile(Path(p)),
    "trace file": lambda p: read_trace(p, TRACE_PROFILE),
    "EDS/DCF": lambda p: mapping_from_eds(p, 7),
    "configuration file": lambda p: load_settings(p, env={}),
}


@pytest.mark.parametrize("reader", sorted(READERS))
@pytest.mark.parametrize("kind", ["fifo", "/dev/zero"])
def test_every_reader_refuses_a_fifo_and_a_device(reader, kind, fifo):
    path = fifo if kind == "fifo" else Path("/dev/zero")
    message = _refused_without_waiting(READERS[reader], path)
    assert str(path) in message and "not a regular file" in message, message


def test_an_eds_within_its_bound_is_still_read():
    assert mapping_from_eds(EDS, 7).tpdo_cob_id > 0


def test_a_configuration_file_beyond_its_bound_is_refused_naming_it(tmp_path):
    big = tmp_path / "mebm.toml"
    big.write_bytes(b"# " + b"x" * (1024 * 1024) + b"\n")
    with pytest.raises(InputError, match=r"config file .*mebm.toml: \d+ bytes, larger than the 1048576 bytes"):
        load_settings(big, env={})
