"""A plausible unit mistake ends in a message in the user's terms, never in "a bug worth reporting" (issue 33,
item 9): the CTMS inverted pendulum with sampling_period 10 (meant 10 ms) or 1 s.

Reference: the pendulum's unstable pole from its characteristic polynomial (closed form below), not the code's
eigenvalue routine: s^2 = m g l (M + m) / p - (terms with b), solved numerically by numpy.roots on the exact
polynomial coefficients of the continuous A."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from solver import InvalidInput, design

from .textbook import pendulum, pendulum_matrices, pendulum_plant_json

REPO = Path(__file__).resolve().parents[2]


def fastest_unstable_time_constant() -> float:
    A = np.array(pendulum_matrices(0.3)[0])
    # char. poly of A = s * (s^3 + c2 s^2 + c1 s + c0): coefficients from A's entries (block structure)
    a22, a23, a42, a43 = A[1, 1], A[1, 2], A[3, 1], A[3, 2]
    cubic = [1.0, -a22, -a43, a22 * a43 - a23 * a42]
    return 1.0 / max(r.real for r in np.roots(cubic))


def test_the_reference_time_constant_is_the_ctms_one():
    assert fastest_unstable_time_constant() == pytest.approx(0.1797, abs=2e-3)  # pole at 5.565 rad/s


def test_h_10_s_is_refused_naming_the_sampling_period_and_the_time_constant():
    tau = fastest_unstable_time_constant()
    with pytest.raises(InvalidInput) as err:
        design(pendulum(10.0), 3)
    assert err.value.field == ("sampling_period",)
    text = str(err.value)
    assert f"{10 / tau:.3g} times" in text and f"{tau:.3g} s" in text, text
    assert "Did you mean 0.01 s" in text


def test_h_1_s_is_a_verdict_in_the_users_terms():
    tau = fastest_unstable_time_constant()
    res = design(pendulum(1.0), 3)  # raised SolverFailed ("IPM ended with status 'max_iterations'")
    assert res.outcome == "not_converged"
    assert res.message.startswith(f"no design was certified: h = 1 s is {1 / tau:.3g} times"), res.message
    assert "bug" not in res.message


def test_the_service_refuses_h_10_s_at_submission_and_answers_h_1_s_with_a_verdict(tmp_path):
    from tests.app.conftest import running_client

    with running_client(f"sqlite:///{tmp_path / 'ncs.db'}", workers=1) as client:
        resp = client.post("/v1/designs", json={"plant": pendulum_plant_json(10.0), "n_drop": 3})
        assert resp.status_code == 422, resp.text
        assert resp.json()["errors"][0]["pointer"] == "/plant/sampling_period", resp.json()
        job = client.post("/v1/designs", json={"plant": pendulum_plant_json(1.0), "n_drop": 3},
                          headers={"Prefer": "wait=60"}).json()
        assert job["status"] == "succeeded", job
        assert job["result"]["outcome"] == "not_converged" and "times the plant's fastest unstable" in \
            job["result"]["message"], job["result"]["message"]


def test_the_cli_says_it_in_one_line_without_warnings(tmp_path):
    (tmp_path / "pend.json").write_text(json.dumps(pendulum_plant_json(1.0)))
    env = {k: v for k, v in os.environ.items() if not k.startswith("NCS_")}
    out = subprocess.run([sys.executable, "-m", "app.cli", "design", "pend.json", "--n-drop", "3"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300, env={**env, "PYTHONPATH": str(REPO)})
    assert out.returncode == 1, out.stderr  # a verdict (not_converged), not a solver failure (3)
    assert "times the plant's fastest unstable time constant" in out.stdout
    assert "Warning" not in out.stderr and len(out.stderr.splitlines()) <= 2, out.stderr
