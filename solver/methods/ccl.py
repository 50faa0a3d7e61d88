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

``solver="IPM"`` solves every SDP with the structured interior-point solver
(:func:`ipm_problem`, started at that ``P = Q = c I``, gains 0); its Step 1 is
always the min-trace start (``ccl_start`` is ignored), since a zero-objective
feasibility SDP has no unique answer.  The certify path is the same.
``solver="AUTO"`` takes the IPM except for a paper-sized problem with the
feasibility start (:func:`solver.compiled.resolve_solver`).
"""

from __future__ import annotations

import time

import numpy as np

from .. import ipm
from ..compiled import cp  # cvxpy, imported on first use
from ..compiled import CompiledProblem, block, check_memory, resolve_solver, schur_block
from ..errors import SolverFailed
from ..network import ModeSet, augmented_matrices
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


def ipm_problem(free: np.ndarray, coef: np.ndarray, active: np.ndarray | None, n_drop: int, margin: float,
                P_k: np.ndarray, Q_k: np.ndarray, start_weight: float, V0: list | None = None) -> ipm.BlockLMI:
    """The CCL SDP of :func:`build` as an :class:`solver.ipm.BlockLMI` with a linear objective.

    ``min <Q_k + w I, P> + <P_k + w I, Q>`` s.t. block 0 ``[[P, I], [I, Q]] >= 0`` (15) and
    block ``1 + s`` ``[[P, Phi_s^T], [Phi_s, Q]] - margin I >= 0`` (13).  ``P``, ``Q`` enter as
    ``L V L^T`` placements; the gains (``theta``, shape (J m, n), columns already scaled as
    ``coef``) through ``[0; E_1 coef_s] theta [I_n 0 ...]`` (the top-left block of ``Phi_s``).

    ``V0 = [P0, Q0, theta0]`` must be strictly feasible (default ``P0 = Q0 = c I``, ``theta0 = 0``
    with ``c`` large enough): the solver starts there and keeps every iterate strictly feasible.
    """
    free = np.asarray(free, dtype=np.float64)
    coef = np.asarray(coef, dtype=np.float64)
    S, n, _ = free.shape
    J, m = coef.shape[1], coef.shape[3]
    size = n * n_drop
    k = 2 * size
    nb = S + 1
    Phi0 = augmented_matrices(free, n_drop)  # (S, size, size), gains 0
    if V0 is None:
        c = margin + 1.0 + 2.0 * float(max(np.linalg.norm(Phi0, 2, axis=(1, 2)).max(), 1.0))
        V0 = [c * np.eye(size), c * np.eye(size)] + ([np.zeros((J * m, n))] if J * m > 0 else [])
    P0, Q0 = V0[0], V0[1]
    top = np.zeros((k, size))
    top[:size] = np.eye(size)
    bot = np.zeros((k, size))
    bot[size:] = np.eye(size)
    variables = [ipm.MatrixVariable("P", (size, size), size, [(np.broadcast_to(top, (nb, k, size)), None, 1.0)]),
                 ipm.MatrixVariable("Q", (size, size), size, [(np.broadcast_to(bot, (nb, k, size)), None, 1.0)])]
    Phi = Phi0.copy()
    if J * m > 0:
        gL = ipm._gain_L(coef, active)  # (S, n, J m)
        L = np.zeros((nb, k, J * m))
        L[1:, size:size + n] = gL
        R = np.zeros((nb, n, k))
        R[:, :, :n] = np.eye(n)
        variables.append(ipm.MatrixVariable("theta", (J * m, n), None, [(L, R, 1.0)]))
        Phi[:, :n, :n] += gL @ V0[2]
    C = np.empty((nb, k, k))
    C[:, :size, :size] = P0
    C[:, size:, size:] = Q0
    C[0, size:, :size] = np.eye(size)
    C[0, :size, size:] = np.eye(size)
    C[1:, size:, :size] = Phi
    C[1:, :size, size:] = np.swapaxes(Phi, 1, 2)
    C[1:] -= margin * np.eye(k)
    w = float(start_weight)
    obj = [(Q_k + w * np.eye(size)).ravel(), (P_k + w * np.eye(size)).ravel()]
    if J * m > 0:
        obj.append(np.zeros(J * m * n))
    return ipm.BlockLMI(C=C, variables=variables, V0=list(V0), objective=np.concatenate(obj))


def _solve_ipm(modes: ModeSet, values: dict, n_drop: int, time_limit: float | None, V0: list | None = None):
    """One CCL SDP with the structured IPM: ``(info, P, Q, theta (J, m, n), V)``."""
    from ..compiled import SolveInfo
    from ..errors import SolverFailed

    start = time.perf_counter()
    coef0, active = modes.scheme_coef()
    coef_s, gscale = ipm._gain_scale(coef0)
    prob = ipm_problem(modes.free, coef_s, active, n_drop, values["margin"], values["P_k"], values["Q_k"],
                       values["start_weight"], V0)
    sol = ipm.solve_block_lmi(prob, ipm.IPMOptions(time_limit=time_limit))
    status = {"optimal": "optimal", "inaccurate": "optimal_inaccurate"}.get(sol.status)
    if status is None:  # the iterate is strictly feasible whatever the status, but a time limit or breakdown ends the run
        raise SolverFailed(f"IPM ended with status {sol.status!r} after {sol.iterations} iterations "
                           f"(primal residual {sol.primal_residual:.1e}, gap {sol.gap:.1e})", status=sol.status)
    P = 0.5 * (sol.V[0] + sol.V[0].T)
    Q = 0.5 * (sol.V[1] + sol.V[1].T)
    J, m, n = modes.n_free_gains, modes.n_inputs, modes.n_states
    theta = ipm._split_Y(sol.V[2] if len(sol.V) > 2 else None, J, m, n, gscale)
    objective = float(prob.objective @ np.concatenate([v.ravel() for v in sol.V]))
    info = SolveInfo(status=status, solver="IPM", solve_time=sol.timings["total"],
                     wall_time=time.perf_counter() - start, objective=objective, iterations=sol.iterations)
    return info, P, Q, theta, sol.V


def _check_ipm_memory(modes: ModeSet, size: int) -> None:
    """The IPM's dense Schur complement (full and reduced coordinates) and its Kronecker pieces."""
    from .. import compiled as _compiled
    from ..errors import InvalidInput

    gains = modes.n_free_gains * modes.n_inputs * modes.n_states
    full = 2 * size * size + gains
    p = size * (size + 1) + gains
    need = 8 * (2 * full * full + 2 * p * p + 6 * size**4 + 12 * (modes.n_modes + 1) * (2 * size) ** 2)
    if need > _compiled.MAX_SOLVER_MEMORY:
        raise InvalidInput(
            f"the ccl SDP would need about {need / 2**30:.1f} GiB of IPM memory (limit "
            f"{_compiled.MAX_SOLVER_MEMORY / 2**30:.1f} GiB): use fewer modes, a smaller n_drop or the lmi method",
            ("n_drop",),
        )


def run(modes: ModeSet, options: DesignOptions) -> DesignResult:
    size = modes.n_states * modes.n_drop
    solver = resolve_solver(options.solver, "ccl", ccl_side=2 * size, ccl_start=options.ccl_start)
    use_ipm = solver == "IPM"
    if use_ipm:  # structured IPM: the Schur complement over the symmetric P, Q and the gains, dense
        _check_ipm_memory(modes, size)
    else:
        check_memory([2 * modes.n_states * modes.n_drop] * (modes.n_modes + 1), "ccl")
    clock = RunClock()
    n_drop = modes.n_drop
    if not use_ipm:
        compiled, clock.cached, clock.setup = compiled_for(
            modes, ("ccl", n_drop), lambda n, m, S, J, active: build(n, m, S, J, active, n_drop)
        )
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
            if use_ipm:
                # Step 1 as a pure feasibility problem has no unique answer (Clarabel returns a point of
                # its own central path; an IPM with a zero objective would stay at its start), so the
                # IPM path always takes the bounded min-trace start: a feasible point, as Step 1 asks.
                info, P, Q, theta, _ = _solve_ipm(modes, dict(values, start_weight=1.0) if k == 0 else values,
                                                  n_drop, remaining)
            else:
                info = compiled.solve(values, solver=solver, time_limit=remaining)
                P = compiled.value("P")
                Q = compiled.value("Q")
                theta = np.stack(compiled.value("theta"))
        except SolverFailed as err:
            if not is_time_limit(err, options, clock):
                raise
            message = (f"time limit reached ({options.time_limit:g} s) inside the solver after {len(history)} "
                       "solved iterations; the last iterate is returned")
            break
        clock.add(info)
        status = info.status
        gains = modes.expand(theta)
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
    return finish(modes, "ccl", outcome, gains, cert, A, clock, solver, status, message, history, options)
