"""Job-table operations shared by the HTTP routes and the dispatcher.

Every state change is one short transaction guarded by the job's current
status (and, for running jobs, by the lease owner), so two dispatchers or a
dispatcher and a cancel request can never both win.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta
from typing import Any

from sqlalchemy import and_, case, select, update

from app.jobs.database import Database
from app.jobs.model import Status, Job, utcnow


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
