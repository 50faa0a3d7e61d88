"""The Dask executor: design jobs run on a ``dask.distributed`` cluster.

Selected by ``NCS_DASK_SCHEDULER=tcp://host:8786``. Everything about the queue stays
as with the local pool: the one dispatcher (``app.jobs.dispatcher``) claims jobs
from the database (``FOR UPDATE SKIP LOCKED`` on PostgreSQL), holds and renews their
leases, writes progress and results, enforces time limits and cancel grace, and a
restarted service loses nothing because the database is the source of truth. Only the
executor differs: a claimed job is ``Client.submit``-ted (``app.compute.dask_task.run_job``)
instead of sent down a pipe.

How the usual guarantees map onto Dask:

* **Results**: a future's done-callback puts it on a queue and wakes the dispatcher.
* **Start and progress**: the task logs structured events (``Worker.log_event``): the
  ``Started``/``Progress`` messages as plain dicts (``messages.to_event``), checked and
  turned back into the dataclasses here (``messages.from_event``). The service
  subscribes to the topic (``Client.subscribe_topic``). No database access on the
  cluster, no per-iteration round trip.
* **Where a job runs**: in a *job process*, a child of the Dask worker (one per worker
  thread, kept between jobs; ``app.compute.dask_task``), with the local workers' memory cap
  (``NCS_WORKER_MEMORY_MB``). Its pid is the job's ``worker_pid``.
* **Cooperative cancel**: ``Client.run(request_cancel, task_key, workers=[addr])`` sets
  a flag in the worker process; the task passes it to the job process, whose solver
  callback stops at its next iteration. A job that has not started yet is simply
  ``Future.cancel``-led. A job that ignores the cancel for ``NCS_CANCEL_GRACE`` seconds,
  or runs over ``NCS_JOB_TIME_LIMIT``, is stopped by killing its job process
  (``Client.run(stop_job, ...)``): the Dask worker and the jobs of its other threads go on.
  (Restarting the worker through its nanny, ``Client.restart_workers``, sometimes lost the
  worker for good on ``distributed`` 2026.8.) A job process that dies is replaced at the
  thread's next job; the job it ran is ``Lost``, or ``Failed`` if it aborted under the
  memory cap, as with the local executor.
* **A worker dies mid-job**: the scheduler re-runs the task on another worker. The task's
  first act is a ``Begun`` event (the Dask worker's address and pid), before its job process
  starts (seconds for a new one); a ``Begun`` from another worker, or a ``Started`` from a new
  pid, means a re-run: the dispatcher counts one more attempt (also when the first worker died
  before its job process started), and
  past ``NCS_MAX_ATTEMPTS`` the job ends ``failed`` with the reason. If Dask gives up first
  (``KilledWorker``, scheduler setting ``allowed-failures``) the job is ``Lost``: re-queued
  or failed the same way. A future lost with the scheduler is ``Lost`` too.
* **Capacity**: this service claims at most as many jobs as the cluster has worker
  threads (refreshed every second); with no workers it claims nothing and ``/readyz``
  says not ready.
"""


from __future__ import annotations

import logging
import queue
import threading
import time
import uuid
from typing import Any, Callable

from app.compute.messages import (Begun, Cancelled, ExecutorEvent, Failed, Lost, MalformedEvent, Started, Succeeded,
                                  from_event)
from app.jobs.executor import Executor, FreeSlot
from app.jobs.store import Claimed
from app.settings import Settings

log = logging.getLogger("app.dask")


class _Task:
    """One submitted job: its task key (job id and attempt), future and, once started, where it runs."""

    __slots__ = ("job_id", "key", "future", "address")

    def __init__(self, job_id: str, key: str):
        self.job_id = job_id
        self.key = key
        self.future: Any = None
        self.address: str | None = None


class DaskExecutor(Executor):
    def __init__(self, settings: Settings):
        self.address = settings.dask_scheduler
        self.memory_mb = settings.worker_memory_mb
        self.client: Any = None
        self._wake: Callable[[], None] = lambda: None
        # Filled by Dask's threads (event subscriptions, done callbacks), drained by poll().
        self._inbox: queue.SimpleQueue = queue.SimpleQueue()
        self._tasks: dict[str, _Task] = {}  # by key
        self._events: list[ExecutorEvent] = []
        self._nthreads: dict[str, int] = {}
        self._most_threads = 0
        self._last_info = 0.0
        self._next_connect = 0.0
        self._error: str | None = None

    # -- Executor -------------------------------------------------------------
    def start(self, wake: Callable[[], None]) -> None:
        # Connecting happens in maintain(), on the dispatcher thread: the service starts (and /readyz
        # explains) even while the scheduler is unreachable; it retries every second.
        self._wake = wake

    def maintain(self, now: float) -> None:
        if self.client is not None and not self._connected():
            self._lose_scheduler(f"lost the Dask scheduler at {self.address} (client {self.client.status})")
        if self.client is None and now >= self._next_connect:
            try:
                self._connect()
            except Exception as exc:
                self._error = f"cannot connect to the Dask scheduler at {self.address}: {type(exc).__name__}"
                self._next_connect = time.monotonic() + 1.0
        if self.client is not None and now - self._last_info >= 1.0:
            try:
                self._refresh_workers(now)
            except Exception as exc:
                self._lose_scheduler(f"lost the Dask scheduler at {self.address}: {type(exc).__name__}: {exc}")

    def free_slots(self) -> list[FreeSlot]:
        if not self._connected():
            return []
        # The pid is known only once the task starts on a worker (its Started event).
        return [FreeSlot(None) for _ in range(max(0, sum(self._nthreads.values()) - len(self._tasks)))]

    def submit(self, slot: FreeSlot, job: Claimed) -> _Task:
        from app.compute.dask_task import run_job

        # Unique per submission: a job released by a stopping replica comes back with the same attempt count,
        # and Dask would resume the old, cancelled task under the same key instead of starting this one.
        task = _Task(job.id, f"ncs-design-{job.id}-{job.attempts}-{uuid.uuid4().hex[:8]}")
        self._tasks[task.key] = task
        task.future = self.client.submit(run_job, job.id, task.key, job.request, self.memory_mb, key=task.key,
                                         pure=False, retries=0)
        task.future.add_done_callback(lambda f: self._post("done", f))
        return task

    def poll(self) -> list[ExecutorEvent]:
        while True:
            try:
                kind, payload = self._inbox.get_nowait()
            except queue.Empty:
                break
            if kind == "done":
                self._on_done(payload)
            else:
                self._on_event(payload)
        events, self._events = self._events, []
        return events

    def cancel(self, handle: _Task) -> None:
        from app.compute.dask_task import request_cancel

        if handle.address is None or not self._connected():
            return  # not started (the dispatcher drops it) or no scheduler: the grace timeout handles it
        self._run_on_worker(request_cancel, handle)

    def stop(self, handle: _Task, interrupt: bool = True) -> None:
        self._tasks.pop(handle.key, None)
        fut, address, handle.future = handle.future, handle.address, None
        if fut is not None:
            try:
                fut.cancel()  # the task sees it is released and stops its job process (dask_task.run_job)
            except Exception:  # pragma: no cover
                pass
        if interrupt and address and self._connected():
            from app.compute.dask_task import stop_job

            # Dask cannot interrupt a running task (Future.cancel only forgets it): kill its job process now.
            self._run_on_worker(stop_job, handle)

    def _run_on_worker(self, fn: Callable[[str], Any], handle: _Task) -> None:
        """``fn(task key)`` on the task's worker, off the dispatcher thread: delivering it waits for the
        connection to the worker, up to Dask's connect timeout (30 s) when the worker is gone."""
        client, address, key = self.client, handle.address, handle.key

        def send() -> None:
            try:
                client.run(fn, key, workers=[address], wait=False)
            except Exception as exc:  # the worker is gone, and the job process with it
                log.warning("could not run %s for task %s on Dask worker %s: %s", fn.__name__, key, address, exc)

        threading.Thread(target=send, name=f"ncs-dask-{fn.__name__}", daemon=True).start()

    def shutdown(self) -> None:
        if self.client is not None:
            try:
                self.client.close(timeout=5)
            except Exception:  # pragma: no cover
                pass
            self.client = None

    def configured_workers(self) -> int:
        return self._most_threads

    def alive_workers(self) -> int:
        return len(self._nthreads)

    def ready_workers(self) -> int:
        return sum(self._nthreads.values()) if self._connected() else 0

    @property
    def error(self) -> str | None:
        return self._error

    # -- connection ---------------------------------------------------------------
    def _connected(self) -> bool:
        # A client whose scheduler went away says "connecting" (it tries to reconnect on its own) or
        # "closed"; only "running" can take work, so /readyz is 503 from the moment the connection drops.
        return self.client is not None and self.client.status == "running"

    def _connect(self) -> None:
        from distributed import Client

        from app.compute.dask_task import PROGRESS_TOPIC, START_TOPIC

        # A short timeout: the dispatcher thread waits this long per attempt while the scheduler is down.
        client = Client(self.address, timeout=3, set_as_default=False)
        client.subscribe_topic(START_TOPIC, lambda ev: self._post("event", ev[1]))
        client.subscribe_topic(PROGRESS_TOPIC, lambda ev: self._post("event", ev[1]))
        self.client = client
        self._refresh_workers(time.monotonic())
        log.info("dispatcher connected to the Dask scheduler at %s (%d worker threads)",
                 self.address, self.ready_workers())

    def _post(self, kind: str, payload: Any) -> None:
        self._inbox.put((kind, payload))
        self._wake()

    def _refresh_workers(self, now: float) -> None:
        self._nthreads = dict(self.client.nthreads())
        self._last_info = now
        capacity = sum(self._nthreads.values())
        self._most_threads = max(self._most_threads, capacity)
        self._error = None if capacity else f"no workers connected to the Dask scheduler at {self.address}"

    def _lose_scheduler(self, reason: str) -> None:
        """The scheduler is gone, and with it every task it held (Dask's workers stop with their scheduler):
        each running job is ``Lost`` (back to the queue at the cost of the one attempt it was on), and the
        client is dropped, so the next maintain() connects afresh (a restarted scheduler knows none of the
        old futures or subscriptions)."""
        log.warning("%s; giving back %d running jobs and reconnecting", reason, len(self._tasks))
        self._error = reason
        self._nthreads = {}
        for task in list(self._tasks.values()):
            self.stop(task, interrupt=False)
            self._events.append(Lost(task.job_id, "the Dask scheduler was lost"))
        client, self.client = self.client, None
        # Closing a client whose scheduler is gone can wait for its timeouts: not on the dispatcher thread.
        threading.Thread(target=_close_quietly, args=(client,), name="ncs-dask-close", daemon=True).start()
        self._wake()

    # -- what comes back ------------------------------------------------------------
    def _on_event(self, event: Any) -> None:
        try:
            key, msg = from_event(event)
        except MalformedEvent as exc:
            log.warning("ignoring a Dask event: %s", exc)
            return
        task = self._tasks.get(key)
        if task is None or task.job_id != msg.job_id:
            return  # another replica's job, or one given up
        if isinstance(msg, (Begun, Started)):
            task.address = msg.address
        self._events.append(msg)

    def _on_done(self, fut: Any) -> None:
        task = self._tasks.get(fut.key)
        if task is None or task.future is not fut:
            return
        status = fut.status
        err: BaseException | None = None
        if status == "finished":
            try:
                reply = fut.result(timeout=30)
            except Exception as exc:  # pragma: no cover - the result could not be fetched
                err = exc
            else:
                if isinstance(reply, (Succeeded, Cancelled, Failed, Lost)) and reply.job_id == task.job_id:
                    self._tasks.pop(task.key, None)
                    self._events.append(reply)
                    return
                err = TypeError(f"the task returned {type(reply).__name__}, not a job outcome")
        elif status == "error":
            err = fut.exception(timeout=30)
        self._tasks.pop(task.key, None)
        if err is not None and type(err).__name__ != "KilledWorker":
            self._events.append(Failed(task.job_id, f"Dask task failed: {type(err).__name__}: {err}"))
            return
        reason = (f"Dask gave up on the task: {err}" if err is not None
                  else f"the Dask scheduler lost the task ({status})")
        log.warning("job %s: %s", task.job_id, reason)
        self._events.append(Lost(task.job_id, reason))


def _close_quietly(client: Any) -> None:
    try:
        client.close(timeout=5)
    except Exception:  # pragma: no cover - already gone
        pass
