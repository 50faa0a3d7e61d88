"""The networked loop on a Markov channel as a Markov jump linear system (MJLS), per sample.

Mode ``(c, l, d)``: channel state, plant mode, buffer age ``d = k - i_m`` (ages ``>= n_drop``
merged into ``d = n_drop``, the exhausted buffer).  The state is ``z = x(k)`` when ``d = 0``
(then ``x(i_m) = x(k)``) and when the buffer is exhausted under ``"zero"`` (``x(i_m)`` is no
longer used), else ``z = (x(k), x(i_m))``.  Each transition ``(c, l, d) -> (c', l', d')`` has
probability ``T[c, c'] Pi[l, l'] (1 - loss[c'] or loss[c'])`` and a matrix ``A`` with
``z(k+1) = A z(k)``.  Second moments ``Q_i(k) = E[z z' 1{mode i}]`` follow the positive operator
``L(Q)_j = sum_i p_ij A_ij Q_i A_ij'``; the loop is mean-square stable iff ``rho(L) < 1``.

Proofs (docs/design.md, "Stochastic channels"), both re-checked in float64 with explicit
bounds on the rounding of every operator application:

* ``rho(L) <= beta``: matrices ``P_i > 0`` with ``beta P - L*(P) > 0`` (``L*`` the adjoint,
  ``L*(P)_i = sum_j p_ij A_ij' P_j A_ij``); ``beta < 1`` proves mean-square stability.
* ``rho(L) >= mu``: ``Q0 >= 0`` on the ``d = 0`` modes whose first-return second moments
  under ``L / mu`` (a finite, rigorously rounded-down sum) dominate ``Q0``; ``mu >= 1``
  proves that the loop is not mean-square stable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


EXHAUSTED = ("hold", "zero")
U = np.finfo(np.float64).eps / 2  # unit roundoff
#: Above this operator size the spectral radius comes from ARPACK instead of a dense eigensolver.
DENSE_LIMIT = 2500
#: Up to this operator size the dense eigensolver is used directly.
SMALL = 40


def _sym(M):
    return 0.5 * (M + M.T)


def _eig_err(M: np.ndarray) -> float:
    """Bound on the error of float64 eigvalsh (backward stable; generous constant)."""
    return 64.0 * M.shape[0] * U * float(np.linalg.norm(M))


@dataclass
class Transition:
    src: int
    dst: int
    p: float
    A: np.ndarray
    A_abs: np.ndarray  # entrywise bound on |A| of the exact data (and of the float A)


@dataclass
class Loop:
    """The MJLS of one (family, gains, channel, plant chain, exhaustion policy).

    Attributes
    ----------
    modes : list of tuple (c, l, d)
        Modes reachable from the initial distribution (only these are kept).
    dims : ndarray of int
    transitions : list of Transition
    initial : ndarray
        Probability of each mode at k = 0 (``pi_c / r`` on ``(c, l, 0)``).
    stage : list of ndarray
        Stage cost ``x'Qx + u'Ru`` as ``z' S_i z`` (when weights are given).
    embed : list of ndarray
        ``E_i`` (dim_i, n): where the process noise enters ``z`` in mode i.
    """

    modes: list
    dims: np.ndarray
    transitions: list
    initial: np.ndarray
    n: int
    gamma: float
    stage: list | None = None
    stage_err: np.ndarray | None = None
    embed: list = field(default_factory=list)
    #: The float64 data the loop was built from (for exact re-computation of transition matrices).
    source: dict = field(default_factory=dict, repr=False)
    _stacked: tuple | None = field(default=None, repr=False)

    # ------------------------------------------------------------------ sizes
    @property
    def size(self) -> int:
        return int(np.sum(self.dims ** 2))

    @property
    def offsets(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(self.dims ** 2)])

    def zeros(self) -> list:
        return [np.zeros((d, d)) for d in self.dims]

    def identity(self) -> list:
        return [np.eye(d) for d in self.dims]

    def vec(self, X: list) -> np.ndarray:
        return np.concatenate([x.reshape(-1) for x in X])

    def unvec(self, v: np.ndarray) -> list:
        o = self.offsets
        return [v[o[i]:o[i + 1]].reshape(d, d) for i, d in enumerate(self.dims)]

    def is_fresh(self, i: int) -> bool:
        return self.modes[i][2] == 0

    # ------------------------------------------------------------- operators
    def _stacks(self):
        """Transitions as padded arrays (exact zeros pad every block to the largest dimension)."""
        if getattr(self, "_stacked", None) is None:
            D = int(self.dims.max())
            T = len(self.transitions)
            A = np.zeros((T, D, D))
            A_abs = np.zeros((T, D, D))
            for k, t in enumerate(self.transitions):
                A[k, :t.A.shape[0], :t.A.shape[1]] = t.A
                A_abs[k, :t.A.shape[0], :t.A.shape[1]] = t.A_abs
            src = np.array([t.src for t in self.transitions])
            dst = np.array([t.dst for t in self.transitions])
            p = np.array([t.p for t in self.transitions])

            def grouping(key):  # sums over transitions sharing a mode, by reduceat (np.add.at is slow)
                order = np.argsort(key, kind="stable")
                targets, starts = np.unique(key[order], return_index=True)
                return order, targets, starts

            self._stacked = (D, A, A_abs, src, dst, p, grouping(dst), grouping(src))
        return self._stacked

    def apply(self, X: list, adjoint: bool = False, absolute: bool = False) -> list:
        """``L(X)`` (or ``L*(X)``); ``absolute``: the same with ``|A|`` bounds and ``|X|``."""
        D, A, A_abs, src, dst, p, by_dst, by_src = self._stacks()
        Mat = A_abs if absolute else A
        S = np.zeros((len(self.modes), D, D))
        for i, x in enumerate(X):
            S[i, :x.shape[0], :x.shape[1]] = np.abs(x) if absolute else x
        Y = np.zeros_like(S)
        if adjoint:
            terms = p[:, None, None] * (np.swapaxes(Mat, 1, 2) @ S[dst] @ Mat)
            order, targets, starts = by_src
        else:
            terms = p[:, None, None] * (Mat @ S[src] @ np.swapaxes(Mat, 1, 2))
            order, targets, starts = by_dst
        Y[targets] = np.add.reduceat(terms[order], starts, axis=0)
        return [Y[i, :d, :d] for i, d in enumerate(self.dims)]

    def apply_bounded(self, X: list, adjoint: bool = False) -> tuple[list, np.ndarray]:
        """Float ``L(X)`` and, per block, a bound on the Frobenius norm of its error vs exact data."""
        Y = self.apply(X, adjoint)
        B = self.apply(X, adjoint, absolute=True)
        err = np.array([self.gamma * float(np.linalg.norm(b)) for b in B])
        return [_sym(y) for y in Y], err

    def matrix(self, adjoint: bool = False) -> sp.csr_matrix:
        """The operator on ``vec`` (row-major blocks) as a sparse matrix."""
        o = self.offsets
        rows, cols, vals = [], [], []
        for t in self.transitions:
            blk = t.p * np.kron(t.A, t.A)  # vec_r(A X A') = (A kron A) vec_r(X)
            r0, c0 = o[t.dst], o[t.src]
            rr, cc = np.nonzero(blk)
            rows.append(rr + r0)
            cols.append(cc + c0)
            vals.append(blk[rr, cc])
        size = self.size
        M = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size))
        return M.T.tocsr() if adjoint else M

    def mode_matrix(self) -> np.ndarray:
        """Transition matrix of the modes (rows: from)."""
        M = np.zeros((len(self.modes), len(self.modes)))
        for t in self.transitions:
            M[t.src, t.dst] += t.p
        return M

    def initial_moments(self) -> list:
        return [self.initial[i] * np.eye(d) if self.initial[i] > 0 else np.zeros((d, d))
                for i, d in enumerate(self.dims)]


def build_loop(F: np.ndarray, G: np.ndarray, K: np.ndarray, transition: np.ndarray, loss: np.ndarray,
               stationary: np.ndarray, plant_transitions: np.ndarray, exhausted: str,
               weights: tuple | None = None, initial_plant: np.ndarray | None = None) -> Loop:
    """Build the reachable part of the MJLS (see the module docstring)."""
    r, n, _ = F.shape
    m = G.shape[2]
    N = K.shape[0]
    c = transition.shape[0]
    Pi = plant_transitions
    zero_exhaust = exhausted == "zero"

    def dim(d):
        return n if d == 0 or (d == N and zero_exhaust) else 2 * n

    def gain(d):
        """Gain applied to x(i_m) at age d, or None (zero input)."""
        if d < N:
            return K[d]
        return None if zero_exhaust else K[N - 1]

    # Next x as a map of z, with an entrywise bound of the exact map's magnitude and float error.
    def next_x(l, d):
        Kd = gain(d)
        if d == 0:
            A = F[l] + G[l] @ Kd
            A_abs = (np.abs(F[l]) + np.abs(G[l]) @ np.abs(Kd)) * (1 + (m + 2) * U * 2)
        elif Kd is None:
            A = F[l].copy()
            A_abs = np.abs(F[l])
        else:
            GK = G[l] @ Kd
            A = np.hstack([F[l], GK])
            A_abs = np.hstack([np.abs(F[l]), (np.abs(G[l]) @ np.abs(Kd)) * (1 + (m + 2) * U * 2)])
        return A, A_abs

    def next_z(l, d, d_next):
        X, X_abs = next_x(l, d)
        if d_next == 0 or dim(d_next) == n:
            return X, X_abs
        keep = np.eye(n) if d == 0 else np.hstack([np.zeros((n, n)), np.eye(n)])
        return np.vstack([X, keep]), np.vstack([X_abs, np.abs(keep)])

    cache = {}
    start = [(ci, l, 0) for ci in range(c) for l in range(r) if stationary[ci] > 0]
    w0 = initial_plant if initial_plant is not None else np.full(r, 1.0 / r)
    start = [s for s in start if w0[s[1]] > 0]
    index = {s: i for i, s in enumerate(start)}
    modes = list(start)
    raw = []
    queue = list(start)
    while queue:
        src = queue.pop()
        ci, l, d = src
        for cn in range(c):
            if transition[ci, cn] == 0:
                continue
            for ln in range(r):
                if Pi[l, ln] == 0:
                    continue
                base = transition[ci, cn] * Pi[l, ln]
                for d_next, pe in ((0, 1.0 - loss[cn]), (min(d + 1, N), loss[cn])):
                    p = base * pe
                    if p == 0:
                        continue
                    dst = (cn, ln, d_next)
                    if dst not in index:
                        index[dst] = len(modes)
                        modes.append(dst)
                        queue.append(dst)
                    key = (l, d, d_next)
                    if key not in cache:
                        cache[key] = next_z(l, d, d_next)
                    A, A_abs = cache[key]
                    raw.append((index[src], index[dst], p, A, A_abs))
    dims = np.array([dim(md[2]) for md in modes])
    transitions = [Transition(s, t, p, A, A_abs) for s, t, p, A, A_abs in raw]
    in_degree = np.bincount([t.dst for t in transitions], minlength=len(modes))
    out_degree = np.bincount([t.src for t in transitions], minlength=len(modes))
    # Error of fl(sum_t p_t A X A') against the exact data: two products of inner size <= 2n,
    # the probability (products of three rounded numbers), the sum over transitions, the gains' products.
    k = 2 * int(dims.max()) + max(int(in_degree.max()), int(out_degree.max())) + m + 12
    gamma = 2.0 * k * U / (1 - k * U)
    initial = np.zeros(len(modes))
    for i, (ci, l, d) in enumerate(modes):
        if d == 0:
            initial[i] = stationary[ci] * w0[l]
    loop = Loop(modes=modes, dims=dims, transitions=transitions, initial=initial, n=n, gamma=gamma)
    loop.source = dict(F=F, G=G, K=K, transition=transition, loss=loss, plant_transitions=Pi, exhausted=exhausted)
    loop.embed = [np.eye(n) if dims[i] == n else np.vstack([np.eye(n), np.zeros((n, n))])
                  for i in range(len(modes))]
    if weights is not None:
        Qw, Rw = weights
        stage, stage_err = [], []
        for (ci, l, d), dm in zip(modes, dims):
            Kd = gain(d)
            if d == 0:
                S = Qw + Kd.T @ Rw @ Kd
                S_abs = np.abs(Qw) + np.abs(Kd.T) @ np.abs(Rw) @ np.abs(Kd)
            elif Kd is None:
                S, S_abs = Qw.copy(), np.abs(Qw)
            else:
                KRK = Kd.T @ Rw @ Kd
                S = np.block([[Qw, np.zeros((n, n))], [np.zeros((n, n)), KRK]])
                S_abs = np.block([[np.abs(Qw), np.zeros((n, n))],
                                  [np.zeros((n, n)), np.abs(Kd.T) @ np.abs(Rw) @ np.abs(Kd)]])
            stage.append(_sym(S))
            stage_err.append(2 * (2 * m + 4) * U * float(np.linalg.norm(S_abs)))
        loop.stage = stage
        loop.stage_err = np.array(stage_err)
    return loop


# ---------------------------------------------------------------- spectral radius
def radius_estimate(loop: Loop) -> tuple[float, np.ndarray | None]:
    """Float64 spectral radius of L and a Perron (right) eigenvector, vec form (not a proof)."""
    M = loop.matrix()
    w = None
    if loop.size > SMALL:
        # ARPACK: sparse products only (dense LAPACK eig is slow when BLAS threads compete for cores).
        try:
            with np.errstate(all="ignore"):
                w, V = spla.eigs(M, k=min(6, loop.size - 2), which="LM", maxiter=50000, tol=1e-13)
        except (spla.ArpackNoConvergence, spla.ArpackError, ValueError):
            w = None
        if w is not None and not np.all(np.isfinite(w)):
            w = None
    if w is None:
        if loop.size > DENSE_LIMIT:
            return float("nan"), None
        dense = M.toarray()
        if not np.all(np.isfinite(dense)):
            return float("inf"), None
        w, V = np.linalg.eig(dense)
    rho = float(np.max(np.abs(w)))
    if rho == 0:
        return 0.0, None
    top = np.flatnonzero(np.abs(w) >= rho * (1 - 1e-9))
    best = top[np.argmin(np.abs(w[top] - rho))]
    v = np.real(V[:, best])
    if np.sum(v) < 0:
        v = -v
    return rho, v


@dataclass
class UpperCertificate:
    """``P_i > 0`` with ``beta P - L*(P) > 0`` (re-checked): ``rho(L) <= beta``."""

    beta: float
    P: list
    min_eig_P: float
    decrease: float
    verified: bool

    def to_dict(self) -> dict:
        return {"kind": "coupled_lyapunov", "beta": self.beta, "verified": self.verified,
                "min_eig_P": self.min_eig_P, "decrease": self.decrease,
                "P": [p.tolist() for p in self.P]}


@dataclass
class LowerCertificate:
    """``Q0 >= 0`` on the fresh (d = 0) modes dominated by its first returns under ``L / mu``: ``rho(L) >= mu``."""

    mu: float
    Q0: list
    steps: int
    slack: float
    verified: bool
    kind: str = "first_return_growth"

    def to_dict(self) -> dict:
        return {"kind": "first_return_growth", "mu": self.mu, "verified": self.verified, "steps": self.steps,
                "slack": self.slack, "Q0": [q.tolist() for q in self.Q0]}


def recheck_upper(loops: list, P: list, beta: float) -> UpperCertificate:
    """Re-check ``beta P_i - L_l*(P)_i > 0`` for every loop l (one loop: the Markov case) and ``P_i > 0``.

    Every float operation is covered: the error of ``L*(P)`` against the exact data
    (``Loop.apply_bounded``), the product ``beta P``, the subtraction and eigvalsh.
    """
    P = [_sym(p) for p in P]
    min_p = min(float(np.linalg.eigvalsh(p)[0]) - _eig_err(p) for p in P)
    worst = np.inf
    for loop in loops:
        LP, err = loop.apply_bounded(P, adjoint=True)
        for i, p in enumerate(P):
            D = _sym(beta * p - LP[i])
            bound = err[i] + 4 * U * (beta * float(np.linalg.norm(p)) + float(np.linalg.norm(LP[i])))
            worst = min(worst, float(np.linalg.eigvalsh(D)[0]) - _eig_err(D) - bound)
    return UpperCertificate(beta=float(beta), P=P, min_eig_P=min_p, decrease=float(worst),
                            verified=bool(min_p > 0 and worst > 0))


def certify_upper(loop: Loop, beta: float) -> UpperCertificate | None:
    """Solve ``(beta I - L*) P = I`` and re-check: proves ``rho(L) <= beta`` when it passes."""
    Ms = loop.matrix(adjoint=True)
    A = beta * sp.identity(loop.size, format="csc") - Ms.tocsc()
    rhs = loop.vec(loop.identity())
    try:
        with np.errstate(all="ignore"):
            p = spla.spsolve(A, rhs)
    except (RuntimeError, ValueError):
        return None
    if not np.all(np.isfinite(p)):
        return None
    return recheck_upper([loop], loop.unvec(p), beta)


def _psd_part(M: np.ndarray, rel: float = 1e-9) -> np.ndarray:
    """An exactly positive definite float matrix close to the PSD part of M."""
    M = _sym(M)
    s, V = np.linalg.eigh(M)
    s = np.where(s > rel * max(s[-1], 0.0), s, 0.0)
    C = V * s
    Q = _sym(C @ V.T)
    # fl(V S V') is within gamma |V| S |V'| of the exact PSD product: the shift makes it PD.
    k = M.shape[0] + 4
    eps = 4 * k * U * float(np.linalg.norm(np.abs(V) * s @ np.abs(V).T)) + 1e-14 * max(float(s[-1]), 1e-300)
    return Q + eps * np.eye(M.shape[0])


def certify_lower(loop: Loop, mu: float, perron: np.ndarray | None, max_steps: int = 1500,
                  thorough: bool = True) -> LowerCertificate | None:
    """Prove ``rho(L) >= mu`` by a first-return growth certificate (module docstring).

    Mass ``Q0`` starts on a set C of modes, propagates through ``L / mu`` outside C and is
    collected when it enters C.  Each step subtracts a bound on its rounding error
    (``Ytilde <= L(Y) / mu`` in the PSD order), so the collected sum is a lower bound of the
    exact one; if it dominates ``Q0`` (exactly PSD, nonzero) then the returns repeat forever
    and ``sum_j (L / mu)^j (Q0)`` diverges: ``rho(L) >= mu``.  C is tried as the modes of
    state dimension n carrying the Perron vector's mass (no structural rank loss there), then
    all modes carrying mass, then the fresh modes.
    """
    candidates = []
    if perron is not None:
        blocks = [_sym(b) for b in loop.unvec(perron)]
        mass = np.array([float(np.trace(b)) for b in blocks])
        heavy = mass > 1e-9 * max(float(mass.max()), 1e-300)
        small = heavy & (loop.dims == loop.n)
        for sel in (small, heavy):
            if sel.any():
                candidates.append(([_psd_part(b) if sel[i] else None for i, b in enumerate(blocks)], sel))
    fresh = np.array([loop.is_fresh(i) for i in range(len(loop.modes))])
    candidates.append(([np.eye(d) if fresh[i] else None for i, d in enumerate(loop.dims)], fresh))
    for Q0, sel in candidates:
        cert = _first_return(loop, mu, Q0, sel, max_steps)
        if cert is not None:
            return cert
    if perron is not None and thorough:
        # Growth confined to a face of the cone (e.g. x grows while x(i_m) = 0): exact zeros must
        # stay exact, so track entrywise error bounds instead of identity shifts.
        sets = [sel for _, sel in candidates[:2]]
        # Collecting on one mode avoids comparing two rank-deficient blocks of the same range.
        for i in np.argsort(-mass)[:3]:
            if mass[i] > 0:
                one = np.zeros(len(loop.modes), dtype=bool)
                one[i] = True
                sets.append(one)
        for sel in sets:
            cert = _first_return_entrywise(loop, mu, blocks, sel, max_steps)
            if cert is not None:
                return cert
    return None


def _first_return_entrywise(loop: Loop, mu: float, blocks: list, sel: np.ndarray,
                            max_steps: int) -> LowerCertificate | None:
    """First-return growth with ``Q0 = W W'`` (exactly PSD) and entrywise rounding bounds.

    ``|exact - float| <= E`` entrywise is carried through every step (``|A|``-products), so rows
    and columns that are exactly zero stay exactly zero and the final PSD test runs on the support.
    """
    g = loop.gamma
    Q0, E0 = [], []
    scale = sum(max(float(np.trace(b)), 0.0) for i, b in enumerate(blocks) if sel[i])
    if not scale > 0:
        return None
    for i, d in enumerate(loop.dims):
        if not sel[i]:
            Q0.append(np.zeros((d, d)))
            E0.append(np.zeros((d, d)))
            continue
        s, V = np.linalg.eigh(_sym(blocks[i]) / scale)
        keep = s > 1e-9 * max(float(s[-1]), 1e-300)
        W = V[:, keep] * np.sqrt(s[keep])
        W[np.abs(W) < 1e-13 * max(float(np.abs(W).max(initial=0.0)), 1e-300)] = 0.0
        Q0.append(W @ W.T)  # stands for the exact (PSD) product W W'
        E0.append(2 * (W.shape[1] + 2) * U * (np.abs(W) @ np.abs(W).T))
    members = np.flatnonzero(sel)
    collected = {i: np.zeros_like(Q0[i]) for i in members}
    col_err = {i: np.zeros_like(Q0[i]) for i in members}
    Y, EY = Q0, E0
    best, best_step = -np.inf, 0
    with np.errstate(all="ignore"):
        for step in range(1, max_steps + 1):
            Z = loop.apply(Y)
            Zabs = loop.apply(Y, absolute=True)
            Eprop = loop.apply(EY, absolute=True)
            nxt, nerr = loop.zeros(), loop.zeros()
            for i in range(len(Z)):
                z = _sym(Z[i]) / mu
                e = (g * Zabs[i] + (1 + g) * Eprop[i]) / mu * (1 + 4 * U) + 2 * U * np.abs(z)
                if sel[i]:
                    collected[i] = collected[i] + z
                    col_err[i] = col_err[i] + e + 2 * U * np.abs(collected[i])
                else:
                    nxt[i], nerr[i] = z, e
            Y, EY = nxt, nerr
            if step % 5 == 0 or step == max_steps:
                ok, worst = True, np.inf
                for i in members:
                    D = _sym(collected[i] - Q0[i])
                    ED = col_err[i] + E0[i] + 2 * U * np.abs(D)
                    if not (np.all(np.isfinite(D)) and np.all(np.isfinite(ED))):
                        return None
                    S = np.flatnonzero((np.abs(D) + ED).sum(axis=1) > 0)
                    if S.size == 0:
                        continue
                    Ds = D[np.ix_(S, S)]
                    margin = float(np.linalg.eigvalsh(Ds)[0]) - _eig_err(Ds) - 1.01 * float(
                        np.linalg.norm(ED[np.ix_(S, S)]))
                    worst = min(worst, margin)
                    ok = ok and margin > 0
                if ok:
                    return LowerCertificate(mu=float(mu), Q0=Q0, steps=step, slack=float(worst), verified=True)
                if worst > best + 1e-12 * abs(best):
                    best, best_step = worst, step
                elif step - best_step > 200:
                    return None  # the margin stopped improving
                remaining = sum(float(np.abs(y).sum()) for y in Y)
                total = sum(float(np.abs(c).sum()) for c in collected.values())
                if not np.isfinite(remaining) or remaining < 1e-14 * max(1.0, total):
                    return None
    return None


def _first_return(loop: Loop, mu: float, Q0: list, sel: np.ndarray, max_steps: int) -> LowerCertificate | None:
    scale = sum(float(np.trace(q)) for q in Q0 if q is not None)
    if not scale > 0:
        return None
    Q0 = [np.zeros((d, d)) if q is None else _psd_part(q / scale, rel=0.0) for q, d in zip(Q0, loop.dims)]
    members = np.flatnonzero(sel)
    collected = {i: np.zeros_like(Q0[i]) for i in members}
    slack = {i: 0.0 for i in members}
    Y = Q0
    best, best_step = -np.inf, 0
    with np.errstate(all="ignore"):
        for step in range(1, max_steps + 1):
            Z, err = loop.apply_bounded(Y)
            nxt = loop.zeros()
            for i, z in enumerate(Z):
                z = z / mu
                tau = 1.01 * (err[i] / mu + 4 * U * float(np.linalg.norm(z)))
                if sel[i]:
                    collected[i] = collected[i] + z
                    slack[i] += tau + 2 * U * float(np.linalg.norm(collected[i]))
                else:
                    nxt[i] = z - tau * np.eye(z.shape[0])
            Y = nxt
            if step % 5 == 0 or step == max_steps:
                total = sum(float(np.linalg.norm(c)) for c in collected.values())
                if not np.isfinite(total):
                    return None
                ok, worst = True, np.inf
                for i in members:
                    D = _sym(collected[i] - Q0[i])
                    margin = float(np.linalg.eigvalsh(D)[0]) - _eig_err(D) - slack[i] \
                        - 4 * U * (float(np.linalg.norm(collected[i])) + float(np.linalg.norm(Q0[i])))
                    worst = min(worst, margin)
                    ok = ok and margin > 0
                if ok:
                    return LowerCertificate(mu=float(mu), Q0=Q0, steps=step, slack=float(worst), verified=True)
                if worst > best + 1e-12 * abs(best):
                    best, best_step = worst, step
                elif step - best_step > 200:
                    return None  # the margin stopped improving
                remaining = sum(float(np.linalg.norm(y)) for y in Y)
                if not np.isfinite(remaining) or remaining < 1e-14 * max(1.0, total):
                    return None  # nothing left to return
    return None


@dataclass
class CycleCertificate:
    """A cycle of modes ``i_0 -> ... -> i_k = i_0`` of probability q and product M with ``q rho(M)^2 >= mu^k``.

    ``L^k >= (Q -> q M Q M')`` on block ``i_0`` (one path of the expansion; the rest is PSD), so
    ``rho(L)^k >= q rho(M)^2``.  ``q`` is the exact product of the data's probabilities and ``rho(M) >= r``
    is decided in exact arithmetic (:func:`solver.exact.radius_at_least`).
    """

    mu: float
    cycle: list
    probability: float
    radius_bound: float
    verified: bool = True
    kind: str = "cycle"

    def to_dict(self) -> dict:
        return {"kind": self.kind, "mu": self.mu, "verified": self.verified, "probability": self.probability,
                "radius_bound": self.radius_bound,
                "cycle": [{"channel_state": c, "plant_mode": l, "age": d} for c, l, d in self.cycle]}


def _exact_transition(loop: Loop, t: Transition):
    """The transition's matrix computed exactly from the float64 data (``solver.exact`` tuples)."""
    from . import exact as ex

    src = loop.source
    F, G, K = src["F"], src["G"], src["K"]
    n, N = loop.n, K.shape[0]
    _, l, d = loop.modes[t.src]
    Fe = ex.exact(F[l])
    if d == 0:
        X = ex.add(Fe, ex.matmul(ex.exact(G[l]), ex.exact(K[0])))
    elif loop.dims[t.src] == n:  # exhausted, zero input
        X = Fe
    else:
        q = d if d < N else N - 1
        GK = ex.matmul(ex.exact(G[l]), ex.exact(K[q]))
        A, B, sc = ex._align(Fe, GK)
        X = (np.hstack([A, B]), sc)
    if loop.dims[t.dst] == n:
        return X
    zero_blk = np.zeros((n, n), dtype=object) * 0
    eye = ex.identity(n)[0]
    keep = eye if d == 0 else np.hstack([zero_blk, eye])
    Xm, Km, sc = ex._align(X, (keep, 0))
    return np.vstack([Xm, Km]), sc


def _exact_probability(loop: Loop, t: Transition) -> Fraction:
    src = loop.source
    c, l, d = loop.modes[t.src]
    c2, l2, d2 = loop.modes[t.dst]
    lost = Fraction(float(src["loss"][c2]))
    pe = (1 - lost) if d2 == 0 else lost
    return Fraction(float(src["transition"][c, c2])) * Fraction(float(src["plant_transitions"][l, l2])) * pe


def certify_cycle(loop: Loop, max_length: int = 3, max_cycles: int = 20000, tries: int = 8) -> CycleCertificate | None:
    """Search short cycles of modes for ``q rho(M)^2 > 1`` (float64), then prove the best ones exactly."""
    from . import exact as ex

    if not loop.source:
        return None
    out = {}
    for k, t in enumerate(loop.transitions):
        out.setdefault(t.src, []).append(k)
    found = []
    count = 0

    def walk(start, path, M, q):
        nonlocal count
        here = loop.transitions[path[-1]].dst if path else start
        for k in out.get(here, []):
            t = loop.transitions[k]
            count += 1
            if count > max_cycles:
                return
            M2 = t.A @ M
            q2 = q * t.p
            if t.dst == start:
                with np.errstate(all="ignore"):
                    rho = (float(np.max(np.abs(np.linalg.eigvals(M2)))) if np.all(np.isfinite(M2))
                           else float("nan"))
                score = q2 * rho * rho  # inf, not an OverflowError, for huge radii
                if np.isfinite(rho) and score > 1:
                    L = len(path) + 1
                    found.append((np.exp(np.log(score) / L) if np.isfinite(score) else np.inf, start, path + [k]))
            elif len(path) + 1 < max_length and t.dst > start:  # each cycle once: start at its smallest mode
                walk(start, path + [k], M2, q2)

    for i in range(len(loop.modes)):
        walk(i, [], np.eye(loop.dims[i]), 1.0)
        if count > max_cycles:
            break
    found.sort(key=lambda f: -f[0])
    for _, start, ks in found[:tries]:
        trans = [loop.transitions[k] for k in ks]
        q = Fraction(1)
        for t in trans:
            q *= _exact_probability(loop, t)
        if q == 0:
            continue
        M = ex.product([_exact_transition(loop, t) for t in trans])
        # r >= 1/sqrt(q), rational: then q r^2 >= 1; first try r just below the float radius (a tighter mu)
        den = 1 << 52
        r = Fraction(int(np.ceil(den / math.sqrt(float(q)) * (1 + 1e-12))) + 1, den) if float(q) > 0 else None
        if r is None:
            continue
        while q * r * r < 1:
            r += Fraction(1, den)
        with np.errstate(all="ignore"):
            Mf = np.linalg.multi_dot([t.A for t in reversed(trans)]) if len(trans) > 1 else trans[0].A
            rho_f = float(np.max(np.abs(np.linalg.eigvals(Mf)))) if np.all(np.isfinite(Mf)) else float("nan")
        tight = Fraction(int(den * rho_f * (1 - 1e-9)), den) if np.isfinite(rho_f) and rho_f < 1e300 else r
        if tight > r and ex.radius_at_least(M, tight):
            r = tight
        if r == tight or ex.radius_at_least(M, r):
            L = len(trans)
            # q r^2 >= 1 exactly; its float root rounded down, but never below the proven 1
            qr2 = q * r * r
            mu = max(math.exp((math.log(qr2.numerator) - math.log(qr2.denominator)) / L) * (1 - 1e-12), 1.0)
            return CycleCertificate(mu=mu,
                                    cycle=[loop.modes[t.src] for t in trans], probability=float(q),
                                    radius_bound=float(r))
    return None


# ----------------------------------------------------------------- expected cost
def cost_to_go(loop: Loop, rhs: list) -> list | None:
    """``P = (I - L*)^{-1} rhs`` (float solve; requires rho(L) < 1)."""
    A = sp.identity(loop.size, format="csc") - loop.matrix(adjoint=True).tocsc()
    with np.errstate(all="ignore"):
        p = spla.spsolve(A, loop.vec(rhs))
    if not np.all(np.isfinite(p)):
        return None
    return [_sym(b) for b in loop.unvec(p)]


def recheck_cost(loops: list, P: list) -> bool:
    """Re-check ``P_i - L_l*(P)_i - S_i >= 0`` for every loop l, every rounding bounded (as :func:`recheck_upper`)."""
    P = [_sym(p) for p in P]
    for loop in loops:
        LP, err = loop.apply_bounded(P, adjoint=True)
        for i, p in enumerate(P):
            D = _sym(p - LP[i] - loop.stage[i])
            bound = err[i] + loop.stage_err[i] + 4 * U * (float(np.linalg.norm(p)) + float(np.linalg.norm(LP[i]))
                                                           + float(np.linalg.norm(loop.stage[i])))
            if float(np.linalg.eigvalsh(D)[0]) - _eig_err(D) - bound < 0:
                return False
    return True


def bound_from(P: list, X0: list) -> float:
    """``<P, X0>`` rounded up."""
    total = sum(float(np.sum(p * x)) for p, x in zip(P, X0))
    size = sum(x.size for x in X0)
    return total * (1 + 4 * size * U) + 1e-300


def cost_upper(loop: Loop, X0: list, value: float) -> float | None:
    """Certified upper bound: ``P - L*(P) - S >= 0`` re-checked, then ``J <= <P, X0>``."""
    scale = max(value, 1e-300) / max(sum(float(np.trace(x)) for x in X0), 1e-300)
    for rel in (1e-9, 1e-7, 1e-5, 1e-3):
        eta = rel * scale
        P = cost_to_go(loop, [s + eta * np.eye(s.shape[0]) for s in loop.stage])
        if P is None:
            return None
        if recheck_cost([loop], P):
            return bound_from(P, X0)
    return None


def cost_lower(loop: Loop, X0: list, value: float, max_steps: int = 5000, rel_tol: float = 1e-6) -> float:
    """Witnessed lower bound: the partial sum ``sum_{k<K} <S, L^k(X0)>`` with rigorously rounded-down moments."""
    total = 0.0
    X = X0
    for _ in range(max_steps):
        for i, x in enumerate(X):
            if x.any():
                s = loop.stage[i]
                term = float(np.sum(s * x))
                bound = loop.stage_err[i] * float(np.linalg.norm(x)) + 2 * x.size * U * float(
                    np.sum(np.abs(s) * np.abs(x)))
                total += term - bound
        if value > 0 and total >= value * (1 - rel_tol):
            break
        if sum(float(np.trace(np.abs(x))) for x in X) < 1e-13 * max(1.0, sum(float(np.trace(x)) for x in X0)):
            break
        Z, err = loop.apply_bounded(X)
        X = [z - 1.01 * (err[i] + 4 * U * float(np.linalg.norm(z))) * np.eye(z.shape[0]) for i, z in enumerate(Z)]
    return total * (1 - 1e-12)


def cesaro_modes(loop: Loop, q0: np.ndarray) -> np.ndarray:
    """Long-run average mode distribution from ``q0`` (powers of the lazy chain converge to it)."""
    M = 0.5 * (np.eye(len(loop.modes)) + loop.mode_matrix())
    for _ in range(60):
        M = M @ M
        M /= M.sum(axis=1, keepdims=True)
    return q0 @ M
