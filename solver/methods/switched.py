"""Switched-Lyapunov design (docs/design.md; Daafouz, Riedinger, Iung 2002).

One common slack ``Z`` (the gains are common to all modes) and one ``S_s``
per mode s; in the congruent form (data of mode s multiplied by
``c_s = lambda^(-eta_s)``), for every pair of modes (s, u)::

    [[Z + Z^T - S_s, c_s (A_s Z)^T], [c_s A_s Z, S_u]] >= t I
    A_s Z = free_s Z + sum_j coef_{s,j} Y_j,     Theta_j = Y_j Z^{-1}

Then ``P_s = S_s^{-1}`` satisfies ``A_s^T P_u A_s - rho_s P_s < 0`` for all
pairs (``rho_s = lambda^(2 eta_s)``): ``V = x^T P_s x`` (s the mode of the
interval about to start) decreases whatever the losses and jumps do.  With
``Z = S_s = W`` this contains the ``lmi`` design.  Normalized by
``trace(Z + Z^T) = 2n`` (so t <= 1).  Gains are accepted by the float64
re-check for all S^2 pairs; t* <= 0 is called infeasible only with the
multipliers re-checked by :func:`solver.certificates.check_farkas_switched`.
"""

from __future__ import annotations

import numpy as np

from ..compiled import cp  # cvxpy, imported on first use
from ..compiled import CompiledProblem, DesignSdpSolution, block, check_memory, ipm_memory, resolve_solver
from ..errors import InvalidInput
from ..network import ModeSet
from ..result import DesignResult
from .common import DesignOptions, run_one_shot
from .lmi import compiled_for, ipm_sdp, plant_values

#: Pairwise constraints grow as S^2; refuse beyond this many modes.
MAX_MODES = 128


def build(n: int, m: int, S: int, J: int, active: np.ndarray) -> CompiledProblem:
    Z = cp.Variable((n, n))
    Sm = [cp.Variable((n, n), symmetric=True) for _ in range(S)]
    Y = [cp.Variable((m, n)) for _ in range(J)]
    t = cp.Variable()
    free = cp.Parameter((S * n, n))
    coef = cp.Parameter((S * J * n, m))
    eye2 = np.eye(2 * n)
    cons = [cp.trace(Z + Z.T) == 2 * n]
    blocks = []
    for s in range(S):
        AZ = block(free, s, n) @ Z
        for j in range(J):
            if active[s, j]:
                AZ = AZ + block(coef, s * J + j, n) @ Y[j]
        for u in range(S):
            blocks.append(cp.bmat([[Z + Z.T - Sm[s], AZ.T], [AZ, Sm[u]]]) - t * eye2 >> 0)
    prob = cp.Problem(cp.Maximize(t), cons + blocks)
    return CompiledProblem(prob, {"free": free, "coef": coef},
                           {"Z": Z, "S": Sm, "Y": Y, "t": t, "blocks": blocks})


def solve_sdp(modes: ModeSet, scale: np.ndarray, solver: str = "AUTO", time_limit: float | None = None,
              clock=None) -> DesignSdpSolution:
    """Solve the congruent switched SDP once; ``duals`` has S^2 blocks, pair (s, u) at ``s * S + u``."""
    solver = resolve_solver(solver, "switched", modes.n_modes)
    if solver == "IPM":  # the structured interior-point solver (solver/ipm/), same SDP and dual convention
        return ipm_sdp(modes, "switched", scale, time_limit)
    compiled, cached, setup = compiled_for(modes, "switched", build)
    if clock is not None:
        clock.cached, clock.setup = clock.cached and cached, clock.setup + setup
    info = compiled.solve(plant_values(modes, scale), solver=solver, time_limit=time_limit)
    return DesignSdpSolution(
        t=float(compiled.value("t")), W=compiled.value("Z"), Y=np.stack(compiled.value("Y")),
        S=np.stack(compiled.value("S")), duals=compiled.duals("blocks"), info=info,
    )


def run(modes: ModeSet, options: DesignOptions) -> DesignResult:
    if modes.n_modes > MAX_MODES:
        raise InvalidInput(
            f"the switched design has {modes.n_modes}^2 pairwise LMIs; at most {MAX_MODES} modes are allowed",
            ("n_drop",),
        )
    n, m, S, J = modes.n_states, modes.n_inputs, modes.n_modes, modes.n_free_gains
    ipm_bytes = None
    if resolve_solver(options.solver, "switched", S) == "IPM":  # Z general, S_s stacked, Y_j; S^2 blocks
        ipm_bytes = ipm_memory(n * n + S * n * n + J * m * n + 1, n * n + S * n * (n + 1) // 2 + J * m * n,
                               S * S, 2 * n, S * n * n)
    check_memory([2 * n] * S**2, "switched", ipm_bytes)
    return run_one_shot(modes, "switched", options, solve_sdp)
