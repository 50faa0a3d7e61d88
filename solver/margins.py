"""Stability margins: how many drops, how slow a sampling, and a design grid.

These run many designs; each takes a ``callback(progress: dict) -> bool | None``
called after every design (returning True stops the search, which then
reports what it found so far with ``stopped=True``), so a service can report
progress and cancel.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .design import design
from .errors import InvalidInput, SolverFailed
from .plant import PlantFamily
from .result import DesignResult


@dataclass
class MarginResult:
    """Outcome of a margin search or a design grid.

    Attributes
    ----------
    kind : {"n_drop", "sampling_period", "grid"}
    margin : int or float or None
        Largest n_drop, or largest sampling period (s), with a stabilizing
        design; None when even the smallest fails (and for grids).
    design : DesignResult or None
        The design at the margin (its gains and certificate).
    curve : list of dict
        Every point tried, in order: the parameter, ``outcome``, the max
        spectral radius and the certificate margin.
    method : str
    stopped : bool
        True when the callback stopped the search early.
    message : str
    timings : dict
    """

    kind: str
    margin: float | int | None
    design: DesignResult | None
    curve: list = field(default_factory=list)
    method: str = "lmi"
    stopped: bool = False
    message: str = ""
    timings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "margin": self.margin,
            "design": None if self.design is None else self.design.to_dict(include_certificate_matrix=False),
            "curve": self.curve,
            "method": self.method,
            "stopped": self.stopped,
            "message": self.message,
            "timings": self.timings,
        }


def _point(res: DesignResult, **where) -> dict:
    return {
        **where,
        "outcome": res.outcome,
        "max_spectral_radius": None if res.spectral_radii is None else float(np.max(res.spectral_radii)),
        "certificate_margin": None if res.certificate is None else res.certificate.margin,
        "decay_rate": res.decay_rate,
        "gains": None if res.gains is None else res.gains.tolist(),
    }


#: ``outcome`` of a curve point whose solver failed (e.g. the IPM's iteration cap at a large h): no design
#: was certified there, and nothing was proven either, about that point or any other.
SOLVER_FAILED = "solver_failed"
#: ``outcome`` of a curve point the size guard refused (estimated memory or time over budget): not tried.
OVER_BUDGET = "over_budget"


def _probe(family: PlantFamily, n_drop: int, method: str, design_options: dict, where: dict):
    """One design of a search: ``(result or None, curve point)``; a solver failure is a point, not a crash."""
    try:  # a margin is about stability: plain designs unless a rate is asked for
        res = design(family, n_drop, method=method, **{"decay_rate": None, **design_options})
    except SolverFailed as err:
        return None, {**where, "outcome": SOLVER_FAILED, "max_spectral_radius": None, "certificate_margin": None,
                      "decay_rate": None, "gains": None, "message": f"no certified design: {err}"}
    except InvalidInput as err:
        if "over the limit" not in str(err):
            raise
        # the size guard (solver.compiled.design_size): a point too big to try, which proves nothing either
        return None, {**where, "outcome": OVER_BUDGET, "max_spectral_radius": None, "certificate_margin": None,
                      "decay_rate": None, "gains": None, "message": f"not tried: {err}"}
    return res, _point(res, **where)


def _stabilized(res) -> bool:
    return res is not None and res.outcome == "stabilized"


def _notify(callback, curve, total) -> bool:
    return bool(callback({"step": len(curve), "total": total, "last": curve[-1]})) if callback else False


def max_n_drop(
    family: PlantFamily,
    method: str = "lmi",
    *,
    n_drop_max: int = 20,
    callback: Callable | None = None,
    **design_options,
) -> MarginResult:
    """Largest drop bound with a stabilizing design.

    Designs for n_drop = 1, 2, ... and stops at the first failure: a design
    for N drops also serves N - 1 (its modes are a subset), so feasibility is
    monotone in n_drop for the exact methods.

    Parameters
    ----------
    family : PlantFamily
    method : str
        Any :func:`solver.design` method.
    n_drop_max : int
        Largest n_drop tried (>= 1).
    callback : callable, optional
    **design_options
        Passed to :func:`solver.design` (``scheme``, ``plant_switching``, ...).
    """
    if isinstance(n_drop_max, bool) or not isinstance(n_drop_max, (int, np.integer)) or not 1 <= n_drop_max <= 64:
        raise InvalidInput("n_drop_max must be an integer in 1..64", ("n_drop_max",))
    start = time.perf_counter()
    curve: list = []
    best = None
    stopped = False
    for N in range(1, n_drop_max + 1):
        res, point = _probe(family, N, method, design_options, {"n_drop": N})
        curve.append(point)
        if not _stabilized(res):
            break
        best = res
        if _notify(callback, curve, n_drop_max):
            stopped = True
            break
    else:
        N = n_drop_max
    margin = None if best is None else best.n_drop
    if margin is None:
        message = "no stabilizing design even for n_drop = 1"
    elif margin == n_drop_max and curve[-1]["outcome"] == "stabilized":
        message = f"stabilizing designs up to the largest n_drop tried ({n_drop_max}); the margin may be larger"
    else:
        message = f"largest n_drop with a stabilizing {method} design: {margin}"
    if curve and curve[-1]["outcome"] == SOLVER_FAILED:
        message += (f"; the solver failed at n_drop = {curve[-1]['n_drop']}, which proves nothing: "
                    "the margin may be larger")
    if curve and curve[-1]["outcome"] == OVER_BUDGET:
        message += (f"; n_drop = {curve[-1]['n_drop']} is over the size budget and was not tried, which proves "
                    "nothing: the margin may be larger")
    return MarginResult("n_drop", margin, best, curve, method, stopped, message,
                        {"total": time.perf_counter() - start, "designs": len(curve)})


def _continuous(family: PlantFamily):
    if family.A is None or family.B is None:
        raise InvalidInput("a sampling-period search needs a continuous family (PlantFamily.from_continuous)",
                           ("plant",))
    return family.A, family.B


def max_sampling_period(
    family: PlantFamily,
    n_drop: int,
    method: str = "lmi",
    *,
    h_min: float = 1e-3,
    h_max: float = 2.0,
    tol: float = 1e-3,
    callback: Callable | None = None,
    **design_options,
) -> MarginResult:
    """Largest sampling period h with a stabilizing design, by bisection.

    Bisection assumes the certifiable periods form an interval ``[h_lo, h*]``;
    that is typical but not guaranteed (pathological sampling), so the whole
    curve of periods tried is returned to judge it.  A period without a
    certified design proves nothing about other periods: when ``h_min`` has
    none (at a tiny h the decrease a Lyapunov function can certify is O(h), below
    the LMI margin, and the solver may fail), the search doubles h until a
    period is certified and bisects above it.  A probe whose solver fails is
    recorded as ``outcome="solver_failed"`` (no certified design there, no proof
    either) and bisected like any uncertified point; it never ends the search.

    Parameters
    ----------
    family : PlantFamily
        Built with :meth:`PlantFamily.from_continuous`; rediscretized at each h.
    n_drop : int
    h_min, h_max : float
        Search interval (s), ``0 < h_min < h_max``.
    tol : float
        Absolute tolerance on h (s).
    """
    A, B = _continuous(family)
    try:
        h_min, h_max, tol = float(h_min), float(h_max), float(tol)
    except (TypeError, ValueError):
        raise InvalidInput("h_min, h_max and tol must be numbers", ("h_min",)) from None
    if not (0 < h_min < h_max <= 1e4) or not np.isfinite(h_max):
        raise InvalidInput("need 0 < h_min < h_max", ("h_max",))
    if not (0 < tol < h_max - h_min):
        raise InvalidInput("tol must be positive and below h_max - h_min", ("tol",))
    start = time.perf_counter()
    curve: list = []
    total = int(np.ceil(np.log2((h_max - h_min) / tol))) + 2

    def attempt(h):
        res, point = _probe(PlantFamily.from_continuous(A, B, h), n_drop, method, design_options,
                            {"sampling_period": h})
        curve.append(point)
        return res

    best = None  # the stabilized design with the largest h so far
    stopped = False
    lo = hi = None  # certified at lo, not at hi (hi = None: nothing tried above lo failed yet)
    if _stabilized(res := attempt(h_min)):
        best, lo = res, h_min
    else:
        # A point without a certified design proves nothing about other periods (an "infeasible" is a proof
        # about that h and the LMI margin only; a solver failure proves nothing at all): scan upwards by
        # doubling for a certified period before concluding anything.
        h = h_min
        while not (stopped := _notify(callback, curve, total)) and (h := min(2 * h, h_max)) < h_max:
            if _stabilized(res := attempt(h)):
                best, lo = res, h
                break
    if best is not None and not stopped:
        stopped = _notify(callback, curve, total)
        if not stopped and _stabilized(res := attempt(h_max)):
            best = res
        elif not stopped:
            hi = h_max
            while hi - lo > tol and not (stopped := _notify(callback, curve, total)):
                mid = 0.5 * (lo + hi)
                if _stabilized(res := attempt(mid)):
                    lo, best = mid, res
                else:
                    hi = mid
    margin = None if best is None else max(p["sampling_period"] for p in curve if p["outcome"] == "stabilized")
    failed = [p["sampling_period"] for p in curve if p["outcome"] == SOLVER_FAILED]
    if best is None:
        tried = sorted({p["sampling_period"] for p in curve})
        message = (f"no certified {method} design at any period tried ({', '.join(f'{h:g}' for h in tried)} s); "
                   f"this proves nothing about other periods")
    elif margin == h_max:
        message = f"stabilizing at the largest period tried ({h_max:g} s); the margin may be larger"
    else:
        message = f"largest sampling period with a stabilizing {method} design: {margin:.6g} s (tolerance {tol:g} s)"
    if failed:
        message += (f"; the solver failed at h = {', '.join(f'{h:.6g}' for h in failed)} s (no certified design "
                    "there, and no proof either)")
    if best is not None and margin > h_min and curve[0]["outcome"] != "stabilized":
        message += f"; nothing certified at h_min = {h_min:g} s ({curve[0]['outcome']})"
    return MarginResult("sampling_period", margin, best, curve, method, stopped, message,
                        {"total": time.perf_counter() - start, "designs": len(curve)})


def design_grid(
    family: PlantFamily,
    points: Sequence,
    method: str = "lmi",
    *,
    callback: Callable | None = None,
    **design_options,
) -> MarginResult:
    """Design at every (sampling_period, n_drop) pair; results as a table (``curve``).

    Parameters
    ----------
    family : PlantFamily
        Continuous (rediscretized per h).
    points : sequence of (float, int)
        (h in s, n_drop) pairs.
    """
    A, B = _continuous(family)
    try:
        pairs = [(float(h), int(N)) for h, N in points]
    except (TypeError, ValueError):
        raise InvalidInput("points must be a list of [sampling_period, n_drop] pairs", ("points",)) from None
    if not pairs:
        raise InvalidInput("points must not be empty", ("points",))
    start = time.perf_counter()
    curve: list = []
    stopped = False
    for h, N in pairs:
        curve.append(_probe(PlantFamily.from_continuous(A, B, h), N, method, design_options,
                            {"sampling_period": h, "n_drop": N})[1])
        if _notify(callback, curve, len(pairs)):
            stopped = True
            break
    ok = sum(p["outcome"] == "stabilized" for p in curve)
    return MarginResult("grid", None, None, curve, method, stopped,
                        f"{ok} of {len(curve)} grid points stabilized",
                        {"total": time.perf_counter() - start, "designs": len(curve)})
