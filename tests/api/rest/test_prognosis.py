"""The prognosis through the API: the prognosis endpoint, the status' prognosis
and lost motion, the prognosis plot, and the history components of the stored budget."""

from __future__ import annotations

import uuid
from datetime import timedelta

import numpy as np
import pytest
from sqlalchemy import insert, update

from storage.db import rollup, session_scope, utcnow
from storage.db.models import Cycle, LeadCriteriaRow, Result
from tests.api.rest.conftest import hdr
from tests.api.rest.test_api import V1, run_cycle


def bulk_history(svc, axis_id, n=80, days=160.0, seed=0):
    """``n`` older results over ``days`` days: b̄ = 200 + 2 (T - 20) + 0.02 d + noise."""
    rng = np.random.default_rng(seed)
    now = utcnow()
    d = np.linspace(0.0, days, n, endpoint=False)
    temp = rng.uniform(16.0, 28.0, n)
    b = 200.0 + 2.0 * (temp - 20.0) + 0.02 * d + rng.normal(0, 0.5, n)
    when = [now - timedelta(days=days - float(x)) for x in d]
    engine = svc.factory.kw["bind"]
    with engine.begin() as c:
        # the newest (real) measurement is on day `days` of the axis' service
        c.execute(update(Result).where(Result.axis_id == axis_id).values(utility_day=days))
        for w, t, dd, bb in zip(when, temp, d, b):
            cid = c.execute(insert(Cycle).values(uuid=str(uuid.uuid4()), axis_id=axis_id, trigger="schedule",
                                                 status="ok", requested_at=w, started_at=w, finished_at=w)
                            ).inserted_primary_key[0]
            rid = c.execute(insert(Result).values(
                cycle_id=cid, axis_id=axis_id, measured_at=w, temperature_c=float(t), utility_day=float(dd),
                backlash_mean_um=float(bb), backlash_min_um=float(bb) - 5, backlash_max_um=float(bb) + 5,
                backlash_std_um=2.0, useful_travel_start_mm=0.0, useful_travel_end_mm=200.0, n_samples=1000,
                peak_speed_mm_min=1000.0)).inserted_primary_key[0]
            c.execute(insert(LeadCriteriaRow), [dict(result_id=rid, direction=dn, e_p_um=1.0, e_p_um_per_1000mm=8.0,
                                                     v_u_um=12.0, v_300_um=6.0, v_2pi_um=3.0, n_strokes=1)
                                                for dn in ("positive", "negative")])
    with session_scope(svc.factory) as s:  # as a bulk import leaves it: the rollups rebuilt
        rollup.rebuild(s, axis_id)
    svc.status.invalidate(axis_id)


def test_prognosis_endpoint_status_and_plot(app_env, runner):
    client, svc, keys, axis_id = app_env
    h = hdr(keys["read"])
    runner.backlash_um, runner.temperature_c = 200.0, 20.0
    run_cycle(client, svc, keys, axis_id)
    p = client.get(f"{V1}/axes/{axis_id}/prognosis", headers=h).json()
    assert p["identifiable"] is False and "too few cycles" in p["reason"]
    bulk_history(svc, axis_id)
    p = client.get(f"{V1}/axes/{axis_id}/prognosis", headers=h).json()
    assert p["identifiable"] is True and p["rows_used"] == 81, {k: v for k, v in p.items() if k != "reason"}
    lo, hi = p["fit"]["beta"]["interval_um_per_k"]
    assert lo <= 2.0 <= hi
    assert p["worst_case_temperature_c"] == 30.0 and p["decision_rule"] == "guarded"
    # the demo task's limit is 236 µm: b̄ = 203 + 2 (T - 20) reaches it near 36.5 °C
    assert p["limit_temperature"]["value_c"] == pytest.approx(36.5, abs=1.5), {k: v for k, v in p.items() if k != "reason"}
    assert p["alarm_temperature_c"] > p["limit_temperature"]["value_c"]  # guarded: U above the limit first
    assert p["limit_date"] is not None or p["limit_date_reason"].startswith("not within")
    assert p["clearance_history"]["source"] == "history" and len(p["clearance_history"]["feeds_mm_min"]) == 81
    svc.status.invalidate(axis_id)  # recomputed status, unchanged history: the fit is not redone
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=h).json()
    assert st["prognosis"]["alarm_temperature_c"] == p["alarm_temperature_c"]
    assert st["prognosis"]["computed_at"] == p["computed_at"]
    # the status the MES polls counts the history's points; GET /prognosis lists them
    for c in (st["prognosis"]["clearance_history"], st["lost_motion"]["clearance_history"]):
        assert c["points"] == 81 and "feeds_mm_min" not in c and c["clearance_um"] == p["clearance_history"]["clearance_um"]
    assert st["reversal_mean_um"] == pytest.approx(st["backlash_mean_um"], abs=0.5)
    assert "total lost motion" in st["lost_motion"]["tbe_basis"]
    r = client.get(f"{V1}/axes/{axis_id}/plots/prognosis.png", headers=h)
    assert r.status_code == 200 and r.content[:4] == b"\x89PNG" and len(r.content) > 10000
    assert client.get(f"{V1}/axes/{axis_id}/prognosis").status_code == 401


def test_history_components_join_the_stored_budget(app_env, runner):
    client, svc, keys, axis_id = app_env
    h = hdr(keys["read"])
    for b, t in ((200.0, 19.6), (201.0, 20.4), (199.0, 20.0), (200.5, 20.6), (199.5, 19.8), (200.2, 20.1)):
        runner.backlash_um, runner.temperature_c = b, t
        svc.trigger(axis_id, "test")  # past the REST trigger limit: the service's own door
        assert svc.scheduler.idle(30)
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=h).json()
    names = [c["name"] for c in st["uncertainty_budget"]["backlash_mean"]["components"]]
    assert "repeatability" in names
    rep = next(c for c in st["uncertainty_budget"]["backlash_mean"]["components"] if c["name"] == "repeatability")
    assert 0.1 < rep["standard_um"] < 5.0
    norm = [c["name"] for c in st["uncertainty_budget"]["backlash_mean_20c"]["components"]]
    assert "normalisation" in norm
    assert st["backlash_mean_20c_uncertainty_um"] >= st["backlash_mean_uncertainty_um"]
    assert st["uncertainty_um"] == pytest.approx(st["backlash_mean_uncertainty_um"] / 2, rel=1e-6)
