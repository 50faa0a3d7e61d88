"""/v1/simulations: seeded simulation of given gains (synchronous, size-limited, on the sync process pool)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Depends, Request

from app.api import validation
from app.api.deps import SYNC_RESPONSES, V1_RESPONSES, get_settings, require_api_key, run_sync
from app.examples import SIMULATION_EXAMPLES
from app.api.problems import invalid
from app.api.schemas import Simulation
from app.compute.requests import SimulationRequest
from app.settings import Settings

router = APIRouter(prefix="/v1", dependencies=[Depends(require_api_key)], responses=V1_RESPONSES)


@router.post(
    "/simulations", tags=["simulations"], response_model=Simulation, summary="Simulate given gains (seeded)",
    description="Seeded simulation of the networked loop with the given gains: packet losses (sensor and "
                "control), plant switching and the predictive buffer. Returns t, x, u, mode, sensor_arrived, "
                "control_arrived, effective, eta, ...",
    responses=SYNC_RESPONSES,
)
async def run_simulation(request: Request,
                   body: Annotated[SimulationRequest, Body(openapi_examples=SIMULATION_EXAMPLES)],
                   settings: Settings = Depends(get_settings)):
    errors: list = []
    validation.check_network(body, errors, "simulate", settings=settings)
    shape = validation.check_family_request(body, settings, errors)
    validation.check_steps(body.steps, settings, errors, ["body", "steps"])
    if shape is not None:
        validation.check_gains(body.gains, body.n_drop, shape, errors)
        validation.check_x0(body.x0, shape, errors, ["body", "x0"])
        validation.check_mode(body.mode, shape, errors, ["body", "mode"])
    if errors:
        raise invalid(errors)
    req = body.model_dump(mode="json")
    return await run_sync(request, "simulation", req, loc=["body"], plant=req["plant"])
