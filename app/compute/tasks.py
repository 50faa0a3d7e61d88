"""The solver work the service runs: pure functions of JSON-able dicts.

These run in worker processes (design jobs, simulations, analyses), never
in the event loop. This module imports no web framework so worker
processes stay lean.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from solver.memo import BoundedCache
from solver.result import jsonable


def _digest(text: str) -> str:
    """The key of a memo below: the SHA-256 of the inputs' text, not the text itself, which may be large."""
    import hashlib

    return hashlib.sha256(text.encode()).hexdigest()


# The last values by the digest of their inputs, shared by the threads of one process (docs/design.md §6.1).
_families = BoundedCache(64)  # digest of the plant JSON -> its (read-only) family
_checked = BoundedCache(256)  # digests of inputs that passed check_design_inputs


def build_family(plant: dict[str, Any]):
    """The family of a plant JSON, remembered by digest: a worker that designs the same plant again
    skips its discretization (a matrix exponential per mode, ~0.4 ms of the paper example's ~8 ms job).
    The remembered family's matrices are read-only, so no caller can change what the next one gets."""
    import json

    key = _digest(json.dumps(plant, sort_keys=True, separators=(",", ":")))
    return _families.get_or_compute(key, lambda: _read_only_family(plant))


def _read_only_family(plant: dict[str, Any]):
    # A family that overflows when discretized is reported by the solver as InvalidInput;
    # numpy's overflow warnings on the way there would only clutter the service log.
    with np.errstate(over="ignore", invalid="ignore"):
        fam = _build_family(plant)
    for matrix in (fam.F, fam.G):
        if isinstance(matrix, np.ndarray):
            matrix.flags.writeable = False
    return fam


def _build_family(plant: dict[str, Any]):
    """The library's family from the plant JSON (names and units included: ``PlantFamily.from_dict``)."""
    from solver import PlantFamily

    if plant.get("kind") not in ("continuous", "discrete", "dc_motor"):
        raise ValueError(f"unknown plant kind {plant.get('kind')!r}")
    if plant["kind"] == "dc_motor" and plant.get("units") is None and (plant.get("state_names")
                                                                        or plant.get("input_names")):
        plant = {**plant, "units": {}}  # renamed: the motor's default units name states that no longer exist
    return PlantFamily.from_dict(plant)


def _family_matrices(fam) -> dict[str, Any]:
    out = {
        "F": jsonable(np.asarray(fam.F)),
        "G": jsonable(np.asarray(fam.G)),
        "sampling_period": fam.sampling_period,
    }
    for key in ("state_names", "input_names"):
        if getattr(fam, key, None) is not None:
            out[key] = list(getattr(fam, key))
    if getattr(fam, "units", None):
        out["units"] = dict(fam.units)
    return out


def record_to_dict(record: Any) -> dict[str, Any]:
    """Progress of a job: a solver iteration record, or a margin search's step."""
    if isinstance(record, dict):
        d = record
    elif hasattr(record, "to_dict"):
        d = record.to_dict()
    else:
        d = {k: getattr(record, k, None)
             for k in ("iteration", "objective", "trace_gap", "theorem1", "elapsed")}
    if "step" in d:  # solver.margins progress: {"step", "total", "last": point tried}
        last = d.get("last") or {}
        point = {k: last.get(k) for k in ("n_drop", "sampling_period", "outcome") if k in last}
        return jsonable({"step": d["step"], "total": d.get("total"), "point": point})
    keep = ("iteration", "objective", "trace_gap", "theorem1", "elapsed")
    return jsonable({k: d.get(k) for k in keep})


def per_second(rate: Any, sampling_period: float | None) -> float | None:
    """A per-sample rate lambda as the factor per second, ``lambda^(1/h)``; None without h."""
    if rate is None or not sampling_period or not isinstance(rate, (int, float)) or rate < 0:
        return None
    return jsonable(float(rate) ** (1.0 / float(sampling_period)))


def add_per_second_rates(out: dict[str, Any], sampling_period: float | None) -> dict[str, Any]:
    """Next to every ``decay_rate`` (a factor per sample) of a result and of its certificate: the factor per
    second, the exponential rate in 1/s and the time constant in s (:func:`solver.result.rate_in_time`);
    ``decay_rate_per_second`` stays as the old name of the factor per second."""
    from solver.result import rate_in_time

    for d in (out, out.get("certificate") or {}):
        if "decay_rate" in d:
            rate = d.get("decay_rate")
            ok = isinstance(rate, (int, float)) and not isinstance(rate, bool)
            d.update(jsonable(rate_in_time(rate if ok else None, sampling_period)), decay_rate=rate)
            d["decay_rate_per_second"] = d["decay_factor_per_second"]
    return out


def run_design(request: dict[str, Any], callback: Callable[[Any], bool] | None = None) -> dict[str, Any]:
    """Run one design job; returns the job's JSON result."""
    from solver import design

    from app.compute.requests import DesignRequest

    req = DesignRequest.model_validate(request)  # the stored request, with the defaults of its one model
    plant = req.plant.model_dump()
    fam = build_family(plant)
    net = network_from_request(None if req.network is None else req.network.model_dump())
    res = design(fam, n_drop=req.n_drop, method=req.method, callback=callback, **design_options(req.options),
                 **req.performance_kwargs(), **req.feedback_kwargs(), **network_kwargs("design", net))
    out = jsonable(res.to_dict())
    out.update(_family_matrices(fam))
    if net is not None:
        out["network"] = net.to_dict()
    if req.channel is not None and res.outcome == "stabilized":
        from solver.channel import analyze_channel

        n, m = fam.n_states, fam.n_inputs
        weights = (np.eye(n), np.eye(m)) if req.weights is None else (req.weights.Q, req.weights.R)
        rep = analyze_channel(fam, res.gains, req.n_drop, channel_from_request(req.channel.model_dump()),
                              exhausted=req.exhausted, weights=weights, network=net)
        out["channel"] = channel_report_json(rep, req.n_drop)
    return add_per_second_rates(out, fam.sampling_period)


def design_options(options) -> dict[str, Any]:
    """Keyword arguments of solver.design from a request's validated ``DesignOptions``: every field is
    passed, so the defaults are the model's (``app.compute.requests``), not the solver signature's."""
    return options.model_dump()


def run_margin(request: dict[str, Any], callback: Callable[[Any], bool] | None = None) -> dict[str, Any]:
    """Run one margin job (largest n_drop, largest sampling period, or a design grid)."""
    from solver.margins import design_grid, max_n_drop, max_sampling_period

    from app.compute.requests import MarginRequest

    req = MarginRequest.model_validate(request)
    fam = build_family(req.plant.model_dump())
    kwargs = design_options(req.options)
    kwargs.pop("decay_rate", None)
    if req.search == "n_drop":
        res = max_n_drop(fam, req.method, n_drop_max=req.n_drop_max, callback=callback, **kwargs)
    elif req.search == "sampling_period":
        res = max_sampling_period(fam, req.n_drop, req.method, h_min=req.h_min, h_max=req.h_max, tol=req.tol,
                                  callback=callback, **kwargs)
    else:
        res = design_grid(fam, [(p.sampling_period, p.n_drop) for p in req.points], req.method,
                          callback=callback, **kwargs)
    out = jsonable(res.to_dict())
    if out.get("design"):
        add_per_second_rates(out["design"], fam.sampling_period if req.search != "sampling_period" else None)
    return out


def run_job(request: dict[str, Any], callback: Callable[[Any], bool] | None = None) -> dict[str, Any]:
    """Entry point of the design workers: a margin job carries ``search``, a design job does not."""
    if request.get("search"):
        return run_margin(request, callback)
    return run_design(request, callback)


def _gains_array(gains: list) -> np.ndarray:
    return np.asarray(gains, dtype=float)


def run_simulation(req: dict[str, Any]) -> dict[str, Any]:
    from solver import simulate

    fam = build_family(req["plant"])
    gains = _gains_array(req["gains"])
    n_drop = req.get("n_drop") or gains.shape[0]
    extra = {}
    if req.get("channel") is not None:
        from solver import InvalidInput
        from solver.channel import Channel

        try:
            extra["channel"] = Channel.from_dict(req["channel"])
        except InvalidInput as exc:  # the channel's own fields sit under /channel in the request
            raise InvalidInput(str(exc), ("channel", *exc.field)) from None
        extra.update(exhausted=req.get("exhausted", "hold"), plant_transitions=req.get("plant_transitions"))
        if (req["channel"].get("delays") or [1.0]) != [1.0]:
            raise InvalidInput("simulations draw losses from a channel, not its delays: give the delays as a "
                               "network ({\"kind\": \"delays\", ...}) or analyze them with POST /v1/channels",
                               ("channel", "delays"))
    net = network_from_request(req.get("network"))
    extra.update(network_kwargs("simulate", net))
    tr = simulate(
        fam, gains, n_drop=n_drop, x0=list(req["x0"]), steps=req["steps"], seed=req["seed"],
        loss_model=req["loss_model"], sensor_loss=req["sensor_loss"],
        control_loss=req["control_loss"], plant_switching=req["plant_switching"],
        mode=req.get("mode"), **extra, **_observer_kwargs(req, ("observer_gains", "sensor_n_drop", "xh0")),
    )
    out = jsonable(tr.to_dict())
    if net is not None:
        out["network"] = net.to_dict()
    return out


def _observer_kwargs(req: dict[str, Any], keys: tuple) -> dict[str, Any]:
    """The output-feedback fields a request sets (none for state feedback)."""
    return {k: req[k] for k in keys if req.get(k) is not None}


def run_trace(plant: dict[str, Any], gains: list, n_drop: int, params: dict[str, Any],
              network: dict[str, Any] | None = None) -> dict[str, Any]:
    """The designed loop's seeded simulation (switching plant) plus one run per fixed mode (Fig. 3/4); a design
    made for a ``network`` runs on it (ages drawn from the network, ``ages`` in every run)."""
    from solver import simulate

    fam = build_family(plant)
    K = _gains_array(gains)
    common = dict(n_drop=n_drop, x0=list(params["x0"]), steps=params["steps"], seed=params["seed"],
                  loss_model=params["loss_model"], sensor_loss=params["sensor_loss"],
                  control_loss=params["control_loss"], **network_kwargs("simulate", network_from_request(network)))
    main = simulate(fam, K, plant_switching=params["plant_switching"], mode=params.get("mode"), **common)
    out = jsonable(main.to_dict())
    out["per_mode"] = [
        {"plant_mode": l, **jsonable(simulate(fam, K, plant_switching="none", mode=l, **common).to_dict())}
        for l in range(fam.n_modes)
    ]
    out["query"] = jsonable(params)
    return out


def run_trace_json(plant: dict[str, Any], gains: list, n_drop: int, params: dict[str, Any],
                   network: dict[str, Any] | None = None) -> bytes:
    """:func:`run_trace` as the service's canonical JSON bytes (keys sorted, compact). Encoded here, in the pool's
    process: a long trace is tens of MB of JSON, which on the event loop stalled every other request."""
    import json

    return json.dumps(run_trace(plant, gains, n_drop, params, network), sort_keys=True, separators=(",", ":"),
                      allow_nan=False).encode()


def run_analysis(req: dict[str, Any]) -> dict[str, Any]:
    from solver import analyze

    fam = build_family(req["plant"])
    gains = _gains_array(req["gains"])
    n_drop = req.get("n_drop") or gains.shape[0]
    kwargs = {}
    if req.get("max_products") is not None:
        kwargs["max_products"] = req["max_products"]
    if req.get("max_product_length") is not None:
        kwargs["max_product_length"] = req["max_product_length"]
    for key in ("plant_switching", "bounds"):
        if req.get(key) is not None:
            kwargs[key] = req[key]
    if req.get("weights") is not None:
        kwargs["weights"] = (req["weights"]["Q"], req["weights"]["R"])
    if req.get("output") is not None:
        kwargs["output"] = (req["output"]["C"], req["output"].get("D"))
    for key in ("x0", "disturbance"):
        if req.get(key) is not None:
            kwargs[key] = req[key]
    kwargs.update(_observer_kwargs(req, ("observer_gains", "sensor_n_drop")))
    net = network_from_request(req.get("network"))
    rep = analyze(fam, gains, n_drop=n_drop, **kwargs, **network_kwargs("analyze", net))
    out = jsonable(rep.to_dict())
    if net is not None:
        out["network"] = net.to_dict()
    return add_per_second_rates(out, fam.sampling_period)


def channel_from_request(spec: dict[str, Any]):
    """A request's channel JSON as a :class:`solver.channel.Channel`; its errors name fields under /channel."""
    from solver import InvalidInput
    from solver.channel import Channel

    try:
        return Channel.from_dict(spec)
    except InvalidInput as exc:
        raise InvalidInput(str(exc), ("channel", *exc.field)) from None


def network_from_request(spec: dict[str, Any] | None):
    """A request's ``network`` JSON as a :class:`solver.Network` (None when absent); errors name /network/..."""
    if spec is None:
        return None
    from solver.networks import check_network

    return check_network({k: v for k, v in spec.items() if v is not None or k != "n_drop"})


def network_kwargs(function: str, net) -> dict[str, Any]:
    """``{"network": net}`` for a solver function (``design``, ``analyze``, ``simulate``, ``export_c``) that takes
    one; the paper's network needs none. A solver without network support refuses the others by name (422),
    instead of silently certifying the paper's network."""
    if net is None:
        return {}
    import inspect

    import solver
    from solver import InvalidInput

    if "network" in inspect.signature(getattr(solver, function)).parameters:
        return {"network": net}
    if net.is_bounded_drops:
        return {}
    raise InvalidInput(f"this server's solver.{function} does not take networks yet: {net.describe()} cannot be "
                       "used here; give a bounded_drops network (or none)", ("network", "kind"))


def channel_report_json(rep, n_drop: int) -> dict[str, Any]:
    """A :class:`solver.channel.ChannelReport` as JSON, its certificates summarized (their matrices stay out)."""
    out = jsonable(rep.to_dict())
    for key in ("upper_certificate", "lower_certificate"):
        cert = out.get(key)
        if cert is not None:
            out[key] = {k: cert[k] for k in ("kind", "verified", "beta", "mu", "steps") if k in cert}
    out["n_drop"] = n_drop
    return out


def run_channel(req: dict[str, Any]) -> dict[str, Any]:
    """``analyze_channel`` for ``POST /v1/channels``."""
    from solver import InvalidInput
    from solver.channel import analyze_channel

    fam = build_family(req["plant"])
    gains = _gains_array(req["gains"])
    n_drop = req.get("n_drop") or gains.shape[0]
    weights = None if req.get("weights") is None else (req["weights"]["Q"], req["weights"]["R"])
    channel = channel_from_request(req["channel"])
    try:
        rep = analyze_channel(fam, gains, n_drop, channel, exhausted=req["exhausted"],
                              plant_transitions=req.get("plant_transitions"), weights=weights,
                              noise=req.get("noise"), network=network_from_request(req.get("network")))
    except InvalidInput as exc:
        if exc.field[:1] in (("Q",), ("R",)):
            raise InvalidInput(str(exc), ("weights", *exc.field)) from None
        raise
    return channel_report_json(rep, n_drop)


def run_trace_plot(plant: dict[str, Any], gains: list, n_drop: int, params: dict[str, Any], fmt: str,
                   size: dict[str, Any], network: dict[str, Any] | None = None) -> bytes:
    """The trace of :func:`run_trace` drawn like Fig. 3/4: the switching run, then one column per plant mode
    (with a row of buffer ages on a network)."""
    from solver import simulate
    from solver.plotting import SWITCHING_WORDS, mode_title, render, trace_figure

    fam = build_family(plant)
    K = _gains_array(gains)
    common = dict(n_drop=n_drop, x0=list(params["x0"]), steps=params["steps"], seed=params["seed"],
                  loss_model=params["loss_model"], sensor_loss=params["sensor_loss"],
                  control_loss=params["control_loss"], **network_kwargs("simulate", network_from_request(network)))
    runs = [simulate(fam, K, plant_switching=params["plant_switching"], mode=params.get("mode"), **common)]
    runs += [simulate(fam, K, plant_switching="none", mode=l, **common) for l in range(fam.n_modes)]
    first = SWITCHING_WORDS.get(params["plant_switching"], params["plant_switching"])
    titles = [first[0].upper() + first[1:]] + [mode_title(fam, l) for l in range(fam.n_modes)]
    return render(trace_figure(runs, titles, family=fam, u_max=params.get("u_max"), **size), fmt)


def run_margin_plot(result: dict[str, Any], fmt: str, size: dict[str, Any]) -> bytes:
    """The curve of a finished margin job."""
    from solver.margins import MarginResult
    from solver.plotting import margin_figure, render

    res = MarginResult(kind=result["kind"], margin=result["margin"], design=None, curve=result["curve"],
                       method=result["method"])
    return render(margin_figure(res, **size), fmt)


def run_gains_file(result: dict[str, Any], fmt: str, name: str) -> bytes:
    """A design result as a MATLAB ``.mat`` file or an Octave/MATLAB ``.m`` script (``solver.matlab``)."""
    from solver.matlab import m_script, mat_bytes

    if fmt == "mat":
        return mat_bytes(result)
    return m_script(result, name=name).encode()


def run_controller_zip(result: dict[str, Any], n_drop: int, exhausted: str, prefix: str,
                       metadata: dict[str, Any], precision: str = "float64",
                       plant: dict[str, Any] | None = None) -> bytes:
    """The C controller and actuator buffer of a design's gains with its build and test kit
    (``solver.c_kit.export_kit``: CMake, toolchain file, replay test of a simulated run), zipped."""
    import io
    import zipfile

    from solver.c_kit import export_kit, result_view

    family = build_family(plant) if plant is not None else None
    files = export_kit(result_view(result), n_drop, exhausted=exhausted, prefix=prefix, metadata=metadata,
                       precision=precision, family=family,
                       **network_kwargs("export_c", network_from_request(result.get("network"))))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        for name in sorted(files):
            # a fixed date: the same design gives byte-identical archives (ETags, caches)
            z.writestr(zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0)), files[name])
    return out.getvalue()


#: Design options that decide which SDP is solved (the rest say how it is solved).
SDP_OPTIONS = ("decay_rate", "plant_switching", "scheme")


def run_problem_sdpa(plant: dict[str, Any], n_drop: int, method: str, options: dict[str, Any]) -> bytes:
    """The SDP a design solves, in SDPA sparse format (``solver.export_sdpa``)."""
    from solver import export_sdpa

    kwargs = {k: options[k] for k in SDP_OPTIONS if options.get(k) is not None}
    return export_sdpa(build_family(plant), n_drop, method, **kwargs).encode()


def warm_up() -> None:
    """Import the heavy libraries once so the first job does not pay for it."""
    import solver  # noqa: F401
    import cvxpy  # noqa: F401
    import solver.margins  # noqa: F401

    import app.compute.requests  # noqa: F401  (every job is re-validated into these models)


def check_performance_inputs(plant: dict[str, Any], request: dict[str, Any]) -> int:
    """The solver's own checks of a design request's performance fields (objective, weights, x0, disturbance,
    output, u_max) before a job exists; raises the solver's InvalidInput naming the field.  Returns the sum of
    the design's LMI block sides (for the service's size limit)."""
    from solver.methods.performance import block_sides, prepare
    from solver.network import ModeSet

    from app.compute.requests import DesignRequest

    req = DesignRequest.model_validate(request)
    fam = build_family(plant)
    modes = ModeSet.from_family(fam, req.n_drop, req.options.plant_switching, req.options.scheme)
    kw = req.performance_kwargs()
    objective = kw.pop("objective")
    lifted, _, _ = prepare(modes, req.method, objective, kw.get("weights"), kw.get("x0"), kw.get("disturbance"),
                           kw.get("output"), kw.get("u_max"), req.options.decay_rate, req.options.solver)
    return 0 if lifted is None else sum(block_sides(lifted, objective))


def check_network_performance_inputs(plant: dict[str, Any], request: dict[str, Any], network) -> None:
    """What of a design request's performance fields carries over to ``network`` (docs/design.md §11.3); raises
    the solver's InvalidInput naming the field."""
    from solver.methods.network_performance import check_request

    from app.compute.requests import DesignRequest

    req = DesignRequest.model_validate(request)
    fam = build_family(plant)
    kw = req.performance_kwargs()
    check_request(network, kw.pop("objective"), kw.get("weights"), kw.get("x0"), kw.get("disturbance"),
                  kw.get("output"), kw.get("u_max"), req.options.decay_rate, fam.n_states, fam.n_inputs)


def check_design_inputs(plant_json: str, n_drop: int | None, plant_switching: str, scheme: str) -> None:
    """Build the family and (given ``n_drop``) its closed-loop modes as a design would; raises the solver's
    InvalidInput. Inputs that passed are remembered by digest (not by their JSON, which may be large): a
    sweep submits the same plant many times, and building it costs ~3 ms of the request thread. A
    rejection is not remembered (it raises every time)."""
    import json

    from solver.network import ModeSet

    key = _digest(f"{n_drop}|{plant_switching}|{scheme}|{plant_json}")
    if _checked.get(key, False):
        return
    fam = build_family(json.loads(plant_json))
    if n_drop is not None:
        with np.errstate(over="ignore", invalid="ignore"):
            ModeSet.from_family(fam, n_drop, plant_switching, scheme)
        from solver.design import HOPELESS_GROWTH_LOG, unstable_growth

        growth = unstable_growth(fam)  # a sampling period no design survives (often ms typed as s): a 422 now
        if growth is not None and growth.per_sample_log > HOPELESS_GROWTH_LOG:
            from solver import InvalidInput

            raise InvalidInput(growth.explain(n_drop, "no loop can be certified at this sampling period in "
                                              "double precision"), ("sampling_period",))
    _checked.put(key, True)
