"""Calls the size guard let through (issue 33, item 11): n_drop = 10000 spent 8 s and 0.84 GB before refusing; the
memory message for a 200-state plant blamed n_drop; the CLI's simulate --steps 100000000 hung."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from solver import InvalidInput, PlantFamily, design

from .textbook import pendulum, pendulum_plant_json

REPO = Path(__file__).resolve().parents[2]


def test_n_drop_10000_is_refused_before_anything_is_built():
    tracemalloc.start()
    try:
        with pytest.raises(InvalidInput) as err:
            design(pendulum(), 10000)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert err.value.field == ("n_drop",) and "20000 closed-loop modes" in str(err.value)
    assert peak < 20 * 2**20, f"{peak / 2**20:.0f} MiB allocated before the refusal"


def test_a_design_large_because_of_its_states_names_the_states():
    rng = np.random.default_rng(0)
    n = 200
    fam = PlantFamily([0.5 * np.eye(n) + 0.01 * rng.standard_normal((n, n)) for _ in range(2)],
                      [rng.standard_normal((n, 1)) for _ in range(2)])
    with pytest.raises(InvalidInput) as err:
        design(fam, 3)
    text = str(err.value)
    assert "the 200 states make it large" in text and "n_drop" not in text.split(":", 1)[1], text
    assert err.value.field == ("F",)
    with pytest.raises(InvalidInput) as err:  # and one large because of n_drop still names n_drop
        design(pendulum(), 1000)
    assert err.value.field == ("n_drop",) and "smaller n_drop" in str(err.value)


def test_cli_simulate_with_1e8_steps_is_refused(tmp_path):
    (tmp_path / "pend.json").write_text(json.dumps(pendulum_plant_json(0.01)))
    (tmp_path / "gains.json").write_text(json.dumps([[[1.0, 2.0, 30.0, 5.0]]] * 3))
    env = {k: v for k, v in os.environ.items() if not k.startswith("NCS_")}
    out = subprocess.run([sys.executable, "-m", "app.cli", "simulate", "pend.json", "--gains", "gains.json",
                          "--steps", "100000000"], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                         env={**env, "PYTHONPATH": str(REPO)})
    assert out.returncode == 2, (out.stdout[-500:], out.stderr[-500:])
    assert "(steps)" in out.stderr and "steps = 100000000" in out.stderr, out.stderr
