"""Pieces every design method shares: options, timing, and turning gains into a certified result."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.linalg

from ..certificates import check_farkas, check_farkas_switched, interval_data, uncontrollable_mode
from ..compiled import SolveInfo, resolve_solver, time_left
from ..errors import SolverFailed
from ..lyapunov import (EXACT_MAX_N, Certificate, certify, recheck_common, recheck_lifted,
                        recheck_lifted_exact, recheck_switched)
from ..network import ModeSet, spectral_radii
from ..result import DesignResult, IterationRecord


@dataclass
class DesignOptions:
    """Options shared by all methods (see :func:`solver.design` for their meaning)."""

    solver: str = "AUTO"
    margin: float = 1e-6
    max_iter: int = 50
    time_limit: float | None = None
    callback: Callable | None = None
    ccl_start: str = "feasibility"
    decay_rate: float | None = None
    #: The rate search's probes: the lmi SDP stops once its margin's sign is settled (IPM only); a float in (0, 1]:
    #: stops at the first margin at least that share of the dual bound (:attr:`solver.ipm.IPMOptions.sign_only`).
    sign_only: bool | float = False
    #: ``decay_rate="auto"``'s probes (lmi on the IPM, with ``sign_only``): the Farkas re-check runs inside the solve
    #: at every iterate whose multipliers are a candidate, and the first that passes ends it (docs/design.md §3.2.1).
    early_refute: bool = False
    #: The rate search's warm start for the lmi SDP on the IPM (a :class:`solver.ipm.WarmStart`).
    warm_start: object | None = None
    #: The memory budget (bytes) of the ``"AUTO"`` fallback to Clarabel (:func:`solver.compiled.clarabel_fits`).
    max_memory: float | None = None
    #: A step of a rate search (``decay_rate="max"``/``"auto"``): the SDP's own candidate decides, the gains are not
    #: certified on their own at the rate when it fails (the searches' brackets stay those of docs/design.md §3.2.1).
    rate_search: bool = False

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
        return time_left(time_limit, self.start)

    def countdown(self, time_limit: float | None) -> Callable[[], float | None]:
        """``() -> seconds left of time_limit`` (None without a limit), counted from this run's start: the
        ``seconds_left`` of the steps that check the time as they go (:func:`solver.compiled.out_of_time`)."""
        return lambda: self.remaining(time_limit)

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


#: A reduced candidate whose float64 relative margin is above ``-EXACT_WINDOW`` (and below what float64 confirms) is
#: re-checked exactly (n <= EXACT_MAX_N): float64 rounding of ``A' X A`` where X spans 1e13 reaches 1e-9 (§8.5).
EXACT_WINDOW = 1e-6


def certify_gains(
    modes: ModeSet,
    gains: np.ndarray,
    options: DesignOptions,
    clock: RunClock,
    candidate: np.ndarray | None = None,
    candidate_kind: str = "reduced",
    candidate_source: str = "",
    exact: bool = False,
) -> tuple[Certificate | None, np.ndarray]:
    """Find a float64-verified certificate for ``gains``.

    The method's own candidate is tried first: a reduced common X
    (``"reduced"``, lifted to the augmented P of Theorem 1), an augmented P
    (``"augmented"``) or mode-dependent ``P_s`` (``"switched"``).  With a
    decay rate the candidate must also prove it.  Without a rate, and if the
    candidate fails, fixed-gain LMIs (common, then switched) are solved.
    ``exact``: a reduced candidate whose float64 margin is below what float64 can confirm is re-checked exactly
    (:func:`solver.lyapunov.recheck_lifted_exact`; no decay rate, n <= ``EXACT_MAX_N``, docs/design.md §8.5).

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
        else:  # one re-check, on the reduced form (exact equivalent of the augmented one)
            cert = recheck_lifted(candidate, A, n_drop, candidate_source, rho=rho)
        if cert.verified:
            cert.decay_rate = options.decay_rate
            return cert, A
        if exact and candidate_kind == "reduced" and options.decay_rate is None and modes.F is not None and \
                modes.n_states <= EXACT_MAX_N and cert.min_eig_P > 0 and cert.margin > -EXACT_WINDOW:
            # float64 cannot decide a relative margin this small (a performance certificate spanning 1e11): the
            # same inequality in exact arithmetic on the float64 numbers, the loops rebuilt exactly from F, G, K
            # (float64 can see such a certificate fail by its own rounding: -1.4e-9 for hold-out seed 0, §8.5)
            cert = recheck_lifted_exact(candidate, A, modes.F, modes.G, gains, modes.plants, n_drop, candidate_source)
            if cert.verified:
                return cert, A
    rate = options.decay_rate
    if rate is not None and options.rate_search:
        return None, A  # a rate search's step: its own candidate decides (a failed one is a step without a verdict)
    if np.any(spectral_radii(A) >= (1.0 if rate is None else rate ** modes.eta.astype(float))):
        return None, A  # a mode slower than the rate (or unstable) has no certificate
    if rate is not None and candidate_kind != "switched" and A.shape[0] == 1:
        # one loop: the Lyapunov solution of the loop scaled by the rate is a certificate wherever one exists (near
        # the best rate the SDP's own W^-1 can miss the float64 re-check by its rounding, docs/design.md §3.2)
        try:
            scaled = A[0] * rate ** -float(modes.eta[0])
            with warnings.catch_warnings():  # (an ill-conditioned solve is the re-check's to judge)
                warnings.simplefilter("ignore")
                X = scipy.linalg.solve_discrete_lyapunov(scaled.T, np.eye(A.shape[1]))
            cert = recheck_lifted(X, A, n_drop, "lyapunov", rho=rho) if np.all(np.isfinite(X)) else None
            if cert is not None and cert.verified:
                cert.decay_rate = rate
                return cert, A
        except (np.linalg.LinAlgError, ValueError):
            pass
    kinds = ("common_quadratic",) if modes.plant_switching == "per_interval" and candidate_kind != "switched" else (
        "common_quadratic", "switched")
    remaining = clock.remaining(options.time_limit)
    if remaining is not None and remaining <= 0:
        return None, A
    try:
        cert = certify(A, n_drop, kinds=kinds, solver=options.solver, time_limit=remaining, on_solve=clock.add,
                       rho=None if rate is None else rho)
    except SolverFailed as err:
        if is_time_limit(err, options, clock):
            return None, A
        raise
    if cert is not None:
        cert.decay_rate = rate
    return cert, A


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
        solver=resolve_solver(info_solver, method, modes.n_modes),
        solver_status=status,
        timings=clock.timings(),
        message=message,
        spectral_radii=None if A is None else modes.reshape_per_mode(spectral_radii(A)),
        scheme=modes.scheme,
        plant_switching=modes.plant_switching,
        decay_rate=options.decay_rate if outcome == "stabilized" else None,
        mode_labels=[modes.label(s) for s in range(modes.n_modes)],
    )


def congruent_scale(modes: ModeSet, rate: float | None) -> np.ndarray:
    """``c_s = lambda^(-eta_s)`` per mode (ones without a rate): multiplies the data of mode s."""
    if rate is None:
        return np.ones(modes.n_modes)
    return float(rate) ** (-modes.eta.astype(float))


def is_time_limit(err: SolverFailed, options: DesignOptions, clock: RunClock) -> bool:
    """Whether a solver failure is the time limit running out (status or clock)."""
    if options.time_limit is None:
        return False
    return "limit" in str(err.status or "").lower() or clock.elapsed >= options.time_limit


#: Outcomes proven by a negative certificate (no gains are reported).
NEGATIVE = ("infeasible", "marginal")


def proof_outcome(proof) -> str:
    """What a negative certificate proves (docs/design.md, "infeasible or marginal").

    "infeasible": no design of any margin (Farkas with ``delta > 0``, up to its gain bound, or an
    uncontrollable unstable mode: no gains at all); "marginal": the Farkas multipliers exclude only
    designs whose relative margin reaches ``proof.margin``.
    """
    return "marginal" if proof.kind in ("farkas", "farkas_limits") and not proof.any_margin else "infeasible"


def prove_infeasible(modes: ModeSet, method: str, duals: np.ndarray | None, rate: float | None,
                     margin: float = 0.0):
    """A solver-independent proof that no design of ``method`` exists at ``rate``, or ``(None, reason)``.

    Tries an unstable uncontrollable plant mode, then the Farkas multipliers
    (re-checked by :mod:`solver.certificates` on interval data rebuilt from the
    plant with rounding bounds).  Returns ``(certificate or None, reason)``.
    """
    reason = "no multipliers"
    if modes.F is not None:  # the structural proof first: it excludes every gain, of any method
        unc = uncontrollable_mode(modes.F, modes.G, 1.0 if rate is None else rate)
        if unc is not None:
            unc.decay_rate = rate
            return unc, ""
    if duals is not None and modes.F is not None:
        free, dfree, coef, dcoef = interval_data(modes.F, modes.G, modes.plants, modes.gain_map,
                                                 scale=congruent_scale(modes, rate))
        if method == "switched":
            S, n2 = modes.n_modes, duals.shape[-1]
            cert = check_farkas_switched(duals.reshape(S, S, n2, n2), free, coef, dfree, dcoef, rate,
                                         margin=margin / modes.n_states)
        else:
            cert = check_farkas(duals, free, coef, dfree, dcoef, rate, margin=margin / modes.n_states)
        if cert.verified:
            return cert, ""
        reason = f"the dual multipliers do not pass the Farkas re-check (delta = {cert.delta:.3g})"
    return None, reason


def run_one_shot(modes: ModeSet, method: str, options: DesignOptions, solve_sdp) -> DesignResult:
    """The result of a one-SDP method (``lmi``, ``switched``).

    ``solve_sdp(modes, scale, solver, time_limit, clock) -> DesignSdpSolution`` solves the congruent
    SDP.  Stabilized needs gains whose certificate passes the float64 re-check
    at the rate; infeasible needs a certificate from :func:`prove_infeasible`;
    anything else is ``not_converged`` with the reason.
    """
    clock = RunClock()
    rate = options.decay_rate
    rate_txt = "" if rate is None else f" at decay rate {rate:.6g}"
    extra = {"sign_only": options.sign_only, "start": options.warm_start} if method == "lmi" and (
        options.sign_only or options.warm_start is not None) else {}
    scale = congruent_scale(modes, rate)
    proven: dict = {}
    if extra and options.early_refute and options.sign_only and rate is not None:
        def refute(X):
            # the re-check of every design's infeasible verdict, on this iterate's multipliers; kept for _verdict
            try:
                proof, _ = prove_infeasible(modes, method, X[0], rate, options.margin)
            except (ValueError, ArithmeticError, np.linalg.LinAlgError):  # an iterate's: the solve goes on
                return False
            if proof is None or proof_outcome(proof) != "infeasible":
                return False
            proven["duals"], proven["proof"] = X[0], proof
            return True
        extra["refute"] = refute
    try:
        sol = solve_sdp(modes, scale, options.solver, options.time_limit, clock, **extra)
    except SolverFailed as err:
        if is_time_limit(err, options, clock):
            record = IterationRecord(0, float("nan"), None, False, None, float("nan"), clock.elapsed)
            return finish(modes, method, "not_converged", None, None, None, clock, options.solver,
                          str(err.status), f"time limit reached ({options.time_limit:g} s) inside the solver"
                                           f"{rate_txt}; no iterate", [record], options)
        return _after_failure(modes, method, options, solve_sdp, scale, clock, err, rate_txt)
    return _verdict(modes, method, options, clock, sol, rate_txt, proven=proven)


def _after_failure(modes: ModeSet, method: str, options: DesignOptions, solve_sdp, scale, clock: RunClock,
                   err: SolverFailed, rate_txt: str) -> DesignResult:
    """A verdict after the solver gave up (never an exception out of :func:`run_one_shot`, issue 29).

    The IPM's last iterate is strictly feasible for its own margin ``t`` whatever its status (max_iterations,
    numerical_error near the feasibility boundary): its gains may pass the float64 re-check, its multipliers
    the Farkas re-check.  Without a verdict from it, under ``solver="AUTO"`` Clarabel solves the same SDP (when
    it fits the memory budget, :func:`solver.compiled.clarabel_fits`); otherwise "not_converged" naming both
    failures.  The progress callback sees one record: the returned verdict's.
    """
    from ..compiled import clarabel_fits

    def report(res: DesignResult) -> DesignResult:
        if options.callback is not None and res.history:
            options.callback(res.history[-1])
        return res

    failures = [str(err)]
    sol = getattr(err, "solution", None)
    if sol is not None and sol.W is not None and np.all(np.isfinite(sol.W)):
        res = _verdict(modes, method, options, clock, sol, rate_txt, report=False)
        if res.outcome != "not_converged":
            res.message += f" (from the last iterate after: {err})"
            return report(res)
        failures.append(f"its last iterate: {res.message}")
    if str(options.solver).upper() == "AUTO" and resolve_solver("AUTO", method, modes.n_modes) != "CLARABEL" \
            and clarabel_fits(method, modes.n_states, modes.n_inputs, modes.n_plants, modes.n_drop,
                              modes.plant_switching, modes.scheme, max_memory=options.max_memory):
        remaining = clock.remaining(options.time_limit)
        if remaining is None or remaining > 0:
            try:
                sol = solve_sdp(modes, scale, "CLARABEL", remaining, clock)
                res = _verdict(modes, method, options, clock, sol, rate_txt, report=False)
                if res.outcome != "not_converged":
                    res.message += f" (Clarabel, after: {err})"
                    return report(res)
                failures.append(f"Clarabel: {res.message}")
            except SolverFailed as err2:
                failures.append(f"Clarabel: {err2}")
    record = IterationRecord(0, float("nan"), None, False, None, float("nan"), clock.elapsed)
    return report(finish(modes, method, "not_converged", None, None, None, clock, options.solver,
                         str(err.status or ""), f"the solver gave up{rate_txt} and no verdict is proven: "
                         + "; ".join(failures), [record], options))


def _verdict(modes: ModeSet, method: str, options: DesignOptions, clock: RunClock, sol, rate_txt: str,
             report: bool = True, proven: dict | None = None) -> DesignResult:
    """Gains re-checked, or a Farkas proof, or "not_converged", from one SDP solution (``report``: its record
    goes to the progress callback)."""
    rate = options.decay_rate
    clock.add(sol.info)
    info, t = sol.info, sol.t
    gains = cert = A = None
    theta = None
    if np.isfinite(t) and t > 0:
        try:
            if method == "switched":
                theta = np.linalg.solve(sol.W.T, np.swapaxes(sol.Y, 1, 2)).swapaxes(1, 2)  # Theta_j = Y_j Z^{-1}
                candidate, kind = np.linalg.inv(sol.S), "switched"
            else:
                theta = np.linalg.solve(sol.W, np.swapaxes(sol.Y, 1, 2)).swapaxes(1, 2)  # Theta_j = Y_j W^{-1}
                candidate, kind = np.linalg.inv(sol.W), "reduced"
        except np.linalg.LinAlgError:  # a failed solver's iterate may be singular: no gains from it
            theta = None
    if theta is not None and np.all(np.isfinite(theta)):
        gains = modes.expand(theta)
        cert, A = certify_gains(modes, gains, options, clock, candidate=candidate, candidate_kind=kind,
                                candidate_source=method)
    record = IterationRecord(
        iteration=0, objective=t, trace_gap=None, theorem1=cert is not None,
        certificate_margin=None if cert is None else cert.margin, solve_time=info.solve_time, elapsed=clock.elapsed,
    )

    def result(outcome, message, certificate=cert):
        keep = outcome not in NEGATIVE  # a proven-infeasible design has no gains to report
        res = finish(modes, method, outcome, gains if keep else None, certificate, A if keep else None, clock,
                     info.solver, info.status, message, [record], options)
        res.sdp = sol  # the rate search's model (solver/rate_search.py) reads the multipliers; not exported
        return res

    if report and options.callback is not None:
        options.callback(record)
    if cert is not None:
        return result("stabilized", f"stabilized; SDP margin t* = {t:.3g}, {cert.kind} certificate re-checked "
                                    f"(relative margin {cert.margin:.3g}){rate_txt}")
    if proven and proven.get("duals") is sol.duals:  # the solve's own stop: these multipliers passed in the loop
        proof, reason = proven["proof"], ""
    else:
        proof, reason = prove_infeasible(modes, method, sol.duals, rate, options.margin)
    if proof is not None:
        return result(proof_outcome(proof), f"{proof.statement()}; t* = {t:.3g}", certificate=proof)
    if np.isfinite(t) and t > 0:
        return result("not_converged", f"the SDP reported margin t* = {t:.3g} but no certificate passed the "
                                       f"float64 re-check{rate_txt}, and {reason}")
    return result("not_converged", f"the SDP's best margin is t* = {t:.3g}{rate_txt}, but {reason} and no "
                                   "uncontrollable unstable mode was found: no verdict is proven")
