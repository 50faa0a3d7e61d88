"""The baselines: what a user would write from the paper with plain cvxpy.

Nothing here is cached or parametrized: every iteration builds a fresh
``cp.Problem`` from numpy constants and calls ``solve()``, so cvxpy
canonicalizes it again each time.  The formulations are the same as the
library's (same constraints, same margin, same objective, same solver with
its default settings), so the difference in wall time is the cost of
rebuilding, not of solving a different problem.  The Clarabel time of every
solve is recorded too, to show that the two solve the same SDPs.

* :func:`ccl_rebuild` - the paper's CCL (Sec. III.D): Step 1 feasibility,
  then Step 2 ``min trace(P Q_k + P_k Q)`` subject to (13) and (15) for all
  plants and all eta; stop at the first Step 2 iterate whose gains satisfy
  Theorem 1, checked by the eigenvalues of the iterate's own P.
* :func:`lmi_rebuild` - the exact convex design of docs/design.md §3.1 built
  once and solved once (``max t`` s.t. the LMIs, ``trace W = n``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np


@dataclass
class HandResult:
    """What a hand-written run did: outcome, iterations, wall and Clarabel time."""

    outcome: str
    gains: np.ndarray | None
    iterations: int  # solves of the CCL SDP (Step 1 counts as one), 1 for lmi
    wall: float
    solver_time: float  # sum of Clarabel's own solve times
    solve_times: list = field(default_factory=list)
    message: str = ""


def _closed_loop(F, G, K, eta):
    """A_{l,eta}(K) = F^eta + sum_{t=0}^{eta-1} F^t G K_{eta-t} (eq. 8); K is a list K_1..K_N."""
    A = np.linalg.matrix_power(F, eta)
    for t in range(eta):
        A = A + np.linalg.matrix_power(F, t) @ G @ K[eta - t - 1]
    return A


def _augmented(A, n, N):
    """Phi (eq. 10) as a numpy array or a cvxpy expression."""
    if N == 1:
        return A
    I, Z = np.eye(n), np.zeros((n, n))
    rows = [[A] + [Z] * (N - 1)]
    for i in range(1, N):
        rows.append([I if j == i - 1 else Z for j in range(N)])
    return cp.bmat(rows) if isinstance(A, cp.Expression) else np.block(rows)


def theorem1_holds(F_list, G_list, K, P, N) -> bool:
    """Theorem 1 with the iterate's P: P > 0 and Phi^T P Phi - P < 0 for every (l, eta)."""
    n = F_list[0].shape[0]
    P = 0.5 * (P + P.T)
    if np.linalg.eigvalsh(P)[0] <= 0:
        return False
    for F, G in zip(F_list, G_list):
        for eta in range(1, N + 1):
            Phi = _augmented(_closed_loop(F, G, K, eta), n, N)
            D = Phi.T @ P @ Phi - P
            if np.linalg.eigvalsh(0.5 * (D + D.T))[-1] >= 0:
                return False
    return True


def ccl_rebuild(family, n_drop, margin=1e-6, max_iter=50, time_limit=None) -> HandResult:
    """The paper's CCL loop, rebuilding the cvxpy problem at every iteration."""
    F_list, G_list = [np.asarray(F) for F in family.F], [np.asarray(G) for G in family.G]
    n, m, N = F_list[0].shape[0], G_list[0].shape[1], n_drop
    size = n * N
    start = time.perf_counter()
    P_k = Q_k = None
    solve_times = []
    K_val = None
    for k in range(max_iter + 1):
        opts = {}
        if time_limit is not None:
            left = time_limit - (time.perf_counter() - start)
            if left <= 0:
                return HandResult("not_converged", K_val, k, time.perf_counter() - start, sum(solve_times),
                                  solve_times, "time limit")
            opts["time_limit"] = left
        P = cp.Variable((size, size), symmetric=True)
        Q = cp.Variable((size, size), symmetric=True)
        K = [cp.Variable((m, n)) for _ in range(N)]
        cons = [cp.bmat([[P, np.eye(size)], [np.eye(size), Q]]) >> 0]  # (15)
        for F, G in zip(F_list, G_list):
            for eta in range(1, N + 1):
                Phi = _augmented(_closed_loop(F, G, K, eta), n, N)
                cons.append(cp.bmat([[P, Phi.T], [Phi, Q]]) >> margin * np.eye(2 * size))  # (13), times -1
        if k == 0:
            objective = cp.Minimize(0)  # Step 1: feasibility
        else:
            objective = cp.Minimize(cp.trace(P @ Q_k) + cp.trace(P_k @ Q))  # Step 2
        prob = cp.Problem(objective, cons)
        prob.solve(solver=cp.CLARABEL, **opts)
        solve_times.append(prob.solver_stats.solve_time)
        if prob.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
            return HandResult("solver_failed", None, k + 1, time.perf_counter() - start, sum(solve_times),
                              solve_times, prob.status)
        K_val = [Kq.value for Kq in K]
        if k >= 1 and theorem1_holds(F_list, G_list, K_val, P.value, N):
            return HandResult("stabilized", np.stack(K_val), k + 1, time.perf_counter() - start,
                              sum(solve_times), solve_times, f"Theorem 1 holds after {k} iterations")
        P_k, Q_k = P.value, Q.value
    return HandResult("not_converged", np.stack(K_val), max_iter + 1, time.perf_counter() - start,
                      sum(solve_times), solve_times, "iteration cap")


def lmi_rebuild(family, n_drop, margin=1e-6) -> HandResult:
    """The exact convex design, built from numpy constants and solved once."""
    F_list, G_list = [np.asarray(F) for F in family.F], [np.asarray(G) for G in family.G]
    n, m, N = F_list[0].shape[0], G_list[0].shape[1], n_drop
    start = time.perf_counter()
    W = cp.Variable((n, n), symmetric=True)
    Y = [cp.Variable((m, n)) for _ in range(N)]
    t = cp.Variable()
    cons = [cp.trace(W) == n]
    for F, G in zip(F_list, G_list):
        for eta in range(1, N + 1):
            AW = np.linalg.matrix_power(F, eta) @ W
            for s in range(eta):
                AW = AW + np.linalg.matrix_power(F, s) @ G @ Y[eta - s - 1]
            cons.append(cp.bmat([[W, AW.T], [AW, W]]) >> t * np.eye(2 * n))
    prob = cp.Problem(cp.Maximize(t), cons)
    prob.solve(solver=cp.CLARABEL)
    st = prob.solver_stats.solve_time
    if prob.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        return HandResult("solver_failed", None, 1, time.perf_counter() - start, st, [st], prob.status)
    if t.value <= margin:
        return HandResult("infeasible", None, 1, time.perf_counter() - start, st, [st])
    Wv = 0.5 * (W.value + W.value.T)
    K = [np.linalg.solve(Wv, Yq.value.T).T for Yq in Y]  # K_q = Y_q W^{-1}
    X = np.linalg.inv(Wv)
    ok = all(
        np.linalg.eigvalsh(X - A.T @ X @ A)[0] > 0
        for F, G in zip(F_list, G_list)
        for A in (_closed_loop(F, G, K, eta) for eta in range(1, N + 1))
    )
    return HandResult("stabilized" if ok else "not_converged", np.stack(K), 1, time.perf_counter() - start, st, [st])
