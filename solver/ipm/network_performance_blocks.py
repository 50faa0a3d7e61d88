"""The network performance designs' SDPs as grouped structured LMIs (docs/design.md §11.3, "On the IPM").

:func:`network_performance_problem` builds the :class:`solver.ipm.model.GroupedLMI` of the cost, l2-gain and
Kothare (cost with input limits) designs on a network automaton, the blocks of
:func:`solver.methods.network_performance.solve` (the cvxpy form Clarabel solves); :func:`solve_network_performance`
solves it (:func:`solver.ipm.algorithm.solve_grouped`) and maps the answer back.  The model only.

Variables: the slack's diagonal blocks ``Z0..Z{zb-1}`` (n x n, general), the node matrices as one stack ``W``
(V k x k, each block reads its row block through a selector, as in :mod:`solver.ipm.network_blocks`), the gains
as one stack ``Y`` (N m x n, each gain's coefficients scaled to unit size), without x0 the start nodes' ``X``
(stack of symmetric n x n) and the scalar ``g`` (the bound; gamma of the Kothare form).  Groups:

=============  =========================================================================  ==================
group          blocks                                                                     side
=============  =========================================================================  ==================
``cost``       ``[[Z + Z' - W_v, (A_e Z)', (L_e Z)'], [A_e Z, W_w, 0], [L_e Z, 0, I]]``   2k + p
               (``g I`` in the corner for the Kothare form), every transition
``hinf``       ``[[Z + Z' - W_v, 0, (A_e Z)', (C_e Z)'], [0, g I, B', D'],                2k + p_w + p
               [A_e Z, B, W_w, 0], [C_e Z, D, 0, I]]``, every transition
``start``      ``[[level, (S x0)'], [S x0, W_v]]`` or ``[[X_v, S'], [S, W_v]]``, start    k + 1 or n + k
               nodes (level ``g``, or 1 for the Kothare form)
``trace``      ``level - trace X_v`` (without x0)                                         1
``input``      ``[[u_i^2, y], [y', Z + Z' - W_v]]`` (Kothare), per node, gain, input       k + 1
=============  =========================================================================  ==================

The cost and output rows of each transition (``[free | coef | D]``, meeting only an identity or ``g I`` on the
diagonal) are replaced by their triangular factor (an orthogonal congruence of the tail rows, exact, as
docs/design.md §8.3.1), padded with zero rows to the group's side.  Phase 1 (``max t``) from ``V = 0``; phase
2 minimizes ``g``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .algorithm import GroupedSolution, IPMOptions, solve_grouped
from .model import BlockGroup, GroupedLMI

__all__ = ["NetworkPerformanceProblem", "NetworkPerformanceSolution", "network_performance_problem",
           "solve_network_performance"]


@dataclass
class NetworkPerformanceProblem:
    """A network performance design's SDP on the structured solver and what maps its answer back.

    Attributes
    ----------
    lmi : GroupedLMI
    gain_scale : ndarray, shape (N,)
        ``Y_j = Y'_j / gain_scale[j]``.
    shape : dict
        ``n, m, N, k, zb, V``.
    input_index : list of (v, j, b, i)
        The ``input`` group's blocks: node v, gain ``K_(j+1)`` reading slack block b, input i.
    start : ndarray of int
        The ``start`` group's node indices.
    """

    lmi: GroupedLMI
    gain_scale: np.ndarray
    shape: dict
    input_index: list
    start: np.ndarray


def _tail(free: np.ndarray, coef: np.ndarray, extra: np.ndarray | None):
    """The triangular factor of the rows ``[free | coef_0 .. coef_(N-1) | extra]`` split back into its parts."""
    N, p, m = coef.shape
    T = np.hstack([free] + [coef[j] for j in range(N)] + ([] if extra is None else [extra]))
    if T.shape[0] > T.shape[1]:
        T = np.linalg.qr(T, mode="r")
    k = free.shape[1]
    c = T[:, k:k + N * m].reshape(T.shape[0], N, m).transpose(1, 0, 2)
    return T[:, :k], c, (None if extra is None else T[:, k + N * m:])


def _transition_group(ch, kind: str, kothare: bool, gs: np.ndarray, strict: float) -> BlockGroup:
    """The ``cost`` or ``hinf`` group: one block per transition (module docstring)."""
    prob = ch.prob
    n, m, N, k, zb = prob.n, prob.m, prob.N, prob.k, prob.zblocks
    E = prob.n_blocks
    rows = ch.cost if kind == "cost" else ch.output
    tails = [_tail(rows[e].free, rows[e].coef, None if kind == "cost" else ch.D[e]) for e in range(E)]
    p = max(t[0].shape[0] for t in tails)
    pw = 0 if kind == "cost" else max(B.shape[1] for B in ch.B)  # lifted: eta p_w columns, padded with zeros
    s = 2 * k + pw + p
    a0, c0 = k + pw, 2 * k + pw  # first row of A_e Z, of the tail
    sa = (1 + strict) if kothare else 1.0
    C = np.zeros((E, s, s))
    Lz = np.zeros((zb, E, s, n))
    Ly = np.zeros((zb, E, s, N * m))
    eye_n = np.eye(n)
    for e in range(E):
        A0 = sa * prob.free[e]
        f, cf, dd = tails[e]
        r = f.shape[0]
        for b in range(zb):
            Eb = np.zeros((k, n))
            Eb[b * n:(b + 1) * n] = eye_n
            Lz[b, e, :k] = Eb
            Lz[b, e, a0:a0 + k] = A0 @ Eb
            Lz[b, e, c0:c0 + r] = f @ Eb
        for j in range(N):
            b = prob.right[e, j]
            if b >= 0:
                Ly[b, e, a0:a0 + k, j * m:(j + 1) * m] = sa * prob.coef[e, j] / gs[j]
            bt = rows[e].right[j]
            if bt >= 0:
                Ly[bt, e, c0:c0 + r, j * m:(j + 1) * m] += cf[j] / gs[j]
        if kind == "hinf":
            B = ch.B[e]
            C[e, a0:a0 + k, k:k + B.shape[1]] = B
            C[e, c0:c0 + r, k:k + dd.shape[1]] = dd
            C[e, k:a0, a0:] = C[e, a0:, k:a0].T
    tail = np.zeros((1, s, s))
    tail[0, c0:, c0:] = np.eye(p)
    scalars = {}
    if kind == "cost" and kothare:
        scalars["g"] = np.broadcast_to(tail, (E, s, s))
    else:
        C += tail
    if kind == "hinf":
        D = np.zeros((1, s, s))
        D[0, k:a0, k:a0] = np.eye(pw)
        scalars["g"] = np.broadcast_to(D, (E, s, s))
    terms = {}
    for b in range(zb):
        R = np.zeros((n, s))
        R[:, b * n:(b + 1) * n] = eye_n
        terms[f"Z{b}"] = [(Lz[b], np.broadcast_to(R, (E, n, s)), 1.0)]
        if N * m and Ly[b].any():
            terms.setdefault("Y", []).append((Ly[b], np.broadcast_to(R, (E, n, s)), 1.0))
    P1 = np.zeros((s, k))
    P1[:k] = np.eye(k)
    P2 = np.zeros((s, k))
    P2[a0:a0 + k] = np.eye(k)
    terms["W"] = [(np.broadcast_to(P1, (E, s, k)), np.broadcast_to(P1.T, (E, k, s)), -0.5, np.asarray(prob.src)),
                  (np.broadcast_to(P2, (E, s, k)), np.broadcast_to(P2.T, (E, k, s)), 0.5, np.asarray(prob.dst))]
    return BlockGroup(kind, C, terms, scalars)


def network_performance_problem(ch, kind: str, x0: np.ndarray | None = None, u_max: np.ndarray | None = None,
                                strict: float = 0.0, limit_slack: float = 0.0) -> NetworkPerformanceProblem:
    """The SDP of :func:`solver.methods.network_performance.solve` as a :class:`GroupedLMI`.

    Parameters
    ----------
    ch : solver.methods.network_performance.Channels
    kind : {"cost", "hinf"}
    x0 : ndarray, shape (n,), optional
    u_max : ndarray, shape (m,), optional
        Cost only: the Kothare form (``g`` is gamma, the state rows ``1 + strict`` times stricter, the input
        blocks with ``u_max (1 - limit_slack)``).
    """
    from ..methods.network_performance import gain_rows

    prob = ch.prob
    n, m, N, k, zb = prob.n, prob.m, prob.N, prob.k, prob.zblocks
    V = len(prob.nodes)
    kothare = kind == "cost" and u_max is not None
    rows = ch.cost if kind == "cost" else ch.output
    # each gain's coefficients scaled to unit size over the state and the tail rows
    gs = np.zeros(N)
    for e in range(prob.n_blocks):
        for j in range(N):
            if prob.right[e, j] >= 0:
                gs[j] = max(gs[j], float(np.abs(prob.coef[e, j]).max()))
            if rows[e].right[j] >= 0:
                gs[j] = max(gs[j], float(np.abs(rows[e].coef[j]).max()))
    gs = np.where(gs > 0, gs, 1.0)
    groups = [_transition_group(ch, kind, kothare, gs, strict)]
    S = ch.history
    start = np.asarray(ch.start, dtype=int)
    ns = len(start)
    use_X = kind == "cost" and x0 is None
    if kind == "cost":
        level_var = not kothare
        if x0 is not None:
            s = S @ x0
            C = np.zeros((ns, k + 1, k + 1))
            C[:, 0, 1:] = s
            C[:, 1:, 0] = s
            if not level_var:
                C[:, 0, 0] = 1.0
            Lw = np.zeros((1, k + 1, k))
            Lw[0, 1:] = np.eye(k)
            sc = {}
            if level_var:
                D = np.zeros((1, k + 1, k + 1))
                D[0, 0, 0] = 1.0
                sc["g"] = np.broadcast_to(D, (ns, k + 1, k + 1))
            groups.append(BlockGroup("start", C, {"W": [(np.broadcast_to(Lw, (ns, k + 1, k)), None, 1.0, start)]},
                                     sc))
        else:
            C = np.zeros((ns, n + k, n + k))
            C[:, n:, :n] = S
            C[:, :n, n:] = S.T
            Lx = np.zeros((1, n + k, n))
            Lx[0, :n] = np.eye(n)
            Lw = np.zeros((1, n + k, k))
            Lw[0, n:] = np.eye(k)
            idx = np.arange(ns)
            groups.append(BlockGroup("start", C, {"X": [(np.broadcast_to(Lx, (ns, n + k, n)), None, 1.0, idx)],
                                                  "W": [(np.broadcast_to(Lw, (ns, n + k, k)), None, 1.0, start)]}))
            Ct = np.zeros((ns, 1, 1)) if level_var else np.ones((ns, 1, 1))
            xt = []
            for i in range(n):
                Li = np.zeros((1, 1, n))
                Li[0, 0, i] = 1.0
                xt.append((np.broadcast_to(Li, (ns, 1, n)), None, -1.0, idx))
            groups.append(BlockGroup("trace", Ct, {"X": xt}, {"g": np.ones((ns, 1, 1))} if level_var else {}))
    input_index = []
    if kothare:
        for v, pairs in enumerate(gain_rows(prob)):
            for j, b in pairs:
                for i in range(m):
                    input_index.append((v, j, b, i))
        nb = len(input_index)
        if nb:
            C = np.zeros((nb, k + 1, k + 1))
            C[:, 0, 0] = (np.asarray(u_max, float)[[i for *_, i in input_index]] * (1 - limit_slack)) ** 2
            Ly = np.zeros((nb, k + 1, N * m))
            Lz = np.zeros((zb, nb, k + 1, n))
            for q, (v, j, b, i) in enumerate(input_index):
                Ly[q, 0, j * m + i] = 1.0 / gs[j]
            terms = {}
            for b in range(zb):
                R = np.zeros((n, k + 1))
                R[:, 1 + b * n:1 + (b + 1) * n] = np.eye(n)
                Lz[b, :, 1 + b * n:1 + (b + 1) * n] = np.eye(n)
                terms[f"Z{b}"] = [(Lz[b], np.broadcast_to(R, (nb, n, k + 1)), 1.0)]
                on = np.array([bb == b for _, _, bb, _ in input_index])
                if on.any():
                    terms.setdefault("Y", []).append((Ly * on[:, None, None], np.broadcast_to(R, (nb, n, k + 1)),
                                                      1.0))
            Lw = np.zeros((1, k + 1, k))
            Lw[0, 1:] = np.eye(k)
            terms["W"] = [(np.broadcast_to(Lw, (nb, k + 1, k)), None, -1.0,
                           np.array([v for v, *_ in input_index]))]
            groups.append(BlockGroup("input", C, terms))
    matrices = [(f"Z{b}", (n, n), None) for b in range(zb)] + [("W", (V * k, k), k), ("Y", (N * m, n), None)]
    if use_X:
        matrices.append(("X", (ns * n, n), n))
    V0 = [np.zeros(sh) for _, sh, _ in matrices] + [np.zeros((1, 1))]
    lmi = GroupedLMI(matrices, ["g"], groups, V0)
    return NetworkPerformanceProblem(lmi=lmi, gain_scale=gs, shape=dict(n=n, m=m, N=N, k=k, zb=zb, V=V),
                                     input_index=input_index, start=start)


@dataclass
class NetworkPerformanceSolution:
    """Result of :func:`solve_network_performance` in the design's coordinates.

    Attributes
    ----------
    status : str
        :class:`GroupedSolution`'s.
    W : ndarray, shape (V, k, k)
    Y : ndarray, shape (N, m, n)
    Z : ndarray, shape (zb, n, n)
    value : float
        ``g`` attained (nan without phase 2).
    raw : GroupedSolution
    problem : NetworkPerformanceProblem
    """

    status: str
    W: np.ndarray
    Y: np.ndarray
    Z: np.ndarray
    value: float
    raw: GroupedSolution
    problem: NetworkPerformanceProblem


def solve_network_performance(problem: NetworkPerformanceProblem,
                              options: IPMOptions | None = None) -> NetworkPerformanceSolution:
    """``min g`` by :func:`solve_grouped` (one phase from the infeasible start, the two phases as its fallback,
    docs/design.md §8.3.2), mapped back to ``(W, Y, Z)``."""
    sol = solve_grouped(problem.lmi, {"g": 1.0}, options)
    sh = problem.shape
    n, m, N, k, zb, V = sh["n"], sh["m"], sh["N"], sh["k"], sh["zb"], sh["V"]
    W = np.asarray(sol.V["W"]).reshape(V, k, k)
    W = 0.5 * (W + np.swapaxes(W, 1, 2))
    Y = np.asarray(sol.V["Y"]).reshape(N, m, n) / problem.gain_scale[:, None, None]
    Z = np.stack([np.asarray(sol.V[f"Z{b}"]) for b in range(zb)])
    return NetworkPerformanceSolution(status=sol.status, W=W, Y=Y, Z=Z, value=float(sol.V["g"]) if np.isfinite(
        sol.value) else float("nan"), raw=sol, problem=problem)
