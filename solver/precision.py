"""Single-precision controllers: gains rounded to float32 and the certificate re-checked on them.

docs/design.md, "Single precision": the target runs the loop with the rounded gains ``K~ = fl32(K)`` and
computes every packet entry ``u = K~_q x`` in float32 from a state rounded to float32.  Per entry,
``|u - K~_q x| <= gamma32(n + 1) |K~_q| |x| + 2^-126 (n + |K~_q| 1)`` (elementwise; n products and sums,
one rounding of x, any order of summation, fused multiply-adds included; the absolute term covers underflow,
gradual or flushed to zero, and only matters for states below about 1e-37 |x(0)|: the proof below is of
the relative part, i.e. convergence down to that floor), so over an interval of mode s

    x(i + eta_s) = A_s(K~) x + w,    ||w||_2 <= beta_s ||x||_2,
    beta_s = gamma32(n + 1) sum_q ||coef_{s,q}||_2 || |K~_q| ||_2.

A quadratic certificate ``V_s(x) = x' P_s x`` of the rounded loop absorbs the perturbation when, for every
pair (s, t) of a mode and the next,

    sigma_st^2 P_s - A_s' P_t A_s > 0,   sigma_st = lambda^eta_s - sqrt(lambda_max(P_t) / lambda_min(P_s)) beta_s,

because ``||(A_s x + w)||_{P_t} <= ||A_s x||_{P_t} + sqrt(lambda_max(P_t)) beta_s ||x||_2`` and
``||x||_2 <= ||x||_{P_s} / sqrt(lambda_min(P_s))``.  ``lambda = 1`` proves stability; a design's certified
decay rate is kept as the claim.  The check is the float64 eigenvalue re-check of
:mod:`solver.lyapunov` (relative margin ``RECHECK_TOL``); float64 rounding is some nine orders below
float32's and is covered by that margin.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import InvalidInput
from .lyapunov import RECHECK_TOL
from .network import ModeSet

PRECISIONS = ("float64", "float32")

#: Unit roundoff of float32 (round to nearest).
U32 = 2.0**-24

#: Safety factor on the computed norms and eigenvalue ratios entering beta (they are float64 estimates).
_SAFETY = 1.001


def gamma32(k: int) -> float:
    """``k u / (1 - k u)`` with ``u = 2^-24``: relative error bound of a k-term float32 dot product."""
    return k * U32 / (1.0 - k * U32)


def round_gains(gains: np.ndarray) -> np.ndarray:
    """The gains the float32 code stores: ``fl32(K)`` as float64 values (exactly representable).

    Raises
    ------
    InvalidInput
        When an entry overflows float32 (``|K| > 3.4e38``).
    """
    with np.errstate(over="ignore"):
        K32 = np.asarray(gains, dtype=np.float64).astype(np.float32)
    if not np.all(np.isfinite(K32)):
        raise InvalidInput("a gain overflows float32 (|K| > 3.4e38)", ("precision",))
    return K32.astype(np.float64)


def packet_error_bound(gains: np.ndarray) -> float:
    """Relative bound of the float32 packet: ``|u - K x| <= gamma32(n + 1) |K| |x|`` entrywise (plus the
    absolute underflow term ``2^-126 (n + |K| 1)``, module docstring).

    Parameters
    ----------
    gains : ndarray, shape (n_drop, m, n)
    """
    return gamma32(np.shape(gains)[-1] + 1)


@dataclass
class Float32Proof:
    """The certificate of the loop the float32 code closes.

    Attributes
    ----------
    verified : bool
    gains : ndarray, shape (n_drop, m, n)
        ``fl32(K)`` (as float64).
    claim : str
        ``"stability"`` or ``"decay rate <lambda>"``.
    decay_rate : float or None
    source : str
        Which Lyapunov matrices were re-checked: ``"design"`` (the design's own certificate) or
        ``"fixed_gain_lmi"`` (a common certificate computed for the rounded gains).
    relative_error : float
        ``gamma32(n + 1)``: the entrywise relative bound of the packet.
    beta : ndarray, shape (S,)
        Per-mode bound ``||w|| <= beta_s ||x||`` of the rounding over an interval.
    margin : float
        Smallest relative decrease ``lambda_min(sigma^2 P_s - A_s' P_t A_s) / lambda_max(P_s)`` (> RECHECK_TOL).
    rounding_share : float
        Largest ``sqrt(kappa) beta_s / (lambda^eta_s - ||A_s||_P)``: the share of the certificate's room that
        float32 rounding uses (< 1 when verified).
    reason : str
    """

    verified: bool
    gains: np.ndarray
    claim: str
    decay_rate: float | None
    source: str
    relative_error: float
    beta: np.ndarray
    margin: float
    rounding_share: float
    reason: str = ""
    tried: list = field(default_factory=list)


def _check(P: np.ndarray, A: np.ndarray, beta: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """(margin, rounding share) of ``sigma_st^2 P_s - A_s' P_t A_s``; P of shape (S, n, n) (or (1, n, n): common)."""
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    S = A.shape[0]
    common = P.shape[0] == 1
    if common:
        P = np.broadcast_to(P, (S,) + P.shape[1:])
    eig = np.linalg.eigvalsh(P)
    if np.any(eig[:, 0] <= 0):
        return -np.inf, np.inf
    lo, hi = eig[:, 0], eig[:, -1]
    # ||A_s||_{P_s -> P_t} = ||L_t' A_s L_s^-T||_2 with P = L L'
    L = np.linalg.cholesky(P)
    Linv = np.linalg.inv(L)
    margin, share = np.inf, 0.0
    for s in range(S):
        for t in ([s] if common else range(S)):
            kappa = np.sqrt(hi[t] / lo[s]) * _SAFETY
            sigma = target[s] - kappa * beta[s]
            norm = np.linalg.norm(L[t].T @ A[s] @ Linv[s].T, 2)
            room = target[s] - norm
            share = max(share, np.inf if room <= 0 else kappa * beta[s] / room)
            if sigma <= 0:
                margin = -np.inf
                continue
            D = sigma**2 * P[s] - A[s].T @ P[t] @ A[s]
            margin = min(margin, float(np.linalg.eigvalsh(0.5 * (D + D.T))[0] / hi[s]))
    return margin, share


def certify_float32(family, gains, n_drop: int, *, plant_switching: str = "per_interval",
                    decay_rate: float | None = None, certificate=None) -> Float32Proof:
    """Round the gains to float32 and prove the loop the float32 code closes (module docstring).

    Parameters
    ----------
    family : PlantFamily
    gains : ndarray, shape (n_drop, m, n)
    n_drop : int
    plant_switching : {"per_interval", "per_sample"}
    decay_rate : float, optional
        The claim to keep (per-sample rate lambda in (0, 1]); None proves stability.
    certificate : Certificate, optional
        The design's certificate in the plant's coordinates, tried first.

    Returns
    -------
    Float32Proof
        ``verified`` False with the reason when neither the design's certificate nor a fresh common
        certificate of the rounded loop covers the rounding.
    """
    from .lyapunov import common_lmi

    K32 = round_gains(gains)
    modes = ModeSet.from_family(family, n_drop, plant_switching=plant_switching)
    A = modes.closed_loops(K32)
    n = A.shape[-1]
    g = packet_error_bound(K32)
    abs_norms = np.array([np.linalg.norm(np.abs(Kq), 2) for Kq in K32])  # || |K~_q| ||_2
    coef_norms = np.linalg.norm(modes.coef, ord=2, axis=(-2, -1))  # (S, n_drop)
    beta = g * (coef_norms @ abs_norms) * _SAFETY
    lam = 1.0 if decay_rate is None else float(decay_rate)
    target = lam ** modes.eta.astype(float)
    claim = "stability" if decay_rate is None else f"decay rate {lam:.6g}"

    candidates = []
    if certificate is not None and getattr(certificate, "verified", False):
        if certificate.kind == "switched" and np.shape(certificate.P) == (modes.n_modes, n, n):
            candidates.append(("design", np.asarray(certificate.P, dtype=float)))
        elif certificate.X is not None and np.shape(certificate.X) == (n, n):
            candidates.append(("design", np.asarray(certificate.X, dtype=float)[None]))
    tried = []
    best = None
    for attempt in range(2):
        if attempt == 1:
            try:
                X, _, _ = common_lmi(A, target**2)
            except Exception as exc:  # a failed solve only means no second candidate
                tried.append(("fixed_gain_lmi", f"solve failed: {exc}"))
                break
            if X is None or not np.all(np.isfinite(X)):
                tried.append(("fixed_gain_lmi", "no certificate for the rounded gains"))
                break
            candidates.append(("fixed_gain_lmi", np.asarray(X, dtype=float)[None]))
        while candidates:
            source, P = candidates.pop(0)
            try:
                margin, share = _check(P, A, beta, target)
            except np.linalg.LinAlgError:  # a certificate too ill-conditioned to factor proves nothing here
                margin, share = -np.inf, np.inf
            tried.append((source, f"margin {margin:.3g}, rounding uses {share:.3g} of the room"))
            if best is None or margin > best[1]:
                best = (source, margin, share)
            if margin > RECHECK_TOL:
                return Float32Proof(True, K32, claim, decay_rate, source, g, beta, margin, share,
                                    f"{claim} proven for the float32 loop ({source} certificate, relative margin "
                                    f"{margin:.3g}; rounding uses {share:.3g} of the certificate's room)", tried)
    source, margin, share = best if best is not None else ("none", -np.inf, np.inf)
    reason = (f"the float32 gains lose the proof of {claim}: with the float32 rounding of K x "
              f"(|u - K x| <= {g:.3g} |K| |x|, up to beta = {beta.max():.3g} |x| per interval) no certificate "
              f"keeps a relative margin above {RECHECK_TOL:g} (best: {source}, margin {margin:.3g}, "
              f"rounding needs {share:.3g} of its room); export in float64")
    return Float32Proof(False, K32, claim, decay_rate, source, g, beta, margin, share, reason, tried)
