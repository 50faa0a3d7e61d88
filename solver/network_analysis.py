"""Stability of given gains on a network automaton (delays, reordering, weakly-hard patterns).

The loop is the switched system ``xi(t+1) = A[l_t, d_t] xi(t)`` on the augmented state
``xi = (x(t), ..., x(t-N+1))`` (:func:`solver.networks.loop_matrices`) whose age sequence
``d_t`` is a run of the network automaton and whose plant mode ``l_t`` switches as
``plant_switching`` allows.  Both are tracked by one *product automaton*: a state is
``v = (node, plant mode)`` and its matrix is ``A_v = A[l, age(node)]``.

* ``stable=True``: a node-dependent quadratic Lyapunov function, ``P_v > 0`` with
  ``A_v^T P_w A_v - P_v < 0`` for every edge ``v -> w`` (Lee and Dullerud 2006; Philippe et al.
  2016), found by an SDP (Clarabel or SCS through cvxpy) and re-checked in float64 with
  ``eigvalsh``: ``V_v(xi) = xi^T P_v xi`` decreases along every admissible run.
* ``stable=False``: a cycle of the product automaton whose matrix product has spectral radius
  ``>= 1``, proven in exact arithmetic on the float64 data (:mod:`solver.exact`); the
  admissible run repeating that cycle forever does not converge.
* ``stable=None``: neither; a bracket on the constrained joint spectral radius (CJSR) is given:
  below, the best cycle; above, the smallest rate ``rho`` with a re-checked certificate of
  ``A_v^T P_w A_v <= rho^2 P_v``.

docs/design.md, "Networks: delays and weakly-hard patterns".
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from . import exact
from .errors import InvalidInput, SolverFailed
from .lyapunov import RECHECK_TOL, _sym
from .networks import Network, loop_matrices

#: Largest Lyapunov SDP built: product states times the augmented dimension.
MAX_LMI_ROWS = 6000
#: Exact proofs are attempted up to this augmented dimension (integer characteristic polynomials).
MAX_EXACT_DIMENSION = 24


@dataclass(frozen=True)
class ProductAutomaton:
    """Network nodes times plant modes: ``states[v] = (node, mode)``, ``succ[v]`` the next states."""

    states: list
    succ: list
    ages: np.ndarray
    modes: np.ndarray

    @property
    def size(self) -> int:
        return len(self.states)


def product_automaton(net: Network, n_plants: int, plant_switching: str) -> ProductAutomaton:
    """The states ``(node, plant mode)`` and their edges.

    ``"per_interval"`` (the paper's model): the plant mode may change only at a sample where a newer
    packet reached the buffer (the age did not grow); ``"per_sample"``: at every sample.
    """
    if plant_switching not in ("per_interval", "per_sample"):
        raise InvalidInput("plant_switching must be 'per_interval' or 'per_sample'", ("plant_switching",))
    states = [(i, l) for i in range(net.nodes) for l in range(n_plants)]
    index = {s: k for k, s in enumerate(states)}
    succ = []
    for i, l in states:
        out = []
        for j in net.successors(i):
            fresh = net.ages[j] <= net.ages[i]
            for l2 in range(n_plants):
                if l2 == l or fresh or plant_switching == "per_sample":
                    out.append(index[(j, l2)])
        succ.append(out)
    return ProductAutomaton(states, succ, np.array([net.ages[i] for i, _ in states]),
                            np.array([l for _, l in states]))


@dataclass
class NetworkCertificate:
    """A node-dependent quadratic Lyapunov function on the augmented state, re-checked in float64.

    Attributes
    ----------
    kind : str
        ``"node_dependent"``.
    P : ndarray, shape (V, n*N, n*N)
        One matrix per product state ``states[v] = (network node, plant mode)``.
    states : list of (int, int)
    min_eig_P : float
    decrease : float
        Smallest eigenvalue of ``rho^2 P_v - A_v^T P_w A_v`` over all edges.
    margin : float
        ``decrease / max lambda_max(P_v)``; verified iff ``min_eig_P > 0`` and ``margin > RECHECK_TOL``.
    verified : bool
    source : str
    decay_rate : float or None
        The per-sample rate ``rho`` certified (None: plain stability, rho = 1).
    worst_edge : (int, int) or None
    """

    kind: str
    P: np.ndarray
    states: list
    min_eig_P: float
    decrease: float
    margin: float
    verified: bool
    source: str
    decay_rate: float | None = None
    worst_edge: tuple | None = None

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "source": self.source,
            "verified": self.verified,
            "margin": self.margin,
            "decrease": self.decrease,
            "min_eig_P": self.min_eig_P,
            "condition_number": float(max(np.linalg.cond(M) for M in self.P)),
            "decay_rate": self.decay_rate,
            "worst_edge": None if self.worst_edge is None else list(self.worst_edge),
            "states": [{"node": int(i), "plant": int(l)} for i, l in self.states],
            "P": self.P.tolist(),
        }


def recheck_node_dependent(P: np.ndarray, A_states: np.ndarray, product: ProductAutomaton, rho: float = 1.0,
                           source: str = "node_lmi") -> NetworkCertificate:
    """Float64 re-check: ``P_v > 0`` and ``rho^2 P_v - A_v^T P_w A_v > 0`` for every edge ``v -> w``."""
    P = _sym(np.asarray(P, dtype=np.float64))
    eig = np.linalg.eigvalsh(P)
    worst, worst_edge = np.inf, None
    for v, out in enumerate(product.succ):
        At = A_states[v].T
        if not out:
            continue
        diff = rho**2 * P[v][None] - At[None] @ P[out] @ A_states[v][None]
        dec = np.linalg.eigvalsh(_sym(diff))[:, 0]
        k = int(np.argmin(dec))
        if dec[k] < worst:
            worst, worst_edge = float(dec[k]), (v, out[k])
    top = float(eig[:, -1].max())
    margin = worst / top if top > 0 else -np.inf
    ok = bool(eig[:, 0].min() > 0 and margin > RECHECK_TOL)
    return NetworkCertificate("node_dependent", P, list(product.states), float(eig[:, 0].min()), worst,
                              float(margin), ok, source, None if rho == 1.0 else float(rho), worst_edge)


def node_sdp_memory(succ, D: int, solver: str = "AUTO") -> int:
    """Bytes of the node SDP on the solver ``solver`` runs it on (docs/design.md §11.4).

    The structured IPM's :func:`solver.ipm.network_blocks.node_memory` under ``"IPM"``, and under ``"AUTO"`` when it fits
    :data:`solver.compiled.MAX_SOLVER_MEMORY`; otherwise Clarabel's KKT system, one dense ``(D(D+1)/2)^2`` scaling
    per PSD cone of side D (one per edge and per state).
    """
    from .compiled import MAX_SOLVER_MEMORY, clarabel_kkt_bytes
    from .ipm.network_blocks import node_memory

    name = str(solver).upper()
    if name in ("IPM", "AUTO"):
        need = node_memory(succ, D)
        if name == "IPM" or need <= MAX_SOLVER_MEMORY:
            return need
    return clarabel_kkt_bytes([int(D)] * (sum(len(out) for out in succ) + len(succ)))


class NodeLMI:
    """``P_v >= I``, ``A_v^T P_w A_v - rho^2 P_v <= -I`` for every edge, minimize ``sum_v trace P_v``.

    The conditions are homogeneous in P, so the normalization loses nothing; ``rho^2`` is a
    cvxpy parameter, so a bisection on the rate re-solves without rebuilding.  Under ``solver="AUTO"`` the
    SDP runs first on the structured IPM in its max-t form (:func:`solver.ipm.network_blocks.node_problem`, the same
    conditions; block-sparse Schur complement, docs/design.md §11.4) when its memory fits the budget
    (:meth:`ipm_fits`), and on Clarabel when the IPM's P fails the float64 re-check short of a converged
    ``t* <= 0``.
    """

    def __init__(self, A_states: np.ndarray, product: ProductAutomaton):
        self.A_states, self.product = A_states, product
        self.problem = None
        self.ipm_solves = 0

    def _build(self):
        from .compiled import cp

        A_states, product = self.A_states, self.product
        V, D = A_states.shape[0], A_states.shape[1]
        self.rho2 = cp.Parameter(nonneg=True, value=1.0)
        self.P = [cp.Variable((D, D), symmetric=True) for _ in range(V)]
        eye = np.eye(D)
        cons = []
        for v in range(V):
            cons.append(self.P[v] >> eye)
            for w in product.succ[v]:
                E = A_states[v].T @ self.P[w] @ A_states[v] - self.rho2 * self.P[v]
                cons.append(0.5 * (E + E.T) << -eye)
        self.problem = cp.Problem(cp.Minimize(sum(cp.trace(P) for P in self.P)), cons)

    def ipm_fits(self) -> bool:
        """Whether the structured IPM's memory (:func:`solver.ipm.network_blocks.node_memory`) fits the budget."""
        from .compiled import MAX_SOLVER_MEMORY
        from .ipm.network_blocks import node_memory

        if self.__dict__.get("_fits") is None:
            self._fits = node_memory(self.product.succ, self.A_states.shape[1]) <= MAX_SOLVER_MEMORY
        return self._fits

    def _ipm(self, rho: float, only: bool):
        """The IPM's P when it decides (passes the re-check, or converged to ``t* <= 0``: None), else False."""
        from .ipm.network_blocks import solve_node

        self.ipm_solves += 1
        try:
            t, P, status = solve_node(self.A_states, self.product.succ, rho)
        except (SolverFailed, np.linalg.LinAlgError, ValueError):
            return None if only else False
        if np.isfinite(t) and t > 0 and recheck_node_dependent(P, self.A_states, self.product, rho).verified:
            return P
        if only or (status == "optimal" and not t > 0):
            return None
        return False

    def solve(self, rho: float, solver: str):
        """The P matrices (V, D, D), or None when the solver reports no solution."""
        from .compiled import cp

        name = str(solver).upper()
        if name == "IPM" or (name == "AUTO" and self.ipm_fits()):
            P = self._ipm(rho, name == "IPM")
            if P is not False:
                return P
        if self.problem is None:
            self._build()
        self.rho2.value = float(rho) ** 2
        name = {"SCS": cp.SCS}.get(name, cp.CLARABEL)
        try:
            with warnings.catch_warnings():
                # "optimal_inaccurate" answers are used only through the float64 re-check
                warnings.simplefilter("ignore", UserWarning)
                self.problem.solve(solver=name)
        except cp.error.SolverError as err:
            raise SolverFailed(f"the node-dependent Lyapunov SDP failed: {err}", "solver_error") from None
        if self.problem.status not in ("optimal", "optimal_inaccurate") or self.P[0].value is None:
            return None
        return np.array([P.value for P in self.P])


def fixed_gain_certificate(family, K: np.ndarray, net: Network, rate: float | None = None, *,
                           plant_switching: str = "per_interval", solver: str = "AUTO") -> NetworkCertificate | None:
    """The node analysis of given gains at one per-sample decay rate (docs/design.md §11.1, "Fixed-rate fallback").

    The node SDP of :class:`NodeLMI` on the product automaton (one ``P_v`` per network node and plant mode, on the
    augmented state) at ``rho = rate`` (None: plain stability, ``rho = 1``), re-checked in float64 by
    :func:`recheck_node_dependent` at that rate: ``V_v(xi) = xi^T P_v xi`` shrinks by ``rate^2`` per sample along
    every admissible run.

    Parameters
    ----------
    family : PlantFamily
    K : ndarray, shape (N, m, n)
        The gains, ``N = net.n_drop``.
    net : Network
    rate : float or None
        The per-sample decay rate to certify.
    plant_switching, solver : str
        As for :func:`analyze_network`.

    Returns
    -------
    NetworkCertificate or None
        The verified certificate; None when no P passes the re-check, the solver fails, or the SDP is over the
        limits :func:`analyze_network` refuses up front (a fallback never raises for them).
    """
    from .compiled import MAX_SOLVER_MEMORY

    A = loop_matrices(family, K, net)
    product = product_automaton(net, family.n_modes, plant_switching)
    D = A.shape[-1]
    if product.size * D > MAX_LMI_ROWS or node_sdp_memory(product.succ, D, solver) > MAX_SOLVER_MEMORY:
        return None
    A_states = A[product.modes, product.ages]  # (V, D, D)
    if not np.all(np.isfinite(A_states)):
        return None
    rho = 1.0 if rate is None else float(rate)
    try:
        P = NodeLMI(A_states, product).solve(rho, solver)
    except SolverFailed:
        return None
    if P is None or not np.all(np.isfinite(P)):
        return None
    cert = recheck_node_dependent(P, A_states, product, rho, source="node_lmi" if rate is None else "node_lmi_rate")
    return cert if cert.verified else None


def cycle_products(A_states: np.ndarray, product: ProductAutomaton, max_length: int, max_products: int):
    """Closed walks of the product automaton up to ``max_length`` and ``rho(product)^(1/length)``.

    Every closed walk is searched from its smallest state (the others on it are larger), so each
    cycle is met once per rotation class.  Returns the best ``(estimate, states)`` per length
    (``states`` in the order applied), the length up to which every closed walk was examined, and
    whether the budget ``max_products`` (walks per start state and length) cut the search short.
    """
    from .network import spectral_radii

    V = product.size
    # products held at once stay under ~80 MB whatever the state dimension
    max_products = max(1, min(int(max_products), int(1e7 // A_states.shape[-1] ** 2)))
    best: dict = {}
    searched = max_length  # every closed walk up to this length was examined
    for v in range(V):
        paths = np.array([[v]], dtype=np.int64)
        prods = A_states[v][None]
        for k in range(1, max_length + 1):
            closes = np.array([v in product.succ[p[-1]] for p in paths], dtype=bool)
            if closes.any():
                rho = spectral_radii(prods[closes]) ** (1.0 / k)
                i = int(np.argmax(rho))
                if rho[i] > best.get(k, (-1.0, None))[0]:
                    best[k] = (float(rho[i]), tuple(int(s) for s in paths[closes][i]))
            if k == max_length:
                break
            parent, nxt = [], []
            for idx, p in enumerate(paths):
                for w in product.succ[p[-1]]:
                    if w >= v:
                        parent.append(idx)
                        nxt.append(w)
            if not parent:
                break
            if len(parent) > max_products:
                searched = min(searched, k)
                break
            parent = np.array(parent)
            nxt = np.array(nxt)
            prods = A_states[nxt] @ prods[parent]
            paths = np.concatenate([paths[parent], nxt[:, None]], axis=1)
    return best, searched, searched < max_length


def exact_loop(F, G, K, d: int, N: int) -> tuple:
    """The augmented matrix ``A[l, d]`` of :func:`solver.networks.loop_matrices`, exactly (``(M, s)``)."""
    n = F.shape[0]
    Fe = exact.exact(F)
    GK = exact.matmul(exact.exact(G), exact.exact(K[d]))
    top_left = exact.add(Fe, GK) if d == 0 else Fe
    s = max(top_left[1], GK[1])
    M = np.zeros((n * N, n * N), dtype=object)
    M[:, :] = 0
    M[:n, :n] = top_left[0] * (1 << (s - top_left[1]))
    if d > 0:
        M[:n, d * n:(d + 1) * n] = GK[0] * (1 << (s - GK[1]))
    for i in range(1, N):
        for j in range(n):
            M[i * n + j, (i - 1) * n + j] = 1 << s
    return M, s


def prove_cycle(family, K, N: int, product: ProductAutomaton, cycle: tuple, estimate: float):
    """Exact ``rho`` of a cycle's product: ``(proven lower bound of rho^(1/k) or None, proven >= 1, note)``."""
    if family.n_states * N > MAX_EXACT_DIMENSION:
        return None, False, f"no exact proof above dimension {MAX_EXACT_DIMENSION} (n * n_drop)"
    try:
        mats = [exact_loop(family.F[product.modes[v]], family.G[product.modes[v]], K, int(product.ages[v]), N)
                for v in cycle]
    except ValueError as err:
        return None, False, str(err)
    bound, unstable = exact.proven_rate(mats, estimate)
    if bound is None:
        return None, unstable, "no positive lower bound could be proven for the cycle"
    return bound, unstable, "proven exactly"


def analyze_network(family, K: np.ndarray, net: Network, *, plant_switching: str = "per_interval",
                    max_product_length: int = 6, max_products: int = 100_000, bounds: str = "quadratic",
                    rate_tol: float = 1e-3, solver: str = "AUTO"):
    """The fields of :class:`solver.analysis.AnalysisReport` for gains ``K`` (N, m, n) on ``net``."""
    N = net.n_drop
    A = loop_matrices(family, K, net)  # (r, N, D, D)
    product = product_automaton(net, family.n_modes, plant_switching)
    D = A.shape[-1]
    if product.size * D > MAX_LMI_ROWS:
        raise InvalidInput(
            f"{product.size} automaton states (network nodes x plant modes) of size {D} make a Lyapunov SDP "
            f"of {product.size * D} rows, above the limit of {MAX_LMI_ROWS}: use a smaller network or n_drop",
            ("network",))
    need = node_sdp_memory(product.succ, D, solver)
    from .compiled import MAX_SOLVER_MEMORY

    if need > MAX_SOLVER_MEMORY:
        raise InvalidInput(
            f"{product.size} automaton states of size {D} make a Lyapunov SDP that would need about "
            f"{need / 2**30:.1f} GiB of solver memory (limit {MAX_SOLVER_MEMORY / 2**30:.1f} GiB): use a smaller "
            "network or n_drop", ("network",))
    A_states = A[product.modes, product.ages]  # (V, D, D)
    with np.errstate(over="ignore", invalid="ignore"):
        norm = float(np.max(np.sum(np.abs(A_states), axis=-1)))
    if not np.isfinite(norm) or (norm > 1.0 and max_product_length * np.log10(norm) > 300.0):
        raise InvalidInput("the gains are too large to analyze in float64 (products of the closed-loop "
                           "matrices overflow); scale them down or use a shorter max_product_length", ("gains",))
    best, checked, _ = cycle_products(A_states, product, max_product_length, max_products)
    order = sorted(best.items(), key=lambda kv: -kv[1][0])
    estimate, cycle = order[0][1]
    proven, unstable, note = prove_cycle(family, K, N, product, cycle, estimate)
    if not unstable:
        for _, (est, other) in order[1:]:
            if est ** len(other) < 1 - 1e-6:
                continue
            bound, other_unstable, _ = prove_cycle(family, K, N, product, other, est)
            if bound is not None and (proven is None or bound > proven):
                proven = bound
            if other_unstable:
                cycle, unstable, note = other, True, f"proven on a cycle of length {len(other)}"
                break
    labels = [{"age": int(product.ages[v]), "plant": int(product.modes[v]), "node": int(product.states[v][0])}
              for v in cycle]
    unstable_cycle = None
    certificate = None
    failure = ""
    lmi = None
    if unstable:
        stable = False
        unstable_cycle = {"ages": [c["age"] for c in labels], "modes": [c["plant"] for c in labels],
                          "nodes": [c["node"] for c in labels]}
        reason = (f"the admissible age cycle {unstable_cycle['ages']} (plant modes {unstable_cycle['modes']}) "
                  f"repeated forever gives a product with spectral radius >= 1 (proven exactly; float64 estimate "
                  f"of rho^(1/length) = {estimate:.6g})")
    else:
        try:
            lmi = NodeLMI(A_states, product)
            P = lmi.solve(1.0, solver)
            if P is not None:
                cert = recheck_node_dependent(P, A_states, product)
                certificate = cert if cert.verified else None
                if not cert.verified:
                    failure = f"; the solver's P failed the float64 re-check (margin {cert.margin:.3g})"
        except SolverFailed as err:
            failure = f"; {err}"
        if certificate is not None:
            stable = True
            reason = (f"node-dependent quadratic Lyapunov certificate on {net.describe()} re-checked in float64 "
                      f"(relative margin {certificate.margin:.3g})")
        else:
            stable = None
            reason = (f"no node-dependent quadratic certificate on {net.describe()} and no admissible cycle up to "
                      f"length {checked} proven to have spectral radius >= 1 (float64 estimate {estimate:.6g}; "
                      f"{note}){failure}")
    upper = None
    if bounds != "none":
        try:
            lmi = lmi or NodeLMI(A_states, product)
            # under "AUTO" the probes run on the IPM alone when it fits: a probe it does not certify is not certified
            # (a Clarabel fallback there doubled the cost of the infeasible probes below the CJSR, where the IPM
            # stops "inaccurate" at t ~ 0); n = 4, weakly_hard(3, 8, 4), 64 states: 26 s against 136 s on Clarabel
            # (CPU), and its bound 0.6407 against 0.6548
            name = str(solver).upper()
            probes = ("IPM" if lmi.ipm_fits() else "CLARABEL") if name == "AUTO" else solver
            upper, rate_cert = certified_cjsr_upper(lmi, A_states, product, estimate, rate_tol, probes,
                                                    known_stable=certificate is not None)
        except SolverFailed:
            upper, rate_cert = None, None
        if stable is None and upper is not None and upper < 1 and rate_cert is not None:
            # the rate search certified a decay the plain solve missed (numerical failure at rho = 1)
            stable, certificate = True, rate_cert
            reason = (f"node-dependent quadratic Lyapunov certificate on {net.describe()} with decay rate "
                      f"{upper:.6g} per sample, re-checked in float64 (relative margin {certificate.margin:.3g})")
    radii = np.max(np.abs(np.linalg.eigvals(A)), axis=-1)  # (r, N)
    return dict(
        stable=stable,
        spectral_radii=radii,
        certificate=certificate,
        jsr_lower_bound=proven,
        jsr_lower_estimate=estimate,
        worst_sequence=labels,
        product_length_checked=checked,
        reason=reason,
        jsr_upper_bound_quadratic=upper,
        decay_rate=upper if upper is not None and upper < 1 else None,
        mode_labels=[{"age": d, "plant": l} for l in range(family.n_modes) for d in range(N)],
        unstable_cycle=unstable_cycle,
    )


def certified_cjsr_upper(lmi: NodeLMI, A_states, product, lower: float, tol: float, solver: str,
                         known_stable: bool):
    """Smallest rate ``rho`` (per sample) with a re-checked node-dependent certificate, by bisection.

    Returns ``(rho, certificate)``, the certificate re-checked by :func:`recheck_node_dependent` at
    that rate, or ``(None, None)``.  With ``known_stable`` the search starts at ``rho = 1``.
    """
    found = {}

    def ok(rho):
        try:
            P = lmi.solve(rho, solver)
        except SolverFailed:  # a numerical failure proves nothing either way: not certified at this rate
            return False
        if P is None:
            return False
        cert = recheck_node_dependent(P, A_states, product, rho=rho, source="node_lmi_rate")
        if cert.verified:
            found[rho] = cert
        return cert.verified

    norms = np.linalg.norm(A_states, ord=2, axis=(1, 2))
    top = max(1.0, 1.01 * float(np.max(norms)))
    if known_stable:
        hi = 1.0
    else:
        # grow from the best cycle: near the CJSR the SDP is better conditioned than at max ||A_v||
        hi = 1.25 * max(1.0, lower)
        while not ok(hi):
            if hi >= top:
                return None, None
            hi = min(2.0 * hi, top)
    lo = max(lower, 0.0)
    # quadratic bounds are often tight: a rate just above the best cycle usually settles it in one solve
    first = lower * (1 + 2 * tol)
    if lo < first < hi:
        if ok(first):
            hi = first
        else:
            lo = first
    while hi - lo > tol * hi:
        mid = 0.5 * (lo + hi)
        if ok(mid):
            hi = mid
        else:
            lo = mid
    return float(hi), found.get(hi)
