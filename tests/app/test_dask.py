"""The job lifecycle with the Dask backend (``NCS_DASK_SCHEDULER``).

A real ``dask.distributed.LocalCluster`` with separate worker processes (each under a
nanny, talking the scheduler's TCP protocol), and the service (ASGI app, real dispatcher
thread) submitting to it; the database is SQLite or, with NCS_TEST_DATABASE_URL, PostgreSQL.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from app.examples import PAPER_PLANT

from .conftest import REPO, running_client, wait_for, worker_pid_of

distributed = pytest.importorskip("distributed")

PAPER_LMI = {"plant": PAPER_PLANT, "n_drop": 3, "method": "lmi"}
MEDIUM = {"plant": PAPER_PLANT, "n_drop": 5, "method": "ccl", "options": {"solver": "CLARABEL"}}  # ~2 s
SLOW = {"plant": PAPER_PLANT, "n_drop": 6, "method": "ccl", "options": {"max_iter": 50, "solver": "CLARABEL"}}  # many seconds


def local_cluster() -> distributed.LocalCluster:
    """Two worker processes with nannies, one thread each, the repository importable."""
    pythonpath = os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                    worker_dashboard_address=None, env={"PYTHONPATH": pythonpath})


@pytest.fixture(scope="module")
def cluster():
    with local_cluster() as c:
        yield c


@pytest.fixture(scope="module")
def client(cluster, module_db):
    # A long cancel grace: the cancel test checks that the job stops cooperatively, not by the grace's kill.
    with running_client(module_db, dask_scheduler=cluster.scheduler_address, cancel_grace=60.0,
                        job_time_limit=60.0) as c:
        deadline = time.monotonic() + 60
        while c.get("/readyz").status_code != 200:
            assert time.monotonic() < deadline, c.get("/readyz").json()
            time.sleep(0.1)
        yield c


def wait_for_the_whole_cluster(client, timeout: float = 90.0) -> None:
    """Both workers registered and ready: a test that killed a Dask worker leaves its nanny restarting it,
    and the next kill test starts from a whole cluster."""
    deadline = time.monotonic() + timeout
    while True:
        resp = client.get("/readyz")
        workers = resp.json().get("workers", {})
        if resp.status_code == 200 and workers.get("alive") == 2 and workers.get("ready") == 2:
            return
        assert time.monotonic() < deadline, resp.json()
        time.sleep(0.1)


def test_readyz_reports_the_cluster(client):
    body = client.get("/readyz").json()
    assert body["workers"]["alive"] == 2 and body["workers"]["ready"] == 2, body


@pytest.mark.parametrize("method", ["lmi", "ccl"])
def test_paper_example_on_the_cluster_matches_the_solver(client, cluster, method):
    from solver import PlantFamily, design

    job_id = client.post("/v1/designs", json={**PAPER_LMI, "method": method}).json()["id"]
    job = wait_for(client, job_id, timeout=90)
    assert job["status"] == "succeeded", job
    assert job["result"]["outcome"] == "stabilized" and job["attempts"] == 1
    fam = PlantFamily.from_continuous(A=PAPER_PLANT["A"], B=PAPER_PLANT["B"], sampling_period=0.1)
    np.testing.assert_allclose(np.asarray(job["result"]["gains"]), design(fam, n_drop=3, method=method).gains,
                               rtol=1e-6, atol=1e-8)
    if method == "ccl":
        assert job["progress"]["iteration"] is not None
    # It ran in one of the cluster's worker processes.
    from app.jobs.database import Database
    from app.jobs.tables import Job

    db = Database(client.app.state.settings.database_url)
    with db.read() as s:
        pid = s.get(Job, job_id).worker_pid
    db.dispose()
    # ... in a job process of one of the cluster's workers, kept for the worker thread's next job.
    with distributed.Client(cluster.scheduler_address, set_as_default=False) as dc:
        assert parent_pid(pid) in set(dc.run(os.getpid).values())


def test_many_jobs_fill_both_workers(client):
    ids = [client.post("/v1/designs", json=PAPER_LMI).json()["id"] for _ in range(20)]
    jobs = [wait_for(client, i, timeout=90) for i in ids]
    assert {j["status"] for j in jobs} == {"succeeded"}
    assert all(j["attempts"] == 1 for j in jobs)


def parent_pid(pid: int) -> int:
    with open(f"/proc/{pid}/stat") as f:
        return int(f.read().rsplit(")", 1)[1].split()[1])


def is_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()[0] != "Z"


def dask_worker_pids(cluster) -> set[int]:
    with distributed.Client(cluster.scheduler_address, set_as_default=False) as dc:
        return set(dc.run(os.getpid).values())


def test_cancel_a_running_job_cooperatively(client, cluster):
    workers = dask_worker_pids(cluster)
    job_id = client.post("/v1/designs", json=SLOW).json()["id"]
    pid = worker_pid_of(client, job_id, timeout=60)
    wait_for(client, job_id, statuses=("running",))
    resp = client.post(f"/v1/designs/{job_id}/cancel")
    assert resp.status_code in (200, 202), resp.text
    job = wait_for(client, job_id, timeout=50)  # well within the 60 s grace after which it would be killed
    assert job["status"] == "cancelled", job
    # The solver stopped at its callback: its job process and the Dask workers all live on.
    assert is_alive(pid) and dask_worker_pids(cluster) == workers


def test_killed_job_process_mid_job_is_retried_and_the_worker_goes_on(client, cluster):
    wait_for_the_whole_cluster(client)
    workers = dask_worker_pids(cluster)
    job_id = client.post("/v1/designs", json=MEDIUM).json()["id"]
    first = worker_pid_of(client, job_id, timeout=60)
    os.kill(first, signal.SIGKILL)
    job = wait_for(client, job_id, timeout=120)
    assert job["status"] == "succeeded", job
    assert job["result"]["outcome"] == "stabilized"
    assert job["attempts"] == 2, job  # the run in the killed job process counted as an attempt
    assert not is_alive(first)
    assert dask_worker_pids(cluster) == workers


def test_killed_dask_worker_mid_job_is_retried_and_the_job_finishes(client, cluster):
    wait_for_the_whole_cluster(client)
    job_id = client.post("/v1/designs", json=MEDIUM).json()["id"]
    job_process = worker_pid_of(client, job_id, timeout=60)
    os.kill(parent_pid(job_process), signal.SIGKILL)  # the Dask worker; its job process dies with it
    job = wait_for(client, job_id, timeout=120)
    assert job["status"] == "succeeded", job
    assert job["result"]["outcome"] == "stabilized"
    assert job["attempts"] == 2, job  # the run on the killed worker counted as an attempt
    # The nanny restarts the killed worker; the cluster serves the next job.
    nxt = wait_for(client, client.post("/v1/designs", json=PAPER_LMI).json()["id"], timeout=90)
    assert nxt["status"] == "succeeded"


def test_time_limit_on_the_cluster_kills_the_job_process_not_the_worker(cluster, db_url):
    from solver.compiled import design_size

    # a limit the up-front estimate lets through (solver.compiled.design_size: CCL's first step and iteration, 1.9 s
    # with today's constants), far under the job's run time
    limit = max(1.5, round(1.5 * design_size("ccl", 2, 1, 3, 6, solver="CLARABEL").total_seconds, 1))
    with running_client(db_url, dask_scheduler=cluster.scheduler_address, job_time_limit=limit) as client:
        wait_for_the_whole_cluster(client)
        workers = dask_worker_pids(cluster)
        job_id = client.post("/v1/designs", json=SLOW).json()["id"]
        pid = worker_pid_of(client, job_id, timeout=60)
        job = wait_for(client, job_id, timeout=60)
        assert job["status"] == "failed" and "time limit" in job["error"] and f"{limit:g} s" in job["error"], job
        assert job["attempts"] == 1
        deadline = time.monotonic() + 30
        while is_alive(pid):
            assert time.monotonic() < deadline, "the job process outlived its time limit"
            time.sleep(0.05)
        # Both workers are the ones from before, and both still take jobs (the stopped thread with a new
        # job process).
        ids = [client.post("/v1/designs", json=PAPER_LMI).json()["id"] for _ in range(6)]
        assert {wait_for(client, i, timeout=90)["status"] for i in ids} == {"succeeded"}
        assert dask_worker_pids(cluster) == workers


def test_killed_dask_worker_with_no_attempts_left_fails_the_job_with_the_reason(cluster, db_url):
    with running_client(db_url, dask_scheduler=cluster.scheduler_address, max_attempts=1) as client:
        wait_for_the_whole_cluster(client)
        job_id = client.post("/v1/designs", json=MEDIUM).json()["id"]
        os.kill(worker_pid_of(client, job_id, timeout=60), signal.SIGKILL)
        job = wait_for(client, job_id, timeout=60)
        assert job["status"] == "failed", job
        assert "died" in job["error"] and "1 of 1 attempts" in job["error"], job["error"]
        assert job["attempts"] == 1


def test_design_over_the_memory_cap_on_the_cluster_fails_with_the_setting_named(cluster, db_url):
    from .test_limits import BIG

    with running_client(db_url, dask_scheduler=cluster.scheduler_address, worker_memory_mb=60,
                        max_attempts=3) as client:
        wait_for_the_whole_cluster(client)
        workers = dask_worker_pids(cluster)
        job = wait_for(client, client.post("/v1/designs", json=BIG).json()["id"], timeout=120)
        assert job["status"] == "failed", job
        assert "memory limit exceeded" in job["error"] and "NCS_WORKER_MEMORY_MB" in job["error"], job["error"]
        assert job["attempts"] == 1  # not retried: it would fail the same way
        assert dask_worker_pids(cluster) == workers


def test_a_replica_that_stops_releases_its_running_job_and_the_job_process_stops(cluster, db_url):
    with running_client(db_url, dask_scheduler=cluster.scheduler_address) as client:
        wait_for_the_whole_cluster(client)
        workers = dask_worker_pids(cluster)
        job_id = client.post("/v1/designs", json=SLOW).json()["id"]
        pid = worker_pid_of(client, job_id, timeout=60)
        wait_for(client, job_id, statuses=("running",))
    # The replica put the job back in the queue and cancelled its future; nobody would read the result, so
    # the task kills its job process rather than finish the job.
    deadline = time.monotonic() + 10
    while is_alive(pid):
        assert time.monotonic() < deadline, "the released job kept running"
        time.sleep(0.05)
    assert dask_worker_pids(cluster) == workers
    with running_client(db_url, dask_scheduler=cluster.scheduler_address) as client:
        job = wait_for(client, job_id, timeout=120)  # the next replica runs it again
        assert job["status"] == "succeeded" and job["attempts"] == 1, job


# -- Issue 20: a Dask worker that dies before the job's Started, and a job that kills its worker every time ----

@pytest.fixture(scope="module")
def cold_cluster():
    """A cluster of its own: its worker threads have no job process yet, so a job's first run spends seconds
    between its task beginning (``Begun``) and its job process reporting ``Started``."""
    with local_cluster() as c:
        yield c


def _run_of(client, job_id: str, seen: set, timeout: float = 120.0):
    """The next (address, Dask worker pid) the job's task began on that is not in ``seen``; None once the job
    is no longer running here."""
    disp = client.app.state.dispatcher
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        running = disp.running.get(job_id)
        if running is None and client.get(f"/v1/designs/{job_id}").json()["status"] != "queued":
            return None, None
        if running is not None and running.run is not None and running.run not in seen:
            return running.run, running.pid
        time.sleep(0.005)
    raise AssertionError(f"job {job_id} began on no new worker within {timeout} s")


def test_dask_worker_killed_between_the_claim_and_started_counts_an_attempt(cold_cluster, db_url):
    with running_client(db_url, dask_scheduler=cold_cluster.scheduler_address) as client:
        wait_for_the_whole_cluster(client)
        job_id = client.post("/v1/designs", json=MEDIUM).json()["id"]
        run, pid = _run_of(client, job_id, set())
        assert pid is None, "the job process had started already: not the window this test is about"
        os.kill(run[1], signal.SIGKILL)  # the Dask worker, while its new job process is still starting
        job = wait_for(client, job_id, timeout=180)
        assert job["status"] == "succeeded", job
        assert job["attempts"] == 2, job  # the run on the killed worker counted, though it never Started


def test_job_that_kills_its_worker_every_time_ends_failed_after_max_attempts(cold_cluster, db_url):
    with running_client(db_url, dask_scheduler=cold_cluster.scheduler_address, max_attempts=3) as client:
        wait_for_the_whole_cluster(client, timeout=180)
        job_id = client.post("/v1/designs", json=MEDIUM).json()["id"]
        seen: set = set()
        while True:
            run, _ = _run_of(client, job_id, seen, timeout=180)
            if run is None:
                break
            seen.add(run)
            try:
                os.kill(run[1], signal.SIGKILL)  # every worker the job begins on dies
            except ProcessLookupError:
                pass
        job = wait_for(client, job_id, timeout=60)
        assert job["status"] == "failed", job
        assert job["attempts"] == 3 and "3 of 3 attempts" in job["error"], job
        assert len(seen) == 3, seen
