"""The design facade: ``design(family, n_drop, method=...)``, like ``scipy.optimize.minimize``."""

from __future__ import annotations

from typing import Callable

import numpy as np

from .compiled import check_solver
from .errors import InvalidInput
from .methods import ccl, lmi
from .methods.common import DesignOptions
from .network import check_n_drop
from .plant import PlantFamily
from .result import DesignResult

#: Method name -> module with ``run(family, n_drop, options)``.
METHODS = {"lmi": lmi, "ccl": ccl}


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
) -> DesignResult:
    """Design predictive gains ``K_1..K_{n_drop}`` that stabilize the networked loop.

    Parameters
    ----------
    family : PlantFamily
        r plant modes with n states and m inputs.
    n_drop : int
        Drop bound N >= 1: at most ``n_drop - 1`` consecutive lost packets.
    method : {"lmi", "ccl"}
        ``"lmi"``: the exact convex design (one SDP). ``"ccl"``: the paper's
        cone complementarity linearization.
    solver : {"CLARABEL", "SCS"}
        Conic solver; Clarabel (interior point) by default.
    margin : float
        Strictness margin of the LMIs (normalized; must exceed the solver
        tolerance).  For ``lmi``, "infeasible" means no design reaches it.
    max_iter : int
        Iteration cap of iterative methods.
    time_limit : float, optional
        Wall-clock limit in seconds for the whole design.
    callback : callable, optional
        ``callback(record: IterationRecord) -> bool | None`` after every
        iteration; returning True stops the design (``not_converged``).
    ccl_start : {"feasibility", "min_trace"}
        CCL Step 1: the paper's pure feasibility problem, or ``min trace(P + Q)``.

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
    n_drop = check_n_drop(n_drop)
    if method not in METHODS:
        raise InvalidInput(f"method must be one of {sorted(METHODS)}, got {method!r}", ("method",))
    if not (isinstance(margin, (int, float)) and np.isfinite(margin) and 0 < margin < 1):
        raise InvalidInput("margin must be a number in (0, 1)", ("margin",))
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise InvalidInput("max_iter must be an integer >= 1", ("max_iter",))
    if time_limit is not None and not (np.isfinite(time_limit) and time_limit > 0):
        raise InvalidInput("time_limit must be positive (seconds)", ("time_limit",))
    if ccl_start not in ("feasibility", "min_trace"):
        raise InvalidInput("ccl_start must be 'feasibility' or 'min_trace'", ("ccl_start",))
    options = DesignOptions(
        solver=check_solver(solver),
        margin=float(margin),
        max_iter=int(max_iter),
        time_limit=None if time_limit is None else float(time_limit),
        callback=callback,
        ccl_start=ccl_start,
    )
    return METHODS[method].run(family, n_drop, options)
