"""The design job lifecycle through the ASGI app (real dispatcher, real worker processes, real solver)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from app.examples import DESIGN_EXAMPLES, PAPER_GAINS_H01, PAPER_PLANT

from .conftest import assert_problem, running_client, wait_for

PAPER_LMI = DESIGN_EXAMPLES["paper_lmi"]["value"]
PAPER_CCL = DESIGN_EXAMPLES["paper_ccl"]["value"]
# The paper's plant with n_drop = 6 and CCL: its first iteration alone takes several seconds,
# a reliably slow job for the cancel tests.
SLOW = {"plant": PAPER_PLANT, "n_drop": 6, "method": "ccl", "options": {"max_iter": 50, "solver": "CLARABEL"}}


@pytest.fixture(scope="module")
def client(module_db):
    with running_client(module_db, workers=2, cancel_grace=1.0) as c:
        yield c


def paper_family():
    from solver import PlantFamily

    return PlantFamily.from_continuous(A=PAPER_PLANT["A"], B=PAPER_PLANT["B"], sampling_period=0.1)


@pytest.mark.parametrize("method", ["lmi", "ccl"])
def test_paper_example_designs_match_the_solver(client, method):
    from solver import design

    payload = {**PAPER_LMI, "method": method}
    resp = client.post("/v1/designs", json=payload)
    assert resp.status_code == 202, resp.text
    job = resp.json()
    assert resp.headers["location"] == f"/v1/designs/{job['id']}"
    assert job["status"] in ("queued", "running")
    assert job["request"]["options"]["solver"] == "AUTO"  # defaults are filled in
    done = wait_for(client, job["id"])
    assert done["status"] == "succeeded", done
    res = done["result"]
    assert res["outcome"] == "stabilized" and done["outcome"] == "stabilized"
    for key in ("gains", "certificate", "spectral_radii", "F", "G", "history", "timings", "solver"):
        assert key in res, key
    gains = np.asarray(res["gains"])
    assert gains.shape == (3, 1, 2)
    direct = design(paper_family(), n_drop=3, method=method)
    np.testing.assert_allclose(gains, direct.gains, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(np.asarray(res["F"]), direct_F(), atol=1e-12)
    assert done["started_at"] and done["finished_at"] and done["attempts"] == 1
    if method == "ccl":
        assert done["progress"]["iteration"] is not None


def direct_F():
    return np.asarray(paper_family().F)


def test_dc_motor_and_discrete_plants(client):
    ids = [client.post("/v1/designs", json=DESIGN_EXAMPLES[k]["value"]).json()["id"] for k in ("dc_motor", "discrete")]
    for job_id in ids:
        job = wait_for(client, job_id)
        assert job["status"] == "succeeded", job
        assert job["result"]["outcome"] in ("stabilized", "infeasible", "not_converged")


def test_infeasible_is_a_succeeded_job(client):
    # An unstable mode that the input cannot reach: no controller exists.
    plant = {"kind": "discrete", "F": [[[1.5, 0.0], [0.0, 0.5]]], "G": [[[0.0], [1.0]]]}
    job = wait_for(client, client.post("/v1/designs", json={"plant": plant, "n_drop": 2}).json()["id"])
    assert job["status"] == "succeeded"
    assert job["result"]["outcome"] == "infeasible"
    assert job["result"]["gains"] is None
    assert_problem(client.get(f"/v1/designs/{job['id']}/trace"), 409)


def test_idempotency_key(client):
    headers = {"Idempotency-Key": "abc-123"}
    first = client.post("/v1/designs", json=PAPER_LMI, headers=headers)
    again = client.post("/v1/designs", json=PAPER_LMI, headers=headers)
    assert first.status_code == again.status_code == 202
    assert first.json()["id"] == again.json()["id"]
    assert again.headers.get("idempotent-replayed") == "true"
    other = client.post("/v1/designs", json={**PAPER_LMI, "n_drop": 2}, headers=headers)
    assert_problem(other, 422, "/Idempotency-Key")
    wait_for(client, first.json()["id"])


def test_list_pagination_and_filter(client):
    ids = [client.post("/v1/designs", json=PAPER_LMI).json()["id"] for _ in range(3)]
    for job_id in ids:
        wait_for(client, job_id)
    page = client.get("/v1/designs?limit=2").json()
    assert len(page["items"]) == 2 and page["total"] >= 3
    assert [i["id"] for i in page["items"]] == ids[::-1][:2]  # newest first
    assert page["next"].startswith("/v1/designs?limit=2&offset=2")
    page2 = client.get(page["next"]).json()
    assert page2["items"][0]["id"] == ids[0]
    done = client.get("/v1/designs?status=succeeded&limit=100").json()
    assert all(i["status"] == "succeeded" for i in done["items"])
    assert set(ids) <= {i["id"] for i in done["items"]}
    assert client.get("/v1/designs?status=running&limit=100").json()["total"] == 0
    assert "result" not in page["items"][0]


def test_events_stream_progress_and_end(client):
    job_id = client.post("/v1/designs", json=PAPER_CCL).json()["id"]
    events = []
    with client.stream("GET", f"/v1/designs/{job_id}/events") as resp:
        assert resp.status_code == 200
        assert resp.headers["content-type"].startswith("text/event-stream")
        event = None
        for line in resp.iter_lines():
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: "):
                events.append((event, json.loads(line[6:])))
    kinds = [e for e, _ in events]
    assert kinds[0] == "status" and kinds[-1] == "end"
    assert "progress" in kinds
    assert events[-1][1]["status"] == "succeeded"
    assert events[-1][1]["result"]["outcome"] == "stabilized"


def test_trace_is_byte_identical_and_covers_all_modes(client):
    job = wait_for(client, client.post("/v1/designs", json=PAPER_LMI).json()["id"])
    url = f"/v1/designs/{job['id']}/trace?seed=42&steps=100&x0=-3,2"
    first, second = client.get(url), client.get(url)
    assert first.status_code == 200, first.text
    assert first.content == second.content
    data = first.json()
    for key in ("t", "x", "u"):
        assert key in data
    assert len(data["x"]) in (100, 101)
    assert [m["plant_mode"] for m in data["per_mode"]] == [0, 1, 2]
    other = client.get(f"/v1/designs/{job['id']}/trace?seed=7&steps=100&x0=-3,2")
    assert other.content != first.content
    assert client.get(url, headers={"If-None-Match": first.headers["etag"]}).status_code == 304
    # Independent of the cache: a fresh app computes the same bytes (see test_server for a new process).
    assert_problem(client.get(f"/v1/designs/{job['id']}/trace?x0=1,2,3"), 422, "/x0")
    assert_problem(client.get(f"/v1/designs/{job['id']}/trace?x0=a,b"), 422, "/x0")
    assert_problem(client.get(f"/v1/designs/{job['id']}/trace?steps=100000"), 422, "/steps")
    assert_problem(client.get(f"/v1/designs/{job['id']}/trace?mode=3"), 422, "/mode")


def test_analysis_of_the_papers_gains(client):
    resp = client.post("/v1/analyses", json={"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01})
    assert resp.status_code == 200, resp.text
    report = resp.json()
    assert report["stable"] is True
    assert np.asarray(report["spectral_radii"]).size == 9  # r x n_drop modes (l, eta)


def test_analysis_of_destabilizing_gains(client):
    gains = [[[50.0, 50.0]], [[0.0, 0.0]], [[0.0, 0.0]]]
    report = client.post("/v1/analyses", json={"plant": PAPER_PLANT, "gains": gains}).json()
    assert report["stable"] is False


def test_simulation(client):
    payload = {"plant": PAPER_PLANT, "gains": PAPER_GAINS_H01, "x0": [-3.0, 2.0], "steps": 60, "seed": 42}
    first = client.post("/v1/simulations", json=payload)
    assert first.status_code == 200, first.text
    data = first.json()
    assert {"t", "x", "u", "mode"} <= set(data)
    assert client.post("/v1/simulations", json=payload).json() == data
    assert abs(data["x"][-1][0]) < 0.1  # the loop is stable: the state decays


def test_cancel_queued_job_never_starts(client):
    blockers = [client.post("/v1/designs", json=SLOW).json()["id"] for _ in range(2)]
    for b in blockers:
        wait_for(client, b, ("running",), timeout=30)
    queued = client.post("/v1/designs", json=PAPER_LMI).json()["id"]
    resp = client.post(f"/v1/designs/{queued}/cancel")
    assert resp.status_code == 200, resp.text
    assert resp.json()["status"] == "cancelled"
    for b in blockers:
        t0 = time.monotonic()
        assert client.post(f"/v1/designs/{b}/cancel").status_code == 202
        job = wait_for(client, b, timeout=10)
        assert job["status"] == "cancelled", job
        assert time.monotonic() - t0 < 3.0
    job = client.get(f"/v1/designs/{queued}").json()
    assert job["status"] == "cancelled" and job["started_at"] is None and job["attempts"] == 0
    # Cancelling again is harmless; cancelling a finished job is a conflict.
    assert client.post(f"/v1/designs/{queued}/cancel").status_code == 200
    done = wait_for(client, client.post("/v1/designs", json=PAPER_LMI).json()["id"])
    assert_problem(client.post(f"/v1/designs/{done['id']}/cancel"), 409)


def test_cancel_running_ccl_stops_between_iterations(client):
    # A CCL run with several iterations: the solver callback sees the cancel.
    payload = {"plant": PAPER_PLANT, "n_drop": 5, "method": "ccl", "options": {"solver": "CLARABEL"}}
    job_id = client.post("/v1/designs", json=payload).json()["id"]
    wait_for(client, job_id, ("running",) + ("succeeded",), timeout=30)
    t0 = time.monotonic()
    resp = client.post(f"/v1/designs/{job_id}/cancel")
    job = wait_for(client, job_id, timeout=10)
    if resp.status_code == 409:  # it finished before the cancel arrived: fine, nothing to check
        return
    assert job["status"] == "cancelled" and time.monotonic() - t0 < 3.0


def test_openapi_and_offline_docs(client):
    spec = client.get("/openapi.json").json()
    for path in ("/v1/designs", "/v1/designs/{job_id}", "/v1/designs/{job_id}/events", "/v1/designs/{job_id}/cancel",
                 "/v1/designs/{job_id}/trace", "/v1/simulations", "/v1/analyses", "/healthz", "/readyz"):
        assert path in spec["paths"], path
    examples = spec["paths"]["/v1/designs"]["post"]["requestBody"]["content"]["application/json"]["examples"]
    assert examples["paper_lmi"]["value"]["plant"] == PAPER_PLANT
    html = client.get("/docs").text
    assert "/static/docs/swagger-ui-bundle.js" in html and "cdn" not in html.lower()
    assert client.get("/static/docs/swagger-ui-bundle.js").status_code == 200
    assert client.get("/static/docs/swagger-ui.css").status_code == 200
    assert client.get("/redoc").status_code == 200


def test_health_and_readiness(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    deadline = time.monotonic() + 60  # worker processes import cvxpy first: slow on a busy machine
    while (ready := client.get("/readyz")).status_code != 200 and time.monotonic() < deadline:
        time.sleep(0.1)
    assert ready.status_code == 200, ready.text
    assert ready.json()["workers"]["alive"] == 2


def test_api_keys(db_url):
    with running_client(db_url, run_dispatcher=False, api_keys="k1,k2") as c:
        assert_problem(c.get("/v1/designs"), 401)
        assert_problem(c.get("/v1/designs", headers={"X-API-Key": "nope"}), 401)
        assert c.get("/v1/designs", headers={"X-API-Key": "k2"}).status_code == 200
        assert c.get("/v1/designs", headers={"Authorization": "Bearer k1"}).status_code == 200
        assert c.get("/healthz").status_code == 200


def test_every_solver_method_is_offered_and_runs(client):
    from solver import METHODS

    spec = client.get("/openapi.json").json()
    offered = spec["components"]["schemas"]["DesignRequest"]["properties"]["method"]["enum"]
    assert sorted(offered) == sorted(METHODS)
    ids = {m: client.post("/v1/designs", json={**PAPER_LMI, "method": m}).json()["id"] for m in METHODS}
    for method, job_id in ids.items():
        job = wait_for(client, job_id)
        assert job["status"] == "succeeded" and job["result"]["outcome"] == "stabilized", (method, job)


def test_events_of_a_finished_job_end_at_once(client):
    job = wait_for(client, client.post("/v1/designs", json=PAPER_LMI).json()["id"])
    with client.stream("GET", f"/v1/designs/{job['id']}/events") as resp:
        lines = [line for line in resp.iter_lines() if line.startswith("event: ")]
    assert lines[0] == "event: status" and lines[-1] == "event: end" and len(lines) <= 3


def test_design_options_reach_the_solver(client):
    payload = {**PAPER_LMI, "options": {"decay_rate": "max", "scheme": "predictive", "plant_switching": "per_sample"}}
    job = wait_for(client, client.post("/v1/designs", json=payload).json()["id"])
    assert job["status"] == "succeeded", job
    res = job["result"]
    assert res["outcome"] == "stabilized" and 0 < res["decay_rate"] < 1
    assert res["plant_switching"] == "per_sample"
    trace = client.get(f"/v1/designs/{job['id']}/trace?x0=-3,2&steps=30").json()
    assert trace["query"]["plant_switching"] == "per_sample"  # the design's own switching by default
