"""FastAPI dependencies: settings, the database, auth; running a task on the synchronous pool."""

from __future__ import annotations

import hashlib
import hmac

from fastapi import Depends, Request
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer

from app.jobs.database import Database
from app.api.problems import ProblemException
from app.jobs.job_errors import InvalidComputeInput
from app.settings import Settings

_api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False,
                               description="One of the keys in NCS_API_KEYS (when keys are configured)")
_bearer = HTTPBearer(auto_error=False, description="`Authorization: Bearer <key>`, same keys as X-API-Key")


# The OpenAPI content entry of every error answer (RFC 9457 problem details).
PROBLEM = {"content": {"application/problem+json": {}}}

# Documented on every /v1 operation (problem+json; the 401 is only answered when keys are configured).
V1_RESPONSES = {
    401: {"description": "Missing or unknown API key (only when NCS_API_KEYS is set)", **PROBLEM},
    503: {"description": "Database unavailable (full, read-only or unreachable): nothing was changed; retry after "
                         "`Retry-After` seconds", **PROBLEM,
          "headers": {"Retry-After": {"description": "Seconds to wait", "schema": {"type": "integer"}}}},
}

# The extra answers of the synchronous operations (analyses, simulations), which run on the sync pool.
SYNC_RESPONSES = {413: {"description": "Body over NCS_MAX_BODY_BYTES", **PROBLEM},
                  415: {"description": "The body is not JSON (send Content-Type: application/json)", **PROBLEM},
                  422: {"description": "Invalid request", **PROBLEM}, 503: {"description": "Time limit", **PROBLEM}}


# The dependencies are ``async def`` although they do not await: FastAPI runs a plain ``def`` dependency in
# its thread pool, a hop (queue put, thread wake-up, result back to the loop) that costs more than the work.
async def get_settings(request: Request) -> Settings:
    return request.app.state.settings


async def get_database(request: Request) -> Database:
    return request.app.state.db


def key_digest(key: str) -> bytes:
    return hashlib.sha256(b"ncs-design api key\0" + key.encode("utf-8", "surrogatepass")).digest()


def owner_of(key: str) -> str:
    """What the jobs table stores as a job's owner: a hash of the key, never the key."""
    return key_digest(key).hex()


def match_key(given: str, keys: list[str]) -> bool:
    """Constant-time membership: every configured key is compared (hmac.compare_digest of equal-length
    digests), so neither the timing nor an early exit tells how much of a key matched or which one."""
    given_digest = key_digest(given)
    found = False
    for k in keys:
        found |= hmac.compare_digest(given_digest, key_digest(k))
    return found


async def require_api_key(
    request: Request,
    settings: Settings = Depends(get_settings),
    x_api_key: str | None = Depends(_api_key_header),
    bearer: HTTPAuthorizationCredentials | None = Depends(_bearer),
) -> str | None:
    """The caller's owner id (hash of its key), or None when no keys are configured (open service)."""
    keys = settings.api_keys
    if not keys:
        return None
    given = x_api_key if x_api_key is not None else (bearer.credentials if bearer is not None else None)
    if given is None or not match_key(given, keys):
        raise ProblemException(401, "a valid API key is required: send X-API-Key or Authorization: Bearer",
                               title="Unauthorized", headers={"WWW-Authenticate": "Bearer"})
    return owner_of(given)


def caller_key(request: Request) -> str:
    """Whose turn a synchronous call takes on the pool: the caller's key (hashed), else its address."""
    given = request.headers.get("x-api-key")
    if given is None:
        scheme, _, cred = request.headers.get("authorization", "").partition(" ")
        given = cred.strip() if scheme.lower() == "bearer" and cred.strip() else None
    if given is not None:
        return owner_of(given)
    return "addr:" + (request.client.host if request.client else "")


async def run_sync(request: Request, task: str, *args, loc: list, plant: dict | None):
    """Run a task on the synchronous pool; an input the solver rejects is a 422 naming its field
    (``loc`` is where the task's inputs sit in the HTTP request, ``plant`` the plant they came with)."""
    from app.api.problems import invalid
    from app.api.validation import solver_field_error

    try:
        return await request.app.state.sync_pool.run(task, *args, key=caller_key(request))
    except InvalidComputeInput as exc:
        raise invalid([solver_field_error(exc.field, str(exc), plant, loc)]) from None
