"""The rate-following interior-point path (solver/ipm/rate_path.py, docs/design.md §3.2.2).

References: the closed-form certified rate of an iterate against the blocks' eigenvalues, and the path's
re-checked bracket against the bisection's (``strategy="bisection"``) on the paper's example and on seeded
random families (feasible, infeasible, badly scaled).
"""

import sys

import numpy as np
import pytest

from bench.cases import random_family
from solver import PlantFamily
from solver.ipm.rate_path import certified_rate
from solver.methods.common import DesignOptions
from solver.network import ModeSet

design_module = sys.modules["solver.design"]


def _blocks_min_eig(W, M, eta, lam):
    c = lam ** (-eta)
    top = np.concatenate([np.broadcast_to(W, M.shape), np.swapaxes(c[:, None, None] * M, 1, 2)], axis=2)
    bot = np.concatenate([c[:, None, None] * M, np.broadcast_to(W, M.shape)], axis=2)
    return float(np.linalg.eigvalsh(np.concatenate([top, bot], axis=1))[:, 0].min())


@pytest.mark.parametrize("seed", range(5))
def test_certified_rate_is_where_the_blocks_turn_indefinite(seed):
    rng = np.random.default_rng(seed)
    n, S = 4, 5
    A = rng.standard_normal((n, n))
    W = A @ A.T + 0.5 * np.eye(n)
    M = 0.3 * rng.standard_normal((S, n, n))
    eta = rng.integers(1, 4, S).astype(float)
    lam = certified_rate(W, M, eta)
    assert 0 < lam < np.inf
    assert _blocks_min_eig(W, M, eta, lam * (1 + 1e-6)) > -1e-12
    assert _blocks_min_eig(W, M, eta, lam * (1 - 1e-3)) < 0
    assert certified_rate(-W, M, eta) == np.inf  # W not positive definite: no rate


def _bracket(modes, strategy, tol=1e-3):
    res = design_module._smallest_rate("lmi", modes, DesignOptions(), tol, strategy=strategy)
    return res, res.rate_bracket


def _families():
    fams = [("paper", PlantFamily.paper_example(0.1), 3)]
    for seed in range(12):  # near a nominal plant: mostly feasible
        fams.append((f"near{seed}", random_family(3, 2, 1, seed=seed, spread=0.05), 3))
    for seed in range(4):  # scattered modes: infeasible at every rate for most seeds
        fams.append((f"far{seed}", random_family(3, 3, 1, seed=seed, spread=1.0), 2))
    for seed in range(4):  # badly scaled: states in units 1e-3 .. 1e3 apart
        fam = random_family(3, 2, 1, seed=100 + seed, spread=0.05)
        T = np.diag([1e-3, 1.0, 1e3])
        Ti = np.linalg.inv(T)
        fams.append((f"scaled{seed}", PlantFamily([Ti @ F @ T for F in fam.F], [Ti @ G for G in fam.G]), 3))
    return fams


def test_path_certifies_the_bisections_rate():
    tol = 1e-3
    by_path = 0
    for name, fam, n_drop in _families():
        modes = ModeSet.from_family(fam, n_drop)
        res_b, br_b = _bracket(modes, "bisection", tol)
        res_p, br_p = _bracket(modes, "path", tol)
        assert res_p.outcome == res_b.outcome, name
        if res_b.outcome != "stabilized":
            continue
        by_path += any(e.get("step") == "path" for e in res_p.rate_search)
        # both brackets are re-checked: a certified upper end, a proven lower end (Farkas) within the tolerance
        for br in (br_b, br_p):
            assert br["upper"] - br["lower"] <= tol * br["upper"] * (1 + 1e-9), name
        if br_b["lower_proven"] and br_p["lower_proven"]:  # both contain the smallest certifiable rate
            assert br_p["lower"] <= br_b["upper"] and br_b["lower"] <= br_p["upper"], name
            assert abs(br_p["upper"] - br_b["upper"]) <= tol * max(br_p["upper"], br_b["upper"]), name
        assert res_p.certificate is not None and res_p.certificate.decay_rate == pytest.approx(br_p["upper"])
    assert by_path >= 10  # the path itself closed most brackets (not the fallback)


def test_an_upward_change_of_rate_keeps_the_primal_residual():
    # paper example: down from 1 to 0.3 (below its best rate 0.3374: refuted there), then up to 0.36; the
    # multipliers at 0.36 combine the refuted ones with an earlier iterate's from above, so their primal residual
    # (re-computed by the interior-point method on the new data) is the one they had before the move
    from solver.ipm.rate_path import follow_rate

    modes = ModeSet.from_family(PlantFamily.paper_example(0.1), 3)
    coef, active = modes.scheme_coef()
    calls = {"n": 0}

    def aim(lam, t, upper, rp, q, lo, hi, W, M):
        calls["n"] += 1
        if lam == 1.0 and calls["n"] >= 6:
            return 0.3
        if lam == 0.3 and lo >= 0.3:
            return 0.36
        return None

    path = follow_rate(modes.free, coef, active, modes.eta, lambda lo, hi: False, aim, max_iter=60)
    lams = [r[1] for r in path.rates]
    assert 0.3 <= path.lo < 0.3374 and 0.36 in lams
    k = lams.index(0.36)
    rp_before, rp_after = path.rates[k - 1][4], path.rates[k][4]
    assert rp_before < 1e-8 and rp_after < 1e-8
    assert any(r[1] == 0.36 and r[2] > 0 for r in path.rates[k:])  # and the path goes on to certify 0.36
