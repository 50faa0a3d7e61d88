"""A small process pool for the synchronous endpoints (analyses, simulations, traces, plots).

The pool has ``workers`` slots, each its own one-process executor. A caller waits for a free slot, then
the event loop awaits its result; a call over ``sync_time_limit`` kills only its own slot's process (a
fresh one replaces it on the next call), so the other callers' work is never lost with it.

Free slots are handed out round-robin over the callers' keys (their API key, else their address): a key
that queues many long requests delays another key's request by at most one request per slot, never by
its whole backlog. The time limit counts from the moment a call gets its slot, not while it waits.

Outcomes other than a result are raised as domain errors (``app.jobs.job_errors``).
"""

from __future__ import annotations

import asyncio
import collections
import logging
import multiprocessing as mp
import os
import signal
from concurrent.futures import CancelledError as FutureCancelled
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable

from app.compute.messages import SyncFailed, SyncInvalid, SyncOverMemory, SyncResult
from app.compute.process import memory_message
from app.jobs.job_errors import ComputeFailed, ComputeTimeLimit, InvalidComputeInput, MemoryLimitExceeded, WorkerDied

log = logging.getLogger("app.jobs.sync_pool")


def _processes(executor: ProcessPoolExecutor) -> list:
    # No public API lists (or kills) a pool's processes; after shutdown() the attribute is None.
    return list((getattr(executor, "_processes", None) or {}).values())


class SyncPool:
    """``call``/``initializer`` are the worker's entry points (tests pass their own, importable functions)."""

    def __init__(self, workers: int, time_limit: float, memory_mb: int = 0, *,
                 call: Callable[..., Any] | None = None, initializer: Callable[..., None] | None = None):
        self.workers = max(1, int(workers))
        self.memory_mb = memory_mb
        self.time_limit = time_limit
        self._call = call
        self._initializer = initializer
        self._free: list[int] = list(range(self.workers))  # slot numbers
        self._slots: dict[int, ProcessPoolExecutor] = {}
        self._waiting: dict[str, collections.deque] = {}  # key -> futures of the callers waiting for a slot
        self._turns: collections.deque[str] = collections.deque()  # keys with waiters, in order of arrival
        self._served: dict[str, int] = {}  # key -> number of the last grant it got (the least recent goes next)
        self._grants = 0

    # -- slots, fair over keys -------------------------------------------------------------------------------

    async def _acquire(self, key: str) -> int:
        if self._free and not self._turns:
            self._note_grant(key)
            return self._free.pop()
        waiter = asyncio.get_running_loop().create_future()
        queue = self._waiting.setdefault(key, collections.deque())
        if not queue:
            self._turns.append(key)
        queue.append(waiter)
        try:
            return await waiter
        except asyncio.CancelledError:
            if waiter.done() and not waiter.cancelled():
                self._release(waiter.result())  # granted as we were cancelled: pass the slot on
            else:
                self._forget(key, waiter)
            raise

    def _forget(self, key: str, waiter: asyncio.Future) -> None:
        queue = self._waiting.get(key)
        if queue is not None and waiter in queue:
            queue.remove(waiter)
            if not queue:
                del self._waiting[key]
                self._turns.remove(key)

    def _note_grant(self, key: str) -> None:
        self._grants += 1
        self._served[key] = self._grants
        if len(self._served) > 4096:  # forget the keys that wait for nothing (they rank as never served)
            self._served = {k: v for k, v in self._served.items() if k in self._waiting or v == self._grants}

    def _release(self, slot: int) -> None:
        while self._turns:
            # The waiting key served least recently goes next: a key with a backlog alternates with the others.
            key = min(self._turns, key=lambda k: self._served.get(k, 0))
            queue = self._waiting[key]
            waiter = queue.popleft()
            if not queue:
                del self._waiting[key]
                self._turns.remove(key)
            if not waiter.done():
                self._note_grant(key)
                waiter.set_result(slot)
                return
        self._free.append(slot)

    def waiting(self) -> int:
        """How many calls wait for a slot."""
        return sum(len(q) for q in self._waiting.values())

    # -- processes -------------------------------------------------------------------------------------------

    def _executor(self, slot: int) -> ProcessPoolExecutor:
        ex = self._slots.get(slot)
        if ex is None:
            initializer = self._initializer
            if initializer is None:
                from app.compute.sync_worker import init_sync_worker as initializer
            ex = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"),
                                     initializer=initializer, initargs=(os.getpid(), self.memory_mb))
            self._slots[slot] = ex
        return ex

    def _discard(self, slot: int) -> None:
        ex = self._slots.pop(slot, None)
        if ex is None:
            return
        for p in _processes(ex):
            try:
                p.kill()
            except Exception:  # pragma: no cover
                pass
        ex.shutdown(wait=False, cancel_futures=True)

    @staticmethod
    def _aborted(procs: list) -> bool:
        """Whether a process of a broken pool died of SIGABRT."""
        for proc in procs:
            proc.join(timeout=1.0)
            if proc.exitcode == -signal.SIGABRT:
                return True
        return False

    async def run(self, task: str, *args: Any, key: str = "") -> Any:
        """The task's result; raises InvalidComputeInput, MemoryLimitExceeded, ComputeTimeLimit, WorkerDied
        or ComputeFailed. ``key`` names the caller for the fair turns (callers of one key share a turn)."""
        call = self._call
        if call is None:
            from app.compute.sync_worker import call_sync as call

        slot = await self._acquire(key)
        try:
            executor = self._executor(slot)
            procs: list = []
            try:
                fut = executor.submit(call, task, *args)
                procs = _processes(executor)
                out = await asyncio.wait_for(asyncio.wrap_future(fut), self.time_limit)
            except (asyncio.TimeoutError, TimeoutError):
                self._discard(slot)
                raise ComputeTimeLimit(task, self.time_limit) from None
            except (BrokenProcessPool, FutureCancelled):
                procs = procs or _processes(executor)
                aborted = await asyncio.to_thread(self._aborted, procs)
                self._discard(slot)
                if aborted and self.memory_mb > 0:
                    # Under RLIMIT_AS a native allocator (Clarabel is Rust; Rust aborts on a failed allocation
                    # instead of raising) ends the process with SIGABRT. The same request aborts the same way
                    # every time, so it is the request that is over the cap, not a transient fault: a 422.
                    log.warning("a %s worker aborted under the %d MB memory cap", task, self.memory_mb)
                    raise MemoryLimitExceeded(memory_message(self.memory_mb, "request")) from None
                raise WorkerDied(task) from None
            except asyncio.CancelledError:
                self._discard(slot)  # nobody waits for the result: free the slot now, not when it ends
                raise
        finally:
            self._release(slot)
        if isinstance(out, SyncResult):
            return out.value
        if isinstance(out, SyncInvalid):
            raise InvalidComputeInput(tuple(out.field), out.message)
        if isinstance(out, SyncOverMemory):
            raise MemoryLimitExceeded(memory_message(out.memory_mb, "request"))
        assert isinstance(out, SyncFailed), out
        raise ComputeFailed(f"the {task} failed: {out.reason}")

    def shutdown(self) -> None:
        slots, self._slots = self._slots, {}
        for ex in slots.values():
            ex.shutdown(wait=True, cancel_futures=True)
