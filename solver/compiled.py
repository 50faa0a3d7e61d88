"""Compiled conic problems: build a cvxpy problem once per shape, re-solve with new data.

cvxpy canonicalizes a problem on every fresh ``solve()`` (tens of ms), while
Clarabel solves the small SDPs here in about a millisecond.  Every method
therefore builds its problem with :class:`cvxpy.Parameter` (DPP) once per
*shape* and keeps it in a bounded per-process LRU cache; re-solving only
maps new parameter values to the conic data.
"""

from __future__ import annotations

import os
import threading
import warnings
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable, Hashable

import numpy as np

from .errors import InvalidInput, SolverFailed


class _LazyCvxpy:
    """cvxpy, imported on first use.

    Importing cvxpy takes most of ``import solver``'s time (about 0.7 s of 1 s), and the default
    paths (the structured IPM for ``lmi``, ``switched`` and every bisection) never touch it.
    """

    def __getattr__(self, name):
        import cvxpy

        return getattr(cvxpy, name)


cp = _LazyCvxpy()

#: Solvers a user may pick.  "AUTO" (the default) is the fastest one that gives the same verdicts,
#: per problem (:func:`resolve_solver`).  "IPM" is the structured interior-point solver
#: (solver/ipm.py) for the lmi, switched and ccl designs and the common fixed-gain certificate LMI;
#: the switched fixed-gain LMI falls back to Clarabel under both names.
#: "CLARABEL" (interior point through cvxpy) and "SCS" (first order) stay selectable.
SOLVERS = {"AUTO": "CLARABEL", "IPM": "CLARABEL", "CLARABEL": "CLARABEL", "SCS": "SCS"}  # cvxpy solver names

#: Largest CCL block side ``2 n n_drop`` that "AUTO" leaves to Clarabel when the default
#: ``ccl_start="feasibility"`` is asked for: the paper's example (n = 2, n_drop = 3) sits here, where
#: Clarabel takes a fraction of a second and its Step 1 reproduces the paper's gains (eq. 23/24).
#: Above it the IPM is 4x to 50x faster (docs/performance.md, "`ccl`").
CCL_FEASIBILITY_SIDE = 12


def resolve_solver(solver: str, problem: str, n_modes: int = 1, *, ccl_side: int | None = None,
                   ccl_start: str = "feasibility") -> str:
    """The solver that runs ``problem`` ("lmi", "switched", "common_lmi", "ccl", or any other) for ``solver``.

    "AUTO" picks the structured IPM for the lmi and switched designs (every decay-rate bisection step
    too) and the common fixed-gain LMI, where it was measured faster with identical verdicts
    (bench/ipm_check.py, docs/performance.md).  For ``ccl`` (block side ``ccl_side = 2 n n_drop``) it
    picks the IPM too, whose Step 1 is always the min-trace start, except where the feasibility start
    is asked for and the problem is paper-sized (``ccl_side <= CCL_FEASIBILITY_SIDE``): there Clarabel
    runs, since a pure feasibility Step 1 has no unique answer and Clarabel's is the one that
    reproduces the paper's gains.  Clarabel runs everything else (the switched fixed-gain LMI).
    ``n_modes`` is kept for a size-dependent choice (none is needed today).
    """
    name = str(solver).upper()
    if name != "AUTO":
        return name
    if problem == "ccl":
        paper_sized = ccl_side is not None and ccl_side <= CCL_FEASIBILITY_SIDE
        return "CLARABEL" if ccl_start == "feasibility" and paper_sized else "IPM"
    return "IPM" if problem in ("lmi", "switched", "common_lmi") else "CLARABEL"

_ACCEPTED = ("optimal", "optimal_inaccurate")  # cp.OPTIMAL, cp.OPTIMAL_INACCURATE


#: Refuse SDPs whose interior-point KKT system would need more memory than this
#: (bytes; ``NCS_SOLVER_MAX_MEMORY`` overrides).  Clarabel keeps a dense
#: ``d x d`` block per PSD cone of side k, ``d = k (k + 1) / 2``: a CCL design with
#: n = 8, n_drop = 8 and 32 modes would need about 17 GB.
MAX_SOLVER_MEMORY = int(float(os.environ.get("NCS_SOLVER_MAX_MEMORY", 4 * 2**30)))


def check_memory(cone_sides, what: str) -> None:
    """Raise InvalidInput when PSD cones of these sides would not fit in :data:`MAX_SOLVER_MEMORY`."""
    need = sum(8 * (k * (k + 1) // 2) ** 2 for k in cone_sides)
    if need > MAX_SOLVER_MEMORY:
        raise InvalidInput(
            f"the {what} SDP would need about {need / 2**30:.1f} GiB of solver memory (limit "
            f"{MAX_SOLVER_MEMORY / 2**30:.1f} GiB): use fewer modes, a smaller n_drop or the lmi method",
            ("n_drop",),
        )


def check_solver(solver: str) -> str:
    name = str(solver).upper()
    if name not in SOLVERS:
        raise InvalidInput(f"solver must be one of {sorted(SOLVERS)}, got {solver!r}", ("solver",))
    return name


@dataclass
class SolveInfo:
    """What one conic solve reported.

    Attributes
    ----------
    status : str
        cvxpy status string (``"optimal"``, ``"optimal_inaccurate"``, ...).
    solver : str
        Solver name.
    solve_time : float
        The solver's own reported solve time (s).
    wall_time : float
        Wall time of the whole re-solve through cvxpy (s).
    objective : float
    iterations : int or None
        Solver iterations.
    """

    status: str
    solver: str
    solve_time: float
    wall_time: float
    objective: float
    iterations: int | None


class CompiledProblem:
    """A DPP cvxpy problem with named parameters and variables.

    Parameters
    ----------
    problem : cvxpy.Problem
    parameters : dict of str -> cvxpy.Parameter
    variables : dict of str -> cvxpy.Variable or list of them
    """

    def __init__(self, problem: cp.Problem, parameters: dict, variables: dict):
        if not problem.is_dcp(dpp=True):
            raise AssertionError("compiled problems must be DPP")
        self.problem = problem
        self.parameters = parameters
        self.variables = variables
        self.n_solves = 0
        self._lock = threading.Lock()

    def solve(self, values: dict, solver: str = "CLARABEL", time_limit: float | None = None) -> SolveInfo:
        """Set parameter values, solve, and return solver facts.

        Parameters
        ----------
        values : dict
            ``name -> ndarray`` for every parameter.
        solver : {"AUTO", "IPM", "CLARABEL", "SCS"}
            The first two run Clarabel here (the structured IPM has its own entry points).
        time_limit : float, optional
            Seconds the solver may take.

        Raises
        ------
        SolverFailed
            When the solver errors out or ends without an optimal (or
            optimal-inaccurate) answer.  Every problem built here is feasible
            and bounded by construction, so any other status is a failure of
            the solver, not a property of the plant.
        """
        name = check_solver(solver)
        opts: dict = {}
        if name == "SCS":
            opts.update(eps_abs=1e-7, eps_rel=1e-7, max_iters=200_000)
            if time_limit is not None:
                opts["time_limit_secs"] = float(time_limit)
        elif time_limit is not None:
            opts["time_limit"] = float(time_limit)
        with self._lock:
            for key, value in values.items():
                self.parameters[key].value = value
            start = time.perf_counter()
            try:
                with warnings.catch_warnings():
                    # cvxpy warns on inaccurate solutions; the status is returned and acted on instead.
                    warnings.simplefilter("ignore", UserWarning)
                    # warm_start=False: cvxpy would otherwise hand Clarabel the previous
                    # solver object to update, and the answer would depend on what this
                    # problem solved before, not only on the data.
                    self.problem.solve(solver=SOLVERS[name], warm_start=False, **opts)
            except cp.error.SolverError as err:
                raise SolverFailed(f"{name} failed: {err}", status="solver_error") from err
            wall = time.perf_counter() - start
            self.n_solves += 1
            status = self.problem.status
            stats = self.problem.solver_stats
            info = SolveInfo(
                status=status,
                solver="CLARABEL" if name in ("IPM", "AUTO") else name,  # their fallback
                solve_time=float(stats.solve_time) if stats and stats.solve_time is not None else float("nan"),
                wall_time=wall,
                objective=float(self.problem.value) if self.problem.value is not None else float("nan"),
                iterations=stats.num_iters if stats else None,
            )
        if status not in _ACCEPTED:
            raise SolverFailed(f"{name} ended with status {status!r}", status=status)
        return info

    def duals(self, name: str) -> np.ndarray:
        """Dual values of a list of PSD constraints stored under ``name`` in ``variables``, stacked."""
        return np.stack([np.array(c.dual_value, dtype=np.float64) for c in self.variables[name]])

    def value(self, name: str):
        var = self.variables[name]
        if isinstance(var, list):
            return [np.array(v.value, dtype=np.float64) for v in var]
        return np.array(var.value, dtype=np.float64)


class ProblemCache:
    """Bounded LRU cache of compiled problems, keyed by shape (one per process).

    Parameters
    ----------
    maxsize : int
        Number of compiled problems kept; the least recently used is dropped.
    """

    def __init__(self, maxsize: int = 32):
        self.maxsize = maxsize
        self._items: OrderedDict[Hashable, CompiledProblem] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def get(self, key: Hashable, build: Callable[[], CompiledProblem]) -> tuple[CompiledProblem, bool]:
        """Return ``(problem, was_cached)``, building and storing it on a miss."""
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                self.hits += 1
                return self._items[key], True
        compiled = build()
        with self._lock:
            self.misses += 1
            self._items[key] = compiled
            self._items.move_to_end(key)
            while len(self._items) > self.maxsize:
                self._items.popitem(last=False)
        return compiled, False

    def clear(self) -> None:
        with self._lock:
            self._items.clear()

    def __len__(self) -> int:
        return len(self._items)

    def keys(self) -> list:
        with self._lock:
            return list(self._items)


#: The process-wide cache every method uses (each worker process has its own);
#: ``NCS_PROBLEM_CACHE_SIZE`` sets its bound.
problem_cache = ProblemCache(maxsize=max(1, int(os.environ.get("NCS_PROBLEM_CACHE_SIZE", "32"))))


@dataclass
class DesignSdpSolution:
    """One solve of a design SDP in the congruent form (the interface every conic backend meets).

    The SDP is ``max t`` subject to the normalization (``trace W = n`` for ``lmi``,
    ``trace(Z + Z^T) = 2 n`` for ``switched``) and one block constraint
    ``block_b - t I >= 0`` (side 2n) per mode (``lmi``, b = s) or per pair of modes
    (``switched``, b = s * S + u).  The data of mode s are ``free_s`` and ``coef_s``
    already multiplied by ``c_s = lambda^(-eta_s)``, so no block carries a decay factor.

    Attributes
    ----------
    t : float
        Optimal margin t*.
    W : ndarray, shape (n, n)
        ``lmi``: W (symmetric); ``switched``: the common slack Z (not symmetric).
    Y : ndarray, shape (J, m, n)
        ``Y_j = Theta_j W`` (``Theta_j Z``), the scheme's free gains times W (Z).
    S : ndarray, shape (S, n, n), or None
        ``switched``: the mode matrices ``S_s`` (certificate ``P_s = S_s^{-1}``).
    duals : ndarray, shape (B, 2n, 2n)
        PSD dual matrix of each block constraint, in block order, as cvxpy returns
        them: for ``max t`` with the ``t I`` term, ``sum_b trace(duals_b) = 1``, and
        ``sum_b <duals_b, block_b(W, Y)> = t* `` at the optimum.
    info : SolveInfo
    """

    t: float
    W: np.ndarray
    Y: np.ndarray
    S: np.ndarray | None
    duals: np.ndarray
    info: SolveInfo


def schur_block(top_left, lower_left, bottom_right) -> cp.Expression:
    """The symmetric block matrix ``[[top_left, lower_left^T], [lower_left, bottom_right]]``.

    cvxpy's ``>>`` silently symmetrizes its argument, so an asymmetric block
    would be a wrong constraint rather than an error: every LMI here is built
    through this one function, which transposes the same expression.
    """
    return cp.bmat([[top_left, lower_left.T], [lower_left, bottom_right]])


def block(stacked: cp.Expression, index: int, rows: int) -> cp.Expression:
    """Row block ``index`` (``rows`` rows) of a vertically stacked parameter."""
    return stacked[index * rows:(index + 1) * rows, :]
