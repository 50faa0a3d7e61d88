"""Exact convex design (DESIGN.md section 3): one SDP, no iteration.

Theorem 1 for the augmented loop holds iff some ``X > 0`` has
``A_s^T X A_s - X < 0`` for every mode s.  With ``W = X^{-1}`` and the
scheme's free gains ``Theta_j = Y_j W^{-1}`` the condition is linear::

    [[rho_s W, (free_s W + sum_j coef_{s,j} Y_j)^T],
     [free_s W + sum_j coef_{s,j} Y_j,          W]] >= t I

with ``rho_s = 1`` (``lambda^(2 eta_s)`` for a guaranteed per-sample decay
rate lambda).  We solve ``max t`` subject to ``trace W = n``: the problem is
always feasible and bounded (t <= 1), so the solver never has to detect
infeasibility; a design with the requested margin exists iff ``t* > margin``.
The certificate ``X = W^{-1}`` is lifted to the augmented P and re-checked
in float64.
"""

from __future__ import annotations

import time

import cvxpy as cp
import numpy as np

from .. import ipm
from ..compiled import CompiledProblem, block, check_memory, problem_cache, schur_block
from ..network import ModeSet
from ..result import DesignResult
from .common import DesignOptions, RunClock, certify_gains, conclude_one_shot


def build(n: int, m: int, S: int, J: int, active: np.ndarray) -> CompiledProblem:
    """The DPP problem for one shape; plant data and decay factors are Parameters.

    Parameters are stacked (few of them): cvxpy validates every Parameter on
    assignment, which costs more than the whole solve when there is one per mode.
    """
    W = cp.Variable((n, n), symmetric=True)
    Y = [cp.Variable((m, n)) for _ in range(J)]
    t = cp.Variable()
    free = cp.Parameter((S * n, n))  # row block s: free_s
    coef = cp.Parameter((S * J * n, m))  # row block s*J + j: coef_{s,j}
    rho = cp.Parameter(S, nonneg=True)
    eye2 = np.eye(2 * n)
    cons = [cp.trace(W) == n]
    for s in range(S):
        AW = block(free, s, n) @ W
        for j in range(J):
            if active[s, j]:
                AW = AW + block(coef, s * J + j, n) @ Y[j]
        cons.append(schur_block(rho[s] * W, AW, W) - t * eye2 >> 0)
    prob = cp.Problem(cp.Maximize(t), cons)
    return CompiledProblem(prob, {"free": free, "coef": coef, "rho": rho}, {"W": W, "Y": Y, "t": t})


def compiled_for(modes: ModeSet, kind: str, builder) -> tuple[CompiledProblem, bool, float]:
    """Cached problem for this method and shape: ``(problem, was_cached, build_seconds)``."""
    _, active = modes.scheme_coef()
    n, m, S, J = modes.n_states, modes.n_inputs, modes.n_modes, modes.n_free_gains
    start = time.perf_counter()
    compiled, cached = problem_cache.get((kind,) + modes.shape_key(), lambda: builder(n, m, S, J, active))
    return compiled, cached, (0.0 if cached else time.perf_counter() - start)


def plant_values(modes: ModeSet) -> dict:
    """Parameter values shared by the methods: stacked free parts and scheme coefficients."""
    coef, _ = modes.scheme_coef()
    S, n, m = modes.n_modes, modes.n_states, modes.n_inputs
    return {"free": modes.free.reshape(S * n, n), "coef": coef.reshape(S * modes.n_free_gains * n, m)}


def run(modes: ModeSet, options: DesignOptions) -> DesignResult:
    check_memory([2 * modes.n_states] * modes.n_modes, "lmi")
    clock = RunClock()
    if options.solver == "IPM":  # the structured interior-point solver, solver/ipm.py
        info, sol = ipm.design_solve(modes, "lmi", options.rho(modes), options.time_limit)
        t, W, Y = sol.t, sol.W, sol.Y
    else:
        compiled, clock.cached, clock.setup = compiled_for(modes, "lmi", build)
        values = plant_values(modes)
        values["rho"] = options.rho(modes)
        info = compiled.solve(values, solver=options.solver, time_limit=options.time_limit)
        t = float(compiled.value("t"))
        W = compiled.value("W")
        W = 0.5 * (W + W.T)
        Y = np.stack(compiled.value("Y"))
    clock.add(info)
    if t <= options.margin:
        return conclude_one_shot(modes, "lmi", options, clock, info, t,
                                 infeasible="no common quadratic Lyapunov design exists (trace W = n)")
    theta = np.linalg.solve(W, np.swapaxes(Y, 1, 2)).swapaxes(1, 2)  # Theta_j = Y_j W^{-1}, W symmetric
    gains = modes.expand(theta)
    cert, A = certify_gains(modes, gains, options, clock, candidate=np.linalg.inv(W), candidate_source="lmi")
    return conclude_one_shot(modes, "lmi", options, clock, info, t, gains=gains, cert=cert, A=A)
