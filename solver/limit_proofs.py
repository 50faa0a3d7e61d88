"""Farkas proofs that no design meets input limits from a given initial state (docs/design.md §8).

An input-limited design (``u_max`` with ``x0``; also the cost design with ``u_max``) needs ``W > 0`` and the
scheme's free ``Y_j`` (``Theta_j = Y_j W^{-1}``) with, for every mode s, buffered gain q and input j::

    stability  L_s = [[W, (c_s A_s W)^T], [c_s A_s W, W]]   >= 0    c_s A_s W = free_s W + sum_j coef_{s,j} Y_j
    input      I_qj = [[u_j^2, (Y_q)_j], [(Y_q)_j^T, W]]    >= 0    Y_q = sum_j gain_map[q, j] Y_j
    x0         X    = [[1, x0^T], [x0, W]]                  >= 0

(``c_s = lambda^(-eta_s)`` at a decay rate lambda, 1 otherwise; ``{x : x' W^{-1} x <= 1}`` is the invariant
set.)  :func:`limits_multipliers` solves ``max t`` s.t. every block ``- t I >= 0``; when ``t* < 0`` its dual
multipliers, PSD with total trace 1, are a Farkas certificate: their adjoint vanishes in every (W, Y)
direction and ``sum_b <C_b, Z_b> = t* < 0`` (``C_b`` the constant parts ``u_j^2 e_1 e_1^T``, ``e_1 e_1^T``,
``[[0, x0^T], [x0, 0]]``).  :func:`check_limits_farkas` re-checks them from the plant data alone.

The multipliers are a :class:`LimitMultipliers`, whatever produced them: the structured IPM's phase-1
multipliers of the same max-t SDP (:func:`limits_multipliers`, ``solver="IPM"``; the default under ``"AUTO"``) or
the dual values of the max-t SDP through cvxpy and Clarabel (``solver="CLARABEL"``; ``"AUTO"``'s fallback when the
IPM's do not pass the re-check).  The re-check never asks which solver made them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .certificates import (
    EXACT_MAX_SIDE,
    Prover,
    U,
    _sym,
    gamma,
    interval_data,
    lambda_min_lower,
    stability_adjoint,
)
from .network import ModeSet


@dataclass
class LimitMultipliers:
    """PSD multipliers of the input-limited design's blocks (total trace 1).

    Attributes
    ----------
    stability : ndarray, shape (S, 2n, 2n)
        ``Z_s`` of ``L_s``, in the order of ``modes.plants``.
    inputs : ndarray, shape (n_drop, m, n + 1, n + 1)
        ``Z_qj`` of ``I_qj`` (first row/column: the ``u_j^2`` corner); zero for a gain the scheme keeps at 0.
    x0 : ndarray, shape (n + 1, n + 1)
        ``Z_x`` of the x0 block (first row/column: the ``1`` corner).
    t : float
        ``sum_b <C_b, Z_b>`` of these (normalized) multipliers, whichever solver made them: the SDP's ``t*`` in
        exact arithmetic; informative only, the check recomputes it with its rounding bounds.
    solver : str
        Who made them (``"IPM"``, ``"CLARABEL"``; empty: given by the caller); informative only.
    """

    stability: np.ndarray
    inputs: np.ndarray
    x0: np.ndarray
    t: float = float("nan")
    solver: str = ""


@dataclass
class LimitFarkasCertificate:
    """A re-checked proof that no design meets the input limits from ``x0``.

    Attributes
    ----------
    kind : str
        ``"farkas_limits"``.
    multipliers : LimitMultipliers
    verified : bool
        Whether the re-check passed (at ``margin``).
    any_margin : bool
        True when designs of every margin are excluded (the outcome "infeasible"); False when only designs
        whose blocks all hold with ``>= margin I`` are (the outcome "marginal").
    margin : float
        Absolute strictness of the excluded designs' blocks (0 with ``any_margin``).
    radius : float
        The proof excludes every design with ``trace W < radius^2`` (the sum of the squared semi-axes of the
        invariant ellipsoid ``x' W^{-1} x <= 1``); ``inf``: every design.
    constant : float
        Proven upper bound of ``sum_b <C_b, Z_b + mu_b I>`` (negative when verified).
    slope : float
        Proven upper bound of ``lambda_max(Q) + sum_b k_b mu_b`` (the ``trace W`` coefficient).
    e_bound : float
        Proven upper bound of ``||E||_F * ||Y||_F / sqrt(trace W)`` over every design meeting the limits.
    decay_rate : float or None
    u_max, x0 : ndarray
    """

    multipliers: LimitMultipliers
    verified: bool
    any_margin: bool
    margin: float
    radius: float
    constant: float
    slope: float
    e_bound: float
    decay_rate: float | None
    u_max: np.ndarray
    x0: np.ndarray
    kind: str = "farkas_limits"
    method: str = "lmi"
    scaled: bool = False

    def statement(self) -> str:
        rate = "" if self.decay_rate is None else f" at decay rate {self.decay_rate:.6g}"
        size = ("of any size" if np.isinf(self.radius)
                else f"whose squared semi-axes sum to less than {self.radius ** 2:.3g} (trace W)")
        what = (f"no gains with a common quadratic Lyapunov function{rate} keep |u_j| <= u_max[j] on an invariant "
                f"ellipsoid x' W^-1 x <= 1 containing x0, {size}")
        if self.any_margin:
            return f"{what} (Farkas certificate of the input limits, re-checked in float64)"
        return (f"marginal: {what}, whose LMI blocks hold with margin >= {self.margin:.3g}; designs with a smaller "
                "margin are not excluded (Farkas certificate of the input limits, re-checked in float64)")

    def to_dict(self) -> dict:
        m = self.multipliers
        return {
            "kind": self.kind,
            "method": self.method,
            "verified": self.verified,
            "any_margin": self.any_margin,
            "margin": self.margin,
            "radius": None if np.isinf(self.radius) else float(self.radius),
            "radius_unbounded": bool(np.isinf(self.radius)),
            "constant": self.constant,
            "slope": self.slope,
            "e_bound": self.e_bound,
            "decay_rate": self.decay_rate,
            "scaled": self.scaled,
            "statement": self.statement(),
            "u_max": self.u_max.tolist(),
            "x0": self.x0.tolist(),
            "limit_multipliers": {"stability": m.stability.tolist(), "inputs": m.inputs.tolist(), "x0": m.x0.tolist()},
        }


def _scale(modes: ModeSet, rate: float | None) -> np.ndarray:
    return np.ones(modes.n_modes) if rate is None else float(rate) ** (-modes.eta.astype(float))


# ------------------------------------------------------------------------------------- the check
def check_limits_farkas(modes: ModeSet, multipliers: LimitMultipliers, u_max, x0, decay_rate: float | None = None,
                        margin: float = 0.0) -> LimitFarkasCertificate:
    """Re-check Farkas multipliers of the input-limited design; independent of the solver that made them.

    The interval data are rebuilt from the plant (``modes.F``, ``modes.G``) with elementwise error bounds
    (:func:`solver.certificates.interval_data`).  For any ``(W, Y)`` whose blocks all hold with ``>= margin I``
    and shifts ``mu_b`` that make ``Z_b + mu_b I`` PSD (proven)::

        margin T <= sum_b <Z_b + mu_b I, F_b(W, Y)> = <Q, W> + sum_j <E_j, Y_j> + c + sum_b mu_b tr F_b
                 <= a tr W + e sqrt(tr W) + c'

    with ``Q, E`` the adjoint (zero in exact arithmetic for an exact certificate), ``tr F_b = k_b tr W +
    const_b`` (``k_b = 2`` for ``L_s``, 1 otherwise), ``a >= lambda_max(Q) + sum_b k_b mu_b``,
    ``c' >= c + sum_b mu_b const_b`` and ``e >= ||E||_F ||Y||_F / sqrt(tr W)``: the input blocks give
    ``||(Y_q)_j||_2^2 <= u_j^2 lambda_max(W)``, so ``||Y||_F^2 <= N' ||u||^2 tr W / lambda_min(M^T M)``
    (``N'`` gains the scheme does not fix at 0).  With ``s = sqrt(tr W)`` the right side is negative for
    ``0 <= s < radius``: every such design is excluded.

    Parameters
    ----------
    modes : ModeSet
        With the plant data (``modes.F``, ``modes.G``); user coordinates.
    multipliers : LimitMultipliers
    u_max : array_like, shape (m,)
    x0 : array_like, shape (n,)
    decay_rate : float, optional
        The rate of the stability blocks (``c_s = rate^(-eta_s)``).
    margin : float
        Strictness ``tau >= 0`` of the excluded designs (0: every design).

    Returns
    -------
    LimitFarkasCertificate
        ``verified`` when ``radius > 0`` (and ``radius`` at least ``sqrt(trace(x0 x0^T))``: the x0 block forces
        ``W >= x0 x0^T``, so a smaller radius excludes nothing).
    """
    cert, _ = _check(modes, multipliers, u_max, x0, decay_rate, margin, Prover(exact=False))
    if cert.verified and cert.any_margin:
        return cert
    n = modes.n_states
    if 2 * n <= EXACT_MAX_SIDE:  # the float bounds may have fallen short by their own slack: exact ones decide
        again, _ = _check(modes, multipliers, u_max, x0, decay_rate, margin, Prover(exact=True))
        if again.verified and (again.any_margin or not cert.verified):
            return again
    return cert


def _check(modes, mult, u_max, x0, decay_rate, margin, prover):
    n, m, N = modes.n_states, modes.n_inputs, modes.n_drop
    u = np.asarray(u_max, dtype=np.float64).reshape(m)
    x = np.asarray(x0, dtype=np.float64).reshape(n)
    Zs = _sym(np.asarray(mult.stability, dtype=np.float64))
    Zi = _sym(np.asarray(mult.inputs, dtype=np.float64))
    Zx = _sym(np.asarray(mult.x0, dtype=np.float64))
    M = np.asarray(modes.gain_map, dtype=np.float64)
    active = np.any(M != 0, axis=1)  # gains the scheme does not fix at zero: their input blocks exist
    S = Zs.shape[0]

    def fail():
        return LimitFarkasCertificate(mult, False, False, margin, 0.0, np.inf, np.inf, np.inf, decay_rate, u, x)

    shapes_ok = (Zs.shape == (modes.n_modes, 2 * n, 2 * n) and Zi.shape == (N, m, n + 1, n + 1)
                 and Zx.shape == (n + 1, n + 1))
    if not shapes_ok or not all(np.all(np.isfinite(a)) for a in (Zs, Zi, Zx)):
        return fail(), prover
    Zi = Zi * active[:, None, None, None]  # blocks that do not exist carry no multiplier
    free, dfree, coef, dcoef = interval_data(modes.F, modes.G, modes.plants, M, scale=_scale(modes, decay_rate))
    Q, errQ, E, errE = stability_adjoint(Zs, free, coef, dfree, dcoef)
    # the W corners of the input and x0 blocks: <Z_b, F_b> adds <Zw_b, W>
    Zw = Zi[:, :, 1:, 1:]
    abs_terms = np.abs(Q) + errQ + np.sum(np.abs(Zw), axis=(0, 1)) + np.abs(Zx[1:, 1:])
    Q = Q + np.sum(Zw, axis=(0, 1)) + Zx[1:, 1:]
    errQ = errQ + gamma(N * m + 2) * abs_terms
    # the Y entries of the input blocks: <Z_qj, I_qj> adds 2 (Y_q)_j z_qj, (Y_q)_j = sum_i M[q, i] (Y_i)_j
    z = Zi[:, :, 1:, 0]  # (N, m, n)
    Ein = 2 * np.einsum("qi,qjc->ijc", M, z)
    errEin = 2 * gamma(N + 2) * np.einsum("qi,qjc->ijc", np.abs(M), np.abs(z))
    E_tot = E + Ein
    errE_tot = errE + errEin + gamma(2) * (np.abs(E) + np.abs(Ein))
    # the constant parts: u_j^2 a_qj, and 1 a_x + 2 x0' z_x
    a_in = Zi[:, :, 0, 0]
    c_terms = np.concatenate([(a_in * u[None, :] ** 2).ravel(), [Zx[0, 0], 2 * float(x @ Zx[1:, 0])]])
    c = float(np.sum(c_terms))
    errc = gamma(N * m + n + 6) * (float(np.sum(np.abs(a_in) * u[None, :] ** 2)) + abs(Zx[0, 0])
                                   + 2 * float(np.abs(x) @ np.abs(Zx[1:, 0]))) + 2 * _TINY_ABS
    # PSD shifts
    mu_s = np.maximum(0.0, -prover.min_lower_many(Zs))
    small = np.concatenate([Zi[active].reshape(-1, n + 1, n + 1), Zx[None]])
    mu_small = np.maximum(0.0, -prover.min_lower_many(small))
    mu_in, mu_x = mu_small[:-1].reshape(int(active.sum()), m), float(mu_small[-1])
    slope = prover.max_upper(_sym(Q), float(np.linalg.norm(errQ)))
    slope = (slope + (2 * float(np.sum(mu_s)) + float(np.sum(mu_in)) + mu_x) * (1 + 4 * U)) * (1 + 8 * U) + _TINY_ABS
    const_mu = (float(np.sum(mu_in * u[None, :] ** 2)) + mu_x) * (1 + 8 * U)
    constant = (c + errc + const_mu) + 4 * U * (abs(c) + errc + const_mu)  # the two additions rounded
    # ||Y||_F <= kappa sqrt(tr W): kappa^2 = N' ||u||^2 / lambda_min(M^T M) (M^T M exact: small integers or
    # entries whose products round at most once per term; the bound allows for it)
    lam_M = lambda_min_lower(M.T @ M, gamma(N) * float(np.linalg.norm(np.abs(M).T @ np.abs(M))))
    if lam_M <= 0:
        return fail(), prover
    kappa = np.sqrt(float(active.sum()) * float(u @ u) / lam_M) * (1 + 16 * U)
    e_norm = (float(np.linalg.norm(E_tot)) + float(np.linalg.norm(errE_tot))) * (1 + 8 * U)
    e_bound = e_norm * kappa * (1 + 4 * U)
    trace = float(np.sum(np.trace(Zs, axis1=1, axis2=2)) + np.sum(np.trace(Zi, axis1=2, axis2=3))
                  + np.trace(Zx))
    T = max(0.0, trace * (1 - gamma(2 * n * (S + N * m + 1) + 2)))
    room = -(constant - margin * T * (1 - 4 * U))  # > 0 needed: s = 0 must be excluded
    radius = _radius(slope, e_bound, room)
    radius_any = _radius(slope, e_bound, -constant)
    floor = float(np.sqrt(x @ x))  # every design has tr W >= |x0|^2
    verified = radius > floor * (1 + 8 * U)
    any_margin = radius_any > floor * (1 + 8 * U)
    return LimitFarkasCertificate(mult, bool(verified), bool(any_margin), 0.0 if any_margin else margin,
                                  radius_any if any_margin else radius, float(constant), float(slope),
                                  float(e_bound), decay_rate, u, x), room


#: Absolute rounding floor (underflow of the products).
_TINY_ABS = 2.0 ** -1000


def _radius(a: float, e: float, room: float) -> float:
    """Largest ``R`` with ``a s^2 + e s - room < 0`` for all ``0 <= s < R`` (rounded down); 0 if ``room <= 0``."""
    if room <= 0:
        return 0.0
    disc = e * e + 4.0 * a * room
    disc += 8 * U * (e * e + 4.0 * abs(a) * room)  # an upper bound: a larger disc only shortens the radius
    if disc < 0:  # a < 0 and the parabola stays below zero: every s is excluded
        return np.inf
    denom = e + np.sqrt(disc)
    if denom <= 0:
        return np.inf
    return float(2.0 * room / denom * (1 - 16 * U))


# ------------------------------------------------------------------------------------- the SDP
def limits_multipliers(modes: ModeSet, u_max, x0, decay_rate: float | None = None,
                       time_limit: float | None = None, solver: str = "CLARABEL") -> LimitMultipliers | None:
    """Dual multipliers of ``max t`` s.t. every block of the input-limited design ``- t I >= 0``.

    Returns None when the solver fails or ``t*`` is not negative (the limits may be met: no proof to give).
    The multipliers are normalized to total trace 1 (the dual of ``max t`` has it in exact arithmetic).

    ``solver``: ``"IPM"``: the structured IPM's phase 1 (:func:`solver.ipm.performance_problem` with
    ``objective="limits"``, the same blocks); ``"CLARABEL"``: cvxpy and Clarabel.
    """
    if str(solver).upper() == "IPM":
        return _ipm_multipliers(modes, u_max, x0, decay_rate, time_limit)[0]
    from .compiled import cp, schur_block
    from .errors import SolverFailed
    from .brackets import solve_sdp

    n, m, N = modes.n_states, modes.n_inputs, modes.n_drop
    u = np.asarray(u_max, dtype=np.float64).reshape(m)
    x = np.asarray(x0, dtype=np.float64).reshape(n, 1)
    M = modes.gain_map
    free, _, coef, _ = interval_data(modes.F, modes.G, modes.plants, M, scale=_scale(modes, decay_rate))
    W = cp.Variable((n, n), symmetric=True)
    Y = [cp.Variable((m, n)) for _ in range(M.shape[1])]
    t = cp.Variable()
    stab, inp, x0c = [], {}, None
    for s in range(free.shape[0]):
        AW = free[s] @ W + sum(coef[s, j] @ Y[j] for j in range(M.shape[1]))
        stab.append(schur_block(W, AW, W) - t * np.eye(2 * n) >> 0)
    for q in range(N):
        if not np.any(M[q]):
            continue
        Yq = sum(M[q, j] * Y[j] for j in range(M.shape[1]) if M[q, j] != 0)
        for j in range(m):
            inp[q, j] = schur_block(np.array([[u[j] ** 2]]), Yq[j:j + 1, :].T, W) - t * np.eye(n + 1) >> 0
    x0c = schur_block(np.ones((1, 1)), x, W) - t * np.eye(n + 1) >> 0
    prob = cp.Problem(cp.Maximize(t), stab + list(inp.values()) + [x0c])
    try:
        info = solve_sdp(prob, "CLARABEL", time_limit)
    except SolverFailed:
        return None
    if info.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or t.value is None or not float(t.value) < 0:
        return None
    Zs = np.stack([np.asarray(c.dual_value, dtype=float) for c in stab])
    Zi = np.zeros((N, m, n + 1, n + 1))
    for (q, j), c in inp.items():
        Zi[q, j] = np.asarray(c.dual_value, dtype=float)
    Zx = np.asarray(x0c.dual_value, dtype=float)
    return _normalized(Zs, Zi, Zx, u, x.reshape(n), "CLARABEL")


def _normalized(Zs, Zi, Zx, u, x, solver: str) -> LimitMultipliers | None:
    """The multipliers scaled to total trace 1, with ``t = sum_b <C_b, Z_b>`` of the scaled ones (the constant
    parts ``u_j^2 e_1 e_1^T`` and ``[[1, x0^T], [x0, 0]]``): one normalization for every solver."""
    total = float(np.trace(Zs, axis1=1, axis2=2).sum() + np.trace(Zi, axis1=2, axis2=3).sum() + np.trace(Zx))
    if not np.isfinite(total) or total <= 0:
        return None
    Zs, Zi, Zx = Zs / total, Zi / total, Zx / total
    t = float(np.sum(Zi[:, :, 0, 0] * u[None, :] ** 2) + Zx[0, 0] + 2 * x @ Zx[1:, 0])
    return LimitMultipliers(Zs, Zi, Zx, t, solver)


def _ipm_multipliers(modes: ModeSet, u_max, x0, decay_rate, time_limit) -> tuple[LimitMultipliers | None, bool]:
    """Phase-1 multipliers of the structured IPM on the max-t SDP (see :func:`limits_multipliers`).

    Returns ``(multipliers, settled)``: ``settled`` is False when the IPM failed (another solver may try), True
    when it converged (with ``t* >= 0`` the multipliers are None: the limits may be met, no proof exists).
    """
    from . import ipm
    from .lifting import lift_modes

    n, m, N = modes.n_states, modes.n_inputs, modes.n_drop
    u = np.asarray(u_max, dtype=np.float64).reshape(m)
    x = np.asarray(x0, dtype=np.float64).reshape(n)
    lifted = lift_modes(modes, cost=False)
    prob = ipm.performance_problem(lifted, "limits", x, u, c=_scale(modes, decay_rate))
    try:
        sol = ipm.solve_grouped(prob.lmi, None, ipm.IPMOptions(gap_tol=1e-10, feas_tol=1e-10, max_iter=150,
                                                              time_limit=time_limit))
    except (np.linalg.LinAlgError, FloatingPointError, ValueError):
        return None, False
    if sol.status not in ("optimal", "inaccurate", "infeasible", "stalled"):
        return None, False
    if not sol.t_upper < 0:
        return None, True
    X = sol.X
    stab = np.asarray(X["stability"], dtype=np.float64)
    order = np.concatenate([np.asarray(prob.modes[g], dtype=int) for g in prob.modes])
    Zs = np.empty_like(stab)
    Zs[order] = stab  # the group's blocks in the order of ``prob.modes`` (the plants')
    Zi = np.zeros((N, m, n + 1, n + 1))
    for b, (q, j) in enumerate(prob.input_index):
        Zi[q, j] = X["input"][b]
    Zx = np.asarray(X["x0"][0], dtype=np.float64)
    mult = _normalized(Zs, Zi, Zx, u, x, "IPM")
    return mult, mult is not None


def prove_limits_infeasible(modes: ModeSet, u_max, x0, decay_rate: float | None = None, margin: float = 1e-6,
                            strict: float | None = None, multipliers: LimitMultipliers | None = None,
                            time_limit: float | None = None, solver: str = "AUTO"):
    """A re-checked proof that no input-limited design contains ``x0``, or ``(None, reason)``.

    Tried at ``decay_rate`` (None: the non-strict ``A_s' X A_s <= X``, every common quadratic Lyapunov
    function); when that SDP has ``t* >= 0`` and ``strict`` is given (a design whose stability blocks carry the
    factor ``1 + strict``), at the rate ``decay_rate (1 + strict)^(-1/n_drop)``, which every such design meets
    (``eta_s <= n_drop``); also when the first proof holds only with a margin.  Checked at margin 0 first
    (outcome "infeasible"), then at ``margin`` ("marginal"); a proof of any margin wins over a marginal one.

    Parameters
    ----------
    multipliers : LimitMultipliers, optional
        From any solver, for ``decay_rate`` (default: :func:`limits_multipliers`).
    solver : {"AUTO", "IPM", "CLARABEL"}
        Who makes the multipliers: ``"AUTO"`` the structured IPM, and Clarabel only when the IPM's give no proof
        at that rate; ``"IPM"``/``"CLARABEL"`` that one alone.
    """
    if x0 is None or u_max is None or modes.F is None:
        return None, "no x0 (a small enough ellipsoid always meets the limits)"
    rates = [decay_rate]
    if strict is not None and multipliers is None:
        rates.append((1.0 if decay_rate is None else float(decay_rate)) * (1 + strict) ** (-1.0 / modes.n_drop))
    reason = "the input-limit feasibility SDP did not report t* < 0"
    marginal = None  # a proof for designs of margin >= ``margin`` only: kept unless a stricter rate proves more
    for rate in rates:
        name = str(solver).upper()
        makers = [None] if multipliers is not None else ["IPM", "CLARABEL"] if name == "AUTO" else [name]
        for maker in makers:
            if maker == "IPM":
                mult, settled = _ipm_multipliers(modes, u_max, x0, rate, time_limit)
                if mult is None and settled:
                    break  # the IPM converged to t* >= 0: nothing to prove, no second solver asked
            else:
                mult = multipliers if maker is None else limits_multipliers(modes, u_max, x0, rate, time_limit, maker)
            if mult is None:
                continue
            cert = check_limits_farkas(modes, mult, u_max, x0, rate, 0.0)
            if cert.verified:
                return cert, ""
            if margin > 0 and marginal is None:
                cert = check_limits_farkas(modes, mult, u_max, x0, rate, margin)
                if cert.verified:
                    marginal = cert
                    break
            reason = (f"the input-limit multipliers do not pass the Farkas re-check (constant {cert.constant:.3g}, "
                      f"radius {cert.radius:.3g} <= |x0|)")
    return (marginal, "") if marginal is not None else (None, reason)
