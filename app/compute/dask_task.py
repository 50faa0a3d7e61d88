"""What runs inside a Dask worker process (see ``app.jobs.dask_executor`` for the service side).

Kept lean on purpose: it imports no web framework and needs no database access;
a Dask worker only needs this package installed (``pip install ncs-design``).

* :func:`run_job` is the task. The job itself runs in a *job process*: a child of the Dask
  worker, one per worker thread, started on the thread's first job and kept for the next
  ones. It is the local executor's worker process (``app.compute.worker.worker_main``:
  the same messages, one BLAS thread, the memory cap, death with its parent), so a job
  behaves the same on both executors. The task reports ``Started`` (worker address and
  the job process's pid) and throttled ``Progress`` through Dask's structured events
  (``Worker.log_event``: fire-and-forget, batched, forwarded by the scheduler to the
  subscribed service; the messages travel as plain dicts, ``messages.to_event``), and
  returns the job process's outcome: ``Succeeded``, ``Cancelled``, ``Failed``, or ``Lost``
  when the job process died under it.
* :func:`request_cancel`, run on the worker by the service (``Client.run``), cancels a
  running job cooperatively: the task passes it to the job process, whose solver callback
  stops at its next iteration. A task whose future the service cancelled (a job given up,
  or released by a replica that shuts down) kills its job process: its result would be
  dropped.
* :func:`stop_job` stops a job now (time limit, or a cancel not honoured within the grace):
  it kills the job process, not the Dask worker. Restarting a whole worker through its
  nanny (``Client.restart_workers``) would also end the jobs of the worker's other threads,
  and on ``distributed`` 2026.8 a worker restarted while another one of the cluster died
  sometimes never came back (reproduced on a ``LocalCluster``, see docs/design.md §6).
"""

from __future__ import annotations

import dataclasses
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection
from typing import Any

from app.compute.messages import (Begun, Cancel, Cancelled, Failed, JobOutcome, Lost, Progress, Ready, Run, Started,
                                  Succeeded, to_event)

START_TOPIC = "ncs-design-start"
PROGRESS_TOPIC = "ncs-design-progress"
START_TIMEOUT = 120.0  # seconds a new job process may take to import the solver and report Ready
POLL_EVERY = 0.05  # seconds between the task's checks for a cancel while it waits on its job process

_lock = threading.Lock()
# By task key (job id and attempt, unique per submission): two attempts of one job can run on one worker at
# once (a crashed replica's task goes on while another replica re-submits the job).
_running: dict[str, "JobProcess"] = {}  # task key -> the job process running it
_cancelled: set[str] = set()  # tasks asked to stop cooperatively
_stopped: set[str] = set()  # tasks whose job process was killed on purpose
_processes: dict[int, "JobProcess"] = {}  # worker thread id -> its job process


async def request_cancel(key: str) -> bool:
    """Cooperative cancel of the task ``key``, run on the worker's event loop (``Client.run``, which can only
    skip waiting for a coroutine function's answer). Returns whether this worker is running the task."""
    with _lock:
        if key not in _running:
            return False
        _cancelled.add(key)
    return True


async def stop_job(key: str) -> bool:
    """Kill the job process running the task ``key`` (SIGKILL); the worker and its other threads go on.
    Returns whether this worker was running the task."""
    return _stop(key)


def _stop(key: str) -> bool:
    with _lock:  # held while killing: the task cannot hand its process to the thread's next job meanwhile
        process = _running.get(key)
        if process is None:
            return False
        _stopped.add(key)
        process.kill()
    return True


class JobProcess:
    """A child process running ``worker_main``, talking over a socket pair (``multiprocessing`` cannot start
    children of a Dask worker, a daemonic process)."""

    def __init__(self, memory_mb: int):
        parent_sock, child_sock = socket.socketpair()
        code = ("import sys; from app.compute.dask_task import job_process_main; "
                "job_process_main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))")
        try:
            self.popen = subprocess.Popen(
                [sys.executable, "-c", code, str(child_sock.fileno()), str(os.getpid()), str(memory_mb)],
                pass_fds=(child_sock.fileno(),), stdin=subprocess.DEVNULL)
        except BaseException:
            parent_sock.close()
            raise
        finally:
            child_sock.close()
        self.conn = Connection(parent_sock.detach())
        self.pid = self.popen.pid
        self.memory_mb = memory_mb

    def wait_ready(self, timeout: float) -> bool:
        """Wait for the job process's Ready (it imports the solver first); False if it died or took too long."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                if self.conn.poll(0.2) and isinstance(self.conn.recv(), Ready):
                    return True
            except (EOFError, OSError):
                return False
            if self.popen.poll() is not None:
                return False
        return False

    def alive(self) -> bool:
        return self.popen.poll() is None

    def kill(self) -> None:
        try:
            self.popen.send_signal(signal.SIGKILL)
        except OSError:  # pragma: no cover - already gone
            pass

    def reap(self) -> int | None:
        """Wait for the (dying or killed) process to exit; its exit code (None if it lingers)."""
        try:
            return self.popen.wait(5)
        except subprocess.TimeoutExpired:  # pragma: no cover - a killed process in uninterruptible I/O
            self.kill()
            return None

    def close(self) -> None:
        self.kill()
        self.reap()
        self.conn.close()


def job_process_main(fd: int, parent_pid: int, memory_mb: int) -> None:
    """Entry point of a job process (see :class:`JobProcess`)."""
    from app.compute.worker import worker_main

    worker_main(Connection(fd), parent_pid, memory_mb)


def _job_process(memory_mb: int) -> JobProcess | None:
    """This worker thread's job process, started (and awaited) if it has none, it died, or it has another
    memory cap (replicas may differ); None if it could not start."""
    thread = threading.get_ident()
    process = _processes.get(thread)
    if process is not None and process.alive() and process.memory_mb == memory_mb:
        return process
    if process is not None:
        process.close()
        _processes.pop(thread, None)
    _forget_exited_threads()
    try:
        process = JobProcess(memory_mb)
    except OSError:  # no process could be started (file descriptors, memory): the job may run elsewhere
        return None
    if not process.wait_ready(START_TIMEOUT):
        process.close()
        return None
    _processes[thread] = process
    return process


def _forget_exited_threads() -> None:
    """Close the job processes of worker threads that exited (Dask's pool retires a thread that rejoins after
    ``secede``). The process got SIGKILL with its thread (PR_SET_PDEATHSIG follows the thread that started
    it); what is left is to reap it and close its socket."""
    alive = {t.ident for t in threading.enumerate()}
    for thread in [t for t in _processes if t not in alive]:
        _processes.pop(thread).close()


def _released(worker: Any, key: str) -> bool:
    """Whether the scheduler no longer wants the task: the service cancelled its future (a job given up,
    a cancel before the job started, a replica shutting down), so its result would be dropped."""
    ts = worker.state.tasks.get(key)
    return ts is None or ts.state in ("cancelled", "released", "forgotten")


def run_job(job_id: str, key: str, request: dict[str, Any], memory_mb: int = 0) -> JobOutcome | Lost:
    """The Dask task: run one job in this worker thread's job process (see the module docstring)."""
    from distributed import get_worker

    from app.compute.worker import outcome_of_death

    worker = get_worker()
    # First, before the job process starts (seconds when it is new): a worker that dies from here on has
    # cost this job an attempt, and the service can tell (messages.Begun).
    worker.log_event(START_TOPIC, to_event(key, Begun(job_id, os.getpid(), worker.address)))
    process = _job_process(memory_mb)
    if process is None:
        return Lost(job_id, f"the job process on Dask worker {worker.address} could not start")
    if _released(worker, key):
        return Cancelled(job_id)  # given up while the job process started: nobody waits for this job
    with _lock:
        _running[key] = process
    worker.log_event(START_TOPIC, to_event(key, Started(job_id, process.pid, worker.address)))
    last: dict[str, Any] | None = None
    cancel_sent = False
    try:
        process.conn.send(Run(job_id, request))
        while True:
            if not cancel_sent and key in _cancelled:
                process.conn.send(Cancel(job_id))
                cancel_sent = True
            if not process.conn.poll(POLL_EVERY):
                if _released(worker, key):
                    # Given up by the service (e.g. a replica released it on shutdown; it runs again
                    # elsewhere): finishing it would only hold this thread.
                    _stop(key)
                continue
            msg = process.conn.recv()
            if isinstance(msg, Progress) and msg.job_id == job_id:
                last = msg.record  # at most one every worker.PROGRESS_EVERY seconds
                worker.log_event(PROGRESS_TOPIC, to_event(key, msg))
            elif isinstance(msg, (Succeeded, Cancelled, Failed)) and msg.job_id == job_id:
                return msg if msg.progress is not None else dataclasses.replace(msg, progress=last)
    except (EOFError, OSError):
        code = process.reap()
        if key in _stopped:
            return Cancelled(job_id, progress=last)  # the service stopped it and no longer waits for it
        return outcome_of_death(job_id, process.pid, code, memory_mb)
    finally:
        with _lock:
            _running.pop(key, None)
            _cancelled.discard(key)
            _stopped.discard(key)
