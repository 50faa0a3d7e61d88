"""POST /v1/channels: the library's analyze_channel over HTTP, typed, with 422s naming the field; the client."""

from __future__ import annotations

import numpy as np
import pytest

from app.client import Client
from app.examples import CHANNEL_EXAMPLES, PAPER_GAINS_H01, PAPER_PLANT
from solver import Channel, PlantFamily, analyze_channel

from app.api.schemas import ChannelAnalysis

from .conftest import assert_problem, running_client
from .test_exports_and_listings import _documented


@pytest.fixture(scope="module")
def http(module_db):
    with running_client(module_db, workers=1, max_channel_size=2000) as c:
        yield c


def test_example_matches_the_library(http):
    body = CHANNEL_EXAMPLES["paper_gilbert_elliott"]["value"]
    resp = http.post("/v1/channels", json=body)
    assert resp.status_code == 200, resp.text
    data = resp.json()
    fam = PlantFamily.from_dict(PAPER_PLANT)
    ref = analyze_channel(fam, np.array(PAPER_GAINS_H01), 3, Channel.gilbert_elliott(0.05, 0.3, 0.01, 0.8),
                          exhausted="zero", weights=(np.eye(2), np.eye(1)))
    assert data["ms_stable"] is True and data["upper_certificate"]["verified"] is True
    assert "P" not in data["upper_certificate"]
    assert data["burst_rate"] == pytest.approx(ref.burst_rate, rel=1e-12)
    assert data["expected_cost"] == pytest.approx(ref.expected_cost, rel=1e-9)
    assert data["bursts"]["rate_per_second"] == pytest.approx(ref.burst_rate / 0.1, rel=1e-12)
    _documented(ChannelAnalysis, data, "channel")


@pytest.mark.parametrize("change, pointer", [
    ({"channel": {"kind": "bernoulli", "loss": 1.5}}, "/channel"),
    ({"channel": {"kind": "markov", "transition": [[0.5, 0.4], [0.5, 0.5]], "loss": [0, 1]}}, "/channel"),
    ({"exhausted": "drop"}, "/exhausted"),
    ({"plant_transitions": [[0.5, 0.5]]}, "/plant_transitions"),
    ({"weights": {"Q": [[-1, 0], [0, 1]], "R": [[1]]}}, "/weights/Q"),
    ({"channel": {"kind": "markov", "transition": np.full((12, 12), 1 / 12).tolist(), "loss": [0.1] * 12}},
     "/channel"),
])
def test_bad_input_is_a_422_naming_the_field(http, change, pointer):
    body = {**CHANNEL_EXAMPLES["paper_gilbert_elliott"]["value"], **change}
    assert_problem(http.post("/v1/channels", json=body), 422, pointer)


def test_client_returns_typed_results(http):
    client = Client("http://testserver", http_client=http, poll_interval=0.05)
    fam = PlantFamily.from_dict(PAPER_PLANT)
    res = client.analyze_channel(fam, PAPER_GAINS_H01, Channel.bernoulli(0.3), exhausted="hold",
                                 weights=(np.eye(2), np.eye(1)))
    ref = analyze_channel(fam, np.array(PAPER_GAINS_H01), 3, Channel.bernoulli(0.3), weights=(np.eye(2), np.eye(1)))
    assert res.ms_stable is True and res.expected_cost == pytest.approx(ref.expected_cost, rel=1e-9)
    assert res.burst_rate == pytest.approx(0.7 * 0.3**3, rel=1e-12)
    run = client.simulate(fam, PAPER_GAINS_H01, [1.0, 0.0], steps=50, seed=3, channel=Channel.bernoulli(0.5),
                          exhausted="zero")
    assert run.raw["loss_model"] == "channel" and run.state.shape == (51, 2)


def test_simulation_on_a_channel_is_the_library_run(http):
    body = {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "x0": [-3.0, 2.0], "steps": 200, "seed": 5,
            "channel": {"kind": "gilbert_elliott", "p_gb": 0.2, "p_bg": 0.2, "loss_good": 0.1, "loss_bad": 0.9},
            "exhausted": "zero", "plant_transitions": [[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]]}
    resp = http.post("/v1/simulations", json=body)
    assert resp.status_code == 200, resp.text
    data = resp.json()
    from solver import simulate

    ref = simulate(PlantFamily.from_dict(PAPER_PLANT), np.array(PAPER_GAINS_H01), 3, [-3.0, 2.0], 200, 5,
                   channel=Channel.gilbert_elliott(0.2, 0.2, 0.1, 0.9), exhausted="zero",
                   plant_transitions=body["plant_transitions"])
    assert data["loss_model"] == "channel" and max(data["buffer_index"]) > 3
    assert data["channel_state"] == ref.channel_state.tolist()
    np.testing.assert_allclose(data["x"], ref.state, rtol=1e-12)
    bad = {**body, "channel": {"kind": "markov", "transition": [[0.5, 0.4], [0.5, 0.5]], "loss": [0, 1]}}
    assert_problem(http.post("/v1/simulations", json=bad), 422, "/channel/transition")


def test_a_design_request_with_a_channel_reports_the_designed_gains_on_it(http):
    link = {"kind": "gilbert_elliott", "p_gb": 0.05, "p_bg": 0.3, "loss_good": 0.01, "loss_bad": 0.8}
    body = {"plant": PAPER_PLANT, "n_drop": 3, "channel": link, "exhausted": "zero"}  # cost: Q = I, R = I
    resp = http.post("/v1/designs", json=body, headers={"Prefer": "wait=60"})
    assert resp.status_code == 201, resp.text
    result = resp.json()["result"]
    assert result["outcome"] == "stabilized"
    fam = PlantFamily.from_dict(PAPER_PLANT)
    ref = analyze_channel(fam, np.array(result["gains"]), 3, Channel.gilbert_elliott(0.05, 0.3, 0.01, 0.8),
                          exhausted="zero", weights=(np.eye(2), np.eye(1)))
    got = result["channel"]
    assert got["ms_stable"] is ref.ms_stable is True and got["n_drop"] == 3
    assert got["burst_rate"] == pytest.approx(ref.burst_rate, rel=1e-12)
    assert got["expected_cost"] == pytest.approx(ref.expected_cost, rel=1e-9)
    assert "P" not in got["upper_certificate"]
    # without a channel the result has none
    plain = http.post("/v1/designs", json={"plant": PAPER_PLANT, "n_drop": 3}, headers={"Prefer": "wait=60"})
    assert plain.json()["result"].get("channel") is None


@pytest.mark.parametrize("channel, pointer", [
    ({"kind": "markov", "transition": [[0.5, 0.4], [0.5, 0.5]], "loss": [0, 1]}, "/channel"),
    ({"kind": "bernoulli", "loss": 1.5}, "/channel"),
    ({"kind": "markov", "transition": np.full((12, 12), 1 / 12).tolist(), "loss": [0.1] * 12}, "/channel"),
])
def test_a_design_request_with_a_bad_channel_is_a_422_before_any_job(http, channel, pointer):
    before = http.get("/v1/designs").json()
    resp = http.post("/v1/designs", json={"plant": PAPER_PLANT, "n_drop": 3, "channel": channel})
    assert_problem(resp, 422, pointer)
    assert http.get("/v1/designs").json() == before


def test_the_client_designs_for_a_channel(http):
    client = Client("http://testserver", http_client=http, poll_interval=0.05)
    fam = PlantFamily.from_dict(PAPER_PLANT)
    res = client.design(fam, 3, channel=Channel.bernoulli(0.3), exhausted="hold")
    ref = analyze_channel(fam, res.gains, 3, Channel.bernoulli(0.3), exhausted="hold")
    assert res.raw["channel"]["ms_stable"] is True
    assert res.raw["channel"]["ms_radius"] == pytest.approx(ref.ms_radius, rel=1e-9)


def test_a_dead_link_says_so_over_http(http):
    """Issue 33, item 8: Channel.bernoulli(1.0) answered burst rate 0 and no bursts ever."""
    body = {"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01, "channel": {"kind": "bernoulli", "loss": 1.0}}
    resp = http.post("/v1/channels", json=body)
    assert resp.status_code == 200, resp.text
    data = resp.json()
    assert data["bursts"]["never_delivers"] is True and data["burst_rate"] == 1.0, data["bursts"]
    assert data["reason"].startswith("the channel never delivers"), data["reason"]
