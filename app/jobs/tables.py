"""SQLAlchemy models. The ``jobs`` table is the queue and the source of truth."""

from __future__ import annotations

import uuid
from dataclasses import dataclass
from enum import StrEnum
from datetime import datetime, timezone
from typing import Any

from sqlalchemy import JSON, Boolean, DateTime, Index, Integer, String, Text
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

class Status(StrEnum):
    """A job's life: queued -> running -> succeeded | failed | cancelled (running -> queued on a retry)."""

    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"

    @property
    def finished(self) -> bool:
        return self in FINISHED


FINISHED = frozenset({Status.SUCCEEDED, Status.FAILED, Status.CANCELLED})


def utcnow() -> datetime:
    return datetime.now(timezone.utc)


def new_id() -> str:
    return str(uuid.uuid4())


class Base(DeclarativeBase):
    pass


class Job(Base):
    __tablename__ = "jobs"

    id: Mapped[str] = mapped_column(String(36), primary_key=True, default=new_id)
    kind: Mapped[str] = mapped_column(String(32), default="design")
    status: Mapped[str] = mapped_column(String(16), default=Status.QUEUED.value)
    method: Mapped[str] = mapped_column(String(32))
    n_drop: Mapped[int] = mapped_column(Integer)
    request: Mapped[dict[str, Any]] = mapped_column(JSON)
    request_hash: Mapped[str] = mapped_column(String(64))
    idempotency_key: Mapped[str | None] = mapped_column(String(255), unique=True, default=None)
    progress: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    error: Mapped[str | None] = mapped_column(Text, default=None)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    lease_owner: Mapped[str | None] = mapped_column(String(64), default=None)
    lease_expires_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), default=None)
    worker_pid: Mapped[int | None] = mapped_column(Integer, default=None)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), default=None)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), default=None)
    updated_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow, onupdate=utcnow)
    # sha256 of the API key that created the job (app.api.deps.owner_of); None when no keys are configured.
    owner: Mapped[str | None] = mapped_column(String(64), default=None)

    __table_args__ = (
        Index("ix_jobs_status_created", "status", "created_at"),
        Index("ix_jobs_created", "created_at"),
        Index("ix_jobs_owner_created", "owner", "created_at"),
        # Fair claims and per-owner quotas (app.jobs.store): the owners with queued jobs, each one's oldest
        # queued job and its queued count are index seeks and range counts.
        Index("ix_jobs_status_owner_created", "status", "owner", "created_at", "id"),
    )


@dataclass(slots=True)
class JobRecord:
    """One job as read (or as just written) by the store: a plain snapshot of its row, attached to no
    session. The store's hot paths build these from Core rows (``JobRecord(**row._mapping)``); they cost a
    fraction of an ORM instance and carry the same attributes."""

    id: str
    kind: str
    status: str
    method: str
    n_drop: int
    request: dict[str, Any]
    request_hash: str
    idempotency_key: str | None
    progress: dict[str, Any] | None
    result: dict[str, Any] | None
    error: str | None
    attempts: int
    cancel_requested: bool
    lease_owner: str | None
    lease_expires_at: datetime | None
    worker_pid: int | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    updated_at: datetime
    owner: str | None
