"""Fairness between owners (API keys), on a real server with two keys: claims go owner by owner in turn, so
key B's job starts within one job of being queued while key A has a backlog of hundreds; a key's queue quota
answers 429 naming that key's own limit and does not touch the other key. SQLite, or PostgreSQL with
NCS_TEST_DATABASE_URL.

The ordering is read from the jobs table (``started_at`` is set by the claim), not timed."""

from __future__ import annotations

import statistics
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
from sqlalchemy import select

from app.api.deps import owner_of
from app.jobs.database import Database
from app.jobs.tables import Job
from bench.harness import FAST, SLOW

KEY_A, KEY_B = "key-a-" + "0" * 16, "key-b-" + "1" * 16


def _post(base: str, key: str, body: dict, **headers) -> httpx.Response:
    return httpx.post(base + "/v1/designs", json=body, headers={"X-API-Key": key, **headers}, timeout=120)


def _flood(base: str, key: str, body: dict, n: int) -> list[httpx.Response]:
    """``n`` submissions from 8 concurrent clients (the backlog builds faster than one worker drains it)."""
    with ThreadPoolExecutor(8) as pool:
        return list(pool.map(lambda _: _post(base, key, body), range(n)))


def _starts(url: str, key: str) -> list[tuple]:
    """(started_at, finished_at) of every started job of ``key``, in UTC (SQLite gives them naive)."""
    db = Database(url)
    try:
        with db.read_conn() as c:
            rows = c.execute(select(Job.started_at, Job.finished_at).where(
                Job.owner == owner_of(key), Job.started_at.is_not(None))).all()
    finally:
        db.dispose()
    return [tuple(_utc(t) for t in row) for row in rows]


def _utc(t):
    from datetime import timezone

    return t if t is None or t.tzinfo is not None else t.replace(tzinfo=timezone.utc)


def _ts(text: str):
    from datetime import datetime

    return datetime.fromisoformat(text.replace("Z", "+00:00"))


def test_b_starts_within_one_job_while_a_has_a_backlog_of_hundreds(db_url, start_server):
    server = start_server(db_url, NCS_WORKERS=1, NCS_API_KEYS=f"{KEY_A},{KEY_B}")
    accepted = [r for r in _flood(server.base, KEY_A, SLOW, 300) if r.status_code == 202]
    assert len(accepted) == 300
    backlog = httpx.get(server.base + "/v1/designs?status=queued&limit=1", headers={"X-API-Key": KEY_A}).json()
    assert backlog["total"] >= 100, backlog  # A really has a backlog of hundreds when B arrives

    b = _post(server.base, KEY_B, FAST, Prefer="wait=60")
    assert b.status_code == 201, b.text  # finished within the wait, long before A's backlog
    job = b.json()
    queued_at, started_at = _ts(job["created_at"]), _ts(job["started_at"])
    a_runs = _starts(db_url, KEY_A)
    a_started_between = [s for s, _ in a_runs if queued_at < s < started_at]
    # One worker: at most the one job of A that was claimed when the worker fell free.
    assert len(a_started_between) <= 1, (len(a_started_between), job)
    a_times = [(f - s).total_seconds() for s, f in a_runs if f is not None]
    print(f"\nB waited {(started_at - queued_at).total_seconds():.3f} s from queued to started; A's jobs took "
          f"{statistics.median(a_times):.3f} s (median of {len(a_times)}); A jobs started meanwhile: "
          f"{len(a_started_between)}; A still queued at B's submission: {backlog['total']}")


def test_without_fair_scheduling_b_waits_behind_a(db_url, start_server):
    """The same flood with NCS_FAIR_SCHEDULING=false: B's job stays queued while A's start one after another
    (the test above can fail)."""
    server = start_server(db_url, NCS_WORKERS=1, NCS_API_KEYS=f"{KEY_A},{KEY_B}", NCS_FAIR_SCHEDULING="false")
    assert all(r.status_code == 202 for r in _flood(server.base, KEY_A, SLOW, 30))
    b = _post(server.base, KEY_B, FAST)
    assert b.status_code == 202
    queued_at = _ts(b.json()["created_at"])
    deadline = time.monotonic() + 120
    while True:
        later = [s for s, _ in _starts(db_url, KEY_A) if s > queued_at]
        if len(later) >= 3:
            break
        assert time.monotonic() < deadline, "A's jobs stopped starting"
        time.sleep(0.1)
    job = httpx.get(server.base + f"/v1/designs/{b.json()['id']}", headers={"X-API-Key": KEY_B}).json()
    assert job["status"] == "queued", job


def test_quota_429_names_the_owners_own_limit_and_does_not_touch_the_other_key(db_url, start_server):
    server = start_server(db_url, NCS_WORKERS=1, NCS_API_KEYS=f"{KEY_A},{KEY_B}", NCS_MAX_QUEUED_PER_OWNER=5,
                          NCS_MAX_QUEUE_DEPTH=100)
    answers = [_post(server.base, KEY_A, SLOW) for _ in range(12)]
    refused = [r for r in answers if r.status_code == 429]
    assert 5 <= sum(r.status_code == 202 for r in answers) <= 7, [r.status_code for r in answers]
    assert refused, [r.status_code for r in answers]
    for r in refused:
        assert r.headers["content-type"].startswith("application/problem+json")
        body = r.json()
        assert body["type"].endswith("/owner-quota"), body
        assert "NCS_MAX_QUEUED_PER_OWNER" in body["detail"] and "limit is 5" in body["detail"], body
        assert int(r.headers["retry-after"]) >= 1
    b = _post(server.base, KEY_B, FAST)
    assert b.status_code == 202, b.text  # B still gets in
    again = _post(server.base, KEY_A, FAST)
    assert again.status_code == 429  # and A is still at its limit
    page = httpx.get(server.base + "/problems/owner-quota")
    assert page.status_code == 200 and "NCS_MAX_QUEUED_PER_OWNER" in page.text


def test_two_replicas_each_alternate_between_owners(db_url, start_server):
    """Two services on one database (PostgreSQL: claims with FOR UPDATE SKIP LOCKED), one worker each: A floods
    through one replica, B submits through the other; B's job starts before more than one job per worker of
    A's backlog."""
    keys = dict(NCS_WORKERS=1, NCS_API_KEYS=f"{KEY_A},{KEY_B}")
    first, second = start_server(db_url, **keys), start_server(db_url, **keys)
    assert all(r.status_code == 202 for r in _flood(first.base, KEY_A, SLOW, 200))
    b = _post(second.base, KEY_B, FAST, Prefer="wait=60")
    assert b.status_code == 201, b.text
    job = b.json()
    queued_at, started_at = _ts(job["created_at"]), _ts(job["started_at"])
    between = [s for s, _ in _starts(db_url, KEY_A) if queued_at < s < started_at]
    assert len(between) <= 2, (len(between), job)  # one per worker, two workers in all
    print(f"\ntwo replicas: B waited {(started_at - queued_at).total_seconds():.3f} s; A jobs started meanwhile: "
          f"{len(between)}")
