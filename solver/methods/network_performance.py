"""Cost and l2-gain designs on a network automaton (docs/design.md §11.3).

The network LMI of :mod:`solver.methods.network_lmi` (one Lyapunov matrix per node, one slack ``Z`` common to
every transition) with the performance channels of each transition ``e: v -> w`` (and plant mode), all of them
affine in ``(Z, Y)`` after ``Y_j = K_j Z_b``:

* cost:  ``[[Z + Z' - W_v, (A_e Z)', (L_e Z)'], [A_e Z, W_w, 0], [L_e Z, 0, I]] >= 0``, so that
  ``A_e' P_w A_e - P_v + L_e' L_e <= 0`` (``P_v = W_v^{-1}``): ``V`` drops by at least the transition's stage cost;
* hinf:  ``[[Z + Z' - W_v, 0, (A_e Z)', (C_e Z)'], [0, g I, B_e', D_e'], [A_e Z, B_e, W_w, 0], [C_e Z, D_e, 0, I]]
  >= 0``, the bounded-real inequality with node-dependent P.

``L_e`` (``C_e``, ``B_e``, ``D_e``) are the lifted interval's cost rows (channel) of :mod:`solver.lifting` on the
lifted form, and one sample's ``[Q^(1/2) e_0'; R^(1/2) K_(d+1) e_d']`` (``z = C x + D u``, ``B = [E; 0]``) on the
augmented one.  The bound is ``max_v x0' S' P_v S x0`` (``trace S' P_v S``) over the nodes a run may start in,
``S`` the initial history (``x0``, or ``x0`` repeated on the augmented state).  Every figure is re-checked in
float64 (:func:`certify`), also with one matrix per sequence of the last transitions (:func:`memory_bracket`),
and the lower bound is the exact value of the worst admissible run searched (closed walks repeated,
:func:`lower_bound`, and a first stretch before one, :func:`worst_run`), both independent of the solver.

The design SDP runs on the structured IPM (:func:`solve_ipm`, the model of
:mod:`solver.ipm.network_performance_blocks`) or on Clarabel through cvxpy (:func:`solve`); when neither certifies,
the stability design's gains are bracketed instead, or its Farkas refutation of the network LMI is the verdict
(docs/design.md §11.3, "When the convex SDP certifies nothing").
"""

from __future__ import annotations

import dataclasses
import itertools
import time
import types
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ..brackets import (LowerBound, NetworkPerformance, _allowance, _data_error, _lyapunov_once, _lyapunov_residual,
                        _moment, _norms_pruned, _primitive_period, _sym, certify_hinf, check_x0, exact_cost_witness,
                        exact_witness, hinf_norm_lower, hinf_norm_peak, limits_note, lyapunov, period_system,
                        sequence_cost, shortest_lead)
from ..certificates import uncontrollable_mode
from ..compiled import cp, time_left
from ..errors import InvalidInput, SolverFailed
from ..lifting import TINY, check_channel, check_u_max, check_weights, lift_modes
from ..network import ModeSet
from ..result import DesignResult, IterationRecord
from ..scaling import Scaling
from ..transients import TRANSIENT_WORK, transient_witness
from . import network_lmi

#: Closed walks valued for the lower bound at most (cost; hinf: ``MAX_WALKS_HINF``), shortest first.
MAX_WALKS = 4000
MAX_WALKS_HINF = 300
#: Longest closed walk searched (transitions).
MAX_WALK_LENGTH = 12
#: Open walks kept while extending (the breadth of the search).
MAX_OPEN = 20000
#: Walks re-valued with the refined sweep (hinf), and (cost) on their own after the stacked values.
REFINED = 4
REFINED_COST = 16
#: Pairs of the best closed walks combined for the l2 gain (:func:`combined_walks`, while the bracket is open by more
#: than ``COMBINE_ABOVE_GAP``): how many walks (8 found the same witnesses on the badly scaled families at 1.5x the
#: CPU, 4 and 5 lower ends up to 5 % lower), the largest power of each, the longest combination (transitions).
COMBINE_BEST = 6
COMBINE_POWER = 3
COMBINE_LENGTH = 24
COMBINE_ABOVE_GAP = 1e-3
#: The guided search for runs that settle into a closed walk after a first stretch (cost, :func:`worst_run`): runs
#: kept per step, steps (transitions), and the closed walks (at most ``TAIL_WALKS``, up to ``TAIL_LENGTH`` long, from
#: every node) that may end a run.
RUN_BEAM = 64
RUN_DEPTH = 60
TAIL_WALKS = 400
TAIL_LENGTH = 8
#: The guided search runs while the bracket is open by more than this (relative to the upper end).
LOWER_CLOSED = 1e-6
#: Rounds of the gain refinement of the stability design's gains (:func:`refine_gains`), and the relative gain of a
#: round below which it stops.
REFINE_ROUNDS = 8
REFINE_TOL = 1e-3
#: A bracket open by more than this (upper / lower - 1) tries the bounds with memory (:func:`memory_bracket`).
MEMORY_GAP = 1e-2
#: Most matrices of a bound with memory (:func:`lookahead_lift` for the cost, :func:`memory_lift` for the l2 gain)
#: the brackets try: memory one, a longer memory (each costs a Clarabel SDP of that many matrices: 170 took 11 s, 42
#: 1.3 s; 85 lowered a delays(1, 3) bound by 6 %), and the longest memory (the count caps it first on the six
#: families of docs/performance.md; a look-ahead of 4 closed a two-mode switched loop to 0.03 %).
MAX_MEMORY_NODES = 256
MAX_LONGER_MEMORY_NODES = 128
MAX_MEMORY = 6
#: Largest fixed-gain SDP of a memory the brackets solve without a time limit (with one: the time left), in
#: Clarabel's CPU seconds as :func:`fixed_gain_seconds` estimates them; a longer memory is not tried and the message
#: says so (a 6-state loop on delays(2, 3): memory one 4.4 s, two 20 s, three 116 s, estimated 107 s).
MEMORY_LEVEL_SECONDS = 60.0
#: The input-limited designs' sets, as their messages name them.
NODE_SETS = "the node ellipsoids (invariant along every admissible run; re-checked)"
#: Largest look-ahead SDP of a switched loop tried (:func:`lookahead_cost`): its blocks (S^(L+1)) times their side
#: squared.  Each is a Clarabel SDP: a design of 50 interval modes at n = 12 would pose 2500 blocks of side 12 even at
#: L = 1; the hold-out families that closed pose at most 32 blocks of side 4 (n = 4, 2 modes, L = 4).
LOOKAHEAD_WORK = 20000
#: Extra strictness of the invariance blocks and slack on u_max inside the SDP (as in the single-network design).
STRICT = 1e-5
LIMIT_SLACK = 1e-6
#: Largest semi-axis of the node ellipsoids searched (times max(1, |x0|)): K = 0 may keep a stable plant anywhere.
MAX_RADIUS = 1e3


# ------------------------------------------------------------------------------------------- the channels
@dataclass
class Rows:
    """Rows ``free + sum_j coef[j] K_j R_j`` on the Lyapunov state (``R_j`` reads slack block ``right[j]``).

    free : (p, k); coef : (N, p, m); right : (N,) int, -1 where ``K_j`` is absent.
    """

    free: np.ndarray
    coef: np.ndarray
    right: np.ndarray

    def value(self, gains: np.ndarray, n: int) -> np.ndarray:
        out = self.free.copy()
        for j, b in enumerate(self.right):
            if b >= 0 and np.any(self.coef[j]):
                out[:, b * n:(b + 1) * n] += self.coef[j] @ gains[j]
        return out

    def times_z(self, Z, Y, n: int, zblocks: int):
        """``rows(K) Z`` with ``Y_j = K_j Z_(right_j)`` (cvxpy)."""
        out = self.free @ Z
        for j, b in enumerate(self.right):
            if b >= 0 and np.any(self.coef[j]):
                term = self.coef[j] @ Y[j]
                if zblocks == 1:
                    out = out + term
                else:
                    p = self.free.shape[0]
                    cols = [term if c == b else np.zeros((p, n)) for c in range(zblocks)]
                    out = out + cp.hstack(cols)
        return out


@dataclass
class Channels:
    """The performance data of every transition of a :class:`network_lmi.NetworkProblem`.

    state : list of Rows (``A_e``); cost : list of Rows (``L_e``) or None; output : list of Rows (``C_e``) or
    None; B, D : lists of arrays or None; start : Lyapunov-matrix indices a run may start in; history : (k, n)
    ``S``, the initial state on the Lyapunov state from ``x0``.
    """

    prob: object
    state: list
    cost: list | None
    output: list | None
    B: list | None
    D: list | None
    start: np.ndarray
    history: np.ndarray
    Q: np.ndarray | None = None
    R: np.ndarray | None = None
    #: Lifted form: the lifted modes (with the plant data, for the loop-data bounds) and each transition's mode.
    lifted: object | None = None
    lifted_seq: list | None = None
    #: Augmented form, hinf: the channel's (C_z, D_z) per plant mode.
    output_data: tuple | None = None

    def numeric(self, gains: np.ndarray) -> list[dict]:
        n = self.prob.n
        out = []
        for e in range(self.prob.n_blocks):
            L = None if self.cost is None else self.cost[e].value(gains, n)
            out.append({"A": self.state[e].value(gains, n), "L": L, "S": None if L is None else L.T @ L,
                        "B": None if self.B is None else self.B[e], "D": None if self.D is None else self.D[e],
                        "C": None if self.output is None else self.output[e].value(gains, n),
                        "src": int(self.prob.src[e]), "dst": int(self.prob.dst[e])})
        if self.prob.F is not None:
            loop_errors(self, np.asarray(gains, dtype=np.float64), out)
        return out


def loop_errors(ch: "Channels", gains: np.ndarray, data: list[dict]) -> None:
    """Add to every transition's data entrywise bounds of the distance of its float64 matrices to the deployed
    loop's (built exactly from the float64 F, G, gains, Q, R and channel), which the re-checks add to their
    allowance (docs/design.md §8.4, "Loop data").  Lifted form: the lifted modes' bounds
    (:meth:`solver.lifting.Lifted.errors`), widened by any difference of the two float64 evaluations.  Augmented
    form: ``A_e`` holds F, identities and one ``G K`` product, the stage matrix ``e0'Q e0 + sel' K' R K sel`` and
    the output ``C e0 + D K sel`` (B and D exact): each one rounded sum (Higham §3.1)."""
    from ..certificates import gamma
    from ..lifting import _symm, close

    prob = ch.prob
    if prob.form == "lifted":
        if ch.lifted is None:
            return
        per_mode = ch.lifted.numeric(gains)
        for d, s in zip(data, ch.lifted_seq):
            ref = per_mode[s]
            for key in ("A", "S", "B", "C", "D"):
                dkey = "d" + key
                if d.get(key) is None or ref.get(dkey) is None:
                    d[dkey] = None
                else:
                    X, Y = (_symm(d[key]), _symm(ref[key])) if key == "S" else (d[key], ref[key])
                    d[dkey] = close(X, Y, ref[dkey])
        return
    n, m, k = prob.n, prob.m, prob.k
    absK = np.abs(gains)
    for e, d in enumerate(data):
        terms = np.abs(prob.free[e])
        for j, b in enumerate(prob.right[e]):
            if b >= 0:
                terms[:, b * n:(b + 1) * n] += np.abs(prob.coef[e, j]) @ absK[j]
        d["dA"] = 2 * gamma(m + 2) * terms + TINY
        d["dS"] = d["dB"] = d["dC"] = d["dD"] = None
        age = int(np.flatnonzero(prob.right[e] >= 0)[0]) if np.any(prob.right[e] >= 0) else None
        cols = slice(n * age, n * (age + 1)) if age is not None else None
        if d.get("S") is not None and ch.Q is not None:
            S_alt, terms = np.zeros((k, k)), np.zeros((k, k))
            S_alt[:n, :n] += ch.Q
            terms[:n, :n] += np.abs(ch.Q)
            if cols is not None:
                K = gains[age]
                S_alt[cols, cols] += K.T @ ch.R @ K
                terms[cols, cols] += absK[age].T @ np.abs(ch.R) @ absK[age]
            d["dS"] = close(_symm(d["S"]), S_alt, 2 * gamma(2 * (n + m) + 2) * terms + TINY)
        if d.get("C") is not None and ch.output_data is not None:
            C, D = ch.output_data
            l = int(prob.labels[e]["plant"])
            C_alt = np.zeros_like(d["C"])
            C_alt[:, :n] = C[l]
            terms = np.abs(C_alt)
            if cols is not None:
                C_alt[:, cols] += D[l] @ gains[age]
                terms[:, cols] += np.abs(D[l]) @ absK[age]
            d["dC"] = close(d["C"], C_alt, 2 * gamma(m + 2) * terms + TINY)


def initial_history(prob) -> np.ndarray:
    """``S`` with ``state(0) = S x0``: x0 itself (lifted form), or the history ``(x0, ..., x0)`` (augmented form:
    the state before sample 0 is x0, simulate's convention); shape (k, n)."""
    return np.eye(prob.n) if prob.form == "lifted" else np.vstack([np.eye(prob.n)] * prob.N)


def channels(family, network, objective: str, weights=None, disturbance=None, output=None,
             plant_switching: str = "per_interval") -> Channels:
    """Build the network problem and the performance channels of ``objective`` ("cost" or "hinf")."""
    prob = network_lmi.build_problem(family, network, plant_switching)
    n, m, N, k = prob.n, prob.m, prob.N, prob.k
    r = family.n_modes
    state = [Rows(prob.free[e], prob.coef[e], prob.right[e]) for e in range(prob.n_blocks)]
    cost = out_rows = Bs = Ds = None
    Q = R = lifted = seq = output_data = None
    if objective == "cost":
        Q, R = check_weights(weights, n, m)
    if prob.form == "lifted":
        modes = ModeSet.from_family(family, N, plant_switching=plant_switching)
        lifted = lift_modes(modes, weights, disturbance if objective == "hinf" else None, output,
                            cost=objective == "cost")
        edges = network_lmi.lifted_edges(network)
        seq = [s for _, _, eta in edges for s in range(modes.n_modes) if modes.eta[s] == eta]
        assert len(seq) == prob.n_blocks
        zero = np.zeros(N, dtype=int)
        if objective == "cost":
            cost = [Rows(lifted.lifted[s].cost.free, lifted.lifted[s].cost.coef, zero) for s in seq]
        else:
            out_rows = [Rows(lifted.lifted[s].output.free, lifted.lifted[s].output.coef, zero) for s in seq]
            Bs = [lifted.lifted[s].B for s in seq]
            Ds = [lifted.lifted[s].D for s in seq]
    else:
        ages = np.asarray(network.ages)
        plants = [int(lab["plant"]) for lab in prob.labels]
        e0 = np.zeros((n, k))
        e0[:, :n] = np.eye(n)
        if objective == "cost":
            from ..lifting import _psd_root

            Qh, Rh = _psd_root(Q), _psd_root(R)
            cost = []
            for e in range(prob.n_blocks):
                d = int(ages[_source_node(prob, e)])
                free = np.vstack([Qh @ e0, np.zeros((m, k))])
                coef = np.zeros((N, n + m, m))
                coef[d, n:] = Rh
                right = np.full(N, -1)
                right[d] = d
                cost.append(Rows(free, coef, right))
        else:
            E, C, D = check_channel(disturbance, output, r, n, m)
            out_rows, Bs, Ds = [], [], []
            output_data = (np.asarray(C, dtype=np.float64), np.asarray(D, dtype=np.float64))
            for e in range(prob.n_blocks):
                d, l = int(ages[_source_node(prob, e)]), plants[e]
                coef = np.zeros((N, C.shape[1], m))
                coef[d] = D[l]
                right = np.full(N, -1)
                right[d] = d
                out_rows.append(Rows(C[l] @ e0, coef, right))
                Bs.append(np.vstack([E[l], np.zeros((k - n, E.shape[2]))]))
                Ds.append(np.zeros((C.shape[1], E.shape[2])))
    start = np.arange(len(prob.nodes))
    return Channels(prob, state, cost, out_rows, Bs, Ds, start, initial_history(prob), Q, R, lifted, seq,
                    output_data)


def _source_node(prob, e: int) -> int:
    """Automaton node a transition starts from."""
    return int(prob.nodes[prob.src[e]])


# ------------------------------------------------------------------------------------------- re-checks
def check_cost_nodes(P: np.ndarray, data: list[dict]) -> tuple[bool, float]:
    """Float64 re-check: every ``P_v > 0`` and ``A_e' P_w A_e - P_v + S_e <= 0`` below the rounding allowance."""
    P = _sym(P)
    if not np.all(np.isfinite(P)) or np.linalg.eigvalsh(P)[:, 0].min() <= 0:
        return False, np.inf
    worst, passed = -np.inf, True
    for d in data:
        Pv, Pw = P[d["src"]], P[d["dst"]]
        APA = d["A"].T @ Pw @ d["A"]
        # |A|'|P||A| bounds the rounding of forming A'P A (Higham, ch. 3), which ||A'P A|| need not
        absA = np.abs(d["A"])
        size = np.linalg.norm(absA.T @ np.abs(Pw) @ absA, 2) + np.linalg.norm(Pv, 2) + np.linalg.norm(d["S"], 2)
        value = np.linalg.eigvalsh(_sym(APA - Pv + d["S"]))[-1] / size
        worst = max(worst, value)
        passed = passed and value + _data_error(Pw, d) / size < -_allowance(P.shape[-1])
    return bool(passed), float(worst)


def history_value(P: np.ndarray, S: np.ndarray, x0: np.ndarray | None, weight: np.ndarray | None = None) -> float:
    """``x0' S' P S x0``, or without x0 ``trace S' P S`` (``sum_i w_i (S' P S)_ii`` with ``weight``: the user's
    trace in balanced coordinates, :attr:`solver.scaling.PerformanceScaling.trace_weight`)."""
    if x0 is not None:
        return float(x0 @ S.T @ P @ S @ x0)
    M = S.T @ P @ S
    return float(np.trace(M)) if weight is None else float(np.sum(weight * np.diagonal(M)))


def history_moment(ch: Channels, x0: np.ndarray | None, weight: np.ndarray | None = None) -> np.ndarray:
    """``M`` on the Lyapunov state with ``<P, M> = history_value(P, S, x0, weight)``: ``S x0 x0' S'``, or
    ``S diag(w) S'`` (the trace)."""
    return ch.history @ _moment(ch.history.shape[1], x0, weight) @ ch.history.T


def bound_of(P: np.ndarray, ch: Channels, x0: np.ndarray | None, weight: np.ndarray | None = None) -> float:
    """``max_v x0' S' P_v S x0`` (the trace without x0, weighted with ``weight``) over the start nodes."""
    return max(history_value(P[v], ch.history, x0, weight) for v in ch.start)


def certify(P0: np.ndarray, ch: Channels, data: list[dict], kind: str, x0=None, weight: np.ndarray | None = None):
    """The solver's node matrices scaled until the float64 re-check passes: ``(P, upper, reason)``.

    cost: ``c P0`` passes when ``c (P0_v - A_e' P0_w A_e) >= S_e``: ``c`` is the largest generalized eigenvalue over
    the transitions.  hinf: for ``P = c P0`` (c near 1) the smallest g is the largest eigenvalue of the Schur
    complement ``N22 - N21 N11^-1 N12`` of the bounded-real matrix at g = 0.  Either is then re-checked.
    """
    P0 = _sym(np.asarray(P0, float))
    if not np.all(np.isfinite(P0)):
        return None, None, "the solver's node matrices are not finite"
    if kind == "cost":
        try:
            c = max(float(scipy.linalg.eigh(_sym(d["S"]), _sym(P0[d["src"]] - d["A"].T @ P0[d["dst"]] @ d["A"]),
                                            eigvals_only=True)[-1]) for d in data)
            c = max(c, 1e-300)
        except (np.linalg.LinAlgError, ValueError):
            c = 1.0
        worst = np.inf
        for bump in (1e-12, 1e-10, 1e-8, 1e-6, 1e-4):
            P = c * (1 + bump) * P0
            ok, worst = check_cost_nodes(P, data)
            if ok:
                return P, bound_of(P, ch, x0, weight), ""
        return None, None, f"no multiple of the solver's node matrices passes the re-check (worst {worst:.3g})"
    return certify_hinf(P0, data)


def fixed_gain(ch: Channels, data: list[dict], kind: str, x0=None, time_limit: float | None = None,
               trace_weight: np.ndarray | None = None, coordinates: np.ndarray | None = None,
               n_nodes: int | None = None):
    """Node matrices for fixed gains (the smallest bound, a Clarabel SDP within ``time_limit`` s): a candidate
    for :func:`certify`.  ``trace_weight`` (n,): the cost bound ``sum_i w_i (S' P_v S)_ii`` instead of the trace
    (balanced coordinates, :attr:`solver.scaling.PerformanceScaling.trace_weight`).

    ``coordinates`` (V, k, k), positive definite node matrices ``Pi_v = L_v L_v'`` (a stability certificate of the
    same gains): the SDP is first posed in the coordinates ``xi = L_v^-T eta`` at node v, where they are the
    identity (``P~_v = L_v^-1 P_v L_v^-T``, ``A~_e = L_w' A_e L_v^-T``; the same optimum).  On barely stable gains of
    badly scaled plants the node matrices span ten or more decades, and Clarabel fails on the plain form where it
    solves this one (docs/design.md §11.3, "The fixed-gain SDP in the certificate's coordinates").  ``n_nodes``:
    the number of matrices (default: the automaton's nodes; :func:`memory_lift` has its own).
    """
    V = len(ch.prob.nodes) if n_nodes is None else int(n_nodes)
    reasons = []
    if coordinates is not None:
        try:
            L = np.linalg.cholesky(_sym(np.asarray(coordinates, float)))
        except np.linalg.LinAlgError:
            L = None
        if L is not None:
            T = np.linalg.inv(L).transpose(0, 2, 1)  # T_v = L_v^-T: T_v' Pi_v T_v = I
            moved = [dict(d, A=L[d["dst"]].T @ d["A"] @ T[d["src"]],
                          S=None if d["S"] is None else T[d["src"]].T @ d["S"] @ T[d["src"]],
                          B=None if d["B"] is None else L[d["dst"]].T @ d["B"],
                          C=None if d["C"] is None else d["C"] @ T[d["src"]]) for d in data]
            history = np.einsum("vji,jk->vik", L, ch.history)  # L_v' S
            P, why = _fixed_gain_sdp(ch, moved, kind, history, x0, time_limit, trace_weight, normalize=True)
            if P is not None:
                return np.einsum("vij,vjk,vlk->vil", L, P, L), ""  # P_v = L_v P~_v L_v'
            reasons.append(f"in the certificate's coordinates: {why}")
    P, why = _fixed_gain_sdp(ch, data, kind, np.stack([ch.history] * V), x0, time_limit, trace_weight)
    return P, "; ".join(reasons + [why]) if P is None else ""


def _fixed_gain_sdp(ch: Channels, data: list[dict], kind: str, history: np.ndarray, x0, time_limit, trace_weight,
                    normalize: bool = False):
    """The SDP of :func:`fixed_gain` on ``data`` with ``history[v]`` the initial history at node v (``normalize``:
    the stage costs divided by the largest one's norm, and the answer multiplied back: in the certificate's
    coordinates they are the only data far from 1)."""
    k, V = ch.prob.k, history.shape[0]
    P = [cp.Variable((k, k), symmetric=True) for _ in range(V)]
    cons = []
    if kind == "cost":
        size = max(max(float(np.linalg.norm(d["S"], 2)) for d in data), 1e-300) if normalize else 1.0
        tau = cp.Variable()
        for d in data:
            M = P[d["src"]] - d["A"].T @ P[d["dst"]] @ d["A"] - d["S"] / size
            cons.append(0.5 * (M + M.T) >> 0)
        # the bound from start v is <P_v, H_v>, H_v = S_v G S_v' (G = x0 x0', diag(trace_weight) or I), each H_v
        # divided by the largest one's norm (the same P): with trace weights spanning 11 decades (badly
        # scaled states) Clarabel failed on the weights written out and solves this form (docs/design.md §11.3)
        G = np.outer(x0, x0) if x0 is not None else np.diag(trace_weight) if trace_weight is not None else None
        H = {v: _sym(history[v] @ history[v].T if G is None else history[v] @ G @ history[v].T) for v in ch.start}
        scale = max(max(float(np.linalg.norm(h, 2)) for h in H.values()), 1e-300)
        for v in ch.start:
            cons.append(cp.trace((H[v] / scale) @ P[v]) <= tau)
        cons += [X >> 0 for X in P]
        obj = tau
    else:
        size = 1.0
        g = cp.Variable()
        for d in data:
            AB = np.hstack([d["A"], d["B"]])
            CD = np.hstack([d["C"], d["D"]])
            p = d["B"].shape[1]
            top = cp.bmat([[P[d["src"]], np.zeros((k, p))], [np.zeros((p, k)), g * np.eye(p)]])
            M = top - AB.T @ P[d["dst"]] @ AB - CD.T @ CD
            cons.append(0.5 * (M + M.T) >> 0)
        cons += [X >> 0 for X in P]
        obj = g
    try:
        with warnings.catch_warnings():  # an inaccurate answer is a proposal like any other: re-checked
            warnings.simplefilter("ignore", UserWarning)
            cp.Problem(cp.Minimize(obj), cons).solve(
                solver=cp.CLARABEL, **({} if time_limit is None else {"time_limit": float(max(time_limit, 1e-3))}))
    except cp.error.SolverError as err:
        return None, f"the fixed-gain SDP failed ({err})"
    if P[0].value is None:
        return None, "the fixed-gain SDP has no solution (the gains may not stabilize every admissible run)"
    return size * np.stack([X.value for X in P]), ""


def _rows_of(rows: Rows, K: list, n: int, k: int):
    """``rows(K)`` as a cvxpy expression of the gain variables ``K`` (one (m, n) per buffer slot)."""
    out = rows.free
    for j, b in enumerate(rows.right):
        if b >= 0 and np.any(rows.coef[j]):
            select = np.zeros((n, k))
            select[:, b * n:(b + 1) * n] = np.eye(n)
            out = out + rows.coef[j] @ K[j] @ select
    return out


def gains_for_nodes(ch: Channels, P: np.ndarray, kind: str, level: float | None = None,
                    time_limit: float | None = None) -> np.ndarray | None:
    """Gains that keep the node matrices ``P`` (V, k, k) a certificate with the most room: ``max t`` subject to
    ``(1 - t) P_v >= A_e(K)' P_w A_e(K) + L_e(K)' L_e(K)`` on every transition (cost), or the bounded-real
    inequality at ``level`` = g (hinf), each written by its Schur complement (affine in K for fixed P).  The gains ``P`` was
    computed for are feasible with ``t = 0``, so the answer keeps P (and its bound) valid and leaves room for a
    smaller one (:func:`refine_gains`).  None when the solver gives nothing."""
    prob = ch.prob
    n, m, N, k = prob.n, prob.m, prob.N, prob.k
    K = [cp.Variable((m, n)) for _ in range(N)]
    t = cp.Variable()
    P = _sym(np.asarray(P, float))
    try:
        # A' P_w A through P_w = R' R (no inverse of P_w: the least P is nearly singular, W = P_w^-1 spans 1e8)
        R = [np.linalg.cholesky(X).T for X in P]
    except np.linalg.LinAlgError:
        return None
    cons = []
    for e in range(prob.n_blocks):
        v, w = int(prob.src[e]), int(prob.dst[e])
        RA = R[w] @ _rows_of(ch.state[e], K, n, k)
        # the room is relative to P_v (t P_v, not t I): the same for every scaling of the state
        if kind == "cost":
            L = _rows_of(ch.cost[e], K, n, k)
            p = L.shape[0]
            M = cp.bmat([[(1 - t) * P[v], RA.T, L.T],
                         [RA, np.eye(k), np.zeros((k, p))],
                         [L, np.zeros((p, k)), np.eye(p)]])
        else:
            C = _rows_of(ch.output[e], K, n, k)
            RB, D = R[w] @ ch.B[e], ch.D[e]
            pw, pz = RB.shape[1], C.shape[0]
            M = cp.bmat([[(1 - t) * P[v], np.zeros((k, pw)), RA.T, C.T],
                         [np.zeros((pw, k)), level * np.eye(pw), RB.T, D.T],
                         [RA, RB, np.eye(k), np.zeros((k, pz))],
                         [C, D, np.zeros((pz, k)), np.eye(pz)]])
        cons.append(0.5 * (M + M.T) >> 0)
    cons.append(t <= 1)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            cp.Problem(cp.Maximize(t), cons).solve(
                solver=cp.CLARABEL, **({} if time_limit is None else {"time_limit": float(max(time_limit, 1e-3))}))
    except cp.error.SolverError:
        return None
    if t.value is None or not all(np.all(np.isfinite(Kj.value)) for Kj in K if Kj.value is not None):
        return None
    return np.stack([Kj.value if Kj.value is not None else np.zeros((m, n)) for Kj in K])


def refine_gains(ch: Channels, gains: np.ndarray, kind: str, x0=None, time_limit: float | None = None,
                 rounds: int = REFINE_ROUNDS, trace_weight: np.ndarray | None = None,
                 coordinates: np.ndarray | None = None) -> tuple[np.ndarray, list]:
    """The stability design's gains improved for the objective by alternating the fixed-gain SDP (node matrices
    of least bound for the gains, :func:`fixed_gain`) and :func:`gains_for_nodes` (gains that keep those node
    matrices valid with the most room): each round's bound is at most the last one's (docs/design.md §11.3, "Gains
    refined for the objective").  Stops after ``rounds``, when a round gains less than ``REFINE_TOL`` relative, or
    at ``time_limit``.  ``coordinates``: node matrices proving ``gains`` stable, where the first fixed-gain SDP is
    posed (:func:`fixed_gain`); each later one is posed where the last round's node matrices are the identity (they
    hold for the new gains).  Returns the gains of the least bound the fixed-gain SDP found (float figures,
    proposals: the caller brackets them) and each round's bound."""
    start = time.perf_counter()
    best, best_value, values = np.asarray(gains, float), np.inf, []
    K = best
    for _ in range(rounds):
        left = time_left(time_limit, start, floor=1e-3)
        if left is not None and left <= 1e-3:
            break
        P, _ = fixed_gain(ch, ch.numeric(K), kind, x0, left, trace_weight=trace_weight, coordinates=coordinates)
        if P is None:
            break
        coordinates = P
        value = bound_of(P, ch, x0, trace_weight) if kind == "cost" else None
        if kind != "cost":
            value = _hinf_level(ch, P, K)
        if value is None or not np.isfinite(value):
            break
        values.append(float(value))
        if value < best_value:
            improved = best_value - value > REFINE_TOL * abs(value)
            best, best_value = K, value
            if not improved:
                break
        else:
            break
        nxt = gains_for_nodes(ch, P, kind, None if kind == "cost" else value ** 2,
                              time_left(time_limit, start, floor=1e-3))
        if nxt is None:
            break
        K = nxt
    return best, values


def _hinf_level(ch: Channels, P: np.ndarray, gains: np.ndarray) -> float | None:
    """The least g**0.5 for which ``P`` meets the bounded-real inequality with ``gains`` (a float estimate for the
    refinement's bookkeeping; the bracket re-checks)."""
    P_ok, upper, _ = certify(P, ch, ch.numeric(gains), "hinf")
    return None if P_ok is None else float(upper)


# ------------------------------------------------------------------------------------------- lower bound
def closed_walks(prob, start, max_length: int = MAX_WALK_LENGTH, max_count: int = MAX_WALKS,
                 max_open: int = MAX_OPEN) -> list[tuple]:
    """Closed walks of the transition graph from each start index, shortest first (each a tuple of transitions).

    Each is an admissible run when repeated forever from its first node.
    """
    out_edges = [[] for _ in range(len(prob.nodes))]
    for e in range(prob.n_blocks):
        out_edges[prob.src[e]].append(e)
    found, open_ = [], [((), int(v)) for v in start]
    for _ in range(max_length):
        nxt = []
        for walk, node in open_:
            first = int(prob.src[walk[0]]) if walk else node
            for e in out_edges[node]:
                w = walk + (e,)
                if prob.dst[e] == first:
                    found.append(w)
                    if len(found) >= max_count:
                        return found
                nxt.append((w, int(prob.dst[e])))
        open_ = nxt[:max_open]
        if not open_:
            break
    return found


#: Closed walks at most (the shortest) that charge and release in the l2 gain's transient witness (all pairs scored).
TRANSIENT_WALKS = 64
#: Relative residual of scipy's answer above which a walk's Lyapunov equation is solved again in the coordinates
#: of the certificate (:func:`walk_value`).
WALK_RESIDUAL = 1e-12


def walk_value(data: list[dict], walk, ch: Channels, x0=None, hint: np.ndarray | None = None,
               weight: np.ndarray | None = None) -> float:
    """The exact cost from the walk's start (``x0' S' P_per S x0``, ``trace``) of repeating it; ``inf`` for an
    unstable walk.

    ``hint``: the certificate's matrix of the walk's first node (``Phi' P_v Phi < P_v`` over a closed walk), the
    coordinates of :func:`solver.brackets.lyapunov` when scipy's answer has a residual above
    ``WALK_RESIDUAL``.  On badly scaled plants scipy's Kronecker matrix has a reciprocal condition of 1e-17 (a
    warning per walk), yet its answers stay within 1e-10 of the doubled series ``sum Phi'^k L'L Phi^k``; the
    contraction coordinates, 3-20x slower over 4000 walks, only serve the ones it gets wrong."""
    sys = period_system(data, list(walk))
    if not np.max(np.abs(np.linalg.eigvals(sys["Phi"]))) < 1:
        return np.inf
    Phi, Q = sys["Phi"], sys["L"].T @ sys["L"]
    Pp = _lyapunov_once(Phi, Q, "direct" if Phi.shape[0] < 10 else "bilinear")
    if Pp is None or _lyapunov_residual(Phi, Pp, Q) > WALK_RESIDUAL:
        try:
            Pp = lyapunov(Phi, Q, hint)
        except np.linalg.LinAlgError:
            return np.nan
    return history_value(Pp, ch.history, x0, weight)


def combined_walks(prob, walks: list, values) -> list:
    """Longer closed walks for the l2 gain's lower end: ``a^i b^j`` (``i, j <= COMBINE_POWER``, at most
    ``COMBINE_LENGTH`` transitions) for each pair of the ``COMBINE_BEST`` best walks (by ``values``) through a common
    node, both rotated to start there.  A gain that needs the loop to alternate between two bad cycles (the worst
    direction of one feeding the other's) is missed by short walks alone: on the badly scaled families of
    docs/design.md §11.3 they raised the lower end by 1-5 %.  ``values``: the walks' (nan for none)."""
    order = np.argsort(-np.nan_to_num(np.asarray(values, dtype=float), nan=-np.inf))[:COMBINE_BEST]
    through = {}
    for i in order:
        w = tuple(walks[i])
        for r in range(len(w)):
            rotated = w[r:] + w[:r]
            through.setdefault(int(prob.src[rotated[0]]), []).append(rotated)
    seen = {tuple(w) for w in walks}
    out = []
    for node in sorted(through):
        rotations = list(dict.fromkeys(through[node]))
        for a, b in itertools.combinations(rotations, 2):
            for i in range(1, COMBINE_POWER + 1):
                for j in range(1, COMBINE_POWER + 1):
                    w = a * i + b * j
                    if len(w) <= COMBINE_LENGTH and w not in seen:
                        seen.add(w)
                        out.append(w)
    return out


def lower_bound(ch: Channels, data: list[dict], kind: str, x0=None, stop: float = np.inf,
                max_length: int = MAX_WALK_LENGTH, certificate: np.ndarray | None = None,
                weight: np.ndarray | None = None):
    """Worst closed walk searched: ``(value, walk, walks valued)``; ``stop`` (the certified upper end): no walks
    combined (hinf) once the best is within ``COMBINE_ABOVE_GAP`` of it.

    Every walk is valued in stacks first (:mod:`solver.periodic`), the best again on its own.  cost: the walks from
    the start nodes (:func:`_costliest_walks`, :func:`walk_value`); ``certificate``: node matrices ``P_v`` (one per
    node), the coordinates of each walk's Lyapunov equation; ``weight``: the trace's (:func:`history_value`).
    hinf: the walks from every node and, while the bracket is open, their combinations (:func:`combined_walks`),
    by :func:`_stacked_gains`, the ``REFINED`` best by the refined sweep."""
    start = ch.start if kind == "cost" else np.arange(len(ch.prob.nodes))
    walks = closed_walks(ch.prob, start, max_length, MAX_WALKS if kind == "cost" else MAX_WALKS_HINF)
    if not walks:
        return None, None, 0
    best, arg = -np.inf, None
    if kind == "cost":
        for i in _costliest_walks(ch, data, walks, x0, weight):
            hint = None if certificate is None else certificate[int(ch.prob.src[walks[i][0]])]
            v = walk_value(data, walks[i], ch, x0, hint, weight)
            if (np.isfinite(v) or v == np.inf) and v > best:
                best, arg = v, walks[i]
        return (None if arg is None else best), arg, len(walks)
    values = _stacked_gains(data, walks)
    if np.any(np.isfinite(values)) and np.nanmax(values) < stop * (1 - COMBINE_ABOVE_GAP):
        more = combined_walks(ch.prob, walks, values)
        walks = walks + more
        values = np.concatenate([values, _stacked_gains(data, more)])
    for i in np.argsort(-np.nan_to_num(values, nan=-np.inf))[:REFINED]:
        if np.isfinite(values[i]):  # the stacked value is a gain evaluated at a frequency; the sweep may beat it
            fine = max(float(values[i]), hinf_norm_lower(period_system(data, list(walks[i]))))
            if fine > best:
                best, arg = fine, walks[i]
    return (None if arg is None else best), arg, len(walks)


def _stacked_gains(data: list[dict], walks: list) -> np.ndarray:
    """The l2 gain of repeating each walk (``nan``: unstable, or pruned as below the ``max(REFINED,
    COMBINE_BEST)`` best), by the stacked level-set iteration of :func:`solver.brackets._norms_pruned`: every
    value is a gain evaluated at a frequency, a lower bound on the walk's."""
    from .. import periodic

    values = np.full(len(walks), np.nan)
    if not walks:
        return values
    arrays = periodic.mode_arrays(data)
    systems = []
    for pos, idx in periodic.group_by_length(walks).values():
        sys = periodic.period_stack(arrays, idx, "hinf")
        good = periodic.spectral_radius(sys["Phi"]) < 1
        systems.append((pos[good], {key: v[good] for key, v in sys.items()}))
    _norms_pruned(systems, values, max(REFINED, COMBINE_BEST))
    return values


def _costliest_walks(ch: Channels, data: list[dict], walks: list, x0, weight) -> np.ndarray:
    """Indices of the ``REFINED_COST`` costliest walks by their stacked values (:mod:`solver.periodic`: the
    Stein sum by doubling, ``<P_per, M>`` with ``M`` the initial history's moment), unstable walks first, then those
    whose sum did not settle (a radius within rounding of 1); :func:`walk_value` then values them on their own.  One
    Lyapunov solve per walk (4000 a bracket) was half of a network cost design's CPU."""
    M = history_moment(ch, x0, weight)
    Pp, stable, done = _walk_costs(data, walks)
    approx = np.einsum("ij,pji->p", M, Pp)
    rank = np.where(stable, np.where(done, 0.0, 1.0), 2.0)  # an unstable walk first: its cost is unbounded
    return np.lexsort((-approx, -rank))[:REFINED_COST]


def _walk_costs(data: list[dict], walks: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(P, stable, settled)``: each walk's periodic cost matrix from its first node (the Stein sum by doubling of
    :mod:`solver.periodic`, zero where it did not settle), whether the walk is stable, and whether its sum settled."""
    from .. import periodic

    k = data[0]["A"].shape[0]
    P = np.zeros((len(walks), k, k))
    stable, settled = np.zeros(len(walks), dtype=bool), np.zeros(len(walks), dtype=bool)
    arrays = periodic.mode_arrays(data)
    for pos, idx in periodic.group_by_length(walks).values():
        sys = periodic.period_stack(arrays, idx, "cost")
        Pp, stable[pos], settled[pos] = periodic.stein_screened(sys["Phi"], sys["S"])
        P[pos] = np.where(settled[pos][:, None, None], Pp, 0.0)
    return P, stable, settled


def worst_run(ch: Channels, data: list[dict], x0=None, weight: np.ndarray | None = None,
              nodes: np.ndarray | None = None, floor: float = -np.inf, stop: float = np.inf,
              memory: tuple | None = None):
    """The costliest admissible run found that takes a first stretch once and then repeats a closed walk (cost):
    ``(value, lead, walk, runs valued)``, ``value`` None when none beats ``floor``.

    A beam over the automaton from the start nodes: each run is carried as its cost so far and the moment
    ``Sigma = T M T'`` of its state (``M`` x0's or the trace's on the initial history, ``T`` the stretch's
    transition), extended by every transition leaving its node; the ``RUN_BEAM`` best by their cost so far plus
    ``<P_v, Sigma>`` (``nodes``, the certificate: what the rest may cost at most; without it the best tail; with
    ``memory = (P, keys, L)``, a certified look-ahead of :func:`memory_bracket`, a closer estimate: the largest
    ``<P_q, Sigma>`` over the sequences q leaving the run's node) go on,
    for ``RUN_DEPTH`` steps or until ``stop``.  Every extension is valued as a lower bound with the costliest stable
    closed walk from its node repeated after it; the best is re-valued on its own (:func:`solver.brackets.
    sequence_cost`, the walk's equation in the certificate's coordinates).  A closed walk from a start node alone
    (:func:`lower_bound`) misses runs whose first intervals cost most from x0 and whose worst period comes later
    (docs/design.md §11.3, "The lower end")."""
    prob, V = ch.prob, len(ch.prob.nodes)
    cycles = closed_walks(prob, np.arange(V), TAIL_LENGTH, TAIL_WALKS)
    cycle_P, _, settled = _walk_costs(data, cycles) if cycles else (None, None, np.zeros(0, dtype=bool))
    first = np.array([int(prob.src[w[0]]) for w in cycles], dtype=int)
    tails = [[cycles[i] for i in np.flatnonzero(settled & (first == v))] for v in range(V)]
    tail_P = [cycle_P[settled & (first == v)] if tails[v] else None for v in range(V)]
    M = history_moment(ch, x0, weight)
    src = np.asarray(prob.src)
    acc, at = np.zeros(len(ch.start)), np.asarray(ch.start, dtype=int)
    sig, paths = np.stack([M] * len(ch.start)), [()] * len(ch.start)
    lookahead = None  # per node, the look-ahead's matrices of the sequences leaving it
    if memory is not None:
        leaves = np.array([int(data[q[0]]["src"]) for _, q in memory[1]])  # the node each sequence leaves
        lookahead = [memory[0][leaves == v] if np.any(leaves == v) else None for v in range(V)]
    best, found, count = floor, None, 0
    for _ in range(RUN_DEPTH):
        parts = []
        for e, d in enumerate(data):
            rows = np.flatnonzero(at == src[e])
            if rows.size:
                nxt = d["A"][None] @ sig[rows] @ d["A"].T[None]
                parts.append((acc[rows] + np.einsum("ij,bji->b", d["S"], sig[rows]), np.full(rows.size, d["dst"]),
                              0.5 * (nxt + np.swapaxes(nxt, 1, 2)), [paths[r] + (e,) for r in rows]))
        if not parts:
            break
        acc = np.concatenate([p[0] for p in parts])
        at = np.concatenate([p[1] for p in parts])
        sig = np.concatenate([p[2] for p in parts])
        paths = [q for p in parts for q in p[3]]
        count += acc.size
        tail_value, tail_arg = np.zeros(acc.size), np.full(acc.size, -1)
        for v in np.unique(at):
            rows = np.flatnonzero(at == v)
            if tail_P[v] is not None:
                values = np.einsum("cij,bji->bc", tail_P[v], sig[rows])
                tail_value[rows], tail_arg[rows] = values.max(axis=1), values.argmax(axis=1)
        low = acc + tail_value
        i = int(np.argmax(low))
        if low[i] > best and tail_arg[i] >= 0:
            best, found = float(low[i]), (paths[i], tails[at[i]][tail_arg[i]])
        if best >= stop:
            break
        if lookahead is not None:  # the most the next transitions' matrices allow from the node
            ahead = np.full(acc.size, -np.inf)
            for v in np.unique(at):
                rows = np.flatnonzero(at == v)
                if lookahead[v] is not None:
                    ahead[rows] = np.einsum("cij,bji->bc", lookahead[v], sig[rows]).max(axis=1)
        else:
            ahead = tail_value if nodes is None else np.einsum("bij,bji->b", nodes[at], sig)
        keep = np.argsort(-(acc + ahead), kind="stable")[:RUN_BEAM]
        acc, at, sig, paths = acc[keep], at[keep], sig[keep], [paths[j] for j in keep]
    if found is None:
        return None, 0, (), count
    lead, walk = found
    hint = None if nodes is None else nodes[int(prob.src[walk[0]])]
    value = sequence_cost(data, lead, walk, M, hint)
    return (value, len(lead), tuple(lead) + tuple(walk), count) if value > floor else (None, 0, (), count)


def _walk_labels(prob, walk) -> list:
    """``(plant, eta)`` (lifted) or ``(plant, age)`` (augmented) per transition: the witness."""
    out = []
    for e in walk:
        lab = prob.labels[e]
        if prob.form == "lifted":
            plant = lab.get("plant", lab.get("plants", [0]))
            plant = plant[0] if isinstance(plant, (list, tuple)) and len(set(plant)) == 1 else plant
            out.append((tuple(plant) if isinstance(plant, list) else plant, int(prob.length[e])))
        else:
            out.append((int(lab["plant"]), int(lab["age"])))
    return out


def memory_count(data: list[dict], memory: int = 1) -> int:
    """The number of admissible sequences of ``memory`` transitions (the matrices of :func:`memory_lift` and of
    :func:`lookahead_lift`), counted without listing them (by node, O(transitions) a step)."""
    src, dst = np.array([d["src"] for d in data]), np.array([d["dst"] for d in data])
    V = int(max(src.max(), dst.max())) + 1
    ending = np.ones(len(data))  # admissible sequences of the last l transitions, by the last one
    for _ in range(memory - 1):
        ending = np.bincount(dst, weights=ending, minlength=V)[src]
    return int(round(float(ending.sum())))


def _sequences(data: list[dict], memory: int) -> list[tuple]:
    """The admissible sequences of ``memory`` transitions, in lexicographic order."""
    seqs = [(e,) for e in range(len(data))]
    for _ in range(memory - 1):
        seqs = [q + (f,) for q in seqs for f in range(len(data)) if data[f]["src"] == data[q[-1]]["dst"]]
    return seqs


def _leaving(data: list[dict]) -> list[list[int]]:
    """The transitions leaving each automaton node (index: node)."""
    nodes = 1 + max(max(d["src"], d["dst"]) for d in data)
    return [[f for f in range(len(data)) if data[f]["src"] == v] for v in range(nodes)]


def memory_lift(ch: Channels, data: list[dict], memory: int = 1):
    """The transition graph of the l2 gain's bound with memory: one node per admissible sequence ``q`` of the last
    ``memory`` transitions (the state just after them), ``q`` going to ``q[1:] + (f,)`` with ``f``'s data for every
    ``f`` leaving ``dst(q[-1])``.  A quadratic function per node of this graph is a path-dependent Lyapunov function
    of that memory, which may bound far below the automaton's node matrices (docs/design.md §11.3, "Memory of the
    last transitions").  The cost looks ahead instead (:func:`lookahead_lift`).

    Returns ``(channels, lifted data, keys)``: the channels (no start nodes: the l2 gain starts from rest), the lifted
    data (each transition's data and rounding bounds unchanged) and each lifted node's key ``("last", q)``; with
    ``memory = 1`` the nodes are the transitions in order."""
    seqs = _sequences(data, memory)
    index = {q: i for i, q in enumerate(seqs)}
    leaving = _leaving(data)
    lifted = [dict(data[f], src=i, dst=index[(q + (f,))[-memory:]]) for i, q in enumerate(seqs)
              for f in leaving[data[q[-1]]["dst"]]]
    return dataclasses.replace(ch, start=np.zeros(0, dtype=int)), lifted, [("last", q) for q in seqs]


def lookahead_lift(ch: Channels, data: list[dict], memory: int = 1):
    """The transition graph with one node per admissible sequence of the next ``memory`` transitions (the state
    just before them): a node ``q = (e_1, ..., e_L)`` goes to ``(e_2, ..., e_L, f)`` for every ``f`` leaving
    ``dst(e_L)``, carrying ``e_1``'s data; the start nodes are the sequences whose first transition leaves a start
    node.  Matrices ``P_q`` with ``A_1' P_q' A_1 - P_q + S_1 <= 0`` on its edges bound the cost of every run by
    ``max_q <P_q, M>`` over those start nodes: one matrix per first stretch, where the memory of the last
    transitions (:func:`memory_lift`) would have one for all runs from a start (docs/design.md §11.3, "Look-ahead").

    Returns ``(channels, lifted data, keys)`` as :func:`memory_lift`, the keys ``("next", q)``."""
    seqs = _sequences(data, memory)
    index = {q: i for i, q in enumerate(seqs)}
    leaving = _leaving(data)
    lifted = [dict(data[q[0]], src=i, dst=index[q[1:] + (f,)]) for i, q in enumerate(seqs)
              for f in leaving[data[q[-1]]["dst"]]]
    starts = {int(v) for v in ch.start}
    start = [i for i, q in enumerate(seqs) if int(data[q[0]]["src"]) in starts]
    return dataclasses.replace(ch, start=np.asarray(start, dtype=int)), lifted, [("next", q) for q in seqs]


def _one_node(data: list[dict], n: int) -> tuple:
    """Interval modes any of which may follow any (bounded drops, :mod:`solver.brackets`) as a one-node graph:
    ``(channels, data)`` for :func:`memory_bracket` (the Lyapunov state is the state, the history the identity)."""
    ch = Channels(prob=types.SimpleNamespace(k=n, nodes=(0,)), state=None, cost=None, output=None, B=None, D=None,
                  start=np.zeros(1, dtype=int), history=np.eye(n))
    return ch, [dict(d, src=0, dst=0) for d in data]


def lookahead_cost(data: list[dict], x0=None, weight: np.ndarray | None = None, P: np.ndarray | None = None,
                   lower: float | None = None, time_limit: float | None = None, upper: float | None = None):
    """The cost bound of one matrix per sequence of the next L interval modes of a bounded-drops loop (``data`` of
    :meth:`solver.lifting.Lifted.numeric`; every mode may follow every mode): L = 1, 2, ... ``MAX_MEMORY`` while at
    most ``MAX_LONGER_MEMORY_NODES`` matrices and open by more than ``MEMORY_GAP`` above ``lower``, the first in the
    coordinates of the common certificate ``P``, each in the last's (docs/design.md §8.4, "Look-ahead"); stopped
    when the last step's fall, repeated, would not reach ``upper`` (the bound already certified otherwise).
    ``(matrices (S^L, n, n) in :func:`lookahead_lift`'s order, upper, L)`` of the least certified, or None."""
    n = data[0]["A"].shape[0]
    ch, graph = _one_node(data, n)
    start, best, previous = time.perf_counter(), None, None
    for memory in range(1, MAX_MEMORY + 1):
        if best is not None and lower is not None and best[1] <= lower * (1 + MEMORY_GAP):
            break
        if len(data) ** (memory + 1) * n * n > LOOKAHEAD_WORK:  # its S^(L+1) blocks of side n on Clarabel
            break
        left = None if time_limit is None else time_left(time_limit, start, floor=1e-3)
        Pm, bound, keys, _ = memory_bracket(ch, graph, "cost", x0, None if P is None else P[None], left, weight, memory,
                                            previous)
        if Pm is None:
            break
        fall = np.inf if best is None else best[1] - bound
        if best is None or bound < best[1]:
            best = (Pm, bound, memory)
        previous = (Pm, keys, memory)
        if upper is not None and bound - fall > upper:  # (a slowly contracting loop: 967, 611, 551, 517 against 468)
            break
    return best


def lookahead_check(data: list[dict], P: np.ndarray) -> bool:
    """The float64 re-check of :func:`lookahead_cost`'s matrices ``P`` (S^L, n, n) on ``data`` (S modes)."""
    S, count = len(data), P.shape[0]
    memory = max(1, int(round(np.log(count) / np.log(S)))) if S > 1 else 1
    if S ** memory != count:
        return False
    _, lifted, _ = lookahead_lift(*_one_node(data, P.shape[-1]), memory)
    return check_cost_nodes(P, lifted)[0]


def _shorter(key: tuple, memory: int) -> tuple:
    """The key with ``memory`` transitions that a node of a longer memory refines: a look-ahead's (``("next", q)``)
    that of its first transitions, a memory's (``("last", q)``) that of its last."""
    when, q = key
    return when, q[:memory] if when == "next" else q[len(q) - memory:]


def fixed_gain_seconds(blocks: int, side: int) -> float:
    """Clarabel's CPU seconds on a fixed-gain SDP of ``blocks`` transition blocks of side ``side``, fitted on 2-core
    machine A (8, 21, 55 and 144 blocks of side 18 took 1.3, 4.4, 20 and 116 s; 68 and 328 blocks of side 12, 3.4 and
    38 s; each within 1.25x of the fit)."""
    return 2.66e-9 * float(blocks) ** 1.6 * float(side) ** 5.7


def memory_bracket(ch: Channels, data: list[dict], kind: str, x0=None, nodes: np.ndarray | None = None,
                   time_limit: float | None = None, trace_weight: np.ndarray | None = None, memory: int = 1,
                   previous: tuple | None = None):
    """The certified bound of ``memory`` transitions (the cost's look-ahead, :func:`lookahead_lift`; the l2 gain's
    memory, :func:`memory_lift`): the fixed-gain SDP on the lifted graph, posed in the coordinates of ``previous``
    (``(P, keys, memory)`` of a certified bound of a shorter memory: each node takes the matrix of the node it
    refines) or else of the node matrices ``nodes`` (each lifted node its automaton node: the one its sequence leaves
    for the cost, the one it reached for the l2 gain), re-checked as any node matrices (:func:`certify`).
    ``(P (count, k, k) or None, upper or None, keys, reason)``."""
    count = memory_count(data, memory)
    cap = MAX_MEMORY_NODES if memory == 1 else MAX_LONGER_MEMORY_NODES
    if count > cap:
        return None, None, [], f"{count} matrices of memory {memory} exceed {cap}"
    lch, lifted, keys = lookahead_lift(ch, data, memory) if kind == "cost" else memory_lift(ch, data, memory)
    side = lch.prob.k + (0 if kind == "cost" else lifted[0]["B"].shape[1])
    seconds = fixed_gain_seconds(len(lifted), side)
    cap, what = (MEMORY_LEVEL_SECONDS, "the cap without a time limit") if time_limit is None else \
        (time_limit, "the time left")
    if seconds > cap:
        return None, None, keys, (f"not tried: its SDP ({len(lifted)} blocks of side {side}) is estimated at "
                                  f"{seconds:.3g} s, above {what} ({cap:.3g} s)")
    coordinates = None
    if previous is not None:
        where = {key: i for i, key in enumerate(previous[1])}
        coordinates = np.asarray(previous[0])[[where[_shorter(key, previous[2])] for key in keys]]
    elif nodes is not None:
        coordinates = np.asarray(nodes)[[data[q[0]]["src"] if when == "next" else data[q[-1]]["dst"]
                                         for when, q in keys]]
    P0, why = fixed_gain(lch, lifted, kind, x0, time_limit, trace_weight=trace_weight, coordinates=coordinates,
                         n_nodes=count)
    if P0 is None:
        return None, None, keys, why
    P, upper, why = certify(P0, lch, lifted, kind, x0, trace_weight)
    if coordinates is not None and (P is None or kind == "cost"):
        # the SDP's optimum is on the cone's edge (P_v - A' P_w A singular where the stage cost is), where rounding
        # leaves it just outside or the re-check's multiple far above it; a little of the coordinates' matrices, a
        # certificate of the lift with room, brings it in: the least bound that passes is kept (the l2 gain's
        # re-check, a bisection on the level, costs 10-20 of the cost's: there only when the answer alone fails)
        norm = np.linalg.norm(P0, 2, axis=(-2, -1)).max() / np.linalg.norm(coordinates, 2, axis=(-2, -1)).max()
        for share in (1e-8, 1e-6, 1e-4, 1e-2):
            P_s, upper_s, why_s = certify(P0 + share * norm * coordinates, lch, lifted, kind, x0, trace_weight)
            if P_s is not None and (P is None or upper_s < upper):
                P, upper, why = P_s, upper_s, why_s
    return P, upper, keys, why


def bracket(ch: Channels, gains: np.ndarray, kind: str, P0=None, x0=None,
            time_limit: float | None = None, trace_weight: np.ndarray | None = None,
            memory: bool = True) -> NetworkPerformance:
    """The certified bracket of ``kind`` for given gains on the network (float64 upper, witnessed lower;
    ``time_limit``: the fixed-gain SDP's, in seconds, 0 to skip it; ``trace_weight``: the cost's trace weights,
    balanced coordinates, :func:`history_value`).  ``memory``: when the node matrices leave the bracket open by
    more than ``MEMORY_GAP``, try the bounds of memory one, two, ... ``MAX_MEMORY`` (:func:`memory_bracket`, each
    in the coordinates of the last one certified; ``mode_certificate``, ``memory``) while it stays open: for the
    cost one matrix per sequence of the next transitions (:func:`lookahead_lift`), for the l2 gain of the last
    (:func:`memory_lift`)."""
    start = time.perf_counter()
    data = ch.numeric(gains)
    P = upper = None
    reason = ""
    if P0 is not None:
        P, upper, reason = certify(P0, ch, data, kind, x0, trace_weight)
    if P is None and (time_limit is None or time_limit > 0):
        Pf, why = fixed_gain(ch, data, kind, x0, time_limit, trace_weight=trace_weight)
        if Pf is not None:
            P, upper, why = certify(Pf, ch, data, kind, x0, trace_weight)
        reason = why if not reason else f"{reason}; fixed-gain SDP: {why}"
    lower, walk, count = lower_bound(ch, data, kind, x0, stop=np.inf if upper is None else upper, certificate=P,
                                     weight=trace_weight)
    lead, released = 0, None
    if kind == "cost" and lower is not None and np.isfinite(lower) and \
            (upper is None or lower < upper * (1 - LOWER_CLOSED)):
        value, found_lead, found, runs = worst_run(ch, data, x0, trace_weight, P, floor=lower,
                                                   stop=np.inf if upper is None else upper)
        count += runs
        if value is not None:
            lower, lead, walk = value, found_lead, found
    if kind == "hinf" and lower is not None and np.isfinite(lower) and lower > 0 and \
            (upper is None or upper > lower * (1 + COMBINE_ABOVE_GAP)):
        # driven along one closed walk, released at rest along another from the same node (docs/design.md §11.3)
        walks = closed_walks(ch.prob, np.arange(len(ch.prob.nodes)), MAX_WALK_LENGTH,
                             min(TRANSIENT_WALKS, int(np.sqrt(TRANSIENT_WORK) / ch.prob.k)))
        released = transient_witness(data, lower, walks, [int(ch.prob.src[w[0]]) for w in walks])
        count += len(walks)
        if released is not None:
            lower, lead, walk = released.value, len(released.charge) * released.periods, \
                tuple(released.charge * released.periods + released.release)
    if P is not None and lower is not None and lower > upper * (1 + 1e-6):  # inf: an unstable walk
        P, upper, reason = None, None, f"the witness walk ({lower:.6g}) exceeds the certified bound; refused"
    node_upper, memory_P, level, previous, skipped = upper, None, 0, None, ""
    for tried in range(1, (MAX_MEMORY if memory else 0) + 1):
        left = None if time_limit is None or time_limit <= 0 else time_left(time_limit, start, floor=1e-3)
        if not ((upper is None or lower is None or upper > lower * (1 + MEMORY_GAP)) and
                (left is None or left > 1e-3) and (lower is None or np.isfinite(lower))):
            break
        Pm, bound, keys, why = memory_bracket(ch, data, kind, x0, P, left, trace_weight, tried, previous)
        if Pm is not None and (lower is None or lower <= bound * (1 + 1e-6)) and (upper is None or bound < upper):
            memory_P, upper, level, previous = Pm, bound, tried, (Pm, keys, tried)
        elif P is None and memory_P is None and why:
            reason = f"{reason}; memory {tried}: {why}"
        if Pm is None and why.startswith("not tried"):
            skipped = f"; memory {tried} {why}"
        if Pm is None:  # too many matrices, or a lift the SDP or the re-check failed on: a longer one is larger
            break
    if kind == "cost" and previous is not None and lower is not None and np.isfinite(lower) and \
            lower < upper * (1 - LOWER_CLOSED):
        # the run search again, ranked by the look-ahead's matrices: the node matrices' ranking, looser, let the
        # beam drop the run that led to the costliest stretch (delays(1, 2), badly scaled seed 1)
        value, found_lead, found, runs = worst_run(ch, data, x0, trace_weight, P, floor=lower, stop=upper,
                                                   memory=previous)
        count += runs
        if value is not None and value <= upper * (1 + 1e-6):
            lower, lead, walk = value, found_lead, found
    exact_note = ""
    if released is None and walk is not None and lower is not None and np.isfinite(lower) and lower > 0:
        # the witness valued exactly, as on bounded drops (docs/design.md §11.3): the closed walk's gain at its peak,
        # the run's cost along its exact states
        left = None if time_limit is None or time_limit <= 0 else (lambda: time_left(time_limit, start))
        found = LowerBound(value=lower, witness=[], patterns=count, note="", lead=lead, pattern=tuple(walk))
        if kind == "hinf":
            found = found._replace(peak=hinf_norm_peak(period_system(data, list(walk)), frequency=True)[1])
            value, exact_note = exact_witness(data, found, left)
        else:
            value, exact_note = exact_cost_witness(data, found, x0, trace_weight, left, ch.history)
        if value is not None and (upper is None or value <= upper * (1 + 1e-6)):
            lower = value
        elif value is not None:  # (cannot happen for a valid certificate) the float64 value stays, and says so
            exact_note = f"float64 witness, not a proof (its exact value {value:.6g} is above the certified bound)"
    if walk is not None and released is None:  # one infinite run, one witness, whatever rounding picked among its
        # spellings (a transient stays as evaluated: `lead` marks where its disturbance acts)
        prefix, period = shortest_lead(walk[:lead], _primitive_period(list(walk[lead:])))
        walk, lead = tuple(prefix + period), len(prefix)
    what = "cost" if kind == "cost" else "l2 gain"
    if memory_P is not None:
        when = "next" if kind == "cost" else "last"
        last = f"{when} transition" if level == 1 else f"sequence of the {when} {level} transitions"
        message = f"{what} certified <= {upper:.6g} (float64 re-check of one matrix per {last})"
        if node_upper is not None:
            message += f"; the node matrices alone: {node_upper:.6g}"
    else:
        message = (f"{what} certified <= {upper:.6g} (float64 re-check of the node matrices)" if P is not None
                   else f"no certified upper bound: {reason}")
    message += skipped if P is not None or memory_P is not None else ""
    if lower is not None:
        shape = f"; {lead} transitions once, then a closed walk of {len(walk) - lead} repeated" if lead else ""
        if lead and kind == "hinf":
            on = "the deployed loop" if released.deployed else "the float64 transition data as exact rationals"
            shape += f" at rest (the disturbance in the first ones only; evaluated exactly on {on})"
        message += f"; worst admissible run searched: {lower:.6g} ({count} walks and runs valued{shape})"
        if exact_note and released is None:
            message += f"; {exact_note}"
    prob = ch.prob
    return NetworkPerformance(
        kind=kind, upper=upper, lower=lower, witness=[] if walk is None else _walk_labels(prob, walk),
        certificate=P, verified=P is not None or memory_P is not None, x0=x0, patterns=count, message=message,
        walk=[] if walk is None else [dict(prob.labels[e]) for e in walk], form=prob.form,
        start_nodes=[int(prob.nodes[v]) for v in ch.start], certificate_upper=node_upper,
        mode_certificate=memory_P, lead=lead, memory=level)


# ------------------------------------------------------------------------------------------- the design SDP
def _solve_clarabel(problem, time_limit: float | None, what: str) -> float:
    """Solve ``problem`` on Clarabel; the elapsed wall seconds.  Raises SolverFailed naming ``what``."""
    opts = {} if time_limit is None else {"time_limit": float(max(time_limit, 1e-3))}
    start = time.perf_counter()
    try:
        with warnings.catch_warnings():  # an inaccurate answer is a proposal like any other: re-checked
            warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=cp.CLARABEL, **opts)
    except cp.error.SolverError as err:
        raise SolverFailed(f"Clarabel failed on the {what}: {err}", status="solver_error") from None
    return time.perf_counter() - start


def solve(ch: Channels, kind: str, x0=None, time_limit: float | None = None, u_max=None):
    """The design SDP (Clarabel): ``(W, Y, Z, value, status, seconds)``; ``W`` None without an answer.

    ``u_max`` (cost only): the Kothare form (docs/design.md §11.3): ``W_v = gamma P_v^-1``, the cost rows against
    ``gamma I`` (the state rows a hair stricter, ``1 + STRICT``, so that the ellipsoids' invariance survives the
    float64 re-check), ``[[1, (S x0)'], [S x0, W_v]] >= 0`` at the start nodes (``[[X_v, S'], [S, W_v]] >= 0``,
    ``trace X_v <= 1`` without x0) and the input blocks of :func:`solve_limits` per node and gain; minimize gamma.
    ``value`` is gamma, the cost bound of ``P_v = gamma W_v^-1``.
    """
    prob = ch.prob
    kothare = kind == "cost" and u_max is not None
    n, m, k = prob.n, prob.m, prob.k
    Zb, Z, W, Y = network_lmi.cvx_variables(prob)
    cons = []
    g = cp.Variable()
    for e in range(prob.n_blocks):
        AZ = ch.state[e].times_z(Z, Y, n, prob.zblocks)
        top = Z + Z.T - W[prob.src[e]]
        if kind == "cost":
            LZ = ch.cost[e].times_z(Z, Y, n, prob.zblocks)
            p = ch.cost[e].free.shape[0]
            tail = g * np.eye(p) if kothare else np.eye(p)
            if kothare:
                AZ = (1 + STRICT) * AZ
            M = cp.bmat([[top, AZ.T, LZ.T], [AZ, W[prob.dst[e]], np.zeros((k, p))],
                         [LZ, np.zeros((p, k)), tail]])
        else:
            CZ = ch.output[e].times_z(Z, Y, n, prob.zblocks)
            B, D = ch.B[e], ch.D[e]
            pw, pz = B.shape[1], D.shape[0]
            M = cp.bmat([[top, np.zeros((k, pw)), AZ.T, CZ.T],
                         [np.zeros((pw, k)), g * np.eye(pw), B.T, D.T],
                         [AZ, B, W[prob.dst[e]], np.zeros((k, pz))],
                         [CZ, D, np.zeros((pz, k)), np.eye(pz)]])
        cons.append(0.5 * (M + M.T) >> 0)
    if kind == "cost":
        S = ch.history
        level = 1.0 if kothare else g
        for v in ch.start:
            if x0 is None:
                X = cp.Variable((n, n), symmetric=True)
                cons += [cp.bmat([[X, S.T], [S, W[v]]]) >> 0, cp.trace(X) <= level]
            else:
                s = (S @ x0).reshape(-1, 1)
                top = np.ones((1, 1)) if kothare else cp.reshape(g, (1, 1), order="C")
                cons.append(cp.bmat([[top, s.T], [s, W[v]]]) >> 0)
    if kothare:
        cons += _input_blocks(prob, Z, W, Y, u_max)
    problem = cp.Problem(cp.Minimize(g), cons)
    elapsed = _solve_clarabel(problem, time_limit, f"network {kind} SDP")
    if W[0].value is None or Zb[0].value is None:
        return None, None, None, np.nan, str(problem.status), elapsed
    Wv = np.stack([0.5 * (w.value + w.value.T) for w in W])
    Yv = np.stack([np.zeros((m, n)) if y.value is None else y.value for y in Y])
    Zv = np.stack([z.value for z in Zb])
    return Wv, Yv, Zv, float(g.value), str(problem.status), elapsed


#: The IPM's gap and feasibility tolerances on the network performance SDPs.
IPM_TOL = 1e-10


def solve_ipm(ch: Channels, kind: str, x0=None, time_limit: float | None = None, u_max=None):
    """The design SDP of :func:`solve` on the structured IPM (:mod:`solver.ipm.network_performance_blocks`):
    ``(W, Y, Z, value, status, seconds)``.

    Phase 2's last iterate is strictly feasible whatever its status: a proposal for the re-checks.  On the
    augmented form the infimum is not attained (the optimal ``P_v`` vanishes on the history blocks no future
    input reads, ``W_v`` grows without bound there): phase 2 creeps towards it and stops at its iteration cap
    (motor, delays(1, 3): 100 iterations, 3e-9 above the infimum, Clarabel 3e-6 above it).  Raises
    SolverFailed when there is none (phase 1 found no interior point: status "infeasible" when its
    multipliers bound ``max t < 0``)."""
    from ..ipm import IPMOptions
    from ..ipm.network_performance_blocks import network_performance_problem, solve_network_performance

    kothare = kind == "cost" and u_max is not None
    begin = time.perf_counter()
    problem = network_performance_problem(ch, kind, x0, u_max, strict=STRICT if kothare else 0.0,
                                          limit_slack=LIMIT_SLACK if kothare else 0.0)
    sol = solve_network_performance(problem, IPMOptions(gap_tol=IPM_TOL, feas_tol=IPM_TOL, time_limit=time_limit))
    elapsed = time.perf_counter() - begin
    if not np.isfinite(sol.value):
        raise SolverFailed(f"IPM ended with status {sol.status!r} on the network {kind} SDP after "
                           f"{sol.raw.iterations} iterations (phase 1 t = {sol.raw.t:.3g}, bound "
                           f"{sol.raw.t_upper:.3g})", status=sol.status)
    return sol.W, sol.Y, sol.Z, sol.value, sol.status, elapsed


def gains_from(prob, Y: np.ndarray, Z: np.ndarray) -> np.ndarray:
    K = np.empty_like(Y)
    for j in range(prob.N):
        b = 0 if prob.zblocks == 1 else j
        K[j] = np.linalg.solve(Z[b].T, Y[j].T).T
    return K


# ------------------------------------------------------------------------------------------- the design
OBJECTIVES = ("cost", "hinf")


def check_request(network, objective: str, weights, x0, disturbance, output, u_max, decay_rate, n: int, m: int):
    """Refuse what does not carry over to a network (docs/design.md §11.3), naming the field and why.

    Returns ``(x0, u_max)`` checked (float arrays or None)."""
    where = f"network={network.describe()}"
    if objective not in ("stability",) + OBJECTIVES:
        raise InvalidInput(f"objective must be one of ('stability', 'cost', 'hinf'), got {objective!r}",
                           ("objective",))
    if u_max is not None:
        if objective == "hinf":
            raise InvalidInput("u_max with objective='hinf' is not available (the set would depend on the "
                               "disturbance energy)", ("u_max",))
        u_max = check_u_max(u_max, m)
    if objective == "stability":
        for name, value in (("weights", weights), ("disturbance", disturbance), ("output", output)) + (
                (("x0", x0),) if u_max is None else ()):
            if value is not None:
                raise InvalidInput(f"{name} needs objective='cost' or 'hinf'" + (" (or u_max, for x0)"
                                                                                 if name == "x0" else ""), (name,))
        if decay_rate == "max" and u_max is not None:
            raise InvalidInput("decay_rate='max' cannot be combined with u_max; give a rate", ("decay_rate",))
        return check_x0(x0, n), u_max
    if decay_rate not in (None, "auto"):
        raise InvalidInput(f"decay_rate combines with objective='stability' only (on {where} too)",
                           ("decay_rate",))
    if objective == "hinf" and disturbance is None:
        raise InvalidInput("objective='hinf' needs disturbance=E", ("disturbance",))
    if objective == "cost" and (disturbance is not None or output is not None):
        raise InvalidInput("disturbance and output go with objective='hinf'", ("disturbance",))
    if objective == "hinf" and weights is not None:
        raise InvalidInput("weights go with objective='cost'", ("weights",))
    if objective == "hinf" and x0 is not None:
        raise InvalidInput("x0 goes with objective='cost' (the l2 gain starts from x = 0)", ("x0",))
    return check_x0(x0, n), u_max


def _scaled(family, objective, weights, disturbance, output, scaling: str):
    """The scaling layer (:func:`solver.scaling.performance_balance`): ``(scale or None, family~, weights~,
    disturbance~, output~)`` in balanced coordinates."""
    from ..scaling import performance_balance

    if scaling == "none":
        return None, family, weights, disturbance, output
    N = 1
    modes = ModeSet.from_family(family, N)
    lifted = lift_modes(modes, weights, disturbance if objective == "hinf" else None, output,
                        cost=objective == "cost")
    scale = performance_balance(family, lifted)
    if scale.is_identity:
        return None, family, weights, disturbance, output
    fam = scale.plain.family(family)
    if objective == "cost":
        return scale, fam, scale.weights(*check_weights(weights, family.n_states, family.n_inputs)), None, None
    E, C, D = scale.channel(*check_channel(disturbance, output, family.n_modes, family.n_states, family.n_inputs))
    return scale, fam, None, E, (C, D)


def run(family, network, objective: str, *, weights=None, x0=None, disturbance=None, output=None,
        u_max=None, plant_switching: str = "per_interval", scaling: str = "auto", time_limit: float | None = None,
        callback=None, solver: str = "AUTO", fallback: bool = True) -> DesignResult:
    """A cost or l2-gain design on ``network`` with its certified bracket (docs/design.md §11.3).

    The SDP runs in balanced coordinates (``scaling="auto"``); the gains are mapped back and every reported figure
    is re-checked in the user's: the bracket (:func:`bracket`, the mapped node matrices as candidate, the fixed-gain
    SDP otherwise) and the stability certificate (:func:`network_lmi.recheck_network` of the bound's matrices, else
    the fixed-gain node analysis).  ``u_max`` (cost only): the Kothare form of :func:`solve`; the same node
    matrices ``W_v^-1``, mapped back, are re-checked as invariant ellipsoids whose inputs meet the limits
    (:func:`check_invariant_nodes`, x0's history inside) and land in ``res.invariant_set``.

    ``solver``: "AUTO" (the structured IPM, :func:`solve_ipm`; Clarabel as well when the IPM's answer does not
    pass the re-checks and ``fallback``, the better re-checked answer kept), "IPM" or "CLARABEL" alone.

    Returns
    -------
    DesignResult
        "stabilized" with a :class:`network_lmi.NodeCertificate` and ``performance`` (a :class:`NetworkPerformance`);
        "infeasible" with an unstable mode no input reaches (:func:`solver.certificates.uncontrollable_mode`);
        "not_certified" with a :class:`network_lmi.NetworkFarkasCertificate` when the network LMI that every
        solution of the performance SDP contains (its blocks' leading ``2k x 2k`` parts) is proven infeasible;
        "not_converged" otherwise (the reason in ``message``), also when the gains are certified but the input
        limits are not proven (gains and bracket kept, ``invariant_set`` None).
    """
    start = time.perf_counter()
    x0 = None if x0 is None else np.asarray(x0, float)
    u_max = None if u_max is None else np.asarray(u_max, float)
    kothare = objective == "cost" and u_max is not None
    ch_user = channels(family, network, objective, weights, disturbance, output, plant_switching)
    scale, fam, w_s, d_s, o_s = _scaled(family, objective, weights, disturbance, output, scaling)
    ch = ch_user if scale is None else channels(fam, network, objective, w_s, d_s, o_s, plant_switching)
    prob = ch_user.prob
    x0_s = x0 if scale is None else scale.x0(x0)
    u_s = None if not kothare else u_max if scale is None else scale.u_max(u_max)
    # the cvxpy form (:func:`solve`) runs on Clarabel whatever other conic solver is named
    order = list(dict.fromkeys(n if n == "IPM" else "CLARABEL" for n in network_lmi.solver_order(solver, fallback)))
    base = dict(method="network_lmi", n_drop=prob.N, solver=order[0], plant_switching=plant_switching,
                mode_labels=prob.labels)
    where = f"{network.describe()}; {prob.form} form, {len(prob.nodes)} node matrices, {prob.n_blocks} transitions"
    timings = {"total": 0.0, "solver": 0.0, "setup": 0.0, "solves": 0, "cached": False}
    unc = uncontrollable_mode(np.asarray(family.F, float), np.asarray(family.G, float), 1.0)
    if unc is not None:  # an unstable mode no input reaches: no gains at all, on any network
        timings["total"] = time.perf_counter() - start
        return DesignResult(outcome="infeasible", gains=None, certificate=unc, timings=timings, objective=objective,
                            **base, message=f"{unc.statement()}: no gains stabilize the loop on {where}, so no "
                                            f"{objective} bound exists")
    best, history, failures, status = None, [], [], ""
    for name in order:
        if best is not None and best["good"]:
            break
        if history and time_limit is not None and time.perf_counter() - start >= time_limit:
            failures.append(f"time limit reached ({time_limit:g} s) before {name}")
            break
        try:
            W, Y, Z, value, status, seconds = (solve_ipm if name == "IPM" else solve)(
                ch, objective, x0_s, time_left(time_limit, start, floor=1e-3), u_s)
            why = f"the network {objective} SDP gave no node matrices ({status})"
        except SolverFailed as err:
            W, status, seconds, value, why = None, str(err.status or err), 0.0, np.nan, str(err)
        timings["solver"] += seconds
        timings["solves"] += 1
        record = IterationRecord(len(history), value, None, False, None, seconds, time.perf_counter() - start)
        history.append(record)
        if callback is not None:
            callback(record)
        if W is None:
            failures.append(f"{name}: {why}")
            continue
        cand = _candidate(ch_user, prob, scale, objective, kothare, W, Y, Z, value, x0, u_max, time_limit, start,
                          ch=None if scale is None else ch)
        if cand is None:
            failures.append(f"{name}: its node matrices or slack are singular ({status})")
            continue
        cand.update(solver=name, status=status)
        record.theorem1 = cand["cert"] is not None
        record.certificate_margin = None if cand["cert"] is None else cand["cert"].margin
        if best is None or _rank(cand) > _rank(best):
            best = cand
        if not cand["good"]:
            failures.append(f"{name}: {_shortfall(cand, objective)}")
    timings["total"] = time.perf_counter() - start
    timings["setup"] = max(timings["total"] - timings["solver"], 0.0)
    via = "" if not failures or (best is not None and best["good"]) else " (" + "; ".join(failures) + ")"
    if best is None or best["cert"] is None or (kothare and best["inv"] is None):
        # the convex SDP certified nothing: the stability design (its CCL iteration on the exact node
        # conditions included) decides, its gains bracketed with their own fixed-gain node matrices
        plain = _stability_design(family, network, u_max if kothare else None, x0, plant_switching, scaling,
                                  solver, fallback, time_limit, start)
        timings["solver"] += plain.timings.get("solver", 0.0)
        timings["solves"] += plain.timings.get("solves", 0)
        timings["total"] = time.perf_counter() - start
        timings["setup"] = max(timings["total"] - timings["solver"], 0.0)
        history += plain.history
        why = "; ".join(failures) if failures else "no certified answer"
        if plain.outcome == "stabilized":
            def bracket_of(gains, stability_nodes=None):
                P0 = None if scale is None else _balanced_fixed_gain(ch, scale, gains, objective, x0_s,
                                                                     time_left(time_limit, start, floor=1e-3))
                perf = bracket(ch_user, gains, objective, P0=P0, x0=x0,
                               time_limit=time_left(time_limit, start, floor=1e-3))
                if not perf.verified and scale is not None:
                    perf = _balanced_bracket(ch, scale, gains, objective, None, x0,
                                             time_left(time_limit, start, floor=1e-3)) or perf
                if not perf.verified and stability_nodes is not None:
                    perf = _stability_bracket(ch, ch_user, scale, gains, objective, stability_nodes, x0,
                                              time_left(time_limit, start, floor=1e-3)) or perf
                return perf

            gains, cert = plain.gains, plain.certificate
            nodes = _user_nodes(plain, ch_user.prob)
            perf = bracket_of(gains, nodes)
            how = f"not optimized for the {objective}"
            if perf.verified and not kothare:
                if nodes is not None and scale is not None:
                    nodes = scale.plain.quadratic(nodes)
                refined = _refined(ch, ch_user, scale, gains, objective, x0_s, perf, bracket_of, time_limit, start,
                                   coordinates=nodes)
                timings["solves"] += refined["solves"]
                if refined["gains"] is not None:
                    gains, cert, perf = refined["gains"], refined["cert"], refined["perf"]
                how = refined["how"]
            timings["total"] = time.perf_counter() - start
            base.update(method=plain.method, solver=plain.solver)
            outcome = "stabilized" if perf.verified else "not_converged"  # not without the bracket asked for
            res = DesignResult(outcome=outcome, gains=gains, certificate=cert, history=history,
                               timings=timings, solver_status=plain.solver_status,
                               objective=objective, performance=perf,
                               spectral_radii=network_lmi.spectral_radii(prob.closed_loops(gains)), **base,
                               message=f"the network {objective} SDP certified nothing ({why}); the "
                                       f"{'input-limited ' if kothare else ''}stability design's gains instead, "
                                       f"bracketed with their fixed-gain node matrices ({how}): {plain.message}; "
                                       f"{perf.message}")
            res.invariant_set = plain.invariant_set if kothare else None
            return res
        if plain.outcome == "not_certified":
            if plain.certificate.kind == "farkas_network_limits":
                bound = plain.certificate.bound
                scope = "" if np.isinf(bound) else f" within ||Z||_F < {bound:.3g}"
                what = (f"with these limits solves that SDP (its blocks' leading 2k x 2k parts are the invariance "
                        f"blocks; the same input and x0 blocks), so no {objective} bound of this form exists"
                        f"{scope} on {where}")
            else:
                what = (f"solves that LMI (its blocks' leading 2k x 2k parts), so no {objective} bound of this form "
                        f"exists on {where}, and cone complementarity on the exact node conditions found no gains")
            return DesignResult(outcome="not_certified", gains=None, certificate=plain.certificate, history=history,
                                timings=timings, solver_status=plain.solver_status, objective=objective, **base,
                                message=f"{plain.certificate.statement()}; every solution of the network "
                                        f"{objective} SDP {what} ({why})")
        via = f" ({why}; the {'input-limited ' if kothare else ''}stability design: {plain.message})"
    if best is None:
        return DesignResult(outcome="not_converged", gains=None, certificate=None, history=history, timings=timings,
                            solver_status=status, objective=objective, **base,
                            message=f"the network {objective} SDP gave no gains on {where}{via}")
    base["solver"] = best["solver"]
    gains, perf, cert, inv = best["gains"], best["perf"], best["cert"], best["inv"]
    if cert is None:
        return DesignResult(outcome="not_converged", gains=gains, certificate=None, history=history, timings=timings,
                            solver_status=best["status"], objective=objective, performance=perf, **base,
                            message=f"the network {objective} SDP gave gains but no node certificate passed the "
                                    f"float64 re-check on {where}; {perf.message}{via}")
    if kothare and inv is None:  # as the single-network design: the limits unproven are not claimed
        return DesignResult(outcome="not_converged", gains=gains, certificate=cert, history=history,
                            timings=timings, solver_status=best["status"], objective=objective, performance=perf,
                            **base, message=f"stabilizing gains found on {where} but the input limits are not "
                                            f"proven: {best['inv_reason']}; {perf.message}{via}")
    if not perf.verified:  # "stabilized" only with the bracket the objective asked for
        return DesignResult(outcome="not_converged", gains=gains, certificate=cert, history=history,
                            timings=timings, solver_status=best["status"], objective=objective, performance=perf,
                            **base, message=f"stabilizing gains found on {where} (node certificate re-checked) but "
                                            f"no certified {objective} bound: {perf.message}{via}")
    limits = f"; {limits_note(inv, NODE_SETS)}" if kothare else ""
    res = DesignResult(outcome="stabilized", gains=gains, certificate=cert, history=history, timings=timings,
                       solver_status=best["status"], objective=objective, performance=perf,
                       spectral_radii=network_lmi.spectral_radii(prob.closed_loops(gains)), **base,
                       message=f"stabilized on {where} ({best['solver']}); node certificate re-checked (relative "
                               f"margin {cert.margin:.3g}){limits}; {perf.message}{via}")
    res.invariant_set = inv
    return res


def _candidate(ch_user: Channels, prob, scale, objective: str, kothare: bool, W, Y, Z, value, x0, u_max,
               time_limit, start, ch: Channels | None = None) -> dict | None:
    """One solver's answer mapped back and re-checked: gains, bracket, node certificate, invariant sets.

    ``ch``: the balanced channels (with ``scale``), where the bracket is made when the user's coordinates confirm
    none (:func:`_balanced_bracket`)."""
    try:
        gains = gains_from(prob, Y, Z)
        X = np.linalg.inv(W)  # the Kothare form's ellipsoids (P_v = gamma X_v); P_v = X_v otherwise
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(gains)) or not np.all(np.isfinite(X)):
        return None
    P0 = P0_balanced = value * X if kothare else X
    if scale is not None:
        gains = scale.plain.gains_back(gains)
        P0 = scale.quadratic_back(P0, objective)
        X = scale.quadratic_back(X)
    perf = bracket(ch_user, gains, objective, P0=P0, x0=x0, time_limit=time_left(time_limit, start, floor=1e-3))
    if not perf.verified and ch is not None:
        perf = _balanced_bracket(ch, scale, gains, objective, P0_balanced, x0, time_left(time_limit, start,
                                                                                          floor=1e-3)) or perf
    inv, inv_reason = None, ""
    if kothare:
        inv, inv_reason = check_invariant_nodes(X, prob, gains, u_max, ch_user.history, x0)
    cert = None
    if perf.verified and perf.certificate is not None:
        cert = network_lmi.recheck_network(prob, perf.certificate, gains, source=f"network_{objective}")
        cert = cert if cert.verified else None
    if cert is None:
        cert = network_lmi.node_analysis(prob, gains, None, time_left(time_limit, start, floor=1e-3))
    good = cert is not None and perf.verified and (not kothare or inv is not None)
    return dict(gains=gains, perf=perf, cert=cert, inv=inv, inv_reason=inv_reason, good=good)


def _balanced_fixed_gain(ch: Channels, scale, gains: np.ndarray, objective: str, x0_s, time_limit):
    """The fixed-gain node matrices of the user's ``gains`` found in balanced coordinates (``ch``: the balanced
    channels), mapped back: the candidate :func:`bracket` re-checks in the user's (None when there is none).
    Badly scaled plants (states from 1e-3 to 1e3) leave the fixed-gain SDP in the user's coordinates without an
    answer that passes the re-check; the balanced one has one (docs/design.md §11.3)."""
    t, u = scale.plain.state, scale.plain.input
    balanced = gains * t[None, None, :] / u[None, :, None]  # K~ = U^-1 K T
    weight = scale.trace_weight if objective == "cost" and x0_s is None else None
    P, _ = fixed_gain(ch, ch.numeric(balanced), objective, x0_s, time_limit, trace_weight=weight)
    return None if P is None else scale.quadratic_back(P, objective)


def _user_nodes(res: DesignResult, prob) -> np.ndarray | None:
    """The node matrices of a network stability design's certificate in the user's coordinates (exact: the
    balancing is by powers of two), when they are node matrices of ``prob``; else None."""
    P = getattr(res.certificate, "P", None)
    if res.certificate is None or not res.certificate.verified or P is None or np.ndim(P) != 3 \
            or P.shape[0] != len(prob.nodes) or P.shape[-1] != prob.k:
        return None
    if (res.scaling or {}).get("certificate") == "scaled":
        P = Scaling(np.asarray(res.scaling["state"]), np.asarray(res.scaling["input"])).quadratic_back(P)
    return np.asarray(P, dtype=float)


def _stability_bracket(ch: Channels, ch_user: Channels, scale, gains: np.ndarray, objective: str,
                       nodes: np.ndarray, x0, time_limit: float | None = None) -> NetworkPerformance | None:
    """The bracket of the stability design's gains made from its certificate's node matrices (``nodes``, the user's
    coordinates): the fixed-gain SDP posed in their coordinates (:func:`fixed_gain`, Clarabel solves it where it
    fails on the plain form: badly scaled families near the stability boundary) and a multiple of them
    (:func:`certify`, finite since they prove stability with a margin), the smaller certified bound.  Made in the
    user's coordinates, else in the balanced ones (``ch``, ``scale``)."""
    def least(ch_: Channels, K: np.ndarray, P_nodes: np.ndarray, x0_, weight):
        data = ch_.numeric(K)
        proposal, _ = fixed_gain(ch_, data, objective, x0_, time_limit, trace_weight=weight, coordinates=P_nodes)
        found = []
        for P0 in (proposal, P_nodes):
            if P0 is not None:
                P, upper, _ = certify(P0, ch_, data, objective, x0_, weight)
                if P is not None:
                    found.append((upper, P))
        return min(found, key=lambda c: c[0])[1] if found else None

    P = least(ch_user, gains, nodes, x0, None)
    if P is not None:
        return bracket(ch_user, gains, objective, P0=P, x0=x0, time_limit=0.0)
    if scale is None:
        return None
    t, u = scale.plain.state, scale.plain.input
    weight = scale.trace_weight if objective == "cost" and x0 is None else None
    P = least(ch, gains * t[None, None, :] / u[None, :, None], scale.plain.quadratic(nodes), scale.x0(x0), weight)
    return None if P is None else _balanced_bracket(ch, scale, gains, objective, P, x0, 0.0)


def _refined(ch: Channels, ch_user: Channels, scale, gains: np.ndarray, objective: str, x0_s, perf, bracket_of,
             time_limit, start, coordinates: np.ndarray | None = None) -> dict:
    """:func:`refine_gains` on the stability design's gains (in balanced coordinates when ``scale``), kept only when
    their bracket (``bracket_of``, the user's re-check) certifies a smaller bound and their node certificate
    passes (the bound's node matrices, else the fixed-gain node SDP)."""
    prob = ch_user.prob
    work = gains if scale is None else gains * scale.plain.state[None, None, :] / scale.plain.input[None, :, None]
    weight = scale.trace_weight if scale is not None and objective == "cost" and x0_s is None else None
    K, values = refine_gains(ch, work, objective, x0_s, time_left(time_limit, start, floor=1e-3),
                             trace_weight=weight, coordinates=coordinates)
    out = {"gains": None, "cert": None, "perf": None, "solves": 2 * len(values),
           "how": f"not optimized for the {objective}: the refinement found no better gains"}
    if K is work:
        return out
    K = K if scale is None else scale.plain.gains_back(K)
    mine = bracket_of(K)
    if not (mine.verified and mine.upper < perf.upper):
        return out
    cert = None if mine.certificate is None else \
        network_lmi.recheck_network(prob, mine.certificate, K, source=f"network_{objective}")
    if cert is None or not cert.verified:
        cert = network_lmi.node_analysis(prob, K, None, time_left(time_limit, start, floor=1e-3))
    if cert is None:
        return out
    what = "cost" if objective == "cost" else "l2 gain"
    out.update(gains=K, cert=cert, perf=mine,
               how=f"refined for the {objective} by {len(values)} rounds of fixed-gain and fixed-node SDPs: certified "
                   f"{what} {perf.upper:.6g} for the stability design's gains, {mine.upper:.6g} for these")
    return out


def _balanced_bracket(ch: Channels, scale, gains: np.ndarray, objective: str, P0, x0, time_limit):
    """The bracket of the user's ``gains`` made and re-checked in balanced coordinates (``ch``, ``scale``; ``P0``
    the balanced candidate or None), in the user's figures; None when it certifies nothing there either.

    The balanced data are the user's under an exact powers-of-two similarity, so the balanced re-check proves the
    same inequalities; it is the one that stands when the user's coordinates are too badly scaled to resolve the
    margin (relative eigenvalues of 1e-17 there; docs/design.md §11.3), as for the bounded-drops brackets
    (:func:`solver.brackets.bracket_back`)."""
    t, u = scale.plain.state, scale.plain.input
    balanced = gains * t[None, None, :] / u[None, :, None]  # K~ = U^-1 K T
    weight = scale.trace_weight if objective == "cost" and x0 is None else None
    perf = bracket(ch, balanced, objective, P0=P0, x0=scale.x0(x0), time_limit=time_limit, trace_weight=weight)
    if not perf.verified:
        return None
    k = scale.cost if objective == "cost" else scale.gain
    message = perf.message
    what = "cost" if objective == "cost" else "l2 gain"
    for phrase, v in ((f"{what} certified <= ", perf.upper), ("worst admissible run searched: ", perf.lower),
                      ("the node matrices alone: ", perf.certificate_upper)):
        if v is not None and np.isfinite(v):
            message = message.replace(f"{phrase}{v:.6g}", f"{phrase}{v * k:.6g}", 1)
    return NetworkPerformance(
        kind=perf.kind, upper=perf.upper * k, lower=None if perf.lower is None else perf.lower * k,
        witness=perf.witness, certificate=scale.quadratic_back(perf.certificate, objective), verified=True, x0=x0,
        patterns=perf.patterns, message=message + "; re-checked in balanced coordinates (powers-of-two scaling: the "
                                                  "same inequalities)",
        walk=perf.walk, form=perf.form, start_nodes=perf.start_nodes,
        certificate_upper=None if perf.certificate_upper is None else perf.certificate_upper * k,
        mode_certificate=scale.quadratic_back(perf.mode_certificate, objective), lead=perf.lead, memory=perf.memory)


def _rank(c: dict) -> tuple:
    """Order of candidates: re-checked first, then stabilizing, a certified bound, limits proven, the lower bound."""
    upper = c["perf"].upper if c["perf"].verified else np.inf
    return (c["good"], c["cert"] is not None, c["perf"].verified, c["inv"] is not None, -upper)


def _shortfall(c: dict, objective: str) -> str:
    """What a candidate's re-checks did not prove."""
    if c["cert"] is None:
        return "gains without a node certificate passing the float64 re-check"
    if not c["perf"].verified:
        return f"no certified {objective} bound ({c['perf'].message})"
    return f"input limits not proven ({c['inv_reason']})"


def _stability_design(family, network, u_max, x0, plant_switching: str, scaling: str, solver: str, fallback: bool,
                      time_limit, start) -> DesignResult:
    """The stability design on ``network`` (:func:`network_lmi.run_balanced`, cone complementarity included), or the
    input-limited one (:func:`run_limits`) with ``u_max``: the fallback of :func:`run` when its SDP certifies
    nothing.  Its "not_certified" is a re-checked Farkas certificate of the network LMI (section 11.1), which every
    solution of the performance SDPs solves at ``t = 0`` (each transition block's leading ``2k x 2k`` part)."""
    left = time_left(time_limit, start, floor=1e-3)
    if u_max is not None:
        return run_limits(family, network, u_max, x0=x0, plant_switching=plant_switching, scaling=scaling,
                          time_limit=left, solver=solver)
    return network_lmi.run_balanced(family, network, scaling=scaling, plant_switching=plant_switching,
                                    time_limit=left, solver=solver, fallback=fallback)


# ------------------------------------------------------------------------------------------- input limits


def gain_rows(prob) -> list[list[tuple[int, int]]]:
    """Per Lyapunov index v, the ``(j, b)`` pairs: gain ``K_(j+1)`` applied to slack/state block b from node v."""
    out = [set() for _ in prob.nodes]
    for e in range(prob.n_blocks):
        for j in range(prob.N):
            b = prob.right[e, j]
            if b >= 0 and np.any(prob.coef[e, j]):
                out[prob.src[e]].add((j, int(b)))
    return [sorted(s) for s in out]


def check_invariant_nodes(X: np.ndarray, prob, gains: np.ndarray, u_max: np.ndarray, history: np.ndarray,
                          x0=None, rate: float | None = None):
    """Node ellipsoids ``{xi : xi' (c X_v) xi <= 1}`` whose inputs meet the limits, re-checked in float64.

    Needs every ``X_v > 0`` and ``A_e' X_w A_e - rho_e X_v`` below minus the rounding allowance (``rho_e = 1``, or
    ``lambda^(2 length_e)``): a state in ``E_v`` at node v is in ``E_w`` at the next node w.  Every input applied
    from node v is ``K_j R_b xi`` (``R_b`` the state block the gain reads), whose largest value on ``E_v`` is
    ``sqrt(r X_v^-1 r') / sqrt(c)``; ``c`` makes the tightest of them ``u_max``.  x0 (its initial history ``S x0``)
    must lie in every node's set.  Returns ``(c X or None, reason)``; with every applied gain zero (no input ever
    moves) ``X = 0``, the whole state space.
    """
    X = _sym(np.asarray(X, float))
    if not np.any(gains):  # every input is zero from every state: the whole space, x' 0 x <= 1
        return np.zeros_like(X), ""
    if not np.all(np.isfinite(X)) or np.linalg.eigvalsh(X)[:, 0].min() <= 0:
        return None, "a node ellipsoid matrix is not positive definite"
    A = prob.closed_loops(gains)
    rho = np.ones(prob.n_blocks) if rate is None else float(rate) ** (2.0 * prob.length)
    for e in range(prob.n_blocks):
        APA = A[e].T @ X[prob.dst[e]] @ A[e]
        size = np.linalg.norm(APA, 2) + np.linalg.norm(X[prob.src[e]], 2)
        if np.linalg.eigvalsh(_sym(APA - rho[e] * X[prob.src[e]]))[-1] / size >= -_allowance(X.shape[-1]):
            return None, f"the node ellipsoids are not shown invariant on transition {e} (float64 re-check)"
    n, k = prob.n, prob.k
    need, applied = 0.0, False
    for v, pairs in enumerate(gain_rows(prob)):
        for j, b in pairs:
            applied = applied or bool(np.any(gains[j]))
            rows = np.zeros((prob.m, k))
            rows[:, b * n:(b + 1) * n] = gains[j]
            need = max(need, float(np.max(np.einsum("ij,ij->i", rows, np.linalg.solve(X[v], rows.T).T)
                                          / u_max**2)))
    if not applied:  # the gains that are not zero never act (no node applies them)
        return np.zeros_like(X), ""
    if not (np.isfinite(need) and need > 0):  # (u_max so large that its square overflows)
        return None, f"the input limits' scale is not a positive float64 ({need!r})"
    Xc = need * (1 + 1e-9) * X
    if x0 is not None:
        s = history @ x0
        level = max(float(s @ Xv @ s) for Xv in Xc)
        if level > 1:
            return None, f"x0 lies outside the certified node sets (max xi0' X_v xi0 = {level:.6g} > 1)"
    return Xc, ""


def _input_blocks(prob, Z, W, Y, u_max: np.ndarray) -> list:
    """``[[u_i^2, y], [y', Z + Z' - W_v]] >= 0`` for every node v, gain applied from it and input i (§11.3)."""
    n, m = prob.n, prob.m
    cons = []
    for v, pairs in enumerate(gain_rows(prob)):
        H = Z + Z.T - W[v]
        for j, b in pairs:
            for i in range(m):
                row = Y[j][i:i + 1, :]
                if prob.zblocks > 1:
                    row = cp.hstack([row if col == b else np.zeros((1, n)) for col in range(prob.zblocks)])
                # a hair inside the limit, so that x0 on the sets' boundary survives the re-check's rounding
                M = cp.bmat([[np.array([[(u_max[i] * (1 - LIMIT_SLACK)) ** 2]]), row], [row.T, H]])
                cons.append(0.5 * (M + M.T) >> 0)
    return cons


def solve_limits(prob, history: np.ndarray, u_max: np.ndarray, x0=None, rate: float | None = None,
                 time_limit: float | None = None):
    """``max tau`` s.t. the invariance blocks, the input blocks ``[[u^2, y], [y', Z + Z' - W_v]] >= 0``,
    ``tau I <= W_v <= radius^2 I`` and x0's history inside every ``W_v`` ellipsoid: ``(W, Y, Z, status, s)``."""
    n, m, k = prob.n, prob.m, prob.k
    Zb, Z, W, Y = network_lmi.cvx_variables(prob)
    tau = cp.Variable()
    c = (np.ones(prob.n_blocks) if rate is None else float(rate) ** (-prob.length.astype(float))) * (1 + STRICT)
    cons = []
    for e in range(prob.n_blocks):
        AZ = Rows(prob.free[e], prob.coef[e], prob.right[e]).times_z(Z, Y, n, prob.zblocks)
        M = cp.bmat([[Z + Z.T - W[prob.src[e]], c[e] * AZ.T], [c[e] * AZ, W[prob.dst[e]]]])
        cons.append(0.5 * (M + M.T) >> 0)
    cons += _input_blocks(prob, Z, W, Y, u_max)
    radius = MAX_RADIUS * (1.0 if x0 is None else max(1.0, float(np.linalg.norm(x0))))
    for Wv in W:
        cons += [Wv << radius**2 * np.eye(k), Wv >> tau * np.eye(k)]
        if x0 is not None:
            s = (history @ x0).reshape(-1, 1)
            cons.append(cp.bmat([[np.ones((1, 1)), s.T], [s, Wv]]) >> 0)
    problem = cp.Problem(cp.Maximize(tau), cons)
    elapsed = _solve_clarabel(problem, time_limit, "network input-limit SDP")
    if W[0].value is None or Zb[0].value is None or tau.value is None or not tau.value > 0:
        return None, None, None, str(problem.status), elapsed
    Wv = np.stack([0.5 * (w.value + w.value.T) for w in W])
    Yv = np.stack([np.zeros((m, n)) if y.value is None else y.value for y in Y])
    return Wv, Yv, np.stack([z.value for z in Zb]), str(problem.status), elapsed


def run_limits(family, network, u_max, *, x0=None, decay_rate: float | None = None,
               plant_switching: str = "per_interval", scaling: str = "auto", time_limit: float | None = None,
               callback=None, solver: str = "AUTO") -> DesignResult:
    """A design on ``network`` whose inputs meet ``u_max`` from node-dependent invariant ellipsoids (§11.3).

    Solved in balanced coordinates (:func:`solver.scaling.balance`, the plain part of the scaling layer); the
    gains and the node ellipsoids are mapped back and re-checked in the user's (:func:`check_invariant_nodes`,
    :func:`network_lmi.recheck_network`).  ``res.invariant_set`` holds the node matrices (V, k, k).  When
    nothing is certified and ``x0`` is given, a Farkas certificate of the SDP (its multipliers from ``solver``,
    "AUTO": the IPM, then Clarabel; re-checked on the user's problem by
    :func:`solver.network_limit_proofs.check_network_limits`) makes the outcome "not_certified".
    """
    from ..scaling import balance

    start = time.perf_counter()
    u_max = np.asarray(u_max, float)
    x0 = None if x0 is None else np.asarray(x0, float)
    prob = network_lmi.build_problem(family, network, plant_switching)
    history = initial_history(prob)
    scale = balance(family) if scaling == "auto" else None
    scale = None if scale is None or scale.is_identity else scale
    prob_s = prob if scale is None else network_lmi.build_problem(scale.family(family), network, plant_switching)
    base = dict(method="network_lmi", n_drop=prob.N, solver="CLARABEL", plant_switching=plant_switching,
                mode_labels=prob.labels)
    try:
        W, Y, Z, status, seconds = solve_limits(
            prob_s, history, u_max if scale is None else u_max / scale.input,
            x0 if (x0 is None or scale is None) else x0 / scale.state, decay_rate, time_limit)
    except SolverFailed as err:
        W, status, seconds = None, str(err), 0.0
    timings = {"total": 0.0, "solver": seconds, "setup": 0.0, "solves": 1, "cached": False}
    record = IterationRecord(0, float("nan"), None, False, None, seconds, time.perf_counter() - start)
    if callback is not None:
        callback(record)
    where = f"{network.describe()}; {prob.form} form, {len(prob.nodes)} node matrices, {prob.n_blocks} transitions"
    rate_txt = "" if decay_rate is None else f" at decay rate {decay_rate:.6g}"
    gains = inv = None
    reason = f"the network input-limit SDP gave no ellipsoids ({status})"
    if W is not None:
        try:
            gains = gains_from(prob_s, Y, Z)
            X = np.linalg.inv(W)
        except np.linalg.LinAlgError:
            gains = None
        if gains is not None and np.all(np.isfinite(gains)):
            if scale is not None:
                gains = scale.gains_back(gains)
                X = scale.quadratic_back(X)
            inv, reason = check_invariant_nodes(X, prob, gains, u_max, history, x0, decay_rate)
        else:
            gains = None
    cert = None
    if inv is not None:
        cert = network_lmi.recheck_network(prob, inv, gains, decay_rate, source="network_limits")
        if not cert.verified:
            cert = network_lmi.node_analysis(prob, gains, decay_rate, time_left(time_limit, start, floor=1e-3))
    timings["total"] = time.perf_counter() - start
    timings["setup"] = max(timings["total"] - seconds, 0.0)
    if cert is None:
        why = reason if inv is None else "no node certificate passed the float64 re-check"
        proof, proof_why = None, "no x0 (a small enough ellipsoid always meets the limits)"
        if x0 is not None:
            from ..network_limit_proofs import prove_network_limits

            proof_start = time.perf_counter()
            proof, proof_why = prove_network_limits(family, network, u_max, x0, decay_rate, STRICT, LIMIT_SLACK,
                                                    plant_switching, solver, time_left(time_limit, start, floor=1e-3))
            timings["solves"] += 1
            timings["total"] = time.perf_counter() - start
            timings["setup"] = max(timings["total"] - seconds - (time.perf_counter() - proof_start), 0.0)
            timings["solver"] = seconds + time.perf_counter() - proof_start
        if proof is not None:
            return DesignResult(outcome="not_certified", gains=None, certificate=proof, history=[record],
                                timings=timings, solver_status=status, objective="stability",
                                decay_rate=decay_rate, **{**base, "solver": proof.multipliers.solver},
                                message=f"{proof.statement()}, on {where} (multipliers from "
                                        f"{proof.multipliers.solver}; the design's SDP: {why})")
        why += f"; no Farkas certificate of the limits: {proof_why}"
        return DesignResult(outcome="not_converged", gains=None, certificate=None, history=[record], timings=timings,
                            solver_status=status, objective="stability", decay_rate=decay_rate, **base,
                            message=f"no input-limited design certified on {where}{rate_txt}: {why}")
    res = DesignResult(outcome="stabilized", gains=gains, certificate=cert, history=[record], timings=timings,
                       solver_status=status, objective="stability", decay_rate=decay_rate,
                       spectral_radii=network_lmi.spectral_radii(prob.closed_loops(gains)), **base,
                       message=f"stabilized on {where}{rate_txt}; node certificate re-checked (relative margin "
                               f"{cert.margin:.3g}); {limits_note(inv, NODE_SETS)}")
    res.invariant_set = inv
    return res
