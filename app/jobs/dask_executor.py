"""Dask backend of the dispatcher: design jobs run on a ``dask.distributed`` cluster.

Selected by ``NCS_DASK_SCHEDULER=tcp://host:8786``. Everything about the queue stays
as with the local pool (``app.jobs.dispatcher``): the same dispatcher thread claims jobs
from the database (``FOR UPDATE SKIP LOCKED`` on PostgreSQL), holds and renews their
leases, writes progress and results, and a restarted service loses nothing because
the database is the source of truth. Only the executor differs: a claimed job is
``Client.submit``-ted (``app.compute.dask_task.run_job``) instead of sent down a pipe.

How the usual guarantees map onto Dask:

* **Results**: a future's done-callback puts it on a queue and wakes the dispatcher.
* **Progress**: the task logs structured events (``Worker.log_event``); the service
  subscribes to the topic (``Client.subscribe_topic``). No database access on the
  cluster, no per-iteration round trip.
* **Cooperative cancel**: ``Client.run(request_cancel, job_id, workers=[addr])`` sets
  a flag in the worker process that the solver callback reads. A job that has not
  started yet is simply ``Future.cancel``-led. Dask cannot interrupt a running task
  (``Future.cancel`` only forgets it), so a job that ignores the cancel for
  ``NCS_CANCEL_GRACE`` seconds, or runs over ``NCS_JOB_TIME_LIMIT``, is stopped by
  restarting its worker (``Client.restart_workers``, needs the worker's nanny).
* **A worker dies mid-job**: the scheduler re-runs the task on another worker. The
  task's start event then comes from a new pid: the job's ``attempts`` grows, and past
  ``NCS_MAX_ATTEMPTS`` the job ends ``failed`` with the reason. If Dask gives up first
  (``KilledWorker``, scheduler setting ``allowed-failures``) the job is re-queued or
  failed the same way. A future lost with the scheduler is re-queued.
* **Capacity**: this service claims at most as many jobs as the cluster has worker
  threads (refreshed every second); with no workers it claims nothing and ``/readyz``
  says not ready.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any, Callable

from app.jobs import store as jobs
from app.jobs.database import Database
from app.jobs.dispatcher import Dispatcher, _Slot
from app.jobs.model import Status
from app.settings import Settings

log = logging.getLogger("app.dask")


class DaskDispatcher(Dispatcher):
    def __init__(self, db: Database, settings: Settings, on_finished: Callable[[str], None] | None = None):
        super().__init__(db, settings, on_finished)
        self.address = settings.dask_scheduler
        self.slots = []
        self.client: Any = None
        self._events: queue.SimpleQueue = queue.SimpleQueue()
        self._by_key: dict[str, _Slot] = {}
        self._nthreads: dict[str, int] = {}
        self._last_info = 0.0
        self._next_connect = 0.0

    # -- public -----------------------------------------------------------
    def start(self) -> None:
        # Connect from the dispatcher thread: the service starts (and /readyz explains) even
        # while the scheduler is unreachable; the thread retries every second.
        self._thread = threading.Thread(target=self._run, name="ncs-dispatcher-dask", daemon=True)
        self._thread.start()

    def alive_workers(self) -> int:
        return len(self._nthreads)

    def ready_workers(self) -> int:
        return sum(self._nthreads.values()) if self._connected() else 0

    def _connected(self) -> bool:
        # A client whose scheduler went away says "connecting" (it tries to reconnect on its own) or
        # "closed"; only "running" can take work, so /readyz is 503 from the moment the connection drops.
        return self.client is not None and self.client.status == "running"

    def worker_pids(self) -> list[int]:
        return [s.pid for s in self.slots if s.job_id and s.pid]

    # -- connection ---------------------------------------------------------
    def _connect(self) -> None:
        from distributed import Client

        from app.compute.dask_task import PROGRESS_TOPIC, START_TOPIC

        # A short timeout: the dispatcher thread waits this long per attempt while the scheduler is down.
        client = Client(self.address, timeout=3, set_as_default=False)
        client.subscribe_topic(START_TOPIC, lambda ev: self._post("start", ev[1]))
        client.subscribe_topic(PROGRESS_TOPIC, lambda ev: self._post("progress", ev[1]))
        self.client = client
        self._refresh_workers(time.monotonic())
        log.info("dispatcher connected to the Dask scheduler at %s (%d worker threads)",
                 self.address, self.ready_workers())

    def _post(self, kind: str, payload: Any) -> None:
        self._events.put((kind, payload))
        self.notify()

    def _refresh_workers(self, now: float) -> None:
        self._nthreads = dict(self.client.nthreads())
        self._last_info = now
        capacity = sum(self._nthreads.values())
        while len(self.slots) < capacity:
            self.slots.append(_Slot(len(self.slots)))
        self.start_error = None if capacity else f"no workers connected to the Dask scheduler at {self.address}"

    # -- the loop -----------------------------------------------------------
    def _tick(self) -> None:
        now = time.monotonic()
        if self.client is not None and not self._connected():
            self._lose_scheduler(f"lost the Dask scheduler at {self.address} (client {self.client.status})")
        if self.client is None and now >= self._next_connect:
            try:
                self._connect()
            except Exception as exc:
                self.start_error = f"cannot connect to the Dask scheduler at {self.address}: {type(exc).__name__}"
                self._next_connect = time.monotonic() + 1.0
        if self.client is not None and now - self._last_info >= 1.0:
            try:
                self._refresh_workers(now)
            except Exception as exc:
                self._lose_scheduler(f"lost the Dask scheduler at {self.address}: {type(exc).__name__}: {exc}")
        self._process_events()
        # Leases, pending results and the queue go on while disconnected; with no capacity nothing is claimed.
        super()._tick()

    def _lose_scheduler(self, reason: str) -> None:
        """The scheduler is gone, and with it every task it held (Dask's workers stop with their scheduler):
        each running job goes back to the queue at the cost of the one attempt it was on, and the client is
        dropped, so the next tick connects afresh (a restarted scheduler knows none of the old futures or
        subscriptions)."""
        log.warning("%s; re-queueing %d running jobs and reconnecting",
                    reason, sum(1 for s in self.slots if s.job_id))
        self.start_error = reason
        self._nthreads = {}
        for slot in self.slots:
            if slot.job_id is None:
                continue
            job_id = slot.job_id
            self._drop(slot)
            slot.clear_job()
            slot.pid = None
            outcome = jobs.retry_or_fail(self.db, job_id, self.owner, "the Dask scheduler was lost",
                                         self.settings.max_attempts)
            if outcome is not None and Status(outcome).finished:
                self.on_finished(job_id)
        client, self.client = self.client, None
        # Closing a client whose scheduler is gone can wait for its timeouts: not on the dispatcher thread.
        threading.Thread(target=_close_quietly, args=(client,), name="ncs-dask-close", daemon=True).start()
        self.notify()

    def _drain(self, slot: _Slot) -> None:
        pass  # events arrive through self._events

    def _idle_slots(self) -> list[_Slot]:
        if not self._connected():
            return []
        capacity = sum(self._nthreads.values())
        busy = sum(1 for s in self.slots if s.job_id is not None)
        free = [s for s in self.slots if s.job_id is None and s.pending is None]
        return free[:max(0, capacity - busy)]

    def _pid_for(self, slot: _Slot) -> int | None:
        return None  # known once the task starts on a worker (its start event)

    def _submit(self, slot: _Slot, claimed: jobs.Claimed) -> None:
        from app.compute.dask_task import run_job

        key = f"ncs-design-{claimed.id}-{claimed.attempts}"
        slot.pid = None
        slot.address = None
        slot.key = key
        self._by_key[key] = slot
        fut = self.client.submit(run_job, claimed.id, key, claimed.request, key=key, pure=False, retries=0)
        slot.future = fut
        fut.add_done_callback(lambda f: self._post("done", f))

    def _process_events(self) -> None:
        while True:
            try:
                kind, payload = self._events.get_nowait()
            except queue.Empty:
                return
            if kind == "done":
                self._on_done(payload)
                continue
            slot = self._by_key.get(payload.get("key"))
            if slot is None or slot.job_id != payload.get("job"):
                continue  # another replica's job, or one we gave up
            if kind == "progress":
                slot.progress, slot.progress_dirty = payload["progress"], True
            elif kind == "start":
                self._on_start(slot, payload)

    def _on_start(self, slot: _Slot, ev: dict) -> None:
        job_id, pid = slot.job_id, int(ev["pid"])
        if slot.pid is not None and pid != slot.pid:
            # The scheduler re-ran the task elsewhere: its previous worker died mid-job.
            reason = f"Dask worker {slot.address} (pid {slot.pid}) died"
            outcome = jobs.note_retry(self.db, job_id, self.owner, reason, self.settings.max_attempts)
            log.warning("%s running job %s -> %s", reason, job_id, outcome)
            if outcome != Status.RUNNING:
                self._forget(slot)
                return
        slot.pid, slot.address = pid, ev["address"]
        slot.started = time.monotonic()  # the time limit counts from the real start, not from the claim
        jobs.set_worker_pid(self.db, job_id, self.owner, pid)

    def _on_done(self, fut: Any) -> None:
        slot = self._by_key.get(fut.key)
        if slot is None or slot.future is not fut:
            return
        job_id = slot.job_id
        status = fut.status
        if status == "finished":
            try:
                reply = fut.result(timeout=30)
            except Exception as exc:  # pragma: no cover - the result could not be fetched
                reply = None
                err: BaseException | None = exc
            else:
                err = None
            if reply is not None:
                self._drop(slot)
                self._handle(slot, reply)
                return
        elif status == "error":
            err = fut.exception(timeout=30)
        else:
            err = None
        progress = slot.progress
        self._drop(slot)
        if err is not None and type(err).__name__ != "KilledWorker":
            self._finish(slot, job_id, Status.FAILED, error=f"Dask task failed: {type(err).__name__}: {err}",
                         progress=progress)
            return
        slot.clear_job()
        reason = (f"Dask gave up on the task: {err}" if err is not None
                  else f"the Dask scheduler lost the task ({status})")
        outcome = jobs.retry_or_fail(self.db, job_id, self.owner, reason, self.settings.max_attempts)
        log.warning("job %s: %s -> %s", job_id, reason, outcome)
        self.notify()

    def _drop(self, slot: _Slot) -> None:
        key = slot.key
        if key is not None:
            self._by_key.pop(key, None)
        slot.key = None
        slot.future = None

    def _forget(self, slot: _Slot, restart: bool = False) -> None:
        """Stop caring about a slot's task: cancel its future and, if it runs, stop its worker."""
        fut, address = slot.future, slot.address
        self._drop(slot)
        slot.clear_job()
        slot.pid = None
        if fut is not None:
            try:
                fut.cancel()
            except Exception:  # pragma: no cover
                pass
        if restart and address and self.client is not None:
            # A running Python thread cannot be interrupted: restart the worker process (via its nanny).
            client = self.client

            def restart_worker() -> None:
                try:
                    client.restart_workers([address], timeout=60, raise_for_error=False)
                except Exception:  # pragma: no cover - best effort
                    log.exception("could not restart Dask worker %s", address)

            threading.Thread(target=restart_worker, name="ncs-dask-restart", daemon=True).start()

    def _check(self, slot: _Slot, now: float) -> None:
        st = self.settings
        if slot.job_id is None:
            return
        job_id = slot.job_id
        if slot.pid is not None and now - slot.started > st.job_time_limit:
            self._forget(slot, restart=True)
            self._finish(slot, job_id, Status.FAILED,
                         error=f"time limit exceeded: the design ran longer than {st.job_time_limit:g} s "
                               f"(NCS_JOB_TIME_LIMIT) and was stopped")
            return
        if slot.cancel_sent is not None and now - slot.cancel_sent > st.cancel_grace:
            started = slot.pid is not None
            self._forget(slot, restart=started)
            self._finish(slot, job_id, Status.CANCELLED,
                         error="cancelled by request (worker stopped)" if started else "cancelled by request")

    def _send_cancel(self, slot: _Slot) -> None:
        address = slot.address
        if slot.pid is None or address is None:  # still waiting on the cluster: just drop it
            job_id = slot.job_id
            self._forget(slot)
            self._finish(slot, job_id, Status.CANCELLED, error="cancelled by request")
            return
        from app.compute.dask_task import request_cancel

        if not self._connected():
            return  # the grace timeout handles it
        try:
            self.client.run(request_cancel, slot.job_id, workers=[address], wait=False)
        except Exception:  # pragma: no cover - the worker is gone; the grace timeout handles it
            log.exception("could not send cancel for job %s", slot.job_id)

    def _shutdown(self) -> None:
        for slot in self.slots:
            try:
                self._flush_pending(slot)
            except Exception:  # pragma: no cover - the lease expires and the job runs again
                log.exception("could not record the end of job %s", slot.pending and slot.pending[0])
            job_id = slot.job_id
            if job_id is not None:
                self._forget(slot)
                try:
                    jobs.release(self.db, job_id, self.owner)
                except Exception:  # pragma: no cover - the lease will expire instead
                    log.exception("could not release job %s", job_id)
        if self.client is not None:
            try:
                self.client.close(timeout=5)
            except Exception:  # pragma: no cover
                pass
            self.client = None


def _close_quietly(client: Any) -> None:
    try:
        client.close(timeout=5)
    except Exception:  # pragma: no cover - already gone
        pass
