"""Switched plant families ``x(k+1) = F_l x(k) + G_l u(k)``, l = 1..r (eq. 1).

A family is stored in discrete time.  Continuous families (eq. 2) are
discretized by the exact zero-order hold of eq. 3::

    expm([[A, B], [0, 0]] * h) = [[F, G], [0, I]]
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.linalg

from .errors import InvalidInput

# Eq. 19 of the paper (the matrices its eq. 20 and its results are built on).
# Table I's parameters give a different A for J = 0.03 (see README): the paper
# example reproduces the paper, the DC motor builder follows the physics.
_PAPER_A = (
    [[-4.0, -0.03], [0.5, -6.667]],
    [[-4.0, -0.03], [0.75, -10.0]],
    [[-4.0, -0.03], [1.5, -20.0]],
)
_PAPER_B = ([[2.0], [0.0]],) * 3


def _matrix_list(name: str, mats, ndim_cols: int | None = None) -> list[np.ndarray]:
    """Convert a list of matrices to float64 arrays, naming the bad one on error."""
    if isinstance(mats, np.ndarray):
        if mats.ndim == 2:
            raise InvalidInput(f"{name} must be a list of matrices, one per plant mode", (name,))
        mats = list(mats)
    if not isinstance(mats, (list, tuple)) or len(mats) == 0:
        raise InvalidInput(f"{name} must be a non-empty list of matrices, one per plant mode", (name,))
    out = []
    for i, mat in enumerate(mats):
        try:
            arr = np.array(mat, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidInput(f"{name}[{i}] is not a numeric matrix", (name, i)) from None
        if arr.ndim == 1 and ndim_cols == 1:
            arr = arr.reshape(-1, 1)
        if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
            raise InvalidInput(f"{name}[{i}] must be a non-empty 2-D matrix, got shape {arr.shape}", (name, i))
        if not np.all(np.isfinite(arr)):
            raise InvalidInput(f"{name}[{i}] has NaN or infinite entries", (name, i))
        out.append(arr)
    return out


def _check_family(Fs, Gs, fname: str, gname: str) -> tuple[int, int]:
    if len(Fs) != len(Gs):
        raise InvalidInput(
            f"{fname} has {len(Fs)} modes but {gname} has {len(Gs)}; give one pair per plant mode", (gname,)
        )
    n = Fs[0].shape[0]
    m = Gs[0].shape[1]
    for i, (Fi, Gi) in enumerate(zip(Fs, Gs)):
        if Fi.shape[0] != Fi.shape[1]:
            raise InvalidInput(f"{fname}[{i}] must be square, got shape {Fi.shape}", (fname, i))
        if Fi.shape != (n, n):
            raise InvalidInput(
                f"{fname}[{i}] has shape {Fi.shape} but mode 0 has {(n, n)}: all modes need the same state size",
                (fname, i),
            )
        if Gi.shape[0] != n:
            raise InvalidInput(f"{gname}[{i}] has {Gi.shape[0]} rows but the state size is {n}", (gname, i))
        if Gi.shape[1] != m:
            raise InvalidInput(
                f"{gname}[{i}] has {Gi.shape[1]} columns but mode 0 has {m}: all modes need the same input size",
                (gname, i),
            )
    return n, m


def _check_sampling_period(h) -> float:
    try:
        h = float(h)
    except (TypeError, ValueError):
        raise InvalidInput("sampling_period must be a number (seconds)", ("sampling_period",)) from None
    if not np.isfinite(h) or h <= 0:
        raise InvalidInput(f"sampling_period must be positive and finite, got {h}", ("sampling_period",))
    return h


def zero_order_hold(A: np.ndarray, B: np.ndarray, sampling_period: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretization (eq. 3).

    Parameters
    ----------
    A : ndarray, shape (n, n)
        Continuous state matrix (1/s).
    B : ndarray, shape (n, m)
        Continuous input matrix.
    sampling_period : float
        Sampling period h in seconds.

    Returns
    -------
    F : ndarray, shape (n, n)
        ``expm(A h)``.
    G : ndarray, shape (n, m)
        ``int_0^h expm(A tau) dtau B``.
    """
    n, m = B.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = A
    block[:n, n:] = B
    phi = scipy.linalg.expm(block * sampling_period)
    return phi[:n, :n], phi[:n, n:]


@dataclass(frozen=True, eq=False)
class PlantFamily:
    """A family of r discrete-time linear plants sharing n states and m inputs.

    Parameters
    ----------
    F : sequence of array_like, each (n, n)
        State matrices ``F_l``, one per plant mode.
    G : sequence of array_like, each (n, m)
        Input matrices ``G_l``.
    sampling_period : float, optional
        Sampling period h in seconds; only used to label time axes.
    A, B : ndarray, optional
        Continuous matrices the family was discretized from (kept for reference).
    name : str, optional
        Label used in reports.

    Attributes
    ----------
    F : ndarray, shape (r, n, n)
    G : ndarray, shape (r, n, m)

    Raises
    ------
    InvalidInput
        On non-square or mismatched matrices, non-finite entries, an empty
        family or a non-positive sampling period; ``err.field`` names the
        offending field and mode.
    """

    F: np.ndarray
    G: np.ndarray
    sampling_period: float | None = None
    A: np.ndarray | None = field(default=None, repr=False)
    B: np.ndarray | None = field(default=None, repr=False)
    name: str | None = None

    def __post_init__(self):
        Fs = _matrix_list("F", self.F)
        Gs = _matrix_list("G", self.G, ndim_cols=1)
        _check_family(Fs, Gs, "F", "G")
        h = None if self.sampling_period is None else _check_sampling_period(self.sampling_period)
        F = np.stack(Fs)
        G = np.stack(Gs)
        F.setflags(write=False)
        G.setflags(write=False)
        object.__setattr__(self, "F", F)
        object.__setattr__(self, "G", G)
        object.__setattr__(self, "sampling_period", h)

    # ------------------------------------------------------------------ builders
    @classmethod
    def from_continuous(cls, A: Sequence, B: Sequence, sampling_period: float, name: str | None = None) -> "PlantFamily":
        """Discretize a continuous family ``dx/dt = A_l x + B_l u`` by zero-order hold (eq. 3).

        Parameters
        ----------
        A : sequence of array_like, each (n, n)
            Continuous state matrices (1/s).
        B : sequence of array_like, each (n, m)
            Continuous input matrices.
        sampling_period : float
            Sampling period h in seconds, > 0.
        """
        As = _matrix_list("A", A)
        Bs = _matrix_list("B", B, ndim_cols=1)
        _check_family(As, Bs, "A", "B")
        h = _check_sampling_period(sampling_period)
        pairs = [zero_order_hold(Ai, Bi, h) for Ai, Bi in zip(As, Bs)]
        for i, (Fi, Gi) in enumerate(pairs):
            if not (np.all(np.isfinite(Fi)) and np.all(np.isfinite(Gi))):
                raise InvalidInput(f"A[{i}] overflows when discretized at h = {h}", ("A", i))
        return cls(
            F=[p[0] for p in pairs],
            G=[p[1] for p in pairs],
            sampling_period=h,
            A=np.stack(As),
            B=np.stack(Bs),
            name=name,
        )

    @classmethod
    def dc_motor(
        cls,
        inertias: Sequence[float],
        sampling_period: float,
        resistance: float = 2.0,
        inductance: float = 0.5,
        torque_constant: float = 0.15,
        back_emf_constant: float = 0.15,
        damping: float = 0.2,
    ) -> "PlantFamily":
        """DC motor with switching inertia, from the physics of eq. 16/18.

        State ``x = [i_a, omega]`` (A, rad/s), input armature voltage (V)::

            A = [[-R/L, -Kb/L], [Km/J, -B/J]],   B = [[1/L], [0]]

        Parameters
        ----------
        inertias : sequence of float
            Moment of inertia J of each plant mode (kg m^2), > 0.
        sampling_period : float
            h in seconds.
        resistance, inductance, torque_constant, back_emf_constant, damping : float
            R (ohm), L (H), Km (N m/A), Kb (V s/rad), B (N m s/rad); defaults are Table I.

        Notes
        -----
        With Table I's values this gives ``A = [[-4, -0.3], [5, -6.667]]`` for
        J = 0.03, not eq. 19's ``[[-4, -0.03], [0.5, -6.667]]``; use
        :meth:`paper_example` to reproduce the paper's numbers.
        """
        params = {
            "resistance": resistance,
            "inductance": inductance,
            "torque_constant": torque_constant,
            "back_emf_constant": back_emf_constant,
            "damping": damping,
        }
        for key, value in params.items():
            try:
                ok = np.isfinite(float(value))
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise InvalidInput(f"{key} must be a finite number", (key,))
        if float(inductance) <= 0:
            raise InvalidInput("inductance must be positive", ("inductance",))
        try:
            Js = [float(J) for J in inertias]
        except (TypeError, ValueError):
            raise InvalidInput("inertias must be a list of numbers", ("inertias",)) from None
        if not Js:
            raise InvalidInput("inertias must list at least one inertia", ("inertias",))
        for i, J in enumerate(Js):
            if not np.isfinite(J) or J <= 0:
                raise InvalidInput(f"inertias[{i}] must be positive, got {J}", ("inertias", i))
        R, L, Km, Kb, Bd = (float(v) for v in params.values())
        A = [[[-R / L, -Kb / L], [Km / J, -Bd / J]] for J in Js]
        B = [[[1.0 / L], [0.0]] for _ in Js]
        return cls.from_continuous(A, B, sampling_period, name="dc_motor")

    @classmethod
    def paper_example(cls, sampling_period: float = 0.1) -> "PlantFamily":
        """The paper's switched DC motor, eq. 19 (three inertias), discretized at h."""
        return cls.from_continuous(_PAPER_A, _PAPER_B, sampling_period, name="paper_example")

    # ---------------------------------------------------------------- properties
    @property
    def n_modes(self) -> int:
        """Number r of plant modes."""
        return self.F.shape[0]

    @property
    def n_states(self) -> int:
        """State dimension n."""
        return self.F.shape[1]

    @property
    def n_inputs(self) -> int:
        """Input dimension m."""
        return self.G.shape[2]

    def to_dict(self) -> dict:
        """JSON-able description (discrete matrices, and continuous ones when known)."""
        out = {
            "n_modes": self.n_modes,
            "n_states": self.n_states,
            "n_inputs": self.n_inputs,
            "sampling_period": self.sampling_period,
            "F": self.F.tolist(),
            "G": self.G.tolist(),
        }
        if self.A is not None:
            out["A"] = self.A.tolist()
            out["B"] = self.B.tolist()
        return out
