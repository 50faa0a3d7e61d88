"""The performance designs' scaling layer (solver/scaling.py, PerformanceScaling) and their robustness.

* the layer is exact: the scaled lifted data are the user's, scaled entry by entry (powers of two);
* badly scaled random families (state scales 1e-3 to 1e3, input scales 1e-2 to 1e2): a cost or H-infinity
  design answers "stabilized" with a re-checked bracket whenever the plain design stabilizes, and never raises;
* one mode, ``n_drop = 1``, a nearly unreachable unstable mode: the cost design is the Riccati optimum;
* a solver that fails is a verdict, not an exception.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from solver import PlantFamily, design
from solver.errors import SolverFailed
from solver.lifting import lift_modes
from solver.network import ModeSet
from solver.scaling import performance_balance


def _family(seed: int, bad: bool) -> PlantFamily:
    rng = np.random.default_rng(seed)
    n, m, r = int(rng.integers(2, 5)), int(rng.integers(1, 3)), int(rng.integers(1, 3))
    F = rng.normal(size=(r, n, n)) * 0.6
    G = rng.normal(size=(r, n, m))
    if bad:
        t = 10.0 ** rng.uniform(-3, 3, n)
        F = F / t[None, :, None] * t[None, None, :]
        G = G / t[None, :, None] * 10.0 ** rng.uniform(-2, 2, m)[None, None, :]
    return PlantFamily(F=F, G=G, sampling_period=0.1)


def test_scaled_lifted_data_are_the_users_scaled_exactly():
    family = _family(3, True)
    modes = ModeSet.from_family(family, 2)
    E = np.ones((family.n_states, 1))
    lifted = lift_modes(modes, (np.diag(np.arange(1.0, family.n_states + 1) * 1e3), np.eye(family.n_inputs)), E,
                        None, cost=True)
    scale = performance_balance(family, lifted)
    assert not scale.plain.is_identity and scale.cost != 1.0
    t, u = scale.plain.state, scale.plain.input
    assert np.all(np.log2(np.concatenate([t, u, [scale.cost, scale.disturbance, scale.output]])) % 1 == 0)
    rng = np.random.default_rng(0)
    gains_s = rng.normal(size=(2, family.n_inputs, family.n_states))
    gains = scale.plain.gains_back(gains_s)
    user, scaled = lifted.numeric(gains), scale.lifted(lifted).numeric(gains_s)
    for d, ds in zip(user, scaled):
        np.testing.assert_allclose(ds["A"], d["A"] / t[:, None] * t[None, :], rtol=1e-13, atol=0)
        np.testing.assert_allclose(ds["L"], d["L"] * t[None, :] / np.sqrt(scale.cost), rtol=1e-13, atol=0)
        np.testing.assert_allclose(ds["C"], d["C"] * t[None, :] / scale.output, rtol=1e-13, atol=0)
        np.testing.assert_array_equal(ds["B"], d["B"] / t[:, None] * scale.disturbance)
    # a quadratic form maps back by the congruence: x' P x = cost x~' P~ x~ with x = T x~
    P_s = np.cov(rng.normal(size=(family.n_states, 50)))
    x_s = rng.normal(size=family.n_states)
    P = scale.quadratic_back(P_s, "cost")
    assert (t * x_s) @ P @ (t * x_s) == pytest.approx(scale.cost * x_s @ P_s @ x_s, rel=1e-12)


@pytest.mark.parametrize("seed", range(8))
def test_performance_designs_stabilize_whenever_the_plain_design_does(seed):
    family = _family(seed, bad=True)
    n_drop = 1 + seed % 3
    plain = design(family, n_drop, decay_rate=None)
    for objective, kw in (("cost", {}), ("hinf", {"disturbance": np.eye(family.n_states)[:, :1]})):
        res = design(family, n_drop, objective=objective, **kw)  # raises nothing on a valid request
        if plain.outcome == "stabilized":
            assert res.outcome == "stabilized", (objective, res.message)
            perf = res.performance
            assert perf is not None and perf.verified and perf.upper is not None, (objective, res.message)
            assert perf.lower is None or perf.lower <= perf.upper * (1 + 1e-9)
        elif res.outcome == "stabilized":  # a certificate the plain design missed must stand on its own
            assert res.certificate is not None and res.certificate.verified


def test_nearly_unreachable_unstable_mode_reaches_the_riccati_optimum():
    F = np.array([[1.05, 0.0, 0.0], [0.3, 0.5, 0.1], [0.0, 0.2, 0.7]])
    G = np.array([[1e-3], [1.0], [0.5]])  # the unstable first state is barely reached by the input
    family = PlantFamily(F=F[None], G=G[None], sampling_period=0.1)
    P = scipy.linalg.solve_discrete_are(F, G, np.eye(3), np.eye(1))
    K = -np.linalg.solve(np.eye(1) + G.T @ P @ G, G.T @ P @ F)
    res = design(family, 1, objective="cost")
    assert res.outcome == "stabilized", res.message
    assert res.performance.upper == pytest.approx(np.trace(P), rel=1e-6)
    assert res.performance.upper >= np.trace(P) * (1 - 1e-9)
    assert np.max(np.abs(res.gains[0] - K)) <= 1e-5 * np.max(np.abs(K))


def test_a_failing_solver_is_a_verdict(monkeypatch):
    from solver.methods import performance

    def fail(*args, **kwargs):
        raise SolverFailed("injected failure", status="solver_error")

    monkeypatch.setattr(performance, "solve", fail)
    family = PlantFamily.paper_example()
    res = design(family, 2, objective="cost")
    # the performance SDP never answered: the plain design's gains, with their own re-checked bracket
    assert res.outcome == "stabilized", res.message
    assert "injected failure" in res.message
    assert res.performance is not None and res.performance.verified
    res = design(family, 2, objective="hinf", disturbance=np.ones((family.n_states, 1)))
    assert res.outcome == "stabilized" and res.performance.verified


@pytest.mark.parametrize("seed", range(10))
def test_one_mode_random_plants_reproduce_the_riccati_cost(seed):
    rng = np.random.default_rng(1000 + seed)
    n, m = int(rng.integers(2, 6)), int(rng.integers(1, 3))
    F = rng.normal(size=(n, n)) * 0.7
    G = rng.normal(size=(n, m))
    if seed % 2:  # states 1e-3 to 1e3 apart
        t = 10.0 ** rng.uniform(-3, 3, n)
        F, G = F / t[:, None] * t[None, :], G / t[:, None]
    P = scipy.linalg.solve_discrete_are(F, G, np.eye(n), np.eye(m))
    K = -np.linalg.solve(np.eye(m) + G.T @ P @ G, G.T @ P @ F)
    res = design(PlantFamily(F=F[None], G=G[None], sampling_period=0.1), 1, objective="cost")
    assert res.outcome == "stabilized", res.message
    assert res.performance.upper == pytest.approx(np.trace(P), rel=1e-6)
    assert res.performance.upper >= np.trace(P) * (1 - 1e-9)
    assert np.max(np.abs(res.gains[0] - K)) <= 1e-5 * np.max(np.abs(K))
