"""The requests the service accepts, as pydantic models: the HTTP contract's bodies, and what a worker
re-validates a stored request into, so every default (``n_drop``, ``method``, the design options...) is
written once, here.

Matrices are JSON lists of rows; a plant family is a list of matrices, one
per mode. Numbers must be finite JSON numbers: strings, booleans, NaN and
Infinity are rejected with the offending element's location.
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import AllowInfNan, BaseModel, ConfigDict, Field, Strict

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


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ContinuousPlant(_Strict):
    """Continuous-time family `dx/dt = A_l x + B_l u`, discretized by zero-order hold."""

    kind: Literal["continuous"]
    A: list[Matrix] = Field(description="One n x n matrix per plant mode.")
    B: list[Matrix] = Field(description="One n x m matrix per plant mode.")
    sampling_period: Number = Field(gt=0, description="Sampling period h in seconds (> 0).")


class DiscretePlant(_Strict):
    """Discrete-time family `x(k+1) = F_l x(k) + G_l u(k)`."""

    kind: Literal["discrete"]
    F: list[Matrix] = Field(description="One n x n matrix per plant mode.")
    G: list[Matrix] = Field(description="One n x m matrix per plant mode.")
    sampling_period: Number | None = Field(
        None, gt=0, description="Optional sampling period (s), only used to label time axes."
    )


class DcMotorPlant(_Strict):
    """The paper's DC motor (eq. 16/18) with switching inertia, built from physical parameters.

    Note: this uses eq. 18 with the given parameters. The paper's printed eq. 19 matrices
    differ from Table I; to reproduce the paper exactly, send eq. 19 as a `continuous` plant.
    """

    kind: Literal["dc_motor"]
    inertias: list[Annotated[Number, Field(gt=0)]] = Field(
        description="Moment of inertia J per plant mode (kg m^2).", min_length=1
    )
    sampling_period: Number = Field(gt=0, description="Sampling period h in seconds.")
    resistance: Number = Field(2.0, gt=0, description="Armature resistance R (ohm).")
    inductance: Number = Field(0.5, gt=0, description="Armature inductance L (H).")
    torque_constant: Number = Field(0.15, description="Torque constant K_m.")
    back_emf_constant: Number = Field(0.15, description="Back-EMF constant K_b.")
    damping: Number = Field(0.2, ge=0, description="Viscous damping B.")


Plant = Annotated[Union[ContinuousPlant, DiscretePlant, DcMotorPlant], Field(discriminator="kind")]


class DesignOptions(_Strict):
    solver: Literal["CLARABEL", "SCS"] = Field("CLARABEL", description="SDP solver used by cvxpy.")
    margin: Number = Field(1e-6, gt=0, le=1, description="Strictness margin of the LMIs.")
    max_iter: Int = Field(50, ge=1, le=1000, description="Iteration cap of iterative methods (ccl).")
    decay_rate: Annotated[Number, Field(gt=0, le=1)] | Literal["max"] | None = Field(
        None, description="Demand a per-sample decay rate lambda in (0, 1] (|x(i_{m+1})| <= lambda^eta |x(i_m)| in "
        "the certificate's norm), or `\"max\"` to find the smallest by bisection. `lmi` and `switched` only."
    )
    plant_switching: Literal["per_interval", "per_sample"] = Field(
        "per_interval", description="Plant mode constant over an interval between effective packets (the paper), "
        "or free to jump at every sample (r + r^2 + ... + r^n_drop modes)."
    )
    scheme: Literal["predictive", "hold", "zero"] = Field(
        "predictive", description="The paper's predictive buffer, or a baseline: hold the last input (all K_q "
        "equal) or zero input on loss (K_q = 0 for q > 1)."
    )


class DesignRequest(_Strict):
    plant: Plant
    n_drop: Int = Field(3, ge=1, description="N_drop: at most n_drop - 1 consecutive losses.")
    method: MethodName = Field(
        "lmi", description="`lmi`: exact convex design (one SDP); `ccl`: the paper's cone "
        "complementarity linearization (iterative, reports progress)."
    )
    options: DesignOptions = Field(default_factory=DesignOptions)


class SimulationRequest(_Strict):
    plant: Plant
    gains: list[Matrix] = Field(description="n_drop gain matrices K_1..K_N, each m x n.")
    n_drop: Int | None = Field(None, ge=1, description="Defaults to the number of gain matrices.")
    x0: Vector = Field(description="Initial state (length n).")
    steps: Int = Field(100, ge=1)
    seed: Int = Field(42, ge=0)
    loss_model: Literal["paper", "bernoulli"] = "paper"
    sensor_loss: Number = Field(0.2, ge=0, lt=1)
    control_loss: Number = Field(0.2, ge=0, lt=1)
    plant_switching: Literal["per_interval", "per_sample", "none"] = "per_interval"
    mode: Int | None = Field(None, ge=0, description="Fixed plant mode (0-based) when plant_switching is none.")


class AnalysisRequest(_Strict):
    plant: Plant
    gains: list[Matrix] = Field(description="n_drop gain matrices K_1..K_N, each m x n.")
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


class GridPoint(_Strict):
    sampling_period: Number = Field(gt=0, description="h in seconds.")
    n_drop: Int = Field(ge=1)


class MarginRequest(_Strict):
    """A stability-margin job: many designs in the worker pool, with progress and cancel."""

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
    options: DesignOptions = Field(default_factory=DesignOptions)
