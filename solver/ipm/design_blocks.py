"""The design methods' SDPs as structured LMIs, and their solve calls (docs/design.md).

``lmi_problem`` / ``switched_problem`` build the :class:`solver.ipm.model.BlockLMI` of the ``lmi`` and
``switched`` designs; ``solve_*`` and ``design_solve*`` solve them with :mod:`solver.ipm.algorithm` and
return the variables in the design's coordinates.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from dataclasses import replace

from ..memo import BoundedCache
from .algorithm import IPMOptions, IPMSolution, WarmStart, _SolveStatus, solve_block_lmi
from .model import BlockLMI, MatrixVariable

def _selectors(n: int):
    """``P1`` (2n, n) selecting the top half, ``P2`` the bottom half."""
    P1 = np.zeros((2 * n, n))
    P1[:n] = np.eye(n)
    P2 = np.zeros((2 * n, n))
    P2[n:] = np.eye(n)
    return P1, P2


def _gain_L(coef: np.ndarray, active: np.ndarray | None) -> np.ndarray:
    """``[coef_{s,1} ... coef_{s,J}]`` per mode, inactive terms zeroed: shape (S, n, J m)."""
    S, J, n, m = coef.shape
    c = coef if active is None else coef * np.asarray(active, dtype=float)[:, :, None, None]
    return c.transpose(0, 2, 1, 3).reshape(S, n, J * m)


def lmi_problem(free: np.ndarray, coef: np.ndarray, active: np.ndarray | None = None,
                rho: np.ndarray | None = None) -> BlockLMI:
    """The ``lmi`` design SDP as a :class:`BlockLMI` (docs/design.md, "The structured interior-point solver").

    ``max t`` s.t. ``trace W = n`` and, per mode s,
    ``[[rho_s W, (A_s W)^T], [A_s W, W]] - t I >= 0`` with
    ``A_s W = free_s W + sum_j coef_{s,j} Y_j``.

    Parameters
    ----------
    free : ndarray, shape (S, n, n)
    coef : ndarray, shape (S, J, n, m)
    active : ndarray of bool, shape (S, J), optional
        Terms left out where False (as :meth:`solver.network.ModeSet.scheme_coef` says).
    rho : ndarray, shape (S,), optional
        Top-left factors (default 1; the congruent decay-rate form needs none).
    """
    free = np.asarray(free, dtype=np.float64)
    coef = np.asarray(coef, dtype=np.float64)
    S, n, _ = free.shape
    J, m = coef.shape[1], coef.shape[3]
    P2, Rleft, Lbot, C0, a, V0, LF0 = _lmi_consts(S, n, J * m)
    # sym([[rho/2 W], [F W]] [I 0]) = [[rho W, (F W)^T], [F W, 0]] (no cancellation for huge F),
    # plus the sym-kind term [0; I] W [0, I] (one Kronecker product per pair instead of four).
    LF = LF0.copy()  # (S, 2n, n): [I/2; 0] per mode
    LF[:, n:] = free
    C = C0.copy()  # [[I, 0], [0, I]] per mode
    C[:, n:, :n] = free
    C[:, :n, n:] = free.transpose(0, 2, 1)
    if rho is not None:
        sq2 = np.asarray(rho, dtype=np.float64)  # sqrt(rho)^2
        LF[:, :n] *= sq2[:, None, None]
        C[:, :n, :n] *= sq2[:, None, None]
    W = MatrixVariable("W", (n, n), n, [(LF, Rleft, 1.0), (Lbot, None, 1.0)])
    variables = [W]
    if J * m > 0:
        LY = np.zeros((S, 2 * n, J * m))
        LY[:, n:] = _gain_L(coef, active)  # [0; coef_s]
        variables.append(MatrixVariable("Y", (J * m, n), None, [(LY, Rleft, 1.0)]))
    return BlockLMI(C=C, variables=variables, V0=V0, equality=a)


#: Shape-only pieces of :func:`lmi_problem` (selectors, identities, the trace normalization), read-only.
_LMI_CONSTS = BoundedCache(64)


def _lmi_consts(S: int, n: int, Jm: int):
    return _LMI_CONSTS.get_or_compute((S, n, Jm), lambda: _build_lmi_consts(S, n, Jm))


def _build_lmi_consts(S: int, n: int, Jm: int):
    P1, P2 = _selectors(n)
    eye = np.eye(n)
    C0 = np.zeros((S, 2 * n, 2 * n))
    C0[:, :n, :n] = eye
    C0[:, n:, n:] = eye
    LF0 = np.zeros((S, 2 * n, n))
    LF0[:, :n] = 0.5 * eye
    a = np.zeros(n * n + Jm * n)
    a[: n * n: n + 1] = 1.0  # trace W
    V0 = [eye] + ([np.zeros((Jm, n))] if Jm > 0 else [])
    c = (P2, np.broadcast_to(P1.T, (S, n, 2 * n)), np.broadcast_to(P2, (S, 2 * n, n)), C0, a, V0, LF0)
    for arr in (P2, eye, C0, LF0, a, *V0):
        arr.flags.writeable = False
    return c


def switched_problem(free: np.ndarray, coef: np.ndarray, active: np.ndarray | None = None,
                     rho: np.ndarray | None = None) -> BlockLMI:
    """The ``switched`` design SDP as a :class:`BlockLMI`.

    ``max t`` s.t. ``trace Z = n`` and, for every pair (s, u) (block ``s S + u``),
    ``[[rho_s (Z + Z^T - S_s), (A_s Z)^T], [A_s Z, S_u]] - t I >= 0``.
    The ``S_s`` are one stacked variable (S n, n) of symmetric n x n blocks.
    """
    free = np.asarray(free, dtype=np.float64)
    coef = np.asarray(coef, dtype=np.float64)
    S, n, _ = free.shape
    J, m = coef.shape[1], coef.shape[3]
    P1, P2 = _selectors(n)
    B = S * S
    s_of = np.repeat(np.arange(S), S)
    u_of = np.tile(np.arange(S), S)
    sq = np.ones(S) if rho is None else np.sqrt(np.asarray(rho, dtype=np.float64))
    sqb = sq[s_of][:, None, None]
    Rleft = np.broadcast_to(P1.T, (B, n, 2 * n))
    Z = MatrixVariable("Z", (n, n), None, [(sqb * P1[None], sqb * P1.T[None], 1.0),
                                           (P2[None] @ free[s_of], Rleft, 1.0)])
    # Block (s, u) sees S_s (top left) and S_u (bottom right) only: row-block selections of the stack.
    Lss = sqb * P1[None]
    Lsu = np.broadcast_to(P2, (B, 2 * n, n))
    Sv = MatrixVariable("S", (S * n, n), n, [(Lss, sqb * P1.T[None], -0.5, s_of),
                                            (Lsu, np.broadcast_to(P2.T, (B, n, 2 * n)), 0.5, u_of)])
    variables = [Z, Sv]
    if J * m > 0:
        LY = P2[None] @ _gain_L(coef, active)[s_of]
        variables.append(MatrixVariable("Y", (J * m, n), None, [(LY, Rleft, 1.0)]))
    C = np.zeros((B, 2 * n, 2 * n))
    C[:, :n, :n] = (sq[s_of] ** 2)[:, None, None] * np.eye(n)
    C[:, n:, n:] = np.eye(n)
    C[:, n:, :n] = free[s_of]
    C[:, :n, n:] = np.swapaxes(free[s_of], 1, 2)
    a = np.zeros(sum(v.size for v in variables))
    a[: n * n: n + 1] = 1.0  # trace Z
    V0 = [np.eye(n), np.tile(np.eye(n), (S, 1))] + ([np.zeros((J * m, n))] if J * m > 0 else [])
    return BlockLMI(C=C, variables=variables, V0=V0, equality=a)


def _split_Y(Ystack: np.ndarray | None, J: int, m: int, n: int, scale: np.ndarray) -> np.ndarray:
    if Ystack is None:
        return np.zeros((J, m, n))
    return Ystack.reshape(J, m, n) / scale[:, None, None]


def _gain_scale(coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scale each free gain's coefficients to unit size: ``coef_j / s_j`` with ``Y_j = Y'_j / s_j``.

    Input matrices of 1e6 (or 1e-6) would otherwise make the Y columns of the
    Schur complement 1e12 times larger (smaller) than W's.
    """
    if coef.size == 0:
        return coef, np.ones(coef.shape[1])
    s = np.abs(coef).max(axis=(0, 2, 3))
    s = np.where(s > 0, s, 1.0)
    return coef / s[None, :, None, None], s


@dataclass(kw_only=True)
class _DesignSolution(_SolveStatus):
    """The fields every design SDP's result shares (see :class:`LMISolution`)."""

    t: float
    Y: np.ndarray
    duals: np.ndarray
    trace_multiplier: float
    upper: float

    @staticmethod
    def shared(sol: IPMSolution, t0: float, setup: float) -> dict:
        """The status, residual and timing fields from the core's solution (``t0``: start of the call)."""
        timings = dict(sol.timings, setup=setup)
        timings["total"] = time.perf_counter() - t0
        return dict(t=sol.t, duals=sol.X, upper=sol.upper, status=sol.status, iterations=sol.iterations,
                    primal_residual=sol.primal_residual, dual_residual=sol.dual_residual, gap=sol.gap,
                    timings=timings)


@dataclass(kw_only=True)
class LMISolution(_DesignSolution):
    """Result of :func:`solve_lmi` (primal and dual solutions of the ``lmi`` SDP).

    Attributes
    ----------
    t : float
        Attained optimal value (the returned ``W``, ``Y`` make every block
        ``>= t I`` up to rounding, whatever the status).
    W : ndarray, shape (n, n)
        Symmetric, ``trace W = n``.
    Y : ndarray, shape (J, m, n)
    duals : ndarray, shape (S, 2n, 2n)
        ``Z_s``, the multiplier of block s's constraint ``L_s(W, Y) - t I >= 0``:
        PSD, ``sum_s trace Z_s = 1`` -- the same normalization as
        ``constraint.dual_value`` from cvxpy with Clarabel for the same problem.
    trace_multiplier : float
        Multiplier of ``trace W == n`` with cvxpy's sign convention:
        ``sum_s A_W^*(Z_s) = trace_multiplier * I`` at the optimum
        (``A_W^*`` the adjoint of the W-part of the blocks), so ``t* = n *
        trace_multiplier`` ... up to the rho terms (exact for rho = 1).
    upper : float
        Dual objective ``sum_s <C_s, Z_s>``: an upper bound on ``t*`` up to
        ``primal_residual``.
    status : {"optimal", "inaccurate", "max_iterations", "time_limit", "numerical_error"}
    iterations : int
    primal_residual, dual_residual, gap : float
        Relative residuals of the multipliers' equations and of the blocks, and the relative gap.
    timings : dict
        Seconds: ``setup`` (building the structure), ``assembly``, ``factorization``,
        ``line_search``, ``other``, ``total``.
    """

    W: np.ndarray


@dataclass(kw_only=True)
class SwitchedSolution(_DesignSolution):
    """Result of :func:`solve_switched`.

    Attributes
    ----------
    t : float
    Z : ndarray, shape (n, n)
    S : ndarray, shape (S, n, n)
    Y : ndarray, shape (J, m, n)
    duals : ndarray, shape (S*S, 2n, 2n)
        Multiplier of the block of pair (s, u) at index ``s S + u``; ``sum trace = 1``.
    trace_multiplier : float
        Multiplier of ``trace(Z + Z^T) == 2n`` (cvxpy's convention, the constraint as written
        in solver/methods/switched.py).
    upper, status, iterations, primal_residual, dual_residual, gap, timings
        As in :class:`LMISolution`.
    """

    Z: np.ndarray
    S: np.ndarray


def _check_data(free, coef, active):
    free = np.asarray(free, dtype=np.float64)
    coef = np.asarray(coef, dtype=np.float64)
    if free.ndim != 3 or free.shape[1] != free.shape[2] or coef.ndim != 4 or coef.shape[0] != free.shape[0] \
            or coef.shape[2] != free.shape[1]:
        raise ValueError(f"free must be (S, n, n) and coef (S, J, n, m); got {free.shape} and {coef.shape}")
    if not (np.all(np.isfinite(free)) and np.all(np.isfinite(coef))):
        raise ValueError("free and coef must be finite")
    if active is not None:
        active = np.asarray(active, dtype=bool)
        if active.shape != coef.shape[:2]:
            raise ValueError(f"active must have shape {coef.shape[:2]}, got {active.shape}")
    return free, coef, active


def _solve_scaled(build, free, coef, active, rho, options, start: WarmStart | None = None):
    """Check the data, scale the gains' coefficients, build with ``build`` and solve.

    ``start``: a warm start in the design's coordinates (``V = [W, Y]``, ``Y`` of shape (J, m, n), the
    ``lmi`` form only), mapped to the scaled gains here.
    Returns ``(IPMSolution, (S, J, n, m), gain scale, setup seconds)``.
    """
    t0 = time.perf_counter()
    free, coef, active = _check_data(free, coef, active)
    coef_s, gscale = _gain_scale(coef)
    prob = build(free, coef_s, active, rho)
    if start is not None:
        S, J, n, m = coef.shape
        V = [start.V[0]] + ([(np.asarray(start.V[1]) * gscale[:, None, None]).reshape(J * m, n)]
                            if J * m > 0 else [])
        start = replace(start, V=V)
    setup = time.perf_counter() - t0
    return solve_block_lmi(prob, options, start), coef.shape, gscale, setup


def solve_lmi(free, coef, active=None, rho=None, options: IPMOptions | None = None,
              start: WarmStart | None = None) -> LMISolution:
    """Solve the ``lmi`` design SDP (see :func:`lmi_problem`) with the structured IPM.

    Parameters
    ----------
    free : array_like, shape (S, n, n)
    coef : array_like, shape (S, J, n, m)
    active : array_like of bool, shape (S, J), optional
    rho : array_like, shape (S,), optional
    options : IPMOptions, optional
    start : WarmStart, optional
        Warm start, ``V = [W, Y]`` with ``Y`` of shape (J, m, n) (e.g. another rate's solution).

    Returns
    -------
    LMISolution

    Raises
    ------
    ValueError
        On inconsistent shapes or non-finite data.
    """
    t0 = time.perf_counter()
    sol, (S, J, n, m), gscale, setup = _solve_scaled(lmi_problem, free, coef, active, rho, options, start)
    W = sol.V[0]
    W = 0.5 * (W + W.T)
    Y = _split_Y(sol.V[1] if len(sol.V) > 1 else None, J, m, n, gscale)
    return LMISolution(W=W, Y=Y, trace_multiplier=sol.equality_multiplier,
                       **_DesignSolution.shared(sol, t0, setup))


def solve_switched(free, coef, active=None, rho=None, options: IPMOptions | None = None) -> SwitchedSolution:
    """Solve the ``switched`` design SDP (see :func:`switched_problem`) with the structured IPM.

    Parameters and errors as :func:`solve_lmi`; returns :class:`SwitchedSolution`.
    """
    t0 = time.perf_counter()
    sol, (S, J, n, m), gscale, setup = _solve_scaled(switched_problem, free, coef, active, rho, options)
    Sm = sol.V[1].reshape(S, n, n)
    Sm = 0.5 * (Sm + np.swapaxes(Sm, 1, 2))
    Y = _split_Y(sol.V[2] if len(sol.V) > 2 else None, J, m, n, gscale)
    return SwitchedSolution(Z=sol.V[0], S=Sm, Y=Y, trace_multiplier=0.5 * sol.equality_multiplier,
                            **_DesignSolution.shared(sol, t0, setup))


def solve_common_fixed_gain(A, rho=None, options: IPMOptions | None = None) -> LMISolution:
    """The fixed-gain certificate LMI of ``analyze`` (Theorem 1 for given closed loops ``A_s``).

    ``max t`` s.t. ``trace X = n`` and ``[[rho_s X, X A_s], [A_s^T X, X]] - t I >= 0``:
    the ``lmi`` structure with ``free_s = A_s^T`` and no gains, so ``W`` of the result is ``X``.
    ``t* > 0`` iff some ``X > 0`` has ``rho_s X - A_s^T X A_s > 0`` for all s, the same verdict as
    the cvxpy form in solver/lyapunov.py (whose ``t`` bounds only the top-left block, so the
    magnitudes differ; only the sign is used before the float64 re-check).

    Parameters
    ----------
    A : array_like, shape (S, n, n)
    rho : array_like, shape (S,), optional
    options : IPMOptions, optional

    Returns
    -------
    LMISolution
        ``W`` is the certificate candidate X; ``Y`` is empty (shape (0, 0, n)).
    """
    A = np.asarray(A, dtype=np.float64)
    S, n, _ = A.shape
    return solve_lmi(np.swapaxes(A, 1, 2), np.zeros((S, 0, n, 0)), None, rho, options)


# ----------------------------------------------------------------------------- the design methods' hook
def design_solve(modes, kind: str = "lmi", rho=None, time_limit: float | None = None, free=None, coef=None,
                 sign_only: bool | float = False, start: WarmStart | None = None, refute=None):
    """Solve a design method's SDP for a :class:`solver.network.ModeSet` the way ``CompiledProblem.solve`` would.

    The one call solver/methods/lmi.py and switched.py make when ``solver="IPM"``.

    Parameters
    ----------
    modes : solver.network.ModeSet
    kind : {"lmi", "switched"}
    rho : ndarray, shape (S,), optional
    time_limit : float, optional
    free, coef : ndarray, optional
        Replace ``modes.free`` (S, n, n) and ``modes.scheme_coef()[0]`` (S, J, n, m), e.g. by the
        congruent decay-rate form's ``lambda^(-eta_s)``-scaled ones.
    sign_only : bool
        Stop once the sign of the margin is settled (:attr:`IPMOptions.sign_only`; status
        ``"optimal_inaccurate"``): the rate search's probes.
    start : WarmStart, optional
        ``lmi`` only: a warm start (``V = [W, Y]``), e.g. a neighbouring rate's solution.
    refute : callable, optional
        With ``sign_only``: :attr:`IPMOptions.refute`, the caller's Farkas re-check asked inside the solve.

    Returns
    -------
    info : solver.compiled.SolveInfo
        ``status`` in cvxpy's words (``"optimal"``, ``"optimal_inaccurate"``).
    solution : LMISolution or SwitchedSolution

    Raises
    ------
    solver.errors.SolverFailed
        When the iteration ends without an (almost) optimal point.
    """
    from ..compiled import SolveInfo
    from ..errors import SolverFailed

    coef0, active = modes.scheme_coef()
    coef = coef0 if coef is None else coef
    free = modes.free if free is None else free
    if rho is not None and np.all(np.asarray(rho) == 1.0):
        rho = None
    opts = IPMOptions(time_limit=time_limit, sign_only=sign_only, refute=refute)
    warm, start = start, time.perf_counter()
    solve = {"lmi": solve_lmi, "switched": solve_switched}[kind]
    sol = solve(free, coef, active, rho, opts, **({"start": warm} if warm is not None else {}))
    wall = time.perf_counter() - start
    status = {"optimal": "optimal", "inaccurate": "optimal_inaccurate", "feasible": "optimal_inaccurate",
              "infeasible": "optimal_inaccurate"}.get(sol.status)
    if status is None:
        err = SolverFailed(f"IPM ended with status {sol.status!r} after {sol.iterations} iterations "
                           f"(primal residual {sol.primal_residual:.1e}, gap {sol.gap:.1e})", status=sol.status)
        # the last iterate (every block >= t I up to rounding, whatever the status) and its multipliers: the
        # caller may still re-check a design or a Farkas proof from them (solver.methods.common.run_one_shot)
        err.iterate = (SolveInfo(status=sol.status, solver="IPM", solve_time=sol.timings["total"], wall_time=wall,
                                 objective=sol.t, iterations=sol.iterations), sol)
        raise err
    info = SolveInfo(status=status, solver="IPM", solve_time=sol.timings["total"], wall_time=wall,
                     objective=sol.t, iterations=sol.iterations)
    return info, sol


def design_solve_fixed_gain(A, rho=None, time_limit: float | None = None):
    """``(X, t, info)`` of :func:`solve_common_fixed_gain`, as ``solver.lyapunov.common_lmi`` returns them."""
    from ..compiled import SolveInfo
    from ..errors import SolverFailed

    start = time.perf_counter()
    if rho is not None and np.all(np.asarray(rho) == 1.0):
        rho = None
    sol = solve_common_fixed_gain(A, rho, IPMOptions(time_limit=time_limit))
    status = {"optimal": "optimal", "inaccurate": "optimal_inaccurate"}.get(sol.status)
    if status is None:
        raise SolverFailed(f"IPM ended with status {sol.status!r} after {sol.iterations} iterations", status=sol.status)
    info = SolveInfo(status=status, solver="IPM", solve_time=sol.timings["total"],
                     wall_time=time.perf_counter() - start, objective=sol.t, iterations=sol.iterations)
    return sol.W, sol.t, info
