"""A synchronous Python client of the ncs-design service (httpx; no FastAPI needed).

    from app.client import Client

    with Client("http://127.0.0.1:8000", api_key="...") as c:
        res = c.design(plant, n_drop=3)          # waits for the job, returns a DesignResult
        res.gains                                # ndarray (n_drop, m, n), gains[q-1] = K_q

``plant`` may be a :class:`solver.PlantFamily`, a list of python-control ``StateSpace`` objects
(one per plant mode; continuous ones need ``sampling_period=``) or the service's plant JSON as a
dict (``{"kind": "continuous", "A": [...], "B": [...], "sampling_period": 0.1}``, ``"discrete"`` with
``F``/``G`` or ``"dc_motor"`` with ``inertias``).  Errors of the service raise :class:`ServiceError`
carrying its ``application/problem+json`` body.

Jobs are submitted with an ``Idempotency-Key`` (so a retried submission never makes a second job)
and ``Prefer: wait=N`` (RFC 7240: a server that supports it answers once the job is done or N
seconds have passed); the client then polls ``GET /v1/designs/{id}`` with backoff until the job ends.
"""

from __future__ import annotations

import time
import uuid
from dataclasses import dataclass, field
from typing import Any

import httpx
import numpy as np

__all__ = ["Client", "ServiceError", "JobFailed", "Job", "DesignResult", "AnalysisResult", "SimulationResult",
           "MarginResult", "plant_json"]

TERMINAL = ("succeeded", "failed", "cancelled")


# ----------------------------------------------------------------------------------------- errors
class ServiceError(Exception):
    """An error answer of the service (RFC 9457 problem details).

    Attributes
    ----------
    status : int
        HTTP status.
    title, detail, type : str or None
    errors : list of dict
        For 422: one entry per bad field, each with ``loc``, ``pointer``, ``msg``, ``type``.
    problem : dict
        The whole problem+json body (or ``{"detail": text}`` when the body was not JSON).
    """

    def __init__(self, status: int, problem: dict):
        self.status = status
        self.problem = problem
        self.title = problem.get("title")
        self.detail = problem.get("detail")
        self.type = problem.get("type")
        self.errors = list(problem.get("errors") or [])
        lines = [f"{status} {self.title or 'error'}" + (f": {self.detail}" if self.detail else "")]
        lines += [f"  {e.get('pointer') or e.get('loc')}: {e.get('msg')}" for e in self.errors]
        super().__init__("\n".join(lines))


class JobFailed(Exception):
    """A job ended ``failed`` or ``cancelled`` (``job.error`` says why)."""

    def __init__(self, job: "Job"):
        self.job = job
        super().__init__(f"job {job.id} {job.status}" + (f": {job.error}" if job.error else ""))


# ------------------------------------------------------------------------------------------ results
def _array(value) -> np.ndarray | None:
    return None if value is None else np.asarray(value, dtype=float)


@dataclass
class Job:
    """A design or margin job as the service reports it.

    Attributes
    ----------
    id : str
    status : {"queued", "running", "succeeded", "failed", "cancelled"}
    method : str
    n_drop : int
    outcome : str or None
        The design's outcome once succeeded.
    error : str or None
    progress : dict or None
        Latest progress (iteration, objective, ... or step/total for margin jobs).
    result : dict or None
        The raw JSON result (see :class:`DesignResult` / :class:`MarginResult` for typed views).
    label : str or None
        The label given at submission.
    plant : dict or None
        Plant summary: ``kind``, ``n`` states, ``m`` inputs, ``r`` plant modes, ``sampling_period`` (s).
    margin : int or float or None
        Margin jobs, once succeeded: the largest n_drop (a count) or sampling period (s), see ``margin_kind``.
    margin_kind : str or None
        Margin jobs: ``n_drop``, ``sampling_period`` or ``grid``.
    links : dict
        Related URLs (``self``, ``events``, ``trace``, ``gains_mat``, ``gains_m``, ``curve``).
    raw : dict
        The whole JSON answer (``DesignJob`` / ``MarginJob`` / ``JobSummary`` in ``/openapi.json``).
    """

    id: str
    status: str
    method: str
    n_drop: int
    outcome: str | None = None
    error: str | None = None
    progress: dict | None = None
    result: dict | None = None
    label: str | None = None
    plant: dict | None = None
    margin: float | None = None
    margin_kind: str | None = None
    links: dict = field(default_factory=dict, repr=False)
    raw: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_json(cls, data: dict) -> "Job":
        return cls(id=data["id"], status=data["status"], method=data.get("method", ""),
                   n_drop=data.get("n_drop", 0), outcome=data.get("outcome"), error=data.get("error"),
                   progress=data.get("progress"), result=data.get("result"), label=data.get("label"),
                   plant=data.get("plant"), margin=data.get("margin"), margin_kind=data.get("margin_kind"),
                   links=data.get("links") or {}, raw=data)

    @property
    def done(self) -> bool:
        return self.status in TERMINAL


def _nested(value):
    """Arrays (or lists of them, one per plant mode) as JSON lists."""
    if isinstance(value, (list, tuple)):
        return [_nested(v) for v in value]
    return np.asarray(value, dtype=float).tolist()


def performance_json(weights=None, x0=None, disturbance=None, output=None, u_max=None) -> dict:
    """The performance fields of a design/analysis request, from :func:`solver.design`'s arguments."""
    body: dict = {}
    if weights is not None:
        body["weights"] = {"Q": _nested(weights[0]), "R": _nested(weights[1])}
    if x0 is not None:
        body["x0"] = _nested(x0)
    if disturbance is not None:
        body["disturbance"] = _nested(disturbance)
    if output is not None:
        body["output"] = {"C": _nested(output[0]), "D": None if output[1] is None else _nested(output[1])}
    if u_max is not None:
        body["u_max"] = _nested(u_max)
    return body


def _performance(data: dict | None):
    if not data:
        return None
    from solver.brackets import Performance

    return Performance.from_dict(data)


@dataclass
class DesignResult:
    """A finished design.

    Attributes
    ----------
    outcome : {"stabilized", "infeasible", "marginal", "not_certified", "not_converged"}
        ``stabilized`` only with a certificate that passed the service's float64 re-check; ``not_certified``
        (on a network): the convex condition is proven infeasible, which does not prove that no gains exist.
    gains : ndarray, shape (n_drop, m, n), or None
        ``gains[q-1] = K_q``: after an effective packet at ``i_m`` the buffer plays
        ``u(i_m + q - 1) = K_q x(i_m)``.
    certificate : dict or None
        ``kind`` (``common_quadratic`` or ``switched``: stability proofs; ``farkas`` or ``uncontrollable``:
        proofs that no design exists), ``verified``, ``margin`` (relative decrease,
        ``decrease / lambda_max(P)``), ``P``, ``X``, ... (``Certificate`` in ``/openapi.json``).
    message : str
    n_drop : int
    method : str
    spectral_radii : ndarray or None
        Spectral radius of each interval closed loop, shape (r, n_drop) per interval switching.
    F, G : ndarray or None
        The discretized plant, shapes (r, n, n) and (r, n, m).
    sampling_period : float or None
        h in seconds.
    decay_rate : float or None
        Per-sample rate lambda the certificate proves, when one was asked for.
    decay_factor_per_second : float or None
        The factor the state's norm shrinks by over one second, ``lambda^(1/h)``.
    exponential_rate, time_constant : float or None
        The same rate in 1/s (``-ln(lambda)/h``) and its time constant in s.
    settling : dict or None
        The certified settling time (``samples``, ``seconds`` to 2 % of the initial state, worst case).
    decay_rate_per_second : float or None
        Old name of ``decay_factor_per_second``.
    state_names, input_names : list of str or None
    units : dict or None
        Names and units of the plant's states and inputs.
    job_id : str or None
        The service job (None for an in-process design).
    objective : str
        ``stability``, ``cost`` or ``hinf``.
    performance : solver.brackets.Performance or None
        ``cost``/``hinf``: the certified bracket, the same type as the library's ``res.performance``
        (``kind``, ``upper``, ``lower``, ``witness``, ``certificate``, ``verified``, ``gap``; ``Performance`` in
        ``/openapi.json``; ``perf["upper"]`` also works).
    invariant_set : ndarray, shape (n, n), or None
        With ``u_max``: X of ``{x : x' X x <= 1}``, from which every applied input meets the limits.
    observer_gains : ndarray, shape (r, n, p), or None
        Output feedback (``feedback="output"``): the observer gains L; ``raw["observer"]`` and
        ``raw["joint_certificate"]`` hold their proof and the whole loop's certificate.
    network : dict or None
        The network the gains are certified for (null: the paper's ``bounded_drops``).
    raw : dict
        The JSON result (``DesignResult`` in ``/openapi.json``).
    """

    outcome: str
    gains: np.ndarray | None
    certificate: dict | None
    message: str
    n_drop: int
    method: str
    spectral_radii: np.ndarray | None = None
    F: np.ndarray | None = None
    G: np.ndarray | None = None
    sampling_period: float | None = None
    decay_rate: float | None = None
    decay_factor_per_second: float | None = None
    exponential_rate: float | None = None
    time_constant: float | None = None
    settling: dict | None = None
    decay_rate_per_second: float | None = None
    state_names: list | None = None
    input_names: list | None = None
    units: dict | None = None
    job_id: str | None = None
    objective: str = "stability"
    performance: Any = None
    invariant_set: np.ndarray | None = None
    observer_gains: np.ndarray | None = None
    network: dict | None = None
    raw: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_json(cls, result: dict, job_id: str | None = None) -> "DesignResult":
        return cls(outcome=result["outcome"], gains=_array(result.get("gains")),
                   certificate=result.get("certificate"), message=result.get("message", ""),
                   n_drop=int(result["n_drop"]), method=result.get("method", ""),
                   spectral_radii=_array(result.get("spectral_radii")), F=_array(result.get("F")),
                   G=_array(result.get("G")), sampling_period=result.get("sampling_period"),
                   decay_rate=result.get("decay_rate"), decay_rate_per_second=result.get("decay_rate_per_second"),
                   decay_factor_per_second=result.get("decay_factor_per_second"),
                   exponential_rate=result.get("exponential_rate"), time_constant=result.get("time_constant"),
                   settling=result.get("settling"), state_names=result.get("state_names"),
                   input_names=result.get("input_names"), units=result.get("units"), job_id=job_id,
                   objective=result.get("objective") or "stability", performance=_performance(result.get("performance")),
                   invariant_set=_array(result.get("invariant_set")),
                   observer_gains=_array(result.get("observer_gains")), network=result.get("network"), raw=result)

    @property
    def success(self) -> bool:
        return self.outcome == "stabilized"

    @property
    def max_spectral_radius(self) -> float | None:
        return None if self.spectral_radii is None else float(np.max(self.spectral_radii))

    def to_json(self) -> dict:
        """The JSON result (what the service returned)."""
        return self.raw

    def plant_family(self):
        """The designed (discretized) plant as a :class:`solver.PlantFamily`, e.g. for
        ``solver.control_interop.closed_loop_systems(res.plant_family(), res.gains)``."""
        from solver.plant import PlantFamily

        labels = {k: self.raw[k] for k in ("state_names", "input_names", "units") if self.raw.get(k) is not None}
        return PlantFamily(F=self.F, G=self.G, sampling_period=self.sampling_period, **labels)


@dataclass
class AnalysisResult:
    """An analysis of given gains.

    Attributes
    ----------
    stable : bool or None
        True: certified by a re-checked Lyapunov certificate; False: a mode product is unstable;
        None: unknown.
    reason : str
    spectral_radii : ndarray
    max_spectral_radius : float
    certificate : dict or None
    decay_rate : float or None
        Best certified per-sample decay rate.
    decay_factor_per_second : float or None
        The factor per second, ``lambda^(1/h)`` (``decay_rate_per_second``: its old name).
    cost, hinf : dict or None
        The certified brackets asked for with ``weights``/``x0`` and ``disturbance`` (``Performance``).
    raw : dict
        The JSON report (``AnalysisReport`` in ``/openapi.json``).
    """

    stable: bool | None
    reason: str
    spectral_radii: np.ndarray
    max_spectral_radius: float
    certificate: dict | None
    decay_rate: float | None
    decay_rate_per_second: float | None = None
    decay_factor_per_second: float | None = None
    cost: dict | None = None
    hinf: dict | None = None
    raw: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_json(cls, data: dict) -> "AnalysisResult":
        return cls(stable=data.get("stable"), reason=data.get("reason", ""),
                   spectral_radii=np.asarray(data.get("spectral_radii"), dtype=float),
                   max_spectral_radius=data.get("max_spectral_radius"), certificate=data.get("certificate"),
                   decay_rate=data.get("decay_rate"), decay_rate_per_second=data.get("decay_rate_per_second"),
                   decay_factor_per_second=data.get("decay_factor_per_second"), cost=data.get("cost"),
                   hinf=data.get("hinf"), raw=data)


def _channel_json(channel) -> dict:
    """A channel as request JSON: a :class:`solver.channel.Channel` becomes its ``markov`` form."""
    if hasattr(channel, "to_dict"):  # the request's markov form has only these fields
        data = channel.to_dict()
        return {k: data[k] for k in ("kind", "transition", "loss", "delays") if k in data}
    return channel


def network_json(network) -> dict | None:
    """A network as request JSON: a :class:`solver.Network` (its ``to_dict``), CLI text (``"delays:2,3"``,
    :meth:`solver.Network.parse`) or the JSON itself."""
    if network is None or isinstance(network, dict):
        return network
    if isinstance(network, str):
        from solver import Network

        network = Network.parse(network)
    return network.to_dict()


@dataclass
class ChannelAnalysisResult:
    """Given gains on a stochastic channel (``ChannelAnalysis`` in ``/openapi.json``).

    Attributes
    ----------
    burst_rate : float
        Probability per sample that a run of >= n_drop lost samples starts.
    mean_time_between_bursts : float or None
        Samples (None: never).
    ms_stable : bool or None
        Proven / refuted mean-square stability; None: unknown.
    ms_radius : float or None
    expected_cost : float or None
    reason : str
    raw : dict
    """

    burst_rate: float
    mean_time_between_bursts: float | None
    ms_stable: bool | None
    ms_radius: float | None
    expected_cost: float | None
    reason: str
    raw: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_json(cls, data: dict) -> "ChannelAnalysisResult":
        return cls(burst_rate=data["burst_rate"], mean_time_between_bursts=data.get("mean_time_between_bursts"),
                   ms_stable=data.get("ms_stable"), ms_radius=data.get("ms_radius"),
                   expected_cost=data.get("expected_cost"), reason=data.get("reason", ""), raw=data)


@dataclass
class SimulationResult:
    """A seeded simulated run; arrays are indexed by sample k.

    Attributes
    ----------
    time : ndarray, shape (steps + 1,)
        Seconds (samples when the plant has no sampling period).
    state : ndarray, shape (steps + 1, n)
    input : ndarray, shape (steps, m)
    mode : ndarray of int, shape (steps,)
        Plant mode (0-based) over [k, k+1).
    effective : ndarray of bool, shape (steps,)
        A new packet reached the buffer at k.
    per_mode : list of SimulationResult
        For a design's trace: one run per fixed plant mode (same losses).
    ages : ndarray of int, shape (steps,), or None
        The buffer packet's age ``k - stamp`` at each sample (runs on a ``network``).
    raw : dict
    """

    time: np.ndarray
    state: np.ndarray
    input: np.ndarray
    mode: np.ndarray
    effective: np.ndarray
    per_mode: list = field(default_factory=list)
    ages: np.ndarray | None = None
    raw: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_json(cls, data: dict) -> "SimulationResult":
        return cls(time=np.asarray(data["t"], dtype=float), state=np.asarray(data["x"], dtype=float),
                   input=np.asarray(data["u"], dtype=float), mode=np.asarray(data["mode"], dtype=int),
                   effective=np.asarray(data["effective"], dtype=bool),
                   per_mode=[cls.from_json(run) for run in data.get("per_mode") or []],
                   ages=None if data.get("ages") is None else np.asarray(data["ages"], dtype=int), raw=data)


@dataclass
class MarginResult:
    """A finished margin search.

    Attributes
    ----------
    kind : {"n_drop", "sampling_period", "grid"}
    margin : float or int or None
        The largest n_drop, or the largest sampling period in seconds, with a stabilizing design.
    curve : list of dict
        Every point tried with its outcome and max spectral radius.
    method : str
    raw : dict
    """

    kind: str
    margin: float | None
    curve: list
    method: str
    raw: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_json(cls, data: dict) -> "MarginResult":
        return cls(kind=data["kind"], margin=data.get("margin"), curve=list(data.get("curve") or []),
                   method=data.get("method", ""), raw=data)


# -------------------------------------------------------------------------------------------- plants
def _is_family(obj) -> bool:
    return all(hasattr(obj, a) for a in ("F", "G", "n_modes", "sampling_period"))


def plant_json(plant, sampling_period: float | None = None) -> dict:
    """The service's plant JSON for a PlantFamily, python-control systems or a plant dict.

    A family that was discretized from continuous matrices is sent as ``continuous`` (so margin
    searches over the sampling period can re-discretize it), any other as ``discrete``.

    Raises
    ------
    TypeError
        For anything else, saying what is accepted.
    """
    if isinstance(plant, dict):
        from solver.plant import PlantFamily

        PlantFamily.from_dict(plant, sampling_period)  # the library's checks (NaN, shapes): InvalidInput, not a 422
        return plant if sampling_period is None else {**plant, "sampling_period": sampling_period}
    if not _is_family(plant):
        systems = plant if isinstance(plant, (list, tuple)) else [plant]
        if systems and all(hasattr(s, "state_labels") and hasattr(s, "dt") for s in systems):
            from solver.plant import PlantFamily

            plant = PlantFamily.from_statespace(list(systems), sampling_period=sampling_period)
        else:
            raise TypeError("plant must be a solver.PlantFamily, a list of control.StateSpace (one per plant "
                            "mode) or the service's plant JSON as a dict")
    if plant.A is not None and plant.sampling_period is not None:
        out = {"kind": "continuous", "A": np.asarray(plant.A).tolist(), "B": np.asarray(plant.B).tolist(),
               "sampling_period": plant.sampling_period}
    else:
        out = {"kind": "discrete", "F": np.asarray(plant.F).tolist(), "G": np.asarray(plant.G).tolist()}
        if plant.sampling_period is not None:
            out["sampling_period"] = plant.sampling_period
    # names and units travel too: the service's figures and exports label states and inputs with them
    for key in ("state_names", "input_names", "mode_names"):
        if getattr(plant, key, None) is not None:
            out[key] = list(getattr(plant, key))
    if getattr(plant, "units", None):
        out["units"] = dict(plant.units)
    if getattr(plant, "C", None) is not None:
        out["C"] = np.asarray(plant.C).tolist()
    return out


def _lists(options: dict) -> dict:
    """Arrays among keyword options (``observer_gains``, ``xh0``) as JSON lists."""
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in options.items()}


def _gains_json(gains) -> list:
    from solver.network import check_gains

    K = np.asarray(gains, dtype=float)
    if K.ndim == 3:  # the library's check (NaN, infinity) before JSON encoding would fail on it
        check_gains(K, *K.shape)
    return K.tolist()


def _trace_query(x0, steps: int | None, seed: int | None, query: dict) -> dict:
    """Query parameters of a trace (JSON or picture): ``x0`` as one comma-separated value."""
    params = {k: v for k, v in (("steps", steps), ("seed", seed)) if v is not None}
    params.update(query)
    if x0 is not None:
        params["x0"] = ",".join(repr(float(v)) for v in x0)
    return params


# --------------------------------------------------------------------------------------------- client
class Client:
    """Synchronous client of the ncs-design HTTP API (``/v1``).

    Parameters
    ----------
    base_url : str
        E.g. ``"http://127.0.0.1:8000"``.
    api_key : str, optional
        Sent as ``X-API-Key`` (needed when the service has ``NCS_API_KEYS``).
    timeout : float, default 30
        Seconds for one HTTP request (waiting for a job is not bounded by it).
    poll_interval : float, default 0.1
        First pause between polls of a running job (s); it doubles up to ``max_poll_interval``.
    max_poll_interval : float, default 2
    http_client : httpx.Client, optional
        A ready client to send requests with (e.g. a Starlette ``TestClient``); ``base_url``
        is then only used to build URLs.
    """

    def __init__(self, base_url: str, api_key: str | None = None, timeout: float = 30.0, *,
                 poll_interval: float = 0.1, max_poll_interval: float = 2.0,
                 http_client: httpx.Client | None = None):
        headers = {"Accept": "application/json", "User-Agent": "ncs-design-client"}
        if api_key:
            headers["X-API-Key"] = api_key
        self._owns_http = http_client is None
        self._http = http_client or httpx.Client(base_url=base_url.rstrip("/"), timeout=timeout)
        self._headers = headers
        self.base_url = base_url.rstrip("/")
        self.poll_interval = poll_interval
        self.max_poll_interval = max_poll_interval

    # -- plumbing
    def close(self) -> None:
        if self._owns_http:
            self._http.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _request(self, method: str, path: str, *, json: Any = None, params: dict | None = None,
                 headers: dict | None = None) -> httpx.Response:
        url = path if self._owns_http else self.base_url + path
        resp = self._http.request(method, url, json=json, params=params, headers={**self._headers, **(headers or {})})
        if resp.status_code >= 400:
            try:
                problem = resp.json()
                if not isinstance(problem, dict):
                    problem = {"detail": str(problem)}
            except ValueError:
                problem = {"detail": resp.text[:500] or resp.reason_phrase}
            raise ServiceError(resp.status_code, problem)
        return resp

    @staticmethod
    def _prefer(wait) -> dict:
        if wait is True:
            return {"Prefer": "wait=10"}
        if wait and wait is not False:
            return {"Prefer": f"wait={max(1, int(min(float(wait), 60)))}"}
        return {}

    def _wait(self, kind: str, job: Job, wait) -> Job:
        """Poll until the job ends (``wait=True``) or ``wait`` seconds pass (then TimeoutError)."""
        deadline = None if wait is True else time.monotonic() + float(wait)
        pause = self.poll_interval
        while not job.done:
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                raise TimeoutError(f"job {job.id} still {job.status} after {wait} s")
            time.sleep(pause if left is None else min(pause, left))
            pause = min(pause * 2, self.max_poll_interval)
            prefer = self._prefer(True if left is None else max(left, 1))
            job = Job.from_json(self._request("GET", f"/v1/{kind}s/{job.id}", headers=prefer).json())
        return job

    def _submit(self, kind: str, body: dict, wait) -> Job:
        headers = {"Idempotency-Key": str(uuid.uuid4()), **self._prefer(wait)}
        job = Job.from_json(self._request("POST", f"/v1/{kind}s", json=body, headers=headers).json())
        if wait is False or wait is None or wait == 0:
            return job
        job = self._wait(kind, job, wait)
        if job.status != "succeeded":
            raise JobFailed(job)
        return job

    # -- designs
    def design(self, plant, n_drop: int | None = None, method: str = "lmi", *, wait: bool | float = True,
               sampling_period: float | None = None, label: str | None = None, objective: str | None = None,
               weights=None, x0=None, disturbance=None, output=None, u_max=None, channel=None,
               exhausted: str = "hold", feedback: str | None = None, sensor_n_drop: int | None = None,
               observer: str | None = None, noise=None, network=None, **options) -> DesignResult | Job:
        """Design gains K_1..K_{n_drop} on the service.

        Parameters
        ----------
        plant : PlantFamily, list of control.StateSpace or dict
            See :func:`plant_json`.
        n_drop : int, optional
            At most ``n_drop - 1`` consecutive losses (the service's default without a network; a
            network's own ``n_drop`` otherwise).
        method : str, default "lmi"
            ``lmi`` (one SDP), ``ccl`` (the paper's iteration), ... (``GET /openapi.json`` lists them).
        wait : bool or float, default True
            True: block until the job ends; a number: at most that many seconds (then
            ``TimeoutError``; the job keeps running); False: return the queued :class:`Job`.
        sampling_period : float, optional
            h in seconds for continuous python-control systems.
        label : str, optional
            Your name for the job (at most 200 characters), shown in :meth:`jobs`.
        objective, weights, x0, disturbance, output, u_max
            As in :func:`solver.design` (``"cost"`` / ``"hinf"``, ``(Q, R)``, ``(C, D)``, ...; docs/design.md §8).
        feedback, sensor_n_drop, observer, noise
            Output feedback, as in :func:`solver.design` (``"output"``, an int, ``"per_mode"``/``"common"``,
            ``(W, V)``; docs/design.md §12); the plant needs ``C``.
        channel, exhausted
            A :class:`solver.channel.Channel` (or its JSON) to judge the designed gains on; the result's
            ``raw["channel"]`` is then the report of :meth:`analyze_channel` (burst rate, ``ms_stable``, ...).
        network : solver.Network, str or dict, optional
            The network to design for (``Network.delays(2, 3)``, ``"delays:2,3"`` or its JSON).
        **options
            ``decay_rate``, ``plant_switching``, ``scheme``, ``solver``, ``margin``, ``max_iter``
            (the request's ``options``).

        Returns
        -------
        DesignResult, or Job when ``wait=False``.

        Raises
        ------
        ServiceError
            The service refused the request (``.errors`` names the fields).
        JobFailed
            The job failed or was cancelled.
        """
        body = {"plant": plant_json(plant, sampling_period), "method": method}
        if n_drop is not None:
            body["n_drop"] = n_drop
        if network is not None:
            body["network"] = network_json(network)
        if label is not None:
            body["label"] = label
        if options:
            body["options"] = options
        if objective is not None:
            body["objective"] = objective
        body.update(performance_json(weights=weights, x0=x0, disturbance=disturbance, output=output, u_max=u_max))
        if channel is not None:
            body["channel"] = _channel_json(channel)
            body["exhausted"] = exhausted
        for key, value in (("feedback", feedback), ("sensor_n_drop", sensor_n_drop), ("observer", observer)):
            if value is not None:
                body[key] = value
        if noise is not None:
            body["noise"] = {"W": np.asarray(noise[0], dtype=float).tolist(),
                             "V": np.asarray(noise[1], dtype=float).tolist()}
        job = self._submit("design", body, wait)
        if not job.done:
            return job
        return DesignResult.from_json(job.result, job_id=job.id)

    def design_request(self, body: dict, wait: bool | float = True) -> DesignResult | Job:
        """Submit a whole design request (the JSON of ``POST /v1/designs``, e.g. read from a file) as it is."""
        job = self._submit("design", body, wait)
        if not job.done:
            return job
        return DesignResult.from_json(job.result, job_id=job.id)

    def result(self, job_id: str, wait: bool | float = True) -> DesignResult:
        """The result of a design job submitted earlier (waits like :meth:`design`)."""
        job = self.job(job_id)
        job = self._wait("design", job, wait) if wait else job
        if not job.done:
            raise TimeoutError(f"job {job.id} is still {job.status}")
        if job.status != "succeeded":
            raise JobFailed(job)
        return DesignResult.from_json(job.result, job_id=job.id)

    def job(self, job_id: str, kind: str = "design") -> Job:
        """One job (``kind`` ``"design"`` or ``"margin"``)."""
        return Job.from_json(self._request("GET", f"/v1/{kind}s/{job_id}").json())

    def jobs(self, kind: str = "design", status: str | None = None, limit: int = 20, offset: int = 0) -> list[Job]:
        """One page of jobs, newest first."""
        params = {"limit": limit, "offset": offset}
        if status:
            params["status"] = status
        data = self._request("GET", f"/v1/{kind}s", params=params).json()
        return [Job.from_json(item) for item in data["items"]]

    def cancel(self, job_id: str, kind: str = "design") -> Job:
        """Ask a job to stop (a queued one never starts; a running one ends ``cancelled`` shortly)."""
        return Job.from_json(self._request("POST", f"/v1/{kind}s/{job_id}/cancel").json())

    # -- synchronous computations
    def analyze(self, plant, gains, n_drop: int | None = None, *, sampling_period: float | None = None,
                weights=None, x0=None, disturbance=None, output=None, network=None, **options) -> AnalysisResult:
        """Certify given gains (``POST /v1/analyses``): Theorem 1 certificate and spectral radii.

        ``gains`` has shape (n_drop, m, n); ``options``: ``plant_switching``, ``bounds``,
        ``max_product_length``.  ``weights``/``x0`` and ``disturbance``/``output`` ask for the cost and
        l2-gain brackets (``result.cost``, ``result.hinf``), as in :func:`solver.analyze`; ``network`` (a
        :class:`solver.Network`, ``"delays:2,3"`` or its JSON) the verdict on that network.
        """
        body = {"plant": plant_json(plant, sampling_period), "gains": _gains_json(gains), **_lists(options),
                **performance_json(weights=weights, x0=x0, disturbance=disturbance, output=output)}
        if network is not None:
            body["network"] = network_json(network)
        if n_drop is not None:
            body["n_drop"] = n_drop
        return AnalysisResult.from_json(self._request("POST", "/v1/analyses", json=body).json())

    def analyze_channel(self, plant, gains, channel, n_drop: int | None = None, *,
                        sampling_period: float | None = None, **options) -> ChannelAnalysisResult:
        """Given gains on a stochastic channel (``POST /v1/channels``).

        ``channel``: a :class:`solver.channel.Channel` or its JSON (``{"kind": "gilbert_elliott", ...}``);
        ``options``: ``exhausted``, ``plant_transitions``, ``weights`` (``{"Q": ..., "R": ...}`` or a pair),
        ``noise``, ``network`` (the result's ``raw["network_violations"]``: how often the channel breaks it).
        A channel made with ``Channel.with_delays`` sends its delays.
        """
        channel = _channel_json(channel)
        if options.get("network") is not None:
            options["network"] = network_json(options["network"])
        weights = options.get("weights")
        if isinstance(weights, (tuple, list)):
            options["weights"] = {"Q": np.asarray(weights[0], dtype=float).tolist(),
                                  "R": np.asarray(weights[1], dtype=float).tolist()}
        for key in ("plant_transitions", "noise"):
            if isinstance(options.get(key), np.ndarray):
                options[key] = options[key].tolist()
        body = {"plant": plant_json(plant, sampling_period), "gains": _gains_json(gains), "channel": channel,
                **options}
        if n_drop is not None:
            body["n_drop"] = n_drop
        return ChannelAnalysisResult.from_json(self._request("POST", "/v1/channels", json=body).json())

    def simulate(self, plant, gains, x0, n_drop: int | None = None, *, steps: int = 100, seed: int = 42,
                 sampling_period: float | None = None, **options) -> SimulationResult:
        """A seeded simulation of given gains (``POST /v1/simulations``).

        ``options``: ``loss_model``, ``sensor_loss``, ``control_loss``, ``plant_switching``, ``mode``; or
        ``channel`` (a :class:`solver.channel.Channel` or its JSON), ``exhausted``, ``plant_transitions``; or
        ``network`` (a :class:`solver.Network`, ``"delays:2,3"`` or its JSON): ages drawn from it (``ages``).
        """
        if options.get("network") is not None:
            options["network"] = network_json(options["network"])
        if options.get("channel") is not None:
            options["channel"] = _channel_json(options["channel"])
        if isinstance(options.get("plant_transitions"), np.ndarray):
            options["plant_transitions"] = options["plant_transitions"].tolist()
        body = {"plant": plant_json(plant, sampling_period), "gains": _gains_json(gains),
                "x0": [float(v) for v in x0], "steps": steps, "seed": seed, **_lists(options)}
        if n_drop is not None:
            body["n_drop"] = n_drop
        return SimulationResult.from_json(self._request("POST", "/v1/simulations", json=body).json())

    def trace(self, job_id: str, *, x0=None, steps: int = 100, seed: int = 42, **query) -> SimulationResult:
        """The designed loop's seeded run (``GET /v1/designs/{id}/trace``), with one run per plant mode."""
        params = _trace_query(x0, steps, seed, query)
        return SimulationResult.from_json(self._request("GET", f"/v1/designs/{job_id}/trace", params=params).json())

    def trace_image(self, job_id: str, fmt: str = "png", *, x0=None, steps: int | None = None,
                    seed: int | None = None, **query) -> bytes:
        """The trace as a PNG or SVG picture (same parameters as :meth:`trace`)."""
        params = _trace_query(x0, steps, seed, query)
        return self._request("GET", f"/v1/designs/{job_id}/trace.{fmt}", params=params).content

    def gains_file(self, job_id: str, fmt: str = "mat") -> bytes:
        """A succeeded design as a MATLAB ``.mat`` file (``fmt="mat"``) or an Octave/MATLAB script (``"m"``):
        ``K`` (n_drop x m x n), ``K1..KN``, ``F``, ``G``, the certificate's ``P``, ``n_drop``, ``outcome``."""
        if fmt not in ("mat", "m"):
            raise ValueError('fmt must be "mat" or "m"')
        return self._request("GET", f"/v1/designs/{job_id}/gains.{fmt}").content

    def controller_zip(self, job_id: str, *, exhausted: str = "hold", prefix: str = "ncs",
                       precision: str = "float64") -> bytes:
        """A succeeded design's C controller and actuator buffer (``GET /v1/designs/{id}/controller.zip``):
        a zip of ``<prefix>_controller.h`` and ``.c`` (see :func:`solver.export_c`) with the build and test kit
        (:func:`solver.c_kit.export_kit`); ``precision="float32"`` for single precision, certified on the
        rounded gains (refused with the reason when they lose the proof)."""
        return self._request("GET", f"/v1/designs/{job_id}/controller.zip",
                             params={"exhausted": exhausted, "prefix": prefix, "precision": precision}).content

    def problem_sdpa(self, job_id: str) -> str:
        """The design's SDP in SDPA sparse format (``GET /v1/designs/{id}/problem.dat-s``, see
        :func:`solver.export_sdpa`); its optimum is ``-result.history[-1].objective``."""
        return self._request("GET", f"/v1/designs/{job_id}/problem.dat-s").text

    # -- margins
    def margins(self, plant, search: str, method: str = "lmi", *, wait: bool | float = True,
                sampling_period: float | None = None, label: str | None = None,
                **params) -> MarginResult | Job:
        """A stability-margin search (``POST /v1/margins``).

        Parameters
        ----------
        search : {"n_drop", "sampling_period", "grid"}
        **params
            ``n_drop``, ``n_drop_max``, ``h_min``, ``h_max``, ``tol``, ``points``, ``options``.
        """
        body = {"plant": plant_json(plant, sampling_period), "search": search, "method": method, **params}
        if label is not None:
            body["label"] = label
        job = self._submit("margin", body, wait)
        if not job.done:
            return job
        return MarginResult.from_json(job.result)

    def ready(self) -> bool:
        """Whether ``/readyz`` answers 200."""
        try:
            return self._http.get(("" if self._owns_http else self.base_url) + "/readyz").status_code == 200
        except httpx.HTTPError:
            return False
