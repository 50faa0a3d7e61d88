"""Performance designs on textbook plants (tests/solver/plants.py) against independent references.

* one plant mode, ``n_drop = 1``: the loop is plain LQR, so the default ``design(..., objective="cost")``
  must reproduce ``dlqr`` (``scipy.linalg.solve_discrete_are``): cost ``trace P`` to 1e-6, gains to 1e-5;
* the H-infinity design's certified level against a dense frequency sweep of the designed loop;
* the two-mode pendulum at ``n_drop = 3``: a bracket of gap below 5 %, its lower end the cost of a pattern
  simulated here from the plant data.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from solver import design

from .plants import PENDULUM_Q, bus_suspension, pendulum

BUS_Q = np.diag([1e6, 0.0, 1e6, 0.0])  # body travel and suspension deflection, force in N (R = 1e-4)


def _dlqr(F, G, Q, R):
    P = scipy.linalg.solve_discrete_are(F, G, Q, R)
    return P, -np.linalg.solve(R + G.T @ P @ G, G.T @ P @ F)


CASES = {
    "pendulum Q=I": (lambda: pendulum(), np.eye(4), np.eye(1)),
    "pendulum CTMS weights": (lambda: pendulum(), PENDULUM_Q, np.eye(1)),
    "pendulum CTMS weights / 5000": (lambda: pendulum(), PENDULUM_Q / 5000, np.eye(1) / 5000),
    "bus Q=I": (lambda: bus_suspension()[0], np.eye(4), np.eye(1)),
    "bus weights": (lambda: bus_suspension()[0], BUS_Q, 1e-4 * np.eye(1)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_one_mode_cost_design_is_dlqr(case):
    make, Q, R = CASES[case]
    family = make()
    P, K = _dlqr(family.F[0], family.G[0], Q, R)
    res = design(family, 1, objective="cost", weights=(Q, R))
    assert res.outcome == "stabilized", res.message
    perf = res.performance
    assert perf.verified and perf.upper is not None, res.message
    optimum = float(np.trace(P))
    assert perf.upper >= optimum * (1 - 1e-9)  # a certified bound cannot be below the optimum
    assert abs(perf.upper - optimum) <= 1e-6 * optimum
    assert np.max(np.abs(res.gains[0] - K)) <= 1e-5 * np.max(np.abs(K))


def _sweep_hinf(A, B, C, D, points=200_001):
    """Largest gain on a dense grid, a log grid near 0 and a fine grid (spacing 1e-7) around every pole angle:
    a lower bound of the norm, independent of solver/."""
    near = [np.linspace(t - 0.01, t + 0.01, 200_001) for t in np.abs(np.angle(np.linalg.eigvals(A)))]
    w = np.unique(np.clip(np.concatenate([np.linspace(0.0, np.pi, points), np.logspace(-8, 0, 20_001)] + near),
                          0.0, np.pi))
    z = np.exp(1j * w)
    best = 0.0
    n = A.shape[0]
    for idx in np.array_split(np.arange(w.size), 40):
        H = C[None] @ np.linalg.solve(z[idx, None, None] * np.eye(n)[None] - A[None],
                                      np.broadcast_to(B, (idx.size,) + B.shape)) + D[None]
        best = max(best, float(np.max(np.linalg.norm(H, ord=2, axis=(1, 2)))))
    return best


@pytest.mark.parametrize("plant", ["pendulum", "bus"])
def test_one_mode_hinf_level_matches_a_frequency_sweep(plant):
    if plant == "pendulum":
        family = pendulum()
        E = family.G[0]  # a force disturbance at the input
    else:
        family, E = bus_suspension()  # the road
    res = design(family, 1, objective="hinf", disturbance=E)
    assert res.outcome == "stabilized", res.message
    K = res.gains[0]
    A = family.F[0] + family.G[0] @ K
    C = np.vstack([np.eye(4), K])  # default output z = [x; u]
    sweep = _sweep_hinf(A, E, C, np.zeros((5, E.shape[1])))
    perf = res.performance
    assert perf.verified
    assert perf.upper >= sweep * (1 - 1e-9)  # the certificate bounds the loop's norm
    assert perf.upper <= sweep * (1 + 1e-4)  # and an LTI loop's bounded-real certificate is tight
    assert perf.lower == pytest.approx(sweep, rel=1e-6)


def _pattern_cost(family, gains, Q, R, witness, periods=3000, lead=0):
    """trace of the cost of ``witness[:lead]`` once, then ``witness[lead:]`` repeated, simulated from e_1 .. e_n."""
    n = family.n_states
    total = 0.0
    X = np.eye(n)  # every initial basis state at once
    for i in range(periods):
        for plant, eta in (witness if i == 0 else witness[lead:]):
            x0 = X
            for t in range(eta):
                U = gains[t] @ x0
                total += float(np.sum(X * (Q @ X)) + np.sum(U * (R @ U)))
                X = family.F[plant] @ X + family.G[plant] @ U
    return total


@pytest.mark.parametrize("weights", ["I", "CTMS"])
def test_two_mode_pendulum_bracket_closes_to_five_percent(weights):
    family = pendulum((0.2, 0.3))
    Q, R = (np.eye(4), np.eye(1)) if weights == "I" else (PENDULUM_Q, np.eye(1))
    res = design(family, 3, objective="cost", weights=(Q, R))
    assert res.outcome == "stabilized", res.message
    perf = res.performance
    assert perf.verified and perf.gap is not None and perf.gap < 0.05, res.message
    simulated = _pattern_cost(family, res.gains, Q, R, perf.witness, lead=perf.lead)
    assert simulated == pytest.approx(perf.lower, rel=1e-6)
    assert simulated <= perf.upper
