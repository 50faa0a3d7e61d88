"""Bad input: every error is problem+json naming the field, and no job row is left behind."""

from __future__ import annotations

import copy
import json

import pytest

from app.examples import PAPER_GAINS_H01, PAPER_PLANT

from .conftest import assert_problem, running_client


@pytest.fixture(scope="module")
def client(module_db):
    # No dispatcher: validation must reject all of these before any job exists.
    with running_client(module_db, run_dispatcher=False, max_states=6, max_modes=5, max_n_drop=8,
                        max_lmi_size=500, max_body_bytes=20_000, max_simulation_steps=500) as c:
        yield c


def body(**plant_changes):
    plant = copy.deepcopy(PAPER_PLANT)
    plant.update(plant_changes)
    return {"plant": plant, "n_drop": 3, "method": "lmi"}


A = PAPER_PLANT["A"]
B = PAPER_PLANT["B"]

BAD_DESIGNS = {
    "non-square A": (body(A=[[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]] * 3), "/plant/A/0"),
    "ragged matrix": (body(A=[[[1.0, 2.0], [3.0]]] + A[1:]), "/plant/A/0/1"),
    "B rows differ from A": (body(B=[[[1.0], [0.0], [0.0]]] * 3), "/plant/B/0"),
    "modes with different n": (body(A=A[:2] + [[[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]],
                                    B=B[:2] + [[[1.0], [0.0], [0.0]]]), "/plant/A/2"),
    "modes with different m": (body(B=B[:2] + [[[1.0, 0.0], [0.0, 1.0]]]), "/plant/B/2"),
    "A and B mode counts differ": (body(B=B[:2]), "/plant/B"),
    "string in matrix": (body(A=[[["1", 2.0], [3.0, 4.0]]] + A[1:]), "/plant/A/0/0/0"),
    "boolean in matrix": (body(A=[[[True, 2.0], [3.0, 4.0]]] + A[1:]), "/plant/A/0/0/0"),
    "null in matrix": (body(A=[[[None, 2.0], [3.0, 4.0]]] + A[1:]), "/plant/A/0/0/0"),
    "empty family": (body(A=[], B=[]), "/plant/A"),
    "empty matrix": (body(A=[[]] + A[1:]), "/plant/A/0"),
    "zero sampling period": (body(sampling_period=0), "/plant/sampling_period"),
    "negative sampling period": (body(sampling_period=-0.1), "/plant/sampling_period"),
    "n over limit": (body(A=[[[0.1 * (i == j) for j in range(7)] for i in range(7)]],
                          B=[[[1.0]] * 7]), "/plant/A"),
    "r over limit": (body(A=A * 2, B=B * 2), "/plant/A"),
    "unknown plant kind": ({"plant": {"kind": "magic"}, "n_drop": 3}, "/plant"),
    "missing plant": ({"n_drop": 3}, "/plant"),
    "unknown field": ({**body(), "ndrop": 3}, "/ndrop"),
    "unknown method": ({**body(), "method": "newton"}, "/method"),
    "bad solver option": ({**body(), "options": {"solver": "MOSEK"}}, "/options/solver"),
    "decay rate zero": ({**body(), "options": {"decay_rate": 0}}, "/options/decay_rate"),
    "decay rate above one": ({**body(), "options": {"decay_rate": 1.5}}, "/options/decay_rate"),
    "decay rate word": ({**body(), "options": {"decay_rate": "fast"}}, "/options/decay_rate"),
    "decay rate with ccl": ({**body(), "method": "ccl", "options": {"decay_rate": 0.9}}, "/options/decay_rate"),
    "unknown scheme": ({**body(), "options": {"scheme": "smith"}}, "/options/scheme"),
    "per-sample switching over the LMI limit": ({**body(), "n_drop": 5, "options": {"plant_switching": "per_sample"}},
                                                "/n_drop"),
    "dc motor negative inertia": ({"plant": {"kind": "dc_motor", "inertias": [0.03, -0.01], "sampling_period": 0.1},
                                   "n_drop": 3}, "/plant/inertias/1"),
    "dc motor tiny inertia overflows": ({"plant": {"kind": "dc_motor", "inertias": [0.03, 1e-300],
                                                   "sampling_period": 0.1}}, "/plant/inertias/1"),
    "continuous plant overflows": (body(A=[[[50.0, 0.0], [0.0, 1.0]]] * 3, sampling_period=100.0), "/plant/A"),
    "dc motor no inertias": ({"plant": {"kind": "dc_motor", "inertias": [], "sampling_period": 0.1}}, "/plant/inertias"),
}


@pytest.mark.parametrize("case", list(BAD_DESIGNS), ids=list(BAD_DESIGNS))
def test_bad_design_is_422_naming_the_field(client, case):
    payload, pointer = BAD_DESIGNS[case]
    assert_problem(client.post("/v1/designs", json=payload), 422, pointer)


@pytest.mark.parametrize("n_drop", [0, -1, 9, 10**9, 2**70, "3", 3.0, True, None])
def test_bad_n_drop(client, n_drop):
    assert_problem(client.post("/v1/designs", json={**body(), "n_drop": n_drop}), 422, "/n_drop")


def test_total_lmi_size_limit(client):
    # ccl with n=2, r=3, n_drop=8: 2*2*8*(3*8+1) = 800 > 500, while lmi (96) is fine.
    resp = client.post("/v1/designs", json={**body(), "method": "ccl", "n_drop": 8})
    problem = assert_problem(resp, 422, "/n_drop")
    assert "LMI size" in problem["detail"]


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_non_finite_numbers(client, literal):
    text = json.dumps(body()).replace("-6.667", literal, 1)
    resp = client.post("/v1/designs", content=text, headers={"content-type": "application/json"})
    assert_problem(resp, 422, "/plant/A/0/1/1")


@pytest.mark.parametrize("text", ['{"plant": ', "not json", '{"plant": {}} trailing', ""])
def test_malformed_json(client, text):
    resp = client.post("/v1/designs", content=text, headers={"content-type": "application/json"})
    assert resp.status_code in (400, 422)
    assert_problem(resp, resp.status_code)


def test_body_over_limit_by_content_length(client):
    big = body()
    big["padding"] = "x" * 30_000
    assert_problem(client.post("/v1/designs", json=big), 413)


def test_body_over_limit_streamed_without_content_length(client):
    def chunks():
        yield b'{"plant": {"kind": "discrete", "F": ['
        for _ in range(2000):
            yield b"[[1.0, 2.0], [3.0, 4.0]],"
        yield b"[[1.0]]]}}"

    resp = client.post("/v1/designs", content=chunks(), headers={"content-type": "application/json"})
    assert_problem(resp, 413)


def test_unknown_job_id_is_404(client):
    for path in ("/v1/designs/00000000-0000-4000-8000-000000000000", "/v1/designs/nope",
                 "/v1/designs/00000000-0000-4000-8000-000000000000/trace",
                 "/v1/designs/00000000-0000-4000-8000-000000000000/events"):
        assert_problem(client.get(path), 404)
    assert_problem(client.post("/v1/designs/00000000-0000-4000-8000-000000000000/cancel"), 404)
    assert_problem(client.get("/v1/no-such-route"), 404)


def test_wrong_method_is_405_problem(client):
    assert_problem(client.delete("/v1/designs"), 405)


def test_bad_list_query(client):
    assert_problem(client.get("/v1/designs?status=done"), 422, "/status")
    assert_problem(client.get("/v1/designs?limit=0"), 422, "/limit")


ANALYSIS = {"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01}
SIM = {**ANALYSIS, "x0": [-3.0, 2.0], "steps": 50, "seed": 1}


@pytest.mark.parametrize("path,payload,pointer", [
    ("/v1/analyses", {**ANALYSIS, "gains": PAPER_GAINS_H01[:2]}, "/gains"),
    ("/v1/analyses", {**ANALYSIS, "gains": [[[1.0, 2.0, 3.0]]] * 3}, "/gains/0"),
    ("/v1/analyses", {**ANALYSIS, "gains": []}, "/gains"),
    ("/v1/analyses", {**ANALYSIS, "n_drop": 0}, "/n_drop"),
    ("/v1/analyses", {**ANALYSIS, "plant": {**PAPER_PLANT, "B": [[[1.0]]] * 3}}, "/plant/B/0"),
    ("/v1/simulations", {**SIM, "x0": [1.0]}, "/x0"),
    ("/v1/simulations", {**SIM, "steps": 501}, "/steps"),
    ("/v1/simulations", {**SIM, "steps": 0}, "/steps"),
    ("/v1/simulations", {**SIM, "mode": 3}, "/mode"),
    ("/v1/simulations", {**SIM, "sensor_loss": 1.0}, "/sensor_loss"),
    ("/v1/simulations", {**SIM, "loss_model": "gilbert"}, "/loss_model"),
])
def test_bad_analysis_and_simulation(client, path, payload, pointer):
    assert_problem(client.post(path, json=payload), 422, pointer)


@pytest.mark.parametrize("scale", [1e100, 1e200, 1.5e308])
def test_analysis_with_huge_finite_gains_is_a_422_naming_gains(client, scale):
    """Issue 20: finite gains of 1e100 or more overflowed the mode products (500 "Solver error")."""
    gains = [[[scale, 0.0]], [[0.0, 0.0]], [[0.0, 0.0]]]
    body = assert_problem(client.post("/v1/analyses", json={**ANALYSIS, "gains": gains}), 422, "/gains")
    assert "too large" in body["detail"], body


@pytest.mark.parametrize("path", ["/v1/designs", "/v1/analyses", "/v1/simulations", "/v1/margins"])
def test_json_body_without_content_type_is_415(client, path):
    """Issue 20: a JSON body sent with no Content-Type at all got 422 "Input should be a valid dictionary"."""
    resp = client.post(path, content=json.dumps(body()).encode())
    assert "content-type" not in resp.request.headers
    problem = assert_problem(resp, 415)
    assert "no Content-Type" in problem["detail"] and "application/json" in problem["detail"], problem


def test_no_job_row_was_left_behind(client):
    # Runs last in this module: all the bad requests above created nothing.
    listing = client.get("/v1/designs").json()
    assert listing["total"] == 0, listing
