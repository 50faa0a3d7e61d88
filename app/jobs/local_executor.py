"""The local executor: ``NCS_WORKERS`` long-lived worker processes (``spawn`` start method; see
``app.compute.worker``), one job at a time each, talking over a pipe.

A worker that dies is replaced; the job it ran is reported ``Lost`` (the dispatcher retries it), or
``Failed`` when it aborted under the memory cap (it would abort again). A worker that dies before it
became ready is restarted with a growing back-off, so a broken install does not spin.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import time
from typing import Any, Callable

from app.compute.messages import (Cancel, Cancelled, ExecutorEvent, Failed, Progress, Ready, Run, Started,
                                  Stop, Succeeded)
from app.compute.worker import outcome_of_death
from app.jobs.executor import Executor, FreeSlot
from app.jobs.store import Claimed
from app.settings import Settings

log = logging.getLogger("app.dispatcher")
_CTX = mp.get_context("spawn")


class _Worker:
    def __init__(self, index: int):
        self.index = index
        self.proc: Any = None
        self.conn: Any = None
        self.pid: int | None = None
        self.ready = False
        self.job_id: str | None = None
        self.spawn_after = 0.0  # monotonic time before which no replacement is started
        self.backoff = 0.0      # grows while workers die before they become ready

    def alive(self) -> bool:
        return self.proc is not None and self.proc.is_alive()


class LocalExecutor(Executor):
    def __init__(self, settings: Settings):
        self.settings = settings
        self.workers = [_Worker(i) for i in range(settings.workers)]
        self.started_workers = 0
        self._events: list[ExecutorEvent] = []
        self._start_error: str | None = None
        self._stopping = False

    # -- Executor -------------------------------------------------------------
    def start(self, wake: Callable[[], None]) -> None:
        for worker in self.workers:
            self._spawn(worker)

    def maintain(self, now: float) -> None:
        for worker in self.workers:
            self._check(worker, now)

    def free_slots(self) -> list[FreeSlot]:
        return [FreeSlot(w.pid, w) for w in self.workers if w.job_id is None and w.ready and w.alive()]

    def submit(self, slot: FreeSlot, job: Claimed) -> _Worker:
        worker: _Worker = slot.token
        worker.job_id = job.id
        self._events.append(Started(job.id, worker.pid or 0))
        try:
            worker.conn.send(Run(job.id, job.request))
        except (OSError, ValueError):
            pass  # a dead worker: the next maintain() reports the job lost
        return worker

    def poll(self) -> list[ExecutorEvent]:
        for worker in self.workers:
            self._drain(worker)
        events, self._events = self._events, []
        return events

    def waitables(self) -> list[Any]:
        out: list[Any] = []
        for w in self.workers:
            if w.conn is not None:
                out.append(w.conn)
            if w.proc is not None:
                out.append(w.proc.sentinel)
        return out

    def cancel(self, handle: _Worker) -> None:
        try:
            handle.conn.send(Cancel(handle.job_id))
        except (AttributeError, OSError, ValueError):
            pass  # dead worker: maintain() reports it

    def stop(self, handle: _Worker, interrupt: bool = True) -> None:
        # A worker busy with a job cannot take another: kill it whatever ``interrupt`` says.
        handle.job_id = None
        self._respawn(handle)

    def shutdown(self) -> None:
        self._stopping = True
        for worker in self.workers:
            if worker.conn is not None:
                try:
                    worker.conn.send(Stop())
                except (OSError, ValueError):
                    pass
        deadline = time.monotonic() + 2.0
        for worker in self.workers:
            if worker.proc is not None:
                worker.proc.join(max(0.0, deadline - time.monotonic()))
            self._kill(worker)

    def configured_workers(self) -> int:
        return len(self.workers)

    def alive_workers(self) -> int:
        return sum(1 for w in self.workers if w.alive())

    def ready_workers(self) -> int:
        return sum(1 for w in self.workers if w.ready and w.alive())

    @property
    def error(self) -> str | None:
        return self._start_error

    def worker_pids(self) -> list[int]:
        return [w.pid for w in self.workers if w.pid]

    # -- worker processes --------------------------------------------------------
    def _spawn(self, worker: _Worker) -> None:
        from app.compute.worker import worker_main

        parent_conn, child_conn = _CTX.Pipe(duplex=True)
        proc = _CTX.Process(target=worker_main, args=(child_conn, os.getpid(), self.settings.worker_memory_mb),
                            name=f"ncs-worker-{worker.index}", daemon=True)
        proc.start()
        child_conn.close()
        worker.proc, worker.conn, worker.pid, worker.ready = proc, parent_conn, proc.pid, False
        self.started_workers += 1

    def _kill(self, worker: _Worker) -> None:
        if worker.proc is not None:
            try:
                worker.proc.kill()
                worker.proc.join(5)
            except Exception:  # pragma: no cover
                pass
        if worker.conn is not None:
            try:
                worker.conn.close()
            except Exception:  # pragma: no cover
                pass
        worker.proc = worker.conn = None
        worker.pid = None
        worker.ready = False

    def _respawn(self, worker: _Worker) -> None:
        never_ready = worker.proc is not None and not worker.ready
        self._kill(worker)
        if never_ready and worker.job_id is None:
            # It died while starting (e.g. the solver cannot be imported): back off, don't spin.
            worker.backoff = min(30.0, max(1.0, worker.backoff * 2))
            worker.spawn_after = time.monotonic() + worker.backoff
            self._start_error = (f"worker process {worker.index} exited during start-up; "
                                 f"retrying in {worker.backoff:g} s")
            return
        worker.backoff = 0.0
        if not self._stopping:
            self._spawn(worker)

    def _drain(self, worker: _Worker) -> None:
        if worker.conn is None:
            return
        try:
            while worker.conn.poll():
                self._handle(worker, worker.conn.recv())
        except (EOFError, OSError):
            pass  # the process is dead; maintain() handles it

    def _handle(self, worker: _Worker, msg: Any) -> None:
        if isinstance(msg, Ready):
            worker.ready, worker.pid, worker.backoff = True, msg.pid, 0.0
            self._start_error = None
            return
        if not isinstance(msg, (Progress, Succeeded, Cancelled, Failed)) or msg.job_id != worker.job_id:
            return  # a stale message of a job given up
        if not isinstance(msg, Progress):
            worker.job_id = None
        self._events.append(msg)

    def _check(self, worker: _Worker, now: float) -> None:
        if worker.proc is None:
            if now >= worker.spawn_after and not self._stopping:
                self._spawn(worker)
            return
        if worker.alive():
            return
        self._drain(worker)  # its last words (a result sent just before it exited) count
        code = worker.proc.exitcode
        job_id, worker.job_id = worker.job_id, None
        if job_id is None:
            log.warning("idle worker %s died (exit %s); replacing it", worker.pid, code)
        else:
            self._events.append(outcome_of_death(job_id, worker.pid, code, self.settings.worker_memory_mb))
        self._respawn(worker)
