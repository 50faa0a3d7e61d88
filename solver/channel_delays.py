"""Channels that deliver packets late: per-packet delays on a Markov loss chain.

A :class:`DelayedChannel` is a :class:`~solver.channel.Channel` (loss chain ``T``, ``loss``)
whose effective packets arrive ``tau`` samples after they are sent, ``tau`` drawn independently
per packet from ``delays`` (``delays[a]`` = P(tau = a | not lost), ``a = 0..D``).  The actuator's
buffer keeps the newest stamp it has received (an older packet never replaces a newer one), so
its age ``d(t) = t - stamp`` obeys ``d(t+1) = d(t) + 1`` or a smaller age, as in
``Network.delays`` (docs/design.md, "Networks").

The age process is Markov on ``(c_t, c_{t-1}, ..., c_{t-D+1}, d)``: a stamp ``s`` newer than
the buffer has not arrived, and, given its channel state ``c_s``, arrives at age ``a`` with the
hazard ``h_c(a) = (1 - loss_c) delays[a] / (1 - (1 - loss_c) sum_{b<a} delays[b])``,
independently of the other stamps.  The newest arrival wins.  Times the plant mode, this is a
Markov jump linear system on ``z = (x(t), ..., x(t-W+1)) [+ x(t-d)]`` (``W = max(D, 1)``; the
stamp block only when ``d >= W``): :func:`build_delayed_loop` gives a :class:`solver.mjls.Loop`
and every certificate of :mod:`solver.mjls` applies unchanged.  With ``delays = [1]`` the loop is
exactly today's (same modes, dimensions and matrices).

:func:`weakly_hard_violation_rate` is the exact rate at which a window constraint "at most m
samples without a fresh packet in any K" breaks: the stationary age process run forward over a
window, counting misses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .channel import STOCHASTIC_TOL, Channel, _positive_int
from .errors import InvalidInput

def check_delays(delays) -> np.ndarray:
    """Validate a delay pmf (``delays[a]`` = P(delay = a samples), a = 0..D) and trim trailing zeros."""
    try:
        pmf = np.array(delays, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidInput("delays must be a list of probabilities (delays[a] = P(delay = a samples))",
                           ("delays",)) from None
    if pmf.size == 0 or not np.all(np.isfinite(pmf)) or np.any(pmf < 0) or np.any(pmf > 1):
        raise InvalidInput("delays must be a non-empty list of probabilities in [0, 1]", ("delays",))
    total = float(pmf.sum())
    if abs(total - 1.0) > STOCHASTIC_TOL:
        raise InvalidInput(f"delays must sum to 1 (P(delay = a) for a = 0, 1, ...), got {total:.17g}", ("delays",))
    last = int(np.flatnonzero(pmf > 0)[-1])
    return pmf[:last + 1]  # not renormalized: a JSON round trip gives back the same numbers


@dataclass(frozen=True, eq=False)
class DelayedChannel(Channel):
    """A :class:`Channel` whose effective packets arrive late (module docstring).

    Parameters
    ----------
    transition, loss, names
        As :class:`Channel`: the loss chain (``loss[c]``: the packet sent in state c never arrives).
    delays : array_like, shape (D + 1,)
        ``delays[a]`` = P(an effective packet arrives ``a`` samples after it was sent); sums to 1.

    Attributes
    ----------
    max_delay : int
        D, the largest delay with positive probability.
    """

    delays: np.ndarray | None = None

    def __post_init__(self):
        super().__post_init__()
        if self.delays is None:
            raise InvalidInput("a DelayedChannel needs delays (a pmf over 0, 1, ... samples)", ("delays",))
        object.__setattr__(self, "delays", check_delays(self.delays))

    @property
    def max_delay(self) -> int:
        return int(self.delays.size - 1)

    def to_dict(self) -> dict:
        out = super().to_dict()
        out["delays"] = self.delays.tolist()
        return out

    def hazard(self, c: int, a: int) -> float:
        """P(a pending packet sent in state ``c`` arrives at age ``a`` | not arrived before)."""
        if a >= self.delays.size:
            return 0.0
        keep = 1.0 - self.loss[c]
        before = 1.0 - keep * float(self.delays[:a].sum())
        return 0.0 if before <= 0 else min(1.0, keep * float(self.delays[a]) / before)

    def sample_arrivals(self, steps: int, rng: np.random.Generator, size: int | None = None):
        """Channel states, effective flags and delays (-1 for lost packets), the chain stationary at 0.

        Returns
        -------
        states, effective : ndarray, shape (size, steps) (or (steps,))
        delay : ndarray of int, same shape: the delay of each sample's packet, -1 if lost.
        """
        states, effective = self.sample(steps, rng, size=size)
        cum = np.cumsum(self.delays)
        cum[-1] = 1.0
        tau = np.searchsorted(cum, rng.random(np.shape(effective)), side="right").clip(0, self.max_delay)
        return states, effective, np.where(effective, tau, -1)


def ages_from_arrivals(delay: np.ndarray) -> np.ndarray:
    """Buffer ages per sample from per-packet delays (-1: lost), sample 0's packet treated as fresh.

    ``delay`` has shape (runs, steps); the newest stamp received by sample t wins.
    """
    delay = np.atleast_2d(delay)
    runs, steps = delay.shape
    newest = np.full((runs, steps), -1, dtype=np.int64)
    s_idx = np.arange(steps)
    for s in range(steps):  # packet s lands at s + delay
        ok = delay[:, s] >= 0
        t = s + delay[:, s]
        ok &= t < steps
        rows = np.flatnonzero(ok)
        newest[rows, t[rows]] = np.maximum(newest[rows, t[rows]], s)
    newest[:, 0] = 0
    newest = np.maximum.accumulate(newest, axis=1)
    return s_idx[None, :] - newest


# ------------------------------------------------------------------------- the age chain
def _age_steps(channel: Channel, key: tuple, d: int, cap: int, cn: int):
    """Next (key, age, probability) from ``(key, d)`` when the next channel state is ``cn``.

    ``key[j]`` is the channel state of stamp ``t - j`` (None when that stamp cannot matter);
    ``cap`` merges ages >= cap.
    """
    pmf = _delays_of(channel)
    D = pmf.size - 1
    W = max(D, 1)
    full = (cn,) + tuple(key)  # full[a]: channel state of stamp t + 1 - a
    out = []
    if D == 0:  # today's chain, bit for bit: effective with 1 - loss, else the age grows
        survive = channel.loss[cn]
        if survive < 1:
            out.append((0, 1.0 - channel.loss[cn]))
    else:
        survive = 1.0
        for a in range(0, min(d, D) + 1):
            h = channel.hazard(full[a], a)
            if h > 0:
                out.append((a, survive * h))
            survive *= 1.0 - h
    if survive > 0:
        out.append((min(d + 1, cap), survive))
    res = []
    for d2, p in out:
        k2 = tuple(full[j] if (j == 0 or j < d2) else None for j in range(W))
        res.append((k2, d2, p))
    return res


def _delays_of(channel: Channel) -> np.ndarray:
    return channel.delays if isinstance(channel, DelayedChannel) else np.ones(1)


def _hazard_any(channel):
    if isinstance(channel, DelayedChannel):
        return channel
    return DelayedChannel(channel.transition, channel.loss, channel.names, delays=[1.0])


def age_chain(channel: Channel, cap: int):
    """The age process as a Markov chain: states ``(key, d)`` reachable from ``d = 0``, sparse transitions.

    Returns
    -------
    states : list of (key, d)
    P : scipy.sparse.csr_matrix, row-stochastic
    initial : ndarray (the chain's stationary channel state with d = 0)
    """
    ch = _hazard_any(channel)
    W = max(ch.max_delay, 1)
    pi = ch.stationary
    start = [((c,) + (None,) * (W - 1), 0) for c in range(ch.n_states) if pi[c] > 0]
    index = {s: i for i, s in enumerate(start)}
    states = list(start)
    rows, cols, vals = [], [], []
    queue = list(start)
    while queue:
        s = queue.pop()
        key, d = s
        for cn in range(ch.n_states):
            pt = ch.transition[key[0], cn]
            if pt == 0:
                continue
            for k2, d2, p in _age_steps(ch, key, d, cap, cn):
                dst = (k2, d2)
                if dst not in index:
                    index[dst] = len(states)
                    states.append(dst)
                    queue.append(dst)
                rows.append(index[s])
                cols.append(index[dst])
                vals.append(pt * p)
    P = sp.csr_matrix((vals, (rows, cols)), shape=(len(states), len(states)))
    initial = np.zeros(len(states))
    for i, (key, d) in enumerate(states):
        if d == 0 and all(k is None for k in key[1:]):
            initial[i] = pi[key[0]]
    return states, P, initial


def _stationary(P: sp.csr_matrix, initial: np.ndarray) -> np.ndarray:
    """Stationary distribution of the chain's recurrent class reached from ``initial`` (one class assumed).

    Fixes the mass of the start state and solves the rest (sparse, no dense normalization row: its
    fill-in would make large chains quadratic); a transient start or several classes fall back to the
    Cesaro mean from ``initial``.
    """
    n = P.shape[0]
    if n == 1:
        return np.ones(1)
    k = int(np.argmax(initial))
    A = (P.T - sp.identity(n, format="csr")).tocsr()
    keep = np.flatnonzero(np.arange(n) != k)
    x = None
    with np.errstate(all="ignore"):
        try:
            red = spla.spsolve(A[keep][:, keep].tocsc(), -A[keep][:, [k]].toarray().ravel())
            x = np.insert(np.atleast_1d(red), k, 1.0)
        except RuntimeError:
            x = None
    if x is None or not np.all(np.isfinite(x)) or np.any(x < -1e-9 * np.max(np.abs(x))) \
            or np.abs(A @ x).max() > 1e-9 * np.abs(x).sum():
        x = initial.copy()
        avg = np.zeros(n)
        for _ in range(20_000):
            x = P.T @ x
            avg += x
        x = avg
    x = np.clip(x, 0.0, None)
    return x / x.sum()


def exhaustion_rate(channel: Channel, n_drop: int) -> float:
    """Probability per sample (stationary) that the buffer's age reaches ``n_drop`` (a burst starts)."""
    states, P, initial = age_chain(channel, n_drop)
    pi = _stationary(P, initial)
    P = P.tocoo()
    ages = np.array([d for _, d in states])
    mask = (ages[P.row] == n_drop - 1) & (ages[P.col] == n_drop)
    return float(np.sum(pi[P.row[mask]] * P.data[mask]))


@dataclass
class WindowViolations:
    """How often a channel breaks "at most ``misses`` samples without a fresh packet in any ``window``".

    Attributes
    ----------
    misses, window : int
    n_drop : int or None
        When given, a sample whose buffer age is ``>= n_drop`` also counts as a violation.
    rate : float
        Stationary probability that the window ending at a sample breaks the constraint.
    rate_per_second : float or None
    mean_time_between : float
        ``1 / rate`` samples (inf when the constraint never breaks); for rare, isolated violations.
    miss_fraction : float
        Stationary probability that a sample has no fresh packet (age > 0).
    states : int
        Size of the recursion (age states times ``misses + 2`` counts).
    """

    misses: int
    window: int
    n_drop: int | None
    rate: float
    rate_per_second: float | None
    mean_time_between: float
    miss_fraction: float
    states: int

    def to_dict(self) -> dict:
        return {"misses": self.misses, "window": self.window, "n_drop": self.n_drop, "rate": self.rate,
                "rate_per_second": self.rate_per_second,
                "mean_time_between": None if not np.isfinite(self.mean_time_between) else self.mean_time_between,
                "miss_fraction": self.miss_fraction, "states": self.states}


def weakly_hard_violation_rate(channel: Channel, misses: int, window: int, n_drop: int | None = None,
                               sampling_period: float | None = None) -> WindowViolations:
    """Exact rate at which the window constraint breaks on ``channel`` (delays included when it has them).

    A *miss* is a sample whose buffer holds no fresh packet (age > 0: lost, or late).  A sample
    violates when the window ending there holds more than ``misses`` misses (or, with ``n_drop``, when
    its age is ``>= n_drop``); from the stationary age process, the probability of that is a forward
    recursion over the window on (age state, misses so far), exact by the Markov property.

    Parameters
    ----------
    channel : Channel or DelayedChannel
    misses : int
        m >= 0, at most m misses in any window.
    window : int
        K >= 1 samples, m < K.
    n_drop : int, optional
    sampling_period : float, optional
        h in seconds, for ``rate_per_second``.
    """
    from .channel import _period

    if not isinstance(channel, Channel):
        raise InvalidInput("channel must be a Channel", ("channel",))
    if isinstance(misses, bool) or not isinstance(misses, (int, np.integer)) or misses < 0:
        raise InvalidInput(f"misses must be an integer >= 0, got {misses!r}", ("misses",))
    window = _positive_int("window", window)
    if misses >= window:
        raise InvalidInput(f"misses ({misses}) must be < window ({window}): otherwise nothing is constrained",
                           ("misses",))
    if n_drop is not None:
        n_drop = _positive_int("n_drop", n_drop)
    h = _period(sampling_period)
    D = int(_delays_of(channel).size - 1)
    cap = max(D + 1, 1 if n_drop is None else n_drop)
    states, P, initial = age_chain(channel, cap)
    ages = np.array([d for _, d in states])
    miss = ages > 0
    pi = _stationary(P, initial)
    # Forward over the window from the stationary age process: v[s, c] = P(age state s, c misses so far),
    # c capped at misses + 1 (already broken); the Markov property makes this exact, with no window histories.
    PT = P.T.tocsr()
    v = np.zeros((len(states), misses + 2))
    v[:, 0] = np.where(miss, 0.0, pi)
    v[:, 1] = np.where(miss, pi, 0.0)
    for _ in range(window - 1):
        w = PT @ v
        v = np.zeros_like(w)
        v[~miss] = w[~miss]
        v[miss, 1:] = w[miss, :-1]
        v[miss, -1] += w[miss, -1]
    broken = v[:, -1].copy()
    if n_drop is not None:
        last = ages >= n_drop
        broken[last] = v[last].sum(axis=1)
    rate = float(min(max(broken.sum(), 0.0), 1.0))
    return WindowViolations(misses=int(misses), window=window, n_drop=n_drop, rate=rate,
                            rate_per_second=None if h is None else rate / h,
                            mean_time_between=1.0 / rate if rate > 0 else float("inf"),
                            miss_fraction=float(pi[miss].sum()), states=len(states) * (misses + 2))


def monte_carlo_violations(channel: Channel, misses: int, window: int, n_drop: int | None = None, *,
                           runs: int = 2000, steps: int = 2000, burn_in: int = 200, seed: int = 0):
    """Fraction of samples whose window breaks the constraint, by simulation: (mean, standard error)."""
    rng = np.random.Generator(np.random.PCG64(int(seed)))
    ch = _hazard_any(channel)
    _, _, delay = ch.sample_arrivals(steps, rng, size=runs)
    ages = ages_from_arrivals(delay)
    miss = (ages > 0).astype(np.int64)
    c = np.cumsum(miss, axis=1)
    c = np.concatenate([np.zeros((runs, 1), dtype=np.int64), c], axis=1)
    counts = c[:, window:] - c[:, :-window]  # window ending at sample t (t = window - 1 ..)
    bad = counts > misses
    if n_drop is not None:
        bad |= ages[:, window - 1:] >= n_drop
    per_run = bad[:, burn_in:].mean(axis=1)
    return float(per_run.mean()), float(per_run.std(ddof=1) / np.sqrt(runs))


# ------------------------------------------------------------------------- the jump linear system
def build_delayed_loop(F, G, K, channel: Channel, plant_transitions, exhausted: str, weights=None):
    """The MJLS of the predictive loop on a delayed channel (module docstring); a :class:`solver.mjls.Loop`.

    Modes are ``(key, l, d)`` (key: the channel states that matter, see :func:`age_chain`).
    """
    from .mjls import U, Loop, Transition, _sym

    ch = _hazard_any(channel)
    r, n, _ = F.shape
    m = G.shape[2]
    N = K.shape[0]
    D = ch.max_delay
    if D > N - 1:
        raise InvalidInput(f"the channel's delays reach {D} samples but the buffer holds n_drop = {N} gains: "
                           f"packets later than n_drop - 1 = {N - 1} samples cannot be applied; use n_drop >= "
                           f"{D + 1} or fold those delays into the loss", ("channel", "delays"))
    W = max(D, 1)
    zero_exhaust = exhausted == "zero"
    Pi = plant_transitions

    def has_stamp(d):
        return d >= W and not (d == N and zero_exhaust)

    def dim(d):
        return n * (W + (1 if has_stamp(d) else 0))

    def sel(d, j):
        """Selector (n, dim(d)) of x(t - j) in z(t) at age d (j < W: window block; else the stamp block)."""
        S = np.zeros((n, dim(d)))
        b = j if j < W else W
        S[:, b * n:(b + 1) * n] = np.eye(n)
        return S

    def gain(d):
        if d < N:
            return K[d]
        return None if zero_exhaust else K[N - 1]

    cache = {}

    def matrices(l, d, d2, arrived):
        key = (l, d, d2, arrived)
        if key in cache:
            return cache[key]
        Kd = gain(d)
        Ssrc = np.zeros((n, dim(d)))
        Ssrc[:, :n] = np.eye(n)
        X = F[l] @ Ssrc
        X_abs = np.abs(X)
        if Kd is not None:
            Sd = sel(d, d)
            GK = G[l] @ Kd
            X = X + GK @ Sd
            X_abs = X_abs + (np.abs(G[l]) @ np.abs(Kd)) @ Sd * (1 + (m + 2) * U * 2)
        rows = [X]
        rows_abs = [X_abs]
        for j in range(W - 1):  # x(t - j) moves to block j + 1
            s = sel(d, j)
            rows.append(s)
            rows_abs.append(s)
        if has_stamp(d2):
            s = sel(d, d) if not arrived else sel(d, d2 - 1)
            rows.append(s)
            rows_abs.append(s)
        A = np.vstack(rows)
        A_abs = np.vstack(rows_abs)
        cache[key] = (A, A_abs)
        return A, A_abs

    pi = ch.stationary
    w0 = np.full(r, 1.0 / r)
    start = [((c,) + (None,) * (W - 1), l, 0) for c in range(ch.n_states) for l in range(r) if pi[c] > 0]
    index = {s: i for i, s in enumerate(start)}
    modes = list(start)
    raw = []
    queue = list(start)
    while queue:
        src = queue.pop()
        key, l, d = src
        for cn in range(ch.n_states):
            pt = ch.transition[key[0], cn]
            if pt == 0:
                continue
            steps = _age_steps(ch, key, d, N, cn)
            for ln in range(r):
                if Pi[l, ln] == 0:
                    continue
                for k2, d2, pa in steps:
                    p = pt * Pi[l, ln] * pa
                    if p == 0:
                        continue
                    dst = (k2, ln, d2)
                    if dst not in index:
                        index[dst] = len(modes)
                        modes.append(dst)
                        queue.append(dst)
                    arrived = d2 != min(d + 1, N)  # an arrival's age is <= D < n_drop
                    A, A_abs = matrices(l, d, d2, arrived)
                    raw.append((index[src], index[dst], p, A, A_abs))
    dims = np.array([dim(md[2]) for md in modes])
    transitions = [Transition(s, t, p, A, A_abs) for s, t, p, A, A_abs in raw]
    in_degree = np.bincount([t.dst for t in transitions], minlength=len(modes))
    out_degree = np.bincount([t.src for t in transitions], minlength=len(modes))
    # As solver.mjls.build_loop, plus the hazards' few operations per arrival probability.
    k = 2 * int(dims.max()) + max(int(in_degree.max()), int(out_degree.max())) + m + 12 + 6 * (D + 1)
    gamma = 2.0 * k * U / (1 - k * U)
    initial = np.zeros(len(modes))
    for i, (key, l, d) in enumerate(modes):
        if d == 0 and all(c is None for c in key[1:]):
            initial[i] = pi[key[0]] * w0[l]
    loop = Loop(modes=modes, dims=dims, transitions=transitions, initial=initial, n=n, gamma=gamma)
    loop.source = {}  # no exact re-computation of these transitions: certify_cycle is skipped
    loop.embed = [np.vstack([np.eye(n), np.zeros((dm - n, n))]) for dm in dims]
    if weights is not None:
        Qw, Rw = weights
        stage, stage_err = [], []
        for (_, l, d), dm in zip(modes, dims):
            E0 = np.zeros((n, dm))
            E0[:, :n] = np.eye(n)
            S = E0.T @ Qw @ E0
            S_abs = np.abs(S)
            Kd = gain(d)
            if Kd is not None:
                KS = Kd @ sel(d, d)
                S = S + KS.T @ Rw @ KS
                S_abs = S_abs + (np.abs(Kd) @ sel(d, d)).T @ np.abs(Rw) @ (np.abs(Kd) @ sel(d, d))
            stage.append(_sym(S))
            stage_err.append(2 * (2 * m + 4) * U * float(np.linalg.norm(S_abs)))
        loop.stage = stage
        loop.stage_err = np.array(stage_err)
    return loop


def initial_moments(loop) -> list:
    """``E[z(0) z(0)' 1{mode}]`` with ``E[x(0) x(0)'] = I`` and no past (``x(t) = 0`` for t < 0)."""
    out = []
    for i, dm in enumerate(loop.dims):
        X = np.zeros((dm, dm))
        if loop.initial[i] > 0:
            X[:loop.n, :loop.n] = loop.initial[i] * np.eye(loop.n)
        out.append(X)
    return out


def monte_carlo_delayed_cost(family, K, channel: Channel, Qw, Rw, exhausted, Pi, kind, runs, horizon, rng):
    """Per-run costs ``sum_{k < horizon} x'Qx + u'Ru`` on a delayed channel (x(0) ~ N(0, I))."""
    ch = _hazard_any(channel)
    r, n = family.n_modes, family.n_states
    N = K.shape[0]
    _, _, delay = ch.sample_arrivals(horizon, rng, size=runs)
    delay[:, 0] = np.where(delay[:, 0] >= 0, delay[:, 0], 0)
    ages = ages_from_arrivals(delay)
    x = rng.standard_normal((runs, n))
    plant = rng.integers(0, r, size=runs)
    draws = rng.random((horizon, runs))
    F, G = np.asarray(family.F, dtype=np.float64), np.asarray(family.G, dtype=np.float64)
    cum = np.cumsum(Pi, axis=1)
    cum[:, -1] = 1.0
    hist = np.zeros((horizon, runs, n))
    cost = np.zeros(runs)
    rr = np.arange(runs)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(horizon):
            hist[k] = x
            age = ages[:, k]
            xm = hist[k - age, rr]
            u = np.einsum("rij,rj->ri", K[np.minimum(age, N - 1)], xm)
            if exhausted == "zero":
                u[age >= N] = 0.0
            cost += np.einsum("ri,ij,rj->r", x, Qw, x) + np.einsum("ri,ij,rj->r", u, Rw, u)
            x = np.einsum("rij,rj->ri", F[plant], x) + np.einsum("rij,rj->ri", G[plant], u)
            if kind != "stay":
                plant = np.minimum((draws[k][:, None] >= cum[plant]).sum(axis=1), r - 1)
    return cost


def _network_spec(network) -> dict:
    """The network's JSON form (a :class:`solver.Network` or its ``to_dict()``)."""
    from .networks import check_network

    return check_network(network).to_dict()


def network_violations(channel: Channel, network, sampling_period: float | None = None) -> dict:
    """Exact rate at which the channel's age sequence breaks the network's constraint.

    ``bounded_drops``/``delays``: stationary probability that a sample's age step is not an edge of
    the network (``d >= n_drop``, a late packet the network does not allow); ``weakly_hard``:
    :func:`weakly_hard_violation_rate` with the network's ``n_drop`` (late packets count as misses).
    """
    from .channel import _period

    spec = _network_spec(network)
    kind = spec.get("kind")
    h = _period(sampling_period)
    if kind == "weakly_hard":
        res = weakly_hard_violation_rate(channel, spec.get("misses"), spec.get("window"), spec.get("n_drop"),
                                         sampling_period=h)
        out = {k: v for k, v in res.to_dict().items() if k not in ("misses", "window", "n_drop")}
        out.update(network=spec, what="windows with more than misses samples without a fresh packet, "
                                       "or age >= n_drop")
        return out
    if kind not in ("bounded_drops", "delays"):
        raise InvalidInput(f"a channel's violation rate covers bounded_drops, delays and weakly_hard networks, "
                           f"not {kind!r}", ("network", "kind"))
    n_drop = _positive_int("n_drop", spec.get("n_drop"))
    lo = int(spec.get("min_delay", 0) or 0)
    hi = int(spec.get("max_delay", 0) or 0)
    D = int(_delays_of(channel).size - 1)
    states, P, initial = age_chain(channel, max(n_drop, D + 1))
    pi = _stationary(P, initial)
    P = P.tocoo()
    ages = np.array([d for _, d in states])
    d, d2 = ages[P.row], ages[P.col]
    late = (d2 < d + 1)
    ok = (d2 <= n_drop - 1) & (~late | ((d2 >= lo) & (d2 <= hi)))
    rate = float(np.sum(pi[P.row[~ok]] * P.data[~ok]))
    return {"network": spec, "rate": rate, "rate_per_second": None if h is None else rate / h,
            "mean_time_between": 1.0 / rate if rate > 0 else None,
            "what": "samples whose age step is not allowed (age >= n_drop, or a packet arriving with a delay "
                    "outside [min_delay, max_delay])"}
