"""``mebm maintenance`` without a service: the message says how to name one."""

from __future__ import annotations

import socket

from api.cli.main import main


def test_no_service_names_the_url_option_and_its_environment_variable(capsys, monkeypatch):
    monkeypatch.delenv("MEBM_URL", raising=False)
    with socket.socket() as closed:  # bound, never listening: a connection to it is refused
        closed.bind(("127.0.0.1", 0))
        url = f"http://127.0.0.1:{closed.getsockname()[1]}"
        code = main(["maintenance", "orders", "--url", url, "--key", "any"])
    err = capsys.readouterr().err
    assert code != 0
    assert f"no service at {url}" in err and "--url" in err and "MEBM_URL" in err
