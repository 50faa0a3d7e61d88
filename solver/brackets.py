"""Certified performance brackets: quadratic cost and l2 gain (H-infinity) under every allowed pattern.

A performance figure is a bracket (docs/design.md, "Performance brackets"):

* ``upper``: a common quadratic ``x' P x`` whose inequality on every lifted interval system
  (:mod:`solver.lifting`) passes a float64 re-check here, independent of the solver that proposed P::

      cost:  A_s' P A_s - P + S_s <= 0                                 (bound x0' P x0, or trace P)
      hinf:  [A_s B_s; C_s D_s]' diag(P, I) [A_s B_s; C_s D_s] - diag(P, gamma^2 I) <= 0

  For the cost, the prefix tree on that P (:func:`prefix_search`, :func:`tree_bound`) may prove a smaller bound,
  with a rigorous rounding allowance per node (docs/design.md §8.4, "Tree bound"), and so may one matrix per
  sequence of the next interval modes and the tree on those (§8.4, "Look-ahead"); the quadratic bound stays in
  ``certificate_upper``.

* ``lower``: the exact cost (periodic Lyapunov equation) or H-infinity norm (level-set iteration in float64, then
  the witness's gain at its peak frequency evaluated in exact arithmetic, :func:`exact_witness`: a proven lower
  bound) of the worst allowed periodic pattern searched, or of a prefix followed by one (the cost's prefix search;
  hinf: a charge and its release, :mod:`solver.transients`); ``witness`` is that run.
"""

from __future__ import annotations

import itertools
import time
import warnings
from dataclasses import dataclass, field
from fractions import Fraction
from typing import NamedTuple

import cvxpy as cp
import numpy as np
import scipy.linalg
import scipy.optimize

from .compiled import SolveInfo, out_of_time, time_left
from .errors import InvalidInput, SolverFailed
from .exact import floats, fractions
from .lifting import Lifted

#: Rounding allowance of the float64 re-checks, relative to the size of the terms (eigvalsh is backward
#: stable; forming A' P A costs a few n eps of the norms): ``max(64, 8 k) eps`` for a k x k inequality.
ROUND = 64 * np.finfo(float).eps


def _allowance(k: int) -> float:
    return max(ROUND, 8 * k * np.finfo(float).eps)
#: Periodic patterns searched for the lower bound: up to this many intervals per period at least (longer while
#: every pattern of the next length still fits in the count below, up to MAX_PATTERN_LENGTH) ...
PATTERN_LENGTH = 3
MAX_PATTERN_LENGTH = 16
#: ... and at most this many patterns (shorter periods first).
MAX_PATTERNS = 4000
#: ... (H-infinity: each pattern needs a frequency sweep of its lifted system)
MAX_PATTERNS_HINF = 500
#: Frequencies of the coarse H-infinity sweep on [0, pi] (refined around the best ones).
SWEEP = 97
#: The prefix search (cost; docs/design.md §8.4, "Prefix search"): nodes kept per depth ...
BEAM = 256
#: ... nodes valued in all (each an ``n x n`` congruence: the CPU time scales as ``NODE_BUDGET n^3``) ...
NODE_BUDGET = 60_000
#: ... and periodic tails valued from every node (the best periodic patterns found).
TAILS = 12
#: ... and this many one-interval periods, those whose cost-to-go is largest in its worst direction
#: (:func:`lower_bound`).
STEERED_TAILS = 6


def _sym(M):
    return 0.5 * (M + np.swapaxes(M, -1, -2))


@dataclass
class Performance:
    """A certified performance bracket.

    Attributes
    ----------
    kind : {"cost", "hinf"}
        ``cost``: worst-case ``J = sum_k x(k)' Q x(k) + u(k)' R u(k)`` (w = 0) from ``x0``, or its mean
        over initial states of covariance I (``x0`` None).  ``hinf``: worst-case l2 gain gamma from w
        to z with x(0) = 0.
    upper : float or None
        Certified upper bound (None when no certificate passed the re-check; ``message`` says why): for the cost
        the smaller of ``certificate_upper`` and the prefix tree's certified bound on the same P.
    lower : float or None
        The value of the worst allowed run searched (``inf`` when a periodic pattern is unstable): a periodic
        pattern's, or a prefix's followed by one (``lead``); for hinf exact, and with a prefix the charge-then-release
        witness (docs/design.md §8.4, "Transient witness").
    witness : list of tuple
        That run: ``(plant_mode, eta)`` per interval (``plant_mode`` a tuple of plant indices per sample under
        per-sample switching), its period from ``lead`` on.
    certificate : ndarray, shape (n, n), or None
        P (user coordinates) of the upper bound.
    verified : bool
        Whether ``upper`` is certified: ``certificate`` passed the float64 re-check (or the exact one on its float64
        numbers), or ``exact_certificate`` is set and passed its exact check; ``certificate`` is then possibly only
        that P's float64 rounding, which need not pass any re-check (the message says which, docs/design.md §8.5).
    gap : float or None
        ``max(0, (upper - lower) / upper)`` (0: closed to the witness's rounding).
    x0 : ndarray or None
    patterns : int
        Periodic patterns evaluated for the lower bound.
    message : str
    lead : int
        ``witness[:lead]`` runs once, then ``witness[lead:]`` repeats forever (0: the whole witness is the
        period, repeated from the start; a prefix comes from the prefix search, docs/design.md §8.4; hinf: the
        disturbance acts in the prefix only, the period releases at rest).
    certificate_upper : float or None
        The common quadratic certificate's own bound (``x0' P x0``, ``trace P`` or ``gamma``), what the design's
        SDP minimizes.  ``upper`` is the smaller of it and the prefix tree's certified bound (cost,
        docs/design.md §8.4, "Tree bound"); compare designs or solvers on this field.
    exact_certificate : list of list of Fraction, or None
        An exact rational certificate (n x n, user coordinates): one LTI loop (one mode, ``n_drop = 1``, n <= 8)
        whose float64 certificate cannot reach its cost; P solves ``P = A' P A + S`` exactly for the deployed
        loop ``A = F + G K``, ``S = Q + K' R K`` (the float64 F, G, K, Q, R taken as exact rationals), verified
        exactly, and ``certificate_upper`` is its bound rounded up (docs/design.md §8.5).  hinf: a rational P of
        the bounded-real inequality at ``upper^2`` (the game refinement's), checked exactly on the deployed loop.
        ``certificate`` then stays a float64 certificate (of a larger bound) when one passed, else it is this P's
        float64 rounding (the message says which).  JSON: strings ``"p/q"``.
    mode_certificate : ndarray, shape (S, n, n) or (S^L, n, n), or None
        hinf over several modes: one storage matrix ``P_s`` per loop mode (user coordinates) when they certify a
        smaller l2 gain than the common P (``upper`` is then their bound, ``certificate_upper`` the common one's):
        ``[A_s B_s; C_s D_s]' diag(P_t, I) [A_s B_s; C_s D_s] - diag(P_s, gamma^2 I) <= 0`` for every pair of
        consecutive modes s, t, re-checked in float64 (docs/design.md §8.4, "Mode-dependent storage").  The cost
        over several modes: one matrix ``P_q`` per sequence ``q = (s_1, ..., s_L)`` of the next L interval modes
        (lexicographic order), ``A_s1' P_q' A_s1 - P_q + S_s1 <= 0`` for ``q' = (s_2, ..., s_L, t)`` and every t,
        the bound the largest ``x0' P_q x0`` (``trace P_q``), when below the common P's (docs/design.md §8.4,
        "Look-ahead").  On a
        network (:class:`NetworkPerformance`), shape (count, k, k): for the cost one matrix per sequence of the next
        ``memory`` transitions, for the state just before it (:func:`solver.methods.network_performance.
        lookahead_lift`'s order); for the l2 gain one per sequence of the last ``memory`` transitions, for the state
        just after it (:func:`~solver.methods.network_performance.memory_lift`'s order): a path-dependent Lyapunov
        function, used when it bounds below the node matrices or they pass no re-check (``certificate`` may then be
        None; docs/design.md §11.3).
    """

    kind: str
    upper: float | None
    lower: float | None
    witness: list
    certificate: np.ndarray | None
    verified: bool
    gap: float | None = None
    x0: np.ndarray | None = None
    patterns: int = 0
    message: str = ""
    lead: int = 0
    certificate_upper: float | None = None
    exact_certificate: list | None = None
    mode_certificate: np.ndarray | None = None

    def __post_init__(self):
        if self.certificate_upper is None:
            self.certificate_upper = self.upper
        if self.gap is None and self.upper is not None and self.lower is not None and self.upper > 0:
            # >= 0: a witnessed value (float Lyapunov solves) may pass a closed certified end by rounding (bracket()
            # refuses both beyond 1e-6 relative)
            self.gap = max(0.0, float((self.upper - self.lower) / self.upper)) if np.isfinite(self.lower) else None

    def to_dict(self) -> dict:
        def num(v):
            return None if v is None or not np.isfinite(v) else float(v)

        return {
            "kind": self.kind,
            "upper": num(self.upper),
            "lower": num(self.lower),
            "lower_infinite": self.lower is not None and not np.isfinite(self.lower),
            "witness": [[list(p) if isinstance(p, tuple) else p, int(e)] for p, e in self.witness],
            "certificate": None if self.certificate is None else self.certificate.tolist(),
            "verified": self.verified,
            "gap": num(self.gap),
            "x0": None if self.x0 is None else self.x0.tolist(),
            "patterns": self.patterns,
            "message": self.message,
            "lead": int(self.lead),
            "certificate_upper": num(self.certificate_upper),
            "exact_certificate": None if self.exact_certificate is None else
            [[str(v) for v in row] for row in self.exact_certificate],
            "mode_certificate": None if self.mode_certificate is None else self.mode_certificate.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict) -> "Performance":
        """The inverse of :meth:`to_dict` (the service's JSON ``performance``): the client's results hold
        the same typed bracket as the library's."""
        if cls is Performance and data.get("start_nodes"):  # a network's bracket (docs/design.md §11.3)
            return NetworkPerformance.from_dict(data)
        lower = data.get("lower")
        if lower is None and data.get("lower_infinite"):
            lower = float("inf")
        cert = data.get("certificate")
        x0 = data.get("x0")
        witness = [(tuple(p) if isinstance(p, list) else p, int(e)) for p, e in data.get("witness") or []]
        return cls(kind=data["kind"], upper=data.get("upper"), lower=lower, witness=witness,
                   certificate=None if cert is None else np.array(cert, dtype=np.float64),
                   verified=bool(data.get("verified")), gap=data.get("gap"),
                   x0=None if x0 is None else np.array(x0, dtype=np.float64), patterns=int(data.get("patterns") or 0),
                   message=data.get("message") or "", lead=int(data.get("lead") or 0),
                   certificate_upper=data.get("certificate_upper"),
                   exact_certificate=None if data.get("exact_certificate") is None else
                   [[Fraction(v) for v in row] for row in data["exact_certificate"]],
                   mode_certificate=None if data.get("mode_certificate") is None else
                   np.array(data["mode_certificate"], dtype=np.float64))

    def __getitem__(self, key: str):
        """``perf["upper"]``: the JSON field (results used to hold the bracket as a dict)."""
        return self.to_dict()[key]


@dataclass
class NetworkPerformance(Performance):
    """A certified bracket on a network: ``certificate`` holds one P per node matrix (shape (V, k, k)).

    ``walk`` lists the witness's transitions (``from``/``to`` automaton nodes, plant, age or interval length):
    ``walk[:lead]`` taken once from a start node, then ``walk[lead:]`` repeated forever, is an admissible run whose
    value is ``lower``.  ``form`` as in :class:`solver.methods.network_lmi.NodeCertificate`; ``start_nodes``: the
    nodes the bound covers as starts.  ``memory``: 0 when ``upper`` is the node matrices' bound, else the number of
    transitions each matrix of ``mode_certificate`` is for: the next ones for the cost, the last ones for the l2 gain
    (docs/design.md §11.3, "Look-ahead" and "Memory of the last transitions").
    """

    walk: list = field(default_factory=list)
    form: str = "lifted"
    start_nodes: list = field(default_factory=list)
    memory: int = 0

    def to_dict(self) -> dict:
        out = super().to_dict()
        out.update({"walk": self.walk, "form": self.form, "start_nodes": [int(v) for v in self.start_nodes],
                    "memory": int(self.memory)})
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "NetworkPerformance":
        base = Performance.from_dict({k: v for k, v in data.items() if k not in ("start_nodes", "memory")})
        return cls(**{f: getattr(base, f) for f in Performance.__dataclass_fields__}, walk=list(data.get("walk") or []),
                   form=data.get("form") or "lifted", start_nodes=[int(v) for v in data.get("start_nodes") or []],
                   memory=int(data.get("memory") or 0))


def bracket_back(perf: Performance, scale, lifted: Lifted, gains: np.ndarray, x0: np.ndarray | None) -> Performance:
    """A bracket made in balanced coordinates (:class:`solver.scaling.PerformanceScaling`), in the user's.

    The cost scales by ``scale.cost`` (the l2 gain not at all), P maps by the congruence; the witness is the
    same pattern.  P is re-checked on the user's lifted data (``lifted``, ``gains``); when rounding there is too
    coarse to confirm it, the balanced re-check stands (exact powers-of-two similarity: the same inequality)
    and the message says so.
    """
    cost = perf.kind == "cost"
    k = scale.cost if cost else scale.gain
    P = scale.quadratic_back(perf.certificate, perf.kind)
    message = perf.message
    what = "cost" if cost else "l2 gain"
    for phrase, v in ((f"{what} certified <= ", perf.upper), ("worst periodic pattern searched: ", perf.lower),
                      ("the quadratic certificate alone: ", perf.certificate_upper)):
        if v is not None and np.isfinite(v):
            message = message.replace(f"{phrase}{v:.6g}", f"{phrase}{v * k:.6g}", 1)
    mode_P = scale.quadratic_back(perf.mode_certificate, perf.kind)
    if P is not None:
        data = lifted.numeric(gains)
        ok = check_cost(P, data)[0] if cost else check_hinf(P, (perf.certificate_upper * k)**2, data)[0]
        if mode_P is not None and cost:
            from .methods.network_performance import lookahead_check

            ok = ok and lookahead_check(data, mode_P)
        elif mode_P is not None:
            ok = ok and check_hinf(mode_P, (perf.upper * k)**2, mode_pairs(data))[0]
        message += "" if ok else "; P re-checked in balanced coordinates (powers-of-two scaling)"
    exact_P = None
    if perf.exact_certificate is not None:  # the same congruence, exactly (powers of two)
        inv = [Fraction(float(v)) for v in np.tile(1.0 / scale.plain.state, len(perf.exact_certificate) //
                                                       scale.plain.state.size)]
        factor = Fraction(float(scale.cost if cost else scale.output ** 2))  # as quadratic_back (powers of two)
        exact_P = [[v * inv[i] * inv[j] * factor for j, v in enumerate(row)]
                   for i, row in enumerate(perf.exact_certificate)]
    return Performance(kind=perf.kind, upper=None if perf.upper is None else perf.upper * k,
                       lower=None if perf.lower is None else perf.lower * k, witness=perf.witness, certificate=P,
                       verified=perf.verified, x0=x0, patterns=perf.patterns, message=message, lead=perf.lead,
                       certificate_upper=None if perf.certificate_upper is None else perf.certificate_upper * k,
                       exact_certificate=exact_P, mode_certificate=mode_P)


def check_x0(x0, n: int) -> np.ndarray | None:
    if x0 is None:
        return None
    try:
        x = np.array(x0, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidInput("x0 must be a list of n numbers", ("x0",)) from None
    if x.size != n or not np.all(np.isfinite(x)):
        raise InvalidInput(f"x0 must have {n} finite entries", ("x0",))
    return x


# ---------------------------------------------------------------------------------- re-checks
def _congruence_error(P: np.ndarray, X: np.ndarray, dX) -> float:
    """A bound of ``||X_true' P X_true - X' P X||_2`` for ``|X_true - X| <= dX`` entrywise (None: 0): the Frobenius
    norm of ``dX'|P|(|X| + dX) + (|X| + dX)'|P| dX``, rounded up (docs/design.md §8.4, "Loop data")."""
    if dX is None:
        return 0.0
    aP, aX = np.abs(P), np.abs(X) + dX
    E = dX.T @ aP @ aX
    k = 2 * P.shape[0] + 4
    return float(np.linalg.norm(E + E.T)) * (1 + 2 * k * np.finfo(float).eps)


def _data_error(P: np.ndarray, d: dict, cost: bool = True, P_next: np.ndarray | None = None) -> float:
    """A bound of the 2-norm of the difference between the re-checked inequality's matrix on the float64 loop data
    ``d`` and on the deployed loop (``d["dA"]`` etc. from :meth:`solver.lifting.Lifted.numeric`; 0 without them).
    ``cost``: ``A' P A - P + S``; else the bounded-real matrix of :func:`_brl`."""
    if d.get("dA") is None:
        return 0.0
    eps = np.finfo(float).eps
    if cost:
        dS = d.get("dS")
        e = _congruence_error(P, d["A"], d["dA"]) + (0.0 if dS is None else float(np.linalg.norm(dS)))
        return e * (1 + 4 * eps)
    n, k = d["A"].shape[0], d["B"].shape[1]
    dAB = np.hstack([d["dA"], np.zeros((n, k)) if d.get("dB") is None else d["dB"]])
    dCD = None if d.get("dC") is None else np.hstack([d["dC"], np.zeros_like(d["D"]) if d.get("dD") is None
                                                      else d["dD"]])
    AB = np.hstack([d["A"], d["B"]])
    e = _congruence_error(P if P_next is None else P_next, AB, dAB)
    if dCD is not None:
        e += _congruence_error(np.eye(d["C"].shape[0]), np.hstack([d["C"], d["D"]]), dCD)
    return e * (1 + 4 * eps)


#: A float64 matrix as exact Fractions (lists of rows), for the exact re-checks below.
frac = fractions


def mul(X: list, Y: list) -> list:
    """The exact product of two matrices of Fractions (lists of rows)."""
    return [[sum(X[i][k] * Y[k][j] for k in range(len(Y))) for j in range(len(Y[0]))] for i in range(len(X))]


#: Longest interval whose deployed loop :func:`_exact_loop` rebuilds in rationals: the Fractions' bits grow by about 53
#: per sample and the products' cost with them (the CTMS pendulum's cost design at n_drop = 20: 1.3 s of 1.4 s in
#: the exact re-check; 0.5 s without it); longer ones use the float64 data less their error bound.
EXACT_LOOP_MAX_SAMPLES = 8


def _exact_loop(d: dict):
    """The deployed interval loop of ``d`` in rationals, built from the float64 F, G, K (and Q, R, E, C_z, D_z) that
    :meth:`solver.lifting.Lifted.numeric` attached (``d["plant"]``): ``(A, S, AB, CD)`` as lists of Fractions
    (S None without weights, AB and CD None without a channel), or None without the plant data or for an interval
    longer than :data:`EXACT_LOOP_MAX_SAMPLES` (docs/design.md §8.4, "Loop data")."""
    pl = d.get("plant")
    if pl is None or len(pl["F"]) > EXACT_LOOP_MAX_SAMPLES:
        return None
    Fs, Gs, Ks = [frac(X) for X in pl["F"]], [frac(X) for X in pl["G"]], [frac(X) for X in pl["K"]]
    n = len(Fs[0])

    def add(X, Y):
        return [[a + b for a, b in zip(r, q)] for r, q in zip(X, Y)]

    def tr(X):
        return [list(col) for col in zip(*X)]

    M = [[frac(np.eye(1))[0][0] if i == j else frac(np.zeros((1, 1)))[0][0] for j in range(n)] for i in range(n)]
    Ms = []
    for Fl, Gl, Kt in zip(Fs, Gs, Ks):
        Ms.append(M)
        M = add(mul(Fl, M), mul(Gl, Kt))
    A, S, AB, CD = M, None, None, None
    if pl["Q"] is not None and d.get("S") is not None:
        Q, R = frac(pl["Q"]), frac(pl["R"])
        S = [[0 * Q[0][0]] * n for _ in range(n)]
        for Mt, Kt in zip(Ms, Ks):
            S = add(S, add(mul(mul(tr(Mt), Q), Mt), mul(mul(tr(Kt), R), Kt)))
    if pl["channel"] is not None and d.get("B") is not None:
        E, Cz, Dz = (list(X) for X in pl["channel"])
        eta, pw = len(Fs), E[0].shape[1]
        Es, Cs, Ds = [frac(X) for X in E], [frac(X) for X in Cz], [frac(X) for X in Dz]
        pz = len(Cs[0])
        xw = [[0 * A[0][0]] * (eta * pw) for _ in range(n)]  # effect of w(0 .. eta-1) on x(t), as in lift_modes
        Crows, Drows = [], []
        for t in range(eta):
            Crows += add(mul(Cs[t], Ms[t]), mul(Ds[t], Ks[t]))
            Drows += mul(Cs[t], xw)
            xw = mul(Fs[t], xw)
            for i in range(n):
                for j in range(pw):
                    xw[i][t * pw + j] += Es[t][i][j]
        AB = [A[i] + xw[i] for i in range(n)]
        CD = [Crows[i] + Drows[i] for i in range(eta * pz)]
    return A, S, AB, CD


def check_cost(P: np.ndarray, data: list[dict]) -> tuple[bool, float]:
    """Float64 re-check of ``P > 0`` and ``A_s' P A_s - P + S_s <= 0`` for all modes.

    Returns ``(passed, worst)``: ``worst`` is the largest eigenvalue of the inequality's left side
    relative to the size of its terms (on the float64 data: where it is negative but passing fails, the exact
    re-check decides); passing needs it plus the distance of the float64 loop data to the deployed loop's (``dA``,
    ``dS`` of :meth:`solver.lifting.Lifted.numeric`, relative to the same size: docs/design.md §8.4, "Loop data")
    below minus the rounding allowance (rounding cannot flip it).
    """
    P = _sym(P)
    if np.linalg.eigvalsh(P)[0] <= 0:
        return False, np.inf
    worst, passed = -np.inf, True
    for d in data:
        APA = d["A"].T @ P @ d["A"]
        # |A|'|P||A| bounds the rounding of forming A'P A (Higham, ch. 3), which ||A'P A|| need not
        absA = np.abs(d["A"])
        size = np.linalg.norm(absA.T @ np.abs(P) @ absA, 2) + np.linalg.norm(P, 2) + np.linalg.norm(d["S"], 2)
        value = np.linalg.eigvalsh(_sym(APA - P + d["S"]))[-1] / size
        worst = max(worst, value)
        passed = passed and value + _data_error(P, d) / size < -_allowance(P.shape[0])
    return bool(passed), float(worst)


def _psd_exact(M: list) -> bool:
    """Whether the symmetric rational matrix ``M`` (lists of Fractions) is positive semidefinite, exactly:
    symmetric elimination with diagonal pivots (a zero pivot needs a zero row)."""
    M = [row[:] for row in M]
    n = len(M)
    for k in range(n):
        d = M[k][k]
        if d < 0:
            return False
        if d == 0:
            if any(M[k][j] != 0 for j in range(k + 1, n)):
                return False
            continue
        for i in range(k + 1, n):
            f = M[i][k] / d
            for j in range(k + 1, n):
                M[i][j] -= f * M[k][j]
    return True


def recheck_tree_bound(data: list[dict], P: np.ndarray, bound: float, depth: int, x0: np.ndarray | None = None,
                       weight: np.ndarray | None = None):
    """Exact re-check of a cost bound at one depth of the prefix tree, independent of :func:`prefix_search`.

    In rational arithmetic on the float64 numbers (``fractions.Fraction``): ``P - A_s' P A_s - S_s`` is positive
    semidefinite for every mode (so every continuation of a prefix costs at most ``<P, Sigma>``), and every
    admissible sequence of ``depth`` intervals has ``c_depth + <P, Sigma_depth> <= bound`` (``Sigma_0 = x0 x0'``,
    ``diag(weight)`` or I).  Both together prove that no admissible sequence costs more than ``bound``
    (docs/design.md §8.4, "Tree bound").  Enumerates all ``S^depth`` sequences: small cases only.

    Returns
    -------
    (passed, worst) : (bool, Fraction or None)
        ``worst`` the exact largest ``c_depth + <P, Sigma_depth>`` (None when P's inequality fails).
    """
    from fractions import Fraction

    def tr(X):
        return [list(col) for col in zip(*X)]

    def inner(X, Y):
        return sum(X[i][j] * Y[i][j] for i in range(len(X)) for j in range(len(X)))

    n = np.asarray(P).shape[0]
    Pq = frac(P)
    Pq = [[(Pq[i][j] + Pq[j][i]) / 2 for j in range(n)] for i in range(n)]
    if not _psd_exact(Pq):  # without P >= 0, <P, Sigma_d> < 0 and a divergent sequence passes (A = 2, P = -1)
        return False, None
    modes = []
    for d in data:
        A, Sq = frac(d["A"]), frac(d["S"])
        Sq = [[(Sq[i][j] + Sq[j][i]) / 2 for j in range(n)] for i in range(n)]
        APA = mul(mul(tr(A), Pq), A)
        if not _psd_exact([[Pq[i][j] - APA[i][j] - Sq[i][j] for j in range(n)] for i in range(n)]):
            return False, None
        modes.append((A, tr(A), Sq))
    if x0 is not None:
        xq = [Fraction(float(v)) for v in np.asarray(x0, dtype=np.float64)]
        M = [[xq[i] * xq[j] for j in range(n)] for i in range(n)]
    else:
        w = np.ones(n) if weight is None else np.asarray(weight, dtype=np.float64)
        M = [[Fraction(float(w[i])) if i == j else Fraction(0) for j in range(n)] for i in range(n)]
    worst = None
    stack = [(0, Fraction(0), M)]
    while stack:
        k, c, Sig = stack.pop()
        if k == depth:
            value = c + inner(Pq, Sig)
            worst = value if worst is None or value > worst else worst
            continue
        for A, At, Sq in modes:
            stack.append((k + 1, c + inner(Sq, Sig), mul(mul(A, Sig), At)))
    return bool(worst <= Fraction(float(bound))), worst


#: Largest state dimension for which :func:`check_cost_exact` is tried when the float64 re-check cannot decide.
EXACT_COST_MAX_N = 8


def check_cost_exact(P: np.ndarray, data: list[dict]) -> bool:
    """Exact re-check of the cost certificate: ``P >= 0`` and ``P - A_s' P A_s - S_s >= 0`` for every mode.

    In rational arithmetic (``fractions.Fraction``) on the deployed loop, rebuilt from the float64 F, G, K, Q, R
    the data carry (``d["plant"]``, :meth:`solver.lifting.Lifted.numeric`); without them on the float64 data less
    the bound of their distance to it (docs/design.md §8.4, "Loop data").  So no rounding allowance: it decides
    where :func:`check_cost`'s relative allowance cannot, i.e. where the slack the certificate needs is tiny beside ``|P|`` in some direction (a
    nearly unreachable unstable mode: ``P`` spans 1e11, docs/design.md §8.5).  ``O(n^3)`` rational products
    per mode: small n only (:data:`EXACT_COST_MAX_N`).
    """
    from fractions import Fraction

    P = np.asarray(P, dtype=np.float64)
    if not np.all(np.isfinite(P)) or any(not np.all(np.isfinite(d["A"])) or not np.all(np.isfinite(d["S"]))
                                         for d in data):
        return False
    n = P.shape[0]

    Pq = frac(P)
    Pq = [[(Pq[i][j] + Pq[j][i]) / 2 for j in range(n)] for i in range(n)]
    if not _psd_exact(Pq):
        return False
    for d in data:
        A, Sq = frac(d["A"]), frac(d["S"])
        e = Fraction(_data_error(P, d))  # the deployed loop's distance (docs/design.md §8.4, "Loop data") ...
        exact = _exact_loop(d)
        if exact is not None and exact[1] is not None:  # ... or the deployed loop itself, in rationals
            A, Sq, e = exact[0], exact[1], Fraction(0)
        APA = mul(mul([list(col) for col in zip(*A)], Pq), A)
        if not _psd_exact([[Pq[i][j] - APA[i][j] - (Sq[i][j] + Sq[j][i]) / 2 - (e if i == j else 0)
                            for j in range(n)] for i in range(n)]):
            return False
    return True


def _lyapunov_once(A: np.ndarray, S: np.ndarray, method: str) -> np.ndarray | None:
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            P = scipy.linalg.solve_discrete_lyapunov(A.T, S, method=method)
    except (np.linalg.LinAlgError, ValueError):
        return None
    P = 0.5 * (P + P.T)
    return P if np.all(np.isfinite(P)) else None


def _semidefinite(P: np.ndarray) -> bool:
    """Positive semidefinite up to rounding: no eigenvalue below ``-n eps`` times the largest."""
    eig = np.linalg.eigvalsh(0.5 * (P + P.T))
    return bool(eig[-1] > 0 and eig[0] >= -P.shape[0] * np.finfo(float).eps * eig[-1])


def _lyapunov_residual(A: np.ndarray, P: np.ndarray, S: np.ndarray) -> float:
    """``||A' P A - P + S||_F`` relative to the size of its terms."""
    APA = A.T @ P @ A
    return float(np.linalg.norm(APA - P + S) / max(np.linalg.norm(APA) + np.linalg.norm(P) + np.linalg.norm(S), 1e-300))


#: :func:`lyapunov` keeps scipy's answer when its condition number is at most this (and its residual tiny).
LYAPUNOV_CONDITION = 1e6
#: :func:`lyapunov` tries scipy's Kronecker form beside the bilinear one up to this n (scipy's own switch is 10): an
#: ``n^2 x n^2`` solve, O(n^6) flops and n^4 memory (n = 60: ~1 s and 100 MB per call, in every Hewer step).
KRONECKER_MAX_N = 20


def lyapunov(A: np.ndarray, S: np.ndarray, hint: np.ndarray | None = None) -> np.ndarray:
    """``P = A' P A + S`` (n x n, A stable, S >= 0), solved in coordinates where the loop is a contraction.

    Far from normal loops (a nearly unreachable unstable mode needs gains ~1e5) make both of scipy's methods
    lose everything (the Kronecker form returned an indefinite P with a residual of 1e-10; the bilinear form
    is off by 1e-3): the equation is ill-conditioned in the user's coordinates.  With ``P = L L'`` and
    ``z = L' x`` the loop ``L' A L^-T`` is a contraction (``A' P A < P``), where the equation is well
    conditioned; so the answer is re-solved in the coordinates of a positive definite approximation (``hint``,
    else the better of scipy's two answers by residual), twice (docs/design.md §8.5).  Without one (S
    singular) the plain answer of least residual; ``LinAlgError`` when there is none.
    """
    best, n = None, A.shape[0]
    plain = _lyapunov_once(A, S, "direct" if n < 10 else "bilinear")  # scipy's own choice
    if hint is None and plain is not None:
        # the common case costs one solve: a well conditioned positive definite answer with a small residual
        eig = np.linalg.eigvalsh(plain)
        if eig[0] > 0 and eig[-1] <= LYAPUNOV_CONDITION * eig[0] and _lyapunov_residual(A, plain, S) <= 1e-13:
            return plain
    # scipy's two methods (the Kronecker form only while it is cheap, KRONECKER_MAX_N)
    plains = [plain, _lyapunov_once(A, S, "bilinear")] if n < 10 else \
        [_lyapunov_once(A, S, "direct"), plain] if n <= KRONECKER_MAX_N else [plain]
    firsts = ([hint] if hint is not None else []) + plains
    for P in firsts:
        if P is None:
            continue
        for step in range(3):  # the first candidate itself, then two re-solves in its coordinates
            try:
                L = np.linalg.cholesky(0.5 * (P + P.T))
            except np.linalg.LinAlgError:
                L = None
            # a semidefinite candidate competes too (cost rows that never see part of the state make the solution
            # singular: without it the hint itself was returned, and a witness took the certificate's value); an
            # indefinite one never does (scipy's answers on far from normal loops, residual 1e-10)
            if L is not None or _semidefinite(P):
                residual = _lyapunov_residual(A, P, S)
                if best is None or residual < best[0]:
                    best = (residual, P)
            if L is None or step == 2:  # (a third re-solve would never be looked at)
                break
            At = scipy.linalg.solve_triangular(L, A.T @ L, lower=True).T  # L' A L^-T
            St = scipy.linalg.solve_triangular(L, scipy.linalg.solve_triangular(L, S, lower=True).T, lower=True)
            Pt = _lyapunov_once(At, 0.5 * (St + St.T), "direct" if n < 10 else "bilinear")
            if Pt is None:
                break
            P = L @ Pt @ L.T
            P = 0.5 * (P + P.T)
    if best is None:  # no positive definite approximation (S singular): the plain answer of least residual
        for P in plains:
            if P is None:
                continue
            residual = _lyapunov_residual(A, P, S)
            if best is None or residual < best[0]:
                best = (residual, P)
    if best is None:
        raise np.linalg.LinAlgError("no Lyapunov solution")
    return best[1]


def _trace(P, weight):
    """``trace P`` or ``sum_i weight_i P_ii`` (a trace in other coordinates, :mod:`solver.scaling`)."""
    return float(np.trace(P)) if weight is None else float(np.sum(weight * np.diagonal(P)))


def _upper_value(P, weight, x0) -> float:
    """The certified bound of ``P``: ``trace P`` (weighted) or ``x0' P x0``, rounded upwards.

    The float64 sum of k products is within ``k eps`` of the sum of the absolute terms (Higham, Accuracy and
    Stability, §3.1), so that much is added: the reported number is never below the exact value of ``P``'s."""
    eps = np.finfo(float).eps
    if x0 is None:
        value = _trace(P, weight)
        terms = _trace(np.abs(P), None if weight is None else np.abs(weight))
        k = P.shape[0]
    else:
        value = float(x0 @ P @ x0)
        terms = float(np.abs(x0) @ np.abs(P) @ np.abs(x0))
        k = 2 * P.shape[0]
    return float(np.nextafter(value + 1.01 * (k + 1) * eps * terms, np.inf))


def certify_cost(P0: np.ndarray, data: list[dict], x0: np.ndarray | None, weight: np.ndarray | None = None):
    """Smallest multiple ``c P0`` that passes :func:`check_cost`, and its bound.

    ``c P0`` certifies when ``c (P0 - A' P0 A) >= S``: ``c`` is the largest generalized eigenvalue of
    ``(S_s, P0 - A_s' P0 A_s)`` (a shrink when P0 has slack, a small growth when the solver left it a
    hair infeasible); P0 itself is tried too.  A factor passes :func:`check_cost` or, for n up to
    :data:`EXACT_COST_MAX_N`, :func:`check_cost_exact`.  Returns ``(P or None, bound or None, reason)``
    (``reason`` names the exact re-check when that is what passed).
    """
    P0 = _sym(P0)
    c = 1.0
    try:
        c = max(float(scipy.linalg.eigh(_sym(d["S"]), _sym(P0 - d["A"].T @ P0 @ d["A"]), eigvals_only=True)[-1])
                for d in data)
        c = max(c, 1e-300)
    except (np.linalg.LinAlgError, ValueError):
        c = 1.0  # P0 - A'P0A not positive definite: only P0 itself can still pass
    worst = np.inf
    # Smallest factor first, P0 itself among them: c comes from a float64 eigenvalue problem that is off where P0
    # spans 1e9 and more (a nearly unreachable unstable mode), and a multiple adds slack only along
    # P0 - A'P0A, which is S where P0 is tight; where the float64 allowance cannot decide (n small), the exact
    # re-check does (docs/design.md §8.5: the Riccati refinement's P, lifted along itself, passes only there)
    factors = sorted([c * (1 + bump) for bump in (1e-12, 1e-10, 1e-8, 1e-6, 1e-4)] + [1.0])
    checks = {}
    # the float64 check first on the factors within 1e-8 of the smallest (a bound 1e-8 looser at most), then the
    # exact one where needed: its rational loops cost seconds at n = 8 with 50 modes (the float64 check
    # failing at 1 + 1e-12 once the loop data's distance to the deployed loop is in its allowance)
    for factor in factors:
        if factor <= factors[0] * (1 + 1e-8):
            checks[factor] = check_cost(factor * P0, data)
            if checks[factor][0]:
                return factor * P0, _upper_value(factor * P0, weight, x0), ""
    for factor in factors:
        P = factor * P0
        ok, worst_here = checks[factor] if factor in checks else check_cost(P, data)
        worst = min(worst, worst_here)  # the closest to passing, for the message
        if ok:
            return P, _upper_value(P, weight, x0), ""
        if (worst_here < 0 or factor == 1.0) and P0.shape[0] <= EXACT_COST_MAX_N and check_cost_exact(P, data):
            # (where float64 sees the inequality hold within its allowance, and for P0 itself: a caller's P lifted
            # on purpose, whose slack float64 may not even see)
            return P, _upper_value(P, weight, x0), "exact re-check of P"
    return None, None, ("no multiple of the solver's P passes the float64 re-check "
                        f"(worst relative eigenvalue {worst:.3g})")


def _brl(P, d, g, P_next=None):
    """The bounded-real matrix ``[A B; C D]' diag(P_next, I) [A B; C D] - diag(P, g I)`` (``P_next`` defaults to
    P; a network's transition v -> w has ``P = P_v``, ``P_next = P_w``)."""
    AB = np.hstack([d["A"], d["B"]])
    CD = np.hstack([d["C"], d["D"]])
    n, k = d["A"].shape[0], d["B"].shape[1]
    M = AB.T @ (P if P_next is None else P_next) @ AB + CD.T @ CD
    M[:n, :n] -= P
    M[n:, n:] -= g * np.eye(k)
    return _sym(M), AB, CD


def brl_level(pairs) -> float:
    """The smallest ``g = gamma^2`` at which every bounded-real matrix of ``pairs`` (``(P, P_next, d)``, see
    :func:`_brl`) is negative semidefinite given P (its Schur complement on the disturbance block).

    Raises ``np.linalg.LinAlgError`` when a state block ``A' P_next A - P + C'C`` is not negative definite.
    """
    g = 0.0
    for P, P_next, d in pairs:
        M, _, _ = _brl(P, d, 0.0, P_next)
        n = d["A"].shape[0]
        N11, N12, N22 = M[:n, :n], M[:n, n:], M[n:, n:]
        if np.linalg.eigvalsh(N11)[-1] >= 0:
            raise np.linalg.LinAlgError
        g = max(g, float(np.linalg.eigvalsh(_sym(N22 - N12.T @ np.linalg.solve(N11, N12)))[-1]))
    return g


def check_hinf(P: np.ndarray, g: float, data: list[dict]) -> tuple[bool, float]:
    """Float64 re-check of ``P > 0`` and the bounded-real inequality at ``gamma^2 = g`` for all modes.

    ``P`` (n, n), or one matrix per network node (V, k, k): each ``d`` of ``data`` then names its transition's
    ``src`` and ``dst`` nodes (docs/design.md §11.3)."""
    P = _sym(P)
    nodes = P if P.ndim == 3 else P[None]
    if not np.all(np.isfinite(nodes)) or np.linalg.eigvalsh(nodes)[:, 0].min() <= 0:
        return False, np.inf
    worst, passed = -np.inf, True
    allow = _allowance(P.shape[-1] + max(d["B"].shape[1] for d in data))
    for d in data:
        Pv, Pw = (nodes[d["src"]], nodes[d["dst"]]) if P.ndim == 3 else (P, P)
        M, AB, CD = _brl(Pv, d, g, Pw)
        size = np.linalg.norm(AB, 2) ** 2 * np.linalg.norm(Pw, 2) + np.linalg.norm(CD, 2) ** 2 \
            + np.linalg.norm(Pv, 2) + g
        value = np.linalg.eigvalsh(M)[-1] / size
        worst = max(worst, value)
        # (the deployed loop's distance, as in check_cost)
        passed = passed and value + _data_error(Pv, d, False, Pw) / size < -allow
    return bool(passed), float(worst)


def check_hinf_exact(P: np.ndarray, g: float, data: list[dict]) -> bool:
    """Exact re-check of the bounded-real certificate: ``P >= 0`` and
    ``[A B; C D]' diag(P, I) [A B; C D] - diag(P, g I) <= 0`` for every mode, in rational arithmetic on the deployed
    loop (as :func:`check_cost_exact`; one matrix P, small sizes): it decides where :func:`check_hinf`'s
    relative allowance cannot (P spanning 1e9 and more, docs/design.md §8.4).  ``P`` may be a list of Fractions (an
    exact rational certificate, checked on the deployed loop in rationals only)."""
    from fractions import Fraction

    rational = isinstance(P, list)  # an exact rational certificate (the game refinement's, §8.5)
    if rational:
        Pq = [[Fraction(v) for v in row] for row in P]
        n = len(Pq)
        if not np.isfinite(g) or any(len(row) != n for row in Pq):
            return False
    else:
        P = np.asarray(P, dtype=np.float64)
        if P.ndim != 2 or not np.all(np.isfinite(P)) or not np.isfinite(g):
            return False
        n = P.shape[0]
        Pq = frac(P)
    Pq = [[(Pq[i][j] + Pq[j][i]) / 2 for j in range(n)] for i in range(n)]
    if not _psd_exact(Pq):
        return False
    gq = Fraction(float(g))
    for d in data:
        exact = _exact_loop(d)
        if exact is not None and exact[2] is not None:  # the deployed loop itself, in rationals ...
            AB, CD, e = exact[2], exact[3], Fraction(0)
        elif rational:
            return False  # (no float64 P to size the loop data's distance with)
        else:  # ... or the float64 data less their distance from it (docs/design.md §8.4, "Loop data")
            AB, CD = frac(np.hstack([d["A"], d["B"]])), frac(np.hstack([d["C"], d["D"]]))
            e = Fraction(_data_error(P, d, False))
        k = len(AB[0]) - n
        ABt, CDt = [list(col) for col in zip(*AB)], [list(col) for col in zip(*CD)]
        M = mul(mul(ABt, Pq), AB)
        CC = mul(CDt, CD)
        neg = [[-(M[i][j] + CC[i][j]) + (Pq[i][j] if i < n and j < n else 0) + (gq if i == j and i >= n else 0)
                - (e if i == j else 0) for j in range(n + k)] for i in range(n + k)]
        if not _psd_exact(neg):
            return False
    return True


def certify_hinf(P0: np.ndarray, data: list[dict], level: float | None = None):
    """Smallest ``gamma`` that ``c P0`` (c near 1) certifies, re-checked by :func:`check_hinf`.

    For fixed P the smallest ``g = gamma^2`` is ``max_s lambda_max(N22 - N21 N11^{-1} N12)`` of the
    bounded-real matrix at g = 0 (needs ``N11 < 0``).  ``P0`` one matrix, or one per network node (V, k, k),
    each ``data`` entry then naming its ``src`` and ``dst`` node.  ``level``: the gamma P0 was made for (a
    Riccati solution), used for P0 itself when float64 cannot form that Schur complement (N11 not negative
    definite to float64: P spanning 1e12 and more) and the exact re-check decides (docs/design.md §8.5).
    Returns ``(P or None, gamma or None, reason)``.
    """
    P0 = _sym(np.asarray(P0, dtype=np.float64))
    if not np.all(np.isfinite(P0)):
        return None, None, "the solver's matrices are not finite"
    nodes = P0.ndim == 3
    best = (None, None)
    reason = "the state block A'PA - P + C'C of the solver's P is not negative definite"
    for c in (1.0, 1 + 1e-8, 1 + 1e-6, 1 + 1e-5, 1 + 1e-4, 1 + 1e-3, 1 + 1e-2):
        P = c * P0
        try:
            g = brl_level(((P[d["src"]], P[d["dst"]], d) if nodes else (P, None, d)) for d in data)
        except np.linalg.LinAlgError:
            if level is None or c != 1.0 or nodes or P.shape[0] > EXACT_COST_MAX_N:
                continue
            g = float(level) ** 2  # the Riccati solution's own level, for the exact re-check below
        for bump in (1e-10, 1e-8, 1e-6):
            gb = max(g, 0.0) * (1 + bump) + bump * float(np.max(np.linalg.norm(P, 2, axis=(-2, -1)))) * 1e-3 + 1e-300
            ok, worst = check_hinf(P, gb, data)
            exact = False
            if not ok and (worst < 0 or (c == 1.0 and bump == 1e-10)) and not nodes and \
                    P.shape[0] <= EXACT_COST_MAX_N and \
                    max(d["B"].shape[1] + d["C"].shape[0] for d in data) <= 4 * EXACT_COST_MAX_N:
                ok = exact = check_hinf_exact(P, gb, data)  # the float64 allowance cannot decide (§8.4): exactly
            if ok:
                if best[1] is None or np.sqrt(gb) < best[1]:
                    best = (P, float(np.nextafter(np.sqrt(gb), np.inf)))  # sqrt rounds to nearest: never below
                    how = "exact re-check of P" if exact else ""
                break
            reason = f"the bounded-real re-check fails (worst relative eigenvalue {worst:.3g})"
        if best[0] is not None and c > 1:
            break
    if best[0] is None:
        return None, None, reason
    return best[0], best[1], how


def bounded_real_riccati(d: dict, gamma: float, lift: np.ndarray | None = None) -> np.ndarray | None:
    """The stabilizing solution of the bounded-real Riccati equation of one LTI loop at level ``gamma``:
    ``X = A'XA + C'C + (A'XB + C'D)(g I - D'D - B'XB)^{-1}(B'XA + D'C)``, ``g = gamma^2`` (None when scipy
    finds none).  For ``gamma`` above the loop's l2 gain it is the least P of the bounded-real inequality, so
    ``gamma (1 + delta)`` gives a certificate within ``delta`` of the gain (docs/design.md §8.5).  ``lift`` (n, n)
    is added to ``C'C`` (slack in the state block)."""
    A, B, C, D = d["A"], d["B"], d["C"], d["D"]
    Q = C.T @ C if lift is None else C.T @ C + _sym(lift)
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            X = scipy.linalg.solve_discrete_are(A, B, Q, D.T @ D - gamma ** 2 * np.eye(B.shape[1]), s=C.T @ D)
    except (np.linalg.LinAlgError, ValueError):
        return None
    X = _sym(X)
    return X if np.all(np.isfinite(X)) and np.linalg.eigvalsh(X)[0] > 0 else None


def check_invariant(X: np.ndarray, A: np.ndarray, gains: np.ndarray, u_max: np.ndarray,
                    x0: np.ndarray | None = None, plant: tuple | None = None):
    """Largest ``{x : x' (c X) x <= 1}`` in which every buffered input meets the limits, re-checked.

    Needs ``A_s' X A_s - X <= 0`` for every mode (float64, rounding-safe with the allowance sized by
    ``|A_s|' |X| |A_s|``; where that cannot decide, n <= :data:`EXACT_COST_MAX_N` and ``plant = (F, G, plants)``
    (a :class:`solver.network.ModeSet`'s) is given, in exact arithmetic on the returned matrix and the loops rebuilt
    exactly from F, G and ``gains``, :func:`solver.exact.closed_loop`: the float64 ``A`` is their rounding, and a
    margin float64 cannot see is one that rounding can flip, docs/design.md §8.5): then the set is invariant at
    packet times and every input ``K_q x(i_m)`` has ``|(K_q)_j x| <= sqrt((K_q)_j X^{-1} (K_q)_j') / sqrt(c)``.
    ``c`` is chosen so that this is ``u_max[j]`` for the tightest row.  Returns ``(c X or None, reason)``; with
    every gain zero (no input ever moves) ``X = 0``, the whole state space.
    """
    X = _sym(X)
    if not np.any(gains):  # every input is zero from every state: the whole space, x' 0 x <= 1
        return np.zeros_like(X), ""
    eigX = np.linalg.eigvalsh(X)
    if eigX[0] <= 0:
        return None, "the candidate ellipsoid matrix is not positive definite"
    undecided = []  # modes float64 cannot decide: re-checked in exact arithmetic on the final matrix (small n)
    for s, As in enumerate(A):
        APA = As.T @ X @ As
        # the product's rounding is relative to |A|'|X||A|, not to A'XA (far-from-normal loops: 1e6 apart)
        absA = np.abs(As)
        size = np.linalg.norm(absA.T @ np.abs(X) @ absA, 2) + eigX[-1]
        if np.linalg.eigvalsh(_sym(APA - X))[-1] / size >= -_allowance(X.shape[0]):
            if X.shape[0] > EXACT_COST_MAX_N or plant is None:
                return None, f"the ellipsoid is not shown invariant for mode {s} (float64 re-check)"
            undecided.append(s)
    rows = gains.reshape(-1, gains.shape[-1])  # every (K_q)_j
    lim = np.tile(np.asarray(u_max, dtype=float), gains.shape[0])
    need = np.einsum("ij,ij->i", rows, np.linalg.solve(X, rows.T).T) / lim**2
    c = float(np.max(need)) * (1 + 1e-12)
    if not (np.isfinite(c) and c > 0):  # (u_max so large that its square overflows)
        return None, f"the input limits' scale is not a positive float64 ({c!r})"
    Xc = c * X
    if np.max(np.einsum("ij,ij->i", rows, np.linalg.solve(Xc, rows.T).T) / lim**2) > 1:
        Xc = c * (1 + 1e-9) * X  # rounding of the solve
    if undecided and not _invariant_exact(Xc, plant, gains, undecided):
        return None, f"the ellipsoid is not shown invariant for mode {undecided[0]} (float64 and exact re-checks)"
    if x0 is not None and x0 @ Xc @ x0 > 1:
        return None, f"x0 lies outside the certified set (x0' X x0 = {x0 @ Xc @ x0:.6g} > 1)"
    return Xc, ""


def limits_note(invariant: np.ndarray, where: str) -> str:
    """What a re-checked input-limit set (:func:`check_invariant`, ``check_invariant_nodes``) proves, for a message:
    ``X = 0`` (every applied gain zero) holds from every state, any other set from every state of ``where``."""
    if not np.any(invariant):
        return "every applied gain is zero, so every input is zero: within u_max from every state"
    return f"inputs within u_max from every state of {where}"


def _invariant_exact(X: np.ndarray, plant: tuple, gains: np.ndarray, modes: list) -> bool:
    """Exactly ``X - A_s' X A_s >= 0`` for the modes ``modes``, ``A_s`` rebuilt exactly from ``plant = (F, G,
    plants)`` and ``gains`` (:func:`solver.exact.closed_loop`), ``X`` (n x n float64, symmetrized exactly)."""
    from .exact import closed_loop

    F, G, plants = plant
    n = X.shape[0]
    Xq = [[Fraction(float(v)) for v in row] for row in X]
    Xq = [[(Xq[i][j] + Xq[j][i]) / 2 for j in range(n)] for i in range(n)]
    for s in modes:
        Mi, e = closed_loop(F, G, gains, plants[s])
        Aq = [[Fraction(int(Mi[i, j]), 1 << e) for j in range(n)] for i in range(n)]
        XA = [[sum(Xq[i][k] * Aq[k][j] for k in range(n)) for j in range(n)] for i in range(n)]
        if not _psd_exact([[Xq[i][j] - sum(Aq[k][i] * XA[k][j] for k in range(n)) for j in range(n)]
                           for i in range(n)]):
            return False
    return True


# --------------------------------------------------------------- fixed-gain upper bounds (analyze)
def solve_sdp(prob: cp.Problem, solver: str, time_limit: float | None = None) -> SolveInfo:
    """Solve a performance SDP with Clarabel (``"SCS"`` when asked) at tight tolerances.

    The LQR reproduction (gains to 1e-6) needs tolerances tighter than Clarabel's defaults; when the solver
    stalls there (exponential cones of ``log det``), the defaults are tried once more.  Whatever comes out is
    only a proposal for the float64 re-checks.
    """
    name = "SCS" if str(solver).upper() == "SCS" else "CLARABEL"
    if name == "SCS":
        attempts = [dict(eps_abs=1e-9, eps_rel=1e-9, max_iters=200_000)]
        limit_key = "time_limit_secs"
    else:
        attempts = [dict(tol_gap_abs=1e-11, tol_gap_rel=1e-11, tol_feas=1e-11, tol_ktratio=1e-9, max_iter=500),
                    dict()]
        limit_key = "time_limit"
    start = time.perf_counter()
    for i, opts in enumerate(attempts):
        if time_limit is not None:
            opts[limit_key] = time_left(float(time_limit), start, floor=1e-3)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                prob.solve(solver=getattr(cp, name), **opts)
        except cp.error.SolverError as err:
            if i + 1 < len(attempts):
                continue
            raise SolverFailed(f"{name} failed: {err}", status="solver_error") from err
        if prob.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE, cp.INFEASIBLE) or i + 1 == len(attempts):
            break
    stats = prob.solver_stats
    value = prob.value
    return SolveInfo(status=prob.status, solver=name,
                     solve_time=float(stats.solve_time) if stats and stats.solve_time is not None else float("nan"),
                     wall_time=time.perf_counter() - start,
                     objective=float(value) if value is not None and np.isfinite(value) else float("nan"),
                     iterations=stats.num_iters if stats else None)


def fixed_gain_cost(data: list[dict], x0: np.ndarray | None, solver: str = "AUTO", weight=None):
    """Upper bound for given gains: ``min trace P`` (or ``x0' P x0``) s.t. the cost inequality, re-checked."""
    n = data[0]["A"].shape[0]
    P = cp.Variable((n, n), symmetric=True)
    cons = [P - d["A"].T @ P @ d["A"] - d["S"] >> 0 for d in data]
    obj = (cp.trace(P) if weight is None else cp.sum(cp.multiply(weight, cp.diag(P)))) if x0 is None else x0 @ P @ x0
    status = solve_sdp(cp.Problem(cp.Minimize(obj), cons + [P >> 0]), solver).status
    if P.value is None or status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        return None, None, f"the fixed-gain cost LMI ended with status {status!r} (no common quadratic bound)"
    return certify_cost(P.value, data, x0, weight)


def _brl_lmi(P, d: dict, g, P_next=None):
    """The bounded-real inequality of mode ``d`` as a cvxpy constraint: ``diag(P, g I) - [A B; C D]' diag(P_next, I)
    [A B; C D] >= 0`` (``P_next`` defaults to P; the SDP form of :func:`_brl`)."""
    A, B, C, D = d["A"], d["B"], d["C"], d["D"]
    Pn = P if P_next is None else P_next
    top = P - A.T @ Pn @ A - C.T @ C
    off = -(A.T @ Pn @ B + C.T @ D)
    return cp.bmat([[top, off], [off.T, g * np.eye(B.shape[1]) - B.T @ Pn @ B - D.T @ D]]) >> 0


def fixed_gain_hinf(data: list[dict], solver: str = "AUTO"):
    """Upper bound for given gains: ``min gamma^2`` s.t. the bounded-real inequality on every mode, re-checked."""
    n = data[0]["A"].shape[0]
    P = cp.Variable((n, n), symmetric=True)
    g = cp.Variable()
    cons = [P >> 0] + [_brl_lmi(P, d, g) for d in data]
    status = solve_sdp(cp.Problem(cp.Minimize(g), cons), solver).status
    if P.value is None or status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        return None, None, f"the fixed-gain bounded-real LMI ended with status {status!r} (no common quadratic bound)"
    return certify_hinf(P.value, data)


#: Loop modes at most for the mode-dependent storage of the l2-gain bound (S^2 bounded-real blocks).
MODE_STORAGE_MAX_MODES = 16
#: Relative gap of the bracket above which the mode-dependent storage is tried.
MODE_STORAGE_GAP = 1e-3


def mode_pairs(data: list[dict]) -> list[dict]:
    """Every pair of consecutive loop modes as a transition ``s -> t`` (``src``, ``dst``) carrying mode s's data: any
    mode may follow any (docs/design.md §2), so these are all the steps a storage ``x' P_s x`` has to decrease over."""
    return [dict(d, src=s, dst=t) for s, d in enumerate(data) for t in range(len(data))]


def mode_storage_hinf(data: list[dict], solver: str = "AUTO"):
    """Upper bound for given gains from one storage matrix per loop mode: ``min gamma^2`` s.t.
    ``[A_s B_s; C_s D_s]' diag(P_t, I) [A_s B_s; C_s D_s] <= diag(P_s, gamma^2 I)`` for all modes s, t, ``P_s >= 0``.

    Summed along any mode sequence from ``x(0) = 0`` this gives ``sum |z|^2 <= gamma^2 sum |w|^2`` as the common P
    does, with more freedom: never larger than the common bound (docs/design.md §8.4, "Mode-dependent storage").
    The solver's answer is only a proposal: :func:`certify_hinf` re-checks it on :func:`mode_pairs`.
    Returns ``(P (S, n, n) or None, gamma or None, reason)``.
    """
    S, n = len(data), data[0]["A"].shape[0]
    P = [cp.Variable((n, n), symmetric=True) for _ in range(S)]
    g = cp.Variable()
    cons = [Ps >> 0 for Ps in P]
    cons += [_brl_lmi(P[s], d, g, P[t]) for s, d in enumerate(data) for t in range(S)]
    status = solve_sdp(cp.Problem(cp.Minimize(g), cons), solver).status
    if any(Ps.value is None for Ps in P) or status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        return None, None, f"the mode-dependent bounded-real LMI ended with status {status!r}"
    return certify_hinf(np.array([Ps.value for Ps in P]), mode_pairs(data))


# ------------------------------------------------------------------------- periodic lower bounds
def patterns(n_modes: int, max_length: int = PATTERN_LENGTH, max_count: int = MAX_PATTERNS,
             rotations: bool = True):
    """Periodic mode sequences that are not repetitions of a shorter one, shortest first.

    ``rotations=False`` keeps one sequence per rotation class (the H-infinity norm of a periodic
    system does not depend on the phase it is lifted at; a cost from x0 does).
    """
    out = []
    for k in range(1, max_length + 1):
        for seq in itertools.product(range(n_modes), repeat=k):
            if not rotations and seq != min(seq[i:] + seq[:i] for i in range(k)):
                continue
            if any(k % d == 0 and seq == seq[:d] * (k // d) for d in range(1, k)):
                continue
            out.append(seq)
            if len(out) >= max_count:
                return out
    return out


def period_system(data: list[dict], seq) -> dict:
    """The lifted LTI system of one period of the pattern ``seq`` (mode indices in the order applied).

    ``Phi`` maps x at the period's start to x at its end; ``L`` stacks the cost rows (``S = L' L``);
    ``B``, ``C``, ``D`` the disturbance channel over the period (when present).
    """
    first = data[seq[0]]
    n = first["A"].shape[0]
    T = np.eye(n)  # state at the current interval's start, from x at the period's start
    has_w = first["B"] is not None
    has_cost = first["L"] is not None
    Ls, Cs, Ds_rows = [], [], []
    Tw = None
    widths = [data[s]["B"].shape[1] for s in seq] if has_w else []
    total_w = sum(widths)
    if has_w:
        Tw = np.zeros((n, total_w))
    col = 0
    for i, s in enumerate(seq):
        d = data[s]
        if has_cost:
            Ls.append(d["L"] @ T)
        if has_w:
            C_rows = d["C"] @ T
            D_rows = d["C"] @ Tw
            D_rows[:, col:col + widths[i]] += d["D"]
            Cs.append(C_rows)
            Ds_rows.append(D_rows)
            Tw = d["A"] @ Tw
            Tw[:, col:col + widths[i]] += d["B"]
            col += widths[i]
        T = d["A"] @ T
    return {
        "Phi": T,
        "L": np.vstack(Ls) if has_cost else None,
        "B": Tw,
        "C": np.vstack(Cs) if has_w else None,
        "D": np.vstack(Ds_rows) if has_w else None,
    }


def _sigma_max(sys: dict, omega: np.ndarray) -> np.ndarray:
    """Largest singular value of ``D + C (e^{j w} I - Phi)^{-1} B`` at each frequency."""
    n = sys["Phi"].shape[0]
    z = np.exp(1j * np.atleast_1d(omega))
    M = z[:, None, None] * np.eye(n)[None] - sys["Phi"][None]
    H = sys["D"][None] + sys["C"][None] @ np.linalg.solve(M, np.broadcast_to(sys["B"], (z.size,) + sys["B"].shape))
    return np.linalg.svd(H, compute_uv=False)[:, 0]


def hinf_norm_lower(sys: dict, points: int = SWEEP, refine: bool = True, frequency: bool = False):
    """A lower bound on the H-infinity norm of a stable discrete LTI system: the largest gain found by
    a frequency sweep on [0, pi] and at the angles of the poles, refined (bounded scalar search) around its best
    points and around every pole angle (a lightly damped pole's peak is within a few ``1 - |pole|`` of it:
    the CTMS bus suspension's closed loop peaks at 0.0525 rad/sample, a pole of radius 0.9989, between two
    points of the sweep, which found 15 % of the norm).  ``frequency``: ``(bound, w)``, w (rad/sample) where the
    bound was evaluated."""
    poles = np.linalg.eigvals(sys["Phi"])
    angles = np.abs(np.angle(poles))
    omega = np.unique(np.concatenate([np.linspace(0.0, np.pi, points), angles]))
    gains = _sigma_max(sys, omega)
    best, where = float(np.max(gains)), float(omega[int(np.argmax(gains))])
    if not refine:
        return (best, where) if frequency else best
    spans = [(omega[max(i - 1, 0)], omega[min(i + 1, omega.size - 1)]) for i in np.argsort(gains)[-3:]]
    spacing = np.pi / max(points - 1, 1)
    for theta, radius in zip(angles, np.abs(poles)):
        width = 4.0 * max(1.0 - radius, 0.0) + 1e-9
        if width > PEAK_SPANS * spacing:
            # a peak this wide is sampled by the sweep (it sits on a point or its neighbours, and the best three
            # points are refined above): n = 12, hinf, 60 -> 14 scalar searches, the same bound to 1e-12
            continue
        spans.append((max(theta - width, 0.0), min(theta + width, np.pi)))
    for lo, hi in spans:
        if not hi > lo:
            continue
        res = scipy.optimize.minimize_scalar(lambda w: -_sigma_max(sys, w)[0], bounds=(lo, hi), method="bounded",
                                             options={"xatol": 1e-12})
        if float(-res.fun) > best:
            best, where = float(-res.fun), float(res.x)
    return (best, where) if frequency else best


#: A pole's span is refined only when its peak (``4 (1 - |pole|)`` wide) is narrower than this many sweep spacings.
PEAK_SPANS = 2.0


#: Patterns whose coarse sweep comes closest to the best are refined (the rest keep their sweep value).
REFINED = 4


class LowerBound(NamedTuple):
    """The witnessed lower end of a bracket (:func:`lower_bound`)."""

    value: float | None
    witness: list
    patterns: int
    note: str
    #: ``witness[:lead]`` runs once, then ``witness[lead:]`` repeats forever (0: periodic from the start).
    lead: int = 0
    #: The certified tree bound (:attr:`PrefixSearch.bound`, or :func:`tree_bound` when smaller), None when the
    #: prefix search did not run ...
    bound: float | None = None
    #: ... and how it was proved (search, depth, prefixes valued).
    tree: str = ""
    #: hinf: the witness as loop-mode indices (one period, ``data`` order) and the frequency (rad/sample) of its
    #: valued gain, where :func:`exact_gain_lower` evaluates it exactly (None for the cost).
    pattern: tuple = ()
    peak: float | None = None


def lower_bound(lifted: Lifted, gains: np.ndarray, kind: str, x0: np.ndarray | None = None,
                data: list[dict] | None = None, max_length: int | None = None, max_count: int | None = None,
                weight: np.ndarray | None = None, deep: bool = True, stop: float = np.inf,
                certificate: np.ndarray | None = None, budget: int = NODE_BUDGET) -> LowerBound:
    """Worst allowed pattern searched: a :class:`LowerBound` ``(value, witness, patterns searched, note, lead)``.

    cost: ``trace P_per`` (or ``x0' P_per x0``) with ``P_per = Phi' P_per Phi + S_per``: the exact cost of
    repeating the pattern from the period's start.  hinf: the H-infinity norm of the period's lifted LTI system
    (gains evaluated at the frequencies the level-set iteration finds: a lower bound by construction).  An unstable period gives ``inf`` for the cost (it has a nonzero
    stage cost) and is skipped for hinf.

    Every pattern is valued in stacks (:mod:`solver.periodic`: Stein equations by doubling; H-infinity norms by
    the level-set iteration, patterns that cannot enter the best ``GROW_BEAM`` skipped); the
    ``REFINED`` best are then re-evaluated one by one (:func:`lyapunov`; :func:`hinf_norm_peak`), and the value
    reported is the re-evaluated one of the witness.  ``deep`` (cost): the
    two-run search of :func:`run_patterns` beyond ``max_length``, stopped at ``stop`` (the certified upper bound).
    ``max_length`` None: the longest length whose patterns (all of them, every shorter one too) fit in
    ``max_count``, at least ``PATTERN_LENGTH`` (two modes: length 11 within 4000 patterns).
    ``certificate`` (cost, with ``deep``): the certified P; then :func:`prefix_search` (``budget`` nodes) looks
    for a prefix followed by one of the ``TAILS`` best periodic patterns that costs more (``lead`` > 0).
    """
    from . import periodic

    data = lifted.numeric(gains) if data is None else data
    if max_count is None:
        max_count = MAX_PATTERNS if kind == "cost" else MAX_PATTERNS_HINF
    if max_length is None:
        max_length, total = PATTERN_LENGTH, sum(len(data) ** k for k in range(1, PATTERN_LENGTH + 1))
        while max_length < MAX_PATTERN_LENGTH and total + len(data) ** (max_length + 1) <= max_count:
            max_length += 1
            total += len(data) ** max_length
    pats = patterns(len(data), max_length, max_count, rotations=kind == "cost")
    arrays = periodic.mode_arrays(data)
    approx = np.full(len(pats), np.nan)  # nan: skipped (unstable hinf, unstable cost-free, or pruned)
    unstable = np.zeros(len(pats), dtype=bool)
    systems = []
    for pos, idx in periodic.group_by_length(pats).values():
        sys = periodic.period_stack(arrays, idx, kind)
        if kind == "cost":
            # the Stein sums first: a converged one proves its period stable, eigenvalues only for the rest
            Pp, good, done = periodic.stein_screened(sys["Phi"], sys["S"])
            bad = ~good
            unstable[pos] = bad
            costly = np.any(sys["S"] != 0, axis=(1, 2))
            approx[pos[bad & costly]] = np.inf
            if np.any(good):
                Pp, done = Pp[good], done[good]
                vals = (np.einsum("i,pii->p", np.ones(Pp.shape[-1]) if weight is None else weight, Pp) if x0 is None
                        else np.einsum("i,pij,j->p", x0, Pp, x0))
                vals[~done] = np.inf  # radius within rounding of 1: re-evaluated exactly below if it matters
                approx[pos[good]] = vals
        else:
            bad = ~(periodic.spectral_radius(sys["Phi"]) < 1)
            unstable[pos] = bad
            good = ~bad
            systems.append((pos[good], sys if good.all() else {key: v[good] for key, v in sys.items()}))
    note, skipped, lead, bound, grown_count, tree, peak = "", 0, 0, None, 0, None, None
    # the certificate as coordinates for the witnesses' Lyapunov equations (small n: each costs a few more solves)
    hint = certificate if certificate is not None and certificate.ndim == 2 and \
        certificate.shape[-1] <= EXACT_COST_MAX_N else None
    if kind == "cost":
        if np.any(np.isinf(approx) & unstable):
            first = int(np.flatnonzero(np.isinf(approx) & unstable)[0])
            best, witness = np.inf, pats[first]
            note = "a periodic pattern is unstable (float64 spectral radius >= 1): its cost is unbounded"
        else:
            best, witness = -np.inf, None
            for i in _top(approx, REFINED):
                sys = period_system(data, pats[i])
                # the certificate (S_s + A_s' P A_s <= P for every mode, so Phi' P Phi < P over the period) is the
                # coordinates where the period's equation is well conditioned: without it a loop whose P spans
                # 1e10 got a witness twice its cost, above the certificate, and the bracket was refused (§8.5)
                Pp = lyapunov(sys["Phi"], sys["L"].T @ sys["L"], hint)
                value = float(_trace(Pp, weight) if x0 is None else x0 @ Pp @ x0)
                if value > best:
                    best, witness = value, pats[i]
            runs = None
            if deep:
                value, runs = run_patterns(data, pats, approx, x0, weight, stop=stop)
                if value is not None and value > best:
                    best, witness = value, runs
                    note = f"witness from the two-run search (runs up to {RUN_LENGTH})"
            if deep and certificate is not None and best < stop:
                tails = _tails(data, [pats[i] for i in _top(approx, TAILS)] + ([runs] if runs else []), hint)
                # tails costly from a state a prefix steers to rather than from x0: the one-interval periods whose
                # cost-to-go is largest in its worst direction, the first two guiding continuations too (seed 7159,
                # 20 slowly contracting modes: the tails best from x0 led every continuation to runs of 52.8, the
                # steered ones to 83.1)
                have = {seq for seq, _ in tails}
                steered = _tails(data, [(s,) for s in range(len(data)) if (s,) not in have], hint)
                steered.sort(key=lambda tail: -float(np.linalg.eigvalsh(_sym(tail[1]))[-1]))
                guides = list(range(min(3, len(tails)))) + list(range(len(tails), len(tails) + min(2, len(steered))))
                tails += steered[:STEERED_TAILS]
                found = prefix_search(data, tails, certificate, _moment(data[0]["A"].shape[0], x0, weight),
                                      floor=best, budget=budget, guides=guides)
                bound = found.bound
                tree = f"prefix tree on P, depth {found.depth} ({found.nodes} prefixes valued)"
                if bound > max(best, found.value or -np.inf) * (1 + 1e-9):  # the beam left prefixes open
                    again, count = tree_bound(data, certificate, _moment(data[0]["A"].shape[0], x0, weight),
                                              max(best, found.value or -np.inf))
                    if again < bound:
                        bound, tree = again, f"prefix tree on P, best first ({count} prefixes valued)"
                if found.value is not None and found.value > best:
                    best, witness, lead = found.value, found.prefix + found.tail, len(found.prefix)
                    note = (f"witness from the prefix search ({found.nodes} prefixes valued): {lead} intervals "
                            f"once, then a period of {len(found.tail)}")
    else:
        skipped = int(np.sum(unstable))
        _norms_pruned(systems, approx, GROW_BEAM if deep and len(data) > 1 else REFINED)
        best, witness = -np.inf, None
        cands = [(float(approx[i]), pats[i]) for i in _top(approx, REFINED)]
        # grow only where the exhaustive search leaves a gap worth closing: its coarse sweep values are lower bounds
        if deep and cands and len(data) > 1 and not cands[0][0] >= stop * (1 - GROW_ABOVE_GAP):
            grown, count = grow_patterns(data, [(float(approx[i]), pats[i]) for i in _top(approx, GROW_BEAM)],
                                         max(len(p) for p in pats), stop=stop)
            grown_count = count
            if grown:
                cands = sorted(cands + grown, key=lambda e: -e[0])[:REFINED]
        if cands:  # the best coarse patterns valued on their own (sweep, pole angles, refinement): the largest wins
            fine = [hinf_norm_peak(period_system(data, p), frequency=True) for _, p in cands]
            win = int(np.argmax([v for v, _ in fine]))
            (best, peak), witness = fine[win], cands[win][1]
            if len(witness) > max(len(q) for q in pats):
                note = f"witness grown from the best short patterns ({grown_count} longer patterns valued)"
    if witness is None:
        return LowerBound(None, [], len(pats) + grown_count, f"no stable periodic pattern ({skipped} unstable)")
    # (a)(a) and (a) are one infinite sequence with one value, and so are b (a) and (a) when b = a: which of them wins
    # the comparisons above is decided by rounding (it changed with the machine's BLAS), so the reported period is the
    # shortest one after the shortest prefix
    valued = list(witness[lead:])
    prefix, period = shortest_lead(witness[:lead], _primitive_period(valued))
    witness, lead = prefix + period, len(prefix)
    if peak is not None and len(period) < len(valued):
        peak = primitive_peak(data, witness, len(valued) // len(witness), peak)
    labels = _labels(lifted, witness)
    if skipped:
        note = (note + "; " if note else "") + f"{skipped} unstable periodic patterns skipped"
    return LowerBound(best, labels, len(pats) + grown_count, note, lead, bound, tree or "", tuple(witness), peak)


def _labels(lifted: Lifted, seq) -> list:
    """``(plant_mode, eta)`` per interval of the loop-mode indices ``seq`` (a witness as :class:`Performance` shows
    it)."""
    labels = []
    for s in seq:
        lm = lifted.lifted[s]
        plant = lm.plants[0] if lifted.modes.plant_switching == "per_interval" else tuple(lm.plants)
        labels.append((plant, lm.eta))
    return labels


def primitive_peak(data: list[dict], period, r: int, peak: float) -> float:
    """The frequency (rad/sample, in [0, pi]) of ``period``'s lifted system where the ``r``-fold period (``period``
    repeated r times) has its gain at ``peak``: the r-fold lifting's singular values at ``e^{jw}`` are the short
    period's at the r-th roots, ``(w + 2 pi k) / r`` (folded into [0, pi]: real data); the root of the largest gain."""
    roots = np.array([(peak + 2 * np.pi * k) / r for k in range(r)]) % (2 * np.pi)
    roots = np.where(roots > np.pi, 2 * np.pi - roots, roots)
    return float(roots[int(np.argmax(_sigma_max(period_system(data, tuple(period)), roots)))])


def _primitive_period(period: list) -> list:
    """The shortest block whose repetition is ``period`` (``[a, b, a, b]`` -> ``[a, b]``)."""
    n = len(period)
    for k in range(1, n):
        if n % k == 0 and period == period[:k] * (n // k):
            return period[:k]
    return period


def shortest_lead(prefix, period) -> tuple[list, list]:
    """``prefix`` once, then ``period`` forever, as the same sequence with the shortest prefix: a prefix that ends
    with the period's last element is the period rotated (``a`` then ``(a)`` forever is ``(a)`` forever).  Which of
    the two a search reports is decided by rounding (the two values agree to it), so the witness is this one."""
    prefix, period = list(prefix), list(period)
    while prefix and prefix[-1] == period[-1]:
        prefix.pop()
        period = period[-1:] + period[:-1]
    return prefix, period


def _tails(data: list[dict], seqs: list, hint: np.ndarray | None = None) -> list:
    """``(pattern, P_T)`` of the stable patterns among ``seqs`` (``P_T`` its periodic cost from its start;
    ``hint`` the certificate, coordinates for :func:`lyapunov`)."""
    out, seen = [], set()
    for seq in seqs:
        seq = tuple(seq)
        if seq in seen:
            continue
        seen.add(seq)
        sys = period_system(data, seq)
        if np.max(np.abs(np.linalg.eigvals(sys["Phi"]))) < 1:
            out.append((seq, lyapunov(sys["Phi"], sys["L"].T @ sys["L"], hint)))
    return out


#: The deeper search (cost): two runs ``a^i b^j`` of modes from the best short patterns, ``i, j <= RUN_LENGTH`` ...
RUN_LENGTH = 24
#: ... over every mode when there are at most this many, else over the most frequent ones in the best short patterns.
RUN_MODES = 6


def run_patterns(data: list[dict], short: list, values: np.ndarray, x0: np.ndarray | None = None,
                 weight: np.ndarray | None = None, max_run: int = RUN_LENGTH, max_modes: int = RUN_MODES,
                 stop: float = np.inf):
    """The deeper lower-bound search: the worst two-run pattern ``a^i b^j`` (cost), ``(value, pattern)``.

    The short patterns' worst witnesses repeat long-drop intervals with a switch between them (CTMS pendulum,
    two masses: the witness of length 6 is ``(m1, 3)(m2, 3)^5``); their runs are searched far beyond the
    exhaustive length.  ``a`` and ``b`` range over the modes of the best short patterns (``short``, valued by
    ``values``; every mode when there are at most ``max_modes``); each run's cost is accumulated by powers, every pattern valued by doubling in one stack, and
    the search stops once a value reaches ``stop`` (the certified upper bound: nothing can exceed it).  The
    winner is re-evaluated on its own (:func:`period_system`, :func:`lyapunov`), and
    that value is returned.  ``(None, None)`` when nothing was found.
    """
    from . import periodic

    counts: dict = {}
    for i in _top(values, 8):
        for s in short[i]:
            counts[s] = counts.get(s, 0) + 1
    chosen = list(range(len(data))) if len(data) <= max_modes else sorted(counts, key=lambda s: -counts[s])[:max_modes]
    if len(chosen) < 2 or not np.all(np.isfinite(values[~np.isnan(values)])):
        return None, None
    n = data[0]["A"].shape[0]
    power, cost = {}, {}
    for s in chosen:  # A_s^k and sum_{t<k} (A_s^t)' S_s A_s^t, k = 0..max_run
        Pw, Sm = [np.eye(n)], [np.zeros((n, n))]
        for _ in range(max_run):
            Sm.append(Sm[-1] + Pw[-1].T @ data[s]["S"] @ Pw[-1])
            Pw.append(data[s]["A"] @ Pw[-1])
        power[s], cost[s] = np.array(Pw), np.array(Sm)
    best, arg = -np.inf, None
    ks = np.arange(1, max_run + 1)
    for a in chosen:
        for b in chosen:
            if a == b:
                continue
            Ai, Si = power[a][ks], cost[a][ks]  # (k, n, n)
            Phi = (power[b][ks][None, :] @ Ai[:, None]).reshape(-1, n, n)  # B^j A^i, (i, j) row-major
            S = (Si[:, None] + np.swapaxes(Ai, 1, 2)[:, None] @ cost[b][ks][None, :] @ Ai[:, None]).reshape(-1, n, n)
            Pp, ok, done = periodic.stein_screened(Phi, S)
            if not np.any(ok):
                continue
            Pp, done = Pp[ok], done[ok]
            vals = (np.einsum("i,pii->p", np.ones(n) if weight is None else weight, Pp) if x0 is None
                    else np.einsum("i,pij,j->p", x0, Pp, x0))
            vals[~done] = -np.inf
            k = int(np.argmax(vals))
            if vals[k] > best:
                i, j = divmod(int(np.flatnonzero(ok)[k]), max_run)
                best, arg = float(vals[k]), (a,) * (i + 1) + (b,) * (j + 1)
            if best >= stop:
                break
    if arg is None:
        return None, None
    sys = period_system(data, arg)  # the winner on its own
    if not np.max(np.abs(np.linalg.eigvals(sys["Phi"]))) < 1:
        return None, None
    Pp = lyapunov(sys["Phi"], sys["L"].T @ sys["L"])
    return float(_trace(Pp, weight) if x0 is None else x0 @ Pp @ x0), arg


@dataclass
class PrefixSearch:
    """What :func:`prefix_search` found.

    Attributes
    ----------
    value : float or None
        The exact cost of ``prefix`` followed by ``tail`` repeated forever (re-evaluated on its own); None when
        no sequence beat the search's ``floor``.
    prefix, tail : tuple of int
        Loop-mode indices: the intervals applied once, then the period repeated (empty when ``value`` is None).
    bound : float
        The certified tree bound (docs/design.md §8.4, "Tree bound"): no admissible sequence costs more, given
        that ``P``'s inequality holds in exact arithmetic on the float64 data (:func:`check_cost`).  Every node
        value ``c + <P, Sigma>`` carries a rigorous rounding allowance; the smallest per-depth bound is kept.
    depth : int
        The depth whose bound is ``bound`` (0: the root, ``<P, M>`` with its allowance).
    nodes : int
        Prefixes valued.
    """

    value: float | None
    prefix: tuple
    tail: tuple
    bound: float
    nodes: int
    depth: int = 0


def _moment(n: int, x0: np.ndarray | None, weight: np.ndarray | None) -> np.ndarray:
    """``M`` with the objective ``<P, M>``: ``x0 x0'`` (cost from x0), ``diag(weight)`` or I (mean cost)."""
    if x0 is not None:
        return np.outer(x0, x0)
    return np.eye(n) if weight is None else np.diag(np.asarray(weight, dtype=float))


def sequence_cost(data: list[dict], prefix, tail, M: np.ndarray, hint: np.ndarray | None = None) -> float:
    """``<P_prefix + Phi' P_tail Phi, M>``: the exact cost of ``prefix`` then ``tail`` repeated forever
    (``Phi`` the prefix's transition, ``P_tail`` the tail's periodic cost, :func:`lyapunov` in the coordinates of
    ``hint``, the certificate); ``inf`` when the tail is unstable."""
    n = data[0]["A"].shape[0]
    T, Pp = np.eye(n), np.zeros((n, n))
    for s in prefix:
        Pp += T.T @ data[s]["S"] @ T
        T = data[s]["A"] @ T
    sys = period_system(data, tail)
    if not np.max(np.abs(np.linalg.eigvals(sys["Phi"]))) < 1:
        return np.inf
    Pt = lyapunov(sys["Phi"], sys["L"].T @ sys["L"], hint)
    return float(np.sum(_sym(Pp + T.T @ Pt @ T) * M))


def _cycle(seq: tuple, max_period: int = 64) -> tuple[tuple, tuple]:
    """``(prefix, period)`` with ``seq`` = ``prefix`` + the period repeated (its last copy possibly cut short),
    the shortest period (up to ``max_period``) that repeats at least three times at the end, the prefix as short
    as it then goes; ``(seq[:-1], seq[-1:])`` when none does."""
    for p in range(1, min(max_period, len(seq) // 3) + 1):
        if seq[-3 * p:] == seq[-p:] * 3:
            i = len(seq) - 3 * p
            while i > 0 and seq[i - 1] == seq[i - 1 + p]:
                i -= 1
            return seq[:i], seq[i:i + p]
    return seq[:-1], seq[-1:]


def _rollouts(A: np.ndarray, Sm: np.ndarray, Sig: np.ndarray, V: np.ndarray, P: np.ndarray, steps: int):
    """Greedy continuations from the moments ``Sig`` (R, n, n): each step takes the mode with the largest
    ``<S_s, Sigma> + <V, A_s Sigma A_s'>``, until ``<P, Sigma>`` (the certificate's bound on the rest) is below
    ``1e-13`` of the cost so far, or after ``steps`` steps.  Returns ``(cost so far (R,), modes (R, k), work)``."""
    At = np.swapaxes(A, 1, 2)
    R, S = Sig.shape[0], A.shape[0]
    cost, seqs, work = np.zeros(R), [], 0
    live = np.ones(R, dtype=bool)
    for _ in range(steps):
        nxt = A[None] @ Sig[:, None] @ At[None]  # (R, S, n, n)
        stage = np.einsum("sij,rji->rs", Sm, Sig)
        s = np.argmax(stage + np.einsum("ij,rsji->rs", V, nxt), axis=1)
        cost += np.where(live, stage[np.arange(R), s], 0.0)
        Sig = nxt[np.arange(R), s]
        seqs.append(s)
        work += R * S
        live &= np.einsum("ij,rji->r", P, Sig) > 1e-13 * cost
        if not np.any(live):
            break
    return cost, np.array(seqs).T, work


#: Greedy continuations (:func:`_rollouts`): at most this many steps each ...
ROLLOUT_STEPS = 4000
#: ... from this many of the most promising prefixes, at depths 1, 2, 4, 8, ...
ROLLOUTS = 4


def _gamma(k: int) -> float:
    """Higham's ``gamma_k = k u / (1 - k u)`` (u the unit roundoff): a sum of k float64 products of nonnegative
    magnitudes errs by at most ``gamma_k`` times the sum of their absolute values (any summation order)."""
    u = np.finfo(float).eps / 2
    return k * u / (1 - k * u)


#: Relative margin on a computed rounding allowance (it is itself a float64 sum of nonnegative terms, exact to a
#: few ``gamma_k``, far below this).
ALLOWANCE_MARGIN = 1e-6


def _certified(value, allowance):
    """``value + allowance`` rounded up: at least the exact sum (float64, ``value + allowance >= 0``)."""
    u = np.finfo(float).eps / 2
    return (value + allowance * (1 + ALLOWANCE_MARGIN)) * (1 + 4 * u)


class _TreeValues:
    """Node values ``c + <P, Sigma>`` of the prefix tree with their rounding allowances (docs/design.md §8.4, "Tree
    bound"), shared by the beam search (:func:`prefix_search`) and the best-first bound (:func:`tree_bound`).

    With ``p = sqrt(diag P)``, a symmetric error F of a moment moves every later node value by at most ``p'|F|p``
    (its cost-to-go ``<Q, F>`` has ``0 <= Q <= P``); one congruence ``A Sigma A'`` errs by ``gamma_2n |A||Sigma||A'|``
    (``p' . p = w_s'|Sigma|w_s`` with ``w_s = |A_s|'p``), its symmetrization by ``u |Sigma'|``; an inner product of
    ``n^2`` terms by ``gamma_{n^2+1}``; an addition by ``u`` of its result.

    ``P`` (Q, n, n): look-ahead matrices (one per sequence of the next intervals, docs/design.md §8.4, "Look-ahead"):
    every continuation then costs at most ``max_q <P_q, Sigma>``, and ``p``, ``|P|`` are the entrywise largest over
    q (each cost-to-go is below one of them).
    """

    def __init__(self, data: list[dict], P: np.ndarray):
        self.A = np.stack([d["A"] for d in data])
        self.At = np.swapaxes(self.A, 1, 2)
        self.Sm = np.stack([_sym(d["S"]) for d in data])
        self.P = _sym(P)
        self.Ps = self.P if self.P.ndim == 3 else self.P[None]
        n = self.A.shape[1]
        self.p = np.sqrt(np.maximum(np.diagonal(self.Ps, axis1=1, axis2=2).max(axis=0), 0.0))
        self.Wp = np.einsum("sij,i->sj", np.abs(self.A), self.p)  # (S, n)
        self.absS, self.absP = np.abs(self.Sm), np.abs(self.Ps).max(axis=0)
        self.g_dot, self.g_mom, self.g_one = _gamma(n * n + 1), _gamma(2 * n), _gamma(1)
        # gradual underflow breaks the relative model: at most a few n^3 roundings of 2^-1074 per entry and step
        self.tiny = n**3 * 1e-300 * (1.0 + float(np.sum(self.p)))**2

    def root(self, M: np.ndarray):
        """``(Sigma (1, n, n), c (1,), allowance (1,), certified value)`` of the empty prefix (``M`` rounded once,
        ``x0 x0'``)."""
        Sig = _sym(M)
        allow = self.g_one * float(self.p @ np.abs(Sig) @ self.p)
        value = float(np.max(np.sum(self.Ps * Sig, axis=(1, 2))))
        cert = float(_certified(value, allow + self.g_dot * float(np.sum(self.absP * np.abs(Sig)))
                                + self.g_one * abs(value)))
        return Sig[None], np.zeros(1), np.array([allow]), cert

    def children(self, Sig: np.ndarray, c: np.ndarray, allow: np.ndarray):
        """Every parent (``Sig`` (B, n, n), ``c``, ``allow`` (B,)) extended by every mode: ``(c2, Sig2, allow2, up,
        cert)``, shapes (B, S), (B, S, n, n), (B, S) x 3: cost so far, moment, carried allowance, computed value
        ``c2 + <P, Sig2>`` and its certified upper bound."""
        absSig = np.abs(Sig)
        c2 = c[:, None] + np.einsum("sij,bji->bs", self.Sm, Sig)
        Sig2 = self.A[None] @ Sig[:, None] @ self.At[None]
        Sig2 = 0.5 * (Sig2 + np.swapaxes(Sig2, -1, -2))
        absSig2 = np.abs(Sig2)
        allow2 = (allow[:, None] + self.g_dot * np.einsum("sij,bij->bs", self.absS, absSig) + self.g_one * np.abs(c2)
                  + self.g_mom * np.einsum("si,bij,sj->bs", self.Wp, absSig, self.Wp)
                  + self.g_one * np.einsum("i,bsij,j->bs", self.p, absSig2, self.p) + self.tiny)
        if self.Ps.shape[0] == 1:
            up = c2 + np.einsum("ij,bsji->bs", self.Ps[0], Sig2)
        else:
            up = c2 + np.einsum("qij,bsji->bsq", self.Ps, Sig2).max(axis=-1)
        cert = _certified(up, allow2 + self.g_dot * np.einsum("ij,bsij->bs", self.absP, absSig2)
                          + self.g_one * np.abs(up))
        return c2, Sig2, allow2, up, cert


def prefix_search(data: list[dict], tails: list, P: np.ndarray, M: np.ndarray, floor: float = -np.inf,
                  beam: int = BEAM, budget: int = NODE_BUDGET, max_depth: int | None = None,
                  guides: list | None = None) -> PrefixSearch:
    """Branch and bound over admissible interval sequences: a prefix, then a periodic tail (cost).

    A node is a prefix ``s_1 .. s_k`` with its cost so far ``c = sum_i <S_{s_i}, Sigma_{i-1}>`` and its moment
    ``Sigma_k = Phi M Phi'`` (``Phi = A_{s_k} .. A_{s_1}``; ``M`` as :func:`_moment`).  Every continuation costs
    at most ``c + <P, Sigma_k>`` (``P`` the certificate: ``A_s' P A_s - P + S_s <= 0`` for every mode), and the
    tail ``T`` repeated forever costs exactly ``c + <P_T, Sigma_k>`` (``tails``: ``(pattern, P_T)`` pairs).
    Depth by depth every node is extended by every mode; nodes whose bound does not exceed the best value found
    (above ``floor``, the periodic search's) are dropped, of the rest the ``beam`` with the largest bounds are
    kept, until none is left, ``budget`` nodes have been valued or ``max_depth`` is reached.  Greedy
    continuations (:func:`_rollouts`, the certificate and the best tails as value functions) from the root and
    from the ``ROLLOUTS`` most promising nodes at depths 1, 2, 4, 8, ... supply long sequences: each ends in a
    cycle (:func:`_cycle`) that becomes the tail.  The best candidates are re-evaluated on their own
    (:func:`sequence_cost`); ``value`` is None when nothing beats ``floor``.  ``guides``: the positions in ``tails``
    whose ``P_T`` guide a continuation from the root besides P (default the first three).

    The certified tree bound (docs/design.md §8.4, "Tree bound"): each node's ``c + <P, Sigma>`` plus a
    rigorous allowance for the rounding of ``c``, ``Sigma`` and the inner products (a forward error bound
    carried along the path), the largest over the nodes valued at depth d and the nodes dropped (pruned or
    beyond the beam) above it; the smallest over the depths.  ``P`` must be a certificate whose inequality
    passed :func:`check_cost`: the bound is proved for it, not re-checked here.
    """
    values = _TreeValues(data, P)
    A, Sm, P = values.A, values.Sm, values.P
    PT = np.stack([_sym(Pt) for _, Pt in tails]) if tails else None
    n, S = A.shape[1], A.shape[0]
    # above n = 8 the budget shrinks as n^-3 (the same CPU time), the beam to ~16 MB of moments per depth
    scale = min(1.0, (8.0 / n) ** 3)
    budget, steps = int(budget * scale), max(int(ROLLOUT_STEPS * scale), 1)
    beam = int(min(beam, max(8, 2_000_000 // (S * n * n))))
    Sig, c, allow, tree = values.root(M)
    tree_depth = 0
    best = floor
    candidates = []  # (approximate value, prefix, tail or None: the prefix ends in a cycle)
    history = []  # per depth: (parent position, mode) of the kept nodes
    dropped, nodes = -np.inf, 0  # dropped: the largest certified value of a node not kept (pruned or beam)

    def path(depth, b):
        out = []
        for d in range(depth - 1, -1, -1):
            parents, modes = history[d]
            out.append(int(modes[b]))
            b = int(parents[b])
        return tuple(reversed(out))

    guides = range(min(3, len(tails))) if guides is None else guides
    for V in [P] + [PT[i] for i in guides]:  # from the root
        cost, seqs, work = _rollouts(A, Sm, Sig, V, P, steps)
        nodes += work
        candidates.append((float(cost[0]), tuple(int(v) for v in seqs[0]), None))
        best = max(best, float(cost[0]))
    while Sig.shape[0] and nodes < budget and (max_depth is None or len(history) < max_depth):
        B = Sig.shape[0]
        c2, Sig2, allow2, up, cert = values.children(Sig, c, allow)
        nodes += B * S
        if tails:
            tail = c2[..., None] + np.einsum("tij,bsji->bst", PT, Sig2)
            t_best = np.argmax(tail, axis=-1)
            lo = np.take_along_axis(tail, t_best[..., None], axis=-1)[..., 0]
            k = int(np.argmax(lo))
            if lo.flat[k] > best:
                b, s = divmod(k, S)
                best = float(lo.flat[k])
                candidates.append((best, path(len(history), b) + (s,), tails[int(t_best.flat[k])][0]))
        up, cert, c2, Sig2 = up.ravel(), cert.ravel(), c2.ravel(), Sig2.reshape(B * S, n, n)
        allow2 = allow2.ravel()
        live = np.flatnonzero(up > best + 1e-12 * abs(best))
        pruned = np.ones(up.size, dtype=bool)
        if live.size > beam:
            live = live[np.argsort(-up[live], kind="stable")[:beam]]
        pruned[live] = False
        if np.any(pruned):  # every continuation of a node not kept is covered by its own certified value
            # (np.max of a NaN is NaN, and Python's max(dropped, nan) is dropped: a NaN must make the level infinite)
            worst = float(np.max(cert[pruned]))
            dropped = max(dropped, worst if np.isfinite(worst) else np.inf)
        history.append((live // S, live % S))
        Sig, c, allow = Sig2[live], c2[live], allow2[live]
        depth = len(history)
        # depth d: every admissible sequence passes a node valued here or a node dropped above
        top = float(np.max(cert[live])) if live.size else -np.inf
        level = max(dropped, top if not np.isnan(top) else np.inf)
        if not np.isfinite(level):
            level = np.inf
        if level < tree:
            tree, tree_depth = level, depth
        if live.size and depth & (depth - 1) == 0:  # depths 1, 2, 4, 8, ...: continue the most promising greedily
            top = np.argsort(-up[live], kind="stable")[:ROLLOUTS]
            cost, seqs, work = _rollouts(A, Sm, Sig[top], P, P, steps)
            nodes += work
            for r, b in enumerate(top):
                value = float(c[b] + cost[r])
                if value > best:
                    best = value
                    candidates.append((value, path(depth, int(b)) + tuple(int(v) for v in seqs[r]), None))
    found = PrefixSearch(value=None, prefix=(), tail=(), bound=float(tree), nodes=nodes, depth=tree_depth)
    for _, prefix, tail in sorted(candidates, key=lambda e: -e[0])[:4]:
        if tail is None:
            prefix, tail = _cycle(prefix)
        value = sequence_cost(data, prefix, tail, M, P if P.shape[0] <= EXACT_COST_MAX_N else None)
        if np.isfinite(value) and value > floor and (found.value is None or value > found.value):
            found.value, found.prefix, found.tail = value, tuple(prefix), tuple(tail)
    return found


#: The best-first tree bound (:func:`tree_bound`): nodes valued, a quarter of the prefix search's ...
BOUND_BUDGET = NODE_BUDGET // 4
#: ... taken from the frontier this many at a time (one stacked expansion).
BOUND_BATCH = 64


def tree_bound(data: list[dict], P: np.ndarray, M: np.ndarray, best: float, budget: int = BOUND_BUDGET):
    """The tree bound by best-first expansion (docs/design.md §8.4, "Tree bound"): ``(bound, nodes valued)``.

    The frontier starts at the root; the ``BOUND_BATCH`` nodes of largest certified value are replaced by their
    children, those whose computed value is at most ``best`` (a witnessed cost) closed.  At every step each
    admissible sequence passes a frontier node or a closed one, so ``max(frontier, closed)`` bounds every
    sequence's cost; the smallest over the steps is returned.  It goes straight at the prefixes that set the
    bound, where the beam of :func:`prefix_search` drops some of them for width.  ``budget`` scales as
    :func:`prefix_search`'s above n = 8.
    """
    import heapq

    values = _TreeValues(data, P)
    n, S = values.A.shape[1], values.A.shape[0]
    budget = int(budget * min(1.0, (8.0 / n) ** 3))
    cap = budget + BOUND_BATCH * S + 1
    sigs, cs, allows = np.empty((cap, n, n)), np.empty(cap), np.empty(cap)
    Sig, c, allow, bound = values.root(M)
    sigs[0], cs[0], allows[0] = Sig[0], c[0], allow[0]
    heap, size, closed, nodes = [(-bound, 0)], 1, -np.inf, 0
    while heap and nodes < budget:
        ids = [heapq.heappop(heap)[1] for _ in range(min(BOUND_BATCH, len(heap)))]
        c2, Sig2, allow2, up, cert = values.children(sigs[ids], cs[ids], allows[ids])
        nodes += up.size
        up, cert = up.ravel(), cert.ravel()
        shut = ~(up > best)  # NaN counts as closed: its certified value (NaN) makes the level infinite below
        if np.any(shut):
            closed = max(closed, float(np.max(cert[shut])) if np.all(np.isfinite(cert[shut])) else np.inf)
        keep = np.flatnonzero(~shut)
        k = keep.size
        sigs[size:size + k], cs[size:size + k] = Sig2.reshape(-1, n, n)[keep], c2.ravel()[keep]
        allows[size:size + k] = allow2.ravel()[keep]
        for j, i in enumerate(keep):
            heapq.heappush(heap, (-float(cert[i]), size + j))
        size += k
        level = max(closed, -heap[0][0] if heap else -np.inf)
        bound = min(bound, level if np.isfinite(level) else np.inf)
    return float(bound), nodes


def _top(values: np.ndarray, count: int) -> list[int]:
    """Positions of the ``count`` largest non-NaN values, largest first (earliest position on ties)."""
    order = [int(i) for i in np.argsort(-np.nan_to_num(values, nan=-np.inf), kind="stable") if not np.isnan(values[i])]
    return order[:count]


#: The H-infinity pattern growth (docs/design.md §8.4): patterns kept per length ...
GROW_BEAM = 12
#: ... the longest period grown ...
GROW_LENGTH = 32
#: ... and the pattern intervals valued in all (a pattern of k intervals costs a sweep of a k-interval lifted system),
#: times ``min(1, (4 / n)^3)`` for n states (a sweep's cost grows like n^3); a count, not a time, so that the witness
#: does not depend on the machine ...
GROW_BUDGET = 1500
#: ... and only when the exhaustive search's best coarse value is more than this far below the upper end (relative):
#: n = 8 random family of ``bench speed``: the growth took 5 s without moving the 6.4e-4 gap (by 1e-5 of it), which the
#: certified upper end sets.
GROW_ABOVE_GAP = 1e-3


def grow_patterns(data: list[dict], seeds: list, start: int, stop: float = np.inf, beam: int = GROW_BEAM,
                  max_length: int = GROW_LENGTH, budget: int | None = None) -> tuple[list, int]:
    """Longer periodic patterns for the H-infinity lower bound, grown from the best ones: ``(value, pattern)``
    pairs (witnessed gains) and the number of patterns valued.

    Every pattern of the beam (initially ``seeds``, the exhaustive search's best) is extended by every loop mode
    (one per rotation class, repetitions of shorter patterns skipped); the extensions are valued by the stacked
    level-set iteration, skipping those that cannot enter the ``beam`` best (:func:`_norms_pruned`), and
    the ``beam`` best become the next beam, until the period reaches ``max_length``, a value reaches ``stop``,
    ``budget`` pattern intervals have been valued (default :data:`GROW_BUDGET` scaled by the state dimension; a
    level's extensions are cut where they would pass it, in the beam's order).
    """
    from . import periodic

    if budget is None:
        budget = max(int(GROW_BUDGET * min(1.0, (4.0 / data[0]["A"].shape[0]) ** 3)), 1)

    arrays = periodic.mode_arrays(data)
    beam_pats = [p for _, p in seeds]
    found, seen, count, work = [], set(beam_pats), 0, 0
    best = max((v for v, _ in seeds), default=-np.inf)
    while beam_pats and work < budget:
        new = []
        for p in beam_pats:
            if len(p) >= max_length:
                continue
            for s in range(len(data)):
                q = p + (s,)
                k = len(q)
                q = min(q[i:] + q[:i] for i in range(k))
                if q in seen or any(k % d == 0 and q == q[:d] * (k // d) for d in range(1, k)):
                    continue
                seen.add(q)
                new.append(q)
        keep = np.cumsum([len(q) for q in new]) <= budget - work
        new = [q for q, k in zip(new, keep) if k]
        if not new:
            break
        values = np.full(len(new), np.nan)
        systems = []
        for pos, idx in periodic.group_by_length(new).values():
            sys = periodic.period_stack(arrays, idx, "hinf")
            good = periodic.spectral_radius(sys["Phi"]) < 1
            systems.append((pos[good], {key: v[good] for key, v in sys.items()}))
        _norms_pruned(systems, values, beam)
        count += len(new)
        work += sum(len(q) for q in new)
        top = _top(values, beam)
        found.extend((float(values[i]), new[i]) for i in top)
        beam_pats = [new[i] for i in top]
        if top and values[top[0]] > best:
            best = float(values[top[0]])
        if best >= stop:
            break
    return found, count


def _norms_pruned(systems: list, values: np.ndarray, keep: int = 1) -> None:
    """H-infinity norms of the stacked patterns into ``values``, skipping those that cannot be among the ``keep`` best.

    Patterns are taken by decreasing cheap upper bound (:func:`solver.periodic.gain_upper_bounds`), 64 at a time;
    a pattern whose bound is below the ``keep``-th best value found so far (the floor) stays NaN.  The others go
    through the level-set iteration (:func:`solver.periodic.level_set_norms`) started at the floor: one batched
    pencil eigenvalue problem shows a pattern's norm is below the floor (it keeps the witnessed gain of its start,
    below the floor), the rest converge to their norm (docs/design.md §8.4).  Where the pencil is ill-conditioned
    the ``SWEEP``-point sweep values the pattern instead.  Every value is a gain evaluated at a frequency.
    """
    from . import periodic

    omega = np.linspace(0.0, np.pi, SWEEP)
    systems = [(pos, periodic.gram_form(sys)) for pos, sys in systems if pos.size]
    bounds = [(pos, sys, periodic.gain_upper_bounds(sys)) for pos, sys in systems]
    entries = sorted(((float(ub[i]), g, i) for g, (_, _, ub) in enumerate(bounds) for i in range(ub.size)),
                     key=lambda e: -e[0])
    found: list = []
    floor, start = -np.inf, 0
    while start < len(entries) and entries[start][0] > floor:
        batch = []
        while start < len(entries) and len(batch) < 64 and entries[start][0] > floor:
            batch.append(entries[start])
            start += 1
        for g in sorted({e[1] for e in batch}):
            pos, sys, _ = bounds[g]
            rows = np.array([e[2] for e in batch if e[1] == g])
            sub = {k: v[rows] for k, v in sys.items()}
            vals, _, status = periodic.level_set_norms(sub, floor)
            swept = status == 2
            if np.any(swept):
                vals[swept] = np.maximum(vals[swept], periodic.sweep_gains({k: v[swept] for k, v in sub.items()},
                                                                          omega))
            values[pos[rows]] = vals
            found.extend(vals.tolist())
            if len(found) >= keep:
                floor = float(np.partition(found, len(found) - keep)[len(found) - keep])


#: The level-set tolerance of the witnesses' own valuation (:func:`hinf_norm_peak`): the search's 1e-10 stopped
#: 1.4e-10 below the peak of a resonance of radius 1 - 1e-5 (the golden-section refinement's value).
PEAK_TOL = 1e-14


def hinf_norm_peak(sys: dict, frequency: bool = False):
    """The H-infinity norm of one stable discrete LTI system as a witnessed gain: the level-set iteration
    (:func:`solver.periodic.level_set_norms`) finds the peak frequency, the gain is evaluated there by an SVD of
    ``D + C (e^{jw} I - Phi)^{-1} B`` and polished by a bounded scalar search within 1e-7 rad of it (the
    iteration stops within ~1e-9 of the peak value).  Where the pencil is ill-conditioned: :func:`hinf_norm_lower`
    (sweep and refinement).  ``frequency``: ``(gain, w)`` with w (rad/sample) the frequency of that gain, where
    :func:`exact_gain_lower` evaluates the witness exactly (docs/design.md §8.4)."""
    from . import periodic

    stack = {k: np.asarray(sys[k])[None] for k in ("Phi", "B", "C", "D")}
    _, omega, status = periodic.level_set_norms(periodic.gram_form(stack), tol=PEAK_TOL)
    if status[0] == 2:
        return hinf_norm_lower(sys, frequency=frequency)
    w = float(omega[0])
    best = float(_sigma_max(sys, w)[0])
    lo, hi = max(w - 1e-7, 0.0), min(w + 1e-7, np.pi)
    res = scipy.optimize.minimize_scalar(lambda x: -_sigma_max(sys, x)[0], bounds=(lo, hi), method="bounded",
                                         options={"xatol": 1e-14})
    if float(-res.fun) > best:
        best, w = float(-res.fun), float(res.x)
    return (best, w) if frequency else best


#: :func:`exact_loop_cost` solves exactly where the float64 bound is above the loop's float64 cost by this much.
EXACT_LOOP_GAP = 1e-8


def exact_loop_cost(lifted: Lifted, gains: np.ndarray, data: list[dict], P: np.ndarray | None, upper: float | None,
                    how: str, x0: np.ndarray | None, weight: np.ndarray | None):
    """The exact cost certificate of one LTI loop whose float64 certificate cannot reach its cost (docs/design.md §8.5).

    One plant mode, ``n_drop = 1``, n <= :data:`EXACT_COST_MAX_N`: ``P = A' P A + S`` is solved in exact rational
    arithmetic for ``A = F + G K``, ``S = Q + K' R K`` (the float64 numbers taken as exact,
    :func:`solver.exact.lyapunov_exact`, verified exactly there), so its bound is the loop's cost itself.  Tried only
    where float64 falls short: no certificate ``P``, one that needed the exact re-check (``how``), or a bound
    ``upper`` above the loop's float64 cost by more than :data:`EXACT_LOOP_GAP`.  Returns ``(P exact, bound rounded
    up, P rounded to float64, bound rounded down)``, else None.
    """
    from .exact import lyapunov_exact, rational_down, rational_up

    modes = lifted.modes
    if len(data) != 1 or getattr(modes, "n_drop", None) != 1 or getattr(modes, "F", None) is None or \
            modes.F.shape[0] != 1 or lifted.Q is None or lifted.R is None or gains.shape[0] != 1:
        return None
    F, G, K = modes.F[0], modes.G[0], gains[0]
    n = F.shape[0]
    A, S = data[0]["A"], data[0]["S"]
    if n > EXACT_COST_MAX_N or A.shape != (n, n) or not np.all(np.isfinite(K)) or \
            not np.max(np.abs(np.linalg.eigvals(A))) < 1:
        return None
    # the bracket's loop must be this one (its float64 rounding): else the exact P would certify another system
    if not (np.allclose(A, F + G @ K, rtol=0, atol=1e-9 * max(1.0, float(np.max(np.abs(A))))) and np.allclose(
            S, lifted.Q + K.T @ lifted.R @ K, rtol=0, atol=1e-9 * max(1.0, float(np.max(np.abs(S)))))):
        return None
    if P is not None and "exact" not in how:
        try:
            estimate = _upper_value(lyapunov(A, _sym(S), P), weight, x0)
        except np.linalg.LinAlgError:
            estimate = None
        if estimate is not None and not upper > estimate * (1 + EXACT_LOOP_GAP):
            return None
    Pq = lyapunov_exact(F, G, K, lifted.Q, lifted.R)
    if Pq is None:
        return None
    if x0 is None:
        w = [Fraction(1)] * n if weight is None else [Fraction(float(v)) for v in weight]
        value = sum(w[i] * Pq[i][i] for i in range(n))
    else:
        xq = [Fraction(float(v)) for v in x0]
        value = sum(xq[i] * Pq[i][j] * xq[j] for i in range(n) for j in range(n))
    bound = rational_up(value)
    # kept even when above ``upper``: a float64 certificate re-checked (exactly) on the loop's float64 rounding
    # fl(F + G K) certifies that loop, whose cost differs from the deployed one's by up to 3e-5 (hold-out seed 4:
    # 9.66780e12 against 9.66785e12, the witness 9.66788e12 above the former refused the bracket)
    return Pq, bound, floats(Pq), rational_down(value)


def bracket(lifted: Lifted, gains: np.ndarray, kind: str, P0: np.ndarray | None = None,
            x0: np.ndarray | None = None, solver: str = "AUTO", weight: np.ndarray | None = None,
            exact_hinf: tuple | None = None, seconds_left=None) -> Performance:
    """The certified bracket of ``kind`` for given gains.

    ``P0``: a candidate certificate (a design's); without one (or when it fails the re-check) the
    fixed-gain LMI proposes P.  Either way P is accepted only through the float64 re-check.
    ``weight`` (n,): the mean cost is ``sum_i weight_i P_ii`` instead of ``trace P`` (the user's trace of a design
    made in balanced coordinates, :class:`solver.scaling.PerformanceScaling`).
    ``exact_hinf``: ``(P, g)``, a rational P (lists of Fractions) and a float64 ``g = gamma^2`` proposed for one LTI
    loop, accepted through :func:`check_hinf_exact` (docs/design.md §8.5).
    ``seconds_left``: ``() -> seconds or None`` (a design's time limit): the exact rational cost certificate (up
    to 2 s at n = 8), the exact hinf witness (:func:`exact_witness`) and the deep lower-bound searches are not
    started once <= 0.
    """
    data = lifted.numeric(gains)
    P = upper = None
    reason, how = "", ""  # why nothing passed so far; what certified the accepted P (certify_* name it)
    certify = (lambda Pc: certify_cost(Pc, data, x0, weight)) if kind == "cost" else (lambda Pc: certify_hinf(Pc, data))
    if P0 is not None and np.all(np.isfinite(P0)):
        P, upper, why = certify(P0)
        reason, how = (why, "") if P is None else ("", why)
    if P is None:
        try:
            P, upper, why = fixed_gain_cost(data, x0, solver, weight) if kind == "cost" else fixed_gain_hinf(data, solver)
        except SolverFailed as err:
            P, upper, why = None, None, str(err)
        if P is None:
            reason = why if not reason else f"{reason}; fixed-gain LMI: {why}"
        else:
            how = why
    if P is None and kind == "cost" and len(data) == 1 and data[0]["A"].shape[0] <= EXACT_COST_MAX_N and \
            np.all(np.isfinite(data[0]["A"])) and np.max(np.abs(np.linalg.eigvals(data[0]["A"]))) < 1:
        # one LTI loop whose P spans too much for the LMI and the float64 re-check (§8.5): its own cost matrix,
        # lifted along itself, through the exact re-check
        try:
            X = lyapunov(data[0]["A"], _sym(data[0]["S"]))
            for eps in (1e-12, 1e-10, 1e-8, 1e-6):
                Pc, uc, why = certify_cost(lyapunov(data[0]["A"], _sym(data[0]["S"]) + eps * X, X), data, x0, weight)
                if Pc is not None:
                    P, upper, how = Pc, uc, why or "the loop's Lyapunov solution"
                    break
        except np.linalg.LinAlgError:
            pass
    exact_P = exact_lower = None
    if kind == "hinf" and exact_hinf is not None and len(data) == 1:
        # one LTI loop, an exact rational P of the bounded-real inequality (the game refinement's, §8.5): checked
        # exactly on the deployed loop; float64 cannot hold that P where it spans 1e13 (its rounding needs slack
        # that costs 1e-4 of the level)
        Pq, g = exact_hinf
        if check_hinf_exact(Pq, g, data):
            gamma = float(np.nextafter(np.sqrt(g), np.inf))  # sqrt rounds to nearest: never below
            if upper is None or gamma < upper:
                exact_P, upper = Pq, gamma
                if P is None:
                    P = _sym(floats(Pq))
                    how = ("exact rational certificate (bounded-real inequality checked exactly on the loop F + G K; "
                           "`certificate` is its float64 rounding)")
                else:
                    how = ("exact rational certificate (bounded-real inequality checked exactly on the loop F + G K; "
                           "`certificate` is a float64 one of a larger level)")
                exact_lower = exact_gain_lower(data, (0,))
    if kind == "cost" and not out_of_time(seconds_left):
        rational = exact_loop_cost(lifted, gains, data, P, upper, how, x0, weight)
        if rational is not None:
            exact_P, bound, Pf, exact_lower = rational
            if P is None:
                P, how = Pf, ("exact rational certificate (P = A'PA + S solved exactly for the loop F + G K; "
                              "`certificate` is its float64 rounding)")
            else:
                how = ("exact rational certificate (P = A'PA + S solved exactly for the loop F + G K; `certificate` "
                       "is a float64 one for its float64 rounding fl(F + G K))")
            upper = bound
    # out of time: the exhaustive short patterns only (the deeper searches are counts of up to 60 000 nodes, not times)
    found = lower_bound(lifted, gains, kind, x0, data=data, weight=weight, stop=np.inf if upper is None else upper,
                        certificate=P, deep=not out_of_time(seconds_left))
    lower, witness, count, note, lead = found.value, found.witness, found.patterns, found.note, found.lead
    seed = lower  # the float64 witness: where the bounded-real Riccati candidates below start
    if exact_lower is not None and lower is not None and np.isfinite(lower):
        # one loop, one allowed pattern: its cost is the exact P's value (the float64 witness of a loop whose P spans
        # 1e13 is off by more than 1e-6, hold-out seed 9: above the exact bound)
        lower = exact_lower
    elif kind == "cost" and lower is not None and np.isfinite(lower) and lower > 0:
        # the witness's cost valued exactly (docs/design.md §8.4, "Exact witness (cost)"): a proven lower end
        value, why = exact_cost_witness(data, found, x0, weight, seconds_left)
        if value is not None:
            lower = value
        if why:
            note = f"{note}; {why}" if note else why
    elif kind == "hinf" and lower is not None and np.isfinite(lower) and lower > 0 and found.peak is not None:
        # the float64 witness is no proof on an ill-conditioned loop (above the pattern's exact gain by up to 27x):
        # the pattern's exact lifted period evaluated at its peak frequency (docs/design.md §8.4, "Lower bound")
        value, why = exact_witness(data, found, seconds_left)
        if value is not None:
            lower = value
        note = f"{note}; {why}" if note else why
    if kind == "hinf" and len(data) > 1 and lower is not None and np.isfinite(lower) and lower > 0 and \
            (upper is None or upper > lower * (1 + GROW_ABOVE_GAP)) and not out_of_time(seconds_left):
        # a disturbance that charges the loop under one pattern, released as output under another at rest, can beat
        # every periodic pattern (docs/design.md §8.4, "Transient witness"; zero-input hold-out seed 9124: 23.8 -> 31.1)
        from .transients import transient_witness

        released = transient_witness(data, lower)
        if released is not None:
            # spelled as evaluated (no shortest_lead: moving an interval of the charge into the period would move it
            # out of the stretch the disturbance acts on, which `lead` marks)
            prefix, period = list(released.charge) * released.periods, list(released.release)
            lower, lead = released.value, len(prefix)
            witness = _labels(lifted, prefix + period)
            loop = "the deployed loop" if released.deployed else "the float64 loop data as exact rationals"
            what = (f"witness: a {len(released.charge)}-interval pattern driven {released.periods} times, then a "
                    f"{len(released.release)}-interval pattern without disturbance forever (evaluated exactly on "
                    f"{loop}; float64: {released.float_value / released.value - 1:+.2g} relative)")
            note = f"{what}; periodic search: {note}" if note else what
    if kind == "hinf" and len(data) == 1 and seed is not None and np.isfinite(seed) and seed > 0 and (
            upper is None or upper > seed * (1 + 1e-7)):
        # one LTI loop (one mode, n_drop = 1): the witness is its l2 gain (frequency sweep), and the bounded-real
        # Riccati solution a hair above it is the least certificate there (§8.5); the SDP's P can be 1e-3 off
        small = data[0]["A"].shape[0] <= EXACT_COST_MAX_N
        for delta in (1e-8, 1e-7, 1e-6, 1e-5, 3e-5, 1e-4):
            X = bounded_real_riccati(data[0], seed * (1 + delta))
            if X is None:
                continue
            Pc, gc, why = certify_hinf(X, data, seed * (1 + delta))
            # the Riccati solution is tight in the state block; where P spans 1e11 its float64 rounding (1e-5
            # absolute) needs slack there: the equation with C'C + eps X (exact re-check, small n only, §8.5)
            for eps in (1e-7, 1e-6, 1e-5, 1e-4) if Pc is None and small else ():
                Xl = bounded_real_riccati(data[0], seed * (1 + delta), lift=eps * X)
                if Xl is not None:
                    Pc, gc, why = certify_hinf(Xl, data, seed * (1 + delta))
                    if Pc is not None:
                        break
            if Pc is not None and (upper is None or gc < upper):
                P, upper, how, exact_P = Pc, gc, why or "bounded-real Riccati solution", None
                break
    quadratic, tree, mode_P = upper, "", None
    if kind == "hinf" and P is not None and 1 < len(data) <= MODE_STORAGE_MAX_MODES and lower is not None and \
            np.isfinite(lower) and upper > lower * (1 + MODE_STORAGE_GAP):
        # a switched loop whose common storage leaves a gap: one storage per mode (docs/design.md §8.4)
        try:
            Pm, gm, _ = mode_storage_hinf(data, solver)
        except SolverFailed:
            Pm = None
        if Pm is not None and gm < upper:
            mode_P, upper = Pm, gm
            tree = f"mode-dependent storage, {len(data)} matrices; the quadratic certificate alone: {quadratic:.6g}"
    if P is not None and exact_P is None and found.bound is not None and found.bound < upper:
        # (not on an exact certificate: the tree values the float64 loop, not the deployed one)
        # the prefix tree's certified bound (docs/design.md §8.4, "Tree bound"): the same P, a tighter number
        upper = found.bound
        tree = f"{found.tree}; the quadratic certificate alone: {quadratic:.6g}"
    if kind == "cost" and P is not None and exact_P is None and len(data) > 1 and lower is not None and \
            np.isfinite(lower) and upper > lower * (1 + LOOKAHEAD_GAP) and not out_of_time(seconds_left):
        # a switched loop whose single P leaves a gap: one matrix per sequence of the next intervals (docs/design.md
        # §8.4, "Look-ahead"; a two-mode loop near the stability boundary: 181 -> 120.73 against a run of 120.70)
        from .methods.network_performance import lookahead_cost

        ahead = lookahead_cost(data, x0, weight, P, lower, None if seconds_left is None else seconds_left(), upper)
        if ahead is not None:
            Pq, bound, memory = ahead
            what = f"one matrix per sequence of the next {memory} intervals, {len(Pq)} matrices"
            if bound > lower * (1 + LOOKAHEAD_GAP) and not out_of_time(seconds_left):
                # the prefix tree on the look-ahead matrices: a node's continuations cost at most max_q <P_q, Sigma>
                # (docs/design.md §8.4, "Look-ahead"); its root is the look-ahead's bound, and the smaller of it and
                # the tree on P is kept below
                again, count = tree_bound(data, Pq, _moment(data[0]["A"].shape[0], x0, weight), lower)
                if again < bound:
                    bound, what = again, f"prefix tree on {what}, best first ({count} prefixes valued)"
            if bound < upper:
                mode_P, upper = Pq, bound
                tree = f"{what}; the quadratic certificate alone: {quadratic:.6g}"
    if P is not None and lower is not None and np.isfinite(lower) and lower > upper * (1 + 1e-6):
        # cannot happen for a valid certificate: refuse both rather than report a contradiction
        P, upper, quadratic, mode_P = None, None, None, None
        reason = f"the witness pattern ({lower:.6g}) exceeds the certified bound; refused"
    what = "cost" if kind == "cost" else "l2 gain"
    if P is not None:
        message = f"{what} certified <= {upper:.6g} ({tree or how or 'float64 re-check of P'})"
    else:
        message = f"no certified upper bound: {reason}"
    if lower is not None:
        message += f"; worst periodic pattern searched: {lower:.6g} ({count} patterns)"
    if note:
        message += f"; {note}"
    return Performance(kind=kind, upper=upper, lower=lower, witness=witness, certificate=P,
                       verified=P is not None, x0=x0, patterns=count, message=message, lead=lead,
                       certificate_upper=quadratic, exact_certificate=exact_P if P is not None else None,
                       mode_certificate=mode_P)


#: A cost bracket open by more than this (upper / lower - 1) tries the look-ahead bounds (:func:`bracket`).
LOOKAHEAD_GAP = 1e-2
#: The exact witness (:func:`exact_gain_lower`) is evaluated only where its elimination's work :func:`exact_work`,
#: ``k^3 L^2``, is at most this: ``(zI - Phi) Y = B`` has side k = 2n in real form (n at w = 0 or pi, where z is
#: real) and the period's integers grow with its L intervals (docs/design.md §8.4, "Lower bound").  One interval at
#: n = 30 off the real axis (2.2e5: 2.8 s) is in, two at n = 20 (2.6e5: 4.3 s) only on it (3.2e4: 0.4 s).
EXACT_PERIOD_MAX_WORK = 2.3e5
#: A frequency this close (rad/sample) to 0 or pi is evaluated there, at z = 1 or -1 (:func:`_exact_gain_at`), where
#: the float64 gain there is within ``EXACT_SHORTFALL`` of the gain at the frequency itself (:func:`_snaps`): the
#: float64 peak search stops up to ~6e-8 short of pi (its bounded search's tolerance; the n = 20 bench: 3e-12
#: relative lost at 1e-5), while a pole 1e-8 inside the circle at pi - 5e-7 loses 24x of its peak there.
REAL_SNAP = 1e-6
#: ... nor when the integers of that system exceed this many bits (subnormal data; an elimination's cost grows
#: with the square of the bits).
EXACT_PERIOD_MAX_BITS = 20000
#: Where the exact value at the float64 peak is this much (relative) below the float64 witness, w = 0, pi and the
#: period's pole angles are evaluated exactly too.
EXACT_SHORTFALL = 1e-6


def _real_frequency(w: float) -> bool:
    """Whether ``w`` is within :data:`REAL_SNAP` of 0 or pi."""
    return min(abs(w), abs(np.pi - abs(w))) <= REAL_SNAP


def _snaps(sys: dict, w: float) -> bool:
    """Whether :func:`_exact_gain_at` evaluates ``w`` at the real z = 1 or -1: within :data:`REAL_SNAP` of 0 or pi,
    and the float64 gain of the period ``sys`` (``Phi``, ``B``, ``C``, ``D``) there within ``EXACT_SHORTFALL`` of
    its gain at ``w`` (a lightly damped pole near the axis peaks off it)."""
    if not _real_frequency(w) or sys.get("B") is None:
        return False
    with np.errstate(all="ignore"):
        try:
            at, real = _sigma_max(sys, np.array([w, 0.0 if abs(w) < 1 else np.pi]))
        except np.linalg.LinAlgError:
            return False
    return bool(np.isfinite(real) and real >= at * (1 - EXACT_SHORTFALL))


def exact_work(n: int, length: int, real: bool) -> float:
    """The work ``k^3 L^2`` of one exact evaluation (:func:`_exact_gain_at`) of a period of ``length`` intervals of
    ``n`` states: Bareiss elimination on side ``k`` (n for real z, else 2n) whose integers grow with L."""
    k = n if real else 2 * n
    return float(k) ** 3 * float(length) ** 2


def _stack_pairs(pairs: list, axis: int) -> tuple:
    """Concatenate ``(N, s)`` integer matrices (values ``N / 2^s``) along ``axis``, exactly."""
    s = max(t for _, t in pairs)
    return np.concatenate([N * (1 << (s - t)) for N, t in pairs], axis=axis), s


def _placed(X: tuple, col: int, width: int) -> tuple:
    """``(N, s)`` with X's columns placed at ``col`` in a zero matrix of ``width`` columns."""
    N, t = X
    Z = np.zeros((N.shape[0], width), dtype=object) * 0
    Z[:, col:col + N.shape[1]] = N
    return Z, t


def exact_period(data: list[dict], seq, deployed: bool | None = None) -> dict | None:
    """The lifted one-period system of the periodic pattern ``seq`` (loop-mode indices) in exact integer arithmetic,
    as :func:`period_system` builds it in float64: ``x(end) = Phi x(start) + B w``, ``z = C x(start) + D w``.

    Each interval's ``[A_s B_s]``, ``[C_s D_s]`` is the deployed loop rebuilt in rationals from the float64 F, G, K,
    E, C_z, D_z the data carry (:func:`_exact_loop`, docs/design.md §8.4 "Loop data") when every interval has it
    (``deployed`` None or True; True: else None), otherwise the float64 interval data taken as exact rationals
    (``deployed`` False or None).  Every number is dyadic, so a matrix is held as ``(N, s)``, integers N (object
    array) over ``2^s``.  Returns ``{"AB": [Phi B], "CD": [C D], "n": n, "deployed": bool}`` as such pairs, or None
    without a disturbance channel.
    """
    from .exact import dyadic, exact, identity, matmul
    from .exact import add as add_exact

    if data[seq[0]].get("B") is None:
        return None
    n = data[seq[0]]["A"].shape[0]
    blocks = None
    if deployed is not False:
        loops = [_exact_loop(data[s]) for s in seq] if _rebuildable(data, seq, "hinf") else [None]
        if all(lp is not None and lp[2] is not None for lp in loops):
            blocks = []
            for lp in loops:
                N, t = dyadic(lp[2])
                AB = (np.array(N, dtype=object).reshape(n, -1), t)
                N, t = dyadic(lp[3])
                CD = (np.array(N, dtype=object).reshape(len(lp[3]), -1), t)
                blocks.append(((AB[0][:, :n], AB[1]), (AB[0][:, n:], AB[1]), (CD[0][:, :n], CD[1]),
                               (CD[0][:, n:], CD[1])))
        elif deployed:
            return None
    used = blocks is not None
    if blocks is None:
        blocks = [tuple(exact(data[s][k]) for k in ("A", "B", "C", "D")) for s in seq]
    widths = [b[1][0].shape[1] for b in blocks]
    total = sum(widths)
    T, Tw = identity(n), (np.zeros((n, total), dtype=object) * 0, 0)
    Cs, Ds, col = [], [], 0
    for (A, B, C, D), w in zip(blocks, widths):
        Cs.append(matmul(C, T))
        Ds.append(add_exact(matmul(C, Tw), _placed(D, col, total)))
        Tw = add_exact(matmul(A, Tw), _placed(B, col, total))
        T = matmul(A, T)
        col += w
    return {"AB": _stack_pairs([T, Tw], 1), "CD": _stack_pairs([_stack_pairs(Cs, 0), _stack_pairs(Ds, 0)], 1),
            "n": n, "deployed": used}


def _exact_gain_at(period: dict, w: float) -> float | None:
    """A proven lower bound on the l2 gain of the exact lifted system ``period`` (:func:`exact_period`) from one
    frequency ``w`` (rad/sample): ``|H(z) v| / |v|``, rounded down, with ``H(z) = D + C (zI - Phi)^{-1} B``.

    z is the float64 ``cos w + j sin w`` as a rational, lifted by factors ``1 + 2^-50`` to ``|z| >= 1``: for a
    stable period the gain there is at most the H-infinity norm (maximum modulus), which is the pattern's l2 gain
    from x = 0 (lifting is an isometry); an unstable period's gain is infinite or that of its stable minimal part.
    Within :data:`REAL_SNAP` of 0 or pi, z is exactly 1 or -1 where the float64 gain there is as large
    (:func:`_snaps`: the gain of a real system is even about both, so the move costs ``O(REAL_SNAP^2)`` of a peak
    that is not lightly damped) and the system is real.  ``(zI - Phi) Y = B`` is solved over the
    integers (:func:`solver.exact.solve_integer`; complex z: its real form, side 2n, 8x the work of side n),
    H formed exactly, v the top right singular vector of H's float64 rounding, and ``|H v|^2 / |v|^2`` compared
    with the float64 square root in rationals.  None where ``zI - Phi`` is singular or the integers exceed
    :data:`EXACT_PERIOD_MAX_BITS`.
    """
    from .exact import dyadic, solve_integer

    n = period["n"]
    (Nab, sab), (Ncd, scd) = period["AB"], period["CD"]
    zr, zi = Fraction(float(np.cos(w))), Fraction(float(np.sin(w)))
    while zr * zr + zi * zi < 1:
        zr, zi = zr * (1 + Fraction(1, 2 ** 50)), zi * (1 + Fraction(1, 2 ** 50))
    # v: the top right singular vector of H(z) from the exact period rounded once to float64 (only H v is formed
    # exactly: one right-hand side instead of the period's p disturbance columns, each a column of big integers;
    # a v off by e costs e^2 of the value, never its validity)
    ABf = np.array([[int(x) / (1 << sab) for x in row] for row in Nab], dtype=float).reshape(Nab.shape)
    CDf = np.array([[int(x) / (1 << scd) for x in row] for row in Ncd], dtype=float).reshape(Ncd.shape)
    if _snaps({"Phi": ABf[:, :n], "B": ABf[:, n:], "C": CDf[:, :n], "D": CDf[:, n:]}, w):
        zr, zi = Fraction(1 if np.cos(w) > 0 else -1), Fraction(0)
    z = float(zr) if zi == 0 else complex(float(zr), float(zi))  # real z: a real H, a real v
    try:
        Hf = CDf[:, n:] + CDf[:, :n] @ np.linalg.solve(z * np.eye(n) - ABf[:, :n], ABf[:, n:])
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(Hf)):
        return None
    v = np.linalg.svd(Hf, full_matrices=False)[2][0].conj()
    (Z,), t = dyadic([[zr, zi]])
    (V,), u = dyadic([[Fraction(float(x.real)) for x in v] + [Fraction(float(x.imag)) for x in v]])
    p = v.size
    Vr, Vi = np.array(V[:p], dtype=object), np.array(V[p:], dtype=object)
    norm_v = int(np.dot(Vr, Vr) + np.dot(Vi, Vi))
    if norm_v == 0:
        return None
    # (zI - Phi) y = B v over the integers, scaled by 2^(t + sab + u): (Z 2^sab - Phi_N 2^t) y = B_N (V) 2^t,
    # in real form [[Mr, -Zi], [Zi, Mr]] [yr; yi] = [B Vr; B Vi] 2^t, or Mr yr = B Vr 2^t where z and v are real
    Zr, Zi = Z[0] << sab, Z[1] << sab
    A, B = Nab[:, :n] * (1 << t), Nab[:, n:] * (1 << t)
    real = Zi == 0 and not any(Vi)
    k = n if real else 2 * n
    M = [[0] * k for _ in range(k)]
    for i in range(n):
        for j in range(n):
            M[i][j] = -A[i, j]
            if not real:
                M[n + i][n + j] = -A[i, j]
        M[i][i] += Zr
        if not real:
            M[n + i][n + i] += Zr
            M[i][n + i], M[n + i][i] = -Zi, Zi
    rhs = [[int(x)] for x in np.dot(B, Vr)] + ([] if real else [[int(x)] for x in np.dot(B, Vi)])
    bits = max(max((abs(int(x)).bit_length() for row in M for x in row), default=0),
               max((abs(r[0]).bit_length() for r in rhs), default=0))
    if bits > EXACT_PERIOD_MAX_BITS:
        return None
    solved = solve_integer(M, rhs)
    if solved is None:
        return None
    Y, d = solved  # d (yr; yi), integers: y = Y / d, and H v = (C Y / d + D V) / (2^scd 2^u)
    yr = np.array([r[0] for r in Y[:n]], dtype=object)
    yi = np.zeros(n, dtype=object) * 0 if real else np.array([r[0] for r in Y[n:]], dtype=object)
    C, D = Ncd[:, :n], Ncd[:, n:]
    re, im = np.dot(C, yr) + np.dot(D, Vr) * d, np.dot(C, yi) + np.dot(D, Vi) * d
    scale = d << scd  # |H v|^2 / |v|^2 = |re + j im|^2 / (|V|^2 scale^2): 2^u cancels
    q = Fraction(int(np.dot(re, re) + np.dot(im, im)), norm_v * scale * scale)
    f = float(np.sqrt(float(q)))
    while Fraction(f) ** 2 > q:
        f = float(np.nextafter(f, 0.0))
    return f


def exact_witness(data: list[dict], found: LowerBound, seconds_left=None) -> tuple[float | None, str]:
    """The hinf witness ``found`` (:func:`lower_bound`) evaluated exactly: ``(value, note)``, value a proven lower
    bound on the witness pattern's l2 gain (:func:`exact_gain_lower` at ``found.peak``), or None with the reason
    the float64 value stays (the period's work above :data:`EXACT_PERIOD_MAX_WORK`, the run out of time, or the
    exact evaluation failed).  The note says which, for the bracket's message (docs/design.md §8.4)."""
    seq, n = tuple(found.pattern), data[0]["A"].shape[0]
    if not seq or found.peak is None:
        return None, "float64 witness (no peak frequency to evaluate exactly)"
    fl = period_system(data, seq)  # the float64 period: where _exact_gain_at will snap, for the work cap
    real = _snaps(fl, found.peak)
    if exact_work(n, len(seq), real) > EXACT_PERIOD_MAX_WORK:
        return None, (f"float64 witness, not a proof (period {len(seq)} x {n} states at w = {found.peak:.6g} is "
                      f"above the exact evaluation's work {EXACT_PERIOD_MAX_WORK:.3g})")
    if out_of_time(seconds_left):
        return None, "float64 witness, not a proof (no time left for its exact evaluation)"
    period = exact_period(data, seq)
    if period is None:
        return None, "float64 witness, not a proof (no disturbance channel to evaluate exactly)"
    w = found.peak
    at = ("w = 0 (z = 1)" if abs(w) < 1 else "w = pi (z = -1)") if real else f"w = {w:.6g} rad/sample"
    value, where = exact_gain_lower(data, seq, w, period=period), at
    if value is None or value < found.value * (1 - EXACT_SHORTFALL):
        # far below float64's value: the float64 peak may be misplaced (an ill-conditioned period); the level-set
        # iteration's own starting points too (w = 0, pi, the poles' angles), the largest kept
        Phi = floats([[Fraction(int(v), 1 << period["AB"][1]) for v in row[:period["n"]]] for row in period["AB"][0]])
        more = [0.0, float(np.pi)] + sorted({float(w) for w in np.abs(np.angle(np.linalg.eigvals(Phi)))})
        more = [w for w in more if exact_work(n, len(seq), _snaps(fl, w)) <= EXACT_PERIOD_MAX_WORK]
        other = exact_gain_lower(data, seq, more, period=period)
        if other is not None and (value is None or other > value):
            value, where = other, "w = 0, pi and the poles' angles (above the float64 peak's)"
    if value is None:
        return None, "float64 witness, not a proof (its exact evaluation failed: singular or too many bits)"
    loop = "the deployed loop" if period["deployed"] else "the float64 loop data as exact rationals"
    return value, (f"witness gain evaluated exactly at {where} on {loop} "
                   f"(float64: {found.value / value - 1:+.2g} relative)")


#: The exact cost witness (:func:`exact_cost_witness`) runs where the period's intervals' bits, times 2n (the Stein
#: checks' elimination), are at most this (n = 20, five intervals of 53-80-bit data: ~1e4), ...
EXACT_COST_MAX_BITS = 1e5
#: ... for a prefix of at most this many intervals (each adds the interval's bits to the state's integers) ...
EXACT_PREFIX_MAX = 64
#: ... and prefix intervals times n^2 times the starts (x0: one; the trace: n) at most this (products of big
#: integers: n = 30, the trace, a prefix of 11 intervals took 0.3 s).
EXACT_PREFIX_WORK = 4e5


def _rebuildable(data: list[dict], modes, kind: str) -> bool:
    """Whether :func:`_exact_loop` rebuilds every loop mode of ``modes`` with the ``kind`` ("cost": S, "hinf": the
    channel) before any is built (the rebuild in Fractions costs ~0.2 s at n = 12, wasted where one mode lacks it)."""
    for s in modes:
        pl = data[s].get("plant")
        if pl is None or len(pl["F"]) > EXACT_LOOP_MAX_SAMPLES:
            return False
        if kind == "cost" and (pl["Q"] is None or data[s].get("S") is None):
            return False
        if kind == "hinf" and (pl["channel"] is None or data[s].get("B") is None):
            return False
    return True


def _exact_cost_modes(data: list[dict], modes) -> tuple[dict, bool]:
    """``({s: (A_s, S_s)}, deployed)``: each loop mode's interval map and stage cost as exact ``(N, s)`` pairs, the
    deployed loop rebuilt from F, G, K, Q, R (:func:`_exact_loop`) when every mode carries it, else the float64
    interval data taken as exact rationals (S symmetrized exactly)."""
    from .exact import dyadic, exact

    n = data[0]["A"].shape[0]
    rebuilt = _rebuildable(data, modes, "cost")
    loops = {s: _exact_loop(data[s]) for s in modes} if rebuilt else {}
    if rebuilt and all(lp is not None and lp[1] is not None for lp in loops.values()):
        out = {}
        for s, lp in loops.items():
            (NA, ta), (NS, ts) = dyadic(lp[0]), dyadic(lp[1])
            out[s] = ((np.array(NA, dtype=object).reshape(n, n), ta), (np.array(NS, dtype=object).reshape(n, n), ts))
        return out, True
    out = {}
    for s in modes:
        NS, ts = exact(data[s]["S"])
        out[s] = (exact(data[s]["A"]), (NS + NS.T, ts + 1))
    return out, False


def exact_cost_witness(data: list[dict], found: LowerBound, x0=None, weight=None, seconds_left=None,
                       history: np.ndarray | None = None) -> tuple[float | None, str]:
    """The cost witness ``found`` (:func:`lower_bound`: ``pattern[:lead]`` once, then ``pattern[lead:]`` forever)
    valued in exact arithmetic: ``(value, note)``, value a proven lower bound on that sequence's cost from ``x0``
    (``trace`` weighted by ``weight`` without it), or None with the reason the float64 value stays.

    The prefix's stage costs ``x' S_s x`` are summed exactly along the exact states (one per column of the moment's
    square root: x0, or the unit vectors weighted); the tail's cost from the last state, ``x' P_tail x``, is bounded
    below by a rational ``P_low <= P_tail`` whose Stein inequality ``S_per + Phi' P_low Phi - P_low > 0`` is checked
    exactly (:func:`solver.exact.stein_floor`, the transient witness's release floor).  On the deployed loop (F, G,
    K, Q, R in rationals) where the data carry it, else on the float64 interval data (docs/design.md §8.4, "Exact
    witness (cost)").  ``history`` (k x n): the map from x0 to the loop's state (a network's initial history; None:
    I)."""
    seq, lead = tuple(found.pattern), found.lead
    if not seq[lead:] or found.value is None or not np.isfinite(found.value) or found.value <= 0:
        return None, ""
    n = data[0]["A"].shape[0]
    prefix, tail = seq[:lead], seq[lead:]
    starts_count = 1 if x0 is not None else (n if history is None else np.asarray(history).shape[1])
    if len(prefix) > EXACT_PREFIX_MAX or len(prefix) * n * n * starts_count > EXACT_PREFIX_WORK or \
            exact_work(n, len(tail), True) > EXACT_PERIOD_MAX_WORK:
        return None, (f"float64 witness, not a proof (a prefix of {len(prefix)} and a period of {len(tail)} intervals "
                      f"of {n} states are above the exact evaluation's)")
    if out_of_time(seconds_left):
        return None, "float64 witness, not a proof (no time left for its exact evaluation)"
    try:
        return _exact_cost_value(data, found, prefix, tail, x0, weight, history)
    except (ValueError, ArithmeticError) as err:  # non-finite data, a singular or overflowing float64 step
        return None, f"float64 witness, not a proof (its exact evaluation failed: {err})"


def _exact_cost_value(data: list[dict], found: LowerBound, prefix, tail, x0, weight, history) -> tuple:
    """:func:`exact_cost_witness`'s evaluation, once its size passed."""
    from .exact import add as add_exact
    from .exact import bits, exact, identity, matmul, rational_down, stein_floor, transpose

    n = data[0]["A"].shape[0]
    mats, deployed = _exact_cost_modes(data, set(prefix) | set(tail))
    # the period's integers grow by each interval's bits, the Stein checks' (side n, Bareiss) n-fold on top: data of a
    # wide exponent range (a subnormal entry: 1100-bit integers) took 36 s at n = 20 before this cap
    grown = sum(max(bits(mats[k][0][0]), bits(mats[k][1][0])) for k in tail)
    if 2 * n * grown > EXACT_COST_MAX_BITS:
        return None, "float64 witness, not a proof (its period's integers are too wide for the exact evaluation)"

    def value_of(q):  # a 1 x 1 exact pair as a Fraction
        return Fraction(int(q[0][0, 0]), 1 << q[1])

    Phi, Sper = identity(n), (np.zeros((n, n), dtype=object) * 0, 0)
    for k in tail:
        A, S = mats[k]
        image = matmul(matmul(transpose(Phi), S), Phi)
        Sper = add_exact(Sper, image)
        Phi = matmul(A, Phi)
    sys = period_system(data, list(tail))
    try:
        Pt = lyapunov(sys["Phi"], sys["L"].T @ sys["L"])
    except np.linalg.LinAlgError:
        Pt = None
    Pl = None if Pt is None else stein_floor(Phi, Sper, Pt, sys["Phi"])
    if Pl is None:
        return None, "float64 witness, not a proof (its period's exact Stein check failed)"
    H = exact(np.eye(n) if history is None else np.asarray(history, dtype=float))
    if x0 is not None:
        starts = [(matmul(H, exact(np.asarray(x0, dtype=float).reshape(-1, 1))), Fraction(1))]
    else:
        w = np.ones(H[0].shape[1]) if weight is None else np.asarray(weight, dtype=float)
        starts = [((H[0][:, i:i + 1].copy(), H[1]), Fraction(float(w[i]))) for i in range(len(w)) if w[i] != 0]
    total = Fraction(0)
    for x, c in starts:
        for k in prefix:
            A, S = mats[k]
            total += c * value_of(matmul(matmul(transpose(x), S), x))
            x = matmul(A, x)
            if bits(x[0]) > EXACT_PERIOD_MAX_BITS:
                return None, "float64 witness, not a proof (its state's integers grew past the exact evaluation's)"
        total += c * value_of(matmul(matmul(transpose(x), Pl), x))
    if total <= 0:
        return None, "float64 witness, not a proof (its exact evaluation gave no positive bound)"
    value = rational_down(total)
    loop = "the deployed loop" if deployed else "the float64 loop data as exact rationals"
    return value, f"witness cost evaluated exactly on {loop} (float64: {found.value / value - 1:+.2g} relative)"


def exact_gain_lower(data: list[dict], seq=(0,), peak: float | None = None, points: int = 2001,
                     period: dict | None = None) -> float | None:
    """A proven lower bound on the l2 gain of the periodic pattern ``seq`` (loop-mode indices; one LTI loop:
    ``(0,)``): the exact lifted period (:func:`exact_period`, or ``period`` when given) evaluated at frequencies in
    exact arithmetic (:func:`_exact_gain_at`), the largest value.

    ``peak`` (rad/sample): the frequency where float64 found the pattern's largest gain (:func:`hinf_norm_peak`),
    the only one evaluated (or a sequence of frequencies).  Without it a float64 sweep of ``points`` frequencies locates the peaks, and w = 0, pi,
    the poles' angles and the sweep's best points are evaluated (the one-loop exact certificate, docs/design.md
    §8.5: the float64 sweep was 4e-4 above the gain of a loop whose Lyapunov matrices span 1e13, and 7e-8 low at
    a peak at w = 0).  None without a channel or where no evaluation succeeds (``period`` None and ``peak`` None:
    the deployed loop only, as the exact certificate it goes with).
    """
    if period is None:
        period = exact_period(data, tuple(seq), deployed=True if peak is None else None)
    if period is None:
        return None
    if peak is not None:
        candidates = [float(w) for w in np.atleast_1d(peak)]
    else:
        sys = period_system(data, tuple(seq))
        omega = np.linspace(0.0, np.pi, points)
        values = _sigma_max(sys, omega)
        # the ends and the poles' angles too: the float64 values can be wrong enough to miss a peak at w = 0
        # (hold-out seed 31: 7e-8 low there, and the sweep's best point elsewhere)
        candidates = [0.0, float(np.pi)] + [float(w) for w in np.abs(np.angle(np.linalg.eigvals(sys["Phi"])))]
        candidates += [float(omega[i]) for i in np.argsort(values)[-3:]]
        for i in np.argsort(values)[-3:]:
            lo, hi = omega[max(i - 1, 0)], omega[min(i + 1, points - 1)]
            res = scipy.optimize.minimize_scalar(lambda w: -_sigma_max(sys, w)[0], bounds=(lo, hi),
                                                 method="bounded", options={"xatol": 1e-12})
            candidates.append(float(res.x))
    best = None
    for w in candidates:
        f = _exact_gain_at(period, w)
        if f is not None:
            best = f if best is None else max(best, f)
    return best
