"""Job row -> response schema (typed per job kind)."""

from __future__ import annotations

import logging
from typing import Any

from pydantic import BaseModel, ValidationError

from app.api.schemas import (DesignJob, DesignResult, JobSummary, Links, MarginJob, MarginResult, PlantSummary)
from app.compute.requests import DesignRequest, MarginRequest
from app.jobs.tables import Job as JobRow

log = logging.getLogger("app")


def links(job_id: str, kind: str = "design") -> Links:
    if kind == "margin":
        base = f"/v1/margins/{job_id}"
        return Links(self=base, events=f"{base}/events", cancel=f"{base}/cancel", curve=f"{base}/curve.svg")
    base = f"/v1/designs/{job_id}"
    return Links(self=base, events=f"{base}/events", cancel=f"{base}/cancel", trace=f"{base}/trace",
                 gains_mat=f"{base}/gains.mat", gains_m=f"{base}/gains.m")


def plant_summary(plant: Any) -> PlantSummary | None:
    """Kind and sizes of a stored request's plant (None if it cannot be read)."""
    try:
        kind = plant["kind"]
        if kind == "dc_motor":
            n, m, r = 2, 1, len(plant["inertias"])
        else:
            a, b = ("A", "B") if kind == "continuous" else ("F", "G")
            n, m, r = len(plant[a][0]), len(plant[b][0][0]), len(plant[a])
        return PlantSummary(kind=kind, n=n, m=m, r=r, sampling_period=plant.get("sampling_period"))
    except (KeyError, IndexError, TypeError):
        return None


def _common(row: JobRow) -> dict:
    request = row.request if isinstance(row.request, dict) else {}
    result = row.result if isinstance(row.result, dict) else {}
    margin = margin_kind = None
    if row.kind == "margin":
        margin_kind = request.get("search")
        margin = result.get("margin")
    return dict(
        id=row.id, status=row.status, method=row.method, n_drop=row.n_drop, label=request.get("label"),
        plant=plant_summary(request.get("plant")),
        created_at=row.created_at, started_at=row.started_at, finished_at=row.finished_at,
        updated_at=row.updated_at, attempts=row.attempts, cancel_requested=row.cancel_requested,
        progress=row.progress, error=row.error, links=links(row.id, row.kind),
        outcome=result.get("outcome"), margin=margin, margin_kind=margin_kind,
    )


def _typed(model: type[BaseModel], data: dict | None, what: str, job_id: str):
    """The stored JSON as its response model. A stored field the model does not fit (an older or newer
    solver's) is left out, and logged, rather than failing the whole answer."""
    if data is None:
        return None
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        bad = {e["loc"][0] for e in exc.errors() if e["loc"]}
        log.warning("job %s: stored %s fields %s do not fit %s; left out of the answer", job_id, what,
                    sorted(map(str, bad)), model.__name__)
        return model.model_validate({k: v for k, v in data.items() if k not in bad})


def summary(row: JobRow) -> JobSummary:
    return JobSummary(**_common(row))


def full(row: JobRow) -> DesignJob | MarginJob:
    if row.kind == "margin":
        return MarginJob(**_common(row), request=_typed(MarginRequest, row.request, "request", row.id),
                         result=_typed(MarginResult, row.result, "result", row.id))
    return DesignJob(**_common(row), request=_typed(DesignRequest, row.request, "request", row.id),
                     result=_typed(DesignResult, row.result, "result", row.id))
