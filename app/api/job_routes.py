"""What designs and margins share: submitting a job, and one router factory for list / get / cancel /
events of a job kind; the ``Prefer: wait=N`` handling (RFC 7240) of submit and get."""

from __future__ import annotations

import asyncio
import hashlib
import json
import re
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse

from app.api.deps import PROBLEM, V1_RESPONSES, get_database, require_api_key
from app.api.schemas import JOB_MODELS, JobList, JobSummary
from app.api.views import full, summary
from app.jobs import store
from app.jobs.database import Database, unavailable
from app.jobs.tables import FINISHED

ERRORS = {
    404: {"description": "Unknown job id", **PROBLEM},
    422: {"description": "Invalid request (problem+json naming the field)", **PROBLEM},
}
QUEUE_FULL = {"description": "The queue is full (NCS_MAX_QUEUE_DEPTH); retry after `Retry-After` seconds", **PROBLEM,
              "headers": {"Retry-After": {"description": "Seconds to wait", "schema": {"type": "integer"}}}}
PREFERENCE_APPLIED = {"Preference-Applied": {"description": "`wait=N` when the request's `Prefer: wait=N` was "
                                                            "honoured", "schema": {"type": "string"}}}
#: The event stream, documented as OpenAPI 3.1 documents `text/event-stream`: ``schema`` describes ONE event
#: (its fields as a client's SSE parser gives them), not the stream's text.
EVENT_STREAM = {"text/event-stream": {"schema": {
    "title": "JobEvent", "type": "object", "required": ["event", "data"],
    "description": "One Server-Sent Event. `status`: on every status change, `data` is the job summary (JSON); "
                   "`progress`: `data` is the last progress record (JSON); `end`: last, `data` is the full job "
                   "(JSON), then the stream closes. The stream starts with `retry: 1000` and sends `: keep-alive` "
                   "comments every 15 s.",
    "properties": {
        "event": {"type": "string", "enum": ["status", "progress", "end"], "description": "The event's kind"},
        "data": {"type": "string", "contentMediaType": "application/json",
                 "description": "A JSON document: job summary, progress record or full job"},
        "id": {"type": "string", "description": "Sequence number of the event in this stream"},
        "retry": {"type": "integer", "minimum": 0, "description": "Reconnection delay in ms"},
    }}}}


def submit_responses(kind: str) -> dict:
    """OpenAPI responses of a job submission (designs and margins)."""
    model = JOB_MODELS[kind]
    return {
        201: {"description": "Created and already finished (only with `Prefer: wait=N`, when the job ended "
                             "within N seconds)", "model": model, "headers": PREFERENCE_APPLIED},
        202: {"description": "Accepted; poll the Location (optionally with `Prefer: wait=N`) or stream /events",
              "model": model, "headers": {**PREFERENCE_APPLIED, "Location": {
                  "description": "The job's URL", "schema": {"type": "string"}}}},
        413: {"description": "Body over NCS_MAX_BODY_BYTES", **PROBLEM},
        415: {"description": "The body is not JSON (send Content-Type: application/json)", **PROBLEM},
        422: ERRORS[422], 429: QUEUE_FULL,
    }

#: The longest wait a client may ask for; a longer one is cut to this (RFC 7240 lets a server do so).
MAX_WAIT_SECONDS = 60.0
_WAIT = re.compile(r"(?:^|[,;])\s*wait\s*=\s*\"?(\d+(?:\.\d+)?)\"?\s*(?=$|[,;])", re.IGNORECASE)

PreferHeader = Annotated[str | None, Header(
    description="`wait=N` (RFC 7240): answer as soon as the job is finished, or after N seconds "
                f"(at most {MAX_WAIT_SECONDS:g}) with its current state. `Preference-Applied` says it was used.",
    examples=["wait=10"])]
StatusFilter = Annotated[Literal["queued", "running", "succeeded", "failed", "cancelled"] | None,
                         Query(description="Only jobs with this status")]


def requested_wait(prefer: str | None) -> float | None:
    """The seconds of a ``Prefer: wait=N`` header, capped; None when the client did not ask to wait."""
    if not prefer:
        return None
    match = _WAIT.search(prefer)
    if match is None:
        return None
    return min(float(match.group(1)), MAX_WAIT_SECONDS)


async def wait_for_end(request: Request, db: Database, kind: str, job_id: str, owner: str | None, seconds: float):
    """The job once it is finished, or as it is after ``seconds``. A job this process finished comes as its
    dispatcher's finishing write returned it (no read); otherwise it is read again."""
    finished, record = await request.app.state.job_watch.wait(job_id, seconds)
    if finished and record is not None:
        return record
    return await run_in_threadpool(store.get, db, kind, job_id, owner)


async def submit(request: Request, response: Response, kind: str, req: dict, n_drop: int,
                 idempotency_key: str | None, owner: str | None, prefer: str | None) -> JobSummary:
    """Queue a validated job (or replay an idempotent one), wake the dispatcher, and with
    ``Prefer: wait=N`` answer 201 with the finished job if it ends within N seconds."""
    settings = request.app.state.settings
    db: Database = request.app.state.db
    dispatcher = getattr(request.app.state, "dispatcher", None)
    # The dispatcher of this process writes it with its own next transaction; without one, the store does.
    taken = None
    if dispatcher is not None:
        taken = dispatcher.take(store.prepare(kind, req, n_drop, idempotency_key=idempotency_key, owner=owner))
    if taken is not None:
        submitted = await _bounded(dispatcher, taken)
    else:
        submitted = await run_in_threadpool(
            store.submit, db, kind, req, n_drop, idempotency_key=idempotency_key, owner=owner,
            max_queue_depth=settings.max_queue_depth, retry_after=settings.retry_after,
            max_queued_per_owner=settings.max_queued_per_owner)
        if not submitted.replayed and dispatcher is not None:
            dispatcher.notify()
    row = submitted.job
    response.headers["Location"] = f"/v1/{kind}s/{row.id}"
    if submitted.replayed:
        response.headers["Idempotent-Replayed"] = "true"
    wait = requested_wait(prefer)
    if wait is None:
        return full(row)
    response.headers["Preference-Applied"] = f"wait={wait:g}"
    if row.status not in FINISHED:
        row = await wait_for_end(request, db, kind, row.id, owner, wait)
    if row.status in FINISHED:
        response.status_code = 201
    return full(row)


async def _bounded(dispatcher, taken: asyncio.Future):
    """The answer of a submission handed to the dispatcher, within its ``submit_wait_bound``: one the
    dispatcher has not begun to write by then (it is stuck waiting for the database) is withdrawn, never
    written, and answered 503 with the database's current trouble."""
    bound = dispatcher.submit_wait_bound
    try:
        return await asyncio.wait_for(asyncio.shield(taken), bound)
    except asyncio.TimeoutError:
        if not dispatcher.withdraw(taken):
            return await taken  # in a write whose lock wait is bounded by what was left: answered soon
        cause = dispatcher.tick_error or "database is locked"
        raise unavailable(f"{cause} (the submission waited {bound:g} s)") from None


def job_router(kind: str) -> APIRouter:
    """GET list, GET one (with ``Prefer: wait``), POST cancel and GET events of the jobs of ``kind``."""
    plural = f"{kind}s"
    Job = JOB_MODELS[kind]
    router = APIRouter(prefix=f"/v1/{plural}", tags=[plural], dependencies=[Depends(require_api_key)],
                       responses=V1_RESPONSES)

    @router.get("", response_model=JobList, summary=f"List {kind} jobs, newest first",
                operation_id=f"list_{plural}")
    def list_jobs(
        status: StatusFilter = None,
        limit: Annotated[int, Query(ge=1, le=100)] = 20,
        offset: Annotated[int, Query(ge=0, le=2**31 - 1, description="Jobs to skip (at most 2^31 - 1)")] = 0,
        db: Database = Depends(get_database),
        owner: str | None = Depends(require_api_key),
    ) -> JobList:
        rows, total = store.list_jobs(db, kind, status, limit, offset, owner)
        nxt = None
        if offset + len(rows) < total:
            params = f"limit={limit}&offset={offset + limit}" + (f"&status={status}" if status else "")
            nxt = f"/v1/{plural}?{params}"
        return JobList(items=[summary(r) for r in rows], total=total, limit=limit, offset=offset, next=nxt)

    @router.get("/{job_id}", response_model=Job, summary=f"A {kind} job with its result",
                operation_id=f"get_{kind}",
                responses={200: {"headers": PREFERENCE_APPLIED}, 404: ERRORS[404]})
    async def get_job(job_id: str, request: Request, response: Response, prefer: PreferHeader = None,
                      db: Database = Depends(get_database), owner: str | None = Depends(require_api_key)):
        row = await run_in_threadpool(store.get, db, kind, job_id, owner)
        wait = requested_wait(prefer)
        if wait is not None:
            response.headers["Preference-Applied"] = f"wait={wait:g}"
            if row.status not in FINISHED:
                row = await wait_for_end(request, db, kind, job_id, owner, wait)
        return full(row)

    @router.post(
        "/{job_id}/cancel", response_model=Job, status_code=202, summary=f"Cancel a {kind} job",
        operation_id=f"cancel_{kind}",
        description="A queued job is cancelled at once (200) and never starts. A running job is asked to stop "
                    "(202): it ends `cancelled` within about a second. A succeeded or failed job: 409. "
                    "Cancelling a cancelled job again returns it (200).",
        responses={200: {"description": "Cancelled", "model": Job}, 404: ERRORS[404],
                   409: {"description": "The job already finished", **PROBLEM}},
    )
    def cancel_job(job_id: str, request: Request, response: Response, db: Database = Depends(get_database),
                   owner: str | None = Depends(require_api_key)):
        outcome = store.cancel(db, kind, job_id, owner)
        if outcome.at_once:
            response.status_code = 200
            request.app.state.job_watch.finished(job_id, outcome.job)
        elif getattr(request.app.state, "dispatcher", None) is not None:
            request.app.state.dispatcher.notify()
        return full(outcome.job)

    @router.get(
        "/{job_id}/events", summary="Server-Sent Events: progress and the final state",
        response_class=StreamingResponse,
        operation_id=f"{kind}_events",
        description="Events: `status` (on every status change, data = job summary), `progress` (data = "
                    "the last progress record), and a last `end` event with the full job once it is finished; "
                    "then the stream closes.",
        responses={200: {"content": EVENT_STREAM}, 404: ERRORS[404]},
    )
    async def job_events(job_id: str, request: Request, db: Database = Depends(get_database),
                         owner: str | None = Depends(require_api_key)):
        first = full(await run_in_threadpool(store.get, db, kind, job_id, owner))
        return StreamingResponse(_event_stream(request, db, kind, job_id, owner, first),
                                 media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})

    return router


async def _event_stream(request: Request, db: Database, kind: str, job_id: str, owner: str | None,
                        first: JobSummary):
    def load() -> JobSummary | None:
        try:
            return full(store.get(db, kind, job_id, owner))
        except store.JobNotFound:
            return None

    job = first
    last_status = last_progress = None
    seq = 0
    idle = 0.0
    yield "retry: 1000\n\n"
    while True:
        if job.status != last_status:
            seq += 1
            last_status = job.status
            yield f"id: {seq}\nevent: status\ndata: {_summary_json(job)}\n\n"
        prog = job.progress.model_dump() if job.progress else None
        if prog is not None and prog != last_progress:
            seq += 1
            last_progress = prog
            yield f"id: {seq}\nevent: progress\ndata: {json.dumps(prog)}\n\n"
        if job.status in FINISHED:
            seq += 1
            yield f"id: {seq}\nevent: end\ndata: {job.model_dump_json()}\n\n"
            return
        await asyncio.sleep(0.25)
        idle += 0.25
        if idle >= 15:
            idle = 0.0
            yield ": keep-alive\n\n"
        if await request.is_disconnected():
            return
        job = await run_in_threadpool(load) or job


def _summary_json(job: JobSummary) -> str:
    return json.dumps(job.model_dump(mode="json", exclude={"request", "result"}))


# Not imported from solver.plotting: the web process never loads matplotlib, the sync workers draw.
MEDIA_TYPES = {"svg": "image/svg+xml", "png": "image/png"}


def etag_response(request: Request, media_type: str, body: bytes) -> Response:
    """The body with a strong ETag; 304 when the client already has it."""
    etag = '"' + hashlib.sha256(body).hexdigest()[:32] + '"'
    if request.headers.get("if-none-match") == etag:
        return Response(status_code=304, headers={"ETag": etag})
    return Response(content=body, media_type=media_type, headers={"ETag": etag})
