"""The design facade: ``design(family, n_drop, method=...)``, like ``scipy.optimize.minimize``."""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Callable

import numpy as np

from .compiled import check_solver, design_size
from .errors import InvalidInput, SolverFailed
from .methods import ccl, lmi, switched
from .methods.common import NEGATIVE, DesignOptions, proof_outcome
from .ipm import blas_threads
from .lyapunov import recheck_common, recheck_lifted, recheck_switched
from .network import MAX_MODES, PLANT_SWITCHING, SCHEMES, ModeSet, check_n_drop, mode_count
from .plant import PlantFamily
from .result import DesignResult, certified_settling, metric_condition
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
    if decay_rate is not None and decay_rate != "auto":
        if method not in RATE_METHODS:
            raise InvalidInput(f"decay_rate is available with methods {RATE_METHODS}", ("decay_rate",))
        if decay_rate != "max" and (isinstance(decay_rate, bool) or not isinstance(decay_rate, (int, float))
                                    or not 0 < decay_rate <= 1):
            raise InvalidInput("decay_rate must be a number in (0, 1] or 'max'", ("decay_rate",))
    if not (isinstance(rate_tol, (int, float)) and 1e-6 <= rate_tol <= 0.1):
        raise InvalidInput("rate_tol must be in [1e-6, 0.1]", ("rate_tol",))


def design(
    family: PlantFamily,
    n_drop: int | None = None,
    method: str = "lmi",
    *,
    solver: str = "AUTO",
    margin: float = 1e-6,
    max_iter: int = 50,
    time_limit: float | None = None,
    callback: Callable | None = None,
    ccl_start: str = "feasibility",
    decay_rate: float | str | None = "auto",
    rate_tol: float = 1e-3,
    plant_switching: str = "per_interval",
    scheme: str = "predictive",
    max_modes: int = MAX_MODES,
    scaling: str = "auto",
    objective: str = "stability",
    weights=None,
    x0=None,
    disturbance=None,
    output=None,
    u_max=None,
    max_memory: float | None = None,
    network=None,
) -> DesignResult:
    """Design gains ``K_1..K_{n_drop}`` that stabilize the networked loop under any losses and jumps.

    Parameters
    ----------
    family : PlantFamily
        r plant modes with n states and m inputs.
    n_drop : int, optional
        Drop bound N >= 1: at most ``n_drop - 1`` consecutive lost packets (the number of gains).
        Taken from ``network`` when one is given (an error when both are given and differ).
    method : {"lmi", "ccl", "switched"}
        ``"lmi"``: the exact convex design (one SDP, common quadratic Lyapunov
        function). ``"ccl"``: the paper's cone complementarity linearization.
        ``"switched"``: mode-dependent Lyapunov functions (one SDP, less conservative).
    solver : {"AUTO", "IPM", "CLARABEL", "SCS"}
        Conic solver.  ``"AUTO"`` (default): the fastest with the same verdicts, per problem
        (:func:`solver.compiled.resolve_solver`): the structured interior-point solver
        (solver/ipm/) for ``lmi``, every decay-rate bisection step, ``switched`` and the common
        fixed-gain certificate LMI, and ``ccl`` except a paper-sized problem (block side
        ``2 n n_drop <= 12``) with ``ccl_start="feasibility"``; Clarabel there and for the switched
        fixed-gain LMI.  The performance designs (``objective``, ``u_max``) run on the structured
        solver too, with Clarabel when it ends without an answer.  ``"IPM"`` forces the structured solver where it applies (Clarabel
        elsewhere); ``"CLARABEL"`` and ``"SCS"`` (first order) run through cvxpy.
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
    decay_rate : float in (0, 1], "auto", "max" or None
        ``"auto"`` (default): a loop that settles within about 1.5 times the fastest certifiable
        one, with smaller gains: a coarse bisection (:data:`AUTO_SETTLING_TOLERANCE`) finds a certified
        rate ``lambda*`` within 10 % of the best in settling time, then the design is made at
        ``lambda*^(1 / AUTO_SLOWDOWN)`` (settling time ``AUTO_SLOWDOWN = 1.5`` times longer, where
        the LMI has room left, so gains are far smaller than at the optimum).  ``ccl`` has no rate
        and treats ``"auto"`` as None.  ``None``: plain stability (maximizes the LMI's relative
        margin; such loops may contract by only 0.99 per sample).  A number: demand a per-sample decay rate lambda (``|x(i_{m+1})| <= lambda^eta |x(i_m)|``
        in the certificate's norm), or find the smallest one (``"max"``) by bisection on the
        congruent SDP (data of mode s times ``lambda^(-eta_s)``; docs/design.md).  A rate is
        accepted only by the float64 re-check at that rate and rejected only with a
        certificate; ``res.rate_bracket`` gives the bracket.  ``switched`` starts from
        ``lmi``'s certified rate and is never worse.  Gains grow as the rate nears the
        optimum (the LMI's margin vanishes there): a slightly larger rate gives far
        smaller gains.  ``lmi`` and ``switched`` only.
    rate_tol : float
        Relative bisection tolerance on lambda for ``decay_rate="max"``.
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
        gains and certificates back (see :mod:`solver.scaling`).  Designs with an
        ``objective`` other than "stability" or with ``u_max`` run in the user's coordinates.
    max_memory : float, optional
        Memory budget in bytes (default :data:`solver.compiled.MAX_SOLVER_MEMORY`, 4 GiB, or
        ``NCS_SOLVER_MAX_MEMORY``).  Before anything is built, the design's size is estimated
        (:func:`solver.compiled.design_size`) and a design over this budget, or over
        :data:`solver.compiled.MAX_SOLVER_SECONDS` (300 s, ``NCS_SOLVER_MAX_SECONDS``) of estimated
        solver time when no ``time_limit`` is given, is refused with ``InvalidInput`` naming the
        size and the limit.  The same estimate sets the service's limits.
    objective : {"stability", "cost", "hinf"}
        ``"stability"`` (default): the designs above.  ``"cost"``: minimize the certified bound on the
        worst-case quadratic cost ``sum_k x' Q x + u' R u`` over every allowed pattern (``x0' P x0``,
        or ``trace P`` for initial states of covariance I when ``x0`` is None).  ``"hinf"``: minimize
        the certified worst-case l2 gain from the disturbance w to z.  Both: method ``"lmi"`` only,
        solved by Clarabel (also under "AUTO"), ``res.performance`` holds the bracket (certified upper
        bound, worst periodic pattern as the lower bound, its witness); docs/design.md, "Performance".
    weights : (Q, R), optional
        Cost weights (n x n positive semidefinite, m x m positive definite; default identities).
    x0 : array_like of n, optional
        Initial state: the cost objective bounds its cost; with ``u_max`` the invariant set contains it.
    disturbance : array_like
        ``E`` (n x p_w), one for all plant modes or one per mode: ``x(k+1) = F x + G u + E w`` (hinf).
    output : (C, D), optional
        Performance output ``z = C x + D u`` (one pair or one per mode; D may be None); default ``z = [x; u]``.
    u_max : array_like of m, optional
        Input limits: every applied input must satisfy ``|u_j(k)| <= u_max[j]`` from every initial state
        of ``res.invariant_set`` (X of ``x' X x <= 1``; with the largest ball around 0 the design can fit in it,
        and ``x0`` when given) under every allowed pattern.  With ``objective="cost"`` it needs ``x0``; not with "hinf".
    network : solver.Network, optional
        The admissible buffer-age sequences (docs/design.md, "Design on a network").  A bounded-drops
        network runs exactly the design above with its ``n_drop``.  Any other runs the network design
        (:mod:`solver.methods.network_lmi`: node-dependent Lyapunov matrices with a common slack, then cone
        complementarity on the exact node conditions when the convex one certifies nothing), method "lmi"
        and scheme "predictive" only, Clarabel; ``decay_rate`` None, a number, "max" or "auto" (the
        bisection runs on the convex condition); ``objective``, ``u_max`` and the other performance options
        are not supported yet there.  Outcomes: "stabilized" (a node certificate re-checked in float64),
        "infeasible" (an unstable mode no input reaches, or the network admits every bounded-drops run
        and the bounded-drops design is proven infeasible), "not_certified" (the convex condition proven
        infeasible by a Farkas certificate: other gains may exist), "not_converged".

    Returns
    -------
    DesignResult
        ``outcome`` is "stabilized" only with a float64-verified Lyapunov certificate,
        "infeasible" only with a re-checked proof in ``res.certificate`` (``kind="farkas"``:
        multipliers, ``gain_bound``; ``kind="uncontrollable"``: an unstable mode no input
        reaches), and "not_converged" otherwise (the reason in ``message``; also when
        ``time_limit`` runs out, with the best iterate).

    Raises
    ------
    InvalidInput
        Bad arguments (the field is named in ``err.field``).
    SolverFailed
        The conic solver failed (not by the time limit); never reported as "infeasible".
    """
    if not isinstance(family, PlantFamily):
        raise InvalidInput("family must be a PlantFamily", ("family",))
    if network is not None:
        from .networks import check_network

        n_drop = _network_n_drop(network, n_drop)
        network = check_network(network)
        if not network.is_bounded_drops:
            return _network_design(family, network, method, solver=solver, margin=margin, max_iter=max_iter,
                                   time_limit=time_limit, callback=callback, ccl_start=ccl_start,
                                   decay_rate=decay_rate, rate_tol=rate_tol, plant_switching=plant_switching,
                                   scheme=scheme, scaling=scaling, objective=objective,
                                   performance=(weights, x0, disturbance, output, u_max), max_memory=max_memory)
    elif n_drop is None:
        raise InvalidInput("n_drop is required (or give a network)", ("n_drop",))
    if method not in METHODS:
        raise InvalidInput(f"method must be one of {sorted(METHODS)}, got {method!r}", ("method",))
    _check_options(margin, max_iter, time_limit, ccl_start, decay_rate, rate_tol, method)
    if scaling not in ("auto", "none"):
        raise InvalidInput("scaling must be 'auto' or 'none'", ("scaling",))
    check_budget(method, family, n_drop, plant_switching, scheme, max_modes, max_memory, time_limit,
                 solves=solve_count(method, decay_rate, rate_tol, max_iter), solver=solver)
    modes = ModeSet.from_family(family, n_drop, plant_switching=plant_switching, scheme=scheme,
                                max_modes=max_modes)
    if objective != "stability" or any(v is not None for v in (weights, x0, disturbance, output, u_max)):
        res = _performance_design(modes, method, objective, weights, x0, disturbance, output, u_max, solver,
                                  margin, max_iter, time_limit, callback, decay_rate)
        if network is not None:
            res.network = network.to_dict()
        return res
    options = DesignOptions(
        solver=check_solver(solver),
        margin=float(margin),
        max_iter=int(max_iter),
        time_limit=None if time_limit is None else float(time_limit),
        callback=callback,
        ccl_start=ccl_start,
        decay_rate=None if decay_rate in (None, "max", "auto") else float(decay_rate),
    )
    if decay_rate == "auto" and method not in RATE_METHODS:
        decay_rate = None
    scale = balance(family) if scaling == "auto" else None
    # one BLAS thread: the re-checks and proofs are many small LAPACK calls that 2 threads only slow down
    with blas_threads(1):
        if scale is not None and not scale.is_identity:
            scaled_modes = ModeSet.from_family(scale.family(family), n_drop, plant_switching=plant_switching,
                                               scheme=scheme, max_modes=max_modes)
            res = _unscale(_best(method, scaled_modes, options, decay_rate, rate_tol), scale, modes)
        else:
            res = _best(method, modes, options, decay_rate, rate_tol)
    if res is not None and res.outcome == "stabilized" and res.decay_rate is not None:
        res.settling = certified_settling(res.decay_rate, metric_condition(res.certificate, res.scaling),
                                          family.sampling_period)
    if network is not None and res is not None:
        res.network = network.to_dict()
    return res


def _network_n_drop(network, n_drop) -> int:
    """The network's n_drop; a different ``n_drop`` given beside it is an error."""
    from .networks import check_network

    return check_network(network, None if n_drop is None else check_n_drop(n_drop)).n_drop


def _network_design(family: PlantFamily, network, method: str, *, solver, margin, max_iter, time_limit, callback,
                    ccl_start, decay_rate, rate_tol, plant_switching, scheme, scaling, objective, performance,
                    max_memory) -> DesignResult:
    """The design on a network other than bounded drops (:mod:`solver.methods.network_lmi`)."""
    from .certificates import uncontrollable_mode
    from .methods import network_lmi

    where = f"not supported yet for network={network.describe()}"
    if method != "lmi":
        raise InvalidInput(f"method={method!r} is {where}: use method='lmi'", ("method",))
    _check_options(margin, max_iter, time_limit, ccl_start, decay_rate, rate_tol, method)
    if scheme != "predictive":
        raise InvalidInput(f"scheme={scheme!r} is {where}", ("scheme",))
    if plant_switching not in PLANT_SWITCHING:
        raise InvalidInput(f"plant_switching must be one of {PLANT_SWITCHING}", ("plant_switching",))
    if scaling not in ("auto", "none"):
        raise InvalidInput("scaling must be 'auto' or 'none'", ("scaling",))
    if objective != "stability":
        raise InvalidInput(f"objective={objective!r} is {where}", ("objective",))
    for name, value in zip(("weights", "x0", "disturbance", "output", "u_max"), performance):
        if value is not None:
            raise InvalidInput(f"{name} is {where}", (name,))
    check_solver(solver)
    size = design_size("lmi", family.n_states, family.n_inputs, family.n_modes, network.n_drop, plant_switching,
                       solver=solver, network=network)
    size.check(max_memory, float("inf") if time_limit is not None else None,
               solves=solve_count("lmi", decay_rate, rate_tol, max_iter))
    start = time.perf_counter()
    with blas_threads(1):
        prob = network_lmi.build_problem(family, network, plant_switching)
        unc = uncontrollable_mode(np.asarray(family.F, float), np.asarray(family.G, float), 1.0)
        if unc is not None:  # an unstable mode no input reaches: no gains at all, on any network
            res = DesignResult(outcome="infeasible", gains=None, certificate=unc, method="network_lmi",
                               n_drop=network.n_drop, plant_switching=plant_switching,
                               message=f"{unc.statement()}: no gains stabilize the loop on {network.describe()}")
        else:
            res = _network_rates(family, network, prob, decay_rate, rate_tol, time_limit, callback, max_iter,
                                 plant_switching, start)
        if res.outcome not in ("stabilized", "infeasible") and network_lmi.contains_bounded_drops(network):
            res = _bounded_drops_proof(family, network, res, plant_switching, start, time_limit)
    res.network = network.to_dict() if hasattr(network, "to_dict") else None
    if prob.form == "augmented" and family.n_modes > 1 and plant_switching == "per_interval":
        res.message += "; the augmented certificate lets the plant mode switch at every sample (it covers per_interval)"
    res.timings["total"] = time.perf_counter() - start
    if res.outcome == "stabilized" and res.decay_rate is not None:
        res.settling = certified_settling(res.decay_rate, metric_condition(res.certificate, None),
                                          family.sampling_period)
    return res


def _bounded_drops_proof(family, network, res: DesignResult, plant_switching, start, time_limit) -> DesignResult:
    """"infeasible" when the network admits every bounded-drops run and today's design is proven infeasible there.

    Gains that stabilize the network stabilize every run it admits, so a proof that none stabilizes the
    bounded-drops runs (in the sense of that proof) carries over; the converse direction would be wrong.
    """
    remaining = None if time_limit is None else time_limit - (time.perf_counter() - start)
    if remaining is not None and remaining <= 0:
        return res
    try:
        base = design(family, network.n_drop, "lmi", decay_rate=None, plant_switching=plant_switching,
                      time_limit=remaining)
    except (SolverFailed, InvalidInput):
        return res
    if base.outcome != "infeasible":
        return res
    base.method = "network_lmi"
    base.history = res.history + base.history
    base.message = (f"infeasible on {network.describe()}: it admits every run of bounded_drops({network.n_drop}), "
                    f"and for those: {base.message} (network design before this proof: {res.outcome})")
    return base


def _network_rates(family, network, prob, decay_rate, rate_tol, time_limit, callback, max_iter, plant_switching,
                   start) -> DesignResult:
    """``decay_rate`` on a network: a number or None directly; "max"/"auto" by bisection on the convex condition.

    The bisection accepts a rate only with a re-checked certificate; a step without one (not proven
    infeasible) counts as a failure for the bisection only.  When the convex condition certifies nothing at
    rate 1, "auto" falls back to plain stability (with the cone complementarity fallback); "max" reports it.
    """
    from .methods import network_lmi

    def left():
        return None if time_limit is None else max(time_limit - (time.perf_counter() - start), 1e-3)

    def recheck(gains, rate):
        """Plain stability: the network analysis must accept the gains (its own certificate is kept)."""
        if rate is not None:
            return True, None  # analyze() has no rate: the float64 re-check of the node matrices at the rate
        from .analysis import analyze

        try:
            rep = analyze(family, gains, network=network, plant_switching=plant_switching)
        except (InvalidInput, SolverFailed):
            return False, None
        return rep.stable is True, rep.certificate

    def one(rate, use_ccl=True):
        return network_lmi.run(family, network, decay_rate=rate, plant_switching=plant_switching,
                               time_limit=left(), callback=callback, max_iter=max_iter, use_ccl=use_ccl, prob=prob,
                               recheck=recheck)

    if decay_rate not in ("max", "auto"):
        return one(None if decay_rate is None else float(decay_rate))
    best = one(1.0, use_ccl=False)
    if best.outcome != "stabilized":
        plain = one(None)
        plain.message += f"; decay_rate={decay_rate!r}: the convex condition certifies no decay rate"
        return plain
    lo, hi, tries = 0.0, 1.0, [{"decay_rate": 1.0, "outcome": "stabilized"}]
    tol = AUTO_SETTLING_TOLERANCE if decay_rate == "auto" else rate_tol
    while hi > MIN_RATE and (time_limit is None or time.perf_counter() - start < time_limit):
        if decay_rate == "auto":
            s_hi, s_lo = -np.log(min(hi, 1 - 1e-9)), -np.log(max(lo, MIN_RATE))
            if s_lo <= (1 + tol) * s_hi:
                break
            mid = float(np.exp(-np.sqrt(s_hi * s_lo)))
        else:
            if hi - lo <= tol * hi:
                break
            mid = 0.5 * (lo + hi)
        res = one(mid, use_ccl=False)
        tries.append({"decay_rate": mid, "outcome": res.outcome})
        if res.outcome == "stabilized":
            hi, best = mid, res
        else:
            lo = mid
    fastest = hi
    if decay_rate == "auto" and hi < 1.0:
        target = fastest ** (1.0 / AUTO_SLOWDOWN)
        res = one(target, use_ccl=False)
        tries.append({"decay_rate": target, "outcome": res.outcome})
        if res.outcome == "stabilized":
            best = res
    best.rate_search = tries
    best.rate_bracket = {"lower": lo, "upper": fastest, "lower_proven": False, "relative_tolerance": tol}
    best.message += (f"; decay_rate={decay_rate!r}: smallest rate certified by the convex condition {fastest:.6g}, "
                     f"bracket [{lo:.6g}, {fastest:.6g}] (lower end not proven)")
    return best


def _performance_design(modes: ModeSet, method, objective, weights, x0, disturbance, output, u_max, solver,
                        margin, max_iter, time_limit, callback, decay_rate) -> DesignResult:
    """Cost, H-infinity and input-limited designs (:mod:`solver.methods.performance`), user coordinates."""
    from .methods import performance

    lifted, x0, u_max = performance.prepare(modes, method, objective, weights, x0, disturbance, output, u_max,
                                            decay_rate, solver)
    rate = None if decay_rate in (None, "auto") else float(decay_rate)  # "auto": prepare's note
    options = DesignOptions(solver=check_solver(solver), margin=float(margin), max_iter=int(max_iter),
                            time_limit=None if time_limit is None else float(time_limit), callback=callback,
                            decay_rate=rate)
    return performance.run(lifted, options, objective, x0, u_max)


def solve_count(method: str, decay_rate, rate_tol: float, max_iter: int) -> int:
    """How many SDPs a design solves at least (for the time estimate that refuses a design up front).

    ``ccl`` counts Step 1 and one iteration, not ``max_iter``: how many iterations it takes is not known
    before it runs, and the time limit (``time_limit``, the service's job time limit) stops it if needed.
    """
    if method == "ccl":
        return 2
    if decay_rate in ("max", "auto"):
        return int(np.ceil(np.log2(1.0 / rate_tol))) + 2
    return 1


def check_budget(method: str, family: PlantFamily, n_drop, plant_switching: str, scheme: str, max_modes: int,
                 max_memory: float | None, time_limit: float | None, solves: int = 1, solver: str = "AUTO") -> None:
    """Refuse, before building anything, a design whose estimated memory or time is over budget.

    A thin layer over :func:`solver.compiled.design_size` (the estimate the service's limits use too).
    Bad ``n_drop``, ``plant_switching``, ``scheme`` or too many modes are left to
    :class:`ModeSet`, which names them.  With a ``time_limit`` the caller bounded the time, so only
    memory is checked.
    """
    n_drop = check_n_drop(n_drop)
    if plant_switching not in PLANT_SWITCHING or scheme not in SCHEMES:
        return
    if mode_count(family.n_modes, n_drop, plant_switching) > max_modes:
        return
    size = design_size(method, family.n_states, family.n_inputs, family.n_modes, n_drop, plant_switching, scheme,
                       solver)
    size.check(max_memory, float("inf") if time_limit is not None else None, solves=solves)


def _best(method: str, modes: ModeSet, options: DesignOptions, decay_rate, rate_tol: float) -> DesignResult:
    """``switched`` with ``decay_rate="max"`` starts from lmi's certified rate: never worse than lmi."""
    if decay_rate == "max" and method == "switched":
        start = time.perf_counter()
        first = _smallest_rate("lmi", modes, options, rate_tol)
        if first is not None and "time limit reached" in first.message:
            first.method = "switched"
            return first
        if first is not None and first.outcome == "stabilized":
            rest = options if options.time_limit is None else replace(
                options, time_limit=max(options.time_limit - (time.perf_counter() - start), 1e-9))
            return _smallest_rate("switched", modes, rest, rate_tol, upper=first, user_limit=options.time_limit)
    return _run(method, modes, options, decay_rate, rate_tol)


def _run(method: str, modes: ModeSet, options: DesignOptions, decay_rate, rate_tol: float) -> DesignResult:
    if decay_rate == "auto":
        return _auto_rate(method, modes, options)
    if decay_rate != "max":
        return METHODS[method].run(modes, options)
    return _smallest_rate(method, modes, options, rate_tol)


#: ``decay_rate="auto"``: the settling time asked for, as a multiple of the fastest certified one.
AUTO_SLOWDOWN = 1.5
#: ``decay_rate="auto"``: the coarse bisection stops when its bracket ``[lo, hi]`` is within this relative
#: tolerance in settling time (``ln lo / ln hi <= 1 + tol``), so the default loop settles within
#: ``1.5 x 1.1 = 1.65`` times the fastest certifiable one (under 2x).
AUTO_SETTLING_TOLERANCE = 0.1


def _auto_rate(method: str, modes: ModeSet, options: DesignOptions) -> DesignResult:
    """The default design: a rate whose settling time is ``AUTO_SLOWDOWN`` times the best one's.

    At the best rate the LMI's margin vanishes and gains grow without bound; 1.5x its settling time
    leaves the SDP room, so its maximal-margin solution has moderate gains.  The coarse bisection runs
    on the settling time (``-1 / ln lambda``), geometrically, since that is what the tolerance is on.
    """
    start = time.perf_counter()
    try:
        best = _smallest_rate(method, modes, options, AUTO_SETTLING_TOLERANCE, settling=True)
    except SolverFailed:  # at lambda = 1 already: plain stability's SDP is better conditioned
        best = DesignResult(outcome="not_converged", gains=None, certificate=None, method=method,
                            n_drop=modes.n_drop, message="the solver failed at decay rate 1")
    if best is not None and best.outcome != "stabilized" and "time limit" not in best.message:
        # no certified rate at all (not even lambda = 1 with the rate form's margin): plain stability, whose
        # margin is normalized differently, may still certify the loop
        plain = METHODS[method].run(modes, options)
        plain.message += "; decay_rate='auto': no certified decay rate, plain stability design"
        return plain
    if best is None or best.outcome != "stabilized" or best.decay_rate is None or best.decay_rate >= 1.0:
        return best
    fastest = float(best.decay_rate)
    target = fastest ** (1.0 / AUTO_SLOWDOWN)
    remaining = None if options.time_limit is None else options.time_limit - (time.perf_counter() - start)
    if remaining is not None and remaining <= 0:
        return best
    try:
        res = METHODS[method].run(modes, replace(options, decay_rate=target, time_limit=remaining))
    except SolverFailed:  # keep the certified faster loop
        return best
    if res.outcome != "stabilized":  # cannot happen for a convex rate LMI (feasible at a smaller rate)
        return best
    res.rate_search = best.rate_search + [{"decay_rate": target, "outcome": res.outcome,
                                           "proof": None if res.certificate is None else res.certificate.kind}]
    res.rate_bracket = {**best.rate_bracket, "fastest_certified": fastest, "slowdown": AUTO_SLOWDOWN}
    res.decay_rate = target
    res.message += (f"; decay_rate='auto': designed at {target:.6g} per sample = {fastest:.6g}^(1/{AUTO_SLOWDOWN:g}), "
                    f"settling {AUTO_SLOWDOWN:g}x the fastest certified rate's (bracket [{best.rate_bracket['lower']:.6g}, "
                    f"{fastest:.6g}])")
    total = time.perf_counter() - start
    res.timings.update(total=total, solves=len(res.rate_search),
                       solver=best.timings.get("solver", 0.0) + res.timings.get("solver", 0.0))
    return res


#: What a bisection step whose solver failed returns (no certificate, no proof).
FAILED_STEP = object()

#: Rates below this are not searched (``c_s = lambda^(-eta_s)`` would overflow the conditioning).
MIN_RATE = 1e-4


def _smallest_rate(method: str, modes: ModeSet, options: DesignOptions, tol: float,
                   upper: DesignResult | None = None, user_limit: float | None = None,
                   settling: bool = False) -> DesignResult:
    """Bisection on lambda in (0, 1] with relative tolerance ``tol``, on the congruent SDP.

    A rate is accepted only when the float64 re-check of that step's gains and
    certificate passes at the rate; a step is "infeasible" only with a re-checked
    Farkas (or uncontrollable-mode) certificate.  ``res.rate_bracket`` reports
    ``[lower, upper]``: ``upper`` the returned certified rate, ``lower`` the largest rate
    tried below it, and whether that lower end is proven (every design of the
    method at rates <= lower is excluded by a certificate).  ``upper`` (switched): a
    result of another method whose certified rate starts the search (its certificate
    also proves the rate for this method's loop).
    """
    start = time.perf_counter()
    totals = {"setup": 0.0, "solver": 0.0, "solves": 0}
    search: list = []
    runner = METHODS[method].run
    limit = options.time_limit
    timed_out = False

    def attempt(lam):
        nonlocal timed_out
        remaining = None if limit is None else limit - (time.perf_counter() - start)
        if remaining is not None and remaining <= 0:
            timed_out = True
            return None
        try:
            res = runner(modes, replace(options, decay_rate=lam, time_limit=remaining))
        except SolverFailed as err:
            if lam >= 1.0:  # nothing certified yet: the design itself failed
                raise
            # a step the solver could not finish certifies nothing and proves nothing: bisect above it
            search.append({"decay_rate": lam, "outcome": "solver_failed", "proof": None, "message": str(err)})
            return FAILED_STEP
        for key in totals:
            totals[key] += res.timings.get(key, 0)
        search.append({"decay_rate": lam, "outcome": res.outcome,
                       "proof": None if res.certificate is None else res.certificate.kind})
        if res.outcome == "not_converged" and "time limit" in res.message:
            timed_out = True
        return res

    lo, lo_proven, lo_proof, lo_margin = 0.0, True, "infeasible", None
    if upper is not None and upper.outcome == "stabilized" and upper.decay_rate is not None:
        best, hi = upper, float(upper.decay_rate)
        best.method = method
        search.extend({**entry, "decay_rate": entry["decay_rate"], "method": upper.method}
                      for entry in upper.rate_search)
        # lo stays 0: another method's infeasible rates say nothing about this one
    else:
        best = attempt(1.0)
        hi = 1.0
        if best is None or best.outcome != "stabilized":
            if best is not None:
                best.rate_search = search
            return best if best is not None else _time_out(modes, method, options, search)
    def done(lo, hi):
        if not settling:
            return hi - lo <= tol * hi
        # settling times -1/ln(lambda) of the two ends within 1 + tol (ends clamped as in the midpoint, so a
        # bracket pinned at hi = 1 ends too, once lo is within 1e-9 of 1: no certified rate below 1)
        return -np.log(max(lo, MIN_RATE)) <= (1 + tol) * -np.log(min(hi, 1 - 1e-9))

    while not done(lo, hi) and hi > MIN_RATE and not timed_out:
        if settling:  # geometric mean of -ln(lambda) between the ends (hi = 1 and lo = 0 replaced)
            s_hi, s_lo = -np.log(min(hi, 1 - 1e-9)), -np.log(max(lo, MIN_RATE))
            mid = float(np.exp(-np.sqrt(s_hi * s_lo)))
        else:
            mid = 0.5 * (lo + hi)
        res = attempt(mid)
        if res is None:
            break
        if res is FAILED_STEP:
            lo, lo_proven = mid, False
        elif res.outcome == "stabilized":
            hi, best = mid, res
        else:
            lo, lo_proven = mid, res.outcome == "infeasible"
            lo_proof = res.outcome if res.outcome in NEGATIVE else None
            lo_margin = res.certificate.margin if lo_proof == "marginal" else None
    A = modes.closed_loops(best.gains)
    loop = float(np.max(np.max(np.abs(np.linalg.eigvals(A)), axis=-1) ** (1.0 / modes.eta)))
    if lo == 0.0:
        lo_proof = None  # no step below the upper end failed: the lower end 0 is vacuous
    best.rate_bracket = {"lower": lo, "upper": hi, "lower_proven": bool(lo_proven), "lower_proof": lo_proof,
                         "lower_margin": lo_margin, "loop_spectral_rate": loop, "relative_tolerance": tol}
    proven = ("proven: no design of any margin (infeasible)" if lo_proven
              else f"marginal: only designs with relative margin >= {lo_margin:.3g} are excluded"
              if lo_proof == "marginal" else "not proven: a step ended without a verdict")
    best.message += (f"; smallest certified decay rate {hi:.6g}, bracket [{lo:.6g}, {hi:.6g}] (lower end {proven}; "
                     f"relative tolerance {tol:g}, {len(search)} designs)")
    best.rate_search = search
    best.decay_rate = hi
    total = time.perf_counter() - start
    best.timings.update(totals, total=total, overhead=max(total - totals["setup"] - totals["solver"], 0.0))
    if timed_out:
        best.outcome = "not_converged"
        shown = limit if user_limit is None else user_limit
        best.message = (f"time limit reached ({shown:g} s) during the decay-rate bisection; best iterate: "
                        + best.message)
    return best


def _time_out(modes, method, options, search) -> DesignResult:
    return DesignResult(outcome="not_converged", gains=None, certificate=None, method=method, n_drop=modes.n_drop,
                        message=f"time limit reached ({options.time_limit:g} s) before the first design",
                        scheme=modes.scheme, plant_switching=modes.plant_switching,
                        mode_labels=[modes.label(s) for s in range(modes.n_modes)], rate_search=search)


def _proof_back(cert, scale: Scaling, modes: ModeSet):
    """An infeasibility proof made in scaled coordinates, re-checked on the user's data.

    Farkas multipliers map by the congruence ``Z = D^-T Z~ D^-1``, ``D = blkdiag(T, T)``
    (exact: powers of two) and are re-checked on interval data rebuilt from the
    user's F, G; when that re-check fails the scaled one stands (``scaled=True``).
    """
    from .certificates import (check_farkas, check_farkas_switched, describe_uncontrollable, interval_data,
                               uncontrollable_mode)
    from .methods.common import congruent_scale

    if cert.kind == "uncontrollable":
        l, t, u = cert.plant, scale.state, scale.input
        Ft = modes.F[l] / t[:, None] * t[None, :]
        Gt = modes.G[l] / t[:, None] * u[None, :]
        if np.array_equal(Ft * t[:, None] / t[None, :], modes.F[l]) and np.array_equal(
                Gt * t[:, None] / u[None, :], modes.G[l]):
            # the exact proof carries over: the scaled pair is an exact powers-of-two similarity of the user's
            # (no underflow: it scales back exactly); only the float64 description is redone in user coordinates
            cert.eigenvalue, cert.left_vector, cert.residual_eig, cert.residual_input = describe_uncontrollable(
                modes.F[l], modes.G[l], cert.eigenvalue)
            return cert
        mine = uncontrollable_mode(modes.F, modes.G, 1.0 if cert.decay_rate is None else cert.decay_rate)
        if mine is not None:
            mine.decay_rate = cert.decay_rate
            return mine
        cert.left_vector = cert.left_vector / scale.state  # w = T^-1 w~ (the residuals are those of the scaled data)
        return cert
    inv = np.tile(1.0 / scale.state, 2)
    Z = cert.multipliers * inv[:, None] * inv[None, :]
    free, dfree, coef, dcoef = interval_data(modes.F, modes.G, modes.plants, modes.gain_map,
                                             scale=congruent_scale(modes, cert.decay_rate))
    check = check_farkas_switched if cert.method == "switched" else check_farkas
    mine = check(Z, free, coef, dfree, dcoef, cert.decay_rate, margin=cert.margin)
    if mine.verified and (mine.any_margin or not cert.any_margin):  # never weaker than the scaled proof
        return mine
    cert.scaled = True
    return cert


def _unscale(res: DesignResult, scale: Scaling, modes: ModeSet) -> DesignResult:
    """Map a design made in scaled coordinates back, and re-check it in the original ones.

    The powers-of-two similarity makes the scaled re-check exact; the original
    coordinates are re-checked too and, when rounding there is too coarse to
    confirm the margin, the certificate stays in scaled coordinates
    (``res.scaling`` says which).
    """
    res.scaling = {"state": scale.state.tolist(), "input": scale.input.tolist(), "certificate": "original"}
    cert = res.certificate
    if cert is not None and cert.kind in ("farkas", "uncontrollable"):
        before = cert.statement()
        res.certificate = _proof_back(cert, scale, modes)
        res.outcome = proof_outcome(res.certificate)
        if res.message.startswith(before):  # say what the returned (user-coordinate) certificate proves
            res.message = res.certificate.statement() + res.message[len(before):]
        if getattr(res.certificate, "scaled", False):
            res.scaling["certificate"] = "scaled"
    if res.gains is None:
        return res
    res.gains = scale.gains_back(res.gains)
    if cert is None or cert.kind in ("farkas", "uncontrollable"):
        return res
    A = modes.closed_loops(res.gains)
    rho = None if cert.decay_rate is None else cert.decay_rate ** (2.0 * modes.eta)
    if cert.kind == "switched":
        original = recheck_switched(scale.quadratic_back(cert.P), A, cert.source, rho=rho)
    elif cert.X is not None:  # the reduced form in the user's coordinates (the rate too), lifted afresh
        original = recheck_lifted(scale.quadratic_back(cert.X), A, modes.n_drop, cert.source, rho=rho)
    else:
        original = recheck_common(scale.quadratic_back(cert.P), A, modes.n_drop, cert.source)
    if original.verified:
        original.decay_rate = cert.decay_rate
        res.certificate = original
    else:
        res.scaling["certificate"] = "scaled"
    return res
