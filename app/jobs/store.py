"""The job store: every change of a job's state, for the HTTP side (submit, get, list, cancel) and the
dispatcher (claim, lease, progress, finish, retry, release).

Every state change is one short transaction guarded by the job's current
status (and, for running jobs, by the lease owner), so two dispatchers or a
dispatcher and a cancel request can never both win.

The paths every job takes (submit, claim, finish, get, the waiters' "which are finished") are constant
Core statements with bound parameters on a plain connection: SQLAlchemy compiles each once, and a job
costs a few statements' worth of driver work instead of the ORM's per-call statement building and unit
of work. They answer with :class:`~app.jobs.tables.JobRecord` snapshots.
"""

from __future__ import annotations

import hashlib
import json
import uuid
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

from sqlalchemy import and_, bindparam, func, select, text, update
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.engine import Connection
from sqlalchemy.exc import IntegrityError

from app.jobs.database import Database
from app.jobs.job_errors import IdempotencyKeyReused, JobAlreadyFinished, JobNotFound, OwnerQueueFull, QueueFull
from app.jobs.tables import Job, JobRecord, Status, new_id, utcnow

_T = Job.__table__
_C = _T.c
_QUEUED, _RUNNING = Status.QUEUED.value, Status.RUNNING.value


def _record(row) -> JobRecord:
    return JobRecord(**row._mapping)


@dataclass
class Claimed:
    id: str
    request: dict[str, Any]
    attempts: int


_HAS_QUEUED = select(_C.id).where(_C.status == _QUEUED).limit(1)


def has_queued(db: Database) -> bool:
    with db.read_conn() as c:
        return c.execute(_HAS_QUEUED).first() is not None


_CLAIM_IDS = (select(_C.id).where(_C.status == _QUEUED).order_by(_C.created_at, _C.id)
              .limit(bindparam("b_n")).with_for_update(skip_locked=True))
_CLAIM_ONE = (
    update(_T).where(_C.id == bindparam("b_id"), _C.status == _QUEUED)
    .values(status=_RUNNING, lease_owner=bindparam("b_owner", type_=_C.lease_owner.type),
            lease_expires_at=bindparam("b_lease", type_=_C.lease_expires_at.type), attempts=_C.attempts + 1,
            started_at=bindparam("b_now", type_=_C.started_at.type), updated_at=bindparam("b_now"),
            worker_pid=bindparam("b_pid", type_=_C.worker_pid.type))
    .returning(_C.request, _C.attempts)
)

# -- fair claims: one turn per owner with queued work -------------------------------------------------------
# The owners with queued jobs, found by a skip scan of ix_jobs_status_owner_created: one index seek per owner,
# whatever the length of the queue (a GROUP BY would read every queued row); and a last row NULL when jobs
# without an owner are queued (one more index seek). One statement: on PostgreSQL each is a round trip.
_QUEUED_OWNERS = text(
    "WITH RECURSIVE o(owner) AS ("
    " SELECT (SELECT owner FROM jobs WHERE status = 'queued' AND owner IS NOT NULL ORDER BY owner LIMIT 1)"
    " UNION ALL"
    " SELECT (SELECT j.owner FROM jobs j WHERE j.status = 'queued' AND j.owner > o.owner ORDER BY j.owner LIMIT 1)"
    " FROM o WHERE o.owner IS NOT NULL)"
    " SELECT owner FROM o WHERE owner IS NOT NULL"
    " UNION ALL"
    " SELECT NULL WHERE EXISTS (SELECT 1 FROM jobs WHERE status = 'queued' AND owner IS NULL)")
_OLDEST_OF_OWNER = (select(_C.id).where(_C.status == _QUEUED, _C.owner == bindparam("b_qowner"))
                    .order_by(_C.created_at, _C.id).limit(bindparam("b_n")).with_for_update(skip_locked=True))
_OLDEST_UNOWNED = (select(_C.id).where(_C.status == _QUEUED, _C.owner.is_(None))
                   .order_by(_C.created_at, _C.id).limit(bindparam("b_n")).with_for_update(skip_locked=True))
_RUNNING_PER_OWNER = select(_C.owner, func.count()).where(_C.status == _RUNNING).group_by(_C.owner)


class OwnerTurns:
    """Which owner (API key) a dispatcher served last: the order of the next fair claim.

    Claims go round-robin over the owners with queued work, least recently served first, every owner with
    weight 1: a key's next job waits for at most one job of every other key with queued work, however many
    jobs those keys have queued. Kept per dispatcher (no shared row to lock on every claim); with several
    replicas each one alternates, so the order holds globally up to one job per replica.
    """

    def __init__(self) -> None:
        self._last: dict[str | None, int] = {}
        self._clock = 0

    def order(self, owners: list[str | None]) -> list[str | None]:
        return sorted(owners, key=lambda o: self._last.get(o, -1))

    def served(self, owner: str | None) -> None:
        self._clock += 1
        self._last[owner] = self._clock


@dataclass
class ClaimPolicy:
    """How a dispatcher claims: ``turns`` None is oldest first over all owners (no fairness);
    ``max_running_per_owner`` caps the running jobs of one owner over every dispatcher on the database."""

    turns: OwnerTurns | None = None
    max_running_per_owner: int | None = None


def _fair_pick(c: Connection, n: int, policy: ClaimPolicy) -> list[str]:
    """The ids of up to ``n`` queued jobs, one per owner in turn (see :class:`OwnerTurns`), each owner's
    oldest first, skipping owners at their running cap. Rows locked (SKIP LOCKED) until the commit."""
    turns = policy.turns or OwnerTurns()
    owners: list[str | None] = [r[0] for r in c.execute(_QUEUED_OWNERS)]  # None last, if any
    room = {o: n for o in owners}
    if policy.max_running_per_owner is not None and owners:
        running = {o: k for o, k in c.execute(_RUNNING_PER_OWNER)}
        room = {o: min(n, policy.max_running_per_owner - running.get(o, 0)) for o in owners}
    lists = []
    for o in turns.order([o for o in owners if room[o] > 0]):
        if o is None:
            ids = [r[0] for r in c.execute(_OLDEST_UNOWNED, {"b_n": room[o]})]
        else:
            ids = [r[0] for r in c.execute(_OLDEST_OF_OWNER, {"b_qowner": o, "b_n": room[o]})]
        if ids:
            lists.append((o, ids))
    picked: list[str] = []
    depth = 0
    while len(picked) < n and lists:
        for o, ids in lists:
            if depth < len(ids) and len(picked) < n:
                picked.append(ids[depth])
                turns.served(o)
        lists = [(o, ids) for o, ids in lists if len(ids) > depth + 1]
        depth += 1
    return picked


def _claim(c: Connection, owner: str, lease_seconds: float, pids: list[int | None],
           policy: ClaimPolicy | None = None) -> list[Claimed]:
    """Claim up to ``len(pids)`` queued jobs, inside the caller's transaction: owner by owner in turn
    (:func:`_fair_pick`), or the oldest over all owners when ``policy`` asks for neither turns nor a cap.

    The i-th claimed job records ``pids[i]`` as its worker pid (``None``/0: not known yet).
    On PostgreSQL ``FOR UPDATE SKIP LOCKED`` lets several dispatchers claim at once without
    waiting for or double-claiming each other; SQLite serializes the write transactions.
    """
    if policy is None or (policy.turns is None and policy.max_running_per_owner is None):
        ids = [r[0] for r in c.execute(_CLAIM_IDS, {"b_n": len(pids)})]
    else:
        ids = _fair_pick(c, len(pids), policy)
    if not ids:
        return []
    now = utcnow()
    lease = now + timedelta(seconds=lease_seconds)
    out = []
    for job_id, pid in zip(ids, pids):
        row = c.execute(_CLAIM_ONE, {"b_id": job_id, "b_owner": owner, "b_lease": lease, "b_now": now,
                                     "b_pid": pid or None}).first()
        if row is not None:
            out.append(Claimed(job_id, row.request, row.attempts))
    return out


def _running_owned(job_id: str, owner: str):
    return and_(Job.id == job_id, Job.status == Status.RUNNING, Job.lease_owner == owner)


def set_worker_pid(db: Database, job_id: str, owner: str, pid: int) -> None:
    with db.write() as s:
        s.execute(update(Job).where(_running_owned(job_id, owner)).values(worker_pid=pid, updated_at=utcnow()))


def update_progress(db: Database, job_id: str, owner: str, progress: dict[str, Any]) -> None:
    with db.write() as s:
        s.execute(update(Job).where(_running_owned(job_id, owner)).values(progress=progress, updated_at=utcnow()))


_FINISH_VALUES = dict(status=bindparam("b_status", type_=_C.status.type),
                      finished_at=bindparam("b_now", type_=_C.finished_at.type), updated_at=bindparam("b_now"),
                      lease_owner=None, lease_expires_at=None,
                      result=bindparam("b_result", type_=_C.result.type),
                      error=bindparam("b_error", type_=_C.error.type))
_FINISH_WHERE = (_C.id == bindparam("b_id"), _C.status == _RUNNING, _C.lease_owner == bindparam("b_owner"))
# The job as the finishing write left it, but for the two JSON documents the caller already holds (the
# result it writes, the request it claimed): read back they would only be decoded again.
_FINISHED_COLUMNS = [c for c in _C if c.name not in ("request", "result")]
# Two constant statements: the progress column is left as it is when the outcome brings none.
_FINISH = update(_T).where(*_FINISH_WHERE).values(**_FINISH_VALUES).returning(*_FINISHED_COLUMNS)
_FINISH_WITH_PROGRESS = (update(_T).where(*_FINISH_WHERE)
                         .values(**_FINISH_VALUES, progress=bindparam("b_progress", type_=_C.progress.type))
                         .returning(*_FINISHED_COLUMNS))


@dataclass
class Ending:
    """A job's end, as the dispatcher records it; ``request`` is the job's request as claimed (it completes
    the returned record; not written)."""

    job_id: str
    status: str
    result: dict[str, Any] | None = None
    error: str | None = None
    progress: dict[str, Any] | None = None
    request: dict[str, Any] | None = None


def _finish(c: Connection, owner: str, end: Ending) -> JobRecord | None:
    assert end.status in (Status.SUCCEEDED, Status.FAILED, Status.CANCELLED)
    params = {"b_id": end.job_id, "b_owner": owner, "b_status": str(end.status), "b_now": utcnow(),
              "b_result": end.result, "b_error": end.error}
    if end.progress is not None:
        params["b_progress"] = end.progress
    row = c.execute(_FINISH_WITH_PROGRESS if end.progress is not None else _FINISH, params).first()
    if row is None:
        return None
    if end.request is None:  # not known here: read it
        request = c.execute(select(_C.request).where(_C.id == end.job_id)).scalar_one()
    else:
        request = end.request
    return JobRecord(**row._mapping, request=request, result=end.result)


#: A lost attempt with attempts left: back to the queue, lease dropped.
_REQUEUE = dict(status=Status.QUEUED, lease_owner=None, lease_expires_at=None)


def _after_lost_attempt(job, reason: str, max_attempts: int, now, retry: dict) -> dict:
    """Column values for a job whose attempt was lost (worker died, service died, task re-run).

    Cancelled if a cancel was asked for, failed when its attempts are used up (both drop the
    lease), otherwise ``retry`` with the reason recorded.
    """
    if job.cancel_requested:
        return dict(status=Status.CANCELLED, finished_at=now, error="cancelled by request",
                    lease_owner=None, lease_expires_at=None)
    if job.attempts >= max_attempts:
        return dict(status=Status.FAILED, finished_at=now, lease_owner=None, lease_expires_at=None,
                    error=f"{reason}; giving up after {job.attempts} of {max_attempts} attempts")
    return {**retry, "error": f"{reason}; retrying (attempt {job.attempts} of {max_attempts} failed)"}


def retry_or_fail(db: Database, job_id: str, owner: str, reason: str, max_attempts: int) -> str | None:
    """After a worker died: queue the job again, or fail it when its attempts are used up."""
    now = utcnow()
    with db.write() as s:
        job = s.execute(select(Job.attempts, Job.cancel_requested).where(_running_owned(job_id, owner))).first()
        if job is None:
            return None
        values = _after_lost_attempt(job, reason, max_attempts, now, _REQUEUE)
        s.execute(update(Job).where(_running_owned(job_id, owner)).values(worker_pid=None, updated_at=now, **values))
        return values["status"]


def note_retry(db: Database, job_id: str, owner: str, reason: str, max_attempts: int) -> str | None:
    """The executor re-ran a running job by itself (Dask reschedules the task of a dead worker):
    count the attempt; past ``max_attempts`` the job ends failed. Returns the job's new status."""
    now = utcnow()
    with db.write() as s:
        job = s.execute(select(Job.attempts, Job.cancel_requested).where(_running_owned(job_id, owner))).first()
        if job is None:
            return None
        values = _after_lost_attempt(job, reason, max_attempts, now,
                                     dict(status=Status.RUNNING, attempts=job.attempts + 1, started_at=now))
        s.execute(update(Job).where(_running_owned(job_id, owner)).values(worker_pid=None, updated_at=now, **values))
        return values["status"]


def release(db: Database, job_id: str, owner: str) -> None:
    """Graceful shutdown: give a running job back to the queue without using up an attempt."""
    with db.write() as s:
        s.execute(update(Job).where(_running_owned(job_id, owner))
                  .values(status=Status.QUEUED, attempts=Job.attempts - 1, lease_owner=None, lease_expires_at=None,
                          worker_pid=None, progress=None, updated_at=utcnow()))


def heartbeat(db: Database, owner: str, job_ids: list[str], lease_seconds: float) -> None:
    if not job_ids:
        return
    now = utcnow()
    with db.write() as s:
        s.execute(update(Job).where(Job.id.in_(job_ids), Job.status == Status.RUNNING, Job.lease_owner == owner)
                  .values(lease_expires_at=now + timedelta(seconds=lease_seconds)))


def recover_expired(db: Database, max_attempts: int) -> list[str]:
    """Jobs whose service died (lease expired) go back to the queue (or fail/cancel)."""
    now = utcnow()
    with db.read() as s:
        rows = s.execute(select(Job.id).where(Job.status == Status.RUNNING, Job.lease_expires_at < now)).all()
    recovered = []
    for (job_id,) in rows:
        with db.write() as s:
            job = s.execute(select(Job.attempts, Job.cancel_requested, Job.lease_owner)
                            .where(Job.id == job_id, Job.status == Status.RUNNING, Job.lease_expires_at < now)).first()
            if job is None:
                continue
            values = _after_lost_attempt(job, "the service running this job stopped (lease expired)", max_attempts,
                                         now, _REQUEUE)
            s.execute(update(Job).where(Job.id == job_id, Job.status == Status.RUNNING, Job.lease_owner == job.lease_owner)
                      .values(worker_pid=None, updated_at=now, **values))
            recovered.append(job_id)
    return recovered


_CANCEL_REQUESTED = select(_C.id).where(_C.id.in_(bindparam("b_ids", expanding=True)),
                                        _C.cancel_requested.is_(True))


def cancel_requested_among(db: Database, job_ids: list[str]) -> set[str]:
    if not job_ids:
        return set()
    with db.read_conn() as c:
        return {r[0] for r in c.execute(_CANCEL_REQUESTED, {"b_ids": list(job_ids)})}


# -- the request side: submit, read, list, cancel ---------------------------------------------------
def canonical_json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)


def _is_uuid(job_id: str) -> bool:
    """Every job id is a UUID: anything else cannot name a job, and is answered without a query (a NUL
    byte, for one, is an error in PostgreSQL's text protocol, not a miss)."""
    if len(job_id) != 36:
        return False
    try:
        uuid.UUID(job_id)
    except ValueError:
        return False
    return True


def _visible(row: Job | None, kind: str, owner: str | None) -> bool:
    """A job of this kind, visible only to the key that created it (when keys are configured). Others get
    the same JobNotFound as for an id that does not exist, so ids do not leak."""
    return row is not None and row.kind == kind and (owner is None or row.owner == owner)


_GET = select(_T).where(_C.id == bindparam("b_id"))


def get(db: Database, kind: str, job_id: str, owner: str | None = None) -> JobRecord:
    """The job as it is now; JobNotFound when it does not exist or is not the caller's."""
    if not _is_uuid(job_id):
        raise JobNotFound(kind, job_id)

    def read() -> JobRecord | None:
        with db.read_conn() as c:
            row = c.execute(_GET, {"b_id": job_id}).first()
        return _record(row) if row is not None else None

    row = db.retry_on_disconnect(read)
    if not _visible(row, kind, owner):
        raise JobNotFound(kind, job_id)
    return row


@dataclass
class Submitted:
    job: JobRecord
    replayed: bool  # an Idempotency-Key seen before with the same body: the existing job


def scoped_idempotency_key(key: str | None, owner: str | None) -> str | None:
    """Idempotency keys are per API key: two callers using the same key get two jobs (stored hashed)."""
    if key is None or owner is None:
        return key
    return "o:" + hashlib.sha256(f"{owner}:{key}".encode("utf-8", "surrogatepass")).hexdigest()


_BY_IDEMPOTENCY_KEY = select(_T).where(_C.idempotency_key == bindparam("b_key"))
_INSERT = _T.insert()
_QUEUED_COUNT = select(func.count()).select_from(_T).where(_C.status == _QUEUED)
_QUEUED_OF_OWNER = select(func.count()).select_from(_T).where(_C.status == _QUEUED, _C.owner == bindparam("b_qowner"))
_QUEUED_UNOWNED = select(func.count()).select_from(_T).where(_C.status == _QUEUED, _C.owner.is_(None))


def _queued_of(c: Connection, owner: str | None) -> int:
    """How many jobs ``owner`` has queued (an index range count on ix_jobs_status_owner_created)."""
    if owner is None:
        return c.execute(_QUEUED_UNOWNED).scalar_one()
    return c.execute(_QUEUED_OF_OWNER, {"b_qowner": owner}).scalar_one()
_EXISTS = select(_C.id).where(_C.id == bindparam("b_id"))


#: The columns a new job's INSERT sets; the others start NULL.
_INSERTED = ("id", "kind", "status", "method", "n_drop", "request", "request_hash", "idempotency_key", "attempts",
             "cancel_requested", "created_at", "updated_at", "owner")


@dataclass
class Submission:
    """A validated job ready to be inserted: the record the submitter is answered with, and the row."""

    row: JobRecord
    values: dict[str, Any]
    #: When the request handler handed it to the dispatcher (time.monotonic()): its wait is bounded from here.
    handed_at: float = 0.0

    def replay(self, existing: JobRecord) -> Submitted:
        """The answer when the Idempotency-Key is taken by ``existing``."""
        if existing.request_hash != self.row.request_hash:
            raise IdempotencyKeyReused()
        return Submitted(existing, replayed=True)


def prepare(kind: str, request: dict[str, Any], n_drop: int, *, idempotency_key: str | None = None,
            owner: str | None = None) -> Submission:
    digest = hashlib.sha256(canonical_json(request).encode()).hexdigest()
    stored_key = scoped_idempotency_key(idempotency_key, owner)
    now = utcnow()
    row = JobRecord(id=new_id(), kind=kind, status=_QUEUED, method=request["method"], n_drop=n_drop,
                    request=request, request_hash=digest, idempotency_key=stored_key, progress=None, result=None,
                    error=None, attempts=0, cancel_requested=False, lease_owner=None, lease_expires_at=None,
                    worker_pid=None, created_at=now, started_at=None, finished_at=None, updated_at=now, owner=owner)
    return Submission(row, {name: getattr(row, name) for name in _INSERTED})


def _lookup(c: Connection, stored_key: str) -> JobRecord | None:
    found = c.execute(_BY_IDEMPOTENCY_KEY, {"b_key": stored_key}).first()
    return _record(found) if found is not None else None


def submit(db: Database, kind: str, request: dict[str, Any], n_drop: int, *, idempotency_key: str | None = None,
           owner: str | None = None, max_queue_depth: int | None = None, retry_after: int = 5,
           max_queued_per_owner: int | None = None) -> Submitted:
    """Queue a validated job, or return the one an earlier submission with the same Idempotency-Key made.

    Raises IdempotencyKeyReused (same key, other body) and QueueFull (back-pressure: more than
    ``max_queue_depth`` jobs waiting; :class:`OwnerQueueFull` when ``owner`` has ``max_queued_per_owner``
    queued). One short write transaction (the queue-depth counts and the INSERT);
    a connection lost on the way is retried once. An Idempotency-Key is looked up only when the INSERT
    finds it taken (the key is unique) or the queue is full: a new key, the usual case, costs no read.
    (A running dispatcher batches submissions instead: :func:`write_batch`.)
    """
    sub = prepare(kind, request, n_drop, idempotency_key=idempotency_key, owner=owner)
    stored_key = sub.row.idempotency_key

    def lookup() -> JobRecord | None:
        with db.read_conn() as c:
            return _lookup(c, stored_key)

    def insert() -> None:
        # The back-pressure count and the INSERT share one write transaction (one connection checkout and
        # commit per submission, and the count cannot go stale before the insert).
        with db.write_conn() as c:
            if max_queued_per_owner is not None:
                mine = _queued_of(c, owner)
                if mine >= max_queued_per_owner:
                    raise OwnerQueueFull(mine, max_queued_per_owner, retry_after)
            if max_queue_depth is not None:
                queued = c.execute(_QUEUED_COUNT).scalar_one()
                if queued >= max_queue_depth:
                    raise QueueFull(queued, max_queue_depth, retry_after)
            c.execute(_INSERT, sub.values)

    try:
        db.retry_on_disconnect(insert)
    except QueueFull:
        existing = db.retry_on_disconnect(lookup) if stored_key is not None else None
        if existing is None:
            raise
        return sub.replay(existing)  # a retried submission is answered even when the queue is full
    except IntegrityError:
        def committed() -> bool:
            with db.read_conn() as c:
                return c.execute(_EXISTS, {"b_id": sub.row.id}).first() is not None

        if db.retry_on_disconnect(committed):  # the lost connection had committed it after all
            return Submitted(sub.row, replayed=False)
        existing = db.retry_on_disconnect(lookup) if stored_key is not None else None
        if existing is None:  # not a race on the idempotency key: a bug
            raise
        return sub.replay(existing)  # the key is taken: an earlier (or concurrent) request with it
    return Submitted(sub.row, replayed=False)


#: INSERT ... ON CONFLICT DO NOTHING: in a batch, a taken Idempotency-Key must not abort the transaction.
_INSERT_NEW = {"sqlite": sqlite_insert(_T).on_conflict_do_nothing(),
               "postgresql": pg_insert(_T).on_conflict_do_nothing()}


def batches_submissions(db: Database) -> bool:
    """Whether :func:`write_batch` can insert submissions on this database."""
    return db.engine.dialect.name in _INSERT_NEW


def _insert_many(c: Connection, subs: list[Submission], max_queue_depth: int | None,
                 retry_after: int, max_queued_per_owner: int | None = None) -> list[Submitted | Exception]:
    """Each submission in turn, as :func:`submit` would answer it one after the other (Submitted, or the
    QueueFull / OwnerQueueFull / IdempotencyKeyReused it raises), inside the caller's transaction."""
    insert = _INSERT_NEW[c.dialect.name]
    queued = c.execute(_QUEUED_COUNT).scalar_one() if max_queue_depth is not None else 0
    mine: dict[str | None, int] = {}  # per owner in this batch: its queued jobs, counted once
    out: list[Submitted | Exception] = []
    for sub in subs:
        key = sub.row.idempotency_key
        owner = sub.row.owner
        try:
            full = None
            if max_queued_per_owner is not None:
                if owner not in mine:
                    mine[owner] = _queued_of(c, owner)
                if mine[owner] >= max_queued_per_owner:
                    full = OwnerQueueFull(mine[owner], max_queued_per_owner, retry_after)
            if full is None and max_queue_depth is not None and queued >= max_queue_depth:
                full = QueueFull(queued, max_queue_depth, retry_after)
            if full is not None:
                existing = _lookup(c, key) if key is not None else None
                if existing is None:
                    raise full
                out.append(sub.replay(existing))
            elif c.execute(insert, sub.values).rowcount == 1:
                queued += 1
                if owner in mine:
                    mine[owner] += 1
                out.append(Submitted(sub.row, replayed=False))
            elif c.execute(_EXISTS, {"b_id": sub.row.id}).first() is not None:
                out.append(Submitted(sub.row, replayed=False))  # a retried transaction: the first one committed
            else:
                existing = _lookup(c, key) if key is not None else None
                if existing is None:  # pragma: no cover - no other unique column
                    raise RuntimeError(f"job {sub.row.id} conflicts with a row that is not its idempotency key")
                out.append(sub.replay(existing))
        except (QueueFull, IdempotencyKeyReused, RuntimeError) as exc:
            out.append(exc)
    return out


def write_batch(db: Database, owner: str, submissions: list[Submission], endings: list[Ending],
                lease_seconds: float, pids: list[int | None], max_queue_depth: int | None = None,
                retry_after: int = 5, *, max_queued_per_owner: int | None = None, policy: ClaimPolicy | None = None,
                busy_timeout: float | None = None,
                ) -> tuple[list[Submitted | Exception], list[JobRecord | None], list[Claimed]]:
    """One dispatcher write: insert ``submissions`` (answered per submission as :func:`submit` answers, an
    error as the exception it would raise), record ``endings`` and claim up to ``len(pids)`` queued jobs, all
    in one transaction: a worker that just finished a job takes the next one without a second commit.
    Retried once on a connection found dead (every step is safe to repeat). Nothing is written if it raises.

    ``busy_timeout`` (s, SQLite) bounds the wait for the write lock of this transaction (the submitters'
    remaining wait); ``policy`` is how jobs are claimed (:class:`ClaimPolicy`).

    Returns the answers, per ending the job as it now is (None when this owner no longer held it: its lease
    was lost or it was cancelled meanwhile), and the claimed jobs."""
    def run():
        with db.write_conn(busy_timeout) as c:
            answers = (_insert_many(c, submissions, max_queue_depth, retry_after, max_queued_per_owner)
                       if submissions else [])
            ended = [_finish(c, owner, end) for end in endings]
            claimed = _claim(c, owner, lease_seconds, pids, policy) if pids else []
        return answers, ended, claimed

    return db.retry_on_disconnect(run)


def queue_depth(db: Database) -> int:
    with db.read_conn() as c:
        return c.execute(_QUEUED_COUNT).scalar_one()


def list_jobs(db: Database, kind: str, status: str | None, limit: int, offset: int,
              owner: str | None = None) -> tuple[list[Job], int]:
    """One page of the caller's jobs of a kind, newest first, and how many there are in all."""
    q = select(Job).where(Job.kind == kind)
    count = select(func.count()).select_from(Job).where(Job.kind == kind)
    if owner is not None:
        q = q.where(Job.owner == owner)
        count = count.where(Job.owner == owner)
    if status is not None:
        q = q.where(Job.status == status)
        count = count.where(Job.status == status)

    def read() -> tuple[list[Job], int]:
        with db.read() as s:
            rows = s.execute(q.order_by(Job.created_at.desc(), Job.id.desc()).limit(limit).offset(offset)
                             ).scalars().all()
            total = s.execute(count).scalar_one()
            s.expunge_all()
            return list(rows), total

    return db.retry_on_disconnect(read)


@dataclass
class CancelOutcome:
    job: Job
    at_once: bool  # queued (now cancelled) or already cancelled; False: a running job was asked to stop


def cancel(db: Database, kind: str, job_id: str, owner: str | None = None) -> CancelOutcome:
    """Cancel a job: a queued one at once, a running one by request (its dispatcher stops it).
    Raises JobNotFound, and JobAlreadyFinished for a succeeded or failed job."""
    if not _is_uuid(job_id):
        raise JobNotFound(kind, job_id)
    with db.write() as s:  # one short transaction, guarded by the current status
        row = s.get(Job, job_id)
        if not _visible(row, kind, owner):
            raise JobNotFound(kind, job_id)
        now = utcnow()
        at_once = True
        if row.status == Status.QUEUED:
            row.status, row.cancel_requested, row.finished_at = Status.CANCELLED.value, True, now
            row.updated_at, row.error = now, "cancelled by request"
        elif row.status == Status.RUNNING:
            row.cancel_requested, row.updated_at = True, now
            at_once = False
        elif row.status != Status.CANCELLED:
            raise JobAlreadyFinished(job_id, row.status)
        s.flush()
        s.expunge(row)
    return CancelOutcome(row, at_once)


_STATUSES = select(_C.id, _C.status).where(_C.id.in_(bindparam("b_ids", expanding=True)))


def finished_among(db: Database, job_ids: list[str]) -> set[str]:
    """Those of ``job_ids`` that are finished, or gone (deleted): nobody should wait for them."""
    def read() -> set[str]:
        with db.read_conn() as c:
            rows = c.execute(_STATUSES, {"b_ids": list(job_ids)}).all()
        unfinished = {r.id for r in rows if not Status(r.status).finished}
        return set(job_ids) - unfinished

    return db.retry_on_disconnect(read)
