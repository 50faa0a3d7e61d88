"""Wake-ups for requests that wait for a job to finish (``Prefer: wait=N``).

The dispatcher of this process calls :meth:`JobWatch.finished` right after it recorded a job's end, with
the job as that write left it, so a waiting request answers within a loop iteration instead of a poll
interval, and from that record instead of reading the job again. A job finished by another
replica is not seen that way: one reader thread per process asks the database which of all the
waited-on jobs are finished, every ``poll_interval`` seconds while anyone waits. One query for all
waiters, not one per waiter: at 100 designs/s with 16 waiting clients the per-waiter re-reads cost
more service CPU than the dispatcher's claim and finish together.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from typing import Any

log = logging.getLogger("app.jobs.watch")

#: The most ids one "which are finished" query asks about.
POLL_BATCH = 500


class JobWatch:
    #: How many recently finished job ids are remembered: a job that ends between the caller's read and its
    #: registration here is found in them, without a database read on every wait.
    RECENT = 4096
    #: Of those, how many keep the finished job's record (a result is a few kB).
    RECENT_RECORDS = 256

    def __init__(self, finished_among: Callable[[list[str]], Iterable[str]] | None = None,
                 poll_interval: float = 0.05, held: Callable[[list[str]], Iterable[str]] | None = None):
        """``finished_among(ids)`` returns those of ``ids`` that are finished (or gone); without it only this
        process's dispatcher wakes waiters. ``held(ids)``: those of ``ids`` this process's dispatcher runs or is
        recording the end of; it tells their waiters itself, so they are not asked about (a client waiting
        for its job on the replica that runs it costs no query)."""
        self.finished_among = finished_among
        self.held = held
        self.poll_interval = poll_interval
        self._waiters: dict[str, set[tuple[asyncio.AbstractEventLoop, asyncio.Future]]] = {}
        self._recent: OrderedDict[str, None] = OrderedDict()
        self._recent_records: OrderedDict[str, Any] = OrderedDict()
        self._lock = threading.Lock()
        self._someone_waits = threading.Event()
        self._reader: threading.Thread | None = None

    def finished(self, job_id: str, record: Any = None) -> None:
        """Called from any thread when a job ended; ``record`` is the finished job when the caller has it
        (the dispatcher's finishing write returns it), handed to the waiters."""
        self.finished_many([(job_id, record)])

    def finished_many(self, ended: list[tuple[str, Any]],
                      also: list[tuple[asyncio.AbstractEventLoop, asyncio.Future, Any]] = ()) -> None:
        """:meth:`finished` for several jobs: one wake-up per event loop, not one per waiter (waking a loop
        from another thread is a system call that, under load, costs more than the rest of the hand-over).
        ``also``: more answers for :func:`resolve_from_thread` (the dispatcher's answers to the submissions it
        wrote in the same transaction), delivered with the same wake-up."""
        answers: list[tuple[asyncio.AbstractEventLoop, asyncio.Future, Any]] = list(also)
        with self._lock:
            for job_id, record in ended:
                for loop, fut in self._waiters.pop(job_id, ()):
                    answers.append((loop, fut, record))
                self._recent[job_id] = None
                if len(self._recent) > self.RECENT:
                    self._recent.popitem(last=False)
                if record is not None:
                    self._recent_records[job_id] = record
                    if len(self._recent_records) > self.RECENT_RECORDS:
                        self._recent_records.popitem(last=False)
                else:
                    self._recent_records.pop(job_id, None)
        resolve_from_thread(answers)

    async def wait(self, job_id: str, timeout: float) -> tuple[bool, Any]:
        """Wait until the job is finished or ``timeout`` seconds passed: (finished, the finished job's record
        when this process finished it, else None: read it)."""
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        entry = (loop, fut)
        with self._lock:
            if job_id in self._recent:  # it ended between the caller's read and now
                return True, self._recent_records.get(job_id)
            self._waiters.setdefault(job_id, set()).add(entry)
            self._start_reader()
        self._someone_waits.set()
        try:
            return True, await asyncio.wait_for(fut, timeout)
        except asyncio.TimeoutError:
            return False, None
        finally:
            with self._lock:
                waiters = self._waiters.get(job_id)
                if waiters is not None:
                    waiters.discard(entry)
                    if not waiters:
                        del self._waiters[job_id]

    def _start_reader(self) -> None:
        if self.finished_among is None or self._reader is not None:
            return
        self._reader = threading.Thread(target=self._read_loop, name="ncs-job-watch", daemon=True)
        self._reader.start()

    def _read_loop(self) -> None:
        while True:
            self._someone_waits.wait()
            with self._lock:
                ids = list(self._waiters)
                if not ids:
                    self._someone_waits.clear()
                    continue
            time.sleep(self.poll_interval)
            if self.held is not None:
                mine = set(self.held(ids))
                ids = [i for i in ids if i not in mine]
            for start in range(0, len(ids), POLL_BATCH):
                try:
                    done = list(self.finished_among(ids[start:start + POLL_BATCH]))
                except Exception as exc:  # database down: the waits time out and their reads say why
                    log.debug("job watch: %s: %s", type(exc).__name__, exc)
                    continue
                self.finished_many([(job_id, None) for job_id in done])


def resolve_from_thread(answers: list[tuple[asyncio.AbstractEventLoop, asyncio.Future, Any]]) -> None:
    """Resolve futures of event loops from another thread, each with its answer (a result, or the exception
    it raises): one wake-up per event loop, not one per future (waking a loop from another thread is a system
    call that, under load, costs more than the rest of the hand-over). A future already done (its request
    went away) is left alone."""
    by_loop: dict[asyncio.AbstractEventLoop, list[tuple[asyncio.Future, Any]]] = {}
    for loop, fut, answer in answers:
        by_loop.setdefault(loop, []).append((fut, answer))
    for loop, items in by_loop.items():
        try:
            loop.call_soon_threadsafe(_resolve, items)
        except RuntimeError:  # pragma: no cover - that loop is closed
            pass


def _resolve(items: list[tuple[asyncio.Future, Any]]) -> None:
    for fut, answer in items:
        if fut.done():
            continue
        if isinstance(answer, BaseException):
            fut.set_exception(answer)
        else:
            fut.set_result(answer)
