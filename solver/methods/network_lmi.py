"""Convex design on a network automaton (docs/design.md, "Design on a network").

A network (:class:`solver.Network`) is a finite automaton whose runs are the admissible buffer-age sequences.
The design looks for one quadratic Lyapunov function per automaton node and one set of gains, through a
common slack ``Z`` (de Oliveira, Bernussou and Geromel 1999; with node-dependent matrices as in Lee and
Dullerud 2006): for every transition ``v -> w`` of the automaton and every plant mode,

    B_e = [[Z + Z^T - W_v, (c_e A_e Z)^T], [c_e A_e Z, W_w]] >= t I,     W_v >= t I,

with ``A_e Z`` affine in ``(Z, Y)``.  From a solution, ``K_j = Y_j Z_j^{-1}`` and ``P_v = W_v^{-1}`` satisfy
``A_e^T P_w A_e < c_e^{-2} P_v`` (the Schur complement and ``Z^T W^{-1} Z >= Z + Z^T - W``), so
``V(v, state) = state^T P_v state`` decreases along every run.  ``c_e = lambda^(-length)`` demands a decay rate.

Two forms:

* **lifted** (every packet that takes effect is fresh: the network's edges go to age 0 or ``d + 1``, e.g.
  weakly-hard and bounded-drops networks): the state is ``x`` at the samples where a packet takes effect,
  the transitions are the interval maps ``A_{l,eta}(K)`` of :class:`solver.network.ModeSet` along the
  automaton's paths ``0, 1, ..., eta - 1, 0`` between reception nodes, ``Z`` is n x n, ``Y_j = K_j Z``.
  With one reception node (bounded drops) and ``Z = W`` it is the ``lmi`` design.
* **augmented** (late packets, e.g. :meth:`Network.delays`): the state is ``xi(t) = (x(t), ..., x(t-N+1))``,
  one transition per automaton edge and plant mode (the plant may switch at every sample), ``A_{l,d}``
  with ``u(t) = K_{d+1} x(t-d)``; ``Z = blkdiag(Z_0, ..., Z_{N-1})`` so that ``K_{d+1} E_d Z = Y_{d+1} E_d``
  with ``Y_{d+1} = K_{d+1} Z_d``.

Normalized by ``trace(Z + Z^T) = 2 n_Z``; ``max t``.  ``t* > 0`` gives gains, accepted only when the float64
re-check of the node matrices passes (:func:`recheck_network`).  ``t* <= 0``: the dual multipliers are re-checked
as a Farkas certificate of this LMI (:func:`check_network_farkas`): the outcome is "not_certified" (this sufficient
condition has no solution), never "infeasible" by itself.

Solved by the structured IPM (:mod:`solver.ipm.network_blocks`, the same blocks; ``solver="AUTO"``, ``"IPM"``) or by
Clarabel through cvxpy (``"CLARABEL"``; under ``"AUTO"`` the fallback when the IPM's answer decides nothing); the
re-checks above judge either solver's numbers.  The cone complementarity fallback and the fixed-gain node SDP run on
Clarabel.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..certificates import Prover, gamma
from ..compiled import cp, solve_quietly  # cvxpy, imported on first use
from ..errors import InvalidInput, SolverFailed
from ..lyapunov import RECHECK_TOL, Certificate
from ..network import ModeSet, spectral_radii
from ..network_analysis import fixed_gain_certificate
from ..networks import loop_matrices
from ..result import DesignResult, IterationRecord

U = 2.0**-53


# --------------------------------------------------------------------------------------------- the automaton
def fresh_age(network) -> bool:
    """Whether every packet that takes effect is fresh: every edge goes to age 0 or to ``d + 1``."""
    ages = np.asarray(network.ages)
    return all(ages[j] == 0 or ages[j] == ages[i] + 1 for i, j in network.edges)


def lifted_edges(network) -> list[tuple[int, int, int]]:
    """Reception-to-reception transitions ``(v, w, eta)`` of a fresh-age network (node indices of age 0).

    ``eta`` samples from reception node v to reception node w along a path whose ages are ``0, 1, ..., eta-1``.
    """
    ages = np.asarray(network.ages)
    succ = [[] for _ in range(len(ages))]
    for i, j in network.edges:
        succ[i].append(j)
    out = set()
    for v in np.flatnonzero(ages == 0):
        frontier, eta = {int(v)}, 1
        while frontier:
            nxt = set()
            for u in frontier:
                for w in succ[u]:
                    if ages[w] == 0:
                        out.add((int(v), int(w), eta))
                    elif ages[w] == eta:
                        nxt.add(int(w))
            frontier, eta = nxt, eta + 1
    return sorted(out)


def contains_bounded_drops(network) -> bool:
    """Whether every run of ``bounded_drops(network.n_drop)`` is a run of ``network`` (prefix-closed languages).

    Subset construction on the network's ages: the pair (bounded-drops age, set of network nodes the word can
    end in) must never reach an empty set.
    """
    ages = np.asarray(network.ages)
    N = int(network.n_drop)
    succ = [[] for _ in range(len(ages))]
    for i, j in network.edges:
        succ[i].append(j)
    start = [(d, frozenset(np.flatnonzero(ages == d).tolist())) for d in range(N)]
    seen, stack = set(), list(start)
    while stack:
        d, nodes = stack.pop()
        if not nodes:
            return False
        if (d, nodes) in seen:
            continue
        seen.add((d, nodes))
        for e in ([0, d + 1] if d + 1 <= N - 1 else [0]):
            stack.append((e, frozenset(w for u in nodes for w in succ[u] if ages[w] == e)))
    return True


# ------------------------------------------------------------------------------------------- the problem
@dataclass
class NetworkProblem:
    """The network LMI's data: one transition per block.

    Attributes
    ----------
    form : {"lifted", "augmented"}
    nodes : ndarray of int
        Automaton node of each Lyapunov matrix (reception nodes for "lifted", every node for "augmented").
    k : int
        Side of the Lyapunov matrices (n, or n N).
    zblocks : int
        Diagonal blocks of the slack (1 for "lifted", N for "augmented"), each n x n.
    src, dst : ndarray of int, shape (E,)
        Lyapunov-matrix index (into ``nodes``) of each transition's start and end.
    free : ndarray, shape (E, k, k)
        Gain-free part ``A_e = free_e + sum_j coef[e, j] K_j R_{e,j}``.
    coef : ndarray, shape (E, N, k, m)
    right : ndarray of int, shape (E, N)
        Column block (of the slack) the gain K_j reads in transition e (-1: K_j is absent).
    length : ndarray of int, shape (E,)
        Samples the transition spans (for the decay rate: ``c_e = lambda^(-length_e)``).
    labels : list of dict
    """

    form: str
    nodes: np.ndarray
    n: int
    m: int
    N: int
    k: int
    zblocks: int
    src: np.ndarray
    dst: np.ndarray
    free: np.ndarray
    coef: np.ndarray
    right: np.ndarray
    length: np.ndarray
    labels: list = field(default_factory=list)
    F: np.ndarray | None = None
    G: np.ndarray | None = None

    @property
    def n_blocks(self) -> int:
        return len(self.src)

    def closed_loops(self, gains: np.ndarray) -> np.ndarray:
        """``A_e(K)`` for every transition, shape (E, k, k)."""
        A = self.free.copy()
        n = self.n
        for e in range(self.n_blocks):
            for j in range(self.N):
                b = self.right[e, j]
                if b >= 0:
                    A[e][:, b * n:(b + 1) * n] += self.coef[e, j] @ gains[j]
        return A


def build_problem(family, network, plant_switching: str = "per_interval") -> NetworkProblem:
    """The transitions of ``network`` for ``family``, lifted when every packet that takes effect is fresh."""
    N = int(network.n_drop)
    F, G = np.asarray(family.F, float), np.asarray(family.G, float)
    r, n, m = family.n_modes, family.n_states, family.n_inputs
    if fresh_age(network):
        modes = ModeSet.from_family(family, N, plant_switching=plant_switching)
        edges = lifted_edges(network)
        rec = sorted({v for v, _, _ in edges} | {w for _, w, _ in edges})
        index = {v: i for i, v in enumerate(rec)}
        rows = [(v, w, s) for v, w, eta in edges for s in range(modes.n_modes) if modes.eta[s] == eta]
        E = len(rows)
        right = np.full((E, N), -1)
        for e, (_, _, s) in enumerate(rows):
            right[e, :modes.eta[s]] = 0
        return NetworkProblem(
            "lifted", np.array(rec), n, m, N, n, 1,
            np.array([index[v] for v, _, _ in rows]), np.array([index[w] for _, w, _ in rows]),
            modes.free[[s for _, _, s in rows]], modes.coef[[s for _, _, s in rows]], right,
            modes.eta[[s for _, _, s in rows]],
            [{"from": v, "to": w, **modes.label(s)} for v, w, s in rows], F, G)
    ages = np.asarray(network.ages)
    base = loop_matrices(family, np.zeros((N, m, n)), network)
    rows = [(i, j, l) for i, j in network.edges for l in range(r)]
    E, k = len(rows), n * N
    coef = np.zeros((E, N, k, m))
    right = np.full((E, N), -1)
    for e, (i, _, l) in enumerate(rows):
        d = int(ages[i])
        coef[e, d, :n] = G[l]
        right[e, d] = d
    return NetworkProblem(
        "augmented", np.arange(len(ages)), n, m, N, k, N,
        np.array([i for i, _, _ in rows]), np.array([j for _, j, _ in rows]),
        base[[l for _, _, l in rows], [int(ages[i]) for i, _, _ in rows]], coef, right, np.ones(E, dtype=int),
        [{"from": int(i), "to": int(j), "plant": int(l), "age": int(ages[i])} for i, j, l in rows], F, G)


def lmi_size(prob: NetworkProblem) -> tuple[list[int], int]:
    """Cone sides of the SDP and its number of scalar variables."""
    k, n = prob.k, prob.n
    sides = [2 * k] * prob.n_blocks + [k] * len(prob.nodes)
    variables = prob.zblocks * n * n + len(prob.nodes) * k * (k + 1) // 2 + prob.N * prob.m * n + 1
    return sides, variables


@dataclass
class NetworkSolution:
    """One solve of the network LMI: the variables, the multipliers (Farkas layout), how it ended.

    ``multipliers``: one (2k, 2k) per transition, then one (k, k) per node matrix (None when the solver
    returned none); ``solver``: "IPM" or the cvxpy solver's name; ``ipm``: the IPM's own solution (its
    warm start for a neighbouring rate), None for Clarabel.
    """

    t: float
    Z: np.ndarray  # (zblocks, n, n)
    W: np.ndarray  # (V, k, k)
    Y: np.ndarray  # (N, m, n)
    multipliers: list | None
    status: str
    solve_time: float
    solver: str = "CLARABEL"
    iterations: int | None = None
    ipm: object | None = None


def cvx_variables(prob: NetworkProblem):
    """cvxpy variables of the network LMI: the slack's diagonal blocks ``Zb`` and ``Z = blkdiag(Zb)``, one
    ``W_v`` per node, the gains' ``Y_j``: ``(Zb, Z, W, Y)``."""
    n, m, N, k = prob.n, prob.m, prob.N, prob.k
    Zb = [cp.Variable((n, n)) for _ in range(prob.zblocks)]
    Z = Zb[0] if prob.zblocks == 1 else cp.bmat(
        [[Zb[a] if a == b else np.zeros((n, n)) for b in range(prob.zblocks)] for a in range(prob.zblocks)])
    W = [cp.Variable((k, k), symmetric=True) for _ in prob.nodes]
    Y = [cp.Variable((m, n)) for _ in range(N)]
    return Zb, Z, W, Y


def solve_sdp(prob: NetworkProblem, scale: np.ndarray, time_limit: float | None = None, solver: str = "CLARABEL",
              start=None, sign_only: bool = False, per_block: bool = False) -> NetworkSolution:
    """``max t`` of the network LMI (data of transition e multiplied by ``scale[e]``).

    ``per_block``: normalize every slack block (``trace Z_b = n``) instead of the sum (docs/design.md 11.1: a
    restriction of the LMI, which can be proven infeasible where the sum-normalized augmented form cannot).

    ``solver``: "IPM" (the structured interior-point solver, :func:`solver.ipm.network_blocks.solve_network`;
    ``start`` a :class:`solver.ipm.WarmStart` from a neighbouring rate, ``sign_only`` stops once the margin's
    sign is settled), "CLARABEL" or "SCS" (cvxpy).

    Raises
    ------
    SolverFailed
        When the solver ends without an (almost) optimal point.
    """
    name = str(solver).upper()
    if name == "IPM":
        return _solve_ipm(prob, scale, time_limit, start, sign_only, per_block)
    n, m, N, k = prob.n, prob.m, prob.N, prob.k
    Zb, Z, W, Y = cvx_variables(prob)
    t = cp.Variable()
    eye_k = np.eye(k)
    if per_block:  # one normalization per slack block (docs/design.md 11.1)
        cons = [cp.trace(z) == n for z in Zb]
    else:
        cons = [sum(cp.trace(z) for z in Zb) == prob.zblocks * n]
    blocks = []
    for e in range(prob.n_blocks):
        AZ = (scale[e] * prob.free[e]) @ Z
        for j in range(N):
            b = prob.right[e, j]
            if b >= 0:
                term = (scale[e] * prob.coef[e, j]) @ Y[j]
                if prob.zblocks == 1:
                    AZ = AZ + term
                else:
                    pad = [np.zeros((k, n))] * prob.zblocks
                    cols = [term if c == b else pad[c] for c in range(prob.zblocks)]
                    AZ = AZ + cp.hstack(cols)
        M = cp.bmat([[Z + Z.T - W[prob.src[e]], AZ.T], [AZ, W[prob.dst[e]]]])
        blocks.append(0.5 * (M + M.T) - t * np.eye(2 * k) >> 0)
    pos = [Wv - t * eye_k >> 0 for Wv in W]
    problem = cp.Problem(cp.Maximize(t), cons + blocks + pos)
    if name == "SCS":
        opts = {"eps_abs": 1e-7, "eps_rel": 1e-7, "max_iters": 200_000}
        if time_limit is not None:
            opts["time_limit_secs"] = float(max(time_limit, 1e-3))
    else:
        name = "CLARABEL"
        opts = {} if time_limit is None else {"time_limit": float(max(time_limit, 1e-3))}
    start_t = time.perf_counter()
    try:
        with warnings.catch_warnings():  # cvxpy warns on inaccurate solutions: the status is acted on instead
            warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=getattr(cp, name), **opts)
    except cp.error.SolverError as err:
        raise SolverFailed(f"{name} failed on the network LMI: {err}", status="solver_error") from None
    elapsed = time.perf_counter() - start_t
    status = str(problem.status)
    if t.value is None:
        raise SolverFailed(f"{name} ended with status {status} on the network LMI", status=status)
    Zv = np.stack([z.value for z in Zb])
    Wv = np.stack([0.5 * (w.value + w.value.T) for w in W])
    multipliers = [c.dual_value for c in blocks] + [c.dual_value for c in pos]
    multipliers = None if any(d is None for d in multipliers) else [np.asarray(d, float) for d in multipliers]
    # a gain no transition uses (e.g. K_3 when no interval is 3 samples long) stays zero
    Yv = np.stack([np.zeros((m, n)) if y.value is None else y.value for y in Y])
    stats = problem.solver_stats
    return NetworkSolution(float(t.value), Zv, Wv, Yv, multipliers, status, elapsed, name,
                           None if stats is None else stats.num_iters)


def _solve_ipm(prob: NetworkProblem, scale: np.ndarray, time_limit: float | None, start,
               sign_only: bool, per_block: bool = False) -> NetworkSolution:
    """The network LMI on the structured IPM (its blocks: :mod:`solver.ipm.network_blocks`)."""
    from ..ipm import IPMOptions
    from ..ipm.network_blocks import solve_network

    sol = solve_network(prob.free, prob.coef, prob.right, prob.src, prob.dst, len(prob.nodes), prob.zblocks,
                        scale, IPMOptions(time_limit=time_limit, sign_only=sign_only), start, per_block)
    status = {"optimal": "optimal", "inaccurate": "optimal_inaccurate", "feasible": "optimal_inaccurate",
              "infeasible": "optimal_inaccurate"}.get(sol.status)
    if status is None:
        raise SolverFailed(f"IPM ended with status {sol.status!r} on the network LMI after {sol.iterations} "
                           f"iterations (primal residual {sol.primal_residual:.1e}, gap {sol.gap:.1e})",
                           status=sol.status)
    multipliers = sol.multipliers if all(np.all(np.isfinite(X)) for X in sol.multipliers) else None
    return NetworkSolution(float(sol.t), sol.Z, sol.W, sol.Y, multipliers, status, sol.timings["total"], "IPM",
                           sol.iterations, sol)


def gains_from(prob: NetworkProblem, sol: NetworkSolution) -> np.ndarray:
    """``K_j = Y_j Z_b^{-1}`` with b the slack block gain j reads (0 for the lifted form; j - 1 augmented)."""
    K = np.empty_like(sol.Y)
    for j in range(prob.N):
        b = 0 if prob.zblocks == 1 else j
        K[j] = np.linalg.solve(sol.Z[b].T, sol.Y[j].T).T
    return K


# ------------------------------------------------------------------------------------------- re-checks
@dataclass
class NodeCertificate(Certificate):
    """Node-dependent quadratic Lyapunov certificate on a network, re-checked in float64.

    ``P`` has shape (V, k, k): ``P[i]`` belongs to automaton node ``nodes[i]``; ``form`` says on which state
    ("lifted": x at the samples where a packet takes effect; "augmented": ``xi(t)``).  Every transition
    ``v -> w`` (and plant mode) has ``A^T P_w A - rho P_v < 0``.
    """

    form: str = "lifted"
    nodes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind, "source": self.source, "verified": self.verified, "margin": self.margin,
            "decrease": self.decrease, "min_eig_P": self.min_eig_P,
            "condition_number": float(max(np.linalg.cond(M) for M in self.P)),
            "decay_rate": self.decay_rate, "worst_mode": self.worst_mode, "form": self.form,
            "nodes": [int(v) for v in self.nodes], "P": self.P.tolist(), "X": None,
        }


def recheck_network(prob: NetworkProblem, P: np.ndarray, gains: np.ndarray, rate: float | None = None,
                    source: str = "network_lmi") -> NodeCertificate:
    """Float64 re-check of node matrices ``P`` for ``gains`` on every transition of ``prob``.

    Passes when every ``P_v`` is positive definite and every ``rho_e P_v - A_e^T P_w A_e`` has smallest
    eigenvalue above ``RECHECK_TOL`` times the largest eigenvalue of all ``P`` (``rho_e = lambda^(2 length_e)``).
    """
    P = 0.5 * (P + np.swapaxes(P, 1, 2))
    A = prob.closed_loops(gains)
    rho = np.ones(prob.n_blocks) if rate is None else float(rate) ** (2.0 * prob.length)
    eigP = np.linalg.eigvalsh(P)
    dec = rho[:, None, None] * P[prob.src] - np.swapaxes(A, 1, 2) @ P[prob.dst] @ A
    low = np.linalg.eigvalsh(0.5 * (dec + np.swapaxes(dec, 1, 2)))[:, 0]
    top = float(eigP.max())
    worst = int(np.argmin(low))
    decrease = float(low[worst])
    margin = decrease / top if top > 0 else -np.inf
    ok = bool(np.all(np.isfinite(P)) and eigP.min() > 0 and margin > RECHECK_TOL)
    return NodeCertificate("node_dependent", P, None, float(eigP.min()), decrease, margin, ok, source,
                              decay_rate=rate, worst_mode=worst, form=prob.form, nodes=list(prob.nodes))


# ------------------------------------------------------------------------------------------- Farkas
@dataclass
class NetworkFarkasCertificate:
    """Dual multipliers proving that the network LMI has no solution (re-checked in float64).

    For PSD multipliers ``M_e`` (transitions) and ``N_v`` (``W_v >= 0``), every ``(Z, W, Y)`` has
    ``sum <M_e, B_e> + sum <N_v, W_v> = <G, Z> + sum_v <C_v, W_v> + sum_j <E_j, Y_j>``.  If all blocks were
    positive semidefinite and the slack's diagonal blocks had equal traces (the normalization ``tr Z_b = n``,
    up to scale), then, with ``H = (Z + Z^T)/2`` (PSD, ``tr W_v <= 2 tr H``, ``tr B_e <= 4 tr H``),
    ``0 <= -delta tr H + ||G_skew||_F ||Z||_F + ||E||_F ||Y||_F``: no such solution has
    ``max(||Z||_F, ||Y||_F) < gain_bound tr H`` with ``gain_bound = delta / (||G_skew||_F + ||E||_F)``
    (``delta = -mean_b lambda_max(G_b,sym) - 2 sum_v lambda_max(C_v)^+ - 4 sum_e mu_e - 2 sum_v nu_v``,
    ``mu, nu`` the shifts that make the multipliers PSD; ``G_b`` the diagonal blocks of ``G``, the slack's).
    """

    multipliers: list
    delta: float
    e_norm: float
    gain_bound: float
    verified: bool
    form: str
    decay_rate: float | None = None
    skew_norm: float = 0.0
    kind: str = "farkas_network"
    method: str = "network_lmi"
    margin: float = 0.0
    any_margin: bool = True
    scaled: bool = False
    per_block: bool = False

    def statement(self) -> str:
        bound = ("of any size" if np.isinf(self.gain_bound)
                 else f"with ||Z||_F, ||Y||_F < {self.gain_bound:.3g} tr((Z + Z^T)/2)")
        if self.per_block and self.form == "augmented":
            bound += (" whose slack blocks Z_b have equal traces (a restriction of the LMI; the unrestricted one "
                      "reaches t* = 0 and has no Farkas certificate)")
        rate = "" if self.decay_rate is None else f" at decay rate {self.decay_rate:.6g}"
        return (f"not certified: the network LMI ({self.form} form: node-dependent quadratic Lyapunov functions "
                f"with a common slack) has no solution {bound}{rate} (Farkas certificate re-checked in float64); "
                "this excludes that sufficient condition only, not every gain")

    def to_dict(self) -> dict:
        return {"kind": self.kind, "method": self.method, "form": self.form, "verified": self.verified,
                "delta": self.delta, "e_norm": self.e_norm, "skew_norm": self.skew_norm,
                "gain_bound": None if np.isinf(self.gain_bound) else float(self.gain_bound),
                "gain_bound_unbounded": bool(np.isinf(self.gain_bound)), "decay_rate": self.decay_rate,
                "per_block": self.per_block, "statement": self.statement(), "multipliers": [M.tolist() for M in self.multipliers]}


def transition_adjoint(prob: NetworkProblem, M, scale: np.ndarray, g: float):
    """The adjoint of the transition blocks ``B_e`` (section 11.1) at multipliers ``M_e`` (E, 2k, 2k), with
    elementwise rounding bounds (``g`` times the terms' sizes): ``sum_e <M_e, B_e> = <G, Z> + sum_v <C_v, W_v>
    + sum_j <E_j, Y_j>``.  Returns ``(G, errG, C, errC, E, errE)``, shapes (k, k), (V, k, k), (N, m, n)."""
    k, n, V = prob.k, prob.n, len(prob.nodes)
    G, errG = np.zeros((k, k)), np.zeros((k, k))
    C, errC = np.zeros((V, k, k)), np.zeros((V, k, k))
    Ej, errE = np.zeros((prob.N, prob.m, n)), np.zeros((prob.N, prob.m, n))
    for e in range(prob.n_blocks):
        M11, M21, M22 = M[e][:k, :k], M[e][k:, :k], M[e][k:, k:]
        A0 = scale[e] * prob.free[e]
        G += 2 * M11 + 2 * A0.T @ M21
        errG += g * (2 * np.abs(M11) + 2 * np.abs(A0).T @ np.abs(M21))
        C[prob.src[e]] -= M11
        C[prob.dst[e]] += M22
        errC[prob.src[e]] += g * np.abs(M11)
        errC[prob.dst[e]] += g * np.abs(M22)
        for j in range(prob.N):
            b = prob.right[e, j]
            if b >= 0:
                cj = scale[e] * prob.coef[e, j]
                Ej[j] += 2 * cj.T @ M21[:, b * n:(b + 1) * n]
                errE[j] += 2 * g * np.abs(cj).T @ np.abs(M21[:, b * n:(b + 1) * n])
    return G, errG, C, errC, Ej, errE


def slack_pairing(prob: NetworkProblem, G: np.ndarray, errG: np.ndarray, prover) -> tuple[list, float]:
    """How ``<G, Z>`` meets the block-diagonal slack: proven ``lambda_max`` of each diagonal block's symmetric part
    (pairing with ``H_b``) and a bound of the skew parts' Frobenius norm (pairing with ``Z``)."""
    n = prob.n
    lams, skew2 = [], 0.0
    for b in range(prob.zblocks):
        sl = slice(b * n, (b + 1) * n)
        lams.append(prover.max_upper(0.5 * (G[sl, sl] + G[sl, sl].T), float(np.linalg.norm(errG[sl, sl]))))
        skew2 += (float(np.linalg.norm(0.5 * (G[sl, sl] - G[sl, sl].T))) + float(np.linalg.norm(errG[sl, sl]))) ** 2
    return lams, float(np.sqrt(skew2) * (1 + 8 * U))


def check_network_farkas(prob: NetworkProblem, multipliers: list, scale: np.ndarray,
                         rate: float | None = None, per_block: bool = False) -> NetworkFarkasCertificate:
    """Re-check Farkas multipliers of the network LMI on the problem's float64 data (solver-independent).

    ``per_block``: multipliers of the LMI normalized per slack block; the certificate then excludes solutions
    whose slack blocks have equal traces only (``lambda_max`` averaged over the blocks instead of maximized).

    ``multipliers``: one (2k, 2k) matrix per transition, then one (k, k) per Lyapunov matrix.  Rounding of the
    adjoint is bounded elementwise (``gamma`` terms) and the eigenvalue bounds are proven by
    :class:`solver.certificates.Prover`.
    """
    k, E, V = prob.k, prob.n_blocks, len(prob.nodes)
    M = [0.5 * (np.asarray(X, float) + np.asarray(X, float).T) for X in multipliers[:E]]
    Nv = [0.5 * (np.asarray(X, float) + np.asarray(X, float).T) for X in multipliers[E:E + V]]
    prover = Prover(exact=False)
    bad = NetworkFarkasCertificate(M + Nv, -np.inf, np.inf, 0.0, False, prob.form, rate, per_block=per_block)
    if len(M) != E or len(Nv) != V or not all(np.all(np.isfinite(X)) for X in M + Nv):
        return bad
    mu = np.maximum(0.0, -prover.min_lower_many(np.stack(M))) if E else np.zeros(0)
    nu = np.maximum(0.0, -prover.min_lower_many(np.stack(Nv))) if V else np.zeros(0)
    g = gamma(2 * k + 2 * E + 8)
    Gfull, errG, C, errC, Ej, errE = transition_adjoint(prob, M, scale, g)
    C = [C[v] + Nv[v] for v in range(V)]
    # the slack is block diagonal: only the diagonal blocks of G pair with it
    # per_block (every tr H_b the same c, tr H = zb c): sum_b <G_b, H_b> <= c sum_b lambda_max(G_b), i.e. the
    # blocks' mean times tr H
    lams, skew = slack_pairing(prob, Gfull, errG, prover)
    if per_block:
        lam_g = (float(np.sum(lams)) + gamma(len(lams) + 2) * float(np.sum(np.abs(lams)))) / prob.zblocks
    else:  # sum_b <G_b, H_b> <= max_b lambda_max(G_b) tr H
        lam_g = max(lams)
    lam_c = sum(max(0.0, prover.max_upper(C[v], float(np.linalg.norm(errC[v])) + g * float(np.linalg.norm(C[v]))))
                for v in range(V))
    # <N_v + nu_v I, W_v> >= 0 is already in C_v's bound only if N_v is PSD: nu_v tr W_v <= 2 nu_v tr H
    delta = -lam_g - 2 * lam_c - 4 * float(np.sum(mu)) - 2 * float(np.sum(nu))
    delta = delta * (1 - 8 * U) if delta > 0 else delta * (1 + 8 * U)
    e_norm = (float(np.linalg.norm(Ej)) + float(np.linalg.norm(errE))) * (1 + 8 * U)
    if delta <= 0:
        return NetworkFarkasCertificate(M + Nv, float(delta), e_norm, 0.0, False, prob.form, rate, skew_norm=skew,
                                        per_block=per_block)
    total = e_norm + skew
    bound = np.inf if total == 0 else delta / total * (1 - 8 * U)
    return NetworkFarkasCertificate(M + Nv, float(delta), e_norm, float(bound), True, prob.form, rate,
                                    skew_norm=skew, per_block=per_block)


# ------------------------------------------------------------------------------------------- fixed gains
def node_analysis(prob: NetworkProblem, gains: np.ndarray, rate: float | None = None,
                  time_limit: float | None = None) -> NodeCertificate | None:
    """Node matrices for fixed ``gains`` (``max t``: ``P_v >= t I``, ``rho_e P_v - A_e^T P_w A_e >= t I``,
    ``sum tr P_v = V k``), re-checked by :func:`recheck_network`; None when no certificate passes.

    The structured IPM solves it first (:func:`solver.ipm.network_blocks.edge_problem`, when its memory fits the
    budget); Clarabel only when the IPM neither certified nor converged to ``t* <= 0`` (CCL runs this after every
    iteration: docs/design.md §11.1)."""
    A = prob.closed_loops(gains)
    if not np.all(np.isfinite(A)):
        return None
    rho = np.ones(prob.n_blocks) if rate is None else float(rate) ** (2.0 * prob.length)
    k, V = prob.k, len(prob.nodes)
    begin = time.perf_counter()
    decided = _node_analysis_ipm(prob, A, rho, gains, rate, time_limit)
    if decided is not False:
        return decided
    if time_limit is not None:
        time_limit = max(time_limit - (time.perf_counter() - begin), 1e-3)
    P = [cp.Variable((k, k), symmetric=True) for _ in range(V)]
    t = cp.Variable()
    eye = np.eye(k)
    cons = [sum(cp.trace(X) for X in P) == V * k] + [X - t * eye >> 0 for X in P]
    for e in range(prob.n_blocks):
        D = rho[e] * P[prob.src[e]] - A[e].T @ P[prob.dst[e]] @ A[e]
        cons.append(0.5 * (D + D.T) - t * eye >> 0)
    try:
        solve_quietly(cp.Problem(cp.Maximize(t), cons), time_limit=time_limit)
    except cp.error.SolverError:
        return None
    if t.value is None or not t.value > 0:
        return None
    cert = recheck_network(prob, np.stack([X.value for X in P]), gains, rate, source="network_analysis")
    return cert if cert.verified else None


def _node_analysis_ipm(prob: NetworkProblem, A: np.ndarray, rho: np.ndarray, gains: np.ndarray, rate,
                       time_limit: float | None):
    """:func:`node_analysis` on the structured IPM: the re-checked certificate, None when the IPM converged with
    its upper bound on ``t*`` at or below 0, False when it decided nothing (or its memory is over the budget)."""
    from ..compiled import MAX_SOLVER_MEMORY
    from ..ipm import IPMOptions
    from ..ipm.algorithm import solve_block_lmi
    from ..ipm.network_blocks import edge_problem, node_memory

    V = len(prob.nodes)
    succ = [[int(w) for v_, w in zip(prob.src, prob.dst) if v_ == v] for v in range(V)]
    if node_memory(succ, prob.k) > MAX_SOLVER_MEMORY:
        return False
    try:
        sol = solve_block_lmi(edge_problem(A, prob.src, prob.dst, V, rho), IPMOptions(time_limit=time_limit))
    except (SolverFailed, np.linalg.LinAlgError, ValueError):
        return False
    t = float(sol.t)
    if np.isfinite(t) and t > 0:
        P = sol.V[0].reshape(V, prob.k, prob.k)
        cert = recheck_network(prob, 0.5 * (P + np.swapaxes(P, 1, 2)), gains, rate, source="network_analysis")
        if cert.verified:
            return cert
    return None if sol.status == "optimal" and np.isfinite(sol.upper) and sol.upper <= 0 else False


def fixed_rate_certificate(prob: NetworkProblem, family, network, gains: np.ndarray, rate: float | None = None, *,
                           plant_switching: str = "per_interval", solver: str = "AUTO", recheck=None,
                           time_limit: float | None = None, clarabel: bool = True):
    """The fixed-rate fallback (docs/design.md 11.1): a certificate for ``gains`` at ``rate`` that does not use the
    design's own node matrices, or None.

    ``recheck(gains, rate) -> (ok, certificate or None)`` (the design's independent analysis, as in :func:`run`)
    decides first: not ok gives None, a verified certificate of its own is the answer (plain stability:
    ``analyze``'s node analysis at rate 1).  Otherwise (no ``recheck``, or one without a certificate at a decay
    rate) the fixed-gain node SDP in the design's own form (:func:`node_analysis`, re-checked by
    :func:`recheck_network` like the design's matrices), then the fixed-gain node analysis on the product automaton
    (:func:`solver.network_analysis.fixed_gain_certificate`, the augmented state, one matrix per node and plant mode).
    ``clarabel=False`` (Clarabel's memory over the budget, as CCL): the design-form SDP, on Clarabel, is skipped.

    Returns
    -------
    NodeCertificate or solver.network_analysis.NetworkCertificate or None
        Verified by the float64 re-check at ``rate``.
    """
    if not np.all(np.isfinite(gains)):
        return None
    if recheck is not None:
        ok, other = recheck(gains, rate)
        if not ok:
            return None
        if other is not None and getattr(other, "verified", False):
            return other
    cert = node_analysis(prob, gains, rate, time_limit) if clarabel else None
    if cert is not None:
        return cert
    return fixed_gain_certificate(family, np.asarray(gains, float), network, rate, plant_switching=plant_switching,
                                  solver=solver)


def ccl(prob: NetworkProblem, rate: float | None = None, max_iter: int = 50, deadline: float | None = None,
        callback=None, start: float | None = None):
    """The paper's cone complementarity linearization on the exact node conditions (docs/design.md).

    ``[[P_v, A_e(K)^T], [A_e(K), Q_w]] >= eps I`` (exact with ``Q_w = P_w^{-1}``), ``[[P_v, I], [I, Q_v]] >= 0``,
    iterating ``min sum_v tr(P_v Q_v^i + P_v^i Q_v)`` from ``min sum_v tr(P_v + Q_v)``.  After every iteration
    the gains go to :func:`node_analysis`; the first certified gains are returned.

    Returns ``(gains or None, certificate or None, history, solve_seconds)``.
    """
    k, V, n, m = prob.k, len(prob.nodes), prob.n, prob.m
    c = np.ones(prob.n_blocks) if rate is None else float(rate) ** (-prob.length.astype(float))
    P = [cp.Variable((k, k), symmetric=True) for _ in range(V)]
    Q = [cp.Variable((k, k), symmetric=True) for _ in range(V)]
    K = [cp.Variable((m, n)) for _ in range(prob.N)]
    Pi = [cp.Parameter((k, k), symmetric=True) for _ in range(V)]
    Qi = [cp.Parameter((k, k), symmetric=True) for _ in range(V)]
    eye = np.eye(k)
    cons = []
    for e in range(prob.n_blocks):
        A = c[e] * prob.free[e]
        for j in range(prob.N):
            b = prob.right[e, j]
            if b >= 0:
                sel = np.zeros((n, k))
                sel[:, b * n:(b + 1) * n] = np.eye(n)
                A = A + (c[e] * prob.coef[e, j]) @ K[j] @ sel
        M = cp.bmat([[P[prob.src[e]], A.T], [A, Q[prob.dst[e]]]])
        cons.append(0.5 * (M + M.T) >> 1e-6 * np.eye(2 * k))
    cons += [cp.bmat([[P[v], eye], [eye, Q[v]]]) >> 0 for v in range(V)]
    history, solve_time = [], 0.0
    t0 = time.perf_counter() if start is None else start

    def solve(problem):
        nonlocal solve_time
        left = None if deadline is None else deadline - time.perf_counter()
        if left is not None and left <= 0:
            return False
        try:
            solve_quietly(problem, time_limit=left)
        except cp.error.SolverError:
            return False
        solve_time += problem.solver_stats.solve_time or 0.0
        return P[0].value is not None

    if not solve(cp.Problem(cp.Minimize(sum(cp.trace(P[v] + Q[v]) for v in range(V))), cons)):
        return None, None, history, solve_time
    step = cp.Problem(cp.Minimize(sum(cp.trace(P[v] @ Qi[v] + Pi[v] @ Q[v]) for v in range(V))), cons)
    for it in range(1, max_iter + 1):
        for v in range(V):
            Pi[v].value = 0.5 * (P[v].value + P[v].value.T)
            Qi[v].value = 0.5 * (Q[v].value + Q[v].value.T)
        if not solve(step):
            break
        gains = np.stack([np.zeros((m, n)) if x.value is None else x.value for x in K])
        left = None if deadline is None else deadline - time.perf_counter()
        cert = node_analysis(prob, gains, rate, left)
        gap = float(sum(np.trace(P[v].value @ Q[v].value) for v in range(V)) / (V * k) - 1)
        record = IterationRecord(it, float(step.value), gap, cert is not None,
                                 None if cert is None else cert.margin, step.solver_stats.solve_time or 0.0,
                                 time.perf_counter() - t0)
        history.append(record)
        if callback is not None and callback(record):
            break
        if cert is not None:
            cert.source = "network_ccl"
            return gains, cert, history, solve_time
    return None, None, history, solve_time


# ------------------------------------------------------------------------------------------- the design
def to_user_coordinates(res: DesignResult, scale, family, network, prob: NetworkProblem, plant_switching: str,
                       time_limit: float | None) -> DesignResult:
    """A network design made in balanced coordinates, mapped back and re-checked on the user's data.

    Gains map by ``K = U K~ T^-1``, node matrices and Farkas multipliers by the congruence ``T^-T M~ T^-1``
    (``scale``: a :class:`solver.scaling.Scaling`, powers of two, so the maps are exact).  The node certificate is
    re-checked on ``prob`` (the user's network problem); when its relative margin does not survive there (it is not
    invariant under the congruence), the node analysis of the gains in the user's coordinates is tried, then (plain
    stability) the network analysis; when none passes, the balanced certificate stands, which proves the same loop
    (``res.scaling["certificate"] == "scaled"``).
    """
    res.scaling = {"state": scale.state.tolist(), "input": scale.input.tolist(), "certificate": "original"}
    cert = res.certificate
    if res.outcome == "not_certified" and getattr(cert, "kind", None) == "farkas_network":
        rate_scale = (np.ones(prob.n_blocks) if cert.decay_rate is None
                      else float(cert.decay_rate) ** (-prob.length.astype(float)))
        mine = check_network_farkas(prob, [scale.quadratic_back(M) for M in cert.multipliers], rate_scale,
                                    cert.decay_rate, per_block=cert.per_block)
        if mine.verified:
            before, res.certificate = cert.statement(), mine
            if res.message.startswith(before):
                res.message = mine.statement() + res.message[len(before):]
        else:
            cert.scaled = True
            res.scaling["certificate"] = "scaled"
            res.message += "; the Farkas certificate is stated in balanced coordinates (res.scaling)"
    if res.gains is None:
        return res
    res.gains = scale.gains_back(res.gains)
    if res.outcome != "stabilized":
        return res
    rate = res.decay_rate if res.decay_rate is not None else getattr(cert, "decay_rate", None)
    mine = None
    if isinstance(cert, NodeCertificate):
        mine = recheck_network(prob, scale.quadratic_back(cert.P), res.gains, rate, source=cert.source)
        mine = mine if mine.verified else None
    if mine is None:
        mine = node_analysis(prob, res.gains, rate, time_limit)
    if mine is None and rate is None:
        from ..analysis import analyze

        try:
            rep = analyze(family, res.gains, network=network, plant_switching=plant_switching, bounds="none",
                          max_product_length=2)
            mine = rep.certificate if rep.stable is True else None
        except (InvalidInput, SolverFailed):
            mine = None
    res.spectral_radii = spectral_radii(prob.closed_loops(res.gains))
    if mine is not None:
        res.certificate = mine
    else:
        res.scaling["certificate"] = "scaled"
        res.message += ("; the node certificate is stated in balanced coordinates (res.scaling): its relative margin "
                        "does not survive the congruence back to the user's")
    return res


def run_balanced(family, network, *, scaling: str = "auto", plant_switching: str = "per_interval",
                 time_limit: float | None = None, **options) -> DesignResult:
    """:func:`run` in balanced coordinates (``scaling="auto"``, :func:`solver.scaling.balance`), the answer mapped
    back by :func:`to_user_coordinates` (docs/design.md §11.1, "Scaling"); ``scaling="none"``: :func:`run`."""
    from ..scaling import balance

    start = time.perf_counter()
    scale = balance(family) if scaling == "auto" else None
    if scale is None or scale.is_identity:
        return run(family, network, plant_switching=plant_switching, time_limit=time_limit, **options)
    res = run(scale.family(family), network, plant_switching=plant_switching, time_limit=time_limit, **options)
    left = None if time_limit is None else max(float(time_limit) - (time.perf_counter() - start), 1e-3)
    return to_user_coordinates(res, scale, family, network, build_problem(family, network, plant_switching),
                               plant_switching, left)


def solver_order(solver: str, fallback: bool = True) -> list:
    """The solvers the network LMI tries, in order: "AUTO" is the IPM, then Clarabel (``fallback``)."""
    name = str(solver).upper()
    if name == "AUTO":
        return ["IPM", "CLARABEL"] if fallback else ["IPM"]
    return [name]


def run(family, network, *, decay_rate: float | None = None, plant_switching: str = "per_interval",
        time_limit: float | None = None, callback=None, max_iter: int = 50, use_ccl: bool = True,
        prob: NetworkProblem | None = None, recheck=None, solver: str = "AUTO", fallback: bool = True,
        start=None, sign_only: bool = False, per_block: bool = True, rate_search: bool = False) -> DesignResult:
    """One design on ``network`` at ``decay_rate`` (None: plain stability).

    The convex network LMI first, on the solvers of :func:`solver_order` (``"AUTO"``: the structured IPM, and
    Clarabel when the IPM fails, or stops early, or its ``t* > 0`` does not pass the float64 re-check, or its
    ``t* <= 0`` short of optimality gives no Farkas certificate; ``fallback=False`` keeps to the IPM, e.g. when Clarabel's memory is over budget); when it
    certifies nothing, the cone complementarity iteration on the exact node conditions (``use_ccl``, at most
    ``max_iter`` iterations, Clarabel).  ``recheck(gains, rate) -> (ok, certificate or None)``: the independent
    network analysis that must also accept the gains (None: the float64 :func:`recheck_network` of the design's
    own node matrices is the only check).  ``start``, ``sign_only``: the IPM's warm start and early stop (the
    rate search's probes).  ``per_block``: when the augmented form ends at ``t* <= 0`` without a proof, solve
    it once more normalized per slack block (a Farkas certificate of that restriction; docs/design.md 11.1).
    When the SDP's gains are found (``t* > 0``) but its node matrices fail the float64 re-check, the fixed-gain node
    analysis of those gains at ``decay_rate`` decides before CCL (:func:`fixed_rate_certificate`; docs/design.md 11.1,
    "Fixed-rate fallback").  ``rate_search``: a step of a rate search (``decay_rate="max"``/``"auto"``): the SDP's own
    candidate decides, neither the per-block solve nor the fixed-gain node analysis runs (the search's bracket stays
    the convex condition's, docs/design.md 3.2.1).

    Returns
    -------
    DesignResult
        "stabilized" with a :class:`NodeCertificate`; "not_certified" with a
        :class:`NetworkFarkasCertificate` when the convex LMI is proven infeasible and CCL found nothing;
        "not_converged" otherwise.  ``solver`` names the solver whose answer decided, ``timings["solves"]``
        counts every SDP solved; ``res.sdp`` (not exported) is the deciding :class:`NetworkSolution`.  From the
        fixed-rate fallback (``res.fixed_rate_fallback``, not exported), "stabilized" carries the fixed-gain node
        SDP's :class:`NodeCertificate` (the design's form) or a :class:`solver.network_analysis.NetworkCertificate`
        (one ``P`` per network node and plant mode on the augmented state; plain stability: ``recheck``'s own), and
        ``message`` names it.
    """
    start_t = time.perf_counter()
    deadline = None if time_limit is None else start_t + float(time_limit)
    prob = build_problem(family, network, plant_switching) if prob is None else prob
    scale = np.ones(prob.n_blocks) if decay_rate is None else float(decay_rate) ** (-prob.length.astype(float))
    rate_txt = "" if decay_rate is None else f" at decay rate {decay_rate:.6g}"
    order = solver_order(solver, fallback)
    base = dict(method="network_lmi", n_drop=prob.N, solver=order[0], plant_switching=plant_switching,
                mode_labels=prob.labels)

    def accept(gains, own):
        if own is None or not own.verified:
            return None
        if recheck is None:
            return own
        ok, other = recheck(gains, decay_rate)
        return (other if other is not None else own) if ok else None

    def timings(solver_time, solves):
        total = time.perf_counter() - start_t
        return {"total": total, "solver": solver_time, "setup": max(total - solver_time, 0.0), "solves": solves,
                "cached": False}

    def left():
        return None if deadline is None else max(deadline - time.perf_counter(), 1e-3)

    sol = gains = cert = proof = None
    solver_time, solves, history, notes = 0.0, 0, [], []
    failed = []  # (solution, gains, own re-check) of the SDP's gains whose node matrices failed the re-check
    for i, name in enumerate(order):
        last = i == len(order) - 1
        try:
            sol = solve_sdp(prob, scale, left(), name, start=start if name == "IPM" else None,
                            sign_only=sign_only and name == "IPM")
        except SolverFailed as err:
            solves += 1
            if deadline is not None and time.perf_counter() >= deadline:
                return DesignResult(outcome="not_converged", gains=None, certificate=None, history=history, **base,
                                    timings=timings(solver_time, solves),
                                    message=f"time limit reached ({time_limit:g} s) inside the solver{rate_txt}")
            if last:
                if sol is not None:  # the IPM's answer (neither certified nor proven) stands
                    break
                raise
            notes.append(f"{name} failed ({err}), {order[i + 1]} instead")
            continue
        solves += 1
        solver_time += sol.solve_time
        base["solver"] = sol.solver
        gains = cert = proof = None
        if np.isfinite(sol.t) and sol.t > 0:
            gains = gains_from(prob, sol)
            if np.all(np.isfinite(gains)):
                own = recheck_network(prob, np.linalg.inv(sol.W), gains, decay_rate)
                cert = accept(gains, own)
                if not own.verified:
                    failed.append((sol, gains, own))
        elif sol.multipliers is not None:
            proof = check_network_farkas(prob, sol.multipliers, scale, decay_rate)
            proof = proof if proof.verified else None
        record = IterationRecord(0, sol.t, None, cert is not None, None if cert is None else cert.margin,
                                 sol.solve_time, time.perf_counter() - start_t)
        history.append(record)
        if callback is not None:
            callback(record)
        if cert is not None or proof is not None or last or (deadline is not None and time.perf_counter() >= deadline):
            break
        if name == "IPM" and sol.status == "optimal" and not sol.t > 0:
            # converged to t* <= 0 without a proof: the LMI sits on its boundary (the augmented form always can,
            # docs/design.md 11.1); a second solver would only confirm it
            break
        notes.append(f"{name}: t* = {sol.t:.3g} with neither a certificate passing the float64 re-check nor a Farkas "
                     f"proof, {order[i + 1]} instead")
    if (per_block and not rate_search and cert is None and proof is None and sol is not None and prob.zblocks > 1
            and not sol.t > 0 and (deadline is None or time.perf_counter() < deadline)):
        # the augmented form's t* >= 0 always (a zero slack block reaches t = 0, docs/design.md 11.1): the LMI with
        # one normalization per slack block, a restriction, can be proven infeasible (and its solutions are the
        # LMI's too)
        try:
            alt = solve_sdp(prob, scale, left(), sol.solver, per_block=True)
        except SolverFailed as err:
            alt = None
            notes.append(f"per-block normalization: {sol.solver} failed ({err})")
        solves += 1
        if alt is not None:
            solver_time += alt.solve_time
            if np.isfinite(alt.t) and alt.t > 0:
                agains = gains_from(prob, alt)
                if np.all(np.isfinite(agains)):
                    own = recheck_network(prob, np.linalg.inv(alt.W), agains, decay_rate)
                    cert = accept(agains, own)
                    if not own.verified:
                        failed.append((alt, agains, own))
                if cert is not None:
                    sol, gains = alt, agains
            elif alt.multipliers is not None:
                proof = check_network_farkas(prob, alt.multipliers, scale, decay_rate, per_block=True)
                proof = proof if proof.verified else None
                if proof is not None:
                    notes.append(f"t* = {sol.t:.3g} with the sum normalization; {alt.t:.3g} with one per slack "
                                 "block")
                    sol = alt
    via = "" if not notes else "; " + "; ".join(notes)
    where = (f"{network.describe()}; {prob.form} form, {len(prob.nodes)} node matrices, "
             f"{prob.n_blocks} transitions")
    if cert is not None:
        res = DesignResult(outcome="stabilized", gains=gains, certificate=cert, history=history,
                           solver_status=sol.status, timings=timings(solver_time, solves), decay_rate=decay_rate,
                           spectral_radii=spectral_radii(prob.closed_loops(gains)), **base,
                           message=f"stabilized on {where}; network LMI margin t* = {sol.t:.3g} ({sol.solver}), "
                                   f"certificate re-checked (relative margin {cert.margin:.3g}){rate_txt}{via}")
        res.sdp = sol
        return res
    for fsol, fgains, own in ([] if rate_search else reversed(failed)):  # the latest solve's gains first
        if deadline is not None and time.perf_counter() >= deadline:
            break
        fcert = fixed_rate_certificate(prob, family, network, fgains, decay_rate, plant_switching=plant_switching,
                                       solver=solver if fallback else "IPM", recheck=recheck, time_limit=left(),
                                       clarabel=fallback)
        solves += 1
        if fcert is None:
            notes.append(f"the fixed-gain node analysis of the {fsol.solver} gains certified nothing{rate_txt}")
            continue
        which = (f"{prob.form} form, {len(fcert.P)} node matrices" if isinstance(fcert, NodeCertificate) else
                 f"one P per network node and plant mode on the augmented state, {len(fcert.P)} matrices")
        res = DesignResult(outcome="stabilized", gains=fgains, certificate=fcert, history=history,
                           solver_status=fsol.status, timings=timings(solver_time, solves), decay_rate=decay_rate,
                           spectral_radii=spectral_radii(prob.closed_loops(fgains)), **{**base, "solver": fsol.solver},
                           message=f"stabilized on {where}; network LMI margin t* = {fsol.t:.3g} ({fsol.solver}), but "
                                   f"its node matrices failed the float64 re-check (relative margin {own.margin:.3g}); "
                                   f"certificate: the fixed-gain node analysis of these gains ({which}), "
                                   f"re-checked (relative margin {fcert.margin:.3g}){rate_txt}{via}")
        res.sdp, res.fixed_rate_fallback = fsol, True  # (not exported)
        return res
    via = "" if not notes else "; " + "; ".join(notes)
    if use_ccl and (deadline is None or time.perf_counter() < deadline):
        cgains, ccert, chist, ctime = ccl(prob, decay_rate, max_iter, deadline, callback, start_t)
        history += chist
        solver_time, solves = solver_time + ctime, solves + 1 + 2 * len(chist)
        ccert = None if cgains is None else accept(cgains, ccert)
        if ccert is not None:
            base.update(method="network_ccl", solver="CLARABEL")
            return DesignResult(outcome="stabilized", gains=cgains, certificate=ccert, history=history,
                                solver_status="optimal", timings=timings(solver_time, solves),
                                decay_rate=decay_rate, spectral_radii=spectral_radii(prob.closed_loops(cgains)),
                                **base,
                                message=f"stabilized on {where}; the convex network LMI certified nothing (t* = "
                                        f"{sol.t:.3g}), cone complementarity on the exact node conditions did in "
                                        f"{len(chist)} iterations; certificate re-checked (relative margin "
                                        f"{ccert.margin:.3g}){rate_txt}{via}")
    tried = (f"; cone complementarity: {len(history) - sum(r.iteration == 0 for r in history)} iterations without "
             "a certificate") if use_ccl else ""
    if proof is not None:
        res = DesignResult(outcome="not_certified", gains=None, certificate=proof, history=history,
                           solver_status=sol.status, timings=timings(solver_time, solves), **base,
                           message=f"{proof.statement()}; t* = {sol.t:.3g} ({sol.solver}){tried}{via}")
        res.sdp = sol
        return res
    res = DesignResult(outcome="not_converged", gains=None, certificate=None, history=history,
                       solver_status=sol.status, timings=timings(solver_time, solves), **base,
                       message=f"the network LMI's best margin is t* = {sol.t:.3g}{rate_txt}: no certificate passed "
                               f"the float64 re-check and no Farkas certificate was proven{tried}{via}")
    res.sdp = sol
    return res
