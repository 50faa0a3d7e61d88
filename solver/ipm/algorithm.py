"""The primal-dual interior-point iteration (docs/design.md, "The structured interior-point solver").

Mehrotra predictor-corrector with the HKM direction for ``max b^T y`` s.t. ``S = C + A(y) >= 0``: the
steps, the Schur complement solve, the step lengths and the stopping rules.  The problem (operator,
adjoint, Schur complement) comes from a :class:`solver.ipm.model.BlockLMI`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

from .blas import blas_threads, heap_reuse
from .model import BlockLMI
from .schur import dense_ops

__all__ = ["IPMOptions", "IPMSolution", "solve_block_lmi"]


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


#: Block side from which :func:`_not_definite` factors block by block with LAPACK (no copies, stops at the
#: first failed pivot) instead of with the batched gufunc (fewer calls): measured crossover 24-32, side 100
#: 1.8x faster.
_CHOL_LOOP_FROM = 32


def _not_definite(T: np.ndarray) -> np.ndarray:
    """Which of the symmetric blocks ``T`` (overwritten) are not positive definite (a Cholesky failure)."""
    if T.shape[1] < _CHOL_LOOP_FROM:
        return np.isnan(_cholesky(T)[:, -1, -1])
    bad = np.empty(T.shape[0], dtype=bool)
    for i in range(T.shape[0]):
        bad[i] = _potrf(T[i].T, lower=1, clean=0, overwrite_a=1)[1] != 0  # T[i].T: F-ordered, same matrix
    return bad


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
        bvec = np.where(side, beta[1], beta[0])[:, None, None]
        if len(cand) == n2:
            T = dZ * bvec
            T += Z
        else:
            T = dZ[cand] * bvec
            T += Z[cand]
        bad = _not_definite(T)
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
        # M's upper triangle (all a structured assembly fills) is the lower one of M.T, F-ordered: no copy to
        # Fortran order beyond the one that keeps M for a retry.
        fac, info = _potrf(M.T, lower=1, clean=0, overwrite_a=0)
        for reg in (1e-12, 1e-10, 1e-8):
            # Near the optimum of a degenerate problem (repeated modes) M can be singular to rounding:
            # a growing diagonal shift still gives a descent direction (the residuals decide).
            if info == 0:
                break
            fac, info = _potrf((M + np.diag(d * reg + 1e-300)).T, lower=1, clean=0, overwrite_a=1)
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
            op, adj, schur = dense_ops(problem.dense_operator())
        else:
            op, adj = problem.op, problem.adj

            def schur(X, G):
                return problem.schur(X, G, upper=True)
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
