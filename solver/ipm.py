"""A structure-exploiting primal-dual interior-point solver for the design LMIs (docs/design.md).

Every SDP the design methods solve has the form::

    maximize   t
    subject to B_b(V) - t I >= 0,   b = 1..nb        (all blocks of one side k)
               one linear equality on V (the normalization, e.g. trace W = n)

where ``V`` is a handful of matrix variables (symmetric ``W``, general
``Y``, ...) and every block is a sum of terms ``c (L V R + (L V R)^T)`` plus
a constant.  A general conic solver keeps each block's scaling as a dense
``(k(k+1)/2)^2`` matrix in its KKT system; here the Schur complement
``M_ij = sum_b tr(A_i X_b A_j S_b^{-1})`` (HKM direction) is assembled from
Kronecker products of small ``L^T G L'``, ``R X R'^T`` pieces: the sum over
the blocks of ``kron(P_b, Q_b)`` is ONE matrix product
``P^T Q`` of the blocks' vectorized pieces (``P`` of shape (nb, r r'),
``Q`` of shape (nb, c c')), so the cost is ``O(nb n^4)`` BLAS-3 work instead
of ``O(nb k^6)``.

The solver works on the standard pair (``y`` the free variables left after
eliminating the equality, ``X_b`` the block multipliers)::

    (D)  max b^T y   s.t.  S = C + A(y) >= 0
    (P)  min <C, X>  s.t.  A^*(X) + b = 0,  X >= 0

with an infeasible start (``S`` starts strictly feasible, ``X = I / (nb k)``
does not satisfy ``A^*(X) + b = 0``), the HKM symmetrized direction and
Mehrotra's predictor-corrector, separate primal and dual step lengths, and
stops on relative gap and relative primal/dual infeasibility.  Because the
``y`` iterates stay feasible (``S > 0``), ``t = b^T y`` is always an
*attained* value: a returned ``t > margin`` is backed by a feasible
``(W, Y)`` whatever the status; ``<C, X>`` bounds ``t*`` from above once
the primal residual is small.

Public entry points: :func:`solve_lmi` (the ``lmi`` design),
:func:`solve_switched` (the ``switched`` design), :func:`solve_common_fixed_gain`
(the fixed-gain certificate LMI of ``analyze``), and the generic
:class:`BlockLMI` / :func:`solve_block_lmi` they are built on.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.linalg.lapack
import scipy.sparse as sp

__all__ = [
    "MatrixVariable",
    "BlockLMI",
    "IPMOptions",
    "IPMSolution",
    "LMISolution",
    "SwitchedSolution",
    "design_solve",
    "design_solve_fixed_gain",
    "blas_threads",
    "solve_block_lmi",
    "solve_lmi",
    "solve_switched",
    "solve_common_fixed_gain",
    "lmi_problem",
    "switched_problem",
]


# ----------------------------------------------------------------------------- BLAS threads
_BLAS = None


def _blas_controls() -> list:
    """(get, set) pairs of every OpenBLAS loaded in this process (numpy's and scipy's are separate)."""
    global _BLAS
    if _BLAS is not None:
        return _BLAS
    _BLAS = []
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({ln.split()[-1] for ln in fh if "openblas" in ln.lower() and ln.split()[-1].startswith("/")})
    except OSError:
        paths = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for suffix in ("64_", "", "_"):
            for stem in ("scipy_openblas", "openblas"):
                try:
                    get = getattr(lib, f"{stem}_get_num_threads{suffix}")
                    set_ = getattr(lib, f"{stem}_set_num_threads{suffix}")
                except AttributeError:
                    continue
                get.restype = ctypes.c_int
                set_.argtypes = [ctypes.c_int]
                _BLAS.append((get, set_))
                break
            else:
                continue
            break
    return _BLAS


@contextlib.contextmanager
def blas_threads(n: int | None):
    """Run a block with ``n`` OpenBLAS threads (None: leave as is), restoring them after.

    The IPM's BLAS calls are many and small (k = 2n <= 64): on a loaded
    2-core machine OpenBLAS's threads spin against each other and one
    solve took 10-20x longer than single-threaded (measured: n = 12,
    11.5 s vs 0.7 s), so the solver runs single-threaded by default.
    """
    controls = _blas_controls() if n is not None else []
    saved = [get() for get, _ in controls]
    for _, set_ in controls:
        set_(int(n))
    try:
        yield
    finally:
        for (_, set_), old in zip(controls, saved):
            set_(old)


_LIBC = None
#: glibc ``mallopt`` parameters (malloc.h).
_M_TRIM_THRESHOLD, _M_MMAP_MAX = -1, -4


def _libc():
    global _LIBC
    if _LIBC is None:
        try:
            lib = ctypes.CDLL("libc.so.6")
            lib.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
            lib.malloc_trim.argtypes = [ctypes.c_size_t]
            _LIBC = lib
        except (OSError, AttributeError):
            _LIBC = False
    return _LIBC


@contextlib.contextmanager
def heap_reuse(enabled: bool = True):
    """Keep freed large arrays in the heap for the block's duration, then hand them back.

    glibc serves arrays above its mmap threshold (128 kB to 32 MB) by fresh ``mmap`` and unmaps them on
    free, so every iteration's temporaries (the Schur matrix, the Kronecker pieces: tens of MB at
    n = 50) fault in their pages again: at n = 50, r = 5, n_drop = 10 that was 456 000 page faults and
    a third of the CPU time, as system time.  Inside this block large allocations come from the heap
    and freed memory stays there for the next iteration; ``malloc_trim`` returns it at the end.
    A no-op where glibc is absent.
    """
    lib = _libc() if enabled else False
    if not lib:
        yield
        return
    lib.mallopt(_M_MMAP_MAX, 0)
    lib.mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)
    try:
        yield
    finally:
        lib.mallopt(_M_MMAP_MAX, 65536)  # glibc's default
        lib.mallopt(_M_TRIM_THRESHOLD, 128 * 1024)
        lib.malloc_trim(0)


# ----------------------------------------------------------------------------- problem description
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


#: Basis matrices T per variable structure (they depend on shapes only, not on the plant data).
_BASIS_CACHE: dict = {}


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
    equality : ndarray, shape (n_full,) or None
        Coefficients ``a`` of the one linear equality on the row-major
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

    def __post_init__(self):
        self.nb, self.k = self.C.shape[0], self.C.shape[1]
        offsets = np.cumsum([0] + [v.size for v in self.variables])
        self.slices = [slice(int(offsets[i]), int(offsets[i + 1])) for i in range(len(self.variables))]
        self.n_full = int(offsets[-1]) + 1  # + t, the last entry
        self.with_t = self.objective is None
        key = (tuple((v.shape, v.sym_block) for v in self.variables),
               None if self.equality is None else self.equality.tobytes(), self.with_t)
        if key not in _BASIS_CACHE:
            if len(_BASIS_CACHE) > 64:
                _BASIS_CACHE.clear()
            T = self._basis()
            _BASIS_CACHE[key] = (T, np.asarray(T[-1, :].todense()).ravel(), None)
        self.T, self.b, _ = _BASIS_CACHE[key]
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
        a = T.T @ np.append(self.equality, 0.0)
        piv = int(np.argmax(np.abs(a)))
        # Eliminate the pivot parameter: y_piv = -(sum_{j != piv} a_j y_j) / a_piv (x0 already satisfies it).
        keep = np.array([j for j in range(col) if j != piv])
        E = sp.lil_matrix((col, col - 1))
        E[keep, np.arange(col - 1)] = 1.0
        E[piv, :] = -a[keep] / a[piv]
        return (T @ E.tocsr()).tocsr()

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
    @staticmethod
    def _pieces(L, R, coef, X, G, *sel):
        Lt = np.swapaxes(L, 1, 2)
        sel = sel[0] if sel else None
        if R is None:
            return (L, None, coef, G @ L, X @ L, None, None, Lt, sel)
        Rt = np.swapaxes(R, 1, 2)
        return (L, R, coef, G @ L, X @ L, G @ Rt, X @ Rt, Lt, sel)

    @staticmethod
    def _pair(a, b, shape_a, shape_b, nb):
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
            K = BlockLMI._pair(b, a, shape_b, shape_a, nb)
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

    def schur(self, X: np.ndarray, G: np.ndarray) -> np.ndarray:
        """``M_ij = sum_b tr(A_i X_b A_j G_b)`` in the reduced coordinates, shape (p, p).

        For terms ``c (L E R + R^T E^T L^T)`` and ``c' (L' E' R' + ...)`` the four
        products of ``tr(A_E X A_E' G)`` are Kronecker products of small pieces
        (row-major ``E = e_a e_b^T``, ``E' = e_c e_d^T``)::

            (L^T G L')_ac (R X R'^T)_bd + (L^T X L')_ac (R G R'^T)_bd
          + (R'G L)^T_ad (R X L')_bc   + (L^T X R'^T)_ad (R G L')_bc

        and each sum over blocks is one GEMM over the stacked pieces (see :meth:`_pair`).
        """
        nf = self.n_full
        M = np.empty((nf, nf))
        cache = [[self._pieces(*term[:3], X, G, *term[3:]) for term in var_terms] for var_terms in self.sel_terms]
        nb = self.nb
        for i, (vi, si) in enumerate(zip(self.variables, self.slices)):
            for j in range(i, len(self.variables)):
                vj, sj = self.variables[j], self.slices[j]
                block = None
                for ta, a in enumerate(cache[i]):
                    for tb, b in enumerate(cache[j]):
                        if i == j and tb < ta:
                            continue  # added below as the transpose of (tb, ta): only the projection counts
                        K = self._pair(a, b, vi.shape, vj.shape, nb)
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
        col = -self.adj_full(GX)
        col[-1] = np.einsum("bij,bji->", X, G)
        M[-1, :] = col
        M[:, -1] = col
        Tt = self.Tt
        return np.asarray(Tt @ np.asarray(Tt @ M).T)

    def dense_operator(self) -> np.ndarray:
        """The basis matrices ``A_i`` as one array (p, nb, k, k) (small problems, tests)."""
        T = _BASIS_CACHE[self._key][2]
        if T is None:
            T = self.T.toarray()
            _BASIS_CACHE[self._key] = _BASIS_CACHE[self._key][:2] + (T,)
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
                self._eq_dir = (self.equality @ full[:-1].reshape(self.n_full - 1, -1)).reshape(nb, k, k)
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


# ----------------------------------------------------------------------------- options and results
@dataclass
class IPMOptions:
    """Tolerances and limits of the interior-point method.

    Attributes
    ----------
    gap_tol : float
        Stop when ``|<C,X> - b^T y| / (1 + |<C,X>| + |b^T y|)`` is below this ...
    feas_tol : float
        ... and the relative primal and dual residuals are below this.
    max_iter : int
        Iteration cap (the method never hangs on degenerate data).
    step : float
        Fraction of the step to the boundary that is taken.
    time_limit : float or None
        Seconds; the best iterate so far is returned with status ``"time_limit"``.
    dense : bool or None
        Force (True) or forbid (False) the dense-operator Schur path; None picks
        it for small problems, where it needs fewer numpy calls.
    threads : int or None
        OpenBLAS threads during the solve (default 1, see :func:`blas_threads`;
        None leaves the process setting alone).
    """

    gap_tol: float = 1e-8
    feas_tol: float = 1e-8
    max_iter: int = 100
    step: float = 0.98
    time_limit: float | None = None
    dense: bool | None = None
    threads: int | None = 1


@dataclass(kw_only=True)
class _SolveStatus:
    """How a solve ended: the fields the raw and the design results share."""

    status: str
    iterations: int
    primal_residual: float
    dual_residual: float
    gap: float
    timings: dict


@dataclass(kw_only=True)
class IPMSolution(_SolveStatus):
    """Raw result of :func:`solve_block_lmi` in the solver's own coordinates.

    Attributes
    ----------
    t : float
        ``b^T y``: attained by the returned variables (``S >= 0`` throughout).
    upper : float
        ``<C, X>``: an upper bound on ``t*`` up to the primal residual.
    V : list of ndarray
        The matrix variables at the returned iterate.
    X : ndarray, shape (nb, k, k)
        Block multipliers (PSD, ``sum_b trace X_b = 1`` up to the primal residual).
    equality_multiplier : float
        Multiplier ``nu`` of the equality ``<a, vec V> = beta``:
        ``A_V^*(X) = nu a`` at the optimum (cvxpy/Clarabel's sign for ``== `` in a
        maximization, see :func:`solve_lmi`).
    status : {"optimal", "inaccurate", "max_iterations", "time_limit", "numerical_error"}
    iterations : int
    primal_residual, dual_residual, gap : float
        Relative residual of ``A^*(X) + b = 0``, of ``S = C + A(y)`` (zero by construction: ``S`` is
        recomputed from ``y`` and is positive definite at the returned iterate) and the relative gap.
    timings : dict
        Seconds in ``assembly`` (Schur complement), ``factorization``,
        ``line_search`` (step lengths), ``other`` and ``total``.
    """

    t: float
    upper: float
    V: list
    X: np.ndarray
    equality_multiplier: float


def _onehot(index: np.ndarray, n: int) -> sp.csr_matrix:
    """Sparse (n, len(index)) matrix summing the rows of ``index == g`` into row g."""
    m = len(index)
    return sp.csr_matrix((np.ones(m), (index, np.arange(m))), shape=(n, m))


_potrf = scipy.linalg.lapack.dpotrf
_potrs = scipy.linalg.lapack.dpotrs

try:  # the gufuncs behind np.linalg, without its per-call wrapper (type checks, errstate): ~5-20 us per call saved
    from numpy.linalg import _umath_linalg as _ul

    _chol, _inv, _eigvalsh = _ul.cholesky_lo, _ul.inv, _ul.eigvalsh_lo
except (ImportError, AttributeError):  # pragma: no cover - other numpy layouts
    _chol, _inv, _eigvalsh = np.linalg.cholesky, np.linalg.inv, np.linalg.eigvalsh


def _cholesky(Z: np.ndarray) -> np.ndarray:
    """Batched lower Cholesky factors; a block that is not positive definite comes back as NaNs."""
    if _chol is np.linalg.cholesky:  # pragma: no cover
        try:
            return _chol(Z)
        except np.linalg.LinAlgError:
            out = np.empty_like(Z)
            for i in range(Z.shape[0]):
                try:
                    out[i] = _chol(Z[i])
                except np.linalg.LinAlgError:
                    out[i] = np.nan
            return out
    return _chol(Z)


if _chol is not np.linalg.cholesky:
    _cholesky = _chol  # noqa: F811 - the gufunc itself already returns NaNs for a failed block


#: Block side from which the step lengths come from Cholesky trials (:func:`_steps_chol`) instead of
#: eigenvalues: a batched eigvalsh costs 6-15 Cholesky factorizations of the same blocks (measured: 18 blocks
#: of side 4, 45 us vs 8 us; 100 of side 24, 4.7 ms vs 0.06-0.5 ms), and the bisection needs about 6-9
#: trials on a shrinking set of candidate blocks.
_CHOL_STEPS_FROM = 10


def _steps_eig(Li: np.ndarray, dZ: np.ndarray, nb: int, cap: float, rtol: float) -> tuple[float, float]:
    """``min(cap, alpha*)`` per half, ``alpha*`` the largest alpha with ``Z + alpha dZ >= 0``.

    ``Li`` holds the inverse Cholesky factors of both halves (X's blocks, then S's); one batched
    eigvalsh call serves both.
    """
    lam = _eigvalsh(Li @ dZ @ Li.transpose(0, 2, 1))[:, 0]
    lx, ls = float(lam[:nb].min()), float(lam[nb:].min())
    ax = cap if not lx < -1.0 / cap else -1.0 / lx  # NaN (a broken direction) gives cap; caught by the caller
    as_ = cap if not ls < -1.0 / cap else -1.0 / ls
    return ax, as_


def _steps_chol(Z: np.ndarray, dZ: np.ndarray, nb: int, cap: float, rtol: float) -> tuple[float, float]:
    """``min(cap, alpha*)`` per half from below, to within a factor ``1 + rtol``, by Cholesky trials.

    ``alpha*`` is the largest alpha with ``Z + alpha dZ >= 0`` over the blocks of a half (X's
    blocks ``[:nb]``, S's ``[nb:]``). A bisection on ``log alpha``: a trial factors ``Z_b + beta_h
    dZ_b`` of the candidate blocks; a failure sets ``hi``, and the blocks that passed at that beta
    (their own ``alpha*_b > beta >= alpha*``) leave the candidates for good; a pass sets ``lo``.
    The returned ``lo`` passed the test, so every step ``<= lo`` keeps the blocks positive definite.
    """
    n2 = Z.shape[0]
    lo = [0.0, 0.0]
    hi = [cap, cap]
    beta = [cap, cap]
    cand = np.arange(n2)
    side = cand >= nb  # half of each candidate (False: X, True: S)
    active = [True, True]
    for _ in range(64):
        bvec = np.where(side, beta[1], beta[0])
        if len(cand) == n2:
            T = Z + bvec[:, None, None] * dZ
        else:
            T = Z[cand] + bvec[:, None, None] * dZ[cand]
        bad = np.isnan(_cholesky(T)[:, -1, -1])
        keep = np.zeros(len(cand), dtype=bool)
        for h in (0, 1):
            if not active[h]:
                continue
            mine = side == bool(h)
            fail = bad & mine
            if fail.any():
                hi[h] = beta[h]
                keep |= fail
            else:
                lo[h] = beta[h]
                keep |= mine
            if lo[h] == cap or (lo[h] > 0.0 and hi[h] <= lo[h] * (1.0 + rtol)) or hi[h] < 1e-14 * cap:
                active[h] = False
                keep &= ~mine
            else:
                beta[h] = hi[h] * 0.25 if lo[h] == 0.0 else (lo[h] * hi[h]) ** 0.5
        if not (active[0] or active[1]):
            break
        cand, side = cand[keep], side[keep]
    return lo[0], lo[1]


@dataclass
class _Core:
    """What the iteration returns, in the solver's coordinates."""

    y: np.ndarray
    X: np.ndarray
    status: str
    iterations: int
    primal_residual: float
    gap: float
    upper: float
    timings: dict


def _ipm_core(C, b, op, adj, schur, o: IPMOptions, t_start: float, feasible_start: bool = False,
              x_start: float | None = None) -> _Core:
    """Mehrotra predictor-corrector with the HKM direction for ``max b^T y, S = C + A(y) >= 0``.

    The ``y`` iterates stay feasible: ``S`` is recomputed as ``C + A(y)`` (no
    drift), so the dual residual is zero and the predictor's right-hand side
    is just ``b``; ``X`` starts infeasible (``A^*(X) + b != 0``) and its
    residual is driven to zero by the Newton steps.
    """
    with np.errstate(invalid="ignore"):  # a failed Cholesky factor is NaNs (checked), not a warning
        return _ipm_loop(C, b, op, adj, schur, o, t_start, feasible_start, x_start)


def _ipm_loop(C, b, op, adj, schur, o, t_start, feasible_start, x_start) -> _Core:
    tim = {"assembly": 0.0, "factorization": 0.0, "line_search": 0.0}
    perf = time.perf_counter
    nb, k = C.shape[0], C.shape[1]
    N = nb * k
    # Step lengths: eigenvalues for small blocks (one batched call), Cholesky trials for larger ones.
    chol_steps = k >= _CHOL_STEPS_FROM
    steps = _steps_chol if chol_steps else _steps_eig
    cap = 1.0 / o.step
    eye = np.eye(k)
    Cf = C.reshape(-1)
    y = np.zeros(b.shape[0])
    # t far enough below every block's smallest eigenvalue: S = C - t I > 0.
    # (feasible_start: C itself is positive definite and y = 0 is the start; no t coordinate.)
    if not feasible_start:
        y[-1] = float(_eigvalsh(C)[:, 0].min()) - max(1.0, float(np.abs(C).max()))
    S = C + op(y)
    # x_start: the multipliers' start X = x_start I (default 1/N, the max-t form's sum tr X = 1).
    X = np.broadcast_to(eye * (1.0 / N if x_start is None else x_start), (nb, k, k)).copy()
    normb = 1.0 + math.sqrt(float(b @ b))
    status = "max_iterations"
    best = None
    it = 0
    ad = 0.0
    for it in range(o.max_iter + 1):
        Z = np.concatenate([X, S])
        LL = _cholesky(Z)
        if np.isnan(LL[:, -1, -1]).any():
            # Rounding made the new S (recomputed from y) or X singular: shorten the last step.
            if best is None or ad < 1e-12:
                status = "numerical_error"
                break
            ad *= 0.5
            y = y_prev + ad * dy
            S = C + op(y)
            X = X_prev + ad * dX if ap > ad else X
            continue
        if chol_steps:
            Li = None
            LSi = _inv(LL[nb:])
        else:
            Li = _inv(LL)
            LSi = Li[nb:]
        G = LSi.transpose(0, 2, 1) @ LSi
        r_p = -b - adj(X)
        Xf = X.reshape(-1)
        pobj = float(Cf @ Xf)
        dobj = float(b @ y)
        XS = float(Xf @ S.reshape(-1))
        mu = XS / N
        rp = math.sqrt(float(r_p @ r_p)) / normb
        denom = 1.0 + abs(pobj) + abs(dobj)
        gap = max(abs(pobj - dobj), XS) / denom
        score = max(rp, gap)
        if best is None or score < best[0]:
            best = (score, it, y, X, rp, gap, pobj)
        if rp < o.feas_tol and gap < o.gap_tol:
            status = "optimal"
            break
        if it - best[1] >= 8 and best[0] < 1e-6:
            status = "stalled"  # no progress for 8 iterations near the optimum: rounding floor reached
            break
        if it == o.max_iter:
            break
        if o.time_limit is not None and perf() - t_start > o.time_limit:
            status = "time_limit"
            break
        t0 = perf()
        M = schur(X, G)
        t1 = perf()
        tim["assembly"] += t1 - t0
        d = M.diagonal()
        dmax = float(d.max())
        anydead = float(d.min()) <= 1e-14 * dmax
        if anydead:
            dead = d <= 1e-14 * dmax
            # Directions no block sees (a zero input matrix, an inactive gain): pin them (dy_i = 0)
            # instead of regularizing all of M, which stalls the residuals.
            M = M.copy()
            M[dead, :] = 0.0
            M[:, dead] = 0.0
            M[dead, dead] = 1.0
        fac, info = _potrf(M, lower=1, clean=0, overwrite_a=0)
        for reg in (1e-12, 1e-10, 1e-8):
            # Near the optimum of a degenerate problem (repeated modes) M can be singular to rounding:
            # a growing diagonal shift still gives a descent direction (the residuals decide).
            if info == 0:
                break
            fac, info = _potrf(M + np.diag(d * reg + 1e-300), lower=1, clean=0)
        if info != 0:
            status = "numerical_error"
            break
        tim["factorization"] += perf() - t1

        def direction(h, RcG):
            dy = _potrs(fac, h, lower=1)[0]
            dS = op(dy)
            W = RcG - X @ dS @ G
            return dy, dS, 0.5 * (W + W.transpose(0, 2, 1))

        # Predictor (affine scaling), R_c = -X S: the right-hand side adj(R_c G) - r_p is b.
        hb = np.where(dead, 0.0, b) if anydead else b
        dy, dS, dX = direction(hb, -X)
        t3 = perf()
        ap, ad = steps(Z if chol_steps else Li, np.concatenate([dX, dS]), nb, 1.0, 0.1)
        tim["line_search"] += perf() - t3
        Sf, dXf, dSf = S.reshape(-1), dX.reshape(-1), dS.reshape(-1)
        mu_aff = (XS + ad * float(Xf @ dSf) + ap * float(dXf @ Sf) + ap * ad * float(dXf @ dSf)) / N
        sigma = min(1.0, max(0.0, (mu_aff / mu) ** 3)) if mu > 0 else 0.0
        # Corrector: R_c = sigma mu I - X S - dX_aff dS_aff.
        RcG = sigma * mu * G - X - dX @ dS @ G
        h = adj(RcG) - r_p
        if anydead:
            h[dead] = 0.0
        dy, dS, dX = direction(h, RcG)
        t4 = perf()
        ap, ad = steps(Z if chol_steps else Li, np.concatenate([dX, dS]), nb, cap, 0.02)
        ap, ad = min(1.0, o.step * ap), min(1.0, o.step * ad)
        tim["line_search"] += perf() - t4
        y_prev, X_prev = y, X
        X = X + ap * dX
        y = y + ad * dy
        S = C + op(y)
        if not math.isfinite(float(y.sum()) + float(X.sum())):
            status = "numerical_error"
            break
    if status != "optimal" and best is not None:
        _, _, y, X, rp, gap, pobj = best
        if status in ("max_iterations", "numerical_error", "stalled") and max(rp, gap) < 1e-6:
            # Stalled close to the optimum (rounding): like Clarabel's "almost solved".
            status = "inaccurate"
    tim["total"] = perf() - t_start
    tim["other"] = tim["total"] - tim["assembly"] - tim["factorization"] - tim["line_search"]
    return _Core(y=y, X=X, status=status, iterations=it, primal_residual=float(rp), gap=float(gap),
                 upper=float(np.vdot(C, X)), timings=tim)


def _dense_ops(Aop: np.ndarray):
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


def solve_block_lmi(problem: BlockLMI, options: IPMOptions | None = None) -> IPMSolution:
    """Solve a :class:`BlockLMI` by an infeasible primal-dual path-following method.

    HKM direction, Mehrotra predictor-corrector, Schur complement from
    :meth:`BlockLMI.schur` (or from the dense operator for small problems).

    Parameters
    ----------
    problem : BlockLMI
    options : IPMOptions, optional

    Returns
    -------
    IPMSolution
    """
    o = options or IPMOptions()
    large = problem.n_full**2 > 2**20  # a Schur matrix above 8 MB: page faults would cost more than the solve
    with blas_threads(o.threads), heap_reuse(large):
        t_start = time.perf_counter()
        dense = o.dense if o.dense is not None else (problem.p * problem.nb * problem.k**2 <= 60000)
        if dense:
            op, adj, schur = _dense_ops(problem.dense_operator())
        else:
            op, adj, schur = problem.op, problem.adj, problem.schur
        x_start = None
        if not problem.with_t:
            # A general objective fixes the multipliers' scale (A^*(X) = -b): start X = xi I with
            # xi fitted to it, not at the max-t form's 1/N (which stalls the dual steps).
            g = adj(np.broadcast_to(np.eye(problem.k), problem.C.shape))  # A^*(I)
            gg = float(g @ g)
            x_start = 1.0 / (problem.nb * problem.k)
            if gg > 0:  # least-squares xi for A^*(xi I) = -b, at least |b| / |A^*(I)|
                x_start = max(x_start, -float(problem.b @ g) / gg, float(np.linalg.norm(problem.b)) / np.sqrt(gg))
        core = _ipm_core(problem.C, problem.b, op, adj, schur, o, t_start, feasible_start=not problem.with_t,
                         x_start=x_start)
        x = problem.full(core.y)
        V = [v0 + x[sl].reshape(var.shape) for var, sl, v0 in zip(problem.variables, problem.slices, problem.V0)]
        nu = 0.0
        if problem.equality is not None:
            a = problem.equality
            eq_dir = problem.__dict__.get("_eq_dir")
            if eq_dir is not None:  # a . A_full^*(X) = <A_full(a), X>
                nu = float(eq_dir.reshape(-1) @ core.X.reshape(-1)) / float(a @ a)
            else:
                nu = float(a @ problem.adj_full(core.X)[:-1] / (a @ a))
        return IPMSolution(t=float(x[-1]), upper=core.upper, V=V, X=core.X, equality_multiplier=nu,
                           status=core.status, iterations=core.iterations, primal_residual=core.primal_residual,
                           dual_residual=0.0, gap=core.gap, timings=core.timings)


# ----------------------------------------------------------------------------- the design families
def _selectors(n: int):
    """``P1`` (2n, n) selecting the top half, ``P2`` the bottom half."""
    P1 = np.zeros((2 * n, n))
    P1[:n] = np.eye(n)
    P2 = np.zeros((2 * n, n))
    P2[n:] = np.eye(n)
    return P1, P2


def _gain_L(coef: np.ndarray, active: np.ndarray | None) -> np.ndarray:
    """``[coef_{s,1} ... coef_{s,J}]`` per mode, inactive terms zeroed: shape (S, n, J m)."""
    S, J, n, m = coef.shape
    c = coef if active is None else coef * np.asarray(active, dtype=float)[:, :, None, None]
    return c.transpose(0, 2, 1, 3).reshape(S, n, J * m)


def lmi_problem(free: np.ndarray, coef: np.ndarray, active: np.ndarray | None = None,
                rho: np.ndarray | None = None) -> BlockLMI:
    """The ``lmi`` design SDP as a :class:`BlockLMI` (docs/design.md, "The structured interior-point solver").

    ``max t`` s.t. ``trace W = n`` and, per mode s,
    ``[[rho_s W, (A_s W)^T], [A_s W, W]] - t I >= 0`` with
    ``A_s W = free_s W + sum_j coef_{s,j} Y_j``.

    Parameters
    ----------
    free : ndarray, shape (S, n, n)
    coef : ndarray, shape (S, J, n, m)
    active : ndarray of bool, shape (S, J), optional
        Terms left out where False (as :meth:`solver.network.ModeSet.scheme_coef` says).
    rho : ndarray, shape (S,), optional
        Top-left factors (default 1; the congruent decay-rate form needs none).
    """
    free = np.asarray(free, dtype=np.float64)
    coef = np.asarray(coef, dtype=np.float64)
    S, n, _ = free.shape
    J, m = coef.shape[1], coef.shape[3]
    P2, Rleft, Lbot, C0, a, V0, LF0 = _lmi_consts(S, n, J * m)
    # sym([[rho/2 W], [F W]] [I 0]) = [[rho W, (F W)^T], [F W, 0]] (no cancellation for huge F),
    # plus the sym-kind term [0; I] W [0, I] (one Kronecker product per pair instead of four).
    LF = LF0.copy()  # (S, 2n, n): [I/2; 0] per mode
    LF[:, n:] = free
    C = C0.copy()  # [[I, 0], [0, I]] per mode
    C[:, n:, :n] = free
    C[:, :n, n:] = free.transpose(0, 2, 1)
    if rho is not None:
        sq2 = np.asarray(rho, dtype=np.float64)  # sqrt(rho)^2
        LF[:, :n] *= sq2[:, None, None]
        C[:, :n, :n] *= sq2[:, None, None]
    W = MatrixVariable("W", (n, n), n, [(LF, Rleft, 1.0), (Lbot, None, 1.0)])
    variables = [W]
    if J * m > 0:
        LY = np.zeros((S, 2 * n, J * m))
        LY[:, n:] = _gain_L(coef, active)  # [0; coef_s]
        variables.append(MatrixVariable("Y", (J * m, n), None, [(LY, Rleft, 1.0)]))
    return BlockLMI(C=C, variables=variables, V0=V0, equality=a)


#: Shape-only pieces of :func:`lmi_problem` (selectors, identities, the trace normalization), read-only.
_LMI_CONSTS: dict = {}


def _lmi_consts(S: int, n: int, Jm: int):
    key = (S, n, Jm)
    c = _LMI_CONSTS.get(key)
    if c is None:
        if len(_LMI_CONSTS) > 64:
            _LMI_CONSTS.clear()
        P1, P2 = _selectors(n)
        eye = np.eye(n)
        C0 = np.zeros((S, 2 * n, 2 * n))
        C0[:, :n, :n] = eye
        C0[:, n:, n:] = eye
        LF0 = np.zeros((S, 2 * n, n))
        LF0[:, :n] = 0.5 * eye
        a = np.zeros(n * n + Jm * n)
        a[: n * n: n + 1] = 1.0  # trace W
        V0 = [eye] + ([np.zeros((Jm, n))] if Jm > 0 else [])
        c = (P2, np.broadcast_to(P1.T, (S, n, 2 * n)), np.broadcast_to(P2, (S, 2 * n, n)), C0, a, V0, LF0)
        for arr in (P2, eye, C0, LF0, a, *V0):
            arr.flags.writeable = False
        _LMI_CONSTS[key] = c
    return c


def switched_problem(free: np.ndarray, coef: np.ndarray, active: np.ndarray | None = None,
                     rho: np.ndarray | None = None) -> BlockLMI:
    """The ``switched`` design SDP as a :class:`BlockLMI`.

    ``max t`` s.t. ``trace Z = n`` and, for every pair (s, u) (block ``s S + u``),
    ``[[rho_s (Z + Z^T - S_s), (A_s Z)^T], [A_s Z, S_u]] - t I >= 0``.
    The ``S_s`` are one stacked variable (S n, n) of symmetric n x n blocks.
    """
    free = np.asarray(free, dtype=np.float64)
    coef = np.asarray(coef, dtype=np.float64)
    S, n, _ = free.shape
    J, m = coef.shape[1], coef.shape[3]
    P1, P2 = _selectors(n)
    B = S * S
    s_of = np.repeat(np.arange(S), S)
    u_of = np.tile(np.arange(S), S)
    sq = np.ones(S) if rho is None else np.sqrt(np.asarray(rho, dtype=np.float64))
    sqb = sq[s_of][:, None, None]
    Rleft = np.broadcast_to(P1.T, (B, n, 2 * n))
    Z = MatrixVariable("Z", (n, n), None, [(sqb * P1[None], sqb * P1.T[None], 1.0),
                                           (P2[None] @ free[s_of], Rleft, 1.0)])
    # Block (s, u) sees S_s (top left) and S_u (bottom right) only: row-block selections of the stack.
    Lss = sqb * P1[None]
    Lsu = np.broadcast_to(P2, (B, 2 * n, n))
    Sv = MatrixVariable("S", (S * n, n), n, [(Lss, sqb * P1.T[None], -0.5, s_of),
                                            (Lsu, np.broadcast_to(P2.T, (B, n, 2 * n)), 0.5, u_of)])
    variables = [Z, Sv]
    if J * m > 0:
        LY = P2[None] @ _gain_L(coef, active)[s_of]
        variables.append(MatrixVariable("Y", (J * m, n), None, [(LY, Rleft, 1.0)]))
    C = np.zeros((B, 2 * n, 2 * n))
    C[:, :n, :n] = (sq[s_of] ** 2)[:, None, None] * np.eye(n)
    C[:, n:, n:] = np.eye(n)
    C[:, n:, :n] = free[s_of]
    C[:, :n, n:] = np.swapaxes(free[s_of], 1, 2)
    a = np.zeros(sum(v.size for v in variables))
    a[: n * n: n + 1] = 1.0  # trace Z
    V0 = [np.eye(n), np.tile(np.eye(n), (S, 1))] + ([np.zeros((J * m, n))] if J * m > 0 else [])
    return BlockLMI(C=C, variables=variables, V0=V0, equality=a)


def _split_Y(Ystack: np.ndarray | None, J: int, m: int, n: int, scale: np.ndarray) -> np.ndarray:
    if Ystack is None:
        return np.zeros((J, m, n))
    return Ystack.reshape(J, m, n) / scale[:, None, None]


def _gain_scale(coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scale each free gain's coefficients to unit size: ``coef_j / s_j`` with ``Y_j = Y'_j / s_j``.

    Input matrices of 1e6 (or 1e-6) would otherwise make the Y columns of the
    Schur complement 1e12 times larger (smaller) than W's.
    """
    if coef.size == 0:
        return coef, np.ones(coef.shape[1])
    s = np.abs(coef).max(axis=(0, 2, 3))
    s = np.where(s > 0, s, 1.0)
    return coef / s[None, :, None, None], s


@dataclass(kw_only=True)
class _DesignSolution(_SolveStatus):
    """The fields every design SDP's result shares (see :class:`LMISolution`)."""

    t: float
    Y: np.ndarray
    duals: np.ndarray
    trace_multiplier: float
    upper: float

    @staticmethod
    def shared(sol: IPMSolution, t0: float, setup: float) -> dict:
        """The status, residual and timing fields from the core's solution (``t0``: start of the call)."""
        timings = dict(sol.timings, setup=setup)
        timings["total"] = time.perf_counter() - t0
        return dict(t=sol.t, duals=sol.X, upper=sol.upper, status=sol.status, iterations=sol.iterations,
                    primal_residual=sol.primal_residual, dual_residual=sol.dual_residual, gap=sol.gap,
                    timings=timings)


@dataclass(kw_only=True)
class LMISolution(_DesignSolution):
    """Result of :func:`solve_lmi` (primal and dual solutions of the ``lmi`` SDP).

    Attributes
    ----------
    t : float
        Attained optimal value (the returned ``W``, ``Y`` make every block
        ``>= t I`` up to rounding, whatever the status).
    W : ndarray, shape (n, n)
        Symmetric, ``trace W = n``.
    Y : ndarray, shape (J, m, n)
    duals : ndarray, shape (S, 2n, 2n)
        ``Z_s``, the multiplier of block s's constraint ``L_s(W, Y) - t I >= 0``:
        PSD, ``sum_s trace Z_s = 1`` -- the same normalization as
        ``constraint.dual_value`` from cvxpy with Clarabel for the same problem.
    trace_multiplier : float
        Multiplier of ``trace W == n`` with cvxpy's sign convention:
        ``sum_s A_W^*(Z_s) = trace_multiplier * I`` at the optimum
        (``A_W^*`` the adjoint of the W-part of the blocks), so ``t* = n *
        trace_multiplier`` ... up to the rho terms (exact for rho = 1).
    upper : float
        Dual objective ``sum_s <C_s, Z_s>``: an upper bound on ``t*`` up to
        ``primal_residual``.
    status : {"optimal", "inaccurate", "max_iterations", "time_limit", "numerical_error"}
    iterations : int
    primal_residual, dual_residual, gap : float
        Relative residuals of the multipliers' equations and of the blocks, and the relative gap.
    timings : dict
        Seconds: ``setup`` (building the structure), ``assembly``, ``factorization``,
        ``line_search``, ``other``, ``total``.
    """

    W: np.ndarray


@dataclass(kw_only=True)
class SwitchedSolution(_DesignSolution):
    """Result of :func:`solve_switched`.

    Attributes
    ----------
    t : float
    Z : ndarray, shape (n, n)
    S : ndarray, shape (S, n, n)
    Y : ndarray, shape (J, m, n)
    duals : ndarray, shape (S*S, 2n, 2n)
        Multiplier of the block of pair (s, u) at index ``s S + u``; ``sum trace = 1``.
    trace_multiplier : float
        Multiplier of ``trace(Z + Z^T) == 2n`` (cvxpy's convention, the constraint as written
        in solver/methods/switched.py).
    upper, status, iterations, primal_residual, dual_residual, gap, timings
        As in :class:`LMISolution`.
    """

    Z: np.ndarray
    S: np.ndarray


def _check_data(free, coef, active):
    free = np.asarray(free, dtype=np.float64)
    coef = np.asarray(coef, dtype=np.float64)
    if free.ndim != 3 or free.shape[1] != free.shape[2] or coef.ndim != 4 or coef.shape[0] != free.shape[0] \
            or coef.shape[2] != free.shape[1]:
        raise ValueError(f"free must be (S, n, n) and coef (S, J, n, m); got {free.shape} and {coef.shape}")
    if not (np.all(np.isfinite(free)) and np.all(np.isfinite(coef))):
        raise ValueError("free and coef must be finite")
    if active is not None:
        active = np.asarray(active, dtype=bool)
        if active.shape != coef.shape[:2]:
            raise ValueError(f"active must have shape {coef.shape[:2]}, got {active.shape}")
    return free, coef, active


def solve_lmi(free, coef, active=None, rho=None, options: IPMOptions | None = None) -> LMISolution:
    """Solve the ``lmi`` design SDP (see :func:`lmi_problem`) with the structured IPM.

    Parameters
    ----------
    free : array_like, shape (S, n, n)
    coef : array_like, shape (S, J, n, m)
    active : array_like of bool, shape (S, J), optional
    rho : array_like, shape (S,), optional
    options : IPMOptions, optional

    Returns
    -------
    LMISolution

    Raises
    ------
    ValueError
        On inconsistent shapes or non-finite data.
    """
    t0 = time.perf_counter()
    free, coef, active = _check_data(free, coef, active)
    S, J, n, m = coef.shape
    coef_s, gscale = _gain_scale(coef)
    prob = lmi_problem(free, coef_s, active, rho)
    setup = time.perf_counter() - t0
    sol = solve_block_lmi(prob, options)
    W = sol.V[0]
    W = 0.5 * (W + W.T)
    Y = _split_Y(sol.V[1] if len(sol.V) > 1 else None, J, m, n, gscale)
    return LMISolution(W=W, Y=Y, trace_multiplier=sol.equality_multiplier,
                       **_DesignSolution.shared(sol, t0, setup))


def solve_switched(free, coef, active=None, rho=None, options: IPMOptions | None = None) -> SwitchedSolution:
    """Solve the ``switched`` design SDP (see :func:`switched_problem`) with the structured IPM.

    Parameters and errors as :func:`solve_lmi`; returns :class:`SwitchedSolution`.
    """
    t0 = time.perf_counter()
    free, coef, active = _check_data(free, coef, active)
    S, J, n, m = coef.shape
    coef_s, gscale = _gain_scale(coef)
    prob = switched_problem(free, coef_s, active, rho)
    setup = time.perf_counter() - t0
    sol = solve_block_lmi(prob, options)
    Sm = sol.V[1].reshape(S, n, n)
    Sm = 0.5 * (Sm + np.swapaxes(Sm, 1, 2))
    Y = _split_Y(sol.V[2] if len(sol.V) > 2 else None, J, m, n, gscale)
    return SwitchedSolution(Z=sol.V[0], S=Sm, Y=Y, trace_multiplier=0.5 * sol.equality_multiplier,
                            **_DesignSolution.shared(sol, t0, setup))


def solve_common_fixed_gain(A, rho=None, options: IPMOptions | None = None) -> LMISolution:
    """The fixed-gain certificate LMI of ``analyze`` (Theorem 1 for given closed loops ``A_s``).

    ``max t`` s.t. ``trace X = n`` and ``[[rho_s X, X A_s], [A_s^T X, X]] - t I >= 0``:
    the ``lmi`` structure with ``free_s = A_s^T`` and no gains, so ``W`` of the result is ``X``.
    ``t* > 0`` iff some ``X > 0`` has ``rho_s X - A_s^T X A_s > 0`` for all s, the same verdict as
    the cvxpy form in solver/lyapunov.py (whose ``t`` bounds only the top-left block, so the
    magnitudes differ; only the sign is used before the float64 re-check).

    Parameters
    ----------
    A : array_like, shape (S, n, n)
    rho : array_like, shape (S,), optional
    options : IPMOptions, optional

    Returns
    -------
    LMISolution
        ``W`` is the certificate candidate X; ``Y`` is empty (shape (0, 0, n)).
    """
    A = np.asarray(A, dtype=np.float64)
    S, n, _ = A.shape
    return solve_lmi(np.swapaxes(A, 1, 2), np.zeros((S, 0, n, 0)), None, rho, options)


# ----------------------------------------------------------------------------- the design methods' hook
def design_solve(modes, kind: str = "lmi", rho=None, time_limit: float | None = None, free=None, coef=None):
    """Solve a design method's SDP for a :class:`solver.network.ModeSet` the way ``CompiledProblem.solve`` would.

    The one call solver/methods/lmi.py and switched.py make when ``solver="IPM"``.

    Parameters
    ----------
    modes : solver.network.ModeSet
    kind : {"lmi", "switched"}
    rho : ndarray, shape (S,), optional
    time_limit : float, optional
    free, coef : ndarray, optional
        Replace ``modes.free`` (S, n, n) and ``modes.scheme_coef()[0]`` (S, J, n, m), e.g. by the
        congruent decay-rate form's ``lambda^(-eta_s)``-scaled ones.

    Returns
    -------
    info : solver.compiled.SolveInfo
        ``status`` in cvxpy's words (``"optimal"``, ``"optimal_inaccurate"``).
    solution : LMISolution or SwitchedSolution

    Raises
    ------
    solver.errors.SolverFailed
        When the iteration ends without an (almost) optimal point.
    """
    from .compiled import SolveInfo
    from .errors import SolverFailed

    coef0, active = modes.scheme_coef()
    coef = coef0 if coef is None else coef
    free = modes.free if free is None else free
    if rho is not None and np.all(np.asarray(rho) == 1.0):
        rho = None
    opts = IPMOptions(time_limit=time_limit)
    start = time.perf_counter()
    solve = {"lmi": solve_lmi, "switched": solve_switched}[kind]
    sol = solve(free, coef, active, rho, opts)
    wall = time.perf_counter() - start
    status = {"optimal": "optimal", "inaccurate": "optimal_inaccurate"}.get(sol.status)
    if status is None:
        raise SolverFailed(f"IPM ended with status {sol.status!r} after {sol.iterations} iterations "
                           f"(primal residual {sol.primal_residual:.1e}, gap {sol.gap:.1e})", status=sol.status)
    info = SolveInfo(status=status, solver="IPM", solve_time=sol.timings["total"], wall_time=wall,
                     objective=sol.t, iterations=sol.iterations)
    return info, sol


def design_solve_fixed_gain(A, rho=None, time_limit: float | None = None):
    """``(X, t, info)`` of :func:`solve_common_fixed_gain`, as ``solver.lyapunov.common_lmi`` returns them."""
    from .compiled import SolveInfo
    from .errors import SolverFailed

    start = time.perf_counter()
    if rho is not None and np.all(np.asarray(rho) == 1.0):
        rho = None
    sol = solve_common_fixed_gain(A, rho, IPMOptions(time_limit=time_limit))
    status = {"optimal": "optimal", "inaccurate": "optimal_inaccurate"}.get(sol.status)
    if status is None:
        raise SolverFailed(f"IPM ended with status {sol.status!r} after {sol.iterations} iterations", status=sol.status)
    info = SolveInfo(status=status, solver="IPM", solve_time=sol.timings["total"],
                     wall_time=time.perf_counter() - start, objective=sol.t, iterations=sol.iterations)
    return sol.W, sol.t, info
