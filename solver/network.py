"""Closed loops of the predictive networked controller over one inter-packet interval.

Between two effective packets ``eta`` samples apart the actuator plays the
buffered inputs ``u(i_m + q - 1) = K_q x(i_m)``, so (eq. 8, with the power of
F written correctly as ``F^t``)::

    x(i_{m+1}) = A_{l,eta}(K) x(i_m),
    A_{l,eta}(K) = F_l^eta + sum_{t=0}^{eta-1} F_l^t G_l K_{eta-t}

which is affine in the gains.  Modes are the pairs (l, eta), l = 0..r-1
(plant index, 0-based as in the family's lists) and eta = 1..n_drop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InvalidInput
from .plant import PlantFamily

#: Refuse problems whose mode count would make every method crawl.
MAX_MODES = 4096


def check_n_drop(n_drop) -> int:
    """Validate the drop bound (an integer >= 1: at most n_drop - 1 consecutive losses)."""
    if isinstance(n_drop, bool) or not isinstance(n_drop, (int, np.integer)):
        if isinstance(n_drop, float) and float(n_drop).is_integer():
            n_drop = int(n_drop)
        else:
            raise InvalidInput(f"n_drop must be an integer >= 1, got {n_drop!r}", ("n_drop",))
    n_drop = int(n_drop)
    if n_drop < 1:
        raise InvalidInput(f"n_drop must be >= 1, got {n_drop}", ("n_drop",))
    return n_drop


@dataclass(frozen=True)
class IntervalData:
    """Gain-independent pieces of every interval closed loop.

    Attributes
    ----------
    F_pow : ndarray, shape (r, n_drop, n, n)
        ``F_pow[l, eta-1] = F_l^eta``.
    FtG : ndarray, shape (r, n_drop, n, m)
        ``FtG[l, t] = F_l^t G_l`` for t = 0..n_drop-1.
    """

    F_pow: np.ndarray
    FtG: np.ndarray

    @property
    def n_drop(self) -> int:
        return self.F_pow.shape[1]

    @classmethod
    def from_family(cls, family: PlantFamily, n_drop: int) -> "IntervalData":
        n_drop = check_n_drop(n_drop)
        r, n, m = family.n_modes, family.n_states, family.n_inputs
        if r * n_drop > MAX_MODES:
            raise InvalidInput(
                f"r * n_drop = {r * n_drop} closed-loop modes exceeds the limit {MAX_MODES}", ("n_drop",)
            )
        F_pow = np.empty((r, n_drop, n, n))
        FtG = np.empty((r, n_drop, n, m))
        for l in range(r):
            power = np.eye(n)
            for t in range(n_drop):
                FtG[l, t] = power @ family.G[l]
                power = power @ family.F[l]
                F_pow[l, t] = power
        if not (np.all(np.isfinite(F_pow)) and np.all(np.isfinite(FtG))):
            raise InvalidInput(f"F^{n_drop} overflows: the plant is too unstable for this n_drop", ("F",))
        return cls(F_pow=F_pow, FtG=FtG)


def check_gains(gains, n_drop: int, n_inputs: int, n_states: int) -> np.ndarray:
    """Return gains as a float64 array of shape (n_drop, m, n), K_1 first."""
    try:
        K = np.array(gains, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInput("gains must be a list of numeric m x n matrices", ("gains",)) from None
    if n_inputs == 1 and K.ndim == 2 and K.shape == (n_drop, n_states):
        K = K.reshape(n_drop, 1, n_states)
    if K.shape != (n_drop, n_inputs, n_states):
        raise InvalidInput(
            f"gains must have shape (n_drop, m, n) = {(n_drop, n_inputs, n_states)}, got {K.shape}", ("gains",)
        )
    if not np.all(np.isfinite(K)):
        raise InvalidInput("gains have NaN or infinite entries", ("gains",))
    return K


def mode_list(n_plants: int, n_drop: int) -> list[tuple[int, int]]:
    """All closed-loop modes (l, eta) in the order used by every array here: l major, eta minor."""
    return [(l, eta) for l in range(n_plants) for eta in range(1, n_drop + 1)]


def closed_loop_matrices(data: IntervalData, gains: np.ndarray) -> np.ndarray:
    """Interval closed loops ``A_{l,eta}(K)`` (eq. 8).

    Parameters
    ----------
    data : IntervalData
    gains : ndarray, shape (n_drop, m, n)

    Returns
    -------
    ndarray, shape (r, n_drop, n, n)
    """
    r, N = data.F_pow.shape[:2]
    A = data.F_pow.copy()
    for eta in range(1, N + 1):
        for t in range(eta):
            # F^t G K_{eta-t}; gains[q-1] is K_q
            A[:, eta - 1] += data.FtG[:, t] @ gains[eta - t - 1]
    return A


def augmented_matrices(A: np.ndarray) -> np.ndarray:
    """Augmented closed loops ``Phi_{l,eta}`` (eq. 10) from ``A_{l,eta}``.

    Parameters
    ----------
    A : ndarray, shape (r, n_drop, n, n)

    Returns
    -------
    ndarray, shape (r, n_drop, n*n_drop, n*n_drop)
        Top-left block ``A_{l,eta}``, identities on the block sub-diagonal.
    """
    r, N, n, _ = A.shape
    Phi = np.zeros((r, N, n * N, n * N))
    Phi[:, :, :n, :n] = A
    for j in range(1, N):
        Phi[:, :, j * n:(j + 1) * n, (j - 1) * n:j * n] = np.eye(n)
    return Phi


def spectral_radii(A: np.ndarray) -> np.ndarray:
    """Spectral radius of every mode, shape (r, n_drop)."""
    return np.max(np.abs(np.linalg.eigvals(A)), axis=-1)
