"""``ncs-design design | analyze | simulate | channel``: the CLI's computing commands (see :mod:`app.cli`).

In-process they call the solver library directly (no service, no web framework imported); with
``--server URL`` they go through :class:`app.client.Client`.  Results print as a short human
summary on stdout; ``--output`` writes machine formats.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from solver.result import jsonable

EXIT_OK, EXIT_NO, EXIT_USAGE, EXIT_FAILED = 0, 1, 2, 3


class UsageError(Exception):
    """Bad usage or input: printed as one line, exit 2."""


# --------------------------------------------------------------------------------------------- files
def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except OSError as exc:
        raise UsageError(f"cannot read {path}: {exc.strerror}") from None
    except json.JSONDecodeError as exc:
        raise UsageError(f"{path} is not valid JSON: {exc}") from None


def load_plant(path: str, sampling_period: float | None = None):
    """A PlantFamily from a plant file (.json: the service's plant JSON or a request holding one; .mat)."""
    from solver.plant import PlantFamily

    p = Path(path)
    if not p.exists():
        raise UsageError(f"plant file {path} does not exist")
    if p.suffix.lower() == ".mat":
        from solver.matlab import plant_from_mat

        return plant_from_mat(str(p), sampling_period=sampling_period)
    data = _read_json(p)
    if isinstance(data, dict) and isinstance(data.get("plant"), dict):
        data = data["plant"]  # a whole design request
    fam = PlantFamily.from_dict(data, sampling_period=sampling_period)
    return fam if fam.name else _renamed(fam, p.stem)


def _renamed(fam, name: str):
    from dataclasses import replace

    return replace(fam, name=name)


def load_gains(path: str) -> np.ndarray:
    """Gains (n_drop, m, n) from a JSON result/list or a .mat file with K or K1..KN."""
    p = Path(path)
    if not p.exists():
        raise UsageError(f"gains file {path} does not exist")
    if p.suffix.lower() == ".mat":
        import scipy.io

        try:
            d = scipy.io.loadmat(str(p))
        except Exception as exc:
            raise UsageError(f"{path} is not a readable .mat file: {exc}") from None
        if "K" in d and np.asarray(d["K"]).ndim == 3:
            return np.asarray(d["K"], dtype=float)
        ks = []
        while f"K{len(ks) + 1}" in d:
            ks.append(np.asarray(d[f"K{len(ks) + 1}"], dtype=float))
        if not ks:
            raise UsageError(f"{path} has neither K (n_drop x m x n) nor K1, K2, ...")
        return np.stack(ks)
    data = _read_json(p)
    if isinstance(data, dict):  # a design result, or a whole job holding one
        data = (data["result"] if isinstance(data.get("result"), dict) else data).get("gains")
    if data is None:
        raise UsageError(f"{path} has no gains (an infeasible design?)")
    try:
        return np.asarray(data, dtype=float)
    except (TypeError, ValueError):
        raise UsageError(f"{path}: gains must be a list of n_drop matrices m x n") from None


def _parse_decay_rate(text: str | None):
    if text is None or text in ("max", "auto"):
        return text
    if text == "none":
        return None
    try:
        return float(text)
    except ValueError:
        raise UsageError(f"--decay-rate must be a number in (0, 1], 'auto', 'max' or 'none', got {text!r}") from None


def _json_arg(text: str | None, flag: str):
    """A JSON value given inline or as ``@file``."""
    if text is None:
        return None
    try:
        return _read_json(Path(text[1:])) if text.startswith("@") else json.loads(text)
    except json.JSONDecodeError as exc:
        raise UsageError(f"{flag} must be JSON (inline or @file): {exc}") from None


def _numbers(text: str | None, flag: str):
    if text is None:
        return None
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise UsageError(f"{flag} must be comma-separated numbers, got {text!r}") from None


def performance_kwargs(args) -> dict:
    """solver.design/analyze keywords from the performance flags (docs/design.md §8)."""
    kw: dict = {}
    weights = _json_arg(args.weights, "--weights")
    if weights is not None:
        if not isinstance(weights, dict) or set(weights) != {"Q", "R"}:
            raise UsageError('--weights must be {"Q": [[...]], "R": [[...]]}')
        kw["weights"] = (weights["Q"], weights["R"])
    out = _json_arg(args.performance_output, "--performance-output")
    if out is not None:
        if not isinstance(out, dict) or "C" not in out:
            raise UsageError('--performance-output must be {"C": [[...]], "D": [[...]]}')
        kw["output"] = (out["C"], out.get("D"))
    for key, value in (("x0", _numbers(args.perf_x0, "--x0")),
                       ("disturbance", _json_arg(args.disturbance, "--disturbance")),
                       ("objective", getattr(args, "objective", None)),
                       ("u_max", _numbers(getattr(args, "u_max", None), "--u-max"))):
        if value is not None:
            kw[key] = value
    return kw


def _lookahead_alone(perf: dict) -> float:
    """The look-ahead matrices' own cost bound, ``max_q x0' P_q x0`` (``trace P_q`` without x0, docs/design.md §8.4)."""
    P = np.asarray(perf["mode_certificate"], dtype=float)
    x0 = perf.get("x0")
    if x0 is None:
        return float(np.trace(P, axis1=1, axis2=2).max())
    x = np.asarray(x0, dtype=float)
    return float(np.einsum("i,qij,j->q", x, P, x).max())


def performance_summary(perf: dict | None, name: str) -> list[str]:
    if not perf:
        return []
    upper = "none certified" if perf.get("upper") is None else f"{perf['upper']:.6g}"
    source = "re-checked certificate"
    quadratic = perf.get("certificate_upper")
    if perf.get("mode_certificate") is not None and perf.get("start_nodes") is not None:  # §11.3
        memory = int(perf.get("memory") or 1)
        when = "next" if perf.get("kind") == "cost" else "last"  # look-ahead for the cost, memory for the l2 gain
        source = (f"one re-checked matrix per {when} transition" if memory == 1 else
                  f"one re-checked matrix per sequence of the {when} {memory} transitions") + (
            "" if quadratic is None else f"; the node matrices alone: {quadratic:.6g}")
    elif perf.get("mode_certificate") is not None and quadratic is not None:  # §8.4
        source = "one re-checked storage per loop mode"
        if perf.get("kind") == "cost":
            source = "one re-checked matrix per sequence of the next intervals"
            ahead = _lookahead_alone(perf)
            if perf.get("upper") is not None and perf["upper"] < ahead * (1 - 1e-9):
                source = f"prefix tree on {source}, whose bound alone is {ahead:.6g}"
        source += f"; the common certificate alone: {quadratic:.6g}"
    elif perf.get("upper") is not None and quadratic is not None and quadratic > perf["upper"]:
        source = f"prefix tree on the re-checked certificate, whose bound alone is {quadratic:.6g}"  # §8.4
    lower = "-" if perf.get("lower") is None else f"{perf['lower']:.6g}"
    pairs = [f"({p}, {e})" for p, e in perf.get("witness") or []]
    lead = int(perf.get("lead") or 0)
    if lead:  # a prefix run once, then the period repeated (docs/design.md §8.4)
        witness = f"{' '.join(pairs[:lead])}, then the period {' '.join(pairs[lead:])}"
        return [f"{name}: upper {upper} ({source}), lower {lower} (worst pattern searched: {witness})"]
    return [f"{name}: upper {upper} ({source}), lower {lower} (worst periodic pattern {' '.join(pairs)})"]


# ------------------------------------------------------------------------------------------- summary
def _fmt_matrix(M) -> str:
    M = np.atleast_2d(np.asarray(M, dtype=float))
    return "[" + "; ".join(" ".join(f"{v:.6g}" for v in row) for row in M) + "]"


def plant_summary(fam) -> str:
    h = f"h = {fam.sampling_period:g} s" if fam.sampling_period is not None else "no sampling period"
    names = ""
    if fam.state_names:
        names = "; x = [" + ", ".join(fam.state_label(i) for i in range(fam.n_states)) + "]"
    if fam.input_names:
        names += ", u = [" + ", ".join(fam.input_label(j) for j in range(fam.n_inputs)) + "]"
    return (f"plant {fam.name or ''}: r = {fam.n_modes} modes, n = {fam.n_states} states, "
            f"m = {fam.n_inputs} inputs, {h}{names}").replace("plant :", "plant:")


def settling_lines(settling: dict | None) -> list[str]:
    """The certified rate in time units and the settling time it guarantees."""
    if not settling:
        return []
    line = f"certified decay rate: {settling['decay_rate']:.4g} per sample"
    if settling.get("exponential_rate") is not None:
        line += (f" = factor {settling['decay_factor_per_second']:.3g} per second (exponential rate "
                 f"{settling['exponential_rate']:.3g} 1/s, time constant {settling['time_constant']:.3g} s)")
    seconds = "" if settling.get("seconds") is None else f" = {settling['seconds']:.3g} s"
    return [line, f"certified settling time to 2 % of |x0|, worst case over every allowed loss and switching "
                  f"sequence: {settling['samples']} samples{seconds}"]


def design_summary(result: dict) -> list[str]:
    lines = [f"design: method {result.get('method')}, n_drop = {result['n_drop']}: {result['outcome']}"]
    cert = result.get("certificate")
    if cert:
        checked = 'verified' if cert.get('verified') else 'NOT verified'
        if cert.get("kind") in ("common_quadratic", "switched"):  # a Lyapunov certificate: stabilized
            lines.append(f"certificate: {cert.get('kind')}, {checked}, relative margin of this certificate's P "
                         f"{cert['margin']:.3g} (min decrease / lambda_max(P))")
        else:  # a proof of infeasibility (farkas, uncontrollable) says what it proves in words
            lines.append(f"certificate: {cert.get('kind')}, {checked}: {cert.get('statement') or ''}".rstrip(": "))
    if result.get("max_spectral_radius") is not None:
        lines.append(f"max spectral radius of the interval closed loops: {result['max_spectral_radius']:.4g}")
    lines += settling_lines(result.get("settling"))
    lines += performance_summary(result.get("performance"), result.get("objective") or "performance")
    if result.get("invariant_set") is not None:
        lines.append(f"input limits hold from x' X x <= 1, X = {_fmt_matrix(result['invariant_set'])}")
    for q, K in enumerate(result.get("gains") or []):
        lines.append(f"K_{q + 1} = {_fmt_matrix(K)}")
    if result.get("message"):
        lines.append(f"message: {result['message']}")
    return lines


# ------------------------------------------------------------------------------------------ commands
def _network(args):
    """``--network`` as a :class:`solver.Network` (None without it)."""
    text = getattr(args, "network", None)
    if text is None:
        return None
    from solver import Network

    return Network.parse(text)


def _network_kwargs(function: str, net) -> dict:
    """``network=`` for an in-process solver call (a solver without network support refuses by name)."""
    from app.compute.tasks import network_kwargs

    return network_kwargs(function, net)


def _client(args):
    from app.client import Client

    return Client(args.server, api_key=args.api_key)


def _request_file(path: str):
    """The JSON of a whole design request (a dict with a ``"plant"``), or None for a plant file."""
    p = Path(path)
    if p.suffix.lower() == ".mat" or not p.exists():
        return None
    data = _read_json(p)
    return data if isinstance(data, dict) and isinstance(data.get("plant"), dict) else None


def design_request_from_file(request: dict, args) -> dict:
    """The request file with the command line's flags over it, validated like the service validates it.

    Every field of ``POST /v1/designs`` is honoured (the design runs through the service's own task); a
    field the request model does not know is refused by name, so nothing in the file is silently dropped."""
    from pydantic import ValidationError

    from app.compute.requests import DesignRequest

    req = json.loads(json.dumps(request))  # a copy
    if args.sampling_period is not None:
        req["plant"]["sampling_period"] = args.sampling_period
    for key, value in (("n_drop", args.n_drop), ("method", args.method)):
        if value is not None:
            req[key] = value
    options = dict(req.get("options") or {})
    for key, value in (("plant_switching", args.plant_switching), ("scheme", args.scheme),
                       ("solver", args.solver)):
        if value is not None:
            options[key] = value
    if args.decay_rate is not None:
        options["decay_rate"] = _parse_decay_rate(args.decay_rate)
    if options:
        req["options"] = options
    perf = performance_kwargs(args)
    for key in ("objective", "u_max", "x0", "disturbance"):
        if key in perf:
            req[key] = perf[key]
    if "weights" in perf:
        req["weights"] = dict(zip("QR", perf["weights"]))
    if "output" in perf:
        req["output"] = dict(zip("CD", perf["output"]))
    try:
        model = DesignRequest.model_validate(req)
    except ValidationError as exc:
        lines = []
        for e in exc.errors()[:10]:
            where = ".".join(str(x) for x in e["loc"]) or "(request)"
            what = "is not a field of a design request" if e["type"] == "extra_forbidden" else e["msg"]
            lines.append(f"{where} {what}" if e["type"] == "extra_forbidden" else f"{where}: {what}")
        raise UsageError(f"{args.plant}: " + "; ".join(lines)) from None
    return model.model_dump(mode="json", exclude_unset=True)  # the service's defaults apply to the rest


def cmd_design(args) -> int:
    request = _request_file(args.plant)
    if request is not None:
        return _design_request(request, args)
    if args.n_drop is None and getattr(args, "network", None) is None:
        raise UsageError("--n-drop is required (or --network SPEC, whose N is the drop bound, or a request file "
                         "with \"n_drop\")")
    fam = load_plant(args.plant, args.sampling_period)
    options = {k: v for k, v in (("plant_switching", args.plant_switching), ("scheme", args.scheme),
                                 ("feedback", args.feedback), ("sensor_n_drop", args.sensor_n_drop),
                                 ("observer", args.observer), ("solver", args.solver)) if v is not None}
    if args.decay_rate is not None:  # given: 'none' means plain stability (None), not the default "auto"
        options["decay_rate"] = _parse_decay_rate(args.decay_rate)
    perf = performance_kwargs(args)
    suffix = Path(args.output).suffix.lower() if args.output else None
    if suffix not in (None, ".json", ".mat", ".m"):
        raise UsageError(f"--output must end in .json, .mat or .m, got {args.output!r}")
    method = args.method or "lmi"
    net = _network(args)
    if net is not None and args.n_drop is not None and args.n_drop != net.n_drop:
        raise UsageError(f"--n-drop {args.n_drop} disagrees with --network {args.network!r} (n_drop = {net.n_drop})")
    n_drop = net.n_drop if net is not None else args.n_drop
    print(plant_summary(fam))
    if net is not None:
        print(f"network: {net.describe()}")
    if args.server:
        with _client(args) as c:
            result = c.design(fam, n_drop=n_drop, method=method, network=net, **perf, **options).raw
    else:
        from solver import design

        res = design(fam, n_drop=n_drop, method=method, **perf, **options, **_network_kwargs("design", net))
        result = jsonable(res.to_dict())
        result.update(F=fam.F.tolist(), G=fam.G.tolist(), sampling_period=fam.sampling_period)
        if net is not None:
            result["network"] = net.to_dict()
    return _report_design(args, suffix, result, fam, net)


def _design_request(request: dict, args) -> int:
    """``design REQUEST.json``: the whole request, run as the service runs it (every field honoured)."""
    suffix = Path(args.output).suffix.lower() if args.output else None
    if suffix not in (None, ".json", ".mat", ".m"):
        raise UsageError(f"--output must end in .json, .mat or .m, got {args.output!r}")
    req = design_request_from_file(request, args)
    from solver.plant import PlantFamily

    fam = PlantFamily.from_dict(req["plant"])
    fam = fam if fam.name else _renamed(fam, Path(args.plant).stem)
    print(plant_summary(fam))
    asked = [f"{k} {req[k]}" for k in ("objective", "u_max", "x0") if k in req and req[k] != "stability"]
    asked += [k for k in ("weights", "disturbance", "output", "channel") if k in req]
    options = req.get("options") or {}
    print(f"request {args.plant}: n_drop {req.get('n_drop', 3)}, method {req.get('method', 'lmi')}, solver "
          f"{options.get('solver', 'AUTO')}" + ("".join(f", {a}" for a in asked)))
    if args.server:
        with _client(args) as c:
            result = c.design_request(req).raw
    else:
        from app.compute.tasks import run_design

        result = run_design(req)
    return _report_design(args, suffix, result, fam)


def _report_design(args, suffix, result: dict, fam, net=None) -> int:
    print("\n".join(design_summary(result)), flush=True)
    if result.get("observer_gains") is not None:
        print(f"observer gains L (one n x p per plant mode): {json.dumps(result['observer_gains'])}")
    if result["outcome"] == "stabilized" and result.get("gains") and result.get("feedback", "state") == "state" \
            and net is None:
        print(simulated_settling(fam, result))
    if args.output:
        _write_design(args.output, suffix, result, fam)
        print(f"wrote {args.output}")
    return EXIT_OK if result["outcome"] == "stabilized" else EXIT_NO


def simulated_settling(fam, result: dict, seed: int = 42) -> str:
    """One seeded run from x0 = all ones: where it settled, next to the certified worst case."""
    from solver import simulate

    certified = (result.get("settling") or {}).get("samples") or 100
    steps = int(min(max(2 * certified, 100), 10_000))
    run = simulate(fam, np.asarray(result["gains"]), result["n_drop"], x0=np.ones(fam.n_states), steps=steps,
                   seed=seed)
    k = run.settling_samples()
    if k is None:
        return f"simulated run (seed {seed}, x0 = all ones, {steps} samples): not within 2 % of |x0| by its end"
    seconds = "" if fam.sampling_period is None else f" = {k * fam.sampling_period:.3g} s"
    return f"simulated settling to 2 % of |x0| (seed {seed}, x0 = all ones, paper's loss model): {k} samples{seconds}"


def _write_design(path: str, suffix: str, result: dict, fam) -> None:
    from solver.matlab import m_script, save_mat

    if suffix == ".json":
        Path(path).write_text(json.dumps(result, indent=1, allow_nan=False) + "\n")
    elif suffix == ".mat":
        save_mat(path, result, fam)
    else:
        Path(path).write_text(m_script(result, fam, name=Path(path).stem))


def cmd_analyze(args) -> int:
    fam = load_plant(args.plant, args.sampling_period)
    gains = load_gains(args.gains)
    net = _network(args)
    n_drop = args.n_drop or (net.n_drop if net is not None else len(gains))
    kwargs = {"plant_switching": args.plant_switching} if args.plant_switching else {}
    kwargs.update(performance_kwargs(args))
    print(plant_summary(fam))
    if args.server:
        with _client(args) as c:
            report = c.analyze(fam, gains, n_drop, network=net, **kwargs).raw
    else:
        from solver import analyze

        report = jsonable(analyze(fam, gains, n_drop=n_drop, **kwargs, **_network_kwargs("analyze", net)).to_dict())
        if net is not None:
            report["network"] = net.to_dict()
    verdict = {True: "stable (certified)", False: "UNSTABLE", None: "unknown"}[report["stable"]]
    on = "" if net is None else f" on {net.describe()}"
    print(f"analysis, n_drop = {n_drop}{on}: {verdict}: {report.get('reason', '')}")
    if report.get("max_spectral_radius") is not None:
        print(f"max spectral radius of the interval closed loops: {report['max_spectral_radius']:.4g}")
    if report.get("margin") is not None:
        print(f"relative margin of analyze's own certificate P (min decrease / lambda_max(P), the P that maximizes "
              f"it for these gains; a design's P can have a smaller one): {report['margin']:.3g}")
    if report.get("decay_rate") is not None:
        from solver.result import rate_in_time

        rate = rate_in_time(report["decay_rate"], fam.sampling_period)
        extra = ("" if rate["exponential_rate"] is None else
                 f" (exponential rate {rate['exponential_rate']:.3g} 1/s, time constant {rate['time_constant']:.3g} s)")
        print(f"best certified decay rate: {report['decay_rate']:.4g} per sample{extra}")
    for line in performance_summary(report.get("cost"), "cost") + performance_summary(report.get("hinf"), "l2 gain"):
        print(line)
    if args.output:
        Path(args.output).write_text(json.dumps(report, indent=1) + "\n")
        print(f"wrote {args.output}")
    return EXIT_OK if report["stable"] is True else EXIT_NO


def cmd_simulate(args) -> int:
    fam = load_plant(args.plant, args.sampling_period)
    gains = load_gains(args.gains)
    net = _network(args)
    n_drop = args.n_drop or (net.n_drop if net is not None else len(gains))
    if args.x0 is None:
        x0 = [1.0] * fam.n_states
    else:
        try:
            x0 = [float(v) for v in args.x0.split(",")]
        except ValueError:
            raise UsageError(f"--x0 must be comma-separated numbers, e.g. --x0 1,-0.5, got {args.x0!r}") from None
    if args.plot and Path(args.plot).suffix.lower() not in (".png", ".svg"):
        raise UsageError(f"--plot must end in .png or .svg, got {args.plot!r}")
    opts = dict(steps=args.steps, seed=args.seed, plant_switching=args.plant_switching, mode=args.mode)
    print(plant_summary(fam))
    if args.server:
        with _client(args) as c:
            run = c.simulate(fam, gains, x0, n_drop, network=net, **{k: v for k, v in opts.items() if v is not None})
        data = run.raw
    else:
        from solver import simulate

        run = simulate(fam, gains, n_drop, x0=x0, **opts, **_network_kwargs("simulate", net))
        data = jsonable(run.to_dict())
        if net is not None:
            data["network"] = net.to_dict()
    ages = getattr(run, "ages", None)
    if ages is not None and net is not None:
        ages = np.asarray(ages)
        print(f"buffer ages on {net.describe()}: max {int(ages.max())}, "
              f"{int(np.sum(ages > 0))} samples without a fresh packet")
    lost = int(np.sum(~np.asarray(run.effective)))
    peak = float(np.max(np.linalg.norm(run.state, axis=1)))
    print(f"simulated {args.steps} samples (seed {args.seed}): {lost} without a new packet; "
          f"|x| from {np.linalg.norm(run.state[0]):.4g} (peak {peak:.4g}) to {np.linalg.norm(run.state[-1]):.4g}")
    if args.output:
        Path(args.output).write_text(json.dumps(data) + "\n")
        print(f"wrote {args.output}")
    if args.plot:
        from solver.plotting import SWITCHING_WORDS, render, trace_figure

        title = SWITCHING_WORDS.get(args.plant_switching, args.plant_switching).capitalize()
        Path(args.plot).write_bytes(render(trace_figure([run], [title], family=fam), Path(args.plot).suffix[1:].lower()))
        print(f"wrote {args.plot}")
    return EXIT_OK


def cmd_codegen(args) -> int:
    from solver.c_kit import export_kit, result_view

    gains = load_gains(args.result)
    n_drop = args.n_drop or len(gains)
    metadata = {"file": Path(args.result).name}
    source = gains
    if Path(args.result).suffix.lower() == ".json":
        data = _read_json(Path(args.result))
        if isinstance(data, dict):
            job = data
            result = data["result"] if isinstance(data.get("result"), dict) else data
            cert = result.get("certificate") or {}
            metadata.update({k: v for k, v in (("id", job.get("id")), ("method", result.get("method")),
                                               ("outcome", result.get("outcome")),
                                               ("certificate", cert.get("kind"))) if v is not None})
            source = result_view(result)  # the float32 re-check starts from the design's certificate
    family = load_plant(args.plant, args.sampling_period) if args.plant else None
    if args.precision == "float32" and family is None:
        raise UsageError("--precision float32 needs --plant: the certificate is re-checked on the rounded gains")
    files = export_kit(source, n_drop, exhausted=args.exhausted, prefix=args.prefix, metadata=metadata,
                       precision=args.precision, family=family)
    out = Path(args.out)
    for name, text in files.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(text)
        print(f"wrote {out / name}")
    return EXIT_OK


def cmd_export_sdpa(args) -> int:
    if args.server:
        raise UsageError("export-sdpa runs in-process; a service's design has GET /v1/designs/{id}/problem.dat-s")
    fam = load_plant(args.plant, args.sampling_period)
    decay_rate = _parse_decay_rate(args.decay_rate)
    options = {k: v for k, v in (("decay_rate", decay_rate), ("plant_switching", args.plant_switching),
                                 ("scheme", args.scheme)) if v is not None}
    from solver import export_sdpa

    text = export_sdpa(fam, args.n_drop, method=args.method, **options)
    if args.output:
        Path(args.output).write_text(text)
        print(f"wrote {args.output}: its optimum is -t*, t* = the design's history[-1].objective")
    else:
        sys.stdout.write(text)
    return EXIT_OK


def _channel_from_args(args):
    from solver.channel import Channel

    if args.loss is not None:
        return Channel.bernoulli(args.loss)
    if args.gilbert_elliott is not None:
        try:
            values = [float(v) for v in args.gilbert_elliott.split(",")]
        except ValueError:
            values = []
        if len(values) != 4:
            raise UsageError("--gilbert-elliott needs four numbers P_GB,P_BG,LOSS_GOOD,LOSS_BAD, got "
                             f"{args.gilbert_elliott!r}")
        return Channel.gilbert_elliott(*values)
    return Channel.from_dict(_read_json(Path(args.channel_file)))


def cmd_channel(args) -> int:
    from solver.channel import analyze_channel, loss_sweep

    if args.plot and Path(args.plot).suffix.lower() not in (".png", ".svg"):
        raise UsageError(f"--plot must end in .png or .svg, got {args.plot!r}")
    fam = load_plant(args.plant, args.sampling_period)
    if args.gains is None and not (args.design and args.n_drop):
        raise UsageError("give --gains FILE (or --design with --n-drop N)")
    gains = None if args.gains is None else load_gains(args.gains)
    n_drop = args.n_drop or len(gains)
    channel = _channel_from_args(args)
    if args.delays is not None:
        channel = channel.with_delays(_numbers(args.delays, "--delays"))
    net = _network(args)
    weights = None if args.no_cost else (np.eye(fam.n_states), np.eye(fam.n_inputs))
    print(plant_summary(fam))
    if args.design:
        from solver.channel import design_channel

        res = design_channel(fam, n_drop, channel, exhausted=args.exhausted, weights=weights)
        print(f"channel design, n_drop = {n_drop}: {res.outcome} ({res.message})")
        if res.gains is None:
            return EXIT_NO
        gains = res.gains
        for q, K in enumerate(gains, start=1):
            print(f"K_{q} = {_fmt_matrix(K)}")
    rep = analyze_channel(fam, gains, n_drop, channel, exhausted=args.exhausted, weights=weights, network=net)
    h = fam.sampling_period
    per = f"{rep.burst_rate / h * 3600:.4g} per hour" if h else f"{rep.burst_rate:.4g} per sample"
    runs = (f"the buffer's age reaching {n_drop} (losses and late packets, delays {list(rep.delays)})"
            if rep.delays is not None else f"runs of >= {n_drop} lost samples")
    print(f"channel: loss fraction {channel.loss_fraction:.4g}; {runs}: {per} "
          f"(mean time between: {rep.mean_time_between_bursts:.4g} samples)")
    if rep.network_violations is not None:
        v = rep.network_violations
        per = f"{v['rate'] / h * 3600:.4g} per hour" if h else f"{v['rate']:.4g} per sample"
        print(f"network {net.describe()}: broken at {per} ({v['what']})")
    verdict = {True: "mean-square stable (certified)", False: "NOT mean-square stable (certified)",
               None: "unknown"}[rep.ms_stable]
    print(f"exhausted = {args.exhausted}: {verdict}; radius {rep.ms_radius:.6g}: {rep.reason}")
    if rep.expected_cost is not None:
        print(f"expected cost (Q = I, R = I, E x0 x0' = I): {rep.expected_cost:.6g} "
              f"in [{rep.expected_cost_lower:.6g}, {rep.expected_cost_upper:.6g}]")
    if args.target_per_hour is not None:
        if not h:
            raise UsageError("--target-per-hour needs a plant with a sampling period")
        best = channel.smallest_n_drop(args.target_per_hour / 3600.0, sampling_period=h, max_n_drop=1000)
        print(f"smallest n_drop with <= {args.target_per_hour:g} bursts per hour: {best}")
    if args.output:
        out = jsonable(rep.to_dict())
        if args.design:
            out = {"gains": jsonable(np.asarray(gains).tolist()), "n_drop": n_drop, "analysis": out}
        Path(args.output).write_text(json.dumps(out) + "\n")
        print(f"wrote {args.output}")
    if args.plot:
        from solver.plotting import channel_figure, render

        sweep = None
        if weights is not None:
            sweep = loss_sweep(fam, gains, n_drop, np.linspace(0.0, 0.9, 10), weights=weights)
        fig = channel_figure(channel, range(1, max(2 * n_drop, 8) + 1), h, sweep)
        Path(args.plot).write_bytes(render(fig, Path(args.plot).suffix[1:].lower()))
        print(f"wrote {args.plot}")
    return EXIT_OK if rep.ms_stable is True else EXIT_NO


COMMANDS = {"design": cmd_design, "analyze": cmd_analyze, "simulate": cmd_simulate, "codegen": cmd_codegen,
            "export-sdpa": cmd_export_sdpa, "channel": cmd_channel}


def run_command(args) -> int:
    """Run a computing command; bad input becomes one line on stderr and exit 2, never a traceback."""
    from solver.errors import InvalidInput, SolverFailed

    try:
        from app.client import JobFailed, ServiceError
    except ImportError:  # pragma: no cover - httpx missing: only --server needs it
        JobFailed = ServiceError = ()  # type: ignore[assignment]
    try:
        return COMMANDS[args.command](args)
    except UsageError as exc:
        print(f"ncs-design {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except InvalidInput as exc:
        where = ".".join(str(f) for f in exc.field)
        print(f"ncs-design {args.command}: invalid input{' (' + where + ')' if where else ''}: {exc}",
              file=sys.stderr)
        return EXIT_USAGE
    except ServiceError as exc:
        one_line = str(exc).replace("\n", ";")
        print(f"ncs-design {args.command}: the service refused the request: {one_line}", file=sys.stderr)
        return EXIT_USAGE if 400 <= exc.status < 500 else EXIT_FAILED
    except JobFailed as exc:
        print(f"ncs-design {args.command}: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except SolverFailed as exc:
        print(f"ncs-design {args.command}: the solver failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except OSError as exc:  # connection refused, unwritable output, ...
        print(f"ncs-design {args.command}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except Exception as exc:
        import httpx

        if isinstance(exc, httpx.HTTPError):
            print(f"ncs-design {args.command}: cannot reach {args.server}: {exc}", file=sys.stderr)
            return EXIT_FAILED
        raise
