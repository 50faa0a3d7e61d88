"""One typed result for the library and the client, the dict forms of ``output``/``weights`` the HTTP API uses,
and input-limit messages that start with the limits, not with "CLARABEL failed" (issue 33, item 14)."""

from __future__ import annotations

import importlib

import numpy as np

from solver import PlantFamily, SolverFailed, design
from solver.brackets import Performance

E = [[1.0], [0.0]]


def test_output_and_weights_take_the_json_dict_form():
    fam = PlantFamily.paper_example()
    pair = design(fam, 3, objective="hinf", disturbance=E, output=([[1.0, 0.0]], [[0.1]]))
    as_dict = design(fam, 3, objective="hinf", disturbance=E, output={"C": [[1.0, 0.0]], "D": [[0.1]]})
    assert as_dict.performance.upper == pair.performance.upper
    cost_pair = design(fam, 3, objective="cost", weights=(np.eye(2), np.eye(1)))
    cost_dict = design(fam, 3, objective="cost", weights={"Q": np.eye(2).tolist(), "R": [[1.0]]})
    assert cost_dict.performance.upper == cost_pair.performance.upper


def test_performance_round_trips_through_its_json():
    res = design(PlantFamily.paper_example(), 3, objective="cost")
    back = Performance.from_dict(res.performance.to_dict())
    assert isinstance(back, Performance)
    assert back.to_dict() == res.performance.to_dict()
    assert back["upper"] == back.upper == res.performance.upper


def test_an_input_limited_design_the_solver_gives_up_on_names_the_limits_first(monkeypatch):
    performance = importlib.import_module("solver.methods.performance")

    def gives_up(*args, **kwargs):
        raise SolverFailed("CLARABEL failed: numerical error", status="solver_error")

    monkeypatch.setattr(performance, "run", gives_up)
    # The performance path turns a solver's failure into a verdict (never an exception), naming the limits first.
    res = design(PlantFamily.paper_example(), 3, u_max=[0.5], x0=[1.0, 0.0])
    assert res.outcome == "not_converged"
    text = res.message
    assert text.startswith("no design was certified within the input limits u_max = [0.5] from x0 = [1, 0]"), text
    assert "the conic solver reported: CLARABEL failed: numerical error" in text
    assert text.endswith("so this design asks for none")  # decay_rate="auto": no rate certified under the limits
