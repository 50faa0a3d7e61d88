"""Seeded step-by-step simulation of the networked predictive loop (Sec. II).

Per sample k the sensor packet crosses switch S1 and, if it arrived, the
time-stamped control packet ``[K_1 x(k), ..., K_N x(k)]`` crosses S2.  A step
is *effective* when both arrive (Sec. II.E); the buffer (Sec. II.F) then
holds the new predictions and plays ``u(i_m + q - 1) = K_q x(i_m)`` until the
next effective step.  At most ``n_drop - 1`` consecutive steps are
non-effective: a step that would exceed the bound is forced effective.
Sample 0 is effective (the loop starts with a delivered packet).

Randomness comes from ``numpy.random.Generator(PCG64(seed))`` with all
draws made up front in a fixed order, so a seed gives the same run on every
machine.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InvalidInput
from .network import check_gains, check_n_drop
from .plant import PlantFamily
from .workload import check_simulation

LOSS_MODELS = ("paper", "bernoulli")
PLANT_SWITCHING = ("per_interval", "per_sample", "none")


@dataclass
class SimulationResult:
    """A simulated run; arrays are indexed by sample k.

    Attributes
    ----------
    time : ndarray, shape (steps + 1,)
        ``k * h`` in seconds (``k`` when the family has no sampling period).
    state : ndarray, shape (steps + 1, n)
    input : ndarray, shape (steps, m)
        Input applied over [k, k+1).
    mode : ndarray of int, shape (steps,)
        Plant mode (0-based) active over [k, k+1).
    sensor_arrived, control_arrived, effective : ndarray of bool, shape (steps,)
        Switch S1 closed, switch S2 closed, and both (a new packet reached the buffer).
    buffer_index : ndarray of int, shape (steps,)
        q of the prediction ``K_q x(i_m)`` applied at k (1 = fresh packet).
    interval_start : ndarray of int
        Effective samples ``i_m``.
    eta : ndarray of int
        ``i_{m+1} - i_m`` for every completed interval (len(interval_start) - 1 entries).
    """

    time: np.ndarray
    state: np.ndarray
    input: np.ndarray
    mode: np.ndarray
    sensor_arrived: np.ndarray
    control_arrived: np.ndarray
    effective: np.ndarray
    buffer_index: np.ndarray
    interval_start: np.ndarray
    eta: np.ndarray
    seed: int
    loss_model: str
    plant_switching: str
    n_drop: int
    #: Channel state per sample (runs on a :class:`~solver.channel.Channel` only).
    channel_state: np.ndarray | None = None
    #: Age ``d(k) = k - stamp`` of the packet the buffer plays at sample k (-1: no packet yet), shape (steps,).
    ages: np.ndarray | None = None
    #: ``Network.to_dict()`` of the network simulated (runs given ``network=``).
    network: dict | None = None
    #: Output feedback: the controller's estimate ``xh(k|k)``, shape (steps + 1, n) (last row ``xh(steps|steps-1)``).
    estimate: np.ndarray | None = None

    def settling_samples(self, fraction: float = 0.02) -> int | None:
        """First sample from which ``|x(k)| <= fraction |x(0)|`` for the rest of the run (None: not settled).

        A property of this one run (seed, losses, jumps), next to the certified worst case
        (``DesignResult.settling``).
        """
        norms = np.linalg.norm(self.state, axis=1)
        above = np.nonzero(norms > fraction * norms[0])[0]
        if norms[0] == 0 or above.size == 0:
            return 0
        k = int(above[-1]) + 1
        return k if k < len(norms) else None

    def to_dict(self) -> dict:
        extra = {} if self.channel_state is None else {"channel_state": self.channel_state.tolist()}
        if self.network is not None:
            extra["network"] = self.network
        if self.estimate is not None:
            extra["estimate"] = self.estimate.tolist()
        return extra | {
            "ages": None if self.ages is None else self.ages.tolist(),
            "t": self.time.tolist(),
            "x": self.state.tolist(),
            "u": self.input.tolist(),
            "mode": self.mode.tolist(),
            "sensor_arrived": self.sensor_arrived.tolist(),
            "control_arrived": self.control_arrived.tolist(),
            "effective": self.effective.tolist(),
            "buffer_index": self.buffer_index.tolist(),
            "interval_start": self.interval_start.tolist(),
            "eta": self.eta.tolist(),
            "seed": self.seed,
            "loss_model": self.loss_model,
            "plant_switching": self.plant_switching,
            "n_drop": self.n_drop,
        }


def _probability(name: str, value) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InvalidInput(f"{name} must be a probability in [0, 1)", (name,)) from None
    if not (0.0 <= value < 1.0):
        raise InvalidInput(f"{name} must be a probability in [0, 1), got {value}", (name,))
    return value


def simulate(
    family: PlantFamily,
    gains,
    n_drop: int | None = None,
    x0=None,
    steps: int | None = None,
    seed: int | None = 0,
    *,
    network=None,
    arrivals=None,
    loss_model: str = "paper",
    sensor_loss: float = 0.2,
    control_loss: float = 0.2,
    plant_switching: str = "per_interval",
    mode: int | None = None,
    switch_probability: float = 1.0,
    channel=None,
    exhausted: str = "hold",
    plant_transitions=None,
    observer_gains=None,
    sensor_n_drop: int | None = None,
    xh0=None,
    max_memory: float | None = None,
    time_limit: float | None = None,
) -> SimulationResult:
    """Simulate the networked loop with random packet losses and plant jumps.

    Parameters
    ----------
    family : PlantFamily
    gains : array_like, shape (n_drop, m, n)
    n_drop : int, optional
        The paper's network; give this or ``network``.
    x0 : array_like, shape (n,)
        Initial state.
    steps : int
        Number of samples simulated (>= 1).
    seed : int
        Seed of ``Generator(PCG64(seed))`` (default 0).
    network : Network, dict or str, optional
        Draw admissible age sequences of this network (:class:`solver.Network`): the run starts at a
        node of the smallest age, uniformly, and moves to a successor drawn uniformly at every sample;
        the state before sample 0 is ``x0`` (a packet of age d at sample 0 carries ``x(-d) = x0``).
        Plant jumps as ``plant_switching`` says, "per_interval" meaning at samples where a newer
        packet reached the buffer.  A network equal to ``bounded_drops`` runs the loss models below
        unchanged.  ``tr.ages`` holds the ages, ``tr.effective`` marks samples with a newer packet.
    arrivals : sequence of (int, int), optional
        Replay these packet deliveries instead of drawing any: ``(stamp, arrival_sample)`` delivers
        the packet computed from ``x(stamp)`` just before the output of ``arrival_sample``
        (``>= stamp``).  The buffer keeps the newest stamp (late, reordered and duplicate packets as
        in the generated C buffer, :func:`solver.export_c`); before the first packet the input is
        zero; once the held packet is ``n_drop`` or more samples old, ``exhausted`` applies.
        Deliveries at or after ``steps`` are ignored.
    loss_model : {"paper", "bernoulli"}
        ``"paper"``: at each effective step the next interval length eta is
        uniform in 1..n_drop, and each lost step loses the sensor or the
        control packet with equal chance.  ``"bernoulli"``: every sensor packet
        is lost with probability ``sensor_loss`` and every control packet with
        ``control_loss``, independently, truncated by the bound.
    sensor_loss, control_loss : float
        Loss probabilities of the Bernoulli model, in [0, 1).
    plant_switching : {"per_interval", "per_sample", "none"}
        When the plant mode may jump: at effective steps (the paper's model),
        at every sample, or never.
    mode : int, optional
        Initial plant mode (0-based); drawn at random when None.
    switch_probability : float
        Chance that a jump opportunity redraws the mode (uniformly among all r).
    channel : Channel, optional
        Draw losses from this Markov channel instead (docs/design.md, "Stochastic channels"):
        its state at sample 0 from the stationary distribution, sample 0 effective, and runs of
        lost samples of any length, also beyond the bound.  ``loss_model``, ``sensor_loss``,
        ``control_loss``, ``plant_switching`` and ``switch_probability`` are then not used
        (``sensor_arrived`` and ``control_arrived`` both record ``effective``).
    exhausted : {"hold", "zero"}
        With a channel: the input once ``n_drop`` samples passed without an effective packet
        (``K_N x(i_m)`` held, or zero).  ``buffer_index`` then exceeds ``n_drop``.
    plant_transitions : array_like (r, r), optional
        With a channel: per-sample Markov chain of the plant mode (row l: probabilities of the
        next mode); None keeps the initial mode.
    observer_gains : array_like (r, n, p), optional
        Output feedback (docs/design.md, "Output feedback"): the controller measures ``y = C x`` over a
        lossy sensor link (``sensor_loss``, at most ``sensor_n_drop - 1`` lost in a row), runs the observer
        and sends ``K_j xh(k|k)``; the control link loses with ``control_loss`` (at most ``n_drop - 1`` in a
        row).  ``tr.estimate`` holds the estimate.  Uses ``family.C``.
    sensor_n_drop : int, optional
        With ``observer_gains`` (default ``n_drop``).
    xh0 : array_like (n,), optional
        With ``observer_gains``: the initial estimate (default 0).
    max_memory, time_limit : float, optional
        Budget in bytes and seconds (defaults: 4 GiB, ``NCS_SOLVER_MAX_MEMORY``; 300 s,
        ``NCS_SOLVER_MAX_SECONDS``): a simulation whose estimated cost is over it is refused with
        ``InvalidInput`` naming ``steps`` before anything is allocated (:mod:`solver.workload`).

    Returns
    -------
    SimulationResult
    """
    if not isinstance(family, PlantFamily):
        raise InvalidInput("family must be a PlantFamily", ("family",))
    net = None
    if network is not None:
        from .networks import check_network

        net = check_network(network, n_drop)
        n_drop = net.n_drop
    elif n_drop is None:
        raise InvalidInput("give n_drop (the paper's network) or network=Network...", ("n_drop",))
    if x0 is None:
        raise InvalidInput("x0 (the initial state) is required", ("x0",))
    if steps is None:
        raise InvalidInput("steps is required", ("steps",))
    seed = 0 if seed is None else seed
    n_drop = check_n_drop(n_drop)
    n, m, r = family.n_states, family.n_inputs, family.n_modes
    K = check_gains(gains, n_drop, m, n)
    try:
        x = np.array(x0, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidInput("x0 must be a list of numbers", ("x0",)) from None
    if x.shape != (n,) or not np.all(np.isfinite(x)):
        raise InvalidInput(f"x0 must hold {n} finite numbers", ("x0",))
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise InvalidInput("steps must be an integer >= 1", ("steps",))
    check_simulation(int(steps), n, m, max_memory, time_limit)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InvalidInput("seed must be a non-negative integer", ("seed",))
    if loss_model not in LOSS_MODELS:
        raise InvalidInput(f"loss_model must be one of {LOSS_MODELS}", ("loss_model",))
    if plant_switching not in PLANT_SWITCHING:
        raise InvalidInput(f"plant_switching must be one of {PLANT_SWITCHING}", ("plant_switching",))
    sensor_loss = _probability("sensor_loss", sensor_loss)
    control_loss = _probability("control_loss", control_loss)
    switch_probability = float(switch_probability)
    if not 0.0 <= switch_probability <= 1.0:
        raise InvalidInput("switch_probability must be in [0, 1]", ("switch_probability",))
    if mode is not None and (isinstance(mode, bool) or not isinstance(mode, (int, np.integer)) or not 0 <= mode < r):
        raise InvalidInput(f"mode must be an integer in 0..{r - 1}", ("mode",))

    if arrivals is not None or (net is not None and not net.is_bounded_drops):
        if channel is not None:
            raise InvalidInput("channel and network/arrivals are alternatives: pass one", ("channel",))
        if plant_switching not in ("per_interval", "per_sample", "none"):
            raise InvalidInput(f"plant_switching must be one of {PLANT_SWITCHING}", ("plant_switching",))
        tr = _simulate_network(family, K, n_drop, x, steps, int(seed), mode, net, arrivals, exhausted,
                               plant_switching, switch_probability)
        tr.network = None if net is None else net.to_dict()
        return tr
    if observer_gains is not None:
        from .observer import simulate_output

        if channel is not None:
            raise InvalidInput("output feedback runs on the Bernoulli links (sensor_loss, control_loss), not on "
                               "a channel", ("channel",))
        tr = simulate_output(family, K, n_drop, observer_gains, x, steps, int(seed),
                               sensor_n_drop=n_drop if sensor_n_drop is None else sensor_n_drop,
                               sensor_loss=sensor_loss, control_loss=control_loss, xh0=xh0,
                               plant_switching=plant_switching, mode=mode, switch_probability=switch_probability)
        if tr.ages is None:
            tr.ages = tr.buffer_index - 1
        return tr
    if channel is not None:
        return _simulate_channel(family, K, n_drop, x, steps, int(seed), mode, channel, exhausted, plant_transitions)
    if plant_transitions is not None:
        raise InvalidInput("plant_transitions applies to runs on a channel (pass channel=...)",
                           ("plant_transitions",))

    rng = np.random.Generator(np.random.PCG64(int(seed)))
    # All draws up front, in a fixed order: reproducible whatever branch a step takes.
    draw_sensor = rng.random(steps)
    draw_control = rng.random(steps)
    draw_eta = rng.integers(1, n_drop + 1, size=steps)
    draw_switch = rng.random(steps)
    draw_mode = rng.integers(0, r, size=steps)
    current = int(rng.integers(0, r)) if mode is None else int(mode)

    state = np.empty((steps + 1, n))
    inputs = np.empty((steps, m))
    modes = np.empty(steps, dtype=np.int64)
    sensor = np.empty(steps, dtype=bool)
    control = np.empty(steps, dtype=bool)
    effective = np.empty(steps, dtype=bool)
    qs = np.empty(steps, dtype=np.int64)
    state[0] = x
    buffer = None
    q = 0
    lost_in_row = 0
    next_effective = 0  # paper model: the sample of the next effective packet
    for k in range(steps):
        if k == 0:
            s_ok = c_ok = True
        elif loss_model == "paper":
            if k == next_effective:
                s_ok = c_ok = True
            else:
                s_ok = draw_sensor[k] >= 0.5
                c_ok = False
        else:
            s_ok = draw_sensor[k] >= sensor_loss
            c_ok = s_ok and draw_control[k] >= control_loss
            if not (s_ok and c_ok) and lost_in_row >= n_drop - 1:
                s_ok = c_ok = True  # the bound: at most n_drop - 1 consecutive losses
        eff = s_ok and c_ok
        if eff:
            buffer = K @ x  # (n_drop, m): the predictions K_q x(i_m)
            q = 1
            lost_in_row = 0
            if loss_model == "paper":
                next_effective = k + int(draw_eta[k])
        else:
            q += 1
            lost_in_row += 1
        jump = (plant_switching == "per_sample" and k > 0) or (plant_switching == "per_interval" and eff and k > 0)
        if jump and draw_switch[k] < switch_probability:
            current = int(draw_mode[k])
        u = buffer[q - 1]
        x = family.F[current] @ x + family.G[current] @ u
        state[k + 1] = x
        inputs[k] = u
        modes[k] = current
        sensor[k], control[k], effective[k], qs[k] = s_ok, c_ok, eff, q
    starts = np.flatnonzero(effective)
    h = family.sampling_period
    time_axis = np.arange(steps + 1) * (h if h is not None else 1.0)
    return SimulationResult(
        time=time_axis,
        state=state,
        input=inputs,
        mode=modes,
        sensor_arrived=sensor,
        control_arrived=control,
        effective=effective,
        buffer_index=qs,
        interval_start=starts,
        eta=np.diff(starts),
        seed=int(seed),
        loss_model=loss_model,
        plant_switching=plant_switching,
        n_drop=n_drop,
        ages=qs - 1,
        network=None if net is None else net.to_dict(),
    )


def _simulate_channel(family, K, n_drop, x, steps, seed, mode, channel, exhausted, plant_transitions):
    """One run on a Markov channel; the buffer may run dry (``exhausted`` policy)."""
    from .channel import Channel, _check_exhausted, check_plant_transitions

    if not isinstance(channel, Channel):
        raise InvalidInput("channel must be a Channel", ("channel",))
    exhausted = _check_exhausted(exhausted)
    r, n, m = family.n_modes, family.n_states, family.n_inputs
    Pi, kind = check_plant_transitions(plant_transitions, r)
    if kind == "arbitrary":
        raise InvalidInput("simulate needs a plant chain (an r x r matrix) or None", ("plant_transitions",))
    rng = np.random.Generator(np.random.PCG64(seed))
    # Fixed draw order: channel (initial state, transitions, losses), initial plant mode, plant jumps.
    states, effective = channel.sample(steps, rng)
    effective = effective.copy()
    effective[0] = True  # the loop starts with a delivered packet
    first_mode = int(rng.integers(0, r))
    draw_plant = rng.random(steps)
    current = first_mode if mode is None else int(mode)
    cum = np.cumsum(Pi, axis=1)
    cum[:, -1] = 1.0
    state = np.empty((steps + 1, n))
    inputs = np.empty((steps, m))
    modes = np.empty(steps, dtype=np.int64)
    qs = np.empty(steps, dtype=np.int64)
    state[0] = x
    buffer = None
    q = 0
    for k in range(steps):
        if effective[k]:
            buffer = K @ x
            q = 1
        else:
            q += 1
        if q <= n_drop:
            u = buffer[q - 1]
        else:
            u = buffer[n_drop - 1] if exhausted == "hold" else np.zeros(m)
        x = family.F[current] @ x + family.G[current] @ u
        state[k + 1] = x
        inputs[k] = u
        modes[k] = current
        qs[k] = q
        current = int(np.searchsorted(cum[current], draw_plant[k], side="right"))
        current = min(current, r - 1)
    return _one_link_result(family, state, inputs, modes, effective, qs, seed, "channel",
                            "stay" if kind == "stay" else "markov", n_drop, channel_state=states)


def _one_link_result(family, state, inputs, modes, effective, buffer_index, seed, loss_model, plant_switching,
                     n_drop, channel_state=None) -> SimulationResult:
    """A run whose only link is the control one (channels, networks, replays): both switches record ``effective``."""
    starts = np.flatnonzero(effective)
    h = family.sampling_period
    return SimulationResult(
        time=np.arange(len(state)) * (h if h is not None else 1.0), state=state, input=inputs, mode=modes,
        sensor_arrived=effective.copy(), control_arrived=effective.copy(), effective=effective,
        buffer_index=buffer_index, interval_start=starts, eta=np.diff(starts), seed=seed, loss_model=loss_model,
        plant_switching=plant_switching, n_drop=n_drop, channel_state=channel_state, ages=buffer_index - 1)


def check_arrivals(arrivals) -> list:
    """``[(stamp, arrival_sample), ...]`` as int pairs with ``0 <= stamp <= arrival_sample``."""
    try:
        pairs = [tuple(p) for p in arrivals]
    except TypeError:
        raise InvalidInput("arrivals must be a list of [stamp, arrival_sample] pairs", ("arrivals",)) from None
    out = []
    for k, p in enumerate(pairs):
        if len(p) != 2 or any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) for v in p):
            raise InvalidInput(f"arrivals[{k}] must be a pair of integers [stamp, arrival_sample]", ("arrivals", k))
        stamp, at = int(p[0]), int(p[1])
        if stamp < 0:
            raise InvalidInput(f"arrivals[{k}]: stamp {stamp} must be >= 0 (sample 0 is the first)", ("arrivals", k))
        if at < stamp:
            raise InvalidInput(f"arrivals[{k}]: a packet stamped {stamp} cannot arrive at sample {at}, before it "
                               "was sent (arrival_sample >= stamp)", ("arrivals", k))
        out.append((stamp, at))
    return out


def _simulate_network(family, K, n_drop, x, steps, seed, mode, net, arrivals, exhausted, plant_switching,
                      switch_probability):
    """One run whose buffer ages follow a network automaton (drawn) or a list of deliveries (replayed)."""
    from .channel import _check_exhausted

    exhausted = _check_exhausted(exhausted)
    r, n, m = family.n_modes, family.n_states, family.n_inputs
    rng = np.random.Generator(np.random.PCG64(seed))
    # Fixed draw order: start node, successors, initial plant mode, jumps, jump modes.
    draw_start = rng.random()
    draw_next = rng.random(steps)
    first_mode = int(rng.integers(0, r))
    draw_switch = rng.random(steps)
    draw_mode = rng.integers(0, r, size=steps)
    current = first_mode if mode is None else int(mode)
    ages = np.empty(steps, dtype=np.int64)
    if arrivals is not None:
        by_sample: dict = {}
        for stamp, at in check_arrivals(arrivals):
            if at < steps:
                by_sample.setdefault(at, []).append(stamp)
        newest = None
        for t in range(steps):
            for stamp in by_sample.get(t, ()):
                newest = stamp if newest is None else max(newest, stamp)
            ages[t] = -1 if newest is None else t - newest
    else:
        low = int(net.ages.min())
        starts = [i for i in range(net.nodes) if net.ages[i] == low]
        node = starts[min(int(draw_start * len(starts)), len(starts) - 1)]
        for t in range(steps):
            ages[t] = net.ages[node]
            succ = net.successors(node)
            node = succ[min(int(draw_next[t] * len(succ)), len(succ) - 1)]
    state = np.empty((steps + 1, n))
    inputs = np.empty((steps, m))
    modes = np.empty(steps, dtype=np.int64)
    effective = np.zeros(steps, dtype=bool)
    state[0] = x
    for t in range(steps):
        d = int(ages[t])
        fresh = d >= 0 and (t == 0 or ages[t - 1] < 0 or d <= ages[t - 1])
        effective[t] = fresh
        jump = t > 0 and (plant_switching == "per_sample" or (plant_switching == "per_interval" and fresh))
        if jump and draw_switch[t] < switch_probability:
            current = int(draw_mode[t])
        if d < 0:
            u = np.zeros(m)
        else:
            xs = state[max(t - d, 0)]  # before sample 0 the state is x0
            if d < n_drop:
                u = K[d] @ xs
            else:
                u = K[n_drop - 1] @ xs if exhausted == "hold" else np.zeros(m)
        x = family.F[current] @ x + family.G[current] @ u
        state[t + 1] = x
        inputs[t] = u
        modes[t] = current
    return _one_link_result(family, state, inputs, modes, effective, ages + 1, seed,
                            "arrivals" if arrivals is not None else "network", plant_switching, n_drop)
