"""The paper's design: cone complementarity linearization (Theorem 2, Sec. III.D).

Find ``P, Q > 0`` (size n*n_drop) and gains K with, for every mode s = (l, eta)::

    [[P, Phi_s^T], [Phi_s, Q]] >= margin I     (13)  (the paper's form times -1)
    [[P, I], [I, Q]] >= 0                        (15)

Step 1 finds a feasible start; Step 2 solves ``min trace(P Q_k + P_k Q)``
and repeats.  The paper's Step 3 test ``|trace(P Q_k + P_k Q)| < delta``
cannot fire (the objective tends to ``2 n n_drop``, DESIGN.md section 3), so we
stop at the first Step 2 iterate whose gains satisfy Theorem 1: the iterate's
own P is re-checked in float64, and if it fails, Theorem 1 is solved as an
LMI with the gains fixed.  The iteration cap bounds the loop.

Step 1 is always feasible (``P = Q = c I`` with c large), so CCL can never
prove that no design exists: where none does it ends ``not_converged``.
"""

from __future__ import annotations

import time

import cvxpy as cp
import numpy as np

from ..compiled import CompiledProblem, block, problem_cache, schur_block
from ..network import IntervalData, spectral_radii
from ..plant import PlantFamily
from ..result import DesignResult, IterationRecord
from .common import DesignOptions, RunClock, certify_gains


def build(n: int, m: int, r: int, n_drop: int) -> CompiledProblem:
    """One DPP problem serving Step 1 and Step 2.

    The objective is ``trace(P Q_k + P_k Q) + start_weight * trace(P + Q)``:
    Step 1 sets ``P_k = Q_k = 0`` (and ``start_weight`` 0 for the paper's pure
    feasibility start, 1 for a bounded start), Step 2 sets the last iterate.
    """
    N = n_drop
    size = n * N
    P = cp.Variable((size, size), symmetric=True)
    Q = cp.Variable((size, size), symmetric=True)
    K = [cp.Variable((m, n)) for _ in range(N)]
    P_k = cp.Parameter((size, size), symmetric=True)
    Q_k = cp.Parameter((size, size), symmetric=True)
    start_weight = cp.Parameter(nonneg=True)
    margin = cp.Parameter(nonneg=True)
    F_pow = cp.Parameter((r * N * n, n))  # row block l*N + eta-1: F_l^eta
    FtG = cp.Parameter((r * N * n, m))  # row block l*N + t: F_l^t G_l
    eye_n = np.eye(n)
    zero_n = np.zeros((n, n))
    eye_2 = np.eye(2 * size)
    # Rows 2..N of Phi (eq. 10) do not depend on the gains: shift the stacked past states.
    shift_rows = [[eye_n if col == row - 1 else zero_n for col in range(N)] for row in range(1, N)]
    cons = [schur_block(P, np.eye(size), Q) >> 0]  # (15)
    for l in range(r):
        for eta in range(1, N + 1):
            A_s = block(F_pow, l * N + eta - 1, n) + sum(block(FtG, l * N + s, n) @ K[eta - s - 1] for s in range(eta))
            Phi = cp.bmat([[A_s] + [zero_n] * (N - 1)] + shift_rows) if N > 1 else A_s
            cons.append(schur_block(P, Phi, Q) - margin * eye_2 >> 0)  # (13)
    objective = cp.sum(cp.multiply(P, Q_k)) + cp.sum(cp.multiply(P_k, Q)) + start_weight * (cp.trace(P) + cp.trace(Q))
    prob = cp.Problem(cp.Minimize(objective), cons)
    params = {
        "P_k": P_k,
        "Q_k": Q_k,
        "start_weight": start_weight,
        "margin": margin,
        "F_pow": F_pow,
        "FtG": FtG,
    }
    return CompiledProblem(prob, params, {"P": P, "Q": Q, "K": K})


def compiled_for(family: PlantFamily, n_drop: int) -> tuple[CompiledProblem, bool, float]:
    r, n, m = family.n_modes, family.n_states, family.n_inputs
    start = time.perf_counter()
    compiled, cached = problem_cache.get(("ccl", n, m, r, n_drop), lambda: build(n, m, r, n_drop))
    return compiled, cached, (0.0 if cached else time.perf_counter() - start)


def run(family: PlantFamily, n_drop: int, options: DesignOptions) -> DesignResult:
    clock = RunClock()
    data = IntervalData.from_family(family, n_drop)
    compiled, clock.cached, clock.setup = compiled_for(family, n_drop)
    r, n, m = family.n_modes, family.n_states, family.n_inputs
    size = n * n_drop
    values = {
        "F_pow": data.F_pow.reshape(r * n_drop * n, n),
        "FtG": data.FtG.reshape(r * n_drop * n, m),
        "margin": options.margin,
        "P_k": np.zeros((size, size)),
        "Q_k": np.zeros((size, size)),
        "start_weight": 1.0 if options.ccl_start == "min_trace" else 0.0,
    }
    history: list[IterationRecord] = []
    gains = None
    cert = None
    A = None
    status = ""
    message = ""
    outcome = "not_converged"
    for k in range(options.max_iter + 1):
        remaining = clock.remaining(options.time_limit)
        if remaining is not None and remaining <= 0:
            message = f"time limit of {options.time_limit:g} s reached after {k - 1} iterations"
            break
        info = compiled.solve(values, solver=options.solver, time_limit=remaining)
        clock.add(info)
        status = info.status
        P = compiled.value("P")
        Q = compiled.value("Q")
        gains = np.stack(compiled.value("K"))
        cert, A = certify_gains(
            data, gains, options, clock, candidate=P, candidate_source="ccl_iterate", candidate_is_reduced=False
        )
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
    else:
        message = f"iteration cap of {options.max_iter} reached without a certified iterate"
    if outcome != "stabilized":
        cert = None
    return DesignResult(
        outcome=outcome,
        gains=gains,
        certificate=cert,
        method="ccl",
        n_drop=n_drop,
        history=history,
        solver=options.solver,
        solver_status=status,
        timings=clock.timings(),
        message=message,
        spectral_radii=None if A is None else spectral_radii(A),
    )
