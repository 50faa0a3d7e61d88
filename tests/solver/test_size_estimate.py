"""The one size estimate (issue 29 item 4, issue 33 item 11): :func:`solver.compiled.design_size` of the whole
request, checked against what the designs build (counted blocks, variables, Schur pieces and solves), and the
refusals it drives (before anything is built, naming the dimension that makes the request large).

No timings here: the estimate's error against measured CPU is bench/size_calibration.py's table."""

from __future__ import annotations

import numpy as np
import pytest

from solver import InvalidInput, PlantFamily, design
from solver.compiled import design_path, design_size
from solver.design import request_size
from solver.network import ModeSet

from .textbook import pendulum


def _built_lmi(fam, n_drop, switching="per_interval", scheme="predictive"):
    from solver.ipm.design_blocks import lmi_problem

    modes = ModeSet.from_family(fam, n_drop, plant_switching=switching, scheme=scheme)
    coef, active = modes.scheme_coef()
    return modes, coef, active, lmi_problem(modes.free, coef, active)


@pytest.mark.parametrize("fam, n_drop, switching, scheme", [
    (PlantFamily.paper_example(0.1), 3, "per_interval", "predictive"),
    (PlantFamily.paper_example(0.1), 3, "per_sample", "predictive"),
    (PlantFamily.paper_example(0.1), 4, "per_interval", "hold"),
    (pendulum(), 12, "per_interval", "predictive"),
])
def test_the_plain_estimate_counts_the_blocks_variables_and_schur_pieces_built(fam, n_drop, switching, scheme):
    modes, coef, active, prob = _built_lmi(fam, n_drop, switching, scheme)
    n, m = fam.n_states, fam.n_inputs
    size = design_size("lmi", n, m, fam.n_modes, n_drop, switching, scheme, decay_rate=None)
    nb, k, _ = prob.C.shape
    assert (size.n_modes, size.lmi_size) == (modes.n_modes, nb * k) and k == 2 * n
    sym = n * (n + 1) // 2
    built = sum(sym if v.sym_block else v.size for v in prob.variables) + 1  # + t
    assert size.n_variables == built
    # each block touches W, t and the gains of the samples its interval applies (the active ones)
    touched = [sym + 1 + int(np.count_nonzero(np.any(coef[s] != 0, axis=(1, 2)))) * m * n
               for s in range(modes.n_modes)]
    assert size.schur_entries == sum(v * v for v in touched)


def test_large_n_drop_grows_as_the_counted_work():
    # The Schur pieces (sum of v_b^2 over 2 N blocks of up to N m n gain variables) grow as N^3 and the Schur
    # complement's factorization (p^3, p ~ N m n) too: the estimate per solve follows the counts from n_drop 50
    # to 200 (issue 33: the 200-interval design ran 20 times longer than the old estimate said).
    fam = pendulum()
    sizes = {N: design_size("lmi", 4, 1, 2, N) for N in (50, 100, 200)}
    for a, b in ((50, 100), (100, 200)):
        counted = sizes[b].schur_entries / sizes[a].schur_entries
        assert 7.0 < counted < 9.0
        # faster than the blocks (2x): the assembly's k sum v_b^2 and the factorization's p^3 take over
        assert 2.0 < sizes[b].seconds / sizes[a].seconds <= counted
    modes, coef, active, prob = _built_lmi(fam, 50)
    assert prob.C.shape[0] == sizes[50].n_modes


def test_the_whole_request_picks_its_path_and_counts_its_solves():
    fam = PlantFamily.paper_example(0.1)
    plain = request_size("lmi", fam, 3)
    auto = request_size("lmi", fam, 3, decay_rate="auto")
    best = request_size("lmi", fam, 3, decay_rate="max", rate_tol=1e-3)
    assert (plain.path, auto.path, best.path) == ("plain", "auto", "max")
    assert plain.solves == 1 and best.solves == int(np.ceil(np.log2(1e3))) + 2
    assert auto.total_seconds > plain.total_seconds and best.total_seconds > plain.total_seconds
    assert design_path("ccl", decay_rate="auto") == "ccl"
    assert design_path(objective="cost", decay_rate="auto") == "cost"
    assert design_path(u_max=[1.0]) == "u_max"


@pytest.mark.parametrize("objective, extra", [
    ("cost", {}),
    ("hinf", {"disturbance": "ones"}),
    ("stability", {"u_max": "ones"}),
])
@pytest.mark.parametrize("fam, N", [(PlantFamily.paper_example(0.1), 3), (pendulum(), 5)])
def test_the_performance_estimate_counts_the_blocks_the_ipm_solves(objective, extra, fam, N):
    # design_size models the IPM's compact, merged groups (solver/ipm/performance_blocks.py) from the sizes alone:
    # the sides and counts, summed, and the variables equal the built problem's
    from solver.methods.performance import block_sides, prepare
    from solver.ipm.performance_blocks import performance_problem

    extra = {key: np.ones((fam.n_states, 1)) if key == "disturbance" else np.ones(fam.n_inputs) for key in extra}
    modes = ModeSet.from_family(fam, N)
    lifted, x0, u_max = prepare(modes, "lmi", objective, None, None, extra.get("disturbance"), None,
                                extra.get("u_max"), None)
    size = request_size("lmi", fam, N, objective=objective, **extra)
    compact = performance_problem(lifted, objective, x0, u_max)
    assert size.lmi_size == sum(g.C.shape[0] * g.C.shape[1] for g in compact.lmi.groups_spec)
    assert size.n_variables == len(compact.lmi.b)
    # the lifted form's blocks (the IPM's compact, merged groups are no larger: docs/design.md §8.3.1)
    prob = performance_problem(lifted, objective, x0, u_max, compact=False, merge=False)
    lifted_groups = [g for g in prob.lmi.groups_spec if g.name.startswith(("cost_eta", "hinf_eta", "stability"))]
    assert sum(g.C.shape[0] * g.C.shape[1] for g in lifted_groups) == sum(block_sides(lifted, objective))
    kinds = ("cost", "hinf", "stability")
    assert sum(g.C.shape[0] * g.C.shape[1] for g in compact.lmi.groups_spec if g.name.startswith(kinds)) <= \
        sum(block_sides(lifted, objective))
    inputs = N * fam.n_inputs if "u_max" in extra else 0
    assert sum(g.C.shape[0] for g in prob.lmi.groups_spec if g.name == "input") == inputs


PATH_REQUESTS = {"plain": {"decay_rate": None}, "rate": {"decay_rate": 0.9}, "auto": {"decay_rate": "auto"},
                 "max": {"decay_rate": "max"},
                 "cost": {"objective": "cost"}, "hinf": {"objective": "hinf"}, "u_max": {"u_max": [1.0]},
                 "switched": {"method": "switched", "decay_rate": None}, "ccl": {"method": "ccl"}}


@pytest.mark.parametrize("path", sorted(PATH_REQUESTS))
def test_every_path_s_estimate_is_finite_positive_and_grows_with_n(path):
    # bench/size_calibration.py measures the error; here only what holds whatever the constants: every path's time
    # and memory are finite and positive, and more states never cost less (r = 5, m = 2, n_drop = 10, n = 2..60)
    kw = dict(PATH_REQUESTS[path])
    method = kw.pop("method", "lmi")
    last = None
    for n in (2, 4, 8, 12, 20, 30, 45, 60):
        size = design_size(method, n, 2, 5, 10 if method != "switched" else 3, **kw)
        assert size.path == path
        for value in (size.total_seconds, size.seconds, size.memory, size.step_seconds):
            assert np.isfinite(value) and value > 0, (path, n, size)
        assert size.total_seconds > size.search_seconds
        if last is not None:
            assert size.total_seconds > last.total_seconds and size.memory >= last.memory, (path, n)
        last = size


def test_the_lower_bound_search_is_counted_for_the_brackets_only():
    from solver.compiled import lower_bound_work

    for path in ("cost", "hinf"):
        size = design_size("lmi", 8, 2, 5, 10, objective=path)
        flops, memory = lower_bound_work(path, 8, size.n_modes, 10, 1, 10)
        assert size.search_seconds > 0 and flops > 0 and memory > 0 and size.memory >= memory
    assert design_size("lmi", 8, 2, 5, 10, u_max=[1.0]).search_seconds == 0.0
    assert design_size("lmi", 8, 2, 5, 10).search_seconds == 0.0


def _nothing_built(monkeypatch):
    import solver.methods.performance as perf
    import solver.network as net

    def built(*args, **kwargs):
        raise AssertionError("the design was built before the refusal")

    monkeypatch.setattr(net, "gain_map", built)  # the first array a ModeSet builds (n_drop x n_drop)
    monkeypatch.setattr(perf, "lift_modes", built)


def test_n_drop_10000_is_refused_before_the_modes_are_built_naming_n_drop(monkeypatch):
    _nothing_built(monkeypatch)
    with pytest.raises(InvalidInput) as err:
        design(pendulum(), 10000)
    assert err.value.field == ("n_drop",) and "n_drop = 10000" in str(err.value), str(err.value)
    # under the mode limit the estimate refuses, naming n_drop and the path whose solves it counted
    with pytest.raises(InvalidInput) as err:
        design(pendulum(), 2000, max_memory=1e15)
    text = str(err.value)
    assert err.value.field == ("n_drop",) and "n_drop = 2000 makes it large" in text, text
    assert "4000 closed-loop modes" in text and "auto path" in text


def test_a_performance_design_too_large_is_refused_before_lifting(monkeypatch):
    _nothing_built(monkeypatch)
    with pytest.raises(InvalidInput) as err:
        design(pendulum(), 400, objective="cost")
    assert err.value.field == ("n_drop",) and "(cost path, 4 states" in str(err.value), str(err.value)


def test_states_are_named_when_they_make_the_design_large(monkeypatch):
    _nothing_built(monkeypatch)
    n = 200
    fam = PlantFamily([0.5 * np.eye(n)] * 2, [np.ones((n, 1))] * 2)
    with pytest.raises(InvalidInput) as err:
        design(fam, 3)
    text = str(err.value)
    assert err.value.field == ("F",) and "the 200 states make it large" in text and "n_drop = 3 makes" not in text


def test_a_design_for_a_channel_counts_its_analysis_and_names_the_channel(monkeypatch):
    import sys

    from solver.channel import Channel, design_for_channel
    from solver.workload import channel_operator_size

    fam, ch = pendulum(), Channel.gilbert_elliott(0.05, 0.5, 0.0, 0.9)
    N = ch.smallest_n_drop(1e-4, max_n_drop=50)
    size = channel_operator_size(ch.n_states, fam.n_modes, N, fam.n_states)
    plain = request_size("lmi", fam, N)
    both = request_size("lmi", fam, N, channel_size=size)
    assert both.channel_size == size == ch.n_states * fam.n_modes * (N + 1) * (2 * fam.n_states) ** 2
    assert both.total_seconds == pytest.approx(plain.total_seconds + both.channel_seconds)
    assert both.memory == max(plain.memory, both.channel_memory)
    # a budget between the design's memory and the analysis's refuses before the design runs, naming the channel
    monkeypatch.setattr(sys.modules["solver.design"], "design",
                        lambda *a, **k: (_ for _ in ()).throw(AssertionError("designed before the refusal")))
    assert plain.memory < both.channel_memory
    with pytest.raises(InvalidInput) as err:
        design_for_channel(fam, ch, 1e-4, per="sample", max_memory=(plain.memory + both.channel_memory) / 2)
    assert err.value.field == ("channel",) and f"operator of size up to {size}" in str(err.value), str(err.value)


@pytest.mark.parametrize("path", sorted(PATH_REQUESTS))
def test_astronomical_per_sample_counts_are_refused_not_raised(path):
    # per-sample switching over 1000 samples: 3^1000 loop modes, beyond a float; the estimate saturates and refuses
    kw = dict(PATH_REQUESTS[path])
    method = kw.pop("method", "lmi")
    size = design_size(method, 4, 1, 3, 1000, "per_sample", **kw)
    assert size.total_seconds >= 1e290 and size.memory >= 1e290
    with pytest.raises(InvalidInput):
        size.check()
