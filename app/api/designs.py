"""/v1/designs: submit, inspect, list, stream, cancel design jobs; traces."""

from __future__ import annotations

import asyncio
import functools
import hashlib
import json
import math
from typing import Annotated, Literal

from fastapi import APIRouter, Body, Depends, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, make_transient

from app.api import validation
from app.compute import tasks
from app.jobs.database import Database
from app.api.deps import V1_RESPONSES, get_database, get_session, get_settings, require_api_key, run_sync
from app.examples import DESIGN_EXAMPLES
from app.jobs.model import FINISHED, Status, Job as JobRow, new_id, utcnow
from app.api.problems import TYPE_BASE, ProblemException, field_error, invalid
from app.api.schemas import Job, JobList
from app.compute.requests import DesignRequest
from app.settings import Settings
from app.api.views import full, summary

router = APIRouter(prefix="/v1/designs", tags=["designs"], dependencies=[Depends(require_api_key)],
                   responses=V1_RESPONSES)

QUEUE_FULL = {"description": "The queue is full (NCS_MAX_QUEUE_DEPTH); retry after `Retry-After` seconds",
              "content": {"application/problem+json": {}},
              "headers": {"Retry-After": {"description": "Seconds to wait", "schema": {"type": "integer"}}}}

ERRORS = {
    404: {"description": "Unknown job id", "content": {"application/problem+json": {}}},
    422: {"description": "Invalid request (problem+json naming the field)", "content": {"application/problem+json": {}}},
}


def canonical_json(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)


def _not_found(job_id: str, kind: str = "design") -> ProblemException:
    return ProblemException(404, f"no {kind} job with id {job_id!r}", title="Not Found")


def visible(row: JobRow | None, kind: str, owner: str | None) -> bool:
    """A job of this kind, visible only to the key that created it (when keys are configured). Others get
    the same 404 as for an id that does not exist, so ids do not leak."""
    return row is not None and row.kind == kind and (owner is None or row.owner == owner)


def _read_retrying(session: Session, fn):
    """A read, once more on a fresh connection if the first one was dead (terminated backend, restart)."""
    from sqlalchemy.exc import DBAPIError

    try:
        return fn()
    except DBAPIError as exc:
        if not exc.connection_invalidated:
            raise
        session.rollback()
        return fn()


def _get_retrying(session: Session, job_id: str) -> JobRow | None:
    return _read_retrying(session, lambda: session.get(JobRow, job_id))


def _load(session: Session, job_id: str, kind: str = "design", owner: str | None = None) -> JobRow:
    row = _get_retrying(session, job_id) if len(job_id) <= 36 else None
    if not visible(row, kind, owner):
        raise _not_found(job_id, kind)
    return row


@functools.lru_cache(maxsize=256)
def _build_family_ok(plant_json: str) -> bool:
    tasks.build_family(json.loads(plant_json))
    return True


def scoped_idempotency_key(key: str | None, owner: str | None) -> str | None:
    """Idempotency keys are per API key: two callers using the same key get two jobs (stored hashed)."""
    if key is None or owner is None:
        return key
    return "o:" + hashlib.sha256(f"{owner}:{key}".encode("utf-8", "surrogatepass")).hexdigest()


def validate_family(plant_dict: dict) -> None:
    """Build the family with the solver (ZOH of small matrices) to catch what it rejects.

    A plant that built once is remembered (LRU of 256 plants, keyed by its canonical JSON):
    a sweep submits the same plant many times, and building it costs ~3 ms of the request
    thread (a third of the service process's CPU per paper-example job in the service
    benchmark). Rejections are not cached; they raise every time.
    """
    from solver import InvalidInput

    try:
        _build_family_ok(canonical_json(plant_dict))
    except InvalidInput as exc:
        raise invalid([validation.solver_field_error(getattr(exc, "field", ()), str(exc), plant_dict)])


#: OpenAPI responses of every job submission (designs and margins).
SUBMIT_RESPONSES = {
    202: {"description": "Accepted; poll the Location or stream /events"},
    413: {"description": "Body over NCS_MAX_BODY_BYTES", "content": {"application/problem+json": {}}},
    422: ERRORS[422], 429: QUEUE_FULL,
}


@router.post(
    "", status_code=202, response_model=Job,
    summary="Submit a design job",
    responses=SUBMIT_RESPONSES,
)
def submit_design(
    request: Request,
    response: Response,
    body: Annotated[DesignRequest, Body(openapi_examples=DESIGN_EXAMPLES)],
    idempotency_key: Annotated[str | None, Header(max_length=255, description="Same key and body -> same job")] = None,
    settings: Settings = Depends(get_settings),
    session: Session = Depends(get_session),
    db: Database = Depends(get_database),
    owner: str | None = Depends(require_api_key),
) -> Job:
    validation.check_design(body, settings)
    req = body.model_dump(mode="json")
    validate_family(req["plant"])
    return submit_job("design", req, req["n_drop"], idempotency_key, request, response, session, db, owner,
                      settings)


def submit_job(kind: str, req: dict, n_drop: int, idempotency_key: str | None, request: Request,
               response: Response, session: Session, db: Database, owner: str | None = None,
               settings: Settings | None = None) -> Job:
    """Insert a validated job (or replay an idempotent one) and wake the dispatcher."""
    digest = hashlib.sha256(canonical_json(req).encode()).hexdigest()
    location = f"/v1/{kind}s/"

    def replay(row: JobRow) -> Job:
        if row.request_hash != digest:
            raise invalid([field_error(["header", "Idempotency-Key"],
                                       "this Idempotency-Key was already used with a different request body",
                                       "idempotency_key_reused")])
        response.headers["Location"] = location + row.id
        response.headers["Idempotent-Replayed"] = "true"
        return full(row)

    def lookup() -> JobRow | None:
        session.rollback()  # a fresh snapshot
        found = session.execute(select(JobRow).where(JobRow.idempotency_key == stored_key)).scalar_one_or_none()
        if found is not None:
            session.expunge(found)
        session.rollback()  # never keep a transaction open past this point
        return found

    stored_key = scoped_idempotency_key(idempotency_key, owner)
    if idempotency_key is not None:
        existing = lookup()
        if existing is not None:
            return replay(existing)
    if settings is not None:  # back-pressure: refuse new work while the queue is over its depth
        def count_queued() -> int:
            # The rollback is part of the retried read: a connection that dies between the count and
            # the end of its transaction is a lost connection too, not an unavailable database.
            n = session.execute(select(func.count()).select_from(JobRow).where(JobRow.status == Status.QUEUED)).scalar_one()
            session.rollback()
            return n

        queued = _read_retrying(session, count_queued)
        if queued >= settings.max_queue_depth:
            raise ProblemException(
                429, f"the queue holds {queued} jobs, the limit is {settings.max_queue_depth} "
                     f"(NCS_MAX_QUEUE_DEPTH); retry after {settings.retry_after} s", title="Too Many Requests",
                type_=TYPE_BASE + "queue-full", headers={"Retry-After": str(settings.retry_after)})
    now = utcnow()
    row = JobRow(id=new_id(), kind=kind, status=Status.QUEUED, method=req["method"], n_drop=n_drop,
                 request=req, request_hash=digest, idempotency_key=stored_key, attempts=0,
                 cancel_requested=False, created_at=now, updated_at=now, owner=owner)
    def insert():
        make_transient(row)  # a retry after a lost connection inserts the row again
        with db.write() as ws:  # one short INSERT transaction
            ws.add(row)
            ws.flush()
            ws.expunge(row)

    try:
        db.retry_on_disconnect(insert)
    except IntegrityError:
        if _get_retrying(session, row.id) is not None:  # the lost connection had committed it after all
            session.rollback()
            return _accepted(request, response, row, location)
        # a concurrent request with the same key won the race
        existing = lookup() if idempotency_key is not None else None
        if existing is None:
            raise
        return replay(existing)
    return _accepted(request, response, row, location)


def _accepted(request: Request, response: Response, row: JobRow, location: str) -> Job:
    dispatcher = getattr(request.app.state, "dispatcher", None)
    if dispatcher is not None:
        dispatcher.notify()
    response.headers["Location"] = location + row.id
    return full(row)


@router.get("", response_model=JobList, summary="List design jobs, newest first")
def list_designs(
    request: Request,
    status: Annotated[Literal["queued", "running", "succeeded", "failed", "cancelled"] | None,
                      Query(description="Only jobs with this status")] = None,
    limit: Annotated[int, Query(ge=1, le=100)] = 20,
    offset: Annotated[int, Query(ge=0, le=2**31 - 1, description="Jobs to skip (at most 2^31 - 1)")] = 0,
    session: Session = Depends(get_session),
    owner: str | None = Depends(require_api_key),
) -> JobList:
    return list_jobs("design", status, limit, offset, session, owner)


def list_jobs(kind: str, status: str | None, limit: int, offset: int, session: Session,
              owner: str | None = None) -> JobList:
    """One page of the caller's jobs of a kind, newest first (shared by /v1/designs and /v1/margins)."""
    q = select(JobRow).where(JobRow.kind == kind)
    count = select(func.count()).select_from(JobRow).where(JobRow.kind == kind)
    if owner is not None:
        q = q.where(JobRow.owner == owner)
        count = count.where(JobRow.owner == owner)
    if status is not None:
        q = q.where(JobRow.status == status)
        count = count.where(JobRow.status == status)
    rows = session.execute(q.order_by(JobRow.created_at.desc(), JobRow.id.desc()).limit(limit).offset(offset)).scalars().all()
    total = session.execute(count).scalar_one()
    nxt = None
    if offset + len(rows) < total:
        params = f"limit={limit}&offset={offset + limit}" + (f"&status={status}" if status else "")
        nxt = f"/v1/{kind}s?{params}"
    return JobList(items=[summary(r) for r in rows], total=total, limit=limit, offset=offset, next=nxt)


@router.get("/{job_id}", response_model=Job, summary="A design job with its result", responses={404: ERRORS[404]})
def get_design(job_id: str, session: Session = Depends(get_session),
               owner: str | None = Depends(require_api_key)) -> Job:
    return full(_load(session, job_id, owner=owner))


@router.post(
    "/{job_id}/cancel", response_model=Job, status_code=202,
    summary="Cancel a design job",
    description="A queued job is cancelled at once (200) and never starts. A running job is asked to stop "
                "(202): it ends `cancelled` within about a second. A succeeded or failed job: 409. "
                "Cancelling a cancelled job again returns it (200).",
    responses={200: {"description": "Cancelled"}, 404: ERRORS[404],
               409: {"description": "The job already finished", "content": {"application/problem+json": {}}}},
)
def cancel_design(job_id: str, request: Request, response: Response,
                  db: Database = Depends(get_database), owner: str | None = Depends(require_api_key)) -> Job:
    return cancel_job("design", job_id, request, response, db, owner)


def cancel_job(kind: str, job_id: str, request: Request, response: Response, db: Database,
               owner: str | None = None) -> Job:
    """Cancel a job of a kind (shared by /v1/designs and /v1/margins)."""
    if len(job_id) > 36:
        raise _not_found(job_id, kind)
    notify = False
    with db.write() as ws:  # one short transaction, guarded by the current status
        row = ws.get(JobRow, job_id)
        if not visible(row, kind, owner):
            raise _not_found(job_id, kind)
        now = utcnow()
        if row.status == Status.QUEUED:
            row.status, row.cancel_requested, row.finished_at = Status.CANCELLED, True, now
            row.updated_at, row.error = now, "cancelled by request"
            response.status_code = 200
        elif row.status == Status.RUNNING:
            row.cancel_requested, row.updated_at = True, now
            notify = True
        elif row.status == Status.CANCELLED:
            response.status_code = 200
        else:
            raise ProblemException(409, f"job {job_id} already finished with status {row.status!r}; "
                                        "it cannot be cancelled", title="Conflict")
        ws.flush()
        out = full(row)
    if notify and getattr(request.app.state, "dispatcher", None) is not None:
        request.app.state.dispatcher.notify()
    return out


@router.get(
    "/{job_id}/events", summary="Server-Sent Events: progress and the final state",
    description="Events: `status` (on every status change, data = job summary), `progress` (data = "
                "iteration, objective, trace_gap, theorem1, elapsed), and a last `end` event with the full "
                "job once it is finished; then the stream closes.",
    responses={200: {"content": {"text/event-stream": {}}}, 404: ERRORS[404]},
)
async def design_events(job_id: str, request: Request, db=Depends(get_database),
                        owner: str | None = Depends(require_api_key)):
    return await job_events("design", job_id, request, db, owner)


async def job_events(kind: str, job_id: str, request: Request, db: Database, owner: str | None = None):
    """The SSE stream of a job of a kind (shared by /v1/designs and /v1/margins)."""
    def load():
        with db.read() as s:
            row = s.get(JobRow, job_id) if len(job_id) <= 36 else None
            return full(row) if visible(row, kind, owner) else None

    first = await run_in_threadpool(load)
    if first is None:
        raise _not_found(job_id, kind)

    async def stream():
        job = first
        last_status = last_progress = None
        seq = 0
        idle = 0.0
        yield "retry: 1000\n\n"
        while True:
            if job.status != last_status:
                seq += 1
                last_status = job.status
                yield f"id: {seq}\nevent: status\ndata: {summary_json(job)}\n\n"
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

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


def summary_json(job: Job) -> str:
    data = job.model_dump(mode="json", exclude={"request", "result"})
    return json.dumps(data)


def _parse_x0(raw: str | None, n: int) -> list[float]:
    if raw is None:
        return [1.0] * n
    try:
        vals = [float(v) for v in raw.split(",")]
    except ValueError:
        raise invalid([field_error(["query", "x0"], "x0 must be comma-separated numbers, e.g. x0=-3,2", "float_parsing")])
    if not all(math.isfinite(v) for v in vals):
        raise invalid([field_error(["query", "x0"], "x0 entries must be finite", "finite_number")])
    if len(vals) != n:
        raise invalid([field_error(["query", "x0"], f"x0 has {len(vals)} entries, the plant has n = {n} states",
                                   "vector_mismatch")])
    return vals


class TraceQuery:
    """Query parameters of a trace (JSON or image); the same query gives the same run."""

    def __init__(
        self,
        seed: Annotated[int, Query(ge=0)] = 42,
        steps: Annotated[int, Query(ge=1)] = 100,
        x0: Annotated[str | None, Query(description="Initial state, comma-separated (default: all ones)",
                                        examples=["-3,2"])] = None,
        loss_model: Literal["paper", "bernoulli"] = "paper",
        sensor_loss: Annotated[float, Query(ge=0, lt=1)] = 0.2,
        control_loss: Annotated[float, Query(ge=0, lt=1)] = 0.2,
        plant_switching: Annotated[Literal["per_interval", "per_sample", "none"] | None,
                                   Query(description="Default: the design's own plant_switching option")] = None,
        mode: Annotated[int | None, Query(ge=0)] = None,
    ):
        self.seed, self.steps, self.x0, self.loss_model = seed, steps, x0, loss_model
        self.sensor_loss, self.control_loss = sensor_loss, control_loss
        self.plant_switching, self.mode = plant_switching, mode


async def _trace_inputs(job_id: str, q: TraceQuery, db: Database, settings: Settings, owner: str | None):
    """The succeeded design's request, result and the validated simulation parameters."""
    def load():
        with db.read() as s:
            row = s.get(JobRow, job_id) if len(job_id) <= 36 else None
            return (row.status, row.request, row.result) if visible(row, "design", owner) else None

    got = await run_in_threadpool(load)
    if got is None:
        raise _not_found(job_id)
    status, req, result = got
    if status != Status.SUCCEEDED or not result or not result.get("gains"):
        why = f"status is {status!r}" if status != Status.SUCCEEDED else f"outcome is {result.get('outcome')!r}"
        raise ProblemException(409, f"design {job_id} has no gains to simulate ({why})", title="Conflict")
    n = len(result["F"][0])
    r = len(result["F"])
    errors: list = []
    validation.check_steps(q.steps, settings, errors, ["query", "steps"])
    if q.mode is not None and q.mode >= r:
        errors.append(field_error(["query", "mode"], f"mode {q.mode} does not exist: the plant has {r} modes "
                                  "(0-based)", "mode_out_of_range"))
    if errors:
        raise invalid(errors)
    plant_switching = q.plant_switching or (req.get("options") or {}).get("plant_switching") or "per_interval"
    params = dict(seed=q.seed, steps=q.steps, x0=_parse_x0(q.x0, n), loss_model=q.loss_model,
                  sensor_loss=q.sensor_loss, control_loss=q.control_loss, plant_switching=plant_switching,
                  mode=q.mode)
    return req, result, params


# Not imported from solver.plotting: the web process never loads matplotlib, the sync workers draw.
MEDIA_TYPES = {"svg": "image/svg+xml", "png": "image/png"}


def etag_response(request: Request, media_type: str, body: bytes) -> Response:
    """The body with a strong ETag; 304 when the client already has it."""
    etag = '"' + hashlib.sha256(body).hexdigest()[:32] + '"'
    if request.headers.get("if-none-match") == etag:
        return Response(status_code=304, headers={"ETag": etag})
    return Response(content=body, media_type=media_type, headers={"ETag": etag})


@router.get(
    "/{job_id}/trace",
    summary="Seeded simulation of the designed loop (all plant modes)",
    description="The top level is the run with the requested plant switching (like Fig. 3/4); `per_mode` holds "
                "one run per fixed plant mode with the same losses. The same query always returns "
                "byte-identical JSON (keys sorted, compact).",
    responses={200: {"content": {"application/json": {}}}, 404: ERRORS[404],
               409: {"description": "The design has no gains (not succeeded or not stabilized)",
                     "content": {"application/problem+json": {}}}, 422: ERRORS[422]},
)
async def design_trace(
    job_id: str,
    request: Request,
    q: TraceQuery = Depends(),
    db=Depends(get_database),
    settings: Settings = Depends(get_settings),
    owner: str | None = Depends(require_api_key),
):
    req, result, params = await _trace_inputs(job_id, q, db, settings, owner)
    cache = request.app.state.trace_cache
    key = (job_id, canonical_json(params))
    body = cache.get(key)
    if body is None:
        out = await run_sync(request, "trace", req["plant"], result["gains"], req["n_drop"], params,
                             loc=["query"], plant=req["plant"])
        body = canonical_json(out).encode()
        cache.put(key, body)
    return etag_response(request, "application/json", body)


@router.get(
    "/{job_id}/trace.{fmt}",
    summary="The trace as a picture (SVG or PNG), like the paper's Fig. 3/4",
    description="States (top) and inputs (bottom) over time: first the run with the requested plant switching, "
                "then one column per fixed plant mode; samples whose packet was lost are shaded and marked. "
                "Same query parameters as `/trace`, plus the picture size in pixels.",
    responses={200: {"content": {"image/svg+xml": {}, "image/png": {}}}, 404: ERRORS[404],
               409: {"description": "The design has no gains", "content": {"application/problem+json": {}}},
               422: ERRORS[422]},
)
async def design_trace_image(
    job_id: str,
    fmt: Literal["svg", "png"],
    request: Request,
    q: TraceQuery = Depends(),
    width: Annotated[int, Query(ge=200, le=4000, description="Width in pixels")] = 1200,
    height: Annotated[int, Query(ge=150, le=3000, description="Height in pixels")] = 600,
    db=Depends(get_database),
    settings: Settings = Depends(get_settings),
    owner: str | None = Depends(require_api_key),
):
    req, result, params = await _trace_inputs(job_id, q, db, settings, owner)
    size = {"width": width / 100, "height": height / 100, "dpi": 100}
    cache = request.app.state.trace_cache
    key = (job_id, canonical_json(params), fmt, width, height)
    body = cache.get(key)
    if body is None:
        body = await run_sync(request, "trace_plot", req["plant"], result["gains"], req["n_drop"], params, fmt,
                              size, loc=["query"], plant=req["plant"])
        cache.put(key, body)
    return etag_response(request, MEDIA_TYPES[fmt], body)
