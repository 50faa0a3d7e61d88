"""The primal-dual interior-point iteration (docs/design.md, "The structured interior-point solver").

Mehrotra predictor-corrector with the HKM direction for ``max b^T y`` s.t. ``S = C + A(y) >= 0``: the
steps, the Schur complement solve, the step lengths and the stopping rules.  The problem (operator,
adjoint, Schur complement) comes from a :class:`solver.ipm.model.BlockLMI`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

from .blas import blas_threads, heap_reuse
from .model import BlockLMI, GroupedLMI
from .schur import dense_ops

__all__ = ["GroupedSolution", "IPMOptions", "IPMSolution", "WarmStart", "solve_block_lmi", "solve_grouped"]


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
    sign_only : bool
        The max-t form stops once the sign of ``t*`` is settled with room (the rate search's probes):
        status ``"feasible"`` at the first iterate with ``t > 0`` and ``t`` at least half the upper bound
        ``<C, X>`` (primal residual below 1e-6), ``"infeasible"`` at the first with ``<C, X> < 0``, the
        lower bound within half of it and the primal residual below ``feas_tol`` (the multipliers then are
        a Farkas candidate, re-checked by the caller).  A float ``r`` in (0, 1] instead of True: ``t`` at least
        ``r`` times the upper bound for ``"feasible"`` (``decay_rate="auto"``'s final design: a margin within
        ``1 - r`` of the optimum, docs/design.md §3.5).
    """

    gap_tol: float = 1e-8
    feas_tol: float = 1e-8
    max_iter: int = 100
    step: float = 0.98
    time_limit: float | None = None
    #: Iteration cap of the objective's solve after phase 1 (None: ``max_iter``), e.g. a first stage that only
    #: has to give a shape (docs/design.md §8.3.3).
    objective_max_iter: int | None = None
    dense: bool | None = None
    threads: int | None = 1
    sign_only: bool | float = False
    #: With ``sign_only``: ``refute(X) -> bool`` is asked at every iterate with ``<C, X> < 0`` and the primal residual
    #: below ``feas_tol`` whose lower bound is not yet within half of it; True (the caller's Farkas re-check of these
    #: multipliers passed) ends the solve ``"infeasible"`` there (docs/design.md §3.2.1).
    refute: object | None = None
    #: The max-t form's data may change between iterations (the rate-following path, docs/design.md §3.2.2):
    #: ``retarget(y, X, S, upper, t, primal_residual)`` is called at every iterate before the stopping rules
    #: and returns None (go on), ``"stop"`` (status ``"stopped"``, this iterate returned) or new data
    #: ``(C, op, adj, schur, y, X)`` (the next iteration starts from them; ``C + op(y)`` positive definite),
    #: or ``(C, op, adj, schur, y, X, S)``: the slacks ``S`` (positive definite) are kept and the new data's dual
    #: residual ``S - C - op(y)`` is carried and removed by the Newton steps, as in an infeasible start.
    retarget: object | None = None
    #: Mehrotra's centring ``sigma = (mu_aff / mu) ** sigma_power``; the hinf design's SDPs take 2 (more centring
    #: after a short predictor step: the n = 12 hinf SDP 45 + 10 -> 35 + 7 iterations, docs/design.md §7, §8.3.2).
    sigma_power: float = 3.0


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
    equality_multiplier : float or ndarray of shape (q,)
        Multiplier ``nu`` of the equality ``<a, vec V> = beta`` (one per row when there are q):
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
    equality_multiplier: float | np.ndarray


#: A grouped or objective solve whose best ``max(primal residual, gap)`` is below this and has not improved for
#: 8 iterations stops (a plain max-t solve: below 1e-6).
STALL_SCORE = 1e-4
#: ... and an objective solve whose best gap is below STALL_GAP stops after STALL_FAST iterations in which the score
#: did not halve (docs/design.md §8.3.2).
STALL_GAP = 1e-6
STALL_FAST = 3
#: ... and one whose best score is below STALL_TIGHT at the first iteration that does not halve it (docs/design.md
#: §8.3.2: the second stage's last 2-3 iterations at n = 12 / 20 only raised the primal residual or took the gap
#: from 7e-9 to 4e-9).
STALL_TIGHT = 1e-7
#: Iterative-refinement steps of each Newton direction against the exact operator (see ``direction``).
REFINE_STEPS = 4
#: ... of the predictor's (only its step lengths and ``dX dS`` enter the corrector, whose own refinement keeps
#: ``adj(dX) = r_p``).
PREDICTOR_REFINE = 0
#: ... in problems whose blocks' sides sum to at least this (``sum_b k_b``; n = 12, n_drop = 10 cost: 2574): small
#: ones, where the refinement costs little, keep it (a one-mode loop whose P spans 6e8, ``sum_b k_b`` 27, lost its
#: certified bracket without it: tests/solver/test_performance_scaling.py).
PREDICTOR_REFINE_FROM = 500
#: ... until the direction's error in ``adj(dX) = r_p`` is below this fraction of ``|r_p|``.
REFINE_TO = 0.1
_potrf = scipy.linalg.lapack.dpotrf
_potrs = scipy.linalg.lapack.dpotrs
_trtri = scipy.linalg.lapack.dtrtri

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
#: ... and, in a problem of several groups, from ``nb k^3`` (a group's Cholesky work) this large: the paper
#: example's cost SDP has groups of 1-3 blocks of side 10-13, whose step lengths took half the solve by trials.
_CHOL_STEPS_WORK = 1e5


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


#: Block side from which :func:`_tri_inverse` inverts the Cholesky factors block by block with LAPACK's triangular
#: inverse (a third of the general inverse's flops) instead of the batched general inverse: sides 46-95 (the cost
#: and hinf groups of docs/design.md §8.3.1) 2.1-2.4x faster, i.e. ~5 % of an iteration.
_TRI_INV_FROM = 32


def _tri_inverse(L: np.ndarray) -> np.ndarray:
    """The inverses of a stack of lower-triangular (Cholesky) factors."""
    if L.shape[1] < _TRI_INV_FROM:
        return _inv(L)
    out = np.empty_like(L)
    for i in range(L.shape[0]):
        out[i] = _trtri(L[i], lower=1)[0]
    return out


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


def _dense_factor(M: np.ndarray, d: np.ndarray, dead):
    """A solver ``h -> dy`` of ``M dy = h`` (upper triangle of M read; ``dead`` pinned to ``dy = 0``), or None."""
    if dead is not None:
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
        return None
    return lambda h: _potrs(fac, h, lower=1)[0]


@dataclass
class _Core:
    """What the iteration returns, in the solver's coordinates (``X``: one array per group)."""

    y: np.ndarray
    X: list
    status: str
    iterations: int
    primal_residual: float
    gap: float
    upper: float
    timings: dict
    interior: bool = True  # False: an infeasible start (``slack_start``) that never reached C + A(y) > 0


def _ipm_core(C, b, op, adj, schur, o: IPMOptions, t_start: float, feasible_start: bool = False,
              x_start: float | None = None, offset: float | None = None, phase1: bool = False,
              y_start: np.ndarray | None = None, slack_start: float | None = None) -> _Core:
    """Mehrotra predictor-corrector with the HKM direction for ``max b^T y, S_g = C_g + A_g(y) >= 0``.

    ``C`` is a list of block arrays (one per group, shape (nb_g, k_g, k_g)); ``op(y)`` returns the list of
    the groups' changes, ``adj`` takes such a list and ``schur(X, G)`` two of them.  The ``y`` iterates
    stay feasible: ``S`` is recomputed as ``C + A(y)`` (no drift), so the dual residual is zero and the
    predictor's right-hand side is just ``b``; ``X`` starts infeasible (``A^*(X) + b != 0``) and its
    residual is driven to zero by the Newton steps.

    ``offset``: a general objective ``f = offset - b^T y`` (the relative gap is taken on f's values, with
    no ``1 +`` floor).  ``phase1``: the max-t form stopped early (status ``"feasible"``) at the first
    iterate with ``t > 0`` and ``t`` at least half the current upper bound (so the start of the next
    phase is strictly feasible and away from the boundary).

    ``y_start``: a warm start (the max-t form only): ``S = C + A(y_start)`` must be positive definite
    (:func:`warm_start` makes one from a neighbouring problem's solution); ``x_start`` then is a list of
    multipliers.

    ``slack_start``: the infeasible start of a general objective (docs/design.md §8.3.2): ``y = 0`` whatever
    the blocks there, ``S_g = slack_start I`` and the dual residual ``E = S - C - A(y)`` carried along, each
    Newton step aiming at ``S + dS = C + A(y + dy)`` (``dS = A(dy) - E``), so a dual step of length alpha
    leaves ``(1 - alpha) E``.  ``E`` is dropped (``S = C + A(y)``, the feasible iteration from then on) at
    the first iterate where ``C + A(y)`` itself is positive definite; until then no iterate is a candidate
    answer (the status then is ``"no_interior"`` when the iteration ends, at the latest after
    :data:`ONE_PHASE_GIVE_UP` iterations).
    """
    with np.errstate(invalid="ignore"):  # a failed Cholesky factor is NaNs (checked), not a warning
        return _ipm_loop(C, b, op, adj, schur, o, t_start, feasible_start, x_start, offset, phase1, y_start,
                         slack_start)


def _ipm_loop(C, b, op, adj, schur, o, t_start, feasible_start, x_start, offset=None, phase1=False,
              y_start=None, slack_start=None) -> _Core:
    fixed_dead = len(C) > 1 or offset is not None
    dead0 = None
    tim = {"assembly": 0.0, "factorization": 0.0, "line_search": 0.0}
    perf = time.perf_counter
    ng = len(C)
    nbs = [c.shape[0] for c in C]
    N = sum(c.shape[0] * c.shape[1] for c in C)
    # Step lengths: eigenvalues for small blocks (one batched call), Cholesky trials for larger ones.
    chol = [c.shape[1] >= _CHOL_STEPS_FROM for c in C]
    if ng > 1:  # groups: a few blocks each, where one eigvalsh call beats the trials' per-call overhead
        chol = [ch and c.shape[0] * c.shape[1]**3 >= _CHOL_STEPS_WORK for ch, c in zip(chol, C)]
    cap = 1.0 / o.step
    eyes = [np.eye(c.shape[1]) for c in C]
    Cf = [c.reshape(-1) for c in C]
    y = np.zeros(b.shape[0])
    # t far enough below every block's smallest eigenvalue: S = C - t I > 0.
    # (feasible_start: C itself is positive definite and y = 0 is the start; no t coordinate.)
    if y_start is not None:
        y = np.array(y_start, dtype=np.float64)
    elif not feasible_start:
        y[-1] = min(float(_eigvalsh(c)[:, 0].min()) for c in C) - max(1.0, max(float(np.abs(c).max()) for c in C))
    S = [c + d for c, d in zip(C, op(y))]
    E = E_prev = None  # the dual residual S - C - A(y) of an infeasible start (None: S = C + A(y))
    if slack_start is not None:
        E = [np.eye(c.shape[1]) * s0 - s for c, s, s0 in zip(C, S, np.broadcast_to(slack_start, (ng,)))]
        S = [s + e for s, e in zip(S, E)]
    # x_start: the multipliers' start X = x_start I (default 1/N, the max-t form's sum tr X = 1).
    if isinstance(x_start, list):  # given multipliers (phase 2: centred on the start's S)
        X = x_start
    else:
        xs = 1.0 / N if x_start is None else x_start
        X = [np.broadcast_to(e * xs, c.shape).copy() for e, c in zip(eyes, C)]
    normb = 1.0 + math.sqrt(float(b @ b))
    floor, off = (1.0, 0.0) if offset is None else (1e-300, offset)
    status = "max_iterations"
    best = None
    prog = (math.inf, 0)  # the last iterate whose score halved the previous such one's
    it = 0
    ap = ad = 0.0
    rp = gap = math.inf  # reported as such when the start itself cannot be factored
    y_prev = X_prev = dy = dX = None  # the last step, shortened when rounding breaks the next factorization
    for it in range(o.max_iter + 1):
        Z = [np.concatenate([x, s]) for x, s in zip(X, S)]
        LL = [_cholesky(z) for z in Z]
        if ng == 1 and np.isnan(LL[0][:, -1, -1]).any() or ng > 1 and any(np.isnan(ll[:, -1, -1]).any() for ll in LL):
            # Rounding made the new S (recomputed from y) or X singular: shorten the last step.
            if y_prev is None or ad < 1e-12:
                status = "numerical_error"
                break
            ad *= 0.5
            y = y_prev + ad * dy
            S = [c + d for c, d in zip(C, op(y))]
            if E_prev is not None:
                E = [(1.0 - ad) * e for e in E_prev]
                S = [s + e for s, e in zip(S, E)]
            X = [xp + ad * d for xp, d in zip(X_prev, dX)] if ap > ad else X
            continue
        Li, G = [], []
        for g in range(ng):
            nb = nbs[g]
            if chol[g]:
                Li.append(None)
                LSi = _tri_inverse(LL[g][nb:])
            else:
                Li.append(_inv(LL[g]))
                LSi = Li[g][nb:]
            G.append(LSi.transpose(0, 2, 1) @ LSi)
        r_p = -b - adj(X)
        Xf = [x.reshape(-1) for x in X]
        pobj = XS = 0.0
        for c, x, s in zip(Cf, Xf, S):
            pobj += float(c @ x)
            XS += float(x @ s.reshape(-1))
        dobj = float(b @ y)
        mu = XS / N
        rp = math.sqrt(float(r_p @ r_p)) / normb
        denom = floor + abs(off - pobj) + abs(off - dobj)
        gap = max(abs(pobj - dobj), XS) / denom
        score = max(rp, gap) if E is None else math.inf  # an infeasible iterate is no answer
        if best is None or score < best[0]:
            best = (score, it, y, X, rp, gap, pobj)
        if o.retarget is not None:
            new = o.retarget(y, X, S, pobj, dobj, rp)
            if isinstance(new, str):
                best, status = (score, it, y, X, rp, gap, pobj), "stopped"
                break
            if new is not None:  # another problem of the same shape: its residuals and steps from the next iterate
                C, op, adj, schur, y, X = new[:6]
                Cf = [c.reshape(-1) for c in C]
                S = [c + d for c, d in zip(C, op(y))]
                if len(new) > 6 and new[6] is not None:
                    # the slacks kept (still centred with X): the new data's dual residual E = S - C - A(y) is
                    # carried as in the infeasible start, and the next Newton step aims at the new data's
                    # central path from there (the tangent predictor and the corrector in one step)
                    E = [s_keep - s for s_keep, s in zip(new[6], S)]
                    S = list(new[6])
                else:  # the slacks recomputed from the new data: no residual (one left by an earlier move is stale)
                    E = None
                E_prev = None
                best = None
                continue
        if rp < o.feas_tol and gap < o.gap_tol and E is None:
            status = "optimal"
            break
        if phase1 and dobj > 0.0 and rp < 1e-3 and dobj >= 0.5 * pobj:
            best = (score, it, y, X, rp, gap, pobj)
            status = "feasible"
            break
        if o.sign_only and offset is None:
            if dobj > 0.0 and rp < 1e-6 and dobj >= (0.5 if o.sign_only is True else o.sign_only) * pobj:
                best, status = (score, it, y, X, rp, gap, pobj), "feasible"
                break
            if pobj < 0.0 and rp < o.feas_tol and (dobj >= 2.0 * pobj or (
                    o.refute is not None and E is None and o.refute(X))):
                best, status = (score, it, y, X, rp, gap, pobj), "infeasible"
                break
        if score < 0.5 * prog[0]:
            prog = (score, it)
        if E is None and offset is not None and best[5] <= STALL_GAP and best[0] < STALL_SCORE \
                and it - prog[1] >= STALL_FAST:
            # converged (gap) and the score no longer halving: the rounding floor (n = 12, n_drop = 10 cost SDP: the
            # primal residual from 5e-6 up to 4e-4 in one step at mu ~ 4e-9, and no better iterate in 8 more)
            status = "stalled"
            break
        if E is None and offset is not None and best[0] < STALL_TIGHT and it > prog[1]:
            status = "stalled"
            break
        if E is None and it - best[1] >= 8 and best[0] < (STALL_SCORE if fixed_dead else 1e-6):
            # no progress for 8 iterations near the optimum: rounding floor reached (the best iterate is returned;
            # at n = 12, n_drop = 10 the cost SDP's primal residual creeps up after ~40 iterations for 60 more)
            status = "stalled"
            break
        if it == o.max_iter:
            break
        if E is not None and slack_start is not None and it >= ONE_PHASE_GIVE_UP:
            # the dual residual not dropped yet: most likely no interior (docs/design.md §8.3.2); the two phases run
            status = "max_iterations"
            break
        if o.time_limit is not None and perf() - t_start > o.time_limit:
            status = "time_limit"
            break
        t0 = perf()
        M = solve = None  # the last iteration's Schur matrix and factor go before the next one is built
        M = schur(X, G)
        t1 = perf()
        tim["assembly"] += t1 - t0
        d = M.diagonal()
        dmax = float(d.max())
        if fixed_dead and dead0 is not None:
            # grouped problems: only the directions unseen at the start are pinned; later the diagonal's range
            # grows with the scalings (X_b -> rank deficient) and a relative threshold froze live directions
            # (phase 2 stalled 1e-4 above the optimum)
            dead = dead0
            anydead = bool(dead.any())
        else:
            anydead = float(d.min()) <= 1e-14 * dmax
            if anydead:
                dead = d <= 1e-14 * dmax
            if fixed_dead:
                dead0 = dead if anydead else np.zeros(d.shape, dtype=bool)
        # a structured Schur complement (solver.ipm.sparse_schur) factors itself
        pins = dead if anydead else None
        solve = _dense_factor(M, d, pins) if isinstance(M, np.ndarray) else M.factor(pins)
        if solve is None:
            status = "numerical_error"
            break
        tim["factorization"] += perf() - t1

        def direction(h, RcG, steps=REFINE_STEPS):
            dy = solve(h)
            ne_prev, best_dir = math.inf, None
            for refine in range(steps + 1):
                dS = op(dy)
                if E is not None:  # aim at S + dS = C + A(y + dy)
                    dS = [ds - e for ds, e in zip(dS, E)]
                dX = []
                for x, ds, g, rc in zip(X, dS, G, RcG):
                    W = rc - x @ ds @ g
                    dX.append(0.5 * (W + W.transpose(0, 2, 1)))
                if refine == steps or not fixed_dead:  # grouped problems only (the plain LMI does not need it)
                    break
                # Iterative refinement on the exact operator: the step must give adj(dX) = r_p; near the optimum
                # the Schur complement is ill-conditioned and its rounding left the primal residual growing again
                # (n = 12, n_drop = 10 cost SDP: r_p from 1e-4 back to 5e-3, no convergence in 100 iterations)
                e = adj(dX) - r_p
                if anydead:
                    e[dead] = 0.0
                ne = math.sqrt(float(e @ e))
                if not ne > REFINE_TO * math.sqrt(float(r_p @ r_p)) + 1e-14 * normb or ne > 0.5 * ne_prev:
                    if ne > ne_prev:  # the last correction made it worse: undo it
                        dy, dS, dX = best_dir
                    break
                ne_prev, best_dir = ne, (dy, dS, dX)
                dy = dy + solve(e)
            return dy, dS, dX

        def step_lengths(dX, dS, cap_, rtol):
            ap_, ad_ = cap_, cap_
            for g in range(ng):
                a1, a2 = (_steps_chol if chol[g] else _steps_eig)(Z[g] if chol[g] else Li[g],
                                                                  np.concatenate([dX[g], dS[g]]), nbs[g], cap_, rtol)
                ap_, ad_ = min(ap_, a1), min(ad_, a2)
            return ap_, ad_

        # Predictor (affine scaling), R_c = -X S: the right-hand side adj(R_c G) - r_p is b.
        XEG = None if E is None else [x @ e @ g for x, e, g in zip(X, E, G)]
        hb = b if E is None else b + adj([0.5 * (w + w.transpose(0, 2, 1)) for w in XEG])
        hb = np.where(dead, 0.0, hb) if anydead else hb
        dy, dS, dX = direction(hb, [-x for x in X], PREDICTOR_REFINE if N >= PREDICTOR_REFINE_FROM else REFINE_STEPS)
        t3 = perf()
        ap, ad = step_lengths(dX, dS, 1.0, 0.1)
        tim["line_search"] += perf() - t3
        xds = dxs = dxds = 0.0
        for x, s, dx, ds in zip(Xf, S, dX, dS):
            dsf, dxf = ds.reshape(-1), dx.reshape(-1)
            xds += float(x @ dsf)
            dxs += float(dxf @ s.reshape(-1))
            dxds += float(dxf @ dsf)
        mu_aff = (XS + ad * xds + ap * dxs + ap * ad * dxds) / N
        sigma = min(1.0, max(0.0, (mu_aff / mu) ** o.sigma_power)) if mu > 0 else 0.0
        # Corrector: R_c = sigma mu I - X S - dX_aff dS_aff.
        RcG = [sigma * mu * g - x - dx @ ds @ g for g, x, dx, ds in zip(G, X, dX, dS)]
        h = adj(RcG if E is None else [r + 0.5 * (w + w.transpose(0, 2, 1)) for r, w in zip(RcG, XEG)]) - r_p
        if anydead:
            h[dead] = 0.0
        dy, dS, dX = direction(h, RcG)
        t4 = perf()
        ap, ad = step_lengths(dX, dS, cap, 0.02)
        ap, ad = min(1.0, o.step * ap), min(1.0, o.step * ad)
        tim["line_search"] += perf() - t4
        y_prev, X_prev = y, X
        X = [x + ap * d for x, d in zip(X, dX)]
        y = y + ad * dy
        S = [c + d for c, d in zip(C, op(y))]
        E_prev = E
        if E is not None:
            if any(np.isnan(_cholesky(s)[:, -1, -1]).any() for s in S):
                E = [(1.0 - ad) * e for e in E]
                S = [s + e for s, e in zip(S, E)]
            else:  # C + A(y) > 0: feasible from here on
                E = None
        if not math.isfinite(float(y.sum()) + sum(float(x.sum()) for x in X)):
            status = "numerical_error"
            break
    interior = E is None and not (best is not None and best[0] == math.inf)
    if not interior:  # an infeasible start that never reached C + A(y) > 0: no answer
        status = "no_interior" if status in ("max_iterations", "numerical_error") else status
        best = None
    if status not in ("optimal", "feasible", "infeasible") and best is not None:
        _, _, y, X, rp, gap, pobj = best
        if status in ("max_iterations", "numerical_error", "stalled") and max(rp, gap) < 1e-6:
            # Stalled close to the optimum (rounding): like Clarabel's "almost solved".
            status = "inaccurate"
    tim["total"] = perf() - t_start
    tim["other"] = tim["total"] - tim["assembly"] - tim["factorization"] - tim["line_search"]
    return _Core(y=y, X=X, status=status, iterations=it, primal_residual=float(rp), gap=float(gap),
                 upper=sum(float(np.vdot(c, x)) for c, x in zip(C, X)), timings=tim, interior=interior)


@dataclass
class WarmStart:
    """A start for :func:`solve_block_lmi` from a neighbouring problem's solution (docs/design.md, "Rate search").

    The max-t form is feasible at every ``V``: ``t = lambda_min(blocks at V) - shift`` makes the start strictly
    feasible whatever the new data.  An optimum of the old problem is badly centred for the new one
    (``X_b S_b ~ 0``: the multipliers are rank deficient where the slacks are not), so ``t`` is lowered by
    ``shift`` and the multipliers are blended with the identity: ``X = (1 - blend) X_old + blend I / N``
    (``sum tr X = 1`` kept).  Both only move the start; the iteration and its stopping rules are those of
    a cold solve, so the optimum reached is the same.

    Attributes
    ----------
    V : list of ndarray
        The variables (the problem's ``variables`` order and shapes), e.g. :attr:`IPMSolution.V`.
    X : ndarray, shape (nb, k, k), optional
        Multipliers (PSD); None starts them at ``I / N``.
    shift : float
        How far below the blocks' smallest eigenvalue ``t`` starts (> 0; absolute, the blocks' units).
    blend : float
        Weight of ``I / N`` in the multipliers' start, in (0, 1].
    """

    V: list
    X: np.ndarray | None = None
    shift: float = 1e-2
    blend: float = 0.1


def _coordinate_rows(problem: BlockLMI) -> np.ndarray:
    """For each reduced coordinate ``y_j``, a full coordinate equal to it (``x = T y``: a row of ``T`` whose
    only entry is a 1 in column j).  Every direction but the equality's pivot has one."""
    rows = problem.__dict__.get("_coord_rows")
    if rows is None:
        T = problem.T.tocsr()
        nnz = np.diff(T.indptr)
        rows = np.full(T.shape[1], -1)
        for r in np.flatnonzero(nnz == 1)[::-1]:  # the first such row of each column wins
            if T.data[T.indptr[r]] == 1.0:
                rows[T.indices[T.indptr[r]]] = r
        if (rows < 0).any():
            raise ValueError("the problem's basis has a coordinate without its own entry")
        problem._coord_rows = rows
    return rows


def _warm_y(problem: BlockLMI, start: WarmStart, op) -> tuple[np.ndarray, list]:
    """``y`` and the multipliers of a :class:`WarmStart` (the max-t form)."""
    x = np.concatenate([(np.asarray(v, dtype=np.float64) - v0).ravel() for v, v0 in zip(start.V, problem.V0)]
                       + [np.zeros(1)])
    y = x[_coordinate_rows(problem)]
    y[-1] = 0.0
    B = problem.C + op(y)
    y[-1] = float(_eigvalsh(B)[:, 0].min()) - start.shift
    N = problem.nb * problem.k
    eye = np.broadcast_to(np.eye(problem.k) / N, problem.C.shape)
    if start.X is None:
        X = eye.copy()
    else:
        X0 = 0.5 * (start.X + np.swapaxes(start.X, 1, 2))
        X = (1.0 - start.blend) * X0 / max(float(np.trace(X0, axis1=1, axis2=2).sum()), 1e-300) + start.blend * eye
    return y, [X]


def solve_block_lmi(problem: BlockLMI, options: IPMOptions | None = None,
                    start: WarmStart | None = None) -> IPMSolution:
    """Solve a :class:`BlockLMI` by an infeasible primal-dual path-following method.

    HKM direction, Mehrotra predictor-corrector, Schur complement from
    :meth:`BlockLMI.schur` (or from the dense operator for small problems).

    Parameters
    ----------
    problem : BlockLMI
    options : IPMOptions, optional
    start : WarmStart, optional
        A warm start (max-t form only), e.g. the solution of the same problem with other data.

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
        y_start = None
        if start is not None:
            if not problem.with_t:
                raise ValueError("a warm start needs the max-t form")
            y_start, x_start = _warm_y(problem, start, op)
        core = _ipm_core([problem.C], problem.b, lambda y: [op(y)], lambda U: adj(U[0]),
                         lambda X, G: schur(X[0], G[0]), o, t_start, feasible_start=not problem.with_t,
                         x_start=x_start, y_start=y_start)
        core.X = core.X[0]
        x = problem.full(core.y)
        V = [v0 + x[sl].reshape(var.shape) for var, sl, v0 in zip(problem.variables, problem.slices, problem.V0)]
        nu = 0.0
        if problem.equality is not None:
            a = np.atleast_2d(problem.equality)
            eq_dir = problem.__dict__.get("_eq_dir")
            if eq_dir is not None:  # a . A_full^*(X) = <A_full(a), X>
                proj = eq_dir.reshape(len(a), -1) @ core.X.reshape(-1)
            else:
                proj = a @ problem.adj_full(core.X)[:-1]
            # least squares: A_V^*(X) = a^T nu
            nu = np.linalg.solve(a @ a.T, proj)
            nu = float(nu[0]) if np.ndim(problem.equality) == 1 else nu
        return IPMSolution(t=float(x[-1]), upper=core.upper, V=V, X=core.X, equality_multiplier=nu,
                           status=core.status, iterations=core.iterations, primal_residual=core.primal_residual,
                           dual_residual=0.0, gap=core.gap, timings=core.timings)


@dataclass(kw_only=True)
class GroupedSolution(_SolveStatus):
    """Result of :func:`solve_grouped`.

    Attributes
    ----------
    status : {"optimal", "inaccurate", "infeasible", "no_interior", "max_iterations", "time_limit", \
              "numerical_error", "stalled"}
        ``"infeasible"``: phase 1 ended with ``t_upper < -1e-6`` times the constants' size (and a primal
        residual below 1e-6);
        then ``X`` is a Farkas certificate (below).  Otherwise the status of the last phase run.
    V : dict
        Variable name -> value (matrix variables as arrays, scalars as floats).  Whatever the status,
        every block at V is positive definite when ``t > 0`` (phase 2 keeps its iterates strictly feasible).
    value : float
        ``<c, V>`` at the returned V (attained); ``nan`` without phase 2.
    lower : float
        ``value - gap``: a lower bound on the optimum up to the primal residual (``nan`` without phase 2).
    t : float
        Phase 1's attained ``t`` (every block ``>= t I`` at its point); ``nan`` when the one-phase solve answered.
    t_upper : float
        Phase 1's ``sum_g <C_g, X_g>``: an upper bound on ``max t`` up to its primal residual (``nan`` likewise).
    X : dict
        Group name -> multipliers, shape (nb_g, k_g, k_g), PSD, in the blocks' order.  After phase 2:
        the objective's multipliers.  When infeasible: phase 1's, normalized ``sum_g sum_b trace X_b = 1``,
        with ``sum_g A_g^*(X_g) = 0`` on every variable direction up to ``primal_residual`` and
        ``sum_g <C_g, X_g> = t_upper < 0`` (``C_g``: the groups' constant parts, ``problem.C``).
    phase1_iterations : int
        0 when the one-phase solve answered.
    iterations, primal_residual, dual_residual, gap, timings
        As in :class:`IPMSolution` (of the last phase; ``iterations`` counts every phase run, a one-phase attempt
        that gave no answer included).
    """

    V: dict
    value: float
    lower: float
    t: float
    t_upper: float
    X: dict
    phase1_iterations: int


#: Phase 2's multipliers start this many times above the least-squares fit of ``A^*(xi I) = -b``: from the fit
#: itself (or from ``xi S^{-1}``, centred) the first directions are huge and the iterates run away along
#: directions the objective barely sees (paper example, cost from x0: no convergence in 100 iterations);
#: from 10-1000 times above, 13-20 iterations (measured on the paper example's cost, x0 and hinf SDPs); at n = 12,
#: n_drop = 10 the cost SDP's phase 2 takes ~45 iterations from 100 times above and ~37 from 1000 times (10: none).
X_START_FACTOR = 1000.0


def _x_start(adj, b, C, factor: float = X_START_FACTOR) -> list:
    """Phase 2's multipliers ``X_g = xi I``: ``xi`` is ``factor`` times the least-squares
    fit of ``A^*(xi I) = -b`` (a general objective fixes the multipliers' scale), or ``|b| / |A^*(I)|``.
    """
    g = adj([np.broadcast_to(np.eye(c.shape[1]), c.shape) for c in C])  # A^*(I)
    gg = float(g @ g)
    xs = 1.0 / sum(c.shape[0] * c.shape[1] for c in C)
    if gg > 0:
        xs = max(xs, -float(b @ g) / gg, float(np.linalg.norm(b)) / np.sqrt(gg))
    return [np.broadcast_to(np.eye(c.shape[1]) * (factor * xs), c.shape).copy() for c in C]


#: Phase 1 calls a problem infeasible only when ``max t`` is below ``-INFEASIBLE_T`` times the constants' size:
#: the performance SDPs are weakly feasible at ``V = 0`` (``t* = 0`` there) and near-marginal loops (P ~ 1e6)
#: have ``t* ~ 1e-11``, which the multipliers' ``upper ~ -1e-11`` cannot tell apart (seeded random families).
INFEASIBLE_T = 1e-6


#: The one-phase solve's start (docs/design.md §8.3.2): slacks ``S_g = SLACK_START max(1, max |C_g|) I``, multipliers
#: at the least-squares fit of ``A^*(xi I) = -b`` (n = 12 cost and hinf SDPs of ``bench speed``: slacks 1-1000 times,
#: multipliers 0.1-10 times the fit or 10-10^4 absolute gave no fewer iterations on both).
SLACK_START = 10.0

#: The one-phase solve gives up (status ``"no_interior"``, the two phases then run) when its dual residual ``E`` has
#: not been dropped after this many iterations (docs/design.md §8.3.2: a problem without an interior otherwise runs
#: the attempt to ``max_iter``; the slowest drop measured is 51 iterations, a hinf SDP that then falls back).
ONE_PHASE_GIVE_UP = 40


#: Phase 1 of the two phases stops at these tolerances at most, whatever the objective's (its own stop is ``t > 0``).
PHASE1_TOL = 1e-8


def _one_phase(problem: GroupedLMI, objective: dict, o: IPMOptions, t_start: float):
    """``min <c, V>`` from ``V = V0`` by the infeasible start (:func:`_ipm_core`'s ``slack_start``): the problem in the
    objective form, its ``(core, offset)``."""
    two = problem.at(np.zeros(problem.p), objective)
    op, adj, schur = two.ops(o.dense)
    offset = _offset(two, objective)
    s0 = np.array([SLACK_START * max(1.0, float(np.abs(c).max())) for c in two.C])
    core = _ipm_core(two.C, two.b, op, adj, schur, o, t_start, feasible_start=True,
                     x_start=_x_start(adj, two.b, two.C, 1.0), offset=offset, slack_start=s0)
    return two, core, offset


def solve_grouped(problem: GroupedLMI, objective: dict | None = None,
                  options: IPMOptions | None = None, one_phase: bool = True,
                  y_start: np.ndarray | None = None, x_start: list | None = None) -> GroupedSolution:
    """Solve a :class:`GroupedLMI` in one phase, else in two (docs/design.md, §7 "Objectives", §8.3.2).

    With an objective, first in one phase: ``min <c, V>`` from the infeasible start (every slack ``s I``, the
    dual residual carried along and dropped at the first point where every block is positive definite).  When
    it ends at a strictly feasible point with status ``"optimal"``, ``"inaccurate"``, ``"stalled"`` or
    ``"time_limit"``, that is the answer (``t`` and ``t_upper`` ``nan``, ``phase1_iterations`` 0); otherwise
    (no such point, or ``"max_iterations"`` / ``"numerical_error"``) the two phases below run.  The attempt gives up
    after :data:`ONE_PHASE_GIVE_UP` iterations without a strictly feasible point.

    Phase 1: ``max t`` s.t. every block ``- t I >= 0`` from ``problem`` (built without an objective),
    stopped at the first iterate with ``t > 0`` and ``t >= upper / 2`` (strictly feasible, away from the
    boundary).  When it ends with ``t* < 0`` the problem is infeasible and the multipliers are the
    certificate.  Phase 2: ``min <c, V>`` (``objective``: variable name -> coefficients) from phase 1's
    point, which keeps every block positive definite.

    Parameters
    ----------
    problem : GroupedLMI
        The max-t form (``objective=None``).
    objective : dict, optional
        Without it only phase 1 runs, to its optimum.
    options : IPMOptions, optional
    one_phase : bool
        False: the two phases only (the reference the tests compare the one-phase answer with).
    y_start : ndarray, optional
        A strictly feasible point in ``problem``'s coordinates (``t`` = 0): only the objective runs, from there
        (phase 2's start and multipliers), and ``phase1_iterations`` is 0.
    x_start : list of ndarray, optional
        With ``y_start``: the multipliers to start from (one positive definite array per group, e.g. a previous
        solve's carried over by a congruence, docs/design.md §8.3.2) instead of phase 2's.

    Returns
    -------
    GroupedSolution
    """
    o = options or IPMOptions()
    large = problem.n_full**2 > 2**20
    names = [g.name for g in problem.groups_spec]
    with blas_threads(o.threads), heap_reuse(large):
        t_start = time.perf_counter()
        done, timings = 0, {"assembly": 0.0, "factorization": 0.0, "line_search": 0.0}
        if objective and y_start is not None:
            two = problem.at(np.asarray(y_start, dtype=np.float64), objective)
            op2, adj2, schur2 = two.ops(o.dense)
            offset = _offset(two, objective)
            core2 = _ipm_core(two.C, two.b, op2, adj2, schur2, o, t_start, feasible_start=True,
                              x_start=_x_start(adj2, two.b, two.C) if x_start is None else list(x_start),
                              offset=offset)
            _add_timings(timings, core2.timings)
            out = _objective_answer(two, core2, offset, names, 0)
            out.update(t=float("nan"), t_upper=float("nan"))
            return _grouped_solution(problem, out, timings, t_start)
        if objective and one_phase:
            two, core2, offset = _one_phase(problem, objective, o, t_start)
            _add_timings(timings, core2.timings)
            if core2.interior and core2.status in ("optimal", "inaccurate", "stalled", "time_limit"):
                out = _objective_answer(two, core2, offset, names, 0)
                out.update(t=float("nan"), t_upper=float("nan"))
                return _grouped_solution(problem, out, timings, t_start)
            done = core2.iterations  # no answer: the two phases (the attempt's iterations and time count)
        op, adj, schur = problem.ops(o.dense)
        o1 = o
        if objective is not None and (o.gap_tol > PHASE1_TOL or o.feas_tol > PHASE1_TOL):
            # a loose objective tolerance (a first stage, docs/design.md §8.3.2) is not phase 1's: stopped "optimal"
            # at gap 1e-2 before t > 0, phase 1 would call a problem with an interior "no_interior"
            o1 = dataclasses.replace(o, gap_tol=min(o.gap_tol, PHASE1_TOL), feas_tol=min(o.feas_tol, PHASE1_TOL))
        core = _ipm_core(problem.C, problem.b, op, adj, schur, o1, t_start, phase1=objective is not None)
        t = float(problem.full(core.y)[-1])
        it1 = core.iterations
        _add_timings(timings, core.timings)
        V1 = problem.variables_at(core.y)
        out = dict(V=dict(zip(problem.names, V1)), value=float("nan"), lower=float("nan"), t=t,
                   t_upper=core.upper, X=dict(zip(names, core.X)), phase1_iterations=it1, status=core.status,
                   iterations=done + it1, primal_residual=core.primal_residual, dual_residual=0.0, gap=core.gap)
        scale = max(1.0, max(float(np.abs(c).max()) for c in problem.C))
        if core.status in ("optimal", "inaccurate", "stalled") and core.upper < -INFEASIBLE_T * scale \
                and core.primal_residual < 1e-6:
            out["status"] = "infeasible"
        elif objective is not None and t > 0:
            two = problem.at(core.y, objective)
            op2, adj2, schur2 = two.ops(o.dense)
            offset = _offset(two, objective)
            xst = _x_start(adj2, two.b, two.C)
            o2 = o if o.objective_max_iter is None else dataclasses.replace(o, max_iter=o.objective_max_iter)
            core2 = _ipm_core(two.C, two.b, op2, adj2, schur2, o2, t_start, feasible_start=True,
                              x_start=xst, offset=offset)
            _add_timings(timings, core2.timings)
            out.update(_objective_answer(two, core2, offset, names, it1, done + it1))
        elif objective is not None:
            out["status"] = "no_interior"  # phase 1 found no t > 0 and no certificate either
    return _grouped_solution(problem, out, timings, t_start)


def _offset(two: GroupedLMI, objective: dict) -> float:
    """``<c, V0>``: the objective form's value is ``offset - b^T y``."""
    c_full = np.concatenate([np.broadcast_to(np.asarray(objective.get(nm, 0.0), dtype=np.float64), sh).ravel()
                             for nm, sh in zip(two.names, two.shapes)])
    return float(c_full @ np.concatenate([v.ravel() for v in two.V0]))


def _add_timings(total: dict, part: dict) -> None:
    for key in ("assembly", "factorization", "line_search"):
        total[key] += part[key]


def _objective_answer(two: GroupedLMI, core: _Core, offset: float, names: list, it1: int,
                      before: int | None = None) -> dict:
    """The :class:`GroupedSolution` fields of an objective solve (``it1``: phase-1 iterations before it,
    ``before``: all iterations before it)."""
    return dict(V=dict(zip(two.names, two.variables_at(core.y))), value=offset - float(two.b @ core.y),
                lower=offset - core.upper, X=dict(zip(names, core.X)), status=core.status, phase1_iterations=it1,
                iterations=(it1 if before is None else before) + core.iterations, dual_residual=0.0,
                primal_residual=core.primal_residual, gap=core.gap)


def _grouped_solution(problem: GroupedLMI, out: dict, timings: dict, t_start: float) -> GroupedSolution:
    timings["total"] = time.perf_counter() - t_start
    timings["other"] = timings["total"] - timings["assembly"] - timings["factorization"] - timings["line_search"]
    out["V"] = {k: (float(v[0, 0]) if k in problem.scalar_names else v) for k, v in out["V"].items()}
    return GroupedSolution(timings=timings, **out)
