"""The structured LMI model: matrix variables, their Kronecker-structured terms, the blocks (docs/design.md).

A :class:`BlockLMI` says *which* blocks and *which* variables; the algorithm that solves it lives in
:mod:`solver.ipm.algorithm`, the Schur complement assembly in :mod:`solver.ipm.schur`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..memo import BoundedCache
from .schur import _onehot, assemble

__all__ = ["BlockGroup", "BlockLMI", "GroupedLMI", "MatrixVariable"]


@dataclass
class MatrixVariable:
    """One matrix variable and the terms through which it enters the blocks.

    Parameters
    ----------
    name : str
    shape : (int, int)
        ``(r, c)``.
    sym_block : int or None
        If set, the variable is a vertical stack of ``r / sym_block`` symmetric
        ``sym_block x sym_block`` matrices (``sym_block = r = c`` for one
        symmetric matrix); otherwise it is general.
    terms : list of (L, R, coef) or (L, R, coef, sel)
        ``L`` of shape (nb, k, r), ``R`` of shape (nb, c, k), ``coef`` a float:
        the variable contributes ``coef (L_b V R_b + (L_b V R_b)^T)`` to block b.
        ``R = None`` (symmetric variables only) means ``coef L_b V L_b^T``.
        With ``sel`` (int array (nb,)) the variable is a stack of ``r / r_s`` row blocks of
        ``r_s = L.shape[2]`` rows and block b sees only row block ``sel[b]`` (``V`` above is
        that row block): the switched design's per-mode ``S_s``.  The Schur complement then
        sums each block's Kronecker pieces only into the row blocks it touches.
    """

    name: str
    shape: tuple
    sym_block: int | None
    terms: list = field(default_factory=list)

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]


class _Sel:
    """A 0/1 selection matrix that is the same for every block (``[0; I]``, ``[I 0]``, ...), as a factor.

    Stands for the stack ``E`` (nb, m, q) with ``E_b = I_m[:, idx]`` (``t=False``) or its
    transpose ``I_m[idx, :]`` (``t=True``): a product with it is an index (no arithmetic).
    The Schur assembly multiplies every term's ``L``, ``R`` with ``X_b``, ``S_b^{-1}`` and with
    each other; in the design families most of these factors are such selectors, so most of
    those batched products become slices.
    """

    __array_ufunc__ = None  # ndarray @ _Sel defers to __rmatmul__

    def __init__(self, idx: np.ndarray, m: int, t: bool, _ix=None):
        self.idx, self.m, self.t = idx, m, t
        q = len(idx)
        self.shape = (1, q, m) if t else (1, m, q)
        if _ix is None:
            r = np.arange(idx[0], idx[0] + q) if q else idx
            _ix = slice(int(idx[0]), int(idx[0]) + q) if q and np.array_equal(idx, r) else idx
        self._ix = _ix
        self._T = None

    def swapaxes(self, a, b):
        if self._T is None:
            self._T = _Sel(self.idx, self.m, not self.t, self._ix)
            self._T._T = self
        return self._T

    def __rmatmul__(self, Z):  # Z @ E
        if not self.t:
            return Z[..., self._ix]
        out = np.zeros(Z.shape[:-1] + (self.m,))
        out[..., self._ix] = Z
        return out

    def __matmul__(self, Z):  # E @ Z
        if self.t:
            return Z[..., self._ix, :]
        out = np.zeros(Z.shape[:-2] + (self.m, Z.shape[-1]))
        out[..., self._ix, :] = Z
        return out

    @staticmethod
    def of(M):
        """``M`` (nb, a, b) as a :class:`_Sel` if it is one 0/1 selector broadcast over the blocks, else ``M``."""
        if not isinstance(M, np.ndarray) or M.ndim != 3 or (M.shape[0] > 1 and M.strides[0] != 0):
            return M
        E = M[0]
        if E.size == 0 or not np.all((E == 0.0) | (E == 1.0)):
            return M
        if np.all(E.sum(axis=0) == 1.0):
            return _Sel(np.argmax(E, axis=0), E.shape[0], False)
        if np.all(E.sum(axis=1) == 1.0):
            return _Sel(np.argmax(E, axis=1), E.shape[1], True)
        return M


#: Basis matrices per variable structure (they depend on shapes only, not on the plant data):
#: ``(T, its last row, T dense or None until asked for)``.
_BASIS_CACHE = BoundedCache(64)


@dataclass
class BlockLMI:
    """``max t`` s.t. ``C_b + sum_V terms_b(V) - t I >= 0`` and ``<a, vec V> = beta``.

    Parameters
    ----------
    C : ndarray, shape (nb, k, k)
        Constant part of the blocks at ``V = V0``.
    variables : list of MatrixVariable
    V0 : list of ndarray
        A point satisfying the equality (the start; ``C`` is the blocks' value there).
    equality : ndarray, shape (n_full - 1,) or (q, n_full - 1), or None
        Coefficients ``a`` of one linear equality (or the rows of q independent ones) on the row-major
        concatenation of the variables (``beta`` is implied by ``V0``).
    """

    C: np.ndarray
    variables: list
    V0: list
    equality: np.ndarray | None = None
    #: ``None``: ``max t`` as above.  Otherwise coefficients ``c`` (row-major concatenation of the
    #: variables): the problem is ``min <c, vec V>`` s.t. ``C_b + sum terms_b(V) >= 0`` -- no ``t``,
    #: and ``V0`` must be strictly feasible (``C`` positive definite), since the start is ``y = 0``.
    objective: np.ndarray | None = None
    #: ``None``: the dense Schur complement (:func:`solver.ipm.schur.assemble`).  Otherwise an object whose
    #: ``assemble(problem, X, G)`` returns a structured Schur complement with ``diagonal()`` and ``factor(dead)``
    #: (:class:`solver.ipm.sparse_schur.NodeStructure`: block-sparse in the node matrices of a network).
    schur_structure: object | None = None

    def __post_init__(self):
        self.nb, self.k = self.C.shape[0], self.C.shape[1]
        offsets = np.cumsum([0] + [v.size for v in self.variables])
        self.slices = [slice(int(offsets[i]), int(offsets[i + 1])) for i in range(len(self.variables))]
        self.n_full = int(offsets[-1]) + 1  # + t, the last entry
        self.with_t = self.objective is None
        key = (tuple((v.shape, v.sym_block) for v in self.variables),
               None if self.equality is None else self.equality.tobytes(), self.with_t)
        self.T, self.b, _ = _BASIS_CACHE.get_or_compute(key, self._basis_entry)
        if not self.with_t:
            self.b = -(self.T.T @ np.append(np.asarray(self.objective, dtype=np.float64), 0.0))
        self.p = self.T.shape[1]
        self._key = key

    @property
    def sel_terms(self) -> list:
        """Every variable's terms with block-constant selector factors as :class:`_Sel` (built once)."""
        terms = self.__dict__.get("_sel_terms")
        if terms is None:
            terms = self._sel_terms = [[(_Sel.of(t[0]), _Sel.of(t[1]), *t[2:]) for t in var.terms]
                                       for var in self.variables]
        return terms

    @property
    def Tt(self) -> sp.csr_matrix:
        """``T^T`` as CSR (kept: a sparse transpose per call cost as much as the product)."""
        Tt = self.__dict__.get("_Tt")
        if Tt is None:
            Tt = self._Tt = self.T.T.tocsr()
        return Tt

    def _basis_entry(self) -> tuple:
        """The basis cache's entry of this structure: ``(T, T's last row (dense), None)``."""
        T = self._basis()
        return T, np.asarray(T[-1, :].todense()).ravel(), None

    def _basis(self) -> sp.csr_matrix:
        """Sparse ``T`` with ``x_full = x0 + T y`` over the symmetric, equality-respecting directions."""
        rows, cols, vals = [], [], []
        col = 0
        for var, sl in zip(self.variables, self.slices):
            r, c = var.shape
            base = sl.start
            if var.sym_block is None:
                for e in range(r * c):
                    rows.append(base + e), cols.append(col), vals.append(1.0)
                    col += 1
            else:
                q = var.sym_block
                for blk in range(r // q):
                    for i in range(q):
                        for j in range(i, q):
                            rows.append(base + (blk * q + i) * c + j), cols.append(col), vals.append(1.0)
                            if i != j:
                                rows.append(base + (blk * q + j) * c + i), cols.append(col), vals.append(1.0)
                            col += 1
        if self.with_t:
            rows.append(self.n_full - 1), cols.append(col), vals.append(1.0)  # t
            col += 1
        T = sp.csr_matrix((vals, (rows, cols)), shape=(self.n_full, col))
        if self.equality is None:
            return T
        # One equality at a time: the directions left after eliminating the earlier ones keep them satisfied.
        for row in np.atleast_2d(self.equality):
            a = T.T @ np.append(row, 0.0)
            piv = int(np.argmax(np.abs(a)))
            col = T.shape[1]
            # Eliminate the pivot parameter: y_piv = -(sum_{j != piv} a_j y_j) / a_piv (x0 already satisfies it).
            keep = np.array([j for j in range(col) if j != piv])
            E = sp.lil_matrix((col, col - 1))
            E[keep, np.arange(col - 1)] = 1.0
            E[piv, :] = -a[keep] / a[piv]
            T = (T @ E.tocsr()).tocsr()
        return T

    # ----------------------------------------------------------------- the operator and its adjoint
    def full(self, y: np.ndarray) -> np.ndarray:
        return self.T @ y

    def op(self, y: np.ndarray) -> np.ndarray:
        """``A(y)``: the blocks' change for a step ``y``, shape (nb, k, k)."""
        x = self.T @ y
        out = np.multiply(-x[-1], np.eye(self.k))[None].repeat(self.nb, axis=0)
        for var, sl, terms in zip(self.variables, self.slices, self.sel_terms):
            V = x[sl].reshape(var.shape)
            for L, R, coef, *sel in terms:
                Vb = V.reshape(-1, L.shape[2], var.shape[1])[sel[0]] if sel else V
                if R is None:
                    out += coef * (L @ Vb @ np.swapaxes(L, 1, 2))
                else:
                    LVR = L @ Vb @ R
                    if LVR.ndim == 2:  # both factors are selectors shared by every block: one matrix for all
                        LVR = LVR[None]
                    out += coef * (LVR + np.swapaxes(LVR, 1, 2))
        return out

    def adj_full(self, U: np.ndarray, plain: bool = False) -> np.ndarray:
        """``A_full^*(U)``: ``sum_b tr(A_i U_b)`` per full coordinate (U may be nonsymmetric).

        ``plain``: with the terms as given (no selector detection).
        """
        Us = U + np.swapaxes(U, 1, 2)
        Ut = np.swapaxes(U, 1, 2)
        g = np.empty(self.n_full)
        all_terms = [var.terms for var in self.variables] if plain else self.sel_terms
        for var, sl, terms in zip(self.variables, self.slices, all_terms):
            acc = np.zeros(var.shape)
            for L, R, coef, *sel in terms:
                Lt = np.swapaxes(L, 1, 2)
                if R is None:  # tr(L E_ab L^T U) = (L^T U^T L)_ab
                    per = Lt @ Ut @ L
                else:
                    per = Lt @ Us @ np.swapaxes(R, 1, 2)
                if sel:
                    acc += coef * (_onehot(sel[0], var.shape[0] // L.shape[2]) @ per.reshape(self.nb, -1)).reshape(
                        var.shape)
                else:
                    acc += coef * per.sum(axis=0)
            g[sl] = acc.ravel()
        g[-1] = -np.trace(U, axis1=1, axis2=2).sum()
        return g

    def adj(self, U: np.ndarray) -> np.ndarray:
        return self.Tt @ self.adj_full(U)

    # ----------------------------------------------------------------- Schur complement (HKM)
    def schur(self, X: np.ndarray, G: np.ndarray, upper: bool = False) -> np.ndarray:
        """``M_ij = sum_b tr(A_i X_b A_j G_b)`` in the reduced coordinates, shape (p, p) (:func:`solver.ipm.schur.assemble`),
        or the structured form of :attr:`schur_structure`.

        ``upper``: only the upper triangle is filled (what the interior-point iteration factors).
        """
        if self.schur_structure is not None:
            return self.schur_structure.assemble(self, X, G)
        return assemble(self, X, G, upper=upper)

    def dense_operator(self) -> np.ndarray:
        """The basis matrices ``A_i`` as one array (p, nb, k, k) (small problems, tests)."""
        # this model's entry may have been dropped since it was built (models built since filled the cache)
        T = _BASIS_CACHE.get(self._key, (None, None, None))[2]
        if T is None:
            T = self.T.toarray()
            _BASIS_CACHE.put(self._key, (self.T, np.asarray(self.T[-1, :].todense()).ravel(), T))
        p, k, nb = self.p, self.k, self.nb
        if not any(len(term) > 3 for var in self.variables for term in var.terms):
            # Each full coordinate's matrices (unit entry E_ab of a variable: sym(c L E_ab R) = c
            # L[:, a] R[b, :] + transpose, or c L[:, a] L[:, b]^T), then one GEMM with the basis.
            full = np.zeros((self.n_full, nb, k, k))
            full[-1] = -np.eye(k)
            for var, sl in zip(self.variables, self.slices):
                acc = full[sl].reshape(var.shape[0], var.shape[1], nb, k, k)
                for L, R, coef in var.terms:
                    Lt = L.transpose(2, 0, 1)[:, None, :, :, None]  # (r, 1, nb, k, 1)
                    if R is None:
                        acc += coef * (Lt * L.transpose(2, 0, 1)[None, :, :, None, :])
                    else:
                        P = Lt * R.transpose(1, 0, 2)[None, :, :, None, :]
                        acc += coef * (P + P.transpose(0, 1, 2, 4, 3))
            if self.equality is not None:  # the equality's direction, for its multiplier (solve_block_lmi)
                self._eq_dir = (np.atleast_2d(self.equality) @ full[:-1].reshape(self.n_full - 1, -1)).reshape(
                    -1, nb, k, k)
            return (T.T @ full.reshape(self.n_full, -1)).reshape(p, nb, k, k)
        out = np.zeros((p, nb, k, k))
        out -= T[-1][:, None, None, None] * np.eye(k)
        for var, sl in zip(self.variables, self.slices):
            for L, R, coef, *sel in var.terms:
                Vs = T[sl].T.reshape(p, 1, *var.shape)
                if sel:
                    Vs = Vs.reshape(p, -1, L.shape[2], var.shape[1])[:, sel[0]]
                if R is None:
                    out += coef * (L @ Vs @ np.swapaxes(L, 1, 2))
                else:
                    LVR = L @ Vs @ R
                    out += coef * (LVR + np.swapaxes(LVR, 2, 3))
        return out


@dataclass
class BlockGroup:
    """One group of blocks of one side: ``C_b + sum_V terms_b(V) + sum_s v_s D_{s,b} >= 0``, b = 1..nb.

    Parameters
    ----------
    name : str
        How the result names the group's multipliers (:class:`solver.ipm.algorithm.GroupedSolution`).
    C : ndarray, shape (nb, k, k)
        The blocks at ``V = V0``.
    terms : dict
        Matrix variable name -> its Kronecker terms in this group (as :attr:`MatrixVariable.terms`).
    scalars : dict
        Scalar variable name -> ``D`` of shape (nb, k, k): the variable enters as ``v D_b``.
    """

    name: str
    C: np.ndarray
    terms: dict = field(default_factory=dict)
    scalars: dict = field(default_factory=dict)


class GroupedLMI:
    """Several groups of blocks, each of one side, in the same variables (docs/design.md, §7 "Groups").

    ``max t`` s.t. every block ``- t I >= 0`` (``objective=None``: phase 1), or ``min <c, vec V>`` s.t.
    every block ``>= 0`` from a strictly feasible ``V0`` (phase 2).  Matrix variables enter through
    Kronecker terms (each group is a :class:`BlockLMI` over them, and its Schur complement is
    :func:`solver.ipm.schur.assemble` of that group); scalar variables (``1 x 1``) through explicit
    matrices ``D`` (their Schur rows are adjoints, like ``t``'s).  No equality constraint.

    Parameters
    ----------
    matrices : list of (name, shape, sym_block)
        The matrix variables (see :class:`MatrixVariable`).
    scalars : list of str
        The scalar variables, after the matrix variables in the coordinates.
    groups : list of BlockGroup
    V0 : list of ndarray
        The start (matrix variables, then scalars as (1, 1) arrays); the groups' ``C`` are the blocks there.
    objective : dict or None
        Variable name -> coefficient array of its shape (``<c, V>`` is summed over the named variables).
    """

    def __init__(self, matrices: list, scalars: list, groups: list, V0: list, objective: dict | None = None):
        self.matrices, self.scalar_names, self.groups_spec, self.V0 = list(matrices), list(scalars), groups, V0
        self.objective = objective
        names = [m[0] for m in matrices] + list(scalars)
        shapes = [tuple(m[1]) for m in matrices] + [(1, 1)] * len(scalars)
        self.names, self.shapes = names, shapes
        c = None
        if objective is not None:
            c = np.concatenate([np.broadcast_to(np.asarray(objective.get(nm, 0.0), dtype=np.float64), sh).ravel()
                                for nm, sh in zip(names, shapes)])
        self.groups = []
        for g in groups:
            variables = [MatrixVariable(nm, tuple(sh), sb, list(g.terms.get(nm, []))) for nm, sh, sb in matrices]
            variables += [MatrixVariable(nm, (1, 1), 1, []) for nm in scalars]
            self.groups.append(BlockLMI(C=np.ascontiguousarray(g.C, dtype=np.float64), variables=variables,
                                        V0=V0, objective=c))
        g0 = self.groups[0]
        self.T, self.Tt, self.b, self.p, self.slices, self.n_full = g0.T, g0.Tt, g0.b, g0.p, g0.slices, g0.n_full
        self.with_t = g0.with_t
        # reduced coordinate of each scalar (no equality: a 1 x 1 symmetric variable is one column of T)
        self.scalar_cols = {nm: int(self.T[self.slices[len(matrices) + i].start].indices[0])
                            for i, nm in enumerate(scalars)}
        self.D = [[(self.scalar_cols[nm], np.asarray(D, dtype=np.float64)) for nm, D in g.scalars.items()]
                  for g in groups]
        self.C = [grp.C for grp in self.groups]

    @property
    def sides(self) -> list:
        return [c.shape[1] for c in self.C]

    def full(self, y: np.ndarray) -> np.ndarray:
        return self.T @ y

    def variables_at(self, y: np.ndarray) -> list:
        """``V0 + dV(y)``: the variables (matrix variables, then scalars as (1, 1) arrays)."""
        x = self.T @ y
        return [v0 + x[sl].reshape(sh) for v0, sl, sh in zip(self.V0, self.slices, self.shapes)]

    def ops(self, dense: bool | None = None):
        """``op``, ``adj``, ``schur`` over the list of groups (per group: dense basis or Kronecker pieces)."""
        per = []
        for grp, D in zip(self.groups, self.D):
            use_dense = dense if dense is not None else (grp.p * grp.nb * grp.k**2 <= 60000)
            if use_dense:
                from .schur import dense_ops

                A = grp.dense_operator()
                if D:
                    A = A.copy()
                    for col, Dm in D:
                        A[col] += Dm
                per.append(dense_ops(A))
            else:
                per.append(self._kron_ops(grp, D))

        def op(y):
            return [o[0](y) for o in per]

        def adj(U):
            out = per[0][1](U[0])
            for o, u in zip(per[1:], U[1:]):
                out = out + o[1](u)
            return out

        def schur(X, G):
            M = per[0][2](X[0], G[0])
            for o, x, g in zip(per[1:], X[1:], G[1:]):
                M = M + o[2](x, g)
            return M

        return op, adj, schur

    @staticmethod
    def _kron_ops(grp: BlockLMI, D: list):
        """One group's Kronecker-path ``op``, ``adj``, ``schur``, with its scalars' ``D`` terms added."""
        if not D:
            return grp.op, grp.adj, grp.schur

        def op(y):
            out = grp.op(y)
            for col, Dm in D:
                out = out + y[col] * Dm
            return out

        def adj(U):
            g = grp.adj(U)
            for col, Dm in D:
                g[col] += float(np.vdot(Dm, U))
            return g

        def schur(X, G):
            M = grp.schur(X, G)
            # tr(A_s X A_i G) = tr(A_i (G D_s X)): the scalar's row is an adjoint (like t's in assemble)
            for col, Dm in D:
                row = adj(G @ Dm @ X)
                M[col, :] = row
                M[:, col] = row
            return M

        return op, adj, schur

    def at(self, y: np.ndarray, objective: dict) -> "GroupedLMI":
        """The phase-2 problem: the same blocks, ``min <c, V>``, started at the phase-1 point ``y``."""
        V = self.variables_at(y)
        t = float(self.full(y)[-1]) if self.with_t else 0.0
        groups = []
        op, _, _ = self.ops(dense=False)
        for g, c, d in zip(self.groups_spec, self.C, op(y)):
            C2 = c + d + t * np.eye(c.shape[1])  # the blocks at V (d holds -t I)
            groups.append(BlockGroup(g.name, C2, g.terms, g.scalars))
        return GroupedLMI(self.matrices, self.scalar_names, groups, V, objective)
