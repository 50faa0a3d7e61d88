"""Liveness and readiness probes."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from app.api.problems import PROBLEM_MEDIA_TYPE
from app.api.schemas import Health, Readiness

router = APIRouter(tags=["health"])


@router.get("/healthz", summary="Liveness: the process answers", response_model=Health)
def healthz():
    return {"status": "ok"}


@router.get("/readyz", summary="Readiness: the database takes writes and workers are alive",
            response_model=Readiness,
            description="200 when a write transaction can begin on the database (a probe that changes nothing, "
                        "its answer reused for 1 s) and workers are ready. 503 problem+json with `checks` "
                        "otherwise; `checks.database` names the cause (locked, read-only, unreachable, full).",
            responses={503: {"description": "Not ready (problem+json with `checks`)",
                             "content": {"application/problem+json": {}}}})
async def readyz(request: Request):
    state = request.app.state
    checks: dict = {}
    ok = True
    problem = await run_in_threadpool(state.db.write_problem)
    if problem is None:
        checks["database"] = "ok"
    else:
        ok = False
        checks["database"] = f"cannot take writes: {problem}"
    disp = getattr(state, "dispatcher", None)
    if disp is None:
        checks["workers"] = {"dispatcher": "disabled"}
    else:
        alive, ready = disp.alive_workers(), disp.ready_workers()
        checks["workers"] = {"configured": disp.configured_workers(), "alive": alive, "ready": ready,
                             "dispatcher": "running" if disp.thread_alive() else "stopped"}
        if disp.error:
            checks["workers"]["last_error"] = disp.error
        if not disp.thread_alive() or ready == 0:
            ok = False
    if ok:
        return {"status": "ready", **checks}
    body = {"type": "about:blank", "title": "Service Unavailable", "status": 503,
            "detail": "not ready: " + ", ".join(f"{k}={v}" for k, v in checks.items()),
            "instance": request.url.path, "checks": checks}
    return JSONResponse(body, status_code=503, media_type=PROBLEM_MEDIA_TYPE)
