"""The design facade: ``design(family, n_drop, method=...)``, like ``scipy.optimize.minimize``."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from .compiled import check_solver
from .errors import InvalidInput
from .methods import ccl, lmi, switched
from .methods.common import DesignOptions
from .lyapunov import recheck_common, recheck_switched
from .network import MAX_MODES, ModeSet
from .plant import PlantFamily
from .result import DesignResult
from .scaling import Scaling, balance

#: Method name -> module with ``run(modes, options)``.
METHODS = {"lmi": lmi, "ccl": ccl, "switched": switched}
#: Methods that can demand a decay rate (CCL's augmented form has no rate).
RATE_METHODS = ("lmi", "switched")


def _check_options(margin, max_iter, time_limit, ccl_start, decay_rate, rate_tol, method):
    if isinstance(margin, bool) or not (isinstance(margin, (int, float)) and np.isfinite(margin) and 0 < margin < 1):
        raise InvalidInput("margin must be a number in (0, 1)", ("margin",))
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise InvalidInput("max_iter must be an integer >= 1", ("max_iter",))
    if time_limit is not None and not (isinstance(time_limit, (int, float)) and np.isfinite(time_limit)
                                       and time_limit > 0):
        raise InvalidInput("time_limit must be positive (seconds)", ("time_limit",))
    if ccl_start not in ("feasibility", "min_trace"):
        raise InvalidInput("ccl_start must be 'feasibility' or 'min_trace'", ("ccl_start",))
    if decay_rate is not None:
        if method not in RATE_METHODS:
            raise InvalidInput(f"decay_rate is available with methods {RATE_METHODS}", ("decay_rate",))
        if decay_rate != "max" and (isinstance(decay_rate, bool) or not isinstance(decay_rate, (int, float))
                                    or not 0 < decay_rate <= 1):
            raise InvalidInput("decay_rate must be a number in (0, 1] or 'max'", ("decay_rate",))
    if not (isinstance(rate_tol, (int, float)) and 1e-6 <= rate_tol <= 0.1):
        raise InvalidInput("rate_tol must be in [1e-6, 0.1]", ("rate_tol",))


def design(
    family: PlantFamily,
    n_drop: int,
    method: str = "lmi",
    *,
    solver: str = "CLARABEL",
    margin: float = 1e-6,
    max_iter: int = 50,
    time_limit: float | None = None,
    callback: Callable | None = None,
    ccl_start: str = "feasibility",
    decay_rate: float | str | None = None,
    rate_tol: float = 1e-3,
    plant_switching: str = "per_interval",
    scheme: str = "predictive",
    max_modes: int = MAX_MODES,
    scaling: str = "auto",
) -> DesignResult:
    """Design gains ``K_1..K_{n_drop}`` that stabilize the networked loop under any losses and jumps.

    Parameters
    ----------
    family : PlantFamily
        r plant modes with n states and m inputs.
    n_drop : int
        Drop bound N >= 1: at most ``n_drop - 1`` consecutive lost packets.
    method : {"lmi", "ccl", "switched"}
        ``"lmi"``: the exact convex design (one SDP, common quadratic Lyapunov
        function). ``"ccl"``: the paper's cone complementarity linearization.
        ``"switched"``: mode-dependent Lyapunov functions (one SDP, less conservative).
    solver : {"CLARABEL", "SCS"}
        Conic solver; Clarabel (interior point) by default.
    margin : float
        Strictness margin of the LMIs (normalized; must exceed the solver
        tolerance).  For ``lmi``/``switched``, "infeasible" means no design reaches it.
    max_iter : int
        Iteration cap of iterative methods.
    time_limit : float, optional
        Wall-clock limit in seconds for the whole design.  It is checked between
        iterations and handed to the solver, which checks it between its own
        iterations; problem construction is not interruptible, so it is a soft
        limit (the service enforces a hard one by stopping the worker process).
    callback : callable, optional
        ``callback(record: IterationRecord) -> bool | None`` after every
        iteration; returning True stops the design (``not_converged``).
    ccl_start : {"feasibility", "min_trace"}
        CCL Step 1: the paper's pure feasibility problem, or ``min trace(P + Q)``.
    decay_rate : float in (0, 1], "max" or None
        Demand a per-sample decay rate lambda (``|x(i_{m+1})| <= lambda^eta |x(i_m)|``
        in the certificate's norm), or find the smallest one by bisection
        (to ``rate_tol``).  ``lmi`` and ``switched`` only.
    rate_tol : float
        Bisection tolerance on lambda for ``decay_rate="max"``.
    plant_switching : {"per_interval", "per_sample"}
        Plant mode constant over an interval (the paper), or free to jump at every sample.
    scheme : {"predictive", "hold", "zero"}
        The paper's predictive buffer, or a baseline: hold the last input
        (all K_q equal) or zero input on loss (K_q = 0 for q > 1).
    max_modes : int
        Refuse mode sets larger than this (per-sample switching has sum r^eta modes).
    scaling : {"auto", "none"}
        ``"auto"`` designs in balanced coordinates (diagonal powers of two) when
        the family's entries spread over more than three decades, and maps
        gains and certificates back (see :mod:`solver.scaling`).

    Returns
    -------
    DesignResult
        ``outcome`` is "stabilized" only with a float64-verified certificate.

    Raises
    ------
    InvalidInput
        Bad arguments (the field is named in ``err.field``).
    SolverFailed
        The conic solver failed; never reported as "infeasible".
    """
    if not isinstance(family, PlantFamily):
        raise InvalidInput("family must be a PlantFamily", ("family",))
    if method not in METHODS:
        raise InvalidInput(f"method must be one of {sorted(METHODS)}, got {method!r}", ("method",))
    _check_options(margin, max_iter, time_limit, ccl_start, decay_rate, rate_tol, method)
    if scaling not in ("auto", "none"):
        raise InvalidInput("scaling must be 'auto' or 'none'", ("scaling",))
    modes = ModeSet.from_family(family, n_drop, plant_switching=plant_switching, scheme=scheme,
                                max_modes=max_modes)
    options = DesignOptions(
        solver=check_solver(solver),
        margin=float(margin),
        max_iter=int(max_iter),
        time_limit=None if time_limit is None else float(time_limit),
        callback=callback,
        ccl_start=ccl_start,
        decay_rate=None if decay_rate in (None, "max") else float(decay_rate),
    )
    scale = balance(family) if scaling == "auto" else None
    if scale is not None and not scale.is_identity:
        scaled_modes = ModeSet.from_family(scale.family(family), n_drop, plant_switching=plant_switching,
                                           scheme=scheme, max_modes=max_modes)
        return _unscale(_run(METHODS[method].run, scaled_modes, options, decay_rate, rate_tol), scale, modes)
    return _run(METHODS[method].run, modes, options, decay_rate, rate_tol)


def _run(runner, modes: ModeSet, options: DesignOptions, decay_rate, rate_tol: float) -> DesignResult:
    if decay_rate != "max":
        return runner(modes, options)
    return _smallest_rate(runner, modes, options, rate_tol)


def _smallest_rate(runner, modes: ModeSet, options: DesignOptions, tol: float) -> DesignResult:
    """Bisection on lambda in (0, 1]: every design at a feasible lambda is certified for it."""
    totals = {"total": 0.0, "setup": 0.0, "solver": 0.0, "solves": 0}

    def attempt(lam):
        res = runner(modes, replace(options, decay_rate=lam))
        for key in totals:
            totals[key] += res.timings.get(key, 0)
        search.append({"decay_rate": lam, "outcome": res.outcome})
        return res

    search: list = []
    best = attempt(1.0)
    if best.outcome == "stabilized":
        lo, hi = 0.0, 1.0
        while hi - lo > tol:
            mid = 0.5 * (lo + hi)
            res = attempt(mid)
            if res.outcome == "stabilized":
                hi, best = mid, res
            else:
                lo = mid
        best.message += f"; smallest certified decay rate {hi:.4g} (bisection to {tol:g}, {len(search)} designs)"
    best.rate_search = search
    best.timings.update(totals, overhead=max(totals["total"] - totals["setup"] - totals["solver"], 0.0))
    return best


def _unscale(res: DesignResult, scale: Scaling, modes: ModeSet) -> DesignResult:
    """Map a design made in scaled coordinates back, and re-check it in the original ones.

    The powers-of-two similarity makes the scaled re-check exact; the original
    coordinates are re-checked too and, when rounding there is too coarse to
    confirm the margin, the certificate stays in scaled coordinates
    (``res.scaling`` says which).
    """
    res.scaling = {"state": scale.state.tolist(), "input": scale.input.tolist(), "certificate": "original"}
    if res.gains is None:
        return res
    res.gains = scale.gains_back(res.gains)
    cert = res.certificate
    if cert is None:
        return res
    A = modes.closed_loops(res.gains)
    if cert.kind == "switched":
        original = recheck_switched(scale.quadratic_back(cert.P), A, cert.source)
    else:
        X = None if cert.X is None else scale.quadratic_back(cert.X)
        original = recheck_common(scale.quadratic_back(cert.P), A, modes.n_drop, cert.source, X=X)
    if original.verified:
        original.decay_rate = cert.decay_rate
        res.certificate = original
    else:
        res.scaling["certificate"] = "scaled"
    return res
