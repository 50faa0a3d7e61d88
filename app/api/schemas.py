"""Pydantic response schemas of the HTTP contract (the request bodies are ``app.compute.requests``).

Every field says its shape and unit. Notation: n states, m inputs, r plant modes, ``n_drop`` = N (at most
N - 1 consecutive losses), S closed-loop modes (``modes``: S = r N per interval, r + r^2 + ... + r^N per
sample), h the sampling period in seconds. A *per-sample rate* lambda bounds ``|x(i_{m+1})| <= lambda^eta
|x(i_m)|`` (eta samples between effective packets) in the certificate's norm; its *per-second* form is
``lambda^(1/h)`` (the factor by which the norm bound shrinks per second). Numbers inside result arrays are null where
the computation gave a non-finite value. Result models accept fields they do not list (newer solver versions add some), so clients should ignore unknown fields too.
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_serializer, model_serializer

from app.compute.requests import DESIGN_OUTCOMES, DesignRequest, MarginRequest

#: A number in a result; null where the computation gave a non-finite value (NaN, infinity).
Num = float | None
Matrix = list[list[Num]]


class _Open(BaseModel):
    """A result object: documented fields, and any further ones the solver adds (kept as they are)."""

    model_config = ConfigDict(extra="allow")


# -- closed-loop modes, certificates --------------------------------------------------------------
class ModeLabel(_Open):
    """One closed-loop mode s of the interval maps ``A_s``: the plant mode(s) over the interval and its length."""

    plant: int | None = Field(None, description="Per-interval switching: the plant mode l (0-based) over the "
                                                "whole interval.")
    plants: list[int] | None = Field(None, description="Per-sample switching: the plant mode (0-based) at each of "
                                                       "the eta samples of the interval.")
    eta: int | None = Field(None, description="Interval length eta in samples (1 .. n_drop): eta - 1 losses before the next "
                                 "effective packet.")
    age: int | None = Field(None, description="On a network: the buffer age d (samples) the mode applies, "
                                              "`u = K_{d+1} x(t - d)`.")
    from_: int | None = Field(None, alias="from", description="On a network: the automaton node (0-based) the "
                                                                "transition leaves.")
    to: int | None = Field(None, description="On a network: the automaton node (0-based) it enters.")
    node: int | None = Field(None, description="On a network: the automaton node (0-based) of the sample.")

    @model_serializer(mode="wrap")
    def _network_fields_when_set(self, handler):
        # The network fields appear only on networks: the paper's answers stay as they were.
        return {k: v for k, v in handler(self).items() if v is not None or k not in ("age", "from", "to", "node")}


class LeftVector(_Open):
    real: list[Num] = Field(description="Real part of the left eigenvector w (length n).")
    imag: list[Num] = Field(description="Imaginary part of w (length n).")


class CertificateState(_Open):
    node: int = Field(description="Automaton node (0-based) of the network.")
    plant: int = Field(description="Plant mode (0-based).")


class UnstableCycle(_Open):
    """An admissible cycle of the network whose closed-loop product has spectral radius >= 1 (proven)."""

    ages: list[int] = Field(description="The buffer age at each sample of the cycle (samples).")
    modes: list[int] = Field(description="The plant mode (0-based) at each sample.")
    nodes: list[int] | None = Field(None, description="On a network: the automaton node (0-based) at each sample.")


class Certificate(_Open):
    """The proof behind a verdict. Which fields are set depends on `kind`:

    * `common_quadratic` (Theorem 1): `P` ((n N) x (n N)), `X` (n x n), `margin`, `decrease`, `min_eig_P`...
    * `switched` (mode-dependent Lyapunov, Daafouz et al.): `P` (S x n x n, one matrix per mode), same scalars.
    * `farkas` (no design of the method exists): `multipliers` (S x 2n x 2n), `gain_bound`, `delta`, `e_norm`.
    * `uncontrollable` (no gains can stabilize): `plant`, `eigenvalue`, `left_vector`, `residual_eig`,
      `residual_input`.
    * On a `network`: node-dependent quadratic certificates (`P`: one matrix per automaton node, `nodes`, or
      per (node, plant mode), `states`; `form` says on which state) and `farkas_network` (the network LMI has
      no solution: outcome `not_certified`; with `per_block` true, only solutions whose slack blocks have equal
      traces are excluded).
    """

    kind: str = Field(description="`common_quadratic`, `switched` (stability proofs), `farkas` or "
                                  "`uncontrollable` (proofs that no design exists).")
    verified: bool | None = Field(None, description="True iff the service re-checked the certificate in float64 "
                                                    "(or exact) arithmetic against the original condition.")
    exact: bool | None = Field(None, description="`common_quadratic`/`switched`: true when `verified` comes from "
                                                 "the exact rational re-check on the loop rebuilt from the float64 "
                                                 "plant and gains (n <= 8, where float64 could not decide its tiny "
                                                 "margin), not the float64 one.")
    source: str | None = Field(None, description="What produced it (`lmi`, `switched`, `ccl_iterate`, "
                                                 "`theorem1_lmi`, `switched_lmi`, `sdp_dual`, ...).")
    statement: str | None = Field(None, description="`farkas`, `uncontrollable`: what the certificate proves, "
                                                    "in words.")
    method: str | None = Field(None, description="`farkas`: the design method it excludes (`lmi` or `switched`).")
    margin: float | None = Field(
        None, description="`common_quadratic`/`switched`: relative decrease `decrease / lambda_max(P)` "
        "(dimensionless, relative to the largest eigenvalue of the re-checked matrix P: the reduced `X` for "
        "`common_quadratic`, whose `A_s^T X A_s < X` is equivalent to Theorem 1; accepted above 1e-9). "
        "`farkas`: the relative strictness tau of the excluded designs (outcome `marginal`: only those).")
    decrease: float | None = Field(None, description="Smallest eigenvalue of `P - Phi_s^T P Phi_s` over all modes "
                                                     "(absolute, in the units of P).")
    min_eig_P: float | None = Field(None, description="Smallest eigenvalue of P (of every P_s); must be > 0.")
    condition_number: float | None = Field(None, description="Largest 2-norm condition number of the P matrices.")
    decay_rate: float | None = Field(None, description="Per-sample rate lambda the certificate also proves (or "
                                                       "excludes, for `farkas`); null when none was asked for.")
    decay_factor_per_second: float | None = Field(
        None, description="The factor the state's norm shrinks by over one second, `decay_rate^(1/h)` (dimensionless, "
        "in (0, 1]); null without a sampling period.")
    exponential_rate: float | None = Field(
        None, description="The same rate in 1/s, `-ln(decay_rate)/h`: the norm is below `c exp(-rate t)`.")
    time_constant: float | None = Field(None, description="`1 / exponential_rate` in seconds.")
    decay_rate_per_second: float | None = Field(
        None, description="Deprecated name of `decay_factor_per_second` (a factor per second, not a rate in 1/s).")
    worst_mode: int | None = Field(None, description="Index into `modes` of the mode with the smallest decrease.")
    P: Matrix | list[Matrix] | None = Field(
        None, description="`common_quadratic`: the augmented Theorem 1 matrix, (n N) x (n N). `switched`: S "
        "matrices n x n, `P[s]` for mode `modes[s]`. Omitted in the designs of a margin curve.")
    form: str | None = Field(None, description="Network certificates: `lifted` (x at the samples where a packet "
                                               "takes effect) or `augmented` (xi(t) = (x(t), ..., x(t-N+1))).")
    nodes: list[int] | None = Field(None, description="Network certificates: the automaton node of each `P[i]`.")
    states: list[CertificateState] | None = Field(None, description="Network analyses: the (node, plant mode) of "
                                                                    "each `P[i]`.")
    worst_edge: list[int] | None = Field(None, description="Network analyses: the edge `[i, j]` (indices into "
                                                           "`states`) with the smallest decrease.")
    X: Matrix | None = Field(None, description="`common_quadratic`: the reduced certificate on x(i_m), n x n "
                                               "(`A_s^T X A_s < X` for all s).")
    multipliers: list[Matrix] | list[list[Matrix]] | None = Field(
        None, description="`farkas`: PSD multipliers Z_s, S x 2n x 2n in the order of `modes` (`switched` "
        "method: S x S x 2n x 2n).")
    gain_bound: float | None = Field(None, description="`farkas`: no design with relative margin >= `margin` "
                                                       "and gain norm `sqrt(sum_q ||K_q||_2^2)` below this exists; "
                                                       "null = any norm.")
    gain_bound_any_margin: float | None = Field(None, description="`farkas`: the same for designs of any margin "
                                                                  "(0: none excluded, outcome `marginal`).")
    any_margin: bool | None = Field(None, description="`farkas`: whether designs of every margin are excluded "
                                                      "(outcome `infeasible`) or only those with margin >= `margin` "
                                                      "(outcome `marginal`).")
    gain_bound_unbounded: bool | None = Field(None, description="`farkas`: true when `gain_bound` is infinite.")
    delta: float | None = Field(None, description="`farkas`: proven lower bound of `-lambda_max(Q)` less the PSD "
                                                  "shifts.")
    e_norm: float | None = Field(None, description="`farkas`: proven upper bound of `||E||_F`.")
    skew_norm: float | None = Field(None, description="`farkas`, switched method: bound of the skew part of "
                                                      "the slack coefficient.")
    scaled: bool | None = Field(None, description="`farkas`: true when it holds in the design's balanced "
                                                  "coordinates (`scaling`).")
    plant: int | None = Field(None, description="`uncontrollable`: the plant mode l (0-based).")
    eigenvalue: list[Num] | None = Field(None, description="`uncontrollable`: [real, imaginary] part of the "
                                                             "eigenvalue of F_l no input reaches (|lambda| >= 1).")
    left_vector: LeftVector | None = Field(None, description="`uncontrollable`: left eigenvector w "
                                                             "(w^H F_l = lambda w^H, w^H G_l = 0).")
    residual_eig: float | None = Field(None, description="`uncontrollable`: float64 residual "
                                                         "`||w^H F_l - lambda w^H||`.")
    residual_input: float | None = Field(None, description="`uncontrollable`: float64 residual `||w^H G_l||`.")
    dimension: int | None = Field(None, description="`uncontrollable`: dimension of the uncontrollable part.")


# -- designs ---------------------------------------------------------------------------------------
class IterationRecord(_Open):
    iteration: int | None = Field(None, description="0 is the feasible start (CCL Step 1), then 1, 2, ...")
    objective: float | None = Field(None, description="Objective value of the solved SDP.")
    trace_gap: float | None = Field(None, description="CCL: `trace(P Q)/(n N) - 1` (0 when PQ = I).")
    theorem1: bool | None = Field(None, description="Whether this iterate's gains satisfy Theorem 1 (re-checked).")
    certificate_margin: float | None = Field(None, description="Relative margin of that certificate "
                                                               "(see `Certificate.margin`).")
    solve_time: float | None = Field(None, description="The conic solver's own time for this iteration (s).")
    elapsed: float | None = Field(None, description="Wall time since the design started (s).")


class Timings(_Open):
    total: float | None = Field(None, description="Wall time of the whole computation (s).")
    setup: float | None = Field(None, description="Problem build time (s); 0 when a compiled problem was reused.")
    solver: float | None = Field(None, description="Sum of the conic solver's own times (s).")
    overhead: float | None = Field(None, description="The rest of `total` (s).")
    solves: int | None = Field(None, description="Number of conic solves.")
    cached: bool | None = Field(None, description="Whether the compiled problem was reused.")
    designs: int | None = Field(None, description="Margin jobs: number of designs run (a count, not seconds).")


class RatePoint(_Open):
    decay_rate: float | None = Field(None, description="Per-sample rate lambda tried.")
    outcome: str | None = Field(None, description="The design's outcome at that rate.")
    proof: str | None = Field(None, description="Kind of the certificate behind that outcome (`common_quadratic`, "
                                                "`switched`, `farkas`, `uncontrollable`; null: none).")
    method: str | None = Field(None, description="The method of that step when it differs from the result's.")
    message: str | None = Field(None, description="`outcome: solver_failed`: the solver's words (such a step "
                                                  "certifies nothing and proves nothing).")
    step: str | None = Field(None, description="How the rate was chosen (`path`: an end of the rate-following "
                                               "interior-point path; `newton`, `below`, `close`, `bisect`, ...: a probe).")
    iterations: int | None = Field(None, description="`step: path`: the path's Newton steps.")
    solves: int | None = Field(None, description="`step: path`: those steps in SDP-equivalents (in `solve_count`).")


class Settling(_Open):
    """What a certified decay rate guarantees, in time units."""

    fraction: float | None = Field(None, description="Settling means reaching this fraction of |x(0)| (0.02).")
    samples: int | None = Field(None, description="Samples after which |x| <= fraction |x(0)| at every packet "
                                                  "instant, worst case over every allowed loss and switching sequence.")
    seconds: float | None = Field(None, description="The same in seconds (`samples h`); null without h.")
    metric_condition: float | None = Field(None, description="Condition number of the certificate's metric "
                                                             "(the bound's factor is its square root).")
    decay_rate: float | None = Field(None, description="The certified rate, a factor per sample.")
    decay_factor_per_second: float | None = Field(None, description="The factor per second, `decay_rate^(1/h)`.")
    exponential_rate: float | None = Field(None, description="The rate in 1/s, `-ln(decay_rate)/h`.")
    time_constant: float | None = Field(None, description="`1 / exponential_rate`, in seconds.")


class RateBracket(_Open):
    lower: float | None = Field(None, description="Lower end of the bisection (per sample).")
    upper: float | None = Field(None, description="Upper end: the returned certified rate (per sample).")
    lower_proven: bool | None = Field(None, description="Every design of the method at `lower` is excluded by a "
                                                        "Farkas/uncontrollable certificate (of any margin).")
    lower_proof: str | None = Field(None, description="What the step at `lower` proved: `infeasible` (no design of "
                                                      "any margin), `marginal` (only designs with relative margin "
                                                      ">= `lower_margin` excluded) or null (no proof).")
    lower_margin: float | None = Field(None, description="The margin of a `marginal` lower end.")
    loop_spectral_rate: float | None = Field(None, description="`max_s rho(A_s)^(1/eta_s)` of the returned loop: "
                                                               "no certificate for these gains goes below it.")
    relative_tolerance: float | None = Field(None, description="Relative tolerance of the bisection.")
    fastest_certified: float | None = Field(None, description="`decay_rate: auto`: the fastest rate the coarse "
                                                              "bisection certified (per sample).")
    slowdown: float | None = Field(None, description="`decay_rate: auto`: settling time asked for, as a multiple of "
                                                     "the fastest certified one's (1.5).")
    open_loop_rate: float | None = Field(None, description="`decay_rate: auto` on a plant whose every mode is stable "
                                                           "without control: its open-loop spectral radius per sample.")
    open_loop_speedup: float | None = Field(None, description="`decay_rate: auto` on such a plant: the rate is no "
                                                              "smaller than `open_loop_rate ** open_loop_speedup` "
                                                              "(settling at most that many times faster than the "
                                                              "plant's own, 10).")


class Scaling(_Open):
    state: list[Num] | None = Field(None, description="Diagonal state scaling (length n), powers of two.")
    input: list[Num] | None = Field(None, description="Diagonal input scaling (length m).")
    certificate: str | None = Field(None, description="Coordinates `certificate` is expressed in (`original` or "
                                                      "`scaled`).")


class Performance(_Open):
    """A certified performance bracket (docs/design.md §8): `lower <= true worst case <= upper`."""

    kind: str = Field(description="`cost`: worst-case `sum_k x'Qx + u'Ru` (w = 0) from `x0`, or its mean over "
                                  "initial states of covariance I; `hinf`: worst-case l2 gain from w to z, x(0) = 0.")
    upper: float | None = Field(None, description="Certified upper bound (a re-checked quadratic certificate; for the "
                                                  "cost the smaller of its bound and the prefix tree's certified bound "
                                                  "on it, for hinf of `mode_certificate`'s when set, docs/design.md "
                                                  "§8.4); null when none passed the float64 re-check (`message` says "
                                                  "why).")
    certificate_upper: float | None = Field(None, description="The quadratic certificate's own bound (`x0'Px`, "
                                                              "`trace P` or gamma): what the design's SDP minimizes.")
    lower: float | None = Field(None, description="The value of the worst allowed run searched (`witness`): a "
                                                  "proven lower bound on its cost or l2 gain, evaluated in exact "
                                                  "arithmetic (the message says where a float64 value stands "
                                                  "instead; docs/design.md §8.4).")
    lower_infinite: bool | None = Field(None, description="True when a periodic pattern is unstable (infinite cost).")
    witness: list[list[int | list[int]]] | None = Field(
        None, description="That run: `[plant_mode, eta]` per interval (`plant_mode` a list of plant modes per sample "
        "under per-sample switching), the first `lead` once, then the rest repeated forever (hinf: the disturbance "
        "acts in the first `lead` only).")
    certificate: Matrix | list[Matrix] | None = Field(
        None, description="P (n x n) of the upper bound: `x'Px` bounds the cost from x (cost), or is the bounded-real "
        "storage (hinf). On a `network`: one P per node matrix (V x k x k, `form` says on which state).")
    verified: bool | None = Field(None, description="Whether `upper` is certified: `certificate` passed the float64 "
                                  "re-check (or the exact one), or `exact_certificate` passed its exact check (then "
                                  "`certificate` may be only its float64 rounding; `message` says which), or on a "
                                  "`network` `mode_certificate` passed it (`certificate` may then be null).")
    exact_certificate: list[list[str]] | None = Field(
        None, description="One LTI loop (one mode, n_drop = 1, n <= 8) whose float64 certificate cannot reach its "
        "bound: P (n x n, strings `p/q`), for the cost solving `P = A'PA + S` exactly for the loop F + G K, for hinf "
        "the bounded-real inequality at `upper^2`, verified exactly on that loop; `certificate_upper` is its bound "
        "rounded up (docs/design.md §8.5).")
    mode_certificate: list[Matrix] | None = Field(
        None, description="hinf over several loop modes: one storage P_s per mode (S x n x n) when they certify a "
        "smaller l2 gain than the common P; `upper` is then their bound (docs/design.md §8.4). On a `network`: one P "
        "per sequence of the last `memory` transitions, for the state just after it, then (cost) one per start node and "
        "shorter run start, when they certify a smaller bound than the node matrices (`certificate_upper`) or the "
        "node matrices pass no re-check (docs/design.md §11.3).")
    gap: float | None = Field(None, description="`(upper - lower) / upper`.")
    x0: list[Num] | None = Field(None, description="The initial state of a cost bound (null: mean over x0).")
    patterns: int | None = Field(None, description="Periodic patterns evaluated for `lower`.")
    lead: int | None = Field(None, description="The witness's first `lead` intervals run once, then the rest repeats "
                                               "forever (0: the whole witness is the period, from the start).")
    message: str | None = Field(None, description="The bracket in words.")
    walk: list[dict[str, int]] | None = Field(
        None, description="On a `network`: the witness's transitions (`from`, `to` automaton nodes, `plant`, and `age` "
        "or `eta`); the first `lead` once from a start node, then the rest repeated forever, is an admissible run "
        "whose value is `lower` (docs/design.md §11.3).")
    form: str | None = Field(None, description="On a `network`: `lifted` (x at packet receptions) or `augmented` "
                                               "(the stacked state (x(t), ..., x(t-N+1))).")
    start_nodes: list[int] | None = Field(None, description="On a `network`: the automaton nodes a run may start "
                                                            "in; the bound is the largest over them.")
    memory: int | None = Field(None, description="On a `network`: 0 when `upper` is the node matrices' bound, else the "
                                                 "number of transitions each matrix of `mode_certificate` is for: the "
                                                 "next ones (cost) or the last ones (l2 gain; docs/design.md §11.3).")


class ObserverObstruction(_Open):
    """A sensor pattern under which no observer gain makes the estimate converge (docs/design.md §12)."""

    kind: str = Field(description="`unobservable_pattern`.")
    mode: int = Field(description="The plant mode (0-based).")
    eigenvalue: list[Num] = Field(description="[real, imaginary] part of the eigenvalue of F^M on the subspace.")
    modulus: float = Field(description="Its modulus (>= 1).")
    basis: Matrix = Field(description="n x d basis of the F^M-invariant subspace inside ker C (exact rationals).")
    period: int = Field(description="M = sensor_n_drop: M - 1 measurements lost, then one received.")


class ObserverDesign(_Open):
    """The observer gains of an output-feedback design and what proves them."""

    outcome: str = Field(description="`certified`, `no_observer` (with `obstruction`) or `not_certified`.")
    gains: list[Matrix] | None = Field(None, description="L, r x n x p.")
    certificate: list[Matrix] | None = Field(None, description="Q_sigma (n x n) per sensor node sigma (measurements "
                                             "lost in a row), re-checked in float64.")
    decay_rate: float | None = Field(None, description="Per-sample rate the error certificate proves (null: 1).")
    kind: str | None = Field(None, description="`per_mode`, `common` or `kalman`.")
    message: str | None = Field(None, description="The outcome in words.")
    obstruction: ObserverObstruction | None = Field(None, description="`no_observer`: the proof.")
    error_bound: list[Matrix] | None = Field(None, description="With `noise`: X_sigma (n x n per sensor node), a "
                                             "certified bound E[e e'] <= X_sigma under every admissible sensor pattern.")


class JointCertificate(_Open):
    """One quadratic certificate `V = x'Px + e'Q_sigma e` of the whole output-feedback loop."""

    kind: str = Field(description="`joint_block_diagonal`.")
    P: Matrix = Field(description="n x n, on the state at delivered packets.")
    Q: list[Matrix] = Field(description="n x n per sensor node, on the filtered estimation error.")
    blocks: int = Field(description="Interval x sensor-pattern x next-mode inequalities re-checked.")
    worst: float = Field(description="Largest proven upper bound of their eigenvalues (< 0).")
    checked: bool = Field(description="True: re-checked in float64 without the solver.")


class ErrorCycle(_Open):
    """A periodic admissible sensor pattern whose estimation error grows."""

    plant: int = Field(description="Plant mode (0-based), constant.")
    arrivals: list[bool] = Field(description="Measurement arrivals of one period.")
    rate: float = Field(description="Growth per sample, rho(period map)^(1/period) > 1.")


class OutputAnalysis(_Open):
    """The verdict on an output-feedback loop with given K and L."""

    stable: bool | None = Field(description="True with `certificate`, false with a proof, null otherwise.")
    reason: str = Field(description="The verdict in words.")
    certificate: JointCertificate | None = Field(None, description="The joint certificate when stable.")
    error_cycle: ErrorCycle | None = Field(None, description="When the estimate diverges: the pattern.")


class NetworkEcho(_Open):
    """The network a result is for, as the request gave it (`kind` and its parameters)."""

    kind: str = Field(description="`bounded_drops`, `delays`, `weakly_hard`, `automaton` (or `intersection`).")
    n_drop: int | None = Field(None, description="N: the buffer's age stays <= N - 1.")
    max_delay: int | None = Field(None, description="`delays`: largest delay (samples).")
    min_delay: int | None = Field(None, description="`delays`: smallest delay (samples).")
    misses: int | None = Field(None, description="`weakly_hard`: misses allowed per window.")
    window: int | None = Field(None, description="`weakly_hard`: the window (samples).")
    ages: list[int] | None = Field(None, description="`automaton`: the age of each node.")
    edges: list[list[int]] | None = Field(None, description="`automaton`: the edges `[i, j]`.")

    @model_serializer(mode="wrap")
    def _as_given(self, handler):
        # The network exactly as the request gave it: a delays network has no `ages` (not `"ages": null`).
        return {k: v for k, v in handler(self).items() if v is not None}


#: Every outcome of a design.
DesignOutcome = Literal[DESIGN_OUTCOMES]  # type: ignore[valid-type]


class DesignResult(_Open):
    """The result of a design job (`outcome` is an answer: `infeasible` is a succeeded job too)."""

    outcome: DesignOutcome = Field(
        description="`stabilized` (gains with a re-checked certificate), `infeasible` (no design of this method "
        "exists, of any margin; `certificate` proves it), `marginal` (the Farkas certificate excludes only designs "
        "with relative margin >= `certificate.margin`; smaller-margin designs may exist), `not_certified` (on a "
        "`network`: the convex sufficient condition is proven infeasible, `certificate` attached, which does not "
        "prove that no gains exist) or `not_converged`.")
    network: NetworkEcho | None = Field(None, description="The network the gains are designed and certified "
                                                             "for (as in the request); null: the paper's.")
    method: str | None = Field(None, description="Design method: `lmi`, `ccl` or `switched`.")
    n_drop: int | None = Field(None, description="N: at most N - 1 consecutive losses.")
    gains: list[Matrix] | None = Field(
        None, description="n_drop x m x n: `gains[q-1] = K_q`; after an effective packet at i_m the actuator "
        "applies `u(i_m + q - 1) = K_q x(i_m)`. Input units per state unit. Null when infeasible.")
    certificate: Certificate | None = Field(None, description="The proof of the outcome (see its `kind`).")
    spectral_radii: Matrix | list[Num] | None = Field(
        None, description="Spectral radius of every interval closed loop `A_{l,eta}(K)` (eq. 8, dimensionless, "
        "per interval of eta samples, not per sample): r x n_drop, `[l][eta-1]`, for per-interval switching; "
        "a flat list of S in the order of `modes` for per-sample switching.")
    max_spectral_radius: float | None = Field(None, description="Largest of `spectral_radii` (< 1 is necessary "
                                                                "for stability, not sufficient).")
    history: list[IterationRecord] | None = Field(None, description="One record per solver iteration.")
    iterations: int | None = Field(None, description="Iterations after the start (0 for one-shot methods).")
    solver: str | None = Field(None, description="Solver that produced the gains: `IPM`, `CLARABEL`, `SCS`, or "
                               "`scipy` (the one-mode Riccati refinement, solver_status `riccati`).")
    solver_status: str | None = Field(None, description="Status of the last conic solve.")
    timings: Timings | None = Field(None, description="Where the time went (s).")
    message: str | None = Field(None, description="The outcome in words.")
    scheme: str | None = Field(None, description="`predictive` (the paper), `hold` or `zero` (baselines).")
    plant_switching: str | None = Field(None, description="`per_interval` or `per_sample`.")
    decay_rate: float | None = Field(None, description="Per-sample decay rate lambda the certificate proves, when "
                                                       "one was asked for.")
    decay_factor_per_second: float | None = Field(
        None, description="The factor the state's norm shrinks by over one second, `decay_rate^(1/h)` (dimensionless, "
        "in (0, 1]); null without a sampling period.")
    exponential_rate: float | None = Field(
        None, description="The same rate in 1/s, `-ln(decay_rate)/h`: the norm is below `c exp(-rate t)`.")
    time_constant: float | None = Field(None, description="`1 / exponential_rate` in seconds.")
    decay_rate_per_second: float | None = Field(
        None, description="Deprecated name of `decay_factor_per_second` (a factor per second, not a rate in 1/s).")
    settling: Settling | None = Field(None, description="What the certified decay rate guarantees: `samples` and "
                                  "`seconds` to 2 % of the initial state's norm, worst case over every allowed loss "
                                  "and switching sequence (at packet instants), the rate as `decay_rate`, "
                                  "`decay_factor_per_second`, `exponential_rate` (1/s), `time_constant` (s), and the "
                                  "certificate metric's `metric_condition`. Null without a certified rate.")
    rate_search: list[RatePoint] | None = Field(None, description="`decay_rate: max`: every rate tried, in order.")
    solve_count: int | None = Field(None, description="How many SDPs the design solved (warm or cold, the rate "
                                                      "search's and the certificates' included): its cost in "
                                                      "units of one plain design's solve.")
    rate_bracket: RateBracket | None = Field(None, description="`decay_rate: max`: the ends of the bisection.")
    modes: list[ModeLabel] | None = Field(None, description="The S closed-loop modes, in the order of the flat "
                                                            "arrays (`worst_mode`, switched `P`, multipliers).")
    scaling: Scaling | None = Field(None, description="The diagonal scaling the design was made in (null: none).")
    F: list[Matrix] | None = Field(None, description="The discretized plant: r x n x n, `F[l]` for plant mode l.")
    G: list[Matrix] | None = Field(None, description="r x n x m, `G[l]` for plant mode l.")
    sampling_period: float | None = Field(None, description="h in seconds (null for a discrete plant without one).")
    state_names: list[str] | None = Field(None, description="Names of the n states (from the plant).")
    input_names: list[str] | None = Field(None, description="Names of the m inputs (from the plant).")
    units: dict[str, str] | None = Field(None, description="Unit of each named state or input.")
    objective: str | None = Field(None, description="`stability`, `cost` or `hinf`: what the design optimized.")
    performance: Performance | None = Field(None, description="`cost`/`hinf`: the certified bracket.")
    invariant_set: Matrix | list[Matrix] | None = Field(
        None, description="With `u_max`: X (n x n) of `{x : x'Xx <= 1}`: from every state in it, under every "
        "allowed pattern, every applied input meets the limits (re-checked). On a `network`: one X per node matrix "
        "(V x k x k, docs/design.md §11.3).")
    channel: "ChannelAnalysis | None" = Field(
        None, description="With a `channel` in the request and a stabilized design: the designed gains on that "
        "channel (as `POST /v1/channels` answers).")
    feedback: str | None = Field(None, description="`output` for output feedback (absent for state feedback).")
    observer_gains: list[Matrix] | None = Field(
        None, description="`feedback: output`: the observer gains L, r x n x p (`observer_gains[l]` for plant mode l).")
    observer: "ObserverDesign | None" = Field(
        None, description="`feedback: output`: the observer design and its proof.")
    joint_certificate: "JointCertificate | None" = Field(
        None, description="`feedback: output`, stabilized: `V = x'Px + e'Q_sigma e` for the whole loop.")


# -- margins -------------------------------------------------------------------------------------
class CurvePoint(_Open):
    n_drop: int | None = Field(None, description="The drop bound N of this design.")
    sampling_period: float | None = Field(None, description="h of this design (s).")
    outcome: str | None = Field(None, description="The design's outcome at this point.")
    max_spectral_radius: float | None = Field(None, description="Largest interval closed-loop spectral radius "
                                                                "(dimensionless; null without gains).")
    certificate_margin: float | None = Field(None, description="Relative margin of its certificate "
                                                               "(`Certificate.margin`).")
    decay_rate: float | None = Field(None, description="Per-sample decay rate proven, if asked for.")
    gains: list[Matrix] | None = Field(None, description="n_drop x m x n gains at this point (null if none).")


class MarginResult(_Open):
    """The result of a margin job."""

    kind: str = Field(description="The search: `n_drop`, `sampling_period` or `grid`.")
    margin: float | int | None = Field(
        None, description="`n_drop` search: the largest N (losses in a row + 1, a count) with a stabilizing "
        "design; `sampling_period`: the largest h in seconds; null when even the smallest fails, and for grids.")
    design: DesignResult | None = Field(None, description="The design at the margin (certificate matrices "
                                                          "omitted).")
    curve: list[CurvePoint] | None = Field(None, description="Every point tried, in order.")
    method: str | None = Field(None, description="Design method used at every point.")
    stopped: bool | None = Field(None, description="True when the search was cancelled early.")
    message: str | None = Field(None, description="The margin in words, with its unit.")
    timings: Timings | None = Field(None, description="Where the time went (s).")


# -- analyses, simulations, traces ---------------------------------------------------------------
class AnalysisReport(_Open):
    """Stability analysis of given gains (`POST /v1/analyses`)."""

    cost: Performance | None = Field(None, description="With `weights` or `x0`: the certified cost bracket.")
    hinf: Performance | None = Field(None, description="With `disturbance`: the certified l2-gain bracket.")
    output: "OutputAnalysis | None" = Field(None, description="With `observer_gains`: the whole output-feedback "
                                            "loop's verdict.")

    stable: bool | None = Field(description="True: certified (re-checked certificate); false: a mode product "
                                            "is proven unstable (`worst_sequence`); null: unknown.")
    reason: str | None = Field(None, description="The verdict in words.")
    spectral_radii: Matrix | list[Num] | None = Field(
        None, description="Spectral radius of every interval closed loop (dimensionless, per interval): r x "
        "n_drop (`[l][eta-1]`) per interval, flat S per sample (order of `modes`).")
    max_spectral_radius: float | None = Field(None, description="Largest of `spectral_radii`.")
    margin: float | None = Field(None, description="The certificate's relative margin (`Certificate.margin`).")
    certificate: Certificate | None = Field(None, description="The certificate when `stable` is true.")
    jsr_lower_bound: float | None = Field(
        None, description="Proven lower bound of the joint spectral radius of the interval maps, "
        "`rho(product)^(1/length)` (per interval, dimensionless): >= 1 means unstable.")
    jsr_lower_estimate: float | None = Field(None, description="Its float64 estimate (not a proof).")
    jsr_upper_bound: float | None = Field(None, description="Smallest certified upper bound of that JSR "
                                                            "(per interval).")
    jsr_upper_bound_quadratic: float | None = Field(None, description="From common quadratic certificates.")
    jsr_upper_bound_switched: float | None = Field(None, description="From switched certificates "
                                                                     "(`bounds: all`).")
    decay_rate: float | None = Field(None, description="Best certified per-sample decay rate lambda.")
    decay_factor_per_second: float | None = Field(
        None, description="The factor the state's norm shrinks by over one second, `decay_rate^(1/h)` (dimensionless, "
        "in (0, 1]); null without a sampling period.")
    exponential_rate: float | None = Field(
        None, description="The same rate in 1/s, `-ln(decay_rate)/h`: the norm is below `c exp(-rate t)`.")
    time_constant: float | None = Field(None, description="`1 / exponential_rate` in seconds.")
    decay_rate_per_second: float | None = Field(
        None, description="Deprecated name of `decay_factor_per_second` (a factor per second, not a rate in 1/s).")
    worst_sequence: list[ModeLabel] | None = Field(None, description="The product attaining `jsr_lower_bound`, "
                                                                     "in the order applied.")
    product_length_checked: int | None = Field(None, description="Longest product examined.")
    scaling: list[Num] | None = Field(None, description="State scaling (length n) of a certificate found for "
                                                          "the balanced loops; null: none.")
    modes: list[ModeLabel] | None = Field(None, description="The S closed-loop modes in order.")
    timings: dict[str, float | int | bool | None] | None = Field(None, description="Where the time went (s).")
    network: NetworkEcho | None = Field(None, description="The network the verdict is for (as in the request); "
                                                             "null: the paper's.")
    unstable_cycle: UnstableCycle | None = Field(
        None, description="When `stable` is false: the destabilizing pattern, one entry per sample, repeated "
        "forever: `ages` (buffer ages), `modes` (plant modes, 0-based) and on a network `nodes`.")


class Simulation(_Open):
    """A seeded run; arrays are indexed by sample k = 0 .. steps."""

    t: list[Num] = Field(description="Time of each sample, steps + 1 values: `k h` in seconds (k when the plant "
                                       "has no sampling period).")
    x: Matrix = Field(description="State, (steps + 1) x n, in the plant's state units.")
    estimate: Matrix | None = Field(None, description="With `observer_gains`: the controller's estimate xh(k|k), "
                                    "(steps + 1) x n.")
    u: Matrix = Field(description="Input applied over [k, k+1), steps x m.")
    mode: list[int] = Field(description="Plant mode (0-based) over [k, k+1), steps values.")
    sensor_arrived: list[bool] = Field(description="Sensor packet arrived at k (switch S1), steps values.")
    control_arrived: list[bool] = Field(description="Control packet arrived at k (switch S2), steps values.")
    effective: list[bool] = Field(description="Both arrived: a new packet reached the buffer at k.")
    buffer_index: list[int] = Field(description="q of the prediction `K_q x(i_m)` applied at k (1 = fresh).")
    ages: list[int] | None = Field(None, description="Age of the buffer's packet at each sample, `k - stamp` "
                                                     "(-1 before the first packet).")
    interval_start: list[int] = Field(description="The effective samples i_m.")
    eta: list[int] = Field(description="`i_{m+1} - i_m` of every completed interval (samples).")
    seed: int | None = Field(None, description="Seed of the packet losses and plant jumps.")
    loss_model: str | None = Field(None, description="`paper`, `bernoulli` or `channel`.")
    plant_switching: str | None = Field(None, description="`per_interval`, `per_sample` or `none` (on a "
                                                         "channel: `stay` or `markov`).")
    n_drop: int | None = Field(None, description="N: at most N - 1 consecutive non-effective samples.")
    channel_state: list[int] | None = Field(None, description="Channel state (0-based) at each sample, steps "
                                                              "values (runs on a channel only).")
    network: NetworkEcho | None = Field(None, description="The network the run's ages were drawn from.")


class ModeRun(Simulation):
    plant_mode: int = Field(description="The fixed plant mode (0-based) of this run.")


class TraceQueryEcho(_Open):
    seed: int | None = Field(None, description="Seed used.")
    steps: int | None = Field(None, description="Samples simulated.")
    x0: list[Num] | None = Field(None, description="Initial state (length n).")
    loss_model: str | None = Field(None, description="`paper` or `bernoulli`.")
    sensor_loss: float | None = Field(None, description="Sensor packet loss probability per sample.")
    control_loss: float | None = Field(None, description="Control packet loss probability per sample.")
    plant_switching: str | None = Field(None, description="Plant switching of the top-level run.")
    mode: int | None = Field(None, description="Fixed plant mode of the top-level run, if any.")


class Trace(Simulation):
    """The designed loop's seeded run with the requested switching, and one run per fixed plant mode."""

    per_mode: list[ModeRun] = Field(description="One run per plant mode (r runs), same losses, no jumps.")
    query: TraceQueryEcho = Field(description="The simulation parameters used (defaults filled in).")


# -- jobs ------------------------------------------------------------------------------------------
class MarginPoint(_Open):
    n_drop: int | None = Field(None, description="N of the last point tried.")
    sampling_period: float | None = Field(None, description="h of the last point tried (s).")
    outcome: str | None = Field(None, description="Its design's outcome.")


class Progress(_Open):
    iteration: int | None = Field(None, description="Design jobs: the solver iteration (CCL Step 2 count).")
    objective: float | None = Field(None, description="Design jobs: objective of the last SDP.")
    trace_gap: float | None = Field(None, description="CCL: `trace(P Q)/(n N) - 1` of the last iterate.")
    theorem1: bool | None = Field(None, description="Design jobs: the last iterate satisfies Theorem 1.")
    elapsed: float | None = Field(None, description="Wall time since the design started (s).")
    step: int | None = Field(None, description="Margin jobs: designs done so far.")
    total: int | None = Field(None, description="Margin jobs: designs planned (an upper bound).")
    point: MarginPoint | None = Field(None, description="Margin jobs: the last point tried and its outcome.")


class Links(BaseModel):
    self: str = Field(description="This job.")
    events: str = Field(description="Server-Sent Events of this job.")
    cancel: str = Field(description="POST here to cancel.")
    trace: str | None = Field(None, description="Design jobs: the seeded simulation (also .svg, .png).")
    gains_mat: str | None = Field(None, description="Design jobs: gains and certificate as a MATLAB .mat file.")
    gains_m: str | None = Field(None, description="Design jobs: the same as an Octave/MATLAB script.")
    curve: str | None = Field(None, description="Margin jobs: the plot of every point tried (.svg or .png).")


class PlantSummary(BaseModel):
    kind: str = Field(description="`continuous`, `discrete` or `dc_motor`.")
    n: int = Field(description="Number of states.")
    m: int = Field(description="Number of inputs.")
    r: int = Field(description="Number of plant modes.")
    sampling_period: float | None = Field(None, description="h in seconds (null for a discrete plant without one).")


def _utc(dt: datetime | None) -> datetime | None:
    if dt is None:
        return None
    if dt.tzinfo is None:
        return dt.replace(tzinfo=timezone.utc)
    return dt.astimezone(timezone.utc)


class JobSummary(BaseModel):
    id: str = Field(description="Job id (a UUID).")
    status: Literal["queued", "running", "succeeded", "failed", "cancelled"] = Field(
        description="queued -> running -> succeeded | failed | cancelled.")
    method: str = Field(description="Design method (`lmi`, `ccl`, `switched`).")
    n_drop: int = Field(description="N of a design; the largest N a margin job designs for.")
    label: str | None = Field(None, description="The label given at submission, if any.")
    plant: PlantSummary | None = Field(None, description="What was designed for: kind and sizes.")
    created_at: datetime = Field(description="Submission time (UTC).")
    started_at: datetime | None = Field(None, description="Start of the last attempt (UTC).")
    finished_at: datetime | None = Field(None, description="End time (UTC).")
    updated_at: datetime = Field(description="Last change (UTC).")
    attempts: int = Field(description="Attempts started (a worker that died causes a retry).")
    cancel_requested: bool = Field(description="A cancel was asked for.")
    progress: Progress | None = Field(None, description="The latest progress record.")
    outcome: str | None = Field(None, description="Design jobs, once succeeded: the outcome (`stabilized`, "
                                                  "`infeasible`, `marginal`, `not_certified` on a network, "
                                                  "`not_converged`).")
    margin: float | int | None = Field(None, description="Margin jobs, once succeeded: the margin (largest N, a "
                                                          "count, or largest h in seconds; see `margin_kind`).")
    margin_kind: str | None = Field(None, description="Margin jobs: the search (`n_drop`, `sampling_period`, "
                                                      "`grid`).")
    error: str | None = Field(None, description="Why the job failed (or the last retry reason).")
    links: Links = Field(description="Related URLs.")

    @field_serializer("created_at", "started_at", "finished_at", "updated_at")
    def _ser_dt(self, dt: datetime | None):
        dt = _utc(dt)
        return None if dt is None else dt.isoformat().replace("+00:00", "Z")


_JOB_EXAMPLE = {
    "id": "3f0c8a52-8d55-4a4e-9b0e-6d1f0f5a2c11", "status": "succeeded", "method": "lmi", "n_drop": 3,
    "created_at": "2026-11-21T05:44:42.428524Z", "started_at": "2026-11-21T05:44:42.448170Z",
    "finished_at": "2026-11-21T05:44:42.555394Z", "updated_at": "2026-11-21T05:44:42.555394Z",
    "label": "motor rig A", "plant": {"kind": "continuous", "n": 2, "m": 1, "r": 3, "sampling_period": 0.1},
    "attempts": 1, "margin": None, "margin_kind": None, "cancel_requested": False, "outcome": "stabilized", "error": None,
    "progress": {"iteration": 0, "objective": 0.6538, "trace_gap": None, "theorem1": True, "elapsed": 0.0962},
    "links": {"self": "/v1/designs/3f0c8a52-8d55-4a4e-9b0e-6d1f0f5a2c11",
              "events": "/v1/designs/3f0c8a52-8d55-4a4e-9b0e-6d1f0f5a2c11/events",
              "cancel": "/v1/designs/3f0c8a52-8d55-4a4e-9b0e-6d1f0f5a2c11/cancel",
              "trace": "/v1/designs/3f0c8a52-8d55-4a4e-9b0e-6d1f0f5a2c11/trace"},
    "request": {"plant": {"kind": "continuous", "sampling_period": 0.1,
                          "A": [[[-4.0, -0.03], [0.5, -6.667]], [[-4.0, -0.03], [0.75, -10.0]],
                                [[-4.0, -0.03], [1.5, -20.0]]],
                          "B": [[[2.0], [0.0]], [[2.0], [0.0]], [[2.0], [0.0]]]},
                "n_drop": 3, "method": "lmi",
                "options": {"solver": "AUTO", "margin": 1e-06, "max_iter": 50, "decay_rate": "auto",
                            "plant_switching": "per_interval", "scheme": "predictive"}},
    "result": {
        "outcome": "stabilized", "method": "lmi", "n_drop": 3,
        "gains": [[[-4.0611, 0.1010]], [[-0.0021, -0.0305]], [[-0.0003, -0.0056]]],
        "certificate": {"kind": "common_quadratic", "verified": True, "margin": 0.1192,
                        "X": [[1.5279, -0.0228], [-0.0228, 0.7437]], "P": [[1.5279, -0.0228, 0.0, 0.0, 0.0, 0.0], "... (n n_drop x n n_drop)"]},
        "spectral_radii": [[0.514, 0.264, 0.136], [0.369, 0.136, 0.050], [0.138, 0.020, 0.003]],
        "max_spectral_radius": 0.514,
        "F": [[[0.6703, -0.0018], [0.0294, 0.5134]], "..."], "G": [[[0.1648], [0.0035]], "..."],
        "sampling_period": 0.1, "history": [{"iteration": 0, "objective": 0.6538, "theorem1": True}],
        "iterations": 0, "solver": "IPM", "solver_status": "optimal",
        "timings": {"total": 0.0966, "solver": 0.0014}, "message": "stabilized; certificate re-checked",
    },
}


class DesignJob(JobSummary):
    """A design job: its accepted request and, once succeeded, its result."""

    model_config = ConfigDict(json_schema_extra={"examples": [_JOB_EXAMPLE]})

    request: DesignRequest = Field(description="The design request as accepted (defaults filled in).")
    result: DesignResult | None = Field(None, description="When succeeded: the design (outcome, gains, "
                                                          "certificate, ...). Null before.")


class MarginJob(JobSummary):
    """A margin job: its accepted request and, once succeeded, its result."""

    request: MarginRequest = Field(description="The margin request as accepted (defaults filled in).")
    result: MarginResult | None = Field(None, description="When succeeded: margin, design at the margin, curve.")


#: Kept for callers of the first layout: a design job.
Job = DesignJob

JOB_MODELS: dict[str, type[JobSummary]] = {"design": DesignJob, "margin": MarginJob}


class JobList(BaseModel):
    items: list[JobSummary] = Field(description="One page of jobs, newest first (no request or result).")
    total: int = Field(description="Jobs matching the filter in all.")
    limit: int = Field(description="Page size asked for.")
    offset: int = Field(description="Jobs skipped.")
    next: str | None = Field(None, description="URL of the next page, if any.")


class ProblemError(BaseModel):
    loc: list[str | int] = Field(description="pydantic location: `body`/`query`/`header`, then the path.")
    pointer: str = Field(description="JSON pointer (RFC 6901) into the request body, e.g. `/plant/A/1/0/2`.")
    msg: str = Field(description="What is wrong and how to fix it.")
    type: str = Field(description="Machine-readable error kind (e.g. `single_matrix`, `matrix_not_square`).")


class Problem(BaseModel):
    type: str = Field("about:blank", description="URL of a page of this service (`/problems/{slug}`) that "
                                                 "explains the problem and how to fix it.")
    title: str = Field(description="Short summary of the problem type.")
    status: int = Field(description="HTTP status code.")
    detail: str | None = Field(None, description="This occurrence in words.")
    instance: str | None = Field(None, description="The request path.")
    errors: list[ProblemError] | None = Field(None, description="Invalid input: one entry per bad field.")


class Health(BaseModel):
    status: Literal["ok"] = Field(description="Always `ok`: the process answers.")


class WorkersStatus(_Open):
    configured: int | None = Field(None, description="Worker processes (or Dask slots) configured.")
    alive: int | None = Field(None, description="Of those, alive.")
    ready: int | None = Field(None, description="Of those, ready for a job.")
    dispatcher: str | None = Field(None, description="`running`, `stopped` or `disabled`.")
    last_error: str | None = Field(None, description="The dispatcher's last error, if any.")


class Readiness(_Open):
    status: Literal["ready"] = Field(description="`ready` (else the answer is a 503 problem).")
    database: str = Field(description="`ok` when reachable.")
    workers: WorkersStatus = Field(description="Worker pool state.")



# -- stochastic channels (POST /v1/channels) ---------------------------------------------------------------
class BurstStatistics(_Open):
    """How often the channel breaks the drop bound (exact, from the chain)."""

    n_drop: int = Field(description="Drop bound N: a burst is a run of >= N lost samples.")
    rate: float = Field(description="Probability per sample that a burst starts (1/sample).")
    rate_per_second: float | None = Field(None, description="The same per second (1/s); null without h.")
    mean_time_between: float | None = Field(None, description="Mean time between bursts (samples); null: never.")
    mean_time_between_seconds: float | None = Field(None, description="The same in seconds.")
    loss_fraction: float = Field(description="Stationary fraction of samples without an effective packet.")
    mean_run_length: float | None = Field(None, description="Mean length of a run of lost samples (samples).")
    run_length_pmf: list[float] = Field(description="P(run length = l) for l = 1, 2, ... (entry l - 1).")
    run_length_tail: float = Field(description="P(run length > len(run_length_pmf)).")
    sampling_period: float | None = Field(None, description="h (s).")
    never_delivers: bool = Field(False, description="The link delivers a sample with probability below 1e-9 (loss "
                                                    "fraction 1): one endless run of losses, so `rate` is 1 and "
                                                    "no drop bound holds.")


class ChannelCertificate(_Open):
    """Summary of a re-checked certificate on the second-moment operator's spectral radius."""

    kind: str = Field(description="`coupled_lyapunov` (radius <= beta), `first_return_growth` (radius >= mu).")
    verified: bool = Field(description="The float64 re-check with rounding bounds passed.")
    beta: float | None = Field(None, description="Proven upper bound of the radius (per sample).")
    mu: float | None = Field(None, description="Proven lower bound of the radius (per sample).")
    steps: int | None = Field(None, description="Steps of the growth certificate.")


class NetworkViolations(_Open):
    """How often a channel breaks a network's constraint (exact, from its Markov chain)."""

    network: NetworkEcho = Field(description="The network (as in the request).")
    rate: float = Field(description="Stationary probability per sample that the sample breaks it.")
    rate_per_second: float | None = Field(None, description="`rate / h` (1/s); null without a sampling period.")
    mean_time_between: float | None = Field(None, description="`1 / rate` samples; null when it never breaks.")
    what: str = Field(description="What counts as a violation.")
    miss_fraction: float | None = Field(None, description="`weakly_hard`: stationary probability that a sample has "
                                                          "no fresh packet (lost or late).")
    states: int | None = Field(None, description="`weakly_hard`: size of the chain solved (age process times the "
                                                 "window's miss flags).")


class ChannelAnalysis(_Open):
    """Given gains on a stochastic channel (`POST /v1/channels`)."""

    n_drop: int = Field(description="Buffer length N.")
    burst_rate: float = Field(description="Probability per sample that a run of >= n_drop lost samples starts.")
    mean_time_between_bursts: float | None = Field(None, description="Samples between bursts (mean); null: never.")
    mean_time_between_bursts_seconds: float | None = Field(None, description="The same in seconds.")
    bursts: BurstStatistics = Field(description="Burst statistics.")
    ms_stable: bool | None = Field(description="True/false: mean-square stability proven/refuted by a "
                                               "re-checked certificate; null: unknown (`reason`).")
    ms_radius: float | None = Field(None, description="Spectral radius of the second-moment operator (float64 "
                                                      "estimate, per sample); null for arbitrary switching.")
    ms_radius_upper: float | None = Field(None, description="Proven upper bound of that radius.")
    ms_radius_lower: float | None = Field(None, description="Proven lower bound of that radius.")
    expected_cost: float | None = Field(None, description="E sum x'Qx + u'Ru (exact linear equations).")
    expected_cost_upper: float | None = Field(None, description="Certified upper bound of the expected cost.")
    expected_cost_lower: float | None = Field(None, description="Lower bound (rigorous partial sums).")
    stationary_cost: float | None = Field(None, description="Long-run cost per sample with process noise.")
    upper_certificate: ChannelCertificate | None = Field(None, description="The certificate of "
                                                                           "`ms_radius_upper`.")
    lower_certificate: ChannelCertificate | None = Field(None, description="The certificate of "
                                                                           "`ms_radius_lower`.")
    exhausted: str = Field(description="`hold` or `zero`.")
    plant_transitions: str = Field(description="`stay`, `markov` or `arbitrary`.")
    n_modes: int = Field(description="Modes of the jump system (channel state, plant mode, buffer age).")
    reason: str = Field(description="The verdict in words.")
    delays: list[float] | None = Field(None, description="The channel's delay distribution, when it has one "
                                                         "(`burst_rate` is then the rate the buffer's age reaches "
                                                         "n_drop, late packets included).")
    network_violations: NetworkViolations | None = Field(None, description="With a request `network`: how often "
                                                                           "the channel breaks it.")


DesignResult.model_rebuild()  # its `channel` field names ChannelAnalysis, defined below it
