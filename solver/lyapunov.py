"""Lyapunov certificates for the interval closed loops, and their float64 re-check.

Theorem 1 asks for ``P > 0`` of size n*n_drop with
``Phi_s^T P Phi_s - P < 0`` for every mode s = (l, eta).  Because Phi_s is
block lower triangular with diagonal blocks (A_s, 0, ..., 0), this holds iff
an n x n ``X > 0`` has ``A_s^T X A_s - X < 0`` for all s (DESIGN.md section 3):
from X one builds ``P = blkdiag(X, a_1 I, ..., a_{N-1} I)`` with
``a_j = mu (N - j) / N`` where ``mu = min_s lambda_min(X - A_s^T X A_s)``.

Whatever produced a certificate, :func:`recheck` tests the *augmented* P
against the original condition with ``numpy.linalg.eigvalsh``; a result is
called certified only when that re-check passes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np

from .compiled import CompiledProblem, SolveInfo, block, problem_cache, schur_block
from .network import augmented_matrices

#: Smallest relative decrease ``lambda_min(P - Phi^T P Phi) / lambda_max(P)``
#: accepted by the float64 re-check.  Far above double rounding (~1e-16 times
#: the norms involved) and far below what a solver tolerance of 1e-8 leaves.
RECHECK_TOL = 1e-9


@dataclass
class Certificate:
    """A quadratic Lyapunov certificate ``V(Gamma) = Gamma^T P Gamma`` for the augmented loop.

    Attributes
    ----------
    P : ndarray, shape (n*n_drop, n*n_drop)
        Certificate of Theorem 1 for the augmented state.
    X : ndarray, shape (n, n) or None
        The reduced certificate on x(i_m) when P was lifted from one.
    min_eig_P : float
        ``lambda_min(P)`` (must be > 0).
    decrease : float
        ``min_s lambda_min(P - Phi_s^T P Phi_s)``, absolute.
    margin : float
        ``decrease / lambda_max(P)``: relative decrease per interval.
    verified : bool
        True iff the float64 re-check passed (``min_eig_P > 0`` and
        ``margin > RECHECK_TOL``).
    source : str
        What produced P: ``"lmi"``, ``"ccl_iterate"`` or ``"theorem1_lmi"``.
    kind : str
        ``"common_quadratic"``.
    """

    P: np.ndarray
    X: np.ndarray | None
    min_eig_P: float
    decrease: float
    margin: float
    verified: bool
    source: str
    kind: str = "common_quadratic"
    worst_mode: tuple[int, int] | None = field(default=None)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "source": self.source,
            "verified": self.verified,
            "margin": self.margin,
            "decrease": self.decrease,
            "min_eig_P": self.min_eig_P,
            "condition_number": float(np.linalg.cond(self.P)),
            "worst_mode": list(self.worst_mode) if self.worst_mode else None,
            "P": self.P.tolist(),
            "X": None if self.X is None else self.X.tolist(),
        }


def recheck(P: np.ndarray, A: np.ndarray, source: str, X: np.ndarray | None = None) -> Certificate:
    """Re-check an augmented certificate against Theorem 1 in float64.

    Parameters
    ----------
    P : ndarray, shape (n*n_drop, n*n_drop)
    A : ndarray, shape (r, n_drop, n, n)
        Interval closed loops for the gains being certified.
    source : str
    X : ndarray, optional
        Reduced certificate P was lifted from (reported only).
    """
    P = 0.5 * (P + P.T)
    Phi = augmented_matrices(A)
    eig_P = np.linalg.eigvalsh(P)
    diff = P - np.swapaxes(Phi, -1, -2) @ P @ Phi
    diff = 0.5 * (diff + np.swapaxes(diff, -1, -2))
    mins = np.linalg.eigvalsh(diff)[..., 0]  # (r, n_drop)
    worst = np.unravel_index(np.argmin(mins), mins.shape)
    decrease = float(mins[worst])
    margin = decrease / float(eig_P[-1]) if eig_P[-1] > 0 else -np.inf
    verified = bool(eig_P[0] > 0 and margin > RECHECK_TOL)
    return Certificate(
        P=P,
        X=X,
        min_eig_P=float(eig_P[0]),
        decrease=decrease,
        margin=float(margin),
        verified=verified,
        source=source,
        worst_mode=(int(worst[0]), int(worst[1]) + 1),
    )


def lift(X: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Augmented ``P = blkdiag(X, a_1 I, ..., a_{N-1} I)`` from a reduced certificate X.

    Returns a matrix even when X certifies nothing; :func:`recheck` decides.
    """
    r, N, n, _ = A.shape
    X = 0.5 * (X + X.T)
    decrease = X - np.swapaxes(A, -1, -2) @ X @ A
    mu = float(np.min(np.linalg.eigvalsh(0.5 * (decrease + np.swapaxes(decrease, -1, -2)))[..., 0]))
    P = np.zeros((n * N, n * N))
    P[:n, :n] = X
    for j in range(1, N):
        P[j * n:(j + 1) * n, j * n:(j + 1) * n] = max(mu, 0.0) * (N - j) / N * np.eye(n)
    return P


def _build_theorem1(n: int, n_modes: int) -> CompiledProblem:
    X = cp.Variable((n, n), symmetric=True)
    t = cp.Variable()
    A = cp.Parameter((n_modes * n, n))  # row block s: A_s
    eye = np.eye(n)
    cons = [X >> t * eye, cp.trace(X) == n]
    for s in range(n_modes):
        # Schur form of X - A^T X A >= t I: linear in X for a given A (DPP).
        cons.append(schur_block(X - t * eye, X @ block(A, s, n), X) >> 0)
    prob = cp.Problem(cp.Maximize(t), cons)
    return CompiledProblem(prob, {"A": A}, {"X": X, "t": t})


def theorem1_lmi(A: np.ndarray, solver: str = "CLARABEL", time_limit: float | None = None):
    """Best-margin common quadratic certificate for fixed gains (Theorem 1 as an LMI).

    Solves ``max t`` s.t. ``X - A_s^T X A_s >= t I``, ``X >= t I``, ``trace X = n``.
    ``t > 0`` iff Theorem 1 holds for these gains.

    Parameters
    ----------
    A : ndarray, shape (r, n_drop, n, n)

    Returns
    -------
    X : ndarray, shape (n, n)
    t : float
    info : SolveInfo
    """
    r, N, n, _ = A.shape
    compiled, _ = problem_cache.get(("theorem1", n, r * N), lambda: _build_theorem1(n, r * N))
    info: SolveInfo = compiled.solve({"A": A.reshape(r * N * n, n)}, solver=solver, time_limit=time_limit)
    return compiled.value("X"), float(compiled.value("t")), info
