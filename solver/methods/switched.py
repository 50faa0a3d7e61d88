"""Switched-Lyapunov design (DESIGN.md section 3; Daafouz, Riedinger, Iung 2002).

One common slack ``Z`` (the gains are common to all modes) and one ``S_s``
per mode s; for every pair of modes (s, t)::

    [[rho_s (Z + Z^T - S_s), (A_s Z)^T], [A_s Z, S_t]] >= t I
    A_s Z = free_s Z + sum_j coef_{s,j} Y_j,     Theta_j = Y_j Z^{-1}

Then ``P_s = S_s^{-1}`` satisfies ``A_s^T P_t A_s - rho_s P_s < 0`` for all
pairs: ``V = x^T P_s x`` (s the mode of the interval about to start) decreases
whatever the losses and jumps do.  With ``Z = S_s = W`` this contains the
``lmi`` design, so it stabilizes every family ``lmi`` does, and more.
Normalized by ``trace(Z + Z^T) = 2n`` (so t <= 1); a design with the margin
exists iff ``t* > margin``.  The certificate is re-checked in float64 for all
S^2 pairs.
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np

from .. import ipm
from ..compiled import CompiledProblem, block, check_memory, schur_block
from ..errors import InvalidInput
from ..network import ModeSet
from ..result import DesignResult
from .common import DesignOptions, RunClock, certify_gains, conclude_one_shot
from .lmi import compiled_for, plant_values

#: Pairwise constraints grow as S^2; refuse beyond this many modes.
MAX_MODES = 128


def build(n: int, m: int, S: int, J: int, active: np.ndarray) -> CompiledProblem:
    Z = cp.Variable((n, n))
    Sm = [cp.Variable((n, n), symmetric=True) for _ in range(S)]
    Y = [cp.Variable((m, n)) for _ in range(J)]
    t = cp.Variable()
    free = cp.Parameter((S * n, n))
    coef = cp.Parameter((S * J * n, m))
    rho = cp.Parameter(S, nonneg=True)
    eye2 = np.eye(2 * n)
    cons = [cp.trace(Z + Z.T) == 2 * n]
    for s in range(S):
        AZ = block(free, s, n) @ Z
        for j in range(J):
            if active[s, j]:
                AZ = AZ + block(coef, s * J + j, n) @ Y[j]
        for u in range(S):
            cons.append(schur_block(rho[s] * (Z + Z.T - Sm[s]), AZ, Sm[u]) - t * eye2 >> 0)
    prob = cp.Problem(cp.Maximize(t), cons)
    return CompiledProblem(prob, {"free": free, "coef": coef, "rho": rho}, {"Z": Z, "S": Sm, "Y": Y, "t": t})


def run(modes: ModeSet, options: DesignOptions) -> DesignResult:
    if modes.n_modes > MAX_MODES:
        raise InvalidInput(
            f"the switched design has {modes.n_modes}^2 pairwise LMIs; at most {MAX_MODES} modes are allowed",
            ("n_drop",),
        )
    check_memory([2 * modes.n_states] * modes.n_modes**2, "switched")
    clock = RunClock()
    if options.solver == "IPM":  # the structured interior-point solver, solver/ipm.py
        info, sol = ipm.design_solve(modes, "switched", options.rho(modes), options.time_limit)
        t, Z, Y, S_all = sol.t, sol.Z, sol.Y, sol.S
    else:
        compiled, clock.cached, clock.setup = compiled_for(modes, "switched", build)
        values = plant_values(modes)
        values["rho"] = options.rho(modes)
        info = compiled.solve(values, solver=options.solver, time_limit=options.time_limit)
        t = float(compiled.value("t"))
        Z, Y, S_all = compiled.value("Z"), np.stack(compiled.value("Y")), np.stack(compiled.value("S"))
    clock.add(info)
    if t <= options.margin:
        return conclude_one_shot(modes, "switched", options, clock, info, t,
                                 infeasible="no switched-Lyapunov design with a common slack exists")
    theta = np.linalg.solve(Z.T, np.swapaxes(Y, 1, 2)).swapaxes(1, 2)  # Theta_j = Y_j Z^{-1}
    gains = modes.expand(theta)
    P = np.linalg.inv(S_all)
    cert, A = certify_gains(modes, gains, options, clock, candidate=P, candidate_kind="switched",
                            candidate_source="switched")
    return conclude_one_shot(modes, "switched", options, clock, info, t, gains=gains, cert=cert, A=A)
