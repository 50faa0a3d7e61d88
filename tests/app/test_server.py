"""Against the real server process (``python -m app.cli serve`` = ``ncs-design serve``, uvicorn)."""

from __future__ import annotations

import os
import signal
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import numpy as np

from app.jobs.database import Database
from app.examples import PAPER_PLANT
from app.jobs.tables import Job

TERMINAL = ("succeeded", "failed", "cancelled")
PAPER_LMI = {"plant": PAPER_PLANT, "n_drop": 3, "method": "lmi"}


def wait_all(base: str, ids: list[str], timeout: float) -> dict[str, dict]:
    deadline = time.monotonic() + timeout
    done: dict[str, dict] = {}
    with httpx.Client(base_url=base, timeout=10) as c:
        while len(done) < len(ids):
            for job_id in ids:
                if job_id not in done:
                    job = c.get(f"/v1/designs/{job_id}").json()
                    if job["status"] in TERMINAL:
                        done[job_id] = job
            if time.monotonic() > deadline:
                pending = {i: c.get(f"/v1/designs/{i}").json()["status"] for i in ids if i not in done}
                raise AssertionError(f"jobs not finished after {timeout} s: {pending}")
            time.sleep(0.1)
    return done


def test_real_server_designs_the_paper_example(db_url, start_server):
    from solver import PlantFamily, design

    server = start_server(db_url, NCS_WORKERS=1)
    resp = httpx.post(server.base + "/v1/designs", json=PAPER_LMI, timeout=10)
    assert resp.status_code == 202, resp.text
    job = wait_all(server.base, [resp.json()["id"]], timeout=60)[resp.json()["id"]]
    assert job["status"] == "succeeded", job
    fam = PlantFamily.from_continuous(A=PAPER_PLANT["A"], B=PAPER_PLANT["B"], sampling_period=0.1)
    direct = design(fam, n_drop=3, method="lmi")
    np.testing.assert_allclose(np.asarray(job["result"]["gains"]), direct.gains, rtol=1e-6, atol=1e-8)
    # The trace is byte-identical across processes (no cache involved in a fresh server).
    url = f"/v1/designs/{job['id']}/trace?seed=42&steps=100&x0=-3,2"
    first = httpx.get(server.base + url, timeout=30)
    assert first.status_code == 200
    server.stop()
    again = start_server(db_url, NCS_WORKERS=1)
    assert httpx.get(again.base + url, timeout=30).content == first.content


def _pids_alive(pids):
    alive = []
    for pid in pids:
        try:
            os.kill(pid, 0)
            with open(f"/proc/{pid}/stat") as f:
                if f.read().split()[2] != "Z":
                    alive.append(pid)
        except (ProcessLookupError, FileNotFoundError):
            pass
    return alive


def _worker_pids(server_pid: int) -> list[int]:
    try:
        with open(f"/proc/{server_pid}/task/{server_pid}/children") as f:
            return [int(p) for p in f.read().split()]
    except FileNotFoundError:
        return []


def test_sigkill_with_jobs_queued_and_running_then_restart_finishes_all(db_url, start_server):
    env = dict(NCS_WORKERS=2, NCS_LEASE_SECONDS=2, NCS_POLL_INTERVAL=0.05)
    server = start_server(db_url, **env)
    slow = {"plant": PAPER_PLANT, "n_drop": 5, "method": "ccl", "options": {"solver": "CLARABEL"}}  # ~2 s each
    with httpx.Client(base_url=server.base, timeout=10) as c:
        ids = [c.post("/v1/designs", json=slow).json()["id"] for _ in range(2)]
        ids += [c.post("/v1/designs", json=PAPER_LMI).json()["id"] for _ in range(6)]
        deadline = time.monotonic() + 30
        while c.get("/v1/designs?status=running").json()["total"] == 0:
            assert time.monotonic() < deadline, "nothing started"
            time.sleep(0.05)
    children = _worker_pids(server.proc.pid)
    server.kill()  # SIGKILL: no shutdown handler runs
    db = Database(db_url)
    with db.read() as s:
        states = {j.id: j.status for j in s.query(Job).all()}
    db.dispose()
    assert "running" in states.values() and "queued" in states.values(), states
    # The orphaned worker processes die with the service (PR_SET_PDEATHSIG).
    deadline = time.monotonic() + 5
    while _pids_alive(children) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert children and _pids_alive(children) == []
    again = start_server(db_url, **env)
    done = wait_all(again.base, ids, timeout=120)
    assert {j["status"] for j in done.values()} == {"succeeded"}, done
    assert all(j["result"]["outcome"] == "stabilized" for j in done.values())
    assert max(j["attempts"] for j in done.values()) == 2  # the running ones were retried


def test_200_concurrent_submissions(db_url, start_server):
    server = start_server(db_url, NCS_WORKERS=1)
    limits = httpx.Limits(max_connections=100, max_keepalive_connections=100)
    with httpx.Client(base_url=server.base, timeout=60, limits=limits) as c:
        def submit(i):
            return c.post("/v1/designs", json=PAPER_LMI, headers={"Idempotency-Key": f"k{i}"})

        with ThreadPoolExecutor(max_workers=100) as pool:
            responses = list(pool.map(submit, range(200)))
        problems = [r.text for r in responses if r.status_code != 202]
        assert problems == [], problems[:3]
        ids = {r.json()["id"] for r in responses}
        assert len(ids) == 200
        # Replaying concurrently returns the same jobs, creating nothing.
        with ThreadPoolExecutor(max_workers=100) as pool:
            replays = list(pool.map(submit, range(200)))
        assert {r.json()["id"] for r in replays} == ids
        assert c.get("/v1/designs").json()["total"] == 200
        assert c.get("/readyz").status_code == 200
    log = server.log.name
    server.stop()
    with open(log, "rb") as f:
        text = f.read().decode(errors="replace")
    assert "database is locked" not in text and "Traceback" not in text, text[-3000:]


def test_concurrent_requests_with_one_idempotency_key_make_one_job(db_url, start_server):
    server = start_server(db_url, NCS_WORKERS=1)
    with httpx.Client(base_url=server.base, timeout=60, limits=httpx.Limits(max_connections=40)) as c:
        def submit(_):
            return c.post("/v1/designs", json=PAPER_LMI, headers={"Idempotency-Key": "same-key"})

        with ThreadPoolExecutor(max_workers=40) as pool:
            responses = list(pool.map(submit, range(40)))
        assert {r.status_code for r in responses} == {202}
        assert len({r.json()["id"] for r in responses}) == 1
        assert c.get("/v1/designs").json()["total"] == 1


def test_sigterm_gives_running_jobs_back_without_using_an_attempt(db_url, start_server):
    env = dict(NCS_WORKERS=1)
    server = start_server(db_url, **env)
    slow = {"plant": PAPER_PLANT, "n_drop": 5, "method": "ccl", "options": {"solver": "CLARABEL"}}
    with httpx.Client(base_url=server.base, timeout=10) as c:
        job_id = c.post("/v1/designs", json=slow).json()["id"]
        deadline = time.monotonic() + 30
        while c.get(f"/v1/designs/{job_id}").json()["status"] != "running":
            assert time.monotonic() < deadline
            time.sleep(0.05)
    server.proc.terminate()  # SIGTERM: graceful shutdown
    # uvicorn shuts down gracefully, then re-raises the signal (exit status -15).
    assert server.proc.wait(20) in (0, -signal.SIGTERM)
    db = Database(db_url)
    with db.read() as s:
        row = s.get(Job, job_id)
        assert row.status == "queued" and row.attempts == 0
    db.dispose()
    again = start_server(db_url, **env)
    job = wait_all(again.base, [job_id], timeout=120)[job_id]
    assert job["status"] == "succeeded" and job["attempts"] == 1
