"""Result objects of :func:`solver.design` (named fields, like scipy's ``OptimizeResult``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .lyapunov import Certificate

OUTCOMES = ("stabilized", "infeasible", "marginal", "not_certified", "not_converged")


def _num(x):
    """JSON-safe float (NaN/inf become None)."""
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


@dataclass
class IterationRecord:
    """One iteration of an iterative method (one record for one-shot methods).

    Attributes
    ----------
    iteration : int
        0 is the feasible start (CCL Step 1), then 1, 2, ...
    objective : float
        Objective value of the solved SDP.
    trace_gap : float or None
        ``trace(P Q) / (n n_drop) - 1`` (CCL only): 0 when PQ = I.
    theorem1 : bool
        Whether the iterate's gains satisfy Theorem 1 (a certificate re-checked in float64).
    certificate_margin : float or None
        Relative margin of that certificate.
    solve_time : float
        The solver's own time for this iteration (s).
    elapsed : float
        Wall time since the design started (s).
    """

    iteration: int
    objective: float
    trace_gap: float | None
    theorem1: bool
    certificate_margin: float | None
    solve_time: float
    elapsed: float

    def to_dict(self) -> dict:
        return {
            "iteration": self.iteration,
            "objective": _num(self.objective),
            "trace_gap": _num(self.trace_gap),
            "theorem1": self.theorem1,
            "certificate_margin": _num(self.certificate_margin),
            "solve_time": _num(self.solve_time),
            "elapsed": _num(self.elapsed),
        }


#: Settling means reaching this fraction of the initial state's norm (2 %).
SETTLING_FRACTION = 0.02


def rate_in_time(decay_rate: float | None, sampling_period: float | None) -> dict:
    """A per-sample contraction factor lambda in the units engineers read, with their names.

    Returns ``decay_rate`` (lambda, a factor per sample), ``decay_factor_per_second`` (``lambda^(1/h)``,
    the factor over one second), ``exponential_rate`` (``-ln(lambda)/h`` in 1/s: ``|x| <= c e^(-rate t)``)
    and ``time_constant`` (``h / -ln(lambda)`` in s); the last three are None without h (or for lambda = 1).
    """
    out = {"decay_rate": decay_rate, "decay_factor_per_second": None, "exponential_rate": None,
           "time_constant": None}
    if decay_rate is None or not sampling_period or not 0 < decay_rate <= 1:
        return out
    h = float(sampling_period)
    out["decay_factor_per_second"] = float(decay_rate) ** (1.0 / h)
    rate = -math.log(decay_rate) / h
    out["exponential_rate"] = rate
    out["time_constant"] = 1.0 / rate if rate > 0 else None
    return out


def certified_settling(decay_rate: float | None, metric_condition: float, sampling_period: float | None,
                       fraction: float = SETTLING_FRACTION) -> dict | None:
    """The settling time a certified rate guarantees, worst case over every allowed loss and switching sequence.

    In the certificate's norm ``|x(i_m)|_P <= lambda^(i_m) |x(0)|_P`` at every sample ``i_m`` where a packet
    takes effect, so in the Euclidean norm ``|x(i_m)| <= sqrt(kappa) lambda^(i_m) |x(0)|`` with ``kappa`` the
    condition number of the certificate's metric: below ``fraction`` of the initial norm from
    ``k = ceil(ln(fraction / sqrt(kappa)) / ln(lambda))`` samples on (between packets the state may still move
    for up to n_drop - 1 samples).
    """
    if decay_rate is None or not 0 < decay_rate < 1 or not np.isfinite(metric_condition):
        return None
    samples = int(math.ceil(math.log(fraction / math.sqrt(metric_condition)) / math.log(decay_rate)))
    return {"fraction": fraction, "samples": max(samples, 0),
            "seconds": None if not sampling_period else max(samples, 0) * float(sampling_period),
            "metric_condition": float(metric_condition), **rate_in_time(decay_rate, sampling_period)}


def metric_condition(certificate, scaling: dict | None = None) -> float:
    """Condition number of the norm a certificate's rate is stated in (its reduced X, or all switched P_s)."""
    if certificate is None or getattr(certificate, "P", None) is None:
        return float("inf")
    mats = certificate.X if getattr(certificate, "X", None) is not None else certificate.P
    mats = np.asarray(mats)
    eig = np.linalg.eigvalsh(mats if mats.ndim == 3 else mats[None])
    lo, hi = float(eig.min()), float(eig.max())
    kappa = hi / lo if lo > 0 else float("inf")
    if scaling and scaling.get("certificate") == "scaled":  # stated in balanced coordinates: back to the user's
        state = np.asarray(scaling["state"], dtype=float)
        kappa *= float(state.max() / state.min()) ** 2
    return kappa


@dataclass
class DesignResult:
    """Outcome of a controller design.

    Attributes
    ----------
    outcome : {"stabilized", "infeasible", "marginal", "not_certified", "not_converged"}
        ``stabilized`` only with a certificate that passed the float64 re-check; ``infeasible``
        only with a proof that no design of any margin exists (up to the Farkas certificate's
        ``gain_bound_any_margin``); ``marginal`` when the Farkas certificate excludes only designs
        whose relative margin reaches ``certificate.margin`` (designs with a smaller margin may exist);
        ``not_certified`` (designs on a network): the convex sufficient condition is proven infeasible
        (its Farkas certificate in ``certificate``, re-checked in float64), which does not prove that no
        gains exist.
    gains : ndarray, shape (n_drop, m, n), or None
        ``gains[q-1] = K_q``; the last iterate's gains when not stabilized (may be None).
    certificate : Certificate or None
    method : str
    n_drop : int
    history : list of IterationRecord
    solver : str
    solver_status : str
        Status of the last conic solve.
    timings : dict
        ``total`` wall time, ``setup`` (problem build, 0 when cached),
        ``solver`` (sum of the solver's own times), ``overhead`` (the rest), in s;
        ``cached`` whether the compiled problem was reused; ``solves`` count.
    message : str
    spectral_radii : ndarray or None
        Spectral radius of every interval closed loop for ``gains``: shape
        (r, n_drop) for per-interval plant switching, (S,) per sample (see ``mode_labels``).
    scheme : {"predictive", "hold", "zero"}
    plant_switching : {"per_interval", "per_sample"}
    decay_rate : float or None
        Per-sample decay rate lambda the certificate proves, when one was asked for.
    mode_labels : list of dict
        The closed-loop modes in the order of the flat arrays.
    rate_search : list of dict
        For ``decay_rate="max"``: every rate tried, its outcome and the kind of proof.
    rate_bracket : dict or None
        For ``decay_rate="max"``: ``lower`` and ``upper`` ends of the bisection (``upper`` is the
        returned certified rate), ``lower_proven`` (every design of the method at rate ``lower`` is
        excluded by a Farkas/uncontrollable certificate), ``loop_spectral_rate`` (the returned
        loop's ``max_s rho(A_s)^(1/eta_s)``, below which no certificate for these gains can go).
    scaling : dict or None
        The diagonal state/input scaling the design was made in (None when none was needed)
        and in which coordinates ``certificate`` is expressed.
    objective : {"stability", "cost", "hinf"}
        What the design optimized (see :func:`solver.design`).
    performance : Performance or None
        For ``objective="cost"``/``"hinf"``: the certified bracket (:class:`solver.brackets.Performance`).
    invariant_set : ndarray, shape (n, n), or None
        With ``u_max``: X of the ellipsoid ``{x : x' X x <= 1}`` from which, under every allowed pattern,
        every applied input meets the limits (re-checked in float64).
    settling : dict or None
        What the certified ``decay_rate`` guarantees (:func:`certified_settling`): ``samples`` and
        ``seconds`` to 2 % of the initial state's norm, worst case over every allowed sequence;
        the rate as ``decay_rate`` (per sample), ``decay_factor_per_second``, ``exponential_rate``
        (1/s) and ``time_constant`` (s); ``metric_condition``.  None without a certified rate.
    network : dict or None
        The network the design is made for (``Network.to_dict()``); None for the paper's bounded drops.
    """

    outcome: str
    gains: np.ndarray | None
    certificate: Certificate | None
    method: str
    n_drop: int
    history: list[IterationRecord] = field(default_factory=list)
    solver: str = "CLARABEL"
    solver_status: str = ""
    timings: dict = field(default_factory=dict)
    message: str = ""
    spectral_radii: np.ndarray | None = None
    scheme: str = "predictive"
    plant_switching: str = "per_interval"
    decay_rate: float | None = None
    mode_labels: list = field(default_factory=list)
    rate_search: list = field(default_factory=list)
    scaling: dict | None = None
    rate_bracket: dict | None = None
    objective: str = "stability"
    performance: object | None = None
    invariant_set: np.ndarray | None = None
    settling: dict | None = None
    network: dict | None = None

    @property
    def iterations(self) -> int:
        """Number of solved iterations after the start (0 for one-shot methods)."""
        return max((rec.iteration for rec in self.history), default=0)

    @property
    def success(self) -> bool:
        return self.outcome == "stabilized"

    def to_dict(self, include_certificate_matrix: bool = True) -> dict:
        cert = None
        if self.certificate is not None:
            cert = self.certificate.to_dict()
            if not include_certificate_matrix:
                for key in ("P", "X", "multipliers", "limit_multipliers", "left_vector"):
                    cert.pop(key, None)
        return {
            "outcome": self.outcome,
            "method": self.method,
            "n_drop": self.n_drop,
            "gains": None if self.gains is None else self.gains.tolist(),
            "certificate": cert,
            "spectral_radii": None if self.spectral_radii is None else self.spectral_radii.tolist(),
            "max_spectral_radius": None if self.spectral_radii is None else float(np.max(self.spectral_radii)),
            "history": [rec.to_dict() for rec in self.history],
            "iterations": self.iterations,
            "solver": self.solver,
            "solver_status": self.solver_status,
            "timings": {k: (_num(v) if isinstance(v, float) else v) for k, v in self.timings.items()},
            "message": self.message,
            "scheme": self.scheme,
            "plant_switching": self.plant_switching,
            "decay_rate": self.decay_rate,
            "rate_search": self.rate_search,
            "modes": self.mode_labels,
            "scaling": self.scaling,
            "rate_bracket": self.rate_bracket,
            "objective": self.objective,
            "performance": None if self.performance is None else self.performance.to_dict(),
            "invariant_set": None if self.invariant_set is None else self.invariant_set.tolist(),
            "settling": self.settling,
            "network": self.network,
        }


def jsonable(obj):
    """``obj`` as plain JSON values: arrays to lists, numpy scalars to Python ones, non-finite floats to None.

    JSON has no NaN or infinity, so a non-finite number becomes ``null``; fields where infinity means something
    carry a companion flag (e.g. ``gain_bound_unbounded``).  Objects with ``to_dict()`` (results, certificates)
    are converted through it.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if obj is None or isinstance(obj, (str, int)):
        return obj
    if hasattr(obj, "to_dict"):
        return jsonable(obj.to_dict())
    return str(obj)
