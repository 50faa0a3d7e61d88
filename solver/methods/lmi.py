"""Exact convex design (DESIGN.md section 3): one SDP, no iteration.

Theorem 1 for the augmented loop holds iff some ``X > 0`` has
``A_s^T X A_s - X < 0`` for every mode s = (l, eta).  With ``W = X^{-1}`` and
``Y_q = K_q W`` the condition is linear::

    [[c_eta W, (F_l^eta W + sum_t F_l^t G_l Y_{eta-t})^T],
     [F_l^eta W + sum_t F_l^t G_l Y_{eta-t},          W]] >= t I

with ``c_eta = 1`` (``lambda^(2 eta)`` for a guaranteed per-sample decay
rate lambda).  We solve ``max t`` subject to ``trace W = n``: the problem is
always feasible and bounded (t <= 1), so the solver never has to detect
infeasibility; the design exists with the requested margin iff ``t* > margin``.
Gains are ``K_q = Y_q W^{-1}`` and the certificate ``X = W^{-1}`` is lifted
to the augmented P and re-checked in float64.
"""

from __future__ import annotations

import time

import cvxpy as cp
import numpy as np

from ..compiled import CompiledProblem, block, problem_cache, schur_block
from ..network import IntervalData, spectral_radii
from ..plant import PlantFamily
from ..result import DesignResult, IterationRecord
from .common import DesignOptions, RunClock, certify_gains


def build(n: int, m: int, r: int, n_drop: int) -> CompiledProblem:
    """The DPP problem for one shape; plant data and decay weights are Parameters."""
    W = cp.Variable((n, n), symmetric=True)
    Y = [cp.Variable((m, n)) for _ in range(n_drop)]
    t = cp.Variable()
    # Few, stacked parameters: cvxpy validates every Parameter on assignment, which
    # costs more than the whole solve when there is one per mode.
    F_pow = cp.Parameter((r * n_drop * n, n))  # row block l*n_drop + eta-1: F_l^eta
    FtG = cp.Parameter((r * n_drop * n, m))  # row block l*n_drop + t: F_l^t G_l
    decay = cp.Parameter(n_drop, nonneg=True)
    eye2 = np.eye(2 * n)
    cons = [cp.trace(W) == n]
    for l in range(r):
        for eta in range(1, n_drop + 1):
            AW = block(F_pow, l * n_drop + eta - 1, n) @ W + sum(
                block(FtG, l * n_drop + s, n) @ Y[eta - s - 1] for s in range(eta)
            )
            cons.append(schur_block(decay[eta - 1] * W, AW, W) - t * eye2 >> 0)
    prob = cp.Problem(cp.Maximize(t), cons)
    params = {"F_pow": F_pow, "FtG": FtG, "decay": decay}
    return CompiledProblem(prob, params, {"W": W, "Y": Y, "t": t})


def compiled_for(family: PlantFamily, n_drop: int) -> tuple[CompiledProblem, bool, float]:
    """Cached problem for this shape: ``(problem, was_cached, build_seconds)``."""
    r, n, m = family.n_modes, family.n_states, family.n_inputs
    start = time.perf_counter()
    compiled, cached = problem_cache.get(("lmi", n, m, r, n_drop), lambda: build(n, m, r, n_drop))
    return compiled, cached, (0.0 if cached else time.perf_counter() - start)


def run(family: PlantFamily, n_drop: int, options: DesignOptions, decay_rate: float = 1.0) -> DesignResult:
    clock = RunClock()
    data = IntervalData.from_family(family, n_drop)
    compiled, clock.cached, clock.setup = compiled_for(family, n_drop)
    r, n, m = family.n_modes, family.n_states, family.n_inputs
    values = {
        "F_pow": data.F_pow.reshape(r * n_drop * n, n),
        "FtG": data.FtG.reshape(r * n_drop * n, m),
        "decay": decay_rate ** (2.0 * np.arange(1, n_drop + 1)),
    }
    info = compiled.solve(values, solver=options.solver, time_limit=options.time_limit)
    clock.add(info)
    t = float(compiled.value("t"))
    W = compiled.value("W")
    W = 0.5 * (W + W.T)
    Y = np.stack(compiled.value("Y"))
    record = IterationRecord(
        iteration=0, objective=t, trace_gap=None, theorem1=False, certificate_margin=None,
        solve_time=info.solve_time, elapsed=clock.elapsed,
    )
    common = dict(method="lmi", n_drop=n_drop, solver=info.solver, solver_status=info.status, history=[record])
    if t <= options.margin:
        return DesignResult(
            outcome="infeasible", gains=None, certificate=None, timings=clock.timings(),
            message=(
                f"no common quadratic Lyapunov design exists: the best normalized margin is "
                f"t* = {t:.3g} <= margin {options.margin:g} (trace W = n)"
            ),
            **common,
        )
    gains = np.linalg.solve(W, np.swapaxes(Y, 1, 2)).swapaxes(1, 2)  # K_q = Y_q W^{-1}, W symmetric
    cert, A = certify_gains(data, gains, options, clock, candidate=np.linalg.inv(W), candidate_source="lmi")
    record.theorem1 = cert is not None
    record.certificate_margin = None if cert is None else cert.margin
    if options.callback is not None:
        options.callback(record)
    if cert is None:
        return DesignResult(
            outcome="not_converged", gains=gains, certificate=None, timings=clock.timings(),
            spectral_radii=spectral_radii(A),
            message=f"the SDP reported margin t* = {t:.3g} but no certificate passed the float64 re-check",
            **common,
        )
    return DesignResult(
        outcome="stabilized", gains=gains, certificate=cert, timings=clock.timings(),
        spectral_radii=spectral_radii(A),
        message=f"stabilized; SDP margin t* = {t:.3g}, certificate re-checked (relative margin {cert.margin:.3g})",
        **common,
    )
