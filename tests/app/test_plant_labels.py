"""Plant JSON: names and units reach the library and the figures; a single matrix gets one error."""

from __future__ import annotations

import pytest

from .conftest import assert_problem, running_client

PLANT = {"kind": "continuous", "sampling_period": 0.1,
         "A": [[[-4.0, -0.03], [0.5, -6.667]], [[-4.0, -0.03], [1.5, -20.0]]],
         "B": [[[2.0], [0.0]], [[2.0], [0.0]]],
         "state_names": ["current", "speed"], "input_names": ["voltage"],
         "units": {"current": "A", "speed": "rad/s", "voltage": "V"}}


@pytest.fixture(scope="module")
def client(module_db):
    with running_client(module_db, workers=1) as c:
        yield c


@pytest.mark.parametrize("field,plant", [
    ("A", {"kind": "continuous", "sampling_period": 0.1, "A": [[-1.0, 0.0], [0.0, -2.0]], "B": [[[1.0], [0.0]]]}),
    ("B", {"kind": "continuous", "sampling_period": 0.1, "A": [[[-1.0, 0.0], [0.0, -2.0]]], "B": [[1.0], [0.0]]}),
    ("F", {"kind": "discrete", "F": [[1.0, 0.1], [0.0, 1.0]], "G": [[[0.0], [0.1]]]}),
    ("G", {"kind": "discrete", "F": [[[1.0, 0.1], [0.0, 1.0]]], "G": [[0.0], [0.1]]}),
])
def test_a_single_matrix_gets_one_error_saying_how_to_wrap_it(client, field, plant):
    body = assert_problem(client.post("/v1/designs", json={"plant": plant, "n_drop": 2}), 422)
    assert len(body["errors"]) == 1, body
    err = body["errors"][0]
    assert err["pointer"] == f"/plant/{field}" and err["type"] == "single_matrix"
    assert "one per plant mode" in err["msg"] and f'"{field}": [' in err["msg"]


def test_single_gain_matrix_gets_one_error(client):
    body = assert_problem(client.post("/v1/analyses", json={"plant": PLANT, "gains": [[-1.0, 0.0]]}), 422)
    assert [e["pointer"] for e in body["errors"]] == ["/gains"] and "K_1..K_N" in body["errors"][0]["msg"]


def test_names_and_units_reach_result_and_figure(client):
    job = client.post("/v1/designs", json={"plant": PLANT, "n_drop": 2}, headers={"Prefer": "wait=60"}).json()
    assert job["status"] == "succeeded", job
    res = job["result"]
    assert res["state_names"] == ["current", "speed"] and res["input_names"] == ["voltage"]
    assert res["units"]["speed"] == "rad/s"
    svg = client.get(f"/v1/designs/{job['id']}/trace.svg?steps=30").text
    assert "speed (rad/s)" in svg and "voltage (V)" in svg


def test_dc_motor_names_its_states_by_default(client):
    plant = {"kind": "dc_motor", "inertias": [0.03, 0.05], "sampling_period": 0.1}
    job = client.post("/v1/designs", json={"plant": plant, "n_drop": 2}, headers={"Prefer": "wait=60"}).json()
    assert job["result"]["state_names"] == ["i_a", "omega"] and job["result"]["units"]["omega"] == "rad/s"
    assert "omega (rad/s)" in client.get(f"/v1/designs/{job['id']}/trace.svg?steps=30").text


def test_bad_names_name_the_field(client):
    bad = {**PLANT, "state_names": ["only_one"]}
    assert_problem(client.post("/v1/designs", json={"plant": bad}), 422, "/plant/state_names")
    bad = {**PLANT, "units": {"nope": "m"}}
    assert_problem(client.post("/v1/designs", json={"plant": bad}), 422, "/plant/units")
    bad = {**PLANT, "state_names": ["x" * 65, "y"]}
    assert_problem(client.post("/v1/designs", json={"plant": bad}), 422, "/plant/state_names/0")


def test_client_sends_names_and_gets_them_back(client):
    from app.client import plant_json
    from solver import PlantFamily

    fam = PlantFamily.dc_motor([0.03, 0.05], sampling_period=0.1)
    sent = plant_json(fam)
    assert sent["state_names"] == ["i_a", "omega"] and sent["units"]["v_a"] == "V"
    job = client.post("/v1/designs", json={"plant": sent, "n_drop": 2}, headers={"Prefer": "wait=60"}).json()
    assert job["result"]["input_names"] == ["v_a"]


def test_mode_names_title_the_trace_figure_instead_of_indices(client):
    # issue 22, item 7: the figure's titles and plant-mode strip say the plant's names, not "mode 0/1/2"
    from app.client import plant_json

    from tests.solver.cartpole import cartpole

    plant = plant_json(cartpole())
    assert plant["mode_names"] == ["pole 0.2 m", "pole 0.3 m", "pole 0.4 m"]
    job = client.post("/v1/designs", json={"plant": plant, "n_drop": 3, "options": {"decay_rate": None}},
                      headers={"Prefer": "wait=60"}).json()
    assert job["status"] == "succeeded", job
    svg = client.get(f"/v1/designs/{job['id']}/trace.svg?steps=100&x0=0,0,0.1,0").text
    assert "Plant fixed: pole 0.3 m" in svg and "Plant may switch when a packet arrives" in svg
    assert "per_interval" not in svg and "mode 0" not in svg
    bad = {**plant, "mode_names": ["a", "b"]}
    problem = assert_problem(client.post("/v1/designs", json={"plant": bad, "n_drop": 3}), 422, "/plant/mode_names")
    assert "mode_names has 2 names but the plant has 3" in problem["detail"]
