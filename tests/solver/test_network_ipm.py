"""The network design on the structured IPM (solver/ipm/network_blocks.py) against a second solver (Clarabel),
the plain lmi design, the solver-independent Farkas re-check and brute force over admissible cycles."""

import numpy as np
import pytest

from solver import Network, PlantFamily, analyze, design
from solver import ipm
from solver.methods import network_lmi
from solver.network import ModeSet
from solver.rate_search import network_margin_model

from .paper_data import EQ20_F, EQ20_G
from .test_network_design import DELAY_FAMILY, WEAKLY_HARD_FAMILY, max_cycle_rate, random_runs_decay
from .textbook import pendulum

MOTOR = PlantFamily(list(EQ20_F), list(EQ20_G), sampling_period=0.1)
#: x+ = 4 x + 0.1 u (either sign of F): no gain holds it over intervals of 1..3 samples
TOO_UNSTABLE = PlantFamily([[[4.0]], [[-4.0]]], [[[0.1]], [[0.1]]])


def _random_family(n, seed):
    rng = np.random.default_rng(seed)
    F = rng.normal(size=(n, n))
    F = 1.05 * F / max(abs(np.linalg.eigvals(F)))
    return PlantFamily([F], [rng.normal(size=(n, 1))])


def _both(fam, net, rate=None):
    prob = network_lmi.build_problem(fam, net)
    scale = np.ones(prob.n_blocks) if rate is None else rate ** (-prob.length.astype(float))
    a = network_lmi.solve_sdp(prob, scale, solver="IPM")
    b = network_lmi.solve_sdp(prob, scale, solver="CLARABEL")
    return prob, scale, a, b


CASES = [
    (DELAY_FAMILY, Network.delays(1, 2), None),
    (MOTOR, Network.delays(1, 3), None),
    (MOTOR, Network.delays(1, 3), 0.8),
    (MOTOR, Network.weakly_hard(2, 5, 3), None),
    (WEAKLY_HARD_FAMILY, Network.weakly_hard(2, 5, 3), 0.95),
    (TOO_UNSTABLE, Network.weakly_hard(1, 3, 3), None),
    (TOO_UNSTABLE, Network.delays(2, 3, min_delay=1), None),
    (_random_family(3, 3), Network.delays(2, 3), None),
    (_random_family(3, 4), Network.weakly_hard(3, 8, 4) & Network.delays(1, 4), None),
]


@pytest.mark.parametrize("fam,net,rate", CASES, ids=lambda x: x.describe() if hasattr(x, "describe") else None)
def test_ipm_and_clarabel_reach_the_same_optimal_margin(fam, net, rate):
    prob, scale, a, b = _both(fam, net, rate)
    assert a.solver == "IPM" and b.solver == "CLARABEL"
    assert a.status in ("optimal", "optimal_inaccurate")
    assert abs(a.t - b.t) <= 1e-6 * max(1.0, abs(b.t)), (prob.form, a.t, b.t)
    if a.t > 1e-6:
        # the IPM's variables attain its margin: every block >= t I up to rounding (the IPM's iterates are feasible)
        K = network_lmi.gains_from(prob, a)
        cert = network_lmi.recheck_network(prob, np.linalg.inv(a.W), K, rate)
        assert cert.verified, cert.margin


def test_bounded_drops_network_lmi_on_the_ipm_contains_the_lmi_design():
    """One reception node: Z = W is the lmi design, so the network LMI's margin is at least the lmi SDP's, and
    the lmi design's own (W, Y) is a feasible point of the network LMI with that margin."""
    net = Network.bounded_drops(3)
    prob, scale, a, b = _both(MOTOR, net)
    modes = ModeSet.from_family(MOTOR, 3)
    _, plain = ipm.design_solve(modes, "lmi")
    assert prob.form == "lifted" and len(prob.nodes) == 1
    assert a.t >= plain.t - 1e-7 and abs(a.t - b.t) <= 1e-6
    # the lmi design's gains, through the network method forced onto the IPM, are certified on the network
    res = network_lmi.run(MOTOR, net, solver="IPM", use_ccl=False)
    assert res.outcome == "stabilized" and res.solver == "IPM" and res.timings["solves"] == 1
    assert max_cycle_rate(MOTOR, res.gains, net, 5) < 1.0
    # the lmi point in the network LMI: blocks [[2W - W, (A W)^T], [A W, W]] are the lmi blocks
    theta = np.linalg.solve(plain.W, np.swapaxes(plain.Y, 1, 2)).swapaxes(1, 2)
    gains = modes.expand(theta)
    A = prob.closed_loops(gains)
    low = min(np.linalg.eigvalsh(np.block([[plain.W, (Ae @ plain.W).T], [Ae @ plain.W, plain.W]]))[0] for Ae in A)
    assert low >= plain.t - 1e-7
    # and design() on bounded_drops is today's design, to solver tolerance
    np.testing.assert_allclose(design(MOTOR, network=net, decay_rate=None).gains, design(MOTOR, 3, decay_rate=None).gains,
                               rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("net", [Network.weakly_hard(1, 3, 3), Network.weakly_hard(3, 8, 4) & Network.delays(1, 4)],
                         ids=["weakly_hard", "weakly_hard_and_delays"])
def test_not_certified_carries_a_farkas_certificate_from_the_ipm_dual(net):
    res = design(TOO_UNSTABLE, network=net, decay_rate=None, solver="IPM", max_iter=2)
    prob = network_lmi.build_problem(TOO_UNSTABLE, net)
    assert res.outcome == "not_certified", res.message
    assert res.solver == "IPM" and res.certificate.kind == "farkas_network" and res.certificate.verified
    assert res.certificate.delta > 0 and res.gains is None
    again = network_lmi.check_network_farkas(prob, res.certificate.multipliers, np.ones(prob.n_blocks))
    assert again.verified and again.form == prob.form
    assert not network_lmi.check_network_farkas(prob, [-M for M in res.certificate.multipliers],
                                                np.ones(prob.n_blocks)).verified
    # the multipliers are PSD (to rounding), one per transition and one per node matrix
    E, V = prob.n_blocks, len(prob.nodes)
    M, Nv = res.certificate.multipliers[:E], res.certificate.multipliers[E:]
    assert len(Nv) == V and min(np.linalg.eigvalsh(X)[0] for X in M + Nv) > -1e-9 * max(np.trace(X) for X in M)


@pytest.mark.parametrize("solver", ["IPM", "CLARABEL"])
def test_delays_network_not_certified_by_the_per_block_normalization(solver):
    """The augmented form with the sum normalization always reaches t = 0 (a zero slack block); normalized per
    slack block it is proven infeasible, and the proof names the restriction (docs/design.md 11.1)."""
    net = Network.delays(2, 3, min_delay=1)
    prob = network_lmi.build_problem(TOO_UNSTABLE, net)
    assert prob.form == "augmented" and prob.zblocks == 3
    ones = np.ones(prob.n_blocks)
    # the point that defeats the sum normalization: Z = blkdiag(0, 0, N I), W = 0, Y = 0, every block PSD
    n, k = prob.n, prob.k
    Z = np.zeros((k, k))
    Z[-n:, -n:] = prob.zblocks * np.eye(n)
    low = min(np.linalg.eigvalsh(np.block([[Z + Z.T, (prob.free[e] @ Z).T], [prob.free[e] @ Z, np.zeros((k, k))]]))[0]
              for e in range(prob.n_blocks))
    assert low >= -1e-12
    plain = network_lmi.solve_sdp(prob, ones, solver=solver)
    assert plain.t > -1e-6 and not network_lmi.check_network_farkas(prob, plain.multipliers, ones).verified
    res = network_lmi.run(TOO_UNSTABLE, net, solver=solver, use_ccl=False)
    assert res.outcome == "not_certified", res.message
    cert = res.certificate
    assert cert.verified and cert.per_block and cert.delta > 0 and "equal traces" in cert.statement()
    again = network_lmi.check_network_farkas(prob, cert.multipliers, ones, per_block=True)
    assert again.verified and abs(again.delta - cert.delta) <= 1e-12 * abs(cert.delta)
    # the same multipliers prove nothing about the sum-normalized LMI (it has the point above), nor negated
    assert not network_lmi.check_network_farkas(prob, cert.multipliers, ones).verified
    assert not network_lmi.check_network_farkas(prob, [-M for M in cert.multipliers], ones, per_block=True).verified
    # the restricted LMI's optimum is strictly negative on both solvers (a second solver as reference)
    other = network_lmi.solve_sdp(prob, ones, solver="CLARABEL" if solver == "IPM" else "IPM", per_block=True)
    assert other.t < 0 and abs(other.t - res.sdp.t) <= 1e-5 * max(1.0, abs(other.t))


def test_per_block_normalization_is_a_restriction_and_feasible_designs_keep_the_sum():
    """MOTOR on delays(1, 3) at decay rate 0.8: t* > 0 with the sum normalization (certified design), t* < 0 with
    one per slack block -- the per-block LMI loses solutions, so the design solves the sum first."""
    net = Network.delays(1, 3)
    prob = network_lmi.build_problem(MOTOR, net)
    scale = 0.8 ** (-prob.length.astype(float))
    for solver in ("IPM", "CLARABEL"):
        a = network_lmi.solve_sdp(prob, scale, solver=solver)
        b = network_lmi.solve_sdp(prob, scale, solver=solver, per_block=True)
        assert a.t > 1e-3 and b.t < -1e-3, (solver, a.t, b.t)
    res = network_lmi.run(MOTOR, net, decay_rate=0.8, solver="IPM", use_ccl=False)
    assert res.outcome == "stabilized" and res.timings["solves"] == 1
    assert max_cycle_rate(MOTOR, res.gains, net, 6) < 0.8


def test_ipm_model_eliminates_several_equalities():
    """BlockLMI with q equalities: every direction of the reduced basis keeps all of them (exact zero)."""
    net = Network.delays(2, 3)
    prob = network_lmi.build_problem(_random_family(3, 3), net)
    from solver.ipm.network_blocks import network_problem
    lmi, _ = network_problem(prob.free, prob.coef, prob.right, prob.src, prob.dst, len(prob.nodes), prob.zblocks,
                             per_block=True)
    a = np.atleast_2d(lmi.equality)
    assert a.shape[0] == 3
    T = lmi.T.toarray()
    assert np.abs(a @ T[:-1]).max() <= 1e-14 and np.linalg.matrix_rank(T) == T.shape[1]
    one, _ = network_problem(prob.free, prob.coef, prob.right, prob.src, prob.dst, len(prob.nodes), prob.zblocks)
    assert T.shape[1] == one.p - 2  # one parameter less per equality


def test_design_reports_the_ipm_and_clarabel_as_asked():
    net = Network.weakly_hard(2, 5, 3)
    auto = design(WEAKLY_HARD_FAMILY, network=net, decay_rate=None)
    clar = design(WEAKLY_HARD_FAMILY, network=net, decay_rate=None, solver="CLARABEL")
    forced = design(WEAKLY_HARD_FAMILY, network=net, decay_rate=None, solver="IPM")
    assert auto.solver == forced.solver == "IPM" and clar.solver == "CLARABEL"
    assert auto.outcome == clar.outcome == forced.outcome == "stabilized"
    assert auto.solve_count == 1 and clar.solve_count == 1
    for res in (auto, clar):
        assert analyze(WEAKLY_HARD_FAMILY, res.gains, network=net).stable is True
        assert max_cycle_rate(WEAKLY_HARD_FAMILY, res.gains, net, 8) < 1.0


def test_auto_falls_back_to_clarabel_when_the_ipm_fails(monkeypatch):
    from solver.errors import SolverFailed

    real = network_lmi._solve_ipm

    def broken(*args, **kwargs):
        raise SolverFailed("IPM ended with status 'numerical_error'", status="numerical_error")

    monkeypatch.setattr(network_lmi, "_solve_ipm", broken)
    net = Network.weakly_hard(2, 5, 3)
    res = design(WEAKLY_HARD_FAMILY, network=net, decay_rate=None)
    assert res.outcome == "stabilized" and res.solver == "CLARABEL" and res.solve_count == 2
    assert "IPM failed" in res.message
    alone = design(WEAKLY_HARD_FAMILY, network=net, decay_rate=None, solver="IPM")  # no fallback: a verdict
    assert alone.outcome == "not_converged" and "numerical_error" in alone.message
    monkeypatch.setattr(network_lmi, "_solve_ipm", real)


def test_textbook_motor_on_a_delays_network_on_the_ipm():
    """The paper's motor with packets up to one sample late (delays(1, 3)): the augmented form on the IPM."""
    net = Network.delays(1, 3)
    res = design(MOTOR, network=net, decay_rate=None)
    assert res.outcome == "stabilized" and res.solver == "IPM" and res.method == "network_lmi", res.message
    assert "augmented form" in res.message
    assert analyze(MOTOR, res.gains, network=net).stable is True
    assert max_cycle_rate(MOTOR, res.gains, net, 5) < 1.0
    assert random_runs_decay(MOTOR, res.gains, net, runs=20, steps=300) < 1e-3


def test_textbook_pendulum_on_a_weakly_hard_network_on_the_ipm():
    """CTMS inverted pendulum (two pole lengths), at most one lost packet in any 3: IPM and Clarabel agree."""
    fam = pendulum()
    net = Network.weakly_hard(1, 3, 2)
    prob, scale, a, b = _both(fam, net)
    assert abs(a.t - b.t) <= 1e-6 * max(1.0, abs(b.t)) and a.t > 0
    res = design(fam, network=net, decay_rate=None)
    assert res.outcome == "stabilized" and res.solver == "IPM", res.message
    assert analyze(fam, res.gains, network=net).stable is True
    assert random_runs_decay(fam, res.gains, net, runs=10, steps=3000) < 1e-2


def test_decay_rate_max_on_the_ipm_matches_clarabel_and_bounds_every_cycle():
    """The rate search (solver/rate_search.py's model steps, IPM probes warm started) against Clarabel's."""
    net = Network.weakly_hard(2, 5, 3)
    tol = 1e-2
    ipm_res = design(WEAKLY_HARD_FAMILY, network=net, decay_rate="max", rate_tol=tol)
    clar = design(WEAKLY_HARD_FAMILY, network=net, decay_rate="max", rate_tol=tol, solver="CLARABEL")
    assert ipm_res.outcome == clar.outcome == "stabilized" and ipm_res.solver == "IPM"
    lo, hi = ipm_res.rate_bracket["lower"], ipm_res.rate_bracket["upper"]
    assert hi - lo <= tol * hi and hi == ipm_res.decay_rate
    # the two searches bracket the same smallest rate of the convex condition (each to its tolerance)
    assert clar.rate_bracket["lower"] <= hi * (1 + 1e-6) and lo <= clar.decay_rate * (1 + 1e-6)
    assert max_cycle_rate(WEAKLY_HARD_FAMILY, ipm_res.gains, net, 8) <= ipm_res.decay_rate * (1 + 1e-9)
    auto = design(WEAKLY_HARD_FAMILY, network=net)  # decay_rate="auto"
    assert auto.outcome == "stabilized" and hi <= auto.decay_rate < 1.0


def test_network_margin_model_is_tangent_to_the_margin():
    """The model's slope at a rate against a finite difference of the IPM's optimal margin."""
    net = Network.delays(1, 3)
    prob = network_lmi.build_problem(MOTOR, net)
    lam, h = 0.85, 1e-4

    def t_at(rate):
        return network_lmi.solve_sdp(prob, rate ** (-prob.length.astype(float)), solver="IPM")

    sol = t_at(lam)
    t0, q, eta = network_margin_model(prob, sol, lam)
    slope_model = float(np.sum(q * (-eta) / lam))
    slope_fd = (t_at(lam + h).t - t_at(lam - h).t) / (2 * h)
    assert abs(t0 - sol.t) < 1e-12
    assert abs(slope_model - slope_fd) <= 1e-3 * max(1.0, abs(slope_fd)), (slope_model, slope_fd)


def test_design_on_a_delays_network_returns_the_per_block_farkas_certificate():
    """design(network=delays) end to end: "not_certified" from the per-block LMI's multipliers (IPM), re-checked
    independently."""
    net = Network.delays(2, 3, min_delay=1)
    res = design(TOO_UNSTABLE, network=net, solver="AUTO", max_iter=2)
    assert res.outcome == "not_certified", res.message
    assert res.solver == "IPM" and res.certificate.per_block and res.certificate.to_dict()["per_block"]
    prob = network_lmi.build_problem(TOO_UNSTABLE, net)
    assert network_lmi.check_network_farkas(prob, res.certificate.multipliers, np.ones(prob.n_blocks),
                                            per_block=True).verified


def test_a_solver_failure_on_a_network_is_a_verdict_not_an_exception(monkeypatch):
    """solver="IPM" has no fallback: its failure must come back as "not_converged", never as SolverFailed."""
    from solver import Network, PlantFamily, design
    from solver.errors import SolverFailed
    from solver.methods import network_lmi

    def failing(*args, **kwargs):
        raise SolverFailed("IPM ended with status 'max_iterations'", status="max_iterations")

    monkeypatch.setattr(network_lmi, "solve_sdp", failing)
    res = design(PlantFamily.paper_example(0.1), network=Network.delays(1, 3), solver="IPM", decay_rate=None)
    assert res.outcome == "not_converged" and res.gains is None and "max_iterations" in res.message
    assert res.network == Network.delays(1, 3).to_dict()
