"""The requests the service accepts, as pydantic models: the HTTP contract's bodies, and what a worker
re-validates a stored request into, so every default (``n_drop``, ``method``, the design options...) is
written once, here.

Matrices are JSON lists of rows; a plant family is a list of matrices, one
per mode. Numbers must be finite JSON numbers: strings, booleans, NaN and
Infinity are rejected with the offending element's location.
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import AllowInfNan, BaseModel, ConfigDict, Field, StringConstraints, Strict, field_validator
from pydantic_core import PydanticCustomError

Number = Annotated[float, Strict(), AllowInfNan(False)]
Int = Annotated[int, Strict()]
Matrix = list[list[Number]]
Vector = list[Number]

try:  # the methods the solver library offers (e.g. "lmi", "ccl")
    from solver import METHODS as _SOLVER_METHODS

    METHODS = tuple(_SOLVER_METHODS)
except Exception:  # pragma: no cover - solver not importable
    METHODS = ("lmi", "ccl")
MethodName = Literal[METHODS]  # type: ignore[valid-type]

try:  # a design's outcomes (solver.result.OUTCOMES) and, on networks, "not_certified"
    from solver.result import OUTCOMES as _SOLVER_OUTCOMES
except Exception:  # pragma: no cover - solver not importable
    _SOLVER_OUTCOMES = ("stabilized", "infeasible", "marginal", "not_converged")
DESIGN_OUTCOMES = tuple(dict.fromkeys((*_SOLVER_OUTCOMES, "not_certified")))


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


def _is_single_matrix(value) -> bool:
    """A list of rows of numbers where a list of matrices (one per plant mode) was expected."""
    return (isinstance(value, list) and bool(value) and all(
        isinstance(row, list) and row and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row)
        for row in value))


def _one_error_for_single_matrix(field: str, what: str):
    """A before-validator: one error saying how to wrap a single matrix, instead of one per row."""

    def check(value):
        if _is_single_matrix(value):
            raise PydanticCustomError(
                "single_matrix",
                "{field} must be a list of {what}, but got a single matrix; for one {item} wrap it in a list: "
                "\"{field}\": [{example}]",
                {"field": field, "what": what, "item": "gain" if field == "gains" else "plant mode",
                 "example": "[[...], [...]]"})
        return value

    return check


# No control characters (like a job's label): names and units are written into SVG (XML refuses NUL and the
# other C0 controls), MATLAB files and figure text.
Name = Annotated[str, StringConstraints(min_length=1, max_length=64, pattern=r"^[^\x00-\x1f\x7f]*$")]
Unit = Annotated[str, StringConstraints(max_length=32, pattern=r"^[^\x00-\x1f\x7f]*$")]
# A units key: a pattern on a dict key becomes JSON Schema patternProperties (an untyped object to generators), so
# keys are checked by the library (a key with a control character is no state or input name: 422 naming it).
UnitKey = Annotated[str, StringConstraints(min_length=1, max_length=64)]
_NAMES = dict(max_length=1000)


def _labels():
    """Optional names and units of a plant's states and inputs (every plant kind): figures, MATLAB and
    python-control exports use them (``PlantFamily.state_names``, ``input_names``, ``units``)."""
    return (
        Field(None, **_NAMES, description="Names of the n states in order (e.g. `[\"i_a\", \"omega\"]`); "
              "distinct. Used in figure labels and exports."),
        Field(None, **_NAMES, description="Names of the m inputs in order (e.g. `[\"v_a\"]`); distinct."),
        Field(None, max_length=2000, description="Unit of each named state or input (e.g. "
              "`{\"omega\": \"rad/s\"}`); keys must be in state_names or input_names. Shown in figure labels."),
    )


_WRAP_DOC = " A plant with one mode is still a list: `[M]`."


class ContinuousPlant(_Strict):
    """Continuous-time family `dx/dt = A_l x + B_l u`, discretized by zero-order hold."""

    kind: Literal["continuous"] = Field(description="`continuous`: A, B and a sampling period.")
    A: list[Matrix] = Field(description="One n x n matrix per plant mode (1/s)." + _WRAP_DOC)
    B: list[Matrix] = Field(description="One n x m matrix per plant mode." + _WRAP_DOC)
    sampling_period: Number = Field(gt=0, description="Sampling period h in seconds (> 0).")
    state_names: list[Name] | None
    input_names: list[Name] | None
    units: dict[UnitKey, Unit] | None
    state_names, input_names, units = _labels()
    mode_names: list[Name] | None = Field(None, **_NAMES, description="Names of the r plant modes in order (e.g. "
                                          "`[\"pole 0.2 m\", \"pole 0.3 m\"]`); distinct. Used in figure titles.")

    C: Union[Matrix, list[Matrix]] | None = Field(
        None, description="Measured outputs `y = C x` (p x n, one for every mode or one per mode) for output "
        "feedback (`feedback: output`).")
    _single_A = field_validator("A", mode="before")(_one_error_for_single_matrix("A", "n x n matrices, one per plant mode"))
    _single_B = field_validator("B", mode="before")(_one_error_for_single_matrix("B", "n x m matrices, one per plant mode"))


class DiscretePlant(_Strict):
    """Discrete-time family `x(k+1) = F_l x(k) + G_l u(k)`."""

    kind: Literal["discrete"] = Field(description="`discrete`: F, G per sample.")
    F: list[Matrix] = Field(description="One n x n matrix per plant mode." + _WRAP_DOC)
    G: list[Matrix] = Field(description="One n x m matrix per plant mode." + _WRAP_DOC)

    C: Union[Matrix, list[Matrix]] | None = Field(
        None, description="Measured outputs `y = C x` (p x n, one for every mode or one per mode) for output "
        "feedback (`feedback: output`).")
    _single_F = field_validator("F", mode="before")(_one_error_for_single_matrix("F", "n x n matrices, one per plant mode"))
    _single_G = field_validator("G", mode="before")(_one_error_for_single_matrix("G", "n x m matrices, one per plant mode"))
    sampling_period: Number | None = Field(
        None, gt=0, description="Optional sampling period (s), only used to label time axes."
    )
    state_names: list[Name] | None
    input_names: list[Name] | None
    units: dict[UnitKey, Unit] | None
    state_names, input_names, units = _labels()
    mode_names: list[Name] | None = Field(None, **_NAMES, description="Names of the r plant modes in order (e.g. "
                                          "`[\"pole 0.2 m\", \"pole 0.3 m\"]`); distinct. Used in figure titles.")


class DcMotorPlant(_Strict):
    """The paper's DC motor (eq. 16/18) with switching inertia, built from physical parameters.

    Note: this uses eq. 18 with the given parameters. The paper's printed eq. 19 matrices
    differ from Table I; to reproduce the paper exactly, send eq. 19 as a `continuous` plant.
    """

    kind: Literal["dc_motor"] = Field(description="`dc_motor`: built from physical parameters; states i_a (A), "
                                      "omega (rad/s), input v_a (V) unless named otherwise.")
    C: Union[Matrix, list[Matrix]] | None = Field(
        None, description="Measured outputs `y = C x` (p x n, one for every mode or one per mode) for output "
        "feedback (`feedback: output`).")
    inertias: list[Annotated[Number, Field(gt=0)]] = Field(
        description="Moment of inertia J per plant mode (kg m^2).", min_length=1
    )
    sampling_period: Number = Field(gt=0, description="Sampling period h in seconds.")
    resistance: Number = Field(2.0, gt=0, description="Armature resistance R (ohm).")
    inductance: Number = Field(0.5, gt=0, description="Armature inductance L (H).")
    torque_constant: Number = Field(0.15, description="Torque constant K_m (N m/A).")
    back_emf_constant: Number = Field(0.15, description="Back-EMF constant K_b (V s/rad).")
    damping: Number = Field(0.2, ge=0, description="Viscous damping B (N m s/rad).")
    state_names: list[Name] | None
    input_names: list[Name] | None
    units: dict[UnitKey, Unit] | None
    state_names, input_names, units = _labels()
    mode_names: list[Name] | None = Field(None, **_NAMES, description="Names of the r plant modes in order (e.g. "
                                          "`[\"pole 0.2 m\", \"pole 0.3 m\"]`); distinct. Used in figure titles.")


Plant = Annotated[Union[ContinuousPlant, DiscretePlant, DcMotorPlant], Field(
    discriminator="kind",
    description="The switched plant family, one of three kinds chosen by `kind`: `continuous` (A, B per mode and "
                "a sampling period: zero-order hold), `discrete` (F, G per mode) or `dc_motor` (the paper's motor "
                "from physical parameters, one mode per inertia). Optional `state_names`, `input_names`, `units`, "
                "`mode_names`.")]


class DesignOptions(_Strict):
    solver: Literal["AUTO", "IPM", "CLARABEL", "SCS"] = Field(
        "AUTO", description="SDP solver. `AUTO`: the fastest with the same verdicts per problem (the structured "
        "interior-point solver `IPM` for `lmi`, decay-rate bisections, `switched`, the common "
        "fixed-gain LMI and `ccl` above the paper's size (block side 2 n n_drop > 12); Clarabel elsewhere). `IPM`, `CLARABEL` (via cvxpy) or `SCS` (first order) force one.")
    margin: Number = Field(1e-6, gt=0, le=1, description="Strictness margin of the LMIs.")
    max_iter: Int = Field(50, ge=1, le=1000, description="Iteration cap of iterative methods (ccl).")
    decay_rate: Annotated[Number, Field(gt=0, le=1)] | Literal["max", "auto"] | None = Field(
        "auto", description="`\"auto\"` (default): a loop settling within about 1.5x the fastest certifiable one, "
        "with moderate gains (coarse bisection for the best rate lambda*, then a design at lambda*^(1/1.5); `ccl`: "
        "plain stability). A number: demand a per-sample decay rate lambda in (0, 1] (|x(i_{m+1})| <= "
        "lambda^eta |x(i_m)| in the certificate's norm); `\"max\"`: the smallest by bisection; null: plain "
        "stability (largest LMI margin, often a slow loop). Rates: `lmi` and `switched`."
    )
    plant_switching: Literal["per_interval", "per_sample"] = Field(
        "per_interval", description="Plant mode constant over an interval between effective packets (the paper), "
        "or free to jump at every sample (r + r^2 + ... + r^n_drop modes)."
    )
    scheme: Literal["predictive", "hold", "zero"] = Field(
        "predictive", description="The paper's predictive buffer, or a baseline: hold the last input (all K_q "
        "equal) or zero input on loss (K_q = 0 for q > 1)."
    )


#: A user's label of a job: shown in job listings; printable text, at most 200 characters.
Label = Annotated[str, StringConstraints(min_length=1, max_length=200, pattern=r"^[^\x00-\x1f\x7f]*$")]
_LABEL = dict(description="Your name for the job (at most 200 printable characters, no control characters); "
                          "shown in job listings.", examples=["motor rig A, h = 0.1 s"])


class Weights(_Strict):
    """Cost weights of `J = sum_k x(k)' Q x(k) + u(k)' R u(k)`."""

    Q: Matrix = Field(description="n x n, symmetric positive semidefinite (state weight).")
    R: Matrix = Field(description="m x m, symmetric positive definite (input weight).")


PerMode = Union[Matrix, list[Matrix]]


class Output(_Strict):
    """Performance output `z(k) = C_l x(k) + D_l u(k)`."""

    C: PerMode = Field(description="p x n, one matrix for every plant mode or a list with one per mode.")
    D: PerMode | None = Field(None, description="p x m, one or one per mode; null means zero.")


Probability = Annotated[float, Strict(), AllowInfNan(False), Field(ge=0, le=1)]


#: Delay distribution of a channel's packets (docs/design.md, "Networks"): `delays[a]` = P(an effective packet
#: arrives a samples late), a = 0..D; sums to 1; D <= n_drop - 1.
Delays = Annotated[list[Probability], Field(min_length=1, max_length=64)]
_DELAYS = dict(description="Per-packet delay distribution: `delays[a]` = P(an effective packet arrives a samples "
                           "after it was sent), a = 0, 1, ...; sums to 1; the largest delay must be <= n_drop - 1. "
                           "Late packets are applied with their age (the newest stamp wins). Null: no delays.")


class BernoulliChannel(_Strict):
    """Independent losses: each sample is not effective with probability `loss`."""

    kind: Literal["bernoulli"] = Field(description="`bernoulli`: independent losses.")
    loss: Probability = Field(description="Loss probability per sample (dimensionless).")
    delays: Delays | None = Field(None, **_DELAYS)


class GilbertElliottChannel(_Strict):
    """Two states, good and bad, switching per sample."""

    kind: Literal["gilbert_elliott"] = Field(description="`gilbert_elliott`: a two-state (good, bad) link.")
    p_gb: Probability = Field(description="P(good -> bad) per sample.")
    p_bg: Probability = Field(description="P(bad -> good) per sample.")
    loss_good: Probability = Field(0.0, description="Loss probability of a sample in the good state.")
    loss_bad: Probability = Field(1.0, description="Loss probability of a sample in the bad state.")
    delays: Delays | None = Field(None, **_DELAYS)


class MarkovChannel(_Strict):
    """A general channel: an irreducible Markov chain, per sample, and a loss probability per state."""

    kind: Literal["markov"] = Field(description="`markov`: a general chain.")
    transition: list[list[Probability]] = Field(max_length=16, description="c x c row-stochastic matrix: "
                                                "`transition[i][j]` = P(state j next | state i).")
    loss: list[Probability] = Field(max_length=16, description="Loss probability per state (length c).")
    delays: Delays | None = Field(None, **_DELAYS)


ChannelSpec = Annotated[Union[BernoulliChannel, GilbertElliottChannel, MarkovChannel], Field(
    discriminator="kind", description="The packet channel (Markov chain of loss probabilities).")]


Age = Annotated[int, Strict(), Field(ge=0, le=64)]


class BoundedDropsNetwork(_Strict):
    """The paper's network: a packet arrives in its own sample or never, at most n_drop - 1 losses in a row."""

    kind: Literal["bounded_drops"] = Field(description="`bounded_drops`: the paper's network (the default).")
    n_drop: Int = Field(ge=1, le=4096, description="N: at most N - 1 samples in a row without a fresh packet.")


class DelaysNetwork(_Strict):
    """Packets arrive min_delay..max_delay samples late or never; the newest stamp wins; ages <= n_drop - 1."""

    kind: Literal["delays"] = Field(description="`delays`: late and out-of-order packets.")
    max_delay: Age = Field(description="Largest delay of a packet that arrives (samples); <= n_drop - 1.")
    n_drop: Int = Field(ge=1, le=4096, description="N: the buffer's age stays <= N - 1.")
    min_delay: Age = Field(0, description="Smallest delay (samples); <= max_delay.")


class WeaklyHardNetwork(_Strict):
    """At most `misses` samples without a fresh packet in any `window` consecutive samples."""

    kind: Literal["weakly_hard"] = Field(description="`weakly_hard`: an (m, K) window constraint.")
    misses: Age = Field(description="m: samples without a fresh packet allowed in any window.")
    window: Int = Field(ge=1, le=32, description="K: the window (samples).")
    n_drop: Int = Field(ge=1, le=4096, description="N: also at most N - 1 in a row.")


class AutomatonNetwork(_Strict):
    """A general network: an automaton whose runs are the admissible buffer-age sequences."""

    kind: Literal["automaton"] = Field(description="`automaton`: nodes with an age each, and edges.")
    ages: list[Age] = Field(min_length=1, max_length=256, description="The buffer age of each node (samples).")
    edges: list[Annotated[list[Annotated[int, Strict(), Field(ge=0)]], Field(min_length=2, max_length=2)]] = Field(
        min_length=1, max_length=4096, description="Pairs `[i, j]`: the age may go from node i's to node j's "
        "(j's age <= i's + 1). Every node needs an out-edge.")
    n_drop: Int | None = Field(None, ge=1, le=4096, description="N (default: the largest age + 1).")


NetworkSpec = Annotated[Union[BoundedDropsNetwork, DelaysNetwork, WeaklyHardNetwork, AutomatonNetwork], Field(
    discriminator="kind",
    description="The network the loop runs on: which buffer-age sequences can happen (docs/design.md, "
                "\"Networks\"). `bounded_drops` is the paper's (the default when null); `delays` adds late and "
                "out-of-order packets; `weakly_hard` an (m, K) window constraint; `automaton` any. The network's "
                "`n_drop` is the design's: `n_drop`, when given too, must agree.")]
_NETWORK = dict(default=None, description="The network the loop runs on (null: the paper's `bounded_drops` with "
                "this `n_drop`): `bounded_drops`, `delays` (late and out-of-order packets), `weakly_hard` (an (m, K) "
                "window) or `automaton`. Its `n_drop` is the request's.")


class _Performance(_Strict):
    """Performance fields shared by design and analysis requests (docs/design.md §8)."""

    weights: Weights | None = Field(None, description="Cost weights (Q, R); with `objective: cost` the default is "
                                                      "identities.")
    x0: Vector | None = Field(None, description="Initial state (length n): the cost is bounded from it; with `u_max` "
                                                "the invariant set contains it.")
    disturbance: PerMode | None = Field(None, description="E (n x p_w), one or one per plant mode: "
                                                          "`x(k+1) = F x + G u + E w` (hinf).")
    output: Output | None = Field(None, description="z = C x + D u (hinf); default z = [x; u].")


class Noise(_Strict):
    """Noise covariances of output feedback: `x(k+1) = F x + G u + w`, `y = C x + v`."""

    W: Matrix = Field(description="n x n process noise covariance (symmetric PSD).")
    V: Matrix = Field(description="p x p measurement noise covariance (symmetric positive definite).")


_OBSERVER_GAINS = dict(description="Output feedback: the observer gains L (one n x p matrix per plant mode); "
                                   "uses the plant's `C`.")


class DesignRequest(_Performance):
    label: Label | None = Field(None, **_LABEL)
    plant: Plant
    n_drop: Int = Field(3, ge=1, description="N_drop: at most n_drop - 1 consecutive losses.")
    method: MethodName = Field(
        "lmi", description="`lmi`: exact convex design (one SDP); `ccl`: the paper's cone "
        "complementarity linearization (iterative, reports progress)."
    )
    options: DesignOptions = Field(default_factory=DesignOptions, description="Solver and design options.")
    objective: Literal["stability", "cost", "hinf"] = Field(
        "stability", description="`stability` (default): the stabilizing design. `cost`: minimize the certified "
        "worst-case quadratic cost over every allowed pattern (`weights`, optional `x0`). `hinf`: minimize the "
        "certified worst-case l2 gain from w to z (`disturbance`, optional `output`). `lmi` only.")
    u_max: list[Annotated[Number, Field(gt=0)]] | None = Field(
        None, description="Input limits (length m): every applied input satisfies |u_j| <= u_max[j] from every "
        "state of the result's `invariant_set`, under every allowed pattern. With `cost` it needs `x0`.")
    channel: ChannelSpec | None = Field(
        None, description="A lossy channel to judge the designed gains on (they are designed for the drop bound "
        "n_drop): the result's `channel` gives the burst rate, mean-square stability when the buffer runs dry "
        "(`exhausted`) and the expected cost (the request's `weights`, else Q = I, R = I), as `POST /v1/channels` "
        "does.")
    exhausted: Literal["hold", "zero"] = Field(
        "hold", description="With a channel: the input once n_drop samples passed without an effective packet.")
    feedback: Literal["state", "output"] = Field(
        "state", description="`state` (default): the controller receives x. `output`: it measures y = C x (the "
        "plant's `C`) over a lossy sensor link and runs an observer; the result adds `observer_gains` and one "
        "`joint_certificate` for plant, estimate and buffer (docs/design.md §12).")
    sensor_n_drop: Int | None = Field(None, ge=1, le=20, description="`feedback: output`: at most "
                                      "sensor_n_drop - 1 measurements lost in a row (default n_drop).")
    observer: Literal["per_mode", "common"] = Field(
        "per_mode", description="`feedback: output`: one observer gain per plant mode, or one for all.")
    noise: Noise | None = Field(None, description="`feedback: output`: process and measurement noise covariances; "
                                "the observer starts from the Kalman gains.")
    network: NetworkSpec | None = Field(**_NETWORK)

    def performance_kwargs(self) -> dict:
        """Keyword arguments of solver.design for the performance fields."""
        return performance_kwargs(self, objective=self.objective, u_max=self.u_max)

    def feedback_kwargs(self) -> dict:
        """Keyword arguments of solver.design for output feedback (none for state feedback)."""
        if self.feedback == "state":
            return {} if self.sensor_n_drop is None and self.noise is None else {
                "sensor_n_drop": self.sensor_n_drop, "noise": None if self.noise is None else (self.noise.W, self.noise.V)}
        return {"feedback": "output", "sensor_n_drop": self.sensor_n_drop, "observer": self.observer,
                "noise": None if self.noise is None else (self.noise.W, self.noise.V)}


def performance_kwargs(req, **extra) -> dict:
    """``weights``, ``x0``, ``disturbance``, ``output`` of a request as solver.design/analyze keywords."""
    out = dict(extra)
    if req.weights is not None:
        out["weights"] = (req.weights.Q, req.weights.R)
    if req.x0 is not None:
        out["x0"] = req.x0
    if req.disturbance is not None:
        out["disturbance"] = req.disturbance
    if req.output is not None:
        out["output"] = (req.output.C, req.output.D)
    return out


_single_gains = _one_error_for_single_matrix("gains", "n_drop gain matrices K_1..K_N (each m x n)")


class SimulationRequest(_Strict):
    plant: Plant
    gains: list[Matrix] = Field(description="n_drop gain matrices K_1..K_N, each m x n (`gains[q-1] = K_q`).")
    _single = field_validator("gains", mode="before")(_single_gains)
    n_drop: Int | None = Field(None, ge=1, description="Defaults to the number of gain matrices.")
    x0: Vector = Field(description="Initial state (length n).")
    steps: Int = Field(100, ge=1, description="Samples to simulate.")
    seed: Int = Field(42, ge=0, description="Seed of the losses and plant jumps: same seed, same run.")
    loss_model: Literal["paper", "bernoulli"] = Field("paper", description="`paper`: the paper's loss process; "
                                                      "`bernoulli`: independent losses.")
    sensor_loss: Number = Field(0.2, ge=0, lt=1, description="Sensor packet loss probability per sample.")
    control_loss: Number = Field(0.2, ge=0, lt=1, description="Control packet loss probability per sample.")
    plant_switching: Literal["per_interval", "per_sample", "none"] = Field(
        "per_interval", description="When the plant mode may jump (`none`: fixed `mode`).")
    mode: Int | None = Field(None, ge=0, description="Fixed plant mode (0-based) when plant_switching is none.")
    channel: ChannelSpec | None = Field(
        None, description="Draw losses from this Markov channel instead (its state at 0 from the stationary "
        "distribution, sample 0 effective, runs past the bound included); loss_model, sensor_loss, control_loss "
        "and plant_switching are then not used.")
    exhausted: Literal["hold", "zero"] = Field(
        "hold", description="With a channel: the input once n_drop samples passed without an effective packet.")
    plant_transitions: Matrix | None = Field(
        None, description="With a channel: per-sample Markov chain of the plant mode (r x r); null keeps the "
        "initial mode (`mode`, or drawn uniformly).")
    observer_gains: list[Matrix] | None = Field(
        None, description="Output feedback: the observer gains L (one n x p matrix per plant mode, the plant's "
        "`C`); `sensor_loss` then loses measurements, `control_loss` control packets, and the run adds `estimate`.")
    sensor_n_drop: Int | None = Field(None, ge=1, le=20, description="With `observer_gains`: at most "
                                      "sensor_n_drop - 1 measurements lost in a row (default n_drop).")
    xh0: Vector | None = Field(None, description="With `observer_gains`: the initial estimate (default 0).")
    network: NetworkSpec | None = Field(**_NETWORK)


class AnalysisRequest(_Performance):
    """Stability analysis of given gains; with `weights` (or `x0`) also the cost bracket, with `disturbance`
    the l2-gain bracket."""

    plant: Plant
    gains: list[Matrix] = Field(description="n_drop gain matrices K_1..K_N, each m x n (`gains[q-1] = K_q`).")
    _single = field_validator("gains", mode="before")(_single_gains)
    n_drop: Int | None = Field(None, ge=1, description="Defaults to the number of gain matrices.")
    max_product_length: Int | None = Field(
        None, ge=1, le=8, description="Longest mode product searched for a destabilizing pattern "
        "(default 4; the number of products per length is capped by NCS_MAX_ANALYSIS_PRODUCTS)."
    )
    plant_switching: Literal["per_interval", "per_sample"] = Field(
        "per_interval", description="Plant mode constant over an interval (the paper), or free to jump per sample."
    )
    bounds: Literal["quadratic", "all", "none"] = Field(
        "quadratic", description="Joint-spectral-radius upper bounds and best certified decay rate to compute: "
        "from common quadratic certificates, also from switched ones (`all`, slower), or none."
    )
    observer_gains: list[Matrix] | None = Field(None, **_OBSERVER_GAINS)
    sensor_n_drop: Int | None = Field(None, ge=1, le=20, description="With `observer_gains`: at most "
                                      "sensor_n_drop - 1 measurements lost in a row (default n_drop).")
    network: NetworkSpec | None = Field(**_NETWORK)


class CostWeights(_Strict):
    Q: Matrix = Field(description="n x n state weight (symmetric PSD).")
    R: Matrix = Field(description="m x m input weight (symmetric PSD).")


class ChannelRequest(_Strict):
    """Given gains on a stochastic channel: bursts, mean-square stability, expected cost."""

    plant: Plant
    gains: list[Matrix] = Field(description="n_drop gain matrices K_1..K_N, each m x n (`gains[q-1] = K_q`).")
    _single = field_validator("gains", mode="before")(_single_gains)
    n_drop: Int | None = Field(None, ge=1, description="Defaults to the number of gain matrices.")
    channel: ChannelSpec
    exhausted: Literal["hold", "zero"] = Field(
        "hold", description="Input once n_drop samples passed without an effective packet: keep `K_N x(i_m)` "
        "(`hold`) or 0 (`zero`).")
    plant_transitions: Matrix | Literal["arbitrary"] | None = Field(
        None, description="Per-sample Markov chain of the plant mode (r x r, row l: probabilities of the next "
        "mode); null: the mode never changes (uniform at k = 0); `arbitrary`: any switching (a sufficient LMI test).")
    weights: CostWeights | None = Field(None, description="Weights of the expected cost "
                                                          "`E sum x'Qx + u'Ru` (E x(0) x(0)' = I).")
    noise: Matrix | None = Field(None, description="Process noise covariance W (n x n): adds the stationary cost "
                                                   "per sample (needs weights).")
    network: NetworkSpec | None = Field(
        None, description="A network to hold the channel against: the result's `network_violations` gives the "
        "exact rate at which the channel breaks it (drop bound, delay range or weakly-hard window).")


class GridPoint(_Strict):
    sampling_period: Number = Field(gt=0, description="h in seconds.")
    n_drop: Int = Field(ge=1, description="N at this point.")


class MarginRequest(_Strict):
    """A stability-margin job: many designs in the worker pool, with progress and cancel."""

    label: Label | None = Field(None, **_LABEL)
    plant: Plant
    search: Literal["n_drop", "sampling_period", "grid"] = Field(
        description="`n_drop`: the largest drop bound with a design (n_drop = 1, 2, ... up to `n_drop_max`); "
        "`sampling_period`: the largest h for the given `n_drop`, by bisection on [h_min, h_max] (continuous "
        "or dc_motor plants); `grid`: a design at every (h, n_drop) in `points`."
    )
    method: MethodName = Field("lmi", description="Design method used at every point.")
    n_drop: Int | None = Field(None, ge=1, description="The drop bound of a `sampling_period` search.")
    n_drop_max: Int = Field(12, ge=1, le=64, description="Largest n_drop an `n_drop` search tries.")
    h_min: Number = Field(1e-3, gt=0, description="Smallest sampling period tried (s).")
    h_max: Number = Field(2.0, gt=0, description="Largest sampling period tried (s).")
    tol: Number = Field(1e-3, gt=0, description="Tolerance of the bisection on h (s).")
    points: list[GridPoint] | None = Field(None, description="The (h, n_drop) pairs of a `grid`.")
    options: DesignOptions = Field(default_factory=DesignOptions, description="Solver and design options.")
