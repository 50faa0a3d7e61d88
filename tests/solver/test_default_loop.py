"""The default design gives a usable loop (issue 22, item 3): its certified settling time is within 2x of the
fastest certified design's, and the settling figures it reports hold on simulated runs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solver import PlantFamily, design, simulate
from solver.result import certified_settling, rate_in_time

from .cartpole import cartpole


def _random_family(seed):
    rng = np.random.default_rng(seed)
    F = [np.eye(3) + 0.15 * rng.standard_normal((3, 3)) for _ in range(2)]
    G = [rng.standard_normal((3, 1)) for _ in range(2)]
    return PlantFamily(F=F, G=G, sampling_period=0.05)


@pytest.mark.parametrize("fam", [cartpole(), PlantFamily.paper_example(0.1), _random_family(0), _random_family(7)],
                         ids=["cartpole", "paper", "random0", "random7"])
def test_default_settles_within_twice_the_fastest_certified_loop(fam):
    default = design(fam, n_drop=3)
    fastest = design(fam, n_drop=3, decay_rate="max")
    plain = design(fam, n_drop=3, decay_rate=None)
    assert default.outcome == fastest.outcome == plain.outcome == "stabilized"
    assert default.certificate.verified and default.certificate.decay_rate == default.decay_rate
    # the rate promise alone (samples per e-fold), and the certified 2 % settling time
    assert math.log(fastest.decay_rate) / math.log(default.decay_rate) <= 2
    assert default.settling["samples"] <= 2 * fastest.settling["samples"]
    assert plain.settling is None and plain.decay_rate is None  # None keeps meaning plain stability


def test_certified_settling_bounds_every_simulated_run():
    """Monte Carlo over seeded loss/jump sequences: at packet instants past the certified settling time the state
    is within 2 % of its initial norm (the bound is worst case over every allowed sequence)."""
    fam = cartpole()
    res = design(fam, n_drop=3)
    k = res.settling["samples"]
    rng = np.random.default_rng(0)
    for seed in range(20):
        x0 = rng.standard_normal(4)
        run = simulate(fam, res.gains, 3, x0=x0, steps=k + 50, seed=seed)
        starts = run.interval_start[run.interval_start >= k]
        norms = np.linalg.norm(run.state[starts], axis=1)
        assert np.all(norms <= 0.02 * np.linalg.norm(x0) * (1 + 1e-9)), seed
        assert run.settling_samples() is not None and run.settling_samples() <= k + 3 - 1


def test_rates_in_time_units_closed_forms():
    lam, h = 0.9, 0.1
    out = rate_in_time(lam, h)
    assert out["decay_factor_per_second"] == pytest.approx(0.9**10)  # a factor per second
    assert out["exponential_rate"] == pytest.approx(-math.log(0.9) / 0.1)  # a rate in 1/s
    assert out["time_constant"] == pytest.approx(0.1 / -math.log(0.9))
    # e-fold per time constant: lam^(tau / h) = 1/e
    assert lam ** (out["time_constant"] / h) == pytest.approx(math.exp(-1))
    s = certified_settling(lam, 4.0, h)
    # sqrt(kappa) lam^k <= 0.02 first at k = ceil(ln(0.01) / ln(0.9)) = 44
    assert s["samples"] == 44 and s["seconds"] == pytest.approx(4.4)
    assert 2 * 0.9**44 <= 0.02 < 2 * 0.9**43


def test_a_bisection_step_the_solver_fails_is_no_proof_and_no_crash(monkeypatch):
    """A rate step whose solver fails (SolverFailed) is recorded and bisected above, never taken as a proof."""
    import importlib

    from solver import SolverFailed

    design_module = importlib.import_module("solver.design")
    lmi = design_module.METHODS["lmi"]
    real = lmi.run

    def flaky(modes, options):
        if options.decay_rate is not None and options.decay_rate < 0.99:
            raise SolverFailed("injected: IPM ended with status 'max_iterations'")
        return real(modes, options)

    monkeypatch.setattr(lmi, "run", flaky)
    monkeypatch.setattr(design_module, "RATE_SEARCH", "model")  # the probes' search (the path runs no lmi.run)
    res = design(cartpole(), n_drop=3, decay_rate="max")
    assert res.outcome == "stabilized" and res.decay_rate >= 0.99 and res.certificate.verified
    failed = [step for step in res.rate_search if step["outcome"] == "solver_failed"]
    assert failed and all("injected" in step["message"] for step in failed)
    assert res.rate_bracket["lower_proven"] is False
    auto = design(cartpole(), n_drop=3)
    assert auto.outcome == "stabilized" and auto.certificate.verified


def test_the_default_bisection_ends_when_only_rate_one_certifies(monkeypatch):
    """Regression: with nothing certified below lambda = 1 the settling bisection used to creep towards 1 forever."""
    import importlib

    from solver import SolverFailed

    lmi = importlib.import_module("solver.design").METHODS["lmi"]
    real = lmi.run

    def only_one(modes, options):
        if options.decay_rate is not None and options.decay_rate < 1.0:
            raise SolverFailed("injected")
        return real(modes, options)

    monkeypatch.setattr(lmi, "run", only_one)
    monkeypatch.setattr(importlib.import_module("solver.design"), "RATE_SEARCH", "model")  # every probe by lmi.run
    res = design(PlantFamily.paper_example(0.1), n_drop=3)
    assert res.outcome == "stabilized" and res.decay_rate == 1.0 and res.settling is None
    assert 5 < len(res.rate_search) < 40 and res.rate_bracket["lower"] > 1 - 2e-9


@pytest.mark.parametrize("u_max", [5.0, 2.0])
def test_input_limits_with_the_default_rate_still_give_a_settling_loop(u_max):
    """Issue 33, item 10: with u_max the default asked for no rate, and the largest ellipsoid won: the CTMS two-pole
    pendulum got a cart-position gain of 0.000, a spectral radius 0.9998 per sample (the cart travelled 42 m) and
    settling=None at 5 N, "not_converged" at 2 N.  Now: a certified rate, its settling time, the limits from x0."""
    from .textbook import pendulum

    fam, x0 = pendulum(), np.array([0.0, 0.0, 0.1, 0.0])
    res = design(fam, 4, u_max=[u_max], x0=x0)
    assert res.outcome == "stabilized" and res.certificate.verified
    assert res.decay_rate is not None and res.decay_rate < 1 and res.certificate.decay_rate == res.decay_rate
    assert res.settling is not None and res.settling["seconds"] < 10.0
    assert float(x0 @ res.invariant_set @ x0) <= 1.0
    # the limits on the set, in closed form: max over x' X x <= 1 of |k x| is sqrt(k X^-1 k')
    Xi = np.linalg.inv(res.invariant_set)
    assert max(float(np.sqrt(k @ Xi @ k)) for k in res.gains[:, 0, :]) <= u_max * (1 + 1e-9)
    # not faster than the default loop without limits (whose rate the limits do not allow here), and it says why
    free = design(fam, 4)
    assert res.decay_rate >= free.decay_rate and "the limits do not hold at the default loop's rate" in res.message
    # Monte Carlo over seeded loss and jump sequences: inputs within u_max, settled within the certified time
    k = res.settling["samples"]
    for seed in range(10):
        run = simulate(fam, res.gains, 4, x0=x0, steps=k + 50, seed=seed)
        assert np.max(np.abs(run.input)) <= u_max * (1 + 1e-9), seed
        starts = run.interval_start[run.interval_start >= k]
        assert np.all(np.linalg.norm(run.state[starts], axis=1) <= 0.02 * np.linalg.norm(x0) * (1 + 1e-9)), seed
        assert np.max(np.abs(run.state[:, 0])) < 0.5  # the cart stays within half a metre (42 m before)
