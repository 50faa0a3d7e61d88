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
from solver.ipm.rate_path import certified_rate, refuted_rate
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
    # only a rate below a given one: the same rate when it is, inf when it is not
    assert certified_rate(W, M, eta, below=lam * (1 + 1e-6)) == lam
    assert certified_rate(W, M, eta, below=lam * (1 - 1e-6)) == np.inf


@pytest.mark.parametrize("seed", range(5))
def test_refuted_rate_is_where_the_scaled_multipliers_turn_indefinite(seed):
    rng = np.random.default_rng(seed)
    n, S, lam = 3, 4, 0.7
    G = rng.standard_normal((S, 2 * n, 2 * n))
    X = G @ np.swapaxes(G, 1, 2) + 0.1 * np.eye(2 * n)
    eta = rng.integers(1, 4, S).astype(float)

    def min_eig(new):
        r = ((new / lam) ** eta)[:, None, None]
        Z = X.copy()
        Z[:, n:, :n] *= r
        Z[:, :n, n:] *= r
        return float(np.linalg.eigvalsh(Z)[:, 0].min())

    top = refuted_rate(X, eta, lam)
    assert lam < top < np.inf  # positive definite multipliers carry above their own rate
    assert min_eig(top * (1 - 1e-7)) > -1e-10
    assert min_eig(top * (1 + 1e-3)) < 0
    assert min_eig(0.5 * lam) > 0  # and to every rate below
    Z = X.copy()
    Z[0, :n, :n] = -np.eye(n)
    assert refuted_rate(Z, eta, lam) == lam  # a diagonal block not positive definite: no room


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


def _certifies_rate(fam, n_drop, gains, X, rate):
    """Independent float64 check of the decay claim (docs/design.md §3.1): ``X > 0`` and
    ``A^T X A - rate^(2 eta) X < 0`` for every interval closed loop ``A_{l,eta}``, built by stepping."""
    from .paper_data import interval_matrix_by_stepping

    if np.linalg.eigvalsh(X)[0] <= 0:
        return False
    for F, G in zip(fam.F, fam.G):
        for eta in range(1, n_drop + 1):
            A = interval_matrix_by_stepping(F, G, gains, eta)
            D = A.T @ X @ A - rate ** (2 * eta) * X
            if np.linalg.eigvalsh(0.5 * (D + D.T))[-1] >= 0:
                return False
    return True


_SHORT = [("paper", PlantFamily.paper_example(0.1), 3),
          ("near0", random_family(3, 2, 1, seed=0, spread=0.05), 3),
          ("near1", random_family(3, 2, 1, seed=1, spread=0.05), 3)]


@pytest.mark.parametrize("name,fam,n_drop", _SHORT, ids=[f[0] for f in _SHORT])
def test_a_path_stopped_early_hands_its_certified_rate_to_the_probes(monkeypatch, name, fam, n_drop):
    # the path stops at its step cap before its bracket closes (status max_iterations, no refuted rate needed):
    # its certified rate is re-checked and the probes start there (before: the path was discarded, the probes
    # started again from lambda = 1); the end result is the bisection's rate to the tolerance
    rate_search = sys.modules["solver.rate_search"]
    tol = 1e-3
    monkeypatch.setattr(rate_search, "PATH_MAX_ITER", 8)
    modes = ModeSet.from_family(fam, n_drop)
    res_p, br_p = _bracket(modes, "path", tol)
    first = res_p.rate_search[0]
    assert first.get("step") == "path" and first["outcome"] == "stabilized" and first["iterations"] <= 8
    assert 1.0 not in [e["decay_rate"] for e in res_p.rate_search]  # no probe restarted from lambda = 1
    assert res_p.outcome == "stabilized" and br_p["upper"] <= first["decay_rate"]
    assert br_p["upper"] - br_p["lower"] <= tol * br_p["upper"] * (1 + 1e-9)
    res_b, br_b = _bracket(modes, "bisection", tol)
    if br_b["lower_proven"] and br_p["lower_proven"]:
        assert abs(br_p["upper"] - br_b["upper"]) <= tol * max(br_p["upper"], br_b["upper"])
    assert _certifies_rate(fam, n_drop, res_p.gains, res_p.certificate.X, br_p["upper"] * (1 + 1e-9))


def test_a_path_stopped_early_keeps_its_gains_when_the_probes_run_out_of_time(monkeypatch):
    # the time limit forced deterministically: every probe after the path reports "time limit reached" (as the
    # runner does when its share runs out). Before: not_converged with no gains; now the path's certified gains
    rate_search = sys.modules["solver.rate_search"]
    monkeypatch.setattr(rate_search, "PATH_MAX_ITER", 8)
    out_of_time = type("OutOfTime", (), {"run": staticmethod(
        lambda modes, options: design_module._time_out(modes, "lmi", options, []))})
    monkeypatch.setitem(design_module.METHODS, "lmi", out_of_time)
    fam = PlantFamily.paper_example(0.1)
    modes = ModeSet.from_family(fam, 3)
    res = design_module._smallest_rate("lmi", modes, DesignOptions(time_limit=100.0), 1e-3, strategy="path")
    assert res.outcome == "not_converged" and "time limit" in res.message
    assert res.gains is not None and res.rate_search[0]["step"] == "path"
    rate = res.rate_search[0]["decay_rate"]
    assert res.decay_rate == rate < 1.0 and res.certificate.decay_rate == pytest.approx(rate)
    assert res.rate_bracket["upper"] == rate and res.rate_bracket["lower"] < rate
    assert _certifies_rate(fam, 3, res.gains, res.certificate.X, rate * (1 + 1e-9))


@pytest.mark.parametrize("seed", range(4))
def test_pruned_raise_cache_gives_the_same_multipliers(seed):
    # _raise uses the earlier iterate with the smallest lambda_a >= new; every new rate is <= the certified end:
    # the pruned cache gives the same multipliers as the full one, and holds one entry at or above the end
    from solver.ipm.rate_path import _prune_above, _raise

    rng = np.random.default_rng(seed)
    n, S = 2, 3
    eta = np.array([1.0, 2.0, 3.0])

    def psd(scale=1.0):
        A = rng.standard_normal((S, 2 * n, 2 * n))
        return scale * (A @ np.swapaxes(A, 1, 2)) + 1e-2 * np.eye(2 * n)

    lams = rng.uniform(0.3, 1.0, 12)
    above = [(lam, lam ** -eta, psd()) for lam in lams]
    hi = float(np.median(lams))
    kept = _prune_above(above, hi)
    assert sum(a[0] >= hi for a in kept) == 1 and len(kept) == sum(lams < hi) + 1
    assert min(a[0] for a in above if a[0] >= hi) in [a[0] for a in kept]
    for new in rng.uniform(0.2, hi, 6):
        c2 = new ** -eta
        Xb = psd()
        X2 = Xb.copy()
        X2[:, n:, :n] *= 3.0  # an upward move that leaves the cone
        X2[:, :n, n:] *= 3.0
        up = np.ones(S, dtype=bool)
        full = _raise(X2.copy(), Xb, up, new, c2, above, n)
        pruned = _raise(X2.copy(), Xb, up, new, c2, kept, n)
        np.testing.assert_array_equal(full, pruned)


def _margin_by_clarabel(modes, lam):
    """``max t`` of the congruent rate SDP at ``lam`` (docs/design.md §3.2) written out in cvxpy, on Clarabel."""
    import cvxpy as cp

    coef, active = modes.scheme_coef()
    S, n = modes.n_modes, modes.n_states
    J, m = coef.shape[1], coef.shape[3]
    W = cp.Variable((n, n), symmetric=True)
    Y = [cp.Variable((m, n)) for _ in range(J)]
    t = cp.Variable()
    cons = [cp.trace(W) == n]
    for s in range(S):
        c = lam ** (-float(modes.eta[s]))
        M = modes.free[s] @ W + sum(coef[s, j] @ Y[j] for j in range(J) if active[s, j])
        B = cp.bmat([[W, c * M.T], [c * M, W]])
        cons.append(0.5 * (B + B.T) - t * np.eye(2 * n) >> 0)
    cp.Problem(cp.Maximize(t), cons).solve(solver=cp.CLARABEL)
    return float(t.value)


def test_a_change_of_rate_that_keeps_the_slacks_converges_to_the_new_rates_optimum():
    # paper example: from lambda = 1 to 0.36 in one move (every c_s changes by far more than KEEP_FROM: the slacks
    # are kept and the new data's dual residual is carried by the Newton steps); the iteration then converges to the
    # optimum of the SDP at 0.36, the margin an independent cvxpy/Clarabel solve of the written-out SDP finds
    from solver.ipm import rate_path
    from solver.ipm.rate_path import follow_rate

    modes = ModeSet.from_family(PlantFamily.paper_example(0.1), 3)
    coef, active = modes.scheme_coef()
    assert float(np.max(np.abs((1 / 0.36) ** modes.eta - 1))) >= rate_path.KEEP_FROM
    calls = {"n": 0}

    def aim(lam, t, upper, rp, q, lo, hi, W, M):
        calls["n"] += 1
        return 0.36 if lam == 1.0 and calls["n"] >= 4 else None

    path = follow_rate(modes.free, coef, active, modes.eta, lambda lo, hi: False, aim, max_iter=40)
    lams = [r[1] for r in path.rates]
    k = lams.index(0.36)
    assert path.rates[k][2] == path.rates[k - 1][2]  # y kept: the margin t is not shifted by the move
    t_star = _margin_by_clarabel(modes, 0.36)
    _, lam, t, upper, rp = path.rates[-1]
    assert lam == 0.36 and rp < 1e-8
    assert t == pytest.approx(t_star, abs=1e-6) and upper == pytest.approx(t_star, abs=1e-6)


_path_search = sys.modules["solver.rate_search"].path_search


def _path_of(monkeypatch, modes, tol=1e-3, max_iter=None):
    """``_path_bracket``'s result and the path it re-checked (the path captured on its way)."""
    rate_search = sys.modules["solver.rate_search"]
    if max_iter is not None:
        monkeypatch.setattr(rate_search, "PATH_MAX_ITER", max_iter)
    seen = {}
    inner = rate_search.path_search

    def keep(*a, **k):
        seen["path"], his = inner(*a, **k)
        return seen["path"], his

    monkeypatch.setattr(rate_search, "path_search", keep)
    width = -np.log1p(-tol)
    out = design_module._path_bracket(modes, DesignOptions(), False, width,
                                      lambda lo, hi: rate_search.rate_done(lo, hi, tol, False))
    return out, seen["path"]


def _exact_negative_farkas(modes, Z, rate):
    """Own exact check (fractions) that multipliers ``Z`` (S, 2n, 2n) at ``rate`` contradict the design LMIs for
    n = 2: every ``Z_s`` positive semidefinite (Sylvester on the principal minors) and ``Q = sum_s (Z11 + Z22 +
    Z21^T free_s + free_s^T Z21)`` negative definite, ``free_s`` the exact interval product times
    ``fl(rate^-eta_s)``."""
    from fractions import Fraction
    from itertools import combinations

    def det(M):
        M = [row[:] for row in M]
        k, d = len(M), Fraction(1)
        for i in range(k):
            p = next((r for r in range(i, k) if M[r][i] != 0), None)
            if p is None:
                return Fraction(0)
            if p != i:
                M[i], M[p], d = M[p], M[i], -d
            d *= M[i][i]
            for r in range(i + 1, k):
                f = M[r][i] / M[i][i]
                M[r] = [a - f * b for a, b in zip(M[r], M[i])]
        return d

    n = modes.n_states
    assert n == 2
    Q = [[Fraction(0)] * n for _ in range(n)]
    for s, seq in enumerate(modes.plants):
        Zs = [[Fraction(float(x)) for x in row] for row in 0.5 * (Z[s] + Z[s].T)]
        for k in range(1, 2 * n + 1):  # positive semidefinite: every principal minor >= 0
            for idx in combinations(range(2 * n), k):
                assert det([[Zs[i][j] for j in idx] for i in idx]) >= 0
        P = [[Fraction(int(i == j)) for j in range(n)] for i in range(n)]
        for p in seq:
            Fp = [[Fraction(float(x)) for x in row] for row in modes.F[p]]
            P = [[sum(Fp[i][k] * P[k][j] for k in range(n)) for j in range(n)] for i in range(n)]
        c = Fraction(float(rate ** -float(modes.eta[s])))
        for i in range(n):
            for j in range(n):
                Q[i][j] += Zs[i][j] + Zs[n + i][n + j] + c * sum(
                    Zs[n + k][i] * P[k][j] + P[k][i] * Zs[n + k][j] for k in range(n))
    return Q[0][0] < 0 and det([[-x for x in row] for row in Q]) > 0


def test_the_path_refutes_up_to_the_scaled_multipliers_rate(monkeypatch):
    # paper example: the refuting iterate's multipliers, their off-diagonal blocks scaled (refuted_rate), give the
    # lower end above that iterate's own rate; the scaled multipliers are re-checked here in exact arithmetic
    # (positive semidefinite, the adjoint on W negative definite), and the bracket holds the bisection's rate
    from solver.ipm.rate_path import REFUTE_SHARE

    modes = ModeSet.from_family(PlantFamily.paper_example(0.1), 3)
    out, path = _path_of(monkeypatch, modes)
    own, t, upper = path.lo_at
    assert upper < 0 and own < path.lo and out["lo"] == path.lo and out["lo_proof"] == "infeasible"
    assert path.lo <= refuted_rate(path.duals, modes.eta.astype(float), path.lo) * (1 + 1e-12)
    eta = modes.eta.astype(float)
    assert any(it_lam == own and path.lo == pytest.approx(own * (top / own) ** REFUTE_SHARE, rel=1e-12)
               for _, it_lam, top in path.refutes)
    assert _exact_negative_farkas(modes, path.duals, path.lo)
    # the multipliers at the iterate's own rate (scaled back) have the same dual bound <C, X>
    r = ((own / path.lo) ** eta)[:, None, None]
    back = path.duals.copy()
    back[:, 2:, :2] *= r
    back[:, :2, 2:] *= r
    assert np.linalg.eigvalsh(back)[:, 0].min() > 0
    res_b, br_b = _bracket(modes, "bisection")
    assert path.lo <= br_b["upper"] and out["hi"] - path.lo <= 1e-3 * out["hi"]


@pytest.mark.parametrize("name,fam,n_drop", _SHORT, ids=[f[0] for f in _SHORT])
def test_the_probes_after_a_stopped_path_use_the_certifying_iterates_model(monkeypatch, name, fam, n_drop):
    # the path stopped at 8 steps: the probes' first model is the iterate's own (its rate, its margin t, its
    # multipliers), rebased to the certified end; before, it was the re-check's (margin ~0 at hi: Newton root
    # within the tolerance of hi, and the first probe was always "close")
    from solver.rate_search import model_root, rate_done

    modes = ModeSet.from_family(fam, n_drop)
    out, path = _path_of(monkeypatch, modes, max_iter=8)
    hi, model = out["hi"], out["model"]
    lam0, t0 = path.hi_at
    coef, active = modes.scheme_coef()
    # own reference: m(lambda) = t0 + sum_b q_b ((lam0 / lambda)^eta_b - 1), q_b = 2 c_b <X21_b, M_b> at lam0
    M = modes.free @ path.W + np.einsum("sjnm,jmk->snk", coef * active[:, :, None, None], path.Y)
    n = modes.n_states
    q = 2 * lam0 ** -modes.eta * np.einsum("bij,bij->b", path.X_hi[:, n:, :n], M)
    for lam in (0.5 * hi, 0.9 * hi, hi, min(1.0, 1.1 * hi)):
        ref = t0 + np.sum(q * ((lam0 / lam) ** modes.eta - 1))
        got = model[0] + np.sum(model[1] * ((hi / lam) ** model[2] - 1))
        assert got == pytest.approx(ref, rel=1e-9, abs=1e-12)
    root = model_root(model, hi, 1e-12, hi)
    assert root is None or not rate_done(root, hi, 1e-3, False)
    monkeypatch.setattr(sys.modules["solver.rate_search"], "path_search", _path_search)
    res_p, _ = _bracket(modes, "path")
    assert res_p.rate_search[0]["step"] == "path" and res_p.rate_search[1]["step"] != "close"
