"""A block-sparse Schur complement for LMIs whose blocks each touch a few node matrices (docs/design.md §11.4).

The node SDP of ``analyze(network=)`` (:func:`solver.ipm.network_blocks.node_problem`) has one variable, a stack of
V symmetric node matrices ``P_v`` (D x D), and blocks that each read one or two of them (an edge ``v -> w`` reads
``P_v`` and ``P_w``).  Its Schur complement ``M_ij = sum_b tr(A_i X_b A_j G_b)`` is then block-sparse in the node
coordinates: the ``q x q`` block of nodes ``(u, v)`` (``q = D (D + 1) / 2``) is nonzero only when some block reads
both, so the dense ``(V q)^2`` matrix of :func:`solver.ipm.schur.assemble` is replaced by

* the nonzero node blocks, assembled per block-touched node pair from the products of
  :func:`solver.ipm.schur._products` (bucketed once, :meth:`NodeStructure._entries`) in the symmetric coordinates;
* a dense border: the ``t`` coordinate (its row is an adjoint, as in the dense assembly);
* the equality ``<a, vec V> = beta``, kept as a constraint (a Lagrange multiplier) instead of eliminated: the
  algorithm's reduced coordinates drop its pivot ``x_piv = w^T y``, which couples every node's trace coordinates,
  so ``E^T M0 E dy = h`` is solved as ``[[M0, a], [a^T, 0]] [x; lam] = [E^+^T h; 0]``, ``dy = x`` without the pivot;

and factored by a block Cholesky over the node graph, in a minimum-degree order of the nodes (fill computed once,
symbolically), each node's column of blocks one BLAS-3 panel; the border is eliminated through its small dense
Schur complement.  Memory: the factor's blocks (``q^2`` each, one per node and per edge of the filled node graph)
instead of ``(V q)^2``.

The model selects it (:attr:`solver.ipm.model.BlockLMI.schur_structure`); the algorithm sees an object with
``diagonal()`` and ``factor(dead)`` (:class:`SparseSchur`) instead of an array.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg.lapack
from scipy.linalg.blas import dsyrk as _syrk
from scipy.linalg.blas import dtrsm as _trsm

from .schur import _plan, _products

__all__ = ["NodeStructure", "SparseSchur", "minimum_degree", "node_factor_size"]

_potrf = scipy.linalg.lapack.dpotrf


def minimum_degree(V: int, pairs) -> tuple[np.ndarray, list]:
    """A minimum-degree elimination order of a graph of V nodes and its filled structure.

    Parameters
    ----------
    V : int
    pairs : iterable of (int, int)
        Edges (either orientation; self loops ignored).

    Returns
    -------
    order : ndarray of int, shape (V,)
        ``order[k]``: the node eliminated k-th.
    below : list of list of int
        ``below[k]``: the positions ``i > k`` of the nodes joined to the k-th one when it is eliminated (the nonzero
        blocks of column k of the Cholesky factor), sorted.
    """
    adj = [set() for _ in range(V)]
    for u, v in pairs:
        if u != v:
            adj[u].add(v)
            adj[v].add(u)
    alive = set(range(V))
    order = []
    while alive:
        v = min(alive, key=lambda u: (len(adj[u]), u))
        order.append(v)
        nb = adj[v]
        for a in nb:
            adj[a] |= nb
            adj[a].discard(a)
            adj[a].discard(v)
        alive.discard(v)
        adj[v] = nb  # kept: the neighbours at elimination
    pos = np.empty(V, dtype=int)
    pos[order] = np.arange(V)
    below = [sorted(int(pos[a]) for a in adj[v]) for v in order]
    return np.array(order, dtype=int), below


def node_factor_size(V: int, pairs) -> tuple[int, int]:
    """The node graph's Cholesky factor in minimum-degree order: its number of ``q x q`` blocks (diagonal and fill
    included) and its largest elimination front (the most off-diagonal blocks in one factor column)."""
    _, below = minimum_degree(V, pairs)
    return V + sum(len(b) for b in below), max((len(b) for b in below), default=0)


class NodeStructure:
    """What the block-sparse Schur complement needs of a problem, built once (shapes and selections only).

    The problem has one matrix variable, a stack of symmetric ``D x D`` node matrices whose every term carries a
    row-block selection (``MatrixVariable.terms`` with ``sel``), ``t`` (the max-t form) or an objective, and at most
    one equality.
    """

    def __init__(self, problem):
        if len(problem.variables) != 1:
            raise ValueError("the block-sparse Schur complement takes one stacked node variable")
        var = problem.variables[0]
        D = var.sym_block
        if D is None or var.shape[1] != D or any(len(t) < 4 for t in var.terms):
            raise ValueError("the node variable must be a stack of symmetric matrices read through selections")
        plan = _plan(problem)
        if plan.E is not None:
            raise ValueError("the block-sparse Schur complement takes at most one equality")
        self.D, self.V = D, var.shape[0] // D
        self.q = D * (D + 1) // 2
        self.with_t = problem.with_t
        self.p0 = plan.p0
        self.piv, self.w = plan.piv, plan.w
        touched = np.stack([np.asarray(t[3], dtype=int) for t in var.terms], axis=1)  # (nb, terms)
        pairs = {(int(a), int(b)) for row in touched for a in row for b in row}
        self.order, self.below = minimum_degree(self.V, pairs)
        self.pos = np.empty(self.V, dtype=int)
        self.pos[self.order] = np.arange(self.V)
        # each column k of the factor: its diagonal block then the blocks of the rows below[k], one contiguous array
        self.index = [{i: 1 + a for a, i in enumerate(b)} for b in self.below]
        i1, j1 = np.triu_indices(D)
        self.i1, self.j1 = i1, j1
        self.diag = np.flatnonzero(i1 == j1)

    def _entries(self, problem):
        """The static bucketing of every (block, product pair) into the stored node block it adds to (built once).

        Every term is a list of products ``c L V R`` (:func:`solver.ipm.schur._products`; ``V`` the node matrix it
        selects); for a symmetric coordinate ``E`` and products ``u``, ``v`` of the terms of nodes ``x``, ``y`` of
        block b, ``tr(c_u L_u E R_u X_b c_v L_v E' R_v G_b) = c_u c_v tr(E P E' Q)`` with ``P = R_u X_b L_v``,
        ``Q = R_v G_b L_u``: an entry of the node block ``(x, y)``, or with ``P``, ``Q`` swapped of ``(y, x)``
        (``tr(E P E' Q) = tr(E' Q E P)``).  Two different terms of one block add ``K + K^T``: both orientations.
        """
        var_terms = problem.sel_terms[0]
        prods = _products(var_terms)
        sels = [np.asarray(t[3], dtype=int) for t in var_terms]
        nb = problem.nb
        pairs, src, swap, key = [], [], [], []
        for ta in range(len(prods)):
            for tb in range(ta, len(prods)):
                for u in prods[ta]:
                    for v in prods[tb]:
                        pid = len(pairs)
                        pairs.append((u, v))
                        x, y = self.pos[sels[ta]], self.pos[sels[tb]]
                        b = np.arange(nb)
                        hi, lo = np.maximum(x, y), np.minimum(x, y)
                        k = lo * self.V + hi
                        src.append(pid * nb + b), key.append(k), swap.append(x < y)
                        if ta != tb:  # the pair's transpose: its (y, x) entry, the same stored block when x == y
                            same = x == y
                            src.append(pid * nb + b[same]), key.append(k[same]), swap.append(np.ones(same.sum(), bool))
        src, swap, key = np.concatenate(src), np.concatenate(swap), np.concatenate(key)
        order = np.argsort(key, kind="stable")
        src, swap, key = src[order], swap[order], key[order]
        bounds = np.flatnonzero(np.diff(key)) + 1
        starts = np.concatenate([[0], bounds])
        ends = np.concatenate([bounds, [len(key)]])
        blocks = [(int(key[s]) // self.V, int(key[s]) % self.V, int(s), int(e)) for s, e in zip(starts, ends)]
        D = self.D
        i1, j1 = self.i1, self.j1
        I, J = i1[:, None], j1[:, None]
        K, L = i1[None, :], j1[None, :]

        def flat(a, b, c, d):  # Y4[a, b, c, d] in the flat Y
            return ((a * D + b) * D + c) * D + d

        gather = [flat(J, K, L, I), flat(J, L, K, I), flat(I, K, L, J), flat(I, L, K, J)]
        return pairs, src, swap, blocks, gather

    def assemble(self, problem, X: np.ndarray, G: np.ndarray) -> "SparseSchur":
        """The Schur complement at multipliers ``X`` and inverse slacks ``G`` (nb, k, k) as a :class:`SparseSchur`.

        Per stored node block, its entries' ``sum c P (x) Q`` is one GEMM of the stacked ``vec P``, ``vec Q``
        (``Y[(b, c), (d, a)] = sum P[b, c] Q[d, a]``), projected onto the symmetric coordinates by four gathers:
        ``M[(ij), (kl)] = Y[j,k,l,i] + Y[j,l,k,i] + Y[i,k,l,j] + Y[i,l,k,j]``, halved on diagonal coordinates.
        """
        got = problem.__dict__.get("_sparse_entries")
        if got is None:
            got = problem._sparse_entries = self._entries(problem)
        pairs, src, swap, blocks, gather = got
        D, q = self.D, self.q
        P = np.empty((len(pairs), problem.nb, D, D))
        Q = np.empty_like(P)
        for i, (u, v) in enumerate(pairs):
            Lu, Ru, _, cu = u
            Lv, Rv, _, cv = v
            P[i] = (cu * cv) * (Ru @ X @ Lv)
            Q[i] = Rv @ G @ Lu
        P, Q = P.reshape(-1, D * D), Q.reshape(-1, D * D)
        Pf, Qf = P[src], Q[src]
        Pf[swap], Qf[swap] = Q[src[swap]], P[src[swap]]
        cols = [np.zeros(((1 + len(b)) * q, q)) for b in self.below]
        for lo, hi, s, e in blocks:
            Y = (Pf[s:e].T @ Qf[s:e]).reshape(-1)
            red = Y[gather[0]]
            for g in gather[1:]:
                red += Y[g]
            red[self.diag] *= 0.5
            red[:, self.diag] *= 0.5
            a = 0 if lo == hi else self.index[lo][hi]
            cols[lo][a * q:(a + 1) * q] += red
        border = None
        if self.with_t:
            plan = _plan(problem)
            col = -problem.adj_full(G @ X)
            col[-1] = np.einsum("bij,bji->", X, G)
            border = plan.T0t @ col
        return SparseSchur(self, cols, border, lambda: self.assemble(problem, X, G))


class SparseSchur:
    """The block-sparse Schur complement ``M = E^T M0 E`` of one iteration (what :meth:`NodeStructure.assemble` makes).

    ``cols[k]``: column k (elimination order) of ``M0``'s node part, lower blocks; ``border``: ``M0``'s ``t`` row
    (full ``p0`` coordinates, t last) or None.
    """

    def __init__(self, st: NodeStructure, cols: list, border, rebuild):
        self.st, self.cols, self.border, self._rebuild = st, cols, border, rebuild
        q, V = st.q, st.V
        self._dnodes = np.stack([np.diagonal(c[:q]) for c in cols])  # (V, q) by position
        self.p = st.p0 - (0 if st.piv is None else 1)
        piv = st.piv
        self._pivrow = None
        if piv is not None and piv < V * q:  # the pivot's row of M0 (node part, node order), for the diagonal
            u, a = divmod(piv, q)
            row = np.zeros((V, q))
            pu = st.pos[u]
            for k in range(V):
                if k == pu:
                    row[u] = cols[k][:q][a]
                elif k < pu and pu in st.index[k]:
                    i = st.index[k][pu]
                    row[st.order[k]] = cols[k][i * q:(i + 1) * q][a]
                elif k > pu and k in st.index[pu]:
                    i = st.index[pu][k]
                    row[st.order[k]] = cols[pu][i * q:(i + 1) * q][:, a]
            self._pivrow = np.concatenate([row.ravel(), [] if border is None else [border[piv]]])

    # ------------------------------------------------------------------ coordinates
    def _full_of(self, h):
        """Reduced ``h`` (p) as full ``p0`` coordinates with a zero at the pivot."""
        return h if self.st.piv is None else np.insert(h, self.st.piv, 0.0)

    def diagonal(self) -> np.ndarray:
        st = self.st
        d0 = np.empty(st.p0)
        d0[:st.V * st.q] = self._dnodes[st.pos].ravel()
        if self.border is not None:
            d0[-1] = self.border[-1]
        if st.piv is None:
            return d0
        piv = st.piv
        m = np.delete(self._pivrow, piv)
        return np.delete(d0, piv) + 2.0 * st.w * m + st.w**2 * self._pivrow[piv]

    def dense(self) -> np.ndarray:
        """``M`` as a dense (p, p) matrix (before :meth:`factor`; tests and small problems)."""
        st, q = self.st, self.st.q
        M0 = np.zeros((st.p0, st.p0))
        for k in range(st.V):
            u = st.order[k]
            M0[u * q:(u + 1) * q, u * q:(u + 1) * q] = self.cols[k][:q]
            for i in st.below[k]:
                v = st.order[i]
                Bl = self.cols[k][st.index[k][i] * q:(st.index[k][i] + 1) * q]
                M0[v * q:(v + 1) * q, u * q:(u + 1) * q] = Bl
                M0[u * q:(u + 1) * q, v * q:(v + 1) * q] = Bl.T
        if self.border is not None:
            M0[-1, :] = self.border
            M0[:, -1] = self.border
        if st.piv is None:
            return M0
        E = np.insert(np.eye(self.p), st.piv, st.w, axis=0)
        return E.T @ M0 @ E

    # ------------------------------------------------------------------ factorization
    def factor(self, dead=None):
        """A solver ``h -> dy`` of ``M dy = h`` (``dead``: reduced coordinates pinned to ``dy = 0``), or None.

        A failed factorization (``M`` singular to rounding near a degenerate optimum) is retried with a growing
        diagonal shift of the node part, as the dense path does.
        """
        st = self.st
        n_nodes = st.V * st.q
        dead0 = np.zeros(st.p0, dtype=bool)
        if dead is not None:
            dead0[np.flatnonzero(dead) + ((np.flatnonzero(dead) >= st.piv) if st.piv is not None else 0)] = True
        cols = self.cols
        for reg in (0.0, 1e-12, 1e-10, 1e-8):
            if reg:
                cols = self.cols = self._rebuild().cols
            self._pin(cols, dead0[:n_nodes], reg)
            if _block_cholesky(cols, st):
                break
        else:
            return None
        # the border: t (unless pinned) and the equality's constraint row a (a_piv = 1, a_j' = -w_j)
        F, H = [], []
        if self.border is not None and not dead0[-1]:
            c = np.where(dead0[:n_nodes], 0.0, self.border[:n_nodes])
            F.append(c)
            H.append(("t", float(self.border[-1])))
        if st.piv is not None:
            a = np.zeros(st.p0)
            a[st.piv] = 1.0
            a[np.arange(st.p0) != st.piv] = -st.w
            a[dead0] = 0.0
            F.append(a[:n_nodes])
            H.append(("eq", 0.0))
        Fm = np.stack(F, axis=1) if F else np.zeros((n_nodes, 0))
        BF = self._solve_nodes(cols, Fm)
        Hm = np.diag([h for _, h in H]) if H else np.zeros((0, 0))
        S = Hm - Fm.T @ BF
        with_t = self.border is not None

        def solve(h):
            x = self._full_of(np.asarray(h, dtype=np.float64))
            x = np.where(dead0, 0.0, x)
            hn = x[:n_nodes]
            z0 = self._solve_nodes(cols, hn[:, None])[:, 0]
            rhs = np.array([x[-1] if kind == "t" else 0.0 for kind, _ in H]) - Fm.T @ z0
            z = np.linalg.solve(S, rhs) if len(rhs) else rhs
            out = x.copy()
            out[:n_nodes] = z0 - BF @ z
            if with_t:
                out[-1] = z[0] if H and H[0][0] == "t" else 0.0
            out[dead0] = 0.0
            return out if st.piv is None else np.delete(out, st.piv)

        return solve

    def _pin(self, cols, dead, reg):
        """Pinned node coordinates get a unit row and column; ``reg`` shifts the diagonal by ``reg`` times itself."""
        st, q = self.st, self.st.q
        if reg:
            for k in range(st.V):
                c = cols[k][:q]
                c[np.diag_indices(q)] += reg * np.abs(self._dnodes[k]) + 1e-300
        if not dead.any():
            return
        for u in np.flatnonzero(dead.reshape(st.V, q).any(axis=1)):
            loc = np.flatnonzero(dead.reshape(st.V, q)[u])
            pu = st.pos[u]
            for k in range(st.V):
                if k == pu:
                    c = cols[k][:q]
                    c[loc, :] = 0.0
                    c[:, loc] = 0.0
                    c[loc, loc] = 1.0
                elif k < pu and pu in st.index[k]:
                    i = st.index[k][pu]
                    cols[k][i * q:(i + 1) * q][loc] = 0.0
                elif k > pu and k in st.index[pu]:
                    i = st.index[pu][k]
                    cols[pu][i * q:(i + 1) * q][:, loc] = 0.0

    def _solve_nodes(self, cols, B):
        """``B^{-1} R`` for the factored node part, ``R`` (V q, r) in node order."""
        st, q = self.st, self.st.q
        Z = B.reshape(st.V, q, -1)[st.order].copy()  # by position
        for k in range(st.V):  # forward: L z = b
            L = cols[k]
            Z[k] = _trsm(1.0, L[:q], Z[k], lower=1)
            if st.below[k]:
                Z[st.below[k]] -= (L[q:] @ Z[k]).reshape(len(st.below[k]), q, -1)
        for k in range(st.V - 1, -1, -1):  # backward: L^T x = z
            L = cols[k]
            if st.below[k]:
                Z[k] -= L[q:].T @ Z[st.below[k]].reshape(-1, Z.shape[2])
            Z[k] = _trsm(1.0, L[:q], Z[k], lower=1, trans_a=1)
        return Z[st.pos].reshape(st.V * q, -1)


def _block_cholesky(cols, st) -> bool:
    """Right-looking block Cholesky of the node part in place (lower factor); False when not positive definite."""
    q = st.q
    for k in range(st.V):
        C = cols[k]
        Lkk, info = _potrf(C[:q].T, lower=0, clean=1, overwrite_a=0)  # C[:q].T upper == C[:q] lower
        if info != 0:
            return False
        C[:q] = Lkk.T
        rows = st.below[k]
        if not rows:
            continue
        # L_ik = A_ik L_kk^{-T} for the whole panel at once
        C[q:] = _trsm(1.0, C[:q], C[q:], side=1, lower=1, trans_a=1)
        W = _syrk(1.0, C[q:], lower=1)  # panel panel^T, lower triangle
        for a, i in enumerate(rows):
            Wi = W[a * q:(a + 1) * q]
            Ci = cols[i]
            Ci[:q] -= Wi[:, a * q:(a + 1) * q]
            for b_, j in enumerate(rows[:a]):
                # block (i, j), i > j: column j's array holds it
                pos = st.index[j][i]
                cols[j][pos * q:(pos + 1) * q] -= Wi[:, b_ * q:(b_ + 1) * q]
    return True
