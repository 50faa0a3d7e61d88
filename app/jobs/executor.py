"""The interface between the dispatcher (``app.jobs.dispatcher``) and what runs its jobs.

The dispatcher owns everything about the job table: claiming, leases, heartbeats, progress writes,
retries, time limits, cancel grace and finishing through the store. An executor only runs claimed
jobs somewhere and reports back with the typed messages of ``app.compute.messages``
(``Started``, ``Progress``, ``Succeeded``/``Cancelled``/``Failed``, ``Lost``). Two implementations:
local worker processes (``app.jobs.local_executor``) and a Dask cluster (``app.jobs.dask_executor``).

All methods are called from the dispatcher thread only.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Callable

from app.compute.messages import ExecutorEvent
from app.jobs.store import Claimed


class FreeSlot:
    """Room for one more job. ``pid`` is the worker process the job will run on when the executor knows it
    before the job starts (it is then recorded with the claim, saving a database write), else None."""

    __slots__ = ("pid", "token")

    def __init__(self, pid: int | None, token: Any = None):
        self.pid = pid
        self.token = token  # the executor's own reference (e.g. its worker slot)


class Executor(ABC):
    @abstractmethod
    def start(self, wake: Callable[[], None]) -> None:
        """Start the workers (or connect). ``wake()`` wakes the dispatcher; an executor whose events do not
        arrive on :meth:`waitables` calls it when it has some."""

    @abstractmethod
    def maintain(self, now: float) -> None:
        """Housekeeping once per dispatcher tick: replace dead workers, reconnect, refresh the capacity."""

    @abstractmethod
    def free_slots(self) -> list[FreeSlot]:
        """Room for this many more jobs now (empty while nothing can take work)."""

    @abstractmethod
    def submit(self, slot: FreeSlot, job: Claimed) -> Any:
        """Run a claimed job in a slot from :meth:`free_slots`; returns the handle :meth:`cancel` and :meth:`stop`
        take. A job that cannot be handed over is reported later as ``Lost``."""

    @abstractmethod
    def poll(self) -> list[ExecutorEvent]:
        """The messages that arrived since the last call, in order; each names a job this executor holds."""

    def waitables(self) -> list[Any]:
        """Objects ``multiprocessing.connection.wait`` can sleep on until :meth:`poll` has something."""
        return []

    @abstractmethod
    def cancel(self, handle: Any) -> None:
        """Ask the job to stop at its next solver iteration (cooperative; the dispatcher enforces a grace)."""

    @abstractmethod
    def stop(self, handle: Any, interrupt: bool = True) -> None:
        """Stop caring about the job: no message about it follows. ``interrupt`` also stops a running
        computation where that costs more than dropping it (the Dask executor kills the job's process on its
        worker; a local worker process is always killed, it cannot take another job otherwise)."""

    @abstractmethod
    def shutdown(self) -> None:
        """Stop the workers (or disconnect); jobs still held were given up with :meth:`stop` first."""

    # -- for /readyz ---------------------------------------------------------
    @abstractmethod
    def configured_workers(self) -> int: ...

    @abstractmethod
    def alive_workers(self) -> int: ...

    @abstractmethod
    def ready_workers(self) -> int:
        """Workers that can take a job now; 0 makes the service not ready."""

    @property
    def error(self) -> str | None:
        """Why workers are missing (start-up failures, no scheduler), cleared once they are back."""
        return None
