"""Resource limits: no single request can take the service down. A design over the worker memory cap ends
`failed` saying so; an analysis over it is a 422; simulation steps and analysis products are capped.
(The per-job time limit: tests/app/test_queue.py::test_time_limit_fails_the_job_with_a_clear_reason; the
synchronous time limit: test_config_and_migrations.py::test_synchronous_time_limit_is_a_503_problem...)"""

from __future__ import annotations

import numpy as np
import pytest

from app.examples import PAPER_GAINS_H01, PAPER_PLANT

from .conftest import assert_problem, running_client, wait_for

# n = 12, r = 6, n_drop = 8 (LMI size 1152, inside the size limits): its SDP needs a few hundred MB.
_F = (np.eye(12) * 0.9 + 0.01 * np.ones((12, 12))).tolist()
BIG = {"plant": {"kind": "discrete", "F": [_F] * 6, "G": [np.ones((12, 3)).tolist()] * 6},
       "n_drop": 4, "method": "lmi", "options": {"solver": "CLARABEL"}}
# Clarabel through cvxpy outgrows a 60 MB cap at run time (its address space: allocator arenas, BLAS buffers) while
# design_size's estimate of its peak allocations (43 MiB) lets it through: the run-time cap is what stops it.


def test_big_passes_the_up_front_estimate_so_the_run_time_cap_is_what_is_tested():
    from solver.compiled import design_size

    assert design_size("lmi", 12, 3, 6, BIG["n_drop"], solver="CLARABEL").memory < 60 * 2**20
ANALYSIS = {"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01}


def test_design_over_the_worker_memory_cap_fails_with_a_clear_reason(db_url):
    with running_client(db_url, workers=1, worker_memory_mb=60, max_attempts=3) as c:
        job = wait_for(c, c.post("/v1/designs", json=BIG).json()["id"], timeout=120)
        assert job["status"] == "failed", job
        assert "memory limit exceeded" in job["error"] and "NCS_WORKER_MEMORY_MB" in job["error"], job["error"]
        assert job["attempts"] == 1  # not retried: it would fail the same way
        assert c.app.state.dispatcher.alive_workers() == 1 or c.get("/healthz").status_code == 200


def test_analysis_over_the_memory_cap_is_a_422_and_the_pool_goes_on(db_url):
    # n = 20, r = 20 modes, n_drop = 4: 80 interval modes; allowing 10^6 products lets the enumeration reach
    # length 3 (512,000 products of 20x20 matrices, ~1.6 GB), far over the 150 MB cap whatever the LMI solver.
    n, r = 20, 20
    F = [(np.eye(n) * 0.5).tolist()] * r
    G = [np.ones((n, 1)).tolist()] * r
    body = {"plant": {"kind": "discrete", "F": F, "G": G}, "n_drop": 4, "gains": [np.zeros((1, n)).tolist()] * 4,
            "max_product_length": 8}
    with running_client(db_url, run_dispatcher=False, worker_memory_mb=150, max_lmi_size=100_000,
                        max_analysis_products=1_000_000) as c:
        problem = assert_problem(c.post("/v1/analyses", json=body), 422)  # without the cap: 30 s, then 503
        # The library's own estimate (solver.workload, issue 33 item 7) now refuses it before the enumeration
        # starts: 10^6 products of 20 x 20 matrices are over its 4 GiB budget, let alone the 150 MB cap.
        detail = problem["detail"]
        assert ("memory limit exceeded" in detail and "NCS_WORKER_MEMORY_MB" in detail) or (
            "would need about" in detail and "of memory" in detail and "max_products" in detail), detail
        assert c.post("/v1/analyses", json=ANALYSIS).json()["stable"] is True


def test_analysis_products_are_capped(db_url):
    with running_client(db_url, run_dispatcher=False, max_analysis_products=10) as c:
        rep = c.post("/v1/analyses", json={**ANALYSIS, "max_product_length": 8}).json()
        # 9 interval modes: length 2 already needs 81 products > 10, so only single modes are enumerated.
        assert rep["product_length_checked"] == 1, rep
        assert_problem(c.post("/v1/analyses", json={**ANALYSIS, "max_product_length": 9}), 422,
                       "/max_product_length")


def test_simulation_and_trace_steps_are_capped(db_url):
    with running_client(db_url, workers=1, max_simulation_steps=300) as c:
        sim = {**ANALYSIS, "x0": [-3.0, 2.0]}
        assert c.post("/v1/simulations", json={**sim, "steps": 300}).status_code == 200
        body = assert_problem(c.post("/v1/simulations", json={**sim, "steps": 301}), 422, "/steps")
        assert "NCS_MAX_SIMULATION_STEPS" in body["detail"]
        job = wait_for(c, c.post("/v1/designs", json={"plant": PAPER_PLANT, "n_drop": 3}).json()["id"])
        assert c.get(f"/v1/designs/{job['id']}/trace?steps=300").status_code == 200
        assert_problem(c.get(f"/v1/designs/{job['id']}/trace?steps=301"), 422, "/steps")
        assert_problem(c.get(f"/v1/designs/{job['id']}/trace?steps=10000000000000000000000"), 422, "/steps")


def test_a_design_over_the_estimated_memory_or_time_is_a_422_before_any_job(db_url):
    # The library's estimate (solver.compiled.design_size) against the service's budgets: a 4-state, 3-mode
    # cart-pole at n_drop = 100 needs ~140 MiB of solver memory; at n_drop = 60 with decay_rate "max" ~1.3 s
    # (bench/size_calibration.py), one plain solve ~0.5 s: a job time limit between the two refuses the first.
    from solver.compiled import design_size

    from tests.solver.cartpole import cartpole

    fam = cartpole()
    plant = {"kind": "discrete", "F": fam.F.tolist(), "G": fam.G.tolist(), "sampling_period": 0.02}
    assert 100 * 2**20 < design_size("lmi", 4, 1, 3, 100).memory < 200 * 2**20
    best = design_size("lmi", 4, 1, 3, 60, decay_rate="max").total_seconds
    plain = design_size("lmi", 4, 1, 3, 60, decay_rate=None).total_seconds
    limit = float(f"{(best * plain) ** 0.5:.2g}")
    assert plain < limit < best
    with running_client(db_url, run_dispatcher=False, worker_memory_mb=100, max_n_drop=1000,
                        max_lmi_size=10**6, job_time_limit=limit) as c:
        problem = assert_problem(c.post("/v1/designs", json={"plant": plant, "n_drop": 100}), 422, "/n_drop")
        assert "NCS_WORKER_MEMORY_MB" in problem["detail"] and "MiB of solver memory" in problem["detail"]
        problem = assert_problem(c.post("/v1/designs", json={"plant": plant, "n_drop": 60,
                                                             "options": {"decay_rate": "max"}}), 422, "/n_drop")
        assert "NCS_JOB_TIME_LIMIT" in problem["detail"] and f"limit of {limit:g} s" in problem["detail"]
        assert c.get("/v1/designs").json()["items"] == []


def test_the_service_estimates_the_whole_request_as_the_library(db_url):
    # One estimate for every path (solver.compiled.design_size): a cost design's larger blocks, its Newton steps and
    # its bracket's lower-bound search make it ~7 times the plain one at n_drop = 20, and the job time limit between
    # the two refuses only the cost design, with the library's message.
    from solver import InvalidInput
    from solver.design import request_size

    from tests.solver.cartpole import cartpole

    fam = cartpole()
    plant = {"kind": "discrete", "F": fam.F.tolist(), "G": fam.G.tolist(), "sampling_period": 0.02}
    plain = request_size("lmi", fam, 20, decay_rate=None)
    cost = request_size("lmi", fam, 20, objective="cost")
    limit = (plain.total_seconds * cost.total_seconds) ** 0.5
    assert plain.total_seconds < limit < cost.total_seconds
    with pytest.raises(InvalidInput) as lib:
        cost.check(max_seconds=limit)
    with running_client(db_url, run_dispatcher=False, job_time_limit=limit) as c:
        assert c.post("/v1/designs", json={"plant": plant, "n_drop": 20, "options": {"decay_rate": None}}
                      ).status_code == 202
        problem = assert_problem(c.post("/v1/designs", json={"plant": plant, "n_drop": 20, "objective": "cost"}),
                                 422, "/n_drop")
        assert "cost path" in problem["detail"] and "NCS_JOB_TIME_LIMIT" in problem["detail"]
        assert str(lib.value).split(" would take")[0] in problem["detail"]
