"""The library's guards on the analyses (issue 33, item 7): simulate, analyze_channel, critical_loss and analyze
refuse a call whose estimate is over budget before any work, with InvalidInput naming the size, and take
``max_memory=``/``time_limit=`` like design(). Each refused call is checked to allocate almost nothing."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from solver import Channel, InvalidInput, PlantFamily, analyze, analyze_channel, critical_loss, simulate
from solver.workload import channel_operator_size

from .cartpole import cartpole

GAINS_2 = [[[-0.5, -0.2]], [[-0.3, -0.1]]]


def _refused(fn, *args, **kwargs) -> InvalidInput:
    tracemalloc.start()
    try:
        with pytest.raises(InvalidInput) as err:
            fn(*args, **kwargs)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20 * 2**20, f"the refusal came after {peak / 2**20:.0f} MiB were allocated"
    return err.value


def _small_gains(fam, n_drop):
    return np.zeros((n_drop, fam.n_inputs, fam.n_states))


def test_simulate_with_1e8_steps_is_refused_naming_steps():
    fam = PlantFamily.paper_example()
    err = _refused(simulate, fam, GAINS_2, 2, [1.0, 0.0], 10**8, 0)
    assert err.field == ("steps",)
    assert "steps = 100000000" in str(err) and "NCS_SOLVER_MAX_" in str(err), err
    # and a budget of one's own: 10^5 steps are about 10 s by the estimate
    err = _refused(simulate, fam, GAINS_2, 2, [1.0, 0.0], 10**5, 0, time_limit=1.0)
    assert "limit of 1 s (time_limit=)" in str(err), err
    err = _refused(simulate, fam, GAINS_2, 2, [1.0, 0.0], 10**6, 0, max_memory=2**20)
    assert "max_memory=" in str(err) and "memory" in str(err), err
    assert simulate(fam, GAINS_2, 2, [1.0, 0.0], 50, 0, time_limit=1.0).state.shape == (51, 2)


def test_bad_budgets_are_refused_naming_the_option():
    fam = PlantFamily.paper_example()
    for kw in ({"time_limit": 0}, {"time_limit": float("nan")}, {"max_memory": -1}, {"max_memory": "1 GB"}):
        with pytest.raises(InvalidInput) as err:
            simulate(fam, GAINS_2, 2, [1.0, 0.0], 10, 0, **kw)
        assert err.value.field == tuple(kw), err.value


def test_channel_analysis_over_budget_names_the_operator_size():
    fam = cartpole()  # 4 states, 3 modes
    n_drop = 20
    size = channel_operator_size(2, 3, n_drop, 4)
    assert size == 2 * 3 * 21 * 64  # the service's c r (n_drop + 1) (2n)^2
    err = _refused(analyze_channel, fam, _small_gains(fam, n_drop), n_drop, Channel.gilbert_elliott(0.1, 0.3),
                   time_limit=1.0)
    assert err.field == ("channel",)
    assert f"operator of size up to {size}" in str(err) and "time_limit=" in str(err), err
    err = _refused(analyze_channel, fam, _small_gains(fam, n_drop), n_drop, Channel.gilbert_elliott(0.1, 0.3),
                   max_memory=2**20)
    assert "max_memory=" in str(err), err


def test_critical_loss_counts_its_bisection():
    fam = cartpole((0.2, 0.3))  # the reported 58 s case: 4 states, 2 modes
    err = _refused(critical_loss, fam, _small_gains(fam, 5), 5, time_limit=5.0)
    assert "spectral-radius estimates" in str(err) and "operator of size up to" in str(err), err
    with pytest.raises(InvalidInput):
        critical_loss(fam, _small_gains(fam, 5), 5, tol=0.0)


def test_analysis_uses_the_design_estimate():
    fam = cartpole()
    n_drop = 12
    err = _refused(analyze, fam, _small_gains(fam, n_drop), n_drop, bounds="all", time_limit=0.5)
    assert err.field == ("n_drop",)
    text = str(err)
    assert "36 closed-loop modes" in text and "switched certificate has LMI size" in text, text
    assert "limit of 0.5 s (time_limit=)" in text
    # The same call without the switched certificate and bounds fits in a generous budget.
    rep = analyze(PlantFamily.paper_example(), GAINS_2, 2, certificates=("common_quadratic",), bounds="none",
                  time_limit=60.0)
    assert rep.stable in (True, False, None)
