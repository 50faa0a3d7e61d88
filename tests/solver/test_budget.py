"""The size guard: a design whose estimated memory or time is over budget is refused before anything is built
(issue 22, item 1: a cart-pole with n_drop = 1000 grew to 21.5 GB before the kernel killed it)."""

from __future__ import annotations

import tracemalloc

import pytest

import importlib
from solver import InvalidInput, design
from solver import compiled
from solver.compiled import MAX_SOLVER_MEMORY, design_size

design_module = importlib.import_module("solver.design")

from .cartpole import cartpole


def test_cartpole_with_n_drop_1000_is_refused_before_anything_is_built(monkeypatch):
    def no_modes(*args, **kwargs):
        raise AssertionError("the mode set was built: the guard came too late")

    monkeypatch.setattr(design_module.ModeSet, "from_family", no_modes)
    with pytest.raises(InvalidInput) as err:
        design(cartpole(), n_drop=1000)
    assert err.value.field == ("n_drop",)
    text = str(err.value)
    # names the size (modes, LMI size, memory) and the limit with its override
    assert "3000 closed-loop modes" in text and "LMI size 24000" in text
    assert "GiB of solver memory" in text and "limit of 4 GiB" in text and "NCS_SOLVER_MAX_MEMORY" in text


def test_the_time_estimate_refuses_a_long_bisection_unless_a_time_limit_is_given(monkeypatch):
    fam = cartpole()
    size = design_size("lmi", 4, 1, 3, 280)
    assert size.memory < MAX_SOLVER_MEMORY  # memory alone would let it through
    monkeypatch.setattr(design_module.ModeSet, "from_family", lambda *a, **k: (_ for _ in ()).throw(KeyError))
    # a budget under the calibrated estimate of this bisection (bench/size_calibration.py; 30-60 s) and above the
    # one-SDP design's
    best = design_size("lmi", 4, 1, 3, 280, decay_rate="max").total_seconds
    budget = round(0.6 * best)
    assert design_size("lmi", 4, 1, 3, 280, decay_rate=None).total_seconds < budget
    monkeypatch.setattr(compiled, "MAX_SOLVER_SECONDS", float(budget))
    with pytest.raises(InvalidInput, match=f"would take about .* s .* over the limit of {budget} s"):
        design(fam, n_drop=280, decay_rate="max")
    with pytest.raises(KeyError):  # a time_limit bounds the time: the guard lets it through to ModeSet
        design(fam, n_drop=280, decay_rate="max", time_limit=10)
    with pytest.raises(InvalidInput, match="limit of 1 MiB"):  # the memory budget is overridable both ways
        design(fam, n_drop=280, time_limit=10, max_memory=2**20)


def test_memory_estimate_matches_the_measured_peak():
    """Independent reference: tracemalloc's peak of numpy allocations during the real design."""
    fam = cartpole()
    design(fam, n_drop=3)  # warm caches
    for n_drop in (40, 60):
        tracemalloc.start()
        res = design(fam, n_drop=n_drop, decay_rate=None)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        # under "AUTO" the IPM's failure falls back to Clarabel (through cvxpy): the peak is then that solver's
        estimate = design_size("lmi", 4, 1, 3, n_drop, solver=res.solver).memory
        assert estimate / 3 < peak < 3 * estimate, (n_drop, peak, estimate)


def test_the_service_and_the_library_share_one_estimate():
    from app.api import validation

    for method in ("lmi", "ccl", "switched"):
        for switching in ("per_interval", "per_sample"):
            assert validation.lmi_size(method, 3, 2, 4, switching) == design_size(method, 3, 1, 2, 4,
                                                                                 switching).lmi_size
    # the closed forms the service documented (NCS_MAX_LMI_SIZE): 2 n M, 2 n N (M + 1), 2 n M^2
    n, r, N = 3, 2, 4
    M = r * N
    assert [design_size(k, n, 1, r, N).lmi_size for k in ("lmi", "ccl", "switched")] == [
        2 * n * M, 2 * n * N * (M + 1), 2 * n * M**2]
