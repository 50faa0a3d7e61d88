"""/v1/channels: given gains on a stochastic channel (synchronous, size-limited, on the sync process pool)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Depends, Request

from app.api import validation
from app.api.deps import SYNC_RESPONSES, V1_RESPONSES, get_settings, require_api_key, run_sync
from app.api.problems import invalid
from app.api.schemas import ChannelAnalysis
from app.compute.requests import ChannelRequest
from app.examples import CHANNEL_EXAMPLES
from app.settings import Settings

router = APIRouter(prefix="/v1", dependencies=[Depends(require_api_key)], responses=V1_RESPONSES)


@router.post(
    "/channels", tags=["channels"], response_model=ChannelAnalysis,
    summary="Given gains on a lossy channel: burst rate, mean-square stability, expected cost",
    description="The loop as a Markov jump linear system on (channel state, plant mode, buffer age), the buffer "
                "running dry after n_drop lost samples (`exhausted`). `ms_stable` is true or false only with a "
                "re-checked certificate on the second-moment operator. Runs synchronously (bounded by "
                "NCS_MAX_CHANNEL_SIZE).",
    responses=SYNC_RESPONSES,
)
async def run_channel(request: Request,
                      body: Annotated[ChannelRequest, Body(openapi_examples=CHANNEL_EXAMPLES)],
                      settings: Settings = Depends(get_settings)):
    errors: list = []
    validation.check_network(body, errors, sets_n_drop=False, settings=settings)
    shape = validation.check_family_request(body, settings, errors)
    if shape is not None:
        n_drop = validation.check_gains(body.gains, body.n_drop, shape, errors)
        if not errors:
            validation.check_n_drop(n_drop, settings, errors)
            validation.check_channel_size(body.channel, shape, n_drop, settings, errors)
    if errors:
        raise invalid(errors)
    req = body.model_dump(mode="json")
    return await run_sync(request, "channel", req, loc=["body"], plant=req["plant"])
