"""``mebm serve`` (what ``make run`` runs) prints a one-time sign-in link for the demo read key."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import httpx

from tests.waiting import poll

ROOT = Path(__file__).resolve().parents[3]


def test_banner_link_signs_in_once(tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    for k in ("MEBM_DATABASE_URL", "MEBM_BOOTSTRAP_ADMIN_KEY", "MEBM_HOST", "MEBM_PORT", "MEBM_DATA_DIR"):
        env.pop(k, None)
    log = tmp_path / "serve.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "api.cli", "serve", "--port", "0", "--no-scheduler",
                                 "--data-dir", str(tmp_path / "data")], cwd=ROOT, env=env, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        pattern = re.compile(r"sign-in link for the demo read key, valid 10 min: (http://\S+/ui/sign-in/[\w-]+)\)")
        m = poll(lambda: pattern.search(log.read_text()) or proc.poll() is not None, 120.0, 0.2)
        assert m and m is not True, log.read_text()
        link = m.group(1)
        read_key = re.search(r"read \(MES\):\s+(\S+)", log.read_text()).group(1)
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
