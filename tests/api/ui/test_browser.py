"""The dashboard in a real headless chromium."""

from __future__ import annotations

import re

import numpy as np
import pytest

from storage.dataset import write_dataset
from storage.db import config_repo, results_repo, session_scope
from tests.api.rest.test_gap import store_case
from tests.api.ui.conftest import SCREENSHOTS
from tests.waiting import poll


def sign_in(page, srv, role: str) -> None:
    page.context.clear_cookies()
    page.goto(srv.link(role))
    page.click("#link-sign-in")
    page.wait_for_url(re.compile(r"/ui/$"))


@pytest.fixture(scope="module")
def page(browser):
    p = browser.new_page()
    yield p
    p.close()


@pytest.fixture(scope="module")
def alarm(ui_server):
    """One good measurement below the limit, then one above it: an ALARM and an active alert;
    two more axes of another machine, one OK, one WARNING, one never measured."""
    ui_server.measure(200.0)
    ui_server.measure(250.0)
    ui_server.measure(150.0, ui_server.add_axis("hmc-630", "x"))
    ui_server.measure(228.0, ui_server.add_axis("hmc-630", "z"))
    ui_server.add_axis("hmc-630", "b")
    with session_scope(ui_server.svc.factory) as s:
        _, alerts = results_repo.list_alerts(s, "active")
    assert len(alerts) == 1
    return alerts[0]


def test_one_time_link_signs_in_and_shows_the_fleet(page, ui_server, alarm):
    link = ui_server.link("read")
    page.context.clear_cookies()
    # a link preview (a chat or mail scanner) fetches the link: that spends nothing
    preview = page.request.get(link)
    assert preview.status == 200 and "Sign in as ui-read" in preview.text()
    page.goto(link)
    page.click("#link-sign-in")
    page.wait_for_url(re.compile(r"/ui/$"))
    row = page.locator(f"tr.axis-row[data-axis-id='{ui_server.axis_id}']")
    assert row.locator(".state").inner_text().strip() == "ALARM"
    assert re.search(r"\d+\.\d ± \d+\.\d µm", row.locator("td.b").inner_text())  # b̄ ± U in µm
    assert "µm" in row.inner_text() and "vmc-850" in row.inner_text()
    assert page.locator(".alerts tr.alert-row").count() == 1
    # sorted by urgency: ALARM, WARNING, no verdict yet, OK
    states = [e.get_attribute("data-state") for e in page.locator("tr.axis-row").all()]
    assert states == ["ALARM", "WARNING", "UNKNOWN", "OK"]
    # the session cookie is HttpOnly and SameSite=Strict; no key in the URL
    (cookie,) = [c for c in page.context.cookies() if c["name"] == "mebm_session"]
    assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
    assert ui_server.keys["read"] not in page.url
    # the fleet refreshes itself without a reload: the polled region is replaced
    page.evaluate("window.__marker = 1")
    page.wait_for_selector("#fleet[data-refreshed]", state="attached", timeout=30000)
    assert page.evaluate("window.__marker") == 1
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SCREENSHOTS / "fleet.png"))

    # the same link again: refused
    page.context.clear_cookies()
    resp = page.goto(link)
    assert resp.status == 403 and "already been used" in page.locator("#error-message").inner_text()


def test_expired_link_is_refused(page, ui_server):
    link = ui_server.link("read")
    page.context.clear_cookies()
    page.goto(link)  # the page opened in time, its button clicked too late
    ui_server.clock.offset_s += 601.0  # past the 10 minutes
    try:
        page.click("#link-sign-in")
        assert "expired" in page.locator("#error-message").inner_text()
        assert not [c for c in page.context.cookies() if c["name"] == "mebm_session"]
        assert page.goto(link).status == 403
    finally:
        ui_server.clock.offset_s -= 601.0


def test_axis_page_renders_its_charts(page, ui_server, alarm):
    sign_in(page, ui_server, "read")
    page.click(f"tr.axis-row[data-axis-id='{ui_server.axis_id}'] a.axis-link")
    page.wait_for_url(re.compile(rf"/ui/axes/{ui_server.axis_id}$"))
    assert "restore the backlash below" in page.locator("#verdict").inner_text()
    imgs = page.locator(".chart img")
    assert imgs.count() == 6
    for i in range(imgs.count()):
        img = imgs.nth(i)
        img.scroll_into_view_if_needed()
        poll(lambda: img.evaluate("e => e.complete"), 30.0)
        assert img.evaluate("e => e.naturalWidth") > 100, img.get_attribute("src")
    # the figures are not the "nothing to draw" placeholder: a real plot has many colours
    png = page.request.get(f"{ui_server.url}/ui/axes/{ui_server.axis_id}/plots/backlash_profile.png").body()
    assert len(png) > 20000
    assert page.locator("table.cycles tbody tr").count() == 2
    assert page.locator("button.measure").is_disabled()  # a read key cannot move the axis
    # both polled regions refresh from their fragments
    page.wait_for_selector("#axis-now[data-refreshed]", state="attached", timeout=30000)
    page.wait_for_selector("#axis-cycles[data-refreshed]", state="attached", timeout=30000)
    assert "restore the backlash" in page.locator("#verdict").inner_text()
    page.evaluate("window.scrollTo(0, 0)")
    page.screenshot(path=str(SCREENSHOTS / "axis.png"))
    csv = page.request.get(f"{ui_server.url}/ui/axes/{ui_server.axis_id}/history.csv?range=all")
    lines = csv.text().strip().splitlines()
    assert lines[0].startswith("measurement_id,measured_at_utc,backlash_mean_um,temperature_c") and len(lines) == 3


def test_the_prognosis_is_drawn_at_the_scale_of_figs_10_and_15_and_the_icon_is_found(page, ui_server, alarm):
    missing = []
    page.on("response", lambda r: missing.append(r.url) if r.status >= 400 else None)
    sign_in(page, ui_server, "read")
    page.goto(f"{ui_server.url}/ui/axes/{ui_server.axis_id}")
    shown = {}
    for name in ("backlash_trend", "tbe_history", "prognosis"):
        img = page.locator(f".chart img[src*='/plots/{name}.png']")
        img.scroll_into_view_if_needed()
        poll(lambda: img.evaluate("e => e.complete && e.naturalWidth > 0"), 30.0)
        # pixels on screen per pixel of the PNG: the same for figures of one size and dpi
        shown[name] = img.evaluate("e => e.getBoundingClientRect().width / e.naturalWidth")
    assert shown["prognosis"] == pytest.approx(shown["tbe_history"], rel=0.02), shown
    assert shown["tbe_history"] == pytest.approx(shown["backlash_trend"], rel=0.02), shown
    icon = page.evaluate("document.querySelector('link[rel=icon]').href")
    assert page.request.get(icon).status == 200
    assert not missing, missing


def test_acknowledge_needs_an_operate_key(page, ui_server, alarm):
    sign_in(page, ui_server, "read")
    button = page.locator(f"tr.alert-row[data-alert-id='{alarm.id}'] button.ack")
    assert button.is_disabled()
    # the form posted anyway (CSRF token of the page, read key): refused by the server
    status = page.evaluate(
        """async (id) => { const csrf = document.querySelector("input[name=csrf]").value;
           const r = await fetch(`/ui/alerts/${id}/ack`, {method: "POST", body: new URLSearchParams({csrf})});
           return r.status; }""", alarm.id)
    assert status == 403
    with session_scope(ui_server.svc.factory) as s:
        assert results_repo.list_alerts(s, "active")[1][0].acknowledged_at is None

    sign_in(page, ui_server, "operate")
    page.locator(f"tr.alert-row[data-alert-id='{alarm.id}'] button.ack").click()
    page.wait_for_url(re.compile(r"/ui/\?msg="))
    assert "acknowledged by ui-operate" in page.locator(".flash").inner_text()
    assert "by ui-operate" in page.locator(f"tr.alert-row[data-alert-id='{alarm.id}'] .ack-state").inner_text()


def test_a_form_post_without_csrf_token_is_refused(page, ui_server, alarm):
    sign_in(page, ui_server, "operate")
    calls = ui_server.runner.calls
    statuses = page.evaluate(
        """async (axis) => { const out = [];
           for (const body of [new URLSearchParams({}), new URLSearchParams({csrf: "forged"})]) {
             const r = await fetch(`/ui/axes/${axis}/measure`, {method: "POST", body});
             out.push(r.status); }
           return out; }""", ui_server.axis_id)
    assert statuses == [403, 403]
    assert ui_server.runner.calls == calls  # nothing was measured
    # the sign-in form without its token is refused too
    page.context.clear_cookies()
    status = page.evaluate(
        """async (key) => (await fetch("/ui/sign-in", {method: "POST", body: new URLSearchParams({key})})).status""",
        ui_server.keys["admin"])
    assert status == 403
    # nor is a sign-in link spent by a post without the sign-in page's token
    link = ui_server.link("read")
    status = page.evaluate(
        """async (u) => (await fetch(u, {method: "POST", body: new URLSearchParams({csrf: "forged"})})).status""", link)
    assert status == 403 and page.request.get(link).status == 200


def demo_like_history(folder, n_runs: int = 3, travel_mm: float = 60.0, seed: int = 5) -> list[str]:
    """Round trips of the demo axis (api/service/demo.py: its twin's thermal lead, cyclic
    error at the screw lead, encoders and noise; the demo's feed, acceleration and 400 Hz
    servo rate) through a shop temperature swinging 19-23 °C, over a shorter travel than
    the demo's 1000 mm so that a diagnosis of them is short (three 60 mm runs: a dozen CPU
    seconds); stored as the service stores runs. Returns the run files."""
    from api.service.config.settings import DEMO_SIMULATOR, demo_axis
    from api.service.demo import DEMO_ENCODERS, DEMO_LEAD_ERROR_UM_PER_M, DEMO_LEAD_GROWTH_PPM_PER_K
    from core.dataset import Dataset, MachineSpec
    from core.sim import AxisModel, CyclicError, Effects, Thermal, round_trip, simulate

    cfg = demo_axis(travel_mm=(0.0, travel_mm)).settings
    spec, sim = cfg.spec, DEMO_SIMULATOR
    effects = Effects(thermal=Thermal(lead_error_um_per_m=DEMO_LEAD_ERROR_UM_PER_M,
                                      lead_growth_ppm_per_k=DEMO_LEAD_GROWTH_PPM_PER_K),
                      cyclic_error=CyclicError.of((spec.screw_lead_mm, sim.cyclic_error_um, 0.0)))
    rng = np.random.default_rng(seed)
    runs = []
    for i in range(n_runs):
        t = 21.0 + 2.0 * np.sin(2 * np.pi * i / n_runs)
        model = AxisModel.from_axis_spec(spec, sim.backlash_um_at_20c + sim.backlash_um_per_k * (t - 20.0),
                                         effects=effects, encoders=DEMO_ENCODERS)
        program = round_trip(-3.0, travel_mm + 3.0, cfg.measure_feed_mm_min, cfg.measure_acceleration_mm_s2,
                             dwell_s=0.2)
        trace = simulate({"y": model}, program, temperature_c=float(t), rate_hz=sim.servo_rate_hz, rng=rng)
        runs.append(trace.to_run(f"rt_y_{i:02d}.csv", utility_day=0.1 * i))
    write_dataset(folder, Dataset(MachineSpec("demo-vmc", {"y": spec}), tuple(runs)))
    return [r.spec.file for r in runs]


def test_gap_diagnosis_of_a_demo_like_history_shows_its_progress_then_the_report(page, ui_server):
    """Started from the gap page, the diagnosis is followed by its job id until the report
    is on the page (not only until it started); a run stored while it computes does not
    send the page back to the idle button."""
    with session_scope(ui_server.svc.factory) as s:
        axis = config_repo.get_axis(s, ui_server.axis_id)
    folder = ui_server.svc.executor.dataset_folder(axis)
    files = demo_like_history(folder)
    sign_in(page, ui_server, "read")
    page.goto(f"{ui_server.url}/ui/axes/{ui_server.axis_id}/gap")
    assert re.search(rf"about \d+ (s|min) for {min(len(files), 16)} runs", page.locator("#gap-promise").inner_text())
    page.click("#gap-start")
    page.wait_for_url(re.compile(r"/gap\?job=\d+$"))
    job_id = int(page.url.rsplit("=", 1)[1])
    state = page.locator(".gap-state")
    if state.get_attribute("data-gap") in ("queued", "running"):  # (a fast machine may be done already)
        assert re.search(rf"(Waiting in the queue|Diagnosing \d+ runs) \(job {job_id}", state.inner_text())
        # a run stored meanwhile (the next scheduled measurement): the page keeps following its job
        from dataclasses import replace

        from storage.dataset import append_runs, read_dataset

        scratch = folder.with_name(folder.name + "-next")
        demo_like_history(scratch, n_runs=1, seed=9)
        nxt = read_dataset(scratch)
        append_runs(folder, nxt.machine, [type(nxt.runs[0])(replace(nxt.runs[0].spec, file="rt_y_99.csv"),
                                                            nxt.runs[0].columns)])
        # a poll the service does not answer: the page keeps its state and says so
        page.route("**/gap.frag*", lambda route: route.fulfill(status=500, body="down"))
        page.wait_for_selector(".poll-trouble", timeout=60000)
        assert "HTTP 500" in page.locator(".poll-trouble").inner_text()
        assert page.locator(".gap-state").get_attribute("data-gap") in ("queued", "running")
        page.unroute("**/gap.frag*")
    # the deadline only catches a diagnosis that never ends, on however busy a machine
    page.wait_for_selector("#gap-result, #gap-error", timeout=900000)
    assert page.locator("#gap-error").count() == 0, page.locator("#gap-error").inner_text()
    assert page.locator(".gap-state").get_attribute("data-job") == str(job_id)
    assert page.locator("#gap-result").inner_text().startswith("Diagnosis: ")
    assert page.locator("table.candidates tbody tr").count() >= 2
    used = re.search(r"(\d+) runs used \((\S+) to (\S+)\)", page.locator(".gap-state").inner_text())
    assert used and used[2] == files[0]
    assert re.match(r"Computed \d+ s ago .* in \d+ (s|min)\.", page.locator("#gap-age").inner_text())
    # the report says which runs it used and how many were stored since (the job read the
    # newest runs when it started: the run stored meanwhile, or not yet)
    since = page.locator("#gap-since").inner_text()
    if used[3] == files[-1] and (folder / "rt_y_99.csv").exists():
        assert int(used[1]) == len(files) and since.startswith("1 run stored since: start the diagnosis again")
    else:
        assert since.startswith("No run stored since")


def test_gap_diagnosis_runs_in_the_background_and_arrives(page, ui_server):
    with session_scope(ui_server.svc.factory) as s:
        axis = config_repo.get_axis(s, ui_server.axis_id)
    case = store_case(ui_server.svc, axis.id, "cyclic_error", seed=11)
    sign_in(page, ui_server, "read")
    page.goto(f"{ui_server.url}/ui/axes/{ui_server.axis_id}/gap")
    page.click("#gap-start")
    # the start returns at once; the page polls until the report arrives
    page.wait_for_selector("#gap-queued, #gap-running, #gap-result", timeout=30000)
    page.wait_for_selector("#gap-result, #gap-error", timeout=900000)
    assert page.locator("#gap-result").inner_text() == f"Diagnosis: {case.label}"
    assert page.locator("table.candidates tbody tr").count() >= 2
    assert "µm" in page.locator(".gap-state").inner_text()
    assert re.match(r"Computed \d+ s ago", page.locator("#gap-age").inner_text())  # a cached result says its age
    # the residual plots: one per test run, measured vs model before and after the effect
    imgs = page.locator(".residuals img")
    assert imgs.count() >= 1
    for i in range(imgs.count()):
        img = imgs.nth(i)
        img.scroll_into_view_if_needed()
        poll(lambda: img.evaluate("e => e.complete"), 60.0)
        assert img.evaluate("e => e.naturalWidth") > 100, img.get_attribute("src")
    assert "→" in page.locator(".residuals figcaption").first.inner_text()
    page.evaluate("window.scrollTo(0, 0)")
    page.screenshot(path=str(SCREENSHOTS / "gap.png"), full_page=True)


def test_a_full_queue_is_shown_with_the_reason_and_what_to_do(page, ui_server):
    """Starting while the service computes as many diagnoses as it runs at once: the page
    says so, when the first is expected to end, and offers the start again."""
    import threading

    from api.service.gap_jobs import JobAbandoned, run_set

    jobs = ui_server.svc.gap_jobs
    with session_scope(ui_server.svc.factory) as s:
        axis = config_repo.get_axis(s, ui_server.axis_id)
    folder = ui_server.svc.executor.dataset_folder(axis)
    demo_like_history(folder, n_runs=4)
    release, held = threading.Event(), threading.Event()
    jobs.hold(lambda: (held.set(), release.wait(600)))  # the queue is busy with another job
    assert held.wait(60)
    others = [jobs.start(run_set(folder, n), folder, n, ("held", n)) for n in range(2, 2 + jobs.max_pending)]
    try:
        sign_in(page, ui_server, "read")
        page.goto(f"{ui_server.url}/ui/axes/{ui_server.axis_id}/gap")
        page.click("#gap-start")
        page.wait_for_url(re.compile(r"/gap\?refused=1"))
        refused = page.locator("#gap-refused").inner_text()
        assert f"computing {jobs.max_pending} gap diagnoses, the most it runs at once" in refused
        assert re.search(r"expected to end in about \d+ (s|min): start this one again then", refused)
        assert page.locator("#gap-start").is_visible()  # what to do: start again
    finally:
        jobs.forget()  # the held jobs are dropped, not computed
        release.set()
        for job in others:
            assert isinstance(job.future.exception(timeout=120), JobAbandoned)


def test_admin_creates_a_key_that_signs_in_by_form_then_revokes_it(page, ui_server):
    sign_in(page, ui_server, "admin")
    page.click("nav >> text=Keys")
    page.fill("#name", "shop-tablet")
    page.select_option("#role", "read")
    page.click("form[action='/ui/keys'] button[type=submit]")
    secret = page.locator("#created-key pre").inner_text().strip()
    assert secret.startswith("mebm_") and secret not in page.url
    page.fill("#name", "shop-tablet")  # the same name again: the message is next to the field
    page.click("form[action='/ui/keys'] button[type=submit]")
    assert "exists already" in page.locator("#key-error").inner_text()

    page.click("button:has-text('Sign out')")
    page.wait_for_url(re.compile(r"/ui/sign-in"))
    page.fill("#key", secret)
    page.click("form[action='/ui/sign-in'] button[type=submit]")
    page.wait_for_url(re.compile(r"/ui/$"))
    assert "shop-tablet · read" in page.locator("nav .who").inner_text()
    assert page.goto(f"{ui_server.url}/ui/keys").status == 403  # a read key is no admin

    sign_in(page, ui_server, "admin")
    page.goto(f"{ui_server.url}/ui/keys")
    with session_scope(ui_server.svc.factory) as s:
        key_id = next(k.id for k in config_repo.list_keys(s) if k.name == "shop-tablet")
    page.click(f"tr[data-key-id='{key_id}'] button:has-text('Revoke')")
    assert "'shop-tablet' revoked" in page.locator(".flash").inner_text()
    with session_scope(ui_server.svc.factory) as s:
        assert config_repo.authenticate(s, secret) is None


def test_unknown_axis_is_a_404_page_and_the_api_keeps_its_json(page, ui_server):
    sign_in(page, ui_server, "read")
    resp = page.goto(f"{ui_server.url}/ui/axes/9999")
    assert resp.status == 404 and "no axis with id 9999" in page.locator("#error-message").inner_text()
    api = page.request.get(f"{ui_server.url}/api/v1/axes/9999", headers={"X-API-Key": ui_server.keys["read"]})
    assert api.status == 404 and api.json()["detail"] == "no axis with id 9999"


def test_admin_configures_a_machine_an_axis_its_tasks_and_schedule(page, ui_server):
    sign_in(page, ui_server, "operate")  # configuration is the admin's, as in the REST API
    assert page.goto(f"{ui_server.url}/ui/config").status == 403
    sign_in(page, ui_server, "admin")
    page.click("nav >> text=Configuration")
    page.fill("#machine-name", "lathe #2")  # refused: the message stands next to the field
    page.click("#machine-form button[type=submit]")
    assert "letters, digits" in page.locator("#machine-name-error").inner_text()
    assert page.locator("#machine-name").get_attribute("aria-invalid") == "true"
    page.fill("#machine-name", "lathe-2")
    page.click("#machine-form button[type=submit]")
    assert "machine 'lathe-2' added" in page.locator(".flash").inner_text()

    page.click("text=Add an axis to lathe-2")
    for name, value in {"name": "z", "transmission_mm_per_rev": "10", "screw_lead_mm": "10",
                        "position_gain_per_s": "16", "travel_start_mm": "0", "travel_end_mm": "5",
                        "controller_url": "modbus://127.0.0.1:1"}.items():
        page.fill(f"#f-{name}", value)
    page.click("#axis-form button[type=submit]")
    assert "end - start >= 10 mm" in page.locator("#f-travel_end_mm-error").inner_text()  # the REST API's rule
    page.fill("#f-travel_end_mm", "600")
    page.click("#axis-form button[type=submit]")
    page.wait_for_url(re.compile(r"/ui/config/axes/\d+\?msg="))
    axis_id = int(re.search(r"/axes/(\d+)", page.url).group(1))

    page.fill("input[name=name_0]", "bore R50")
    page.fill("input[name=feed_mm_min_0]", "300")
    page.fill("input[name=tolerance_um_0]", "20")  # no radius for a circle: refused on its row
    page.click("#tasks-form button[type=submit]")
    assert "radius_mm is required for a circle task" in page.locator("#task-0-error").inner_text()
    page.fill("input[name=radius_mm_0]", "50")
    page.click("#tasks-form button[type=submit]")
    assert "1 machining task(s) saved" in page.locator(".flash").inner_text()
    assert page.locator("input[name=name_0]").input_value() == "bore R50"

    page.fill("#schedule-form #f-cron", "0 6 * * 1-5")  # with the interval still set: not both
    page.click("#schedule-form button[type=submit]")
    assert "not both" in page.locator("#f-cron-error").inner_text()
    page.fill("#schedule-form #f-interval_s", "")
    page.click("#schedule-form button[type=submit]")
    assert "schedule saved" in page.locator(".flash").inner_text()
    with session_scope(ui_server.svc.factory) as s:
        a = config_repo.get_axis(s, axis_id)
    assert a.machine_name == "lathe-2" and a.spec.travel_mm == (0.0, 600.0)
    assert [(t.name, t.radius_mm, t.tolerance_um) for t in a.tasks] == [("bore R50", 50.0, 20.0)]
    assert a.settings.schedule.cron == "0 6 * * 1-5" and a.settings.schedule.interval_s is None
    assert ui_server.svc.scheduler.next_run(axis_id) is not None  # the scheduler follows at once
    page.goto(f"{ui_server.url}/ui/config")
    assert "bore R50 (20 µm)" in page.locator(f"tr.config-axis[data-axis-id='{axis_id}']").inner_text()
    page.screenshot(path=str(SCREENSHOTS / "config.png"), full_page=True)


def test_an_operate_key_records_a_repair_and_the_order_is_verified(page, ui_server, alarm):
    """The maintenance panel (api/ui/maintenance.py): a read key sees the axis' open work
    order and no form; an operate key records a repair, and the page shows the order
    repaired with its verification measurement queued, then verified with its table."""
    import threading

    sign_in(page, ui_server, "read")
    page.goto(f"{ui_server.url}/ui/axes/{ui_server.axis_id}")
    order = page.locator("#work-order")
    assert order.get_attribute("data-state") == "open"
    assert "Restore the backlash below" in page.locator("#restore").inner_text()
    assert page.locator("#maintenance form").count() == 0  # a read key sees no form

    sign_in(page, ui_server, "operate")
    page.goto(f"{ui_server.url}/ui/axes/{ui_server.axis_id}")
    ui_server.runner.backlash_um = 20.0  # what the verification will measure: the play restored
    ui_server.runner.gate, ui_server.runner.gate_timeout_s = threading.Event(), 300.0  # hold it "queued"/"running"
    try:
        page.select_option("#f-kind", "nut_replaced")
        page.fill("#f-note", "ball nut replaced, preload 8 %")
        page.click("#repair-submit")
        page.wait_for_url(re.compile(r"/ui/axes/\d+\?msg="))
        assert "recorded by ui-operate" in page.locator(".flash").inner_text()
        assert page.locator("#work-order").get_attribute("data-state") == "repaired"
        assert re.search(r"Verification measurement \d+: (queued|running)",
                         page.locator("#verification-status").inner_text())
        last = page.locator("table.timeline tr.transition").last
        assert last.get_attribute("data-to") == "repaired" and "ui-operate" in last.inner_text()
    finally:
        ui_server.runner.gate.set()
    assert ui_server.svc.scheduler.idle(120)
    ui_server.runner.gate, ui_server.runner.gate_timeout_s = None, 10.0
    # the verification line polls its fragment until the order has moved on
    page.wait_for_selector("#verification-status #order-now", timeout=60000)
    assert page.locator("#order-now").inner_text() == "verified"
    page.click("#verification-status a")
    page.wait_for_selector("#verification-verdict")
    assert page.locator("#verification-verdict").inner_text().startswith("Verified")
    assert page.locator("table.verification tr[data-key='backlash_mean_um']").count() == 1
    assert "nut replaced" in page.locator("table.repairs").inner_text()
    page.locator("#maintenance").screenshot(path=str(SCREENSHOTS / "maintenance.png"))
    page.click("a:has-text('Every axis')")
    page.wait_for_url(re.compile(r"/ui/maintenance$"))
    assert page.locator("#summary-csv").get_attribute("href") == "/ui/maintenance/summary.csv"
