"""Checks beyond the JSON schema: matrix shapes, family consistency and the
configured size limits. Each error names the field by pydantic ``loc`` and
JSON pointer. Run before a job row is written, so bad input never leaves one.
"""

from __future__ import annotations

from typing import Any

from app.api.problems import field_error, invalid
from app.settings import Settings
from solver.compiled import design_size
from solver.design import performance_dims
from solver.errors import InvalidInput
from solver.network import mode_count  # noqa: F401 (re-exported: the service's name for it)


class Shape:
    def __init__(self, r: int, n: int, m: int):
        self.r, self.n, self.m = r, n, m


def _matrix_shape(mat: list[list[float]], loc: list, errors: list) -> tuple[int, int] | None:
    if len(mat) == 0:
        errors.append(field_error(loc, "matrix has no rows", "matrix_empty"))
        return None
    cols = len(mat[0])
    if cols == 0:
        errors.append(field_error(loc + [0], "matrix row is empty", "matrix_empty"))
        return None
    for i, row in enumerate(mat):
        if len(row) != cols:
            errors.append(field_error(loc + [i], f"row {i} has {len(row)} entries, row 0 has {cols}",
                                      "matrix_ragged"))
            return None
    return len(mat), cols


def _pair_family(plant: Any, names: tuple[str, str], base: list, errors: list) -> Shape | None:
    a_name, b_name = names
    As, Bs = getattr(plant, a_name), getattr(plant, b_name)
    if len(As) == 0:
        errors.append(field_error(base + [a_name], "the family is empty: give at least one mode", "family_empty"))
    if len(Bs) == 0:
        errors.append(field_error(base + [b_name], "the family is empty: give at least one mode", "family_empty"))
    if errors:
        return None
    if len(As) != len(Bs):
        errors.append(field_error(base + [b_name], f"{b_name} has {len(Bs)} modes but {a_name} has {len(As)}",
                                  "family_mismatch"))
        return None
    n = m = None
    for l, (a, b) in enumerate(zip(As, Bs)):
        sa = _matrix_shape(a, base + [a_name, l], errors)
        sb = _matrix_shape(b, base + [b_name, l], errors)
        if sa is None or sb is None:
            continue
        if sa[0] != sa[1]:
            errors.append(field_error(base + [a_name, l], f"{a_name}[{l}] must be square, got {sa[0]} x {sa[1]}",
                                      "matrix_not_square"))
            continue
        if n is None:
            n = sa[0]
        elif sa[0] != n:
            errors.append(field_error(base + [a_name, l], f"{a_name}[{l}] is {sa[0]} x {sa[0]} but mode 0 has "
                                      f"n = {n} states: all modes need the same n", "family_mismatch"))
            continue
        if sb[0] != sa[0]:
            errors.append(field_error(base + [b_name, l], f"{b_name}[{l}] has {sb[0]} rows, {a_name}[{l}] has "
                                      f"{sa[0]}", "matrix_mismatch"))
            continue
        if m is None:
            m = sb[1]
        elif sb[1] != m:
            errors.append(field_error(base + [b_name, l], f"{b_name}[{l}] has {sb[1]} columns but mode 0 has "
                                      f"m = {m} inputs: all modes need the same m", "family_mismatch"))
    if errors or n is None or m is None:
        return None
    return Shape(len(As), n, m)


def plant_shape(plant: Any, settings: Settings, errors: list) -> Shape | None:
    base = ["body", "plant"]
    if plant.kind == "continuous":
        shape = _pair_family(plant, ("A", "B"), base, errors)
        fam_field = "A"
    elif plant.kind == "discrete":
        shape = _pair_family(plant, ("F", "G"), base, errors)
        fam_field = "F"
    else:
        shape = Shape(len(plant.inertias), 2, 1)
        fam_field = "inertias"
    if shape is None:
        return None
    if shape.n > settings.max_states:
        errors.append(field_error(base + [fam_field], f"n = {shape.n} states is over the limit of "
                                  f"{settings.max_states} (NCS_MAX_STATES)", "limit_exceeded"))
    if shape.m > settings.max_inputs:
        errors.append(field_error(base + ["B" if fam_field == "A" else "G"], f"m = {shape.m} inputs is over the "
                                  f"limit of {settings.max_inputs} (NCS_MAX_INPUTS)", "limit_exceeded"))
    if shape.r > settings.max_modes:
        errors.append(field_error(base + [fam_field], f"r = {shape.r} plant modes is over the limit of "
                                  f"{settings.max_modes} (NCS_MAX_MODES)", "limit_exceeded"))
    return shape


def lmi_size(method: str, n: int, r: int, n_drop: int, plant_switching: str = "per_interval") -> int:
    """Sum of the block sizes of all matrix inequalities of a design (:func:`solver.compiled.design_size`)."""
    return design_size(method, n, 1, r, n_drop, plant_switching).lmi_size


def check_size(method: str, shape: Shape, n_drop: int, options: Any, settings: Settings, loc: list,
               errors: list, network: Any = None, req: Any = None) -> None:
    """The library's estimate of the whole request (:func:`solver.compiled.design_size`: the path its
    ``decay_rate``, ``objective`` and ``u_max`` take, on a ``network`` its automaton nodes times the plant
    modes) against the service's budgets: LMI size, worker memory, job time."""
    switching = options.plant_switching
    scheme = getattr(options, "scheme", None) or "predictive"
    pw, pz = performance_dims(getattr(req, "disturbance", None), _output_pair(getattr(req, "output", None)))
    size = design_size(method, shape.n, shape.m, shape.r, n_drop, switching, scheme,
                       getattr(options, "solver", None) or "AUTO", network=network,
                       objective=getattr(req, "objective", None) or "stability",
                       decay_rate=getattr(options, "decay_rate", None), u_max=getattr(req, "u_max", None),
                       n_disturbances=pw, n_outputs=pz,
                       channel_size=channel_size(req.channel, shape, n_drop) if getattr(req, "channel", None) else 0)
    if size.lmi_size > settings.max_lmi_size:
        errors.append(field_error(loc, f"at n_drop = {n_drop} the {method} design has total LMI size "
                                  f"{size.lmi_size} (n = {shape.n}, r = {shape.r}, {switching} switching), over "
                                  f"the limit of {settings.max_lmi_size} (NCS_MAX_LMI_SIZE)", "limit_exceeded"))
        return
    try:
        size.check(settings.worker_memory_mb * 2**20, settings.job_time_limit,
                   memory_name="NCS_WORKER_MEMORY_MB", seconds_name="NCS_JOB_TIME_LIMIT")
    except InvalidInput as err:
        errors.append(field_error(loc, str(err), "limit_exceeded"))


def _output_pair(output: Any) -> Any:
    """A request's ``output`` ({C, D} model or None) as the library's ``(C, D)``."""
    return None if output is None else (getattr(output, "C", None), getattr(output, "D", None))


def check_n_drop(n_drop: int, settings: Settings, errors: list) -> None:
    if n_drop > settings.max_n_drop:
        errors.append(field_error(["body", "n_drop"], f"n_drop = {n_drop} is over the limit of "
                                  f"{settings.max_n_drop} (NCS_MAX_N_DROP)", "limit_exceeded"))


def check_family_request(body: Any, settings: Settings, errors: list) -> Shape | None:
    """The checks every request carrying a plant family and an optional ``n_drop`` starts with."""
    shape = plant_shape(body.plant, settings, errors)
    if body.n_drop is not None:
        check_n_drop(body.n_drop, settings, errors)
    return shape


def check_design(req: Any, settings: Settings, network: Any = None) -> Shape:
    errors: list = []
    shape = plant_shape(req.plant, settings, errors)
    check_n_drop(req.n_drop, settings, errors)
    if shape is not None and not errors:
        check_size(req.method, shape, req.n_drop, req.options, settings,
                   ["body", "n_drop" if network is None else "network"], errors, network=network, req=req)
        if req.options.decay_rate not in (None, "auto") and req.method == "ccl":
            errors.append(field_error(["body", "options", "decay_rate"], "decay_rate is available for the lmi "
                                      "and switched methods, not ccl", "unsupported_option"))
    if errors:
        raise invalid(errors)
    assert shape is not None
    return shape


#: Largest number of points of a grid job.
MAX_GRID_POINTS = 200


def check_margin(req: Any, settings: Settings) -> int:
    """Validate a margin job; returns the largest n_drop it will design for."""
    errors: list = []
    shape = plant_shape(req.plant, settings, errors)
    if req.search in ("sampling_period", "grid") and req.plant.kind == "discrete":
        errors.append(field_error(["body", "plant", "kind"], f"a {req.search} search rediscretizes the plant: "
                                  "give a continuous or dc_motor plant", "needs_continuous_plant"))
    if req.search == "n_drop":
        largest = req.n_drop_max
        if req.n_drop_max > settings.max_n_drop:
            errors.append(field_error(["body", "n_drop_max"], f"n_drop_max = {req.n_drop_max} is over the limit "
                                      f"of {settings.max_n_drop} (NCS_MAX_N_DROP)", "limit_exceeded"))
    elif req.search == "sampling_period":
        largest = req.n_drop or 0
        if req.n_drop is None:
            errors.append(field_error(["body", "n_drop"], "a sampling_period search needs n_drop", "missing"))
        else:
            check_n_drop(req.n_drop, settings, errors)
        if not req.h_min < req.h_max:
            errors.append(field_error(["body", "h_max"], "h_max must be larger than h_min", "range"))
        elif not req.tol < req.h_max - req.h_min:
            errors.append(field_error(["body", "tol"], "tol must be below h_max - h_min", "range"))
        elif (req.h_max - req.h_min) / req.tol > 2**30:
            errors.append(field_error(["body", "tol"], "tol is too small for this interval", "range"))
    else:
        points = req.points or []
        largest = max((p.n_drop for p in points), default=0)
        if not points:
            errors.append(field_error(["body", "points"], "a grid needs at least one (sampling_period, n_drop) "
                                      "point", "missing"))
        elif len(points) > MAX_GRID_POINTS:
            errors.append(field_error(["body", "points"], f"{len(points)} points, at most {MAX_GRID_POINTS}",
                                      "limit_exceeded"))
        elif largest > settings.max_n_drop:
            errors.append(field_error(["body", "points"], f"n_drop = {largest} is over the limit of "
                                      f"{settings.max_n_drop} (NCS_MAX_N_DROP)", "limit_exceeded"))
    if req.options.decay_rate not in (None, "auto"):
        errors.append(field_error(["body", "options", "decay_rate"], "margin jobs search stability margins; "
                                  "decay_rate is a design option", "unsupported_option"))
    if shape is not None and not errors:
        loc = {"n_drop": "n_drop_max", "sampling_period": "n_drop", "grid": "points"}[req.search]
        check_size(req.method, shape, largest, req.options, settings, ["body", loc], errors)
    if errors:
        raise invalid(errors)
    return largest


def check_gains(gains: list, n_drop: int | None, shape: Shape, errors: list, loc: list | None = None) -> int:
    loc = loc or ["body", "gains"]
    if len(gains) == 0:
        errors.append(field_error(loc, "give n_drop gain matrices K_1..K_N", "gains_empty"))
        return 0
    if n_drop is not None and len(gains) != n_drop:
        errors.append(field_error(loc, f"{len(gains)} gain matrices given but n_drop = {n_drop}",
                                  "gains_mismatch"))
    for q, K in enumerate(gains):
        s = _matrix_shape(K, loc + [q], errors)
        if s is not None and s != (shape.m, shape.n):
            errors.append(field_error(loc + [q], f"K_{q + 1} is {s[0]} x {s[1]}, expected m x n = "
                                      f"{shape.m} x {shape.n}", "matrix_mismatch"))
    return n_drop if n_drop is not None else len(gains)


def check_x0(x0: list, shape: Shape, errors: list, loc: list) -> None:
    if len(x0) != shape.n:
        errors.append(field_error(loc, f"x0 has {len(x0)} entries, the plant has n = {shape.n} states",
                                  "vector_mismatch"))


def check_mode(mode: int | None, shape: Shape, errors: list, loc: list) -> None:
    if mode is not None and mode >= shape.r:
        errors.append(field_error(loc, f"mode {mode} does not exist: the plant has {shape.r} modes (0-based)",
                                  "mode_out_of_range"))


def check_steps(steps: int, settings: Settings, errors: list, loc: list) -> None:
    if steps > settings.max_simulation_steps:
        errors.append(field_error(loc, f"steps = {steps} is over the limit of {settings.max_simulation_steps} "
                                  "(NCS_MAX_SIMULATION_STEPS)", "limit_exceeded"))


PLANT_FIELDS = {"A", "B", "F", "G", "sampling_period", "inertias", "resistance", "inductance",
                "torque_constant", "back_emf_constant", "damping", "kind", "family", "state_names",
                "input_names", "units", "name", "mode_names", "C"}


def solver_field_error(field: tuple, message: str, plant: dict[str, Any] | None = None,
                       loc_base: list | None = None) -> dict[str, Any]:
    """Map a solver ``InvalidInput.field`` to a request location.

    Plant fields go under ``/plant``; for a ``dc_motor`` plant the solver's
    per-mode matrices (``("A", l)``) are the ``l``-th inertia.
    """
    field = tuple(field or ())
    if field and field[0] in PLANT_FIELDS:
        if plant is not None and plant.get("kind") == "dc_motor" and field[0] in ("A", "B", "F", "G", "family"):
            field = ("inertias", *field[1:2])
        return field_error(["body", "plant", *field], message, "solver_invalid_input")
    return field_error([*(loc_base or ["body"]), *field], message, "solver_invalid_input")


def check_performance(req: dict[str, Any], settings: Settings, network: Any = None) -> None:
    """The solver's checks of a design request's performance fields (docs/design.md §8; on a ``network`` other than
    bounded drops, §11.3's) and the size of their LMI blocks against ``NCS_MAX_LMI_SIZE``; 422 naming the field."""
    if req.get("objective", "stability") == "stability" and all(
            req.get(k) is None for k in ("weights", "x0", "disturbance", "output", "u_max")):
        return
    from solver import InvalidInput

    from app.compute.tasks import check_performance_inputs

    try:
        if network is not None and not network.is_bounded_drops:
            from app.compute.tasks import check_network_performance_inputs

            check_network_performance_inputs(req["plant"], req, network)
        size = check_performance_inputs(req["plant"], req)
    except InvalidInput as exc:
        field = tuple(getattr(exc, "field", ()))
        if field[:1] == ("weights",) and len(field) > 1:
            field = ("weights", "QR"[field[1]]) + field[2:]
        elif field[:1] == ("output",) and len(field) > 1:
            field = ("output", "CD"[field[1]]) + field[2:]
        elif field[:1] in (("decay_rate",),):
            field = ("options",) + field
        raise invalid([solver_field_error(field, str(exc), req["plant"])]) from None
    if size > settings.max_lmi_size:
        raise invalid([field_error(["body", "objective"], f"the {req.get('objective')} design has total LMI size "
                                   f"{size}, over the limit of {settings.max_lmi_size} (NCS_MAX_LMI_SIZE)",
                                   "limit_exceeded")])


def check_feedback(req: dict[str, Any]) -> None:
    """Output feedback's fields (the plant's C, sensor_n_drop, noise) checked by the solver before a job is made."""
    if req.get("feedback", "state") == "state" and req.get("sensor_n_drop") is None and req.get("noise") is None:
        return
    from solver import InvalidInput
    from solver.observer import prepare_output_design

    from app.compute.tasks import build_family

    try:
        if req.get("feedback", "state") == "state":
            raise InvalidInput("sensor_n_drop and noise apply to output feedback: send \"feedback\": \"output\"",
                               ("sensor_n_drop" if req.get("sensor_n_drop") is not None else "noise",))
        noise = req.get("noise")
        prepare_output_design(build_family(req["plant"]), req["n_drop"], req.get("sensor_n_drop"),
                              req.get("observer", "per_mode"), None if noise is None else (noise["W"], noise["V"]))
    except InvalidInput as exc:
        raise invalid([solver_field_error(tuple(getattr(exc, "field", ())), str(exc), req["plant"])]) from None


def channel_size(channel: Any, shape: Shape, n_drop: int) -> int:
    """Upper bound on the second-moment operator's size of a channel analysis."""
    states = {"bernoulli": 1, "gilbert_elliott": 2}.get(channel.kind) or len(channel.loss)
    # Late packets: the chain remembers the states of the last W samples, the state W + 1 past x's.
    window = max(len(getattr(channel, "delays", None) or [1.0]) - 1, 1)
    return states ** window * shape.r * (n_drop + 1) * ((window + 1) * shape.n) ** 2


def check_channel_size(channel: Any, shape: Shape, n_drop: int, settings: Settings, errors: list) -> None:
    """The second-moment operator of a channel analysis against ``NCS_MAX_CHANNEL_SIZE``."""
    size = channel_size(channel, shape, n_drop)
    if size > settings.max_channel_size:
        errors.append(field_error(["body", "channel"], f"the channel analysis has an operator of size up to {size}, "
                                  f"over the limit of {settings.max_channel_size} (NCS_MAX_CHANNEL_SIZE)",
                                  "limit_exceeded"))


def check_design_channel(req: Any, shape: Shape, settings: Settings) -> None:
    """A design request's channel: its size, and the solver's own checks (a row that does not sum to 1, ...)."""
    if req.channel is None:
        return
    errors: list = []
    check_channel_size(req.channel, shape, req.n_drop, settings, errors)
    if errors:
        raise invalid(errors)
    from solver import InvalidInput

    from app.compute.tasks import channel_from_request

    try:
        channel_from_request(req.channel.model_dump())
    except InvalidInput as exc:
        raise invalid([solver_field_error(getattr(exc, "field", ()), str(exc))]) from None


def check_with_solver(plant: dict[str, Any], n_drop: int | None = None, plant_switching: str = "per_interval",
                      scheme: str = "predictive") -> None:
    """What the solver library itself checks before a design, run before a job exists: the family (the
    zero-order hold of a continuous plant) and, given ``n_drop``, its closed-loop modes (``F^n_drop`` of a
    discrete plant with entries near 1e308 overflows). A rejection is a 422 naming the field."""
    from solver import InvalidInput

    from app.compute.tasks import check_design_inputs
    from app.jobs.store import canonical_json

    try:
        check_design_inputs(canonical_json(plant), n_drop, plant_switching, scheme)
    except InvalidInput as exc:
        raise invalid([solver_field_error(getattr(exc, "field", ()), str(exc), plant)]) from None


def check_network(body: Any, errors: list, function: str | None = None, sets_n_drop: bool = True,
                  settings: Settings | None = None) -> Any:
    """A request's ``network``: the solver's own checks (reachability, ages, ``max_delay <= n_drop - 1``, ...)
    as 422s under ``/network/...``; its ``n_drop`` becomes the request's (an explicit, different ``n_drop`` is
    an error); and, for ``function`` (``design``, ``analyze``, ``simulate``), whether this solver takes it.
    Returns the :class:`solver.Network` or None."""
    if getattr(body, "network", None) is None:
        return None
    from app.compute.tasks import network_from_request, network_kwargs

    given = getattr(body.network, "n_drop", None)
    if settings is not None and given is not None and given > settings.max_n_drop:
        # before the automaton is built: its size grows with n_drop
        errors.append(field_error(["body", "network", "n_drop"], f"n_drop = {given} is over the limit of "
                                  f"{settings.max_n_drop} (NCS_MAX_N_DROP)", "limit_exceeded"))
        return None
    try:
        net = network_from_request(body.network.model_dump())
        if function is not None:
            network_kwargs(function, net)
    except InvalidInput as exc:
        errors.append(solver_field_error(getattr(exc, "field", ()), str(exc)))
        return None
    if sets_n_drop:
        given = body.n_drop if "n_drop" in body.model_fields_set else None
        if given is not None and given != net.n_drop:
            errors.append(field_error(["body", "n_drop"], f"n_drop = {given} disagrees with the network's n_drop = "
                                      f"{net.n_drop} ({net.describe()}): give one of them", "network_mismatch"))
        else:
            body.n_drop = net.n_drop
    return net
