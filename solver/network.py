"""Closed loops of the predictive networked controller over one inter-packet interval.

Between two effective packets ``eta`` samples apart the actuator plays the
buffered inputs ``u(i_m + q - 1) = K_q x(i_m)``.  With the plant mode fixed
over the interval (the paper's model, ``plant_switching="per_interval"``)
this is eq. 8 with the power of F written correctly as ``F^t``::

    x(i_{m+1}) = A_{l,eta}(K) x(i_m),
    A_{l,eta}(K) = F_l^eta + sum_{t=0}^{eta-1} F_l^t G_l K_{eta-t}

When the plant may jump at every sample (``"per_sample"``) a mode is a
sequence of plant indices ``(l_0, ..., l_{eta-1})`` and::

    A_s(K) = F_{l_{eta-1}} ... F_{l_0}
             + sum_{k=0}^{eta-1} F_{l_{eta-1}} ... F_{l_{k+1}} G_{l_k} K_{k+1}

Either way ``A_s(K) = free_s + sum_q coef_{s,q} K_q`` is affine in the gains,
which is all the design methods need.  Baseline schemes restrict the gains
linearly, ``K_q = sum_j M[q, j] Theta_j``: ``"hold"`` (the last input is held,
all K_q equal) and ``"zero"`` (zero input on loss, K_q = 0 for q > 1).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .errors import InvalidInput
from .plant import PlantFamily

#: Default cap on the number of closed-loop modes (r^eta grows fast per sample).
MAX_MODES = 4096

PLANT_SWITCHING = ("per_interval", "per_sample")
SCHEMES = ("predictive", "hold", "zero")


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


def gain_map(scheme: str, n_drop: int) -> np.ndarray:
    """``M`` of shape (n_drop, J) with ``K_q = sum_j M[q-1, j] Theta_j`` for a scheme."""
    if scheme == "predictive":
        return np.eye(n_drop)
    if scheme == "hold":
        return np.ones((n_drop, 1))
    if scheme == "zero":
        return np.eye(n_drop)[:, :1]
    raise InvalidInput(f"scheme must be one of {SCHEMES}, got {scheme!r}", ("scheme",))


def mode_count(n_plants: int, n_drop: int, plant_switching: str) -> int:
    if plant_switching == "per_interval":
        return n_plants * n_drop
    return sum(n_plants**eta for eta in range(1, n_drop + 1))


@dataclass(frozen=True, eq=False)
class ModeSet:
    """Every interval closed loop of a family, as data affine in the gains.

    Attributes
    ----------
    free : ndarray, shape (S, n, n)
        Gain-free part of ``A_s``.
    coef : ndarray, shape (S, n_drop, n, m)
        ``A_s(K) = free_s + sum_q coef[s, q-1] @ K_q``.
    eta : ndarray of int, shape (S,)
        Interval length of each mode (samples).
    plants : tuple of tuple of int
        Plant index of each sample of the interval, per mode.
    n_drop : int
    plant_switching : {"per_interval", "per_sample"}
    scheme : {"predictive", "hold", "zero"}
    gain_map : ndarray, shape (n_drop, J)
    """

    free: np.ndarray
    coef: np.ndarray
    eta: np.ndarray
    plants: tuple
    n_drop: int
    n_plants: int
    plant_switching: str
    scheme: str
    gain_map: np.ndarray
    #: The plant data the modes were built from (r, n, n) and (r, n, m), for solver-independent re-checks.
    F: np.ndarray | None = None
    G: np.ndarray | None = None

    @classmethod
    def from_family(
        cls,
        family: PlantFamily,
        n_drop: int,
        plant_switching: str = "per_interval",
        scheme: str = "predictive",
        max_modes: int = MAX_MODES,
    ) -> "ModeSet":
        n_drop = check_n_drop(n_drop)
        if plant_switching not in PLANT_SWITCHING:
            raise InvalidInput(f"plant_switching must be one of {PLANT_SWITCHING}", ("plant_switching",))
        r, n, m = family.n_modes, family.n_states, family.n_inputs
        count = mode_count(r, n_drop, plant_switching)
        if count > max_modes:  # before gain_map: its n_drop x n_drop map took 0.8 GB at n_drop = 10000
            raise InvalidInput(
                f"{count} closed-loop modes ({plant_switching}, r = {r}, n_drop = {n_drop}) exceed the limit "
                f"of {max_modes}; per-sample switching has sum(r^eta) modes",
                ("n_drop",),
            )
        M = gain_map(scheme, n_drop)
        if plant_switching == "per_interval":
            sequences = [(l,) * eta for l in range(r) for eta in range(1, n_drop + 1)]
        else:
            sequences = [seq for eta in range(1, n_drop + 1) for seq in itertools.product(range(r), repeat=eta)]
        S = len(sequences)
        free = np.empty((S, n, n))
        coef = np.zeros((S, n_drop, n, m))
        for s, seq in enumerate(sequences):
            # Walk the interval backwards: tail = F_{l_{eta-1}} ... F_{l_{k+1}}.
            tail = np.eye(n)
            for k in range(len(seq) - 1, -1, -1):
                coef[s, k] = tail @ family.G[seq[k]]
                tail = tail @ family.F[seq[k]]
            free[s] = tail
        if not (np.all(np.isfinite(free)) and np.all(np.isfinite(coef))):
            raise InvalidInput(f"F^{n_drop} overflows: the plant is too unstable for this n_drop", ("F",))
        return cls(
            free=free,
            coef=coef,
            eta=np.array([len(seq) for seq in sequences]),
            plants=tuple(sequences),
            n_drop=n_drop,
            n_plants=r,
            plant_switching=plant_switching,
            scheme=scheme,
            gain_map=M,
            F=np.array(family.F, dtype=np.float64),
            G=np.array(family.G, dtype=np.float64),
        )

    # ------------------------------------------------------------------ sizes
    @property
    def n_modes(self) -> int:
        return self.free.shape[0]

    @property
    def n_states(self) -> int:
        return self.free.shape[1]

    @property
    def n_inputs(self) -> int:
        return self.coef.shape[3]

    @property
    def n_free_gains(self) -> int:
        """J: independent gain matrices of the scheme."""
        return self.gain_map.shape[1]

    # ------------------------------------------------------- scheme gains
    def scheme_coef(self) -> tuple[np.ndarray, np.ndarray]:
        """Coefficients of the scheme's free gains and their structural support.

        Returns
        -------
        coef : ndarray, shape (S, J, n, m)
            ``A_s = free_s + sum_j coef[s, j] @ Theta_j``.
        active : ndarray of bool, shape (S, J)
            Which terms can be nonzero (the rest are left out of the SDPs).
        """
        coef = np.einsum("sqab,qj->sjab", self.coef, self.gain_map)
        support = np.arange(1, self.n_drop + 1)[None, :] <= self.eta[:, None]  # K_q acts only for q <= eta
        active = (support.astype(float) @ (self.gain_map != 0)) > 0
        return coef, active

    def expand(self, theta: np.ndarray) -> np.ndarray:
        """Full gains ``K`` (n_drop, m, n) from the scheme's free gains ``theta`` (J, m, n)."""
        return np.einsum("qj,jab->qab", self.gain_map, theta)

    def shape_key(self) -> tuple:
        """Everything that changes the structure of an SDP built on this mode set."""
        _, active = self.scheme_coef()
        return (self.n_states, self.n_inputs, self.n_modes, self.n_free_gains, active.tobytes())

    # ----------------------------------------------------------- closed loops
    def closed_loops(self, gains: np.ndarray) -> np.ndarray:
        """``A_s(K)`` for every mode, shape (S, n, n)."""
        return self.free + np.einsum("sqab,qbc->sac", self.coef, gains)

    def reshape_per_mode(self, values: np.ndarray):
        """(r, n_drop) array for per-interval mode sets (the paper's (l, eta) grid); flat otherwise."""
        if self.plant_switching == "per_interval":
            return values.reshape(self.n_plants, self.n_drop)
        return values

    def label(self, s: int) -> dict:
        """JSON-able description of mode s."""
        seq = self.plants[s]
        if self.plant_switching == "per_interval":
            return {"plant": seq[0], "eta": len(seq)}
        return {"plants": list(seq), "eta": len(seq)}


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


def augmented_matrices(A: np.ndarray, n_drop: int) -> np.ndarray:
    """Augmented closed loops ``Phi_s`` (eq. 10) from ``A_s``.

    Parameters
    ----------
    A : ndarray, shape (..., n, n)
    n_drop : int

    Returns
    -------
    ndarray, shape (..., n*n_drop, n*n_drop)
        Top-left block ``A_s``, identities on the block sub-diagonal.
    """
    n = A.shape[-1]
    Phi = np.zeros(A.shape[:-2] + (n * n_drop, n * n_drop))
    Phi[..., :n, :n] = A
    for j in range(1, n_drop):
        Phi[..., j * n:(j + 1) * n, (j - 1) * n:j * n] = np.eye(n)
    return Phi


def spectral_radii(A: np.ndarray) -> np.ndarray:
    """Spectral radius of every matrix in a stack, shape ``A.shape[:-2]``."""
    return np.max(np.abs(np.linalg.eigvals(A)), axis=-1)
