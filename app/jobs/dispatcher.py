"""Dispatcher: claims queued jobs from the database and runs them on a pool
of worker processes.

One daemon thread per service process. It owns ``workers`` long-lived
worker processes (``spawn`` start method; see ``app.compute.worker``), and in a
loop it

* reads worker messages (progress -> job row, results -> finished job),
* replaces dead workers and retries their job (bounded by ``max_attempts``),
* kills a worker whose job exceeded ``job_time_limit`` (job -> failed),
* forwards cancel requests (cooperative first, kill after ``cancel_grace``),
* renews the leases of its running jobs and re-queues jobs whose lease
  expired (their service was killed),
* claims a queued job for every idle worker.

It sleeps in ``multiprocessing.connection.wait`` on the worker pipes, the
process sentinels and a self-pipe that ``notify()`` writes to, so it reacts
immediately to results, deaths and new submissions.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import threading
import time
import uuid
from multiprocessing.connection import wait as mp_wait
from typing import Any, Callable

from sqlalchemy.exc import DBAPIError

from app.compute.messages import Cancel, Cancelled, Failed, Progress, Ready, Run, Stop, Succeeded

from app.jobs import store as jobs
from app.jobs.database import Database
from app.jobs.model import Status
from app.jobs.database import database_reason
from app.settings import Settings

log = logging.getLogger("app.dispatcher")
_CTX = mp.get_context("spawn")


class _Slot:
    def __init__(self, index: int):
        self.index = index
        self.proc: Any = None
        self.conn: Any = None
        self.pid: int | None = None
        self.ready = False
        self.job_id: str | None = None
        self.attempt = 0
        self.started = 0.0
        self.cancel_sent: float | None = None
        self.progress: dict[str, Any] | None = None
        self.progress_written = 0.0
        self.progress_dirty = False
        self.spawn_after = 0.0  # monotonic time before which no replacement is started
        self.backoff = 0.0      # grows while workers die before they become ready
        # A finished job whose final write failed (database full, read-only or unreachable): kept here and
        # written again every tick until it succeeds, so the result is never lost and never half-written.
        self.pending: tuple[str, str, dict[str, Any]] | None = None
        # The Dask executor's handle on the slot's task (app.jobs.dask_executor): its key, future and the
        # address of the worker running it; unused by the local pool.
        self.key: str | None = None
        self.future: Any = None
        self.address: str | None = None

    def clear_job(self) -> None:
        self.job_id = None
        self.cancel_sent = None
        self.progress = None
        self.progress_dirty = False


class Dispatcher:
    def __init__(self, db: Database, settings: Settings, on_finished: Callable[[str], None] | None = None):
        self.db = db
        self.settings = settings
        # Told the id of every job this dispatcher finished, once its end is recorded (Prefer: wait).
        self.on_finished = on_finished or (lambda job_id: None)
        self.owner = f"{os.uname().nodename[:20]}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.slots = [_Slot(i) for i in range(settings.workers)]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._last_heartbeat = 0.0
        self._last_recover = 0.0
        self._last_cancel_check = 0.0
        self.tick_error: str | None = None   # last database/dispatcher error, cleared by a good tick
        self.start_error: str | None = None  # a worker failed to start, cleared when one is ready
        self.started_workers = 0

    # -- public -----------------------------------------------------------
    def start(self) -> None:
        for slot in self.slots:
            self._spawn(slot)
        self._thread = threading.Thread(target=self._run, name="ncs-dispatcher", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        self.notify()
        if self._thread is not None:
            self._thread.join(timeout)
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    def notify(self) -> None:
        try:
            os.write(self._wake_w, b"x")
        except (BlockingIOError, OSError):
            pass

    @property
    def error(self) -> str | None:
        return "; ".join(e for e in (self.tick_error, self.start_error) if e) or None

    def thread_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def alive_workers(self) -> int:
        return sum(1 for s in self.slots if s.proc is not None and s.proc.is_alive())

    def ready_workers(self) -> int:
        return sum(1 for s in self.slots if s.ready and s.proc is not None and s.proc.is_alive())

    def worker_pids(self) -> list[int]:
        return [s.pid for s in self.slots if s.pid]

    # -- worker processes --------------------------------------------------
    def _spawn(self, slot: _Slot) -> None:
        from app.compute.worker import worker_main

        parent_conn, child_conn = _CTX.Pipe(duplex=True)
        proc = _CTX.Process(target=worker_main, args=(child_conn, os.getpid(), self.settings.worker_memory_mb),
                            name=f"ncs-worker-{slot.index}", daemon=True)
        proc.start()
        child_conn.close()
        slot.proc, slot.conn, slot.pid, slot.ready = proc, parent_conn, proc.pid, False
        self.started_workers += 1

    def _kill(self, slot: _Slot) -> None:
        if slot.proc is not None:
            try:
                slot.proc.kill()
                slot.proc.join(5)
            except Exception:  # pragma: no cover
                pass
        if slot.conn is not None:
            try:
                slot.conn.close()
            except Exception:  # pragma: no cover
                pass
        slot.proc = slot.conn = None
        slot.pid = None
        slot.ready = False

    def _respawn(self, slot: _Slot) -> None:
        never_ready = slot.proc is not None and not slot.ready
        self._kill(slot)
        if never_ready and slot.job_id is None:
            # It died while starting (e.g. the solver cannot be imported): back off, don't spin.
            slot.backoff = min(30.0, max(1.0, slot.backoff * 2))
            slot.spawn_after = time.monotonic() + slot.backoff
            self.start_error = f"worker process {slot.index} exited during start-up; retrying in {slot.backoff:g} s"
            return
        slot.backoff = 0.0
        if not self._stop.is_set():
            self._spawn(slot)

    # -- main loop ---------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                try:
                    self._tick()
                    self.tick_error = None
                except DBAPIError as exc:  # database full, read-only or unreachable: back off, go on
                    self.tick_error = f"database unavailable: {database_reason(exc)}"
                    log.warning("dispatcher: %s (%s); retrying in 1 s", self.tick_error, type(exc).__name__)
                    self._stop.wait(1.0)
                    continue
                except Exception as exc:  # anything else: log it whole, back off, go on
                    self.tick_error = f"{type(exc).__name__}: {exc}"
                    log.exception("dispatcher tick failed")
                    self._stop.wait(1.0)
                    continue
                self._sleep()
        finally:
            self._shutdown()

    def _sleep(self) -> None:
        waitables: list[Any] = [self._wake_r]
        for s in self.slots:
            if s.conn is not None:
                waitables.append(s.conn)
            if s.proc is not None:
                waitables.append(s.proc.sentinel)
        try:
            ready = mp_wait(waitables, timeout=self.settings.poll_interval)
        except OSError:
            ready = []
        if self._wake_r in ready:
            try:
                while os.read(self._wake_r, 4096):
                    pass
            except (BlockingIOError, OSError):
                pass

    def _finish(self, slot: _Slot, job_id: str, status: str, **values: Any) -> None:
        """Record a job's end; if the write fails, keep it pending on the slot and retry next tick."""
        slot.clear_job()
        slot.pending = (job_id, status, values)
        self._flush_pending(slot)

    def _flush_pending(self, slot: _Slot) -> None:
        if slot.pending is None:
            return
        job_id, status, values = slot.pending
        jobs.finish(self.db, job_id, self.owner, status, **values)  # raises while the database is down
        slot.pending = None
        self.on_finished(job_id)

    def _tick(self) -> None:
        st = self.settings
        now = time.monotonic()
        for slot in self.slots:
            self._flush_pending(slot)
        for slot in self.slots:
            self._drain(slot)
        for slot in self.slots:
            self._check(slot, now)
        self._flush_progress(now)
        if now - self._last_heartbeat >= st.lease_seconds / 3:
            held = [s.job_id or s.pending[0] for s in self.slots if s.job_id or s.pending]
            jobs.heartbeat(self.db, self.owner, held, st.lease_seconds)
            self._last_heartbeat = now
        if now - self._last_recover >= min(2.0, st.lease_seconds / 2):
            if jobs.recover_expired(self.db, st.max_attempts):
                self.notify()
            self._last_recover = now
        if now - self._last_cancel_check >= st.poll_interval * 0.8:
            self._check_cancels(now)
            self._last_cancel_check = now
        self._fill()

    def _drain(self, slot: _Slot) -> None:
        if slot.conn is None:
            return
        try:
            while slot.conn.poll():
                self._handle(slot, slot.conn.recv())
        except (EOFError, OSError):
            pass  # the process is dead; _check handles it

    def _handle(self, slot: _Slot, msg: Any) -> None:
        if isinstance(msg, Ready):
            slot.ready, slot.pid, slot.backoff = True, msg.pid, 0.0
            self.start_error = None
            return
        job_id = msg.job_id
        if job_id != slot.job_id:
            return  # stale message of a job we already gave up
        if isinstance(msg, Progress):
            slot.progress, slot.progress_dirty = msg.record, True
            return
        progress = msg.progress if msg.progress is not None else slot.progress
        if isinstance(msg, Succeeded):
            self._finish(slot, job_id, Status.SUCCEEDED, result=msg.result, progress=progress)
        elif isinstance(msg, Cancelled):
            self._finish(slot, job_id, Status.CANCELLED, error="cancelled by request", progress=progress)
        elif isinstance(msg, Failed):
            self._finish(slot, job_id, Status.FAILED, error=msg.reason, progress=progress)

    def _check(self, slot: _Slot, now: float) -> None:
        st = self.settings
        if slot.proc is None:
            if now >= slot.spawn_after and not self._stop.is_set():
                self._spawn(slot)
            return
        if not slot.proc.is_alive():
            code = slot.proc.exitcode
            if slot.job_id is not None:
                job_id = slot.job_id
                slot.clear_job()
                if code == -6 and st.worker_memory_mb > 0:
                    # SIGABRT under a memory cap: a native allocation failed (e.g. the solver's KKT system).
                    # It would fail the same way again, so the job ends now, saying why.
                    self._respawn(slot)
                    self._finish(slot, job_id, Status.FAILED, error=f"memory limit exceeded: the worker process "
                                 f"aborted (exit code {code}) when an allocation over the {st.worker_memory_mb} MB "
                                 f"a job may use (NCS_WORKER_MEMORY_MB) failed")
                    log.warning("worker %s aborted running job %s (memory limit)", slot.pid, job_id)
                    return
                reason = f"worker process died (exit code {code})"
                outcome = jobs.retry_or_fail(self.db, job_id, self.owner, reason, st.max_attempts)
                log.warning("worker %s died (exit %s) running job %s -> %s", slot.pid, code, job_id, outcome)
            else:
                log.warning("idle worker %s died (exit %s); replacing it", slot.pid, code)
            self._respawn(slot)
            return
        if slot.job_id is None:
            return
        if now - slot.started > st.job_time_limit:
            job_id = slot.job_id
            self._respawn(slot)
            self._finish(slot, job_id, Status.FAILED,
                         error=f"time limit exceeded: the design ran longer than {st.job_time_limit:g} s "
                               f"(NCS_JOB_TIME_LIMIT) and was stopped")
            return
        if slot.cancel_sent is not None and now - slot.cancel_sent > st.cancel_grace:
            job_id = slot.job_id
            self._respawn(slot)
            self._finish(slot, job_id, Status.CANCELLED, error="cancelled by request (worker stopped)")

    def _check_cancels(self, now: float) -> None:
        running = [s.job_id for s in self.slots if s.job_id and s.cancel_sent is None]
        if not running:
            return
        wanted = jobs.cancel_requested_among(self.db, running)
        for slot in self.slots:
            if slot.job_id in wanted:
                slot.cancel_sent = now
                self._send_cancel(slot)
                if self.settings.cancel_grace == 0:
                    self._check(slot, now + 1)

    # -- the executor: how a claimed job reaches a worker --------------------
    # The local pool (this class) and the Dask backend (app.jobs.dask_executor.DaskDispatcher)
    # differ only in these methods and in _drain/_check/_sleep/_shutdown; claiming,
    # leases, progress, cancel requests and the job-table updates are shared.
    def _idle_slots(self) -> list[_Slot]:
        return [s for s in self.slots if s.job_id is None and s.pending is None and s.ready
                and s.proc is not None and s.proc.is_alive()]

    def _pid_for(self, slot: _Slot) -> int | None:
        """The worker pid recorded with the claim (None when the executor does not know it yet)."""
        return slot.pid

    def _submit(self, slot: _Slot, claimed: jobs.Claimed) -> None:
        try:
            slot.conn.send(Run(claimed.id, claimed.request))
        except (OSError, ValueError):
            pass  # dead worker: the next _check retries the job

    def _send_cancel(self, slot: _Slot) -> None:
        try:
            slot.conn.send(Cancel(slot.job_id))
        except (OSError, ValueError):
            pass

    def _flush_progress(self, now: float) -> None:
        for slot in self.slots:
            if slot.job_id and slot.progress_dirty and now - slot.progress_written >= 0.2:
                jobs.update_progress(self.db, slot.job_id, self.owner, slot.progress)
                slot.progress_dirty = False
                slot.progress_written = now

    def _fill(self) -> None:
        idle = self._idle_slots()
        if not idle or not jobs.has_queued(self.db):
            return
        # One transaction claims a job for every idle slot (and records the worker pids).
        claimed = jobs.claim_many(self.db, self.owner, self.settings.lease_seconds, [self._pid_for(s) for s in idle])
        now = time.monotonic()
        for slot, job in zip(idle, claimed):
            slot.job_id, slot.attempt, slot.started = job.id, job.attempts, now
            slot.cancel_sent, slot.progress, slot.progress_dirty = None, None, False
            self._submit(slot, job)

    def _shutdown(self) -> None:
        for slot in self.slots:
            try:
                self._flush_pending(slot)
            except Exception:  # pragma: no cover - the lease expires and the job runs again
                log.exception("could not record the end of job %s", slot.pending and slot.pending[0])
            job_id = slot.job_id
            if job_id is not None:
                self._kill(slot)
                try:
                    jobs.release(self.db, job_id, self.owner)
                except Exception:  # pragma: no cover - the lease will expire instead
                    log.exception("could not release job %s", job_id)
                slot.clear_job()
            elif slot.conn is not None:
                try:
                    slot.conn.send(Stop())
                except (OSError, ValueError):
                    pass
        deadline = time.monotonic() + 2.0
        for slot in self.slots:
            if slot.proc is not None:
                slot.proc.join(max(0.0, deadline - time.monotonic()))
            self._kill(slot)


def make_dispatcher(db: Database, settings: Settings,
                    on_finished: Callable[[str], None] | None = None) -> Dispatcher:
    """The local process pool, or the Dask backend when ``NCS_DASK_SCHEDULER`` is set."""
    if settings.dask_scheduler:
        from app.jobs.dask_executor import DaskDispatcher

        return DaskDispatcher(db, settings, on_finished)
    return Dispatcher(db, settings, on_finished)
