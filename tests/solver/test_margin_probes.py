"""Margin searches record a failed solver as "no certified design at this point" and never take a point without
a certified design as a proof about other points (issue 22, item 2)."""

from __future__ import annotations

import importlib

import pytest

from solver import SolverFailed, design
from solver.margins import SOLVER_FAILED, design_grid, max_n_drop, max_sampling_period

from .cartpole import cartpole

margins_module = importlib.import_module("solver.margins")


def _failing_above(h_fail: float):
    """design() whose solver fails for sampling periods above h_fail (like the IPM's iteration cap at h = 1 s)."""
    def fake(family, n_drop, **kwargs):
        if family.sampling_period > h_fail:
            raise SolverFailed("IPM ended with status 'max_iterations' (injected)", status="max_iterations")
        return design(family, n_drop, **kwargs)
    return fake


def test_a_failed_probe_is_a_point_of_the_curve_not_a_crash(monkeypatch):
    monkeypatch.setattr(margins_module, "design", _failing_above(0.3))
    res = max_sampling_period(cartpole(), 3, h_min=0.005, h_max=1.0, tol=0.005)
    assert res.curve[1]["sampling_period"] == 1.0 and res.curve[1]["outcome"] == SOLVER_FAILED
    assert "max_iterations" in res.curve[1]["message"] and res.curve[1]["gains"] is None
    # the bisection went on below the failure; the reported margin has a certificate, re-checked by a fresh design
    assert res.margin is not None and 0.1 < res.margin < 0.3
    again = design(cartpole(sampling_period=res.margin), 3, decay_rate=None)  # as margins design
    assert again.outcome == "stabilized" and again.certificate.verified
    assert "solver failed at h = 1" in res.message and "no proof" in res.message


def test_nothing_certified_at_h_min_is_no_proof_about_larger_periods():
    # At h = 0.001 s the decrease a quadratic function can certify is O(h), under the LMI margin: "infeasible"
    # there is a proof about that h only.  The family is stabilized at h = 0.02 s (checked directly).
    fam = cartpole()
    assert design(fam, 3).outcome == "stabilized"
    res = max_sampling_period(fam, 3, h_max=0.5, tol=0.005)  # default h_min = 0.001
    assert res.curve[0]["sampling_period"] == 0.001 and res.curve[0]["outcome"] != "stabilized"
    assert res.margin is not None and res.margin > 0.02
    assert "even at" not in res.message and "nothing certified at h_min = 0.001 s" in res.message
    assert design(cartpole(sampling_period=res.margin), 3, decay_rate=None).outcome == "stabilized"


def test_no_certified_period_at_all_says_it_proves_nothing(monkeypatch):
    monkeypatch.setattr(margins_module, "design", _failing_above(0.0))
    res = max_sampling_period(cartpole(), 3, h_min=0.01, h_max=0.1, tol=0.005)
    assert res.margin is None and all(p["outcome"] == SOLVER_FAILED for p in res.curve)
    assert [p["sampling_period"] for p in res.curve] == pytest.approx([0.01, 0.02, 0.04, 0.08])
    assert "proves nothing" in res.message


def test_n_drop_and_grid_searches_record_failures_too(monkeypatch):
    monkeypatch.setattr(margins_module, "design", _failing_above(0.05))
    res = design_grid(cartpole(), [(0.02, 2), (0.1, 2)])
    assert [p["outcome"] for p in res.curve] == ["stabilized", SOLVER_FAILED]

    def failing_at_3(family, n_drop, **kwargs):
        if n_drop == 3:
            raise SolverFailed("injected")
        return design(family, n_drop, **kwargs)

    monkeypatch.setattr(margins_module, "design", failing_at_3)
    res = max_n_drop(cartpole(), n_drop_max=5)
    assert res.margin == 2 and res.curve[-1]["outcome"] == SOLVER_FAILED and "proves nothing" in res.message


def test_a_point_over_the_size_budget_ends_the_n_drop_search_without_a_crash():
    from solver.margins import OVER_BUDGET

    from solver.compiled import design_size

    fits = design_size("lmi", 4, 1, 3, 3).memory  # the budget: n_drop = 1..3 fit, 4 does not
    assert design_size("lmi", 4, 1, 3, 4).memory > fits
    res = max_n_drop(cartpole(), n_drop_max=5, max_memory=fits)
    assert res.curve[-1]["outcome"] == OVER_BUDGET and "not tried" in res.curve[-1]["message"]
    assert res.margin == res.curve[-2]["n_drop"] and "proves nothing" in res.message
