"""The SDPA export re-solved by cvxpy (Clarabel) through a reader written here, against design's t*."""

from __future__ import annotations

import warnings

import cvxpy as cp
import numpy as np
import pytest

from solver import InvalidInput, PlantFamily, design, export_sdpa


def read_sdpa(text: str):
    """``(c, F)`` of an SDPA sparse file: ``F[i][b]`` dense symmetric blocks, ``i = 0`` is F_0."""
    lines = [ln for ln in text.splitlines() if ln.strip() and ln[0] not in '"*']

    def numbers(line):
        return line.replace(",", " ").replace("{", " ").replace("}", " ").replace("(", " ").replace(")", " ").split()

    m = int(numbers(lines[0])[0])
    nblock = int(numbers(lines[1])[0])
    sizes = [abs(int(v)) for v in numbers(lines[2])[:nblock]]
    c = np.array([float(v) for v in numbers(lines[3])[:m]])
    F = [[np.zeros((k, k)) for k in sizes] for _ in range(m + 1)]
    for line in lines[4:]:
        i, b, r, col, v = numbers(line)[:5]
        M = F[int(i)][int(b) - 1]
        M[int(r) - 1, int(col) - 1] = M[int(col) - 1, int(r) - 1] = float(v)
    return c, F


def resolve(text: str) -> float:
    c, F = read_sdpa(text)
    x = cp.Variable(len(c))
    cons = []
    for b in range(len(F[0])):
        expr = sum(x[i] * F[i + 1][b] for i in range(len(c)) if np.any(F[i + 1][b])) - F[0][b]
        cons.append(0.5 * (expr + expr.T) >> 0)
    prob = cp.Problem(cp.Minimize(c @ x), cons)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        prob.solve(solver=cp.CLARABEL)
    # Clarabel reports the switched SDPs "inaccurate" on design's own cvxpy problem too; the value is still
    # compared below with the structured solver's t*.
    assert prob.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE)
    return prob.value


def badly_scaled():
    fam = PlantFamily.paper_example(0.1)
    T = np.diag([1.0, 1e-4])  # volts next to tenths of a milli-unit
    return PlantFamily(F=[np.linalg.inv(T) @ F @ T for F in fam.F], G=[np.linalg.inv(T) @ G * 1e3 for G in fam.G])


CASES = [
    ("paper lmi", lambda: PlantFamily.paper_example(0.1), 3, {"method": "lmi", "decay_rate": None}),
    ("paper lmi rate", lambda: PlantFamily.paper_example(0.1), 3, {"method": "lmi", "decay_rate": 0.9}),
    ("paper lmi hold", lambda: PlantFamily.paper_example(0.2), 3, {"method": "lmi", "scheme": "hold", "decay_rate": None}),
    ("paper lmi per-sample", lambda: PlantFamily.paper_example(0.1), 2,
     {"method": "lmi", "plant_switching": "per_sample", "decay_rate": None}),
    ("scaled lmi", badly_scaled, 3, {"method": "lmi", "decay_rate": None}),
    ("paper switched", lambda: PlantFamily.paper_example(0.2), 2, {"method": "switched", "decay_rate": None}),
    ("paper switched rate", lambda: PlantFamily.paper_example(0.1), 2, {"method": "switched", "decay_rate": 0.95}),
]


@pytest.mark.parametrize("name, make, n_drop, opts", CASES, ids=[c[0] for c in CASES])
def test_resolved_optimum_is_minus_design_objective(name, make, n_drop, opts):
    fam = make()
    res = design(fam, n_drop, **opts)
    text = export_sdpa(fam, n_drop, **opts)
    t_star = res.history[-1].objective
    assert resolve(text) == pytest.approx(-t_star, rel=1e-5, abs=1e-6)
    if name == "scaled lmi":
        assert "balanced coordinates" in text and res.scaling is not None
    else:
        assert "coordinates: the family's own" in text


def test_header_and_counts():
    fam = PlantFamily.paper_example(0.1)
    text = export_sdpa(fam, 3)
    c, F = read_sdpa(text)
    # t, W minus one diagonal entry (3 - 1 = 2), Y_1..Y_3 (1 x 2 each)
    assert len(c) == 1 + 2 + 6 and len(F[0]) == 9 and F[0][0].shape == (4, 4)
    assert "-t*" in text and "res.history[-1].objective" in text


@pytest.mark.parametrize("kwargs, field", [
    ({"method": "ccl"}, "method"), ({"method": "nope"}, "method"), ({"decay_rate": "max"}, "decay_rate"),
    ({"decay_rate": 1.5}, "decay_rate"), ({"objective": "cost"}, "objective"), ({"scaling": "x"}, "scaling"),
])
def test_refusals_name_the_field(kwargs, field):
    with pytest.raises(InvalidInput) as err:
        export_sdpa(PlantFamily.paper_example(0.1), 3, **kwargs)
    assert err.value.field == (field,)


def test_solve_only_options_are_accepted():
    fam = PlantFamily.paper_example(0.1)
    assert export_sdpa(fam, 3, solver="CLARABEL", margin=1e-7, time_limit=5) == export_sdpa(fam, 3)


def test_the_default_design_is_exported_at_its_certified_rate():
    """design()'s default (decay_rate="auto") searches the rate; its last SDP is the one at res.decay_rate.

    That last solve stops once its margin reaches FINAL_MARGIN_SHARE of the SDP's optimum (docs/design.md §3.5):
    the exported SDP's optimum (Clarabel, -t*) is at least the design's margin and within that share of it."""
    from solver.design import FINAL_MARGIN_SHARE

    fam = PlantFamily.paper_example(0.1)
    res = design(fam, 3)
    assert res.decay_rate is not None and res.decay_rate < 1
    text = export_sdpa(fam, 3, decay_rate=res.decay_rate)
    t_star, t_design = -resolve(text), res.history[-1].objective
    assert t_design > 0 and t_star >= t_design * (1 - 1e-6)
    assert t_design >= FINAL_MARGIN_SHARE * t_star * (1 - 1e-6)
