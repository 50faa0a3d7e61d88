"""Job row -> response schema."""

from __future__ import annotations

from app.jobs.model import Job as JobRow
from app.api.schemas import Job, JobSummary, Links


def links(job_id: str, kind: str = "design") -> Links:
    if kind == "margin":
        base = f"/v1/margins/{job_id}"
        return Links(self=base, events=f"{base}/events", cancel=f"{base}/cancel", curve=f"{base}/curve.svg")
    base = f"/v1/designs/{job_id}"
    return Links(self=base, events=f"{base}/events", cancel=f"{base}/cancel", trace=f"{base}/trace")


def _common(row: JobRow) -> dict:
    return dict(
        id=row.id, status=row.status, method=row.method, n_drop=row.n_drop,
        created_at=row.created_at, started_at=row.started_at, finished_at=row.finished_at,
        updated_at=row.updated_at, attempts=row.attempts, cancel_requested=row.cancel_requested,
        progress=row.progress, error=row.error, links=links(row.id, row.kind),
        outcome=(row.result or {}).get("outcome") if row.result else None,
    )


def summary(row: JobRow) -> JobSummary:
    return JobSummary(**_common(row))


def full(row: JobRow) -> Job:
    return Job(**_common(row), request=row.request, result=row.result)
