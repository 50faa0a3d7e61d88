"""Several service replicas on one database never run a job twice.

Two real ``ncs-design serve`` processes (uvicorn, each with its own dispatcher and worker
pool) share one database (PostgreSQL in the CI's second run, where claims use
``SELECT ... FOR UPDATE SKIP LOCKED``; an SQLite file in the first run). Executions are
counted on the worker side: a ``sitecustomize`` module on the servers' PYTHONPATH wraps
``app.compute.tasks.run_design`` in every process (service and spawned workers) and appends one
line per execution to a file, tagged by the job's unique ``max_iter``.
"""

from __future__ import annotations

import os
import textwrap
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

import httpx

from app.examples import PAPER_PLANT

from .conftest import REPO

JOBS = 60

SITECUSTOMIZE = '''
import os

_log = os.environ.get("NCS_TEST_EXECUTION_LOG")
if _log:
    import app.compute.tasks as _tasks

    _orig = _tasks.run_design

    def run_design(request, callback=None):
        tag = (request.get("options") or {}).get("max_iter")
        fd = os.open(_log, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, f"{tag} {os.getpid()}\\n".encode())
        finally:
            os.close(fd)
        return _orig(request, callback)

    _tasks.run_design = run_design
'''


def _children(pid: int) -> set[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return {int(p) for p in f.read().split()}
    except FileNotFoundError:
        return set()


def test_two_server_processes_on_one_database_run_every_job_exactly_once(db_url, start_server, tmp_path):
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(textwrap.dedent(SITECUSTOMIZE))
    log = tmp_path / "executions.log"
    pythonpath = os.pathsep.join([str(hook), str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env = dict(NCS_WORKERS=2, NCS_POLL_INTERVAL=0.05, NCS_LEASE_SECONDS=5,
               PYTHONPATH=pythonpath, NCS_TEST_EXECUTION_LOG=str(log))
    a = start_server(db_url, **env)
    b = start_server(db_url, **env)
    workers = {a.base: _children(a.proc.pid), b.base: _children(b.proc.pid)}

    def submit(i: int) -> str:
        base = (a, b)[i % 2].base
        body = {"plant": PAPER_PLANT, "n_drop": 3, "method": "lmi", "options": {"max_iter": 100 + i}}
        resp = httpx.post(base + "/v1/designs", json=body, timeout=30)
        assert resp.status_code == 202, resp.text
        return resp.json()["id"]

    with ThreadPoolExecutor(8) as pool:
        ids = list(pool.map(submit, range(JOBS)))

    deadline = time.monotonic() + 120
    with httpx.Client(base_url=a.base, timeout=30) as c:
        while True:
            page = c.get("/v1/designs", params={"status": "succeeded", "limit": 100}).json()
            if page["total"] >= JOBS:
                break
            assert time.monotonic() < deadline, c.get("/v1/designs", params={"limit": 100}).json()
            time.sleep(0.2)
        jobs = [c.get(f"/v1/designs/{i}").json() for i in ids]
    assert all(j["status"] == "succeeded" and j["result"]["outcome"] == "stabilized" for j in jobs)
    assert [j["attempts"] for j in jobs] == [1] * JOBS

    lines = log.read_text().split()
    tags = Counter(int(t) for t in lines[0::2])
    assert tags == Counter(range(100, 100 + JOBS)), tags  # each job executed exactly once
    pids = {int(p) for p in lines[1::2]}
    # Both replicas did work, each in its own worker processes.
    assert pids & workers[a.base] and pids & workers[b.base], (pids, workers)
