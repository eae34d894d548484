"""Fuzzing the OpenAPI schema (schemathesis, bounded examples per operation): no 500,
no response that breaks the schema, no undocumented status code. SQLite only (the
PostgreSQL run of the same handlers is covered by test_api)."""

from __future__ import annotations

from dataclasses import replace

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings

from schemathesis.specs.openapi.checks import positive_data_acceptance

from api.rest import create_app
from api.service.config.settings import LimitSettings
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, make_settings

KEYS: dict[str, str] = {}


@pytest.fixture(scope="module")
def fuzz_schema(tmp_path_factory):
    from storage.db import make_engine, upgrade

    tmp = tmp_path_factory.mktemp("fuzz")
    url = f"sqlite:///{tmp}/fuzz.sqlite3"
    eng = make_engine(url)
    upgrade(eng)
    eng.dispose()
    runner = FakeRunner(backlash_um=250.0)
    # the fuzzer sends wrong keys and many triggers on purpose: limits that would answer
    # 429 to the rest of the run are raised (tests/api/rest/test_bounds.py checks them)
    limits = LimitSettings(auth_failure_burst=10**6, auth_address_failure_burst=10**6, trigger_burst=10**6)
    app = create_app(replace(make_settings(url, tmp), limits=limits), runner=runner)
    with TestClient(app):
        svc = app.state.service
        with session_scope(svc.factory) as s:
            KEYS["admin"] = config_repo.create_key(s, "fuzz-admin", "admin")[1]
            axis_id = config_repo.list_axes(s)[0].id
        svc.scheduler.request(axis_id, "manual", "fuzz")  # one measurement and an alert to read
        assert svc.scheduler.idle(30)
        yield schemathesis.openapi.from_asgi("/api/v1/openapi.json", app)


def test_openapi_fuzz(fuzz_schema):
    failures = []
    operations = [r.ok() for r in fuzz_schema.get_all_operations()]
    assert len(operations) >= 15
    for op in operations:
        @given(case=op.as_strategy())
        @settings(max_examples=25, deadline=None, derandomize=True, database=None,
                  suppress_health_check=list(HealthCheck))
        def run(case):
            # positive_data_acceptance is off: cross-field rules (a circle needs radius_mm,
            # travel end > start, a valid cron expression) cannot be written in JSON Schema,
            # so schema-valid bodies are sometimes, correctly, answered 422 naming the field.
            case.call_and_validate(headers={"X-API-Key": KEYS["admin"]}, excluded_checks=[positive_data_acceptance])

        try:
            run()
        except Exception as exc:  # noqa: BLE001 - collect every operation's failure
            failures.append(f"{op.method.upper()} {op.path}: {str(exc)[:1500]}")
    assert not failures, "\n\n".join(failures)
