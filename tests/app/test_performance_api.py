"""Performance designs and brackets over HTTP: request fields, typed results, 422 naming the field."""

from __future__ import annotations

import numpy as np
import pytest

from app.examples import PAPER_GAINS_H01, PAPER_PLANT

from .conftest import assert_problem, running_client, wait_for


@pytest.fixture(scope="module")
def client(module_db):
    with running_client(module_db, workers=1) as c:
        yield c


def paper_family():
    from solver import PlantFamily

    return PlantFamily.from_continuous(A=PAPER_PLANT["A"], B=PAPER_PLANT["B"], sampling_period=0.1)


def test_cost_design_with_input_limit_matches_the_library(client):
    from solver import design

    body = {"plant": PAPER_PLANT, "n_drop": 2, "objective": "cost",
            "weights": {"Q": [[1, 0], [0, 1]], "R": [[1]]}, "x0": [-3, 2], "u_max": [0.5]}
    resp = client.post("/v1/designs", json=body)
    assert resp.status_code == 202, resp.text
    done = wait_for(client, resp.json()["id"])
    assert done["status"] == "succeeded", done
    res = done["result"]
    assert res["outcome"] == "stabilized" and res["objective"] == "cost"
    perf = res["performance"]
    assert perf["kind"] == "cost" and perf["verified"] and perf["lower"] <= perf["upper"]
    direct = design(paper_family(), 2, objective="cost", weights=(np.eye(2), np.eye(1)), x0=[-3, 2], u_max=[0.5])
    assert perf["upper"] == pytest.approx(direct.performance.upper, rel=1e-6)
    np.testing.assert_allclose(np.asarray(res["invariant_set"]), direct.invariant_set, rtol=1e-5)
    assert [tuple(w) for w in perf["witness"]] == [tuple(w) for w in direct.performance.witness]


def test_hinf_analysis_of_the_paper_gains(client):
    body = {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "disturbance": [[2.0], [0.0]],
            "output": {"C": [[1, 0], [0, 1], [0, 0]], "D": [[0], [0], [1]]}, "bounds": "none"}
    resp = client.post("/v1/analyses", json=body)
    assert resp.status_code == 200, resp.text
    rep = resp.json()
    assert rep["hinf"]["verified"] and rep["hinf"]["lower"] <= rep["hinf"]["upper"]
    assert rep["cost"] is None


@pytest.mark.parametrize("extra, pointer", [
    ({"objective": "cost", "weights": {"Q": [[1, 0], [0, -1]], "R": [[1]]}}, "/weights/Q"),
    ({"objective": "hinf"}, "/disturbance"),
    ({"objective": "cost", "u_max": [1.0]}, "/x0"),
    ({"u_max": [1.0, 2.0]}, "/u_max"),
    ({"weights": {"Q": [[1, 0], [0, 1]], "R": [[1]]}}, "/weights"),
    ({"objective": "cost", "method": "ccl"}, "/method"),
    ({"objective": "bogus"}, "/objective"),
    ({"u_max": [-1.0]}, "/u_max"),
    ({"u_max": [1e200], "x0": [1.0, 0.0]}, "/u_max"),  # its square overflows float64
])
def test_bad_performance_fields_are_422_naming_the_field(client, extra, pointer):
    resp = client.post("/v1/designs", json={"plant": PAPER_PLANT, "n_drop": 2, **extra})
    assert_problem(resp, 422, pointer)


def test_python_client_sends_the_performance_fields(client):
    from app.client import Client
    from solver import design

    service = Client("http://testserver", http_client=client, poll_interval=0.05)
    fam = paper_family()
    E = list(fam.G)
    res = service.design(fam, 2, objective="hinf", disturbance=E, output=(np.vstack([np.eye(2), [[0, 0]]]),
                                                                          np.array([[0.0], [0.0], [1.0]])))
    direct = design(fam, 2, objective="hinf", disturbance=E)  # the same output: z = [x; u]
    assert res.objective == "hinf" and res.performance["upper"] == pytest.approx(direct.performance.upper, rel=1e-6)
    # One typed result for both (issue 33, item 14): the client's bracket is the library's Performance.
    assert type(res.performance) is type(direct.performance)
    assert res.performance.upper == pytest.approx(direct.performance.upper, rel=1e-6)
    assert res.performance.witness == direct.performance.witness
    rep = service.analyze(fam, PAPER_GAINS_H01, 3, weights=(np.eye(2), np.eye(1)), x0=[-3, 2], bounds="none")
    assert rep.cost["verified"] and rep.cost["x0"] == [-3.0, 2.0] and rep.hinf is None


def test_cli_performance_flags(tmp_path):
    import json

    from .test_cli import ncs

    (tmp_path / "motor.json").write_text(json.dumps(PAPER_PLANT))
    out = ncs("design", "motor.json", "--n-drop", 2, "--objective", "cost", "--x0=-3,2", "--u-max", "0.5",
              "--weights", '{"Q": [[1, 0], [0, 1]], "R": [[1]]}', "-o", "cost.json", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "cost: upper" in out.stdout and "input limits hold from" in out.stdout
    result = json.loads((tmp_path / "cost.json").read_text())
    assert result["performance"]["verified"] and result["invariant_set"] is not None
    out = ncs("analyze", "motor.json", "--gains", "cost.json", "--disturbance", "[[2], [0]]", cwd=tmp_path)
    assert out.returncode == 0 and "l2 gain: upper" in out.stdout, out.stderr
    out = ncs("design", "motor.json", "--n-drop", 2, "--objective", "hinf", cwd=tmp_path)
    assert out.returncode == 2 and "disturbance" in out.stderr and "Traceback" not in out.stderr


def test_lifted_blocks_count_against_the_size_limit(client):
    # 700 disturbance channels: blocks of side 2n + eta (p_w + p_z), 3 plant modes x 3 interval lengths, 12690 in
    # all (300 channels, 5490, fit the structured IPM's memory and the size limit: that design is accepted)
    wide = [[1.0] * 700, [0.0] * 700]
    resp = client.post("/v1/designs", json={"plant": PAPER_PLANT, "n_drop": 3, "objective": "hinf",
                                            "disturbance": wide})
    body = assert_problem(resp, 422)
    assert "NCS_MAX_LMI_SIZE" in resp.text or "solver memory" in resp.text, body  # refused before a job exists


def test_trace_figure_of_an_input_limited_design_draws_the_limit(client):
    body = {"plant": PAPER_PLANT, "n_drop": 2, "u_max": [0.5]}
    resp = client.post("/v1/designs", json=body)
    done = wait_for(client, resp.json()["id"])
    assert done["result"]["outcome"] == "stabilized", done
    svg = client.get(f"/v1/designs/{done['id']}/trace.svg?x0=-3,2&steps=30")
    assert svg.status_code == 200, svg.text
    assert "u_max = 0.5" in svg.text


def test_bad_analysis_performance_fields_are_422(client):
    body = {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "weights": {"Q": [[1, 0], [0, 1]], "R": [[0]]},
            "bounds": "none"}
    assert_problem(client.post("/v1/analyses", json=body), 422, "/weights")
    body = {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "disturbance": [[1.0, 2.0, 3.0]], "bounds": "none"}
    assert_problem(client.post("/v1/analyses", json=body), 422, "/disturbance")
