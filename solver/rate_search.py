"""The best decay rate as a root of the SDP's margin (docs/design.md, "Rate search").

The congruent rate SDP of ``lmi`` and ``switched`` (solver/methods/lmi.py) has an optimal margin
``t(lambda)`` that grows with lambda; the best certifiable rate is its root.  By the envelope theorem
the dual multipliers ``Z_b`` of one solve give the margin's slope at that rate, and more: the whole
first-order model

    m(lambda) = t0 + sum_b q_b ((lambda0 / lambda)^eta_b - 1),   q_b = <Z_b, Off_b>

(``Off_b`` the block's off-diagonal part ``c_s M_s`` at the solution, the only part that depends on
lambda, through ``c_s = lambda^(-eta_s)``) is exact for the solution's own variables and tangent to
``t`` at ``lambda0``.  It is affine in ``c`` (one interval length: Newton's step on ``t(c)``).
:func:`next_rate` alternates its root (above the true root where ``t`` is convex) with a rate aimed just below
the root, inside the bisection's bracket ``[lo, hi]`` (``hi``: a certified rate, ``lo``: a rate with no certified
design); a candidate outside the bracket, or steps that do not halve it, hand over to the bisection's midpoint.
Which rates are accepted (float64 re-check) and which lower ends are proven (Farkas) is the bisection's rule
unchanged; only the order in which rates are tried differs, hence the same certified rate to the tolerance.

:func:`path_search` (docs/design.md §3.2.2) replaces the probes by one interior-point path that follows the rate
(:mod:`solver.ipm.rate_path`): where its iterate moves the rate next; the probes stay its fallback.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq

__all__ = ["carry_multipliers", "margin_model", "model_root", "network_margin_model", "next_rate", "path_search",
           "rate_measure", "rate_shift", "rebase_model"]

#: Rates below this are not searched (``c_s = lambda^(-eta_s)`` would overflow the conditioning).
MIN_RATE = 1e-4



def rate_measure(lam: float, settling: bool) -> float:
    """The coordinate the rate tolerance is on (docs/design.md §3.2.2, "Where the rate goes").

    ``-ln(-ln lambda)`` (the settling time's logarithm, up to sign; ``decay_rate="auto"``) with lambda clamped to
    ``[MIN_RATE, 1 - 1e-9]``, else ``ln lambda`` (``-inf`` at lambda = 0).

    Parameters
    ----------
    lam : float
        The decay rate, in [0, 1].
    settling : bool

    Returns
    -------
    float
    """
    if settling:
        return -math.log(-math.log(min(max(lam, MIN_RATE), 1.0 - 1e-9)))
    return math.log(lam) if lam > 0.0 else -math.inf


def rate_shift(lam: float, du: float, settling: bool) -> float:
    """The rate ``du`` above ``lam`` in :func:`rate_measure`'s coordinate (its inverse at ``measure(lam) + du``)."""
    u = rate_measure(lam, settling) + du
    return math.exp(-math.exp(-u)) if settling else math.exp(u)


def rate_done(lo: float, hi: float, tol: float, settling: bool) -> bool:
    """Whether the bracket ``[lo, hi]`` meets the tolerance: ``hi - lo <= tol hi``, or (``settling``) the settling
    times ``-1/ln lambda`` of its ends within ``1 + tol`` (ends clamped as in :func:`rate_midpoint`, so a bracket
    pinned at ``hi = 1`` ends too once ``lo`` is within 1e-9 of 1: no certified rate below 1)."""
    if not settling:
        return hi - lo <= tol * hi
    return -math.log(max(lo, MIN_RATE)) <= (1 + tol) * -math.log(min(hi, 1 - 1e-9))


def rate_midpoint(lo: float, hi: float, settling: bool) -> float:
    """The bisection's next rate: the middle, or (``settling``) the geometric mean of ``-ln lambda`` between the
    ends (``hi = 1`` and ``lo = 0`` replaced by ``1 - 1e-9`` and ``MIN_RATE``)."""
    if settling:
        s_hi, s_lo = -math.log(min(hi, 1 - 1e-9)), -math.log(max(lo, MIN_RATE))
        return math.exp(-math.sqrt(s_hi * s_lo))
    return 0.5 * (lo + hi)


def carry_multipliers(X: np.ndarray, eta: np.ndarray, lam: float, new: float) -> np.ndarray | None:
    """The multipliers ``X`` of rate ``lam`` carried to rate ``new`` (docs/design.md §3.2.1, "Probes start warm").

    The off-diagonal blocks are multiplied by ``c_s / c'_s = (new / lam)^eta_s``, which keeps ``A^*(X)`` and
    ``<C, X>`` (§3.2.2): a primal-feasible ``X`` at ``lam`` stays primal feasible at ``new``, so a warm start
    blended with ``I / N`` (primal feasible at every rate) starts with the old solve's residual instead of the
    change of data's (0.03-0.1 measured: the sign rule's ``1e-8`` then took most of a refuted probe's iterations).

    Parameters
    ----------
    X : ndarray, shape (S, 2n, 2n)
        The multipliers of rate ``lam`` (:func:`solver.ipm.design_blocks.lmi_problem`'s block order).
    eta : ndarray, shape (S,)
    lam, new : float

    Returns
    -------
    ndarray or None
        None when a scaled block is not positive semidefinite (up in rate, beyond
        :func:`solver.ipm.rate_path.refuted_rate`): the caller keeps ``X`` as it is.
    """
    X = np.array(X, dtype=np.float64)
    if X.ndim != 3 or X.shape[1] != X.shape[2] or X.shape[1] % 2 or X.shape[0] != np.size(eta):
        return None
    n = X.shape[1] // 2
    r = (float(new) / float(lam)) ** np.asarray(eta, dtype=np.float64)
    X[:, n:, :n] *= r[:, None, None]
    X[:, :n, n:] *= r[:, None, None]
    if np.any(r > 1.0):
        floor = 1e-12 * float(np.abs(X).max())
        if float(np.linalg.eigvalsh(X[r > 1.0])[:, 0].min()) < -floor:
            return None
    return X


#: :func:`next_rate` raises a rate to certify to the tolerance's end above ``lo`` when it lies below that end
#: or above it by at most this fraction of ``end - lo``.
CLOSE_HIGH_SLACK = 0.25
#: :func:`next_rate`'s first step from the first certified end with no failed rate yet: the Newton root.
FIRST_NEWTON = True


def margin_model(modes, sdp, rate: float):
    """``(t0, q, eta)`` of the first-order model at ``rate`` from one solve, or None.

    Parameters
    ----------
    modes : solver.network.ModeSet
    sdp : solver.compiled.DesignSdpSolution
        The congruent SDP's solution at ``rate`` (``W``: W of ``lmi`` or Z of ``switched``; ``duals``).
    rate : float
        lambda in (0, 1].

    Returns
    -------
    tuple or None
        ``t0`` (float), ``q`` (ndarray, shape (B,), one per block), ``eta`` (ndarray of int, shape (B,)),
        or None when the solve carries no usable multipliers.
    """
    Z = getattr(sdp, "duals", None)
    if Z is None or sdp.W is None or not np.isfinite(sdp.t):
        return None
    Z = np.asarray(Z, dtype=np.float64)
    S, n = modes.n_modes, modes.n_states
    if Z.ndim != 3 or Z.shape[1] != 2 * n or Z.shape[0] % S or not np.all(np.isfinite(Z)):
        return None
    coef, active = modes.scheme_coef()
    c = float(rate) ** (-modes.eta.astype(float))
    M = modes.free @ sdp.W  # (S, n, n): A_s W without the scale
    if coef.size and sdp.Y is not None and np.size(sdp.Y):
        M = M + np.einsum("sjnm,jmk->snk", coef * np.asarray(active, dtype=float)[:, :, None, None], sdp.Y)
    per = Z.shape[0] // S  # lmi: one block per mode; switched: S blocks (s, u) for mode s
    s_of = np.repeat(np.arange(S), per)
    # <Z_b, [[0, (c M)^T], [c M, 0]]> = 2 c tr(Z_b[n:, :n]^T M)
    q = 2.0 * c[s_of] * np.einsum("bij,bij->b", Z[:, n:, :n], M[s_of])
    if not np.all(np.isfinite(q)):
        return None
    return float(sdp.t), q, modes.eta[s_of].astype(float)


def network_margin_model(prob, sdp, rate: float):
    """``(t0, q, eta)`` of the first-order model for the network LMI (:mod:`solver.methods.network_lmi`).

    The same model as :func:`margin_model`: transition e's off-diagonal block ``c_e A_e Z`` is the only part
    that depends on the rate (``c_e = lambda^(-length_e)``), so ``q_e = 2 c_e tr(M_e[k:, :k]^T A_e Z)`` with
    ``M_e`` the transition's multiplier and ``eta_e = length_e``.

    Parameters
    ----------
    prob : solver.methods.network_lmi.NetworkProblem
    sdp : solver.methods.network_lmi.NetworkSolution
        The solve at ``rate`` (its ``multipliers``: one per transition first).
    rate : float

    Returns
    -------
    tuple or None
    """
    multipliers = getattr(sdp, "multipliers", None)
    if multipliers is None or sdp.Z is None or not np.isfinite(sdp.t) or len(multipliers) < prob.n_blocks:
        return None
    k, n, E = prob.k, prob.n, prob.n_blocks
    M = np.stack([np.asarray(X, dtype=np.float64) for X in multipliers[:E]])
    if M.shape[1:] != (2 * k, 2 * k) or not np.all(np.isfinite(M)):
        return None
    Z = np.zeros((k, k))
    for b in range(prob.zblocks):
        Z[b * n:(b + 1) * n, b * n:(b + 1) * n] = sdp.Z[b]
    AZ = prob.free @ Z  # (E, k, k)
    for e in range(E):
        for j in range(prob.N):
            b = prob.right[e, j]
            if b >= 0:
                AZ[e][:, b * n:(b + 1) * n] += prob.coef[e, j] @ sdp.Y[j]
    c = float(rate) ** (-prob.length.astype(float))
    q = 2.0 * c * np.einsum("bij,bij->b", M[:, k:, :k], AZ)
    if not np.all(np.isfinite(q)):
        return None
    return float(sdp.t), q, prob.length.astype(float)


def rebase_model(model, rate: float, new: float):
    """The model of :func:`margin_model` made at ``rate``, written at ``new``: the same function of lambda.

    ``t0 + sum_b q_b ((rate / lambda)^eta_b - 1) = t0' + sum_b q'_b ((new / lambda)^eta_b - 1)`` with
    ``q'_b = q_b (rate / new)^eta_b`` and ``t0' = m(new)``.
    """
    t0, q, eta = model
    r = (float(rate) / float(new)) ** np.asarray(eta, dtype=float)
    return float(t0 + np.sum(q * (r - 1.0))), q * r, eta


def model_root(model, rate: float, lo: float, hi: float) -> float | None:
    """The root of ``m(lambda)`` in ``(lo, hi)`` (a 1-D monotone equation, solved by Brent's method on ln lambda).

    None when the model does not decrease with lambda (no root to aim at) or has no root in the interval.
    """
    t0, q, eta = model
    if not np.any(q < 0):
        return None
    # the blocks' terms summed per interval length (a few distinct eta): plain floats in the root search below
    # (numpy calls per evaluation cost more than the paper example's interior-point iterations)
    powers, inverse = np.unique(np.asarray(eta, dtype=float), return_inverse=True)
    terms = list(zip(powers.tolist(), np.bincount(inverse.ravel(), weights=q, minlength=powers.size).tolist()))
    t0, log_rate = float(t0), math.log(rate)

    def m(u):  # the model at lambda = exp(u): the end points' signs and the root search use this one function
        d = log_rate - u
        return t0 + sum(w * (math.exp(min(e * d, 700.0)) - 1.0) for e, w in terms)

    ua, ub = math.log(max(lo, 1e-12)), math.log(hi)
    ma, mb = m(ua), m(ub)
    if not (ma < 0.0 < mb) and not (ma > 0.0 > mb):
        return None
    # Brent's method (to 1e-12 in ln lambda; ~10 evaluations where a bisection took ~45)
    return math.exp(brentq(m, ua, ub, xtol=1e-12))


def next_rate(lo: float, hi: float, t_lo: float | None, t_hi: float | None, model, done, midpoint,
              from_above: bool = True, previous: tuple | None = None, measure=None,
              model_lo=None, last: str | None = None, tol_width: float | None = None) -> tuple[float, str]:
    """The next rate to try in the bracket ``[lo, hi]`` and how it was chosen (see :func:`_model_step`).

    A rate aimed to be certified (``newton``, ``newton_lo``, ``secant``) that lies below the tolerance's end
    above ``lo`` is raised to that end (``close_high``): more room to certify, and a certified one ends the
    search (n = 50: the Newton root landed 1e-5 below that end, and one more refuted probe followed).
    """
    rate, how = _model_step(lo, hi, t_lo, t_hi, model, done, midpoint, from_above, previous, measure, model_lo,
                            last, tol_width)
    if lo > 0.0 and how in ("newton", "newton_lo", "secant"):
        high_end = _closing_high(lo, hi, done)
        # (also when the rate lies a little above that end: a Newton root lies above the root where the margin
        # is convex; n = 50: 1 % of the bracket above it, and one more refuted probe followed)
        if lo < high_end < hi and rate <= high_end + CLOSE_HIGH_SLACK * (high_end - lo):
            return high_end, "close_high"
    return rate, how


def _model_step(lo: float, hi: float, t_lo: float | None, t_hi: float | None, model, done, midpoint,
                from_above: bool = True, previous: tuple | None = None, measure=None,
                model_lo=None, last: str | None = None, tol_width: float | None = None) -> tuple[float, str]:
    """The next rate to try in the bracket ``[lo, hi]`` and how it was chosen.

    The margin is usually convex in lambda near the root (it flattens towards it), so the Newton root
    of the model at ``hi`` (``newton``) lies above the root: a rate to certify.  The probes alternate
    sides: after a certified rate, a rate aimed just below the root (``below``: the secant's root
    between the margins at ``lo`` and ``hi`` when both are known, or the fixed point of the Newton map
    by a secant through the last two certified ends (Steffensen), or the Newton step mirrored, less half
    the tolerance); after a failed one, ``newton``.  Once the root is within the tolerance of ``hi``,
    ``close`` tries the tolerance's end below ``hi``.  After a refuted rate, the Newton root of the model at
    ``lo`` (``newton_lo``) comes first.  A candidate outside the bracket's inner 96 % (in ``measure``'s
    coordinate; 2 % of at most one unit from each end) is replaced by the bisection's midpoint (``bisect``).

    Parameters
    ----------
    lo, hi : float
        The bracket (``hi`` certified; ``lo`` 0 while no rate failed).
    t_lo, t_hi : float or None
        The SDP's margin at ``lo`` and ``hi`` (None: unknown).
    model : tuple or None
        :func:`margin_model` of the solve at ``hi``.
    done : callable
        ``done(lo, hi)``: whether a bracket is within the tolerance.
    midpoint : callable
        ``midpoint(lo, hi)``: the bisection's next rate.
    from_above : bool
        Whether the last rate tried was certified (it moved ``hi``).
    previous : tuple, optional
        ``(hi', newton')``: the previous certified end and its Newton root.
    model_lo : tuple, optional
        :func:`margin_model` of the solve at ``lo`` (a refuted rate: a converged solve, exact multipliers).
        Its Newton root comes before the model at ``hi``'s and the secant's (which creeps up from below where
        the margin is convex: n = 8, four refuted secant steps), once in a row.
    last : str, optional
        How the previous rate was chosen.
    tol_width : float, optional
        The tolerance's width in ``measure``'s coordinate: the inner margin is at most twice it.
    measure : callable, optional
        An increasing map of the rate to the coordinate the tolerance is on (default: the rate itself).
        The settling search (``decay_rate="auto"``) passes ``-ln(-ln lambda)``: its roots lie next to
        lambda = 1 at large n (0.988 at n = 50), where the inner 96 % of ``[lo, 1]`` in lambda excluded
        every model step and the search bisected from ``[1e-4, 1]`` (four refuted probes, 70 interior-point
        iterations, before the first model step).

    Returns
    -------
    rate : float
    how : {"close", "newton", "secant", "below", "bisect"}
    """
    newton = None if model is None else model_root(model, hi, max(lo, 1e-12), hi)
    low_end = _closing_low(hi, done)
    if newton is not None and done(newton, hi) and low_end > lo:
        return low_end, "close"
    u = measure if measure is not None else (lambda x: x)
    u_lo, u_hi = u(lo), u(hi)
    # (capped: the settling measure puts hi = 1 at 1 - 1e-9, i.e. 20 units up; its differences are log-ratios
    # of settling times, and 2 % of one unit is as far from the ends as a model step needs to keep; and at most
    # twice the tolerance: with lo = 0, 2 % of [0, hi] refused a Newton root 0.4 % below hi for a bisection
    # step to hi / 2, n = 30)
    room = 0.02 * min(u_hi - u_lo, 1.0)
    if tol_width is not None:
        room = min(room, 2.0 * tol_width)

    def inside(c):
        return c is not None and lo < c < hi and u_lo + room < u(c) < u_hi - room

    secant = None
    if lo > 0.0 and t_lo is not None and t_hi is not None and t_lo < 0.0 < t_hi:
        secant = lo + (hi - lo) * (-t_lo) / (t_hi - t_lo)
    newton_lo = None if model_lo is None or lo <= 0.0 else model_root(model_lo, lo, lo, hi)
    if not from_above or newton is None:
        # after a refuted rate: first the Newton root of the model at lo (a converged solve's multipliers: the
        # margin's tangent there); far from the root the margin can be concave (a Newton root then fails);
        # the secant's root lies above the root there
        # (once: a refuted newton_lo says the margin is flat below the root, where its steps shrink linearly)
        # (and only above the secant's root: where the margin is convex the secant's root lies below the root and
        # the tangent's above; below the secant's, the margin is concave there: the paper's example, flat below)
        first = None if last == "newton_lo" or (secant is not None and newton_lo is not None
                                                and newton_lo < secant) else newton_lo
        for cand, how in ((first, "newton_lo"), (newton, "newton"), (secant, "secant")):
            if not from_above and inside(cand):
                return cand, how
        return midpoint(lo, hi), "bisect"
    if FIRST_NEWTON and previous is None and secant is None and inside(newton):
        # the first step from the first probe (lambda = 1, far from the root, where the margin is not yet flat):
        # the mirrored step below overshot the root there (n = 8: 0.44 for a root at 0.78; n = 20: 0.82 for
        # 0.86, 25 interior-point steps to refute), the Newton root is a certified rate close above it
        return newton, "newton"
    below = None
    if previous is not None and previous[1] is not None and previous[0] != hi:
        h1, h2 = previous[1] - previous[0], newton - hi
        if h2 != h1:
            below = hi - h2 * (hi - previous[0]) / (h2 - h1)
    if below is None or not below < newton:
        below = 2.0 * newton - hi
    if secant is not None:
        below = max(below, secant)
    below -= 0.5 * (hi - low_end)
    if inside(below):
        return below, "below"
    if inside(newton):
        return newton, "newton"
    return midpoint(lo, hi), "bisect"


def _closing_high(lo: float, hi: float, done) -> float:
    """The largest ``h`` in ``(lo, hi]`` with ``done(lo, h)`` (to 1e-9 relative, by bisection; ``lo`` when none)."""
    a, b = lo, hi
    if done(lo, hi):
        return hi
    for _ in range(60):
        mid = 0.5 * (a + b)
        if done(lo, mid):
            a = mid
        else:
            b = mid
        if b - a <= 1e-12 * hi:
            break
    return a * (1.0 - 1e-9) if a * (1.0 - 1e-9) > lo else a


def _closing_low(hi: float, done) -> float:
    """The smallest ``lo`` with ``done(lo, hi)`` (to 1e-9 relative, by bisection: ``done`` is monotone in lo)."""
    a, b = 0.0, hi
    for _ in range(60):
        mid = 0.5 * (a + b)
        if done(mid, hi):
            b = mid
        else:
            a = mid
        if b - a <= 1e-12 * hi:
            break
    return b * (1.0 + 1e-9) if b * (1.0 + 1e-9) < hi else b




#: The rate-following path (``RATE_SEARCH = "path"``, docs/design.md §3.2.2) moves to the rate its iterate
#: certifies, less this fraction of the tolerance's width (in the tolerance's coordinate) ...
PATH_BELOW = 0.5
#: ... or to the Newton root of the margin's model (:func:`model_root`) where the iterate settled the margin's sign
PATH_NEWTON = True
#: ... the first move leaves lambda = 1 once the iterate's margin is positive and at least this share of its dual
#: bound (the probes' sign rule; measured 0.25 and 0: more steps on the test families, mixed on the bench rows)
PATH_SETTLED = 0.5
#: ... when that moves the rate by at least this fraction of the width (smaller moves cost a re-centring each).
PATH_MIN_MOVE = 0.125
#: The certified end is re-checked these fractions of the width above the iterate's own rate, the first that
#: passes (room for rounding: at 0.05 the paper's example's re-check failed, its margin 6e-8).
PATH_ABOVE = (0.05, 0.15, 0.3)
#: One SDP-equivalent of the path (``res.solve_count``): this many Newton steps, about a plain design SDP's
#: (the median of a plain design SDP's iterations, measured: paper 10, n = 8 22, 20 45, 30 20, 50 24).
PATH_STEPS_PER_SDP = 22
#: The path's share of the design's ``time_limit``: the probes go on from its certified end in the rest.
PATH_TIME_SHARE = 0.5
#: The path's Newton steps at most (measured: 23-55 on the bench rows; docs/design.md §3.2.2).
PATH_MAX_ITER = 200


def path_search(modes, settling: bool, tol_width: float, done, time_limit: float | None = None):
    """The best rate's bracket from one rate-following interior-point path (:mod:`solver.ipm.rate_path`).

    The path descends by the method of centers: from lambda = 1, after every Newton step the rate moves to
    the one its primal iterate certifies (:func:`solver.ipm.rate_path.certified_rate`) less ``PATH_BELOW``
    of the tolerance's width, until ``done(lo, hi)`` or until the multipliers at the rate reached refute it.

    Parameters
    ----------
    modes : solver.network.ModeSet
    settling : bool
        The tolerance is on ``-ln(-ln lambda)`` (``decay_rate="auto"``), else on ``ln lambda``.
    tol_width : float
        The tolerance's width in that coordinate.
    done : callable
        ``done(lo, hi)``.
    time_limit : float, optional
        The design's limit: the path gets ``PATH_TIME_SHARE`` of it.

    Returns
    -------
    tuple
        ``(path, his)``: the :class:`solver.ipm.rate_path.RatePathResult` and the rates, increasing, at which its
        primal iterate is to be re-checked (the first that passes is the certified end; empty when the path
        certified no rate below 1).
    """
    from .ipm.rate_path import follow_rate

    def shift(lam, du):
        return rate_shift(lam, du, settling)

    def measure(lam):
        return rate_measure(lam, settling)

    def aim(lam, t, upper, rp, q, lo, hi, W, M):
        if not hi < 1.0:
            return None
        if lo >= lam:  # refuted here: up to the middle of the bracket (in the tolerance's coordinate)
            return shift(hi, -0.5 * (measure(hi) - measure(lo)))
        settled = t > 0.0 and rp < 1e-6 and t >= PATH_SETTLED * upper
        if PATH_NEWTON and lam >= 1.0 and not settled:
            return None  # the first move is Newton's, from lambda = 1 once its sign is settled (as the first probe)
        target = min(lam, shift(hi, -PATH_BELOW * tol_width))
        if PATH_NEWTON and lam >= 1.0:
            # the sign is settled here (the probes' rule): the Newton root of the margin's model, above the root
            # where the margin is convex, from the iterate's own margin t (the lower of its bounds)
            newton = model_root((t, q, modes.eta.astype(float)), lam, max(lo, MIN_RATE), lam)
            if newton is not None:
                target = min(target, newton)
        if lo > 0.0:
            target = max(target, shift(lo, 0.25 * tol_width))
        if target >= shift(lam, -PATH_MIN_MOVE * tol_width):
            return None
        return target

    def closed(lo, hi):
        return hi < 1.0 and done(lo, min(shift(hi, PATH_ABOVE[-1] * tol_width), 1.0))

    coef, active = modes.scheme_coef()
    path = follow_rate(modes.free, coef, active, modes.eta, closed, aim, max_iter=PATH_MAX_ITER,
                       time_limit=None if time_limit is None else PATH_TIME_SHARE * time_limit)
    if not (path.hi < 1.0 and path.W is not None):
        return path, []
    return path, path_rates(path.hi, settling, tol_width)


def path_rates(rate: float, settling: bool, tol_width: float) -> list:
    """The rates at which a path iterate certifying ``rate`` is re-checked: ``PATH_ABOVE`` of the tolerance's
    width above it (in :func:`rate_measure`'s coordinate), at most 1."""
    return [min(rate_shift(rate, a * tol_width, settling), 1.0) for a in PATH_ABOVE]


def path_steps_solves(path) -> int:
    """``res.solve_count`` of a path: its Newton steps in SDP-equivalents (``PATH_STEPS_PER_SDP``), at least 1."""
    return max(1, math.ceil(path.iterations / PATH_STEPS_PER_SDP))
