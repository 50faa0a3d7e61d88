"""/v1/margins: stability-margin jobs (largest n_drop, largest sampling period, design grids).

They are jobs like designs (same table, queue, worker pool, progress, cancel and
SSE), with ``kind = "margin"``; only their request and result differ.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Body, Depends, Header, Query, Request, Response
from sqlalchemy.orm import Session

from app.api import validation
from app.jobs.database import Database
from app.api.deps import V1_RESPONSES, get_database, get_session, get_settings, require_api_key, run_sync
from app.examples import MARGIN_EXAMPLES
from app.jobs.model import Status
from app.api.problems import ProblemException
from app.api.designs import (ERRORS, MEDIA_TYPES, SUBMIT_RESPONSES, _load, cancel_job, etag_response, job_events,
                                 list_jobs, submit_job, validate_family)
from app.api.schemas import Job, JobList
from app.compute.requests import MarginRequest
from app.settings import Settings
from app.api.views import full

router = APIRouter(prefix="/v1/margins", tags=["margins"], dependencies=[Depends(require_api_key)],
                   responses=V1_RESPONSES)
KIND = "margin"


@router.post(
    "", status_code=202, response_model=Job,
    summary="Submit a stability-margin job",
    description="Runs many designs in the worker pool: `progress` says how many are done and the last point "
                "tried. When succeeded, `result` holds `margin` (the largest n_drop or sampling period with a "
                "stabilizing design), `design` (that design: gains, certificate), and `curve` (every point tried, "
                "in order, with its outcome, max spectral radius and gains). Cancel it like a design job.",
    responses=SUBMIT_RESPONSES,
)
def submit_margin(
    request: Request,
    response: Response,
    body: Annotated[MarginRequest, Body(openapi_examples=MARGIN_EXAMPLES)],
    idempotency_key: Annotated[str | None, Header(max_length=255, description="Same key and body -> same job")] = None,
    settings: Settings = Depends(get_settings),
    session: Session = Depends(get_session),
    db: Database = Depends(get_database),
    owner: str | None = Depends(require_api_key),
) -> Job:
    largest = validation.check_margin(body, settings)
    req = body.model_dump(mode="json")
    validate_family(req["plant"])
    return submit_job(KIND, req, largest, idempotency_key, request, response, session, db, owner, settings)


@router.get("", response_model=JobList, summary="List margin jobs, newest first")
def list_margins(
    status: Annotated[Literal["queued", "running", "succeeded", "failed", "cancelled"] | None,
                      Query(description="Only jobs with this status")] = None,
    limit: Annotated[int, Query(ge=1, le=100)] = 20,
    offset: Annotated[int, Query(ge=0, le=2**31 - 1, description="Jobs to skip (at most 2^31 - 1)")] = 0,
    session: Session = Depends(get_session),
    owner: str | None = Depends(require_api_key),
) -> JobList:
    return list_jobs(KIND, status, limit, offset, session, owner)


@router.get("/{job_id}", response_model=Job, summary="A margin job with its result", responses={404: ERRORS[404]})
def get_margin(job_id: str, session: Session = Depends(get_session),
               owner: str | None = Depends(require_api_key)) -> Job:
    return full(_load(session, job_id, KIND, owner))


@router.post(
    "/{job_id}/cancel", response_model=Job, status_code=202, summary="Cancel a margin job",
    description="As for designs: queued -> cancelled at once (200), running -> stops within about a second "
                "(202), finished -> 409.",
    responses={200: {"description": "Cancelled"}, 404: ERRORS[404],
               409: {"description": "The job already finished", "content": {"application/problem+json": {}}}},
)
def cancel_margin(job_id: str, request: Request, response: Response, db: Database = Depends(get_database),
                  owner: str | None = Depends(require_api_key)) -> Job:
    return cancel_job(KIND, job_id, request, response, db, owner)


@router.get(
    "/{job_id}/events", summary="Server-Sent Events: progress and the final state",
    responses={200: {"content": {"text/event-stream": {}}}, 404: ERRORS[404]},
)
async def margin_events(job_id: str, request: Request, db=Depends(get_database),
                        owner: str | None = Depends(require_api_key)):
    return await job_events(KIND, job_id, request, db, owner)


@router.get(
    "/{job_id}/curve.{fmt}", summary="Plot of every point the search tried (SVG or PNG)",
    description="Max spectral radius of the designed loop at each point, stabilized or not, and the margin.",
    responses={200: {"content": {"image/svg+xml": {}, "image/png": {}}}, 404: ERRORS[404],
               409: {"description": "The job has not succeeded", "content": {"application/problem+json": {}}}},
)
async def margin_curve(
    job_id: str,
    fmt: Literal["svg", "png"],
    request: Request,
    width: Annotated[int, Query(ge=200, le=4000, description="Width in pixels")] = 800,
    height: Annotated[int, Query(ge=150, le=3000, description="Height in pixels")] = 450,
    session: Session = Depends(get_session),
    owner: str | None = Depends(require_api_key),
):
    row = _load(session, job_id, KIND, owner)
    status, result = row.status, row.result
    session.rollback()  # release the read snapshot before the slow part
    if status != Status.SUCCEEDED or not result:
        raise ProblemException(409, f"margin job {job_id} has no curve yet (status {status!r})", title="Conflict")
    key = (job_id, "curve", fmt, width, height)
    body = request.app.state.trace_cache.get(key)
    if body is None:
        size = {"width": width / 100, "height": height / 100, "dpi": 100}
        body = await run_sync(request, "margin_plot", result, fmt, size, loc=["query"], plant=None)
        request.app.state.trace_cache.put(key, body)
    return etag_response(request, MEDIA_TYPES[fmt], body)
