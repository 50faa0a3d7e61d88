"""The best-rate search (solver/rate_search.py): vs the old bisection, its solve count, the IPM warm start."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from solver import PlantFamily, design
from solver.ipm import IPMOptions, solve_lmi
from solver.ipm.algorithm import WarmStart
from solver.methods import lmi
from solver.methods.common import congruent_scale
from solver.network import ModeSet
from solver.rate_search import margin_model, model_root


DESIGN = sys.modules["solver.design"]


def _both(monkeypatch, family, n_drop, rate, **kw):
    out = {}
    for strategy in ("model", "bisection"):
        monkeypatch.setattr(DESIGN, "RATE_SEARCH", strategy)
        # ("auto" has its own switch: without it both runs were the model search)
        monkeypatch.setattr(DESIGN, "AUTO_RATE_SEARCH", strategy)
        out[strategy] = design(family, n_drop, decay_rate=rate, **kw)
    return out["model"], out["bisection"]


def _families():
    fams = [(PlantFamily.paper_example(0.1), 3), (PlantFamily.paper_example(0.05), 2)]
    for seed in range(48):
        rng = np.random.default_rng(seed)
        n, r, m = int(rng.integers(2, 4)), int(rng.integers(1, 3)), 1
        fams.append((random_family(n, r, m, seed=seed, spread=0.3), int(rng.integers(1, 3))))
    return fams


def random_family(n, r, m, seed, spread):
    """r plant modes scattered around one random nominal plant, each unstable."""
    rng = np.random.default_rng(1000 + seed)
    F0, G0 = rng.standard_normal((n, n)), rng.standard_normal((n, m))
    Fs, Gs = [], []
    for _ in range(r):
        F = F0 + spread * rng.standard_normal((n, n))
        F *= rng.uniform(1.0, 1.3) / np.max(np.abs(np.linalg.eigvals(F)))
        Fs.append(F)
        Gs.append(G0 + spread * rng.standard_normal((n, m)))
    return PlantFamily(F=Fs, G=Gs)


def test_max_rate_equals_bisection_on_50_families(monkeypatch):
    """Same outcome; both rates certified, within rate_tol of each other; never a proof the other contradicts."""
    tol = 1e-3
    compared = differ = 0
    for family, n_drop in _families():
        new, old = _both(monkeypatch, family, n_drop, "max", rate_tol=tol)
        assert new.outcome == old.outcome, (family, n_drop)
        if new.outcome != "stabilized":
            continue
        compared += 1
        if abs(new.decay_rate - old.decay_rate) > tol * old.decay_rate:
            # only where the slower search stopped at a step without a verdict (a solver failure or no proof
            # near the boundary) or at a "marginal" Farkas end (it excludes only designs of some margin): its lower
            # end is not proven, the other may certify a faster rate (the bisection's full solves, whose gains are
            # certified at the rate on their own where W^-1 misses the re-check, docs/design.md §3.2)
            slow = new if new.decay_rate > old.decay_rate else old
            assert not slow.rate_bracket["lower_proven"]
            differ += slow is new
        assert new.certificate.verified and new.certificate.decay_rate == new.decay_rate
        br = new.rate_bracket
        assert br["upper"] - br["lower"] <= tol * br["upper"]
        # a proven lower end of one search cannot lie above the other's certified rate
        if br["lower_proven"]:
            assert br["lower"] < old.decay_rate
        if old.rate_bracket["lower_proven"]:
            assert old.rate_bracket["lower"] < new.decay_rate
    # (the bisection's full solves fail more often at small rates, where c_s = lambda^-eta is large: there the
    # model search, whose probes stop at the margin's sign, certifies faster rates; it is slower in few cases)
    assert compared >= 20 and differ <= compared // 10


def test_auto_matches_bisection_to_its_settling_tolerance(monkeypatch):
    for family, n_drop in _families()[:16]:
        new, old = _both(monkeypatch, family, n_drop, "auto")
        assert new.outcome == old.outcome
        if new.outcome != "stabilized" or new.rate_bracket is None or "fastest_certified" not in new.rate_bracket:
            continue
        f_new, f_old = new.rate_bracket["fastest_certified"], old.rate_bracket["fastest_certified"]
        # both fastest rates lie in [lambda*, lambda*^(1/1.1)] (settling within 10 %)
        ratio = np.log(f_new) / np.log(f_old)
        if not 1 / 1.1 - 1e-9 <= ratio <= 1.1 + 1e-9:  # as for "max": only past a lower end not proven
            # (a step without a verdict, or a "marginal" Farkas end: it excludes only designs of some margin; seed
            # 10: the bisection's marginal end 0.0723, the model search certified 0.0702)
            slow = new if f_new > f_old else old
            assert not slow.rate_bracket["lower_proven"]
        assert new.certificate.verified


def test_paper_example_rate(monkeypatch):
    new, old = _both(monkeypatch, PlantFamily.paper_example(0.1), 3, "max")
    assert new.outcome == old.outcome == "stabilized"
    assert abs(new.decay_rate - old.decay_rate) <= 1e-3 * old.decay_rate
    assert all("step" in e for e in new.rate_search[1:])


def test_solve_count_counts_every_sdp(monkeypatch):
    calls = []
    real = lmi.solve_sdp

    def counting(*args, **kw):
        calls.append(1)
        return real(*args, **kw)

    monkeypatch.setattr(lmi, "solve_sdp", counting)
    fam = PlantFamily.paper_example(0.1)
    for rate in ("max", "auto", 0.6):
        calls.clear()
        res = design(fam, 3, decay_rate=rate)
        # with a rate no fixed-gain LMI runs: the design SDPs only, and the rate-following path's Newton steps in
        # SDP-equivalents (docs/design.md §3.2.2)
        path = sum(e.get("solves", 0) for e in res.rate_search or [])
        assert path == 0 or rate != 0.6
        assert res.solve_count == len(calls) + path
        assert res.to_dict()["solve_count"] == res.solve_count
    calls.clear()
    res = design(fam, 3, decay_rate=None)
    assert res.solve_count >= len(calls) == 1


def _lmi_data(family, n_drop, rate):
    modes = ModeSet.from_family(family, n_drop)
    _, active = modes.scheme_coef()
    v = lmi.plant_values(modes, congruent_scale(modes, rate))
    S, n, m, J = modes.n_modes, modes.n_states, modes.n_inputs, modes.n_free_gains
    return modes, v["free"].reshape(S, n, n), v["coef"].reshape(S, J, n, m), active


@pytest.mark.parametrize("seed", range(6))
def test_warm_start_reaches_the_cold_optimum(seed):
    family = random_family(3, 2, 1, seed=seed, spread=0.3)
    _, f1, c1, act = _lmi_data(family, 2, 1.0)
    _, f2, c2, _ = _lmi_data(family, 2, 0.8)
    first = solve_lmi(f1, c1, act)
    cold = solve_lmi(f2, c2, act)
    for shift, blend in ((1e-2, 0.1), (1e-1, 0.5), (1.0, 1.0)):
        warm = solve_lmi(f2, c2, act, start=WarmStart([first.W, first.Y], first.duals, shift, blend))
        assert warm.status in ("optimal", "inaccurate") and cold.status in ("optimal", "inaccurate")
        assert abs(warm.t - cold.t) <= 1e-6 * (1 + abs(cold.t))
        # the attained value is the blocks' smallest eigenvalue at the returned point (feasible iterates)
        A = f2 @ warm.W + np.einsum("sjnm,jmk->snk", c2 * act[:, :, None, None], warm.Y)
        blocks = np.block([[np.broadcast_to(warm.W, A.shape), np.swapaxes(A, 1, 2)],
                           [A, np.broadcast_to(warm.W, A.shape)]])
        assert np.linalg.eigvalsh(blocks).min() >= warm.t - 1e-7
    # from its own optimum, the same problem: the same value
    again = solve_lmi(f2, c2, act, start=WarmStart([cold.W, cold.Y], cold.duals))
    assert abs(again.t - cold.t) <= 1e-6 * (1 + abs(cold.t))


def test_warm_start_needs_the_max_t_form():
    from solver.ipm.model import BlockLMI, MatrixVariable

    P = MatrixVariable("P", (1, 1), 1, [(np.ones((1, 1, 1)), None, 1.0)])
    prob = BlockLMI(C=np.ones((1, 1, 1)), variables=[P], V0=[np.zeros((1, 1))], objective=np.ones(1))
    from solver.ipm import solve_block_lmi

    with pytest.raises(ValueError):
        solve_block_lmi(prob, IPMOptions(), WarmStart([np.zeros((1, 1))]))


@pytest.mark.parametrize("rate", [1.0, 0.7])
def test_model_slope_is_the_finite_difference(rate):
    """The envelope theorem's slope from the multipliers against a central difference of two more solves."""
    family = PlantFamily.paper_example(0.1)
    modes, f, c, act = _lmi_data(family, 3, rate)
    sol = solve_lmi(f, c, act, options=IPMOptions(gap_tol=1e-11, feas_tol=1e-11))
    sdp = lmi.DesignSdpSolution(t=sol.t, W=sol.W, Y=sol.Y, S=None, duals=sol.duals, info=None)
    t0, q, eta = margin_model(modes, sdp, rate)
    slope = float(np.sum(-eta * q)) / rate  # d/dlambda of t0 + sum q ((rate/lambda)^eta - 1)
    h = 1e-4
    ts = []
    for lam in (rate - h, rate + h):
        _, f2, c2, _ = _lmi_data(family, 3, lam)
        ts.append(solve_lmi(f2, c2, act, options=IPMOptions(gap_tol=1e-11, feas_tol=1e-11)).t)
    fd = (ts[1] - ts[0]) / (2 * h)
    assert abs(slope - fd) <= 1e-3 * abs(fd) + 1e-6
    # the model's root lies between the bracket's ends it is asked for, and the model is monotone there
    root = model_root((t0, q, eta), rate, 0.05, rate)
    if t0 > 0:
        assert root is not None and 0.05 < root < rate


class _Undecided(Exception):
    """The reference's solve settled no sign (the family is left out)."""


def _cold_margin(family, n_drop, rate):
    """``t*`` of the congruent rate SDP at ``rate``: a cold solve to the IPM's default tolerances (no warm
    start, no early stop), in the user's coordinates: its attained ``t`` (every block is ``>= t I`` at its W, Y)."""
    _, f, c, act = _lmi_data(family, n_drop, rate)
    sol = solve_lmi(f, c, act)
    if sol.status in ("optimal", "inaccurate") or sol.t > 0:
        return sol.t
    if sol.upper < -1e-3 and sol.primal_residual < 1e-5:
        return sol.upper  # stopped early far below the best rate (c_s = lambda^-eta large): a clear sign
    raise _Undecided


def _cold_bisection(family, n_drop, tol):
    """The best rate by a plain bisection on the sign of ``t*(lambda)`` (cold full solves), to ``tol``
    relative: ``(a, b)`` with ``t*(a) <= 0 < t*(b)`` (a = 0 when every rate tried is feasible), or None when
    lambda = 1 is not."""
    if _cold_margin(family, n_drop, 1.0) <= 0:
        return None
    a, b = 0.0, 1.0
    while b - a > tol * b:
        mid = 0.5 * (a + b)
        if _cold_margin(family, n_drop, mid) > 0:
            b = mid
        else:
            a = mid
    return a, b


def test_max_rate_equals_a_cold_bisection():
    """``decay_rate="max"`` (the default search: warm sign-only probes, model steps, float64 re-checks and
    Farkas proofs) against a plain cold bisection written here: the paper's example and 30 small random
    families, to rate_tol."""
    tol = 1e-3
    fams = [(PlantFamily.paper_example(0.1), 3)]
    for seed in range(30):  # two or three plant modes: one-mode plants have best rates near 0 (deadbeat)
        rng = np.random.default_rng(500 + seed)
        n, r = int(rng.integers(2, 4)), int(rng.integers(2, 4))
        fams.append((random_family(n, r, 1, seed=500 + seed, spread=0.3), int(rng.integers(1, 3))))
    compared = 0
    for family, n_drop in fams:
        try:
            ref = _cold_bisection(family, n_drop, tol)
        except _Undecided:
            continue
        res = design(family, n_drop, decay_rate="max", rate_tol=tol)
        if ref is None or res.outcome != "stabilized":
            continue
        a, b = ref
        rate = res.decay_rate
        assert res.certificate.verified and res.certificate.decay_rate == rate
        # a certified rate is never one the reference's solver finds infeasible (beyond its rounding)
        assert rate >= a * (1 - 1e-6), (n_drop, rate, ref)
        if res.rate_bracket["lower_proven"]:
            # both brackets hold the best rate and are within tol: their upper ends agree to about tol
            assert abs(rate - b) <= 1.05 * tol * b, (n_drop, rate, ref)
            # the proven lower end of the search is refuted by the reference too
            assert res.rate_bracket["lower"] <= b
            compared += 1
    assert compared >= 20


def _settling(tol):
    """``done`` and the measure of "auto"'s settling-time rule (as in solver.design._smallest_rate)."""
    def done(lo, hi):
        return -np.log(max(lo, 1e-4)) <= (1 + tol) * -np.log(min(hi, 1 - 1e-9))

    def measure(lam):
        return -np.log(-np.log(min(max(lam, 1e-4), 1 - 1e-9)))

    return done, measure


def test_model_step_next_to_one_is_taken_in_the_settling_measure():
    """A root next to lambda = 1 (large n): the Newton root, not the midpoint of [1e-4, 1]."""
    from solver.rate_search import next_rate

    done, measure = _settling(0.1)
    model = (0.0015, np.array([-0.3]), np.array([1.0]))  # m = 0.0015 - 0.3 (1 / lambda - 1): root 1 / 1.005
    rate, how = next_rate(1e-4, 1.0, None, 0.0015, model, done, lambda a, b: 0.5 * (a + b), measure=measure)
    assert how == "newton" and abs(rate - 1 / 1.005) < 1e-9
    # in lambda itself the root lies in the outer 2 % of [1e-4, 1]: the bisection's midpoint
    rate, how = next_rate(1e-4, 1.0, None, 0.0015, model, done, lambda a, b: 0.5 * (a + b))
    assert how == "bisect"


def test_close_high_ends_the_bracket():
    from solver.rate_search import _closing_high, next_rate

    done, measure = _settling(0.1)
    lo, hi = 0.98718, 0.9907
    h = _closing_high(lo, hi, done)
    assert lo < h < hi and done(lo, h) and not done(lo, h * (1 + 1e-7))
    # a refuted lo with a model whose Newton root lies just above that end: the end itself is tried
    eta = np.array([1.0])
    q = np.array([-0.01])
    t_lo = -0.01 * (1 - lo / (h * (1 + 1e-5)))  # m_lo(lambda) = t_lo - 0.01 (lo / lambda - 1): root h (1 + 1e-5)
    rate, how = next_rate(lo, hi, t_lo, 1e-4, None, done, lambda a, b: 0.5 * (a + b), from_above=False,
                          measure=measure, model_lo=(t_lo, q, eta))
    assert how == "close_high" and rate == h


@pytest.mark.parametrize("settling", [False, True])
def test_rate_measure_closed_forms_and_its_shift(settling):
    # the tolerance's coordinate, once for the probes and the path: closed forms, the clamp at MIN_RATE and
    # 1 - 1e-9 (settling), -inf at 0 (ln), and rate_shift its inverse
    from solver.rate_search import MIN_RATE, rate_measure, rate_shift

    for lam in (1e-6, 1e-3, 0.2, 0.9, 0.999):
        ref = -np.log(-np.log(max(lam, MIN_RATE))) if settling else np.log(lam)
        assert rate_measure(lam, settling) == pytest.approx(ref, rel=1e-14)
        for du in (-0.3, 0.01, 0.2):
            back = rate_shift(lam, du, settling)
            if settling and not MIN_RATE <= back <= 1 - 1e-9:
                continue  # clamped there
            assert rate_measure(back, settling) == pytest.approx(
                rate_measure(lam, settling) + du, rel=1e-12, abs=1e-12)
    assert rate_measure(1.0, settling) == pytest.approx(-np.log(-np.log(1 - 1e-9)) if settling else 0.0)
    low = rate_measure(0.0, settling)
    assert low == (-np.log(-np.log(MIN_RATE)) if settling else -np.inf)
    assert rate_shift(0.0, 0.1, settling) == (pytest.approx(rate_shift(MIN_RATE, 0.1, True)) if settling else 0.0)


@pytest.mark.parametrize("seed", range(3))
def test_carried_multipliers_keep_the_residual_and_the_dual_bound(seed):
    """Multipliers carried down in rate (off-diagonal blocks scaled, docs/design.md §3.2.1) give the new rate's
    problem the old rate's ``A^*(X)`` and ``<C, X>`` (its own operators as the reference), stay positive
    semidefinite, and so start a warm solve primal feasible where the uncarried ones do not."""
    from solver.ipm.design_blocks import lmi_problem
    from solver.rate_search import carry_multipliers

    family = random_family(3, 2, 1, seed=seed, spread=0.3)
    modes, f1, c1, act = _lmi_data(family, 2, 0.9)
    _, f2, c2, _ = _lmi_data(family, 2, 0.7)
    first = solve_lmi(f1, c1, act)
    X = first.duals
    carried = carry_multipliers(X, modes.eta, 0.9, 0.7)
    p1, p2 = lmi_problem(f1, c1, act), lmi_problem(f2, c2, act)
    ref = p1.adj(X)
    np.testing.assert_allclose(p2.adj(carried), ref, rtol=0, atol=1e-12 * (1 + np.abs(ref).max()))
    assert np.sum(p2.C * carried) == pytest.approx(np.sum(p1.C * X), rel=1e-12, abs=1e-14)
    assert np.linalg.eigvalsh(carried).min() >= -1e-12
    assert np.abs(p2.adj(X) - ref).max() > 1e-6  # the uncarried ones: the change of data's residual
    # up in rate the scaling can leave the cone: then None (the caller keeps the multipliers)
    up = carry_multipliers(X, modes.eta, 0.9, 0.99)
    assert up is None or np.linalg.eigvalsh(up).min() >= -1e-9
    # the warm start's first iterate: primal feasible with the carried multipliers, not with the old ones
    opts = IPMOptions(max_iter=0)
    start = [first.W, first.Y]
    fed = solve_lmi(f2, c2, act, options=opts, start=WarmStart(start, carried, 1e-2, 0.5))
    old = solve_lmi(f2, c2, act, options=opts, start=WarmStart(start, X, 1e-2, 0.5))
    assert fed.primal_residual < 1e-9 < 1e-5 < old.primal_residual


def test_auto_final_design_keeps_95_percent_of_the_optimal_margin(monkeypatch):
    """"auto"'s final design stops at a margin within 5 % of the SDP's optimum at its rate (docs/design.md §3.5):
    against the optimum from cvxpy/Clarabel at the same rate and coordinates."""
    from .test_rate_path import _margin_by_clarabel

    seen = []
    real = DESIGN.METHODS["lmi"].run

    def spy(modes, options):
        res = real(modes, options)
        seen.append((modes, options, res))
        return res

    monkeypatch.setitem(DESIGN.METHODS, "lmi", type("Spy", (), {"run": staticmethod(spy)}))
    for fam, n_drop in ((PlantFamily.paper_example(0.1), 3), (random_family(3, 2, 1, seed=3, spread=0.3), 2)):
        seen.clear()
        res = design(fam, n_drop)
        assert res.outcome == "stabilized" and res.certificate.verified
        modes, options, final = seen[-1]
        assert options.decay_rate == res.decay_rate and options.sign_only == DESIGN.FINAL_MARGIN_SHARE
        best = _margin_by_clarabel(modes, res.decay_rate)
        assert DESIGN.FINAL_MARGIN_SHARE * best - 1e-6 <= final.sdp.t <= best + 1e-6


def test_auto_bracket_on_the_bench_family_matches_bisection(monkeypatch):
    """The bench's n = 8 row (docs/design.md §3.2.2, "What bounds `"auto"`"): with the carried warm starts, the
    margin share and the 95 % final stop, "auto"'s fastest certified rate lies within its settling tolerance of the
    bisection's, each proven lower end below the other's certified rate, and the final design is certified at
    lambda*^(1/1.5)."""
    from bench.cases import random_family as bench_family

    fam = bench_family(8, 5, 2, seed=0, spread=0.02)
    new, old = _both(monkeypatch, fam, 10, "auto")
    assert new.outcome == old.outcome == "stabilized" and new.certificate.verified
    f_new, f_old = new.rate_bracket["fastest_certified"], old.rate_bracket["fastest_certified"]
    assert 1 / 1.1 - 1e-9 <= np.log(f_new) / np.log(f_old) <= 1.1 + 1e-9
    for a, b in ((new, old), (old, new)):
        if a.rate_bracket["lower_proven"]:
            assert a.rate_bracket["lower"] < b.rate_bracket["fastest_certified"]
    assert new.rate_bracket["lower_proven"]
    assert np.log(new.rate_bracket["lower"]) / np.log(f_new) <= 1.1 + 1e-9
    assert new.decay_rate == pytest.approx(f_new ** (1 / 1.5), rel=1e-12)


def _outsider_family(seed: int, bad: bool) -> tuple[PlantFamily, int]:
    """The generator of issue 29's rate probes: n 2-5, m 1-2, r 1-3, optionally states scaled by 1e-3..1e3."""
    rng = np.random.default_rng(90000 + seed)
    n, m, r = int(rng.integers(2, 6)), int(rng.integers(1, 3)), int(rng.integers(1, 4))
    F = rng.normal(size=(r, n, n)) * rng.uniform(0.4, 0.8)
    G = rng.normal(size=(r, n, m))
    if bad:
        t = 10.0 ** rng.uniform(-3, 3, n)
        F = F / t[None, :, None] * t[None, None, :]
        G = G / t[None, :, None] * 10.0 ** rng.uniform(-2, 2, m)[None, None, :]
    return PlantFamily(F=F, G=G, sampling_period=0.1), int(rng.integers(1, 5))


def _positive_definite_exactly(M) -> bool:
    """Sylvester's criterion on a symmetric Fraction matrix (every leading principal minor > 0)."""
    M = [row[:] for row in M]
    for c in range(len(M)):  # Gaussian elimination without pivoting: the pivots are the minors' ratios
        if M[c][c] <= 0:
            return False
        for r in range(c + 1, len(M)):
            f = M[r][c] / M[c][c]
            M[r] = [x - f * y for x, y in zip(M[r], M[c])]
    return True


@pytest.mark.parametrize("seed, bad", [(18, False), (1, True), (26, False)])
def test_a_rate_just_above_the_best_certified_one_is_stabilized(seed, bad):
    # issue 29's probes: at 1.001 x the rate "max" certified, the fixed-rate design answered "not_converged" (the SDP's
    # W^-1 missed the float64 re-check); the gains' own certificate at the rate decides (docs/design.md §3.2).  One
    # loop (Lyapunov), one plant with n_drop = 2 and two plants (fixed-gain LMI); re-checked here in rationals on the
    # interval maps rebuilt from F, G and the returned gains (every interval length, every plant)
    from fractions import Fraction

    family, n_drop = _outsider_family(seed, bad)
    best = design(family, n_drop, decay_rate="max")
    assert best.outcome == "stabilized"
    rate = best.rate_bracket["upper"] * 1.001
    res = design(family, n_drop, decay_rate=rate)
    assert res.outcome == "stabilized", res.message
    assert res.certificate.kind == "common_quadratic"

    def q(M):
        return [[Fraction(float(v)) for v in row] for row in np.atleast_2d(M)]

    def mul(A, B):
        return [[sum(A[i][k] * B[k][j] for k in range(len(B))) for j in range(len(B[0]))] for i in range(len(A))]

    X = res.certificate.X
    if res.scaling is not None and res.scaling.get("certificate") == "scaled":  # x = T x~, T diagonal powers of two
        t = np.asarray(res.scaling["state"])
        X = X / t[:, None] / t[None, :]  # the user's coordinates, exactly
    X, lam, n = q(X), Fraction(rate), family.n_states
    assert _positive_definite_exactly(X)
    for plant in range(family.F.shape[0]):
        F, G = q(family.F[plant]), q(family.G[plant])
        M = [[Fraction(int(i == j)) for j in range(n)] for i in range(n)]
        for eta in range(1, n_drop + 1):  # M_eta = F M_{eta-1} + G K_eta, the buffer's input K_eta x(i_m)
            GK = mul(G, q(res.gains[eta - 1]))
            M = [[a + b for a, b in zip(r1, r2)] for r1, r2 in zip(mul(F, M), GK)]
            AXA = mul(mul([list(col) for col in zip(*M)], X), M)
            decrease = [[lam ** (2 * eta) * X[i][j] - AXA[i][j] for j in range(n)] for i in range(n)]
            assert _positive_definite_exactly(decrease), (plant, eta)


@pytest.mark.parametrize("rate", [0.31, 0.32])
def test_a_probe_refuted_in_the_solve_carries_the_farkas_proof_of_its_own_multipliers(rate):
    # "auto"'s probes (DesignOptions.early_refute) run the Farkas re-check inside the solve and stop at the first
    # iterate whose multipliers pass it, before the sign rule's lower bound within half of the dual bound (paper
    # example: one iteration fewer at these rates). The verdict must be that re-check's on the returned
    # multipliers, and the rate infeasible by a second solver (Clarabel's optimal margin t* < 0)
    from solver.certificates import check_farkas, interval_data
    from solver.methods.common import DesignOptions

    modes = ModeSet.from_family(PlantFamily.paper_example(0.1), 3)
    runs = [lmi.run(modes, DesignOptions(decay_rate=rate, sign_only=True, early_refute=er, solver="IPM"))
            for er in (False, True)]
    assert [r.outcome for r in runs] == ["infeasible", "infeasible"]
    assert runs[1].sdp.info.iterations < runs[0].sdp.info.iterations
    cert = runs[1].certificate
    assert cert.kind == "farkas" and cert.verified and cert.any_margin
    np.testing.assert_array_equal(cert.multipliers, runs[1].sdp.duals)
    free, dfree, coef, dcoef = interval_data(modes.F, modes.G, modes.plants, modes.gain_map,
                                             scale=congruent_scale(modes, rate))
    again = check_farkas(runs[1].sdp.duals, free, coef, dfree, dcoef, rate, margin=1e-6 / modes.n_states)
    assert again.verified and again.delta == cert.delta
    clarabel = lmi.solve_sdp(modes, congruent_scale(modes, rate), "CLARABEL")
    assert clarabel.t < 0
