"""Readiness that tells the truth (issue 20), on a real server: ``/readyz`` is 503 naming the cause while the
database cannot take a write (SQLite files made immutable, or locked by another writer), 200 after; the
submissions' 503 names the same cause; the process survives (an immutable WAL index used to end it with
SIGBUS); a submission's wait is bounded by NCS_DATABASE_BUSY_TIMEOUT plus a margin."""

from __future__ import annotations

import sqlite3
import subprocess
import time
from pathlib import Path

import httpx
import pytest

from app.jobs.database import sqlite_files
from bench.harness import FAST

from .conftest import PG_URL

sqlite_only = pytest.mark.skipif(bool(PG_URL), reason="SQLite files and locks; PostgreSQL's read-only case is "
                                                      "tests/app/test_faults.py")


def _chattr(flag: str, files: list[Path]) -> None:
    subprocess.run(["chattr", flag, *map(str, files)], check=True, capture_output=True, timeout=10)


def _readyz_until(base: str, status: int, timeout: float = 30.0) -> httpx.Response:
    deadline = time.monotonic() + timeout
    while True:
        r = httpx.get(base + "/readyz", timeout=10)
        if r.status_code == status or time.monotonic() > deadline:
            return r
        time.sleep(0.1)


@sqlite_only
def test_readyz_503_while_the_sqlite_files_are_immutable_and_the_process_survives(db_url, start_server):
    server = start_server(db_url, NCS_WORKERS=1)
    first = httpx.post(server.base + "/v1/designs", json=FAST, headers={"Prefer": "wait=60"}, timeout=90)
    assert first.status_code == 201, first.text  # the WAL and its memory-mapped index exist and are in use
    files = [f for f in sqlite_files(db_url) if f.exists()]
    assert len(files) == 3, files
    try:
        _chattr("+i", files)
    except (OSError, subprocess.CalledProcessError) as exc:
        pytest.skip(f"chattr +i is not available here ({exc}); it needs root and a file system with attributes")
    try:
        ready = _readyz_until(server.base, 503)
        assert ready.status_code == 503, ready.text
        assert "read-only" in ready.json()["checks"]["database"], ready.json()
        for _ in range(5):
            resp = httpx.post(server.base + "/v1/designs", json=FAST, timeout=60)
            assert resp.status_code == 503, resp.text
            assert "read-only" in resp.json()["detail"] and resp.headers["retry-after"], resp.json()
        time.sleep(1.0)  # the dispatcher ticks meanwhile
        assert server.proc.poll() is None, f"the service died: exit {server.proc.returncode}"
    finally:
        _chattr("-i", files)
    assert _readyz_until(server.base, 200).status_code == 200
    after = httpx.post(server.base + "/v1/designs", json=FAST, headers={"Prefer": "wait=60"}, timeout=90)
    assert after.status_code == 201 and after.json()["status"] == "succeeded", after.text
    assert server.proc.poll() is None


@sqlite_only
def test_readyz_503_locked_while_another_process_holds_the_write_lock_and_submissions_wait_a_bounded_time(
        db_url, start_server):
    busy = 2.0
    server = start_server(db_url, NCS_WORKERS=1, NCS_DATABASE_BUSY_TIMEOUT=busy)
    path = sqlite_files(db_url)[0]
    holder = sqlite3.connect(path, timeout=5, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")  # another writer holds the lock
    try:
        ready = _readyz_until(server.base, 503)
        assert ready.status_code == 503 and "locked" in ready.json()["checks"]["database"], ready.text
        waits = []
        for _ in range(3):
            t0 = time.monotonic()
            resp = httpx.post(server.base + "/v1/designs", json=FAST, timeout=60)
            waits.append(time.monotonic() - t0)
            assert resp.status_code == 503 and "locked" in resp.json()["detail"], resp.text
        print(f"\nsubmission waits under a held lock (busy timeout {busy} s): {[round(w, 2) for w in waits]} s")
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    assert _readyz_until(server.base, 200).status_code == 200
    # Nothing refused was written.
    listing = httpx.get(server.base + "/v1/designs").json()
    assert listing["total"] == 0, listing


def test_a_submission_the_dispatcher_has_not_taken_by_the_bound_is_withdrawn_and_answered_503():
    """The dispatcher stuck in another write (heartbeat, progress...) past a submission's bound: the handler
    takes the submission back (it is never written) and answers 503 with the cause; one already in a write is
    awaited (its lock wait is bounded by what was left)."""
    import asyncio

    from sqlalchemy.exc import OperationalError

    from app.api.job_routes import _bounded
    from app.jobs.database import database_reason

    class Stuck:
        submit_wait_bound = 0.05
        tick_error = None

        def __init__(self, taken: bool):
            self.taken, self.asked = taken, 0

        def withdraw(self, fut) -> bool:
            self.asked += 1
            if self.taken:
                fut.get_loop().call_later(0.05, fut.set_result, "written")
            return not self.taken

    async def run(dispatcher):
        return await _bounded(dispatcher, asyncio.get_running_loop().create_future())

    withdrawn = Stuck(taken=False)
    with pytest.raises(OperationalError) as err:
        asyncio.run(run(withdrawn))
    assert withdrawn.asked == 1 and "locked" in database_reason(err.value), err.value
    in_write = Stuck(taken=True)
    assert asyncio.run(run(in_write)) == "written" and in_write.asked == 1
