"""One interior-point path that follows the decay rate (docs/design.md §3.2.2, "The rate-following path").

The ``lmi`` design SDP in the congruent form (:func:`solver.ipm.design_blocks.lmi_problem`) has data
``c_s free_s``, ``c_s coef_s`` with ``c_s = lambda^(-eta_s)``: one problem per rate, all of one shape and one
basis, so an iterate ``(y, X)`` of one rate is an iterate of every other.  :func:`follow_rate` runs the
interior-point iteration of :mod:`solver.ipm.algorithm` once and moves lambda between its iterations (the
``retarget`` hook of :class:`solver.ipm.algorithm.IPMOptions`), towards the rate its caller's ``aim`` names:

* the **primal** iterate ``(W, Y)`` certifies, in closed form, every rate from
  ``lambda_V = max_s sigma_max(W^(-1/2) M_s W^(-1/2))^(1/eta_s)`` up (``M_s = free_s W + coef_s Y``: the block
  ``[[W, c M^T], [c M, W]]`` is positive semidefinite iff ``c sigma_max <= 1``); the smallest seen is the
  bracket's upper end;
* the **dual** iterate at lambda is a Farkas candidate for lambda once ``<C, X> < 0`` with the primal residual
  below ``feas_tol`` (a sign rule, ``SIGN_T``), and with its off-diagonal blocks scaled, for every rate up to
  :func:`refuted_rate`; the lower end is ``REFUTE_SHARE`` of the way there, with the multipliers scaled to it.

At a large change of rate (``KEEP_FROM``) the slacks stay as they are and the iteration carries the new data's dual
residual ``S - C' - A'(y)`` (:attr:`IPMOptions.retarget`), which the next Newton step removes while it moves towards
the new rate's central path (a tangent predictor and its corrector in one step, with the step's own Schur factor).
At a small one the slacks keep their distance to the boundary (``t`` moves by the change of the blocks'
smallest eigenvalue) and the multipliers' off-diagonal blocks are multiplied by ``c_s / c'_s``, which leaves
``A^*(X)`` and ``<C, X>`` unchanged: the primal residual and the dual bound carry over exactly.  Up in rate,
where that leaves the cone, the multipliers are combined with an earlier iterate's from above (:func:`_raise`):
residual and bound are then the combination's (the residual no larger than the larger of the two).  Which rates are certified and which are refuted is decided afterwards by the
design's own float64 re-check and Farkas re-check (solver/rate_search.py); this module only finds candidates.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .algorithm import IPMOptions, _cholesky, _eigvalsh, _inv, _ipm_core
from .blas import blas_threads, heap_reuse
from .design_blocks import _check_data, _gain_L, _gain_scale, lmi_problem
from .schur import dense_ops

__all__ = ["RatePathResult", "follow_rate", "certified_rate", "refuted_rate"]


@dataclass
class RatePathResult:
    """What :func:`follow_rate` found (candidates: the caller re-checks both ends).

    Attributes
    ----------
    status : str
        ``"stopped"`` (``done(lo, hi)`` held) or the interior-point status where the path ended otherwise.
    lo : float
        The lower end: the largest of ``REFUTE_SHARE`` of the way (in ``ln lambda``) from the rate of an iterate whose
        multipliers passed the sign rule to its :func:`refuted_rate` (0: none).
    hi : float
        The smallest rate certified by a primal iterate, :func:`certified_rate` (inf: none).
    W, Y : ndarray or None
        The primal iterate of ``hi`` in the design's coordinates: ``W`` (n, n), ``Y`` (J, m, n).
    X_hi : ndarray or None, shape (S, 2n, 2n)
        The multipliers of that iterate, at its own rate (a warm start for a nearby rate).
    hi_at : tuple or None
        ``(lambda, t)``: that iterate's own rate and margin (its multipliers' scale and the margin model's
        ``t0``, :func:`solver.rate_search.margin_model`).
    duals : ndarray or None, shape (S, 2n, 2n)
        The multipliers of ``lo`` (at rate ``lo``, ``sum_b tr = 1``): the refuting iterate's, their off-diagonal
        blocks scaled from its own rate to ``lo`` (:func:`refuted_rate`).
    lo_at : tuple or None
        ``(lambda, t, upper)``: the refuting iterate's own rate, margin and dual bound (``upper < 0``).
    refutes : list of tuple
        ``(iteration, lambda, refuted_rate)`` of every iterate that passed the sign rule.
    earlier : list of tuple
        ``(rate, W, Y, X, (lambda, t))`` of the iterates that certified the upper end before the last one (at most
        ``KEEP_EARLIER``, the latest first; ``Y`` in the design's coordinates): less converged, better centred,
        for the re-check when the last one's margin is below its resolution (the paper example's).
    iterations : int
        Newton steps (each one Schur complement, as an iteration of a plain solve).
    retargets : int
        Changes of rate.
    rates : list of tuple
        ``(iteration, lambda, t, upper, primal residual)`` at each iterate.
    seconds : float
    """

    status: str
    lo: float = 0.0
    hi: float = math.inf
    W: np.ndarray | None = None
    Y: np.ndarray | None = None
    X_hi: np.ndarray | None = None
    hi_at: tuple | None = None
    duals: np.ndarray | None = None
    lo_at: tuple | None = None
    refutes: list = field(default_factory=list)
    earlier: list = field(default_factory=list)
    iterations: int = 0
    retargets: int = 0
    rates: list = field(default_factory=list)
    seconds: float = 0.0


def certified_rate(W: np.ndarray, M: np.ndarray, eta: np.ndarray, below: float | None = None) -> float:
    """``max_s sigma_max(L^-1 M_s L^-T)^(1/eta_s)`` (``W = L L^T``): the smallest rate ``(W, Y)`` certifies.

    Parameters
    ----------
    W : ndarray, shape (n, n)
    M : ndarray, shape (S, n, n)
        ``M_s = free_s W + coef_s Y`` without the rate's scale.
    eta : ndarray, shape (S,)
        Interval lengths.
    below : float, optional
        Only a rate below this one is wanted (the path's certified end): when some ``I - c_s^2 K_s K_s^T``
        (``c_s = below^-eta_s``, ``K_s = L^-1 M_s L^-T``) is not positive definite, i.e. the rate is not below
        ``below``, inf is returned without the eigenvalues (a batched Cholesky costs 1/40 of them at n = 8: the
        iterates that do not lower the end, most of those converging at a fixed rate, cost a fraction of a step).

    Returns
    -------
    float
        inf when ``W`` is not positive definite.
    """
    # (the gufuncs without numpy.linalg's wrappers: this runs at every iterate of the path)
    with np.errstate(invalid="ignore"):
        L = _cholesky(0.5 * (W + W.T)[None])[0]
    if not np.isfinite(L[-1, -1]):  # not positive definite (a failed factor is NaNs)
        return math.inf
    Li = _inv(L)
    K = Li @ M @ Li.T
    KK = K @ np.swapaxes(K, 1, 2)
    if below is not None and math.isfinite(below) and below > 0.0:
        c2 = (float(below) ** (-2.0 * np.asarray(eta, dtype=np.float64)))[:, None, None]
        with np.errstate(invalid="ignore"):
            F = _cholesky(np.eye(W.shape[0]) - c2 * KK)
        if not np.all(np.isfinite(F[:, -1, -1])):
            return math.inf
    sig2 = _eigvalsh(KK)[:, -1]
    if not np.all(np.isfinite(sig2)):
        return math.inf
    return float(np.max(np.maximum(sig2, 0.0) ** (0.5 / eta)))


def refuted_rate(X: np.ndarray, eta: np.ndarray, lam: float) -> float:
    """The largest rate the multipliers ``X`` of rate ``lam`` carry to: the dual counterpart of :func:`certified_rate`.

    At rate ``lambda'`` the multipliers with their off-diagonal blocks scaled by ``r_s = c_s / c'_s =
    (lambda' / lam)^eta_s`` keep ``A^*(X)`` and ``<C, X>`` (docs/design.md §3.2.2); the block ``[[X11, r X12],
    [r X21, X22]]`` stays positive semidefinite iff ``r sigma_max(L22^-1 X21 L11^-T) <= 1`` (``X_ii = L_ii
    L_ii^T``).  So multipliers whose dual bound ``<C, X>`` is negative at ``lam`` refute every rate up to
    ``lam min_s sigma_s^(-1/eta_s)`` (and every rate below ``lam``, where ``r_s <= 1``), with the same primal
    residual.

    Parameters
    ----------
    X : ndarray, shape (S, 2n, 2n)
        The multipliers at rate ``lam`` (the block order of :func:`solver.ipm.design_blocks.lmi_problem`).
    eta : ndarray, shape (S,)
        Interval lengths.
    lam : float

    Returns
    -------
    float
        ``lam`` when some diagonal block is not positive definite (no room to scale); inf when every
        off-diagonal block vanishes.
    """
    n = X.shape[1] // 2
    with np.errstate(invalid="ignore"):
        L1 = _cholesky(0.5 * (X[:, :n, :n] + np.swapaxes(X[:, :n, :n], 1, 2)))
        L2 = _cholesky(0.5 * (X[:, n:, n:] + np.swapaxes(X[:, n:, n:], 1, 2)))
    if not (np.all(np.isfinite(L1[:, -1, -1])) and np.all(np.isfinite(L2[:, -1, -1]))):
        return float(lam)
    K = _inv(L2) @ X[:, n:, :n] @ np.swapaxes(_inv(L1), 1, 2)
    sig2 = _eigvalsh(K @ np.swapaxes(K, 1, 2))[:, -1]
    if not np.all(np.isfinite(sig2)):
        return float(lam)
    eta = np.asarray(eta, dtype=np.float64)
    with np.errstate(divide="ignore"):
        room = np.where(sig2 > 0.0, np.maximum(sig2, 1e-300) ** (-0.5 / eta), math.inf)
    return float(lam * np.min(room))


@dataclass
class _Data:
    """The constant blocks ``C`` (nb, k, k) of the SDP at one rate (the dense path's stand-in for a BlockLMI)."""

    C: np.ndarray


class _RateFamily:
    """The ``lmi`` SDP at any rate: ``C``, ``op``, ``adj``, ``schur`` for ``c_s = lambda^(-eta_s)``."""

    def __init__(self, free, coef, active, eta, dense: bool | None):
        self.free, coef, self.active = _check_data(free, coef, active)
        self.coef, self.gscale = _gain_scale(coef)
        self.eta = np.asarray(eta, dtype=np.float64)
        self.GL = _gain_L(self.coef, self.active)  # (S, n, J m)
        self.plan = None
        self.T = None
        base = lmi_problem(self.free, self.coef, self.active)
        self.base = base
        self.dense = dense if dense is not None else (base.p * base.nb * base.k**2 <= 60000)
        if self.dense:  # the operator and the constant are affine in c per block: A(c) = A0 + c_b A1
            zero = lmi_problem(0.0 * self.free, 0.0 * self.coef, self.active)
            A0 = zero.dense_operator()
            self.A0, self.A1 = A0, base.dense_operator() - A0
            self.C0, self.C1 = zero.C, base.C - zero.C

    def at(self, lam: float):
        c = float(lam) ** (-self.eta)
        if self.dense:  # (no BlockLMI per rate: the paper example's moves cost more than its Newton steps)
            prob = _Data(self.C0 + c[:, None, None] * self.C1)
            op, adj, schur = dense_ops(self.A0 + c[None, :, None, None] * self.A1)
            return prob, c, op, adj, schur
        prob = lmi_problem(self.free * c[:, None, None], self.coef * c[:, None, None, None], self.active)
        if self.plan is not None:
            prob._schur_plan = self.plan
        op, adj = prob.op, prob.adj

        def schur(X, G, prob=prob):
            M = prob.schur(X, G, upper=True)
            self.plan = prob.__dict__.get("_schur_plan")
            return M
        return prob, c, op, adj, schur

    def variables(self, y):
        """``W`` and the scaled ``Y`` stack (J m, n) at ``y`` (the basis is every rate's)."""
        prob = self.base
        if self.T is None:
            # the basis as a dense matrix where it is small (a sparse product per iterate cost as much as the
            # paper example's Newton step)
            self.T = prob.T.toarray() if prob.T.shape[0] * prob.T.shape[1] <= 250000 else prob.T
        x = self.T @ y
        n = self.free.shape[1]
        W = prob.V0[0] + x[prob.slices[0]].reshape(n, n)
        Y = x[prob.slices[1]].reshape(-1, n) if len(prob.slices) > 1 else np.zeros((0, n))
        return 0.5 * (W + W.T), Y

    def M(self, W, Y):
        return self.free @ W + (self.GL @ Y if Y.size else 0.0)


def _raise(X2, Xb, up, new, c2, above, n):
    """The multipliers at a higher rate ``new`` (docs/design.md §3.2.2).

    ``X2`` (the current multipliers ``Xb`` with their off-diagonal blocks scaled by ``c / c'``) keeps ``A^*(X)``
    and ``<C, X>`` but can leave the cone where ``c / c' > 1`` (the blocks ``up``).  The multipliers of an earlier
    iterate at a rate ``lambda_a >= new`` with primal residual below 1e-6, scaled the same way (``c_a / c' <= 1``:
    they stay positive semidefinite), keep their own ``A^*(X_a)`` and ``<C, X_a>`` (those of that earlier
    iterate, not ``X2``'s).  The combination ``theta X2 + (1 - theta) X_a`` with the largest ``theta`` in 1/2,
    1/4, ... whose smallest eigenvalues keep ``1e-3 (1 - theta)`` of ``X_a``'s is taken: its primal residual and
    dual bound are the same combination of the two iterates' (exactly ``X2``'s only at ``theta = 1``, i.e. when
    ``X2`` stays in the cone); the residual stays below the larger of the two.  Without such an iterate a block
    that would lose definiteness keeps its multiplier (its residual changes).

    Parameters
    ----------
    X2, Xb : ndarray, shape (S, 2n, 2n)
    up : ndarray of bool, shape (S,)
        The blocks with ``c / c' > 1``.
    new : float
        The new rate.
    c2 : ndarray, shape (S,)
        Its scales ``new^(-eta_s)``.
    above : list of tuple
        ``(lambda_a, c_a, X_a)`` of earlier iterates.
    n : int

    Returns
    -------
    ndarray, shape (S, 2n, 2n)
    """
    eye = np.eye(X2.shape[1])

    def above_floor(Z, floor):
        # lambda_min(Z_b) > floor_b per block, by a batched Cholesky of Z_b - floor_b I (a twelfth of the
        # eigenvalues' cost per trial at n = 8, where one move up with its trials cost as much as three steps)
        with np.errstate(invalid="ignore"):
            return np.isfinite(_cholesky(Z - floor[:, None, None] * eye)[:, -1, -1])

    floor = 1e-3 * _eigvalsh(Xb[up])[:, 0]
    ok = above_floor(X2[up], floor)
    if bool(ok.all()):
        return X2
    cand = [a for a in above if a[0] >= new]
    if cand:
        lam_a, c_a, X_a = min(cand, key=lambda a: a[0])
        Xa = X_a.copy()
        ra = (c_a / c2)[:, None, None]
        Xa[:, n:, :n] *= ra
        Xa[:, :n, n:] *= ra
        floor_a = 1e-3 * _eigvalsh(Xa[up])[:, 0]
        theta = 1.0
        for _ in range(12):
            theta *= 0.5
            Z = theta * X2 + (1.0 - theta) * Xa
            # the other blocks combine two positive semidefinite matrices
            if bool(above_floor(Z[up], (1.0 - theta) * floor_a).all()):
                return Z
        return Xa
    bad = np.zeros(len(X2), dtype=bool)
    bad[up] = ~ok
    X2[bad] = Xb[bad]
    return X2


#: The sign rule of a refuted rate: ``<C, X> < 0``, primal residual below ``feas_tol`` and ``t >= SIGN_T <C, X>``
#: (the probes' rule, :attr:`IPMOptions.sign_only`).
SIGN_T = 16.0
#: The lower end is this share (in ``ln lambda``) of the way from the refuting iterate's rate to its
#: :func:`refuted_rate` (below it every scaled block keeps room).
REFUTE_SHARE = 0.9
#: :attr:`RatePathResult.earlier`: how many earlier certifying iterates are kept for the re-check.
KEEP_EARLIER = 4
#: A change of rate that changes some ``c_s`` by at least ``KEEP_FROM`` (relative) keeps the slacks and lets the next
#: Newton step remove the new data's dual residual (docs/design.md §3.2.2); smaller ones shift the slacks by ``t``.
#: Measured (path Newton steps; all moves / none / from 0.1): the 21 test families 680 / 578 / 573, paper 35 / 24 /
#: 25, n = 8 48 / 48 / 45, n = 20 63 / 69 (no closed bracket: rp stalled at 5e-8) / 65, n = 50 42 / 44 / 44.
KEEP_FROM = 0.1
#: At a large move down in rate the multipliers are blended with ``I / N`` by this share (docs/design.md §3.2.2).
#: Measured (path Newton steps, paper / n = 8 / 12 / 20 / 30 / 50; 0 against 0.65): 25 / 43 / 68 / 63 / 60 / 44
#: against 25 / 44 / 47 / 54 / 48 / 44, the 21 test families 369 against 370; 0.5: 24 / 42 / 47 / 61 / 58, families
#: 399; 0.8: 25 / 45 / 68 / 56 / 44.
BLEND_LARGE = 0.65


def _prune_above(above: list, hi: float) -> list:
    """The entries of ``above`` that :func:`_raise` can still use at a new rate ``<= hi``: those below ``hi`` and the
    one with the smallest ``lambda_a >= hi`` (``hi``: the path's certified end, which only decreases)."""
    over = [a for a in above if a[0] >= hi]
    keep = [a for a in above if a[0] < hi]
    if over:
        keep.append(min(over, key=lambda a: a[0]))
    return keep


def follow_rate(free, coef, active, eta, done, aim, lam0: float = 1.0, time_limit: float | None = None,
                max_iter: int = 200, feas_tol: float = 1e-8, dense: bool | None = None) -> RatePathResult:
    """Follow the rate along one interior-point path until ``done(lo, hi)`` (module docstring).

    Parameters
    ----------
    free : array_like, shape (S, n, n)
    coef : array_like, shape (S, J, n, m)
    active : array_like of bool, shape (S, J), or None
    eta : array_like, shape (S,)
        Interval lengths: the block of mode s is scaled by ``lambda^(-eta_s)``.
    done : callable
        ``done(lo, hi) -> bool``: the bracket is closed.
    aim : callable
        ``aim(lam, t, upper, rp, q, lo, hi, W, M) -> float or None``: the next rate (None: keep ``lam``), from
        the iterate's margin ``t``, dual bound ``upper``, primal residual ``rp``, the per-block slopes
        ``q_b = <X_b, Off_b> / sum tr X`` (:func:`solver.rate_search.margin_model`'s ``q``), the bracket so far
        and the iterate's ``W`` (n, n) and ``M`` (S, n, n) (as in :func:`certified_rate`).  Called at most once
        per Newton step.
    lam0 : float
        The first rate.
    time_limit : float, optional
    max_iter : int
    feas_tol : float
        The sign rule's primal residual.
    dense : bool, optional
        The interior-point method's dense-operator choice (default: by size).

    Returns
    -------
    RatePathResult
    """
    start = time.perf_counter()
    fam = _RateFamily(free, coef, active, eta, dense)
    n = fam.free.shape[1]
    out = RatePathResult(status="max_iterations")
    st = {"lam": float(lam0), "it": 0, "above": [], "kept": False}
    st["prob"], st["c"], op, adj, schur = fam.at(lam0)
    st["op"] = op

    def op_now(y):
        return st["op"](y)

    def wrap(op, adj, schur):
        return [st["prob"].C], (lambda y: [op(y)]), (lambda U: adj(U[0])), (lambda X, G: schur(X[0], G[0]))

    def refute(lam, t, upper, rp, Xb):
        # the sign rule at lam; the multipliers, their off-diagonal blocks scaled, refute every rate up to
        # refuted_rate (A^*(X) and <C, X> unchanged): the lower end is taken REFUTE_SHARE of the way there (in
        # ln lambda), where every block keeps room, with the multipliers scaled to it
        if not (upper < 0.0 and rp < feas_tol and t >= SIGN_T * upper):
            return
        top = min(refuted_rate(Xb, fam.eta, lam), 1.0)
        new = lam * (top / lam) ** REFUTE_SHARE if top > lam else lam
        out.refutes.append((st["it"], lam, top))
        if new > out.lo:
            r = ((new / lam) ** fam.eta)[:, None, None]
            Z = Xb.copy()
            Z[:, n:, :n] *= r
            Z[:, :n, n:] *= r
            out.lo, out.duals, out.lo_at = new, Z, (lam, t, upper)

    def retarget(y, X, S, upper, t, rp):
        st["it"] += 1
        lam, c = st["lam"], st["c"]
        Xb = X[0]
        if st.get("moved"):
            # the re-entry after a change of rate: the same W, Y (only t moved) certify the same rate; the
            # multipliers may refute the new one
            st["moved"] = False
            out.rates.append((st["it"], lam, float(t), float(upper), float(rp)))
            refute(lam, float(t), float(upper), float(rp), Xb)
            return "stop" if done(out.lo, out.hi) else None
        W, Y = fam.variables(y)
        M = fam.M(W, Y)
        out.rates.append((st["it"], lam, float(t), float(upper), float(rp)))
        cert = certified_rate(W, M, fam.eta, below=out.hi)
        if cert < out.hi:
            if out.W is not None:
                out.earlier = [(out.hi, out.W, out.Y, out.X_hi, out.hi_at)] + out.earlier[:KEEP_EARLIER - 1]
            out.hi, out.W, out.Y, out.X_hi, out.hi_at = cert, W, Y, Xb.copy(), (lam, float(t))
        refute(lam, float(t), float(upper), float(rp), Xb)
        if done(out.lo, out.hi):
            return "stop"
        trX = float(np.trace(Xb, axis1=1, axis2=2).sum())
        q = 2.0 * c * np.einsum("bij,bij->b", Xb[:, n:, :n], M) / max(trX, 1e-300)
        new = aim(lam, float(t), float(upper), float(rp), q, out.lo, out.hi, W, M)
        if new is None or not np.isfinite(new) or new <= 0.0 or abs(math.log(new / lam)) < 1e-12:
            return None
        prob2, c2, op2, adj2, schur2 = fam.at(new)
        # a residual left by an earlier large move (S is not C + A(y) yet): keep the slacks, carry the new data's
        # (one max instead of np.allclose: this runs at every move, and allclose's overhead showed on the paper size;
        # only after a move that kept the slacks: otherwise the loop set S = C + A(y), and the check, an operator
        # application, cost 2 ms of the path's moves at n = 8)
        pending = False
        if st["kept"]:
            pending = bool(np.max(np.abs(S[0] - st["prob"].C - op_now(y))) > 1e-12 * float(np.abs(S[0]).max()))
            st["kept"] = pending
        # the multipliers' off-diagonal blocks scale by c / c' (A^*(X) and <C, X> unchanged) when that keeps them
        # positive definite, else combined with an earlier iterate's from above (_raise)
        ratio = (c / c2)[:, None, None]
        X2 = Xb.copy()
        X2[:, n:, :n] *= ratio
        X2[:, :n, n:] *= ratio
        up = ratio[:, 0, 0] > 1.0
        if up.any():
            X2 = _raise(X2, Xb, up, new, c2, st["above"], n)
        if rp < 1e-6:
            st["above"].append((lam, c, Xb.copy()))
        st["above"] = _prune_above(st["above"], out.hi)
        st["lam"], st["prob"], st["c"], st["op"] = float(new), prob2, c2, op2
        out.retargets += 1
        st["moved"] = True
        C2, o2, a2, s2 = wrap(op2, adj2, schur2)
        if pending or float(np.max(np.abs(c2 / c - 1.0))) >= KEEP_FROM:
            # the iterate stays as it is, centred: the new data's dual residual is carried by the iteration
            # (IPMOptions.retarget) and the next Newton step aims at the new rate's central path (the primal
            # residual kept)
            st["kept"] = True
            if BLEND_LARGE > 0.0 and not up.any():
                # down in rate (the first move from lambda = 1): the multipliers of a near-optimum are badly centred
                # for the new data (X_b S_b ~ 0), blended with I / N as the probes' warm starts are (I / N is primal
                # feasible at every rate: the residual shrinks by 1 - BLEND_LARGE, the dual bound changes); up in
                # rate _raise's multipliers are kept
                X2 = (1.0 - BLEND_LARGE) * X2 + BLEND_LARGE * np.eye(X2.shape[1]) / (X2.shape[0] * X2.shape[1])
            return C2, o2, a2, s2, np.array(y, dtype=np.float64), [X2], [S[0]]
        # the slacks keep their smallest eigenvalue (t moves with the blocks')
        y2 = np.array(y, dtype=np.float64)
        lmin_old = float(_eigvalsh(S[0])[:, 0].min())
        y2[-1] = 0.0
        B2 = prob2.C + op2(y2)
        y2[-1] = float(_eigvalsh(B2)[:, 0].min()) - lmin_old
        return C2, o2, a2, s2, y2, [X2]

    o = IPMOptions(max_iter=max_iter, time_limit=time_limit, retarget=retarget, gap_tol=0.0, feas_tol=0.0)
    large = fam.base.n_full**2 > 2**20
    with blas_threads(o.threads), heap_reuse(large):
        C, op1, adj1, schur1 = wrap(op, adj, schur)
        core = _ipm_core(C, fam.base.b, op1, adj1, schur1, o, start)
    out.status = core.status
    out.iterations = max(st["it"] - out.retargets - 1, 0)  # a change of rate re-enters the loop without a step
    J, m = fam.coef.shape[1], fam.coef.shape[3]

    def unscaled(Y):
        return Y.reshape(J, m, n) / fam.gscale[:, None, None] if J * m else np.zeros((0, 0, n))

    if out.Y is not None:
        out.Y = unscaled(out.Y)
    out.earlier = [(r, W, unscaled(Y), X, at) for r, W, Y, X, at in out.earlier]
    out.seconds = time.perf_counter() - start
    return out
