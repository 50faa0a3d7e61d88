"""Pieces every design method shares: options, timing, and turning gains into a certified result."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..compiled import SolveInfo
from ..lyapunov import Certificate, lift, recheck, theorem1_lmi
from ..network import IntervalData, closed_loop_matrices, spectral_radii


@dataclass
class DesignOptions:
    """Options shared by all methods (see :func:`solver.design` for their meaning)."""

    solver: str = "CLARABEL"
    margin: float = 1e-6
    max_iter: int = 50
    time_limit: float | None = None
    callback: Callable | None = None
    ccl_start: str = "feasibility"


@dataclass
class RunClock:
    """Wall clock and solver-time accounting of one design run."""

    start: float = field(default_factory=time.perf_counter)
    setup: float = 0.0
    solver_time: float = 0.0
    solves: int = 0
    cached: bool = True

    def add(self, info: SolveInfo) -> None:
        self.solver_time += info.solve_time if np.isfinite(info.solve_time) else 0.0
        self.solves += 1

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    def remaining(self, time_limit: float | None) -> float | None:
        return None if time_limit is None else time_limit - self.elapsed

    def timings(self) -> dict:
        total = self.elapsed
        return {
            "total": total,
            "setup": self.setup,
            "solver": self.solver_time,
            "overhead": max(total - self.setup - self.solver_time, 0.0),
            "solves": self.solves,
            "cached": self.cached,
        }


def certify_gains(
    data: IntervalData,
    gains: np.ndarray,
    options: DesignOptions,
    clock: RunClock,
    candidate: np.ndarray | None = None,
    candidate_source: str = "",
    candidate_is_reduced: bool = True,
) -> tuple[Certificate | None, np.ndarray]:
    """Find a float64-verified Theorem 1 certificate for ``gains``.

    The method's own candidate (a reduced X, or an augmented P) is tried first;
    if it does not pass the re-check, Theorem 1 is solved as an LMI in P for
    the fixed gains.  Returns ``(certificate or None, A)`` where A holds the
    interval closed loops ``A_{l,eta}(gains)``.
    """
    A = closed_loop_matrices(data, gains)
    if candidate is not None and np.all(np.isfinite(candidate)):
        if candidate_is_reduced:
            cert = recheck(lift(candidate, A), A, candidate_source, X=candidate)
        else:
            cert = recheck(candidate, A, candidate_source)
        if cert.verified:
            return cert, A
    if np.max(spectral_radii(A)) >= 1.0:
        return None, A  # no quadratic certificate can exist; skip the SDP
    X, t, info = theorem1_lmi(A, solver=options.solver, time_limit=options.time_limit)
    clock.add(info)
    if t > 0:
        cert = recheck(lift(X, A), A, "theorem1_lmi", X=X)
        if cert.verified:
            return cert, A
    return None, A
