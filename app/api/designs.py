"""/v1/designs: submit design jobs (list, get, cancel and events: ``app.api.job_routes``); traces."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from fastapi import Body, Depends, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from app.api import validation
from app.api.deps import get_database, get_settings, require_api_key, run_sync
from app.api.job_routes import (ERRORS, MEDIA_TYPES, PreferHeader, etag_response, job_router,
                                submit, submit_responses)
from app.api.problems import ProblemException, field_error, invalid
from app.api.schemas import DesignJob, Trace
from app.compute.requests import DesignRequest
from app.examples import DESIGN_EXAMPLES
from app.jobs import store
from app.jobs.database import Database
from app.jobs.store import canonical_json
from app.jobs.tables import Status
from app.settings import Settings

router = job_router("design")

#: Binary answers, documented as such (not as an empty schema).
IMAGES = {"image/svg+xml": {"schema": {"type": "string", "description": "An SVG document"}},
          "image/png": {"schema": {"type": "string", "format": "binary", "description": "A PNG image"}}}


@router.post(
    "", status_code=202, response_model=DesignJob,
    summary="Submit a design job",
    description="Answers 202 with the queued job and its `Location`. With `Prefer: wait=N` it answers 201 with "
                "the finished job when the design ends within N seconds (else 202 as without it).",
    responses=submit_responses("design"),
)
async def submit_design(
    request: Request,
    response: Response,
    body: Annotated[DesignRequest, Body(openapi_examples=DESIGN_EXAMPLES)],
    idempotency_key: Annotated[str | None, Header(max_length=255, description="Same key and body -> same job")] = None,
    prefer: PreferHeader = None,
    settings: Settings = Depends(get_settings),
    owner: str | None = Depends(require_api_key),
):
    errors: list = []
    net = validation.check_network(body, errors, "design", settings=settings)
    if errors:
        raise invalid(errors)
    shape = validation.check_design(body, settings, net)
    req = body.model_dump(mode="json")
    validation.check_with_solver(req["plant"], body.n_drop, body.options.plant_switching, body.options.scheme)
    validation.check_performance(req, settings, net)
    validation.check_feedback(req)
    validation.check_design_channel(body, shape, settings)
    return await submit(request, response, "design", req, body.n_drop, idempotency_key, owner, prefer)


async def _cached_attachment(request: Request, key: tuple, media: str, filename: str, task: str, *args,
                             loc: list, plant: dict[str, Any] | None = None) -> Response:
    """A download made once per ``key`` by a task on the sync pool (kept in the trace cache), sent as an
    attachment with an ETag."""
    body = request.app.state.trace_cache.get(key)
    if body is None:
        body = await run_sync(request, task, *args, loc=loc, plant=plant)
        request.app.state.trace_cache.put(key, body)
    response = etag_response(request, media, body)
    response.headers["Content-Disposition"] = f'attachment; filename="{filename}"'
    return response


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
    row = await run_in_threadpool(store.get, db, "design", job_id, owner)
    status, req, result = row.status, row.request, row.result
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


@router.get(
    "/{job_id}/trace",
    summary="Seeded simulation of the designed loop (all plant modes)",
    description="The top level is the run with the requested plant switching (like Fig. 3/4); `per_mode` holds "
                "one run per fixed plant mode with the same losses. The same query always returns "
                "byte-identical JSON (keys sorted, compact).",
    responses={200: {"model": Trace, "description": "The runs (keys sorted), with an `ETag`"}, 404: ERRORS[404],
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
        body = await run_sync(request, "trace", req["plant"], result["gains"], req["n_drop"], params,
                              req.get("network"), loc=["query"], plant=req["plant"])  # canonical JSON, encoded in the pool
        cache.put(key, body)
    return etag_response(request, "application/json", body)


@router.get(
    "/{job_id}/trace.{fmt}",
    summary="The trace as a picture (SVG or PNG), like the paper's Fig. 3/4",
    description="States (top) and inputs (bottom) over time: first the run with the requested plant switching, "
                "then one column per fixed plant mode; samples whose packet was lost are shaded and marked. "
                "Same query parameters as `/trace`, plus the picture size in pixels.",
    response_class=Response,
    responses={200: {"description": "The figure, with an `ETag`", "content": IMAGES}, 404: ERRORS[404],
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
    if req.get("u_max") is not None:  # a design with input limits: the figure draws them
        params = {**params, "u_max": req["u_max"]}
    size = {"width": width / 100, "height": height / 100, "dpi": 100,
            "settling": (result.get("settling") or {}).get("seconds")}  # the certified worst case, drawn too
    cache = request.app.state.trace_cache
    key = (job_id, canonical_json(params), fmt, width, height)
    body = cache.get(key)
    if body is None:
        body = await run_sync(request, "trace_plot", req["plant"], result["gains"], req["n_drop"], params, fmt,
                              size, req.get("network"), loc=["query"], plant=req["plant"])
        cache.put(key, body)
    return etag_response(request, MEDIA_TYPES[fmt], body)


#: Media types of the MATLAB/Octave exports.
GAINS_FILES = {
    "mat": ("application/x-matlab-data",
            {"schema": {"type": "string", "format": "binary",
                        "description": "MATLAB 5 .mat file: K (n_drop x m x n), K1..KN (m x n), F (n x n x r), "
                                       "G (n x m x r), P (the certificate's matrix), n_drop, outcome, "
                                       "certificate (its kind), h (s)"}}),
    "m": ("text/x-matlab",
          {"schema": {"type": "string", "description": "An Octave/MATLAB script defining the same variables "
                                                       "as gains.mat, with exact (%.17g) numbers"}}),
}
_NO_GAINS = {"description": "The design has not succeeded yet (or was cancelled or failed)",
             "content": {"application/problem+json": {}}}


async def _gains_file(request: Request, job_id: str, fmt: str, db: Database, owner: str | None) -> Response:
    row = await run_in_threadpool(store.get, db, "design", job_id, owner)
    if row.status != Status.SUCCEEDED or not row.result:
        raise ProblemException(409, f"design {job_id} has no result to export yet (status {row.status!r}); wait "
                                    "for it to succeed (GET with Prefer: wait=60)", title="Conflict")
    media, _ = GAINS_FILES[fmt]
    return await _cached_attachment(request, (job_id, "gains", fmt), media, f"ncs-design-{job_id}.{fmt}",
                                    "gains_file", row.result, fmt, job_id, loc=["path"])


@router.get(
    "/{job_id}/gains.mat", summary="The design as a MATLAB .mat file (scipy.io.savemat)",
    description="`load gains.mat` defines `K` (n_drop x m x n, `K(q,:,:)` = K_q), `K1`..`KN` (m x n each), "
                "`F`, `G` (`F(:,:,l)`: plant mode l, so the file is also a plant file for `ncs-design`), the "
                "certificate's `P`, `n_drop`, `outcome`, `certificate` (its kind) and `h` (s). An infeasible "
                "design has no `K1..KN` and `K` is zeros. 409 until the job has succeeded.",
    response_class=Response,
    responses={200: {"description": "The .mat file (Content-Disposition: attachment)",
                     "content": {GAINS_FILES["mat"][0]: GAINS_FILES["mat"][1]}},
               404: ERRORS[404], 409: _NO_GAINS},
)
async def design_gains_mat(job_id: str, request: Request, db: Database = Depends(get_database),
                           owner: str | None = Depends(require_api_key)):
    return await _gains_file(request, job_id, "mat", db, owner)


@router.get(
    "/{job_id}/gains.m", summary="The design as an Octave/MATLAB script",
    description="A script that defines the same variables as `gains.mat` with exact numbers (`run gains.m`).",
    response_class=Response,
    responses={200: {"description": "The .m script (Content-Disposition: attachment)",
                     "content": {GAINS_FILES["m"][0]: GAINS_FILES["m"][1]}},
               404: ERRORS[404], 409: _NO_GAINS},
)
async def design_gains_m(job_id: str, request: Request, db: Database = Depends(get_database),
                         owner: str | None = Depends(require_api_key)):
    return await _gains_file(request, job_id, "m", db, owner)


@router.get(
    "/{job_id}/controller.zip", summary="C99 code of the controller and the actuator's buffer",
    description="A zip of `<prefix>_controller.h` and `<prefix>_controller.c` (`solver.export_c`): "
                "`<prefix>_packet` computes the packet `[K_1 x, ..., K_N x]` on the controller; "
                "`<prefix>_buffer_receive(b, packet, stamp)` and `<prefix>_buffer_output(b, u)` run the "
                "actuator's buffer (newest stamp wins, `u = K_(d+1) x(stamp)` with `d = now - stamp` while "
                "`d < N`, then `exhausted`). C99 (MISRA C:2012), no dynamic memory, no global state. With the "
                "build and test kit (`solver.c_kit.export_kit`): `CMakeLists.txt` (`add_subdirectory`), "
                "`cmake/arm-none-eabi.cmake`, and `test/`: a replay of a seeded simulated run on the host or on "
                "an emulated Cortex-M. `precision=float32` rounds the gains to float32 and re-checks the "
                "certificate on them with the float32 rounding bounded (422 naming `precision` with the reason "
                "when the proof is lost). 409 until the design has gains.",
    response_class=Response,
    responses={200: {"description": "The zip (Content-Disposition: attachment)",
                     "content": {"application/zip": {"schema": {"type": "string", "format": "binary"}}}},
               404: ERRORS[404], 409: _NO_GAINS, 422: ERRORS[422]},
)
async def design_controller_zip(
    job_id: str,
    request: Request,
    exhausted: Annotated[Literal["hold", "zero"], Query(description="Input once the newest packet is N or more "
                                                        "samples old: hold K_N x(stamp), or zero")] = "hold",
    prefix: Annotated[str, Query(pattern=r"^[A-Za-z][A-Za-z0-9_]{0,30}$",
                                 description="Prefix of the C names and files")] = "ncs",
    precision: Annotated[Literal["float64", "float32"],
                         Query(description="Arithmetic of the C code: double, or float with the certificate "
                                           "re-checked on the rounded gains")] = "float64",
    db: Database = Depends(get_database),
    owner: str | None = Depends(require_api_key),
):
    row = await run_in_threadpool(store.get, db, "design", job_id, owner)
    result = row.result or {}
    if row.status != Status.SUCCEEDED or not result.get("gains"):
        why = f"status {row.status!r}" if row.status != Status.SUCCEEDED else f"outcome {result.get('outcome')!r}"
        raise ProblemException(409, f"design {job_id} has no gains to generate code from ({why})", title="Conflict")
    cert = result.get("certificate") or {}
    metadata = {"id": job_id, "method": row.request.get("method"), "outcome": result.get("outcome"),
                "certificate": cert.get("kind")}
    return await _cached_attachment(request, (job_id, "controller", exhausted, prefix, precision),
                                    "application/zip", f"{prefix.lower()}-controller-{job_id}.zip", "controller_zip",
                                    result, row.request["n_drop"], exhausted, prefix, metadata, precision,
                                    row.request.get("plant"), loc=["query"])


@router.get(
    "/{job_id}/problem.dat-s", summary="The design's SDP in SDPA sparse format, to re-solve elsewhere",
    description="The SDP `design` solves for this request (`solver.export_sdpa`), in the coordinates it solves "
                "it in, with a comment header naming the variables; its optimum is `-t*` with "
                "`t* = result.history[-1].objective`. Methods `lmi` and `switched` (`ccl` solves a sequence of "
                "SDPs: 409). With `decay_rate: \"auto\"` (the default) or `\"max\"`, the SDP at the design's certified "
                "rate once it has one.",
    response_class=Response,
    responses={200: {"description": "SDPA sparse text (Content-Disposition: attachment)",
                     "content": {"text/plain": {"schema": {"type": "string"}}}},
               404: ERRORS[404], 409: {"description": "No single SDP for this design (ccl, or a decay-rate "
                                                      "search without a certified rate yet)",
                                       "content": {"application/problem+json": {}}}},
)
async def design_problem_sdpa(job_id: str, request: Request, db: Database = Depends(get_database),
                              owner: str | None = Depends(require_api_key)):
    row = await run_in_threadpool(store.get, db, "design", job_id, owner)
    req = row.request
    if req.get("method") == "ccl":
        raise ProblemException(409, "ccl solves a sequence of SDPs, each built from the previous iterate: there is "
                                    "no single SDP to export (methods lmi and switched have one)", title="Conflict")
    options = dict(req.get("options") or {})
    if options.get("decay_rate") in ("max", "auto"):
        rate = (row.result or {}).get("decay_rate") if row.status == Status.SUCCEEDED else None
        if rate is None:
            raise ProblemException(409, f"design {job_id} searches the decay rate (a bisection over many SDPs) "
                                        "and has no certified rate yet to export the SDP at", title="Conflict")
        options["decay_rate"] = rate
    return await _cached_attachment(request, (job_id, "sdpa", canonical_json(options)), "text/plain; charset=utf-8",
                                    f"ncs-design-{job_id}.dat-s", "problem_sdpa", req["plant"], req["n_drop"],
                                    req.get("method", "lmi"), options, loc=["path"], plant=req["plant"])
