"""A small process pool for the synchronous endpoints (analyses, simulations,
traces). The event loop awaits the result; a call over ``sync_time_limit``
kills the pool's processes (a fresh pool replaces it) and answers 503.
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

from app.problems import ProblemException

log = logging.getLogger("app.syncpool")


def _init_worker(parent_pid: int, memory_mb: int = 0) -> None:
    from app.worker import _die_with_parent, apply_memory_limit, limit_blas_threads

    limit_blas_threads()
    from app import tasks

    _die_with_parent(parent_pid)
    tasks.warm_up()
    apply_memory_limit(memory_mb)
    tasks._MEMORY_MB = memory_mb


class SyncPool:
    def __init__(self, workers: int, time_limit: float, memory_mb: int = 0):
        self.workers = workers
        self.memory_mb = memory_mb
        self.time_limit = time_limit
        self._executor: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()

    def _get(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._executor is None:
                self._executor = ProcessPoolExecutor(
                    max_workers=self.workers, mp_context=mp.get_context("spawn"),
                    initializer=_init_worker, initargs=(os.getpid(), self.memory_mb))
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

    async def run(self, task: str, *args: Any) -> tuple:
        from app.tasks import call_sync

        executor = self._get()
        try:
            fut = executor.submit(call_sync, task, *args)
            return await asyncio.wait_for(asyncio.wrap_future(fut), self.time_limit)
        except (asyncio.TimeoutError, TimeoutError):
            self._discard(executor)
            raise ProblemException(503, f"the {task} took longer than {self.time_limit:g} s "
                                        "(NCS_SYNC_TIME_LIMIT) and was stopped", title="Time limit exceeded")
        except BrokenProcessPool:
            aborted = await asyncio.to_thread(self._aborted, executor)
            self._discard(executor)
            if aborted and self.memory_mb > 0:
                # Under RLIMIT_AS a native allocator (Clarabel is Rust; Rust aborts on a failed allocation
                # instead of raising) ends the process with SIGABRT. The same request aborts the same way
                # every time, so it is the request that is over the cap, not a transient fault: a 422.
                log.warning("a %s worker aborted under the %d MB memory cap", task, self.memory_mb)
                from app.problems import TYPE_BASE
                from app.worker import memory_message

                raise ProblemException(422, memory_message(self.memory_mb, "request"),
                                       title="Resource limit exceeded", type_=TYPE_BASE + "limit-exceeded")
            raise ProblemException(503, f"the {task} worker process died; try again",
                                   title="Worker process died")

    def shutdown(self) -> None:
        with self._lock:
            ex, self._executor = self._executor, None
        if ex is not None:
            ex.shutdown(wait=True, cancel_futures=True)


def unwrap(out: tuple, loc_base: list, plant: dict | None) -> Any:
    """Result of ``tasks.call_sync`` -> the value, or a problem (422 for invalid input, 500 for a crash)."""
    from app.problems import invalid
    from app.validation import solver_field_error

    if out[0] == "ok":
        return out[1]
    if out[0] == "invalid":
        raise invalid([solver_field_error(tuple(out[1]), out[2], plant, loc_base)])
    if out[0] == "memory":
        from app.problems import TYPE_BASE
        from app.worker import memory_message

        raise ProblemException(422, memory_message(out[1], "request"), title="Resource limit exceeded",
                               type_=TYPE_BASE + "limit-exceeded")
    raise ProblemException(500, f"the solver failed: {out[1]}", title="Solver error")
