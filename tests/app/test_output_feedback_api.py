"""Output feedback over HTTP: the plant's C, `feedback: output`, observer gains in analyses and simulations."""

from __future__ import annotations

import numpy as np
import pytest

from solver import PlantFamily, design

from .conftest import assert_problem, running_client, wait_for


@pytest.fixture(scope="module")
def client(module_db):
    with running_client(module_db, workers=1) as c:
        yield c


def motor_plant(C=((0.0, 1.0),)):
    fam = PlantFamily.paper_example()
    return {"kind": "discrete", "F": fam.F.tolist(), "G": fam.G.tolist(), "sampling_period": 0.1,
            "C": [list(r) for r in C]}


def test_output_feedback_design_analysis_and_simulation(client):
    body = {"plant": motor_plant(), "n_drop": 3, "feedback": "output", "sensor_n_drop": 2}
    resp = client.post("/v1/designs", json=body)
    assert resp.status_code == 202, resp.text
    done = wait_for(client, resp.json()["id"])
    assert done["status"] == "succeeded", done
    res = done["result"]
    assert res["outcome"] == "stabilized" and res["feedback"] == "output"
    fam = PlantFamily.from_dict(motor_plant())
    direct = design(fam, 3, feedback="output", sensor_n_drop=2)
    np.testing.assert_allclose(np.asarray(res["observer_gains"]), direct.observer_gains, rtol=1e-6, atol=1e-9)
    assert res["joint_certificate"]["blocks"] == direct.joint_certificate.blocks

    rep = client.post("/v1/analyses", json={"plant": motor_plant(), "gains": res["gains"],
                                           "observer_gains": res["observer_gains"], "sensor_n_drop": 2})
    assert rep.status_code == 200, rep.text
    assert rep.json()["stable"] is True and rep.json()["output"]["certificate"]["blocks"] > 0

    sim = client.post("/v1/simulations", json={"plant": motor_plant(), "gains": res["gains"], "x0": [1.0, 0.0],
                                               "steps": 80, "seed": 3, "loss_model": "bernoulli",
                                               "observer_gains": res["observer_gains"], "sensor_n_drop": 2})
    assert sim.status_code == 200, sim.text
    est = np.asarray(sim.json()["estimate"])
    x = np.asarray(sim.json()["x"])
    assert est.shape == x.shape and np.abs(x[-1] - est[-1]).max() < 1e-6


def test_output_feedback_errors_name_the_field(client):
    body = {"plant": {**motor_plant(), "C": [[1.0, 0.0, 0.0]]}, "n_drop": 3, "feedback": "output"}
    assert_problem(client.post("/v1/designs", json=body), 422, "/plant/C")
    plant = motor_plant()
    del plant["C"]
    assert_problem(client.post("/v1/designs", json={"plant": plant, "n_drop": 3, "feedback": "output"}), 422,
                   "/plant/C")
    assert_problem(client.post("/v1/designs", json={"plant": motor_plant(), "n_drop": 3, "feedback": "output",
                                                    "sensor_n_drop": 0}), 422, "/sensor_n_drop")


def test_client_round_trip(client):
    from app.client import Client

    fam = PlantFamily.from_dict(motor_plant())
    api = Client("http://testserver", http_client=client)
    res = api.design(fam, 3, feedback="output", sensor_n_drop=2)
    assert res.outcome == "stabilized" and res.observer_gains.shape == (3, 2, 1)
    rep = api.analyze(fam, res.gains, observer_gains=res.observer_gains, sensor_n_drop=2)
    assert rep.stable is True
    tr = api.simulate(fam, res.gains, [1.0, 0.0], steps=50, loss_model="bernoulli",
                      observer_gains=res.observer_gains, xh0=np.zeros(2))
    assert "estimate" in tr.raw


def test_cli_output_feedback(tmp_path):
    import json
    import subprocess
    import sys
    from pathlib import Path

    import scipy.io

    plant = tmp_path / "motor.json"
    plant.write_text(json.dumps(motor_plant()))
    repo = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-m", "app.cli", "design", str(plant), "--n-drop", "3", "--feedback",
                          "output", "--sensor-n-drop", "2", "-o", str(tmp_path / "d.mat")], cwd=repo,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "observer gains L" in out.stdout and "output feedback certified" in out.stdout
    assert scipy.io.loadmat(tmp_path / "d.mat")["L"].shape == (2, 1, 3)
