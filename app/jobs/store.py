"""The job store: every change of a job's state, for the HTTP side (submit, get, list, cancel) and the
dispatcher (claim, lease, progress, finish, retry, release).

Every state change is one short transaction guarded by the job's current
status (and, for running jobs, by the lease owner), so two dispatchers or a
dispatcher and a cancel request can never both win.
"""

from __future__ import annotations

import hashlib
import json
import uuid
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

from sqlalchemy import and_, case, func, select, update
from sqlalchemy import insert as insert_stmt
from sqlalchemy.exc import IntegrityError

from app.jobs.database import Database
from app.jobs.errors import IdempotencyKeyReused, JobAlreadyFinished, JobNotFound, QueueFull
from app.jobs.model import Job, Status, new_id, utcnow


@dataclass
class Claimed:
    id: str
    request: dict[str, Any]
    attempts: int


def has_queued(db: Database) -> bool:
    with db.read() as s:
        return s.execute(select(Job.id).where(Job.status == Status.QUEUED).limit(1)).first() is not None


def claim_many(db: Database, owner: str, lease_seconds: float, pids: list[int | None]) -> list[Claimed]:
    """Claim up to ``len(pids)`` of the oldest queued jobs in one transaction (two statements).

    The i-th claimed job records ``pids[i]`` as its worker pid (``None``/0: not known yet).
    On PostgreSQL ``FOR UPDATE SKIP LOCKED`` lets several dispatchers claim at once without
    waiting for or double-claiming each other; SQLite serializes the write transactions.
    """
    with db.write() as s:
        ids = [r.id for r in s.execute(
            select(Job.id)
            .where(Job.status == Status.QUEUED)
            .order_by(Job.created_at, Job.id)
            .limit(len(pids))
            .with_for_update(skip_locked=True)
        ).all()]
        if not ids:
            return []
        now = utcnow()
        known = {i: p for i, p in zip(ids, pids) if p}
        rows = s.execute(
            update(Job)
            .where(Job.id.in_(ids), Job.status == Status.QUEUED)
            .values(status=Status.RUNNING, lease_owner=owner, lease_expires_at=now + timedelta(seconds=lease_seconds),
                    attempts=Job.attempts + 1, started_at=now, updated_at=now,
                    worker_pid=case(known, value=Job.id, else_=None) if known else None)
            .returning(Job.id, Job.request, Job.attempts)
            .execution_options(synchronize_session=False)
        ).all()
    by_id = {r.id: r for r in rows}
    return [Claimed(i, by_id[i].request, by_id[i].attempts) for i in ids if i in by_id]


def _running_owned(job_id: str, owner: str):
    return and_(Job.id == job_id, Job.status == Status.RUNNING, Job.lease_owner == owner)


def set_worker_pid(db: Database, job_id: str, owner: str, pid: int) -> None:
    with db.write() as s:
        s.execute(update(Job).where(_running_owned(job_id, owner)).values(worker_pid=pid, updated_at=utcnow()))


def update_progress(db: Database, job_id: str, owner: str, progress: dict[str, Any]) -> None:
    with db.write() as s:
        s.execute(update(Job).where(_running_owned(job_id, owner)).values(progress=progress, updated_at=utcnow()))


def finish(db: Database, job_id: str, owner: str, status: str, *, result: dict[str, Any] | None = None,
           error: str | None = None, progress: dict[str, Any] | None = None) -> bool:
    assert status in (Status.SUCCEEDED, Status.FAILED, Status.CANCELLED)
    now = utcnow()
    values: dict[str, Any] = dict(status=status, finished_at=now, updated_at=now, lease_owner=None,
                                  lease_expires_at=None, result=result, error=error)
    if progress is not None:
        values["progress"] = progress
    with db.write() as s:
        return s.execute(update(Job).where(_running_owned(job_id, owner)).values(**values)).rowcount == 1


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


def cancel_requested_among(db: Database, job_ids: list[str]) -> set[str]:
    if not job_ids:
        return set()
    with db.read() as s:
        rows = s.execute(select(Job.id).where(Job.id.in_(job_ids), Job.cancel_requested.is_(True))).all()
    return {r[0] for r in rows}


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


def get(db: Database, kind: str, job_id: str, owner: str | None = None) -> Job:
    """The job (detached from its session); JobNotFound when it does not exist or is not the caller's."""
    if not _is_uuid(job_id):
        raise JobNotFound(kind, job_id)

    def read() -> Job | None:
        with db.read() as s:
            row = s.get(Job, job_id)
            if row is not None:
                s.expunge(row)
            return row

    row = db.retry_on_disconnect(read)
    if not _visible(row, kind, owner):
        raise JobNotFound(kind, job_id)
    return row


@dataclass
class Submitted:
    job: Job
    replayed: bool  # an Idempotency-Key seen before with the same body: the existing job


def scoped_idempotency_key(key: str | None, owner: str | None) -> str | None:
    """Idempotency keys are per API key: two callers using the same key get two jobs (stored hashed)."""
    if key is None or owner is None:
        return key
    return "o:" + hashlib.sha256(f"{owner}:{key}".encode("utf-8", "surrogatepass")).hexdigest()


def submit(db: Database, kind: str, request: dict[str, Any], n_drop: int, *, idempotency_key: str | None = None,
           owner: str | None = None, max_queue_depth: int | None = None, retry_after: int = 5) -> Submitted:
    """Queue a validated job, or return the one an earlier submission with the same Idempotency-Key made.

    Raises IdempotencyKeyReused (same key, other body) and QueueFull (back-pressure: more than
    ``max_queue_depth`` jobs waiting). One short INSERT; a connection lost on the way is retried once.
    """
    digest = hashlib.sha256(canonical_json(request).encode()).hexdigest()
    stored_key = scoped_idempotency_key(idempotency_key, owner)

    def replay(row: Job) -> Submitted:
        if row.request_hash != digest:
            raise IdempotencyKeyReused()
        return Submitted(row, replayed=True)

    def lookup() -> Job | None:
        with db.read() as s:
            found = s.execute(select(Job).where(Job.idempotency_key == stored_key)).scalar_one_or_none()
            if found is not None:
                s.expunge(found)
            return found

    if stored_key is not None:
        existing = db.retry_on_disconnect(lookup)
        if existing is not None:
            return replay(existing)
    now = utcnow()
    values = dict(id=new_id(), kind=kind, status=Status.QUEUED.value, method=request["method"], n_drop=n_drop,
                  request=request, request_hash=digest, idempotency_key=stored_key, attempts=0,
                  cancel_requested=False, created_at=now, updated_at=now, owner=owner)
    row = Job(**values)  # the answer; never attached to a session

    def insert() -> None:
        # The back-pressure count and the INSERT share one write transaction (one connection checkout and
        # commit per submission, and the count cannot go stale before the insert); a Core INSERT, not the
        # ORM's unit of work, on this hot path.
        with db.write() as s:
            if max_queue_depth is not None:
                queued = s.execute(_QUEUED_COUNT).scalar_one()
                if queued >= max_queue_depth:
                    raise QueueFull(queued, max_queue_depth, retry_after)
            s.execute(insert_stmt(Job).values(**values))

    try:
        db.retry_on_disconnect(insert)
    except IntegrityError:
        def committed() -> bool:
            with db.read() as s:
                return s.get(Job, row.id) is not None

        if db.retry_on_disconnect(committed):  # the lost connection had committed it after all
            return Submitted(row, replayed=False)
        existing = db.retry_on_disconnect(lookup) if stored_key is not None else None
        if existing is None:  # not a race on the idempotency key: a bug
            raise
        return replay(existing)  # a concurrent request with the same key won the race
    return Submitted(row, replayed=False)


_QUEUED_COUNT = select(func.count()).select_from(Job).where(Job.status == Status.QUEUED)


def queue_depth(db: Database) -> int:
    with db.read() as s:
        return s.execute(_QUEUED_COUNT).scalar_one()


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


def finished_among(db: Database, job_ids: list[str]) -> set[str]:
    """Those of ``job_ids`` that are finished, or gone (deleted): nobody should wait for them."""
    def read() -> set[str]:
        with db.read() as s:
            rows = s.execute(select(Job.id, Job.status).where(Job.id.in_(job_ids))).all()
        unfinished = {r.id for r in rows if not Status(r.status).finished}
        return set(job_ids) - unfinished

    return db.retry_on_disconnect(read)
