"""``mebm serve`` (what ``make run`` runs) writes a one-time sign-in link for the demo read key
to ``<data_dir>/sign-in-link`` (mode 600) and prints only where it is: stdout, kept by a
journal, holds no secret. ``--show-keys`` prints them for an operator at a terminal."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import httpx

from api.cli.main import build_parser

from tests.waiting import poll

ROOT = Path(__file__).resolve().parents[3]


def test_the_sign_in_link_is_in_a_mode_600_file_stdout_names_it_and_it_signs_in_once(tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    for k in ("MEBM_DATABASE_URL", "MEBM_BOOTSTRAP_ADMIN_KEY", "MEBM_HOST", "MEBM_PORT", "MEBM_DATA_DIR"):
        env.pop(k, None)
    log = tmp_path / "serve.log"
    data = tmp_path / "data"
    with open(log, "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "api.cli", "serve", "--port", "0", "--no-scheduler",
                                 "--data-dir", str(data)], cwd=ROOT, env=env, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        pattern = re.compile(r"sign-in link for the demo read key, valid 10 min, in (\S+)\)")
        m = poll(lambda: pattern.search(log.read_text()) or proc.poll() is not None, 120.0, 0.2)
        assert m and m is not True, log.read_text()
        link_file = Path(m.group(1))
        assert link_file == data / "sign-in-link" and link_file.stat().st_mode & 0o777 == 0o600
        link = link_file.read_text().strip()
        assert re.fullmatch(r"http://\S+/ui/sign-in/[\w-]+", link), link
        keys = json.loads((data / "demo-keys.json").read_text())
        admin = (data / "admin-key").read_text().strip()
        printed = log.read_text()
        assert str(data / "admin-key") in printed and str(data / "demo-keys.json") in printed
        for secret in (link.rsplit("/", 1)[1], keys["read"], keys["operate"], admin):
            assert secret not in printed  # stdout names the files, never what is in them
        read_key = keys["read"]
        assert read_key not in link  # a token, never the key
        base = link.split("/ui/")[0]
        assert poll(lambda: httpx.get(f"{base}/healthz").status_code == 200, 60.0, 0.2)
        with httpx.Client() as browser:
            opened = browser.get(link)  # the page with the button (a GET spends nothing)
            assert opened.status_code == 200, opened.text
            csrf = re.search(r'name="csrf" value="([^"]+)"', opened.text).group(1)
            first = browser.post(link, data={"csrf": csrf})
        assert first.status_code == 200, first.text
        cookie = first.headers["set-cookie"]
        assert cookie.startswith("mebm_session=") and "HttpOnly" in cookie and "SameSite=strict" in cookie
        fleet = httpx.get(f"{base}/ui/", cookies={"mebm_session": first.cookies["mebm_session"]})
        assert fleet.status_code == 200 and "· read</span>" in fleet.text and "Fleet" in fleet.text
        again = httpx.get(link)
        assert again.status_code == 403 and "already been used" in again.text
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(30)


def test_serve_takes_show_keys_for_an_operator_at_a_terminal():
    parser = build_parser(["serve"], all_commands=False)
    assert parser.parse_args(["serve", "--show-keys"]).show_keys is True
    assert parser.parse_args(["serve"]).show_keys is False
