"""Designs for a performance objective or input limits (docs/design.md, "Performance designs").

With ``W = P^{-1}`` (``X^{-1}``) and ``Y_j = Theta_j W`` every block below is affine in (W, Y) and a few
scalars; the lifted data come from :mod:`solver.lifting` (``rows.times_w(W, Y)`` is ``rows(K) W``):

* cost (trace):  ``[[W, V_s'], [V_s, diag(W, I)]] >= 0``, ``V_s = [A_s W; L_s W]``, ``[[Z, I], [I, W]] >= 0``,
  minimize ``trace Z`` (``Z >= P``);
* cost (x0):     ``[[W, V_s'], [V_s, diag(W, gamma I)]] >= 0``, ``[[1, x0'], [x0, W]] >= 0``, minimize
  gamma; ``P = gamma W^{-1}`` and ``x0' P x0 <= gamma`` (the invariant set is ``x' W^{-1} x <= 1``);
* hinf:          ``[[diag(W, g I), U_s'], [U_s, diag(W, I)]] >= 0``, ``U_s = [[A_s W, B_s], [C_s W, D_s]]``,
  minimize ``g = gamma^2``;
* input limits:  ``[[u_j^2, (Y_q)_j], [(Y_q)_j', W]] >= 0`` for every buffered gain q and input j; with
  the plain objective the stability blocks ``[[W, c_s (A_s W)'], [c_s A_s W, W]] >= 0`` and
  ``max tau`` s.t. ``W >= tau I`` (the largest ball inside the invariant ellipsoid), x0 inside when given.

Every figure the result reports passes the float64 re-checks of :mod:`solver.brackets`.
Solved by the structured IPM (:mod:`solver.ipm.performance_blocks`, the same blocks; ``solver="AUTO"``, ``"IPM"``)
or by Clarabel through cvxpy (``"CLARABEL"``, tight tolerances; under ``"AUTO"`` a second proposal when the
IPM's does not certify).  :func:`run` works in whatever coordinates its lifted data are in; ``design`` hands it the
balanced ones (:class:`solver.scaling.PerformanceScaling`) and maps the answer back.
"""

from __future__ import annotations

import time
import warnings

import cvxpy as cp
import numpy as np
import scipy.linalg

from .. import compiled
from ..compiled import SolveInfo, check_memory, ipm_memory, out_of_time, schur_block, time_left
from ..errors import SolverFailed
from ..errors import InvalidInput
from ..exact import floats, fractions
from ..lifting import Lifted, check_u_max, lift_modes
from ..brackets import (EXACT_COST_MAX_N, bracket, check_cost, check_cost_exact, check_hinf_exact, check_invariant,
                        check_x0, limits_note, lyapunov, solve_sdp)
from ..result import DesignResult, IterationRecord
from . import lmi
from .common import DesignOptions, RunClock, certify_gains, congruent_scale, finish, proof_outcome

#: Extra strictness of the stability blocks of an input-limited design (the ellipsoid shrinks by it).
STRICT = 1e-5
OBJECTIVES = ("stability", "cost", "hinf")
#: Relative slack on the optimal x0 cost allowed to the tie-break stage (min trace P among x0-optimal designs).
TIE_BREAK = 1e-9
#: The IPM tie-break's first weight relative to gamma_1 / trace P_1 (paper example and random 3-state families:
#: gamma rises by 1e-10 to 1e-9 relative at 1e-4, near the cap of TIE_BREAK).
TIE_WEIGHT = 1e-4
#: Solves of the IPM tie-break at most, and the fraction of the cap's room that ends the search early.
TIE_SOLVES = 3
TIE_WINDOW = 0.2
#: Relative slack on u_max inside the SDP (the re-check uses u_max itself).
LIMIT_SLACK = 1e-6
#: The IPM's gap and residual tolerances here: the LQR reproduction (gains to 1e-6) needs about 1e-10
#: (the gains' error is ~1e4 times the gap), as it needs Clarabel's tolerances at 1e-11.
IPM_TOL = 1e-11
#: Largest semi-axis of the invariant ellipsoid the plain input-limited design looks for (times max(1, |x0|)).
MAX_RADIUS = 1e3
#: The max-tau SDP's first stage stops at this relative gap and primal residual (docs/design.md §8.3.3): it only
#: gives the ellipsoid's shape (n = 8, x0: 1e-1 66 + 53 iterations, 1e-3 74 + 51, 1e-2 69 + 58; 0.5 ended with
#: tau < 0 at n = 12); the second starts from its point with tau backed off to RECENTRE_BACK of its value.
RECENTRE_GAP = 1e-1
RECENTRE_FEAS = 1e-6
RECENTRE_BACK = 0.9
#: ... and its objective's solve (after phase 1) stops after this many iterations (docs/design.md §8.3.3: from x0 its
#: free tau runs off to -8e11 in 100 iterations at n = 12; the final tau is the same to 1e-8 after 10, 20, 30 or 100:
#: n = 8 / 12 / 20 take 93 / 98 / 91 iterations in all instead of 113 / 142 / 152, 94 / 98 / 126 with x0 instead of
#: 119 / 179 / 177).
RECENTRE_ITER = 10
#: Cost and hinf SDPs switch to the state coordinates of their iterate's W at this relative gap and primal residual
#: (docs/design.md §8.3.2): by then W has its answer's shape (n = 12: the switch at 1e-1, 1e-2 or 1e-3 gives the
#: same answer in 11, 7 and 7 more iterations), and in the original coordinates the multipliers' size (~P^2,
#: 1e5) let the rounding of the Newton step's ``X dS S^-1`` floor the primal residual at 1e-6..1e-5.
SWITCH_GAP = 1e-2
SWITCH_FEAS = 1e-6
#: Mehrotra's centring power per objective (``IPMOptions.sigma_power``, default 3; docs/design.md §8.3.2): the hinf
#: SDP's short primal steps came from poor centrality, and more centring cut its iterations (n = 12: 45 + 10 ->
#: 35 + 7, same optimum); the cost SDP's rose with it (n = 10 / 12: 36 -> 38).
SIGMA_POWER = {"hinf": 2.0}


def _blkdiag(*blocks):
    rows = []
    sizes = [b.shape[0] for b in blocks]
    for i, b in enumerate(blocks):
        rows.append([b if i == j else np.zeros((sizes[i], sizes[j])) for j in range(len(blocks))])
    return cp.bmat(rows)


def _gains_of(modes, W: np.ndarray, Y: list) -> np.ndarray:
    theta = np.stack([np.linalg.solve(W, y.T).T for y in Y])  # Theta_j = Y_j W^{-1} (W symmetric)
    return modes.expand(theta)


def input_blocks(modes, W, Y, u_max: np.ndarray, level=None) -> list:
    """``[[u_j^2, (Y_q)_j], [(Y_q)_j', W]] >= 0`` for every gain K_q of the buffer and input j."""
    cons = []
    M = modes.gain_map
    for q in range(modes.n_drop):
        Yq = sum(M[q, j] * Y[j] for j in range(M.shape[1]) if M[q, j] != 0)
        if isinstance(Yq, int):  # K_q = 0 under this scheme
            continue
        for j, u in enumerate(u_max):
            row = Yq[j:j + 1, :]
            # a hair inside the limit, so that x0 on the set's boundary survives the re-check's rounding
            cons.append(schur_block(np.array([[(u * (1 - LIMIT_SLACK))**2]]), row.T, W) >> 0)
    return cons


def build(lifted: Lifted, objective: str, x0, u_max, rate: float | None, cap: float | None = None,
          trace_weight: np.ndarray | None = None):
    """The cvxpy problem and the variables ``(problem, W, Y, extra)`` of one design.

    ``cap`` (cost from x0 without limits): the tie-break stage, ``min trace P`` among designs with
    ``x0' P x0 <= cap`` (only x0' P x0 is optimized otherwise, so P and the gains are not unique).
    ``trace_weight``: ``sum_i w_i Z_ii`` for ``trace Z`` (the user's trace in balanced coordinates).
    """
    modes = lifted.modes
    n, m, J = modes.n_states, modes.n_inputs, modes.n_free_gains
    W = cp.Variable((n, n), symmetric=True)
    Y = [cp.Variable((m, n)) for _ in range(J)]
    M = modes.gain_map
    cons, extra = [], {}
    if objective == "cost":
        # with input limits the Kothare form (P = gamma W^{-1}): its W also shapes the invariant set;
        # without them the plain form (P = W^{-1})
        kothare = u_max is not None
        gamma = cp.Variable()
        for lm in lifted.lifted:
            V = cp.vstack([lm.state.times_w(W, Y, M), lm.cost.times_w(W, Y, M)])
            k = lm.cost.free.shape[0]
            tail = gamma * np.eye(k) if kothare else np.eye(k)
            cons.append(schur_block(W, V, _blkdiag(W, tail)) >> 0)
        if x0 is None:
            Z = cp.Variable((n, n), symmetric=True)
            cons.append(schur_block(Z, np.eye(n), W) >> 0)
            objective_expr, extra["Z"] = cp.Minimize(cp.trace(Z)), Z
        else:
            level = np.ones((1, 1)) if kothare else cp.reshape(gamma, (1, 1), order="C")
            cons.append(schur_block(level, x0.reshape(-1, 1), W) >> 0)
            objective_expr = cp.Minimize(gamma)
            if cap is not None:
                Z = cp.Variable((n, n), symmetric=True)
                cons += [schur_block(Z, np.eye(n), W) >> 0, gamma <= cap]
                objective_expr = cp.Minimize(cp.trace(Z))
        extra["kothare"] = kothare
        extra["gamma"] = gamma
        if trace_weight is not None and "Z" in extra:
            objective_expr = cp.Minimize(cp.sum(cp.multiply(trace_weight, cp.diag(extra["Z"]))))
    elif objective == "hinf":
        g = cp.Variable()
        for lm in lifted.lifted:
            U = cp.bmat([[lm.state.times_w(W, Y, M), lm.B], [lm.output.times_w(W, Y, M), lm.D]])
            top = _blkdiag(W, g * np.eye(lm.B.shape[1]))
            cons.append(schur_block(top, U, _blkdiag(W, np.eye(lm.D.shape[0]))) >> 0)
        objective_expr, extra["g"] = cp.Minimize(g), g
    else:
        c = congruent_scale(modes, rate) * (1 + STRICT)
        for s, lm in enumerate(lifted.lifted):
            cons.append(schur_block(W, c[s] * lm.state.times_w(W, Y, M), W) >> 0)
        # K = 0 may keep an open-loop stable plant inside any ellipsoid: cap the radius so the SDP is bounded
        radius = MAX_RADIUS * (1.0 if x0 is None else max(1.0, float(np.linalg.norm(x0))))
        cons.append(W << radius**2 * np.eye(n))
        # the largest ball inside the invariant ellipsoid (the IPM's objective too; docs/design.md §8.3)
        tau = cp.Variable()
        cons.append(W >> tau * np.eye(n))
        objective_expr = cp.Maximize(tau)
    if u_max is not None:
        cons += input_blocks(modes, W, Y, u_max)
    if x0 is not None and u_max is not None and objective != "cost":
        cons.append(schur_block(np.ones((1, 1)), x0.reshape(-1, 1), W) >> 0)
    return cp.Problem(objective_expr, cons), W, Y, extra


def _ipm_status(status: str) -> str | None:
    return {"optimal": cp.OPTIMAL, "inaccurate": cp.OPTIMAL_INACCURATE, "infeasible": cp.INFEASIBLE}.get(status)


def solve(lifted: Lifted, objective: str, x0, u_max, rate: float | None, solver: str,
          time_limit: float | None = None, cap: float | None = None, trace_weight: np.ndarray | None = None,
          tie_weight: float | None = None, fallback: bool = True):
    """Build and solve one design SDP: ``(info, W, Y, scalars)`` (``W``, ``Y`` None without an answer).

    The tie-break stage (cost from x0): ``cap`` for cvxpy (``min trace Z`` s.t. ``gamma <= cap``), ``tie_weight``
    for the IPM (``min gamma + tie_weight trace Z``, the same guarantee, see :func:`_propose`).

    ``solver``: ``"AUTO"``/``"IPM"``: the structured IPM (:func:`solver.ipm.solve_performance`), returning
    phase 2's last (strictly feasible) iterate when phase 2 did not converge (``info.status`` says so: the
    re-checks judge it, and :func:`run` asks Clarabel too under ``"AUTO"`` when it does not certify);
    ``"AUTO"`` falls back to Clarabel when the IPM ends without an iterate or a proof (``fallback``; else it
    returns no answer, for :func:`run` to decide), ``"IPM"`` raises :class:`SolverFailed` then;
    ``"CLARABEL"``/``"SCS"``: cvxpy.
    ``scalars``: ``gamma`` (cost from x0), ``g`` (hinf) as floats when the problem has them.  ``info.setup``
    holds the seconds spent building the problem (cvxpy's canonicalization included).
    """
    from .. import ipm

    name = str(solver).upper()
    start = time.perf_counter()
    # The tie-break stage's feasible set with the cap is a slice of relative width TIE_BREAK along the optimal
    # face: every point of it is that close to the boundary, phase 1 finds no centred start and phase 2 stalls
    # (paper example: 114 iterations, no answer); the IPM solves the penalized form instead (tie_weight).
    if name in ("IPM", "AUTO"):
        modes = lifted.modes
        c = congruent_scale(modes, rate) * (1 + STRICT) if objective == "stability" else None
        radius = None
        if objective == "stability":
            radius = MAX_RADIUS * (1.0 if x0 is None else max(1.0, float(np.linalg.norm(x0))))
        prob = ipm.performance_problem(lifted, objective, x0, u_max, c=c, radius=radius,
                                       cap=None if tie_weight is not None else cap, tie_weight=tie_weight,
                                       limit_slack=LIMIT_SLACK, trace_weight=trace_weight)
        setup = time.perf_counter() - start
        if radius is not None:
            sol = _solve_recentred(prob, lifted, x0, u_max, c, radius, time_limit, start)
        else:
            sol = _solve_in_answer_coordinates(prob, lifted, objective, x0, u_max, time_limit, start,
                                               cap=None if tie_weight is not None else cap, tie_weight=tie_weight,
                                               trace_weight=trace_weight)
        status = _ipm_status(sol.status)
        # the constants' size without the radius cap (radius^2 ~ 1e7 would hide t* = -0.9 of the paper motor)
        scale = max([1.0] + [float(np.abs(C).max()) for g, C in zip(prob.lmi.groups_spec, prob.lmi.C)
                             if g.name != "radius"])
        if status is None and not np.isfinite(sol.value) and sol.raw.t_upper < -ipm.algorithm.INFEASIBLE_T * scale \
                and sol.raw.primal_residual < 1e-6:
            # phase 1 settled max t < 0 whatever its stop status (the free tau of the "ball" block runs off in
            # phase 1 and ends it with numerical_error/max_iterations, paper motor with u_max = 0.01): no strictly
            # feasible design; run() then looks for a re-checked proof, no second solver is needed
            status = cp.INFEASIBLE
        info = SolveInfo(status=status or sol.status, solver="IPM", solve_time=sol.raw.timings["total"],
                         wall_time=time.perf_counter() - start,
                         objective=sol.value if status != cp.INFEASIBLE else sol.raw.t_upper,
                         iterations=sol.raw.iterations)
        info.setup = setup
        if status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
            return info, sol.W, sol.Y, dict(sol.scalars, ipm=sol)
        if np.isfinite(sol.value):
            # phase 2 ran but did not converge: its iterate is strictly feasible (attained value), a proposal
            # like any other for the re-checks (n = 12, n_drop = 10: its trace 482 vs Clarabel's re-checked 533;
            # the CTMS pendulum's LQR: numerical_error after 121 iterations at the Riccati value, where
            # Clarabel fails); run() asks Clarabel as well under "AUTO" when this one does not certify
            return info, sol.W, sol.Y, dict(sol.scalars, ipm=sol)
        if status == cp.INFEASIBLE or name == "IPM" or not fallback:
            if status is None and name == "IPM":
                raise SolverFailed(f"IPM ended with status {sol.status!r} after {sol.raw.iterations} iterations "
                                   f"(primal residual {sol.raw.primal_residual:.1e}, gap {sol.raw.gap:.1e})",
                                   status=sol.status)
            return info, None, None, {"ipm": sol}
        time_limit = time_left(time_limit, start)
        start = time.perf_counter()
    problem, Wv, Yv, extra = build(lifted, "stability" if objective == "stability" else objective, x0, u_max,
                                   rate, cap=cap, trace_weight=trace_weight)
    info = solve_sdp(problem, "CLARABEL" if name in ("AUTO", "IPM") else name, time_limit)
    info.setup = max(info.wall_time - info.solve_time, 0.0) if np.isfinite(info.solve_time) else 0.0
    if Wv.value is None or info.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        return info, None, None, {}
    scalars = {k: float(v.value) for k, v in extra.items() if k in ("gamma", "g") and v.value is not None}
    return info, Wv.value, [np.array(y.value, dtype=float) for y in Yv], scalars


def similar(lifted: Lifted, T: np.ndarray) -> Lifted:
    """The stability rows of ``lifted`` in state coordinates ``x = T z`` (``T`` invertible): ``A_s`` becomes
    ``T^-1 A_s T`` with the gains ``K_q T`` (``free -> T^-1 free T``, ``coef_q -> T^-1 coef_q``); cost and output
    rows are dropped (the input-limited design's max-tau SDP does not use them)."""
    from ..lifting import AffineRows, LiftedMode

    Ti = np.linalg.inv(T)
    out = [LiftedMode(eta=lm.eta, plants=lm.plants,
                      state=AffineRows(Ti @ lm.state.free @ T, np.einsum("ik,qkm->qim", Ti, lm.state.coef)),
                      cost=None, output=None, B=None, D=None) for lm in lifted.lifted]
    return Lifted(modes=lifted.modes, lifted=out)


def _solve_in_answer_coordinates(prob, lifted: Lifted, objective: str, x0, u_max, time_limit, start, **build):
    """A cost or hinf SDP on the IPM, its last iterations in the state coordinates of its answer (docs/design.md
    §8.3.2): solved as built until the relative gap is below :data:`SWITCH_GAP` (primal residual
    :data:`SWITCH_FEAS`); then, with ``W_1 = T T'`` (``T = W_1^{1/2}``) that iterate's W, the same SDP in the
    coordinates ``x = T z`` (:func:`solver.ipm.performance_problem`'s ``coordinates``, where ``W_1`` is ``I``) from
    the same iterate carried over exactly (:func:`solver.ipm.performance_blocks.recentre`: variables and multipliers
    by congruence), to :data:`IPM_TOL`.  The answer is mapped back (``W = T W' T'``, ``Y = Y' T'``) and kept when
    it is finite; otherwise the first stage's."""
    from .. import ipm
    from ..ipm.performance_blocks import recentre

    power = SIGMA_POWER.get(objective, 3.0)

    def left():
        return time_left(time_limit, start)

    sol = ipm.solve_performance(prob, ipm.IPMOptions(gap_tol=SWITCH_GAP, feas_tol=SWITCH_FEAS, time_limit=left(),
                                                     sigma_power=power))
    switch = sol.status == "optimal" or sol.status == "stalled" and sol.raw.gap <= SWITCH_GAP and np.isfinite(sol.value)
    if not switch or sol.raw.gap <= IPM_TOL and sol.raw.primal_residual <= IPM_TOL:
        return sol  # converged already, or stopped short of SWITCH_GAP (its iterate, if any, is the proposal)
    lam, U = np.linalg.eigh(sol.W)
    sol2 = None
    if lam[0] > 0:
        T = (U * np.sqrt(lam)) @ U.T
        prob2 = ipm.performance_problem(lifted, objective, x0, u_max, limit_slack=LIMIT_SLACK, coordinates=T, **build)
        y0, X0 = recentre(prob, sol, prob2, T)
        sol2 = ipm.solve_performance(prob2, ipm.IPMOptions(gap_tol=IPM_TOL, feas_tol=IPM_TOL, time_limit=left(),
                                                           sigma_power=power), y_start=y0, x_start=X0)
    if sol2 is None or not np.isfinite(sol2.value):
        # no answer in the new coordinates: the first stage's iterate goes on as built to IPM_TOL (its gap may be
        # up to SWITCH_GAP, a loose bound the re-checks would certify)
        y0, X0 = recentre(prob, sol, prob, np.eye(sol.W.shape[0]))
        rest = ipm.solve_performance(prob, ipm.IPMOptions(gap_tol=IPM_TOL, feas_tol=IPM_TOL, time_limit=left(),
                                                          sigma_power=power), y_start=y0, x_start=X0)
        if not np.isfinite(rest.value):
            # an attained but loose value: a proposal for the re-checks (and for Clarabel under AUTO), not an optimum
            sol.status = rest.status if rest.status not in ("optimal", "inaccurate") else "numerical_error"
            return sol
        rest.raw.iterations += sol.raw.iterations
        return rest
    sol2.W = T @ sol2.W @ T.T
    sol2.W = 0.5 * (sol2.W + sol2.W.T)
    sol2.Y = [y @ T.T for y in sol2.Y]
    if "Z" in sol2.scalars:
        Ti = np.linalg.inv(T)
        sol2.scalars["Z"] = Ti.T @ sol2.scalars["Z"] @ Ti
    sol2.raw.iterations += sol.raw.iterations
    sol2.raw.timings = {k: v + sol.raw.timings.get(k, 0.0) for k, v in sol2.raw.timings.items()}
    sol2.problem = prob
    return sol2


def _solve_recentred(prob, lifted: Lifted, x0, u_max, c, radius: float, time_limit, start):
    """The input-limited design's max-tau SDP in two stages (docs/design.md §8.3.3): to ``RECENTRE_GAP`` as
    built; then the same SDP in the coordinates ``x = W_1^{1/2} z`` of the ellipsoid ``W_1`` found (there
    ``W_1 = I``, and ``tau`` in units of ``lambda_min(W_1)``), from the first answer's point, to ``IPM_TOL``.
    The second answer is kept when its tau is at least the first's."""
    from .. import ipm

    sol = ipm.solve_performance(prob, ipm.IPMOptions(gap_tol=RECENTRE_GAP, feas_tol=RECENTRE_FEAS,
                                                     time_limit=time_limit, objective_max_iter=RECENTRE_ITER))
    if not np.isfinite(sol.value) or sol.raw.gap <= IPM_TOL and sol.raw.primal_residual <= IPM_TOL:
        return sol
    lam, U = np.linalg.eigh(sol.W)
    if not lam[0] > 0:
        return sol
    from ..ipm.performance_blocks import coordinates_of

    T, Ti = (U * np.sqrt(lam)) @ U.T, (U / np.sqrt(lam)) @ U.T
    prob2 = ipm.performance_problem(similar(lifted, T), "stability", None if x0 is None else Ti @ x0, u_max, c=c,
                                    radius=radius / np.sqrt(lam[0]), limit_slack=LIMIT_SLACK,
                                    metric=lam[0] * (Ti @ Ti))
    # the first answer in the new coordinates (W = I, Y_j W_1^{-1/2}, tau = RECENTRE_BACK lambda_min(W_1): the first
    # answer's own tau may lag far behind, -5e11 at n = 12 with x0), as the problem's coordinates
    # (x = T y: least squares, exact up to rounding since x is in T's range)
    Ys = [y @ Ti * g for y, g in zip(sol.Y, prob2.gain_scale)]
    x = np.concatenate([np.eye(len(lam)).ravel()] + [y.ravel() for y in Ys]
                       + [[RECENTRE_BACK, 0.0]])
    y0 = coordinates_of(prob2.lmi, x)
    left = time_left(time_limit, start)
    sol2 = ipm.solve_performance(prob2, ipm.IPMOptions(gap_tol=IPM_TOL, feas_tol=IPM_TOL, time_limit=left),
                                 y_start=y0)
    if not np.isfinite(sol2.value) or sol2.value * lam[0] > sol.value:
        return sol
    sol2.W = T @ sol2.W @ T
    sol2.W = 0.5 * (sol2.W + sol2.W.T)
    sol2.Y = [y @ T for y in sol2.Y]
    sol2.scalars["tau"] *= lam[0]
    sol2.value *= lam[0]
    sol2.raw.iterations += sol.raw.iterations
    sol2.raw.timings = {k: v + sol.raw.timings.get(k, 0.0) for k, v in sol2.raw.timings.items()}
    return sol2


def prepare(modes, method: str, objective: str, weights, x0, disturbance, output, u_max, decay_rate,
            solver: str = "AUTO"):
    """Validate a performance / input-limit request and lift its data: ``(lifted, x0, u_max)``.

    ``solver`` picks the memory estimate that refuses a design too large: the structured IPM's own
    (:func:`ipm_bytes`) under ``"AUTO"``/``"IPM"``, Clarabel's KKT system otherwise.
    Raises :class:`solver.errors.InvalidInput` naming the field (the service calls it before a job exists).
    """
    if objective not in OBJECTIVES:
        raise InvalidInput(f"objective must be one of {OBJECTIVES}, got {objective!r}", ("objective",))
    if objective == "stability" and u_max is None:
        for name, value in (("weights", weights), ("x0", x0), ("disturbance", disturbance), ("output", output)):
            if value is not None:
                raise InvalidInput(f"{name} needs objective='cost' or 'hinf' (or u_max, for x0)", (name,))
        return None, None, None
    if method != "lmi":
        raise InvalidInput("objective and u_max need method='lmi' (a common quadratic Lyapunov function)",
                           ("method",))
    if decay_rate == "auto":  # the default asks for a usable loop: these objectives give one by themselves
        decay_rate = None
    if decay_rate == "max":
        raise InvalidInput("decay_rate='max' cannot be combined with an objective or u_max; give a rate",
                           ("decay_rate",))
    if decay_rate is not None and objective != "stability":
        raise InvalidInput("decay_rate combines with u_max and objective='stability' only", ("decay_rate",))
    n, m = modes.n_states, modes.n_inputs
    x0 = check_x0(x0, n)
    if u_max is not None:
        u_max = check_u_max(u_max, m)
        if objective == "hinf":
            raise InvalidInput("u_max with objective='hinf' is not available (the set would depend on the "
                               "disturbance energy)", ("u_max",))
        if objective == "cost" and x0 is None:
            raise InvalidInput("u_max with objective='cost' needs x0 (the limits hold on a set containing x0)",
                               ("x0",))
    if objective == "hinf" and disturbance is None:
        raise InvalidInput("objective='hinf' needs disturbance=E", ("disturbance",))
    if objective != "hinf" and (disturbance is not None or output is not None):
        raise InvalidInput("disturbance and output go with objective='hinf'", ("disturbance",))
    if objective != "cost" and weights is not None:
        raise InvalidInput("weights go with objective='cost'", ("weights",))
    lifted = lift_modes(modes, weights, disturbance if objective == "hinf" else None, output,
                        cost=objective == "cost")
    on_ipm = str(solver).upper() in ("AUTO", "IPM")
    check_memory(block_sides(lifted, objective), objective, ipm_bytes(lifted, objective) if on_ipm else None)
    return lifted, x0, u_max


def ipm_bytes(lifted: Lifted, objective: str) -> int:
    """Peak bytes of the structured IPM on this design's grouped SDP (:func:`solver.compiled.ipm_memory`).

    Every group's Schur complement is a full ``p x p`` matrix added into the sum, and the iterates are the
    blocks of all groups: counted as that many blocks of the largest side (an upper estimate).
    """
    modes = lifted.modes
    n, m, J = modes.n_states, modes.n_inputs, modes.n_free_gains
    sym = n * (n + 1) // 2
    p = 2 * sym + J * m * n + 2  # W, Z (trace objective), the gains, gamma / g and t
    sides = block_sides(lifted, objective, compact=True) + [n + 1] * (modes.n_drop * m)  # + the input-limit blocks
    groups = len(set(sides)) + 3
    return ipm_memory(p, p, len(sides), max(sides), J * m * n) + 8 * groups * p * p


def block_sides(lifted: Lifted, objective: str, compact: bool = False) -> list[int]:
    """Side of every per-mode LMI block of the design (the input-limit blocks are n + 1 each).

    ``compact``: the structured IPM's blocks (docs/design.md §8.3.1: the tail rows reduced to at most
    ``n + eta m`` (cost) or ``n + eta (m + p_w)`` (hinf)); otherwise the lifted ones (the cvxpy form).
    """
    n, m = lifted.modes.n_states, lifted.modes.n_inputs
    J = lifted.modes.n_free_gains
    if objective == "cost":
        return [2 * n + (min(lm.cost.free.shape[0], n + min(lm.eta, J) * m) if compact else lm.cost.free.shape[0])
                for lm in lifted.lifted]
    if objective == "hinf":
        return [2 * n + lm.B.shape[1] + (min(lm.D.shape[0], n + min(lm.eta, J) * m + lm.B.shape[1]) if compact
                                         else lm.D.shape[0]) for lm in lifted.lifted]
    return [2 * n] * len(lifted.lifted)


def _propose(lifted: Lifted, objective: str, x0, u_max, rate, solver: str, clock: RunClock, time_limit,
             trace_weight=None, fallback: bool = True):
    """One solver's proposal ``(info, W, Y, extra)``, with the x0 tie-break stage; raises :class:`SolverFailed`.
    ``fallback``: the first stage's, :func:`solve`'s."""
    info, Wv, Yv, extra = solve(lifted, objective, x0, u_max, rate, solver, clock.remaining(time_limit),
                                trace_weight=trace_weight, fallback=fallback)
    clock.setup += info.setup
    clock.add(info)
    if Wv is not None and objective == "cost" and x0 is not None and u_max is None:
        # the tie-break stage: among the x0-optimal designs (to TIE_BREAK relative) the one of least trace P.
        # cvxpy: min trace Z s.t. gamma <= cap; the IPM: the same problem through its Lagrangian (_tie_break_ipm)
        gamma1 = float(extra["gamma"])
        cap = gamma1 * (1 + TIE_BREAK) + 1e-12 * max(1.0, float(x0 @ x0))
        if str(solver).upper() in ("AUTO", "IPM"):
            found = _tie_break_ipm(lifted, x0, rate, solver, clock, time_limit, trace_weight, Wv, gamma1, cap)
        else:
            try:
                found = solve(lifted, objective, x0, u_max, rate, solver, clock.remaining(time_limit), cap=cap,
                              trace_weight=trace_weight)
            except SolverFailed:
                found = None
            if found is not None and found[1] is not None:
                clock.setup += found[0].setup
                clock.add(found[0])
            else:
                found = None
        if found is not None:
            info, Wv, Yv, extra = found
    return info, Wv, Yv, extra


def _tie_break_ipm(lifted: Lifted, x0, rate, solver: str, clock: RunClock, time_limit, trace_weight, W1,
                   gamma1: float, cap: float):
    """The x0 tie-break stage on the IPM: ``(info, W, Y, scalars)`` of least trace P with ``gamma <= cap``, or None.

    The capped problem's feasible set is too thin for phase 1 to centre in (see :func:`solve`), so the IPM
    solves its Lagrangian ``min gamma + w trace Z`` (``Z >= W^{-1}``; the trace weighted by ``trace_weight``):
    its optimum is the capped problem's optimum for the cap it meets, ``gamma(w)``, which grows with ``w``
    (about as ``w^2``, measured).  Starting from ``w = TIE_WEIGHT gamma_1 / trace P_1`` the weight is moved by
    a secant step in ``log w`` towards ``gamma(w) = cap`` (at most :data:`TIE_SOLVES` solves, stopped once
    ``gamma(w)`` is within :data:`TIE_WINDOW` of the cap); the point kept is the one of least trace Z whose
    attained ``gamma`` meets the cap (so the cap holds at the returned, strictly feasible point).  When the IPM
    gives no iterate under ``"AUTO"``, :func:`solve` asks Clarabel the capped problem itself.
    """
    tw = np.ones(W1.shape[0]) if trace_weight is None else np.asarray(trace_weight, dtype=np.float64)
    try:
        tr1 = float(tw @ np.diag(np.linalg.inv(0.5 * (W1 + W1.T))))
    except np.linalg.LinAlgError:
        return None
    if not (np.isfinite(tr1) and tr1 > 0 and gamma1 > 0):
        return None
    target = cap - gamma1
    w, best, tried = TIE_WEIGHT * gamma1 / tr1, None, []
    for _ in range(TIE_SOLVES):
        try:
            found = solve(lifted, "cost", x0, None, rate, solver, clock.remaining(time_limit), cap=cap,
                          trace_weight=trace_weight, tie_weight=w)
        except SolverFailed:
            break
        info2, W2, _, extra2 = found
        if W2 is None:
            break
        clock.setup += info2.setup
        clock.add(info2)
        if info2.solver != "IPM":  # Clarabel's capped problem (the IPM failed): the cap holds by construction
            return found
        rise = float(extra2["gamma"]) - gamma1
        trace2 = float(tw @ np.diag(np.asarray(extra2["Z"])))
        if rise <= target and (best is None or trace2 < best[0]):
            best = (trace2, found)
        if TIE_WINDOW * target <= rise <= target:
            break
        tried.append((w, max(rise, 1e-3 * target)))
        if len(tried) >= 2 and tried[-1][1] != tried[-2][1] and tried[-1][0] != tried[-2][0]:
            p = np.log(tried[-1][1] / tried[-2][1]) / np.log(tried[-1][0] / tried[-2][0])
            p = min(max(p, 0.5), 4.0)
        else:
            p = 2.0
        step = (0.6 * target / tried[-1][1]) ** (1.0 / p)
        w = tried[-1][0] * min(max(step, 1e-3), 1e3)
    return None if best is None else best[1]


def _evaluate(lifted: Lifted, objective: str, x0, u_max, options: DesignOptions, clock: RunClock, info,
              W, Y, extra, weight=None, gains=None, P0=None, exact_hinf=None) -> dict | None:
    """Gains, certified bracket, stability certificate and invariant set of one proposal (None: W singular).

    ``gains`` and ``P0`` given: a proposal made outside the SDP (the Riccati refinement); ``exact_hinf``: a rational
    bounded-real certificate and its level for them (:func:`solver.brackets.bracket`).
    """
    modes = lifted.modes
    kothare = objective == "cost" and u_max is not None
    if gains is None:
        W = 0.5 * (W + W.T)
        try:
            gains = _gains_of(modes, W, Y)
            Winv = np.linalg.inv(W)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(gains)):
            return None
        P0 = (float(extra["gamma"]) * Winv if kothare else Winv) if objective in ("cost", "hinf") else None
    else:
        Winv = P0
    performance = None
    if objective in ("cost", "hinf"):
        performance = bracket(lifted, gains, objective, P0=P0, x0=x0, solver=options.solver, weight=weight,
                              exact_hinf=exact_hinf, seconds_left=clock.countdown(options.time_limit))
    candidate = performance.certificate if performance is not None and performance.verified else Winv
    # exact: the performance certificate, re-checked exactly there, may hold a relative stability margin (1e-11
    # where P spans 1e11) that float64 cannot confirm; decided in exact arithmetic for small n (§8.5)
    cert, A = certify_gains(modes, gains, options, clock, candidate=candidate, candidate_source=f"lmi_{objective}",
                            exact=candidate is not Winv and modes.n_modes <= EXACT_MODES)
    if cert is None and candidate is not Winv:
        cert, A = certify_gains(modes, gains, options, clock, candidate=Winv, candidate_source=f"lmi_{objective}")
    invariant, inv_reason = None, ""
    if u_max is not None and cert is not None:
        invariant, inv_reason = check_invariant(Winv, A, gains, u_max, x0,
                                                plant=None if modes.F is None else (modes.F, modes.G, modes.plants))
    return {"info": info, "gains": gains, "performance": performance, "cert": cert, "A": A,
            "invariant": invariant, "inv_reason": inv_reason}


#: Modes at most for the exact stability re-check of a performance certificate (each costs an exact n x n product).
EXACT_MODES = 64


def _score(c: dict, u_max) -> tuple:
    """Candidates ordered by: certified, limits proven, bracket certified, smallest upper bound."""
    perf = c["performance"]
    verified = perf is not None and perf.verified
    return (c["cert"] is not None, u_max is None or c["invariant"] is not None, verified or perf is None,
            -perf.certificate_upper if verified else 0.0)


def _good(c: dict | None, u_max) -> bool:
    return c is not None and all(_score(c, u_max)[:3])


#: Newton-Kleinman (Hewer) iterations of the Riccati refinement at most (quadratic convergence: ~10 suffice).
HEWER_STEPS = 60
#: Relative lifts of the refined cost matrix tried in turn (the smallest that passes the re-check is kept).
EPS_STEPS = (1e-14, 1e-13, 1e-12, 1e-11, 1e-10, 1e-9)
#: Slack off P's largest direction, in units of P's largest entry's rounding, tried in turn (§8.5).
SLACK_STEPS = (1 / 16, 1 / 4, 1.0, 4.0, 16.0, 64.0)


def _refined_lyapunov(A: np.ndarray, S: np.ndarray, hint: np.ndarray, steps: int = 2) -> np.ndarray:
    """:func:`solver.brackets.lyapunov` plus iterative refinement: ``P <- P + lyapunov(A, r)`` with the residual
    ``r = A' P A - P + S`` evaluated exactly (``fractions.Fraction``) and rounded once; small n only."""
    n = A.shape[0]
    Aq, Sq = fractions(A), fractions(S)
    P = lyapunov(A, S, hint)
    for _ in range(steps):
        Pq = fractions(P)
        AP = [[sum(Aq[k][i] * Pq[k][j] for k in range(n)) for j in range(n)] for i in range(n)]  # A' P
        r = np.array([[float(sum(AP[i][k] * Aq[k][j] for k in range(n)) - Pq[i][j] + Sq[i][j]) for j in range(n)]
                      for i in range(n)])
        r = 0.5 * (r + r.T)
        if not np.any(r):
            break
        correction = lyapunov(A, r, P) if np.all(np.linalg.eigvalsh(r) >= 0) else _plain_lyapunov(A, r, P)
        P = 0.5 * ((P + correction) + (P + correction).T)
    return P


def _plain_lyapunov(A: np.ndarray, r: np.ndarray, coordinates: np.ndarray) -> np.ndarray:
    """``X = A' X A + r`` for an indefinite r, in the coordinates where ``coordinates`` (> 0) is I."""
    L = np.linalg.cholesky(0.5 * (coordinates + coordinates.T))
    At = scipy.linalg.solve_triangular(L, A.T @ L, lower=True).T
    rt = scipy.linalg.solve_triangular(L, scipy.linalg.solve_triangular(L, r, lower=True).T, lower=True)
    Xt = scipy.linalg.solve_discrete_lyapunov(At.T, 0.5 * (rt + rt.T))
    return L @ Xt @ L.T


#: Hewer steps in exact arithmetic after the float64 ones (n <= EXACT_COST_MAX_N; quadratic convergence).
EXACT_HEWER_STEPS = 3


def _exact_hewer(F: np.ndarray, G: np.ndarray, Q: np.ndarray, R: np.ndarray, K: np.ndarray, seconds_left=None):
    """Hewer's iteration continued with each P solved exactly (:func:`solver.exact.lyapunov_exact`) and each gain
    formed exactly and rounded once (:func:`solver.exact.riccati_gain_exact`); the gain of least exact ``trace P``
    and that P rounded to float64 (None when no exact step was taken).  ``seconds_left``: ``() -> seconds or None``; no
    step starts once it is <= 0 (a step is up to 2 s at n = 8: the design's time limit bounds them).

    Where P spans 1e13 the float64 iteration stops 1e-5 above the Riccati cost (its Lyapunov solutions and the
    products ``G' P F`` lose that much); every exact step is a true Newton step, up to the gain's rounding
    (hold-out seeds 10, 15: 1.6e-5, 5.4e-6 -> below 1e-9; docs/design.md §8.5).
    """
    from ..exact import lyapunov_exact, riccati_gain_exact

    best, best_trace, best_P = K, None, None
    for _ in range(EXACT_HEWER_STEPS):
        if not np.all(np.isfinite(K)) or not np.max(np.abs(np.linalg.eigvals(F + G @ K))) < 1 or \
                out_of_time(seconds_left):
            break
        P = lyapunov_exact(F, G, K, Q, R)
        if P is None:
            break
        trace = sum(P[i][i] for i in range(len(P)))
        if best_trace is not None and not trace < best_trace:
            break  # converged to the gain's rounding
        best, best_trace, best_P = K, trace, P
        K = riccati_gain_exact(F, G, R, P)
        if K is None:
            break
    return best, None if best_P is None else floats(best_P)


def riccati_refine(F: np.ndarray, G: np.ndarray, Q: np.ndarray, R: np.ndarray, K: np.ndarray, loop=None,
                   seconds_left=None):
    """Hewer's (Newton-Kleinman) iteration from a stabilizing ``u = K x`` to the LQR gain of ``(F, G, Q, R)``.

    ``K <- -(R + G' P G)^{-1} G' P F`` with ``P = (F + G K)' P (F + G K) + Q + K' R K``: every iterate
    stabilizes and P decreases monotonically to the Riccati solution, quadratically near it (Hewer 1971).
    Returns ``(K, P)``: the last iterate and a P a hair above its cost matrix (``A'PA - P + S = -eps I`` with
    the smallest ``eps`` among ``EPS_STEPS`` times ``2 |P| + |S|`` whose P passes :func:`check_cost`: the
    re-check's inequality is strict, and the Riccati solution meets it with equality where ``S`` is singular,
    e.g. the CTMS weights ``Q = diag(5000, 0, 100, 0)``), or None when ``K`` does not stabilize.  A proposal
    like any other: the caller's float64 re-checks certify it.  ``loop``: ``K -> (A, S)``, the float64 loop and
    cost matrix of the caller's re-check (its rounding, not ``F + G K``'s, is what an exact re-check of P sees where
    P spans 1e11, docs/design.md §8.5).  ``seconds_left``: ``() -> seconds or None``, the design's time limit: the exact
    steps and lifts stop once it is <= 0.
    """
    if not np.max(np.abs(np.linalg.eigvals(F + G @ K))) < 1:
        return None
    K_prev, last, P = K, None, None  # last: the trace of the last P (in exact arithmetic it decreases)
    for _ in range(HEWER_STEPS):
        A = F + G @ K
        if not np.max(np.abs(np.linalg.eigvals(A))) < 1:
            K = K_prev  # rounding broke the iteration (ill-conditioned Lyapunov equations): keep the last stable one
            break
        P = lyapunov(A, Q + K.T @ R @ K, P)  # the previous P's coordinates (docs/design.md §8.5)
        if last is not None and not np.trace(P) <= last * (1 + 1e-12):
            K = K_prev  # a rise is rounding too (P_k decreases monotonically in exact arithmetic)
            break
        last = float(np.trace(P))
        K_next = -np.linalg.solve(R + G.T @ P @ G, G.T @ P @ F)
        step = np.linalg.norm(K_next - K)
        K_prev, K = K, K_next
        if step <= 1e-14 * max(np.linalg.norm(K), 1e-300):
            break
    if F.shape[0] <= EXACT_COST_MAX_N:
        K, P_exact = _exact_hewer(F, G, Q, R, K, seconds_left)
        if P_exact is not None:
            # the exact cost matrix of these gains, rounded: the coordinates of the solves below (where P spans
            # 1e13 the float64 iteration's last P is no approximation of it: indefinite, hold-out seeds 1, 31)
            P = P_exact
    A, S = (F + G @ K, Q + K.T @ R @ K) if loop is None else loop(K)
    if not np.max(np.abs(np.linalg.eigvals(A))) < 1:
        return None
    P = lyapunov(A, S, P)
    size = 2 * np.linalg.norm(P, 2) + np.linalg.norm(S, 2)
    data = [{"A": A, "S": S}]
    found = None
    for step in EPS_STEPS:
        Pe = lyapunov(A, S + step * size * np.eye(S.shape[0]), P)
        if check_cost(Pe, data)[0]:
            found = Pe
            break
    if S.shape[0] <= EXACT_COST_MAX_N and not out_of_time(seconds_left):
        # the float64 re-check's allowance is relative to |P|: where P spans 1e11 (a nearly unreachable unstable
        # mode) the lift it needs raises trace P by 1e-3 and more; a lift along P itself (slack eps P, relative
        # in every direction) raises it by about eps / (1 - |loop|^2) and passes the exact re-check (§8.5).
        # Its residual must be below eps P in every direction: two steps of iterative refinement with the
        # residual computed exactly (rational arithmetic on the float64 numbers) get there
        lifted = None
        for step in EPS_STEPS + (1e-8, 1e-7):
            Pl = _refined_lyapunov(A, S + step * P, P)
            if check_cost_exact(Pl, data):
                lifted = Pl
                break
        if lifted is None:
            # P's own float64 rounding (1e-5 absolute where its largest eigenvalue is 1e11) needs slack of that
            # size in P's small directions, which a lift along P does not give: slack k u max|P| off P's largest
            # direction, smallest k first (hold-out: 1e-6 .. 1e-4 above the Riccati cost, §8.5)
            w, V = np.linalg.eigh(P)
            off = np.eye(S.shape[0]) - np.outer(V[:, -1], V[:, -1])
            unit = 2.0 ** -52 * float(np.max(np.abs(P)))
            for k in SLACK_STEPS:
                for step in (1e-10, 1e-8):
                    Pl = _refined_lyapunov(A, S + step * P + k * unit * off, P)
                    if check_cost_exact(Pl, data):
                        lifted = Pl
                        break
                if lifted is not None:
                    break
        if lifted is not None and (found is None or np.trace(lifted) < np.trace(found)):
            found = lifted
    return K, (Pe if found is None else found)


def _one_lti_loop(lifted: Lifted) -> bool:
    modes = lifted.modes
    return len(lifted.lifted) == 1 and modes.n_drop == 1 and modes.F is not None and lifted.Q is not None


#: Largest state dimension of the game-Riccati refinement (hinf, one LTI loop): its certificates need the exact
#: re-checks of §8.4, small n only (as ``brackets.EXACT_COST_MAX_N``).
GAME_MAX_N = EXACT_COST_MAX_N
#: Relative width at which the bisection on the game Riccati equation's solvability stops, and the relative steps
#: above its upper end at which gains are taken (the first whose certified level is within GAME_CLOSE of the
#: bisection's end is kept; gains grow without bound at the optimum, a step above it gives a margin).
GAME_TOL = 1e-10
GAME_STEPS = (1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3)
GAME_CLOSE = 1e-6


def _one_hinf_loop(lifted: Lifted) -> bool:
    modes = lifted.modes
    return len(lifted.lifted) == 1 and modes.n_drop == 1 and lifted.has_disturbance and \
        modes.n_states <= GAME_MAX_N


def game_gains(F: np.ndarray, G: np.ndarray, E: np.ndarray, C: np.ndarray, Du: np.ndarray, Dw: np.ndarray,
               gamma: float):
    """The state-feedback H-infinity game Riccati equation of ``x+ = F x + G u + E w``, ``z = C x + Du u + Dw w``
    at level ``gamma`` (docs/design.md §8.5).

    ``X = F'XF + C'C - (F'XB + C'D)(D'D - diag(0, g I) + B'XB)^{-1}(B'XF + D'C)``, ``B = [G E]``, ``D = [Du Dw]``,
    ``g = gamma^2``.  Solvable (a stabilizing solution with ``X >= 0``, ``Du'Du + G'XG > 0`` and
    ``g I - Dw'Dw - E'XE > 0`` on the saddle's blocks) iff some static gain reaches an l2 gain below ``gamma``;
    the minimizer's saddle strategy ``u = K x`` is such a gain, and X solves its closed loop's bounded-real
    equation at gamma (a certificate candidate).  Shapes: F (n, n), G (n, m), E (n, p), C (q, n), Du (q, m),
    Dw (q, p).  Returns ``(K (m, n), X (n, n))`` or None (not solvable, or scipy found no solution).
    """
    n, m = G.shape
    B = np.hstack([G, E])
    D = np.hstack([Du, Dw])
    R = D.T @ D
    R[m:, m:] -= gamma ** 2 * np.eye(E.shape[1])
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            X = scipy.linalg.solve_discrete_are(F, B, C.T @ C, R, s=C.T @ D)
            X = 0.5 * (X + X.T)
            if not np.all(np.isfinite(X)) or np.linalg.eigvalsh(X)[0] < -1e-9 * max(np.abs(X).max(), 1e-300):
                return None
            H = R + B.T @ X @ B
            if np.linalg.eigvalsh(0.5 * (H[:m, :m] + H[:m, :m].T))[0] <= 0 or \
                    np.linalg.eigvalsh(0.5 * (H[m:, m:] + H[m:, m:].T))[-1] >= 0:
                return None
            KL = -np.linalg.solve(H, B.T @ X @ F + D.T @ C)
            K = KL[:m]
            if not (np.max(np.abs(np.linalg.eigvals(F + B @ KL))) < 1 and
                    np.max(np.abs(np.linalg.eigvals(F + G @ K))) < 1) or not np.all(np.isfinite(K)):
                return None
    except (np.linalg.LinAlgError, ValueError):
        return None
    return K, X


def game_level(F, G, E, C, Du, Dw, upper: float | None = None) -> float | None:
    """Bisection (on log gamma, to :data:`GAME_TOL`) for the least level at which :func:`game_gains` is solvable:
    the upper end found (None when nothing up to 1e15 is).  ``upper``: a level known to be reached (a start)."""
    hi = upper if upper is not None and np.isfinite(upper) and upper > 0 else 1.0
    while game_gains(F, G, E, C, Du, Dw, hi) is None:
        hi *= 8.0
        if hi > 1e15:
            return None
    floor = float(np.linalg.norm(Dw, 2)) if Dw.size else 0.0  # the feedthrough: no gain goes below it
    lo = max(floor, hi * 1e-8)
    while lo > floor and game_gains(F, G, E, C, Du, Dw, lo) is not None:
        hi, lo = lo, max(floor, lo * 1e-8)
    while hi > lo * (1 + GAME_TOL) and hi - lo > 1e-300:
        mid = np.sqrt(lo * hi) if lo > 0 else 0.5 * hi
        if game_gains(F, G, E, C, Du, Dw, mid) is None:
            lo = mid
        else:
            hi = mid
    return hi


def run(lifted: Lifted, options: DesignOptions, objective: str, x0: np.ndarray | None,
        u_max: np.ndarray | None, trace_weight: np.ndarray | None = None) -> DesignResult:
    """One performance / input-limited design, every reported figure re-checked (see the module docstring).

    ``trace_weight``: the trace objective ``sum_i w_i P_ii`` (balanced coordinates, :mod:`solver.scaling`).

    Under ``solver="AUTO"`` the IPM's answer is kept when it passes the re-checks (even when the IPM stopped
    short of its tolerances); otherwise Clarabel proposes as well, and the better re-checked proposal wins.
    With one plant mode and ``n_drop = 1`` (a plain LTI loop) a cost design is refined by Hewer's iteration
    to the Riccati solution, kept when its re-checked bound is not larger.
    """
    modes = lifted.modes
    clock = RunClock()
    clock.cached = False
    rate = options.decay_rate
    name = str(options.solver).upper()
    solver_weight = None if trace_weight is None else trace_weight / np.max(trace_weight)
    candidates, failures, info = [], [], None
    try:
        # under "AUTO" an IPM without an answer leaves Clarabel to the second proposal below, after the plain design
        info, Wv, Yv, extra = _propose(lifted, objective, x0, u_max, rate, options.solver, clock,
                                       options.time_limit, solver_weight, fallback=False)
    except SolverFailed as err:
        Wv, failures = None, [str(err)]
    infeasible = info is not None and info.status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE)
    game = objective == "hinf" and u_max is None and _one_hinf_loop(lifted)
    if infeasible and not game:
        return _no_design(lifted, options, clock, objective, f"the {objective} SDP is reported infeasible by "
                          f"{info.solver} ({info.status})", info, x0, u_max)
    if infeasible:  # one LTI loop: the game Riccati equation below decides, not the IPM's verdict (§8.5)
        Wv, failures = None, [f"the hinf SDP is reported infeasible by {info.solver} ({info.status})"]
    if Wv is not None:
        try:  # the stability re-check's own LMI may fail: that loses this candidate, not the run (Clarabel, Riccati)
            candidates.append(_evaluate(lifted, objective, x0, u_max, options, clock, info, Wv, Yv, extra,
                                        trace_weight))
        except SolverFailed as err:
            failures.append(f"the re-check of the SDP's gains: {err}")
    base = None
    if name == "AUTO" and not infeasible and not any(c is not None and c["cert"] is not None for c in candidates):
        # no certified gains from the IPM: the plain design (one SDP) may prove that none exist before Clarabel's
        # second proposal is asked for (an infeasible family, n = 12, 6 loop modes: Clarabel failed twice in 35 s)
        base = lmi.run(modes, options)
        if base.outcome == "infeasible":  # ("marginal" leaves designs of a smaller margin: the refinements below)
            reason = "; ".join(failures) or f"the {objective} SDP gave no certified gains"
            return _no_design(lifted, options, clock, objective, reason, info, x0, u_max, base)
    if name == "AUTO" and not infeasible and not _good(candidates[-1] if candidates else None, u_max) and (
            info is None or info.solver == "IPM") and \
            compiled.clarabel_fits("lmi", modes.n_states, modes.n_inputs, modes.n_plants, modes.n_drop,
                                   modes.plant_switching, modes.scheme, max_memory=options.max_memory,
                                   objective=objective, decay_rate=rate, u_max=u_max,
                                   **lifted.channel_sizes()) and \
            (clock.remaining(options.time_limit) is None or clock.remaining(options.time_limit) > 0):
        try:
            info_c, Wc, Yc, extra_c = _propose(lifted, objective, x0, u_max, rate, "CLARABEL", clock,
                                               options.time_limit, solver_weight)
            info = info if info is not None else info_c
            if Wc is not None:
                candidates.append(_evaluate(lifted, objective, x0, u_max, options, clock, info_c, Wc, Yc, extra_c,
                                            trace_weight))
            elif info_c.status not in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE):
                failures.append(f"CLARABEL ended with status {info_c.status!r}")
        except SolverFailed as err:
            failures.append(str(err))
    candidates = [c for c in candidates if c is not None]
    best = max(candidates, key=lambda c: _score(c, u_max)) if candidates else None
    if objective == "cost" and u_max is None and _one_lti_loop(lifted):
        starts = [] if best is None else [(best["gains"][0], best["info"], True)]
        if not _good(best, u_max):
            # no certified SDP answer (a nearly unreachable unstable mode in mixed coordinates: P spans 1e11, the
            # SDP in W = P^-1 is beyond float64): Hewer's iteration needs only a stabilizing gain, and the plain
            # design's is one (docs/design.md §8.5)
            try:  # the Riccati solver's own answer (QZ, backward stable) first: a proposal like any other
                P_are = scipy.linalg.solve_discrete_are(modes.F[0], modes.G[0], lifted.Q, lifted.R)
                K_are = -np.linalg.solve(lifted.R + modes.G[0].T @ P_are @ modes.G[0],
                                         modes.G[0].T @ P_are @ modes.F[0])
                if np.all(np.isfinite(K_are)):
                    starts.append((K_are, info if info is not None else SolveInfo(
                        status="riccati", solver="scipy", solve_time=0.0, wall_time=0.0, objective=float("nan"),
                        iterations=0), "the Riccati solver's (scipy.linalg.solve_discrete_are)"))
            except (np.linalg.LinAlgError, ValueError):
                pass
            try:
                base = lmi.run(modes, options)
            except SolverFailed:
                base = None
            if base is not None and base.outcome == "stabilized" and base.gains is not None:
                starts.append((base.gains[0], info if info is not None else SolveInfo(
                    status=base.solver_status, solver=base.solver, solve_time=0.0, wall_time=0.0,
                    objective=float("nan"), iterations=0), "the plain design's"))
        for start_gains, start_info, origin in starts:
            try:
                refined = riccati_refine(modes.F[0], modes.G[0], lifted.Q, lifted.R, start_gains,
                                         loop=lambda K: (lambda d: (d["A"], d["S"]))(
                                             lifted.numeric(K[None], errors=False)[0]),  # (no re-check here)
                                         seconds_left=clock.countdown(options.time_limit))
            except (np.linalg.LinAlgError, ValueError):
                refined = None
            try:  # a fixed-gain LMI inside may fail: the refinement is optional, never the reason for no verdict
                c = None if refined is None else _evaluate(lifted, objective, x0, u_max, options, clock, start_info,
                                                           None, None, None, trace_weight, gains=refined[0][None],
                                                           P0=refined[1])
            except SolverFailed:
                c = None
            if c is None:
                continue
            # kept unless its bound is clearly worse: the SDP's own bound is flat at the optimum (the bus
            # suspension, Q = I: equal to 2e-10 with gains 1e-4 apart), the refinement's gains are the Riccati ones
            # (bounds compared only between equal scores: a better score wins whatever the bound, as in max above,
            # and an unverified bracket has no bound to compare)
            if best is None or _score(c, u_max)[:3] > _score(best, u_max)[:3] or (
                    _score(c, u_max)[:3] == _score(best, u_max)[:3] and (
                        not _score(best, u_max)[2] or best["performance"] is None or
                        c["performance"].certificate_upper <= best["performance"].certificate_upper * (1 + 1e-8))):
                best = c
                best["refined"] = origin
            if _good(best, u_max) and (origin is True or modes.n_states > EXACT_COST_MAX_N):
                break  # (small n, no SDP answer: every start, the best certified bound wins; §8.5)
    if game:
        c = _game_refine(lifted, options, clock, info, best, trace_weight)
        if c is not None:
            best = c
    if best is None and infeasible:
        return _no_design(lifted, options, clock, objective, failures[0], info, x0, u_max, base)
    if best is None:
        reason = f"the {objective} SDP " + ("failed (" + "; ".join(failures) + ")" if failures else
                                            f"ended with status {info.status!r}" if info is not None else "failed")
        return _no_design(lifted, options, clock, objective, reason, info, x0, u_max, base)
    info, gains, cert, A = best["info"], best["gains"], best["cert"], best["A"]
    performance, invariant, inv_reason = best["performance"], best["invariant"], best["inv_reason"]
    record = IterationRecord(0, info.objective, None, False, None, info.solve_time, clock.elapsed)
    if cert is None:  # perhaps no stabilizing design exists at all: the plain design may prove it
        base = lmi.run(modes, options) if base is None else base
        if base.outcome in ("infeasible", "marginal"):  # each names what its Farkas certificate proves
            base.message = f"the {objective} SDP gave no certified gains; {base.message}"
            base.objective = objective
            return base
    record.theorem1 = cert is not None
    record.certificate_margin = None if cert is None else cert.margin
    if options.callback is not None:
        options.callback(record)
    rate_txt = "" if rate is None else f" at decay rate {rate:.6g}"
    if cert is None:
        outcome, message = "not_converged", (f"the {objective} SDP gave gains but no stability certificate passed "
                                             f"the float64 re-check{rate_txt}")
    elif u_max is not None and invariant is None:
        if x0 is not None:  # perhaps no design meets the limits from x0 at all: the limits' Farkas proof decides
            return _no_design(lifted, options, clock, objective, f"stabilizing gains found but the input limits "
                              f"are not proven: {inv_reason}", info, x0, u_max)
        outcome, message = "not_converged", f"stabilizing gains found but the input limits are not proven: {inv_reason}"
    elif performance is not None and not performance.verified:  # "stabilized" only with the bracket asked for
        outcome, message = "not_converged", (f"stabilizing gains ({cert.kind} certificate re-checked{rate_txt}) but "
                                             f"no certified {objective} bound")
    else:
        outcome = "stabilized"
        message = f"stabilized; {cert.kind} certificate re-checked (relative margin {cert.margin:.3g}){rate_txt}"
        if cert.exact:
            message = (f"stabilized; {cert.kind} certificate re-checked exactly (float64 relative margin "
                       f"{cert.margin:.3g}, below what float64 confirms)")
        if u_max is not None:
            message += f"; {limits_note(invariant, 'the invariant set (re-checked)')}"
    if best.get("refined") == "game":
        how = (" by exact Newton steps, its least level (the disturbance block's root)"
               if best.get("game_how") == "exact" else ", its least solvable level by bisection")
        message += (f"; gains of the H-infinity game Riccati equation at {best['game_level']:.9g} (1 + "
                    f"{best['game_step']:g}){how} {best['game_bisection']:.9g}")
        if failures and infeasible:
            message += f" ({failures[0]})"
    elif best.get("refined"):
        origin = "the SDP's" if best["refined"] is True else best["refined"]
        message += f"; gains refined to the Riccati solution (Hewer's iteration from {origin} gains)"
    if performance is not None:
        message += f"; {performance.message}"
    res = finish(modes, "lmi", outcome, gains, cert, A, clock, info.solver, info.status, message, [record], options)
    res.objective = objective
    res.performance = performance
    res.invariant_set = invariant
    return res


def _game_refine(lifted: Lifted, options: DesignOptions, clock: RunClock, info, best: dict | None,
                 trace_weight) -> dict | None:
    """hinf, one LTI loop (one mode, ``n_drop = 1``): the gains of the game Riccati equation a hair above its least
    solvable level (:func:`game_level`), re-checked like any proposal (docs/design.md §8.5).

    Returns the candidate when it beats ``best`` (certified first, then a certified level smaller by more than
    1e-9 relative), else None.  Each step of :data:`GAME_STEPS` is tried until a certified level is within
    :data:`GAME_CLOSE` of the bisection's end.
    """
    lm = lifted.lifted[0]
    F, G = lm.state.free, lm.state.coef[0]
    E, C, Du, Dw = lm.B, lm.output.free, lm.output.coef[0], lm.D
    have = best is not None and _good(best, None)
    try:
        level = game_level(F, G, E, C, Du, Dw, best["performance"].certificate_upper if have else None)
    except (np.linalg.LinAlgError, ValueError):
        level = None
    if level is None:
        return None
    start = info if info is not None else SolveInfo(status="riccati", solver="scipy", solve_time=0.0, wall_time=0.0,
                                                    objective=float("nan"), iterations=0)
    found = None
    seconds_left = clock.countdown(options.time_limit)

    def consider(gains, P0, exact_hinf=None, **how) -> bool:
        """Re-check one proposal like any other and keep it when it certifies the smallest level so far; True once
        that level is within GAME_CLOSE of the least one (``how["game_bisection"]``)."""
        nonlocal found
        try:  # a fixed-gain LMI inside may fail: the refinement is optional, never the reason for no verdict
            c = _evaluate(lifted, "hinf", None, None, options, clock, start, None, None, None, trace_weight,
                          gains=gains[None], P0=P0, exact_hinf=exact_hinf)
        except SolverFailed:
            c = None
        if c is None or not _good(c, None):
            return False
        if found is None or c["performance"].certificate_upper < found["performance"].certificate_upper:
            found = c
            found.update(refined="game", **how)
        return found["performance"].certificate_upper <= how["game_bisection"] * (1 + GAME_CLOSE)

    if F.shape[0] <= GAME_MAX_N and not out_of_time(seconds_left):
        # exact Newton on the game Riccati equation, the level by the secant on its disturbance block, and an exact
        # rational bounded-real certificate (scipy's solution is 1e-3 off where X spans 1e13; §8.5); each exact
        # solve is up to 2 s at n = 8: none starts after the time limit
        def check(K, Pq, g):  # (the bracket repeats it: a failing candidate costs no bracket)
            return check_hinf_exact(Pq, g, lifted.numeric(K[None]))

        for step, root, K, Pq, g in _game_exact_proposals(F, G, E, C, Du, Dw, level, check):
            if have and np.sqrt(g) >= best["performance"].certificate_upper or out_of_time(seconds_left):
                break
            P0 = floats(Pq)
            if consider(K, 0.5 * (P0 + P0.T), (Pq, g), game_level=float(np.sqrt(g)), game_step=step,
                        game_bisection=root, game_how="exact"):
                break
        if found is not None:
            level = found["game_bisection"]
    for step in GAME_STEPS if found is None or found["performance"].certificate_upper > level * (1 + GAME_CLOSE) \
            else ():
        if have and level * (1 + step) >= best["performance"].certificate_upper:
            break  # nothing better to find above the certified level
        out = game_gains(F, G, E, C, Du, Dw, level * (1 + step))
        if out is not None and consider(out[0], out[1], game_level=level * (1 + step), game_step=step,
                                        game_bisection=level):
            break
    if found is None or (have and not found["performance"].certificate_upper <
                         best["performance"].certificate_upper * (1 - 1e-9)):
        return None
    return found


def _no_design(lifted: Lifted, options: DesignOptions, clock: RunClock, objective: str, reason: str,
               info: SolveInfo | None, x0: np.ndarray | None = None, u_max: np.ndarray | None = None,
               base: DesignResult | None = None) -> DesignResult:
    """No certified design: "infeasible"/"marginal" (proven) or "not_converged".

    With input limits and ``x0``, a Farkas certificate of the limits (:mod:`solver.limit_proofs`) decides
    first; otherwise the plain stability design (``base`` when it already ran).

    Every objective here asks for a common quadratic Lyapunov function that the plain ``lmi`` design also
    needs (cost with Q > 0 and input limits imply its strict inequality), so its Farkas proof excludes them too.
    """
    if u_max is not None and x0 is not None:  # the limits themselves may be what no design meets
        from ..limit_proofs import prove_limits_infeasible

        name = str(options.solver).upper()
        proof, why_not = prove_limits_infeasible(lifted.modes, u_max, x0, options.decay_rate, options.margin,
                                                 strict=STRICT if objective == "stability" else None,
                                                 time_limit=clock.remaining(options.time_limit),
                                                 solver=name if name in ("AUTO", "IPM") else "CLARABEL")
        # the verdict needs the proof to reach every ellipsoid the plain design searches (W <= radius^2 I)
        reach = np.sqrt(lifted.modes.n_states) * MAX_RADIUS * max(1.0, float(np.linalg.norm(x0)))
        if proof is not None and proof.radius < reach:
            why_not = f"a Farkas certificate of the limits reaches only part of the designs: {proof.statement()}"
            proof = None
        if proof is not None:
            why = proof.statement()
            if proof.decay_rate != options.decay_rate:  # the strict fallback: say why that rate covers the method
                why += (f"; every design of this method meets decay rate {proof.decay_rate:.7g} (its stability "
                        f"blocks carry 1 + {STRICT:g})")
            res = finish(lifted.modes, "lmi", proof_outcome(proof), None, proof, None,
                         clock, proof.multipliers.solver or "CLARABEL", "" if info is None else info.status,
                         f"{reason}; {why}",
                         [IterationRecord(0, float("nan"), None, False, None, float("nan"), clock.elapsed)], options)
            res.objective = objective
            return res
        reason = f"{reason}; {why_not}"
    base = lmi.run(lifted.modes, options) if base is None else base
    if base.outcome in ("infeasible", "marginal"):  # each names what its Farkas certificate proves
        base.message = f"{reason}; {base.message}"
        base.objective = objective
        return base
    if base.outcome == "stabilized":
        why = (f"{reason}, although stabilizing gains exist (plain lmi design); no certificate that the "
               f"{objective} design is impossible was re-checked")
    else:
        why = f"{reason}; the plain stability design did not settle either: {base.message}"
    record = IterationRecord(0, float("nan"), None, False, None, float("nan"), clock.elapsed)
    res = finish(lifted.modes, "lmi", "not_converged", None, None, None, clock,
                 "CLARABEL" if info is None else info.solver, "" if info is None else info.status, why, [record],
                 options)
    res.objective = objective
    return res


#: Newton steps of the exact game iteration at one level at most (quadratic convergence from scipy's X, whose
#: relative error is 1e-3 where X spans 1e13: ~4 steps to the gains' rounding).
GAME_EXACT_STEPS = 8


def game_newton_exact(F, G, E, C, Du, Dw, g, X, K=None, lift=None, steps: int = GAME_EXACT_STEPS,
                      tol: float = 0.0):
    """Newton's iteration on the game Riccati equation at ``g = gamma^2`` (``K`` None), or on the bounded-real
    equation of the loop ``u = K x`` (``K`` given: the disturbance's Kleinman iteration), with each X solved exactly
    (:func:`solver.exact.lyapunov_exact` for the loop ``F + [G E] L`` and the game's stage) and each gain formed
    exactly and rounded once (:func:`solver.exact.game_gain_exact`); docs/design.md §8.5.

    X: the start (n x n Fractions or float64; scipy's solution is 1e-3 off where X spans 1e13, still inside
    Newton's quadratic basin).  ``lift`` (n x n Fractions): added to the stage (slack in the state block).  Stops
    when no entry of X changes by more than ``tol`` times its largest (0: the rounded gains' fixed point; X spans
    1e13, so a relative 1e-15 leaves its small directions 1e-2 off, more than a certificate's slack there).
    Returns ``(L, X, Hww)``: the gains ``[K; L_w]`` (float64) formed from the last X (Fractions) and the disturbance
    block of the saddle there, or None (a singular block or equation, or the bits limit of the exact solves).
    """
    from ..exact import game_gain_exact, game_stage_exact, lyapunov_exact

    if isinstance(X, np.ndarray):
        X = fractions(X)
    n, m = G.shape
    B, D = np.hstack([G, E]), np.hstack([Du, Dw])
    out = None
    for _ in range(steps):
        out = game_gain_exact(F, G, E, C, Du, Dw, g, X, K)
        if out is None or not np.all(np.isfinite(out[0])):
            return None
        S = game_stage_exact(C, D, out[0], g, m)
        if lift is not None:
            S = [[S[i][j] + lift[i][j] for j in range(n)] for i in range(n)]
        X_next = lyapunov_exact(F, B, out[0], None, None, S=S, definite=False)
        if X_next is None:
            return None
        top = max(abs(v) for row in X_next for v in row)
        change = max(abs(a - b) for r, q in zip(X_next, X) for a, b in zip(r, q))
        X = X_next
        if not top > 0 or change <= tol * top:
            break
    out = game_gain_exact(F, G, E, C, Du, Dw, g, X, K)
    if out is None or not np.all(np.isfinite(out[0])):
        return None
    return out[0], X, out[1]


def game_root(F, G, E, C, Du, Dw, level: float, X0):
    """The least level of the game Riccati equation where it ends by its disturbance block: the root of
    ``phi(g) = lambda_max(Dw'Dw - g I + E'X(g)E)`` (X(g) the Newton solution, :func:`game_newton_exact`), by the
    secant method on ``g = gamma^2`` from ``level`` (scipy's bisection, 1e-3 off where X spans 1e13) and
    ``level (1 + 1e-3)``.  phi is smooth through the root (X(g) continues below it; the saddle's sign on w fails
    there), so the secant converges in a few steps, each a warm-started exact Newton solve (docs/design.md §8.5).
    Returns ``(gamma, X)`` (X Fractions at the last level tried) or None (no sign change found, e.g. where the
    level ends by X leaving the stabilizing branch instead)."""
    def phi(g, X):
        r = game_newton_exact(F, G, E, C, Du, Dw, g, X, tol=1e-15)
        if r is None:
            return None
        Hww = floats(r[2])
        return float(np.linalg.eigvalsh(0.5 * (Hww + Hww.T))[-1]), r[1]

    ga, gb = level ** 2, (level * (1 + 1e-3)) ** 2
    a = phi(ga, X0)
    b = None if a is None else phi(gb, a[1])
    if a is None or b is None:
        return None
    (fa, _), (fb, Xb) = a, b
    for _ in range(GAME_SECANT_STEPS):
        if fb == fa:
            return None
        g = gb - fb * (gb - ga) / (fb - fa)
        if not (np.isfinite(g) and g > 0):
            return None
        if abs(g - gb) <= GAME_TOL * g:
            return float(np.sqrt(g)), Xb
        c = phi(g, Xb)
        if c is None:
            return None
        ga, fa = gb, fb
        gb, (fb, Xb) = g, c
    return None


#: Secant steps on the level at most (:func:`game_root`; superlinear, ~6 from scipy's 1e-3).
GAME_SECANT_STEPS = 12


#: Relative steps above the game's least level at which the exact refinement takes gains (:func:`_game_refine`).
GAME_EXACT_LEVELS = (1e-9, 1e-8, 1e-7, 1e-6, 1e-5)
#: Slack added to the loop's bounded-real stage, times ``|C|^2 I``: it covers the rounding of the disturbance's
#: gain in the last Newton step (the value of a rounded gain misses the Riccati inequality by its square).
GAME_EXACT_LIFTS = (1e-12, 1e-14, 1e-10)


def _game_exact_proposals(F, G, E, C, Du, Dw, level: float, check):
    """Gains and exact rational certificates of one LTI loop's H-infinity game (docs/design.md §8.5): the least
    level by :func:`game_root`, the game's gains at ``root (1 + step)`` (:func:`game_newton_exact`, the saddle's
    signs and both loops' stability checked), then the loop's own bounded-real equation at that level with a
    small lift of the stage, solved by the disturbance's exact Newton steps: its X, rational, is the candidate,
    kept when ``check(K, X, g)`` (the exact re-check on the deployed loop) passes.  Yields ``(step, root, K, X, g)``.
    """
    n, m = G.shape
    # scipy's solution a little above its level is the start (its sign tests fail up to 10 % above it where X
    # spans 1e14, hold-out seeds 19, 31, 47: the next step up then)
    start = next((s for s in (game_gains(F, G, E, C, Du, Dw, level * (1 + step)) for step in (1e-3, 1e-2, 1e-1, 1.0))
                  if s is not None), None)
    if start is None:
        return
    try:
        found = game_root(F, G, E, C, Du, Dw, level, start[1])
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError):
        found = None
    if found is None:
        return
    root, X = found
    size = float(np.linalg.norm(C, 2)) ** 2
    for step in GAME_EXACT_LEVELS:
        g = float((root * (1 + step)) ** 2)
        r = game_newton_exact(F, G, E, C, Du, Dw, g, X)
        if r is None:
            continue
        L, X1, Hww = r
        K = L[:m]
        Hf = floats(Hww)
        if not np.linalg.eigvalsh(0.5 * (Hf + Hf.T))[-1] < 0 or \
                not np.max(np.abs(np.linalg.eigvals(F + G @ K))) < 1 or \
                not np.max(np.abs(np.linalg.eigvals(F + np.hstack([G, E]) @ L))) < 1:
            continue
        for eps in GAME_EXACT_LIFTS:
            lift = fractions(eps * size * np.eye(n))
            b = game_newton_exact(F, G, E, C, Du, Dw, g, X1, K=K, lift=lift)
            if b is None:
                continue
            Hb = floats(b[2])
            if not np.linalg.eigvalsh(0.5 * (Hb + Hb.T))[-1] < 0 or not check(K, b[1], g):
                continue
            yield step, root, K, b[1], g
            break
