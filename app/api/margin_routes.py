"""/v1/margins: stability-margin jobs (largest n_drop, largest sampling period, design grids).

They are jobs like designs (same table, queue, worker pool, progress, cancel and
SSE: ``app.api.job_routes``), with ``kind = "margin"``; only their request and result differ.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import Body, Depends, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from app.api import validation
from app.api.deps import get_database, get_settings, require_api_key, run_sync
from app.api.job_routes import (ERRORS, MEDIA_TYPES, PreferHeader, etag_response, job_router,
                                submit, submit_responses)
from app.api.problems import ProblemException
from app.api.designs import IMAGES
from app.api.schemas import MarginJob
from app.compute.requests import MarginRequest
from app.examples import MARGIN_EXAMPLES
from app.jobs import store
from app.jobs.database import Database
from app.jobs.tables import Status
from app.settings import Settings

KIND = "margin"
router = job_router(KIND)


@router.post(
    "", status_code=202, response_model=MarginJob,
    summary="Submit a stability-margin job",
    description="Runs many designs in the worker pool: `progress` says how many are done and the last point "
                "tried. When succeeded, `result` holds `margin` (the largest n_drop or sampling period with a "
                "stabilizing design), `design` (that design: gains, certificate), and `curve` (every point tried, "
                "in order, with its outcome, max spectral radius and gains). Cancel it like a design job. "
                "`Prefer: wait=N` as for designs.",
    responses=submit_responses("margin"),
)
async def submit_margin(
    request: Request,
    response: Response,
    body: Annotated[MarginRequest, Body(openapi_examples=MARGIN_EXAMPLES)],
    idempotency_key: Annotated[str | None, Header(max_length=255, description="Same key and body -> same job")] = None,
    prefer: PreferHeader = None,
    settings: Settings = Depends(get_settings),
    owner: str | None = Depends(require_api_key),
):
    largest = validation.check_margin(body, settings)
    req = body.model_dump(mode="json")
    validation.check_with_solver(req["plant"])
    return await submit(request, response, KIND, req, largest, idempotency_key, owner, prefer)


@router.get(
    "/{job_id}/curve.{fmt}", summary="Plot of every point the search tried (SVG or PNG)",
    description="Max spectral radius of the designed loop at each point, stabilized or not, and the margin.",
    response_class=Response,
    responses={200: {"description": "The figure, with an `ETag`", "content": IMAGES}, 404: ERRORS[404],
               409: {"description": "The job has not succeeded", "content": {"application/problem+json": {}}}},
)
async def margin_curve(
    job_id: str,
    fmt: Literal["svg", "png"],
    request: Request,
    width: Annotated[int, Query(ge=200, le=4000, description="Width in pixels")] = 800,
    height: Annotated[int, Query(ge=150, le=3000, description="Height in pixels")] = 450,
    db: Database = Depends(get_database),
    owner: str | None = Depends(require_api_key),
):
    row = await run_in_threadpool(store.get, db, KIND, job_id, owner)
    status, result = row.status, row.result
    if status != Status.SUCCEEDED or not result:
        raise ProblemException(409, f"margin job {job_id} has no curve yet (status {status!r})", title="Conflict")
    key = (job_id, "curve", fmt, width, height)
    body = request.app.state.trace_cache.get(key)
    if body is None:
        size = {"width": width / 100, "height": height / 100, "dpi": 100}
        body = await run_sync(request, "margin_plot", result, fmt, size, loc=["query"], plant=None)
        request.app.state.trace_cache.put(key, body)
    return etag_response(request, MEDIA_TYPES[fmt], body)
