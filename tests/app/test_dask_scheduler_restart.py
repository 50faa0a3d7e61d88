"""A Dask scheduler that dies and comes back: real ``dask scheduler`` and ``dask worker`` processes on
loopback, two service replicas (ASGI apps with their own dispatcher threads) on one database.

Dask's workers stop with their scheduler, so the outage ends when both are started again (as a
supervisor would). Every replica must then recover by itself within 30 s, without a restart; /readyz
is 503 while no scheduler is reachable; no job is lost; and the outage costs a job at most one attempt.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from contextlib import ExitStack
from pathlib import Path

import pytest

from app.examples import PAPER_PLANT

from .conftest import REPO, free_port, running_client, wait_for

pytest.importorskip("distributed")

DASK = str(Path(sys.executable).with_name("dask"))
MEDIUM = {"plant": PAPER_PLANT, "n_drop": 5, "method": "ccl", "options": {"solver": "CLARABEL"}}  # a couple of seconds each


class DaskProcesses:
    """A scheduler on a fixed loopback port and one worker process (two threads) under its nanny."""

    def __init__(self, port: int, log_dir: Path):
        self.port, self.log_dir = port, log_dir
        self.address = f"tcp://127.0.0.1:{port}"
        self.procs: list[subprocess.Popen] = []

    def _spawn(self, *args: str, name: str) -> subprocess.Popen:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
        log = open(self.log_dir / f"{name}.log", "ab")
        proc = subprocess.Popen([DASK, *args], env=env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
        self.procs.append(proc)
        return proc

    def start(self) -> None:
        self.scheduler = self._spawn("scheduler", "--host", "127.0.0.1", "--port", str(self.port),
                                     "--no-dashboard", name="scheduler")
        self.worker = self._spawn("worker", self.address, "--nworkers", "1", "--nthreads", "2",
                                  "--no-dashboard", "--host", "127.0.0.1", name="worker")

    def kill(self) -> None:
        """SIGKILL the scheduler (the outage) and the worker's process group (it would stop by itself)."""
        for proc in (self.scheduler, self.worker):
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait(10)

    def stop(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                proc.wait(10)


def wait_status(client, code: int, timeout: float) -> float:
    t0 = time.monotonic()
    while client.get("/readyz").status_code != code:
        assert time.monotonic() - t0 < timeout, (code, client.get("/readyz").json())
        time.sleep(0.1)
    return time.monotonic() - t0


def test_every_replica_recovers_from_a_scheduler_restart_and_no_job_is_lost(db_url, tmp_path):
    dask = DaskProcesses(free_port(), tmp_path)
    with ExitStack() as stack:
        stack.callback(dask.stop)
        dask.start()
        settings = dict(dask_scheduler=dask.address, job_time_limit=120.0, max_attempts=3, lease_seconds=10.0)
        replicas = [stack.enter_context(running_client(db_url, **settings)) for _ in range(2)]
        for c in replicas:
            wait_status(c, 200, 90)
        ids = [replicas[i % 2].post("/v1/designs", json=MEDIUM).json()["id"] for i in range(6)]
        # Kill the scheduler while jobs run.
        deadline = time.monotonic() + 60
        while not any(c.get(f"/v1/designs/{i}").json()["status"] == "running" for c in replicas for i in ids):
            assert time.monotonic() < deadline
            time.sleep(0.05)
        dask.kill()
        for c in replicas:
            wait_status(c, 503, 5)  # not ready while no scheduler is reachable
        time.sleep(2)
        for c in replicas:
            assert c.get("/readyz").status_code == 503
        dask.start()
        for c in replicas:
            assert wait_status(c, 200, 30) < 30  # recovered by itself
        for i in ids:
            job = wait_for(replicas[0], i, timeout=180)
            assert job["status"] == "succeeded", job
            assert job["attempts"] <= 2, job  # one outage, at most one attempt
        # And the recovered replicas take new work.
        for c in replicas:
            job = wait_for(c, c.post("/v1/designs", json={**MEDIUM, "method": "lmi"}).json()["id"], timeout=60)
            assert job["status"] == "succeeded" and job["attempts"] == 1, job
