"""The Schur complement of the HKM direction from Kronecker-structured pieces (docs/design.md).

For a :class:`solver.ipm.model.BlockLMI` whose blocks are affine in a few matrix variables through terms
``c (L V R + (L V R)^T)``, ``M_ij = sum_b tr(A_i X_b A_j G_b)`` is assembled from products of small
``L^T G L'``, ``R X R'^T`` pieces (:func:`assemble`); small problems use the explicit basis matrices
(:func:`dense_ops`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.linalg.blas import dsyr2k as _syr2k

from ..memo import BoundedCache

__all__ = ["assemble", "dense_ops", "pair", "pieces"]


def _onehot(index: np.ndarray, n: int) -> sp.csr_matrix:
    """Sparse (n, len(index)) matrix summing the rows of ``index == g`` into row g."""
    m = len(index)
    return sp.csr_matrix((np.ones(m), (index, np.arange(m))), shape=(n, m))


def pieces(L, R, coef, X, G, *sel):
    Lt = np.swapaxes(L, 1, 2)
    sel = sel[0] if sel else None
    if R is None:
        return (L, None, coef, G @ L, X @ L, None, None, Lt, sel)
    Rt = np.swapaxes(R, 1, 2)
    return (L, R, coef, G @ L, X @ L, G @ Rt, X @ Rt, Lt, sel)

def pair(a, b, shape_a, shape_b, nb):
    """Sum over blocks of ``tr(A_E X A_E' G)`` for one term of each variable, shape (r c, r2 c2).

    Layouts: ``[P]_ac [Q]_bd`` is ``kron``; ``[P]_ad [Q]_bc`` a ``kron`` with a
    commutation.  A sym-kind term is ``c L E L^T`` (E symmetric): one product
    per pair instead of four.  Terms with a row-block selection (``sel``) sum each
    block's pieces into the (row block of a, row block of b) pair it touches only,
    instead of a dense product over the whole stack (the switched design's ``S_s``:
    O(nb n^4) instead of O(nb S^2 n^4)).
    """
    L, R, cf, GL, XL, GRt, XRt, Lt, sel = a
    L2, R2, cf2, GL2, XL2, GRt2, XRt2, Lt2, sel2 = b
    r, c = L.shape[2], shape_a[1]  # rows of the (selected) variable block
    r2, c2 = L2.shape[2], shape_b[1]
    na = 1 if sel is None else shape_a[0] // r
    nb2 = 1 if sel2 is None else shape_b[0] // r2
    if sel is None and sel2 is None:
        def mm(P, Q):
            return (P.T @ Q)[None]
    else:
        gid = (np.zeros(nb, dtype=np.intp) if sel is None else sel * nb2) + (0 if sel2 is None else sel2)
        groups, inv = np.unique(gid, return_inverse=True)
        H = _onehot(inv, len(groups))

        def mm(P, Q):
            return (H @ (P[:, :, None] * Q[:, None, :]).reshape(nb, -1)).reshape(len(groups), P.shape[1], -1)
    if R is None and R2 is None:
        # (L^T G L')_ad (L^T X L')_bc
        K = mm((Lt @ GL2).reshape(nb, -1), (Lt @ XL2).reshape(nb, -1)).reshape(-1, r, r2, r, r2).transpose(
            0, 1, 3, 4, 2)
    elif R is None:
        # (L^T G R'^T)_ad (L^T X L')_bc + (L^T G L')_ac (L^T X R'^T)_bd
        K = mm((Lt @ GRt2).reshape(nb, -1), (Lt @ XL2).reshape(nb, -1)).reshape(-1, r, c2, r, r2).transpose(
            0, 1, 3, 4, 2)
        K = K + mm((Lt @ GL2).reshape(nb, -1), (Lt @ XRt2).reshape(nb, -1)).reshape(-1, r, r2, r, c2).transpose(
            0, 1, 3, 2, 4)
    elif R2 is None:
        # Only the projected (symmetric-basis) matrix matters, where block (i, j) is block (j, i)^T.
        K = pair(b, a, shape_b, shape_a, nb)
        return K.reshape(shape_b[0] * c2, shape_a[0] * c).T * 1.0
    else:
        # (L^T G L')_ac (R X R'^T)_bd + (L^T X L')_ac (R G R'^T)_bd
        def mm2(P1, P2, Q1, Q2):  # without selections: stacked along the blocks, one GEMM of twice the depth
            if sel is None and sel2 is None:
                return (np.concatenate([P1, P2]).T @ np.concatenate([Q1, Q2]))[None]
            return mm(P1, Q1) + mm(P2, Q2)

        K = mm2((Lt @ GL2).reshape(nb, -1), (Lt @ XL2).reshape(nb, -1),
                (R @ XRt2).reshape(nb, -1), (R @ GRt2).reshape(nb, -1)).reshape(-1, r, r2, c, c2).transpose(
            0, 1, 3, 2, 4)
        # (R' G L)^T_ad (R X L')_bc + (L^T X R'^T)_ad (R G L')_bc
        K2 = mm2(np.swapaxes(R2 @ GL, 1, 2).reshape(nb, -1), (Lt @ XRt2).reshape(nb, -1),
                 (R @ XL2).reshape(nb, -1), (R @ GL2).reshape(nb, -1))
        K = K + K2.reshape(-1, r, c2, c, r2).transpose(0, 1, 3, 4, 2)
    K = (cf * cf2) * K.reshape(-1, r * c, r2 * c2)
    if sel is None and sel2 is None:
        return K[0]
    full = np.zeros((na, nb2, r * c, r2 * c2))
    full[groups // nb2, groups % nb2] = K
    return full.transpose(0, 2, 1, 3).reshape(na * r * c, nb2 * r2 * c2)

def _coords(var):
    """The reduced coordinates of one variable: ``(A1, B1, A2, B2)`` (entries ``V[A, B]``), as ``_basis`` orders them.

    A symmetric coordinate is the sum of the entries ``(A1, B1)`` and ``(A2, B2)`` (the same entry on the
    diagonal); a general one is ``(A1, B1)`` alone (``A2 = None``).
    """
    r, c = var.shape
    if var.sym_block is None:
        A, B = np.divmod(np.arange(r * c), c)
        return A, B, None, None
    q = var.sym_block
    i, j = np.triu_indices(q)
    blk = np.repeat(np.arange(r // q), len(i))
    i, j = np.tile(i, r // q), np.tile(j, r // q)
    return blk * q + i, j, blk * q + j, i


#: Rows per band of a diagonal block's gather (the band's takes stay in cache).
_BAND = 96


class _Plan:
    """What the assembly needs besides X and G, built once per problem (shapes and the basis only).

    The reduced coordinates before the equality's elimination (``T = T0 E``, ``T0`` the symmetric basis):
    per variable its coordinates (:func:`_coords`) and offset, ``t`` last; and ``E``'s structure, the
    identity with one dense row ``w`` at the pivot ``piv`` (``None``: no equality; ``E``: a general ``E``).
    """

    def __init__(self, problem):
        self.coords = [_coords(v) for v in problem.variables]
        sizes = [len(c[0]) for c in self.coords]
        self.offsets = np.cumsum([0] + sizes)
        self.p0 = int(self.offsets[-1]) + (1 if problem.with_t else 0)
        rows, cols = [], []
        for (A1, B1, A2, B2), var, sl, off in zip(self.coords, problem.variables, problem.slices, self.offsets):
            c = var.shape[1]
            idx = np.arange(len(A1)) + off
            rows += [sl.start + A1 * c + B1]
            cols += [idx]
            if A2 is not None:
                two = (A2 != A1) | (B2 != B1)
                rows += [sl.start + A2[two] * c + B2[two]]
                cols += [idx[two]]
        if problem.with_t:
            rows.append([problem.n_full - 1]), cols.append([self.p0 - 1])
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        T0 = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(problem.n_full, self.p0))
        self.T0t = T0.T.tocsr()
        E = sp.csr_matrix(sp.diags(1.0 / np.asarray(T0.sum(axis=0)).ravel()) @ (self.T0t @ problem.T))
        self.piv, self.w, self.E = None, None, None
        p = problem.p
        if p == self.p0 and (abs(E - sp.identity(p)) > 0).nnz == 0:
            return
        if p == self.p0 - 1:  # identity but for the pivot's row: E[r, r] = 1 above it, E[r, r - 1] = 1 below
            E.sum_duplicates()
            nnz = np.diff(E.indptr)
            single = nnz == 1
            col = np.where(single, E.indices[np.minimum(E.indptr[:-1], len(E.indices) - 1)], -1)
            val = np.where(single, E.data[np.minimum(E.indptr[:-1], len(E.data) - 1)], 0.0)
            r = np.arange(self.p0)
            unit_above = single & (col == r) & (val == 1.0)
            piv = int(np.argmin(unit_above)) if not unit_above.all() else self.p0 - 1
            below = single & (col == r - 1) & (val == 1.0)
            if unit_above[:piv].all() and below[piv + 1:].all():
                self.piv, self.w = piv, E.getrow(piv).toarray().ravel()
                self.wnz = np.flatnonzero(self.w)
                return
        self.E = E

    def positions(self, i, strides):
        """Flat positions of variable i's coordinates ``V[A, B]`` in a piece with strides ``(s_A, s_B)``."""
        cache = self.__dict__.setdefault("_cache", {})
        key = ("positions", i, strides)
        out = cache.get(key)
        if out is None:
            A1, B1, A2, B2 = self.coords[i]
            out = cache[key] = [A1 * strides[0] + B1 * strides[1]] + (
                [] if A2 is None else [A2 * strides[0] + B2 * strides[1]])
        return out

    def diag(self, i):
        """Local indices of variable i's symmetric coordinates on the diagonal (counted twice by a gather)."""
        cache = self.__dict__.setdefault("_cache", {})
        key = ("diag", i)
        if key not in cache:
            A1, B1, A2, B2 = self.coords[i]
            cache[key] = None if A2 is None else np.flatnonzero((A1 == A2) & (B1 == B2))
        return cache[key]


    def pairs(self, i):
        """Upper-triangle index pairs ``(a <= c)`` of a square symmetric variable (the packed pieces' order)."""
        n = int(self.coords[i][1].max()) + 1
        return np.triu_indices(n)

    def packed_positions(self, i, band=_BAND):
        """Per band of rows (as :func:`_gather` cuts a diagonal block): the positions of
        ``Y[{a, c}, {b, d}]`` and ``Y[{a, d}, {b, c}]`` in the packed ``Y`` (upper triangle, pairs ``{x, y}``
        numbered as :meth:`pairs`), for coordinates ``(a, b)`` rows and ``(c, d)`` columns.
        """
        key = ("packed", i, band)
        got = self.__dict__.get("_cache", {}).get(key)
        if got is not None:
            return got
        A, B = self.coords[i][0], self.coords[i][1]
        n = int(B.max()) + 1
        num = np.zeros((n, n), dtype=np.intp)
        iu0, iu1 = np.triu_indices(n)
        num[iu0, iu1] = np.arange(len(iu0))
        num[iu1, iu0] = np.arange(len(iu0))
        m = len(iu0)
        first, second = [], []
        for b0 in range(0, len(A), band):
            b1 = min(len(A), b0 + band)
            a, b = A[b0:b1, None], B[b0:b1, None]
            c, d = A[None, b0:], B[None, b0:]
            for out, (x, y) in ((first, (num[a, c], num[b, d])), (second, (num[a, d], num[b, c]))):
                out.append(np.minimum(x, y) * m + np.maximum(x, y))
        got = (first, second)
        self.__dict__.setdefault("_cache", {})[key] = got
        return got


def _packed_pieces(plan, i, Ps, Qs):
    """The pieces of pairs with symmetric ``P``, ``Q`` (``L^T G L``, ``R X R^T``) of a symmetric variable.

    ``K[(a, c), (b, d)]`` is then symmetric in ``a <-> c`` and in ``b <-> d``: the GEMM runs on the
    packed upper triangles (a quarter of the flops), as ``Y = K + K^T`` (one ``dsyr2k``), and the
    projection is ``Y[{a, c}, {b, d}] + Y[{a, d}, {b, c}]`` (positions precomputed per band).
    """
    Y = _syr2k(1.0, Ps.reshape(Ps.shape[0], -1).T, Qs.reshape(Qs.shape[0], -1).T, trans=0, lower=1)
    first, second = plan.packed_positions(i)
    diag = plan.diag(i)
    return [(Y.T.reshape(-1), [(None, first, None, None), (None, second, None, None)], diag, diag)]


#: Plans by the problem's structure key (:attr:`solver.ipm.model.BlockLMI._key`: the variables' shapes, the equality,
#: the form), which fixes everything a :class:`_Plan` reads (variables, slices, basis): the rate search's probes and
#: "auto"'s final design build one problem per rate, and a plan cost 2 ms of a 3.7 ms first assembly at n = 8.
_PLANS = BoundedCache(64)


def _plan(problem) -> _Plan:
    plan = problem.__dict__.get("_schur_plan")
    if plan is None:
        key = problem.__dict__.get("_key")
        plan = _Plan(problem) if key is None else _PLANS.get_or_compute(key, lambda: _Plan(problem))
        problem._schur_plan = plan
    return plan


def _products(terms):
    """Each term ``c (L V R + R^T V^T L^T)`` as its two products ``c L V R``, ``c R^T V^T L^T``; ``c L V L^T`` as one.

    A product is ``(L, R, transposed, c)``: ``transposed`` says the variable enters as ``V^T`` (its
    row index is the product's column index).
    """
    out = []
    for L, R, coef, *_ in terms:
        if R is None:
            out.append([(L, np.swapaxes(L, 1, 2), False, coef)])
        else:
            out.append([(L, R, False, coef), (np.swapaxes(R, 1, 2), np.swapaxes(L, 1, 2), True, coef)])
    return out


def _square_sym(var) -> bool:
    return var.sym_block is not None and var.sym_block == var.shape[0] == var.shape[1]


def _operands(u, v, X, G, cache):
    """``(P, Q)`` with ``tr(A_u(e_a e_b^T) X A_v(e_c e_d^T) G) = sum_blocks P[x_u, y_v] Q[y_u, x_v]``.

    ``x, y`` are a product's (row, column) index of the variable: ``(a, b)`` for ``L V R``, ``(b, a)``
    for ``R^T V^T L^T`` (likewise ``(c, d)`` for v); ``P = L_u^T G R_v^T``, ``Q = R_u X L_v``.
    """
    Lu, Ru, _, cu = u
    Lv, Rv, _, cv = v
    key = id(v[0]), id(v[1])
    if key not in cache:
        cache[key] = (G @ np.swapaxes(Rv, 1, 2), X @ Lv)
    GRv, XLv = cache[key]
    P = np.swapaxes(Lu, 1, 2) @ GRv
    Q = Ru @ XLv
    return (P if cu * cv == 1.0 else (cu * cv) * P), Q


def _add_pair(groups, u, v, i_sym, j_sym, X, G, cache, transposed_too):
    """Put one product pair's (P, Q) into its GEMM group, keyed by the layout of ``P^T Q``.

    Layouts (full coordinates ``(a, b)`` of variable i, ``(c, d)`` of j): ``"ac"`` is ``K[(a, c), (b, d)]``,
    ``"ad"`` is ``K[(a, d), (b, c)]``.  Only the projection onto the symmetric coordinates counts, so a
    pair of a symmetric variable may rename ``a <-> b`` (or ``c <-> d``): both layouts become ``"ac"``.
    """
    P, Q = _operands(u, v, X, G, cache)
    # P holds (x_u, y_v), Q (y_u, x_v): x_u is a unless u is transposed, y_v is d unless v is transposed.
    if u[2]:  # P holds b: swap the operands so that the first one holds a (K becomes K^T, same entries)
        P, Q = Q, P
        second = "d" if v[2] else "c"
    else:
        second = "c" if v[2] else "d"
    if second == "d" and j_sym:  # P[a, d] Q[b, c] ~ P[a, c] Q[b, d] (c <-> d)
        second = "c"
    elif second == "d" and i_sym:  # P[a, d] Q[b, c] ~ P[b, d] Q[a, c] (a <-> b) = Q[a, c] P[b, d]
        P, Q = Q, P
        second = "c"
    layout = "a" + second
    groups.setdefault((layout, transposed_too), []).append((P.reshape(P.shape[0], -1), Q.reshape(Q.shape[0], -1)))


def _strides(layout, dims_i, dims_j):
    """``(s_a, s_b), (s_c, s_d)``: flat strides of the four indices in the piece ``K`` of a layout."""
    c, (r2, c2) = dims_i[1], dims_j
    if layout == "ac":  # K[(a, c), (b, d)], shape (r r2, c c2)
        return (r2 * c * c2, c2), (c * c2, 1)
    if layout == "ad":  # K[(a, d), (b, c)], shape (r c2, c r2)
        return (c2 * c * r2, r2), (1, c * r2)
    # "ab": K[(a, b), (c, d)], the full-coordinate block
    return (c * r2 * c2, r2 * c2), (c2, 1)


def _gather(out, row0, col0, pieces, upper, out_shape, band=_BAND):
    """``out[row0 + I, col0 + J] = sum`` over the pieces' takes of ``K.flat[rp[I] + cp[J]]`` (the projection).

    ``pieces``: ``(Kflat, takes, halve_rows, halve_cols)``, ``takes`` a list of ``(rp, cp, zero_rows,
    zero_cols)`` (index arrays of rows/columns whose take is dropped, or None); ``halve_*``: local
    indices of rows/columns counted twice (symmetric coordinates on the diagonal, whose two full
    entries are one).  ``upper``: only ``J >= I`` is needed (a diagonal block), done in bands of rows.
    ``rp = None``: ``cp`` is the list of each band's precomputed 2-D positions.
    """
    nI, nJ = out_shape
    for bi, b0 in enumerate(range(0, nI, band)):
        b1 = min(nI, b0 + band)
        j0 = b0 if upper else 0
        acc = None
        for Kf, takes, halve_rows, halve_cols in pieces:
            part = None
            for rp, cp, zero_rows, zero_cols in takes:
                g = np.take(Kf, cp[bi] if rp is None else rp[b0:b1, None] + cp[None, j0:])
                if zero_rows is not None:
                    g[zero_rows[(zero_rows >= b0) & (zero_rows < b1)] - b0] = 0.0
                if zero_cols is not None:
                    g[:, zero_cols[zero_cols >= j0] - j0] = 0.0
                if part is None:
                    part = g
                else:
                    part += g
            if halve_rows is not None:
                part[halve_rows[(halve_rows >= b0) & (halve_rows < b1)] - b0] *= 0.5
            if halve_cols is not None:
                part[:, halve_cols[halve_cols >= j0] - j0] *= 0.5
            if acc is None:
                acc = part
            else:
                acc += part
        out[row0 + b0: row0 + b1, col0 + j0: col0 + nJ] = acc


def _takes(plan, i, j, rs, cs):
    """Every pair of full entries of the coordinates: ``(rp, cp, None, None)`` for the strides ``rs``, ``cs``."""
    return [(rp, cp, None, None) for rp in plan.positions(i, rs) for cp in plan.positions(j, cs)]


def _sym_pieces(plan, i, Ps, Qs, both):
    """The pieces of a symmetric variable's diagonal block from ``Y = K + K^T`` (``K = Ps^T Qs``, layout "ac").

    With ``Y`` the projection needs two takes instead of four: for coordinates ``(a, b)``, ``(c, d)``
    (``a <= b``, ``c <= d``, ``(a, b) <= (c, d)``) it is ``Y[(a, c), (b, d)] + Y[(a, d), (b, c)]``; the
    transposed pair's (``both``) ``Y[(c, a), (d, b)] + Y[(c, b), (d, a)]``.  ``Y`` is one ``dsyr2k``
    (the flops of the GEMM ``K``) that fills only its upper triangle in these coordinates; the second
    take would read the lower one exactly where its row (column) is a diagonal coordinate, where the
    first take alone is the value.
    """
    n = int(plan.coords[i][1].max()) + 1
    Y = _syr2k(1.0, Ps.T, Qs.T, trans=0, lower=1)  # F-ordered: Y.T is C-ordered with the upper triangle set
    Yf = Y.T.reshape(-1)
    rows, cols = _strides("ac", (n, n), (n, n))
    diag = plan.diag(i)
    r1 = plan.positions(i, rows)[0]  # row part of (a, b)
    c1, c2 = plan.positions(i, cols)  # column parts of (c, d), (d, c); with (a, b) as columns: the transposed pair
    out = [(Yf, [(r1, c1, None, None), (r1, c2, diag, None)], None, diag)]
    if both:
        out.append((Yf, [(c1, r1, None, None), (c2, r1, None, diag)], diag, None))
    return out


def assemble(problem, X: np.ndarray, G: np.ndarray, upper: bool = False) -> np.ndarray:
    """``M_ij = sum_b tr(A_i X_b A_j G_b)`` in the reduced coordinates, shape (p, p).

    For terms ``c (L E R + R^T E^T L^T)`` and ``c' (L' E' R' + ...)`` each of the four products of
    ``tr(A_E X A_E' G)`` is a Kronecker product of small pieces (row-major ``E = e_a e_b^T``,
    ``E' = e_c e_d^T``)::

        (L^T G L')_ac (R X R'^T)_bd + (L^T X L')_ac (R G R'^T)_bd
      + (R'G L)^T_ad (R X L')_bc   + (L^T X R'^T)_ad (R G L')_bc

    Per pair of variables, every such product of every pair of terms goes into one GEMM over the stacked
    pieces (one per layout, ``(a, c)`` or ``(a, d)`` rows: a symmetric variable needs one), whose result
    is projected onto the symmetric, equality-eliminated coordinates by index arithmetic (one gather per
    full entry of a coordinate) instead of transposing it into the full coordinates and multiplying
    with the basis.  Terms with a row-block selection (the switched design's ``S_s``) take
    :func:`pair`'s full-coordinate blocks, projected the same way.

    ``upper``: fill only the upper triangle (``i <= j``; what the Cholesky factorization reads); the
    lower one is then arbitrary.
    """
    plan = _plan(problem)
    p0 = plan.p0
    M0 = np.empty((p0, p0))
    nb = problem.nb
    variables = problem.variables
    sel_terms = problem.sel_terms
    has_sel = [any(len(t) > 3 for t in terms) for terms in sel_terms]
    products = [None if s else _products(terms) for s, terms in zip(has_sel, sel_terms)]
    cache = {}
    old = None
    for i, vi in enumerate(variables):
        for j in range(i, len(variables)):
            vj = variables[j]
            dims_i, dims_j = vi.shape, vj.shape
            parts = []  # (K, layout, with its transpose)
            sym_parts = []
            if has_sel[i] or has_sel[j]:
                if old is None:
                    old = [[pieces(*term[:3], X, G, *term[3:]) for term in terms] for terms in sel_terms]
                block = None
                for ta, a in enumerate(old[i]):
                    for tb, b in enumerate(old[j]):
                        if i == j and tb < ta:
                            continue
                        K = pair(a, b, vi.shape, vj.shape, nb)
                        if i == j and tb != ta:
                            K = K + K.T
                        block = K if block is None else block + K
                if block is not None:
                    parts.append((block, "ab", False))
            else:
                groups = {}
                i_sym, j_sym = _square_sym(vi), _square_sym(vj)
                for ta, prods_a in enumerate(products[i]):
                    for tb, prods_b in enumerate(products[j]):
                        if i == j and tb < ta:
                            continue  # added as the transpose of (tb, ta): M is symmetric
                        for iu, u in enumerate(prods_a):
                            for iv, v in enumerate(prods_b):
                                both = i == j and ta != tb
                                if i == j and i_sym and ta == tb and (len(prods_a) == 1 or iu != iv):
                                    # (u, u^T), (u^T, u), (N, N): symmetric pieces L^T G L, R X R^T
                                    P, Q = _operands(u, v, X, G, cache)
                                    iu0, iu1 = plan.pairs(i)
                                    groups.setdefault(("sym", False), []).append((P[:, iu0, iu1], Q[:, iu0, iu1]))
                                    continue
                                if i == j and ta == tb and len(prods_a) == 2 and iu == iv:
                                    # (u^T, u^T) is (u, u) transposed: tr(A_u(E) G A_u(E') X) = tr(A_u(E') X A_u(E) G)
                                    if iu == 1:
                                        continue
                                    both = True
                                _add_pair(groups, u, v, i_sym, j_sym, X, G, cache, both)
                for (layout, both), ops in groups.items():
                    Ps = ops[0][0] if len(ops) == 1 else np.concatenate([o[0] for o in ops])
                    Qs = ops[0][1] if len(ops) == 1 else np.concatenate([o[1] for o in ops])
                    if layout == "sym":
                        sym_parts += _packed_pieces(plan, i, Ps, Qs)
                    elif i == j and i_sym:
                        sym_parts += _sym_pieces(plan, i, Ps, Qs, both)
                    else:
                        parts.append((Ps.T @ Qs, layout, both))
            si, sj = int(plan.offsets[i]), int(plan.offsets[j])
            ni, nj = int(plan.offsets[i + 1]) - si, int(plan.offsets[j + 1]) - sj
            if not parts and not sym_parts:
                M0[si:si + ni, sj:sj + nj] = 0.0
                continue
            halve_i, halve_j = plan.diag(i), plan.diag(j)
            specs = list(sym_parts)
            for K, layout, both in parts:
                rs, cs = _strides(layout, dims_i, dims_j)
                Kf = K.reshape(-1)
                specs.append((Kf, _takes(plan, i, j, rs, cs), halve_i, halve_j))
                if both:  # the transposed pair: (tb, ta)'s block is (ta, tb)'s transposed
                    specs.append((Kf, _takes(plan, i, j, cs, rs), halve_i, halve_j))
            _gather(M0, si, sj, specs, upper=(i == j), out_shape=(ni, nj))
    if problem.with_t:
        # t column: A_t = -I, so M[t, v] = -sum tr(A_v G X) (tr(A X A_t G) = -tr(A X G)).
        col = -problem.adj_full(G @ X)
        col[-1] = np.einsum("bij,bji->", X, G)
        col = plan.T0t @ col
        M0[-1, :] = col
        M0[:, -1] = col
    if not upper:
        il = np.tril_indices(p0, -1)
        M0[il] = M0.T[il]
    return _eliminate(plan, M0, upper)


def _eliminate(plan, M0, upper):
    """``E^T M0 E``: the equality's pivot coordinate removed (``x_piv = w^T y``), by slicing and a rank-2 update."""
    if plan.piv is None and plan.E is None:
        return M0
    if plan.E is not None:  # pragma: no cover - a general E (never built by BlockLMI._basis)
        M = plan.E.T @ (plan.E.T @ M0.T).T
        return np.asarray(M)
    piv, w, nz = plan.piv, plan.w, plan.wnz
    m = np.concatenate([M0[:piv, piv], M0[piv, piv + 1:]])  # row/column piv from the upper triangle
    mpp = M0[piv, piv]
    if piv == 0:
        M = M0[1:, 1:]
    elif piv == M0.shape[0] - 1:
        M = M0[:-1, :-1]
    else:
        M = np.delete(np.delete(M0, piv, axis=0), piv, axis=1)
    # M += w m^T + m w^T + mpp w w^T, touching only the rows and columns where w is nonzero
    wn = w[nz]
    M[nz, :] += wn[:, None] * m[None, :]
    M[:, nz] += m[:, None] * wn[None, :]
    M[np.ix_(nz, nz)] += mpp * (wn[:, None] * wn[None, :])
    return M


def dense_ops(Aop: np.ndarray):
    """``op``, ``adj``, ``schur`` from the explicit basis matrices (p, nb, k, k): few numpy calls."""
    p, nb, k = Aop.shape[0], Aop.shape[1], Aop.shape[2]
    Aflat = Aop.reshape(p, -1)
    Ab = np.ascontiguousarray(Aop.reshape(p, nb, k * k).transpose(1, 0, 2))  # (nb, p, k^2)
    AflatT = Aflat.T
    shape = Aop.shape[1:]

    def op(y):
        return (y @ Aflat).reshape(shape)

    def adj(U):
        return Aflat @ U.reshape(-1)  # A_i symmetric: tr(A_i U) = <A_i, U> for any U

    def schur(X, G):
        # M_ij = sum_b tr(A_ib X_b A_jb G_b) = sum_b vec(A_ib)^T K_b vec(A_jb) with
        # K_b[(a, c), (d, e)] = G_b[a, e] X_b[c, d]: one broadcast product, one batched and one plain GEMM
        # (instead of two batched products over all p * nb basis matrices).
        K = (G[:, :, None, None, :] * X[:, None, :, :, None]).reshape(nb, k * k, k * k)
        return (Ab @ K).transpose(1, 0, 2).reshape(p, -1) @ AflatT

    return op, adj, schur
