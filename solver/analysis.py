"""Stability analysis of given predictive gains: ``analyze(family, gains, n_drop)``.

Three verdicts, each with its evidence:

* ``stable=True``: a Lyapunov certificate (common quadratic, i.e. Theorem 1,
  or mode-dependent) found by an LMI for the fixed gains and re-checked in
  float64 with ``eigvalsh``;
* ``stable=False``: a mode, or a finite product of modes (a concrete pattern
  of losses and plant jumps repeated forever), whose spectral radius is
  *proven* >= 1: the product of the float64 data is computed exactly (integers)
  and its characteristic polynomial put through the Schur-Cohn-Jury test
  (:mod:`solver.exact`); float64 eigenvalues of a product are only a guide;
* ``stable=None``: neither could be shown.

Bounds on the joint spectral radius (JSR) of the interval maps under
arbitrary switching are reported too: the proven lower bound from the best
product, the upper bounds from the best common quadratic and switched
certificates (bisection; above 1 too), and the best certified per-sample decay rate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .compiled import check_solver
from .errors import InvalidInput, SolverFailed
from .lyapunov import MAX_SWITCHED_MODES, Certificate, certified_rate, certify
from .network import MAX_MODES, ModeSet, check_gains, spectral_radii
from .plant import PlantFamily
from .scaling import balance

#: Hard cap on products examined per length (time and memory of the lower bound).
MAX_PRODUCTS = 1_000_000


@dataclass
class AnalysisReport:
    """Result of :func:`analyze`.

    Attributes
    ----------
    stable : bool or None
    spectral_radii : ndarray
        Spectral radius of every interval closed loop: (r, n_drop) per
        interval, (S,) per sample (labelled by ``mode_labels``).
    certificate : Certificate or None
        The re-checked certificate when ``stable`` is True.
    jsr_lower_bound : float or None
        A proven lower bound of the JSR: ``rho(product)^(1/length)`` of the product
        of interval maps (up to ``product_length_checked``) with the largest
        float64 estimate, established exactly (docs/design.md); None when
        nothing positive could be proven (``reason`` says why).
    jsr_lower_estimate : float
        The float64 estimate ``max rho(product)^(1/length)`` (not a proof).
    scaling : list of float or None
        When the certificate was found for the balanced loops ``T^-1 A_s T``
        (``T = diag(scaling)``, powers of two, exact): the state scaling.
    jsr_upper_bound : float or None
        Smallest certified bound (common quadratic or switched) on the JSR of
        the interval maps, also when >= 1; None when none could be certified.
    jsr_upper_bound_quadratic, jsr_upper_bound_switched : float or None
    decay_rate : float or None
        Best certified per-sample decay rate lambda (``|x(i_{m+1})| <= lambda^eta |x(i_m)|``
        in the certificate's norm).
    worst_sequence : list of dict
        The product attaining ``jsr_lower_bound``, in the order applied; when
        ``stable`` is False, repeating it forever destabilizes the loop.
    product_length_checked : int
    reason : str
    timings : dict
    cost : Performance or None
        With ``weights``: the certified bracket of the worst-case quadratic cost of these gains
        (:class:`solver.brackets.Performance`: ``lower``, ``upper``, ``witness``).
    hinf : Performance or None
        With ``disturbance``: the bracket of the worst-case l2 gain from w to z.
    """

    stable: bool | None
    spectral_radii: np.ndarray
    certificate: Certificate | None
    jsr_lower_bound: float | None
    worst_sequence: list
    product_length_checked: int
    reason: str
    jsr_upper_bound_quadratic: float | None = None
    jsr_upper_bound_switched: float | None = None
    decay_rate: float | None = None
    mode_labels: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    jsr_lower_estimate: float | None = None
    scaling: list | None = None
    cost: object | None = None
    hinf: object | None = None
    #: When ``stable`` is False: the destabilizing cycle as ``{"ages": [...], "modes": [...]}`` (one entry
    #: per sample, repeated forever); on a general network also the automaton ``"nodes"``.
    unstable_cycle: dict | None = None
    #: ``Network.to_dict()`` of the network analyzed (None: given by n_drop only).
    network: dict | None = None
    #: With ``observer_gains``: the whole output-feedback loop's verdict (:class:`solver.observer.OutputAnalysis`).
    output: object | None = None

    @property
    def max_spectral_radius(self) -> float:
        return float(np.max(self.spectral_radii))

    @property
    def margin(self) -> float | None:
        return None if self.certificate is None else self.certificate.margin

    @property
    def jsr_upper_bound(self) -> float | None:
        bounds = [b for b in (self.jsr_upper_bound_quadratic, self.jsr_upper_bound_switched) if b is not None]
        return min(bounds) if bounds else None

    def to_dict(self) -> dict:
        extra = {} if self.network is None else {"network": self.network}
        return extra | {
            "stable": self.stable,
            "reason": self.reason,
            "spectral_radii": self.spectral_radii.tolist(),
            "max_spectral_radius": self.max_spectral_radius,
            "margin": self.margin,
            "certificate": None if self.certificate is None else self.certificate.to_dict(),
            "jsr_lower_bound": self.jsr_lower_bound,
            "jsr_lower_estimate": self.jsr_lower_estimate,
            "scaling": self.scaling,
            "jsr_upper_bound": self.jsr_upper_bound,
            "jsr_upper_bound_quadratic": self.jsr_upper_bound_quadratic,
            "jsr_upper_bound_switched": self.jsr_upper_bound_switched,
            "decay_rate": self.decay_rate,
            "worst_sequence": self.worst_sequence,
            "product_length_checked": self.product_length_checked,
            "modes": self.mode_labels,
            "timings": self.timings,
            "cost": None if self.cost is None else self.cost.to_dict(),
            "hinf": None if self.hinf is None else self.hinf.to_dict(),
            "unstable_cycle": self.unstable_cycle,
        } | ({} if self.output is None else {"output": self.output.to_dict()})


def product_lower_bound(A_modes: np.ndarray, max_length: int, max_products: int,
                        per_length: list | None = None) -> tuple[float, tuple, int]:
    """Largest ``rho(A_{s_k} ... A_{s_1})^(1/k)`` over all mode sequences up to a length.

    Parameters
    ----------
    A_modes : ndarray, shape (S, n, n)
    max_length : int
        Longest product tried.
    max_products : int
        Budget of products per length; longer lengths that exceed it are skipped.

    Returns
    -------
    bound : float
    sequence : tuple of int
        Mode indices in the order applied.
    length_checked : int
    per_length : list, optional
        Filled with ``(estimate, sequence)``, the best product of every length checked: a float
        estimate of a long product can outrank a shorter product that exact arithmetic proves.
    """
    S = A_modes.shape[0]
    rho = spectral_radii(A_modes)
    best = int(np.argmax(rho))
    bound, sequence = float(rho[best]), (best,)
    if per_length is not None:
        per_length.append((bound, sequence))
    products = A_modes
    checked = 1
    for k in range(2, max_length + 1):
        if products.shape[0] * S > max_products:
            break
        # products[i] applies sequence i (base-S digits, first applied most significant);
        # extend every sequence by one more mode applied last.
        products = np.einsum("jab,ibc->ijac", A_modes, products).reshape(-1, *A_modes.shape[1:])
        checked = k
        rho_k = spectral_radii(products) ** (1.0 / k)
        i = int(np.argmax(rho_k))
        if per_length is not None:
            per_length.append((float(rho_k[i]), tuple(int(d) for d in np.unravel_index(i, (S,) * k))))
        if rho_k[i] > bound * (1 + 1e-12):
            bound = float(rho_k[i])
            sequence = tuple(int(d) for d in np.unravel_index(i, (S,) * k))
    return bound, sequence, checked


#: Exact proofs are attempted up to this state dimension (integer characteristic polynomials).
MAX_EXACT_STATES = 24


def _prove_product(family: PlantFamily, K: np.ndarray, modes: ModeSet, seq: tuple, estimate: float):
    """Exact proof on the product ``A_seq[-1] ... A_seq[0]`` of the float64 data.

    Returns ``(proven lower bound of the JSR or None, proven rho >= 1, note)``.
    """
    from . import exact

    if family.n_states > MAX_EXACT_STATES:
        return None, False, f"no exact proof above {MAX_EXACT_STATES} states"
    try:
        maps = [exact.closed_loop(family.F, family.G, K, modes.plants[s]) for s in seq]
    except ValueError as err:
        return None, False, str(err)
    k = len(seq)
    bound, unstable = exact.proven_rate(maps, estimate)
    if bound is None:
        return None, unstable, "no positive lower bound could be proven for the product"
    note = "the best product's radius is proven" if abs(bound - estimate) <= 1e-6 * max(estimate, 1e-300) else (
        f"exact arithmetic proves only rho^(1/{k}) >= {bound:.6g}")
    return bound, unstable, note


def _check_products_fit_float64(A: np.ndarray, max_product_length: int) -> None:
    """Products of up to ``max_product_length`` closed loops must be representable in float64, else no bound
    can be computed from them. The infinity norm is submultiplicative and bounds every entry, so products
    stay finite when ``max_s ||A_s||_inf ** max_product_length`` does (with room for the eigenvalue routine).
    Gains that large are an input error, named as such."""
    with np.errstate(over="ignore", invalid="ignore"):
        norm = float(np.max(np.sum(np.abs(A), axis=-1)))
    if not np.isfinite(norm) or (norm > 1.0 and max_product_length * np.log10(norm) > 300.0):
        shown = f"{norm:.3g}" if np.isfinite(norm) else "infinite"
        raise InvalidInput(
            f"the gains are too large to analyze in float64: the closed-loop matrices have norm {shown}, so "
            f"their products of length up to {max_product_length} overflow (scale the gains down or use a "
            "shorter max_product_length)", ("gains",))


def _check_analysis_budget(family, modes, plant_switching, scheme, solver, certificates, bounds, rate_tol,
                           max_products, max_memory, time_limit) -> None:
    """The same estimate as a design's (:func:`solver.compiled.design_size`) for each certificate SDP."""
    from .compiled import design_size
    from .workload import check_estimate

    n, m, r, N = family.n_states, family.n_inputs, family.n_modes, modes.n_drop
    bound_kinds = {"none": (), "quadratic": ("common_quadratic",), "all": ("common_quadratic", "switched")}[bounds]
    steps = int(np.ceil(np.log2(1.0 / max(float(rate_tol), 1e-12)))) + 1 if bound_kinds else 0
    seconds, memory, largest = 0.0, 3.0 * 8 * max_products * n * n, None
    for kind in dict.fromkeys((*certificates, *bound_kinds)):
        if kind == "switched" and modes.n_modes > MAX_SWITCHED_MODES:
            continue  # neither the certificate nor its bounds are tried above this many modes
        size = design_size("switched" if kind == "switched" else "lmi", n, m, r, N, plant_switching, scheme,
                           solver)
        solves = (kind in certificates) + 2 * steps * (kind in bound_kinds)
        seconds += size.seconds * solves
        memory = max(memory, size.memory)
        if largest is None or size.lmi_size > largest[1]:
            largest = (kind, size.lmi_size, size.n_modes)
    what = "the analysis"
    if largest is not None:
        what += (f" ({largest[2]} closed-loop modes, n = {n} states; its {largest[0]} certificate has LMI size "
                 f"{largest[1]})")
    check_estimate(what, seconds, memory, ("n_drop",),
                   "use a smaller n_drop or fewer plant modes, certificates=('common_quadratic',), "
                   "bounds='none' or fewer max_products", max_memory, time_limit)


def _check_search(max_product_length, max_products) -> None:
    """The product search's options: InvalidInput naming the one out of range."""
    if isinstance(max_product_length, bool) or not isinstance(max_product_length, (int, np.integer)) or not (
        1 <= max_product_length <= 12
    ):
        raise InvalidInput("max_product_length must be an integer in 1..12", ("max_product_length",))
    if isinstance(max_products, bool) or not isinstance(max_products, (int, np.integer)) or not (
        1 <= max_products <= MAX_PRODUCTS
    ):
        raise InvalidInput(f"max_products must be an integer in 1..{MAX_PRODUCTS}", ("max_products",))


def analyze(
    family: PlantFamily,
    gains,
    n_drop: int | None = None,
    *,
    network=None,
    max_product_length: int = 4,
    max_products: int = 100_000,
    plant_switching: str = "per_interval",
    scheme: str = "predictive",
    certificates: tuple = ("common_quadratic", "switched"),
    bounds: str = "quadratic",
    rate_tol: float = 1e-3,
    max_modes: int = MAX_MODES,
    solver: str = "AUTO",
    weights=None,
    x0=None,
    disturbance=None,
    output=None,
    observer_gains=None,
    sensor_n_drop: int | None = None,
    max_memory: float | None = None,
    time_limit: float | None = None,
) -> AnalysisReport:
    """Decide stability of the networked loop with given gains under arbitrary losses and jumps.

    Parameters
    ----------
    family : PlantFamily
    gains : array_like, shape (n_drop, m, n)
        ``gains[q-1] = K_q`` (for m = 1 also (n_drop, n)).
    n_drop : int, optional
        The paper's network ``Network.bounded_drops(n_drop)``; give this or ``network``.
    network : Network, dict or str, optional
        The admissible packet patterns (:class:`solver.Network`; docs/design.md, "Networks: delays and
        weakly-hard patterns").  One equal to ``bounded_drops`` takes the interval analysis below
        unchanged; any other is analyzed on the augmented state with one quadratic Lyapunov function
        per automaton state (:mod:`solver.network_analysis`): ``certificate`` is then a
        ``NetworkCertificate``, ``unstable_cycle`` the proven destabilizing admissible cycle,
        ``jsr_lower_bound``/``jsr_upper_bound`` bracket the constrained JSR per sample, and
        ``max_product_length`` bounds the cycle length searched.  ``weights``/``disturbance`` and the
        switched certificate are not available there.
    max_product_length : int
        Longest product of modes searched for a destabilizing pattern (1..12).
    max_products : int
        Budget of products per length (bounds time and memory), at most 1e6.
    plant_switching : {"per_interval", "per_sample"}
    scheme : {"predictive", "hold", "zero"}
        Only used to label the report; the gains are taken as given.
    certificates : tuple of {"common_quadratic", "switched"}
        Certificate kinds tried, in order.
    bounds : {"quadratic", "all", "none"}
        JSR upper bounds and best certified decay rate to compute, by
        bisection: from common quadratic certificates (a few ms per SDP),
        also from switched ones (``"all"``; S^2 pairwise LMIs per SDP, about a
        second for the paper's example), or none.
    rate_tol : float
        Tolerance of those bisections.
    max_modes : int
    solver : {"AUTO", "IPM", "CLARABEL", "SCS"}
        As in :func:`solver.design`: under "AUTO" the common fixed-gain LMI (and its rate bisection)
        runs on the structured IPM, the switched one on Clarabel.
    weights : (Q, R), optional
        Report ``rep.cost``: the bracket of the worst-case cost ``sum_k x' Q x + u' R u`` (from ``x0``, or
        ``trace`` for initial states of covariance I), as in :func:`solver.design` with ``objective="cost"``.
    x0 : array_like of n, optional
    disturbance : array_like, optional
        ``E`` (one or one per plant mode): report ``rep.hinf``, the l2-gain bracket from w to z.
    output : (C, D), optional
        ``z = C x + D u`` (default ``z = [x; u]``).
    observer_gains : array_like (r, n, p), optional
        Output feedback (docs/design.md, "Output feedback"): decide the whole loop with the observer
        ``L`` on ``family.C``; ``rep.output`` (:class:`solver.observer.OutputAnalysis`) holds the joint
        certificate or the proof, and ``rep.stable`` is its verdict.
    sensor_n_drop : int, optional
        With ``observer_gains``: at most ``sensor_n_drop - 1`` lost measurements in a row (default ``n_drop``).
    max_memory, time_limit : float, optional
        Budget in bytes and seconds (defaults: 4 GiB, ``NCS_SOLVER_MAX_MEMORY``; 300 s,
        ``NCS_SOLVER_MAX_SECONDS``).  Each certificate SDP is estimated like a design of the same size
        (:func:`solver.compiled.design_size`; ``switched`` like the switched method), times the solves of its
        rate bisections, plus the product search's ``max_products`` matrices; an analysis over the budget is
        refused with ``InvalidInput`` naming the size before anything is solved.

    Returns
    -------
    AnalysisReport
    """
    if observer_gains is None and sensor_n_drop is not None:
        raise InvalidInput("sensor_n_drop applies to output feedback: pass observer_gains", ("sensor_n_drop",))
    if observer_gains is not None:
        from .observer import analyze_output, check_sensor_n_drop, require_outputs

        require_outputs(family)
        M = check_sensor_n_drop(n_drop if sensor_n_drop is None else sensor_n_drop)
        if any(v is not None for v in (weights, x0, disturbance, output)):
            raise InvalidInput("cost and l2-gain brackets are not available with observer_gains yet",
                               ("observer_gains",))
        rep = analyze(family, gains, n_drop, max_product_length=max_product_length, max_products=max_products,
                      plant_switching=plant_switching, scheme=scheme, certificates=certificates, bounds="none",
                      rate_tol=rate_tol, max_modes=max_modes, solver=solver)
        out = analyze_output(family, gains, n_drop, observer_gains, M, plant_switching=plant_switching,
                             scheme=scheme, state_report=rep)
        out.state_feedback = None  # the report itself is the full-state part
        rep.output = out
        rep.stable = out.stable
        rep.reason = f"output feedback: {out.reason} (full-state loop: {rep.reason})"
        return rep
    start = time.perf_counter()
    if not isinstance(family, PlantFamily):
        raise InvalidInput("family must be a PlantFamily", ("family",))
    net = None
    if network is not None:
        from .networks import check_network

        net = check_network(network, n_drop)
        n_drop = net.n_drop
        if not net.is_bounded_drops:
            return _analyze_network(family, gains, net, start, max_product_length=max_product_length,
                                    max_products=max_products, plant_switching=plant_switching, bounds=bounds,
                                    rate_tol=rate_tol, solver=solver, weights=weights, x0=x0,
                                    disturbance=disturbance, output=output)
    elif n_drop is None:
        raise InvalidInput("give n_drop (the paper's network) or network=Network...", ("n_drop",))
    modes = ModeSet.from_family(family, n_drop, plant_switching=plant_switching, scheme=scheme,
                                max_modes=max_modes)
    K = check_gains(gains, modes.n_drop, family.n_inputs, family.n_states)
    _check_search(max_product_length, max_products)
    for kind in certificates:
        if kind not in ("common_quadratic", "switched"):
            raise InvalidInput("certificates must name 'common_quadratic' and/or 'switched'", ("certificates",))
    if bounds not in ("quadratic", "all", "none"):
        raise InvalidInput("bounds must be 'quadratic', 'all' or 'none'", ("bounds",))
    solver = check_solver(solver)
    _check_analysis_budget(family, modes, plant_switching, scheme, solver, certificates, bounds, rate_tol,
                           max_products, max_memory, time_limit)
    A = modes.closed_loops(K)
    _check_products_fit_float64(A, max_product_length)
    radii = spectral_radii(A)
    candidates: list = []
    estimate, seq, checked = product_lower_bound(A, max_product_length, max_products, per_length=candidates)
    proven, unstable, proof_note = _prove_product(family, K, modes, seq, estimate)
    if not unstable:
        # a proof once found is kept: the float-best product may be a rounding artefact (its exact radius
        # smaller) while a shorter one is proven unstable; try every length whose estimate reaches 1
        for est, other in sorted(candidates, reverse=True):
            if other == seq or est ** len(other) < 1 - 1e-6:
                continue
            bound, other_unstable, _ = _prove_product(family, K, modes, other, est)
            if bound is not None and (proven is None or bound > proven):
                proven = bound
            if other_unstable:
                seq, unstable = other, True
                proof_note = f"proven on a product of length {len(other)}; longer products only estimated"
                break
    worst = [modes.label(s) for s in seq]
    certificate = None
    scaling = None
    upper_q = upper_s = rate = None
    failure = ""
    if unstable:
        stable = False
        if len(worst) == 1:
            reason = (f"mode {worst[0]} has spectral radius >= 1 (proven exactly; float64 estimate "
                      f"{float(radii[seq[0]]):.6g})")
        else:
            reason = (
                f"repeating the sequence of {len(worst)} intervals in worst_sequence gives a product with "
                f"spectral radius >= 1 (proven exactly; float64 estimate of the best product's "
                f"rho^(1/length) = {estimate:.6g})"
            )
    else:
        try:
            certificate = certify(A, modes.n_drop, kinds=tuple(certificates), solver=solver)
            scale = balance(family)
            if certificate is None and not scale.is_identity:
                # T^-1 A_s T is exact (powers of two): a certificate for it proves the same loop
                T = scale.state
                certificate = certify(A / T[None, :, None] * T[None, None, :], modes.n_drop,
                                      kinds=tuple(certificates), solver=solver)
                if certificate is not None:
                    scaling = T.tolist()
        except SolverFailed as err:
            failure = f"; {err}"
        if certificate is not None:
            stable = True
            where = "" if scaling is None else " for T^-1 A_s T (state scaling T in `scaling`, exact)"
            reason = (f"{certificate.kind} certificate re-checked in float64{where} "
                      f"(relative margin {certificate.margin:.3g})")
        else:
            stable = None
            reason = (
                f"no certificate ({', '.join(certificates)}) and no product up to length {checked} proven to have "
                f"spectral radius >= 1 (float64 estimate {estimate:.6g}; {proof_note}){failure}"
            )
    kinds = {"none": (), "quadratic": ("common_quadratic",), "all": ("common_quadratic", "switched")}[bounds]
    rates = []
    for kind in kinds:
        if kind == "switched" and modes.n_modes > MAX_SWITCHED_MODES:
            continue
        # the interval maps' JSR is at most max_s ||A_s||_2 (X = I): search up to there, above 1 too
        top = max(1.0, 1.01 * float(np.max(np.linalg.norm(A, ord=2, axis=(1, 2)))))
        upper, _ = certified_rate(A, modes.eta, kind, per="interval", hi=top, tol=rate_tol * top, solver=solver)
        if kind == "switched":
            upper_s = upper
        else:
            upper_q = upper
        rates.append(certified_rate(A, modes.eta, kind, per="sample", tol=rate_tol, solver=solver)[0])
    rates = [r for r in rates if r is not None]
    rate = min(rates) if rates else None
    cost = hinf = None
    if weights is not None or x0 is not None or disturbance is not None or output is not None:
        cost, hinf = _performance(modes, K, weights, x0, disturbance, output, solver)
    return AnalysisReport(
        stable=stable,
        spectral_radii=modes.reshape_per_mode(radii),
        certificate=certificate,
        jsr_lower_bound=proven,
        jsr_lower_estimate=estimate,
        scaling=scaling,
        worst_sequence=worst,
        product_length_checked=checked,
        reason=reason,
        jsr_upper_bound_quadratic=upper_q,
        jsr_upper_bound_switched=upper_s,
        decay_rate=rate,
        mode_labels=[modes.label(s) for s in range(modes.n_modes)],
        timings={"total": time.perf_counter() - start},
        cost=cost,
        hinf=hinf,
        unstable_cycle=_interval_cycle(worst) if stable is False else None,
        network=None if net is None else net.to_dict(),
    )


def _interval_cycle(worst: list) -> dict:
    """The ages and plant modes, sample by sample, of a destabilizing sequence of intervals."""
    ages, plants = [], []
    for w in worst:
        ages += list(range(w["eta"]))
        plants += list(w["plants"]) if "plants" in w else [w["plant"]] * w["eta"]
    return {"ages": ages, "modes": plants}


def _analyze_network(family, gains, net, start, *, max_product_length, max_products, plant_switching, bounds,
                     rate_tol, solver, weights, x0, disturbance, output) -> AnalysisReport:
    """analyze() on a network other than bounded_drops (solver/network_analysis.py)."""
    from .network_analysis import analyze_network

    if any(v is not None for v in (weights, x0, disturbance, output)):
        raise InvalidInput(f"cost and H-infinity brackets are computed on bounded_drops networks only, not on "
                           f"{net.describe()}", ("weights" if weights is not None else "disturbance",))
    K = check_gains(gains, net.n_drop, family.n_inputs, family.n_states)
    _check_search(max_product_length, max_products)
    if bounds not in ("quadratic", "all", "none"):
        raise InvalidInput("bounds must be 'quadratic', 'all' or 'none'", ("bounds",))
    solver = check_solver(solver)
    fields = analyze_network(family, K, net, plant_switching=plant_switching, max_product_length=max_product_length,
                             max_products=max_products, bounds=bounds, rate_tol=rate_tol, solver=solver)
    return AnalysisReport(**fields, timings={"total": time.perf_counter() - start}, network=net.to_dict())


def _performance(modes: ModeSet, K: np.ndarray, weights, x0, disturbance, output, solver: str):
    """The cost and H-infinity brackets of fixed gains (solver/brackets.py)."""
    from .lifting import lift_modes
    from .brackets import bracket, check_x0

    if disturbance is None and output is not None:
        raise InvalidInput("output needs disturbance=E", ("output",))
    x0 = check_x0(x0, modes.n_states)
    want_cost = weights is not None or x0 is not None
    lifted = lift_modes(modes, weights, disturbance, output, cost=want_cost)
    cost = bracket(lifted, K, "cost", x0=x0, solver=solver) if want_cost else None
    hinf = bracket(lifted, K, "hinf", solver=solver) if disturbance is not None else None
    return cost, hinf
