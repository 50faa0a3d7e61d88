"""app.compute.tasks' memos (solver.memo.BoundedCache by digest): a family built once per plant, read-only;
inputs that fail are not remembered."""

import numpy as np
import pytest

from app.compute import tasks
from solver import InvalidInput


def test_a_plant_is_built_once_and_read_only(monkeypatch):
    monkeypatch.setattr(tasks, "_families", tasks.BoundedCache(2))
    built = []
    original = tasks._build_family
    monkeypatch.setattr(tasks, "_build_family", lambda plant: built.append(1) or original(plant))
    plant = {"kind": "discrete", "F": [[[1.5, 0.0], [0.0, 0.5]]], "G": [[[0.0], [1.0]]]}
    fam = tasks.build_family(plant)
    assert tasks.build_family(dict(reversed(plant.items()))) is fam  # the same JSON, keys in another order
    assert len(built) == 1 and not fam.F.flags.writeable and not fam.G.flags.writeable
    np.testing.assert_array_equal(fam.F[0], [[1.5, 0.0], [0.0, 0.5]])
    other = tasks.build_family({**plant, "F": [[[0.5, 0.0], [0.0, 0.5]]]})
    assert other is not fam and len(built) == 2


def test_a_rejected_plant_is_checked_again(monkeypatch):
    monkeypatch.setattr(tasks, "_checked", tasks.BoundedCache(4))
    bad = '{"kind": "discrete", "F": [[[1.0, 0.0]]], "G": [[[0.0], [1.0]]]}'
    for _ in range(2):
        with pytest.raises(InvalidInput):
            tasks.check_design_inputs(bad, 2, "per_interval", "predictive")
    assert len(tasks._checked) == 0
    good = '{"kind": "discrete", "F": [[[1.5, 0.0], [0.0, 0.5]]], "G": [[[0.0], [1.0]]]}'
    tasks.check_design_inputs(good, 2, "per_interval", "predictive")
    assert len(tasks._checked) == 1
