"""State and input scaling for badly scaled plant families.

Interior-point solvers work to absolute tolerances near 1e-8, so a family
whose entries span many orders of magnitude (volts next to microamperes)
can lose its answer in the tolerance.  We change coordinates
``x = T x~``, ``u = U u~`` with diagonal T, U whose entries are powers of two
(so the similarity ``T^-1 F T`` is exact in floating point), design in the
balanced coordinates, and map back::

    K_q = U K~_q T^-1,    X = T^-T X~ T^-1,    P_s = T^-T P~_s T^-1

Stability verdicts do not depend on coordinates; the re-check is repeated in
the original ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from .plant import PlantFamily


@dataclass(frozen=True)
class Scaling:
    """Diagonal coordinate change: ``state`` (n,) for T, ``input`` (m,) for U (powers of two)."""

    state: np.ndarray
    input: np.ndarray

    @property
    def is_identity(self) -> bool:
        return bool(np.all(self.state == 1.0) and np.all(self.input == 1.0))

    def family(self, family: PlantFamily) -> PlantFamily:
        """The family in scaled coordinates."""
        t, u = self.state, self.input
        F = family.F / t[None, :, None] * t[None, None, :]
        G = family.G / t[None, :, None] * u[None, None, :]
        return PlantFamily(F=F, G=G, sampling_period=family.sampling_period, name=family.name)

    def gains_back(self, gains: np.ndarray) -> np.ndarray:
        """``K = U K~ T^-1`` for gains of shape (n_drop, m, n)."""
        return gains * self.input[None, :, None] / self.state[None, None, :]

    def quadratic(self, P: np.ndarray) -> np.ndarray:
        """``T' P T``: user matrices (..., k n, k n) on k stacked copies of the state in these coordinates (the
        inverse of :meth:`quadratic_back`; exact, powers of two)."""
        t = np.tile(self.state, P.shape[-1] // self.state.size)
        return P * t[..., :, None] * t[..., None, :]

    def quadratic_back(self, P: np.ndarray) -> np.ndarray:
        """``T^-T P~ T^-1`` for (..., k n, k n) matrices on k stacked copies of the state."""
        k = P.shape[-1] // self.state.size
        inv = np.tile(1.0 / self.state, k)
        return P * inv[..., :, None] * inv[..., None, :]


def _power_of_two(v: np.ndarray) -> np.ndarray:
    return np.exp2(np.round(np.log2(v)))


def _reach_rows(F: np.ndarray, G: np.ndarray) -> np.ndarray:
    """Row norms of the controllability matrices ``[G, F G, ..., F^(n-1) G]`` of every mode.

    F is divided by ``max(1, ||F||)`` so that unstable modes do not let the highest
    power dominate: row i measures how strongly the inputs reach state i.
    """
    r, n, m = G.shape
    total = np.zeros(n)
    for l in range(r):
        Fl = F[l] / max(1.0, float(np.linalg.norm(F[l], 2)))
        block = G[l]
        for _ in range(n):
            total += np.sum(block**2, axis=1)
            block = Fl @ block
    return np.sqrt(total)


def balance(family: PlantFamily, threshold: float = 1e3) -> Scaling:
    """Scaling that balances states *and* inputs, or the identity when the family is well scaled.

    T first balances ``sum_l |F_l|`` (row and column norms made comparable,
    LAPACK's ``gebal`` without permutation).  When the inputs then reach the
    states with strengths spread over more than ``threshold`` (a weakly actuated
    state next to a strongly actuated one: the gains must be large in one
    direction only), T also scales every state by the row norm of the
    controllability matrix ``[G, F G, ..., F^(n-1) G]`` (over all modes), so each
    state is measured in units the inputs move it by.  U then gives every column
    of the scaled input matrices a norm near one.  All factors are powers of two;
    applied only when the entries' magnitudes spread over more than ``threshold``.
    """
    n, m = family.n_states, family.n_inputs
    mags = np.abs(np.concatenate([family.F.ravel(), family.G.ravel()]))
    mags = mags[mags > 0]
    if mags.size == 0 or mags.max() / mags.min() <= threshold:
        return Scaling(np.ones(n), np.ones(m))
    summed = np.sum(np.abs(family.F), axis=0) + 1e-300
    _, (scale, _perm) = scipy.linalg.matrix_balance(summed, permute=False, separate=True)
    t = _power_of_two(scale)
    Fs = family.F / t[None, :, None] * t[None, None, :]
    Gs = family.G / t[None, :, None]
    reach = _reach_rows(Fs, Gs)
    live = reach > 0
    if np.count_nonzero(live) >= 2 and reach[live].max() / reach[live].min() > threshold:
        extra = np.where(live, reach / reach[live].max(), 1.0)
        t = t * _power_of_two(extra)
        Gs = family.G / t[None, :, None]
    col = np.sqrt(np.sum(Gs**2, axis=(0, 1)))
    u = _power_of_two(np.where(col > 0, 1.0 / np.where(col > 0, col, 1.0), 1.0))
    return Scaling(t, u)


# ------------------------------------------------------------------ performance designs
@dataclass(frozen=True)
class PerformanceScaling:
    """The coordinates of a performance design: ``x = T x~``, ``u = U u~``, the cost divided by ``cost``,
    the disturbance ``w = disturbance w~`` and the output ``z = output z~``.

    Every factor is a power of two (``cost`` a power of four, so that the cost rows ``L / sqrt(cost)``
    stay exact): the scaled lifted data are the user's, scaled exactly, and a re-check in either
    coordinates checks the same inequality.  Mapping back (docs/design.md, "Performance designs")::

        K = U K~ T^-1,   P = cost T^-T P~ T^-1 (cost),   P = output^2 T^-T P~ T^-1 (hinf),
        X = T^-T X~ T^-1 (invariant set),   cost bound = cost x bound~,   gamma = gamma~ output / disturbance,
        trace P = cost sum_i P~_ii / t_i^2
    """

    plain: Scaling
    cost: float = 1.0
    disturbance: float = 1.0
    output: float = 1.0

    @property
    def is_identity(self) -> bool:
        return self.plain.is_identity and self.cost == 1.0 and self.disturbance == 1.0 and self.output == 1.0

    @property
    def gain(self) -> float:
        """``gamma = gain x gamma~``."""
        return self.output / self.disturbance

    @property
    def trace_weight(self) -> np.ndarray:
        """``w`` of ``trace P = cost sum_i w_i P~_ii`` (``1 / t_i^2``)."""
        return 1.0 / self.plain.state**2

    def x0(self, x0):
        return None if x0 is None else x0 / self.plain.state

    def u_max(self, u_max):
        return None if u_max is None else u_max / self.plain.input

    def weights(self, Q, R):
        """``(Q~, R~) = (T' Q T / cost, U' R U / cost)``: the stage cost's weights in scaled coordinates."""
        t, u = self.plain.state, self.plain.input
        return Q * t[:, None] * t[None, :] / self.cost, R * u[:, None] * u[None, :] / self.cost

    def channel(self, E, C, D):
        """``(E~, C~, D~) = (T^-1 E disturbance, C T / output, D U / output)``, one per plant mode (r, ., .)."""
        t, u = self.plain.state, self.plain.input
        return (E / t[None, :, None] * self.disturbance, C * t[None, None, :] / self.output,
                D * u[None, None, :] / self.output)

    def modes(self, modes):
        """The :class:`solver.network.ModeSet` in scaled coordinates (every entry scaled exactly)."""
        from dataclasses import replace as _replace

        t, u = self.plain.state, self.plain.input
        return _replace(modes, free=modes.free / t[None, :, None] * t[None, None, :],
                        coef=modes.coef / t[None, None, :, None] * u[None, None, None, :],
                        F=None if modes.F is None else modes.F / t[None, :, None] * t[None, None, :],
                        G=None if modes.G is None else modes.G / t[None, :, None] * u[None, None, :])

    def lifted(self, lifted):
        """The lifted interval data (:class:`solver.lifting.Lifted`) in scaled coordinates.

        ``A~ = T^-1 A T`` (coefficients ``T^-1 coef_q U``), cost rows ``L T / sqrt(cost)`` (``L U / sqrt(cost)``),
        output rows ``C T / output`` (``C U / output``), ``B~ = T^-1 B disturbance``, ``D~ = D disturbance / output``.
        """
        from dataclasses import replace as _replace

        from .lifting import AffineRows, Lifted

        t, u = self.plain.state, self.plain.input
        root = np.sqrt(self.cost)

        def rows(r, left, div=1.0):
            if r is None:
                return None
            free = r.free * t[None, :] / div
            coef = r.coef * u[None, None, :] / div
            if left is not None:
                free, coef = free / left[:, None], coef / left[None, :, None]
            return AffineRows(free, coef)

        sw, sz = self.disturbance, self.output
        out = [_replace(lm, state=rows(lm.state, t), cost=rows(lm.cost, None, root),
                        output=rows(lm.output, None, sz), B=None if lm.B is None else lm.B / t[:, None] * sw,
                        D=None if lm.D is None else lm.D * (sw / sz))
               for lm in lifted.lifted]
        Q, R = (None, None) if lifted.Q is None else self.weights(lifted.Q, lifted.R)
        ch = None if lifted.channel is None else self.channel(*lifted.channel)
        return Lifted(modes=self.modes(lifted.modes), lifted=out, Q=Q, R=R, channel=ch)

    def quadratic_back(self, P, kind: str | None = None):
        """``T^-T P~ T^-1``, times ``cost`` for a cost certificate (``kind="cost"``), ``output^2`` for "hinf"."""
        if P is None:
            return None
        back = self.plain.quadratic_back(np.asarray(P))
        return back * {"cost": self.cost, "hinf": self.output**2}.get(kind, 1.0)


def _power_of_four(v: float) -> float:
    return float(4.0 ** np.round(np.log(v) / np.log(4.0)))


def performance_balance(family: PlantFamily, lifted, threshold: float = 1e3) -> PerformanceScaling:
    """:func:`balance` for the plant, then the cost divided by a power of four near the largest weight, and
    the disturbance and output channels (hinf) brought to unit size by powers of two.

    ``lifted``: the user's :class:`solver.lifting.Lifted` data (weights, channels).
    """
    plain = balance(family, threshold)
    t, u = plain.state, plain.input
    cost = sw = sz = 1.0
    if lifted.Q is not None and lifted.R is not None:
        Q, R = lifted.Q, lifted.R
        size = max(np.linalg.norm(Q * t[:, None] * t[None, :], 2), np.linalg.norm(R * u[:, None] * u[None, :], 2))
        if np.isfinite(size) and size > 0:
            cost = _power_of_four(size)
    if lifted.lifted[0].B is not None and lifted.lifted[0].output is not None:
        b = max(np.linalg.norm(lm.B / t[:, None]) for lm in lifted.lifted)
        z = max(max(np.linalg.norm(lm.output.free * t[None, :]), np.linalg.norm(lm.output.coef * u[None, None, :]))
                for lm in lifted.lifted)
        if np.isfinite(b) and b > 0:
            sw = float(_power_of_two(np.array(1.0 / b)))
        if np.isfinite(z) and z > 0:
            sz = float(_power_of_two(np.array(z)))
    return PerformanceScaling(plain, cost, sw, sz)
