"""The IPM-vs-Clarabel cross-check of the performance designs (bench/perf_check.py) on a bounded sample."""

from __future__ import annotations

import numpy as np
import pytest

from bench import perf_check


def test_ipm_and_clarabel_agree_on_a_seeded_sample():
    lines = []
    tallies = perf_check.run(10, objectives=perf_check.OBJECTIVES, out=lines.append)
    text = "\n".join(lines)
    for obj, t in tallies.items():
        assert t.compared + t.unavailable == 10, (obj, text)
        # every compared pair agrees, or the IPM's certified figure is the better one (Clarabel stopped short)
        assert t.within + t.ipm_better == t.compared, text
        if t.unavailable:
            assert f"IPM not available for objective {obj}" in text
    assert "| hinf |" in text


def test_the_harness_reports_a_disagreement(monkeypatch):
    """A wrong IPM answer (here: the figure scaled by 1 + 1e-3, then the verdict flipped) is reported, not hidden."""
    from solver import design as real_design

    def fake(fam, n_drop, solver="AUTO", **kw):
        res = real_design(fam, n_drop, solver="CLARABEL", **kw)
        if solver == "IPM":
            res.solver = "IPM"
            if res.performance is not None and res.performance.upper is not None:
                res.performance.upper *= 1 + 1e-3
                res.performance.certificate_upper *= 1 + 1e-3
            else:
                res.outcome = "flipped"
        return res

    monkeypatch.setattr("solver.design", fake)
    lines = []
    tallies = perf_check.run(2, objectives=("cost (trace)",), out=lines.append)
    t = tallies["cost (trace)"]
    assert t.compared == 2 and t.within == 0 and t.ipm_better == 0
    assert any(line.startswith("worst (cost (trace))") for line in lines)
    assert all(rel > 1e-6 for rel, _ in t.worst)


@pytest.mark.parametrize("seed", [0, 7])
def test_draw_is_seeded_and_small(seed):
    fam, N, x0, u_max, _ = perf_check.draw(seed)
    assert u_max.shape == (fam.n_inputs,) and np.all(u_max > 0)
    again = perf_check.draw(seed)
    assert np.array_equal(np.asarray(fam.F), np.asarray(again[0].F)) and N == again[1]
    assert 2 <= fam.n_states <= 4 and 1 <= fam.n_modes <= 3 and 1 <= N <= 4 and x0.shape == (fam.n_states,)


def test_the_input_limited_cost_design_runs_on_the_ipm():
    """Seed 10 (one plant mode, n_drop 1): every factor of a block group is a shared selector (it once raised)."""
    from solver import design

    fam, N, x0, u_max, _ = perf_check.draw(10)
    res = design(fam, N, solver="IPM", **perf_check.request("u_max + cost", fam, x0, u_max))
    assert str(res.solver).upper() == "IPM"
