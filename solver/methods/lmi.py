"""Exact convex design (docs/design.md): one SDP, no iteration.

Theorem 1 for the augmented loop holds iff some ``X > 0`` has
``A_s^T X A_s - rho_s X < 0`` for every mode s (``rho_s = lambda^(2 eta_s)`` for a
guaranteed per-sample decay rate lambda, 1 for plain stability).  In the
congruent form (multiply ``A_s`` by ``c_s = lambda^(-eta_s)``) every rate has the
same well-conditioned LMI; with ``W = X^{-1}`` and the scheme's free gains
``Theta_j = Y_j W^{-1}``::

    [[W, c_s (free_s W + sum_j coef_{s,j} Y_j)^T],
     [c_s (free_s W + sum_j coef_{s,j} Y_j),  W]] >= t I

We solve ``max t`` subject to ``trace W = n``: always feasible and bounded
(t <= 1).  A positive t* yields gains, accepted only when the float64 re-check
of ``X = W^{-1}`` passes at the rate; t* <= 0 is called infeasible only when
the dual multipliers pass :func:`solver.certificates.check_farkas`.
"""

from __future__ import annotations

import time

import numpy as np

from .. import ipm
from ..compiled import cp  # cvxpy, imported on first use
from ..compiled import (CompiledProblem, DesignSdpSolution, block, check_memory, ipm_memory, problem_cache,
                        resolve_solver, schur_block)
from ..errors import SolverFailed
from ..network import ModeSet
from ..result import DesignResult
from .common import DesignOptions, run_one_shot


def build(n: int, m: int, S: int, J: int, active: np.ndarray) -> CompiledProblem:
    """The DPP problem for one shape; the (congruently scaled) plant data are Parameters.

    Parameters are stacked (few of them): cvxpy validates every Parameter on
    assignment, which costs more than the whole solve when there is one per mode.
    """
    W = cp.Variable((n, n), symmetric=True)
    Y = [cp.Variable((m, n)) for _ in range(J)]
    t = cp.Variable()
    free = cp.Parameter((S * n, n))  # row block s: c_s free_s
    coef = cp.Parameter((S * J * n, m))  # row block s*J + j: c_s coef_{s,j}
    eye2 = np.eye(2 * n)
    cons = [cp.trace(W) == n]
    blocks = []
    for s in range(S):
        AW = block(free, s, n) @ W
        for j in range(J):
            if active[s, j]:
                AW = AW + block(coef, s * J + j, n) @ Y[j]
        blocks.append(schur_block(W, AW, W) - t * eye2 >> 0)
    prob = cp.Problem(cp.Maximize(t), cons + blocks)
    return CompiledProblem(prob, {"free": free, "coef": coef}, {"W": W, "Y": Y, "t": t, "blocks": blocks})


def compiled_for(modes: ModeSet, kind: str, builder) -> tuple[CompiledProblem, bool, float]:
    """Cached problem for this method and shape: ``(problem, was_cached, build_seconds)``."""
    _, active = modes.scheme_coef()
    n, m, S, J = modes.n_states, modes.n_inputs, modes.n_modes, modes.n_free_gains
    start = time.perf_counter()
    compiled, cached = problem_cache.lookup((kind,) + modes.shape_key(), lambda: builder(n, m, S, J, active))
    return compiled, cached, (0.0 if cached else time.perf_counter() - start)


def plant_values(modes: ModeSet, scale: np.ndarray | None = None) -> dict:
    """Stacked free parts and scheme coefficients, mode s multiplied by ``scale[s]`` (the congruent ``c_s``)."""
    coef, _ = modes.scheme_coef()
    S, n, m = modes.n_modes, modes.n_states, modes.n_inputs
    free = modes.free
    if scale is not None:
        free = free * scale[:, None, None]
        coef = coef * scale[:, None, None, None]
    return {"free": free.reshape(S * n, n), "coef": coef.reshape(S * modes.n_free_gains * n, m)}


def solve_sdp(modes: ModeSet, scale: np.ndarray, solver: str = "AUTO", time_limit: float | None = None,
              clock=None, sign_only: bool | float = False, start=None, refute=None) -> DesignSdpSolution:
    """Solve the congruent design SDP once (see :class:`solver.compiled.DesignSdpSolution`).

    Parameters
    ----------
    modes : ModeSet
    scale : ndarray, shape (S,)
        ``c_s = lambda^(-eta_s)`` (ones for plain stability).
    sign_only : bool
        The IPM stops once the margin's sign is settled (the rate search's probes; ignored by Clarabel).
    start : solver.ipm.WarmStart, optional
        The IPM's warm start (ignored by Clarabel).
    refute : callable, optional
        ``refute(X) -> bool``: the Farkas re-check of an iterate's multipliers inside the IPM's solve
        (:attr:`solver.ipm.IPMOptions.refute`; ignored by Clarabel).
    """
    solver = resolve_solver(solver, "lmi", modes.n_modes)
    if solver == "IPM":  # the structured interior-point solver (solver/ipm/), same SDP and dual convention
        return ipm_sdp(modes, "lmi", scale, time_limit, sign_only, start, refute)
    compiled, cached, setup = compiled_for(modes, "lmi", build)
    if clock is not None:
        clock.cached, clock.setup = clock.cached and cached, clock.setup + setup
    info = compiled.solve(plant_values(modes, scale), solver=solver, time_limit=time_limit)
    W = compiled.value("W")
    return DesignSdpSolution(
        t=float(compiled.value("t")), W=0.5 * (W + W.T), Y=np.stack(compiled.value("Y")), S=None,
        duals=compiled.duals("blocks"), info=info,
    )


def ipm_sdp(modes: ModeSet, kind: str, scale: np.ndarray, time_limit: float | None,
            sign_only: bool | float = False, start=None, refute=None) -> DesignSdpSolution:
    """The congruent SDP of ``kind`` ("lmi" or "switched") solved by :func:`solver.ipm.design_solve`."""
    values = plant_values(modes, scale)
    S, n, m, J = modes.n_modes, modes.n_states, modes.n_inputs, modes.n_free_gains
    try:
        info, sol = ipm.design_solve(modes, kind, None, time_limit, free=values["free"].reshape(S, n, n),
                                     coef=values["coef"].reshape(S, J, n, m), sign_only=sign_only, start=start,
                                     refute=refute)
    except SolverFailed as err:  # the last iterate travels with the failure, for the caller's re-checks
        if getattr(err, "iterate", None) is not None:
            err.solution = _design_solution(kind, *err.iterate)
        raise
    return _design_solution(kind, info, sol)


def _design_solution(kind: str, info, sol) -> DesignSdpSolution:
    if kind == "switched":
        return DesignSdpSolution(t=float(sol.t), W=sol.Z, Y=sol.Y, S=sol.S, duals=sol.duals, info=info)
    return DesignSdpSolution(t=float(sol.t), W=sol.W, Y=sol.Y, S=None, duals=sol.duals, info=info)


def check_size(modes: ModeSet, solver: str) -> None:
    """Refuse the design when the solver that will run it (the IPM's own estimate, or Clarabel's) lacks memory."""
    n, m, S, J = modes.n_states, modes.n_inputs, modes.n_modes, modes.n_free_gains
    ipm_bytes = None
    if resolve_solver(solver, "lmi", S) == "IPM":  # W symmetric, Y_j; one block of side 2n per mode
        ipm_bytes = ipm_memory(n * n + J * m * n + 1, n * (n + 1) // 2 + J * m * n, S, 2 * n, n * n)
    check_memory([2 * n] * S, "lmi", ipm_bytes)


def run(modes: ModeSet, options: DesignOptions) -> DesignResult:
    check_size(modes, options.solver)
    return run_one_shot(modes, "lmi", options, solve_sdp)
