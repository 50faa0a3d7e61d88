"""The network design's LMI as a structured LMI (docs/design.md §11.2 "The network LMI on the IPM").

:func:`network_problem` builds the :class:`solver.ipm.model.BlockLMI` of the network LMI of
:mod:`solver.methods.network_lmi` (lifted and augmented forms alike); :func:`solve_network` solves it with
:func:`solver.ipm.algorithm.solve_block_lmi` and returns the variables and multipliers in the design's
coordinates.  The model only: which blocks, which variables; the algorithm is untouched.

Blocks (all of side ``2k``), one per transition e (``v -> w``, a plant mode)::

    [[Z + Z^T - W_v, (A_e Z)^T], [A_e Z, W_w]] - t I >= 0,    A_e Z = free_e Z + sum_j coef_{e,j} Y_j E_b^T

and, for a node that is no transition's end (so that ``W_v >= t I`` is not already a diagonal block of one),
the block of the pseudo-transition ``v -> v`` with ``A = 0``: ``[[Z + Z^T - W_v, 0], [0, W_v]] - t I >= 0``
(its top-left block is implied by any transition that leaves v).  The same ``t*`` as the cone program of
:func:`solver.methods.network_lmi.solve_sdp` with its separate ``W_v >= t I``.

Variables: the slack's diagonal blocks ``Z_0..Z_{zb-1}`` (n x n, general; one term each, placed by a 0/1
selector, with the transition's ``free_e E_b`` below it: the ``lmi`` design's ``[I/2; F]`` trick), the node
matrices as one stacked symmetric variable ``W`` (V k x k; each block reads row block ``src`` top left and
``dst`` bottom right, the ``switched`` design's ``S_s``), and the gains as one stack ``Y`` (N m x n), each
gain's coefficients scaled to unit size.  Equality: ``sum_b trace Z_b = zb n`` (``trace(Z + Z^T) = 2 n_Z``), or
with ``per_block`` one per slack block, ``trace Z_b = n`` (docs/design.md §11.1: the single one lets the augmented
form reach ``t = 0`` with a zero block, so it never has a Farkas certificate).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from .algorithm import IPMOptions, WarmStart, _SolveStatus, solve_block_lmi
from .model import BlockLMI, MatrixVariable
from .sparse_schur import NodeStructure

__all__ = ["NetworkIPMSolution", "edge_problem", "network_problem", "node_problem", "solve_network", "solve_node"]


def _pseudo(src: np.ndarray, dst: np.ndarray, V: int) -> np.ndarray:
    """Nodes no transition ends in (they get a pseudo-transition ``v -> v`` with ``A = 0``)."""
    return np.setdiff1d(np.arange(V), np.asarray(dst, dtype=int))


def network_problem(free, coef, right, src, dst, n_nodes: int, zblocks: int, scale=None, per_block: bool = False):
    """The network LMI as a :class:`BlockLMI`, and the gains' scale.

    Parameters
    ----------
    free : ndarray, shape (E, k, k)
        Gain-free parts of the transitions' maps (``k = zblocks n``).
    coef : ndarray, shape (E, N, k, m)
        ``A_e = free_e + sum_j coef[e, j] K_j E_{right[e, j]}^T``.
    right : ndarray of int, shape (E, N)
        Slack block gain j reads in transition e (-1: absent).
    src, dst : ndarray of int, shape (E,)
        Node matrix of each transition's start and end.
    n_nodes : int
        V, the number of node matrices.
    zblocks : int
        Diagonal blocks of the slack (each n x n).
    scale : ndarray, shape (E,), optional
        Multiplies transition e's data (the congruent decay-rate form ``lambda^(-length_e)``).
    per_block : bool
        One normalization per slack block (``trace Z_b = n``) instead of their sum.

    Returns
    -------
    problem : BlockLMI
        Variables ``Z0..Z{zb-1}``, ``W`` (V k, k), ``Y`` (N m, n) when there are gains; blocks: the E
        transitions, then the pseudo-transitions of :func:`_pseudo`.
    gscale : ndarray, shape (N,)
        ``Y_j = Y'_j / gscale[j]`` (the solver's ``Y'`` has unit-size coefficients).
    """
    free = np.asarray(free, dtype=np.float64)
    coef = np.asarray(coef, dtype=np.float64)
    right = np.asarray(right, dtype=int)
    E, k, _ = free.shape
    N, m = coef.shape[1], coef.shape[3]
    zb = int(zblocks)
    n = k // zb
    V = int(n_nodes)
    sc = np.ones(E) if scale is None else np.asarray(scale, dtype=np.float64)
    extra = _pseudo(src, dst, V)
    nb = E + len(extra)
    src_all = np.concatenate([np.asarray(src, dtype=int), extra])
    dst_all = np.concatenate([np.asarray(dst, dtype=int), extra])
    A0 = np.zeros((nb, k, k))
    A0[:E] = sc[:, None, None] * free
    # the gains' coefficients, each gain scaled to unit size (as solver.ipm.design_blocks._gain_scale)
    cf = np.zeros((nb, N, k, m))
    for j in range(N):
        on = right[:, j] >= 0
        cf[:E][on, j] = sc[on, None, None] * coef[on, j]
    gscale = np.abs(cf).max(axis=(0, 2, 3)) if cf.size else np.ones(N)
    gscale = np.where(gscale > 0, gscale, 1.0)
    cf = cf / gscale[None, :, None, None]
    eye_n = np.eye(n)
    variables = []
    for b in range(zb):
        Eb = np.zeros((k, n))
        Eb[b * n:(b + 1) * n] = eye_n
        # sym([E_b; A0 E_b] Z_b [E_b^T 0]) = [[E_b (Z_b + Z_b^T) E_b^T, (A0 E_b Z_b E_b^T)^T], [A0 E_b Z_b E_b^T, 0]]
        L = np.zeros((nb, 2 * k, n))
        L[:, :k] = Eb
        L[:, k:] = A0 @ Eb
        R = np.zeros((2 * k, n))
        R[:k] = Eb
        variables.append(MatrixVariable(f"Z{b}", (n, n), None, [(L, np.broadcast_to(R.T, (nb, n, 2 * k)), 1.0)]))
    P1 = np.zeros((2 * k, k))
    P1[:k] = np.eye(k)
    P2 = np.zeros((2 * k, k))
    P2[k:] = np.eye(k)
    W = MatrixVariable("W", (V * k, k), k, [
        (np.broadcast_to(P1, (nb, 2 * k, k)), np.broadcast_to(P1.T, (nb, k, 2 * k)), -0.5, src_all),
        (np.broadcast_to(P2, (nb, 2 * k, k)), np.broadcast_to(P2.T, (nb, k, 2 * k)), 0.5, dst_all)])
    variables.append(W)
    if N * m > 0:
        terms = []
        for b in range(zb):
            LY = np.zeros((nb, 2 * k, N * m))
            for j in range(N):
                on = np.flatnonzero(right[:, j] == b)
                LY[on, k:, j * m:(j + 1) * m] = cf[on, j]
            if not LY.any():
                continue
            R = np.zeros((2 * k, n))
            R[b * n:(b + 1) * n] = eye_n
            terms.append((LY, np.broadcast_to(R.T, (nb, n, 2 * k)), 1.0))
        if terms:
            variables.append(MatrixVariable("Y", (N * m, n), None, terms))
    C = np.zeros((nb, 2 * k, 2 * k))  # the blocks at Z_b = I, W_v = I, Y = 0
    C[:, :k, :k] = np.eye(k)
    C[:, k:, k:] = np.eye(k)
    C[:, k:, :k] = A0
    C[:, :k, k:] = np.swapaxes(A0, 1, 2)
    a = np.zeros((zb, sum(v.size for v in variables)))
    for b in range(zb):
        a[b, b * n * n: (b + 1) * n * n: n + 1] = 1.0  # trace Z_b = n, one equality per slack block
    if not per_block:
        a = a.sum(axis=0)  # sum_b trace Z_b = zb n
    V0 = [eye_n.copy() for _ in range(zb)] + [np.tile(np.eye(k), (V, 1))]
    if len(variables) > zb + 1:
        V0.append(np.zeros((N * m, n)))
    return BlockLMI(C=C, variables=variables, V0=V0, equality=a), gscale


@dataclass(kw_only=True)
class NetworkIPMSolution(_SolveStatus):
    """Result of :func:`solve_network` in the design's coordinates.

    Attributes
    ----------
    t : float
        Attained margin (every block ``>= t I`` at the returned variables, whatever the status).
    upper : float
        ``sum_b <C_b, X_b>``: an upper bound on ``t*`` up to ``primal_residual``.
    Z : ndarray, shape (zblocks, n, n)
    W : ndarray, shape (V, k, k)
        Symmetric node matrices.
    Y : ndarray, shape (N, m, n)
    multipliers : list of ndarray
        One (2k, 2k) per transition, then one (k, k) per node matrix (the multiplier of ``W_v >= 0``):
        the layout :func:`solver.methods.network_lmi.check_network_farkas` re-checks.  A pseudo-transition's
        multiplier is split exactly: its bottom-right block is the node's, its top-left block (it pairs with
        ``Z + Z^T - W_v`` only) goes to the top-left block of a transition leaving v.
    duals : ndarray, shape (nb, 2k, 2k)
        The blocks' multipliers as the solver returns them (``sum trace = 1``), for a warm start.
    V : list of ndarray
        The variables in the solver's layout (``Z_b``..., ``W`` stacked, ``Y`` stacked (N m, n)), in the
        design's coordinates: a warm start's ``V`` (:func:`warm_start`).
    """

    t: float
    upper: float
    Z: np.ndarray
    W: np.ndarray
    Y: np.ndarray
    multipliers: list
    duals: np.ndarray
    V: list


def solve_network(free, coef, right, src, dst, n_nodes: int, zblocks: int, scale=None,
                  options: IPMOptions | None = None, start: WarmStart | None = None,
                  per_block: bool = False) -> NetworkIPMSolution:
    """``max t`` of the network LMI (:func:`network_problem`) with the structured IPM.

    Parameters are those of :func:`network_problem`; ``start``: a warm start in the solver's coordinates
    (:attr:`NetworkIPMSolution.V` and ``duals`` of a neighbouring rate's solve).

    Returns
    -------
    NetworkIPMSolution
    """
    t0 = time.perf_counter()
    problem, gscale = network_problem(free, coef, right, src, dst, n_nodes, zblocks, scale, per_block)
    if start is not None:  # the start's Y is in the design's coordinates: scale it as this problem's gains
        Vs = list(start.V)
        if len(Vs) != len(problem.variables) or any(np.shape(v) != np.shape(v0) for v, v0 in zip(Vs, problem.V0)):
            start = None
        else:
            if len(Vs) > int(zblocks) + 1:
                N, m = np.asarray(coef).shape[1], np.asarray(coef).shape[3]
                Vs[-1] = (np.asarray(Vs[-1]).reshape(N, m, -1) * gscale[:, None, None]).reshape(Vs[-1].shape)
            start = replace(start, V=Vs)
    setup = time.perf_counter() - t0
    sol = solve_block_lmi(problem, options, start)
    zb = int(zblocks)
    E = len(src)
    N, m = np.asarray(coef).shape[1], np.asarray(coef).shape[3]
    k = problem.k // 2
    n = k // zb
    V = int(n_nodes)
    Z = np.stack(sol.V[:zb])
    W = sol.V[zb].reshape(V, k, k)
    W = 0.5 * (W + np.swapaxes(W, 1, 2))
    Y = np.zeros((N, m, n)) if len(sol.V) <= zb + 1 else sol.V[zb + 1].reshape(N, m, n) / gscale[:, None, None]
    X = sol.X
    M = [X[e].copy() for e in range(E)]
    Nv = [np.zeros((k, k)) for _ in range(V)]
    src = np.asarray(src, dtype=int)
    for i, v in enumerate(_pseudo(src, dst, V)):
        Xp = X[E + i]
        Nv[v] += Xp[k:, k:]
        leaving = np.flatnonzero(src == v)
        if len(leaving):
            M[leaving[0]][:k, :k] += Xp[:k, :k]
        else:  # no transition leaves v (not a valid network): keep the block's claim honest, drop nothing silently
            Nv[v] += np.nan
    timings = dict(sol.timings, setup=setup)
    timings["total"] = time.perf_counter() - t0
    Vd = list(sol.V[:zb]) + [W.reshape(V * k, k)] + ([Y.reshape(N * m, n)] if len(sol.V) > zb + 1 else [])
    return NetworkIPMSolution(t=sol.t, upper=sol.upper, Z=Z, W=W, Y=Y, multipliers=M + Nv, duals=X, V=Vd,
                              status=sol.status, iterations=sol.iterations, primal_residual=sol.primal_residual,
                              dual_residual=sol.dual_residual, gap=sol.gap, timings=timings)


def warm_start(previous: NetworkIPMSolution, shift: float = 1e-2, blend: float = 0.5) -> WarmStart:
    """A :class:`WarmStart` from a neighbouring rate's solve (same network, other ``scale``)."""
    return replace(WarmStart(list(previous.V), previous.duals), shift=shift, blend=blend)


# ------------------------------------------------------------------------------------ fixed gains: node SDP
#: States from which :func:`node_problem` takes the block-sparse Schur complement.  CPU per solve, one thread, a
#: ring / complete successor graph: at V = 2 and 3 the dense one is faster (D = 2: 1.3-1.4 ms against 2.0-2.4 ms;
#: D = 6: 3.2-4.9 ms against 3.9-5.6 ms); at V = 4 they are even (D = 6: 7.7 / 29 ms dense against 8.5 / 26 ms);
#: the sparse one is faster from V = 6 at D = 6 (22 / 32 ms against 26 / 39 ms), at V = 11 (30 ms against 76 ms)
#: and at V = 64, D = 8 (0.21 s against 5.1 s).
SPARSE_NODE_FROM = 4


def node_problem(A_states, succ, rho: float = 1.0, schur: str = "auto") -> BlockLMI:
    """The node-dependent Lyapunov SDP of ``analyze(network=)`` (docs/design.md §11) as a :class:`BlockLMI`.

    ``max t`` s.t. ``rho^2 P_v - A_v^T P_w A_v - t I >= 0`` for every edge ``v -> w`` of ``succ``,
    ``P_v - t I >= 0`` for every state, ``sum_v trace P_v = V D`` (homogeneous: the normalization loses nothing).

    Parameters
    ----------
    A_states : ndarray, shape (V, D, D)
        The closed-loop map of every product-automaton state.
    succ : list of list of int
        Successors of every state.
    rho : float
        Rate per sample.
    schur : {"auto", "sparse", "dense"}
        The Schur complement: block-sparse in the nodes (:mod:`solver.ipm.sparse_schur`), dense
        (:func:`solver.ipm.schur.assemble`), or the sparse one from :data:`SPARSE_NODE_FROM` states.

    Returns
    -------
    BlockLMI
        One variable ``P`` (V D, D), a stack of symmetric matrices; blocks: the edges in ``succ`` order, then
        one ``P_v >= t I`` per state.
    """
    A_states = np.asarray(A_states, dtype=np.float64)
    V = A_states.shape[0]
    src = np.array([v for v in range(V) for _ in succ[v]], dtype=int)
    dst = np.array([w for v in range(V) for w in succ[v]], dtype=int)
    return edge_problem(A_states[src], src, dst, V, np.full(len(src), float(rho) ** 2), schur)


def edge_problem(A_edges, src, dst, n_nodes: int, rho2, schur: str = "auto") -> BlockLMI:
    """:func:`node_problem` with a map and a rate per edge: ``max t`` s.t. ``rho2_e P_v - A_e^T P_w A_e - t I >= 0``
    for every edge ``e: v -> w``, ``P_v - t I >= 0``, ``sum_v trace P_v = V D`` (the fixed-gain node SDP of a
    network design, :func:`solver.methods.network_lmi.node_analysis`, where parallel edges carry different maps).

    Parameters
    ----------
    A_edges : ndarray, shape (E, D, D)
    src, dst : ndarray of int, shape (E,)
    n_nodes : int
    rho2 : ndarray, shape (E,)
        The squared rate of every edge.
    schur : {"auto", "sparse", "dense"}
        As :func:`node_problem`.
    """
    if schur not in ("auto", "sparse", "dense"):
        raise ValueError(f"schur must be 'auto', 'sparse' or 'dense', got {schur!r}")
    A_edges = np.asarray(A_edges, dtype=np.float64)
    V, D, E = int(n_nodes), A_edges.shape[1], A_edges.shape[0]
    src = np.concatenate([np.asarray(src, dtype=int), np.arange(V)])
    dst = np.concatenate([np.asarray(dst, dtype=int), np.arange(V)])
    nb = len(src)
    eye = np.eye(D)
    c = np.concatenate([np.asarray(rho2, dtype=np.float64), np.ones(V)])
    L1 = c[:, None, None] * eye  # c_b P_src: sym(c_b P R) with R = I and coefficient 1/2
    L2 = np.zeros((nb, D, D))
    L2[:E] = np.swapaxes(A_edges, 1, 2)  # - A_e^T P_w A_e (zero on the positivity blocks)
    P = MatrixVariable("P", (V * D, D), D, [
        (L1, np.broadcast_to(eye, (nb, D, D)), 0.5, src),
        (L2, None, -1.0, dst)])
    C = L1 - L2 @ np.swapaxes(L2, 1, 2)  # the blocks at P_v = I
    a = np.zeros(V * D * D)
    for v in range(V):
        a[v * D * D: (v + 1) * D * D: D + 1] = 1.0
    problem = BlockLMI(C=C, variables=[P], V0=[np.tile(eye, (V, 1))], equality=a)
    if schur == "sparse" or (schur == "auto" and V >= SPARSE_NODE_FROM):
        problem.schur_structure = NodeStructure(problem)
    return problem


def node_memory(succ, D: int, schur: str = "auto") -> int:
    """Bytes the structured IPM needs at its peak for :func:`node_problem` (docs/design.md §11.4).

    The block-sparse path (:mod:`solver.ipm.sparse_schur`): the Cholesky factor's ``q x q`` blocks (``q = D (D + 1)
    / 2``; one per state and per edge of the filled state graph) twice (a retried factorization rebuilds them before
    the old ones go), the largest panel update ``(f q)^2`` (f: the largest elimination front; both from
    :func:`solver.ipm.sparse_schur.node_factor_size`), the assembly's pieces (7 ``D x D`` per block, one ``D^4``
    product, four gathers of ``q^2`` positions) and about 30 block-diagonal iterates, with a quarter more for the
    heap's fragmentation;
    the dense path: :func:`solver.compiled.ipm_memory`.  Measured at V = 64, D = 32: estimate 1.6 GiB, peak
    resident set 1.67 GB.
    """
    from ..compiled import ipm_memory
    from .sparse_schur import node_factor_size

    V, D = len(succ), int(D)
    q = D * (D + 1) // 2
    E = sum(len(out) for out in succ)
    nb = E + V
    if schur == "dense" or (schur == "auto" and V < SPARSE_NODE_FROM):
        full = V * D * D + 1
        return ipm_memory(full, V * q, nb, D, full)
    pairs = [(v, w) for v in range(V) for w in succ[v]]
    blocks, front = node_factor_size(V, pairs)
    return 10 * (2 * blocks * q * q + (front * q) ** 2 + 14 * nb * D * D + D**4 + 4 * q * q + 30 * nb * D * D)


def solve_node(A_states, succ, rho: float = 1.0, options: IPMOptions | None = None, schur: str = "auto"):
    """``(t, P)`` of :func:`node_problem` on the structured IPM, ``P`` of shape (V, D, D), and the IPM's status."""
    problem = node_problem(A_states, succ, rho, schur)
    sol = solve_block_lmi(problem, options)
    V, D = np.shape(A_states)[0], np.shape(A_states)[1]
    P = sol.V[0].reshape(V, D, D)
    return float(sol.t), 0.5 * (P + np.swapaxes(P, 1, 2)), sol.status
