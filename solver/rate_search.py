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
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["margin_model", "model_root", "network_margin_model", "next_rate"]


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
        The solve at ``rate`` (its ``duals``: one multiplier per transition first).
    rate : float

    Returns
    -------
    tuple or None
    """
    duals = getattr(sdp, "duals", None)
    if duals is None or sdp.Z is None or not np.isfinite(sdp.t) or len(duals) < prob.n_blocks:
        return None
    k, n, E = prob.k, prob.n, prob.n_blocks
    M = np.stack([np.asarray(X, dtype=np.float64) for X in duals[:E]])
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


def model_root(model, rate: float, lo: float, hi: float) -> float | None:
    """The root of ``m(lambda)`` in ``(lo, hi)`` (a 1-D monotone equation, solved by bisection on ln lambda).

    None when the model does not decrease with lambda (no root to aim at) or has no root in the interval.
    """
    t0, q, eta = model
    if not np.any(q < 0):
        return None

    def m(lam):
        with np.errstate(over="ignore"):
            return t0 + float(np.sum(q * (np.exp(eta * (math.log(rate) - math.log(lam))) - 1.0)))

    a, b = max(lo, 1e-12), hi
    ma, mb = m(a), m(b)
    if not (ma < 0.0 < mb) and not (ma > 0.0 > mb):
        return None
    la, lb = math.log(a), math.log(b)
    for _ in range(60):
        mid = 0.5 * (la + lb)
        if (m(math.exp(mid)) > 0.0) == (mb > 0.0):
            lb = mid
        else:
            la = mid
        if lb - la < 1e-12:
            break
    return math.exp(0.5 * (la + lb))


def next_rate(lo: float, hi: float, t_lo: float | None, t_hi: float | None, model, done, midpoint,
              from_above: bool = True, previous: tuple | None = None) -> tuple[float, str]:
    """The next rate to try in the bracket ``[lo, hi]`` and how it was chosen.

    The margin is usually convex in lambda near the root (it flattens towards it), so the Newton root
    of the model at ``hi`` (``newton``) lies above the root: a rate to certify.  The probes alternate
    sides: after a certified rate, a rate aimed just below the root (``below``: the secant's root
    between the margins at ``lo`` and ``hi`` when both are known, or the fixed point of the Newton map
    by a secant through the last two certified ends (Steffensen), or the Newton step mirrored, less half
    the tolerance); after a failed one, ``newton``.  Once the root is within the tolerance of ``hi``,
    ``close`` tries the tolerance's end below ``hi``.  A candidate outside the bracket's inner 96 % is
    replaced by the bisection's midpoint (``bisect``).

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

    Returns
    -------
    rate : float
    how : {"close", "newton", "secant", "below", "bisect"}
    """
    newton = None if model is None else model_root(model, hi, max(lo, 1e-12), hi)
    low_end = _closing_low(hi, done)
    if newton is not None and done(newton, hi) and low_end > lo:
        return low_end, "close"
    width = hi - lo

    def inside(c):
        return c is not None and lo + 0.02 * width < c < hi - 0.02 * width

    secant = None
    if lo > 0.0 and t_lo is not None and t_hi is not None and t_lo < 0.0 < t_hi:
        secant = lo + (hi - lo) * (-t_lo) / (t_hi - t_lo)
    if newton is None:
        return midpoint(lo, hi), "bisect"
    if not from_above:
        # far from the root the margin can be concave (the Newton root then fails); the secant's root lies
        # above the root there
        for cand, how in ((newton, "newton"), (secant, "secant")):
            if inside(cand):
                return cand, how
        return midpoint(lo, hi), "bisect"
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


