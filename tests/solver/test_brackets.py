"""Certified cost, H-infinity and input-limit designs and brackets, against independent references.

References: scipy's DARE (LQR), python-control's H-infinity norm and a direct search over static gains,
step-by-step simulation of the buffer (written here, not the library's lifting), seeded random patterns.
"""

import itertools
from fractions import Fraction

import control
import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

from solver import InvalidInput, PlantFamily, analyze, design
from solver.lifting import lift_modes
from solver.network import ModeSet
from solver.brackets import bracket, check_cost

from .paper_data import EQ23_GAINS

Q2, R1 = np.eye(2), np.eye(1)
E_MOTOR = [[1.0], [0.0]]


def unstable_one_mode():
    """A controllable, open-loop unstable 3-state plant with two inputs (seeded)."""
    rng = np.random.default_rng(7)
    F = rng.normal(size=(3, 3))
    F = 1.3 * F / np.max(np.abs(np.linalg.eigvals(F)))
    return F, rng.normal(size=(3, 2))


def unstable_family():
    """Two unstable 2-state modes, one input: needs real gains (the paper's motor is open-loop stable)."""
    F = [[[1.1, 0.3], [0.0, 0.95]], [[1.05, 0.2], [0.1, 1.0]]]
    G = [[[0.2], [1.0]], [[0.1], [0.8]]]
    return PlantFamily(F=F, G=G)


def lqr(F, G, Q, R):
    P = scipy.linalg.solve_discrete_are(F, G, Q, R)
    return P, -np.linalg.solve(R + G.T @ P @ G, G.T @ P @ F)


# ------------------------------------------------------------------------------ lifted data
def step_interval(F, G, E, C, D, Q, R, K, seq, x, w):
    """One interval sample by sample: returns x at its end, z per sample, the stage cost."""
    xi, z, cost = x.copy(), [], 0.0
    for t, l in enumerate(seq):
        u = K[t] @ x
        z.append(C[l] @ xi + D[l] @ u)
        cost += xi @ Q @ xi + u @ R @ u
        xi = F[l] @ xi + G[l] @ u + E[l] @ w[t]
    return xi, np.concatenate(z), cost


@pytest.mark.parametrize("switching", ["per_interval", "per_sample"])
@pytest.mark.parametrize("scheme", ["predictive", "hold"])
def test_lifted_interval_matches_step_by_step(switching, scheme):
    rng = np.random.default_rng(3)
    r, n, m, pw, pz, N = 2, 3, 2, 2, 2, 3
    F, G = rng.normal(size=(r, n, n)), rng.normal(size=(r, n, m))
    E, C, D = rng.normal(size=(r, n, pw)), rng.normal(size=(r, pz, n)), rng.normal(size=(r, pz, m))
    Q = rng.normal(size=(n, n))
    Q = Q @ Q.T
    R = np.diag([1.0, 2.0])
    modes = ModeSet.from_family(PlantFamily(F=F, G=G), N, plant_switching=switching, scheme=scheme)
    lifted = lift_modes(modes, (Q, R), list(E), (list(C), list(D)))
    K = modes.expand(rng.normal(size=(modes.n_free_gains, m, n)))
    data = lifted.numeric(K)
    for s, seq in enumerate(modes.plants):
        x, w = rng.normal(size=n), rng.normal(size=(len(seq), pw))
        x_end, z, _ = step_interval(F, G, E, C, D, Q, R, K, seq, x, w)
        _, _, cost = step_interval(F, G, E, C, D, Q, R, K, seq, x, 0 * w)  # the stage cost is for w = 0
        d = data[s]
        np.testing.assert_allclose(d["A"] @ x + d["B"] @ w.ravel(), x_end, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(d["C"] @ x + d["D"] @ w.ravel(), z, rtol=1e-12, atol=1e-12)
        assert x @ d["S"] @ x == pytest.approx(cost, rel=1e-12)
        np.testing.assert_allclose(d["A"], modes.closed_loops(K)[s], rtol=1e-13, atol=1e-13)


# -------------------------------------------------------------------------------------- LQR
@pytest.mark.parametrize("plant", ["motor", "unstable"])
def test_one_mode_no_drop_is_lqr(plant):
    if plant == "motor":
        fam = PlantFamily.paper_example(0.1)
        F, G = fam.F[0], fam.G[0]
        Q, R = Q2, R1
    else:
        F, G = unstable_one_mode()
        Q, R = np.diag([1.0, 2.0, 0.5]), np.array([[1.0, 0.2], [0.2, 0.5]])
    P, K = lqr(F, G, Q, R)
    res = design(PlantFamily(F=[F], G=[G]), 1, objective="cost", weights=(Q, R))
    assert res.outcome == "stabilized" and res.objective == "cost"
    perf = res.performance
    assert perf.kind == "cost" and perf.verified
    assert perf.upper == pytest.approx(np.trace(P), rel=1e-6)
    assert perf.upper >= np.trace(P) * (1 - 1e-9)  # an upper bound of the optimum
    assert perf.lower == pytest.approx(np.trace(P), rel=1e-6)
    np.testing.assert_allclose(res.gains[0], K, rtol=1e-6, atol=1e-6 * np.abs(K).max())
    assert perf.witness == [(0, 1)]
    x0 = np.array([1.0, -2.0, 0.5])[:F.shape[0]]
    res = design(PlantFamily(F=[F], G=[G]), 1, objective="cost", weights=(Q, R), x0=x0)
    assert res.performance.upper == pytest.approx(x0 @ P @ x0, rel=1e-6)
    assert res.performance.upper >= x0 @ P @ x0 * (1 - 1e-9)
    # only x0' P x0 is optimal: the tie-break stage (least trace P among them) makes P, and the gains, unique
    np.testing.assert_allclose(res.gains[0], K, rtol=1e-6, atol=1e-6 * np.abs(K).max())


def _random_family(seed):
    rng = np.random.default_rng(seed)
    F = [rng.standard_normal((3, 3)) * 0.6 for _ in range(2)]
    G = [rng.standard_normal((3, 1)) for _ in range(2)]
    return PlantFamily(F=F, G=G), 2, rng.standard_normal(3)


def _tie_break_point(fam, n_drop, x0, solver):
    """The cost-from-x0 design's final (W, Y, gamma) through both stages, on unbalanced lifted data."""
    from solver.methods import performance as perf
    from solver.methods.common import RunClock

    modes = ModeSet.from_family(fam, n_drop)
    lifted, x0, _ = perf.prepare(modes, "lmi", "cost", None, x0, None, None, None, None)
    clock = RunClock()
    clock.cached = False
    info, W, Y, extra = perf._propose(lifted, "cost", x0, None, None, solver, clock, None)
    return info, W, float(extra["gamma"]), x0


@pytest.mark.parametrize("case", ["paper", 0, 1])
def test_ipm_tie_break_reaches_the_clarabel_bracket(case):
    """Issue 29: the x0 tie-break (least trace P among the x0-optimal designs) runs on the IPM under "AUTO"
    (its capped problem through the Lagrangian); Clarabel's capped problem is the second solver it is compared with."""
    if case == "paper":
        fam, n_drop, x0 = PlantFamily.paper_example(0.1), 3, np.array([-3.0, 2.0])
    else:
        fam, n_drop, x0 = _random_family(case)
    auto = design(fam, n_drop, objective="cost", x0=x0)
    ref = design(fam, n_drop, objective="cost", x0=x0, solver="CLARABEL")
    assert auto.outcome == ref.outcome == "stabilized" and auto.solver == "IPM"
    a, r = auto.performance, ref.performance
    assert a.verified and r.verified and a.lower <= a.upper and r.lower <= r.upper
    assert a.certificate_upper == pytest.approx(r.certificate_upper, rel=1e-6)  # the SDP optimum, like with like
    if case == "paper":
        assert a.lower == pytest.approx(r.lower, rel=1e-6)
    # the tie-break itself: both meet the cap of the x0 optimum and reach the same least trace P.  (On the random
    # families a gain entry moves by ~1e-3 along the optimal face for a 1e-9 rise of x0' P x0, so the witnessed
    # lower end of the bracket differs by up to ~1e-3 between the two solvers; the upper ends agree.)
    ia, Wa, ga, xs = _tie_break_point(fam, n_drop, x0, "AUTO")
    ir, Wr, gr, _ = _tie_break_point(fam, n_drop, x0, "CLARABEL")
    assert ia.solver == "IPM" and ir.solver == "CLARABEL"
    Pa, Pr = np.linalg.inv(Wa), np.linalg.inv(Wr)
    best = min(ga, gr)
    # Clarabel meets the cap on W to its feasibility tolerance (1e-8); through inv(W) that is up to ~6e-8 relative on
    # x0' P x0 here, and where in that range it lands depends on the machine's BLAS kernels
    assert xs @ Pa @ xs <= best * (1 + 3e-9) and xs @ Pr @ xs <= best * (1 + 2e-7)
    assert np.trace(Pa) == pytest.approx(np.trace(Pr), rel=2e-5)


# ---------------------------------------------------------------------------------- H-infinity
def hinf_norm(F, G, K, E, C, D, points=20001):
    """H-infinity norm of the closed loop by a dense frequency sweep refined by a bounded scalar search.

    (python-control's ``norm(sys, "inf")`` was tried first: near-deadbeat optima put a pole near z = 0,
    where its Hamiltonian test lost 3e-4 here, and it refuses a pole at 0 without slycot.)
    """
    Acl, Ccl = F + G @ K, C + D @ K

    def gain(w):
        z = np.exp(1j * np.atleast_1d(w))[:, None, None]
        H = Ccl @ np.linalg.solve(z * np.eye(F.shape[0]) - Acl, np.broadcast_to(E, (z.shape[0],) + E.shape))
        return np.linalg.svd(H, compute_uv=False)[:, 0] if np.ndim(w) else float(np.linalg.norm(H[0], 2))

    grid = np.linspace(0, np.pi, points)
    values = gain(grid)
    i = int(np.argmax(values))
    opt = scipy.optimize.minimize_scalar(lambda w: -gain(w), bounds=(grid[max(i - 1, 0)], grid[min(i + 1, points - 1)]),
                                         method="bounded", options={"xatol": 1e-13})
    return max(-opt.fun, values[i])


def test_hinf_reference_agrees_with_python_control_away_from_deadbeat():
    F, G, E = np.array([[1.1, 0.2], [0.0, 0.9]]), np.array([[0.0], [1.0]]), np.array([[1.0], [0.5]])
    K = np.array([[-0.6, -0.5]])
    C, D = np.vstack([np.eye(2), np.zeros((1, 2))]), np.array([[0.0], [0.0], [1.0]])
    B = np.hstack([E, np.zeros((2, 2))])  # python-control's discrete norm wants as many inputs as outputs
    ref = control.norm(control.ss(F + G @ K, B, C + D @ K, np.zeros((3, 3)), True), "inf")
    assert hinf_norm(F, G, K, E, C, D) == pytest.approx(ref, rel=1e-6)


def test_one_mode_no_drop_hinf_is_the_optimal_static_level():
    F, G = np.array([[1.1, 0.2], [0.0, 0.9]]), np.array([[0.0], [1.0]])
    E = np.array([[1.0], [0.5]])
    C, D = np.vstack([np.eye(2), np.zeros((1, 2))]), np.array([[0.0], [0.0], [1.0]])
    res = design(PlantFamily(F=[F], G=[G]), 1, objective="hinf", disturbance=E, output=(C, D))
    assert res.outcome == "stabilized"
    perf = res.performance
    assert perf.kind == "hinf" and perf.verified
    level = hinf_norm(F, G, res.gains[0], E, C, D)
    assert perf.upper == pytest.approx(level, rel=1e-4)
    assert perf.lower == pytest.approx(level, rel=1e-4)
    assert perf.lower <= perf.upper * (1 + 1e-9)
    # the optimal static level by a direct search over K (nonconvex, from several starts): never below the
    # LMI's level (the bounded-real LMI is exact for one LTI mode), and it gets there
    found = np.inf
    for k0 in (res.gains[0].ravel(), [-1.0, -1.0], [-3.0, -2.0], [-4.5, -1.0]):
        def level_of(k):
            if np.max(np.abs(np.linalg.eigvals(F + G @ k.reshape(1, 2)))) >= 1:
                return 1e6
            return hinf_norm(F, G, k.reshape(1, 2), E, C, D, points=2001)
        opt = scipy.optimize.minimize(level_of, np.array(k0, float), method="Nelder-Mead",
                                      options={"xatol": 1e-9, "fatol": 1e-11, "maxiter": 4000})
        found = min(found, opt.fun)
    assert found >= perf.upper * (1 - 1e-6)
    assert found == pytest.approx(perf.upper, rel=1e-4)


# ----------------------------------------------------------------------------- simulation
def run_pattern(fam, K, x0, intervals):
    """Cost of a finite sequence of intervals [(plant, eta), ...] by stepping the buffer sample by sample."""
    x, cost = np.array(x0, float), 0.0
    for plant, eta in intervals:
        xm = x.copy()
        for t in range(eta):
            u = K[t] @ xm
            cost += x @ x + u @ u  # Q = I, R = I
            x = fam.F[plant] @ x + fam.G[plant] @ u
    return cost, x


def test_simulated_costs_stay_below_the_certificate_and_the_witness_reaches_the_lower_bound():
    fam = unstable_family()
    x0 = np.array([1.0, -1.0])
    N = 3
    res = design(fam, N, objective="cost", weights=(Q2, R1), x0=x0)
    assert res.outcome == "stabilized"
    perf = res.performance
    assert perf.verified and perf.lower <= perf.upper
    rng = np.random.default_rng(11)
    worst = 0.0
    for _ in range(300):
        seq = [(int(rng.integers(2)), int(rng.integers(1, N + 1))) for _ in range(400)]
        cost, x = run_pattern(fam, res.gains, x0, seq)
        assert np.linalg.norm(x) < 1e-8  # the tail is negligible: the cost is (almost) the whole sum
        worst = max(worst, cost)
    assert worst <= perf.upper
    lead, period = perf.witness[:perf.lead], perf.witness[perf.lead:]  # run once, then repeated
    cost, x = run_pattern(fam, res.gains, x0, lead + period * (2000 // len(period)))
    assert np.linalg.norm(x) < 1e-8
    assert cost == pytest.approx(perf.lower, rel=1e-9)


def _mp_run_cost(fam, K, Q, R, starts, intervals, tail, dps: int = 60):
    """The cost of ``intervals`` once, then ``tail`` repeated until the state is below 1e-45 of its start, from each
    start (summed), stepped sample by sample through the buffer in mpmath at ``dps`` digits with the float64 F, G,
    K, Q, R taken as exact: an independent reference of a witness's cost (the neglected rest is ~1e-90)."""
    import mpmath as mp

    with mp.workdps(dps):
        def m(X):
            return mp.matrix(np.atleast_2d(np.asarray(X, dtype=float)).tolist())

        F, G = [m(f) for f in fam.F], [m(g) for g in fam.G]
        Ks, Qm, Rm = [m(k) for k in K], m(Q), m(R)
        total = mp.mpf(0)
        for x0 in starts:
            x = m(np.asarray(x0, dtype=float).reshape(-1, 1))
            size0 = mp.norm(x)

            def run(x, seq):
                cost = mp.mpf(0)
                for plant, eta in seq:
                    xm = x
                    for t in range(eta):
                        u = Ks[t] * xm
                        cost += (x.T * Qm * x)[0] + (u.T * Rm * u)[0]
                        x = F[plant] * x + G[plant] * u
                return cost, x

            cost, x = run(x, intervals)
            total += cost
            for _ in range(100000):
                if mp.norm(x) < size0 * mp.mpf(10) ** -45:
                    break
                cost, x = run(x, tail)
                total += cost
            else:
                raise AssertionError("the tail did not settle")
        return total


@pytest.mark.parametrize("with_x0", [False, True], ids=["trace", "x0"])
def test_the_cost_witness_is_valued_exactly_below_its_60_digit_cost(with_x0):
    # the witness's cost (a prefix once, then a period forever), stepped sample by sample through the buffer at 60
    # digits, is at least the lower end and within 1e-12 of it: the exact evaluation (the prefix's stage costs in
    # integers, the period's cost from below by a Stein inequality checked exactly) is a proof, no float64 value
    import mpmath as mp

    fam = unstable_family()
    x0 = np.array([1.0, -1.0]) if with_x0 else None
    res = design(fam, 3, objective="cost", weights=(Q2, R1), x0=x0)
    perf = res.performance
    assert res.outcome == "stabilized" and perf.verified
    assert "witness cost evaluated exactly on the deployed loop" in perf.message, perf.message
    lead, period = perf.witness[:perf.lead], perf.witness[perf.lead:]
    ref = _mp_run_cost(fam, res.gains, Q2, R1, [x0] if with_x0 else list(np.eye(2)), lead, period)
    with mp.workdps(60):
        assert mp.mpf(Fraction(perf.lower).numerator) / Fraction(perf.lower).denominator <= ref
    assert perf.lower >= float(ref) * (1 - 1e-12) and perf.lower <= perf.upper


def test_a_cost_witness_too_long_to_value_exactly_keeps_its_float64_value_and_says_so(monkeypatch):
    from solver import brackets

    fam = unstable_family()
    exact = design(fam, 3, objective="cost", weights=(Q2, R1)).performance
    monkeypatch.setattr(brackets, "EXACT_PERIOD_MAX_WORK", 1)
    floated = design(fam, 3, objective="cost", weights=(Q2, R1)).performance
    assert "float64 witness, not a proof" in floated.message and "evaluated exactly" not in floated.message
    assert floated.lower == pytest.approx(exact.lower, rel=1e-12)


@pytest.mark.parametrize("with_x0", [False, True], ids=["trace", "x0"])
def test_a_switched_loop_near_the_boundary_is_bracketed_by_a_lookahead(with_x0):
    """Two plant modes near the stability boundary with a weak input (bench.ipm_check "boundary" seed 7033, n = 4,
    n_drop = 1): the common P bounds the trace cost at 521.5 and its prefix tree at 181.0 against a run of 120.70,
    since one quadratic form must bound every run from every initial state.  One matrix per sequence of the next L
    intervals (docs/design.md §8.4, "Look-ahead") closes the bracket.  Independent check, stepped sample by sample:
    for every sequence of 10 plant modes, the cost of those samples from each initial state plus the look-ahead's
    matrix of the next L modes at the state reached never exceeds the upper end (so neither does any run), and the
    witness costs the lower end."""
    from bench.ipm_check import draw_family

    fam, N, _ = draw_family(7033, max_n=4, max_lmi_rows=48)[:3]
    assert N == 1 and fam.n_modes == 2
    x0 = np.array([1.0, -0.5, 0.25, 2.0]) if with_x0 else None
    res = design(fam, N, objective="cost", decay_rate=None, x0=x0)
    assert res.outcome == "stabilized", res.message
    perf = res.performance
    assert perf.verified and "next" in perf.message and perf.lower <= perf.upper <= 1.01 * perf.lower
    assert perf.certificate_upper > 2 * perf.upper
    P = perf.mode_certificate
    L = int(round(np.log2(P.shape[0])))
    assert P.shape == (2 ** L, 4, 4) and L >= 2
    K = res.gains[0]
    A = [fam.F[p] + fam.G[p] @ K for p in range(2)]
    starts = [x0] if with_x0 else list(np.eye(4))
    T = 10
    for seq in itertools.product(range(2), repeat=T):
        cost, ends = 0.0, []
        for x in starts:
            for p in seq:
                u = K @ x
                cost += x @ x + u @ u  # Q = I, R = I
                x = A[p] @ x
            ends.append(x)
        for nxt in itertools.product(range(2), repeat=L):  # any continuation: its window's matrix bounds the rest
            index = int("".join(map(str, nxt)), 2)
            assert cost + sum(x @ P[index] @ x for x in ends) <= perf.upper * (1 + 1e-9)
    lead, period = perf.witness[:perf.lead], perf.witness[perf.lead:]
    total = 0.0
    for x in starts:
        cost, x = run_pattern(fam, res.gains, x, lead + period * (6000 // len(period)))
        assert np.linalg.norm(x) < 1e-8
        total += cost
    assert total == pytest.approx(perf.lower, rel=1e-9)


@pytest.mark.parametrize("with_x0", [False, True], ids=["trace", "x0"])
def test_the_prefix_tree_on_lookahead_matrices_closes_what_each_leaves_open(with_x0):
    """A two-mode loop near the stability boundary, n = 11 (bench.ipm_check "boundary" seed 7033): the common P
    bounds the cost 2.6-3x above the worst run, its prefix tree 7-11 % above, the look-ahead matrices alone more than
    1 % above; the tree valued with the look-ahead matrices (a node's continuations cost at most
    ``max_q <P_q, Sigma>``, docs/design.md §8.4, "Look-ahead") closes it to 2 %.  Independent check: every sequence of
    10 plant modes followed by either mode forever (its cost-to-go a discrete Lyapunov solution of that mode's loop)
    costs at most the upper end, which is at most the look-ahead matrices' own bound; the witness costs the lower."""
    from bench.ipm_check import draw_family

    fam, N, _ = draw_family(7033)[:3]
    n = fam.n_states
    assert N == 1 and fam.n_modes == 2 and n == 11
    x0 = np.random.default_rng(7033).standard_normal(n) if with_x0 else None
    res = design(fam, N, objective="cost", decay_rate=None, x0=x0)
    assert res.outcome == "stabilized", res.message
    perf = res.performance
    assert perf.verified and "prefix tree on one matrix per sequence of the next" in perf.message, perf.message
    assert perf.lower <= perf.upper <= 1.02 * perf.lower and perf.certificate_upper > 1.5 * perf.upper
    M = np.outer(x0, x0) if with_x0 else np.eye(n)
    assert perf.upper <= max(float(np.sum(P * M)) for P in perf.mode_certificate) * (1 + 1e-12)
    K = res.gains[0]
    A = [fam.F[p] + fam.G[p] @ K for p in range(2)]
    stage = np.eye(n) + K.T @ K  # Q = I, R = I
    to_go = [scipy.linalg.solve_discrete_lyapunov(a.T, stage) for a in A]
    starts = [x0] if with_x0 else list(np.eye(n))
    for seq in itertools.product(range(2), repeat=10):
        cost, ends = 0.0, []
        for x in starts:
            for p in seq:
                cost += x @ stage @ x
                x = A[p] @ x
            ends.append(x)
        for tail in to_go:
            assert cost + sum(x @ tail @ x for x in ends) <= perf.upper * (1 + 1e-9)
    lead, period = perf.witness[:perf.lead], perf.witness[perf.lead:]
    total = 0.0
    for x in starts:
        cost, x = run_pattern(fam, res.gains, x, lead + period * (20000 // len(period)))
        assert np.linalg.norm(x) < 1e-6 * max(1.0, float(np.linalg.norm(x0 if with_x0 else 1.0)))
        total += cost
    assert total == pytest.approx(perf.lower, rel=1e-7)


def test_the_lower_search_follows_tails_a_prefix_steers_to():
    """Four slowly contracting plants, n_drop = 5 (bench.ipm_check "boundary" seed 7159, n = 2: 20 interval modes),
    cost from x0: from x0 itself every plant-0 period is the costliest, yet one interval (0, 2) steers the state to
    where plant 1's (1, 1) repeated costs far more.  The search now also tries the one-interval periods costliest in
    their worst direction as tails and continuations (docs/design.md §8.4, "Prefix search"): its witness costs at least
    that run (stepped sample by sample, its tail by a discrete Lyapunov solution), which the tails best from x0 missed
    (52.8 against 82.9), and the witness simulated costs the lower end."""
    from bench.brackets_check import request
    from bench.ipm_check import draw_family

    fam, N, _ = draw_family(7159)[:3]
    assert (fam.n_states, fam.n_modes, N) == (2, 4, 5)
    x0 = request("cost (x0)", fam, np.random.default_rng(7159))["x0"]
    res = design(fam, N, objective="cost", decay_rate=None, x0=x0)
    perf = res.performance
    assert res.outcome == "stabilized" and perf.verified
    cost, x = run_pattern(fam, res.gains, x0, [(0, 2)])
    A1 = fam.F[1] + fam.G[1] @ res.gains[0]
    steered = cost + x @ scipy.linalg.solve_discrete_lyapunov(A1.T, np.eye(2) + res.gains[0].T @ res.gains[0]) @ x
    assert steered > 1.5 * 52.8
    assert steered <= perf.lower <= perf.upper
    lead, period = perf.witness[:perf.lead], perf.witness[perf.lead:]
    cost, x = run_pattern(fam, res.gains, x0, lead + period * (40000 // sum(e for _, e in period)))
    assert np.linalg.norm(x) < 1e-9 * np.linalg.norm(x0)
    assert cost == pytest.approx(perf.lower, rel=1e-7)


def test_simulated_l2_gain_stays_below_the_certificate():
    fam = unstable_family()
    E = np.array([[0.5], [1.0]])
    res = design(fam, 3, objective="hinf", disturbance=E)
    assert res.outcome == "stabilized" and res.performance.verified
    gamma = res.performance.upper
    rng = np.random.default_rng(5)
    for _ in range(100):
        x, z2, w2 = np.zeros(2), 0.0, 0.0
        for _ in range(60):
            plant, eta = int(rng.integers(2)), int(rng.integers(1, 4))
            xm = x.copy()
            for t in range(eta):
                u = res.gains[t] @ xm
                w = rng.normal(size=1) if rng.random() < 0.5 else np.zeros(1)
                z2 += x @ x + u @ u
                w2 += w @ w
                x = fam.F[plant] @ x + fam.G[plant] @ u + E @ w
        assert z2 <= gamma**2 * w2 * (1 + 1e-12)


# ---------------------------------------------------------------------------------- input limits
def boundary_points(X, count, rng):
    """Points with x' X x = 1."""
    v = rng.normal(size=(count, X.shape[0]))
    v /= np.linalg.norm(v, axis=1)[:, None]
    x = v @ np.linalg.inv(np.linalg.cholesky(X))  # x = L^-T v with X = L L'
    np.testing.assert_allclose(np.einsum("ij,jk,ik->i", x, X, x), 1.0, rtol=1e-10)
    return x


@pytest.mark.parametrize("kwargs", [{}, {"decay_rate": 0.97}, {"objective": "cost", "x0": [2.0, -1.0]}])
def test_inputs_stay_within_limits_from_the_invariant_set(kwargs):
    fam = unstable_family()
    u_max = 1.5
    res = design(fam, 3, u_max=[u_max], **kwargs)
    assert res.outcome == "stabilized", res.message
    X = res.invariant_set
    assert X is not None and np.all(np.linalg.eigvalsh(X) > 0)
    if "x0" in kwargs:
        x0 = np.array(kwargs["x0"])
        assert x0 @ X @ x0 <= 1
    rng = np.random.default_rng(2)
    biggest = 0.0
    for x0 in boundary_points(X, 200, rng):
        x = x0
        for _ in range(80):
            plant, eta = int(rng.integers(2)), int(rng.integers(1, 4))
            xm = x.copy()
            for t in range(eta):
                u = res.gains[t] @ xm
                biggest = max(biggest, float(np.max(np.abs(u))))
                x = fam.F[plant] @ x + fam.G[plant] @ u
    assert biggest <= u_max * (1 + 1e-9)
    assert biggest >= 0.5 * u_max  # the set is not needlessly small: some boundary point uses the limit


def test_input_limits_unreachable_x0_is_infeasible_with_a_proof_of_the_limits():
    from solver.limit_proofs import check_limits_farkas
    from solver.network import ModeSet

    fam = unstable_family()
    res = design(fam, 3, u_max=[0.1], x0=[100.0, 100.0])
    assert res.outcome == "infeasible" and res.certificate.kind == "farkas_limits", res.message
    assert res.invariant_set is None and res.gains is None
    again = check_limits_farkas(ModeSet.from_family(fam, 3), res.certificate.multipliers, [0.1], [100.0, 100.0],
                                res.certificate.decay_rate)
    assert again.verified and again.any_margin


def test_uncontrollable_family_is_infeasible_with_a_proof_for_every_objective():
    fam = PlantFamily(F=[np.diag([1.2, 0.5]), np.diag([1.1, 0.3])], G=[[[0.0], [1.0]], [[0.0], [2.0]]])
    for kwargs in ({"objective": "cost"}, {"objective": "hinf", "disturbance": [[1.0], [1.0]]},
                   {"u_max": [1.0]}):
        res = design(fam, 2, **kwargs)
        assert res.outcome == "infeasible" and res.certificate is not None and res.certificate.verified


# ---------------------------------------------------------------------------------- analyze / API
def test_analyze_brackets_for_the_paper_gains():
    fam = PlantFamily.paper_example(0.1)
    rep = analyze(fam, EQ23_GAINS, 3, weights=(Q2, R1), disturbance=E_MOTOR, bounds="none")
    for perf in (rep.cost, rep.hinf):
        assert perf.verified and 0 < perf.lower <= perf.upper
        assert perf.gap < 1e-3
        assert all(0 <= p < 3 and 1 <= eta <= 3 for p, eta in perf.witness)
    # the certificate itself passes an independent check of the cost inequality
    modes = ModeSet.from_family(fam, 3)
    data = lift_modes(modes, (Q2, R1)).numeric(np.asarray(EQ23_GAINS, float).reshape(3, 1, 2))
    assert check_cost(rep.cost.certificate, data)[0]
    # a design for the cost does at least as well as the paper's gains
    res = design(fam, 3, objective="cost", weights=(Q2, R1))
    assert res.performance.certificate_upper <= rep.cost.certificate_upper  # what the design minimizes


def test_unstable_gains_have_no_upper_bound_and_an_infinite_lower_one():
    fam = unstable_family()
    modes = ModeSet.from_family(fam, 2)
    perf = bracket(lift_modes(modes), np.zeros((2, 1, 2)), "cost")
    assert perf.upper is None and not perf.verified and perf.lower == np.inf
    assert "no certified upper bound" in perf.message


def test_default_design_is_unchanged_and_bad_inputs_name_their_field():
    fam = PlantFamily.paper_example(0.1)
    res = design(fam, 3)
    assert res.objective == "stability" and res.performance is None and res.invariant_set is None
    d = res.to_dict()
    assert d["performance"] is None and d["objective"] == "stability"
    cases = [
        (dict(objective="cost", weights=(np.eye(3), R1)), "weights"),
        (dict(objective="cost", weights=(-Q2, R1)), "weights"),
        (dict(objective="hinf"), "disturbance"),
        (dict(objective="cost", u_max=[1.0]), "x0"),
        (dict(u_max=[1.0, 2.0]), "u_max"),
        (dict(u_max=[-1.0]), "u_max"),
        (dict(objective="bogus"), "objective"),
        (dict(objective="cost", method="ccl"), "method"),
        (dict(weights=(Q2, R1)), "weights"),
        (dict(objective="hinf", disturbance=np.ones((3, 1))), "disturbance"),
    ]
    for kwargs, field in cases:
        with pytest.raises(InvalidInput) as err:
            design(fam, 3, **kwargs)
        assert err.value.field[0] == field, kwargs


def test_performance_to_dict_is_json():
    import json

    fam = PlantFamily.paper_example(0.1)
    res = design(fam, 2, objective="hinf", disturbance=E_MOTOR)
    d = json.loads(json.dumps(res.to_dict()))
    assert d["performance"]["kind"] == "hinf" and d["performance"]["verified"]
    assert d["performance"]["upper"] >= d["performance"]["lower"]
    assert isinstance(d["performance"]["witness"][0][1], int)


def test_mat_and_m_exports_carry_the_bracket_and_the_invariant_set(tmp_path):
    import scipy.io

    from solver.matlab import m_script, save_mat

    fam = PlantFamily.paper_example(0.1)
    res = design(fam, 2, objective="cost", x0=[-3, 2], u_max=[0.5])
    for result in (res, res.to_dict()):
        save_mat(tmp_path / "g.mat", result, fam)
        d = scipy.io.loadmat(tmp_path / "g.mat")
        assert str(d["perf_kind"][0]) == "cost"
        assert float(d["perf_upper"][0, 0]) == res.performance.upper
        np.testing.assert_array_equal(d["X_inv"], res.invariant_set)
        np.testing.assert_array_equal(d["P_perf"], res.performance.certificate)
    assert "X_inv = [" in m_script(res, fam) and "perf_upper = " in m_script(res, fam)


def test_trace_figure_draws_the_input_limit():
    from solver import simulate
    from solver.plotting import trace_figure

    fam = unstable_family()
    res = design(fam, 3, u_max=[1.5])
    X = res.invariant_set
    x0 = boundary_points(X, 1, np.random.default_rng(0))[0]
    tr = simulate(fam, res.gains, 3, x0=x0, steps=40, seed=1)
    assert np.max(np.abs(tr.input)) <= 1.5 * (1 + 1e-9)  # the library's own simulator agrees
    fig = trace_figure([tr], u_max=[1.5])
    inputs = next(ax for ax in fig.axes if ax.get_ylabel() == "input")
    lines = [line for line in inputs.get_lines() if line.get_linestyle() == "--"]
    assert sorted(float(line.get_ydata()[0]) for line in lines) == [-1.5, 1.5]


def interval_maps_by_stepping(fam, K, seq):
    """x(i_m + eta) and the interval cost matrix from x(i_m), by stepping the buffer on basis vectors (Q = R = I)."""
    n = fam.F.shape[1]
    A, L = np.zeros((n, n)), []
    for i in range(n):
        x = xm = np.eye(n)[i]
        rows = []
        for t, l in enumerate(seq):
            u = K[t] @ xm
            rows.append(np.concatenate([x, u]))
            x = fam.F[l] @ x + fam.G[l] @ u
        A[:, i] = x
        L.append(np.concatenate(rows))
    L = np.array(L).T  # stacked [x(t); u(t)] rows per unit initial state
    return A, L.T @ L


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("switching", ["per_interval", "per_sample"])
def test_random_families_cost_certificates_hold_by_independent_stepping(seed, switching):
    rng = np.random.default_rng(100 + seed)
    r, n, N = 2, 2, 2
    F = rng.normal(size=(r, n, n))
    F = F / np.max(np.abs(np.linalg.eigvals(F)), axis=1)[:, None, None] * rng.uniform(0.6, 1.3, size=(r, 1, 1))
    fam = PlantFamily(F=F, G=rng.normal(size=(r, n, 1)))
    res = design(fam, N, objective="cost", plant_switching=switching)
    if res.outcome == "infeasible":
        assert res.certificate is not None and res.certificate.verified
        return
    assert res.outcome == "stabilized", res.message
    perf = res.performance
    assert perf.verified and perf.lower <= perf.upper
    P = perf.certificate
    modes = ModeSet.from_family(fam, N, plant_switching=switching)
    for seq in modes.plants:
        A, S = interval_maps_by_stepping(fam, res.gains, seq)
        assert np.linalg.eigvalsh(A.T @ P @ A - P + S)[-1] <= 1e-12 * np.linalg.norm(P, 2)
    assert np.trace(P) == pytest.approx(perf.certificate_upper, rel=1e-12)
    assert perf.upper <= perf.certificate_upper  # the prefix tree may tighten the reported end, never loosen it


def test_no_certified_bracket_is_not_stabilized(monkeypatch):
    """A design whose gains re-check but whose bound does not certify answers "not_converged" with the gains and
    the reason: "stabilized" comes only with the bracket the objective asked for (single and network designs)."""
    import dataclasses

    from solver import Network
    from solver.methods import network_performance, performance as perf_mod

    def unverified(wrapped):
        def run(*args, **kwargs):
            out = wrapped(*args, **kwargs)
            return dataclasses.replace(out, verified=False, upper=float("inf"), certificate=None)
        return run

    fam = PlantFamily.paper_example(0.1)
    monkeypatch.setattr(perf_mod, "bracket", unverified(perf_mod.bracket))
    res = design(fam, 3, objective="cost")
    assert res.outcome == "not_converged" and res.gains is not None and "no certified cost bound" in res.message
    monkeypatch.setattr(network_performance, "bracket", unverified(network_performance.bracket))
    res = design(fam, network=Network.weakly_hard(1, 3, 3), objective="cost")
    assert res.outcome == "not_converged" and res.gains is not None and "no certified cost bound" in res.message


def test_a_certified_bound_names_what_certified_it_not_an_earlier_failure():
    """A candidate P that fails its re-check, then the fixed-gain LMI's P that passes: the message's reason for the
    certified level is the re-check that passed, not the first candidate's failure (docs/design.md §8.4)."""
    F, G = np.array([[1.1, 0.2], [0.0, 0.8]]), np.array([[1.0], [0.5]])
    fam = PlantFamily(F=F[None], G=G[None], sampling_period=0.1)
    E = np.ones((2, 1))
    gains = np.array([[[-0.8, -0.3]]])  # stabilizing: spectral radius of F + G K below 1
    assert np.max(np.abs(np.linalg.eigvals(F + G @ gains[0]))) < 1
    lifted = lift_modes(ModeSet.from_family(fam, 1), None, E, None)
    perf = bracket(lifted, gains, "hinf", P0=1e-6 * np.eye(2))  # A'PA - P + C'C >= C'C: not negative definite
    assert perf.verified
    certified = perf.message.split("; worst periodic pattern")[0]
    assert certified.startswith("l2 gain certified <= ")
    assert "not negative definite" not in certified and "fixed-gain LMI:" not in certified, perf.message


def test_invariance_of_a_far_from_normal_loop_is_decided_exactly_where_float64_cannot(monkeypatch):
    # A = T diag(1 - 1e-8, 0.5, 0.3) T^-1 with T spanning 1e3, X = T^-T T^-1: A'XA - X <= 0 holds with a margin of
    # 1e-8 in X's metric, far below the rounding of A'XA, which is relative to |A|'|X||A| (1e6 times |A'XA| here)
    import solver.brackets as brackets
    from fractions import Fraction

    rng = np.random.default_rng(0)
    T = np.eye(3) + 1e3 * np.triu(rng.standard_normal((3, 3)), 1)
    Ti = np.linalg.inv(T)
    A = T @ np.diag([1 - 1e-8, 0.5, 0.3]) @ Ti
    X = 0.5 * (Ti.T @ Ti + (Ti.T @ Ti).T)
    K = np.array([[[1.0, 0.0, 0.0]]])
    # the loop is A itself: F = A, G = 0 (the exact re-check rebuilds F + G K from them)
    plant = (A[None], np.zeros((1, 3, 1)), ((0,),))
    Xc, reason = brackets.check_invariant(X, A[None], K, np.array([1.0]), plant=plant)
    assert Xc is not None, reason
    # reference: the leading principal minors of Xc - A'XcA in exact rationals (Sylvester, on the float64 numbers)
    q = [[Fraction(float(v)) for v in row] for row in Xc]
    a = [[Fraction(float(v)) for v in row] for row in A]
    D = [[q[i][j] - sum(a[k][i] * q[k][l] * a[l][j] for k in range(3) for l in range(3)) for j in range(3)]
         for i in range(3)]
    assert D[0][0] >= 0 and D[0][0] * D[1][1] - D[0][1] * D[1][0] >= 0
    # (a semidefinite 3x3 needs every principal minor >= 0; the full determinant and the other 2x2 minors)
    det = (D[0][0] * (D[1][1] * D[2][2] - D[1][2] * D[2][1]) - D[0][1] * (D[1][0] * D[2][2] - D[1][2] * D[2][0])
           + D[0][2] * (D[1][0] * D[2][1] - D[1][1] * D[2][0]))
    assert det >= 0 and D[1][1] * D[2][2] - D[1][2] ** 2 >= 0 and D[0][0] * D[2][2] - D[0][2] ** 2 >= 0
    # float64 alone cannot decide it: without the exact re-check the set is not shown invariant
    monkeypatch.setattr(brackets, "EXACT_COST_MAX_N", 0)
    assert brackets.check_invariant(X, A[None], K, np.array([1.0]), plant=plant)[0] is None


def test_invariance_is_decided_on_the_deployed_loop_not_its_float64_rounding():
    # F + G K = [[0, 1 + 2^-60], [0, 0]] exactly, rounded to [[0, 1], [0, 0]]: X = I meets the rounded loop's
    # A'XA <= X with equality (float64 cannot decide it, the exact re-check on the rounding passed it), but the
    # deployed loop maps e2 to (1 + 2^-60) e1, outside {x'Xx <= 1} (checked here in fractions): refused
    from fractions import Fraction

    from solver.brackets import check_invariant

    F, G = np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[1.0], [0.0]])
    K = np.array([[[0.0, 2.0 ** -60]]])
    A = (F + G @ K[0])[None]
    assert A[0, 0, 1] == 1.0
    a01 = Fraction(1) + Fraction(0) + Fraction(float(G[0, 0])) * Fraction(float(K[0, 0, 1]))
    assert a01 ** 2 > 1  # the deployed loop leaves the unit ball along e2
    Xc, reason = check_invariant(np.eye(2), A, K, np.array([1.0]), plant=(F[None], G[None], ((0,),)))
    assert Xc is None and "not shown invariant" in reason
    # without the plant data the undecided mode is refused as before
    assert check_invariant(np.eye(2), A, K, np.array([1.0]))[0] is None


def test_a_certified_cost_bound_is_never_below_its_certificates_exact_value():
    # the reported number is trace P or x0' P x0 of the certified P, rounded upwards (a float64 sum may round down)
    from fractions import Fraction

    from solver.brackets import certify_cost

    below = 0
    for seed in range(30):
        rng = np.random.default_rng(seed)
        n = 4
        A = 0.3 * rng.standard_normal((n, n))
        S = np.eye(n) + 0.1 * np.diag(rng.uniform(size=n))
        P0 = scipy.linalg.solve_discrete_lyapunov(A.T, S) * (1 + 1e-6)
        x0 = rng.standard_normal(n) * np.array([1e-3, 1.0, 1e3, 1.0])
        for start in (None, x0):
            P, bound, _ = certify_cost(P0, [{"A": A, "S": S}], start)
            assert P is not None
            q = [[Fraction(float(v)) for v in row] for row in P]
            if start is None:
                exact = sum(q[i][i] for i in range(n))
            else:
                xq = [Fraction(float(v)) for v in start]
                exact = sum(xq[i] * q[i][j] * xq[j] for i in range(n) for j in range(n))
            assert Fraction(bound) >= exact
            below += Fraction(float(np.trace(P)) if start is None else float(start @ P @ start)) < exact
    assert below > 0  # the plain float64 value was below the exact one somewhere: the rounding matters


def test_cost_recheck_covers_deployed_loop_rounding():
    """n_drop = 2, G K nearly cancelling F: the float64 interval loop A_2 = F^2 + F G K_1 + G K_2 (0.255) is 1e-8
    off the deployed loop's (exact in the float64 F, G, K), which the relative allowance of the re-check does not
    cover: main certified 1.33717391e8 against the exact worst case 1.33717392e8 (docs/design.md §8.4, "Loop data").
    Reference: the exact worst-case cost of a scalar switched loop, max_s S_s / (1 - A_s^2), in Fractions."""
    from fractions import Fraction as Fr

    from solver.brackets import certify_cost

    F, G = np.array([[[1e4 + 1 / 3]]]), np.array([[[1.0]]])
    lifted = lift_modes(ModeSet.from_family(PlantFamily(F=F, G=G), 2))
    k1, k2 = -9999.833325087962, -4999.993744890774
    data = lifted.numeric(np.array([[[k1]], [[k2]]]))
    f, g, K1, K2 = Fr(F[0, 0, 0]), Fr(G[0, 0, 0]), Fr(k1), Fr(k2)
    A1 = f + g * K1
    A2 = f * A1 + g * K2
    worst = max((1 + K1**2) / (1 - A1**2), (1 + A1**2 + K1**2 + K2**2) / (1 - A2**2))
    assert abs(float(data[1]["A"][0, 0]) - float(A2)) > 1e-9  # the float64 loop is off the deployed one
    P, bound, _ = certify_cost(np.array([[float(worst)]]), data, None)
    assert bound is not None and Fr(bound) >= worst
    assert bound <= float(worst) * (1 + 1e-5)  # the allowance is no wider than the data's error needs


def test_hinf_recheck_covers_deployed_loop_rounding():
    """The case above with a disturbance (E = 1, z = [x; u]): main certified l2 gains whose bounded-real inequality
    fails on the deployed loop (exact in the float64 F, G, K; reference: its matrices written out by hand in
    Fractions for this scalar plant); now each certified level passes there (docs/design.md §8.4, "Loop data")."""
    from fractions import Fraction as Fr

    from solver.brackets import _psd_exact, certify_hinf

    F, G = np.array([[[1e4 + 1 / 3]]]), np.array([[[1.0]]])
    lifted = lift_modes(ModeSet.from_family(PlantFamily(F=F, G=G), 2), disturbance=np.array([[1.0]]), cost=False)
    k1, k2 = -9999.833325087962, -4999.993744890774
    data = lifted.numeric(np.array([[[k1]], [[k2]]]))
    f, K1, K2, one, zero = Fr(F[0, 0, 0]), Fr(k1), Fr(k2), Fr(1), Fr(0)
    A1 = f + K1
    A2 = f * A1 + K2
    # [A B] and [C D] of the two interval modes (eta = 1, 2; B = [F E, E], z(t) = [x(t); u(t)])
    modes = [([A1, one], [[one, zero], [K1, zero]]),
             ([A2, f, one], [[one, zero, zero], [K1, zero, zero], [A1, one, zero], [K2, zero, zero]])]

    def holds(P, g):
        P, g = Fr(float(P)), Fr(float(g))
        for AB, CD in modes:
            k = len(AB)
            neg = [[-(AB[i] * P * AB[j] + sum(r[i] * r[j] for r in CD)) + (P if i == j == 0 else 0)
                    + (g if i == j > 0 else 0) for j in range(k)] for i in range(k)]
            if not _psd_exact(neg):
                return False
        return True

    certified = 0
    for P0 in (1.4e8, 1e9, 1e10):
        P, gam, _ = certify_hinf(np.array([[P0]]), data)
        if P is not None:
            certified += 1
            assert holds(P[0, 0], gam**2), P0
    assert certified == 3


def test_mode_dependent_storage_narrows_a_switched_l2_gain_bracket():
    # issue 29's gap probe (seed 24): two unstable 4-state plants, n_drop = 2, the common storage's bound 4 % above
    # the worst pattern found; one storage per loop mode (docs/design.md §8.4) closes most of it.  Its inequality
    # is checked here on interval maps built by stepping the buffer sample by sample (not the library's lifting)
    rng = np.random.default_rng(70024)
    n, m, r = int(rng.integers(2, 6)), int(rng.integers(1, 3)), int(rng.integers(1, 4))
    F = rng.normal(size=(r, n, n)) * rng.uniform(0.4, 0.8)
    G = rng.normal(size=(r, n, m))
    n_drop = 2
    fam, E = PlantFamily(F=F, G=G, sampling_period=0.1), np.ones((n, 1))
    res = design(fam, n_drop, objective="hinf", disturbance=E)
    perf = res.performance
    assert res.outcome == "stabilized" and perf.verified and perf.mode_certificate is not None
    assert perf.lower <= perf.upper < perf.certificate_upper * (1 - 1e-2)
    assert perf.gap < 0.3 * (perf.certificate_upper - perf.lower) / perf.certificate_upper
    modes = ModeSet.from_family(fam, n_drop)
    Es, Cs = [E] * r, [np.vstack([np.eye(n), np.zeros((m, n))])] * r
    Ds = [np.vstack([np.zeros((n, m)), np.eye(m)])] * r
    blocks = []
    for seq in modes.plants:  # [A B; C D] of the interval by unit responses
        eta = len(seq)
        cols = [step_interval(F, G, Es, Cs, Ds, np.eye(n), np.eye(m), res.gains, seq, x, np.zeros((eta, 1)))
                for x in np.eye(n)]
        for t in range(eta):
            w = np.zeros((eta, 1))
            w[t, 0] = 1.0
            cols.append(step_interval(F, G, Es, Cs, Ds, np.eye(n), np.eye(m), res.gains, seq, np.zeros(n), w))
        blocks.append((np.column_stack([c[0] for c in cols]), np.column_stack([c[1] for c in cols])))
    Pm, g = perf.mode_certificate, perf.upper ** 2
    assert Pm.shape == (len(blocks), n, n) and all(np.linalg.eigvalsh(P)[0] > 0 for P in Pm)
    for s, (AB, CD) in enumerate(blocks):
        k = AB.shape[1] - n
        for t in range(len(blocks)):
            M = AB.T @ Pm[t] @ AB + CD.T @ CD - scipy.linalg.block_diag(Pm[s], g * np.eye(k))
            assert np.linalg.eigvalsh(0.5 * (M + M.T))[-1] <= 1e-9 * (np.abs(Pm).max() + g)
    # and along random switching from x(0) = 0, sample by sample
    for _ in range(50):
        x, z2, w2 = np.zeros(n), 0.0, 0.0
        for _ in range(40):
            plant, eta = int(rng.integers(r)), int(rng.integers(1, n_drop + 1))
            xm = x.copy()
            for t in range(eta):
                u = res.gains[t] @ xm
                w = rng.normal(size=1)
                z2 += x @ x + u @ u
                w2 += w @ w
                x = F[plant] @ x + G[plant] @ u + E @ w
        assert z2 <= g * w2 * (1 + 1e-12)
    # the JSON form and the MATLAB export carry the storage matrices
    from solver.brackets import Performance
    from solver.matlab import matlab_variables, m_script
    np.testing.assert_array_equal(Performance.from_dict(perf.to_dict()).mode_certificate, Pm)
    np.testing.assert_array_equal(np.moveaxis(matlab_variables(res, fam)["P_perf_modes"], -1, 0), Pm)
    assert "P_perf_modes" in m_script(res, fam)


def test_witness_is_reported_by_its_shortest_period():
    from solver.brackets import _primitive_period

    assert _primitive_period([(0, 1), (0, 1)]) == [(0, 1)]
    assert _primitive_period([1, 2, 1, 2, 1, 2]) == [1, 2]
    assert _primitive_period([1, 2, 1]) == [1, 2, 1]
    assert _primitive_period([1, 1, 2, 1, 1, 2]) == [1, 1, 2]
    assert _primitive_period([3]) == [3]


# --------------------------------------------------------------------------- exact hinf witness (§8.4)
def _mp_gain_sweep(F, E, dps: int = 60) -> float:
    """The l2 gain of ``x+ = F x + E w``, ``z = x`` (F's float64 numbers taken as exact) by a sweep in mpmath at
    ``dps`` digits refined around its best point: an independent reference of the H-infinity norm."""
    import mpmath as mp

    n = F.shape[0]
    with mp.workdps(dps):
        Fm = mp.matrix([[mp.mpf(float(v)) for v in row] for row in F])
        Em = mp.matrix([[mp.mpf(float(v)) for v in row] for row in E])

        def gain(w):
            Y = mp.lu_solve(mp.expj(w) * mp.eye(n) - Fm, Em)
            return mp.sqrt(sum(abs(y) ** 2 for y in Y))

        grid = [mp.pi * k / 400 for k in range(401)] + [mp.mpf(10) ** -k for k in range(3, 16)]
        best = max(grid, key=gain)
        lo, hi = max(best - mp.pi / 400, 0), min(best + mp.pi / 400, mp.pi)
        for _ in range(200):  # golden section on the peak (unimodal there)
            a, b = lo + (hi - lo) * 0.382, lo + (hi - lo) * 0.618
            lo, hi = (lo, b) if gain(a) >= gain(b) else (a, hi)
        return max(gain(best), gain(lo), gain(mp.mpf(0)))


def _near_unit_pole_loop(eps: float, seed: int = 0):
    """A stable 3-state plant with a real pole ``1 - eps`` in mixed coordinates (random orthogonal basis), zero
    gains: every interval loop is a power of F, the l2 gain ~1/eps peaks at w = 0."""
    rng = np.random.default_rng(seed)
    V, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    F = V @ np.diag([1 - eps, 0.5, -0.3]) @ V.T
    return F, rng.normal(size=(3, 1)), np.ones((3, 1))


def test_hinf_witness_is_exact_where_the_float64_one_exceeds_the_gain():
    # a pole 1e-12 inside the unit circle in mixed coordinates: the float64 period products and solves put the
    # witness 2e-5 above the pattern's l2 gain (no lower bound); the exact lifted period at the peak frequency is
    # at most that gain and within 1e-12 of it.  Without z = [x; u] and u = 0 every pattern's lifted system has
    # the gain of the sample loop (F, E, I) itself (lifting is an isometry), the reference below.
    from fractions import Fraction
    import mpmath as mp
    from solver.brackets import lower_bound
    from solver.lifting import lift_modes

    F, G, E = _near_unit_pole_loop(1e-12)
    fam = PlantFamily(F=F[None], G=G[None])
    K = np.zeros((2, 1, 3))
    ref = _mp_gain_sweep(F, E)
    # the float64 witness alone (what the bracket reported before)
    lifted = lift_modes(ModeSet.from_family(fam, 2), None, E)
    found = lower_bound(lifted, K, "hinf")
    assert found.value > float(ref) * (1 + 1e-6)
    perf = analyze(fam, K, 2, disturbance=E).hinf
    with mp.workdps(60):
        assert mp.mpf(Fraction(perf.lower).numerator) / Fraction(perf.lower).denominator <= ref
    assert perf.lower >= float(ref) * (1 - 1e-12)
    assert "evaluated exactly" in perf.message, perf.message


def test_exact_witness_never_exceeds_the_mpmath_gain_and_matches_float64_where_well_conditioned():
    # poles 1e-6 .. 1e-10 from the unit circle: the exact witness is below the independent 60-digit gain on every
    # one and within 1e-9 of it (the float64 one is above it already at 1e-6, by 3.8e-11 relative), and on a
    # well-conditioned switched loop it is the float64 witness to rounding
    from fractions import Fraction
    import mpmath as mp

    for eps in (1e-6, 1e-8, 1e-10):
        F, G, E = _near_unit_pole_loop(eps, seed=1)
        ref = _mp_gain_sweep(F, E)
        perf = analyze(PlantFamily(F=F[None], G=G[None]), np.zeros((3, 1, 3)), 3, disturbance=E).hinf
        with mp.workdps(60):
            assert mp.mpf(Fraction(perf.lower).numerator) / Fraction(perf.lower).denominator <= ref, eps
        assert perf.lower >= float(ref) * (1 - 1e-9)
        assert "evaluated exactly" in perf.message, perf.message
    fam = unstable_family()
    res = design(fam, 3, objective="hinf", disturbance=np.array([[0.5], [1.0]]))
    perf = res.performance
    assert "evaluated exactly" in perf.message and "deployed loop" in perf.message
    assert perf.lower <= perf.upper
    from solver.brackets import lower_bound
    lifted = lift_modes(ModeSet.from_family(fam, 3), None, np.array([[0.5], [1.0]]))
    assert perf.lower == pytest.approx(lower_bound(lifted, res.gains, "hinf").value, rel=1e-12)


@pytest.mark.parametrize("switching", ["per_interval", "per_sample"])
def test_exact_period_is_the_pattern_stepped_sample_by_sample_in_rationals(switching):
    # exact_period's [Phi B], [C D] equal, entry for entry, the period stepped through the buffer in Fractions from
    # the float64 F, G, K, E, C, D (the deployed loop); the float64 data variant equals the float64 intervals'
    # products in Fractions
    from fractions import Fraction
    from solver.brackets import exact_period

    rng = np.random.default_rng(11)
    r, n, m, pw, pz, N = 2, 3, 1, 2, 2, 2
    F, G = rng.normal(size=(r, n, n)), rng.normal(size=(r, n, m))
    E, C, D = rng.normal(size=(r, n, pw)), rng.normal(size=(r, pz, n)), rng.normal(size=(r, pz, m))
    modes = ModeSet.from_family(PlantFamily(F=F, G=G), N, plant_switching=switching)
    lifted = lift_modes(modes, None, list(E), (list(C), list(D)))
    K = modes.expand(rng.normal(size=(modes.n_free_gains, m, n)))
    data = lifted.numeric(K)
    q = np.vectorize(Fraction, otypes=[object])
    Fq, Gq, Eq, Cq, Dq, Kq = q(F), q(G), q(E), q(C), q(D), q(K)

    def stepped(seq, x, w):  # w: one row per sample of the period
        zs, t0 = [], 0
        for s in seq:
            xm, plants = x.copy(), modes.plants[s]
            for t, pl in enumerate(plants):
                u = Kq[t] @ xm
                zs.extend(Cq[pl] @ x + Dq[pl] @ u)
                x = Fq[pl] @ x + Gq[pl] @ u + Eq[pl] @ w[t0 + t]
            t0 += len(plants)
        return list(x), zs

    for seq in [(0,), (1, 0), (0, 1, 1)][: 3 if switching == "per_interval" else 2]:
        seq = tuple(s % len(data) for s in seq)
        per = exact_period(data, seq)
        assert per["deployed"]
        (Nab, sab), (Ncd, scd) = per["AB"], per["CD"]
        samples = sum(len(modes.plants[s]) for s in seq)
        zero = Fraction(0)
        cols = []
        for j in range(n + samples * pw):
            x = np.array([Fraction(int(i == j)) for i in range(n)], dtype=object)
            w = np.array([[Fraction(int(n + t * pw + k == j)) for k in range(pw)] for t in range(samples)] or
                         [[zero]], dtype=object)
            cols.append(stepped(seq, x, w))
        for i in range(n):
            assert [Fraction(int(Nab[i, j]), 2 ** sab) for j in range(len(cols))] == [c[0][i] for c in cols]
        for i in range(samples * pz):
            assert [Fraction(int(Ncd[i, j]), 2 ** scd) for j in range(len(cols))] == [c[1][i] for c in cols]
        # the float64 interval data as exact rationals: their products in Fractions
        flo = exact_period(data, seq, deployed=False)
        assert not flo["deployed"]
        Phi = np.eye(n, dtype=object) * Fraction(1)
        for s in seq:
            Phi = q(data[s]["A"]) @ Phi
        (Nf, sf) = flo["AB"]
        assert all(Fraction(int(Nf[i, j]), 2 ** sf) == Phi[i, j] for i in range(n) for j in range(n))


def test_solve_integer_is_the_exact_solution():
    from fractions import Fraction
    from solver.exact import solve_integer

    rng = np.random.default_rng(2)
    for k in (1, 2, 5, 8):
        M = [[int(v) for v in row] for row in rng.integers(-10 ** 12, 10 ** 12, size=(k, k))]
        if k > 1:
            M[0][0] = 0  # a zero pivot: the row exchange
        B = [[int(v) for v in row] for row in rng.integers(-10 ** 6, 10 ** 6, size=(k, 3))]
        X, d = solve_integer(M, B)
        assert d != 0
        for i in range(k):
            for c in range(3):
                assert sum(Fraction(M[i][j]) * Fraction(X[j][c], d) for j in range(k)) == B[i][c]
    assert solve_integer([[1, 2], [2, 4]], [[1], [0]]) is None


def test_a_skipped_exact_witness_keeps_the_float64_value_and_says_so(monkeypatch):
    # over the work cap, or with the run's time up, the float64 witness stays and the message says it is no proof
    from solver import brackets
    from solver.brackets import lower_bound

    F, G, E = _near_unit_pole_loop(1e-8, seed=1)
    fam, K = PlantFamily(F=F[None], G=G[None]), np.zeros((2, 1, 3))
    lifted = lift_modes(ModeSet.from_family(fam, 2), None, E)
    witness = lower_bound(lifted, K, "hinf").value
    perf = bracket(lifted, K, "hinf", seconds_left=lambda: 0.0)
    assert perf.lower == witness and "float64 witness, not a proof (no time left" in perf.message
    monkeypatch.setattr(brackets, "EXACT_PERIOD_MAX_WORK", 2)
    perf = bracket(lifted, K, "hinf")
    assert perf.lower == witness and "float64 witness, not a proof (period" in perf.message
    monkeypatch.undo()
    perf = bracket(lifted, K, "hinf")
    assert perf.lower != witness and "evaluated exactly" in perf.message


def test_a_witness_shortened_to_its_primitive_period_keeps_its_peak():
    # (a)(a)...(a) reported as (a): the peak frequency moves to the root of e^{jw} where (a) has that gain, so the
    # exact witness evaluates the shorter period where the longer one peaked (the r-fold lifting's singular values
    # are the short period's at the r-th roots: checked here against the r-fold period itself)
    from solver.brackets import _sigma_max, hinf_norm_peak, period_system, primitive_peak

    rng = np.random.default_rng(4)
    fam = unstable_family()
    modes = ModeSet.from_family(fam, 3)
    lifted = lift_modes(modes, None, np.array([[0.5], [1.0]]))
    K = modes.expand(0.3 * rng.normal(size=(modes.n_free_gains, 1, 2)) + np.array([[[-0.6, -1.0]]]))
    data = lifted.numeric(K)
    short = (0, 3)
    if not np.max(np.abs(np.linalg.eigvals(period_system(data, short)["Phi"]))) < 1:
        pytest.skip("unstable period")
    for r in (2, 3):
        value, peak = hinf_norm_peak(period_system(data, short * r), frequency=True)
        w = primitive_peak(data, short, r, peak)
        assert 0 <= w <= np.pi
        assert _sigma_max(period_system(data, short), w)[0] == pytest.approx(value, rel=1e-9)
        assert value == pytest.approx(hinf_norm_peak(period_system(data, short)), rel=1e-9)


def test_exact_witness_recovers_from_a_misplaced_float64_peak():
    # a float64 peak frequency far from the true one (pi/2 on a loop that peaks at w = 0): the exact value there is
    # far below the float64 witness, so w = 0, pi and the poles' angles are evaluated too; the value is then the
    # 60-digit gain's (within 1e-12, never above it)
    from fractions import Fraction
    import mpmath as mp
    from solver.brackets import exact_witness, lower_bound

    F, G, E = _near_unit_pole_loop(1e-8, seed=1)
    lifted = lift_modes(ModeSet.from_family(PlantFamily(F=F[None], G=G[None]), 2), None, E)
    K = np.zeros((2, 1, 3))
    found = lower_bound(lifted, K, "hinf")
    ref = _mp_gain_sweep(F, E)
    value, note = exact_witness(lifted.numeric(K), found._replace(peak=np.pi / 2))
    assert "poles' angles" in note, note
    with mp.workdps(60):
        assert mp.mpf(Fraction(value).numerator) / Fraction(value).denominator <= ref
    assert value >= float(ref) * (1 - 1e-12)


def _mp_period_gain(per: dict, z, dps: int = 60):
    """``sigma_max(D + C (zI - Phi)^-1 B)`` of :func:`solver.brackets.exact_period`'s integers at ``z`` in mpmath at
    ``dps`` digits: an independent reference of the exact evaluation."""
    import mpmath as mp

    n = per["n"]
    (Nab, sab), (Ncd, scd) = per["AB"], per["CD"]
    with mp.workdps(dps):
        def mat(N, s):
            return mp.matrix([[mp.mpf(int(v)) / mp.mpf(2) ** s for v in row] for row in N])

        Phi, B, C, D = mat(Nab[:, :n], sab), mat(Nab[:, n:], sab), mat(Ncd[:, :n], scd), mat(Ncd[:, n:], scd)
        H = D + C * mp.inverse(z * mp.eye(n) - Phi) * B
        S = mp.svd_c(H, compute_uv=False)
        return max(S[i] for i in range(S.rows))


def test_a_peak_at_0_or_pi_is_evaluated_on_the_real_system_and_a_longer_period_is_proven():
    # w within REAL_SNAP of pi (the float64 search stops ~6e-8 short of it) or of 0 is evaluated at z = -1 or 1: a
    # real system of side n (the complex one has side 2n; 20-50x the time), its value the 60-digit gain there (never
    # above); off the axis the complex form still runs.  Two intervals of 20 states at pi, above the old work cap
    # (period x n <= 32), now give a proven lower end.
    from fractions import Fraction
    import mpmath as mp
    import solver.exact
    from solver import brackets
    from solver.brackets import LowerBound, _exact_gain_at, exact_period, exact_witness, period_system, _sigma_max

    rng = np.random.default_rng(5)
    n, r = 20, 2
    F = rng.normal(size=(r, n, n))
    F = np.array([f * 0.97 / max(abs(np.linalg.eigvals(f))) for f in F])
    fam = PlantFamily(F=F, G=rng.normal(size=(r, n, 1)))
    E = rng.normal(size=(n, 1))
    lifted = lift_modes(ModeSet.from_family(fam, 1), None, E)
    data = lifted.numeric(np.zeros((1, 1, n)))
    seq = (0, 1)
    per = exact_period(data, seq)
    sides = []
    real_solve = solver.exact.solve_integer

    def recording(M, rhs):
        sides.append(len(M))
        return real_solve(M, rhs)

    solver.exact.solve_integer = recording
    try:
        for w, z in ((np.pi - 6e-8, -1), (3e-7, 1), (0.3, mp.expj(mp.mpf(0.3)))):
            value = _exact_gain_at(per, w)
            with mp.workdps(60):
                ref = _mp_period_gain(per, z)
                assert mp.mpf(Fraction(value).numerator) / Fraction(value).denominator <= ref * (1 + mp.mpf(2) ** -48)
                assert value >= float(ref) * (1 - 1e-12), w
    finally:
        solver.exact.solve_integer = real_solve
    assert sides == [n, n, 2 * n]
    # the witness: the float64 gain at pi - 6e-8, evaluated exactly at pi
    w = np.pi - 6e-8
    found = LowerBound(value=float(_sigma_max(period_system(data, seq), np.array([w]))[0]), witness=[], patterns=1,
                       note="", pattern=seq, peak=w)
    assert len(seq) * n > 32 and brackets.exact_work(n, len(seq), True) <= brackets.EXACT_PERIOD_MAX_WORK
    value, note = exact_witness(data, found)
    assert "evaluated exactly" in note and value == pytest.approx(found.value, rel=1e-12)


@pytest.mark.parametrize("angle", [np.pi - 5e-7, 3e-7], ids=["near_pi", "near_0"])
def test_a_lightly_damped_peak_near_the_axis_is_not_moved_onto_it(angle):
    # a pole pair 1e-8 inside the circle at 5e-7 from pi (or 3e-7 from 0): its gain at z = -1 (1) is ~24x below the
    # peak, so the exact evaluation keeps the complex form there; the value is the float64 peak's (review of the
    # snap to the real axis: it had returned 2.0e6 against 5.0e7)
    from solver.brackets import LowerBound, exact_witness, hinf_norm_peak, period_system

    r = 1 - 1e-8
    A = r * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    data = [{"A": A, "B": np.array([[1.0], [0.0]]), "C": np.array([[0.0, 1.0]]), "D": np.zeros((1, 1)), "L": None,
             "S": None}]
    value, peak = hinf_norm_peak(period_system(data, [0]), frequency=True)
    found = LowerBound(value=value, witness=[], patterns=1, note="", pattern=(0,), peak=peak)
    exact, note = exact_witness(data, found)
    assert "evaluated exactly" in note and "z = " not in note, note
    assert exact == pytest.approx(value, rel=1e-6) and exact <= value * (1 + 1e-12)


def test_a_witness_is_spelled_with_the_shortest_prefix():
    """``prefix`` then ``period`` forever and its spelling by :func:`solver.brackets.shortest_lead` are the same
    sequence (compared over 60 terms on random short spellings), and no shorter prefix spells it: the reported
    witness no longer depends on which spelling rounding let win (``a`` then ``(a)`` forever is ``(a)``)."""
    from solver.brackets import shortest_lead

    def unrolled(prefix, period, count=60):
        return (list(prefix) + list(period) * count)[:count]

    rng = np.random.default_rng(0)
    for _ in range(300):
        prefix = list(rng.integers(0, 2, size=rng.integers(0, 4)))
        period = list(rng.integers(0, 2, size=rng.integers(1, 4)))
        short, rotated = shortest_lead(prefix, period)
        seq, p = unrolled(prefix, period), len(period)
        assert unrolled(short, rotated) == seq and len(rotated) == p
        # the sequence repeats with period p from len(short) on, and from no earlier term
        first = min(k for k in range(len(prefix) + 1) if all(seq[i] == seq[i + p] for i in range(k, 60 - p)))
        assert len(short) == first
    assert shortest_lead([(0, 1)], [(0, 1)]) == ([], [(0, 1)])
