"""MATLAB exports over HTTP (read back with scipy), job listings with plant summary, label, outcome, margin."""

from __future__ import annotations

import io
import uuid

import numpy as np
import pytest
import scipy.io

from .conftest import assert_problem, running_client

PLANT = {"kind": "dc_motor", "inertias": [0.03, 0.05], "sampling_period": 0.1}
WAIT = {"Prefer": "wait=60"}


@pytest.fixture(scope="module")
def client(module_db):
    with running_client(module_db, workers=1) as c:
        yield c


@pytest.fixture(scope="module")
def design(client):
    job = client.post("/v1/designs", json={"plant": PLANT, "n_drop": 3, "label": "rig A"}, headers=WAIT).json()
    assert job["status"] == "succeeded", job
    return job


def test_gains_mat_reads_back_as_the_json_result(client, design):
    resp = client.get(f"/v1/designs/{design['id']}/gains.mat")
    assert resp.status_code == 200
    assert resp.headers["content-type"] == "application/x-matlab-data"
    assert resp.headers["content-disposition"] == f'attachment; filename="ncs-design-{design["id"]}.mat"'
    d = scipy.io.loadmat(io.BytesIO(resp.content))
    res = design["result"]
    K = np.asarray(res["gains"])
    assert d["K"].shape == (3, 1, 2) and np.array_equal(d["K"], K)
    for q in range(3):
        assert np.array_equal(d[f"K{q + 1}"], K[q])
    assert np.array_equal(d["F"], np.moveaxis(np.asarray(res["F"]), 0, -1))
    assert np.array_equal(d["G"], np.moveaxis(np.asarray(res["G"]), 0, -1))
    assert np.array_equal(d["P"], np.asarray(res["certificate"]["P"]))
    assert int(d["n_drop"][0, 0]) == 3 and str(d["outcome"][0]) == "stabilized"
    assert str(d["certificate"][0]) == "common_quadratic" and float(d["h"][0, 0]) == 0.1
    again = client.get(f"/v1/designs/{design['id']}/gains.mat", headers={"If-None-Match": resp.headers["etag"]})
    assert again.status_code == 304


def test_gains_m_defines_the_same_numbers(client, design):
    resp = client.get(f"/v1/designs/{design['id']}/gains.m")
    assert resp.status_code == 200 and resp.headers["content-type"].startswith("text/x-matlab")
    assert resp.headers["content-disposition"].endswith('.m"')
    text = resp.text
    K1 = design["result"]["gains"][0][0]
    line = next(ln for ln in text.splitlines() if ln.startswith("K1 = "))
    values = [float(v) for v in line[len("K1 = ["):-2].split()]
    assert values == K1  # %.17g: exact
    assert "outcome = 'stabilized';" in text and "n_drop = 3;" in text


def test_gains_of_unknown_or_unfinished_jobs_are_problems(client):
    assert_problem(client.get(f"/v1/designs/{uuid.uuid4()}/gains.mat"), 404)
    big = {"plant": PLANT, "n_drop": 4, "method": "ccl", "options": {"max_iter": 1000, "solver": "CLARABEL"}}
    job = client.post("/v1/designs", json=big).json()
    resp = client.get(f"/v1/designs/{job['id']}/gains.m")
    if resp.status_code != 200:  # (the job may already have finished on a fast machine)
        body = assert_problem(resp, 409)
        assert body["type"].endswith("/problems/conflict") and "Prefer: wait" in body["detail"]
    client.post(f"/v1/designs/{job['id']}/cancel")


def test_listing_shows_plant_label_outcome(client, design):
    items = client.get("/v1/designs?limit=100").json()["items"]
    mine = next(i for i in items if i["id"] == design["id"])
    assert mine["label"] == "rig A" and mine["outcome"] == "stabilized"
    assert mine["plant"] == {"kind": "dc_motor", "n": 2, "m": 1, "r": 2, "sampling_period": 0.1}
    assert mine["links"]["gains_mat"] == f"/v1/designs/{design['id']}/gains.mat"
    assert design["label"] == "rig A" and design["request"]["label"] == "rig A"


def test_margin_listing_shows_the_margin(client):
    body = {"plant": PLANT, "search": "n_drop", "n_drop_max": 3, "label": "how many drops"}
    job = client.post("/v1/margins", json=body, headers=WAIT).json()
    assert job["status"] == "succeeded", job
    items = client.get("/v1/margins").json()["items"]
    mine = next(i for i in items if i["id"] == job["id"])
    assert mine["margin"] == job["result"]["margin"] == 3 and mine["margin_kind"] == "n_drop"
    assert mine["label"] == "how many drops" and mine["plant"]["r"] == 2


@pytest.mark.parametrize("label", ["", "x" * 201, "two\nlines", 7])
def test_bad_labels_are_refused_naming_the_field(client, label):
    assert_problem(client.post("/v1/designs", json={"plant": PLANT, "label": label}), 422, "/label")


def test_per_second_rates_next_to_per_sample_ones(client):
    job = client.post("/v1/designs", json={"plant": PLANT, "n_drop": 2, "options": {"decay_rate": 0.9}},
                      headers=WAIT).json()
    res = job["result"]
    assert res["decay_rate"] == pytest.approx(0.9)
    assert res["decay_rate_per_second"] == pytest.approx(0.9 ** 10)
    assert res["certificate"]["decay_rate_per_second"] == pytest.approx(0.9 ** 10)


def test_readme_typed_http_example_runs(db_url, start_server, capsys, monkeypatch):
    from .conftest import doc_block

    server = start_server(db_url, NCS_WORKERS=1, NCS_SYNC_WORKERS=1)
    monkeypatch.setenv("NCS_URL", server.base)
    monkeypatch.delenv("NCS_API_KEY", raising=False)
    path, code = doc_block("http-typed-example", "py")
    exec(compile(code, path, "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    assert printed == ["['current', 'speed'] rad/s", "0.9 0.3487", "(3, 1, 2) True", "['K', 'K1', 'K2', 'K3', 'F']",
                       "rig A 2 2 stabilized", "True True", "1 n_drop = 100 is over the limit of",
                       "True"], printed


def test_results_of_every_certificate_kind_and_unknown_fields_fit_the_models():
    from app.api.schemas import DesignResult
    from app.api.views import _typed

    farkas = {"outcome": "infeasible", "gains": None, "rate_bracket": {"lower": 0.3, "upper": 0.4},
              "certificate": {"kind": "farkas", "method": "lmi", "verified": True, "gain_bound": None,
                              "gain_bound_unbounded": True, "delta": 0.1, "e_norm": 0.0, "margin": 0.0,
                              "statement": "no common quadratic Lyapunov design of any gain norm",
                              "multipliers": [[[1.0, 0.0], [0.0, 1.0]]], "something_new": [1, 2]}}
    res = _typed(DesignResult, farkas, "result", "job")
    assert res.certificate.kind == "farkas" and res.certificate.gain_bound_unbounded
    assert res.model_dump()["certificate"]["something_new"] == [1, 2]
    unc = {"outcome": "infeasible", "certificate": {
        "kind": "uncontrollable", "verified": True, "plant": 0, "eigenvalue": [2.0, 0.0],
        "left_vector": {"real": [1.0, 0.0], "imag": [0.0, 0.0]}, "residual_eig": 0.0, "residual_input": 0.0,
        "dimension": 1}}
    assert _typed(DesignResult, unc, "result", "job").certificate.left_vector.real == [1.0, 0.0]
    odd = {"outcome": "stabilized", "gains": "not a list", "spectral_radii": [[0.5, None]], "timings": {"total": 1}}
    kept = _typed(DesignResult, odd, "result", "job")  # the field that does not fit is left out, not a 500
    assert kept.gains is None and kept.spectral_radii == [[0.5, None]]


def _documented(model, data: dict, where: str) -> None:
    """Every key of a real answer is a documented field of its model (recursively for nested models)."""
    from pydantic import BaseModel

    obj = model.model_validate(data)
    undocumented = set(data) - set(model.model_fields) - {f.alias for f in model.model_fields.values() if f.alias}
    assert not undocumented, f"{where}: undocumented fields {sorted(undocumented)}"
    for name, value in data.items():
        sub = getattr(obj, name, None)
        if isinstance(sub, BaseModel) and isinstance(value, dict):
            _documented(type(sub), value, f"{where}.{name}")
        elif isinstance(sub, list) and sub and isinstance(sub[0], BaseModel) and isinstance(value[0], dict):
            _documented(type(sub[0]), value[0], f"{where}.{name}[0]")


def test_real_answers_are_exactly_the_documented_fields(client, design):
    from app.api import schemas

    _documented(schemas.DesignJob, design, "design job")
    res = design["result"]
    trace = client.get(f"/v1/designs/{design['id']}/trace?steps=20").json()
    _documented(schemas.Trace, trace, "trace")
    body = {"plant": PLANT, "gains": res["gains"], "n_drop": 3}
    _documented(schemas.AnalysisReport, client.post("/v1/analyses", json=body).json(), "analysis")
    sim = client.post("/v1/simulations", json={**body, "x0": [1.0, -1.0], "steps": 10}).json()
    _documented(schemas.Simulation, sim, "simulation")
    for item in client.get("/v1/designs").json()["items"]:
        _documented(schemas.JobSummary, item, "listing")
    margin = client.post("/v1/margins", json={"plant": PLANT, "search": "n_drop", "n_drop_max": 2},
                         headers=WAIT).json()
    _documented(schemas.MarginJob, margin, "margin job")


def test_the_named_one_mode_docs_example_designs(client):
    from app.examples import DESIGN_EXAMPLES

    job = client.post("/v1/designs", json=DESIGN_EXAMPLES["named_one_mode"]["value"], headers=WAIT).json()
    assert job["status"] == "succeeded" and job["result"]["outcome"] == "stabilized", job
    assert job["label"] == "motor rig A" and job["plant"]["r"] == 1 and job["result"]["units"]["omega"] == "rad/s"
