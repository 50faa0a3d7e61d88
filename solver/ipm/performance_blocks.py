"""The performance designs' SDPs as grouped structured LMIs (docs/design.md, §7 and §8.3).

:func:`performance_problem` builds the :class:`solver.ipm.model.GroupedLMI` of a cost, H-infinity or
input-limited design from the lifted data (:mod:`solver.lifting`); :func:`solve_performance` solves it
(:func:`solver.ipm.algorithm.solve_grouped`) and returns ``W``, the gains' ``Y_j`` and the scalars in the
design's coordinates.  The blocks are those of :func:`solver.methods.performance.build` (the cvxpy form the
Clarabel path solves), one group per block kind and side:

========================  ======================================================  =============
group                     blocks (in this order)                                  side
========================  ======================================================  =============
``cost_eta{e}``           ``[[W, V_s'], [V_s, diag(W, I or gamma I)]]``, the      2n + min(e(n+m),
                          modes s with ``eta_s = e`` (``modes`` lists them)      n + e m)
``hinf_eta{e}``           ``[[diag(W, g I), U_s'], [U_s, diag(W, I)]]``           2n + e p_w +
                                                                                  min(e p_z, c)
``stability``             ``[[W, c_s (A_s W)'], [c_s A_s W, W]]``, every mode     2n
``Z``                     ``[[Z, I], [I, W]]``                                    2n
``x0``                    ``[[level, x0'], [x0, W]]`` (level 1 or gamma)          n + 1
``input``                 ``[[u_j^2, (Y_q)_j], [(Y_q)_j', W]]``, (q, j) in        n + 1
                          ``input_index`` order (q-major; gains that are zero
                          under the scheme left out)
``radius``                ``radius^2 I - W``                                      n
``ball``                  ``W - tau I``                                           n
``cap``                   ``cap - gamma``                                         1
========================  ======================================================  =============

The cost and output rows of the lifted blocks are replaced by the triangular factor of their coefficients
(``compact=True``, the default; docs/design.md §8.3.1): the same LMIs, with ``c = n + e (m + p_w)``.  With
``merge=True`` (the default) interval lengths whose sides are within :data:`MERGE_RATIO` share one group
(``cost``, or ``cost_0``, ``cost_1``, ... by increasing side), each block padded to the group's side with an identity.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .algorithm import GroupedSolution, IPMOptions, solve_grouped
from .model import BlockGroup, GroupedLMI

__all__ = ["PerformanceProblem", "PerformanceSolution", "performance_problem", "recentre", "solve_performance"]


@dataclass
class PerformanceProblem:
    """A performance design's SDP on the structured solver, with what maps its answer back.

    Attributes
    ----------
    lmi : GroupedLMI
        The max-t (phase 1) form.
    objective : dict
        Phase 2's ``min <c, V>`` (variable name -> coefficients).
    gain_scale : ndarray, shape (J,)
        ``Y_j = Y'_j / gain_scale[j]`` (the solver's ``Y'`` has unit-size coefficients).
    modes : dict
        Group name -> the loop-mode indices of its blocks (``cost_eta*``, ``hinf_eta*``, ``stability``).
    input_index : list of (q, j)
        The ``input`` group's blocks: gain ``K_{q+1}``, input j.
    one_phase : bool
        Solve in one phase first (docs/design.md §8.3.2): the cost and hinf SDPs.  The input-limited one (max tau)
        keeps the two phases: from the infeasible start its free tau runs off (``b'y`` to -1e13 in the first 48
        iterations at n = 12) and at n = 20 it ends at the iteration cap, after which the two phases ran as well.
    """

    lmi: GroupedLMI
    objective: dict
    gain_scale: np.ndarray
    modes: dict = field(default_factory=dict)
    input_index: list = field(default_factory=list)
    one_phase: bool = True


def _scheme(rows, gain_map, scale) -> np.ndarray:
    """``[c_1 ... c_J] / scale`` of affine rows under the scheme: shape (k, J m)."""
    c = rows.scheme(gain_map) / scale[:, None, None]  # (J, k, m)
    return c.transpose(1, 0, 2).reshape(c.shape[1], -1)


def _stack(items: list, nb: int, k: int, cols: int) -> np.ndarray:
    out = np.zeros((nb, k, cols))
    for b, (r0, M) in enumerate(items):
        out[b, r0:r0 + M.shape[0]] = M
    return out


def _lifted_blocks(lifted, kind: str, s_list, n: int, JM: int, M, scale, c, kothare: bool, compact: bool = True,
                   coordinates: np.ndarray | None = None):
    """The per-mode cost (``kind="cost"``), H-infinity or stability blocks of modes ``s_list`` (one side).

    ``compact``: the tail rows (cost or output rows) replaced by the triangular factor of their coefficient
    matrix (exact, docs/design.md §8.3.1): side ``2n + min(eta (n+m), n + eta m)`` for the cost instead of
    ``2n + eta (n + m)``.  ``coordinates``: ``T`` of the state coordinates ``x = T z`` (applied after the
    factorization, so that the blocks are the congruent images of the untransformed ones, docs/design.md §8.3.2).
    """
    lms = [lifted.lifted[s] for s in s_list]
    Tc = np.eye(n) if coordinates is None else np.asarray(coordinates, dtype=np.float64)
    Ti = np.eye(n) if coordinates is None else np.linalg.inv(Tc)
    nb = len(lms)
    tails = []
    for s, lm in zip(s_list, lms):
        rows = lm.cost if kind == "cost" else lm.output if kind == "hinf" else None
        if rows is None:
            tails.append(None)
            continue
        Ys = _scheme(rows, M, scale) if JM else np.zeros((rows.free.shape[0], 0))
        tails.append((rows.free, Ys, lm.D if kind == "hinf" else None))
    if compact and kind in ("cost", "hinf"):
        # The tail rows T = [free, Ys, D] meet only an identity (or gamma I) on the diagonal, so the orthogonal
        # congruence diag(I, Q') maps them to Q' T without touching that identity; with T = Q R (thin QR over
        # T's nonzero columns, the union over the group so that its blocks keep one side) the rows Q_perp' T
        # vanish and drop out with their identity rows: the same LMI, exactly (docs/design.md §8.3.1).
        T = np.stack([np.hstack([t for t in tl if t is not None]) for tl in tails])
        cols = np.flatnonzero(np.any(T != 0, axis=(0, 1)))
        if T.shape[1] > cols.size:
            out = []
            for f, Ys, D in tails:
                Tb = np.hstack([f, Ys] + ([] if D is None else [D]))
                R = np.zeros((cols.size, Tb.shape[1]))
                R[:, cols] = np.linalg.qr(Tb[:, cols], mode="r")
                a, b = n, n + Ys.shape[1]
                out.append((R[:, :a], R[:, a:b], None if D is None else R[:, b:]))
            tails = out
    if kind == "cost":
        extra, tail = 0, tails[0][0].shape[0]
    elif kind == "hinf":
        extra, tail = lms[0].B.shape[1], tails[0][0].shape[0]
    else:
        extra, tail = 0, 0
    k = 2 * n + extra + tail
    a0 = n + extra  # first row of A_s W
    Lf = np.zeros((nb, k, n))
    Lf[:, :n] = 0.5 * np.eye(n)  # sym([I/2; F] W [I 0]) = [[W, (F W)'], [F W, 0]]
    LY = np.zeros((nb, k, JM))
    C = np.zeros((nb, k, k))
    for b, (s, lm) in enumerate(zip(s_list, lms)):
        # x = T z: A_s -> T^-1 A_s T, gains K -> K T (Y -> Y T^-1 W-side), tail rows -> rows T, B -> T^-1 B
        Lf[b, a0:a0 + n] = c[s] * (Ti @ lm.state.free @ Tc)
        if JM:
            LY[b, a0:a0 + n] = c[s] * (Ti @ _scheme(lm.state, M, scale))
        if tails[b] is not None:
            free, Ys, D = tails[b]
            Lf[b, a0 + n:] = free @ Tc
            if JM:
                LY[b, a0 + n:] = Ys
        if kind == "hinf":
            B = Ti @ lm.B
            C[b, a0:a0 + n, n:a0] = B
            C[b, a0 + n:, n:a0] = D
            C[b, n:a0, a0:] = np.vstack([B, D]).T
    R = np.broadcast_to(np.eye(n, k), (nb, n, k))
    Lb = np.zeros((1, k, n))
    Lb[0, a0:a0 + n] = np.eye(n)
    terms = {"W": [(Lf, R, 1.0), (np.broadcast_to(Lb, (nb, k, n)), None, 1.0)]}
    if JM:
        terms["Y"] = [(LY, R, 1.0)]
    scalars = {}
    if kind == "cost":
        D = np.zeros((nb, k, k))
        D[:, a0 + n:, a0 + n:] = np.eye(tail)
        if kothare:
            scalars["gamma"] = D
        else:
            C += D
    elif kind == "hinf":
        D = np.zeros((nb, k, k))
        D[:, n:a0, n:a0] = np.eye(extra)
        scalars["g"] = D
        C[:, a0 + n:, a0 + n:] += np.eye(tail)
    return C, terms, scalars


#: Interval lengths whose blocks' sides are within this ratio share one group (padded to the largest side).
MERGE_RATIO = 1.25


def _merge_groups(parts: list, n: int):
    """One group of the blocks of several ``(C, terms, scalars)`` (different sides): each block padded to the
    largest side with an identity (``[[B, 0], [0, I]] >= 0`` iff ``B >= 0``), so the Schur complement is assembled
    once instead of once per interval length (the per-group overhead dominated at n = 12, n_drop = 10)."""
    k = max(C.shape[1] for C, _, _ in parts)
    nb = sum(C.shape[0] for C, _, _ in parts)

    def pad(M, rows: bool, cols: bool):
        M = np.asarray(M)
        out = np.zeros((M.shape[0], k if rows else M.shape[1], k if cols else M.shape[2]))
        out[:, :M.shape[1], :M.shape[2]] = M
        return out

    C = np.concatenate([pad(Cg, True, True) for Cg, _, _ in parts])
    b0 = 0
    for Cg, _, _ in parts:
        kg = Cg.shape[1]
        C[b0:b0 + Cg.shape[0], kg:, kg:] += np.eye(k - kg)
        b0 += Cg.shape[0]
    terms = {}
    for var, lst in parts[0][1].items():
        merged = []
        for i, (_, R0, c0) in enumerate(lst):
            Ls = [np.broadcast_to(pt[1][var][i][0], (pt[0].shape[0],) + pt[1][var][i][0].shape[1:]) for pt in parts]
            L = np.concatenate([pad(x, True, False) for x in Ls])
            if np.all(L == L[:1]):  # the same in every block (a selector): keep it broadcast
                L = np.broadcast_to(L[:1], L.shape)
            R = None if R0 is None else np.broadcast_to(np.eye(n, k), (nb, n, k))
            merged.append((L, R, c0))
        terms[var] = merged
    scalars = {v: np.concatenate([pad(np.broadcast_to(pt[2][v], pt[0].shape), True, True) for pt in parts])
               for v in parts[0][2]}
    return C, terms, scalars


def _bordered(n: int, corner: float, border: np.ndarray) -> np.ndarray:
    """``[[corner, border'], [border, 0]]``, shape (1, n + 1, n + 1)."""
    C = np.zeros((1, n + 1, n + 1))
    C[0, 0, 0] = corner
    C[0, 1:, 0] = border
    C[0, 0, 1:] = border
    return C


def performance_problem(lifted, objective: str, x0: np.ndarray | None, u_max: np.ndarray | None,
                        c: np.ndarray | None = None, cap: float | None = None, radius: float | None = None,
                        limit_slack: float = 0.0, trace_weight: np.ndarray | None = None,
                        compact: bool = True, merge: bool = True, tie_weight: float | None = None,
                        metric: np.ndarray | None = None, coordinates: np.ndarray | None = None) -> PerformanceProblem:
    """The SDP of one performance design (the blocks of :func:`solver.methods.performance.build`).

    Parameters
    ----------
    lifted : solver.lifting.Lifted
    objective : {"cost", "hinf", "stability", "limits"}
        ``"stability"``: the plain input-limited design (``u_max`` required), maximize ``tau`` with
        ``W >= tau I`` (the largest ball inside the invariant ellipsoid).  ``"limits"``: the stability, input
        and x0 blocks alone (no ball, no radius, no scalar), whose phase 1 (``max t``) gives the input limits'
        Farkas multipliers (:func:`solver.limit_proofs.limits_multipliers`).
    x0 : ndarray, shape (n,), or None
    u_max : ndarray, shape (m,), or None
    c : ndarray, shape (S,), optional
        Stability blocks' factors (``objective="stability"``).
    cap : float, optional
        Cost from x0 without limits: the tie-break stage (``gamma <= cap``, minimize ``trace Z``).
    radius : float, optional
        ``W <= radius^2 I`` (``objective="stability"``).
    metric : ndarray, shape (n, n), optional
        ``objective="stability"``: ``W >= tau N`` and ``W <= radius^2 N`` with this positive definite ``N``
        instead of ``I`` (the same SDP in state coordinates ``x = T z``, ``N = (T' T)^{-1}``; see
        :func:`solver.methods.performance.similar`).
    limit_slack : float
        ``u_max (1 - limit_slack)`` in the input blocks.
    trace_weight : ndarray, shape (n,), optional
        Minimize ``sum_i w_i Z_ii`` instead of ``trace Z`` (the user's trace in balanced coordinates).
    tie_weight : float, optional
        Cost from x0 without limits: the tie-break stage as one objective, minimize ``gamma + tie_weight trace Z``
        (``sum_i w_i Z_ii`` with ``trace_weight``) with ``Z >= W^{-1}``; no ``cap`` block (its feasible set is a
        slice too thin for phase 1 to centre in, docs/design.md §8.5).
    compact : bool
        Cost and output rows of each lifted block reduced to their triangular factor (docs/design.md §8.3.1:
        the same LMI, side ``3n + eta m`` instead of ``2n + eta (n + m)`` for the cost); False: the lifted
        blocks as written (the reference the tests compare with).
    merge : bool
        The per-mode blocks of every interval length in one group ``cost`` / ``hinf``, each padded to the largest
        side with an identity (:func:`_merge_groups`); False: one group per length (``cost_eta{e}``).
    coordinates : ndarray, shape (n, n), optional
        Cost and hinf: the same SDP in the state coordinates ``x = T z`` (docs/design.md §8.3.2, the recentred
        stage): its variables are ``W' = T^-1 W T^-T``, ``Y' = Y T^-T``, ``Z' = T' Z T`` and every block is the
        congruent image of the untransformed one (:func:`recentre`).
    """
    modes = lifted.modes
    n, m, J = modes.n_states, modes.n_inputs, modes.n_free_gains
    M = modes.gain_map
    JM = J * m
    kinds = [lm.state for lm in lifted.lifted] + [lm.cost for lm in lifted.lifted if lm.cost is not None] + \
        [lm.output for lm in lifted.lifted if lm.output is not None]
    scale = np.ones(J)
    if J:
        scale = np.max([np.abs(r.scheme(M)).max(axis=(1, 2)) for r in kinds], axis=0)
        scale = np.where(scale > 0, scale, 1.0)
    S = len(lifted.lifted)
    kothare = objective == "cost" and u_max is not None
    limits = objective == "limits"
    if limits:
        objective = "stability"
    groups, group_modes, input_index = [], {}, []
    scalars = []
    if objective in ("cost", "hinf", "stability"):
        kind = objective
        cs = np.ones(S) if c is None or objective != "stability" else np.asarray(c, dtype=np.float64)
        if kind == "stability":
            by_side = {0: list(range(S))}
        else:
            by_side = {}
            for s, lm in enumerate(lifted.lifted):
                by_side.setdefault(lm.eta, []).append(s)
        parts = []
        for eta, s_list in sorted(by_side.items()):
            C, terms, sc = _lifted_blocks(lifted, kind, s_list, n, JM, M, scale, cs, kothare, compact,
                                          None if kind == "stability" else coordinates)
            name = "stability" if kind == "stability" else f"{kind}_eta{eta}"
            parts.append((C, terms, sc))
            group_modes[name] = s_list
        if merge and len(parts) > 1:
            # lengths whose sides are within MERGE_RATIO of the bucket's smallest share one padded group (the
            # padding costs (k / k_b)^3 in the blocks' factorizations, one group per length a Schur assembly each)
            buckets, names = [], list(group_modes)
            for name, pt in zip(names, parts):
                if buckets and pt[0].shape[1] <= MERGE_RATIO * buckets[-1][0][1][0].shape[1]:
                    buckets[-1].append((name, pt))
                else:
                    buckets.append([(name, pt)])
            merged_modes = {}
            for i, bucket in enumerate(buckets):
                name = kind if len(buckets) == 1 else f"{kind}_{i}"
                pts = [pt for _, pt in bucket]
                groups.append(BlockGroup(name, *(_merge_groups(pts, n) if len(pts) > 1 else pts[0])))
                merged_modes[name] = [s for nm, _ in bucket for s in group_modes[nm]]
            group_modes = merged_modes
        else:
            groups += [BlockGroup(name, *pt) for name, pt in zip(group_modes, parts)]
    else:
        raise ValueError(f"objective must be 'cost', 'hinf' or 'stability', got {objective!r}")
    Ltop = np.zeros((1, 2 * n, n))
    Ltop[0, :n] = np.eye(n)
    Lbot = np.zeros((1, 2 * n, n))
    Lbot[0, n:] = np.eye(n)
    Lb1 = np.zeros((1, n + 1, n))
    Lb1[0, 1:] = np.eye(n)
    eye_n = np.eye(n)[None]
    metric_n = eye_n if metric is None else np.asarray(metric, dtype=np.float64)[None]
    use_Z = objective == "cost" and (x0 is None or cap is not None or tie_weight is not None)
    if use_Z:
        C = np.zeros((1, 2 * n, 2 * n))
        C[0, :n, n:] = C[0, n:, :n] = np.eye(n)
        groups.append(BlockGroup("Z", C, {"Z": [(Ltop, None, 1.0)], "W": [(Lbot, None, 1.0)]}))
    if objective == "cost":
        scalars = ["gamma"] if (kothare or x0 is not None) else []
    elif objective == "hinf":
        scalars = ["g"]
    else:
        scalars = [] if limits else ["tau"]
    if coordinates is not None and objective in ("cost", "hinf"):
        Ti = np.linalg.inv(coordinates)
        x0 = None if x0 is None else Ti @ x0
        if objective == "cost":
            tw = np.ones(n) if trace_weight is None else np.asarray(trace_weight, dtype=np.float64)
            tw = np.diag(tw) if tw.ndim == 1 else tw
            trace_weight = Ti @ tw @ Ti.T  # <Wt, P> = <T^-1 Wt T^-T, T' P T>
    if x0 is not None:
        level_var = objective == "cost" and not kothare
        D = {"gamma": _bordered(n, 1.0, np.zeros(n))} if level_var else {}
        groups.append(BlockGroup("x0", _bordered(n, 0.0 if level_var else 1.0, x0), {"W": [(Lb1, None, 1.0)]}, D))
    if cap is not None:
        groups.append(BlockGroup("cap", np.full((1, 1, 1), float(cap)), {}, {"gamma": -np.ones((1, 1, 1))}))
    if u_max is not None:
        rows = []
        for q in range(modes.n_drop):
            if not np.any(M[q]):
                continue  # K_q = 0 under this scheme
            for j in range(m):
                L = np.zeros((n + 1, JM))
                for jj in range(J):
                    L[0, jj * m + j] = M[q, jj] / scale[jj]
                rows.append(L)
                input_index.append((q, j))
        nb = len(rows)
        if nb:
            C = np.zeros((nb, n + 1, n + 1))
            C[:, 0, 0] = (np.asarray(u_max, dtype=np.float64)[[j for _, j in input_index]] * (1 - limit_slack))**2
            R = np.broadcast_to(np.eye(n, n + 1, 1), (nb, n, n + 1))
            groups.append(BlockGroup("input", C, {"W": [(np.broadcast_to(Lb1, (nb, n + 1, n)), None, 1.0)],
                                                  "Y": [(np.stack(rows), R, 1.0)]}))
    if objective == "stability" and not limits:
        if radius is not None:
            groups.append(BlockGroup("radius", float(radius)**2 * metric_n, {"W": [(eye_n, None, -1.0)]}))
        groups.append(BlockGroup("ball", np.zeros((1, n, n)), {"W": [(eye_n, None, 1.0)]}, {"tau": -metric_n}))
    matrices = [("W", (n, n), n)]
    if JM:
        matrices.append(("Y", (JM, n), None))
    if use_Z:
        matrices.append(("Z", (n, n), n))
    if not JM:
        for g in groups:
            g.terms.pop("Y", None)
    V0 = [np.zeros(sh) for _, sh, _ in matrices] + [np.zeros((1, 1)) for _ in scalars]
    lmi = GroupedLMI(matrices, scalars, groups, V0)
    if objective == "cost":
        weight = np.eye(n) if trace_weight is None else np.asarray(trace_weight, dtype=np.float64)
        obj = {"Z": np.diag(weight) if weight.ndim == 1 else weight} if use_Z else {"gamma": 1.0}
        if tie_weight is not None:
            obj = {"gamma": 1.0, "Z": float(tie_weight) * obj["Z"]}
    elif objective == "hinf":
        obj = {"g": 1.0}
    else:
        obj = {} if limits else {"tau": -1.0}
    return PerformanceProblem(lmi=lmi, objective=obj, gain_scale=scale, modes=group_modes, input_index=input_index,
                              one_phase=objective in ("cost", "hinf"))


@dataclass
class PerformanceSolution:
    """Result of :func:`solve_performance`.

    Attributes
    ----------
    status : str
        :class:`solver.ipm.algorithm.GroupedSolution`'s.
    W : ndarray, shape (n, n)
    Y : list of ndarray, shape (m, n) each
        ``Y_j = Theta_j W`` (the scheme's free gains times W).
    scalars : dict
        ``gamma``, ``g`` or ``tau`` (whichever the problem has); ``Z`` when present.
    value : float
        The attained objective (``trace Z``, ``gamma``, ``g`` or ``-tau``).
    raw : GroupedSolution
        Everything else: ``X`` per group (Farkas certificate when infeasible), ``t``, iterations, timings.
    problem : PerformanceProblem
    """

    status: str
    W: np.ndarray
    Y: list
    scalars: dict
    value: float
    raw: GroupedSolution
    problem: PerformanceProblem


def solve_performance(problem: PerformanceProblem, options: IPMOptions | None = None,
                      y_start: np.ndarray | None = None, x_start: list | None = None) -> PerformanceSolution:
    """Solve a :class:`PerformanceProblem` (in one phase, else phase 1 and then the objective; only the objective
    from ``y_start``, a strictly feasible point, when given, with multipliers ``x_start`` when given) and map the
    answer back."""
    sol = solve_grouped(problem.lmi, problem.objective, options, one_phase=problem.one_phase, y_start=y_start,
                        x_start=x_start)
    W = sol.V["W"]
    W = 0.5 * (W + W.T)
    J = len(problem.gain_scale)
    Ys = sol.V.get("Y")
    m = 0 if Ys is None or J == 0 else Ys.shape[0] // J
    Y = [Ys[j * m:(j + 1) * m] / problem.gain_scale[j] for j in range(J)] if Ys is not None else []
    scalars = {k: v for k, v in sol.V.items() if k not in ("W", "Y")}
    return PerformanceSolution(status=sol.status, W=W, Y=Y, scalars=scalars, value=sol.value, raw=sol,
                               problem=problem)


def _congruence(problem: PerformanceProblem, name: str, C: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``D_b`` (nb, k, k) of group ``name`` with ``S_b = D_b S'_b D_b'`` between the problem in the user's state
    coordinates and the one in ``x = T z`` (:func:`performance_problem`'s ``coordinates``): ``T`` on the rows of
    ``W`` and ``A_s W``, ``T^-T`` on ``Z``'s, the identity elsewhere (``[[1, x0'], [x0, W]]``, the input blocks and
    padding included)."""
    nb, k, _ = C.shape
    n = T.shape[0]
    D = np.broadcast_to(np.eye(k), (nb, k, k)).copy()
    grp = next(g for g in problem.lmi.groups_spec if g.name == name)
    if name == "Z":
        D[:, :n, :n] = np.linalg.inv(T).T
        D[:, n:, n:] = T
        return D
    if name == "cap":
        return D
    if name in ("x0", "input"):
        D[:, 1:, 1:] = T
        return D
    if name.startswith(("cost", "hinf")):
        Lw = np.broadcast_to(grp.terms["W"][1][0], (nb, k, n))  # the selector of A_s W's rows
        for b in range(nb):
            a0 = int(np.argmax(Lw[b, :, 0]))
            D[b, :n, :n] = T
            D[b, a0:a0 + n, a0:a0 + n] = T
        return D
    raise ValueError(f"no congruence for group {name!r}")


def recentre(first: PerformanceProblem, sol: "PerformanceSolution", second: PerformanceProblem,
             T: np.ndarray) -> tuple[np.ndarray, list]:
    """The start of ``second`` (``first`` in the state coordinates ``x = T z``) at ``sol``'s iterate: ``(y, X)``.

    The variables map as ``W' = T^-1 W T^-T``, ``Y' = Y T^-T``, ``Z' = T' Z T`` (scalars unchanged) and each block's
    multipliers as ``X'_b = D_b' X_b D_b`` (:func:`_congruence`), so ``<X', S'> = <X, S>`` block by block: the same
    iterate of the same problem, in coordinates where the answer's ``W`` is about ``I`` (docs/design.md §8.3.2).
    """
    lmi1, lmi2 = first.lmi, second.lmi
    Ti = np.linalg.inv(T)
    V = sol.raw.V
    parts = []
    for nm, sh in zip(lmi2.names, lmi2.shapes):
        v = np.asarray(V[nm], dtype=np.float64).reshape(sh)
        if nm == "W":
            v = Ti @ v @ Ti.T
            v = 0.5 * (v + v.T)
        elif nm == "Y":
            v = v @ Ti.T
        elif nm == "Z":
            v = T.T @ v @ T
            v = 0.5 * (v + v.T)
        parts.append(v.ravel())
    if lmi2.with_t:
        parts.append(np.zeros(1))
    y = coordinates_of(lmi2, np.concatenate(parts))
    X = []
    for g1, C in zip(lmi1.groups_spec, lmi1.C):
        D = _congruence(first, g1.name, C, T)
        Xg = sol.raw.X[g1.name]
        Xn = D.transpose(0, 2, 1) @ Xg @ D
        X.append(0.5 * (Xn + Xn.transpose(0, 2, 1)))
    return y, X


def coordinates_of(lmi: GroupedLMI, x: np.ndarray) -> np.ndarray:
    """The solver's coordinates ``y`` of the full variable vector ``x`` (``x = T y``, x in T's range): the normal
    equations on the sparse basis (``T' T`` is diagonal for these bases: each full entry is one coordinate; a dense
    least-squares solve took 2.4 s at n = 30)."""
    import scipy.sparse.linalg

    T = lmi.T.tocsc()
    return np.asarray(scipy.sparse.linalg.spsolve((T.T @ T).tocsc(), T.T @ x), dtype=np.float64).reshape(-1)
