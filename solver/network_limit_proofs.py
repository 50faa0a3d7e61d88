"""Farkas proofs that the input-limited network SDP has no solution (docs/design.md §11.3, "Refuting the limits").

The input-limited designs on a network (``u_max`` with ``x0``, plain stability or the Kothare cost form) need a
common slack ``Z`` (block diagonal, ``zb`` blocks), node matrices ``W_v`` and gains ``Y_j`` with::

    invariance  B_e = [[Z + Z' - W_v, (c_e A_e Z)'], [c_e A_e Z, W_w]] >= 0    every transition e: v -> w
    input       I_q = [[u_i^2, y_q], [y_q', Z + Z' - W_v]]          >= 0    every node v, gain j applied from v
                                                                             (reading slack block b), input i;
                                                                             y_q = row i of Y_j in block b
    x0          S_v = [[1, (S x0)'], [S x0, W_v]]                    >= 0    every node v

(``c_e = (1 + strict) rate^(-length_e)``, ``u_i`` the limit times ``1 - slack``: the constants the design's SDP
uses).  :func:`network_limit_multipliers` solves ``max t`` s.t. every block ``- t I >= 0``; when ``t* < 0`` its
dual multipliers (PSD, total trace 1) are a Farkas certificate, whichever solver made them (the structured IPM's
phase 1 on the Kothare model of :mod:`solver.ipm.network_performance_blocks`, or Clarabel through cvxpy).
:func:`check_network_limits` re-checks them on the problem's float64 data and never asks who made them.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .certificates import U, Prover, gamma

#: Absolute rounding floor (underflow of the products).
_TINY_ABS = 2.0 ** -1000


@dataclass
class NetworkLimitMultipliers:
    """PSD multipliers of the input-limited network SDP's blocks (total trace 1).

    Attributes
    ----------
    blocks : ndarray, shape (E, 2k, 2k)
        Of the invariance blocks ``B_e``, in the problem's transition order.
    inputs : ndarray, shape (Q, k + 1, k + 1)
        Of the input blocks, in the order of :func:`input_index` (first row/column: the ``u_i^2`` corner).
    x0 : ndarray, shape (V, k + 1, k + 1)
        Of the x0 blocks, one per node (first row/column: the ``1`` corner).
    t : float
        The SDP's ``t*``; informative only (the check recomputes the constant).
    solver : str
        Who made them; informative only.
    """

    blocks: np.ndarray
    inputs: np.ndarray
    x0: np.ndarray
    t: float = float("nan")
    solver: str = ""


@dataclass
class NetworkLimitCertificate:
    """A re-checked proof that the input-limited network SDP has no solution with ``||Z||_F < bound``.

    Attributes
    ----------
    multipliers : NetworkLimitMultipliers
    verified : bool
        ``bound > floor``: the excluded range ``floor <= ||Z||_F < bound`` is not empty (every solution has
        ``||Z||_F >= floor``); with a finite bound, solutions with ``||Z||_F >= bound`` are not excluded.
    bound : float
        No solution has ``||Z||_F < bound`` (``inf``: no solution at all).
    floor : float
        Every solution has ``||Z||_F >= floor`` (``tr W_v >= |S x0|^2`` and ``2 tr Z >= tr W_v``).
    constant, slope, e_bound : float
        Proven bounds of the certificate's constant (negative when verified), of the ``tr Z`` coefficient and
        of ``||E||_F ||Y||_F / sqrt(tr Z)`` (see :func:`check_network_limits`).
    form : str
    decay_rate : float or None
    u_max, x0 : ndarray
    strict, slack : float
        The constants of the refuted SDP (``c_e`` and ``u_i`` above).
    """

    multipliers: NetworkLimitMultipliers
    verified: bool
    bound: float
    floor: float
    constant: float
    slope: float
    e_bound: float
    form: str
    decay_rate: float | None
    u_max: np.ndarray
    x0: np.ndarray
    strict: float = 0.0
    slack: float = 0.0
    kind: str = "farkas_network_limits"
    method: str = "network_lmi"
    margin: float = 0.0
    any_margin: bool = True
    scaled: bool = False

    def statement(self) -> str:
        size = "of any size" if np.isinf(self.bound) else f"with ||Z||_F < {self.bound:.3g}"
        scope = "" if np.isinf(self.bound) else f" within ||Z||_F < {self.bound:.3g} (larger Z not excluded)"
        rate = "" if self.decay_rate is None else f" at decay rate {self.decay_rate:.6g}"
        as_solved = "" if not (self.strict or self.slack) else (
            f"; as the design states it: invariance blocks {1 + self.strict:.6g} times stricter, limits "
            f"{1 - self.slack:.6g} u_max")
        return (f"not certified: the input-limited network SDP ({self.form} form: node ellipsoids "
                f"x' W_v^-1 x <= 1 invariant along every admissible run{rate} through a common slack Z, "
                f"|u_i| <= u_max_i on them, x0's history in every one{as_solved}) has no solution {size} (every "
                f"solution has ||Z||_F >= {self.floor:.3g}; Farkas certificate re-checked in float64); this excludes that "
                f"sufficient condition with these limits{scope}, not every gain")

    def to_dict(self) -> dict:
        m = self.multipliers
        return {"kind": self.kind, "method": self.method, "form": self.form, "verified": self.verified,
                "bound": None if np.isinf(self.bound) else float(self.bound),
                "bound_unbounded": bool(np.isinf(self.bound)), "floor": self.floor, "constant": self.constant,
                "slope": self.slope, "e_bound": self.e_bound, "decay_rate": self.decay_rate,
                "strict": self.strict, "slack": self.slack, "u_max": self.u_max.tolist(), "x0": self.x0.tolist(),
                "statement": self.statement(),
                "limit_multipliers": {"blocks": m.blocks.tolist(), "inputs": m.inputs.tolist(),
                                      "x0": m.x0.tolist()}}


def input_index(prob) -> list[tuple[int, int, int, int]]:
    """The input blocks ``(v, j, b, i)``: node v, gain ``K_(j+1)`` reading slack block b, input i."""
    from .methods.network_performance import gain_rows

    return [(v, j, b, i) for v, pairs in enumerate(gain_rows(prob)) for j, b in pairs for i in range(prob.m)]


def _scales(prob, rate: float | None, strict: float) -> np.ndarray:
    c = np.ones(prob.n_blocks) if rate is None else float(rate) ** (-prob.length.astype(float))
    return c * (1 + strict)


# ------------------------------------------------------------------------------------- the check
def check_network_limits(prob, multipliers: NetworkLimitMultipliers, u_max, x0, history: np.ndarray,
                         decay_rate: float | None = None, strict: float = 0.0,
                         slack: float = 0.0) -> NetworkLimitCertificate:
    """Re-check Farkas multipliers of the input-limited network SDP on ``prob``'s float64 data.

    For shifts ``mu`` that make every multiplier plus ``mu I`` PSD (proven) and any solution (all blocks PSD),
    with ``H = (Z + Z')/2`` (PSD: ``2 H >= W_v >= (S x0)(S x0)' >= 0``; ``T = tr H = tr Z``)::

        0 <= sum_b <X_b + mu_b I, F_b> = <G, Z> + sum_v <C_v, W_v> + sum_j <E_j, Y_j> + c + sum_b mu_b tr F_b
          <= a T + sigma ||Z||_F + e sqrt(T) + c'

    ``G`` only on the slack's diagonal blocks (``<G_sym, H> <= max_b lambda_max(G_b,sym) T``, ``sigma =
    ||G_skew||_F``); ``<C_v, W_v> <= lambda_max(C_v)^+ 2T``; ``tr B_e <= 4T``, ``tr I_q <= u_i^2 + 2T``,
    ``tr S_v <= 1 + 2T``; each row of an applied gain meets ``|y|^2 <= u_i^2 lambda_max(Z + Z' - W_v) <= 2 u_i^2 T``
    (its input block), so ``||Y||_F <= kappa sqrt(T)``.  With ``T <= sqrt(k) ||Z||_F`` and ``r = ||Z||_F^(1/2)``
    the right side is ``(a^+ sqrt(k) + sigma) r^2 + e k^(1/4) r + c'``, negative for ``r`` below the root when
    ``c' < 0``: no solution has ``||Z||_F < bound``.
    """
    from .methods.network_lmi import slack_pairing, transition_adjoint

    k, n, m, N, E, V = prob.k, prob.n, prob.m, prob.N, prob.n_blocks, len(prob.nodes)
    idx = input_index(prob)
    u = np.asarray(u_max, float).reshape(m) * (1 - slack)
    x = np.asarray(x0, float).reshape(n)
    s = np.asarray(history, float) @ x
    c_e = _scales(prob, decay_rate, strict)
    Mb = np.asarray(multipliers.blocks, float)
    Mi = np.asarray(multipliers.inputs, float)
    Mx = np.asarray(multipliers.x0, float)
    floor = float(s @ s) / (2 * np.sqrt(k)) * (1 - 8 * U)

    def result(ok, bound, constant, slope, e_bound):
        return NetworkLimitCertificate(multipliers, bool(ok), float(bound), floor, float(constant), float(slope),
                                       float(e_bound), prob.form, decay_rate, np.asarray(u_max, float).reshape(m),
                                       x, strict, slack)

    if (Mb.shape != (E, 2 * k, 2 * k) or Mi.shape != (len(idx), k + 1, k + 1) or Mx.shape != (V, k + 1, k + 1)
            or not all(np.all(np.isfinite(a)) for a in (Mb, Mi, Mx))):
        return result(False, 0.0, np.inf, np.inf, np.inf)
    Mb = 0.5 * (Mb + np.swapaxes(Mb, 1, 2))
    Mi = 0.5 * (Mi + np.swapaxes(Mi, 1, 2))
    Mx = 0.5 * (Mx + np.swapaxes(Mx, 1, 2))
    prover = Prover(exact=False)
    g = gamma(2 * k + 2 * E + 2 * len(idx) + V + 8)
    G, errG, C, errC, Ej, errE = transition_adjoint(prob, Mb, c_e, g)  # sum_e <M_e, B_e>
    const_terms = []
    for q, (v, j, b, i) in enumerate(idx):  # <J_q, I_q> = a u_i^2 + 2 z.y + <J22, Z + Z' - W_v>
        J22 = Mi[q, 1:, 1:]
        G += 2 * J22
        errG += g * 2 * np.abs(J22)
        C[v] -= J22
        errC[v] += g * np.abs(J22)
        Ej[j, i] += 2 * Mi[q, 1 + b * n:1 + (b + 1) * n, 0]
        const_terms.append(Mi[q, 0, 0] * u[i] ** 2)
    for v in range(V):  # <X_v, S_v> = a + 2 s.z + <X22, W_v>
        C[v] += Mx[v, 1:, 1:]
        errC[v] += g * np.abs(Mx[v, 1:, 1:])
        const_terms += [Mx[v, 0, 0], 2 * float(s @ Mx[v, 1:, 0])]
    const_terms = np.asarray(const_terms, float)
    c = float(np.sum(const_terms))
    errc = g * float(np.sum(np.abs(const_terms))) * 4 + 2 * _TINY_ABS
    # PSD shifts
    mu_b = np.maximum(0.0, -prover.min_lower_many(Mb)) if E else np.zeros(0)
    mu_i = np.maximum(0.0, -prover.min_lower_many(Mi)) if len(idx) else np.zeros(0)
    mu_x = np.maximum(0.0, -prover.min_lower_many(Mx))
    # the slack is block diagonal: only G's diagonal blocks pair with it
    lams, sigma = slack_pairing(prob, G, errG, prover)
    lam_c = sum(max(0.0, prover.max_upper(0.5 * (C[v] + C[v].T), float(np.linalg.norm(errC[v]))
                                          + g * float(np.linalg.norm(C[v])))) for v in range(V))
    slope = (max(lams) + 2 * lam_c + 4 * float(np.sum(mu_b)) + 2 * float(np.sum(mu_i)) + 2 * float(np.sum(mu_x)))
    slope = slope * (1 + 8 * U) + _TINY_ABS if slope > 0 else slope * (1 - 8 * U) + _TINY_ABS
    u_idx = np.array([u[i] for *_, i in idx])
    const_mu = (float(np.sum(mu_i * u_idx ** 2)) + float(np.sum(mu_x))) * (1 + 8 * U)
    constant = (c + errc + const_mu) + 4 * U * (abs(c) + errc + const_mu)
    # ||Y||_F^2 <= 2 T sum over applied gains j and inputs i of u_i^2 (every applied gain has its input blocks)
    rows = {(j, i) for _, j, _, i in idx}
    kappa = np.sqrt(2 * float(sum(u[i] ** 2 for _, i in rows))) * (1 + 16 * U)
    applied = sorted({j for j, _ in rows})
    absent = [j for j in range(N) if j not in applied]
    if absent and (np.any(Ej[absent]) or np.any(errE[absent])):  # a gain no input block bounds: no proof
        return result(False, 0.0, constant, slope, np.inf)
    e_norm = (float(np.linalg.norm(Ej[applied])) + float(np.linalg.norm(errE[applied]))) * (1 + 8 * U)
    e_bound = e_norm * kappa * (1 + 4 * U)
    a2 = (max(slope, 0.0) * np.sqrt(k) + sigma) * (1 + 8 * U)
    b1 = e_bound * k ** 0.25 * (1 + 8 * U)
    r = _radius(a2, b1, -constant)
    bound = r * r * (1 - 4 * U) if np.isfinite(r) else np.inf
    return result(bound > floor * (1 + 8 * U), bound, constant, slope, e_bound)


def _radius(a: float, e: float, room: float) -> float:
    """Largest ``R`` with ``a r^2 + e r - room < 0`` for all ``0 <= r < R`` (``a, e >= 0``; rounded down)."""
    if room <= 0:
        return 0.0
    if a == 0 and e == 0:
        return np.inf
    disc = (e * e + 4.0 * a * room) * (1 + 8 * U)
    return float(2.0 * room / (e + np.sqrt(disc)) * (1 - 16 * U))


# ------------------------------------------------------------------------------------- the multipliers
def network_limit_multipliers(family, network, u_max, x0, decay_rate: float | None = None, strict: float = 0.0,
                              slack: float = 0.0, plant_switching: str = "per_interval", solver: str = "CLARABEL",
                              time_limit: float | None = None) -> NetworkLimitMultipliers | None:
    """Dual multipliers of ``max t`` s.t. every block of the input-limited network SDP ``- t I >= 0``.

    ``solver``: ``"IPM"``: the structured IPM's phase 1 on the Kothare model of
    :mod:`solver.ipm.network_performance_blocks` (its cost blocks' leading ``2k x 2k`` parts are the invariance
    blocks; the cost rows' tail, whose multiplier the free ``g`` forces to zero, is dropped, its rounding left to
    the check); ``"CLARABEL"``: cvxpy and Clarabel.  None when the solver fails or ``t*`` is not negative.
    Rate given: IPM unavailable (the Kothare model has no rate), Clarabel is used.
    """
    from .methods import network_lmi
    from .methods.network_performance import channels

    ch = channels(family, network, "cost", plant_switching=plant_switching)
    prob = ch.prob
    u = np.asarray(u_max, float)
    x = np.asarray(x0, float)
    if str(solver).upper() == "IPM" and decay_rate is None:
        return _ipm_multipliers(ch, u, x, strict, slack, time_limit)
    from .compiled import cp
    from .methods.network_performance import Rows

    n, k = prob.n, prob.k
    c_e = _scales(prob, decay_rate, strict)
    _, Z, W, Y = network_lmi.cvx_variables(prob)
    t = cp.Variable()
    blocks, inputs, starts = [], [], []
    for e in range(prob.n_blocks):
        AZ = Rows(prob.free[e], prob.coef[e], prob.right[e]).times_z(Z, Y, n, prob.zblocks)
        B = cp.bmat([[Z + Z.T - W[prob.src[e]], c_e[e] * AZ.T], [c_e[e] * AZ, W[prob.dst[e]]]])
        blocks.append(0.5 * (B + B.T) - t * np.eye(2 * k) >> 0)
    for v, j, b, i in input_index(prob):
        row = Y[j][i:i + 1, :]
        if prob.zblocks > 1:
            row = cp.hstack([row if col == b else np.zeros((1, n)) for col in range(prob.zblocks)])
        H = Z + Z.T - W[v]
        I = cp.bmat([[np.array([[(u[i] * (1 - slack)) ** 2]]), row], [row.T, H]])
        inputs.append(0.5 * (I + I.T) - t * np.eye(k + 1) >> 0)
    sx = (ch.history @ x).reshape(-1, 1)
    for v in range(len(prob.nodes)):
        starts.append(cp.bmat([[np.ones((1, 1)), sx.T], [sx, W[v]]]) - t * np.eye(k + 1) >> 0)
    problem = cp.Problem(cp.Maximize(t), blocks + inputs + starts)
    try:
        with warnings.catch_warnings():  # an inaccurate answer is a proposal like any other: re-checked
            warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=cp.CLARABEL, **({} if time_limit is None else {"time_limit": float(max(
                time_limit, 1e-3))}))
    except cp.error.SolverError:
        return None
    if problem.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or t.value is None or not float(t.value) < 0:
        return None
    Mb = np.stack([np.asarray(con.dual_value, float) for con in blocks])
    Mi = np.stack([np.asarray(con.dual_value, float) for con in inputs]) if inputs else np.zeros((0, k + 1, k + 1))
    Mx = np.stack([np.asarray(con.dual_value, float) for con in starts])
    return _normalized(Mb, Mi, Mx, float(t.value), "CLARABEL")


def _normalized(Mb, Mi, Mx, t, solver):
    total = float(np.trace(Mb, axis1=1, axis2=2).sum() + np.trace(Mi, axis1=1, axis2=2).sum()
                  + np.trace(Mx, axis1=1, axis2=2).sum())
    if not np.isfinite(total) or total <= 0:
        return None
    return NetworkLimitMultipliers(Mb / total, Mi / total, Mx / total, t / total, solver)


def _ipm_multipliers(ch, u, x, strict, slack, time_limit):
    """Phase-1 multipliers of the structured IPM on the Kothare model (see :func:`network_limit_multipliers`)."""
    from .ipm import IPMOptions
    from .ipm.algorithm import solve_grouped
    from .ipm.network_performance_blocks import network_performance_problem

    prob = ch.prob
    k = prob.k
    model = network_performance_problem(ch, "cost", x, u, strict=strict, limit_slack=slack)
    try:
        sol = solve_grouped(model.lmi, None, IPMOptions(gap_tol=1e-10, feas_tol=1e-10, max_iter=150,
                                                        time_limit=time_limit))
    except (np.linalg.LinAlgError, FloatingPointError, ValueError):
        return None
    if sol.status not in ("optimal", "inaccurate", "infeasible", "stalled") or not sol.t_upper < 0:
        return None
    if list(model.input_index) != input_index(prob) or not np.array_equal(model.start, np.arange(len(prob.nodes))):
        return None
    Mb = np.asarray(sol.X["cost"], float)[:, :2 * k, :2 * k]
    Mi = np.asarray(sol.X["input"], float) if "input" in sol.X else np.zeros((0, k + 1, k + 1))
    Mx = np.asarray(sol.X["start"], float)
    return _normalized(Mb, Mi, Mx, float(sol.t_upper), "IPM")


def prove_network_limits(family, network, u_max, x0, decay_rate: float | None = None, strict: float = 0.0,
                         slack: float = 0.0, plant_switching: str = "per_interval", solver: str = "AUTO",
                         time_limit: float | None = None):
    """A re-checked :class:`NetworkLimitCertificate`, or ``(None, reason)``.

    ``solver``: ``"AUTO"`` the IPM's multipliers, then Clarabel's when those do not pass; ``"IPM"``,
    ``"CLARABEL"`` (any other name: Clarabel) that one alone.  The check runs on the problem rebuilt from
    ``family`` (user coordinates).
    """
    from .methods import network_lmi
    from .methods.network_performance import initial_history

    if x0 is None:
        return None, "no x0 (a small enough ellipsoid always meets the limits)"
    prob = network_lmi.build_problem(family, network, plant_switching)
    name = str(solver).upper()
    makers = ["IPM", "CLARABEL"] if name == "AUTO" else ["IPM"] if name == "IPM" else ["CLARABEL"]
    reason = "the input-limit feasibility SDP did not report t* < 0"
    for maker in makers:
        mult = network_limit_multipliers(family, network, u_max, x0, decay_rate, strict, slack, plant_switching,
                                         maker, time_limit)
        if mult is None:
            continue
        cert = check_network_limits(prob, mult, u_max, x0, initial_history(prob), decay_rate, strict, slack)
        if cert.verified:
            return cert, ""
        reason = (f"the input-limit multipliers ({maker}) do not pass the Farkas re-check (constant "
                  f"{cert.constant:.3g}, bound {cert.bound:.3g} <= floor {cert.floor:.3g})")
    return None, reason
