"""Wake-ups for requests that wait for a job to finish (``Prefer: wait=N``).

The dispatcher of this process calls :meth:`JobWatch.finished` right after it recorded a job's end, so a
waiting request answers within a loop iteration instead of a poll interval. A job finished by another
replica is not seen here: the waiter also re-reads the job's status, at a growing interval (bounded by
``max_poll``), so it answers within that bound anyway.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable


class JobWatch:
    #: How many recently finished job ids are remembered: a job that ends between the caller's read and its
    #: registration here is found in them, without a database read on every wait.
    RECENT = 4096

    def __init__(self, first_poll: float = 0.05, max_poll: float = 0.5):
        self.first_poll = first_poll
        self.max_poll = max_poll
        self._waiters: dict[str, set[tuple[asyncio.AbstractEventLoop, asyncio.Future]]] = {}
        self._recent: OrderedDict[str, None] = OrderedDict()
        self._lock = threading.Lock()

    def finished(self, job_id: str) -> None:
        """Called from any thread when a job ended."""
        with self._lock:
            waiters = self._waiters.pop(job_id, ())
            self._recent[job_id] = None
            if len(self._recent) > self.RECENT:
                self._recent.popitem(last=False)
        for loop, fut in waiters:
            try:
                loop.call_soon_threadsafe(_resolve, fut)
            except RuntimeError:  # pragma: no cover - that loop is closed
                pass

    async def wait(self, job_id: str, timeout: float, is_finished: Callable[[], Awaitable[bool]]) -> bool:
        """Wait until the job is finished (True) or ``timeout`` seconds passed (False)."""
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        entry = (loop, fut)
        with self._lock:
            if job_id in self._recent:  # it ended between the caller's read and now
                return True
            self._waiters.setdefault(job_id, set()).add(entry)
        deadline = time.monotonic() + timeout
        poll = self.first_poll
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                try:
                    await asyncio.wait_for(asyncio.shield(fut), min(poll, left))
                    return True
                except asyncio.TimeoutError:
                    pass
                if await is_finished():  # finished by another replica
                    return True
                poll = min(poll * 2, self.max_poll)
        finally:
            with self._lock:
                waiters = self._waiters.get(job_id)
                if waiters is not None:
                    waiters.discard(entry)
                    if not waiters:
                        del self._waiters[job_id]


def _resolve(fut: asyncio.Future) -> None:
    if not fut.done():
        fut.set_result(None)
