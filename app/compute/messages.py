"""The messages that cross a process boundary: service <-> design worker (a pipe), service <-> synchronous
pool (a future's result), service <-> Dask task (a future's result, and ``Started``/``Progress`` through
Dask's event log as plain dicts, see :func:`to_event` / :func:`from_event`). Dataclasses, so a sender and
its receivers cannot disagree on a tuple's layout; all of them pickle.

An executor (``app.jobs.executor``) hands the dispatcher only these: ``Started``, ``Progress``, a
``JobOutcome`` (``Succeeded``, ``Cancelled``, ``Failed``) or ``Lost``."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
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
class Started:
    """The job began on a worker process. A second ``Started`` of one job from another pid means the executor
    re-ran it there (Dask re-runs a task whose worker died): one more attempt."""

    job_id: str
    pid: int
    address: str = ""  # the Dask worker's address; empty for a local worker process


@dataclass(frozen=True)
class Begun:
    """A Dask task began on a worker (``worker_pid``: the Dask worker process), before its job process starts
    (up to seconds): a task Dask re-runs after its worker died in that window begins again on another worker,
    so a second ``Begun`` from another worker is one more attempt even when no ``Started`` came between."""

    job_id: str
    worker_pid: int
    address: str


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


# -- executor -> dispatcher (besides the above) ---------------------------------
@dataclass(frozen=True)
class Lost:
    """The job's worker went away mid-job (the process died, Dask gave up on the task or lost its scheduler):
    the job may run again, at the cost of the attempt it was on."""

    job_id: str
    reason: str


ExecutorEvent = Begun | Started | Progress | Succeeded | Cancelled | Failed | Lost


# -- Dask's event log: plain dicts, checked on the way back ------------------------
class MalformedEvent(ValueError):
    pass


_EVENT_TYPES: dict[str, tuple[type, dict[str, type]]] = {
    "begun": (Begun, {"job_id": str, "worker_pid": int, "address": str}),
    "started": (Started, {"job_id": str, "pid": int, "address": str}),
    "progress": (Progress, {"job_id": str, "record": dict}),
}


def to_event(key: str, message: Begun | Started | Progress) -> dict[str, Any]:
    """A message as the plain dict Dask's event log carries; ``key`` names the task (job and attempt)."""
    kind = {Begun: "begun", Started: "started", Progress: "progress"}[type(message)]
    return {"key": key, "kind": kind, "fields": asdict(message)}


def from_event(event: Any) -> tuple[str, Begun | Started | Progress]:
    """The task key and the message of an event written by :func:`to_event`; :class:`MalformedEvent` if the
    dict is not one (another version of this package on a Dask worker, say)."""
    if not isinstance(event, dict) or not isinstance(event.get("key"), str):
        raise MalformedEvent(f"not an ncs-design event: {event!r:.200}")
    kind, fields = event.get("kind"), event.get("fields")
    if kind not in _EVENT_TYPES or not isinstance(fields, dict):
        raise MalformedEvent(f"unknown event kind {kind!r} or no fields")
    cls, types = _EVENT_TYPES[kind]
    if set(fields) != set(types):
        raise MalformedEvent(f"{kind} event has fields {sorted(fields)}, expected {sorted(types)}")
    for name, want in types.items():
        value = fields[name]
        if not isinstance(value, want) or (want is int and isinstance(value, bool)):
            raise MalformedEvent(f"{kind} event field {name!r} is {type(value).__name__}, expected {want.__name__}")
    return event["key"], cls(**fields)


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
