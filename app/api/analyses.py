"""/v1/analyses: analyze given gains (synchronous, size-limited, on the sync process pool)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Depends, Request

from app.api import validation
from app.api.deps import SYNC_RESPONSES, V1_RESPONSES, get_settings, require_api_key, run_sync
from app.examples import ANALYSIS_EXAMPLES
from app.api.problems import invalid
from app.api.schemas import AnalysisReport
from app.compute.requests import AnalysisRequest
from app.settings import Settings

router = APIRouter(prefix="/v1", dependencies=[Depends(require_api_key)], responses=V1_RESPONSES)


@router.post(
    "/analyses", tags=["analyses"], response_model=AnalysisReport, summary="Analyze given gains (Theorem 1 certificate, spectral radii)",
    description="Runs synchronously (the family and the mode products are bounded by the size limits). "
                "`stable` is true (certified by a re-checked Lyapunov certificate), false (a mode product is "
                "unstable) or null (unknown).",
    responses=SYNC_RESPONSES,
)
async def run_analysis(request: Request,
                   body: Annotated[AnalysisRequest, Body(openapi_examples=ANALYSIS_EXAMPLES)],
                   settings: Settings = Depends(get_settings)):
    errors: list = []
    validation.check_network(body, errors, "analyze", settings=settings)
    shape = validation.check_family_request(body, settings, errors)
    req = body.model_dump(mode="json")
    if shape is not None:
        n_drop = validation.check_gains(body.gains, body.n_drop, shape, errors)
        if not errors:
            validation.check_n_drop(n_drop, settings, errors)
            size = validation.lmi_size("ccl", shape.n, shape.r, n_drop)
            if size > settings.max_lmi_size:
                errors.append(validation.field_error(
                    ["body", "gains"], f"the analysis has total LMI size {size}, over the limit of "
                    f"{settings.max_lmi_size} (NCS_MAX_LMI_SIZE)", "limit_exceeded"))
            req["max_products"] = settings.max_analysis_products
    if errors:
        raise invalid(errors)
    return await run_sync(request, "analysis", req, loc=["body"], plant=req["plant"])
