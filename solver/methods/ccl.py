"""The paper's design: cone complementarity linearization (Theorem 2, Sec. III.D).

Find ``P, Q > 0`` (size n*n_drop) and gains K with, for every mode s::

    [[P, Phi_s^T], [Phi_s, Q]] >= margin I     (13)  (the paper's form times -1)
    [[P, I], [I, Q]] >= 0                        (15)

Step 1 finds a feasible start; Step 2 solves ``min trace(P Q_k + P_k Q)``
and repeats.  The paper's Step 3 test ``|trace(P Q_k + P_k Q)| < delta``
cannot fire (the objective tends to ``2 n n_drop``, docs/design.md §3.4), so we
stop at the first Step 2 iterate whose gains satisfy Theorem 1: the iterate's
own P is re-checked in float64, and if it fails, Theorem 1 is solved as an
LMI with the gains fixed.  The iteration cap bounds the loop.

Step 1 is always feasible (``P = Q = c I`` with c large), so CCL can never
prove that no design exists: where none does it ends ``not_converged``.
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np

from ..compiled import CompiledProblem, block, check_memory, schur_block
from ..errors import SolverFailed
from ..network import ModeSet
from ..result import DesignResult, IterationRecord
from .common import DesignOptions, RunClock, certify_gains, finish, is_time_limit
from .lmi import compiled_for, plant_values


def build(n: int, m: int, S: int, J: int, active: np.ndarray, n_drop: int) -> CompiledProblem:
    """One DPP problem serving Step 1 and Step 2.

    The objective is ``trace(P Q_k + P_k Q) + start_weight * trace(P + Q)``:
    Step 1 sets ``P_k = Q_k = 0`` (and ``start_weight`` 0 for the paper's pure
    feasibility start, 1 for a bounded start), Step 2 sets the last iterate.
    """
    N = n_drop
    size = n * N
    P = cp.Variable((size, size), symmetric=True)
    Q = cp.Variable((size, size), symmetric=True)
    theta = [cp.Variable((m, n)) for _ in range(J)]
    P_k = cp.Parameter((size, size), symmetric=True)
    Q_k = cp.Parameter((size, size), symmetric=True)
    start_weight = cp.Parameter(nonneg=True)
    margin = cp.Parameter(nonneg=True)
    free = cp.Parameter((S * n, n))
    coef = cp.Parameter((S * J * n, m))
    eye_n = np.eye(n)
    zero_n = np.zeros((n, n))
    eye_2 = np.eye(2 * size)
    # Rows 2..N of Phi (eq. 10) do not depend on the gains: they shift the stacked past states.
    shift_rows = [[eye_n if col == row - 1 else zero_n for col in range(N)] for row in range(1, N)]
    cons = [schur_block(P, np.eye(size), Q) >> 0]  # (15)
    for s in range(S):
        A_s = block(free, s, n)
        for j in range(J):
            if active[s, j]:
                A_s = A_s + block(coef, s * J + j, n) @ theta[j]
        Phi = cp.bmat([[A_s] + [zero_n] * (N - 1)] + shift_rows) if N > 1 else A_s
        cons.append(schur_block(P, Phi, Q) - margin * eye_2 >> 0)  # (13)
    objective = cp.sum(cp.multiply(P, Q_k)) + cp.sum(cp.multiply(P_k, Q)) + start_weight * (cp.trace(P) + cp.trace(Q))
    params = {"P_k": P_k, "Q_k": Q_k, "start_weight": start_weight, "margin": margin, "free": free, "coef": coef}
    return CompiledProblem(cp.Problem(cp.Minimize(objective), cons), params, {"P": P, "Q": Q, "theta": theta})


def run(modes: ModeSet, options: DesignOptions) -> DesignResult:
    check_memory([2 * modes.n_states * modes.n_drop] * (modes.n_modes + 1), "ccl")
    clock = RunClock()
    n_drop = modes.n_drop
    compiled, clock.cached, clock.setup = compiled_for(
        modes, ("ccl", n_drop), lambda n, m, S, J, active: build(n, m, S, J, active, n_drop)
    )
    size = modes.n_states * n_drop
    values = plant_values(modes)
    values.update(
        margin=options.margin,
        P_k=np.zeros((size, size)),
        Q_k=np.zeros((size, size)),
        start_weight=1.0 if options.ccl_start == "min_trace" else 0.0,
    )
    history: list[IterationRecord] = []
    gains = cert = A = None
    status = ""
    outcome = "not_converged"
    message = f"iteration cap of {options.max_iter} reached without a certified iterate"
    for k in range(options.max_iter + 1):
        remaining = clock.remaining(options.time_limit)
        if remaining is not None and remaining <= 0:
            message = f"time limit reached ({options.time_limit:g} s) after {len(history)} solved iterations"
            break
        try:
            info = compiled.solve(values, solver=options.solver, time_limit=remaining)
        except SolverFailed as err:
            if not is_time_limit(err, options, clock):
                raise
            message = (f"time limit reached ({options.time_limit:g} s) inside the solver after {len(history)} "
                       "solved iterations; the last iterate is returned")
            break
        clock.add(info)
        status = info.status
        P = compiled.value("P")
        Q = compiled.value("Q")
        gains = modes.expand(np.stack(compiled.value("theta")))
        cert, A = certify_gains(modes, gains, options, clock, candidate=P, candidate_kind="augmented",
                                candidate_source="ccl_iterate")
        record = IterationRecord(
            iteration=k,
            objective=info.objective,
            trace_gap=float(np.sum(P * Q)) / size - 1.0,
            theorem1=cert is not None,
            certificate_margin=None if cert is None else cert.margin,
            solve_time=info.solve_time,
            elapsed=clock.elapsed,
        )
        history.append(record)
        stop_requested = bool(options.callback(record)) if options.callback is not None else False
        # The stop rule applies to Step 2 iterates (k >= 1), as the paper's Step 3 does.
        if k >= 1 and cert is not None:
            outcome = "stabilized"
            message = f"Theorem 1 holds after {k} CCL iterations (certificate from {cert.source})"
            break
        if stop_requested:
            message = f"stopped by callback after iteration {k}"
            break
        values["P_k"], values["Q_k"] = 0.5 * (P + P.T), 0.5 * (Q + Q.T)
        values["start_weight"] = 0.0
    if outcome != "stabilized":
        cert = None
    return finish(modes, "ccl", outcome, gains, cert, A, clock, options.solver, status, message, history, options)
