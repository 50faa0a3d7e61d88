"""Lyapunov certificates for the interval closed loops, and their float64 re-check.

Theorem 1 asks for ``P > 0`` of size n*n_drop with
``Phi_s^T P Phi_s - P < 0`` for every mode s.  Because Phi_s is block lower
triangular with diagonal blocks (A_s, 0, ..., 0), this holds iff an n x n
``X > 0`` has ``A_s^T X A_s - X < 0`` for all s (docs/design.md §3.1): from X
one builds ``P = blkdiag(X, a_1 I, ..., a_{N-1} I)`` with
``a_j = mu (N - j) / N`` where ``mu = min_s lambda_min(X - A_s^T X A_s)``.

Mode-dependent ("switched") certificates are ``P_s > 0`` with
``A_s^T P_t A_s - P_s < 0`` for all pairs (s, t): ``V = x^T P_s x`` where s is
the mode of the interval about to start (Daafouz, Riedinger, Iung 2002).

A decay claim with per-sample rate lambda replaces ``P_s`` on the right by
``rho_s P_s`` with ``rho_s = lambda^(2 eta_s)``.

Whatever produced a certificate, the ``recheck_*`` functions test it against
the original condition with ``numpy.linalg.eigvalsh``; a result is called
certified only when that re-check passes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .compiled import cp  # cvxpy, imported on first use
from .compiled import CompiledProblem, SolveInfo, block, problem_cache, resolve_solver, schur_block
from .errors import SolverFailed
from .network import augmented_matrices

#: Smallest relative decrease ``lambda_min(decrease) / lambda_max(P)`` accepted by the
#: float64 re-check: far above double rounding, far below what a solver tolerance leaves.
RECHECK_TOL = 1e-9


def _sym(M):
    return 0.5 * (M + np.swapaxes(M, -1, -2))


@dataclass
class Certificate:
    """A Lyapunov certificate, re-checked in float64.

    Attributes
    ----------
    kind : {"common_quadratic", "switched"}
    P : ndarray
        ``common_quadratic``: the augmented Theorem 1 matrix, shape (n*n_drop, n*n_drop).
        ``switched``: one matrix per mode, shape (S, n, n).
    X : ndarray, shape (n, n), or None
        The reduced common certificate on x(i_m) (``common_quadratic``).
    min_eig_P : float
        Smallest eigenvalue over all matrices re-checked (must be > 0): X when the reduced
        form was re-checked (:func:`recheck_lifted`), else P.
    decrease : float
        Smallest eigenvalue of the decrease matrices (absolute) of the re-checked form.
    margin : float
        ``decrease / lambda_max`` of the re-checked matrix.
    verified : bool
        True iff the float64 re-check passed (or, ``exact``, the exact one).
    source : str
        What produced P (``"lmi"``, ``"switched"``, ``"ccl_iterate"``, ``"theorem1_lmi"``, ``"switched_lmi"``).
    decay_rate : float or None
        Per-sample rate lambda the certificate also proves (``|x(i_m)|`` in its norm
        shrinks by ``lambda^eta`` per interval), when one was asked for.
    worst_mode : int or None
        Index of the mode with the smallest decrease.
    """

    kind: str
    P: np.ndarray
    X: np.ndarray | None
    min_eig_P: float
    decrease: float
    margin: float
    verified: bool
    source: str
    decay_rate: float | None = None
    worst_mode: int | None = field(default=None)
    #: True when ``verified`` comes from the exact re-check (:func:`recheck_lifted_exact`), not the float64 one.
    exact: bool = False

    def to_dict(self) -> dict:
        mats = self.P if self.kind == "switched" else self.P[None]
        return {
            "kind": self.kind,
            "source": self.source,
            "verified": self.verified,
            "margin": self.margin,
            "decrease": self.decrease,
            "min_eig_P": self.min_eig_P,
            "condition_number": float(max(np.linalg.cond(M) for M in mats)),
            "decay_rate": self.decay_rate,
            "worst_mode": self.worst_mode,
            "exact": self.exact,
            "P": self.P.tolist(),
            "X": None if self.X is None else self.X.tolist(),
        }


def _verdict(eig_P_min: float, eig_P_max: float, decrease: np.ndarray) -> tuple[float, float, bool, int]:
    worst = int(np.argmin(decrease))
    dec = float(decrease.flat[worst])
    margin = dec / eig_P_max if eig_P_max > 0 else -np.inf
    return dec, float(margin), bool(eig_P_min > 0 and margin > RECHECK_TOL), worst


def recheck_common(P: np.ndarray, A: np.ndarray, n_drop: int, source: str, X: np.ndarray | None = None) -> Certificate:
    """Re-check an augmented Theorem 1 certificate: ``P > 0``, ``Phi_s^T P Phi_s - P < 0`` for all s.

    Parameters
    ----------
    P : ndarray, shape (n*n_drop, n*n_drop)
    A : ndarray, shape (S, n, n)
        Interval closed loops for the gains being certified.
    """
    P = _sym(P)
    Phi = augmented_matrices(A, n_drop)
    eig_P = np.linalg.eigvalsh(P)
    decrease = np.linalg.eigvalsh(_sym(P - np.swapaxes(Phi, -1, -2) @ P @ Phi))[..., 0]
    dec, margin, ok, worst = _verdict(eig_P[0], eig_P[-1], decrease)
    return Certificate("common_quadratic", P, X, float(eig_P[0]), dec, margin, ok, source, worst_mode=worst)


def recheck_switched(P: np.ndarray, A: np.ndarray, source: str, rho: np.ndarray | None = None) -> Certificate:
    """Re-check a mode-dependent certificate: ``P_s > 0``, ``A_s^T P_t A_s - rho_s P_s < 0`` for all s, t.

    Parameters
    ----------
    P : ndarray, shape (S, n, n)
    A : ndarray, shape (S, n, n)
    rho : ndarray, shape (S,), optional
        Decay factors (1 for plain stability).
    """
    P = _sym(P)
    S = A.shape[0]
    rho = np.ones(S) if rho is None else rho
    eig_P = np.linalg.eigvalsh(P)
    At = np.swapaxes(A, -1, -2)
    # pairs (s, t): rho_s P_s - A_s^T P_t A_s, shape (S, S, n, n)
    diff = rho[:, None, None, None] * P[:, None] - At[:, None] @ P[None, :] @ A[:, None]
    decrease = np.linalg.eigvalsh(_sym(diff))[..., 0].min(axis=1)
    dec, margin, ok, worst = _verdict(eig_P[:, 0].min(), eig_P[:, -1].max(), decrease)
    return Certificate("switched", P, None, float(eig_P[:, 0].min()), dec, margin, ok, source, worst_mode=worst)


def recheck_common_reduced(X: np.ndarray, A: np.ndarray, rho: np.ndarray, source: str) -> Certificate:
    """Re-check ``X > 0``, ``A_s^T X A_s - rho_s X < 0`` (the decay claim on x(i_m))."""
    X = _sym(X)
    eig_X = np.linalg.eigvalsh(X)
    decrease = np.linalg.eigvalsh(_sym(rho[:, None, None] * X - np.swapaxes(A, -1, -2) @ X @ A))[..., 0]
    dec, margin, ok, worst = _verdict(eig_X[0], eig_X[-1], decrease)
    return Certificate("common_quadratic", X, X, float(eig_X[0]), dec, margin, ok, source, worst_mode=worst)


def recheck_lifted(X: np.ndarray, A: np.ndarray, n_drop: int, source: str,
                   rho: np.ndarray | None = None) -> Certificate:
    """Re-check a reduced common certificate once, and attach its augmented Theorem 1 matrix.

    The float64 re-check runs on the n x n condition ``X > 0``, ``rho_s X - A_s^T X A_s > 0``
    (``rho_s = 1`` without a decay rate): docs/design.md §3.1 proves it equivalent to Theorem 1 for
    the augmented loop, whose ``P = lift(X)`` is returned in ``cert.P`` (``rho_s <= 1``, so the plain
    decrease holds too).  Re-checking the augmented ``n n_drop``-sided P instead costs
    ``n_drop^3`` times more and proves nothing more.

    Parameters
    ----------
    X : ndarray, shape (n, n)
    A : ndarray, shape (S, n, n)
    rho : ndarray, shape (S,), optional
        Decay factors ``lambda^(2 eta_s)`` (ones for plain stability).
    """
    rho = np.ones(A.shape[0]) if rho is None else np.asarray(rho, dtype=float)
    cert = recheck_common_reduced(X, A, rho, source)
    if cert.verified and n_drop > 1:
        cert.P = lift(cert.X, A, n_drop)
    return cert


#: Largest state dimension for which :func:`recheck_lifted_exact` is tried (as ``brackets.EXACT_COST_MAX_N``).
EXACT_MAX_N = 8


def recheck_lifted_exact(X: np.ndarray, A: np.ndarray, F: np.ndarray, G: np.ndarray, gains: np.ndarray, plants,
                         n_drop: int, source: str) -> Certificate:
    """The re-check of :func:`recheck_lifted` (no decay rate) decided exactly where float64 cannot.

    ``X > 0`` and ``X - A_s' X A_s > 0`` in exact arithmetic on the float64 numbers, ``A_s`` the interval maps
    computed exactly from ``F`` (r, n, n), ``G`` (r, n, m) and ``gains`` (n_drop, m, n) along ``plants[s]``
    (:func:`solver.exact.lyapunov_decrease`): no rounding allowance, so a relative margin far below
    :data:`RECHECK_TOL` (1e-11 where X spans 1e11: a nearly unreachable unstable mode, docs/design.md §8.5) is
    decided.  ``A`` (S, n, n), the float64 loops, give ``margin`` and ``decrease`` as estimates (for the
    message); ``verified`` is the exact verdict and ``exact`` is set.  Small n only (:data:`EXACT_MAX_N`).
    """
    from .exact import lyapunov_decrease

    X = _sym(np.asarray(X, dtype=np.float64))
    cert = recheck_common_reduced(X, A, np.ones(A.shape[0]), source)
    cert.exact = True
    cert.verified = bool(X.shape[0] <= EXACT_MAX_N and lyapunov_decrease(X, F, G, gains, plants))
    if cert.verified and n_drop > 1:
        # the augmented P needs a decrease mu > 0 (its blocks a_j = mu (N - j) / N); float64 cannot see this one's
        # (it may compute mu <= 0: P = blkdiag(X, 0, ...) is singular), so mu is one the exact check confirms
        scale = float(np.max(np.abs(np.linalg.eigvalsh(X))))
        mu = next((v for v in (max(cert.decrease, 0.0), *(scale * 16.0 ** -k for k in range(4, 20)))
                   if v > 0 and lyapunov_decrease(X, F, G, gains, plants, shift=v)), None)
        if mu is None:
            cert.verified = False
        else:
            cert.P = lift(cert.X, A, n_drop, mu=mu)
    return cert


def lift(X: np.ndarray, A: np.ndarray, n_drop: int, mu: float | None = None) -> np.ndarray:
    """Augmented ``P = blkdiag(X, a_1 I, ..., a_{N-1} I)`` from a reduced certificate X.

    ``mu``: a lower bound of the decrease ``lambda_min(X - A_s' X A_s)`` (default: its float64 estimate).
    Returns a matrix even when X certifies nothing; :func:`recheck_common` decides.
    """
    n = A.shape[-1]
    X = _sym(X)
    if mu is None:
        mu = float(np.min(np.linalg.eigvalsh(_sym(X - np.swapaxes(A, -1, -2) @ X @ A))[..., 0]))
    P = np.zeros((n * n_drop, n * n_drop))
    P[:n, :n] = X
    for j in range(1, n_drop):
        P[j * n:(j + 1) * n, j * n:(j + 1) * n] = max(mu, 0.0) * (n_drop - j) / n_drop * np.eye(n)
    return P


# ---------------------------------------------------------------------- LMIs for fixed gains
def _build_common(n: int, S: int) -> CompiledProblem:
    X = cp.Variable((n, n), symmetric=True)
    t = cp.Variable()
    A = cp.Parameter((S * n, n))  # row block s: A_s
    rho = cp.Parameter(S, nonneg=True)
    eye = np.eye(n)
    cons = [X >> t * eye, cp.trace(X) == n]
    for s in range(S):
        # Schur form of rho_s X - A^T X A >= t I: linear in X for a given A (DPP).
        cons.append(schur_block(rho[s] * X - t * eye, X @ block(A, s, n), X) >> 0)
    return CompiledProblem(cp.Problem(cp.Maximize(t), cons), {"A": A, "rho": rho}, {"X": X, "t": t})


def _build_switched(n: int, S: int) -> CompiledProblem:
    P = [cp.Variable((n, n), symmetric=True) for _ in range(S)]
    t = cp.Variable()
    A = cp.Parameter((S * n, n))
    rho = cp.Parameter(S, nonneg=True)
    eye = np.eye(n)
    cons = [sum(cp.trace(Ps) for Ps in P) == S * n]
    cons += [Ps >> t * eye for Ps in P]
    for s in range(S):
        for u in range(S):
            # rho_s P_s - A_s^T P_u A_s >= t I in Schur form
            cons.append(schur_block(rho[s] * P[s] - t * eye, P[u] @ block(A, s, n), P[u]) >> 0)
    return CompiledProblem(cp.Problem(cp.Maximize(t), cons), {"A": A, "rho": rho}, {"P": P, "t": t})


#: Largest mode count for which the pairwise switched LMI (S^2 blocks) is attempted.
MAX_SWITCHED_MODES = 64


def _solve_fixed_gain(kind: str, A: np.ndarray, rho, solver: str, time_limit) -> tuple[CompiledProblem, SolveInfo]:
    """Solve the cached fixed-gain LMI of a kind for closed loops A (S, n, n) and decay factors rho."""
    S, n, _ = A.shape
    builder = {"common_lmi": _build_common, "switched_lmi": _build_switched}[kind]
    compiled, _ = problem_cache.lookup((kind, n, S), lambda: builder(n, S))
    info = compiled.solve({"A": A.reshape(S * n, n), "rho": np.ones(S) if rho is None else rho},
                          solver=solver, time_limit=time_limit)
    return compiled, info


def common_lmi(A: np.ndarray, rho: np.ndarray | None = None, solver: str = "AUTO", time_limit=None):
    """Best-margin common quadratic certificate for fixed gains (Theorem 1 as an LMI).

    Solves ``max t`` s.t. ``rho_s X - A_s^T X A_s >= t I``, ``X >= t I``, ``trace X = n``;
    ``t > 0`` iff a certificate exists.

    Parameters
    ----------
    A : ndarray, shape (S, n, n)
    rho : ndarray, shape (S,), optional
        Decay factors (default 1).

    Returns
    -------
    X : ndarray, shape (n, n)
    t : float
    info : SolveInfo
    """
    if resolve_solver(solver, "common_lmi") == "IPM":  # solver/ipm/; its t bounds the whole block: only its sign compares
        from .ipm import design_solve_fixed_gain

        return design_solve_fixed_gain(A, rho, time_limit)
    compiled, info = _solve_fixed_gain("common_lmi", A, rho, solver, time_limit)
    return compiled.value("X"), float(compiled.value("t")), info


def switched_lmi(A: np.ndarray, rho: np.ndarray | None = None, solver: str = "AUTO", time_limit=None):
    """Best-margin mode-dependent certificate for fixed gains.

    Solves ``max t`` s.t. ``rho_s P_s - A_s^T P_u A_s >= t I`` for all pairs,
    ``P_s >= t I``, ``sum_s trace P_s = S n``.

    Returns
    -------
    P : ndarray, shape (S, n, n)
    t : float
    info : SolveInfo
    """
    compiled, info = _solve_fixed_gain("switched_lmi", A, rho, solver, time_limit)
    return np.stack(compiled.value("P")), float(compiled.value("t")), info


def certify(A: np.ndarray, n_drop: int, kinds=("common_quadratic", "switched"), solver="AUTO",
            time_limit=None, on_solve: Callable | None = None, rho: np.ndarray | None = None) -> Certificate | None:
    """A verified stability certificate for fixed closed loops, trying the kinds in order.

    The switched kind is skipped above :data:`MAX_SWITCHED_MODES` modes.  ``rho`` (S,): decay factors
    ``lambda^(2 eta_s)`` the certificate must prove (default: plain stability).
    """
    for kind in kinds:
        if kind == "common_quadratic":
            X, t, info = common_lmi(A, rho=rho, solver=solver, time_limit=time_limit)
            if on_solve:
                on_solve(info)
            if t > 0:
                cert = recheck_lifted(X, A, n_drop, "theorem1_lmi", rho=rho)
                if cert.verified:
                    return cert
        elif kind == "switched" and A.shape[0] <= MAX_SWITCHED_MODES:
            P, t, info = switched_lmi(A, rho=rho, solver=solver, time_limit=time_limit)
            if on_solve:
                on_solve(info)
            if t > 0:
                cert = recheck_switched(P, A, "switched_lmi", rho=rho)
                if cert.verified:
                    return cert
    return None


def bisect_rate(feasible: Callable[[float], object], lo: float, hi: float, tol: float):
    """Smallest lambda in (lo, hi] with ``feasible(lambda)`` truthy, to tolerance ``tol``.

    ``feasible`` returns a certificate-like object or None and is assumed
    monotone (feasible at lambda implies feasible above).  Returns
    ``(lambda, evidence, tried)`` with ``tried`` the list of (lambda, ok);
    ``(None, None, tried)`` when even ``hi`` fails.
    """
    tried = []
    best = feasible(hi)
    tried.append((hi, best is not None))
    if best is None:
        return None, None, tried
    best_rate = hi
    while best_rate - lo > tol:
        mid = 0.5 * (lo + best_rate)
        evidence = feasible(mid)
        tried.append((mid, evidence is not None))
        if evidence is None:
            lo = mid
        else:
            best_rate, best = mid, evidence
    return best_rate, best, tried


def certified_rate(A: np.ndarray, eta: np.ndarray, kind: str = "common_quadratic", per: str = "sample",
                   hi: float = 1.0, tol: float = 1e-3, solver: str = "AUTO"):
    """Smallest certified rate for fixed closed loops, by bisection.

    Parameters
    ----------
    A : ndarray, shape (S, n, n)
    eta : ndarray of int, shape (S,)
    kind : {"common_quadratic", "switched"}
    per : {"sample", "interval"}
        ``"sample"``: ``A_s^T P A_s <= lambda^(2 eta_s) P`` (decay per sample);
        ``"interval"``: ``<= lambda^2 P`` (an upper bound of the joint spectral
        radius of the interval maps).
    hi : float
        Upper end of the search.

    Returns
    -------
    rate : float or None
    certificate : Certificate or None
        Re-checked for the decay claim at ``rate``.
    """
    radii = np.max(np.abs(np.linalg.eigvals(A)), axis=-1)
    powers = eta if per == "sample" else np.ones_like(eta)
    lo = float(np.max(radii ** (1.0 / powers)))  # no certificate can beat a mode's own radius

    def feasible(lam):
        rho = lam ** (2.0 * powers)
        try:
            if kind == "common_quadratic":
                X, t, _ = common_lmi(A, rho, solver=solver)
                cert = recheck_common_reduced(X, A, rho, "rate_bisection") if t > 0 else None
            else:
                P, t, _ = switched_lmi(A, rho, solver=solver)
                cert = recheck_switched(P, A, "rate_bisection", rho=rho) if t > 0 else None
        except SolverFailed:
            return None
        if cert is None or not cert.verified:
            return None
        cert.decay_rate = float(lam)
        return cert

    if lo >= hi:
        return None, None
    rate, cert, _ = bisect_rate(feasible, lo, hi, tol)
    return rate, cert
