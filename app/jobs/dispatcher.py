"""Dispatcher: claims queued jobs from the database and runs them on an executor
(``app.jobs.executor``: local worker processes, or a Dask cluster).

One daemon thread per service process. Whatever the executor, in a loop it

* lets the executor do its housekeeping (replace dead workers, reconnect),
* turns the executor's messages into job-table updates: ``Started`` (worker pid;
  a re-run elsewhere is one more attempt), ``Progress`` (written at most every
  0.2 s), an outcome (the job is finished), ``Lost`` (retried, bounded by
  ``max_attempts``),
* stops a job that exceeded ``job_time_limit`` (job -> failed),
* forwards cancel requests (cooperative first, stopped after ``cancel_grace``),
* renews the leases of its running jobs and re-queues jobs whose lease
  expired (their service was killed),
* claims a queued job for every free slot of the executor, in one transaction.

It sleeps in ``multiprocessing.connection.wait`` on the executor's waitables
(worker pipes and process sentinels) and a self-pipe that ``notify()`` writes to,
so it reacts immediately to results, deaths and new submissions.
"""

from __future__ import annotations

import asyncio
import logging
import os
import threading
import time
import uuid
from collections import deque
from multiprocessing.connection import wait as mp_wait
from typing import Any, Callable

from sqlalchemy.exc import DBAPIError

from app.compute.messages import Begun, Cancelled, ExecutorEvent, Failed, Lost, Progress, Started, Succeeded
from app.jobs import store as jobs
from app.jobs.database import Database, database_reason
from app.jobs.executor import Executor
from app.jobs.tables import Status
from app.jobs.watch import resolve_from_thread
from app.settings import Settings

log = logging.getLogger("app.dispatcher")

PROGRESS_WRITE_EVERY = 0.2  # seconds between progress writes of one job
#: A submission handed to the dispatcher waits at most NCS_DATABASE_BUSY_TIMEOUT for the write lock, and is
#: answered within that plus this margin (for the write itself): one the dispatcher has not taken by then
#: (stuck in another write) is withdrawn and answered 503 with the cause.
SUBMIT_WAIT_MARGIN = 5.0


class _Running:
    """A job this dispatcher claimed and handed to its executor."""

    def __init__(self, job_id: str, handle: Any, pid: int | None, request: dict[str, Any] | None = None):
        self.job_id = job_id
        self.handle = handle
        self.request = request              # as claimed: completes the finished job's record
        self.pid = pid                      # recorded with the claim, or by the first Started
        self.address = ""                   # the Dask worker it runs on
        self.run: tuple[str, int] | None = None  # (address, pid) of the Dask worker its task last began on
        self.started: float | None = None   # monotonic; the time limit counts from the real start
        self.cancel_sent: float | None = None
        self.progress: dict[str, Any] | None = None
        self.progress_dirty = False
        # Progress is first written once the job has run PROGRESS_WRITE_EVERY: a short job's progress is
        # written only with its end.
        self.progress_written = time.monotonic()


class Dispatcher:
    def __init__(self, db: Database, settings: Settings, executor: Executor,
                 on_finished: Callable[..., None] | None = None):
        self.db = db
        self.settings = settings
        self.executor = executor
        # Told the jobs this dispatcher finished, once their ends are recorded (Prefer: wait): a list of
        # their ids and the jobs as the finishing write left them (None when this dispatcher no longer held it),
        # and (``also``) the answers to the submissions written in the same transaction, to resolve with the
        # same wake-up of the event loop (:meth:`app.jobs.watch.JobWatch.finished_many`).
        self.on_finished = on_finished or (lambda ended, also=(): resolve_from_thread(list(also)))
        self.owner = f"{os.uname().nodename[:20]}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.running: dict[str, _Running] = {}
        # Finished jobs whose end is not written yet: written at the end of the tick that saw them end, in
        # one transaction with the next claim; while that write fails (database full, read-only or
        # unreachable) they stay here and it is tried again every tick, so a result is never lost and
        # never half-written.
        self.pending: dict[str, jobs.Ending] = {}
        # The executor's messages not handled yet: a tick that fails half-way (database down) leaves the
        # rest here for the next one instead of dropping them.
        self._events: deque[ExecutorEvent] = deque()
        # Submissions handed over by request handlers (:meth:`submit`): inserted by the next tick's write,
        # in one transaction with the ends and the claim, each answered through its future.
        self._submissions: list[tuple[jobs.Submission, asyncio.AbstractEventLoop, asyncio.Future]] = []
        self._submissions_lock = threading.Lock()
        self._closed = False  # the thread has ended: submissions go to the store directly
        self._batches = jobs.batches_submissions(db)
        # How jobs are claimed: owner by owner in turn (NCS_FAIR_SCHEDULING), with an optional running cap.
        self.policy = jobs.ClaimPolicy(jobs.OwnerTurns() if settings.fair_scheduling else None,
                                       settings.max_running_per_owner)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._wake_r, self._wake_w = os.pipe()
        self._wake_pending = False  # a byte is in the wake pipe, not yet read by the dispatcher
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._last_heartbeat = 0.0
        self._last_recover = 0.0
        self._last_cancel_check = 0.0
        self.tick_error: str | None = None  # last database/dispatcher error, cleared by a good tick
        # Whether a claim may find a job without asking first: after a submission here (notify) or a claim
        # that filled every free slot. Otherwise a cheap read (has_queued) comes first, so an idle
        # dispatcher does not take SQLite's write lock every poll interval.
        self._queue_maybe_nonempty = True

    # -- public -----------------------------------------------------------
    def start(self) -> None:
        self.executor.start(self._wake)
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

    def take(self, sub: jobs.Submission) -> asyncio.Future | None:
        """Queue a job as :func:`app.jobs.store.submit` does (same answers and errors, through the returned
        future of the calling event loop), written by this dispatcher's thread together with its own next
        write (ends, claim): under load one commit serves many submissions, a request handler needs no
        thread-pool hop, and a free worker claims the job in the transaction that inserts it. None when this
        dispatcher cannot take it (stopped, or a database without ON CONFLICT): use the store directly."""
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        with self._submissions_lock:
            if self._closed or not self._batches or not self.thread_alive():
                return None
            sub.handed_at = time.monotonic()
            self._submissions.append((sub, loop, fut))
        self.notify()
        return fut

    def withdraw(self, fut: asyncio.Future) -> bool:
        """Take back a submission the dispatcher has not started to write (True): its submitter answers
        without it, and it is never written. False once it is in a write (its answer comes soon)."""
        with self._submissions_lock:
            for i, (_, _, f) in enumerate(self._submissions):
                if f is fut:
                    del self._submissions[i]
                    return True
        return False

    @property
    def submit_wait_bound(self) -> float:
        """The longest a submission handed to this dispatcher waits for its answer (s)."""
        return self.db.busy_timeout + SUBMIT_WAIT_MARGIN

    def _lock_budget(self, subs: list) -> float | None:
        """How long this write may wait for the lock: what is left of its oldest submission's
        lock wait, the database's busy timeout (None without submissions: the whole busy timeout)."""
        if not subs:
            return None
        oldest = min(s.handed_at for s, _, _ in subs)
        return max(0.05, oldest + self.db.busy_timeout - time.monotonic())

    def notify(self) -> None:
        """A job was queued or asked to cancel: look at the table now."""
        self._queue_maybe_nonempty = True
        self._wake()

    def _wake(self) -> None:
        # One byte per sleep, not one per caller: under load every submission calls this, and the write is a
        # system call on the event loop's thread (that releases and retakes the GIL). A caller that finds a
        # byte already on its way needs none: the dispatcher clears the flag only after it emptied the pipe
        # (:meth:`_sleep`), so whatever that caller handed over before looking is seen by the tick that follows.
        if self._wake_pending:
            return
        self._wake_pending = True
        try:
            os.write(self._wake_w, b"x")
        except (BlockingIOError, OSError):
            pass

    @property
    def error(self) -> str | None:
        return "; ".join(e for e in (self.tick_error, self.executor.error) if e) or None

    def thread_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def configured_workers(self) -> int:
        return self.executor.configured_workers()

    def alive_workers(self) -> int:
        return self.executor.alive_workers()

    def ready_workers(self) -> int:
        return self.executor.ready_workers()

    def holds(self, job_ids: list[str]) -> set[str]:
        """Those of ``job_ids`` this dispatcher runs or is recording the end of: it will call ``on_finished``
        for each (from any thread; empty once its thread has ended)."""
        if not self.thread_alive():
            return set()
        running, pending = self.running, self.pending
        return {i for i in job_ids if i in running or i in pending}

    def worker_pid(self, job_id: str) -> int | None:
        """The pid of the worker process running the job, once known (tests and fault scripts kill it)."""
        running = self.running.get(job_id)
        return running.pid if running is not None else None

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
                    self._refuse_submissions(exc)
                    self._stop.wait(1.0)
                    continue
                except Exception as exc:  # anything else: log it whole, back off, go on
                    self.tick_error = f"{type(exc).__name__}: {exc}"
                    log.exception("dispatcher tick failed")
                    self._refuse_submissions(exc)
                    self._stop.wait(1.0)
                    continue
                self._sleep()
        finally:
            self._shutdown()

    def _refuse_submissions(self, exc: BaseException) -> None:
        """A tick failed (``exc``) before it wrote the submissions handed over. A request must not wait for the
        database to come back: they are written now on their own, as the store would write them (a connection
        found dead is retried once: a terminated backend costs a retry, not an error), and hear ``exc`` or
        that write's error only if it fails too (nothing of theirs was written then)."""
        with self._submissions_lock:
            subs, self._submissions = self._submissions, []
        if not subs:
            return
        st = self.settings
        if min(s.handed_at for s, _, _ in subs) + self.db.busy_timeout <= time.monotonic():
            # They waited for the lock as long as they may: answered with the cause now, not after another wait.
            resolve_from_thread([(loop, fut, exc) for _, loop, fut in subs])
            return
        try:
            answers, _, _ = jobs.write_batch(self.db, self.owner, [s for s, _, _ in subs], [], st.lease_seconds, [],
                                             st.max_queue_depth, st.retry_after,
                                             max_queued_per_owner=st.max_queued_per_owner,
                                             busy_timeout=self._lock_budget(subs))
        except BaseException as again:
            resolve_from_thread([(loop, fut, again) for _, loop, fut in subs])
            return
        self._queue_maybe_nonempty = True
        resolve_from_thread([(loop, fut, answer) for (_, loop, fut), answer in zip(subs, answers)])

    def _sleep(self) -> None:
        try:
            ready = mp_wait([self._wake_r, *self.executor.waitables()], timeout=self.settings.poll_interval)
        except OSError:
            ready = []
        if self._wake_r in ready:
            try:
                while os.read(self._wake_r, 4096):
                    pass
            except (BlockingIOError, OSError):
                pass
            # Cleared after the pipe is empty, never before: a caller that wrote its byte between a clear and
            # the read would leave the flag set over an empty pipe, and every later caller would skip its
            # byte, so the dispatcher slept a whole poll interval with submissions waiting. A caller that
            # finds the flag still set here handed its submission over before the tick that follows.
            self._wake_pending = False

    def _tick(self) -> None:
        st = self.settings
        now = time.monotonic()
        if self.pending:  # left by a tick whose write failed: written before anything new is taken on
            self._flush_pending()
        self.executor.maintain(now)
        self._events.extend(self.executor.poll())
        while self._events:
            self._handle(self._events[0])
            self._events.popleft()
        self._check_limits(now)
        self._flush_progress(now)
        if now - self._last_heartbeat >= st.lease_seconds / 3:
            jobs.heartbeat(self.db, self.owner, [*self.running, *self.pending], st.lease_seconds)
            self._last_heartbeat = now
        if now - self._last_recover >= min(2.0, st.lease_seconds / 2):
            if jobs.recover_expired(self.db, st.max_attempts):
                self.notify()
            self._last_recover = now
        if now - self._last_cancel_check >= st.poll_interval * 0.8:
            self._check_cancels(now)
            self._last_cancel_check = now
        self._write_and_fill()

    # -- finishing -------------------------------------------------------------
    def _finish(self, job_id: str, status: str, **values: Any) -> None:
        """A job ended: its end is written at the end of this tick (:meth:`_write_and_fill`), kept pending
        and retried every tick while the write fails."""
        running = self.running.pop(job_id, None)
        self.pending[job_id] = jobs.Ending(job_id, status, request=running.request if running else None, **values)

    def _flush_pending(self) -> None:
        self._write_and_fill(claim=False)

    def _write_and_fill(self, claim: bool = True) -> None:
        """Write the pending ends and claim a queued job for every free slot of the executor, in one
        transaction; then wake the waiters of the ended jobs and hand the claimed ones to the executor."""
        free = self.executor.free_slots() if claim else []
        with self._submissions_lock:
            subs, self._submissions = self._submissions, []
        # A claim is tried when a job may be waiting: after a submission (notify) or a claim that filled
        # every slot, or when something is written anyway (the claim then costs one more statement, not a
        # transaction). Otherwise a cheap read comes first, so an idle dispatcher does not take SQLite's write
        # lock every poll interval.
        if free and not (self._queue_maybe_nonempty or self.pending or subs or jobs.has_queued(self.db)):
            free = []
        if not free and not self.pending and not subs:
            return
        endings = list(self.pending.values())
        st = self.settings
        try:
            answers, ended, claimed = jobs.write_batch(self.db, self.owner, [s for s, _, _ in subs], endings,
                                                       st.lease_seconds, [s.pid for s in free],
                                                       st.max_queue_depth, st.retry_after,
                                                       max_queued_per_owner=st.max_queued_per_owner,
                                                       policy=self.policy, busy_timeout=self._lock_budget(subs))
        except BaseException as exc:  # the database is down: nothing was written; the submitters hear why
            resolve_from_thread([(loop, fut, exc) for _, loop, fut in subs])
            raise
        if free:
            self._queue_maybe_nonempty = len(claimed) == len(free)
        for slot, job in zip(free, claimed):  # first: the workers start while the answers go out
            try:
                handle = self.executor.submit(slot, job)
            except Exception as exc:  # e.g. the Dask client lost its scheduler just now
                log.exception("could not hand job %s to the executor", job.id)
                self.running[job.id] = _Running(job.id, None, slot.pid)
                self._retry_or_fail(job.id, f"could not start the job: {type(exc).__name__}")
                continue
            self.running[job.id] = _Running(job.id, handle, slot.pid, job.request)
        answered = [(loop, fut, answer) for (_, loop, fut), answer in zip(subs, answers)]
        for end in endings:
            del self.pending[end.job_id]
        if endings:  # one wake-up of the event loop for the submitters and the waiters of the ended jobs
            self.on_finished([(end.job_id, record) for end, record in zip(endings, ended)], answered)
        else:
            resolve_from_thread(answered)

    def _retry_or_fail(self, job_id: str, reason: str) -> None:
        self.running.pop(job_id, None)
        outcome = jobs.retry_or_fail(self.db, job_id, self.owner, reason, self.settings.max_attempts)
        log.warning("job %s: %s -> %s", job_id, reason, outcome)
        if outcome is not None and Status(outcome).finished:
            self.on_finished([(job_id, None)])
        self.notify()  # a re-queued job can be claimed at once

    # -- the executor's messages --------------------------------------------------
    def _handle(self, msg: ExecutorEvent) -> None:
        running = self.running.get(msg.job_id)
        if running is None:
            return  # a job given up
        if isinstance(msg, Begun):
            self._on_begun(running, msg)
        elif isinstance(msg, Started):
            self._on_started(running, msg)
        elif isinstance(msg, Progress):
            running.progress, running.progress_dirty = msg.record, True
        elif isinstance(msg, Lost):
            self._retry_or_fail(msg.job_id, msg.reason)
        else:
            progress = msg.progress if msg.progress is not None else running.progress
            if isinstance(msg, Succeeded):
                self._finish(msg.job_id, Status.SUCCEEDED, result=msg.result, progress=progress)
            elif isinstance(msg, Cancelled):
                self._finish(msg.job_id, Status.CANCELLED, error="cancelled by request", progress=progress)
            elif isinstance(msg, Failed):
                self._finish(msg.job_id, Status.FAILED, error=msg.reason, progress=progress)

    def _on_begun(self, running: _Running, msg: Begun) -> None:
        """A Dask task began on a worker; a second one on another worker process is a re-run (its first
        worker died, maybe before the job's process started): one more attempt."""
        run = (msg.address, msg.worker_pid)
        # Where it ran before: the last Begun, or (if that event was lost) the worker of its Started.
        before = running.run or ((running.address, None) if running.pid is not None and running.address else None)
        if before is not None and (before[0] != run[0] or before[1] not in (None, run[1])):
            what = f"Dask worker {before[0]} (pid {before[1] or running.pid}) died"
            if not self._count_retry(running, what):
                return
            running.pid = None  # the Started of this run is not a re-run of its own
        running.run, running.address = run, msg.address

    def _count_retry(self, running: _Running, reason: str) -> bool:
        """The executor re-ran the job by itself: count the attempt. False when the job ended with it
        (attempts used up, or a cancel asked for): it is dropped here."""
        outcome = jobs.note_retry(self.db, running.job_id, self.owner, reason, self.settings.max_attempts)
        log.warning("%s running job %s -> %s", reason, running.job_id, outcome)
        if outcome == Status.RUNNING:
            return True
        self.running.pop(running.job_id, None)
        self.executor.stop(running.handle, interrupt=False)
        if outcome is not None and Status(outcome).finished:
            self.on_finished([(running.job_id, None)])
        return False

    def _on_started(self, running: _Running, msg: Started) -> None:
        running.started = time.monotonic()
        if running.pid == msg.pid:
            return  # recorded with the claim
        same_run = bool(msg.address) and running.run is not None and running.run[0] == msg.address
        if running.pid is not None and not same_run:
            # The executor re-ran the job elsewhere (Dask re-runs a task whose worker died).
            reason = (f"Dask worker {running.address} (pid {running.pid}) died" if running.address
                      else f"worker process {running.pid} died")
            if not self._count_retry(running, reason):
                return
        running.pid, running.address = msg.pid, msg.address
        jobs.set_worker_pid(self.db, running.job_id, self.owner, msg.pid)

    # -- limits and cancels ---------------------------------------------------------
    def _check_limits(self, now: float) -> None:
        st = self.settings
        for running in list(self.running.values()):
            if running.started is not None and now - running.started > st.job_time_limit:
                self._give_up(running, Status.FAILED,
                              f"time limit exceeded: the design ran longer than {st.job_time_limit:g} s "
                              f"(NCS_JOB_TIME_LIMIT) and was stopped")
            elif running.cancel_sent is not None and now - running.cancel_sent > st.cancel_grace:
                self._give_up(running, Status.CANCELLED, "cancelled by request (worker stopped)")

    def _give_up(self, running: _Running, status: str, error: str) -> None:
        self.running.pop(running.job_id, None)
        self.executor.stop(running.handle, interrupt=True)
        self._finish(running.job_id, status, error=error, progress=running.progress)

    def _check_cancels(self, now: float) -> None:
        asked = [r.job_id for r in self.running.values() if r.cancel_sent is None]
        if not asked:
            return
        wanted = jobs.cancel_requested_among(self.db, asked)
        for job_id in wanted:
            running = self.running.get(job_id)
            if running is None:
                continue
            if running.started is None:  # still waiting for a worker: just drop it
                self.running.pop(job_id, None)
                self.executor.stop(running.handle, interrupt=False)
                self._finish(job_id, Status.CANCELLED, error="cancelled by request")
                continue
            running.cancel_sent = now
            self.executor.cancel(running.handle)
        if wanted and self.settings.cancel_grace == 0:
            self._check_limits(now + 1e-3)

    def _flush_progress(self, now: float) -> None:
        for running in self.running.values():
            if running.progress_dirty and now - running.progress_written >= PROGRESS_WRITE_EVERY:
                jobs.update_progress(self.db, running.job_id, self.owner, running.progress)
                running.progress_dirty = False
                running.progress_written = now

    def _shutdown(self) -> None:
        with self._submissions_lock:
            self._closed = True  # later submissions go to the store directly
        try:
            self._flush_pending()  # also inserts the submissions handed over last
        except Exception:  # pragma: no cover - the lease expires and the job runs again
            log.exception("could not record the end of jobs %s", list(self.pending))
        for job_id, running in list(self.running.items()):
            self.executor.stop(running.handle, interrupt=False)
            try:
                jobs.release(self.db, job_id, self.owner)
            except Exception:  # pragma: no cover - the lease will expire instead
                log.exception("could not release job %s", job_id)
        self.running.clear()
        self.executor.shutdown()


def make_dispatcher(db: Database, settings: Settings, on_finished: Callable[..., None] | None = None) -> Dispatcher:
    """The dispatcher on the local process pool, or on Dask when ``NCS_DASK_SCHEDULER`` is set."""
    executor: Executor
    if settings.dask_scheduler:
        from app.jobs.dask_executor import DaskExecutor

        executor = DaskExecutor(settings)
    else:
        from app.jobs.local_executor import LocalExecutor

        executor = LocalExecutor(settings)
    return Dispatcher(db, settings, executor, on_finished)
