"""Pieces every design method shares: options, timing, and turning gains into a certified result."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..compiled import SolveInfo
from ..lyapunov import Certificate, certify, lift, recheck_common, recheck_common_reduced, recheck_switched
from ..network import ModeSet, spectral_radii
from ..result import DesignResult, IterationRecord


@dataclass
class DesignOptions:
    """Options shared by all methods (see :func:`solver.design` for their meaning)."""

    solver: str = "CLARABEL"
    margin: float = 1e-6
    max_iter: int = 50
    time_limit: float | None = None
    callback: Callable | None = None
    ccl_start: str = "feasibility"
    decay_rate: float | None = None

    def rho(self, modes: ModeSet) -> np.ndarray:
        """Decay factors ``lambda^(2 eta_s)`` per mode (ones without a rate)."""
        lam = 1.0 if self.decay_rate is None else self.decay_rate
        return lam ** (2.0 * modes.eta)


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
    modes: ModeSet,
    gains: np.ndarray,
    options: DesignOptions,
    clock: RunClock,
    candidate: np.ndarray | None = None,
    candidate_kind: str = "reduced",
    candidate_source: str = "",
) -> tuple[Certificate | None, np.ndarray]:
    """Find a float64-verified certificate for ``gains``.

    The method's own candidate is tried first: a reduced common X
    (``"reduced"``, lifted to the augmented P of Theorem 1), an augmented P
    (``"augmented"``) or mode-dependent ``P_s`` (``"switched"``).  With a
    decay rate the candidate must also prove it.  Without a rate, and if the
    candidate fails, fixed-gain LMIs (common, then switched) are solved.

    Returns ``(certificate or None, A)`` with ``A`` the closed loops (S, n, n).
    """
    A = modes.closed_loops(gains)
    rho = options.rho(modes)
    n_drop = modes.n_drop
    if candidate is not None and np.all(np.isfinite(candidate)):
        if candidate_kind == "switched":
            cert = recheck_switched(candidate, A, candidate_source, rho=rho)
        elif candidate_kind == "augmented":
            cert = recheck_common(candidate, A, n_drop, candidate_source)
        else:
            cert = recheck_common(lift(candidate, A, n_drop), A, n_drop, candidate_source, X=candidate)
            if cert.verified and options.decay_rate is not None:
                cert.verified = recheck_common_reduced(candidate, A, rho, candidate_source).verified
        if cert.verified:
            cert.decay_rate = options.decay_rate
            return cert, A
    if options.decay_rate is not None or np.max(spectral_radii(A)) >= 1.0:
        return None, A  # a rate is the candidate's to prove; an unstable mode has no certificate
    kinds = ("common_quadratic",) if modes.plant_switching == "per_interval" and candidate_kind != "switched" else (
        "common_quadratic", "switched")
    return certify(A, n_drop, kinds=kinds, solver=options.solver, time_limit=options.time_limit, on_solve=clock.add), A


def finish(
    modes: ModeSet,
    method: str,
    outcome: str,
    gains,
    cert,
    A,
    clock: RunClock,
    info_solver: str,
    status: str,
    message: str,
    history: list,
    options: DesignOptions,
) -> DesignResult:
    """Assemble a DesignResult with the fields every method reports."""
    return DesignResult(
        outcome=outcome,
        gains=gains,
        certificate=cert,
        method=method,
        n_drop=modes.n_drop,
        history=history,
        solver=info_solver,
        solver_status=status,
        timings=clock.timings(),
        message=message,
        spectral_radii=None if A is None else modes.reshape_per_mode(spectral_radii(A)),
        scheme=modes.scheme,
        plant_switching=modes.plant_switching,
        decay_rate=options.decay_rate if outcome == "stabilized" else None,
        mode_labels=[modes.label(s) for s in range(modes.n_modes)],
    )


def conclude_one_shot(
    modes: ModeSet,
    method: str,
    options: DesignOptions,
    clock: RunClock,
    info: SolveInfo,
    t: float,
    *,
    infeasible: str | None = None,
    gains=None,
    cert: Certificate | None = None,
    A=None,
) -> DesignResult:
    """The result of a one-SDP method (``lmi``, ``switched``) from its optimal margin t*.

    ``infeasible`` is the reason when ``t* <= margin``; otherwise the gains
    and the outcome of :func:`certify_gains` decide between stabilized and not_converged.
    """
    record = IterationRecord(
        iteration=0, objective=t, trace_gap=None, theorem1=cert is not None,
        certificate_margin=None if cert is None else cert.margin, solve_time=info.solve_time, elapsed=clock.elapsed,
    )

    def result(outcome, message):
        return finish(modes, method, outcome, gains, cert, A, clock, info.solver, info.status, message, [record],
                      options)

    rate = "" if options.decay_rate is None else f" at decay rate {options.decay_rate:g}"
    if infeasible is not None:
        return result("infeasible", f"{infeasible}: the best normalized margin is t* = {t:.3g} <= margin "
                                    f"{options.margin:g}{rate}")
    if options.callback is not None:
        options.callback(record)
    if cert is None:
        return result("not_converged",
                      f"the SDP reported margin t* = {t:.3g} but no certificate passed the float64 re-check")
    return result("stabilized", f"stabilized; SDP margin t* = {t:.3g}, {cert.kind} certificate re-checked "
                                f"(relative margin {cert.margin:.3g}){rate}")
