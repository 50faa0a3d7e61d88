"""Certificates for the negative verdicts, re-checked by code that does not trust the solver.

``design`` says "infeasible" only with one of these (docs/design.md, "Certificates
for every verdict"):

* :class:`FarkasCertificate` (``kind="farkas"``): PSD multipliers of the design
  LMIs whose weighted sum contradicts every candidate design with relative margin
  ``margin`` and gain norm below ``gain_bound``.  :func:`check_farkas` (``lmi``) and
  :func:`check_farkas_switched` (``switched``) recompute everything from the
  multipliers and interval data rebuilt from the plant, account for rounding, and
  prove the eigenvalue bounds in exact arithmetic.
* :class:`UncontrollableCertificate` (``kind="uncontrollable"``): a plant mode
  with an eigenvalue ``|lambda| >= 1`` that no input reaches (left eigenvector
  ``w``, ``w^H F = lambda w^H``, ``w^H G = 0``), proven in rational arithmetic; the
  case where the best margin is exactly 0 and no strict Farkas multiplier exists.

Conventions (the contract a conic backend must meet): the design SDP is solved
in the *congruent* form with data ``free_s``, ``coef_s`` already multiplied by
``c_s = lambda^(-eta_s)`` (``c_s = 1`` without a decay rate), so every block
reads ``L_s = [[W, (A_s W)^T], [A_s W, W]]`` with ``A_s W = free_s W + sum_j
coef_{s,j} Y_j``.  The multipliers are the PSD dual matrices ``Z_s`` (2n x 2n,
blocks ``[[Z11, Z21^T], [Z21, Z22]]``) of the constraints ``L_s - t I >= 0`` of
``max t s.t. trace W = n``, normalized so that ``sum_s trace Z_s = 1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .memo import BoundedCache

#: Unit roundoff of float64.
U = 2.0**-53

def gamma(k: int) -> float:
    """``k u / (1 - k u)``: relative error bound of a k-term float64 dot product."""
    return k * U / (1.0 - k * U)



def _extended() -> float | None:
    """The unit roundoff of ``np.longdouble`` when it is a binary format with at least a 64-bit significand and
    rounds to nearest now (x87 extended, IEEE quad), else None (float64 only: MSVC, and the double-double
    ``long double`` of POWER, whose rounding the standard model does not describe)."""
    info = np.finfo(np.longdouble)
    if info.nmant not in (63, 112):
        return None
    one, u = np.longdouble(1), np.longdouble(2) ** -(info.nmant + 1)
    # the precision the arithmetic runs at (an x87 control word set to 53 bits would round these away)
    if not (one + 2 * u != one and one + u == one and (one + 3 * u) - one == 4 * u):
        return None
    return float(u)


def _to_float64(X: np.ndarray, dX: np.ndarray, u: float) -> tuple:
    """``X`` (a product computed at unit roundoff ``u``, error bound ``dX``) rounded to float64, and a float64 bound
    of its error: ``dX`` plus the rounding, rounded up."""
    X64 = X.astype(np.float64)
    if X.dtype == np.float64:
        return X64, dX
    d = dX + np.abs(X - X64.astype(X.dtype))  # exact difference of two nearby numbers at the wider precision
    d = d * (1 + 4 * u)  # (the sum above rounded)
    return X64, d.astype(np.float64) * (1 + 2 * U)  # the conversion rounds to nearest


#: Largest side for which an inconclusive floating-point bound is retried in exact arithmetic (Bareiss on
#: the dyadic entries, about 0.1 s at side 40).
EXACT_MAX_SIDE = 40

#: Smallest normal float64: covers the absolute rounding errors of gradual underflow.
_TINY = 2.0**-1022


def cholesky_shift_bound(M: np.ndarray, c: float) -> float | None:
    """A proven ``e >= 0`` with ``lambda_min(M + c I) >= -e``, from a float64 Cholesky of ``fl(M + c I)``; or None.

    docs/design.md, "Floating-point proofs of definiteness": if Cholesky runs to completion on the
    symmetric float64 matrix ``B``, its computed factor satisfies ``R^T R = B + dB`` with
    ``|dB| <= gamma_{k+1} |R^T| |R|`` (Higham, *Accuracy and Stability of Numerical Algorithms*,
    Thm 10.3, any order of summation; we use ``gamma_{k+3}`` to allow for divisions done as
    products with a computed reciprocal), hence ``|dB_ij| <= g sqrt(b_ii b_jj)``,
    ``g = gamma / (1 - gamma)``, and ``lambda_min(B) >= -||dB||_2 >= -g tr(B)`` (Rump, "Verification
    of positive definiteness", BIT 46, 2006).  Forming ``B`` rounds the diagonal only
    (``|error| <= u |b_ii| / (1 - u)``).

    Parameters
    ----------
    M : ndarray, shape (k, k)
        Exactly symmetric, finite.
    c : float
        The shift.
    """
    e = cholesky_shift_bounds(M[None], np.array([c]))[0]
    return None if np.isnan(e) else float(e)


def cholesky_shift_bounds(Ms: np.ndarray, c: np.ndarray) -> np.ndarray:
    """:func:`cholesky_shift_bound` for a stack (S, k, k) and shifts (S,): NaN where Cholesky fails."""
    S, k = Ms.shape[0], Ms.shape[-1]
    B = Ms + c[:, None, None] * np.eye(k)  # off-diagonal entries are copied exactly (x + 0.0 == x)
    d = np.diagonal(B, axis1=1, axis2=2)
    out = np.full(S, np.nan)
    ok = np.all(d > 0, axis=1)
    if not ok.any():
        return out
    with np.errstate(invalid="ignore"):
        R = _cholesky_nan(B[ok])
    ok[ok] = np.all(np.isfinite(R), axis=(1, 2))
    g = gamma(k + 3)
    g = g / (1.0 - g)
    dd = d[ok]
    e = g * np.sum(dd, axis=1) + U / (1.0 - U) * np.max(dd, axis=1)
    # the sum and products above were rounded (a relative gamma), underflow adds absolute errors
    out[ok] = e * (1.0 + gamma(2 * k + 8)) + 4.0 * k * (k + 3) * _TINY
    return out


def _cholesky_nan(B: np.ndarray) -> np.ndarray:
    """Batched lower Cholesky factors, NaNs for a block that is not positive definite."""
    try:
        return np.linalg.cholesky(B)
    except np.linalg.LinAlgError:
        out = np.full_like(B, np.nan)
        for i in range(B.shape[0]):
            try:
                out[i] = np.linalg.cholesky(B[i])
            except np.linalg.LinAlgError:
                pass
        return out


class Prover:
    """Proven eigenvalue bounds: floating-point (Cholesky with rounding terms) or exact (Sylvester, Bareiss).

    ``slack`` accumulates how far the floating-point bounds sit above the float64 estimates: a check whose
    float verdict fails by less than that is retried exactly (:func:`check_farkas`).
    """

    def __init__(self, exact: bool = False):
        self.exact = exact
        self.slack = 0.0

    def shift(self, M: np.ndarray, start: float) -> float:
        """A ``v`` with ``M + v I`` proven positive semidefinite (``lambda_min(M) >= -v``), ``v`` near ``start``."""
        add = max(1e-15 * float(np.linalg.norm(M)), 1e-300)
        if self.exact:
            from .exact import positive_definite_shifted

            for _ in range(200):
                c = start + add
                if positive_definite_shifted(M, c):
                    return c
                add *= 4.0
            return np.inf
        for _ in range(200):
            c = start + add
            e = cholesky_shift_bound(M, c)
            if e is not None:
                v = c + e
                v = v + 4 * U * abs(v) + _TINY  # the addition rounded
                self.slack += v - start
                return v
            add *= 4.0
        return np.inf

    def max_upper(self, M: np.ndarray, err: float = 0.0) -> float:
        """A rigorous upper bound of ``lambda_max`` of a symmetric matrix known to within ``err`` (2-norm)."""
        M = 0.5 * (M + M.T)
        return self.shift(-M, float(np.linalg.eigvalsh(M)[-1])) + err

    def min_lower(self, M: np.ndarray, err: float = 0.0) -> float:
        """A rigorous lower bound of ``lambda_min`` of a symmetric matrix known to within ``err`` (2-norm)."""
        M = 0.5 * (M + M.T)
        return -self.shift(M, -float(np.linalg.eigvalsh(M)[0])) - err

    def min_lower_many(self, Ms: np.ndarray) -> np.ndarray:
        """:meth:`min_lower` of every matrix of a stack (S, k, k): one batched eigvalsh and Cholesky."""
        if self.exact or Ms.shape[0] == 0:
            return np.array([self.min_lower(M) for M in Ms])
        Ms = 0.5 * (Ms + np.swapaxes(Ms, 1, 2))
        start = -np.linalg.eigvalsh(Ms)[:, 0]
        add = np.maximum(1e-15 * np.linalg.norm(Ms, axis=(1, 2)), 1e-300)
        c = start + add
        e = cholesky_shift_bounds(Ms, c)
        v = c + e
        v = v + 4 * U * np.abs(v) + _TINY  # the addition rounded
        out = -v
        for i in np.flatnonzero(np.isnan(e)):  # a failed trial: the one-matrix search with growing shifts
            out[i] = self.min_lower(Ms[i])
        good = ~np.isnan(e)
        self.slack += float(np.sum(v[good] - start[good]))
        return out


def lambda_max_upper(M: np.ndarray, err: float = 0.0, exact: bool = False) -> float:
    """A rigorous upper bound of ``lambda_max`` of a symmetric matrix known to within ``err`` (2-norm).

    ``c I - M`` is proven positive semidefinite (``c`` just above the float64 estimate) by a float64
    Cholesky with its rounding-error bound (:func:`cholesky_shift_bound`), or in exact arithmetic
    (``exact=True``); ``err`` is added (Weyl).
    """
    return Prover(exact).max_upper(M, err)


def lambda_min_lower(M: np.ndarray, err: float = 0.0, exact: bool = False) -> float:
    """A rigorous lower bound of ``lambda_min`` of a symmetric matrix known to within ``err`` (2-norm)."""
    return Prover(exact).min_lower(M, err)


# ------------------------------------------------------------------ interval data with error bounds
def interval_data(F: np.ndarray, G: np.ndarray, plants: tuple, gain_map: np.ndarray, scale=None):
    """Interval matrices ``free_s, coef_{s,j}`` rebuilt from the plant data, with elementwise error bounds.

    Parameters
    ----------
    F : ndarray, shape (r, n, n)
    G : ndarray, shape (r, n, m)
    plants : tuple of tuple of int
        Plant index of every sample of each mode's interval (``ModeSet.plants``).
    gain_map : ndarray, shape (n_drop, J)
        ``K_q = sum_j gain_map[q, j] Theta_j``.
    scale : ndarray, shape (S,), optional
        The congruent factors ``c_s`` (the data of mode s is multiplied by ``c_s``).

    Returns
    -------
    free, dfree : ndarray, shape (S, n, n)
        Computed ``c_s F^eta`` (product over the interval) and a bound of
        ``|computed - exact|`` elementwise (exact: the product of the float64
        plant data in real arithmetic).
    coef, dcoef : ndarray, shape (S, J, n, m)
    """
    F = np.asarray(F, dtype=np.float64)
    G = np.asarray(G, dtype=np.float64)
    gain_map = np.asarray(gain_map, dtype=np.float64)
    tails, dtails, acc, dacc = _interval_products(F, G, plants, gain_map)
    S = len(plants)
    c = (np.ones(S) if scale is None else np.asarray(scale, dtype=np.float64))[:, None, None]
    free = c * tails
    dfree = np.abs(c) * dtails * (1 + 4 * U) + 8 * U * np.abs(free)
    c = c[:, None]
    coef = c * acc
    dcoef = np.abs(c) * dacc * (1 + 4 * U) + 8 * U * np.abs(coef)
    # The bounds themselves were rounded: a factor 2 covers that with a wide margin.
    return free, 2 * dfree, coef, 2 * dcoef


#: :func:`_interval_products` by the plant data, scheme and gain map: the products and their bounds do not depend on
#: the congruent scale, so the rate search's Farkas re-checks (one per refuted rate) share them (2.6 ms of a
#: re-check's 5.4 ms at n = 8, 50 modes); the entries are read-only.
_PRODUCTS = BoundedCache(32)


def _interval_products(F: np.ndarray, G: np.ndarray, plants: tuple, gain_map: np.ndarray) -> tuple:
    """The unscaled interval products of :func:`interval_data`: ``(tails, dtails, acc, dacc)``, the products
    ``F^eta`` per mode and the scheme's ``sum_q gain_map[q, j] cq[s, q]`` in float64 with their error bounds
    (before the scale's rounding and the final factor 2)."""
    data_key = (F.shape, G.shape, F.tobytes(), G.tobytes(), tuple(tuple(int(i) for i in seq) for seq in plants),
                gain_map.shape, gain_map.tobytes())
    return _PRODUCTS.get_or_compute(data_key, lambda: _compute_interval_products(F, G, plants, gain_map))


def _compute_interval_products(F: np.ndarray, G: np.ndarray, plants: tuple, gain_map: np.ndarray) -> tuple:
    n, m = F.shape[1], G.shape[2]
    N, J = gain_map.shape
    S = len(plants)
    # The products in extended precision where there is one: their a-priori bound grows like the products of
    # |F| (n = 50, |F|'s spectral radius 6 against 1.1: 1e-7 against an actual error of 2e-15, and the Farkas
    # re-check of a refuted rate 5e-4 below the root failed by that alone, docs/design.md §3.2.2); rounded to
    # float64 at the end, the conversion's error added to the bound
    ext = _extended()
    dt, u = (np.longdouble, ext) if ext is not None else (np.float64, U)
    Fx, Gx = F.astype(dt), G.astype(dt)
    tails = np.empty((S, n, n), dtype=dt)
    dtails = np.empty((S, n, n), dtype=dt)
    cq = np.zeros((S, N, n, m), dtype=dt)  # cq[s, k]: the product of the interval after sample k, times G of sample k
    dq = np.zeros((S, N, n, m), dtype=dt)
    g = dt((n + 2) * u / (1.0 - (n + 2) * u))  # gamma(n + 2) at the products' unit roundoff
    memo: dict = {}  # interval suffix seq[k:] -> (cq[k], dq[k], tail, dtail): modes share suffixes
    for s, seq in enumerate(plants):
        tail, dtail = np.eye(n, dtype=dt), np.zeros((n, n), dtype=dt)
        for k in range(len(seq) - 1, -1, -1):
            key = tuple(seq[k:])
            if key not in memo:
                Gk, Fk = Gx[seq[k]], Fx[seq[k]]
                memo[key] = (tail @ Gk, dtail @ np.abs(Gk) + g * (np.abs(tail) @ np.abs(Gk)),
                             tail @ Fk, dtail @ np.abs(Fk) + g * (np.abs(tail) @ np.abs(Fk)))
            cq[s, k], dq[s, k], tail, dtail = memo[key]
        tails[s], dtails[s] = tail, dtail
    tails, dtails = _to_float64(tails, dtails, u)
    cq, dq = _to_float64(cq, dq, u)
    # coef_{s,j} = sum_q gain_map[q, j] cq[s, q]: an N-term dot product per entry, in any order (einsum may
    # use BLAS), so its rounding is within gamma_N sum_q |w_qj| |cq[s, q]|; counted twice over below
    absw = np.abs(gain_map)
    absc = np.abs(cq)
    acc = np.einsum("qj,sqab->sjab", gain_map, cq)
    dacc = (np.einsum("qj,sqab->sjab", absw, dq + 2 * U * absc)
            + gamma(N + 1) * np.einsum("qj,sqab->sjab", absw, absc))
    got = (tails, dtails, acc, dacc)
    for arr in got:
        arr.flags.writeable = False
    return got


# ------------------------------------------------------------------ Farkas certificates
@dataclass
class FarkasCertificate:
    """Multipliers proving that no design of a method exists (with gain norm below ``gain_bound``).

    Attributes
    ----------
    kind : str
        ``"farkas"``.
    method : {"lmi", "switched"}
        Which design family is excluded.
    multipliers : ndarray
        ``lmi``: shape (S, 2n, 2n), ``Z_s`` in the order of the result's ``mode_labels``.
        ``switched``: shape (S, S, 2n, 2n), ``Z_{s,u}`` for the pair (s, u).
    gain_bound : float
        No design with relative margin ``margin`` and ``sqrt(sum_j ||Theta_j||_2^2) < gain_bound``
        exists (``Theta_j`` the scheme's free gains; ``K_q`` for the predictive scheme); ``inf`` when
        ``E`` vanishes exactly.
    gain_bound_any_margin : float
        The same bound for designs of any margin (> 0 only when ``delta > 0``; see
        :attr:`any_margin`).
    delta : float
        Proven lower bound of ``-lambda_max(Q)`` less the PSD shifts.
    e_norm : float
        Proven upper bound of ``||E||_F``.
    margin : float
        Relative strictness ``tau`` the excluded designs would have (``L_s >= tau tr(W) I``).
    skew_norm : float
        ``switched`` only: upper bound of the norm of the skew part of the slack coefficient.
    decay_rate : float or None
        The rate whose (congruent) LMIs are excluded; None for plain stability.
    verified : bool
        True iff ``delta > 0`` (the check passed).
    scaled : bool
        True when the check holds only in the design's balanced coordinates (``res.scaling``).
    """

    multipliers: np.ndarray
    gain_bound: float
    delta: float
    e_norm: float
    verified: bool
    method: str = "lmi"
    skew_norm: float = 0.0
    decay_rate: float | None = None
    scaled: bool = False
    kind: str = "farkas"
    margin: float = 0.0
    source: str = "sdp_dual"
    gain_bound_any_margin: float = 0.0

    @property
    def any_margin(self) -> bool:
        """Whether designs of *every* margin (down to 0) are excluded below ``gain_bound_any_margin``.

        True when the multipliers alone contradict the LMIs (``delta > 0``: the outcome
        "infeasible"); False when only the margin makes the room (the outcome "marginal": designs
        with relative margin below ``margin`` may exist).
        """
        return self.gain_bound_any_margin > 0

    def statement(self) -> str:
        what = ("common quadratic Lyapunov design" if self.method == "lmi"
                else "switched-Lyapunov design with a common slack (||Z||_F <= trace(Z + Z^T)/2)")
        rate = "" if self.decay_rate is None else f" at decay rate {self.decay_rate:.6g}"
        if not self.any_margin:
            return (f"marginal: no {what} with relative margin >= {self.margin:.3g} and gain norm < "
                    f"{self.gain_bound:.3g}{rate}; designs with a smaller margin are not excluded "
                    "(Farkas certificate re-checked in float64)")
        bound = ("of any gain norm" if np.isinf(self.gain_bound_any_margin)
                 else f"with gain norm < {self.gain_bound_any_margin:.3g}")
        strict = "" if not self.margin or self.gain_bound <= 1.01 * self.gain_bound_any_margin else (
            f" (< {self.gain_bound:.3g} with relative margin >= {self.margin:.3g})")
        return f"no {what} of any margin {bound}{strict}{rate} (Farkas certificate re-checked in float64)"

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "method": self.method,
            "verified": self.verified,
            "gain_bound": float(self.gain_bound),  # JSON: null when unbounded (see gain_bound_unbounded)
            "gain_bound_unbounded": bool(np.isinf(self.gain_bound)),
            "gain_bound_any_margin": float(self.gain_bound_any_margin),
            "any_margin": self.any_margin,
            "delta": self.delta,
            "margin": self.margin,
            "e_norm": self.e_norm,
            "skew_norm": self.skew_norm,
            "decay_rate": self.decay_rate,
            "scaled": self.scaled,
            "statement": self.statement(),
            "multipliers": self.multipliers.tolist(),
        }


def _sym(M):
    return 0.5 * (M + np.swapaxes(M, -1, -2))


def check_farkas(multipliers: np.ndarray, free: np.ndarray, coef: np.ndarray, dfree=None, dcoef=None,
                 decay_rate: float | None = None, margin: float = 0.0) -> FarkasCertificate:
    """Re-check ``lmi`` Farkas multipliers against interval data; solver-independent.

    For every ``W > 0`` and ``Y`` with all ``L_s(W, Y) >= 0``::

        0 <= sum_s <Z_s + mu_s I, L_s> = <Q, W> + sum_j <E_j, Y_j> + 2 sum_s mu_s tr W
        Q   = sum_s (Z11_s + Z22_s + Z21_s^T free_s + free_s^T Z21_s)
        E_j = 2 sum_s coef_{s,j}^T Z21_s

    and with ``Y_j = Theta_j W``: ``||Y||_F <= kappa tr W``.  A design with relative margin
    ``margin`` (``L_s >= margin tr(W) I``) has ``sum_s <Z_s + mu_s I, L_s> >= margin T tr W`` with
    ``T <= sum_s tr(Z_s + mu_s I)``, so ``margin T + delta <= ||E||_F kappa`` with
    ``delta = -lambda_max(Q) - 2 sum_s mu_s``: no design with ``kappa < (margin T + delta) / ||E||_F``.

    Parameters
    ----------
    multipliers : ndarray, shape (S, 2n, 2n)
        Symmetrized before use (the returned certificate holds the symmetric ones).
    free : ndarray, shape (S, n, n)
    coef : ndarray, shape (S, J, n, m)
    dfree, dcoef : ndarray, optional
        Elementwise bounds of the error of ``free``, ``coef`` (see :func:`interval_data`);
        zero when the data are taken as exact.
    """
    return _retry_exact(_farkas_lmi, multipliers, free, coef, dfree, dcoef, decay_rate, margin)


def _retry_exact(check, *args):
    """Run ``check`` with floating-point bounds; retry in exact arithmetic only when that could change the verdict.

    The exact bounds are at least as tight as the float ones; they can change the verdict (no proof ->
    proof, or a margin-only proof -> a proof for every margin) only when the float room falls short by
    less than the accumulated float slack.
    """
    cert, room, prover = check(*args, Prover(exact=False))
    side = np.asarray(args[0]).shape[-1]
    if not np.isfinite(room) or side > EXACT_MAX_SIDE or cert.any_margin:
        return cert
    window = 4 * prover.slack
    if cert.verified:  # "marginal": could exact bounds make it a proof for every margin?
        if cert.delta - cert.skew_norm + window <= 0:
            return cert
    elif room + window <= 0:
        return cert
    again = check(*args, Prover(exact=True))[0]
    return again if again.verified and (again.any_margin or not cert.verified) else cert


def stability_adjoint(Z: np.ndarray, free: np.ndarray, coef: np.ndarray, dfree: np.ndarray, dcoef: np.ndarray):
    """The adjoint of the stability blocks ``L_s(W, Y)`` applied to multipliers, with rounding bounds.

    ``sum_s <Z_s, L_s(W, Y)> = <Q, W> + sum_j <E_j, Y_j>`` with ``Q = sum_s (Z11_s + Z22_s + Z21_s^T free_s
    + free_s^T Z21_s)`` and ``E_j = 2 sum_s coef_{s,j}^T Z21_s``.

    Returns
    -------
    Q, errQ : ndarray, shape (n, n)
        ``Q`` (symmetrized) and an elementwise bound of ``|computed - exact|`` (exact: from the exact data).
    E, errE : ndarray, shape (J, m, n)
    """
    S, n2, _ = Z.shape
    n = n2 // 2
    Z11, Z21, Z22 = Z[:, :n, :n], Z[:, n:, :n], Z[:, n:, n:]
    FtZ = np.swapaxes(free, 1, 2) @ Z21  # (S, n, n): free_s^T Z21_s
    Q = np.sum(Z11 + Z22 + FtZ + np.swapaxes(FtZ, 1, 2), axis=0)
    Q = _sym(Q)
    absZ21 = np.abs(Z21)
    # rounding of the products (n terms) and of the sum over 4 S terms, plus the data error
    term = np.abs(Z11) + np.abs(Z22) + 2 * (np.swapaxes(np.abs(free), 1, 2) @ absZ21)
    errQ = gamma(n + 4 * S + 4) * np.sum(term, axis=0)
    errQ = errQ + 2 * np.sum(np.swapaxes(dfree, 1, 2) @ absZ21, axis=0)
    errQ = errQ + errQ.T
    E = 2 * np.einsum("sjab,sac->jbc", coef, Z21)  # (J, m, n)
    errE = 2 * gamma(n + S + 2) * np.einsum("sjab,sac->jbc", np.abs(coef), absZ21)
    errE = errE + 2 * np.einsum("sjab,sac->jbc", dcoef, absZ21)
    return Q, errQ, E, errE


def _farkas_lmi(multipliers, free, coef, dfree, dcoef, decay_rate, margin, prover):
    Z = _sym(np.asarray(multipliers, dtype=np.float64))
    S, n2, _ = Z.shape
    n = n2 // 2
    dfree = np.zeros_like(free) if dfree is None else dfree
    dcoef = np.zeros_like(coef) if dcoef is None else dcoef
    if not (np.all(np.isfinite(Z)) and np.all(np.isfinite(free)) and np.all(np.isfinite(coef))):
        return FarkasCertificate(Z, 0.0, -np.inf, np.inf, False, decay_rate=decay_rate), -np.inf, prover
    Q, errQ, E, errE = stability_adjoint(Z, free, coef, dfree, dcoef)
    mu = np.maximum(0.0, -prover.min_lower_many(Z))
    lam_q = prover.max_upper(Q, float(np.linalg.norm(errQ)))
    delta = -lam_q - 2.0 * float(np.sum(mu)) * (1 + 4 * U)
    delta = delta * (1 - 8 * U) if delta > 0 else delta * (1 + 8 * U)
    trace = float(np.sum(np.trace(Z, axis1=1, axis2=2)))
    T = max(0.0, trace * (1 - gamma(2 * n * S + 2)) - abs(trace) * 4 * U)
    room = (margin * T * (1 - 4 * U) + delta)
    exact_zero = not np.any(E) and not np.any(errE)
    e_norm = 0.0 if exact_zero else (float(np.linalg.norm(E)) + float(np.linalg.norm(errE))) * (1 + 8 * U)
    bound, bound_any = _gain_bound(room, e_norm, exact_zero), _gain_bound(delta, e_norm, exact_zero)
    return FarkasCertificate(Z, bound, float(delta), e_norm, bool(room > 0), decay_rate=decay_rate,
                             margin=margin, gain_bound_any_margin=bound_any), room, prover


def _gain_bound(room: float, e_norm: float, exact_zero: bool) -> float:
    """``room / ||E||`` rounded down: designs with a smaller gain norm are excluded (0: none is)."""
    if room <= 0:
        return 0.0
    if exact_zero:
        return np.inf
    return float(room / e_norm * (1 - 4 * U))


def check_farkas_switched(multipliers: np.ndarray, free: np.ndarray, coef: np.ndarray, dfree=None, dcoef=None,
                          decay_rate: float | None = None, margin: float = 0.0) -> FarkasCertificate:
    """Re-check ``switched`` Farkas multipliers ``Z_{s,u}`` (S, S, 2n, 2n); solver-independent.

    The switched LMIs are ``M_{s,u} = [[Z + Z^T - S_s, (A_s Z)^T], [A_s Z, S_u]] >= 0``.
    With ``H = (Z + Z^T)/2`` and the multipliers' blocks::

        sum <Z_su, M_su> = <G, Z> + sum_s <C_s, S_s> + sum_j <E_j, Y_j>
        G   = 2 sum_su (Z11_su + free_s^T Z21_su)
        C_s = sum_u Z22_us - sum_u Z11_su
        E_j = 2 sum_su coef_{s,j}^T Z21_su

    Any feasible point has ``0 <= S_s <= 2 H``, so ``tr S_s <= 2 tr H`` and ``tr M_su <= 4 tr H``;
    hence ``delta tr H <= ||skew G||_F ||Z - H||_F + ||E||_F kappa ||Z||_F`` with
    ``delta = -lambda_max(sym G) - 2 sum_s max(lambda_max C_s, 0) - 4 sum mu_su``.
    A design with relative margin ``margin`` (``M_su >= margin tr(H) I``) adds ``margin T tr H`` on the
    left (``T`` a lower bound of the multipliers' total trace).
    ``gain_bound`` is stated for slacks with ``||Z||_F <= tr H`` (every symmetric PSD Z).
    """
    return _retry_exact(_farkas_switched, multipliers, free, coef, dfree, dcoef, decay_rate, margin)


def _farkas_switched(multipliers, free, coef, dfree, dcoef, decay_rate, margin, prover):
    Z = _sym(np.asarray(multipliers, dtype=np.float64))
    S = Z.shape[0]
    n = Z.shape[-1] // 2
    dfree = np.zeros_like(free) if dfree is None else dfree
    dcoef = np.zeros_like(coef) if dcoef is None else dcoef
    if not (np.all(np.isfinite(Z)) and np.all(np.isfinite(free)) and np.all(np.isfinite(coef))):
        return (FarkasCertificate(Z, 0.0, -np.inf, np.inf, False, method="switched", decay_rate=decay_rate),
                -np.inf, prover)
    Z11, Z21, Z22 = Z[..., :n, :n], Z[..., n:, :n], Z[..., n:, n:]
    FtZ = np.einsum("sba,subc->ac", free, Z21)  # sum_su free_s^T Z21_su
    Gm = 2 * (np.sum(Z11, axis=(0, 1)) + FtZ)
    absZ21 = np.abs(Z21)
    errG = 2 * gamma(n + 2 * S * S + 4) * (np.sum(np.abs(Z11), axis=(0, 1))
                                           + np.einsum("sba,subc->ac", np.abs(free), absZ21))
    errG = errG + 2 * np.einsum("sba,subc->ac", dfree, absZ21)
    symG, skewG = 0.5 * (Gm + Gm.T), 0.5 * (Gm - Gm.T)
    errG_norm = float(np.linalg.norm(errG))
    C = np.sum(np.swapaxes(Z22, 0, 1), axis=1) - np.sum(Z11, axis=1)  # C_s = sum_u Z22_us - sum_u Z11_su
    errC = gamma(2 * S + 2) * (np.sum(np.abs(Z22), axis=0) + np.sum(np.abs(Z11), axis=1))
    c_pos = sum(max(0.0, prover.max_upper(_sym(C[s]), float(np.linalg.norm(errC[s])))) for s in range(S))
    mu = float(np.sum(np.maximum(0.0, -prover.min_lower_many(Z.reshape(S * S, 2 * n, 2 * n)))))
    delta = -prover.max_upper(symG, errG_norm) - 2 * c_pos * (1 + 4 * U) - 4 * mu * (1 + 4 * U)
    delta = delta * (1 - 16 * U) if delta > 0 else delta * (1 + 16 * U)
    trace = float(np.sum(np.trace(Z, axis1=-2, axis2=-1)))
    T = max(0.0, trace * (1 - gamma(2 * n * S * S + 2)) - abs(trace) * 4 * U)
    skew = (float(np.linalg.norm(skewG)) + errG_norm) * (1 + 8 * U)
    E = 2 * np.einsum("sjab,suac->jbc", coef, Z21)
    errE = 2 * gamma(n + S * S + 2) * np.einsum("sjab,suac->jbc", np.abs(coef), absZ21)
    errE = errE + 2 * np.einsum("sjab,suac->jbc", dcoef, absZ21)
    exact_zero = not np.any(E) and not np.any(errE)
    e_norm = 0.0 if exact_zero else (float(np.linalg.norm(E)) + float(np.linalg.norm(errE))) * (1 + 8 * U)
    # ||Z||_F <= tr H and ||Z - H||_F <= ||Z||_F: delta > skew + e_norm kappa excludes the design.
    room = margin * T * (1 - 4 * U) + delta - skew
    bound, bound_any = _gain_bound(room, e_norm, exact_zero), _gain_bound(delta - skew, e_norm, exact_zero)
    return FarkasCertificate(Z, bound, float(delta), e_norm, bool(room > 0), method="switched",
                             skew_norm=skew, decay_rate=decay_rate, margin=margin,
                             gain_bound_any_margin=bound_any), room, prover


# ------------------------------------------------------------------ uncontrollable unstable modes
@dataclass
class UncontrollableCertificate:
    """An unstable plant mode no input reaches: no gains can stabilize the loop.

    Attributes
    ----------
    kind : str
        ``"uncontrollable"``.
    plant : int
        Plant mode l.
    eigenvalue : complex
        ``lambda`` with ``|lambda| >= 1`` (proven with the residuals).
    left_vector : ndarray, shape (n,), complex
        ``w`` with ``w^H F_l = lambda w^H`` and ``w^H G_l = 0`` up to the residuals.
    residual_eig, residual_input : float
        ``||w^H F_l - lambda w^H||_2`` and ``||w^H G_l||_2`` (with ``||w||_2 = 1``) in float64.
    verified : bool
        True iff exact rational arithmetic proved that the uncontrollable part of ``(F_l, G_l)``
        has an eigenvalue with ``|lambda| >= 1`` (or the rate); ``eigenvalue``, ``left_vector`` and
        the residuals are its float64 description.
    dimension : int
        Dimension of the uncontrollable subspace's quotient (exact).
    """

    plant: int
    eigenvalue: complex
    left_vector: np.ndarray
    residual_eig: float
    residual_input: float
    verified: bool
    dimension: int = 1
    kind: str = "uncontrollable"
    margin: float | None = None
    source: str = "left_eigenvector"
    decay_rate: float | None = None

    def statement(self) -> str:
        bound = "1" if self.decay_rate is None else f"the rate {self.decay_rate:.6g}"
        return (f"plant mode {self.plant} has eigenvalue {self.eigenvalue:.6g} (|lambda| = {abs(self.eigenvalue):.6g} "
                f">= {bound}, proven exactly) with a left eigenvector that no input reaches (residuals "
                f"{self.residual_eig:.2g}, {self.residual_input:.2g}): no gains achieve it")

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "verified": self.verified,
            "plant": self.plant,
            "eigenvalue": [float(np.real(self.eigenvalue)), float(np.imag(self.eigenvalue))],
            "left_vector": {"real": np.real(self.left_vector).tolist(), "imag": np.imag(self.left_vector).tolist()},
            "residual_eig": self.residual_eig,
            "residual_input": self.residual_input,
            "dimension": self.dimension,
            "statement": self.statement(),
        }


#: Relative PBH margin above which a plant mode is taken as controllable without the exact test.
PBH_SCREEN = 1e-5


def clearly_controllable(F: np.ndarray, G: np.ndarray) -> bool:
    """Float64 screen: whether every eigenvalue of F is far from uncontrollable (PBH test).

    An uncontrollable eigenvalue ``lambda_0`` (``w^H [F - lambda_0 I, G] = 0``) gives
    ``sigma_min([F - mu I, G]) <= |mu - lambda_0|`` at the computed eigenvalue ``mu``, which lies
    within about ``(u ||F||)^(1/k)`` of it (Jordan block of size k): a margin above
    ``PBH_SCREEN (||F||_F + ||G||_F)`` at every computed eigenvalue rules it out for k <= 3.  Not a
    verdict: False only sends the mode to the exact test (:func:`uncontrollable_mode`), and a missed
    proof leaves the design to its Farkas certificate or "not_converged", never to a wrong answer.
    """
    n, m = G.shape
    scale = float(np.linalg.norm(F) + np.linalg.norm(G))  # Frobenius: >= the 2-norms, cheaper
    if not np.isfinite(scale) or scale == 0:
        return False
    mus = np.linalg.eigvals(F)
    pbh = np.empty((n, n, n + m), dtype=complex)  # [F - mu I, G] for every computed eigenvalue, one batched SVD
    pbh[:, :, :n] = F[None] - mus[:, None, None] * np.eye(n)[None]
    pbh[:, :, n:] = G[None]
    return bool(np.all(np.linalg.svd(pbh, compute_uv=False)[:, -1] > PBH_SCREEN * scale))


#: :func:`clearly_controllable` by the plant mode's data: the screen does not depend on the rate, and the rate
#: search proves a refuted rate per probe (1 ms of a Farkas re-check's 5.4 ms at n = 8, five plant modes).
_SCREENED = BoundedCache(256)


def uncontrollable_mode(F: np.ndarray, G: np.ndarray, rate: float = 1.0) -> UncontrollableCertificate | None:
    """A proven unstable uncontrollable mode of some plant, or None.

    An eigenvalue ``lambda`` of ``F_l`` with left eigenvector ``w`` and ``w^H G_l = 0``
    is untouched by every input: ``w^H x(k)`` evolves as ``lambda^k w^H x(0)`` whatever the
    gains (the adversary may keep plant l forever), so ``|lambda| >= rate`` excludes every
    design with that per-sample rate, of every method.

    Plant modes that a float64 PBH screen shows clearly controllable (:func:`clearly_controllable`)
    are skipped: the proof is only looked for where one can exist.
    The proof is exact (docs/design.md): the controllable subspace of the float64 pair
    ``(F_l, G_l)`` and the map F induces on the quotient are computed in rational
    arithmetic, and a Schur-Cohn test on its characteristic polynomial proves that it has an
    eigenvalue with ``|lambda| >= rate``.  The float64 eigenvalue and left eigenvector
    ``w`` are reported with their residuals for the user to see.
    """
    from fractions import Fraction

    from . import exact

    F = np.asarray(F, dtype=np.float64)
    G = np.asarray(G, dtype=np.float64)
    n = F.shape[1]
    if n > 24:
        return None
    for l in range(F.shape[0]):
        key = (F[l].shape, G[l].shape, F[l].tobytes(), G[l].tobytes())
        if _SCREENED.get_or_compute(key, lambda: clearly_controllable(F[l], G[l])):
            continue
        part = exact.uncontrollable_part(F[l], G[l])
        if not part:
            continue
        poly = exact.charpoly_rational(part)
        if not exact.rational_radius_at_least(poly, Fraction(float(rate))):
            continue
        sub = np.array([[float(x) for x in row] for row in part])
        target = complex(max(np.linalg.eigvals(sub), key=abs))
        return UncontrollableCertificate(l, *describe_uncontrollable(F[l], G[l], target), True, dimension=len(part))
    return None


def describe_uncontrollable(F: np.ndarray, G: np.ndarray, target: complex) -> tuple:
    """The float64 description of a proven uncontrollable eigenvalue near ``target``.

    Returns ``(eigenvalue, w, residual_eig, residual_input)``: the eigenvalue of F closest to
    ``target``, its unit left eigenvector and the residuals (the proof itself is exact, elsewhere).
    """
    vals, vecs = np.linalg.eig(F.T)
    i = int(np.argmin(np.abs(vals - target)))
    w = vecs[:, i] / np.linalg.norm(vecs[:, i])
    r = float(np.linalg.norm(w.conj() @ F - vals[i] * w.conj()))
    ri = float(np.linalg.norm(w.conj() @ G))
    return complex(vals[i]), w, r, ri
