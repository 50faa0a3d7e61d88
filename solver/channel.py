"""Packet channels as finite Markov chains, and how often they break the drop bound.

A :class:`Channel` is a Markov chain over channel states ``c`` (transition matrix
``T``, ``T[c, c']`` = probability of state ``c'`` at the next sample) and, per state,
the probability ``loss[c]`` that the sample's transmission is *not effective* (the
sensor or the control packet is lost, Sec. II.E).  Given the state, losses are
independent of everything else.  Conventions (docs/design.md, "Stochastic channels"):
the chain runs once per sample and starts in its stationary distribution ``pi``.

A *burst* is a run of ``>= n_drop`` consecutive non-effective samples: the
paper's guarantee needs at most ``n_drop - 1``.  With ``D_e = diag(1 - loss)``,
``D_l = diag(loss)`` the probability that a burst starts at a given sample
(the previous sample effective, the next ``n_drop`` lost) is exactly::

    rate(n_drop) = pi D_e (T D_l)^n_drop 1          (Bernoulli: (1 - p) p^n_drop)

and, by renewal, the mean time between burst starts is ``1 / rate`` samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .compiled import solve_quietly
from .errors import InvalidInput
from .workload import channel_operator_size, check_channel

#: Row sums of a transition matrix may differ from 1 by this much (then they are normalized).
STOCHASTIC_TOL = 1e-9


def _probabilities(name: str, value, shape=None) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInput(f"{name} must hold numbers in [0, 1]", (name,)) from None
    if shape is not None and arr.shape != shape:
        raise InvalidInput(f"{name} must have shape {shape}, got {arr.shape}", (name,))
    if not np.all(np.isfinite(arr)) or np.any(arr < 0) or np.any(arr > 1):
        raise InvalidInput(f"{name} must hold probabilities in [0, 1]", (name,))
    return arr


def check_stochastic(name: str, matrix, size: int | None = None) -> np.ndarray:
    """Validate a row-stochastic matrix (rows: probabilities of the next state) and return it."""
    try:
        T = np.array(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInput(f"{name} must be a square matrix of probabilities", (name,)) from None
    if T.ndim != 2 or T.shape[0] != T.shape[1] or T.shape[0] < 1:
        raise InvalidInput(f"{name} must be a square matrix, got shape {T.shape}", (name,))
    if size is not None and T.shape[0] != size:
        raise InvalidInput(f"{name} must be {size} x {size}, got {T.shape}", (name,))
    if not np.all(np.isfinite(T)) or np.any(T < 0) or np.any(T > 1):
        raise InvalidInput(f"{name} must hold probabilities in [0, 1]", (name,))
    sums = T.sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > STOCHASTIC_TOL)
    if bad.size:
        raise InvalidInput(f"row {int(bad[0])} of {name} sums to {float(sums[bad[0]]):.17g}, not 1",
                           (name, int(bad[0])))
    return T / sums[:, None]


def stationary_distribution(T: np.ndarray, name: str = "transition") -> np.ndarray:
    """The unique stationary distribution of an irreducible chain (InvalidInput if not unique)."""
    c = T.shape[0]
    A = np.vstack([T.T - np.eye(c), np.ones((1, c))])
    b = np.zeros(c + 1)
    b[-1] = 1.0
    if np.linalg.matrix_rank(A, tol=1e-10) < c:
        raise InvalidInput(f"{name} has more than one stationary distribution (the chain is reducible)", (name,))
    pi = np.linalg.lstsq(A, b, rcond=None)[0]
    pi = np.clip(pi, 0.0, None)
    return pi / pi.sum()


@dataclass
class BurstStatistics:
    """How often a channel breaks the drop bound ``n_drop`` (exact, from the chain).

    Attributes
    ----------
    n_drop : int
    rate : float
        Probability per sample that a run of ``>= n_drop`` non-effective samples starts.
    rate_per_second : float or None
        ``rate / h`` when the sampling period h is known.
    mean_time_between : float
        ``1 / rate`` samples (inf when no burst can happen).
    mean_time_between_seconds : float or None
    loss_fraction : float
        Stationary probability that a sample is not effective.
    mean_run_length : float
        Mean length of a maximal run of non-effective samples (samples); nan if none occur.
    run_length_pmf : ndarray, shape (max_length,)
        ``P(run length = l)`` for ``l = 1..max_length`` (entry l-1).
    run_length_tail : float
        ``P(run length > max_length)``.
    sampling_period : float or None
    never_delivers : bool
        The link delivers a sample with stationary probability below :data:`DEAD_LINK_DELIVERY` (a loss
        fraction of 1: one run of losses that never ends).  Then ``rate`` is 1 (the bound is broken at every
        sample), ``mean_time_between`` 1 sample, ``mean_run_length`` and ``run_length_tail`` infinite and 1:
        counting runs from a delivered sample would have reported no bursts at all.
    """

    n_drop: int
    rate: float
    rate_per_second: float | None
    mean_time_between: float
    mean_time_between_seconds: float | None
    loss_fraction: float
    mean_run_length: float
    run_length_pmf: np.ndarray
    run_length_tail: float
    sampling_period: float | None
    never_delivers: bool = False

    def to_dict(self) -> dict:
        def num(x):
            return None if x is None or not np.isfinite(x) else float(x)

        return {
            "n_drop": self.n_drop,
            "rate": self.rate,
            "rate_per_second": num(self.rate_per_second),
            "mean_time_between": num(self.mean_time_between),
            "mean_time_between_seconds": num(self.mean_time_between_seconds),
            "loss_fraction": self.loss_fraction,
            "mean_run_length": num(self.mean_run_length),
            "run_length_pmf": self.run_length_pmf.tolist(),
            "run_length_tail": self.run_length_tail,
            "sampling_period": self.sampling_period,
            "never_delivers": self.never_delivers,
        }


@dataclass(frozen=True, eq=False)
class Channel:
    """A packet channel: a Markov chain whose state sets the loss probability of each sample.

    Parameters
    ----------
    transition : array_like, shape (c, c)
        Row-stochastic, per sample: ``transition[i, j]`` = P(state j next | state i).
        The chain must be irreducible (one stationary distribution).
    loss : array_like, shape (c,)
        Per state, the probability that a sample's transmission is not effective.
    names : tuple of str, optional
        State labels.

    Attributes
    ----------
    stationary : ndarray, shape (c,)
        Stationary distribution ``pi`` (the chain's state at sample 0).
    """

    transition: np.ndarray
    loss: np.ndarray
    names: tuple | None = None

    def __post_init__(self):
        T = check_stochastic("transition", self.transition)
        loss = _probabilities("loss", self.loss, shape=(T.shape[0],))
        object.__setattr__(self, "transition", T)
        object.__setattr__(self, "loss", loss)
        object.__setattr__(self, "_pi", stationary_distribution(T))
        if self.names is not None:
            names = tuple(str(s) for s in self.names)
            if len(names) != T.shape[0]:
                raise InvalidInput(f"names must have {T.shape[0]} entries", ("names",))
            object.__setattr__(self, "names", names)

    # ------------------------------------------------------------ constructors
    @classmethod
    def bernoulli(cls, loss: float) -> "Channel":
        """Independent losses with probability ``loss`` per sample (one state)."""
        p = _probabilities("loss", loss, shape=())
        return cls(np.ones((1, 1)), np.array([float(p)]), names=("bernoulli",))

    @classmethod
    def gilbert_elliott(cls, p_gb: float, p_bg: float, loss_good: float = 0.0, loss_bad: float = 1.0) -> "Channel":
        """Two states, good and bad: ``p_gb`` = P(good -> bad), ``p_bg`` = P(bad -> good) per sample."""
        p_gb = float(_probabilities("p_gb", p_gb, shape=()))
        p_bg = float(_probabilities("p_bg", p_bg, shape=()))
        if p_gb + p_bg == 0:
            raise InvalidInput("p_gb and p_bg cannot both be 0 (the chain would never leave its state)", ("p_gb",))
        lg = float(_probabilities("loss_good", loss_good, shape=()))
        lb = float(_probabilities("loss_bad", loss_bad, shape=()))
        return cls([[1 - p_gb, p_gb], [p_bg, 1 - p_bg]], [lg, lb], names=("good", "bad"))

    @classmethod
    def combine(cls, sensor: "Channel", control: "Channel") -> "Channel":
        """One chain for independent sensor and control links: effective iff both packets arrive.

        The state is the pair (sensor state, control state), ``transition = kron(T_s, T_c)``,
        ``loss = 1 - (1 - loss_s) (1 - loss_c)``.
        """
        for name, ch in (("sensor", sensor), ("control", control)):
            if not isinstance(ch, Channel):
                raise InvalidInput(f"{name} must be a Channel", (name,))
        T = np.kron(sensor.transition, control.transition)
        loss = 1.0 - np.outer(1.0 - sensor.loss, 1.0 - control.loss).reshape(-1)
        names = tuple(f"{a}/{b}" for a in sensor.state_names for b in control.state_names)
        return cls(T, loss, names=names)

    @classmethod
    def from_dict(cls, data: dict) -> "Channel":
        """``{"kind": "bernoulli", "loss": p}``, ``{"kind": "gilbert_elliott", "p_gb", "p_bg", "loss_good",
        "loss_bad"}`` or ``{"kind": "markov", "transition": [[...]], "loss": [...]}``."""
        if not isinstance(data, dict):
            raise InvalidInput("channel must be an object", ("channel",))
        if data.get("delays") is not None:
            return cls.from_dict({k: v for k, v in data.items() if k != "delays"}).with_delays(data["delays"])
        kind = data.get("kind")
        try:
            if kind == "bernoulli":
                return cls.bernoulli(data["loss"])
            if kind == "gilbert_elliott":
                return cls.gilbert_elliott(data["p_gb"], data["p_bg"], data.get("loss_good", 0.0),
                                           data.get("loss_bad", 1.0))
            if kind == "markov":
                return cls(data["transition"], data["loss"], names=data.get("names"))
        except KeyError as err:
            raise InvalidInput(f"channel of kind {kind!r} needs {err.args[0]!r}", (err.args[0],)) from None
        raise InvalidInput("channel kind must be 'bernoulli', 'gilbert_elliott' or 'markov'", ("kind",))

    def with_delays(self, delays) -> "Channel":
        """This loss chain with per-packet delays: ``delays[a]`` = P(delay = a samples | not lost).

        Returns a :class:`solver.channel_delays.DelayedChannel`; ``analyze_channel`` then covers late
        and reordered packets (the newest stamp wins).
        """
        from .channel_delays import DelayedChannel

        return DelayedChannel(self.transition, self.loss, self.names, delays=delays)

    def to_dict(self) -> dict:
        return {"kind": "markov", "transition": self.transition.tolist(), "loss": self.loss.tolist(),
                "names": list(self.state_names), "stationary": self.stationary.tolist()}

    # -------------------------------------------------------------- properties
    @property
    def n_states(self) -> int:
        return self.transition.shape[0]

    @property
    def stationary(self) -> np.ndarray:
        return self._pi.copy()

    @property
    def state_names(self) -> tuple:
        return self.names if self.names is not None else tuple(f"s{i}" for i in range(self.n_states))

    @property
    def loss_fraction(self) -> float:
        """Stationary probability that a sample is not effective."""
        return float(self._pi @ self.loss)

    @property
    def never_delivers(self) -> bool:
        """Whether the link delivers a sample with stationary probability below :data:`DEAD_LINK_DELIVERY`
        (``Channel.bernoulli(1.0)``, a Gilbert-Elliott link whose bad state is absorbing and always loses)."""
        return float(self._pi @ (1.0 - self.loss)) < DEAD_LINK_DELIVERY

    def dead_link_reason(self) -> str:
        delivered = float(self._pi @ (1.0 - self.loss))
        return (f"the channel never delivers a sample: its stationary delivery probability is {delivered:.3g} "
                f"(loss fraction {self.loss_fraction:.12g}), below {DEAD_LINK_DELIVERY:g}; every run of losses "
                "is endless, so no drop bound n_drop holds")

    # ------------------------------------------------------------ statistics
    def _runs(self, length: int) -> np.ndarray:
        """Row vectors ``pi D_e (T D_l)^j`` for j = 0..length (shape (length + 1, c))."""
        step = self.transition * self.loss[None, :]
        out = np.empty((length + 1, self.n_states))
        out[0] = self._pi * (1.0 - self.loss)
        for j in range(1, length + 1):
            out[j] = out[j - 1] @ step
        return out

    def burst_rate(self, n_drop: int) -> float:
        """Probability per sample that a run of ``>= n_drop`` non-effective samples starts there."""
        n_drop = _positive_int("n_drop", n_drop)
        return float(self._runs(n_drop)[-1].sum())

    def burst_statistics(self, n_drop: int, sampling_period: float | None = None,
                         max_length: int | None = None) -> BurstStatistics:
        """Burst rate, mean time between bursts and the run-length distribution.

        Parameters
        ----------
        n_drop : int
            Drop bound: a burst is a run of at least ``n_drop`` non-effective samples.
        sampling_period : float, optional
            h in seconds, for rates per second.
        max_length : int, optional
            Length of the run-length distribution returned (default ``max(4 n_drop, 20)``).
        """
        n_drop = _positive_int("n_drop", n_drop)
        h = _period(sampling_period)
        L = max(4 * n_drop, 20) if max_length is None else _positive_int("max_length", max_length)
        if self.never_delivers:
            return BurstStatistics(
                n_drop=n_drop, rate=1.0, rate_per_second=None if h is None else 1.0 / h, mean_time_between=1.0,
                mean_time_between_seconds=h, loss_fraction=self.loss_fraction, mean_run_length=float("inf"),
                run_length_pmf=np.zeros(L), run_length_tail=1.0, sampling_period=h, never_delivers=True)
        at_least = self._runs(max(L + 1, n_drop)).sum(axis=1)  # P(effective, then >= j losses), j = 0..
        starts = at_least[1]
        rate = float(at_least[n_drop])
        if starts > 0:
            pmf = (at_least[1:L + 1] - at_least[2:L + 2]) / starts
            tail = float(at_least[L + 1] / starts)
            mean_run = self.loss_fraction / starts  # lost samples per run start (renewal)
        else:
            pmf, tail, mean_run = np.zeros(L), 0.0, float("nan")
        mtb = 1.0 / rate if rate > 0 else float("inf")
        return BurstStatistics(
            n_drop=n_drop, rate=rate, rate_per_second=None if h is None else rate / h,
            mean_time_between=mtb, mean_time_between_seconds=None if h is None else mtb * h,
            loss_fraction=self.loss_fraction, mean_run_length=float(mean_run),
            run_length_pmf=np.clip(pmf, 0.0, None), run_length_tail=max(tail, 0.0), sampling_period=h,
        )

    def smallest_n_drop(self, target_rate: float, sampling_period: float | None = None,
                        max_n_drop: int = 10_000) -> int | None:
        """The smallest ``n_drop`` whose burst rate is ``<= target_rate``.

        Parameters
        ----------
        target_rate : float
            Bursts per sample, or per second when ``sampling_period`` is given
            (once a year at h = 10 ms: ``target_rate = 1 / 31_557_600``, ``sampling_period=0.01``).
        max_n_drop : int
            Give up (return None) above this bound.

        Returns
        -------
        int or None
            None when no ``n_drop <= max_n_drop`` reaches the target.
        """
        try:
            target = float(target_rate)
        except (TypeError, ValueError):
            raise InvalidInput("target_rate must be a number >= 0", ("target_rate",)) from None
        if not np.isfinite(target) or target < 0:
            raise InvalidInput("target_rate must be a finite number >= 0", ("target_rate",))
        h = _period(sampling_period)
        per_sample = target if h is None else target * h
        if self.never_delivers:
            return None  # the run of losses never ends: no bound is ever met
        step = self.transition * self.loss[None, :]
        v = self._pi * (1.0 - self.loss)
        # The rate is non-increasing in n_drop (a longer run contains a shorter one).
        for n in range(1, int(max_n_drop) + 1):
            v = v @ step
            if v.sum() <= per_sample:
                return n
        return None

    # -------------------------------------------------------------- sampling
    def sample(self, steps: int, rng: np.random.Generator, size: int | None = None):
        """Draw channel states and effective flags, the state at sample 0 from ``pi``.

        Parameters
        ----------
        steps : int
        rng : numpy.random.Generator
        size : int, optional
            Number of independent chains (vectorized); None for one.

        Returns
        -------
        states : ndarray of int, shape (steps,) or (size, steps)
        effective : ndarray of bool, same shape
        """
        steps = _positive_int("steps", steps)
        shape = (1 if size is None else int(size),)
        # Fixed draw order: initial states, transitions, losses.
        u0 = rng.random(shape)
        u = rng.random((steps,) + shape)
        v = rng.random((steps,) + shape)
        cum = np.cumsum(self.transition, axis=1)
        cum[:, -1] = 1.0
        cum_pi = np.cumsum(self._pi)
        cum_pi[-1] = 1.0
        c = self.n_states
        states = np.empty((steps,) + shape, dtype=np.int64)
        s = np.searchsorted(cum_pi, u0, side="right").clip(0, c - 1)
        states[0] = s
        if c == 1:
            states[:] = 0
        else:
            for k in range(1, steps):
                s = (u[k][:, None] >= cum[s]).sum(axis=1).clip(0, c - 1)
                states[k] = s
        effective = v >= self.loss[states]
        states, effective = states.T, effective.T
        if size is None:
            return states[0], effective[0]
        return states, effective


#: Below this stationary probability of delivering a sample, a link is reported as never delivering.
DEAD_LINK_DELIVERY = 1e-9


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise InvalidInput(f"{name} must be an integer >= 1, got {value!r}", (name,))
    return int(value)


def _period(h) -> float | None:
    if h is None:
        return None
    try:
        h = float(h)
    except (TypeError, ValueError):
        raise InvalidInput("sampling_period must be a positive number", ("sampling_period",)) from None
    if not np.isfinite(h) or h <= 0:
        raise InvalidInput("sampling_period must be a positive number", ("sampling_period",))
    return h


# ======================================================================= the loop on a channel
@dataclass
class ChannelReport:
    """Result of :func:`analyze_channel`.

    Attributes
    ----------
    burst_rate : float
        Probability per sample that a run of ``>= n_drop`` non-effective samples starts.
    mean_time_between_bursts : float
        Samples (``inf`` if bursts cannot happen).
    mean_time_between_bursts_seconds : float or None
    bursts : BurstStatistics
    ms_stable : bool or None
        True: ``rho(L) < 1`` proven by a re-checked coupled Lyapunov certificate (or, for arbitrary
        plant jumps, the LMI's re-checked certificate). False: ``rho(L) >= 1`` proven by a
        first-return growth certificate. None: neither (``reason``).
    ms_radius : float or None
        Float64 spectral radius of the second-moment operator (an estimate; None for arbitrary jumps).
    ms_radius_upper, ms_radius_lower : float or None
        Proven bounds on that radius (the certificates' beta and mu).
    expected_cost : float or None
        ``E sum_k x'Qx + u'Ru`` (conventions of docs/design.md), from the linear equations; None
        when not mean-square stable or without weights.
    expected_cost_upper, expected_cost_lower : float or None
        Certified upper bound (re-checked ``P - L*(P) >= S``) and a lower bound from rigorously
        rounded partial sums.
    stationary_cost : float or None
        Cost per sample in the long run with process noise ``noise`` (covariance), when given.
    upper_certificate, lower_certificate : object or None
    exhausted : str
    plant_transitions : str
        ``"stay"``, ``"markov"`` or ``"arbitrary"``.
    n_modes : int
        Modes of the jump system (reachable (channel state, plant mode, buffer age)).
    reason : str
    """

    burst_rate: float
    mean_time_between_bursts: float
    mean_time_between_bursts_seconds: float | None
    bursts: BurstStatistics
    ms_stable: bool | None
    ms_radius: float | None
    ms_radius_upper: float | None
    ms_radius_lower: float | None
    expected_cost: float | None
    expected_cost_upper: float | None
    expected_cost_lower: float | None
    stationary_cost: float | None
    upper_certificate: object | None
    lower_certificate: object | None
    exhausted: str
    plant_transitions: str
    n_modes: int
    reason: str
    #: Set for a delayed channel: its delay pmf; with ``network=``: how often the channel breaks it.
    delays: list | None = None
    network_violations: dict | None = None

    def to_dict(self) -> dict:
        def num(x):
            return None if x is None or not np.isfinite(x) else float(x)

        extra = {}
        if self.delays is not None:
            extra["delays"] = list(self.delays)
        if self.network_violations is not None:
            extra["network_violations"] = self.network_violations
        return extra | {
            "burst_rate": self.burst_rate,
            "mean_time_between_bursts": num(self.mean_time_between_bursts),
            "mean_time_between_bursts_seconds": num(self.mean_time_between_bursts_seconds),
            "bursts": self.bursts.to_dict(),
            "ms_stable": self.ms_stable,
            "ms_radius": num(self.ms_radius),
            "ms_radius_upper": num(self.ms_radius_upper),
            "ms_radius_lower": num(self.ms_radius_lower),
            "expected_cost": num(self.expected_cost),
            "expected_cost_upper": num(self.expected_cost_upper),
            "expected_cost_lower": num(self.expected_cost_lower),
            "stationary_cost": num(self.stationary_cost),
            "upper_certificate": None if self.upper_certificate is None else self.upper_certificate.to_dict(),
            "lower_certificate": None if self.lower_certificate is None else self.lower_certificate.to_dict(),
            "exhausted": self.exhausted,
            "plant_transitions": self.plant_transitions,
            "n_modes": self.n_modes,
            "reason": self.reason,
        }


def _psd(name: str, M, size: int) -> np.ndarray:
    try:
        A = np.array(M, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInput(f"{name} must be a {size} x {size} matrix", (name,)) from None
    if A.ndim == 0 or (A.ndim == 1 and A.shape == (size,)):
        A = np.diag(np.broadcast_to(A, (size,)).astype(np.float64))
    if A.shape != (size, size) or not np.all(np.isfinite(A)):
        raise InvalidInput(f"{name} must be a finite {size} x {size} matrix", (name,))
    if not np.allclose(A, A.T, rtol=1e-12, atol=0):
        raise InvalidInput(f"{name} must be symmetric", (name,))
    A = 0.5 * (A + A.T)
    if np.linalg.eigvalsh(A)[0] < -1e-12 * max(1.0, float(np.abs(A).max())):
        raise InvalidInput(f"{name} must be positive semidefinite", (name,))
    return A


def check_weights(weights, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """``(Q, R)``: symmetric PSD, n x n and m x m (scalars and vectors mean diagonal)."""
    if isinstance(weights, dict) and set(weights) == {"Q", "R"}:  # the service's JSON form
        weights = (weights["Q"], weights["R"])
    if not isinstance(weights, (tuple, list)) or len(weights) != 2:
        raise InvalidInput("weights must be a pair (Q, R) or {\"Q\": ..., \"R\": ...}", ("weights",))
    return _psd("Q", weights[0], n), _psd("R", weights[1], m)


def check_plant_transitions(plant_transitions, r: int):
    """None (stay), "arbitrary", or an r x r row-stochastic matrix."""
    if plant_transitions is None:
        return np.eye(r), "stay"
    if isinstance(plant_transitions, str):
        if plant_transitions == "arbitrary":
            return None, "arbitrary"
        if plant_transitions == "stay":
            return np.eye(r), "stay"
        raise InvalidInput("plant_transitions must be an r x r matrix, 'stay' or 'arbitrary'",
                           ("plant_transitions",))
    return check_stochastic("plant_transitions", plant_transitions, size=r), "markov"


def _check_exhausted(exhausted: str) -> str:
    from .mjls import EXHAUSTED

    if exhausted not in EXHAUSTED:
        raise InvalidInput(f"exhausted must be one of {EXHAUSTED}, got {exhausted!r}", ("exhausted",))
    return exhausted


def _loop_inputs(family, gains, n_drop, channel, exhausted):
    from .network import check_gains, check_n_drop
    from .plant import PlantFamily

    if not isinstance(family, PlantFamily):
        raise InvalidInput("family must be a PlantFamily", ("family",))
    if not isinstance(channel, Channel):
        raise InvalidInput("channel must be a Channel (Channel.bernoulli, Channel.gilbert_elliott, ...)",
                           ("channel",))
    n_drop = check_n_drop(n_drop)
    K = check_gains(gains, n_drop, family.n_inputs, family.n_states)
    return n_drop, K, _check_exhausted(exhausted)


def _verdicts(loop, want_lower: bool = True):
    """Radius estimate, proven bounds and the verdict for one Markov loop."""
    from .mjls import certify_cycle, certify_lower, certify_upper, radius_estimate

    rho, perron = radius_estimate(loop)
    upper = lower = None
    if np.isfinite(rho) and rho < 1:
        gap = 1.0 - rho
        for f in (1e-6, 1e-4, 1e-2, 0.1, 0.5):
            cert = certify_upper(loop, rho + f * gap)
            if cert is not None and cert.verified:
                upper = cert
                break
    if rho >= 1:  # also inf (the operator overflows float64); NaN: no estimate
        lower = certify_lower(loop, 1.0, perron)
        if lower is not None and np.isfinite(rho) and rho > 1 + 1e-6:
            lower = certify_lower(loop, rho * (1 - 1e-6), perron) or lower
        if lower is None:
            # Growth along a direction every mode keeps exactly (e.g. an open-loop mode with stable parts):
            # a cycle of modes whose probability times its radius squared is proven >= 1 in exact arithmetic.
            lower = certify_cycle(loop)
    if want_lower and lower is None and np.isfinite(rho) and rho > 0:
        for f in (1e-6, 1e-2):
            mu = rho * (1 - f)
            cert = certify_lower(loop, mu, perron, max_steps=200, thorough=False)
            if cert is not None:
                lower = cert
                break
    if upper is not None and upper.beta < 1:
        stable, reason = True, f"rho(L) <= {upper.beta:.6g} < 1 by a re-checked coupled Lyapunov certificate"
    elif lower is not None and lower.mu >= 1:
        what = "an exact cycle" if lower.kind == "cycle" else "a re-checked first-return growth"
        stable, reason = False, f"rho(L) >= {lower.mu:.6g} by {what} certificate"
    else:
        stable = None
        reason = (f"spectral radius estimate {rho:.12g}: neither a stability nor an instability certificate "
                  "passed the float64 re-check (too close to 1, or badly conditioned)")
    return rho, upper, lower, stable, reason


def analyze_channel(family, gains, n_drop: int, channel: Channel, *, exhausted: str = "hold",
                    plant_transitions=None, weights=None, noise=None, network=None, observer_gains=None,
                    sensor_channel=None, max_memory: float | None = None,
                    time_limit: float | None = None) -> ChannelReport:
    """The predictive loop on a stochastic channel: bursts, mean-square stability, expected cost.

    Per sample k (docs/design.md, "Stochastic channels"): the buffer age ``d = k - i_m``, the
    input ``u(k) = K_{d+1} x(i_m)`` while ``d < n_drop``, then the ``exhausted`` policy; the
    channel state follows ``channel`` (stationary at k = 0), the plant mode follows
    ``plant_transitions``; sample 0 is effective.

    Parameters
    ----------
    family : PlantFamily
    gains : array_like, shape (n_drop, m, n)
    n_drop : int
        Buffer length N (the design's drop bound).
    channel : Channel
    exhausted : {"hold", "zero"}
        After ``n_drop`` samples without an effective packet: keep applying ``K_N x(i_m)``, or u = 0.
    plant_transitions : None, (r, r) array_like or "arbitrary"
        Per-sample Markov chain of the plant mode (row l: probabilities of the next mode);
        None: the mode never changes (drawn uniformly at k = 0).  ``"arbitrary"``: any switching
        (worst case, as in the paper): a sufficient LMI test with mode-dependent Lyapunov
        matrices per (channel state, age); True only with its re-checked certificate.
    weights : (Q, R), optional
        Stage cost ``x'Qx + u'Ru`` (PSD, n x n and m x m).  Expected cost with ``E[x(0)x(0)'] = I``.
    noise : array_like (n, n), optional
        Process noise covariance W (``x(k+1) = F x + G u + w``): adds ``stationary_cost``, the
        long-run cost per sample.
    network : Network, optional
        Adds ``network_violations``: the exact rate at which the channel breaks that network's
        constraint (drop bound, delay range or weakly-hard window; :mod:`solver.channel_delays`).
        A channel made with :meth:`Channel.with_delays` is analyzed with its late packets whether or
        not a network is given.
    max_memory, time_limit : float, optional
        Budget in bytes and seconds (defaults: 4 GiB, ``NCS_SOLVER_MAX_MEMORY``; 300 s,
        ``NCS_SOLVER_MAX_SECONDS``): an analysis whose second-moment operator is estimated over it is
        refused with ``InvalidInput`` naming the operator's size before it is built (:mod:`solver.workload`).
    observer_gains : array_like (r, n, p), optional
        Output feedback (docs/design.md §12): ``channel`` is then the control link, ``sensor_channel`` (default
        lossless) the measurements' link, ``noise`` the pair ``(W, V)``; the answer is a
        :class:`solver.observer.OutputChannelReport` (mean-square stability and the stationary LQG-like cost).

    Returns
    -------
    ChannelReport
    """
    from .channel_delays import DelayedChannel, build_delayed_loop, exhaustion_rate, initial_moments, \
        network_violations
    from .mjls import build_loop, cesaro_modes, cost_lower, cost_to_go, cost_upper

    if observer_gains is not None or sensor_channel is not None:
        from .observer import analyze_output_channel

        if observer_gains is None:
            raise InvalidInput("sensor_channel applies to output feedback: pass observer_gains", ("sensor_channel",))
        if plant_transitions is not None:
            raise InvalidInput("plant_transitions is not supported with observer_gains yet", ("plant_transitions",))
        return analyze_output_channel(family, gains, n_drop, observer_gains,
                                      Channel.bernoulli(0.0) if sensor_channel is None else sensor_channel, channel,
                                      exhausted=exhausted, weights=weights, noise=noise)

    n_drop, K, exhausted = _loop_inputs(family, gains, n_drop, channel, exhausted)
    r, n, m = family.n_modes, family.n_states, family.n_inputs
    check_channel("the channel analysis", channel_operator_size(channel.n_states, r, n_drop, n), 1,
                  max_memory, time_limit)
    Pi, kind = check_plant_transitions(plant_transitions, r)
    W = None if weights is None else check_weights(weights, n, m)
    noise_cov = None if noise is None else _psd("noise", noise, n)
    if noise_cov is not None and W is None:
        raise InvalidInput("noise needs weights (Q, R) to define the cost", ("weights",))
    bursts = channel.burst_statistics(n_drop, family.sampling_period)
    F, G = np.asarray(family.F, dtype=np.float64), np.asarray(family.G, dtype=np.float64)
    common = dict(burst_rate=bursts.rate, mean_time_between_bursts=bursts.mean_time_between,
                  mean_time_between_bursts_seconds=bursts.mean_time_between_seconds, bursts=bursts,
                  exhausted=exhausted, plant_transitions=kind)
    delayed = isinstance(channel, DelayedChannel)
    if network is not None:
        common["network_violations"] = network_violations(channel, network, family.sampling_period)
    if delayed:
        if kind == "arbitrary":
            raise InvalidInput("a channel with delays needs a plant chain (None or an r x r matrix), not "
                               "'arbitrary'", ("plant_transitions",))
        # The buffer runs dry when its age reaches n_drop (losses and late packets together).
        rate = exhaustion_rate(channel, n_drop)
        mtb = 1.0 / rate if rate > 0 else float("inf")
        h = family.sampling_period
        common.update(burst_rate=rate, mean_time_between_bursts=mtb,
                      mean_time_between_bursts_seconds=None if h is None else mtb * h,
                      delays=channel.delays.tolist())
    if kind == "arbitrary":
        return _dead_link_noted(channel, _analyze_arbitrary(F, G, K, channel, exhausted, W, common))
    if delayed:
        loop = build_delayed_loop(F, G, K, channel, Pi, exhausted, weights=W)
    else:
        loop = build_loop(F, G, K, channel.transition, channel.loss, channel.stationary, Pi, exhausted, weights=W)
    rho, upper, lower, stable, reason = _verdicts(loop)
    cost = cost_hi = cost_lo = stat = None
    if W is not None and stable:
        X0 = initial_moments(loop) if delayed else loop.initial_moments()
        P = cost_to_go(loop, loop.stage)
        if P is not None:
            cost = float(sum(np.sum(p * x) for p, x in zip(P, X0)))
            cost_hi = cost_upper(loop, X0, cost)
            cost_lo = cost_lower(loop, X0, cost)
            if noise_cov is not None:
                q = cesaro_modes(loop, loop.initial)
                stat = float(sum(q[i] * np.sum(P[i] * (E @ noise_cov @ E.T)) for i, E in enumerate(loop.embed)))
    elif W is not None:
        reason += "; expected cost: not finite unless mean-square stable" if stable is False else \
            "; expected cost not computed without a stability proof"
    return _dead_link_noted(channel, ChannelReport(
        ms_stable=stable, ms_radius=rho, ms_radius_upper=None if upper is None else upper.beta,
        ms_radius_lower=None if lower is None else lower.mu, expected_cost=cost, expected_cost_upper=cost_hi,
        expected_cost_lower=cost_lo, stationary_cost=stat, upper_certificate=upper, lower_certificate=lower,
        n_modes=len(loop.modes), reason=reason, **common))


def _dead_link_noted(channel: Channel, report: "ChannelReport") -> "ChannelReport":
    """A verdict on a link that never delivers is the open loop's (or the held input's): say so first."""
    if channel.never_delivers:
        report.reason = f"{channel.dead_link_reason()}; {report.reason}"
    return report


def _analyze_arbitrary(F, G, K, channel, exhausted, W, common) -> ChannelReport:
    """Arbitrary plant switching: common P per (channel state, age) for every plant mode (an LMI)."""
    from .mjls import build_loop

    r = F.shape[0]
    one = np.ones((1, 1))
    loops = [build_loop(F[l:l + 1], G[l:l + 1], K, channel.transition, channel.loss, channel.stationary,
                        one, exhausted, weights=W) for l in range(r)]
    # A constant plant is one of the arbitrary switching sequences: its growth proves instability.
    lower = None
    for loop in loops:
        _, _, low, stable, _ = _verdicts(loop, want_lower=False)
        if stable is False:
            lower = low
            break
    upper, reason = None, ""
    # Every single-plant loop has the same (channel state, age) modes: they depend on the channel only.
    if lower is None and all(lp.modes == loops[0].modes for lp in loops):
        upper, reason = _arbitrary_lmi(loops)
    if lower is not None:
        stable, reason = False, (f"a constant plant mode gives rho(L) >= {lower.mu:.6g} (re-checked first-return "
                                 "growth certificate)")
    elif upper is not None and upper.verified and upper.beta < 1:
        stable, reason = True, (f"mode-dependent Lyapunov LMI for arbitrary plant switching, re-checked: "
                                f"E V decays by {upper.beta:.6g} per sample")
    else:
        stable = None
        reason = reason or "the arbitrary-switching LMI found no certificate that passed the re-check"
    cost_hi = None
    if W is not None and stable:
        cost_hi = _arbitrary_cost(loops)
        reason += ("; expected_cost_upper: worst case over plant switching (re-checked LMI)" if cost_hi is not None
                   else "; no worst-case cost bound passed the re-check")
    return ChannelReport(
        ms_stable=stable, ms_radius=None, ms_radius_upper=None if upper is None or not upper.verified else upper.beta,
        ms_radius_lower=None if lower is None else lower.mu, expected_cost=None, expected_cost_upper=cost_hi,
        expected_cost_lower=None, stationary_cost=None, upper_certificate=upper, lower_certificate=lower,
        n_modes=len(loops[0].modes) * r, reason=reason, **common)


def _arbitrary_cost(loops):
    """Worst-case expected cost over plant switching: min sum_i <P_i, X0_i> with P - L_l*(P) - S >= 0 for every
    plant mode l (cvxpy + Clarabel, a relative margin), re-checked with rounding bounds; None if nothing passes."""
    import cvxpy as cp

    from .mjls import bound_from, recheck_cost

    base = loops[0]
    X0 = base.initial_moments()
    Ps = [cp.Variable((d, d), symmetric=True) for d in base.dims]
    eta = cp.Parameter(nonneg=True)
    cons = []
    for loop in loops:
        LP = [0 for _ in Ps]
        for t in loop.transitions:
            LP[t.src] = LP[t.src] + t.p * (t.A.T @ Ps[t.dst] @ t.A)
        for i, P in enumerate(Ps):
            M = P - LP[i] - loop.stage[i]
            cons.append(0.5 * (M + M.T) >> eta * np.eye(P.shape[0]))
    prob = cp.Problem(cp.Minimize(sum(cp.sum(cp.multiply(P, x)) for P, x in zip(Ps, X0))), cons)
    scale = max(float(np.max([np.trace(s) for s in base.stage])), 1e-12)
    for rel in (1e-7, 1e-5, 1e-3):
        eta.value = rel * scale
        try:
            solve_quietly(prob)
        except cp.error.SolverError:
            continue
        if prob.status in ("optimal", "optimal_inaccurate") and all(P.value is not None for P in Ps):
            P = [0.5 * (P.value + P.value.T) for P in Ps]
            if recheck_cost(loops, P):
                return bound_from(P, X0)
    return None


def _arbitrary_lmi(loops):
    """Find P_i >= I with beta P_i - L_l*(P)_i >= I for every plant mode l (cvxpy + Clarabel), then re-check."""
    import cvxpy as cp

    from .mjls import recheck_upper

    base = loops[0]
    Ps = [cp.Variable((d, d), symmetric=True) for d in base.dims]
    beta = cp.Parameter(nonneg=True)
    cons = [P >> np.eye(P.shape[0]) for P in Ps]
    for loop in loops:
        LP = [0 for _ in Ps]
        for t in loop.transitions:
            LP[t.src] = LP[t.src] + t.p * (t.A.T @ Ps[t.dst] @ t.A)
        for i, P in enumerate(Ps):
            M = beta * P - LP[i]
            cons.append(0.5 * (M + M.T) >> np.eye(P.shape[0]))
    prob = cp.Problem(cp.Minimize(sum(cp.trace(P) for P in Ps)), cons)
    best = None
    lo, hi = 0.0, 1.0
    for it in range(12):
        b = hi if it == 0 else 0.5 * (lo + hi)
        beta.value = b
        try:
            solve_quietly(prob)
        except cp.error.SolverError:
            status = "solver_error"
        else:
            status = prob.status
        cert = None
        if status in ("optimal", "optimal_inaccurate") and all(P.value is not None for P in Ps):
            cert = recheck_upper(loops, [P.value for P in Ps], b)
        if cert is not None and cert.verified:
            best, hi = cert, b
        elif it == 0:
            return None, f"the arbitrary-switching LMI at beta = 1: {status}, no re-checked certificate"
        else:
            lo = b
        if hi - lo < 1e-3:
            break
    return best, ""


def critical_loss(family, gains, n_drop: int, *, exhausted: str = "hold", plant_transitions=None,
                  tol: float = 1e-7, max_memory: float | None = None, time_limit: float | None = None) -> float:
    """The Bernoulli loss probability at which the loop stops being mean-square stable.

    Bisection on ``p`` of the float64 spectral radius of the second-moment operator
    (:func:`analyze_channel` proves the verdict at any given ``p``).  Returns 0.0 when the loop
    is not mean-square stable even without losses and 1.0 when it stays stable for every
    ``p < 1`` (up to ``1 - tol``).  ``max_memory``/``time_limit``: as in :func:`analyze_channel`, for the
    ``log2(1 / tol) + 2`` spectral-radius estimates of the bisection.
    """
    from .mjls import build_loop, radius_estimate

    n_drop, K, exhausted = _loop_inputs(family, gains, n_drop, Channel.bernoulli(0.0), exhausted)
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0 < tol < 0.5:
        raise InvalidInput("tol must be a number in (0, 0.5)", ("tol",))
    check_channel("critical_loss", channel_operator_size(1, family.n_modes, n_drop, family.n_states),
                  int(np.ceil(np.log2(1.0 / tol))) + 2, max_memory, time_limit)
    Pi, kind = check_plant_transitions(plant_transitions, family.n_modes)
    if kind == "arbitrary":
        raise InvalidInput("critical_loss needs a Markov plant chain (or None), not 'arbitrary'",
                           ("plant_transitions",))
    F, G = np.asarray(family.F, dtype=np.float64), np.asarray(family.G, dtype=np.float64)

    def rho(p):
        ch = Channel.bernoulli(p)
        return radius_estimate(build_loop(F, G, K, ch.transition, ch.loss, ch.stationary, Pi, exhausted))[0]

    if not rho(0.0) < 1:
        return 0.0
    hi = 1.0 - tol
    if rho(hi) < 1:
        return 1.0
    lo = 0.0
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if rho(mid) < 1:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


# ===================================================================== Monte Carlo, comparisons, design
@dataclass
class MonteCarloCost:
    """Mean of ``sum_{k < horizon} x'Qx + u'Ru`` over independent runs, with a normal confidence interval.

    Attributes
    ----------
    mean, std_error : float
    ci_low, ci_high : float
        ``mean -/+ z std_error`` at ``confidence``.
    confidence : float
    runs, horizon : int
    seed : int
    """

    mean: float
    std_error: float
    ci_low: float
    ci_high: float
    confidence: float
    runs: int
    horizon: int
    seed: int

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def monte_carlo_cost(family, gains, n_drop: int, channel: Channel, weights, *, exhausted: str = "hold",
                     plant_transitions=None, runs: int = 10_000, horizon: int = 500, seed: int = 0,
                     confidence: float = 0.99) -> MonteCarloCost:
    """Estimate :func:`analyze_channel`'s expected cost by simulation (same conventions).

    ``x(0) ~ N(0, I)``, the channel state at 0 from its stationary distribution, sample 0 effective,
    the plant mode uniform at 0 then following ``plant_transitions``.  All runs advance together
    (vectorized); randomness from ``Generator(PCG64(seed))``.  The sum stops at ``horizon``: pick
    it so that ``ms_radius ** horizon`` is negligible.
    """
    n_drop, K, exhausted = _loop_inputs(family, gains, n_drop, channel, exhausted)
    r, n, m = family.n_modes, family.n_states, family.n_inputs
    Qw, Rw = check_weights(weights, n, m)
    Pi, kind = check_plant_transitions(plant_transitions, r)
    if kind == "arbitrary":
        raise InvalidInput("monte_carlo_cost needs a plant chain (an r x r matrix) or None", ("plant_transitions",))
    runs = _positive_int("runs", runs)
    horizon = _positive_int("horizon", horizon)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InvalidInput("seed must be a non-negative integer", ("seed",))
    if not 0 < float(confidence) < 1:
        raise InvalidInput("confidence must be in (0, 1)", ("confidence",))
    rng = np.random.Generator(np.random.PCG64(int(seed)))
    from .channel_delays import DelayedChannel, monte_carlo_delayed_cost

    if isinstance(channel, DelayedChannel):
        cost = monte_carlo_delayed_cost(family, K, channel, Qw, Rw, exhausted, Pi, kind, runs, horizon, rng)
        return _mc_summary(cost, runs, horizon, seed, confidence)
    _, effective = channel.sample(horizon, rng, size=runs)
    effective[:, 0] = True
    x = rng.standard_normal((runs, n))
    plant = rng.integers(0, r, size=runs)
    draws = rng.random((horizon, runs))
    F, G = np.asarray(family.F, dtype=np.float64), np.asarray(family.G, dtype=np.float64)
    cum = np.cumsum(Pi, axis=1)
    cum[:, -1] = 1.0
    xm = x.copy()
    age = np.zeros(runs, dtype=np.int64)
    cost = np.zeros(runs)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(horizon):
            eff = effective[:, k]
            xm[eff] = x[eff]
            age = np.where(eff, 0, age + 1)
            u = np.einsum("rij,rj->ri", K[np.minimum(age, n_drop - 1)], xm)
            if exhausted == "zero":
                u[age >= n_drop] = 0.0
            cost += np.einsum("ri,ij,rj->r", x, Qw, x) + np.einsum("ri,ij,rj->r", u, Rw, u)
            x = np.einsum("rij,rj->ri", F[plant], x) + np.einsum("rij,rj->ri", G[plant], u)
            if kind != "stay":
                plant = np.minimum((draws[k][:, None] >= cum[plant]).sum(axis=1), r - 1)
    return _mc_summary(cost, runs, horizon, seed, confidence)


def _mc_summary(cost, runs, horizon, seed, confidence) -> MonteCarloCost:
    from scipy.stats import norm

    mean = float(np.mean(cost))
    se = float(np.std(cost, ddof=1) / np.sqrt(runs)) if runs > 1 else float("inf")
    z = float(norm.ppf(0.5 + 0.5 * float(confidence)))
    return MonteCarloCost(mean=mean, std_error=se, ci_low=mean - z * se, ci_high=mean + z * se,
                          confidence=float(confidence), runs=runs, horizon=horizon, seed=int(seed))


def compare_schemes(family, channel: Channel, n_drops, *, schemes=("predictive", "hold", "zero"),
                    exhausted=("hold", "zero"), weights=None, plant_transitions=None, method: str = "lmi") -> list:
    """Design each scheme for each ``n_drop`` and analyze it on the channel.

    Returns
    -------
    list of dict
        One row per (scheme, n_drop, exhausted): ``outcome`` of the design, ``burst_rate``,
        ``ms_stable``, ``ms_radius``, ``expected_cost`` (None when the design failed).
    """
    from .design import design

    if isinstance(exhausted, str):
        exhausted = (exhausted,)
    rows = []
    for scheme in schemes:
        for N in n_drops:
            res = design(family, N, method=method, scheme=scheme)
            for ex in exhausted:
                row = {"scheme": scheme, "n_drop": int(N), "exhausted": ex, "outcome": res.outcome,
                       "burst_rate": channel.burst_rate(N), "ms_stable": None, "ms_radius": None,
                       "expected_cost": None}
                if res.outcome == "stabilized":
                    rep = analyze_channel(family, res.gains, N, channel, exhausted=ex,
                                          plant_transitions=plant_transitions, weights=weights)
                    row.update(ms_stable=rep.ms_stable, ms_radius=rep.ms_radius, expected_cost=rep.expected_cost)
                rows.append(row)
    return rows


@dataclass
class ChannelDesign:
    """Result of :func:`design_for_channel`.

    Attributes
    ----------
    n_drop : int or None
        The smallest drop bound whose burst rate meets the target (None: none up to ``max_n_drop``).
    bursts : BurstStatistics or None
    design : DesignResult or None
    analysis : ChannelReport or None
        :func:`analyze_channel` of the designed gains (when stabilized).
    """

    n_drop: int | None
    bursts: BurstStatistics | None
    design: object | None
    analysis: ChannelReport | None

    def to_dict(self) -> dict:
        return {"n_drop": self.n_drop,
                "bursts": None if self.bursts is None else self.bursts.to_dict(),
                "design": None if self.design is None else self.design.to_dict(),
                "analysis": None if self.analysis is None else self.analysis.to_dict()}


def design_for_channel(family, channel: Channel, target_rate: float, *, per: str = "second",
                       exhausted: str = "hold", plant_transitions=None, weights=None, max_n_drop: int = 50,
                       **design_options) -> ChannelDesign:
    """Pick the smallest ``n_drop`` whose burst rate is below ``target_rate``, design, analyze on the channel.

    Parameters
    ----------
    target_rate : float
        Bursts (runs of ``>= n_drop`` lost samples) per second (``per="second"``, needs the
        family's sampling period) or per sample (``per="sample"``).
    design_options
        Passed to :func:`solver.design` (``method``, ``scheme``, ...).
    """
    from .design import design

    if per not in ("second", "sample"):
        raise InvalidInput("per must be 'second' or 'sample'", ("per",))
    h = None
    if per == "second":
        h = getattr(family, "sampling_period", None)
        if h is None:
            raise InvalidInput("per='second' needs a family with a sampling period", ("per",))
    if not isinstance(channel, Channel):
        raise InvalidInput("channel must be a Channel", ("channel",))
    if channel.never_delivers:
        raise InvalidInput(f"cannot design for this link: {channel.dead_link_reason()}", ("channel",))
    N = channel.smallest_n_drop(target_rate, sampling_period=h, max_n_drop=max_n_drop)
    if N is None:
        return ChannelDesign(None, None, None, None)
    _check_channel_design(family, channel, N, design_options)
    res = design(family, N, **design_options)
    rep = None
    if res.outcome == "stabilized":
        rep = analyze_channel(family, res.gains, N, channel, exhausted=exhausted,
                              plant_transitions=plant_transitions, weights=weights)
    return ChannelDesign(N, channel.burst_statistics(N, family.sampling_period), res, rep)


def _check_channel_design(family, channel: Channel, n_drop: int, options: dict) -> None:
    """The whole request's estimate (the design and the analysis on the channel, :func:`solver.compiled.design_size`)
    against the budget, before either runs; a request :func:`solver.design` would refuse is left to it."""
    from .design import request_size
    from .network import MAX_MODES, PLANT_SWITCHING, mode_count

    switching = options.get("plant_switching", "per_interval")
    if options.get("network") is not None or switching not in PLANT_SWITCHING:
        return
    if mode_count(family.n_modes, n_drop, switching) > options.get("max_modes", MAX_MODES):
        return
    try:
        size = request_size(options.get("method", "lmi"), family, n_drop, switching,
                            options.get("scheme", "predictive"), options.get("solver", "AUTO"),
                            objective=options.get("objective", "stability"),
                            decay_rate=options.get("decay_rate", "auto"), rate_tol=options.get("rate_tol", 1e-3),
                            u_max=options.get("u_max"), disturbance=options.get("disturbance"),
                            output=options.get("output"),
                            channel_size=channel_operator_size(channel.n_states, family.n_modes, n_drop,
                                                               family.n_states))
    except (TypeError, ValueError):  # a malformed option: design() names it
        return
    size.check(options.get("max_memory"), float("inf") if options.get("time_limit") is not None else None)


def loss_sweep(family, gains, n_drop: int, losses, *, exhausted=("hold", "zero"), weights=None,
               plant_transitions=None) -> list:
    """:func:`analyze_channel` on Bernoulli channels over a list of loss probabilities.

    Returns
    -------
    list of dict
        Per (loss, exhausted): ``loss``, ``exhausted``, ``burst_rate``, ``ms_stable``, ``ms_radius``,
        ``expected_cost`` (None unless proven mean-square stable with weights).
    """
    if isinstance(exhausted, str):
        exhausted = (exhausted,)
    rows = []
    for p in losses:
        ch = Channel.bernoulli(p)
        for ex in exhausted:
            rep = analyze_channel(family, gains, n_drop, ch, exhausted=ex, weights=weights,
                                  plant_transitions=plant_transitions)
            rows.append({"loss": float(p), "exhausted": ex, "burst_rate": rep.burst_rate, "ms_stable": rep.ms_stable,
                         "ms_radius": rep.ms_radius, "expected_cost": rep.expected_cost})
    return rows


# ============================================================== design for the channel (mode-dependent Lyapunov)
@dataclass
class ChannelDesignResult:
    """Result of :func:`design_channel`.

    Attributes
    ----------
    outcome : {"stabilized", "not_converged"}
        "stabilized" only when :func:`analyze_channel` proves mean-square stability of the gains
        (its own re-checked certificate, not the SDP's).
    gains : ndarray (n_drop, m, n) or None
    analysis : ChannelReport or None
        Exact expected cost and certificates of the designed gains.
    sdp_bound : float or None
        The SDP's objective, an upper bound of the expected cost if the SDP were solved exactly.
    status : str
        cvxpy status of the SDP.
    message : str
    """

    outcome: str
    gains: np.ndarray | None
    analysis: ChannelReport | None
    sdp_bound: float | None
    status: str
    message: str

    def to_dict(self) -> dict:
        return {"outcome": self.outcome, "gains": None if self.gains is None else self.gains.tolist(),
                "analysis": None if self.analysis is None else self.analysis.to_dict(),
                "sdp_bound": self.sdp_bound, "status": self.status, "message": self.message}


def _sqrt_psd(M: np.ndarray) -> np.ndarray:
    s, V = np.linalg.eigh(M)
    return (V * np.sqrt(np.clip(s, 0.0, None))) @ V.T


def design_channel(family, n_drop: int, channel: Channel, *, exhausted: str = "hold", plant_transitions=None,
                   weights=None, margin: float = 1e-7) -> ChannelDesignResult:
    """Gains ``K_1..K_N`` that make the loop on ``channel`` mean-square stable with small expected cost.

    One SDP (cvxpy + Clarabel) on the jump system of :func:`analyze_channel`, with a Lyapunov matrix
    ``P_i = S_i^{-1}`` per mode (channel state, plant mode, buffer age) and one common slack ``Z``
    (the gains are common to all modes; ``Y_q = K_q Z``).  With ``Zb`` the block-diagonal copy of
    ``Z`` on the mode's state, ``Zb' P_i Zb >= Zb + Zb' - S_i`` turns

        [[Zb + Zb' - S_i, (sqrt(p_ij) A_ij Zb)', (C_i Zb)'], [sqrt(p_ij) A_ij Zb, S_j, 0], [C_i Zb, 0, I]] > 0

    into ``P_i - sum_j p_ij A_ij' P_j A_ij > C_i' C_i`` (``C_i' C_i`` the stage cost), so
    ``J <= sum_i <P_i, X0_i> <= sum_i tr X_i`` with ``[[X_i, I], [I, S_i]] >= 0`` (minimized).
    A sufficient condition (the common slack).  The verdict and the cost come from
    :func:`analyze_channel` on the returned gains, never from the SDP.

    Parameters
    ----------
    family, n_drop, channel, exhausted, plant_transitions
        As in :func:`analyze_channel` (not "arbitrary").
    weights : (Q, R), optional
        Default identities.
    margin : float
        Strictness of the SDP blocks.
    """
    import cvxpy as cp

    from .mjls import build_loop
    from .network import check_n_drop
    from .plant import PlantFamily

    if not isinstance(family, PlantFamily):
        raise InvalidInput("family must be a PlantFamily", ("family",))
    if not isinstance(channel, Channel):
        raise InvalidInput("channel must be a Channel", ("channel",))
    if getattr(channel, "delays", None) is not None and len(channel.delays) > 1:
        raise InvalidInput("design_channel designs for losses only: for late packets design for a network "
                           "(design(family, network=Network.delays(...))) and check it with analyze_channel",
                           ("channel", "delays"))
    N = check_n_drop(n_drop)
    exhausted = _check_exhausted(exhausted)
    r, n, m = family.n_modes, family.n_states, family.n_inputs
    Pi, kind = check_plant_transitions(plant_transitions, r)
    if kind == "arbitrary":
        raise InvalidInput("design_channel needs a plant chain (an r x r matrix) or None", ("plant_transitions",))
    Qw, Rw = check_weights(weights if weights is not None else (np.eye(n), np.eye(m)), n, m)
    Qh, Rh = _sqrt_psd(Qw), _sqrt_psd(Rw)
    F, G = np.asarray(family.F, dtype=np.float64), np.asarray(family.G, dtype=np.float64)
    # The reachable modes and transition probabilities do not depend on the gains.
    loop = build_loop(F, G, np.zeros((N, m, n)), channel.transition, channel.loss, channel.stationary, Pi, exhausted)
    # One slack per gain (Y_q = K_q Z_q, shared by every mode that applies K_q); the part of the
    # state the gains do not touch gets a slack of its own per mode.
    Zg = [cp.Variable((n, n)) for _ in range(N)]
    Y = [cp.Variable((m, n)) for _ in range(N)]
    S = [cp.Variable((d, d), symmetric=True) for d in loop.dims]
    zero_nn = np.zeros((n, n))

    def gain_index(d):
        if d < N:
            return d
        return None if exhausted == "zero" else N - 1

    def pieces(l, d, dim):
        """(Zb, x_next Zb, x(i_m) part of the next state times Zb, stage C Zb) of a mode."""
        if d == 0:
            Z = Zg[0]
            return Z, F[l] @ Z + G[l] @ Y[0], Z, cp.vstack([Qh @ Z, Rh @ Y[0]])
        if dim == n:  # exhausted, zero input: no gain
            Z = cp.Variable((n, n))
            return Z, F[l] @ Z, None, Qh @ Z
        q = gain_index(d)
        Zx = cp.Variable((n, n))
        Zb = cp.bmat([[Zx, zero_nn], [zero_nn, Zg[q]]])
        stage = cp.bmat([[Qh @ Zx, np.zeros((n, n))], [np.zeros((m, n)), Rh @ Y[q]]])
        return Zb, cp.hstack([F[l] @ Zx, G[l] @ Y[q]]), cp.hstack([zero_nn, Zg[q]]), stage

    out = {}
    for t in loop.transitions:
        out.setdefault(t.src, []).append(t)
    cons = []
    for i, (c, l, d) in enumerate(loop.modes):
        dim = int(loop.dims[i])
        Zb, xn, keep, C = pieces(l, d, dim)
        rows = []
        for t in out.get(i, []):
            AZ = xn if int(loop.dims[t.dst]) == n else cp.vstack([xn, keep])
            rows.append((np.sqrt(t.p) * AZ, S[t.dst]))
        blocks_n = [dim] + [S[t.dst].shape[0] for t in out.get(i, [])] + [C.shape[0]]
        k = len(blocks_n)
        M = [[None] * k for _ in range(k)]
        M[0][0] = Zb + Zb.T - S[i]
        for a, (AZ, Sj) in enumerate(rows, start=1):
            M[a][0] = AZ
            M[0][a] = AZ.T
            M[a][a] = Sj
        M[k - 1][0] = C
        M[0][k - 1] = C.T
        M[k - 1][k - 1] = np.eye(C.shape[0])
        for a in range(k):
            for b in range(k):
                if M[a][b] is None:
                    M[a][b] = np.zeros((blocks_n[a], blocks_n[b]))
        cons.append(cp.bmat(M) >> margin * np.eye(sum(blocks_n)))
    X = {}
    for i in np.flatnonzero(loop.initial > 0):
        X[i] = cp.Variable((n, n), symmetric=True)
        cons.append(cp.bmat([[X[i], np.eye(n)], [np.eye(n), S[i]]]) >> 0)
    objective = cp.Minimize(sum(loop.initial[i] * cp.trace(X[i]) for i in X))
    prob = cp.Problem(objective, cons)
    try:
        solve_quietly(prob)
        status = prob.status
    except cp.error.SolverError as err:
        return ChannelDesignResult("not_converged", None, None, None, "solver_error", str(err))
    if status not in ("optimal", "optimal_inaccurate") or any(Z.value is None for Z in Zg):
        return ChannelDesignResult("not_converged", None, None, None, str(status),
                                   f"the SDP ended {status}: no design of this form")
    try:
        K = np.array([y.value @ np.linalg.inv(Z.value) for y, Z in zip(Y, Zg)])
    except np.linalg.LinAlgError:
        return ChannelDesignResult("not_converged", None, None, None, str(status), "a slack Z_q is singular")
    rep = analyze_channel(family, K, N, channel, exhausted=exhausted, plant_transitions=plant_transitions,
                          weights=(Qw, Rw))
    outcome = "stabilized" if rep.ms_stable is True else "not_converged"
    msg = "mean-square stability certified by analyze_channel" if rep.ms_stable else rep.reason
    return ChannelDesignResult(outcome, K, rep, float(prob.value), str(status), msg)
