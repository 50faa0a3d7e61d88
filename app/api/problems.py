"""RFC 9457 problem details for every error response."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.jobs.database import database_reason
from app.jobs.job_errors import (ComputeFailed, ComputeTimeLimit, IdempotencyKeyReused, JobAlreadyFinished,
                                 JobNotFound, MemoryLimitExceeded, OwnerQueueFull, QueueFull, WorkerDied)

log = logging.getLogger("app")

PROBLEM_MEDIA_TYPE = "application/problem+json"
#: Problem types are pages this service serves (``GET /problems/{slug}``, see :data:`PROBLEM_TYPES`); the
#: ``type`` member is made absolute with the request's base URL when one is known.
TYPE_BASE = "/problems/"
PLANT_KINDS = {"continuous", "discrete", "dc_motor"}


#: Every problem type the service answers with: slug -> (title, what happened, how to fix it).
#: ``GET /problems/{slug}`` serves each as a page (app.api.problem_pages).
PROBLEM_TYPES: dict[str, tuple[str, str, str]] = {
    "invalid-request": (
        "Invalid request",
        "The request was read as JSON but a field is missing, has the wrong type or shape, or is over a limit. "
        "Nothing was created.",
        "Look at `errors[]`: each entry names the field by `pointer` (a JSON pointer into your request, e.g. "
        "`/plant/A/1/0/2`) and says what is wrong in `msg`. Matrices are lists of rows; a plant family is a list "
        "of matrices, one per plant mode (wrap a single matrix as `[M]`). Numbers must be finite JSON numbers."),
    "malformed-json": (
        "Malformed JSON",
        "The request body is not valid JSON (a syntax error, not UTF-8, nested too deeply, or a number with too "
        "many digits).",
        "Check the body with a JSON validator (e.g. `python3 -m json.tool`); `detail` gives the character "
        "position. NaN and Infinity are not JSON."),
    "unsupported-media-type": (
        "Unsupported Media Type",
        "A request body was sent with a Content-Type other than JSON (curl's default is a form).",
        "Send `Content-Type: application/json` (curl: `-H 'Content-Type: application/json'`)."),
    "too-large": (
        "Content Too Large",
        "The request body is larger than the service accepts (NCS_MAX_BODY_BYTES).",
        "Send a smaller plant family, or ask the operator to raise NCS_MAX_BODY_BYTES."),
    "limit-exceeded": (
        "Resource limit exceeded",
        "The problem is larger than the service's limits (states, inputs, modes, n_drop, LMI size, memory).",
        "Reduce the size named in `detail`, or run the library locally (`ncs-design design PLANT.json` needs no "
        "service and has no limits)."),
    "not-found": (
        "Not Found",
        "No job with this id exists for your API key (or it is a job of another kind: designs and margins are "
        "separate).",
        "Check the id (from the `Location` header of the submission) and the path (`/v1/designs/{id}` or "
        "`/v1/margins/{id}`), and that you use the same API key that submitted it."),
    "conflict": (
        "Conflict",
        "The job is not in a state that allows this: it has not finished yet, or has no gains (not succeeded, "
        "or its outcome is not `stabilized`), or it already finished and cannot be cancelled.",
        "Wait for the job to succeed (`GET /v1/designs/{id}` with `Prefer: wait=60`, or stream `/events`), then "
        "retry; a design whose outcome is `infeasible` has no gains to export or simulate."),
    "unauthorized": (
        "Unauthorized",
        "The service requires an API key and none, or an unknown one, was sent.",
        "Send `X-API-Key: <key>` or `Authorization: Bearer <key>` with a key from NCS_API_KEYS."),
    "queue-full": (
        "Too Many Requests",
        "More jobs are waiting than the service queues (NCS_MAX_QUEUE_DEPTH).",
        "Retry after the `Retry-After` seconds; the client (`app.client.Client`) does so by itself."),
    "owner-quota": (
        "Too Many Requests",
        "Your API key already has as many jobs queued as one key may (NCS_MAX_QUEUED_PER_OWNER). The limit is "
        "per key: other keys are not affected, and your queued jobs keep their places.",
        "Retry after the `Retry-After` seconds, once some of your queued jobs have started; or cancel queued "
        "jobs you no longer need."),
    "database-unavailable": (
        "Database unavailable",
        "The job database cannot take a write: it is full, read-only, locked by another writer, or unreachable "
        "(the `detail` says which). Nothing was changed.",
        "Retry after the `Retry-After` seconds; if it persists, tell the operator."),
    "time-limit": (
        "Time limit exceeded",
        "A synchronous computation (analysis, simulation, trace, figure) took longer than NCS_SYNC_TIME_LIMIT.",
        "Make the request smaller (fewer steps, shorter `max_product_length`, `bounds: none`), or submit a "
        "design job, which has a longer limit."),
    "worker-died": (
        "Worker process died",
        "The process computing the answer died (for instance out of memory).",
        "Retry once; if it happens again, make the request smaller and tell the operator."),
    "internal-error": (
        "Internal Server Error",
        "An unexpected error in the service or the solver; it has been logged.",
        "Retry once; if it persists, report it with the request that caused it."),
}


def problem_type(request: Request | None, slug: str) -> str:
    """The absolute URI of a problem type page (relative ``/problems/{slug}`` without a request)."""
    path = TYPE_BASE + slug
    if request is None:
        return path
    return str(request.base_url).rstrip("/") + path


#: Problem type of a status when the raiser gives none.
DEFAULT_TYPES = {401: "unauthorized", 404: "not-found", 409: "conflict", 413: "too-large",
                 415: "unsupported-media-type", 429: "queue-full"}


def json_pointer(loc: Sequence[Any]) -> str:
    """JSON pointer (RFC 6901) into the request body for a pydantic ``loc``.

    ``("body", "plant", "continuous", "A", 1)`` -> ``/plant/A/1`` (the
    discriminated union's tag is not part of the document).
    """
    parts = list(loc)
    if parts and parts[0] in ("body", "query", "path", "header"):
        parts = parts[1:]
    out = []
    for i, p in enumerate(parts):
        if i > 0 and parts[i - 1] == "plant" and p in PLANT_KINDS:
            continue
        out.append(str(p).replace("~", "~0").replace("/", "~1"))
    return "/" + "/".join(out) if out else ""


def field_error(loc: Sequence[Any], msg: str, type_: str = "value_error") -> dict[str, Any]:
    loc = [p if isinstance(p, int) else str(p) for p in loc]
    return {"loc": loc, "pointer": json_pointer(loc), "msg": msg, "type": type_}


class ProblemException(Exception):
    """Raise anywhere in a request to answer with a problem+json response."""

    def __init__(self, status: int, detail: str, *, title: str | None = None,
                 type_: str | None = None, errors: Iterable[dict[str, Any]] | None = None,
                 headers: dict[str, str] | None = None):
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.title = title or HTTPStatus(status).phrase
        self.type = type_ or (TYPE_BASE + DEFAULT_TYPES[status] if status in DEFAULT_TYPES else "about:blank")
        self.errors = list(errors) if errors is not None else None
        self.headers = headers


def invalid(errors: list[dict[str, Any]], detail: str | None = None) -> ProblemException:
    if detail is None:
        detail = "; ".join(f"{e['pointer'] or '/'}: {e['msg']}" for e in errors)
    return ProblemException(422, detail, title="Invalid request", type_=TYPE_BASE + "invalid-request",
                            errors=errors)


def problem_response(request: Request | None, status: int, title: str, detail: str | None = None,
                     type_: str = "about:blank", errors: list[dict[str, Any]] | None = None,
                     headers: dict[str, str] | None = None) -> JSONResponse:
    if type_.startswith(TYPE_BASE):
        type_ = problem_type(request, type_[len(TYPE_BASE):])
    body: dict[str, Any] = {"type": type_, "title": title, "status": status}
    if detail is not None:
        body["detail"] = detail
    if request is not None:
        body["instance"] = request.url.path
    if errors is not None:
        body["errors"] = errors
    return JSONResponse(body, status_code=status, media_type=PROBLEM_MEDIA_TYPE, headers=headers)


def _clean_validation_errors(errors: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for e in errors:
        loc = list(e.get("loc", ()))
        msg = e.get("msg", "invalid")
        if e.get("type") == "json_invalid":  # loc holds a character position, not a field
            pos = loc[1] if len(loc) > 1 else None
            reason = (e.get("ctx") or {}).get("error")
            msg = f"{msg}: {reason}" if reason else msg
            if pos is not None:
                msg += f" at character {pos}"
            out.append({"loc": ["body"], "pointer": "", "msg": msg, "type": "json_invalid"})
            continue
        out.append(field_error(loc, msg, e.get("type", "value_error")))
    return out


def database_unavailable(request: Request | None, exc: BaseException) -> JSONResponse:
    """503 for a database outage: the request changed nothing (its transaction was rolled back)."""
    reason = database_reason(exc)
    log.warning("database unavailable on %s %s: %s (%s)", request.method if request else "-",
                request.url.path if request else "-", reason, type(exc).__name__)
    settings = getattr(getattr(request, "app", None), "state", None)
    retry = getattr(getattr(settings, "settings", None), "retry_after", 5)
    return problem_response(request, 503, "Database unavailable",
                            f"{reason}; nothing was changed, retry after {retry} s",
                            TYPE_BASE + "database-unavailable", headers={"Retry-After": str(retry)})


def _allowed_methods(request: Request) -> str:
    """Every method the API documents at this path (Starlette's 405 names only the first matching route's)."""
    import re

    app = request.app
    patterns = getattr(app.state, "allow_patterns", None)
    if patterns is None:
        patterns = []
        for template, ops in app.openapi().get("paths", {}).items():
            regex = "".join("[^/]+" if part.startswith("{") else re.escape(part)
                            for part in re.split(r"(\{[^}]+\})", template))
            methods = {m.upper() for m in ops if m in ("get", "put", "post", "delete", "patch", "options")}
            if "GET" in methods:
                methods.add("HEAD")
            patterns.append((re.compile(regex + "$"), methods))
        app.state.allow_patterns = patterns
    methods: set[str] = set()
    for regex, ms in patterns:
        if regex.match(request.url.path):
            methods |= ms
    return ", ".join(sorted(methods))


def _parse_failure(cause: BaseException | None) -> str:
    if isinstance(cause, UnicodeDecodeError):
        return f"it is not UTF-8 text (byte {cause.start} cannot be decoded)"
    if isinstance(cause, RecursionError):
        return "it is nested too deeply (arrays or objects inside each other)"
    if isinstance(cause, ValueError) and "digits" in str(cause):
        return "a number has too many digits (at most 4300)"
    return "it could not be parsed"


#: Domain error -> (HTTP status, problem title, problem type slug).  QueueFull also sends Retry-After.
DOMAIN_ERRORS = {
    JobNotFound: (404, "Not Found", "not-found"),
    JobAlreadyFinished: (409, "Conflict", "conflict"),
    OwnerQueueFull: (429, "Too Many Requests", "owner-quota"),
    QueueFull: (429, "Too Many Requests", "queue-full"),
    MemoryLimitExceeded: (422, "Resource limit exceeded", "limit-exceeded"),
    ComputeTimeLimit: (503, "Time limit exceeded", "time-limit"),
    WorkerDied: (503, "Worker process died", "worker-died"),
    ComputeFailed: (500, "Solver error", "internal-error"),
}


def _domain_handler(status: int, title: str, slug: str):
    async def handler(request: Request, exc: Exception):
        retry_after = getattr(exc, "retry_after", None)
        headers = None if retry_after is None else {"Retry-After": str(retry_after)}
        return problem_response(request, status, title, str(exc), TYPE_BASE + slug, headers=headers)

    return handler


def install(app: FastAPI) -> None:
    @app.exception_handler(ProblemException)
    async def _problem(request: Request, exc: ProblemException):
        return problem_response(request, exc.status, exc.title, exc.detail, exc.type, exc.errors,
                                exc.headers)

    # The job and compute layers' refusals (app.jobs.job_errors) and their HTTP answers, in one table.
    for error, (status, title, slug) in DOMAIN_ERRORS.items():
        app.add_exception_handler(error, _domain_handler(status, title, slug))

    @app.exception_handler(IdempotencyKeyReused)
    async def _key_reused(request: Request, exc: IdempotencyKeyReused):
        errors = [field_error(["header", "Idempotency-Key"], str(exc), "idempotency_key_reused")]
        return problem_response(request, 422, "Invalid request", str(exc), TYPE_BASE + "invalid-request", errors)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError):
        errors = _clean_validation_errors(exc.errors())
        if any(e["type"] == "json_invalid" for e in errors):
            return problem_response(request, 422, "Malformed JSON",
                                    "The request body is not valid JSON: " + errors[0]["msg"],
                                    TYPE_BASE + "malformed-json", errors)
        detail = "; ".join(f"{e['pointer'] or '/'}: {e['msg']}" for e in errors[:10])
        return problem_response(request, 422, "Invalid request", detail,
                                TYPE_BASE + "invalid-request", errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException):
        if exc.status_code == 400 and exc.detail == "There was an error parsing the body":
            # FastAPI's answer to a body json.loads raised on with something other than a syntax error:
            # say which (the cause is the original exception).
            msg = _parse_failure(exc.__cause__)
            return problem_response(request, 422, "Malformed JSON", "The request body is not valid JSON: " + msg,
                                    TYPE_BASE + "malformed-json",
                                    [{"loc": ["body"], "pointer": "", "msg": msg, "type": "json_invalid"}])
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:
            headers = {**(headers or {}), "Allow": _allowed_methods(request)}
        try:
            title = HTTPStatus(exc.status_code).phrase
        except ValueError:
            title = "Error"
        detail = exc.detail if isinstance(exc.detail, str) else title
        return problem_response(request, exc.status_code, title, detail, headers=headers)

    from sqlalchemy.exc import DBAPIError, IntegrityError, TimeoutError as PoolTimeout

    @app.exception_handler(DBAPIError)
    async def _database(request: Request, exc: DBAPIError):
        if isinstance(exc, IntegrityError):  # a bug, not an outage
            return await _unhandled(request, exc)
        return database_unavailable(request, exc)

    @app.exception_handler(PoolTimeout)
    async def _pool_timeout(request: Request, exc: PoolTimeout):
        return database_unavailable(request, exc)

    @app.exception_handler(Exception)
    async def _unhandled(request: Request, exc: Exception):
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem_response(request, 500, "Internal Server Error",
                                "An unexpected error occurred; it has been logged.", TYPE_BASE + "internal-error")
