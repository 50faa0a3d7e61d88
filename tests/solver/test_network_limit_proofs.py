"""Input limits on a network refuted by a Farkas certificate (docs/design.md §11.3, "Refuting the limits"):
the multipliers re-checked on the problem rebuilt here, the Farkas identity evaluated on blocks assembled here at
random points, homogeneity (u_max and x0 scaled together give the same problem), and the IPM against Clarabel."""

import numpy as np
import pytest

from solver import Network, PlantFamily, design
from solver.methods import network_lmi
from solver.methods.network_performance import LIMIT_SLACK, STRICT, initial_history
from solver.network_limit_proofs import check_network_limits, input_index

from .paper_data import EQ20_F, EQ20_G

MOTOR = PlantFamily(EQ20_F, EQ20_G, sampling_period=0.1)
#: The motor's first mode made open-loop unstable (spectral radius 1.07), as in test_network_performance.py.
UNSTABLE = PlantFamily(np.asarray(EQ20_F)[:1] * 1.6, np.asarray(EQ20_G)[:1], sampling_period=0.1)
NETS = {"delays": Network.delays(1, 3), "weakly_hard": Network.weakly_hard(1, 3, 3)}
#: (family, design options): the motor (open-loop stable: K = 0 meets any limit without a rate) at decay rate
#: 0.5, below its open-loop 0.67; the unstable motor with the Kothare cost.
CASES = {"motor_rate": (MOTOR, dict(decay_rate=0.5)), "unstable_cost": (UNSTABLE, dict(objective="cost"))}
X0 = np.array([100.0, -100.0])
U_TINY = np.array([1e-3])


def lagrangian(prob, mult, u_max, x0, Z, W, Y, c):
    """``sum_b <X_b, F_b(Z, W, Y)>`` with the blocks assembled here (the SDP of §11.3 written out block by block)."""
    n, k = prob.n, prob.k
    Zf = np.zeros((k, k))
    for b in range(prob.zblocks):
        Zf[b * n:(b + 1) * n, b * n:(b + 1) * n] = Z[b]
    total = 0.0
    for e in range(prob.n_blocks):
        AZ = prob.free[e] @ Zf
        for j in range(prob.N):
            b = prob.right[e, j]
            if b >= 0:
                AZ[:, b * n:(b + 1) * n] += prob.coef[e, j] @ Y[j]
        AZ = c[e] * AZ
        B = np.block([[Zf + Zf.T - W[prob.src[e]], AZ.T], [AZ, W[prob.dst[e]]]])
        total += np.sum(mult.blocks[e] * B)
    for q, (v, j, b, i) in enumerate(input_index(prob)):
        y = np.zeros(k)
        y[b * n:(b + 1) * n] = Y[j][i]
        top = np.array([[(u_max[i] * (1 - LIMIT_SLACK)) ** 2]])
        I = np.block([[top, y[None, :]], [y[:, None], Zf + Zf.T - W[v]]])
        total += np.sum(mult.inputs[q] * I)
    s = initial_history(prob) @ x0
    for v in range(len(prob.nodes)):
        S = np.block([[np.ones((1, 1)), s[None, :]], [s[:, None], W[v]]])
        total += np.sum(mult.x0[v] * S)
    return total


def assert_refuted(res, family, net, opts):
    """The verdict "not_certified" with verified multipliers; their Lagrangian, on blocks assembled here (the
    problem rebuilt here), is the negative constant plus a part linear in (Z, W, Y) that vanishes to solver
    accuracy, and every multiplier is PSD to that accuracy."""
    assert res.outcome == "not_certified" and res.gains is None
    cert = res.certificate
    assert cert.kind == "farkas_network_limits" and cert.verified and cert.bound > cert.floor
    assert "not every gain" in res.message and "u_max" in res.message
    # a finite bound excludes only the solutions with ||Z||_F below it, and the message says so
    assert np.isinf(cert.bound) or f"within ||Z||_F < {cert.bound:.3g}" in res.message
    rate = opts.get("decay_rate")
    prob = network_lmi.build_problem(family, net)
    mult = cert.multipliers
    for X in list(mult.blocks) + list(mult.inputs) + list(mult.x0):
        assert np.linalg.eigvalsh(0.5 * (X + X.T))[0] > -1e-6
    c = (np.ones(prob.n_blocks) if rate is None else rate ** (-prob.length.astype(float))) * (1 + STRICT)
    n, k, V = prob.n, prob.k, len(prob.nodes)
    zero = lagrangian(prob, mult, U_TINY, X0, np.zeros((prob.zblocks, n, n)), np.zeros((V, k, k)),
                      np.zeros((prob.N, prob.m, n)), c)
    assert zero < 0 and zero == pytest.approx(cert.constant, rel=1e-6, abs=1e-12)
    rng = np.random.default_rng(0)
    for _ in range(3):
        Z = rng.standard_normal((prob.zblocks, n, n))
        W = rng.standard_normal((V, k, k))
        W = W + np.swapaxes(W, 1, 2)
        Y = rng.standard_normal((prob.N, prob.m, n))
        assert abs(lagrangian(prob, mult, U_TINY, X0, Z, W, Y, c) - zero) < 1e-5 * max(1.0, abs(zero))
    # the same multipliers do not refute the problem from an x0 a million times smaller (on weakly_hard it has
    # solutions: the next test)
    small = check_network_limits(prob, mult, U_TINY, X0 * 1e-6, initial_history(prob), rate, STRICT, LIMIT_SLACK)
    assert not small.verified


@pytest.mark.parametrize("net_name", sorted(NETS))
def test_limits_no_design_meets_are_not_certified_with_a_rechecked_certificate(net_name):
    """Tiny u_max, large x0, the motor at decay rate 0.5 (the Kothare cost: the last test).  On delays(1, 3) the
    convex augmented form fails at this rate without limits too (valid certificate, not a limits-only case)."""
    family, opts = CASES["motor_rate"]
    net = NETS[net_name]
    assert_refuted(design(family, network=net, u_max=U_TINY, x0=X0, **opts), family, net, opts)


@pytest.mark.parametrize("case", sorted(CASES))
def test_limits_a_design_meets_stay_stabilized(case):
    """On weakly_hard(1, 3, 3) a limit 1e4 times larger from x0 100 times smaller is "stabilized" with its
    invariant sets (so the refuted problem above is refuted because of its limits), and with the invariance cap
    left aside the SDP is homogeneous in (u_max, x0): the problem from 1e-6 x0 with the tiny limit has solutions,
    which the re-check of the first test refused to exclude."""
    family, opts = CASES[case]
    res = design(family, network=NETS["weakly_hard"], u_max=U_TINY * 1e4, x0=X0 * 1e-2, **opts)
    assert res.outcome == "stabilized" and res.invariant_set is not None


@pytest.mark.parametrize("net_name", sorted(NETS))
def test_limits_ipm_and_clarabel_agree(net_name):
    """The Kothare cost design on the unstable motor: each solver alone gives "not_certified" with its own
    multipliers (re-checked) for the tiny limit, and the same verdict for the limit 1e4 times larger from x0 100
    times smaller."""
    family, opts = CASES["unstable_cost"]
    net = NETS[net_name]
    verdicts = {}
    for solver in ("IPM", "CLARABEL"):
        res = design(family, network=net, u_max=U_TINY, x0=X0, solver=solver, **opts)
        assert_refuted(res, family, net, opts)
        assert res.certificate.multipliers.solver == solver
        if net_name == "weakly_hard":  # on delays(1, 3) the augmented form refutes the larger limit too
            verdicts[solver] = design(family, network=net, u_max=U_TINY * 1e4, x0=X0 * 1e-2, solver=solver,
                                      **opts).outcome
    if verdicts:
        assert verdicts["IPM"] == verdicts["CLARABEL"] == "stabilized"
