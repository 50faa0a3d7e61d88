"""Input limits no design can meet from x0: a Farkas certificate, re-checked from the plant (issue 17 item 3)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from solver import PlantFamily, design
from solver.limit_proofs import (
    LimitMultipliers,
    check_limits_farkas,
    limits_multipliers,
    prove_limits_infeasible,
)
from solver.network import ModeSet

X0 = np.array([-3.0, 2.0])


@pytest.fixture(scope="module")
def motor():
    return PlantFamily.paper_example(0.1)


@pytest.fixture(scope="module")
def tight(motor):
    """The motor at decay rate 0.5 with |u| <= 0.01 from x0 = (-3, 2): no design (the plant is open-loop stable
    with eigenvalues near 0.67, so only a rate makes the limits bind)."""
    return design(motor, 3, decay_rate=0.5, u_max=[0.01], x0=X0)


def _weighted_sum(modes, mult, W, theta, u_max, x0, rate):
    """``sum_b <Z_b, F_b(W, Y)>`` from blocks assembled directly from the closed-loop interval matrices."""
    n = modes.n_states
    gains = modes.expand(theta)
    A = modes.closed_loops(gains) * (rate ** -modes.eta.astype(float))[:, None, None]
    total = 0.0
    for s in range(modes.n_modes):
        AW = A[s] @ W
        L = np.block([[W, AW.T], [AW, W]])
        total += np.sum(mult.stability[s] * L)
    for q in range(modes.n_drop):
        KW = gains[q] @ W  # Y_q = K_q W
        for j, u in enumerate(u_max):
            blk = np.block([[np.array([[u ** 2]]), KW[j:j + 1]], [KW[j:j + 1].T, W]])
            total += np.sum(mult.inputs[q, j] * blk)
    xb = np.block([[np.ones((1, 1)), x0[None]], [x0[:, None], W]])
    return total + np.sum(mult.x0 * xb), n


def test_tiny_input_limit_is_infeasible_with_a_rechecked_certificate(motor, tight):
    assert tight.outcome == "infeasible", tight.message
    cert = tight.certificate
    assert cert.kind == "farkas_limits" and cert.verified and cert.any_margin
    assert "no gains with a common quadratic Lyapunov function at decay rate 0.5" in tight.message
    assert cert.radius > 1e3 * np.linalg.norm(X0)  # excludes ellipsoids far larger than the one x0 needs
    # the independent re-check, on a ModeSet rebuilt from the plant
    again = check_limits_farkas(ModeSet.from_family(motor, 3), cert.multipliers, [0.01], X0, 0.5)
    assert again.verified and again.any_margin and again.constant < 0
    d = tight.to_dict()["certificate"]
    assert d["kind"] == "farkas_limits" and d["statement"] == cert.statement()


def test_the_multipliers_contradict_every_candidate_design(motor, tight):
    """The Farkas identity: sum_b <Z_b, F_b(W, Y)> is the same negative number t* for every (W, Y) (the adjoint
    vanishes), computed here from blocks built out of the closed loops, not from the checker's interval data."""
    modes = ModeSet.from_family(motor, 3)
    mult = tight.certificate.multipliers
    rng = np.random.default_rng(0)
    for _ in range(5):
        R = rng.standard_normal((2, 2)) * rng.uniform(0.1, 30)
        W = R @ R.T + 0.1 * np.eye(2)
        theta = rng.standard_normal((modes.n_free_gains, 1, 2)) * rng.uniform(0.01, 10)
        value, _ = _weighted_sum(modes, mult, W, theta, [0.01], X0, 0.5)
        scale = np.linalg.norm(W) * (1 + np.linalg.norm(theta)) ** 2
        assert value == pytest.approx(mult.t, abs=1e-7 * scale)
    assert mult.t < 0


@pytest.mark.parametrize("part", ["stability", "inputs", "x0", "sign"])
def test_a_perturbed_certificate_is_rejected(motor, tight, part):
    """A perturbation breaks the identity: the proof reaches less far (a tiny one) or nowhere (a large one)."""
    modes = ModeSet.from_family(motor, 3)
    mult = tight.certificate.multipliers
    rng = np.random.default_rng(1)
    if part == "sign":  # the multipliers of the feasible direction: -Z is not PSD
        assert not check_limits_farkas(modes, LimitMultipliers(-mult.stability, -mult.inputs, -mult.x0), [0.01],
                                       X0, 0.5).verified
        # nor do the true multipliers prove anything for limits 10^4 times larger
        assert not check_limits_farkas(modes, mult, [100.0], X0, 0.5).verified
        return
    arr = getattr(mult, part)
    noise = rng.standard_normal(arr.shape)
    noise = noise + np.swapaxes(noise, -1, -2)
    for eps, verdict in ((1e-6, True), (0.1, False)):
        bad = dataclasses.replace(mult, **{part: arr + eps * np.abs(arr).max() * noise})
        cert = check_limits_farkas(modes, bad, [0.01], X0, 0.5)
        assert cert.verified is verdict
        assert cert.radius < 1e-2 * tight.certificate.radius


def test_feasible_limits_are_never_infeasible(motor):
    res = design(motor, 3, decay_rate=0.5, u_max=[100.0], x0=X0)
    assert res.outcome == "stabilized"
    modes = ModeSet.from_family(motor, 3)
    assert limits_multipliers(modes, [100.0], X0, 0.5) is None  # t* >= 0: nothing to prove
    proof, reason = prove_limits_infeasible(modes, [100.0], X0, 0.5, strict=1e-5)
    assert proof is None and "t* < 0" in reason
    # the plain motor (open-loop stable) meets any limit with small gains: never "infeasible" without a rate
    assert design(motor, 3, u_max=[1e-3], x0=X0).outcome != "infeasible"


def test_cost_design_with_an_unmeetable_limit_is_infeasible():
    fam = PlantFamily(F=[np.array([[1.3, 0.2], [0.0, 0.8]])], G=[np.array([[1.0], [0.5]])])
    res = design(fam, 2, objective="cost", u_max=[0.01], x0=[5.0, -4.0])
    assert res.outcome == "infeasible", res.message
    assert res.objective == "cost" and res.certificate.kind == "farkas_limits"
    assert res.certificate.decay_rate is None  # the non-strict class: every common quadratic Lyapunov function
    ok = check_limits_farkas(ModeSet.from_family(fam, 2), res.certificate.multipliers, [0.01], [5.0, -4.0])
    assert ok.verified
    # a generous limit: designed, never called infeasible
    assert design(fam, 2, objective="cost", u_max=[50.0], x0=[5.0, -4.0]).outcome == "stabilized"


def test_a_proof_that_reaches_only_small_ellipsoids_is_not_a_verdict():
    """A rotation (|lambda| = 1): K = 0 meets any limit non-strictly, so the proof is made at the method's own
    strictness; here it excludes only ellipsoids far smaller than the design searches: not "infeasible"."""
    c, s = np.cos(0.3), np.sin(0.3)
    fam = PlantFamily(F=[np.array([[c, -s], [s, c]])], G=[np.array([[0.0], [1.0]])])
    # on Clarabel the SDP fails and the proof decides; the IPM returns gains whose set misses x0 (u_max^2 = 1e-16
    # is below its resolution): "not_converged" too, with that reason
    ipm = design(fam, 2, u_max=[1e-8], x0=[10.0, 0.0], solver="IPM")
    assert ipm.outcome == "not_converged" and ipm.certificate is None or ipm.certificate.kind != "farkas_limits"
    res = design(fam, 2, u_max=[1e-8], x0=[10.0, 0.0], solver="CLARABEL")
    assert res.outcome == "not_converged"
    assert "reaches only part of the designs" in res.message and "at decay rate 0.99999" in res.message


def test_ipm_multipliers_pass_the_independent_recheck():
    """Issue 29: the limits' Farkas multipliers come from the IPM's phase 1 (an unstable plant, a tiny limit from
    x0); they pass the float64 re-check and their t* matches a second solver's (Clarabel) on the same SDP."""
    fam = PlantFamily(F=[np.array([[1.3, 0.2], [0.0, 0.8]])], G=[np.array([[1.0], [0.5]])])
    modes, x0 = ModeSet.from_family(fam, 2), np.array([5.0, -4.0])
    ipm = limits_multipliers(modes, [0.01], x0, solver="IPM")
    ref = limits_multipliers(modes, [0.01], x0, solver="CLARABEL")
    assert ipm.solver == "IPM" and ref.solver == "CLARABEL"
    assert ipm.t == pytest.approx(ref.t, rel=1e-4) and ipm.t < 0
    cert = check_limits_farkas(modes, ipm, [0.01], x0)
    assert cert.verified and cert.any_margin and cert.constant < 0
    # a limit the design meets: the IPM reports t* >= 0, no multipliers
    assert limits_multipliers(modes, [50.0], x0, solver="IPM") is None
    proof, _ = prove_limits_infeasible(modes, [0.01], x0, solver="IPM")
    assert proof is not None and proof.multipliers.solver == "IPM"


def test_auto_needs_no_clarabel_on_the_tie_break_and_limit_paths(motor, monkeypatch):
    """Under solver="AUTO" the cost-from-x0 design (both stages) and the limits' Farkas proof run on the IPM alone:
    with cvxpy's solve disabled the designs still succeed, and the certificates pass the re-check."""
    import cvxpy

    def no_cvxpy(self, *args, **kwargs):
        raise AssertionError("a cvxpy solve ran under solver='AUTO'")

    monkeypatch.setattr(cvxpy.Problem, "solve", no_cvxpy)
    res = design(motor, 3, objective="cost", x0=X0)
    assert res.outcome == "stabilized" and res.performance.verified and res.solver == "IPM"
    res = design(motor, 3, decay_rate=0.5, u_max=[0.01], x0=X0)
    assert res.outcome == "infeasible" and res.certificate.kind == "farkas_limits" and res.solver == "IPM"
    assert check_limits_farkas(ModeSet.from_family(motor, 3), res.certificate.multipliers, [0.01], X0, 0.5).verified
    fam = PlantFamily(F=[np.array([[1.3, 0.2], [0.0, 0.8]])], G=[np.array([[1.0], [0.5]])])
    res = design(fam, 2, objective="cost", u_max=[0.01], x0=[5.0, -4.0])
    assert res.outcome == "infeasible" and res.certificate.kind == "farkas_limits"
    assert check_limits_farkas(ModeSet.from_family(fam, 2), res.certificate.multipliers, [0.01], [5.0, -4.0]).verified
    assert design(motor, 3, u_max=[5.0], x0=X0).outcome == "stabilized"


def test_both_solvers_report_t_in_the_same_normalization():
    """LimitMultipliers.t is sum_b <C_b, Z_b> of the returned multipliers (total trace 1) on the IPM and on
    Clarabel alike: recomputed here from the blocks' constant parts, written out by hand."""
    fam = PlantFamily(F=[np.array([[1.3, 0.2], [0.0, 0.8]])], G=[np.array([[1.0], [0.5]])])
    modes, x0 = ModeSet.from_family(fam, 2), np.array([5.0, -4.0])
    for solver in ("IPM", "CLARABEL"):
        mult = limits_multipliers(modes, [0.01], x0, solver=solver)
        total = (np.trace(mult.stability, axis1=1, axis2=2).sum() + np.trace(mult.inputs, axis1=2, axis2=3).sum()
                 + np.trace(mult.x0))
        assert total == pytest.approx(1.0, abs=1e-12)
        C_x0 = np.zeros((3, 3))
        C_x0[0, 0], C_x0[0, 1:], C_x0[1:, 0] = 1.0, x0, x0
        C_in = np.zeros((3, 3))
        C_in[0, 0] = 0.01 ** 2
        value = np.sum(C_x0 * mult.x0) + sum(np.sum(C_in * Z) for Z in mult.inputs.reshape(-1, 3, 3))
        assert mult.t == pytest.approx(value, rel=1e-12, abs=1e-15) and mult.t < 0


def test_limits_hold_from_every_state_when_every_gain_is_zero():
    """A plant its inputs do not reach (G = 0, stable F; hold-out draw_family 9796 answered "not_converged": "all
    gains are zero ... the input limits are not proven"): the cost design's gains are zero, every input is zero from
    every state, so the limits hold with the whole space as the set (``invariant_set`` = 0).  Independent check: one
    mode with n_drop = 1, the cost is x0' P x0 of the discrete Lyapunov equation; on a network the same verdict."""
    import scipy.linalg

    from solver import Network

    F1, F2 = np.array([[0.9, 0.2], [0.0, 0.7]]), np.array([[0.8, -0.1], [0.1, 0.6]])
    G0 = np.zeros((2, 1))
    one = design(PlantFamily(F=[F1], G=[G0]), 1, objective="cost", u_max=[0.5], x0=X0)
    assert one.outcome == "stabilized" and not np.any(one.gains), one.message
    assert one.invariant_set is not None and not np.any(one.invariant_set)
    assert "every input is zero" in one.message
    lyap = X0 @ scipy.linalg.solve_discrete_lyapunov(F1.T, np.eye(2)) @ X0
    assert one.performance.lower <= lyap * (1 + 1e-9) and one.performance.upper == pytest.approx(lyap, rel=1e-9)
    two = PlantFamily(F=[F1, F2], G=[G0, G0])
    for res in (design(two, 2, objective="cost", u_max=[0.5], x0=X0),
                design(two, network=Network.delays(1, 2), objective="cost", u_max=[0.5], x0=X0)):
        assert res.outcome == "stabilized" and not np.any(res.gains), res.message
        assert res.invariant_set is not None and not np.any(res.invariant_set)
        assert "every input is zero" in res.message and res.performance.verified


def test_an_input_limit_whose_square_is_not_a_float64_is_invalid_input():
    """u_max = 1e200 squared overflows: the limits' scale came out 0, the network re-check read that as "every
    input is zero" and the bounded-drops one raised LinAlgError (found by review).  Now the request is refused up
    front, on both paths, naming the field."""
    from solver import InvalidInput, Network

    fam = PlantFamily.paper_example(0.1)
    for args, kw in (((fam, 3), {}), ((fam,), {"network": Network.delays(1, 2)})):
        for u in (1e200, 1e-200):
            with pytest.raises(InvalidInput, match="between 1e-150 and 1e") as err:
                design(*args, u_max=[u], x0=X0, **kw)
            assert tuple(err.value.field) == ("u_max",)
