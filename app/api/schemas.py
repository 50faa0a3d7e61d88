"""Pydantic response schemas of the HTTP contract (the request bodies are ``app.compute.requests``)."""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_serializer

class Progress(BaseModel):
    iteration: int | None = Field(None, description="Design jobs: the solver iteration (CCL Step 2 count).")
    objective: float | None = None
    trace_gap: float | None = None
    theorem1: bool | None = None
    elapsed: float | None = None
    step: int | None = Field(None, description="Margin jobs: designs done so far.")
    total: int | None = Field(None, description="Margin jobs: designs planned (an upper bound).")
    point: dict[str, Any] | None = Field(None, description="Margin jobs: the last point tried and its outcome.")


class Links(BaseModel):
    self: str
    events: str
    cancel: str
    trace: str | None = Field(None, description="Design jobs: the seeded simulation (also .svg, .png).")
    curve: str | None = Field(None, description="Margin jobs: the plot of every point tried (.svg or .png).")


def _utc(dt: datetime | None) -> datetime | None:
    if dt is None:
        return None
    if dt.tzinfo is None:
        return dt.replace(tzinfo=timezone.utc)
    return dt.astimezone(timezone.utc)


class JobSummary(BaseModel):
    id: str
    status: Literal["queued", "running", "succeeded", "failed", "cancelled"]
    method: str
    n_drop: int
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    updated_at: datetime
    attempts: int
    cancel_requested: bool
    progress: Progress | None = None
    outcome: str | None = Field(None, description="The design's outcome once succeeded.")
    error: str | None = Field(None, description="Why the job failed (or the last retry reason).")
    links: Links

    @field_serializer("created_at", "started_at", "finished_at", "updated_at")
    def _ser_dt(self, dt: datetime | None):
        dt = _utc(dt)
        return None if dt is None else dt.isoformat().replace("+00:00", "Z")


_JOB_EXAMPLE = {
    "id": "3f0c8a52-8d55-4a4e-9b0e-6d1f0f5a2c11", "status": "succeeded", "method": "lmi", "n_drop": 3,
    "created_at": "2026-11-21T05:44:42.428524Z", "started_at": "2026-11-21T05:44:42.448170Z",
    "finished_at": "2026-11-21T05:44:42.555394Z", "updated_at": "2026-11-21T05:44:42.555394Z",
    "attempts": 1, "cancel_requested": False, "outcome": "stabilized", "error": None,
    "progress": {"iteration": 0, "objective": 0.6538, "trace_gap": None, "theorem1": True, "elapsed": 0.0962},
    "links": {"self": "/v1/designs/3f0c8a52-8d55-4a4e-9b0e-6d1f0f5a2c11",
              "events": "/v1/designs/3f0c8a52-8d55-4a4e-9b0e-6d1f0f5a2c11/events",
              "cancel": "/v1/designs/3f0c8a52-8d55-4a4e-9b0e-6d1f0f5a2c11/cancel",
              "trace": "/v1/designs/3f0c8a52-8d55-4a4e-9b0e-6d1f0f5a2c11/trace"},
    "request": {"plant": {"kind": "continuous", "sampling_period": 0.1,
                          "A": [[[-4.0, -0.03], [0.5, -6.667]], [[-4.0, -0.03], [0.75, -10.0]],
                                [[-4.0, -0.03], [1.5, -20.0]]],
                          "B": [[[2.0], [0.0]], [[2.0], [0.0]], [[2.0], [0.0]]]},
                "n_drop": 3, "method": "lmi",
                "options": {"solver": "CLARABEL", "margin": 1e-06, "max_iter": 50, "decay_rate": None,
                            "plant_switching": "per_interval", "scheme": "predictive"}},
    "result": {
        "outcome": "stabilized", "method": "lmi", "n_drop": 3,
        "gains": [[[-4.0611, 0.1010]], [[-0.0021, -0.0305]], [[-0.0003, -0.0056]]],
        "certificate": {"kind": "common_quadratic", "verified": True, "margin": 0.1192,
                        "X": [[1.5279, -0.0228], [-0.0228, 0.7437]], "P": "... (n n_drop x n n_drop)"},
        "spectral_radii": [[0.514, 0.264, 0.136], [0.369, 0.136, 0.050], [0.138, 0.020, 0.003]],
        "max_spectral_radius": 0.514,
        "F": [[[0.6703, -0.0018], [0.0294, 0.5134]], "..."], "G": [[[0.1648], [0.0035]], "..."],
        "sampling_period": 0.1, "history": [{"iteration": 0, "objective": 0.6538, "theorem1": True}],
        "iterations": 0, "solver": "CLARABEL", "solver_status": "optimal",
        "timings": {"total": 0.0966, "solver": 0.0014}, "message": "stabilized; certificate re-checked",
    },
}


class Job(JobSummary):
    model_config = ConfigDict(json_schema_extra={"examples": [_JOB_EXAMPLE]})

    request: dict[str, Any] = Field(description="The design request as accepted (defaults filled in).")
    result: dict[str, Any] | None = Field(
        None,
        description="When succeeded: outcome, gains (n_drop matrices m x n, K_1 first), certificate, "
        "spectral_radii, F, G (the discretized family), history, timings, solver details.",
    )


class JobList(BaseModel):
    items: list[JobSummary]
    total: int
    limit: int
    offset: int
    next: str | None = Field(None, description="URL of the next page, if any.")


class ProblemError(BaseModel):
    loc: list[str | int]
    pointer: str
    msg: str
    type: str


class Problem(BaseModel):
    type: str = "about:blank"
    title: str
    status: int
    detail: str | None = None
    instance: str | None = None
    errors: list[ProblemError] | None = None


