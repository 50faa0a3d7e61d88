"""The Schur complement of the HKM direction from Kronecker-structured pieces (docs/design.md).

For a :class:`solver.ipm.model.BlockLMI` whose blocks are affine in a few matrix variables through terms
``c (L V R + (L V R)^T)``, ``M_ij = sum_b tr(A_i X_b A_j G_b)`` is assembled from products of small
``L^T G L'``, ``R X R'^T`` pieces (:func:`assemble`); small problems use the explicit basis matrices
(:func:`dense_ops`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

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

def assemble(problem, X: np.ndarray, G: np.ndarray) -> np.ndarray:
    """``M_ij = sum_b tr(A_i X_b A_j G_b)`` in the reduced coordinates, shape (p, p).

    For terms ``c (L E R + R^T E^T L^T)`` and ``c' (L' E' R' + ...)`` the four
    products of ``tr(A_E X A_E' G)`` are Kronecker products of small pieces
    (row-major ``E = e_a e_b^T``, ``E' = e_c e_d^T``)::

        (L^T G L')_ac (R X R'^T)_bd + (L^T X L')_ac (R G R'^T)_bd
      + (R'G L)^T_ad (R X L')_bc   + (L^T X R'^T)_ad (R G L')_bc

    and each sum over blocks is one GEMM over the stacked pieces (see :func:`pair`).
    """
    nf = problem.n_full
    M = np.empty((nf, nf))
    cache = [[pieces(*term[:3], X, G, *term[3:]) for term in var_terms] for var_terms in problem.sel_terms]
    nb = problem.nb
    for i, (vi, si) in enumerate(zip(problem.variables, problem.slices)):
        for j in range(i, len(problem.variables)):
            vj, sj = problem.variables[j], problem.slices[j]
            block = None
            for ta, a in enumerate(cache[i]):
                for tb, b in enumerate(cache[j]):
                    if i == j and tb < ta:
                        continue  # added below as the transpose of (tb, ta): only the projection counts
                    K = pair(a, b, vi.shape, vj.shape, nb)
                    if i == j and tb != ta:
                        K = K + K.T
                    block = K if block is None else block + K
            if block is None:
                block = np.zeros((vi.size, vj.size))
            M[si, sj] = block
            if j != i:
                M[sj, si] = block.T
    # t column: A_t = -I, so M[t, v] = -sum tr(A_v G X) (tr(A X A_t G) = -tr(A X G)).
    GX = G @ X
    col = -problem.adj_full(GX)
    col[-1] = np.einsum("bij,bji->", X, G)
    M[-1, :] = col
    M[:, -1] = col
    Tt = problem.Tt
    return np.asarray(Tt @ np.asarray(Tt @ M).T)


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
