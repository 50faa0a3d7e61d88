"""Fault injection (short variants of scripts/fault_injection.py, the same code): jobs accepted = jobs finished,
none lost, every refused write a 503 problem+json with Retry-After, nothing half-written, recovery measured.
Plus back-pressure: a full queue answers 429 with Retry-After."""

from __future__ import annotations

import sys

import pytest

from app.examples import PAPER_PLANT

from .conftest import PG_URL, REPO, assert_problem, running_client

sys.path.insert(0, str(REPO / "scripts"))
import fault_injection as fi  # noqa: E402

FAST = {"plant": PAPER_PLANT, "n_drop": 3, "method": "lmi"}


def _no_loss(res: dict) -> None:
    assert res["lost"] == 0 and res["finished"] == res["accepted"], res
    assert res["failed"] == 0, res


@pytest.mark.skipif(bool(PG_URL), reason="SQLite's max_page_count; PostgreSQL has no per-connection size cap")
def test_full_sqlite_database_refuses_writes_with_503_then_recovers(db_url):
    res = fi.database_fault(db_url, "full", submissions=15)
    _no_loss(res)
    assert res["refused_503"] >= 10 and res["unexpected"] == [], res
    assert "full" in res["detail"] and "nothing was changed" in res["detail"], res
    assert res["rows_match_accepted"] and res["integrity"] == "ok", res
    assert res["reads_ok_during_fault"] == "15/15", res
    assert "SQL" not in (res["readyz_during"] or ""), res  # readyz names the reason, never statements or data
    assert res["write_recovered_s"] < 5, res


def test_read_only_database_refuses_writes_with_503_then_recovers(db_url):
    res = fi.database_fault(db_url, "read_only", submissions=15)
    _no_loss(res)
    assert res["refused_503"] == 15 and res["unexpected"] == [], res
    assert "read-only" in res["detail"], res
    assert res["rows_match_accepted"], res
    assert res["reads_ok_during_fault"] == "15/15", res
    assert res["write_recovered_s"] < 5, res


@pytest.mark.skipif(not PG_URL, reason="needs PostgreSQL (NCS_TEST_DATABASE_URL)")
def test_postgres_connection_loss_reconnects_without_errors(db_url, tmp_path):
    res = fi.pg_loss(db_url, tmp_path, terminations=3, interval=1.0, clients=3)
    _no_loss(res)
    assert all(k > 0 for k in res["backends_terminated"]), res
    assert res["errors_5xx"] == 0 and res["non_problem_errors"] == [], res
    # (SQLAlchemy's pool may log a traceback when it discards a terminated connection; no request failed.)
    assert res["readyz_after"] == 200 and res["log_unhandled"] == 0, res
    assert res["recover_s_max"] is not None and res["recover_s_max"] < 5, res


@pytest.mark.skipif(not PG_URL or not fi.local_postgres(), reason="needs the local PostgreSQL server (pg_ctlcluster)")
def test_postgres_server_restart_under_load_loses_no_job_and_the_service_recovers(db_url, tmp_path):
    res = fi.pg_loss(db_url, tmp_path, terminations=2, interval=1.5, clients=3, restart=True)
    _no_loss(res)
    assert res["errors_5xx"] == 0 and res["non_problem_errors"] == [], res  # only 503 problem+json meanwhile
    assert res["readyz_after"] == 200 and res["log_unhandled"] == 0, res
    assert res["recover_s_max"] is not None and res["recover_s_max"] < 15, res


def test_sigkill_worker_mid_job_is_retried(db_url, tmp_path):
    res = fi.worker_kill(db_url, tmp_path, kills=2, fast_jobs=3)
    _no_loss(res)
    assert res["slow_job_attempts"] == 3, res
    assert res["recover_s_max"] < 30, res


def test_sigkill_service_with_40_jobs_queued_and_running_then_restart(db_url, tmp_path):
    res = fi.service_kill(db_url, tmp_path, jobs=40, slow_jobs=2)
    _no_loss(res)
    assert res["at_kill"].get("running", 0) >= 1 and res["at_kill"].get("queued", 0) >= 1, res
    assert res["retried"] >= 1, res


def test_back_pressure_429_with_retry_after(db_url):
    with running_client(db_url, run_dispatcher=False, max_queue_depth=3, retry_after=7) as c:
        ids = [c.post("/v1/designs", json=FAST, headers={"Idempotency-Key": f"k{i}"}).json()["id"]
               for i in range(3)]
        resp = c.post("/v1/designs", json=FAST)
        body = assert_problem(resp, 429)
        assert resp.headers["retry-after"] == "7"
        assert "NCS_MAX_QUEUE_DEPTH" in body["detail"] and body["type"].endswith("/queue-full")
        # A replay of an accepted job is not new work: still answered.
        replay = c.post("/v1/designs", json=FAST, headers={"Idempotency-Key": "k0"})
        assert replay.status_code == 202 and replay.json()["id"] == ids[0]
        assert c.get("/v1/designs").json()["total"] == 3  # the refused one left nothing behind
        # Room again once the queue shrinks.
        assert c.post(f"/v1/designs/{ids[0]}/cancel").status_code == 200
        assert c.post("/v1/designs", json=FAST).status_code == 202
        spec = c.get("/openapi.json").json()
        assert "429" in spec["paths"]["/v1/designs"]["post"]["responses"]
