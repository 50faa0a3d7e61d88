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
        # Reads fail too, as docs/service.md says (issue 33, item 5): SQLite writes its WAL index (-shm) even to
        # read, and that write to an immutable file would end the process, so no connection is used at all.
        for path in (f"/v1/designs/{first.json()['id']}", "/v1/designs"):
            resp = httpx.get(server.base + path, timeout=60)
            assert resp.status_code == 503 and "read-only" in resp.json()["detail"], resp.text
        time.sleep(1.0)  # the dispatcher ticks meanwhile
        assert server.proc.poll() is None, f"the service died: exit {server.proc.returncode}"
    finally:
        _chattr("-i", files)
    assert _readyz_until(server.base, 200).status_code == 200
    after = httpx.post(server.base + "/v1/designs", json=FAST, headers={"Prefer": "wait=60"}, timeout=90)
    assert after.status_code == 201 and after.json()["status"] == "succeeded", after.text
    assert server.proc.poll() is None


def test_service_docs_say_reads_fail_on_immutable_files():
    """docs/service.md promised reads are served whatever refuses writes; on immutable files they are not (above)."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "service.md").read_text()
    assert 'immutable (`chattr +i`): then **reads get the same 503 "read-only"**' in text


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


@pytest.fixture
def small_mount(tmp_path):
    """A 3 MiB tmpfs (root only): a file system that can really fill up."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    try:
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(mnt)], check=True,
                       capture_output=True, timeout=10)
    except (OSError, subprocess.CalledProcessError) as exc:
        pytest.skip(f"cannot mount a tmpfs here ({exc}); it needs root")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True, timeout=10)


def _fill(path: Path) -> None:
    with open(path, "wb") as f:
        try:
            while True:
                f.write(b"\0" * 65536)
                f.flush()
        except OSError:
            pass


def test_readyz_503_full_while_the_file_system_is_full(small_mount):
    """Issue 33, item 4: every write got 503 "the database is full" while /readyz answered 200 (its probe writes
    nothing, which a full disk allows)."""
    from .conftest import running_client

    url = f"sqlite:///{small_mount / 'ncs.db'}"
    with running_client(url, run_dispatcher=False) as client:
        assert client.get("/readyz").status_code == 200
        filler = small_mount / "filler"
        _fill(filler)
        try:
            time.sleep(1.1)  # the probe's answer is reused for 1 s
            ready = client.get("/readyz")
            assert ready.status_code == 503, ready.text
            assert "full" in ready.json()["checks"]["database"], ready.json()
            write = client.post("/v1/designs", json=FAST)
            assert write.status_code == 503 and "full" in write.json()["detail"], write.text
        finally:
            filler.unlink()
        time.sleep(1.1)
        assert client.get("/readyz").status_code == 200
        assert client.post("/v1/designs", json=FAST).status_code == 202
