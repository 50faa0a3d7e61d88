"""A small process pool for the synchronous endpoints (analyses, simulations, traces, plots).

The event loop awaits the result; a call over ``sync_time_limit`` kills the pool's processes (a fresh
pool replaces it). Outcomes other than a result are raised as domain errors (``app.jobs.errors``).
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import os
import signal
import threading
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from app.compute.messages import SyncFailed, SyncInvalid, SyncOverMemory, SyncResult
from app.compute.process import memory_message
from app.jobs.errors import ComputeFailed, ComputeTimeLimit, InvalidComputeInput, MemoryLimitExceeded, WorkerDied

log = logging.getLogger("app.jobs.sync_pool")


class SyncPool:
    def __init__(self, workers: int, time_limit: float, memory_mb: int = 0):
        self.workers = workers
        self.memory_mb = memory_mb
        self.time_limit = time_limit
        self._executor: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()

    def _get(self) -> ProcessPoolExecutor:
        from app.compute.sync_worker import init_sync_worker

        with self._lock:
            if self._executor is None:
                self._executor = ProcessPoolExecutor(
                    max_workers=self.workers, mp_context=mp.get_context("spawn"),
                    initializer=init_sync_worker, initargs=(os.getpid(), self.memory_mb))
            return self._executor

    def _discard(self, executor: ProcessPoolExecutor) -> None:
        with self._lock:
            if self._executor is executor:
                self._executor = None
        procs = list(getattr(executor, "_processes", {}).values())  # no public API to kill a pool
        for p in procs:
            try:
                p.kill()
            except Exception:  # pragma: no cover
                pass
        executor.shutdown(wait=False, cancel_futures=True)

    @staticmethod
    def _aborted(executor: ProcessPoolExecutor) -> bool:
        """Whether a process of a broken pool died of SIGABRT (the others are terminated by the pool)."""
        for proc in list(getattr(executor, "_processes", {}).values()):
            proc.join(timeout=1.0)
            if proc.exitcode == -signal.SIGABRT:
                return True
        return False

    async def run(self, task: str, *args: Any) -> Any:
        """The task's result; raises InvalidComputeInput, MemoryLimitExceeded, ComputeTimeLimit, WorkerDied
        or ComputeFailed."""
        from app.compute.sync_worker import call_sync

        executor = self._get()
        try:
            fut = executor.submit(call_sync, task, *args)
            out = await asyncio.wait_for(asyncio.wrap_future(fut), self.time_limit)
        except (asyncio.TimeoutError, TimeoutError):
            self._discard(executor)
            raise ComputeTimeLimit(task, self.time_limit) from None
        except BrokenProcessPool:
            aborted = await asyncio.to_thread(self._aborted, executor)
            self._discard(executor)
            if aborted and self.memory_mb > 0:
                # Under RLIMIT_AS a native allocator (Clarabel is Rust; Rust aborts on a failed allocation
                # instead of raising) ends the process with SIGABRT. The same request aborts the same way
                # every time, so it is the request that is over the cap, not a transient fault: a 422.
                log.warning("a %s worker aborted under the %d MB memory cap", task, self.memory_mb)
                raise MemoryLimitExceeded(memory_message(self.memory_mb, "request")) from None
            raise WorkerDied(task) from None
        if isinstance(out, SyncResult):
            return out.value
        if isinstance(out, SyncInvalid):
            raise InvalidComputeInput(tuple(out.field), out.message)
        if isinstance(out, SyncOverMemory):
            raise MemoryLimitExceeded(memory_message(out.memory_mb, "request"))
        assert isinstance(out, SyncFailed), out
        raise ComputeFailed(f"the {task} failed: {out.reason}")

    def shutdown(self) -> None:
        with self._lock:
            ex, self._executor = self._executor, None
        if ex is not None:
            ex.shutdown(wait=True, cancel_futures=True)
