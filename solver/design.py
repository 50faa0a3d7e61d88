"""The design facade: ``design(family, n_drop, method=...)``, like ``scipy.optimize.minimize``."""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .compiled import check_solver, clarabel_fits, design_size, request_solves, resolve_solver, time_left
from .errors import InvalidInput, SolverFailed
from .methods import ccl, lmi, switched
from .methods.common import NEGATIVE, DesignOptions, proof_outcome
from .ipm import blas_threads
from .lyapunov import recheck_common, recheck_lifted, recheck_lifted_exact, recheck_switched
from .network import MAX_MODES, PLANT_SWITCHING, SCHEMES, ModeSet, check_n_drop, mode_count
from .plant import PlantFamily
from .rate_search import (MIN_RATE, carry_multipliers, margin_model, model_root, network_margin_model, next_rate,
                          rate_done, rate_measure, rate_midpoint)
from .result import DesignResult, certified_settling, metric_condition
from .brackets import bracket_back
from .scaling import Scaling, balance, performance_balance

#: Method name -> module with ``run(modes, options)``.
METHODS = {"lmi": lmi, "ccl": ccl, "switched": switched}
FEEDBACK = ("state", "output")
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
    feedback: str = "state",
    sensor_n_drop: int | None = None,
    observer: str = "per_mode",
    noise=None,
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
        the LMI has room left, so gains are far smaller than at the optimum); on a plant whose every mode
        is stable without control, no faster than ``rho^AUTO_OPEN_LOOP_SPEEDUP`` (``rho`` its open-loop
        spectral radius per sample: settling at most 10 times faster than the open loop's).  With
        ``u_max`` (objective "stability"): that rate when the limits hold there, else the fastest slower
        rate where they do (:func:`_limited_auto`).  ``ccl`` has no rate and treats ``"auto"`` as None.  ``None``: plain stability (maximizes the LMI's relative
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
        ``objective`` or ``u_max`` balance the weights and channels too (powers of two) and map the
        bracket back (:class:`solver.scaling.PerformanceScaling`); so do designs on a ``network``
        (docs/design.md §11.1, "Scaling").
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
        on the structured IPM under "AUTO" (Clarabel's proposal too when the IPM's does not certify;
        one mode with ``n_drop = 1``: refined to the Riccati solution), ``res.performance`` holds the bracket (certified upper
        bound, worst periodic pattern as the lower bound, its witness); docs/design.md, "Performance".
        A cost or hinf design that certifies nothing returns the plain design's gains with their bracket
        when the plain design stabilizes; its solver failures are "not_converged", never ``SolverFailed``.
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
    feedback : {"state", "output"}
        ``"output"``: the controller measures ``y = C x`` (``family.C``) over a lossy sensor link and sends
        predictions from an observer's estimate (docs/design.md, "Output feedback"): the gains K are this
        design's, the observer gains ``res.observer_gains`` come from :func:`solver.observer.design_observer`,
        and "stabilized" needs one certificate for the whole loop (``res.joint_certificate``).
    sensor_n_drop : int, optional
        With ``feedback="output"``: at most ``sensor_n_drop - 1`` measurements lost in a row (default ``n_drop``).
    observer : {"per_mode", "common"}
        With ``feedback="output"``: one observer gain per plant mode (the mode is known at the controller) or one.
    noise : (W, V), optional
        With ``feedback="output"``: process and measurement noise covariances; the observer starts from the
        Kalman gains (without losses and with ``objective="cost"``, the pair is the steady-state LQG controller).
    network : solver.Network, optional
        The admissible buffer-age sequences (docs/design.md, "Design on a network").  A bounded-drops
        network runs exactly the design above with its ``n_drop``.  Any other runs the network design
        (:mod:`solver.methods.network_lmi`: node-dependent Lyapunov matrices with a common slack, then cone
        complementarity on the exact node conditions when the convex one certifies nothing), method "lmi"
        and scheme "predictive" only; the convex condition on the structured IPM under "AUTO" (Clarabel as its
        fallback) and "IPM", on Clarabel under "CLARABEL"; cone complementarity on Clarabel; ``decay_rate``
        None, a number, "max" or "auto" (the model search of solver/rate_search.py on the convex
        condition).  ``objective="cost"``/``"hinf"`` (weights, x0, disturbance, output) and ``u_max`` (with
        ``objective="stability"``, x0 and a rate optional) run :mod:`solver.methods.network_performance`
        (docs/design.md §11.3; cost and hinf on the structured IPM under "AUTO"/"IPM", Clarabel as the fallback;
        the input-limited stability design on Clarabel): ``res.performance`` is a certified bracket over every admissible
        run, ``res.invariant_set`` one ellipsoid per node; ``u_max`` with a cost objective is the
        Kothare form (one SDP: the cost bracket from x0 and inputs within u_max on every admissible run
        from it); ``u_max`` with hinf and ``decay_rate`` with a cost or hinf objective are refused.  Outcomes: "stabilized" (a node certificate
        re-checked in float64),
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
        Bad arguments (the field is named in ``err.field``).  A conic solver's failure is never raised
        (nor reported as "infeasible"): the last iterate's gains and multipliers are re-checked, Clarabel
        tries under ``solver="AUTO"``, and without a proof the outcome is "not_converged" naming it.
    """
    if not isinstance(family, PlantFamily):
        raise InvalidInput("family must be a PlantFamily", ("family",))
    if feedback not in FEEDBACK:
        raise InvalidInput(f"feedback must be one of {FEEDBACK}, got {feedback!r}", ("feedback",))
    if feedback == "output":
        if network is not None:
            raise InvalidInput("output feedback on a network is not supported yet: use n_drop and sensor_n_drop",
                               ("network",))
        from .observer import complete_output_design, prepare_output_design

        sensor_n_drop = prepare_output_design(family, n_drop, sensor_n_drop, observer, noise)
        res = design(family, n_drop, method, solver=solver, margin=margin, max_iter=max_iter, time_limit=time_limit,
                     callback=callback, ccl_start=ccl_start, decay_rate=decay_rate, rate_tol=rate_tol,
                     plant_switching=plant_switching, scheme=scheme, max_modes=max_modes, scaling=scaling,
                     objective=objective, weights=weights, x0=x0, disturbance=disturbance, output=output,
                     u_max=u_max, max_memory=max_memory)
        return complete_output_design(res, family, sensor_n_drop, observer, noise, plant_switching, scheme,
                                      time_limit)
    for name, value in (("sensor_n_drop", sensor_n_drop), ("noise", noise)):
        if value is not None:
            raise InvalidInput(f"{name} applies to output feedback: pass feedback=\"output\"", (name,))
    if network is not None:
        from .networks import check_network

        n_drop = _network_n_drop(network, n_drop)
        network = check_network(network)
        if not network.is_bounded_drops:
            try:
                return _counted(_network_design(
                    family, network, method, solver=solver, margin=margin, max_iter=max_iter, time_limit=time_limit,
                    callback=callback, ccl_start=ccl_start, decay_rate=decay_rate, rate_tol=rate_tol,
                    plant_switching=plant_switching, scheme=scheme, scaling=scaling, objective=objective,
                    performance=(weights, x0, disturbance, output, u_max), max_memory=max_memory))
            except SolverFailed as err:  # a valid request gets a verdict, never the solver's exception
                return DesignResult(outcome="not_converged", gains=None, certificate=None, method="network_lmi",
                                    n_drop=network.n_drop, solver=str(solver).upper(),
                                    solver_status=getattr(err, "status", "") or "", plant_switching=plant_switching,
                                    message=f"the solver gave up and no verdict is proven: {err}",
                                    network=network.to_dict())
    elif n_drop is None:
        raise InvalidInput("n_drop is required (or give a network)", ("n_drop",))
    if method not in METHODS:
        raise InvalidInput(f"method must be one of {sorted(METHODS)}, got {method!r}", ("method",))
    _check_options(margin, max_iter, time_limit, ccl_start, decay_rate, rate_tol, method)
    if scaling not in ("auto", "none"):
        raise InvalidInput("scaling must be 'auto' or 'none'", ("scaling",))
    check_budget(method, family, n_drop, plant_switching, scheme, max_modes, max_memory, time_limit, solver=solver,
                 objective=objective, decay_rate=decay_rate, rate_tol=rate_tol, u_max=u_max, disturbance=disturbance,
                 output=output)
    growth = unstable_growth(family)
    if growth is not None and growth.per_sample_log > HOPELESS_GROWTH_LOG:
        raise InvalidInput(growth.explain(n_drop, "no loop can be certified at this sampling period in double "
                                          "precision"), ("sampling_period",))
    modes = ModeSet.from_family(family, n_drop, plant_switching=plant_switching, scheme=scheme,
                                max_modes=max_modes)
    try:
        res = _design(family, modes, method, n_drop, decay_rate, rate_tol, margin, max_iter, time_limit, callback,
                      ccl_start, scaling, solver, objective, weights, x0, disturbance, output, u_max, max_modes,
                      plant_switching, scheme, max_memory)
        if network is not None and res is not None:
            res.network = network.to_dict()
        if res is not None and res.outcome == "not_converged" and growth is not None and \
                growth.per_sample_log > 1.0 and "solver gave up" in res.message:
            # the solver gave up on a plant that grows a lot between samples: the likely cause is the sampling
            # period (a unit mistake, or too slow a loop), which the user can fix; say that first
            res.message = growth.explain(n_drop, "no design was certified") + f" (the solver: {res.message})"
        return res
    except SolverFailed as err:
        # A valid request gets a verdict, never the solver's exception (issue 29): the methods turn their own
        # failures into verdicts (the last iterate's re-checks, Clarabel under "AUTO"); this is the last guard.
        if growth is None or growth.per_sample_log <= 1.0:
            message = f"the solver gave up and no verdict is proven: {err}"
        else:
            # The solver gave up on a plant that grows a lot between samples: the likely cause is the sampling
            # period (a unit mistake, or too slow a loop), which the user can fix; say that, as a verdict.
            message = growth.explain(n_drop, "no design was certified") + f" (the solver: {err})"
        return DesignResult(outcome="not_converged", gains=None, certificate=None, method=method,
                            n_drop=modes.n_drop, solver=str(solver).upper(),
                            solver_status=getattr(err, "status", "") or "",
                            message=message,
                            scheme=modes.scheme, plant_switching=modes.plant_switching,
                            mode_labels=[modes.label(s) for s in range(modes.n_modes)])


def _design(family, modes, method, n_drop, decay_rate, rate_tol, margin, max_iter, time_limit, callback, ccl_start,
            scaling, solver, objective, weights, x0, disturbance, output, u_max, max_modes, plant_switching,
            scheme, max_memory=None) -> DesignResult:
    if objective == "stability" and u_max is not None and decay_rate == "auto" and method == "lmi" and \
            all(v is None for v in (weights, disturbance, output)):
        def plain_auto(left):
            return _design(family, modes, method, n_drop, "auto", rate_tol, margin, max_iter, left, None, ccl_start,
                           scaling, solver, "stability", None, None, None, None, None, max_modes, plant_switching,
                           scheme, max_memory)

        return _counted(_limited_auto(family, modes, x0, u_max, solver, margin, max_iter, time_limit, callback,
                                      scaling, plain_auto, max_memory))
    if objective != "stability" or any(v is not None for v in (weights, x0, disturbance, output, u_max)):
        res = _performance_design(family, modes, method, objective, weights, x0, disturbance, output, u_max, solver,
                                  margin, max_iter, time_limit, callback, decay_rate, scaling, max_memory)
        if res.outcome == "stabilized" and res.decay_rate is not None and res.settling is None:
            res.settling = certified_settling(res.decay_rate, metric_condition(res.certificate, res.scaling),
                                              family.sampling_period)
        return _counted(res)
    options = DesignOptions(
        solver=check_solver(solver),
        margin=float(margin),
        max_iter=int(max_iter),
        time_limit=None if time_limit is None else float(time_limit),
        callback=callback,
        ccl_start=ccl_start,
        decay_rate=None if decay_rate in (None, "max", "auto") else float(decay_rate),
        max_memory=max_memory,
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
    if res is not None and res.outcome == "not_converged" and scale is None and "solver gave up" in res.message:
        res.message += "; scaling='none' kept the user's coordinates: scaling='auto' balances them first"
    return _counted(res)


def _counted(res: DesignResult) -> DesignResult:
    """Fill ``res.solve_count`` from the run's accounting (every method's clock counts its solves)."""
    if res is not None and res.solve_count is None:
        res.solve_count = int(res.timings.get("solves", 0) or 0)
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
    from .methods import network_performance

    weights, x0, disturbance, output, u_max = performance
    x0, u_max = network_performance.check_request(network, objective, weights, x0, disturbance, output, u_max,
                                                  decay_rate, family.n_states, family.n_inputs)
    check_solver(solver)
    # the performance designs on a network (docs/design.md §11.3) are one SDP on the IPM (Clarabel under "AUTO" as
    # the fallback), the input-limited stability design one on Clarabel: each sized as the path it runs
    performance_design = objective != "stability" or u_max is not None
    pw, pz = performance_dims(disturbance, output)
    limits_only = objective == "stability" and u_max is not None

    shape = ("lmi", family.n_states, family.n_inputs, family.n_modes, network.n_drop, plant_switching)
    request = dict(network=network, objective=objective, u_max=u_max, n_disturbances=pw, n_outputs=pz,
                   decay_rate=None if performance_design else decay_rate, rate_tol=rate_tol)
    size = design_size(*shape, solver="CLARABEL" if limits_only else solver, **request)
    size.check(max_memory, float("inf") if time_limit is not None else None)
    # "AUTO" falls back to Clarabel only where Clarabel fits the memory budget too
    fallback = str(solver).upper() != "AUTO" or clarabel_fits(*shape, max_memory=max_memory, **request)
    start = time.perf_counter()
    if u_max is not None and objective == "stability":  # docs/design.md §11.3
        with blas_threads(1):
            res = network_performance.run_limits(family, network, u_max, x0=x0,
                                                 decay_rate=None if decay_rate == "auto" else decay_rate,
                                                 plant_switching=plant_switching, scaling=scaling,
                                                 time_limit=time_limit, callback=callback, solver=solver)
        res.network = network.to_dict()
        return res
    if objective != "stability":  # docs/design.md §11.3
        with blas_threads(1):
            res = network_performance.run(family, network, objective, weights=weights, x0=x0,
                                          disturbance=disturbance, output=output, u_max=u_max,
                                          plant_switching=plant_switching, scaling=scaling,
                                          time_limit=time_limit, callback=callback, solver=solver,
                                          fallback=fallback)
        res = _performance_proof(family, network, res, objective, plant_switching, start, time_limit)
        res.network = network.to_dict()
        if getattr(res.certificate, "form", None) == "augmented" and family.n_modes > 1 and \
                plant_switching == "per_interval":
            res.message += ("; the augmented certificate lets the plant mode switch at every sample (it covers "
                            "per_interval)")
        return res
    with blas_threads(1):
        prob = network_lmi.build_problem(family, network, plant_switching)
        unc = uncontrollable_mode(np.asarray(family.F, float), np.asarray(family.G, float), 1.0)
        if unc is not None:  # an unstable mode no input reaches: no gains at all, on any network
            res = DesignResult(outcome="infeasible", gains=None, certificate=unc, method="network_lmi",
                               n_drop=network.n_drop, plant_switching=plant_switching,
                               message=f"{unc.statement()}: no gains stabilize the loop on {network.describe()}")
        else:
            # balanced coordinates (powers of two, exact), as the plain design (docs/design.md §11.1, "Scaling")
            scale = balance(family) if scaling == "auto" else None
            if scale is None or scale.is_identity:
                res = _network_rates(family, network, prob, decay_rate, rate_tol, time_limit, callback, max_iter,
                                     plant_switching, start, solver, fallback)
            else:
                scaled = scale.family(family)
                res = _network_rates(scaled, network, network_lmi.build_problem(scaled, network, plant_switching),
                                     decay_rate, rate_tol, time_limit, callback, max_iter, plant_switching, start,
                                     solver, fallback)
                res = network_lmi.to_user_coordinates(res, scale, family, network, prob, plant_switching,
                                                      time_left(time_limit, start, floor=1e-3))
        if res.outcome not in ("stabilized", "infeasible") and network_lmi.contains_bounded_drops(network):
            res = _bounded_drops_proof(family, network, res, plant_switching, start, time_limit)
    res.network = network.to_dict() if hasattr(network, "to_dict") else None
    if (prob.form == "augmented" and family.n_modes > 1 and plant_switching == "per_interval"
            and not (getattr(res, "fixed_rate_fallback", False)
                     and not isinstance(res.certificate, network_lmi.NodeCertificate))):
        # (not for the fixed-rate fallback's certificate on the product automaton: the design's own matrices failed,
        # and that automaton follows per_interval itself)
        res.message += "; the augmented certificate lets the plant mode switch at every sample (it covers per_interval)"
    res.timings["total"] = time.perf_counter() - start
    if res.outcome == "stabilized" and res.decay_rate is not None:
        res.settling = certified_settling(res.decay_rate, metric_condition(res.certificate, res.scaling),
                                          family.sampling_period)
    return res


def _bounded_drops_proof(family, network, res: DesignResult, plant_switching, start, time_limit) -> DesignResult:
    """"infeasible" when the network admits every bounded-drops run and today's design is proven infeasible there.

    Gains that stabilize the network stabilize every run it admits, so a proof that none stabilizes the
    bounded-drops runs (in the sense of that proof) carries over; the converse direction would be wrong.
    """
    remaining = time_left(time_limit, start)
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


def _performance_proof(family, network, res: DesignResult, objective: str, plant_switching, start,
                       time_limit) -> DesignResult:
    """A performance design on ``network`` that found no gains, answered "infeasible" where the stability design on
    the same network is (:func:`_bounded_drops_proof`: the bounded-drops runs it admits), with that proof and in its
    sense (docs/design.md §5, "Infeasible or marginal"; §11.3): gains with a certified bound stabilize those runs."""
    from .methods import network_lmi

    if res.gains is not None or res.outcome not in ("not_certified", "not_converged") or \
            not network_lmi.contains_bounded_drops(network):
        return res
    proof = _bounded_drops_proof(family, network, res, plant_switching, start, time_limit)
    if proof is res:
        return res
    proof.objective = objective
    proof.timings = dict(res.timings, total=time.perf_counter() - start)
    proof.message += (f"; the stability design's verdict on this network, which the {objective} design shares (its "
                      "gains would have to pass the same proof)")
    return proof


def _network_rates(family, network, prob, decay_rate, rate_tol, time_limit, callback, max_iter, plant_switching,
                   start, solver="AUTO", fallback=True) -> DesignResult:
    """``decay_rate`` on a network: a number or None directly; "max"/"auto" by bisection on the convex condition.

    The bisection accepts a rate only with a re-checked certificate; a step without one (not proven
    infeasible) counts as a failure for the bisection only.  When the convex condition certifies nothing at
    rate 1, "auto" falls back to plain stability (with the cone complementarity fallback); "max" reports it.
    """
    from .methods import network_lmi

    notes: list = []

    def left():
        return time_left(time_limit, start, floor=1e-3)

    def recheck(gains, rate):
        """Plain stability: the network analysis must accept the gains (its own certificate is kept)."""
        if rate is not None:
            return True, None  # analyze() has no rate: the float64 re-check of the node matrices at the rate
        from .analysis import analyze

        try:
            # the verdict only: no CJSR bisection, a short cycle search (the design's gains are expected stable)
            rep = analyze(family, gains, network=network, plant_switching=plant_switching, bounds="none",
                          max_product_length=2)
        except InvalidInput as err:  # the analysis refuses the size up front: the design's own re-check stands
            notes.append(f"analyze(network=) refused the size ({err}); the design's float64 re-check of its node "
                         "matrices is the certificate")
            return True, None
        except SolverFailed:
            return False, None
        return rep.stable is True, rep.certificate

    solved = []  # (rate, NetworkSolution) of the IPM's solves, for the warm starts

    def one(rate, use_ccl=True, probe=False):
        """One design at ``rate``, warm started from the nearest rate solved; a probe of the search stops once the
        margin's sign is settled and is a rate search's step (``rate_search``: no per-block solve, no fixed-gain
        node analysis; docs/design.md 11.1)."""
        warm = None
        if rate is not None and WARM_PROBES and solved:
            from .ipm.network_blocks import warm_start

            near = min(solved, key=lambda p: abs(np.log(p[0] / rate)))[1]
            warm = warm_start(near.ipm, WARM_SHIFT, WARM_BLEND)
        try:
            res = network_lmi.run(family, network, decay_rate=rate, plant_switching=plant_switching,
                                  time_limit=left(), callback=callback, max_iter=max_iter,
                                  use_ccl=use_ccl and fallback, prob=prob,
                                  recheck=recheck, solver=solver, fallback=fallback, start=warm,
                                  sign_only=probe and SIGN_ONLY_PROBES, rate_search=probe)
        except SolverFailed as err:
            if rate is None:  # plain stability: design() turns it into "not_converged"
                raise
            # a rate the solvers give up on (near deadbeat its blocks carry rate^-length ~ 1e8) is a failed step
            # of the search, and the design at the target falls back to the fastest certified one (hold-out
            # draw_family 9818 on weakly_hard(1, 3, 3): a probe at 0.0016 raised, after six certified down to 0.011)
            return DesignResult(outcome="not_converged", gains=None, certificate=None, method="network_lmi",
                                n_drop=network.n_drop, plant_switching=plant_switching,
                                message=f"the solvers gave up at decay rate {rate:.6g}: {err}")
        sdp = getattr(res, "sdp", None)
        if rate is not None and sdp is not None and sdp.ipm is not None:
            solved.append((rate, sdp))
        return res

    if decay_rate not in ("max", "auto"):
        res = one(None if decay_rate is None else float(decay_rate))
        if notes and res.outcome == "stabilized":
            res.message += "; " + notes[-1]
        if not fallback and res.outcome != "stabilized":
            res.message += ("; Clarabel (the fallback and the cone complementarity iteration) was not run: its memory "
                            "estimate is over the budget")
        return res
    best = one(1.0, use_ccl=False, probe=True)
    if best.outcome != "stabilized":
        plain = one(None)
        plain.message += f"; decay_rate={decay_rate!r}: the convex condition certifies no decay rate"
        return plain
    tol = AUTO_SETTLING_TOLERANCE if decay_rate == "auto" else rate_tol
    settling = decay_rate == "auto"

    def done(lo, hi):
        return rate_done(lo, hi, tol, settling)

    def midpoint(lo, hi):
        return rate_midpoint(lo, hi, settling)

    solves = best.timings.get("solves", 0)
    lo, hi, tries = 0.0, 1.0, [{"decay_rate": 1.0, "outcome": "stabilized"}]
    t_hi, t_lo = best.sdp.t, None
    previous, from_above, anchor, stalls = None, True, 1.0, 0
    # the search of the plain design (solver/rate_search.py): the root of the margin's first-order model from
    # the last certified solve's multipliers, safeguarded by the bracket; every third stalled step bisects
    while not done(lo, hi) and hi > MIN_RATE and (time_limit is None or time.perf_counter() - start < time_limit):
        if RATE_SEARCH == "model" and stalls < 3:
            model = network_margin_model(prob, best.sdp, hi)
            mid, how = next_rate(max(lo, MIN_RATE if settling else 0.0), hi, t_lo, t_hi, model, done,
                                 lambda a, b: 0.5 * (a + b), from_above, previous)
            if model is not None and (previous is None or previous[0] != hi):
                previous = (hi, model_root(model, hi, max(lo, 1e-12), hi))
        else:
            mid, how = midpoint(lo, hi), "bisect"
        res = one(mid, use_ccl=False, probe=True)
        solves += res.timings.get("solves", 0)
        tries.append({"decay_rate": mid, "outcome": res.outcome, "step": how})
        sdp = getattr(res, "sdp", None)
        if res.outcome == "stabilized":
            hi, best, t_hi = mid, res, sdp.t
        else:
            lo, t_lo = mid, None if sdp is None else sdp.t
        from_above = res.outcome == "stabilized"
        if hi - lo <= 0.5 * anchor or how == "bisect":
            anchor, stalls = hi - lo, 0
        else:
            stalls += 1
    fastest = hi
    if decay_rate == "auto" and hi < 1.0:
        target = fastest ** (1.0 / AUTO_SLOWDOWN)
        res = one(target, use_ccl=False)
        solves += res.timings.get("solves", 0)
        tries.append({"decay_rate": target, "outcome": res.outcome})
        if res.outcome == "stabilized":
            best = res
    best.rate_search = tries
    best.timings["solves"] = solves
    best.rate_bracket = {"lower": lo, "upper": fastest, "lower_proven": False, "relative_tolerance": tol}
    best.message += (f"; decay_rate={decay_rate!r}: smallest rate certified by the convex condition {fastest:.6g}, "
                     f"bracket [{lo:.6g}, {fastest:.6g}] (lower end not proven; {len(tries)} designs)")
    return best


#: Above this growth per sample (log of the largest open-loop eigenvalue modulus, i.e. h over the fastest unstable
#: time constant), the discretized plant's entries are so large (e^30 ~ 1e13) that no certificate survives float64.
HOPELESS_GROWTH_LOG = 30.0


@dataclass(frozen=True)
class UnstableGrowth:
    """The fastest-growing open-loop mode of a family: ``per_sample_log = ln |lambda|max = h / tau``."""

    per_sample_log: float
    mode: int
    sampling_period: float | None

    @property
    def time_constant(self) -> float | None:
        return None if self.sampling_period is None else self.sampling_period / self.per_sample_log

    def explain(self, n_drop: int, verdict: str) -> str:
        g = self.per_sample_log
        factor = f"{np.exp(g):.3g}" if g < 700 else f"e^{g:.0f}"
        lost = max(int(n_drop) - 1, 0)
        burst = ""
        if lost:
            gb = g * (lost + 1)
            burst = f", and {np.exp(gb):.3g} over a burst of {lost} lost samples" if gb < 700 else \
                f", and e^{gb:.0f} over a burst of {lost} lost samples"
        if self.sampling_period is None:
            return (f"{verdict}: the open-loop plant (mode {self.mode}) grows by a factor {factor} per sample{burst}; "
                    "sample faster or lower n_drop")
        h, tau = self.sampling_period, self.time_constant
        hint = ""
        if h >= 0.5 and h / 1000 < tau:
            hint = f" Is sampling_period in seconds? Did you mean {h / 1000:g} s ({h:g} ms)?"
        return (f"{verdict}: h = {h:g} s is {h / tau:.3g} times the plant's fastest unstable time constant, "
                f"{tau:.3g} s (mode {self.mode}): between two samples it grows by a factor {factor}{burst}. Sample "
                f"well below {tau:.2g} s (or lower n_drop).{hint}")


def unstable_growth(family: PlantFamily) -> UnstableGrowth | None:
    """The family's fastest open-loop growth per sample, or None when every mode is Schur stable."""
    best = None
    for i, F in enumerate(np.asarray(family.F, dtype=np.float64)):
        with np.errstate(all="ignore"):
            rho = float(np.max(np.abs(np.linalg.eigvals(F)))) if np.all(np.isfinite(F)) else float("inf")
        g = float(np.log(rho)) if rho > 0 else -np.inf
        if g > 0 and (best is None or g > best[0]):
            best = (g, i)
    if best is None:
        return None
    return UnstableGrowth(best[0], best[1], family.sampling_period)




def _performance_design(family: PlantFamily, modes: ModeSet, method, objective, weights, x0, disturbance, output,
                        u_max, solver, margin, max_iter, time_limit, callback, decay_rate,
                        scaling: str = "auto", max_memory=None) -> DesignResult:
    """Cost, H-infinity and input-limited designs (:mod:`solver.methods.performance`), in balanced coordinates.

    The scaling layer (:func:`solver.scaling.performance_balance`): states, inputs and the cost's size
    balanced by powers of two, the design made there, gains, certificates and the bracket mapped back once
    and re-checked in the user's coordinates.  A cost or H-infinity design that certifies nothing falls back
    to the plain design's gains with their bracket (a performance design stabilizes whenever the plain one
    does); a solver failure is a "not_converged" verdict, never an exception.
    """
    from .methods import performance

    lifted, x0, u_max = performance.prepare(modes, method, objective, weights, x0, disturbance, output, u_max,
                                            decay_rate, solver)
    rate = None if decay_rate in (None, "auto") else float(decay_rate)  # "auto": prepare's note
    options = DesignOptions(solver=check_solver(solver), margin=float(margin), max_iter=int(max_iter),
                            time_limit=None if time_limit is None else float(time_limit), callback=callback,
                            decay_rate=rate, max_memory=max_memory)
    start = time.perf_counter()
    scale = performance_balance(family, lifted) if scaling == "auto" else None
    if scale is not None and scale.is_identity:
        scale = None
    with blas_threads(1):
        try:
            res = _performance_scaled(scale, lifted, options, objective, x0, u_max)
        except SolverFailed as err:
            why = f"the {objective} design's solver failed: {err}" if u_max is None else \
                _input_limit_message(u_max, x0, str(err))
            res = DesignResult(outcome="not_converged", gains=None, certificate=None, method="lmi",
                               n_drop=modes.n_drop, message=why,
                               scheme=modes.scheme, plant_switching=modes.plant_switching,
                               mode_labels=[modes.label(s) for s in range(modes.n_modes)])
            res.objective = objective
        if u_max is not None and res.outcome != "stabilized" and _SOLVER_FAILED.match(res.message or ""):
            res.message = _input_limit_message(u_max, x0, res.message)
        if u_max is not None and objective == "stability" and res.outcome == "not_converged":
            return _limited_plain_fallback(res, family, modes, x0, u_max, solver, margin, time_limit, start,
                                           rate, scaling)
        if res.outcome in ("stabilized", "infeasible", "marginal") or objective not in ("cost", "hinf") \
                or u_max is not None:
            return res
        plain = _plain_design(family, modes, solver, margin, None, time_limit, start, scaling)
        if plain is None or plain.outcome != "stabilized":
            return res
        try:
            if scale is None:
                plain.performance = performance.bracket(lifted, plain.gains, objective, x0=x0, solver=solver)
            else:  # the fixed-gain LMI in balanced coordinates too
                t, u = scale.plain.state, scale.plain.input
                scaled = performance.bracket(scale.lifted(lifted), plain.gains / u[None, :, None] * t[None, None, :],
                                             objective, x0=scale.x0(x0), solver=solver,
                                             weight=scale.trace_weight if objective == "cost" and x0 is None else None)
                plain.performance = bracket_back(scaled, scale, lifted, plain.gains, x0)
        except SolverFailed:
            return res
        if not plain.performance.verified:  # "stabilized" only with the bracket the objective asked for
            res.message += f"; the plain design's gains have no certified {objective} bound either"
            return res
        plain.objective = objective
        plain.message = (f"{res.message}; the plain design's gains instead: {plain.message}; "
                         f"{plain.performance.message}")
        return plain


def _plain_design(family: PlantFamily, modes: ModeSet, solver, margin, rate, time_limit, start,
                  scaling) -> DesignResult | None:
    """The plain ``lmi`` design of a performance design's fallback in what is left of ``time_limit``; None when no
    time is left or it raised (``InvalidInput``: the size guard, which the performance design passed anyway)."""
    remaining = time_left(time_limit, start)
    if remaining is not None and remaining <= 0:
        return None
    try:
        return design(family, modes.n_drop, "lmi", solver=solver, margin=margin, decay_rate=rate,
                      time_limit=remaining, plant_switching=modes.plant_switching, scheme=modes.scheme,
                      scaling=scaling, max_modes=max(MAX_MODES, modes.n_modes))
    except (SolverFailed, InvalidInput):
        return None


def _limited_plain_fallback(res: DesignResult, family: PlantFamily, modes: ModeSet, x0, u_max, solver, margin,
                            time_limit, start, rate, scaling) -> DesignResult:
    """An input-limited design whose SDP certified nothing: the plain design's gains and invariant ellipsoid.

    The plain design's reduced certificate X (``A_s' X A_s < X`` for every interval map, §3 and §5) makes every
    sublevel set of ``x' X x`` invariant at packet times, so :func:`solver.brackets.check_invariant` (float64
    re-check) scales it until every buffered input meets its limit (docs/design.md §8.2, "Input limits"); with
    x0 the set must contain it.  Without such a set ``res`` (not_converged) is returned with the reason.
    """
    from .brackets import check_invariant, limits_note

    plain = _plain_design(family, modes, solver, margin, rate, time_limit, start, scaling)
    if plain is None:
        return res
    cert = plain.certificate
    if plain.outcome != "stabilized" or cert is None or getattr(cert, "X", None) is None:
        return res
    X = np.asarray(cert.X, dtype=np.float64)
    if plain.scaling and plain.scaling.get("certificate") == "scaled":  # x = T x~: X = T^-1 X~ T^-1
        t = np.asarray(plain.scaling["state"], dtype=np.float64)
        X = X / t[:, None] / t[None, :]
    invariant, why = check_invariant(X, modes.closed_loops(plain.gains), plain.gains, u_max, x0,
                                     plant=None if modes.F is None else (modes.F, modes.G, modes.plants))
    if invariant is None:
        res.message += f"; the plain design's gains stabilize, but their ellipsoid is not re-checked: {why}"
        return res
    plain.invariant_set = invariant
    plain.message = (f"{res.message}; the plain design's gains instead: {plain.message}; "
                     f"{limits_note(invariant, 'its invariant set (re-checked)')}")
    return plain


#: ``decay_rate="auto"`` with ``u_max``: the limited rate search stops when its bracket is within this relative
#: tolerance in settling time (as the plain default's, :data:`AUTO_SETTLING_TOLERANCE`).
LIMITED_SETTLING_TOLERANCE = 0.1
#: ... and looks no slower than this rate's settling time (``-1 / ln lambda`` samples; 1e7 samples).
LIMITED_SLOWEST_LOG = 1e-7


def _limited_auto(family: PlantFamily, modes: ModeSet, x0, u_max, solver, margin, max_iter, time_limit, callback,
                  scaling: str, plain_auto, max_memory=None) -> DesignResult:
    """The default design (``decay_rate="auto"``) with input limits: a certified rate, then the limits.

    Without a rate, the input-limited SDP (largest ball in the invariant ellipsoid) is free to return a loop
    that barely decays (the CTMS pendulum, u_max = 5 N: spectral radius 0.9998 per sample, the cart-position
    gain 0, settling unbounded).  So, as the default without limits: first the plain default's rate
    (``plain_auto``: 1.5x the settling time of the fastest certified one); when the limits hold there from
    ``x0`` (and on the invariant set), that design.  Otherwise the fastest rate at which they do, searched
    upward from it geometrically in settling time (each step a re-checked design or a Farkas proof of the
    limits), to :data:`LIMITED_SETTLING_TOLERANCE`.  When no rate is certified under the limits, the design
    without a rate (today's) with a note saying so: "stabilized" then bounds no settling time.
    """
    from .methods import performance

    performance.prepare(modes, "lmi", "stability", None, x0, None, None, u_max, None, solver)  # bad input first
    start = time.perf_counter()

    def left():
        return time_left(time_limit, start, floor=1e-3)

    def out_of_time():
        return time_limit is not None and time.perf_counter() - start >= time_limit

    def limited(rate):
        res = _performance_design(family, modes, "lmi", "stability", None, x0, None, None, u_max, solver, margin,
                                  max_iter, left(), callback, rate, scaling, max_memory)
        search.append({"decay_rate": rate, "outcome": res.outcome,
                       "proof": None if res.certificate is None else res.certificate.kind, "u_max": True})
        spent["solves"] += int(res.timings.get("solves", 0) or 0)
        return res

    search: list = []
    plain = plain_auto(left())
    spent = {"solves": int(plain.timings.get("solves", 0) or 0), "start": start}
    search.extend(plain.rate_search or [])
    if plain.outcome != "stabilized" or plain.decay_rate is None or not plain.decay_rate < 1.0 or out_of_time():
        res = limited(None)
        res.message += (f"; decay_rate='auto' with u_max: the design without limits certified no decay rate "
                        f"({plain.outcome}), so none is asked for here")
        return _limited_done(res, family, search, None, spent)
    default = float(plain.decay_rate)
    first = limited(default)
    if first.outcome == "stabilized":
        first.message += (f"; decay_rate='auto' with u_max: the default loop's rate {default:.6g} per sample "
                          f"(decay_rate='auto' without limits), the limits hold there")
        return _limited_done(first, family, search, {"lower": None, "upper": default, "lower_proven": False,
                                                     "default_rate": default}, spent)
    # the limits bind at the default rate: the fastest slower rate where they hold, geometric in settling time
    s_lo, lo_res, best = -np.log(default), first, None  # s: -ln(lambda) per sample, lo: fails, hi: certified
    s = s_lo
    while best is None and s > LIMITED_SLOWEST_LOG and not out_of_time():
        s = max(s / 4.0, LIMITED_SLOWEST_LOG)
        res = limited(float(np.exp(-s)))
        if res.outcome == "stabilized":
            best, s_hi = res, s
        else:
            s_lo, lo_res = s, res
    if best is None:
        res = limited(None)
        res.message += (f"; decay_rate='auto' with u_max: no decay rate was certified under the limits (tried "
                        f"{sum(1 for e in search if e.get('u_max')) - 1} rates from the default loop's {default:.6g} per sample up to "
                        f"{np.exp(-s):.9g}; at {np.exp(-s_lo):.9g}: {lo_res.outcome}), so this design asks for "
                        f"none" + ("" if res.outcome != "stabilized" else ": it is stable, but no settling time is "
                                   "bounded (try larger u_max, a smaller x0 or a smaller n_drop)"))
        return _limited_done(res, family, search, None, spent)
    while s_lo > (1 + LIMITED_SETTLING_TOLERANCE) * s_hi and not out_of_time():
        s = float(np.sqrt(s_lo * s_hi))
        res = limited(float(np.exp(-s)))
        if res.outcome == "stabilized":
            best, s_hi = res, s
        else:
            s_lo, lo_res = s, res
    lo_rate = float(np.exp(-s_lo))
    proven = lo_res.outcome in NEGATIVE
    best.message += (f"; decay_rate='auto' with u_max: the limits do not hold at the default loop's rate "
                     f"{default:.6g} per sample ({first.outcome}), so the fastest rate where they do, to "
                     f"{LIMITED_SETTLING_TOLERANCE:g} in settling time: {best.decay_rate:.6g} (at {lo_rate:.6g}: "
                     f"{lo_res.outcome}" + (", proven" if proven else ", not proven impossible") + ")")
    return _limited_done(best, family, search, {"lower": lo_rate, "upper": float(best.decay_rate),
                                                "lower_proven": proven, "default_rate": default,
                                                "relative_tolerance": LIMITED_SETTLING_TOLERANCE}, spent)


def _limited_done(res: DesignResult, family: PlantFamily, search: list, bracket, spent: dict) -> DesignResult:
    """The limited default's search record, its cost and, with a certified rate, the settling time it guarantees."""
    res.rate_search = search
    res.rate_bracket = bracket if res.outcome == "stabilized" else None
    if res.outcome == "stabilized" and res.decay_rate is not None:
        res.settling = certified_settling(res.decay_rate, metric_condition(res.certificate, res.scaling),
                                          family.sampling_period)
    res.timings.update(solves=spent["solves"], total=time.perf_counter() - spent["start"])
    return res


def _performance_scaled(scale, lifted, options: DesignOptions, objective: str, x0, u_max) -> DesignResult:
    """One performance design in the coordinates of ``scale`` (None: the user's), mapped back."""
    from .methods import performance

    modes = lifted.modes
    if scale is None:
        return performance.run(lifted, options, objective, x0, u_max)
    weight = scale.trace_weight if objective == "cost" and x0 is None else None
    res = performance.run(scale.lifted(lifted), options, objective, scale.x0(x0), scale.u_max(u_max),
                          trace_weight=weight)
    if u_max is not None and res.outcome != "stabilized":
        # the limits' Farkas proofs are stated and bounded (radius) in the user's coordinates
        return performance.run(lifted, options, objective, x0, u_max)
    res = _unscale(res, scale.plain, modes)
    res.scaling.update(cost=scale.cost, disturbance=scale.disturbance, output=scale.output)
    if res.performance is not None and res.gains is not None:
        scaled = res.performance
        res.performance = bracket_back(scaled, scale, lifted, res.gains, x0)
        res.message = res.message.replace(scaled.message, res.performance.message)
    if res.invariant_set is not None:
        res.invariant_set = scale.quadratic_back(res.invariant_set)
    return res


#: A message that begins with the conic solver's own failure ("CLARABEL failed: ...").
_SOLVER_FAILED = re.compile(r"^(CLARABEL|SCS|IPM|AUTO)\b.*\bfail", re.I)


def _input_limit_message(u_max, x0, cause: str) -> str:
    """An input-limited design the solver gave up on: the limits first (what the user can change), the solver's
    words after (they used to be the whole message: "CLARABEL failed ...")."""
    limits = ", ".join(f"{float(u):.6g}" for u in np.ravel(u_max))
    start = "" if x0 is None else f" from x0 = [{', '.join(f'{float(v):.6g}' for v in np.ravel(x0))}]"
    return (f"no design was certified within the input limits u_max = [{limits}]{start}: the limits may be too "
            f"tight for this drop bound (try larger u_max, a smaller x0 or a smaller n_drop), or the problem is "
            f"badly scaled (give the states in units where they are of order 1); the conic solver reported: {cause}")


def solve_count(method: str, decay_rate, rate_tol: float, max_iter: int) -> int:
    """How many SDPs a design solves at least (:func:`solver.compiled.request_solves`; ``max_iter`` is not used:
    how many ccl iterations run is not known before they run, and the time limit stops them if needed)."""
    return request_solves(method, decay_rate, rate_tol)


def performance_dims(disturbance, output) -> tuple[int, int | None]:
    """``(p_w, p_z)`` of an H-infinity request for :func:`solver.compiled.design_size` (1 and None when not
    given or malformed: the checks after the estimate name a malformed field)."""
    def rows(x, axis):
        try:
            a = np.asarray(x, dtype=float)
        except (TypeError, ValueError, IndexError):
            return None
        return int(a.shape[axis]) if a.ndim in (2, 3) else None

    pw = None if disturbance is None else rows(disturbance, -1)
    pz = None  # output is (C, D) or one pair per mode: p_z is the rows of C
    if isinstance(output, (list, tuple)) and output:
        pz = rows(output[0], 0) or (rows(output[0][0], 0) if isinstance(output[0], (list, tuple)) else None)
    return pw or 1, pz


def request_size(method: str, family: PlantFamily, n_drop: int, plant_switching: str = "per_interval",
                 scheme: str = "predictive", solver: str = "AUTO", *, objective: str = "stability", decay_rate=None,
                 rate_tol: float = 1e-3, u_max=None, disturbance=None, output=None, network=None,
                 channel_size: int = 0):
    """:func:`solver.compiled.design_size` of a request on ``family`` (the disturbance and output give p_w, p_z)."""
    pw, pz = performance_dims(disturbance, output)
    return design_size(method, family.n_states, family.n_inputs, family.n_modes, n_drop, plant_switching, scheme,
                       solver, network=network, objective=objective, decay_rate=decay_rate, rate_tol=rate_tol,
                       u_max=u_max, n_disturbances=pw, n_outputs=pz, channel_size=channel_size)


def check_budget(method: str, family: PlantFamily, n_drop, plant_switching: str, scheme: str, max_modes: int,
                 max_memory: float | None, time_limit: float | None, solver: str = "AUTO", **request) -> None:
    """Refuse, before building anything, a design whose estimated memory or time is over budget.

    A thin layer over :func:`solver.compiled.design_size` (the estimate the service's limits use too) on the
    whole request (``request``: ``objective``, ``decay_rate``, ``rate_tol``, ``u_max``, ``disturbance``,
    ``output``).  Bad ``n_drop``, ``plant_switching``, ``scheme`` or too many modes are left to
    :class:`ModeSet`, which names them.  With a ``time_limit`` the caller bounded the time, so only
    memory is checked.
    """
    n_drop = check_n_drop(n_drop)
    if plant_switching not in PLANT_SWITCHING or scheme not in SCHEMES:
        return
    if mode_count(family.n_modes, n_drop, plant_switching) > max_modes:
        return
    size = request_size(method, family, n_drop, plant_switching, scheme, solver, **request)
    size.check(max_memory, float("inf") if time_limit is not None else None)


def _best(method: str, modes: ModeSet, options: DesignOptions, decay_rate, rate_tol: float) -> DesignResult:
    """``switched`` with ``decay_rate="max"`` starts from lmi's certified rate: never worse than lmi."""
    if decay_rate == "max" and method == "switched":
        start = time.perf_counter()
        first = _smallest_rate("lmi", modes, options, rate_tol)
        if first is not None and "time limit reached" in first.message:
            first.method = "switched"
            return first
        if first is not None and first.outcome == "stabilized":
            rest = replace(options, time_limit=time_left(options.time_limit, start, floor=1e-9))
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


#: ``decay_rate="auto"`` on a plant whose every mode is stable without control: the loop settles at most this many
#: times faster than the open loop (rate no smaller than ``rho_open ** AUTO_OPEN_LOOP_SPEEDUP``), since a faster one
#: buys speed the plant did not need with large gains.  Open-loop-unstable plants keep ``AUTO_SLOWDOWN`` alone.
AUTO_OPEN_LOOP_SPEEDUP = 10.0


def open_loop_rate(modes: ModeSet) -> float | None:
    """The largest spectral radius over the plant modes (per sample) when every one is below 1, else None."""
    if modes.F is None:
        return None
    F = np.asarray(modes.F, dtype=np.float64)
    with np.errstate(all="ignore"):
        if not np.all(np.isfinite(F)):
            return None
        rho = max(float(np.max(np.abs(np.linalg.eigvals(f)))) for f in F.reshape(-1, F.shape[-2], F.shape[-1]))
    return rho if 0.0 < rho < 1.0 else None


def _auto_rate(method: str, modes: ModeSet, options: DesignOptions) -> DesignResult:
    """The default design: a rate whose settling time is ``AUTO_SLOWDOWN`` times the best one's.

    At the best rate the LMI's margin vanishes and gains grow without bound; 1.5x its settling time
    leaves the SDP room, so its maximal-margin solution has moderate gains.  The coarse bisection runs
    on the settling time (``-1 / ln lambda``), geometrically, since that is what the tolerance is on.
    """
    start = time.perf_counter()
    try:
        best = _smallest_rate(method, modes, options, AUTO_SETTLING_TOLERANCE, settling=True, keep_probes=True,
                              strategy=AUTO_RATE_SEARCH if method == "lmi" else None)
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
    how = f"{fastest:.6g}^(1/{AUTO_SLOWDOWN:g}), settling {AUTO_SLOWDOWN:g}x the fastest certified rate's"
    open_loop = open_loop_rate(modes)
    if open_loop is not None and open_loop ** AUTO_OPEN_LOOP_SPEEDUP > target:
        # a plant stable without control needs no fast loop: the fastest one's gains are the price of its speed
        # (the CTMS bus suspension: 737 kN certified peak force from a 5 cm deflection at 1.5x the fastest rate)
        target = open_loop ** AUTO_OPEN_LOOP_SPEEDUP
        how = (f"{open_loop:.6g}^{AUTO_OPEN_LOOP_SPEEDUP:g}: the plant is stable without control (open-loop spectral "
               f"radius {open_loop:.6g} per sample), so settling {AUTO_OPEN_LOOP_SPEEDUP:g}x faster than its own, no "
               f"faster")
    remaining = time_left(options.time_limit, start)
    if remaining is not None and remaining <= 0:
        return best
    try:
        final = replace(options, decay_rate=target, time_limit=remaining,
                        warm_start=_final_start(modes, best.__dict__.pop("probes", ()), target))
        if method == "lmi" and FINAL_MARGIN_SHARE is not None:
            final = replace(final, sign_only=FINAL_MARGIN_SHARE)
        res = METHODS[method].run(modes, final)
    except SolverFailed:  # keep the certified faster loop
        return best
    if res.outcome != "stabilized":  # cannot happen for a convex rate LMI (feasible at a smaller rate)
        return best
    res.rate_search = best.rate_search + [{"decay_rate": target, "outcome": res.outcome,
                                           "proof": None if res.certificate is None else res.certificate.kind}]
    res.rate_bracket = {**best.rate_bracket, "fastest_certified": fastest, "slowdown": AUTO_SLOWDOWN}
    if open_loop is not None:
        res.rate_bracket.update(open_loop_rate=open_loop, open_loop_speedup=AUTO_OPEN_LOOP_SPEEDUP)
    res.decay_rate = target
    res.message += (f"; decay_rate='auto': designed at {target:.6g} per sample = {how} (fastest certified bracket "
                    f"[{best.rate_bracket['lower']:.6g}, {fastest:.6g}])")
    total = time.perf_counter() - start
    res.timings.update(total=total, solves=best.timings.get("solves", 0) + res.timings.get("solves", 0),
                       solver=best.timings.get("solver", 0.0) + res.timings.get("solver", 0.0))
    return res


def _final_start(modes: ModeSet, probes, target: float):
    """The warm start of ``"auto"``'s final solve, or None: of the search's probes ``(rate, SDP solution)``, the
    certified one nearest to ``target`` (in ln lambda), its multipliers carried down when it lies above
    (:func:`_carried`).  Only the start moves; measured: 20 -> 13 interior-point iterations at n = 20, 12 -> 11 on
    the paper's example (to the IPM's tolerances; with :data:`FINAL_MARGIN_SHARE` 7-9)."""
    probes = [(rate, sdp) for rate, sdp in probes if np.isfinite(sdp.t) and sdp.t > 0]
    if not (FINAL_WARM and probes):
        return None
    from .ipm import WarmStart

    rate, sdp = min(probes, key=lambda p: abs(np.log(p[0] / target)))
    return WarmStart([sdp.W, sdp.Y], _carried(modes, sdp, rate, target), shift=WARM_SHIFT, blend=WARM_BLEND)


def _carried(modes: ModeSet, sdp, rate: float, new: float):
    """A probe's multipliers at ``rate`` for a warm start at ``new``: carried there (primal feasible,
    :func:`solver.rate_search.carry_multipliers`) when :data:`CARRY_MULTIPLIERS` and they stay in the cone, else
    as they are."""
    if not CARRY_MULTIPLIERS or sdp.duals is None or new > rate:
        # (down in rate only: up, the carried optimum is worse centred than the blend of today's start; measured
        # on "auto"'s final design, n = 8: 12 iterations against 9, n = 20: 13 against 7)
        return sdp.duals
    X = carry_multipliers(sdp.duals, modes.eta, rate, new)
    return sdp.duals if X is None else X


#: ``decay_rate="auto"``'s final design stops at the first iterate whose margin is at least this share of its dual
#: bound (a margin within 5 % of the SDP's optimum; the IPM's ``sign_only`` with a ratio); None: to the IPM's
#: tolerances (measured, n = 8: 14 iterations and, from a carried start, 25: the last 10 at the rounding floor).
FINAL_MARGIN_SHARE = 0.95
#: Warm starts carry the probe's multipliers to the new rate (off-diagonal blocks scaled, docs/design.md §3.2.1).
CARRY_MULTIPLIERS = True
#: ``decay_rate="auto"``: warm-start the final design at the target rate from the nearest certified probe.
FINAL_WARM = True


#: What a bisection step whose solver failed returns (no certificate, no proof).
FAILED_STEP = object()



#: How the best-rate search runs: "path" (one interior-point path that follows the rate, docs/design.md §3.2.2;
#: ``lmi`` on the IPM, "model" otherwise and as its fallback), "model" (probes at the root of the margin's
#: first-order model from the last solve's multipliers, solver/rate_search.py, safeguarded by the bracket) or
#: "bisection" (the midpoint).
RATE_SEARCH = "path"
#: ``decay_rate="auto"``'s search: its tolerance (10 % in settling time) leaves the sign-stopped probes little to
#: do, where the path must still converge to a refuted rate next to the root (measured, CPU against one plain SDP:
#: n = 8 3.7x against 3.1x, n = 50 3.1x against 2.9x; docs/performance.md).
AUTO_RATE_SEARCH = "model"
#: The model search's probes below lambda = 1 stop once the margin's sign is settled (the IPM's ``sign_only``):
#: a certified probe keeps a design whose margin is at least half the SDP's optimum, a failed one a Farkas
#: candidate re-checked as always.
SIGN_ONLY_PROBES = True
#: ... and start from the nearest probe's solution (docs/design.md, "Rate search"): t lowered by WARM_SHIFT
#: below the blocks' smallest eigenvalue, the multipliers blended with I/N by WARM_BLEND.
WARM_PROBES = True
#: ``"auto"``'s refuted probes stop at the first iterate whose multipliers pass the Farkas re-check (checked in the
#: solve), not at the sign rule's lower bound within half of the dual bound.
EARLY_REFUTE = True
#: ... the first probe (lambda = 1) too: only its sign and its model are used (measured: saves about half a solve)
SIGN_AT_ONE = True
WARM_SHIFT = 0.01
WARM_BLEND = 0.5


def _probe_sign(probe_sign: bool, lam: float, settling: bool) -> bool | float:
    """A probe's ``sign_only`` (:attr:`solver.ipm.IPMOptions.sign_only`): for ``"auto"`` (``settling``) below
    lambda = 1 the margin share :data:`PROBE_MARGIN_SHARE` certifies, at lambda = 1 (the first model) and for
    ``"max"``'s probes half the dual bound."""
    if not probe_sign or not (lam < 1.0 or SIGN_AT_ONE):
        return False
    share = PROBE_MARGIN_SHARE if lam < 1.0 and settling else ONE_MARGIN_SHARE
    return True if share == 0.5 else share


#: A certified probe below lambda = 1 stops once its margin is this share of its dual bound (docs/design.md §3.2.1;
#: measured, CPU of "auto" with 1/2 / 1/4: n = 20 1.69 / 1.46 s, n = 50 19.7 / 18.9 s, paper and n = 8 equal, but
#: the CTMS two-mode pendulum n_drop = 10 0.21 / 0.58 s (12 / 15 solves), n_drop = 50 1.08 / 5.45 s (5 / 8 solves,
#: a probe ends "not_converged" and Clarabel runs): the less converged models mislead on a badly scaled plant).
PROBE_MARGIN_SHARE = 0.5
#: ... the probe at lambda = 1 (the first model; 1/4 there: paper example 50 iterations against 30, n = 50 65 / 55).
ONE_MARGIN_SHARE = 0.5
#: A probe's warm start is the nearest probe at or above its rate (carried down, primal feasible) when there is
#: one (n = 8: the certified probe after a refuted one 12 -> 8 iterations, "auto" 57 -> 48).
WARM_FROM_ABOVE = True


def _smallest_rate(method: str, modes: ModeSet, options: DesignOptions, tol: float,
                   upper: DesignResult | None = None, user_limit: float | None = None,
                   settling: bool = False, strategy: str | None = None, keep_probes: bool = False) -> DesignResult:
    """Search lambda in (0, 1] for the smallest certified rate, relative tolerance ``tol``, on the congruent SDP.

    ``strategy`` (default :data:`RATE_SEARCH` for ``lmi``, "bisection" for ``switched``): "path" closes the
    bracket on one rate-following interior-point path (docs/design.md 3.2.2) and falls back to "model"; "model" tries the
    root of the margin's first-order model (solver/rate_search.py, docs/design.md 3.2.1) inside the bracket,
    "bisection" the midpoint; both keep the same bracket and acceptance rules, so both return a certified rate
    within ``tol`` of the smallest certifiable one (when the lower end is proven).

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
    # the model and the probes' early stop are the lmi SDP's (switched keeps the bisection)
    strategy = (RATE_SEARCH if method == "lmi" else "bisection") if strategy is None else strategy
    probe_sign = strategy in ("model", "path") and SIGN_ONLY_PROBES
    totals = {"setup": 0.0, "solver": 0.0, "solves": 0}
    search: list = []
    runner = METHODS[method].run
    limit = options.time_limit
    timed_out = False

    solved = []  # (rate, SDP solution) of the probes, for the warm starts

    def warm(lam):
        if not (probe_sign and WARM_PROBES and solved):
            return None
        from .ipm import WarmStart

        pool = solved
        carry = settling and CARRY_MULTIPLIERS  # ("auto"'s probes; "max"'s fallback probes as measured before)
        if carry and WARM_FROM_ABOVE and any(r >= lam for r, _ in solved):
            pool = [p for p in solved if p[0] >= lam]
        rate, sdp = min(pool, key=lambda p: abs(np.log(p[0] / lam)))
        X = _carried(modes, sdp, rate, lam) if carry else sdp.duals
        return WarmStart([sdp.W, sdp.Y], X, shift=WARM_SHIFT, blend=WARM_BLEND)

    def attempt(lam):
        nonlocal timed_out
        remaining = time_left(limit, start)
        if remaining is not None and remaining <= 0:
            timed_out = True
            return None
        try:
            res = runner(modes, replace(options, decay_rate=lam, time_limit=remaining, rate_search=True,
                                        sign_only=_probe_sign(probe_sign, lam, settling), warm_start=warm(lam),
                                        early_refute=settling and EARLY_REFUTE and lam < 1.0))
        except SolverFailed as err:
            if lam >= 1.0:  # nothing certified yet: the design itself failed
                raise
            # a step the solver could not finish certifies nothing and proves nothing: bisect above it
            search.append({"decay_rate": lam, "outcome": "solver_failed", "proof": None, "message": str(err)})
            return FAILED_STEP
        for key in totals:
            totals[key] += res.timings.get(key, 0)
        sdp = getattr(res, "sdp", None)
        if sdp is not None and sdp.W is not None and getattr(sdp.info, "solver", "") == "IPM":
            solved.append((lam, sdp))
        search.append({"decay_rate": lam, "outcome": res.outcome,
                       "proof": None if res.certificate is None else res.certificate.kind})
        if res.outcome == "not_converged" and "time limit" in res.message:
            timed_out = True
        return res

    def done(lo, hi):
        return rate_done(lo, hi, tol, settling)

    def midpoint(lo, hi):
        return rate_midpoint(lo, hi, settling)

    def measure(lam):  # the coordinate the tolerance is on: settling times' logarithm, or ln lambda
        return rate_measure(lam, settling)

    tol_width = float(np.log1p(tol) if settling else -np.log1p(-tol))  # done(lo, hi) <=> measure gap <= this

    lo, lo_proven, lo_proof, lo_margin = 0.0, True, "infeasible", None
    path = path_model = None
    if strategy == "path":
        if method == "lmi" and upper is None and resolve_solver(options.solver, "lmi", modes.n_modes) == "IPM":
            try:
                path = _path_bracket(modes, options, settling, tol_width, done)
            except (SolverFailed, ValueError, ArithmeticError, np.linalg.LinAlgError):  # never worse than today
                path = None
        strategy = "model"  # without a closed bracket from the path: today's search (never worse)
    if path is not None:
        best, hi, lo, lo_proof, lo_margin = path["best"], path["hi"], path["lo"], path["lo_proof"], path["lo_margin"]
        path_model = path["model"]  # the model at hi of the iterate that certified it (not of the re-check)
        lo_proven = lo_proof == "infeasible" or lo == 0.0
        search.extend(path["search"])
        for key in totals:
            totals[key] += path["totals"][key]
        solved.append((hi, best.sdp))
    elif upper is not None and upper.outcome == "stabilized" and upper.decay_rate is not None:
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
    t_hi = getattr(getattr(best, "sdp", None), "t", None)
    t_lo, previous, from_above, anchor, stalls, model_lo = None, None, True, hi - lo, 0, None
    while not done(lo, hi) and hi > MIN_RATE and not timed_out:
        # three model steps that did not halve the bracket hand one step to the bisection: never much slower
        if strategy == "model" and stalls < 3:
            sdp = getattr(best, "sdp", None)
            model = None if sdp is None else margin_model(modes, sdp, hi)
            if path_model is not None and best is path["best"]:
                model = path_model
            # the settling bisection's midpoint is for the bisection's steps; next to hi = 1 it lands at 1 - 1e-5
            mid, how = next_rate(max(lo, MIN_RATE if settling else 0.0), hi, t_lo, t_hi, model, done,
                                 lambda a, b: 0.5 * (a + b), from_above, previous, measure, model_lo,
                                 search[-1].get("step"), tol_width)
            if model is not None and (previous is None or previous[0] != hi):
                previous = (hi, model_root(model, hi, max(lo, 1e-12), hi))
        else:
            mid, how = midpoint(lo, hi), "bisect"
        res = attempt(mid)
        if res is None:
            break
        search[-1]["step"] = how
        t_res = getattr(getattr(res, "sdp", None), "t", None)
        if res is FAILED_STEP:
            lo, lo_proven, t_lo, model_lo = mid, False, None, None
        elif res.outcome == "stabilized":
            hi, best, t_hi = mid, res, t_res
        else:
            lo, lo_proven, t_lo = mid, res.outcome == "infeasible", t_res
            sdp_lo = getattr(res, "sdp", None)
            model_lo = None if sdp_lo is None or sdp_lo.W is None else margin_model(modes, sdp_lo, mid)
            lo_proof = res.outcome if res.outcome in NEGATIVE else None
            lo_margin = res.certificate.margin if lo_proof == "marginal" else None
        from_above = res is not FAILED_STEP and res.outcome == "stabilized"
        if hi - lo <= 0.5 * anchor or how == "bisect":
            anchor, stalls = hi - lo, 0
        else:
            stalls += 1
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
    if keep_probes:  # (rate, SDP solution) of the IPM probes: "auto"'s final warm start (popped there)
        best.probes = solved
    total = time.perf_counter() - start
    best.timings.update(totals, total=total, overhead=max(total - totals["setup"] - totals["solver"], 0.0))
    if timed_out:
        best.outcome = "not_converged"
        shown = limit if user_limit is None else user_limit
        best.message = (f"time limit reached ({shown:g} s) during the decay-rate bisection; best iterate: "
                        + best.message)
    return best


def _path_bracket(modes: ModeSet, options: DesignOptions, settling: bool, tol_width: float, done) -> dict | None:
    """The bracket of the rate-following path (solver/rate_search.py, docs/design.md §3.2.2), re-checked, or None.

    The path's primal iterate is re-checked at its certified rates, the smallest first
    (:func:`solver.methods.common.run_one_shot` on that iterate: the float64 re-check of every design), and its
    multipliers at the rate they refute (the Farkas re-check of every design).  The first certified rate that
    passes is the upper end, whether or not the path closed its bracket (it may have stopped at its time share,
    its step cap or a stall); the lower end is the refuted rate when its re-check passes, else 0: the probes go on
    from there while ``not done(lo, hi)``.  None when no certified rate passes: the caller runs today's search.
    """
    from .compiled import DesignSdpSolution, SolveInfo
    from .methods.common import RunClock, certify_gains, run_one_shot
    from .rate_search import _closing_high, path_rates, path_search, path_steps_solves, rebase_model

    path, his = path_search(modes, settling, tol_width, done, options.time_limit)
    if not his:
        return None
    coef, active = modes.scheme_coef()

    def info(t):
        return SolveInfo(status="optimal_inaccurate", solver="IPM", solve_time=0.0, wall_time=0.0, objective=t,
                         iterations=path.iterations)

    def passes(W, Y, t_hi, at_hi):
        # the float64 re-check alone first (run_one_shot's, on the same candidate): a rate it fails at would also
        # run the structural infeasibility proof, which cannot hold where the iterate certifies the rate in closed
        # form (paper example: three failing rates before the one that passes)
        if not t_hi > 0.0:
            return False
        try:
            theta = np.linalg.solve(W, np.swapaxes(Y, 1, 2)).swapaxes(1, 2)
            candidate = np.linalg.inv(W)
        except np.linalg.LinAlgError:
            return False
        if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(candidate))):
            return False
        cert, _ = certify_gains(modes, modes.expand(theta), at_hi, RunClock(), candidate=candidate,
                                candidate_kind="reduced", candidate_source="lmi")
        return cert is not None

    def recheck(W, Y, X, hi):  # the iterate's margin at hi: the blocks' smallest eigenvalue
        M = modes.free @ W
        if coef.size:
            M = M + np.einsum("sjnm,jmk->snk", coef * np.asarray(active, dtype=float)[:, :, None, None], Y)
        c = hi ** (-modes.eta.astype(float))
        blocks = np.block([[np.broadcast_to(W, M.shape), np.swapaxes(c[:, None, None] * M, 1, 2)],
                           [c[:, None, None] * M, np.broadcast_to(W, M.shape)]])
        t_hi = float(np.linalg.eigvalsh(blocks)[:, 0].min())
        # (no multipliers for the re-check: at a rate the iterate itself certifies in closed form no Farkas
        # certificate can pass, and its re-check cost more than the paper example's Newton steps)
        sol = DesignSdpSolution(t=t_hi, W=W, Y=Y, S=None, duals=None, info=info(t_hi))
        at_hi = replace(plain, decay_rate=hi)
        if not passes(W, Y, t_hi, at_hi):
            return sol, None
        res = run_one_shot(modes, "lmi", at_hi, lambda *a, **k: sol)
        sol.duals = X  # the probes' model and warm start (when the path leaves the bracket open)
        return sol, res

    plain = replace(options, sign_only=False, warm_start=None, rate_search=True)
    # the last certifying iterate first, then earlier ones (better centred: the paper example's last one is
    # certified 1e-7 above its re-check's resolution), each at the rates above its own that still close the bracket
    tries = [(his, path.W, path.Y, path.X_hi, path.hi_at)]
    if 0.0 < path.lo < his[-1]:  # the largest rate that still closes the bracket with the path's lower end
        top = _closing_high(path.lo, 1.0, done)
        if his[-1] < top < 1.0:
            tries[0] = (his + [top], path.W, path.Y, path.X_hi, path.hi_at)
    for rate, W, Y, X, at in path.earlier:
        ups = [h for h in path_rates(rate, settling, tol_width) if path.lo <= 0.0 or done(path.lo, h)]
        tries.append((ups, W, Y, X, at))
    for rates, W, Y, X, at in tries:
        for hi in rates:
            sol_hi, res_hi = recheck(W, Y, X, hi)
            if res_hi is not None and res_hi.outcome == "stabilized":
                break
        else:
            continue
        break
    else:
        return None
    # the probes' first model (when the bracket is still open): the iterate's own, made at its own rate (its
    # multipliers' scale, its margin t), rebased to hi; the re-check's margin at hi, the blocks' smallest
    # eigenvalue next to the rate the iterate certifies, put its Newton root within the tolerance of hi and the
    # first probe was always "close" (docs/design.md §3.2.2)
    model = None
    if at is not None:
        own = margin_model(modes, DesignSdpSolution(t=at[1], W=W, Y=Y, S=None, duals=X, info=info(at[1])), at[0])
        model = None if own is None else rebase_model(own, at[0], hi)
    res_hi.sdp = sol_hi
    search = [{"decay_rate": hi, "outcome": res_hi.outcome, "step": "path",
               "proof": None if res_hi.certificate is None else res_hi.certificate.kind,
               "iterations": path.iterations, "solves": path_steps_solves(path)}]  # the path's Newton steps
    out = {"best": res_hi, "hi": hi, "lo": 0.0, "lo_proof": None, "lo_margin": None, "search": search, "model": model,
           "totals": {"setup": 0.0, "solver": path.seconds, "solves": path_steps_solves(path)}}
    if path.duals is None or not 0.0 < path.lo < hi:
        return out
    t_lo = path.lo_at[2] if path.lo_at is not None else -1.0  # the dual bound: <C, X> is kept by the scaling
    sol_lo = DesignSdpSolution(t=t_lo, W=None, Y=None, S=None, duals=path.duals, info=info(t_lo))
    res_lo = run_one_shot(modes, "lmi", replace(plain, decay_rate=path.lo), lambda *a, **k: sol_lo)
    # a lower end whose multipliers fail the re-check proves nothing: the probes go on from the certified end
    if res_lo.outcome in NEGATIVE:
        search.append({"decay_rate": path.lo, "outcome": res_lo.outcome, "step": "path",
                       "proof": None if res_lo.certificate is None else res_lo.certificate.kind})
        out.update(lo=path.lo, lo_proof=res_lo.outcome,
                   lo_margin=res_lo.certificate.margin if res_lo.outcome == "marginal" else None)
    return out


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
    if not original.verified and cert.exact and cert.X is not None and rho is None:
        # a margin only the exact re-check confirmed: the same exact re-check on the user's numbers (§8.5)
        original = recheck_lifted_exact(scale.quadratic_back(cert.X), A, modes.F, modes.G, res.gains, modes.plants,
                                        modes.n_drop, cert.source)
    if original.verified:
        original.decay_rate = cert.decay_rate
        res.certificate = original
    else:
        res.scaling["certificate"] = "scaled"
    return res
