"""app.client.Client against the running service (in-process ASGI), checked against the library."""

import subprocess
import sys

import numpy as np
import pytest

from app.client import Client, DesignResult, Job, JobFailed, ServiceError, plant_json
from solver import PlantFamily, analyze, design, simulate

from .conftest import running_client


@pytest.fixture(scope="module")
def client(module_db):
    with running_client(module_db, workers=1) as http:
        yield Client("http://testserver", http_client=http, poll_interval=0.05)


def test_importable_without_fastapi():
    code = ("import sys; from app.client import Client; "
            "bad = [m for m in ('fastapi', 'starlette', 'sqlalchemy', 'cvxpy') if m in sys.modules]; "
            "print(bad); sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr


def test_design_from_a_family_matches_the_library(client):
    fam = PlantFamily.dc_motor([0.03, 0.05], 0.1)
    res = client.design(fam, n_drop=3)
    ref = design(fam, 3)
    assert isinstance(res, DesignResult) and res.outcome == "stabilized" and res.success
    assert res.gains.shape == (3, 1, 2) and res.job_id
    np.testing.assert_allclose(res.gains, ref.gains, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(res.F, fam.F, rtol=1e-12)
    np.testing.assert_allclose(res.plant_family().G, fam.G, rtol=1e-12)
    assert res.certificate["verified"] is True and res.sampling_period == 0.1
    assert res.max_spectral_radius == pytest.approx(float(np.max(ref.spectral_radii)), rel=1e-6)
    # the same gains analysed and simulated by the service and by the library
    rep = client.analyze(fam, res.gains)
    assert rep.stable is True
    assert rep.max_spectral_radius == pytest.approx(analyze(fam, res.gains, 3).max_spectral_radius, rel=1e-9)
    sim = client.simulate(fam, res.gains, x0=[1.0, -1.0], steps=30, seed=7)
    lib = simulate(fam, res.gains, 3, x0=[1.0, -1.0], steps=30, seed=7)
    np.testing.assert_allclose(sim.state, lib.state, rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(sim.effective, lib.effective)
    tr = client.trace(res.job_id, x0=[1.0, 0.0], steps=20)
    assert tr.state.shape == (21, 2) and len(tr.per_mode) == 2
    assert any(j.id == res.job_id and j.outcome == "stabilized" for j in client.jobs())


def test_design_from_statespace_and_dict(client):
    ct = pytest.importorskip("control")
    systems = [ct.ss([[-4.0, -0.03], [k, -d]], [[2.0], [0.0]], np.eye(2), 0.0)
               for k, d in ((0.5, 6.667), (0.75, 10.0))]
    body = plant_json(systems, sampling_period=0.1)
    assert body["kind"] == "continuous" and body["sampling_period"] == 0.1
    a = client.design(systems, n_drop=2, sampling_period=0.1)
    b = client.design(body, n_drop=2)
    np.testing.assert_allclose(a.gains, b.gains, rtol=1e-9)


def test_no_wait_returns_the_job_and_cancel(client):
    fam = PlantFamily.paper_example(0.1)
    # Clarabel: the IPM (AUTO) finishes this design in ~0.1 s, before the cancel could land.
    job = client.design(fam, n_drop=4, method="ccl", wait=False, max_iter=200, solver="CLARABEL")
    assert isinstance(job, Job) and job.status in ("queued", "running", "succeeded")
    try:
        cancelled = client.cancel(job.id)
    except ServiceError as err:  # it may already have finished
        assert err.status == 409
        return
    assert cancelled.status in ("cancelled", "running") and cancelled.raw["cancel_requested"] is True
    with pytest.raises(JobFailed) as err:
        client.result(job.id, wait=30)
    assert err.value.job.status == "cancelled"


def test_service_errors_carry_the_problem(client):
    with pytest.raises(ServiceError) as err:
        client.design({"kind": "discrete", "F": [[[1.0]]], "G": [[[1.0]]]}, n_drop=0)
    e = err.value
    assert e.status == 422 and e.errors and any("n_drop" in str(x.get("loc")) for x in e.errors)
    assert e.problem["status"] == 422 and "n_drop" in str(e)
    with pytest.raises(ServiceError) as err:
        client.job("no-such-job")
    assert err.value.status == 404 and err.value.title
    with pytest.raises(TypeError, match="PlantFamily"):
        plant_json(np.eye(2))


def test_margins_and_listing(client):
    fam = PlantFamily.paper_example(0.1)
    res = client.margins(fam, "n_drop", n_drop_max=2)
    assert res.kind == "n_drop" and res.margin == 2 and [p["n_drop"] for p in res.curve] == [1, 2]
    margin_jobs = client.jobs(kind="margin")
    assert margin_jobs and margin_jobs[0].status == "succeeded"


def test_trace_image_sends_x0_like_trace(client):
    # issue 22: trace_image(x0=[...]) went out as repeated x0= parameters and got a 422 "x0 has 1 entries"
    import io

    from PIL import Image

    fam = PlantFamily.dc_motor([0.03, 0.05], 0.1)
    res = client.design(fam, n_drop=3)
    png = client.trace_image(res.job_id, "png", x0=[0.5, -1.0], steps=40)
    assert png[:4] == b"\x89PNG" and Image.open(io.BytesIO(png)).size[0] > 100
    assert client.trace(res.job_id, x0=[0.5, -1.0], steps=40).state[0].tolist() == [0.5, -1.0]


def test_bad_numbers_raise_the_library_error_before_sending(client):
    from solver import InvalidInput

    plant = {"kind": "discrete", "F": [[[1.0, float("nan")], [0.0, 1.0]]], "G": [[[0.0], [1.0]]]}
    with pytest.raises(InvalidInput) as err:
        client.design(plant, n_drop=2)
    assert err.value.field[0] == "F"
    fam = PlantFamily.dc_motor([0.03], 0.1)
    with pytest.raises(InvalidInput) as err:
        client.analyze(fam, [[[float("nan"), 0.0]]] * 2)
    assert err.value.field == ("gains",)


def test_httpx_is_a_dependency_of_the_package():
    import tomllib

    from .conftest import REPO

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert any(dep.startswith("httpx") for dep in project["dependencies"])
