"""The network performance designs on the structured IPM (docs/design.md §11.3, "On the IPM") against a second
solver (Clarabel on the cvxpy form of the same SDP), admissible runs stepped sample by sample, a brute-force gain
grid, and the size guard."""

import itertools

import numpy as np
import pytest

from solver import InvalidInput, Network, PlantFamily, design
from solver.ipm.network_performance_blocks import network_performance_problem, solve_network_performance
from solver.ipm import IPMOptions
from solver.methods import network_performance as npf

from .paper_data import EQ20_F, EQ20_G
from .test_network_performance import run_cost

MOTOR = PlantFamily(EQ20_F, EQ20_G, sampling_period=0.1)
E = np.array([[1.0], [0.0]])
X0 = np.array([1.0, -1.0])
FORMS = [("cost", None, None), ("hinf", None, None), ("cost", X0, None), ("cost", X0, np.array([0.1])),
         ("cost", None, np.array([0.1]))]


@pytest.mark.parametrize("kind,x0,u_max", FORMS, ids=["cost", "hinf", "cost_x0", "kothare_x0", "kothare"])
def test_ipm_model_has_clarabels_optimum(kind, x0, u_max):
    """The grouped model's optimum equals the cvxpy form's (Clarabel) to 1e-6 on the lifted form (attained)."""
    net = Network.weakly_hard(1, 3, 3)
    ch = npf.channels(MOTOR, net, kind, disturbance=E if kind == "hinf" else None)
    ref = npf.solve(ch, kind, x0, None, u_max)
    kothare = u_max is not None
    prob = network_performance_problem(ch, kind, x0, u_max, strict=npf.STRICT if kothare else 0.0,
                                       limit_slack=npf.LIMIT_SLACK if kothare else 0.0)
    sol = solve_network_performance(prob, IPMOptions(gap_tol=1e-10, feas_tol=1e-10))
    assert sol.status in ("optimal", "inaccurate"), sol.status
    assert sol.value == pytest.approx(ref[3], rel=1e-6)


@pytest.mark.parametrize("net,kind", [(Network.delays(1, 3), "cost"), (Network.weakly_hard(1, 3, 3), "hinf")],
                         ids=lambda v: v if isinstance(v, str) else v.describe())
def test_ipm_and_clarabel_brackets_agree(net, kind):
    """Today's brackets (Clarabel) and the IPM's: the same to 1e-6 where the optimum is attained (lifted form); on
    the augmented form (delays) the infimum is not attained and Clarabel stops a few 1e-6 short of it, so the
    IPM's certified bound is at most Clarabel's (and within 1e-5)."""
    kw = {"disturbance": E} if kind == "hinf" else {}
    ipm = npf.run(MOTOR, net, kind, solver="IPM", **kw)
    ref = npf.run(MOTOR, net, kind, solver="CLARABEL", **kw)
    assert ipm.outcome == ref.outcome == "stabilized" and ipm.solver == "IPM" and ref.solver == "CLARABEL"
    p, q = ipm.performance, ref.performance
    assert p.verified and q.verified and p.lower <= p.upper and q.lower <= q.upper
    if p.form == "lifted":
        assert p.upper == pytest.approx(q.upper, rel=1e-6)
        assert p.lower == pytest.approx(q.lower, rel=1e-6)
    else:
        assert p.upper <= q.upper * (1 + 1e-8)
        assert p.upper == pytest.approx(q.upper, rel=1e-5)
        assert p.lower == pytest.approx(q.lower, rel=1e-5)


# ------------------------------------------------------------------------------------------- unstable plants
def unstable_plant(seed: int, n: int = 2) -> PlantFamily:
    rng = np.random.default_rng(seed)
    F = rng.standard_normal((n, n))
    F *= 1.1 / np.max(np.abs(np.linalg.eigvals(F)))
    return PlantFamily([F], [rng.standard_normal((n, 1))], sampling_period=0.1)


def test_unstable_plant_on_delays_gets_the_stability_designs_gains_with_a_certified_cost():
    """Open-loop unstable (spectral radius 1.1) on delays(1, 3): the convex cost SDP has no interior (the network
    LMI's t* = 0, docs/design.md §11.3); the stability design's gains (cone complementarity) are bracketed with
    their own node matrices.  Every admissible run of 7 samples from x0, stepped sample by sample, costs at most
    the certified bound."""
    fam = unstable_plant(1)
    net = Network.delays(1, 3)
    res = design(fam, network=net, objective="cost", x0=X0)
    assert res.outcome == "stabilized" and "stability design's gains" in res.message
    perf = res.performance
    assert perf.verified and perf.lower <= perf.upper
    worst, T = 0.0, 7
    for ages in itertools.product(range(net.n_drop), repeat=T):
        if net.admissible(ages):
            worst = max(worst, run_cost(fam.F, fam.G, res.gains, np.eye(2), np.eye(1), X0, ages, [0] * T, ages[0]))
    assert 0 < worst <= perf.upper


@pytest.mark.parametrize("rho,seed", [(1.1, 1), (4.0, 0)])
def test_one_phase_attempt_without_an_interior_gives_up_early(rho, seed):
    """The cost SDP on delays(1, 3) with an unstable plant has no interior (docs/design.md §8.3.2, §11.3): the
    one-phase attempt never becomes strictly feasible and hands over to the two phases after
    ``ONE_PHASE_GIVE_UP`` iterations, not after ``max_iter`` (iteration counts against the two phases alone)."""
    from solver.ipm.algorithm import solve_grouped

    rng = np.random.default_rng(seed)
    F = rng.standard_normal((2, 2))
    F *= rho / np.max(np.abs(np.linalg.eigvals(F)))
    fam = PlantFamily([F], [rng.standard_normal((2, 1))], sampling_period=0.1)
    lmi = network_performance_problem(npf.channels(fam, Network.delays(1, 3), "cost"), "cost", None, None).lmi
    one = solve_grouped(lmi, {"g": 1.0})
    two = solve_grouped(lmi, {"g": 1.0}, one_phase=False)
    assert one.status == two.status == "no_interior" and one.phase1_iterations == two.phase1_iterations
    assert one.iterations <= two.iterations + 45  # max_iter (100) more before the give-up


def test_refuted_network_lmi_gives_not_certified_with_a_proof_that_re_checks():
    """Spectral radius 4 on delays(1, 3): the network LMI is refuted and cone complementarity finds nothing, so the
    cost design says "not_certified" with the Farkas multipliers, which re-check (float64, solver-independent) on
    the problem rebuilt here."""
    from solver.methods import network_lmi

    rng = np.random.default_rng(0)
    F = rng.standard_normal((2, 2))
    F *= 4.0 / np.max(np.abs(np.linalg.eigvals(F)))
    fam = PlantFamily([F], [rng.standard_normal((2, 1))], sampling_period=0.1)
    net = Network.delays(1, 3)
    res = design(fam, network=net, objective="cost")
    assert res.outcome == "not_certified" and res.gains is None and "Farkas" in res.message
    proof = res.certificate
    again = network_lmi.check_network_farkas(network_lmi.build_problem(fam, net), proof.multipliers,
                                             np.ones(len(proof.multipliers)), per_block=proof.per_block)
    assert again.verified and again.delta > 0


def test_uncontrollable_unstable_mode_is_infeasible():
    """x2+ = 1.2 x2 with no input reaching x2: no gains stabilize, whatever the network (the structural proof)."""
    fam = PlantFamily([[[0.5, 0.0], [0.0, 1.2]]], [[[1.0], [0.0]]], sampling_period=0.1)
    res = design(fam, network=Network.delays(1, 3), objective="cost")
    assert res.outcome == "infeasible" and res.gains is None


# ------------------------------------------------------------------------------------------- the size guard
@pytest.mark.parametrize("net", [Network.delays(1, 3), Network.weakly_hard(2, 4, 3)], ids=lambda n: n.describe())
@pytest.mark.parametrize("kind,u_max", [("cost", None), ("hinf", None), ("cost", np.array([0.1]))],
                         ids=["cost", "hinf", "kothare"])
def test_size_estimate_counts_the_ipm_model(net, kind, u_max):
    """design_size of a network performance request against the model the IPM solves, built here: the same LMI
    size (sum of block sides) and variables (the model's reduced coordinates less t); the lifted form's input
    blocks are bounded by one per node, gain and input."""
    from solver.compiled import design_size

    ch = npf.channels(MOTOR, net, kind, disturbance=E if kind == "hinf" else None)
    model = network_performance_problem(ch, kind, None, u_max).lmi
    size = design_size("lmi", 2, 1, MOTOR.n_modes, net.n_drop, network=net, objective=kind, u_max=u_max)
    lmi = sum(C.shape[0] * C.shape[1] for C in model.C)
    assert size.n_variables == model.p - 1
    if u_max is not None and ch.prob.form == "lifted":
        assert lmi <= size.lmi_size < lmi + 3 * 4 * 3
    else:
        assert size.lmi_size == lmi


def test_size_guard_refuses_a_network_performance_design_up_front():
    from solver.compiled import design_size

    net = Network.delays(1, 3)
    size = design_size("lmi", 2, 1, MOTOR.n_modes, net.n_drop, network=net, objective="cost")
    with pytest.raises(InvalidInput) as err:
        design(MOTOR, network=net, objective="cost", max_memory=size.memory / 2)
    assert "network design" in str(err.value) and f"LMI size {size.lmi_size}" in str(err.value)
