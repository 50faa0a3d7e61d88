"""The messages that cross a process boundary: service <-> design worker (a pipe), service <-> synchronous
pool (a future's result), service <-> Dask task (a future's result). Dataclasses, so a sender and its
receivers cannot disagree on a tuple's layout; all of them pickle."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


# -- service -> design worker ------------------------------------------------
@dataclass(frozen=True)
class Run:
    job_id: str
    request: dict[str, Any]


@dataclass(frozen=True)
class Cancel:
    job_id: str


@dataclass(frozen=True)
class Stop:
    pass


# -- design worker -> service ------------------------------------------------
@dataclass(frozen=True)
class Ready:
    pid: int


@dataclass(frozen=True)
class Progress:
    job_id: str
    record: dict[str, Any]


@dataclass(frozen=True)
class Succeeded:
    job_id: str
    result: dict[str, Any]
    progress: dict[str, Any] | None = None


@dataclass(frozen=True)
class Cancelled:
    job_id: str
    progress: dict[str, Any] | None = None


@dataclass(frozen=True)
class Failed:
    """The job failed for a reason a user can act on (the traceback, if any, went to the worker's log)."""

    job_id: str
    reason: str
    progress: dict[str, Any] | None = None


JobOutcome = Succeeded | Cancelled | Failed


# -- synchronous pool -> service ---------------------------------------------
@dataclass(frozen=True)
class SyncResult:
    value: Any


@dataclass(frozen=True)
class SyncInvalid:
    """The solver rejected the input: ``field`` is its path inside the request (e.g. ``("plant", "F", 0)``)."""

    field: tuple = field(default_factory=tuple)
    message: str = ""


@dataclass(frozen=True)
class SyncOverMemory:
    memory_mb: int


@dataclass(frozen=True)
class SyncFailed:
    reason: str


SyncOutcome = SyncResult | SyncInvalid | SyncOverMemory | SyncFailed
