"""Compiled conic problems: build a cvxpy problem once per shape, re-solve with new data.

cvxpy canonicalizes a problem on every fresh ``solve()`` (tens of ms), while
Clarabel solves the small SDPs here in about a millisecond.  Every method
therefore builds its problem with :class:`cvxpy.Parameter` (DPP) once per
*shape* and keeps it in a bounded per-process LRU cache; re-solving only
maps new parameter values to the conic data.
"""

from __future__ import annotations

import math
import os
import threading
import warnings
import time
from dataclasses import dataclass

import numpy as np

from .errors import InvalidInput, SolverFailed
from .memo import BoundedCache


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
#: (solver/ipm/) for the lmi, switched and ccl designs and the common fixed-gain certificate LMI;
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


def ipm_memory(n_full: int, p: int, n_blocks: int, side: int, largest_variable: int) -> int:
    """Bytes the structured IPM (solver/ipm/) needs at its peak, estimated from its arrays.

    The Schur matrix in the reduced coordinates with its Cholesky copy (and the copy that removes an
    eliminated coordinate: ``3 p^2``), the Kronecker pieces of the largest variable (its diagonal
    block's ``dsyr2k`` result, the packed one and their gather positions, or the selection path's
    full-coordinate blocks: up to ``3 v^2``; its pair with the other variables, ``v (n_full - v)``) and about
    30 block-diagonal iterates of ``n_blocks`` blocks of side ``side``, with a quarter more for the
    heap's fragmentation (:func:`solver.ipm.heap_reuse`).  Measured at n = 50, r = 5, n_drop = 10
    (lmi): estimate 0.48 GiB, traced peak 0.29 GiB, peak resident set 0.40 GB with the interpreter.
    """
    v = min(largest_variable, n_full)
    return 10 * (3 * p**2 + 3 * v**2 + v * (n_full - v) + 30 * n_blocks * side**2)


#: Clarabel through cvxpy at its peak: the canonicalized problem holds the same per-block pieces as the
#: structured IPM's Schur pieces, about three times over with the solver's copies (tracemalloc peaks of the
#: cart-pole's lmi design at n_drop = 20, 40, 60: 18, 56, 115 MiB against 23, 52, 118 MiB from this).
CVXPY_MEMORY_FACTOR = 3.0
CVXPY_MEMORY_FIXED = 16 * 2**20


def clarabel_kkt_bytes(cone_sides) -> int:
    """Bytes of Clarabel's KKT system for PSD cones of sides ``cone_sides`` (one dense block per cone)."""
    return sum(8 * (k * (k + 1) // 2) ** 2 for k in cone_sides)


def check_memory(cone_sides, what: str, ipm_bytes: int | None = None) -> None:
    """Raise InvalidInput when the solver's memory would exceed :data:`MAX_SOLVER_MEMORY`.

    ``ipm_bytes``: the structured IPM runs (its own estimate, :func:`ipm_memory`); otherwise
    Clarabel's KKT system for PSD cones of sides ``cone_sides``.
    """
    need = ipm_bytes if ipm_bytes is not None else clarabel_kkt_bytes(cone_sides)
    if need > MAX_SOLVER_MEMORY:
        raise InvalidInput(
            f"the {what} SDP would need about {need / 2**30:.1f} GiB of solver memory (limit "
            f"{MAX_SOLVER_MEMORY / 2**30:.1f} GiB): use fewer modes, a smaller n_drop or the lmi method",
            ("n_drop",),
        )


#: Refuse designs whose estimated solver time is above this (seconds; ``NCS_SOLVER_MAX_SECONDS``
#: overrides; a ``time_limit`` given to :func:`solver.design` replaces it).  The default is the
#: service's job time limit (``NCS_JOB_TIME_LIMIT``).
MAX_SOLVER_SECONDS = float(os.environ.get("NCS_SOLVER_MAX_SECONDS", 300.0))


def time_left(time_limit: float | None, start: float, floor: float | None = None) -> float | None:
    """What is left of ``time_limit`` since ``start``: the time limit of the next step of a run.

    Parameters
    ----------
    time_limit : float or None
        The run's limit (seconds); None: no limit.
    start : float
        The run's start, a :func:`time.perf_counter` reading (seconds).
    floor : float, optional
        The least value returned (seconds), for a solver that needs a positive limit.  None: the plain rest,
        which is ``<= 0`` once the run is out of time (callers that stop then must not pass a floor).

    Returns
    -------
    float or None
        Seconds left (None without a limit).
    """
    if time_limit is None:
        return None
    left = time_limit - (time.perf_counter() - start)
    return left if floor is None else max(left, floor)


def out_of_time(seconds_left) -> bool:
    """Whether a run's time is up: ``seconds_left`` is ``() -> seconds or None`` (None: no limit), e.g.
    :meth:`solver.methods.common.RunClock.countdown`'s; None itself means no limit.  Steps that cannot be cut
    short (an exact elimination) ask it before they start."""
    remaining = None if seconds_left is None else seconds_left()
    return remaining is not None and remaining <= 0



def solve_quietly(problem, solver: str = "CLARABEL", time_limit: float | None = None) -> None:
    """``problem.solve`` on ``solver`` (a cvxpy solver name) within ``time_limit`` seconds, without cvxpy's
    "Solution may be inaccurate" warning: every answer is a proposal the callers re-check, and the status is theirs
    to act on, so the warning only reached the user's terminal.  Raises ``cvxpy.error.SolverError`` as cvxpy does."""
    opts = {} if time_limit is None else {"time_limit": float(max(time_limit, 1e-3))}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        problem.solve(solver=getattr(cp, solver), **opts)

#: The time estimate of :func:`design_size` (docs/design.md §3.6): the path's Newton steps times one step's work,
#: plus the bracket's lower-bound search.  One interior-point step (:func:`_step_seconds`) costs ``2 v^2`` per block
#: touching v variables for the Schur pieces (at ``ESTIMATE_ASSEMBLY_FLOPS_PER_SECOND``), ``k^3`` per block of side
#: k for its products and factorizations (at ``ESTIMATE_BLOCK_FLOPS_PER_SIDE`` per unit of k: rank-k work, at most
#: the BLAS rate), ``p^3 / 3`` for the Schur complement's Cholesky factor (at ``ESTIMATE_FLOPS_PER_SECOND``, LAPACK's
#: rate on this machine, measured, not fitted), ``ESTIMATE_SECONDS_PER_BLOCK`` per block (the batched small calls)
#: and ``ESTIMATE_SECONDS_PER_STEP``.  A solve takes ``I ln(1 + nu)`` steps, ``nu`` the LMI's total side (the
#: barrier parameter: a predictor-corrector's steps grow like ``log(nu / eps)``; measured 10, 15, 22, 21, 24 plain
#: steps at nu = 36, 160, 800, 1200, 10000), ``I`` the path's :data:`ESTIMATE_PATH_ITERATIONS`.  A request adds the
#: lower-bound search (cost, hinf: :func:`lower_bound_work`'s flops at ``ESTIMATE_SEARCH_FLOPS_PER_SECOND`` plus
#: ``ESTIMATE_SEARCH_SECONDS``), ``ESTIMATE_SECONDS_PER_MODE`` per closed-loop mode (building the modes, the float64
#: re-checks) and ``ESTIMATE_SECONDS_FIXED``.  Fitted by ``python -m bench size`` in three least-squares problems
#: on log CPU time (the per-step constants on the measured Newton steps, the search's on its own CPU, the paths'
#: steps and the rest on the whole request), 45 designs, 2026-11-27, the 2-core development machine loaded by other
#: jobs, one BLAS thread; refit after a change to the IPM or the search (``python -m bench size``).
ESTIMATE_FLOPS_PER_SECOND = 2e10
ESTIMATE_ASSEMBLY_FLOPS_PER_SECOND = 3.64e9
ESTIMATE_BLOCK_FLOPS_PER_SIDE = 4.71e6
ESTIMATE_SECONDS_PER_BLOCK = 3.72e-5
ESTIMATE_SECONDS_PER_STEP = 7.7e-7
ESTIMATE_SECONDS_PER_MODE = 4.93e-6
ESTIMATE_SECONDS_FIXED = 5.66e-6
#: Newton steps per structural solve (:func:`request_solves`) and unit of ``ln(1 + nu)``, per path
#: (:func:`design_path`; "plain" is one cold solve): a bisection's probes stop early and the rate path moves between
#: steps (``"auto"``, ``"max"``: 12 structural solves, 60-110 steps measured); a performance design runs a phase 1,
#: a phase 2 and (u_max: three runs, 110-190 steps) a tie-break stage on its own blocks.
ESTIMATE_PATH_ITERATIONS = {"plain": 3.96, "rate": 3.96, "auto": 0.907, "max": 0.621, "cost": 4.06, "hinf": 5.36,
                            "u_max": 17.1, "switched": 2.82, "ccl": 34.0, "network": 56.8}
#: The lower-bound search of a bracket (solver/brackets.py ``lower_bound``): its flops
#: (:func:`lower_bound_work`) at this rate, plus a fixed part per kind (the scalar searches, the re-evaluations).
ESTIMATE_SEARCH_FLOPS_PER_SECOND = {"cost": 6.63e10, "hinf": 1.39e11}
ESTIMATE_SEARCH_SECONDS = {"cost": 0.098, "hinf": 0.0187}
#: Paths :func:`design_size` knows (the keys of :data:`ESTIMATE_PATH_ITERATIONS`).
DESIGN_PATHS = tuple(ESTIMATE_PATH_ITERATIONS)


def design_path(method: str = "lmi", objective: str = "stability", decay_rate=None, u_max=None,
                network=None) -> str:
    """The estimate's name for a request's path: "plain", "rate" (a given decay rate), "auto", "max", "cost",
    "hinf", "u_max", "switched", "ccl" or "network" (a network other than bounded drops)."""
    if network is not None and not getattr(network, "is_bounded_drops", False):
        return "network"
    if objective in ("cost", "hinf"):
        return objective
    if u_max is not None and u_max is not False:
        return "u_max"
    if method in ("switched", "ccl"):
        return method
    if decay_rate in ("auto", "max"):
        return decay_rate
    return "plain" if decay_rate is None else "rate"


def request_solves(method: str, decay_rate, rate_tol: float = 1e-3, objective: str = "stability",
                   u_max=None) -> int:
    """How many SDPs a design solves at least, structurally (a decay-rate bisection counts its steps).

    ``ccl`` counts Step 1 and one iteration, not ``max_iter``: how many iterations it takes is not known
    before it runs, and the time limit (``time_limit``, the service's job time limit) stops it if needed.
    A performance design (``objective`` or ``u_max``) runs at a given rate or none ("auto" is plain there).
    """
    if method == "ccl":
        return 2
    if objective != "stability" or (u_max is not None and u_max is not False):
        return 1
    if decay_rate in ("max", "auto"):
        return int(np.ceil(np.log2(1.0 / float(rate_tol)))) + 2
    return 1


def _step_seconds(blocks, p: int) -> float:
    """Seconds of one interior-point step for ``blocks`` = [(side k, variables touched v, count)] and p variables:
    the Schur pieces (``2 v^2`` per block), the per-block products and factorizations (``k^3``), the Schur
    complement's factorization (``p^3 / 3``), each at its own rate, and the per-block and per-step overheads."""
    pieces = products = 0.0
    n_blocks = 0
    for k, v, count in blocks:
        count = float(min(count, 10**300))  # per-sample counts can be astronomical
        pieces += min(count * 2.0 * float(v) ** 2, 1e300)
        # small blocks run far below the BLAS rate: rank-k work, ESTIMATE_BLOCK_FLOPS_PER_SIDE per unit of k
        rate = min(ESTIMATE_FLOPS_PER_SECOND, ESTIMATE_BLOCK_FLOPS_PER_SIDE * k)
        products += min(count * float(k) ** 3 / rate, 1e300)
        n_blocks += count
    seconds = (pieces / ESTIMATE_ASSEMBLY_FLOPS_PER_SECOND + products
               + float(min(p, 10**100)) ** 3 / 3 / ESTIMATE_FLOPS_PER_SECOND)
    return float(min(seconds + min(n_blocks, 1e300) * ESTIMATE_SECONDS_PER_BLOCK + ESTIMATE_SECONDS_PER_STEP, 1e300))


def lower_bound_work(kind: str, n: int, n_modes: int, n_drop: int, n_disturbances: int = 1,
                     n_outputs: int = 1) -> tuple[float, float]:
    """``(flops, bytes)`` of a bracket's lower-bound search (docs/design.md §8.4) from the sizes alone.

    Counted as solver/brackets.py's ``lower_bound`` runs it (its constants are read from there): ``S`` loop modes,
    ``P`` periodic patterns of up to ``L`` intervals (as many as fit ``MAX_PATTERNS``, or ``MAX_PATTERNS_HINF``).

    * cost: the patterns' products and Stein doublings (about ``(6 L + 60) n^3`` each), the two-run search
      (``c (c - 1)`` mode pairs, ``c = min(S, RUN_MODES)``, ``RUN_LENGTH^2`` patterns of ``70 n^3`` each) and the
      prefix search (``NODE_BUDGET min(1, (8 / n)^3)`` nodes of ``4 n^3 + 2 (TAILS + STEERED_TAILS) n^2``); memory:
      the stacked doublings (``6 P n^2`` numbers) and the prefix search's moments (``beam S n^2`` numbers, ``beam``
      capped at ``2e6 / (S n^2)`` in code: 16 MB per depth), four copies each;
    * hinf: per pattern a frequency sweep (``SWEEP`` points of ``11 n^3 + 16 n^2 w + 8 n w^2`` flops, complex,
      ``w = L n_drop min(p_w, p_z)`` the smaller side of the lifted period) and its eigenvalue bound
      (``40 n^3``), for the exhaustive patterns and the grown ones (``GROW_BUDGET min(1, (4 / n)^3)`` pattern
      intervals, periods up to ``GROW_LENGTH``); memory: the stacked period systems (``P (L r (L q + n) + n^2)``
      numbers, ``r = n_drop p_z``, ``q = n_drop p_w``, three copies) and one sweep step (``CHUNK`` patterns x
      frequencies of ``3 (n^2 + n w + w^2)`` complex numbers, at most ``periodic.STEP_BYTES``).
    """
    from . import brackets, periodic

    n, N = float(n), int(n_drop)
    if int(n_modes) < 1:
        return 0.0, 0.0
    # the pattern counts saturate at their cap (<= 4000) long before S = 1e6; the memory's S is a float (per-sample
    # mode counts can be astronomical)
    S, S_mem = min(int(n_modes), 10**6), float(min(int(n_modes), 10**300))
    cost = kind == "cost"
    cap = brackets.MAX_PATTERNS if cost else brackets.MAX_PATTERNS_HINF
    L, total = brackets.PATTERN_LENGTH, sum(float(S) ** k for k in range(1, brackets.PATTERN_LENGTH + 1))
    while L < brackets.MAX_PATTERN_LENGTH and total + float(S) ** (L + 1) <= cap:
        L += 1
        total += float(S) ** L
    P = min(float(cap), total if cost else total / 2 + S)  # hinf: one pattern per rotation class (about half)
    # the longest period actually valued: the exhaustive patterns stop where the count does
    L_used = next((k for k in range(1, L + 1) if sum(float(S) ** j for j in range(1, k + 1)) >= P), L)
    if cost:
        c = min(S, brackets.RUN_MODES)
        runs = c * (c - 1) * brackets.RUN_LENGTH**2 if c >= 2 else 0
        nodes = brackets.NODE_BUDGET * min(1.0, (8.0 / n) ** 3)
        tails = brackets.TAILS + brackets.STEERED_TAILS
        flops = (P * (6 * L_used + 60) + runs * 70) * n**3 + nodes * (4 * n**3 + 2 * tails * n**2)
        beam = min(brackets.BEAM, max(8, 2e6 // max(S_mem * n * n, 1.0)))
        memory = 8 * 4 * max(6 * P * n * n, runs / max(c * (c - 1), 1) * 8 * n * n, min(beam * S_mem * n * n, 1e300))
        return float(flops), float(min(memory, 1e300))
    q, r = N * int(n_disturbances), N * int(n_outputs)
    grow_budget = max(brackets.GROW_BUDGET * min(1.0, (4.0 / n) ** 3), 1.0)
    L_grow, work, level = L_used, 0.0, brackets.GROW_BEAM * S
    while work < grow_budget and L_grow < brackets.GROW_LENGTH:
        L_grow += 1
        work += level * L_grow
    grown = min(work, grow_budget) / max(L_grow, 1)  # patterns valued by the growth (about)
    L_max = max(L_used, L_grow if S > 1 else L_used)

    def sweep(length):
        w = length * min(q, r)
        return brackets.SWEEP * 4 * (11 * n**3 + 16 * n * n * w + 8 * n * w * w) + 160 * n**3

    flops = P * sweep(L_used) + grown * sweep(L_grow) + brackets.REFINED * 40 * (n + 3) * sweep(L_max) / brackets.SWEEP
    w_max = L_max * min(q, r)
    chunk = min(periodic.CHUNK, (periodic.CHUNK // brackets.SWEEP) * brackets.SWEEP)
    per = 16 * 3 * (n * n + n * w_max + w_max * w_max)  # one pattern at one frequency
    step = min(chunk * per, max(periodic.STEP_BYTES, brackets.SWEEP * per))  # at least one pattern's sweep
    memory = 8 * 3 * max(P * (L_used * r * (L_used * q + n) + n * n), grown * (L_grow * r * (L_grow * q + n))) + step
    return float(flops), float(memory)


@dataclass(frozen=True)
class DesignSize:
    """The size of a design's SDP and the estimated cost of the whole request (:func:`design_size`).

    Attributes
    ----------
    method : str
    n_modes : int
        Interval closed-loop modes (l, eta), or plant sequences per sample.
    lmi_size : int
        Sum of the sides of all matrix inequalities (the service's ``NCS_MAX_LMI_SIZE``).
    n_variables : int
        Scalar decision variables.
    memory : float
        Estimated peak solver memory (bytes): the larger of the structured IPM's
        (a ``v_b x v_b`` Schur piece per block, ``v_b`` the variables block b touches, plus the
        dense ``p x p`` Schur complement) and a general conic solver's (a dense
        ``(k(k+1)/2)^2`` scaling per PSD cone of side k); cost and hinf: at least the bracket's lower-bound
        search's (:func:`lower_bound_work`).
    seconds : float
        Estimated CPU time of one cold solve of the path's SDP (s): ``ESTIMATE_PATH_ITERATIONS["plain"] ln(1 +
        lmi_size)`` interior-point steps (Schur assembly and factorizations at the calibrated rates,
        :func:`_step_seconds`).
    path : str
        The request's path (:func:`design_path`): "plain", "rate", "auto", "max", "cost", "hinf", "u_max",
        "switched", "ccl" or "network".
    solves : int
        SDPs the path solves at least (:func:`request_solves`; a decay-rate bisection about 12).
    total_seconds : float
        Estimated CPU time of the whole request (s): the path's Newton steps (:data:`ESTIMATE_PATH_ITERATIONS`
        per solve), the bracket's lower-bound search (:attr:`search_seconds`), the per-mode work (building the
        modes, re-checks) and a fixed part.
    """

    method: str
    n_modes: int
    lmi_size: int
    n_variables: int
    memory: float
    seconds: float
    #: Automaton nodes of a network design (None for the paper's network).
    nodes: int | None = None
    #: Side of the Lyapunov matrices of a network design (n, or n n_drop on the augmented state).
    state_size: int | None = None
    #: n, and the variables of the Lyapunov matrix (n (n + 1) / 2) and of the gains (J m n): which of the two
    #: dominates says whether the states or n_drop make the design large (0: not known).
    n_states: int = 0
    lyapunov_variables: int = 0
    gain_variables: int = 0
    path: str = "plain"
    solves: int = 1
    total_seconds: float = 0.0
    #: The interval length n_drop (0: not known).
    n_drop: int = 0
    #: A design for a channel: the analysis's operator size and its share of the time and memory estimates.
    channel_size: int = 0
    channel_seconds: float = 0.0
    channel_memory: float = 0.0
    #: Entries of the per-block Schur pieces, ``sum_b v_b^2`` (``v_b`` the variables block b touches): the
    #: assembly's work per iteration is the block side times this.
    schur_entries: float = 0.0
    #: The bracket's lower-bound search (cost, hinf: :func:`lower_bound_work`), part of :attr:`total_seconds`.
    search_seconds: float = 0.0
    #: One interior-point step of the path's SDP (:func:`_step_seconds`).
    step_seconds: float = 0.0

    def _dimension(self, over: str = "") -> tuple[str, tuple]:
        """The hint and the field of the dimension that makes this design large (``over``: "memory" or "time")."""
        if self.channel_size and (self.channel_memory >= self.memory / 2 if over == "memory"
                                  else self.channel_seconds >= self.total_seconds / 2):
            return (f"the channel analysis (its operator of size up to {self.channel_size}) makes it large: use "
                    "a channel with fewer states, a smaller n_drop or fewer plant modes", ("channel",))
        # ccl's Lyapunov matrices live on the augmented state (n n_drop): there n_drop makes them large too.
        if self.n_states and self.method != "ccl" and self.lyapunov_variables > self.gain_variables:
            return (f"the {self.n_states} states make it large (the Lyapunov matrix alone has "
                    f"{self.lyapunov_variables} variables): reduce the model's order (e.g. a balanced truncation) or "
                    "design for fewer states", ("F",))
        drop = f"n_drop = {self.n_drop} makes it large: " if self.n_drop and self.n_states else ""
        hint = drop + "use a smaller n_drop or fewer plant modes" + ("" if self.method == "lmi" else
                                                                     ", or the lmi method")
        return hint, ("n_drop",)

    def check(self, max_memory: float | None = None, max_seconds: float | None = None, *, solves: int | None = None,
              memory_name: str = "NCS_SOLVER_MAX_MEMORY or max_memory=",
              seconds_name: str = "NCS_SOLVER_MAX_SECONDS, or give a time_limit") -> None:
        """Raise InvalidInput (the field of the dimension that makes it large) when the estimate is over a budget.

        ``max_memory`` (bytes) and ``max_seconds`` default to :data:`MAX_SOLVER_MEMORY` and
        :data:`MAX_SOLVER_SECONDS`; ``inf`` (or 0 for memory, like ``NCS_WORKER_MEMORY_MB``) turns a
        check off.  The time is the whole request's (:attr:`total_seconds`); ``solves`` given: that many
        cold solves of :attr:`seconds` instead (an analysis's certificate SDPs).
        """
        max_memory = MAX_SOLVER_MEMORY if max_memory is None else max_memory
        max_seconds = MAX_SOLVER_SECONDS if max_seconds is None else max_seconds
        states = f"{self.n_states} states, " if self.n_states else ""
        drop = f"n_drop = {self.n_drop}, " if self.n_drop else ""
        path = "" if self.path in ("plain", "rate", self.method) else f"{self.path} path, "
        what = (f"the {self.method} design ({path}{states}{drop}{self.n_modes} closed-loop modes, LMI size "
                f"{self.lmi_size}, {self.n_variables} variables)")
        hint, field = self._dimension("memory" if max_memory and self.memory > max_memory else "time")
        if self.nodes is not None:
            what = (f"the network design ({self.nodes} automaton nodes, {self.n_modes} transitions x plant modes, "
                    f"state size {self.state_size}, LMI size {self.lmi_size}, {self.n_variables} variables)")
            hint, field = "use a network with fewer nodes, a smaller n_drop or fewer plant modes", ("n_drop",)
        if max_memory and self.memory > max_memory:
            raise InvalidInput(f"{what} would need about {_bytes(self.memory)} of solver memory, over the limit "
                               f"of {_bytes(max_memory)} ({memory_name}): {hint}", field)
        if solves is None:
            seconds, count = self.total_seconds or self.seconds * self.solves, self.solves
        else:
            seconds, count = self.seconds * solves, solves
        if seconds > max_seconds:
            runs = "" if count == 1 else f" ({count} solves)"
            raise InvalidInput(f"{what} would take about {seconds:.3g} s{runs}, over the limit of "
                               f"{max_seconds:g} s ({seconds_name}): {hint}", field)


def _bytes(x: float) -> str:
    return f"{x / 2**30:.3g} GiB" if x >= 2**30 else f"{x / 2**20:.3g} MiB"


def _steps(path: str, lmi_size: float, solves: int = 1) -> float:
    """Newton steps of ``solves`` structural solves of ``path`` on an LMI of total side ``lmi_size``."""
    return ESTIMATE_PATH_ITERATIONS.get(path, ESTIMATE_PATH_ITERATIONS["plain"]) * solves * math.log1p(lmi_size)


def _total(path: str, step: float, solves: int, n_modes: int, lmi_size: float, search_seconds: float = 0.0) -> float:
    """The whole request's CPU estimate from one interior-point step's (:func:`_step_seconds`): the path's
    Newton steps (:func:`_steps`), the lower-bound search, the per-mode work and the fixed part."""
    return float(min(_steps(path, lmi_size, solves) * step + search_seconds
                     + ESTIMATE_SECONDS_PER_MODE * min(n_modes, 10**300) + ESTIMATE_SECONDS_FIXED, 1e300))


def design_size(method: str, n_states: int, n_inputs: int, n_plants: int, n_drop: int,
                plant_switching: str = "per_interval", scheme: str = "predictive",
                solver: str = "AUTO", network=None, *, objective: str = "stability", decay_rate=None,
                rate_tol: float = 1e-3, u_max=None, n_disturbances: int = 1, n_outputs: int | None = None,
                channel_size: int = 0) -> DesignSize:
    """Size and estimated cost of a design request, from its dimensions alone (no arrays are built).

    The one estimate behind the library's refusal (:func:`solver.design`, :func:`solver.analyze`) and the
    service's limits (``NCS_MAX_LMI_SIZE``, ``NCS_WORKER_MEMORY_MB``, ``NCS_JOB_TIME_LIMIT``), for every path:
    plain, a given rate, ``decay_rate="auto"``/``"max"`` (a bisection), the cost, H-infinity and input-limited
    designs (their blocks as the IPM builds them, docs/design.md §3.6: compact lifted blocks of side
    ``2n + min(eta (n + m), n + min(eta, J) m)`` (cost) and ``2n + eta p_w + min(eta p_z, n + min(eta, J) m + (eta - 1)
    p_w)`` (hinf) merged into groups; the input blocks ``n + 1``; the bracket's lower-bound search), switched, ccl,
    and a network (:func:`network_design_size`; ``n_drop`` is then the network's).
    ``n_drop`` is the interval length of a design for a channel too (:func:`solver.design_for_channel`).

    Parameters
    ----------
    method, n_states, n_inputs, n_plants, n_drop, plant_switching, scheme
        As :func:`solver.design` (``n_plants``: the family's modes r).
    solver : str
        ``"AUTO"``/``"IPM"``: the memory is the structured IPM's (Schur pieces per block and the Schur
        complement); a general conic solver (``"CLARABEL"``, ``"SCS"``): also its dense scaling per PSD cone.
    network : solver.Network, optional
    objective, decay_rate, rate_tol, u_max
        The request's (``u_max``: anything not None asks for input limits).
    n_disturbances, n_outputs : int
        ``p_w`` and ``p_z`` of an H-infinity design (default ``p_z = n + m``, ``z = [x; u]``).
    channel_size : int
        A design for a channel analyzes the designed loop on it: the second-moment operator's size
        (:func:`solver.workload.channel_operator_size`), whose time and memory
        (:func:`solver.workload.channel_estimate`) are added.

    Returns
    -------
    DesignSize
        ``seconds`` one cold solve, ``total_seconds`` the whole request (calibrated by
        ``python -m bench size``), ``memory`` the peak solver memory (bytes).
    """
    path = design_path(method, objective, decay_rate, u_max, network)
    solves = request_solves(method, decay_rate, rate_tol, objective, u_max)
    if path == "network" and (objective in ("cost", "hinf") or (u_max is not None and u_max is not False)):
        return network_performance_size(network, n_states, n_inputs, n_plants, plant_switching, solver,
                                        objective=objective, u_max=u_max, n_disturbances=n_disturbances,
                                        n_outputs=n_outputs)
    if path == "network":
        return network_design_size(network, n_states, n_inputs, n_plants, plant_switching, solver,
                                   path=path, solves=solves)
    n, m, r, N = int(n_states), int(n_inputs), int(n_plants), int(n_drop)
    J = N if scheme == "predictive" else 1
    sym = n * (n + 1) // 2
    # (interval length, number of modes of that length)
    lengths = [(eta, r if plant_switching == "per_interval" else r**eta) for eta in range(1, N + 1)]
    S = sum(count for _, count in lengths)
    k = 2 * n
    if method == "switched":
        p = n * n + S * sym + J * m * n + 1
        blocks = [(k, n * n + 2 * sym + min(eta, J) * m * n + 1, count * S) for eta, count in lengths]
        sides = [(k, S * S)]
        lmi = k * S * S
    elif method == "ccl":
        k = 2 * n * N
        p = 2 * (n * N) * (n * N + 1) // 2 + J * m * n + 1
        blocks = [(k, p, S + 1)]
        sides = [(k, S + 1)]
        lmi = k * (S + 1)
    elif path in ("cost", "hinf", "u_max"):
        # solver/ipm/performance_blocks.py: the compact lifted blocks, of side 2n + min(eta (n + m), n + g m) for the
        # cost and 2n + eta p_w + min(eta p_z, n + g m + (eta - 1) p_w) for hinf (g = min(eta, J) gains; the tail
        # rows reduced to the triangular factor of their nonzero columns, docs/design.md §8.3.1), the lengths whose
        # sides are within MERGE_RATIO of their group's smallest in one group padded to its largest side, every
        # block touching W, the gains and the scalars; u_max: the stability blocks (2n) and the ball (n); the cost:
        # the Z block (2n); then the input blocks (n + 1)
        from .ipm.performance_blocks import MERGE_RATIO

        pw = int(n_disturbances)
        pz = n + m if n_outputs is None else int(n_outputs)
        side = {"cost": lambda e: 2 * n + min(e * (n + m), n + min(e, J) * m),
                "hinf": lambda e: 2 * n + e * pw + min(e * pz, n + min(e, J) * m + (e - 1) * pw),
                "u_max": lambda e: 2 * n}[path]
        p = sym + J * m * n + (sym + 1 if path == "cost" else 2)  # W, the gains, t; Z (cost), g or tau
        v = sym + J * m * n + 2
        groups = []  # [largest side, smallest side, count]
        for eta, count in lengths:
            k_e = side(eta)
            if groups and k_e <= MERGE_RATIO * groups[-1][1]:
                groups[-1][0], groups[-1][2] = max(groups[-1][0], k_e), groups[-1][2] + count
            else:
                groups.append([k_e, k_e, count])
        blocks = [(k_g, v, count) for k_g, _, count in groups]
        blocks += {"cost": [(2 * n, sym + sym, 1)], "hinf": [], "u_max": [(n, sym + 1, 1)]}[path]
        if u_max is not None and u_max is not False:
            blocks.append((n + 1, sym + n + 1, J * m))
        sides = [(side_b, count) for side_b, _, count in blocks]
        lmi = sum(side_b * count for side_b, count in sides)
    else:
        p = sym + J * m * n + 1
        blocks = [(k, sym + min(eta, J) * m * n + 1, count) for eta, count in lengths]
        sides = [(k, S)]
        lmi = k * S
    pieces = sum(count * v**2 for _, v, count in blocks)
    conic = sum(count * 8 * (side * (side + 1) // 2) ** 2 for side, count in sides)
    # + the iterates: about 30 block-diagonal copies of the blocks (X, S, their factors, directions; ipm_memory)
    structured = 8 * (pieces + p * p + 30 * sum(count * side * side for side, _, count in blocks))
    memory = structured if str(solver).upper() in ("AUTO", "IPM") else max(
        CVXPY_MEMORY_FACTOR * structured + CVXPY_MEMORY_FIXED, conic)
    search_seconds = 0.0
    if path in ("cost", "hinf"):  # the bracket's lower-bound search (solver/brackets.py lower_bound)
        flops, search_memory = lower_bound_work(path, n, S, N, n_disturbances,
                                                n + m if n_outputs is None else n_outputs)
        search_seconds = flops / ESTIMATE_SEARCH_FLOPS_PER_SECOND[path] + ESTIMATE_SEARCH_SECONDS[path]
        memory = max(memory, search_memory)
    memory = float(min(memory, 10**300))  # per-sample counts can be astronomical
    step = _step_seconds(blocks, p)
    lmi = min(lmi, 10**300)
    seconds = float(min(_steps("plain", lmi) * step, 1e300))
    total = _total(path, step, solves, S, lmi, search_seconds)
    channel_seconds = channel_memory = 0.0
    if channel_size:
        from .workload import channel_estimate

        channel_seconds, channel_memory = channel_estimate(channel_size)
        total, memory = total + channel_seconds, max(memory, channel_memory)
    return DesignSize(method, S, lmi, p, memory, seconds, n_states=n,
                      lyapunov_variables=(n * N) * (n * N + 1) if method == "ccl" else (S * sym if method == "switched"
                                                                                        else sym),
                      gain_variables=J * m * n, path=path, solves=solves, n_drop=N, total_seconds=total,
                      schur_entries=float(min(pieces, 1e300)), channel_size=int(channel_size),
                      search_seconds=search_seconds, step_seconds=step,
                      channel_seconds=channel_seconds, channel_memory=channel_memory)


def clarabel_fits(method: str, n_states: int, n_inputs: int, n_plants: int, n_drop: int,
                  plant_switching: str = "per_interval", scheme: str = "predictive", *,
                  max_memory: float | None = None, **request) -> bool:
    """Whether Clarabel (through cvxpy) fits the memory budget for this request: the one test behind every
    ``solver="AUTO"`` fallback from the structured IPM to Clarabel.

    The memory is :func:`design_size`'s with ``solver="CLARABEL"`` (cvxpy's copies, ``CVXPY_MEMORY_FACTOR``
    times the structured pieces, or Clarabel's dense KKT blocks, whichever is larger); the budget is
    ``max_memory`` (bytes; default :data:`MAX_SOLVER_MEMORY`, 0 or inf: no limit).  ``request``: the other
    keywords of :func:`design_size` (``objective``, ``u_max``, ``network``, ...).
    """
    budget = MAX_SOLVER_MEMORY if max_memory is None else max_memory
    if not budget:
        return True
    return design_size(method, n_states, n_inputs, n_plants, n_drop, plant_switching, scheme, solver="CLARABEL",
                       **request).memory <= budget


def network_design_size(network, n_states: int, n_inputs: int, n_plants: int,
                        plant_switching: str = "per_interval", solver: str = "AUTO", *, path: str = "network",
                        solves: int = 1) -> DesignSize:
    """Size of the network design (:mod:`solver.methods.network_lmi`), from the automaton's structure alone.

    Nodes x plant modes x the state the Lyapunov matrices live on: the lifted form (every packet that takes
    effect is fresh) has one block of side 2n per reception-to-reception path and plant mode and one n x n
    matrix per reception node; the augmented form one block of side ``2 n N`` per edge and plant mode and one
    ``n N x n N`` matrix per node.  Its cone complementarity fallback has twice the node matrices.  ``solves``: a
    decay-rate bisection's count (:func:`request_solves`).

    Memory: with ``solver`` "AUTO" or "IPM", the structured IPM's (:func:`ipm_memory` of the network LMI's
    :mod:`solver.ipm.network_blocks` model: the node matrices are one stacked variable of ``V k^2`` entries
    whose selection-path Schur pieces are full-coordinate blocks, plus ``2 nb k^4`` per-block products; measured
    traced peaks 10-290 MiB were 0.85-1.2 of this); otherwise the larger of the Schur pieces and a general conic
    solver's dense ``(k(k+1)/2)^2`` scaling per PSD cone of side k (Clarabel runs it, and the cone
    complementarity fallback: under "AUTO" both run only when that estimate fits the budget too), or the analysis
    re-check's node SDP when larger (:func:`solver.network_analysis.node_sdp_memory`, docs/design.md §11.4).
    """
    from .methods.network_lmi import fresh_age, lifted_edges

    n, m, r, N = int(n_states), int(n_inputs), int(n_plants), int(network.n_drop)
    if fresh_age(network):
        edges = lifted_edges(network)
        V = len({v for v, _, _ in edges} | {w for _, w, _ in edges})
        E = sum(r if plant_switching == "per_interval" else r**eta for _, _, eta in edges)
        k, zvars = n, n * n
    else:
        V, E, k, zvars = int(network.nodes), len(network.edges) * r, n * N, N * n * n
    sym = k * (k + 1) // 2
    p = zvars + 2 * V * sym + N * m * n + 1
    touched = zvars + 4 * sym + N * m * n + 1
    pieces = E * touched**2
    cones = [(2 * k, E + V), (k, V)]
    conic = sum(count * 8 * (side * (side + 1) // 2) ** 2 for side, count in cones)
    memory = max(8 * (pieces + p * p), conic)
    if str(solver).upper() in ("AUTO", "IPM"):
        v = V * k * k
        n_full = zvars + v + N * m * n + 1
        memory = ipm_memory(n_full, zvars + V * sym + N * m * n, E + V, 2 * k, v) + 20 * E * k**4
    from .network_analysis import MAX_LMI_ROWS, node_sdp_memory, product_automaton

    product = product_automaton(network, r, plant_switching)
    if product.size * n * N <= MAX_LMI_ROWS:  # the analysis re-check's node SDP (above it analyze refuses, skipped)
        memory = max(memory, node_sdp_memory(product.succ, n * N))
    memory = float(min(memory, 10**300))
    step = _step_seconds([(2 * k, touched, E), (2 * k, 2 * sym, V), (k, sym, V)], p)
    lmi = 2 * k * E + k * V
    return DesignSize("network", E, lmi, p, memory, float(min(_steps("plain", lmi) * step, 1e300)),
                      nodes=int(network.nodes), state_size=k, path=path, solves=solves, step_seconds=step,
                      total_seconds=_total(path, step, solves, E, lmi))


def network_performance_size(network, n_states: int, n_inputs: int, n_plants: int,
                             plant_switching: str = "per_interval", solver: str = "AUTO", *,
                             objective: str = "cost", u_max=None, n_disturbances: int = 1,
                             n_outputs: int | None = None) -> DesignSize:
    """Size of a network performance or input-limited design (docs/design.md §11.3), from the automaton alone.

    The model of :mod:`solver.ipm.network_performance_blocks` (the cvxpy form Clarabel solves has the same
    cones): one transition block of side ``2k + p_w + p`` per transition and plant mode (``p`` the cost or output
    rows after the triangular factor, at most ``k + N m`` (+ ``p_w``) columns), one start block per node (side
    ``n + k`` with its 1 x 1 trace block, the larger of the cost's two forms; ``k + 1`` for x0), and the input
    blocks of side ``k + 1`` (per node, gain applied from it and input).  ``objective="stability"`` with
    ``u_max``: the input-limited design (invariance blocks of side 2k, the input blocks, ``W_v`` between two
    bounds), which runs on Clarabel.  Memory: the structured IPM's (as :func:`ipm_memory`, the node matrices the
    largest variable) with ``solver`` "AUTO"/"IPM", Clarabel's (its dense scaling per cone, the cvxpy copies of
    the Schur pieces) otherwise.
    """
    from .methods.network_lmi import fresh_age, lifted_edges

    n, m, r, N = int(n_states), int(n_inputs), int(n_plants), int(network.n_drop)
    pw1 = int(n_disturbances)
    pz1 = n + m if n_outputs is None else int(n_outputs)
    if fresh_age(network):
        edges = lifted_edges(network)
        V = len({v for v, _, _ in edges} | {w for _, w, _ in edges})
        counts = [(eta, r if plant_switching == "per_interval" else r**eta) for _, _, eta in edges]
        k, zb, gains_per_node = n, 1, N
    else:
        V, k, zb, gains_per_node = int(network.nodes), n * N, N, 1
        counts = [(1, len(network.edges) * r)]
    E = sum(c for _, c in counts)
    kothare = u_max is not None and u_max is not False
    limits_only = objective not in ("cost", "hinf")
    eta_max = max(eta for eta, _ in counts)
    if limits_only:
        pw, p, side = 0, 0, 2 * k
    elif objective == "cost":
        pw = 0
        p = max(min(eta * (n + m), k + N * m) for eta, _ in counts)
    else:
        pw = eta_max * pw1 if k == n else pw1
        p = max(min(eta * pz1, k + N * m + eta * pw1) for eta, _ in counts)
    side = 2 * k + pw + p
    sym_k, sym_n = k * (k + 1) // 2, n * (n + 1) // 2
    gain_vars = N * m * n
    p_vars = zb * n * n + V * sym_k + gain_vars + 1
    blocks = [(side, zb * n * n + 2 * sym_k + gain_vars + 1, E)]
    if objective == "cost":
        p_vars += V * sym_n
        blocks += [(n + k, sym_k + sym_n + 1, V), (1, sym_n + 1, V)]
    if kothare:
        blocks.append((k + 1, sym_k + zb * n * n + gain_vars, V * gains_per_node * m))
    if limits_only:
        blocks += [(k, sym_k + 1, 2 * V)]
    lmi = sum(sd * c for sd, _, c in blocks)
    pieces = sum(c * v**2 for _, v, c in blocks)
    iterates = sum(c * sd * sd for sd, _, c in blocks)
    conic = 8 * sum(c * (sd * (sd + 1) // 2) ** 2 for sd, _, c in blocks)  # clarabel_kkt_bytes, per count
    clarabel = max(CVXPY_MEMORY_FACTOR * 8 * (pieces + p_vars**2) + CVXPY_MEMORY_FIXED, conic)
    if str(solver).upper() in ("AUTO", "IPM") and not limits_only:
        v = V * k * k
        n_full = zb * n * n + v + gain_vars + (V * n * n if objective == "cost" else 0) + 2
        memory = ipm_memory(n_full, p_vars, 1, 0, v) + 10 * 30 * iterates + 5 * E * side**2 * k**2
    else:
        memory = clarabel
    memory = float(min(memory, 10**300))
    step = _step_seconds(blocks, p_vars)
    return DesignSize("network", E, lmi, p_vars, memory, float(min(_steps("plain", lmi) * step, 1e300)),
                      nodes=int(network.nodes), state_size=k, path="network", solves=1, step_seconds=step,
                      total_seconds=_total("network", step, 1, E, lmi))


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


#: The process-wide cache of compiled problems by shape, every method's (each worker process has its own;
#: ``lookup(key, build)`` gives ``(problem, was_cached)``); ``NCS_PROBLEM_CACHE_SIZE`` sets its bound.
problem_cache = BoundedCache(max(1, int(os.environ.get("NCS_PROBLEM_CACHE_SIZE", "32"))))


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
