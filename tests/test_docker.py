"""The Dockerfile, built and run: /readyz, a design through the client, non-root user, /data volume.

Runs when a Docker engine answers (``.ci/run`` installs ``docker.io`` and starts ``dockerd``).
Docker Hub need not be reachable: the base image is a Debian bookworm root filesystem made by
``scripts/make_base_image.sh`` (debootstrap, needs root), built once and reused while the tag
exists.  ``NCS_DOCKER_BASE_IMAGE`` picks another base (e.g. ``python:3.11-slim``).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
LOCAL_BASE = "ncs-design-base:bookworm"
IMAGE = "ncs-design:test"

pytestmark = pytest.mark.slow


def docker(*args, timeout=900, check=True) -> subprocess.CompletedProcess:
    out = subprocess.run(["docker", *args], capture_output=True, text=True, timeout=timeout)
    if check and out.returncode != 0:
        raise AssertionError(f"docker {' '.join(args)} failed ({out.returncode}):\n{out.stdout[-3000:]}\n"
                             f"{out.stderr[-3000:]}")
    return out


def engine_problem() -> str | None:
    if shutil.which("docker") is None:
        return "no docker CLI (apt-get install docker.io)"
    try:
        info = subprocess.run(["docker", "info", "--format", "{{.ServerVersion}}"], capture_output=True,
                              text=True, timeout=30)
    except subprocess.TimeoutExpired:
        return "docker info timed out"
    if info.returncode != 0:
        return f"no Docker engine answers (start dockerd): {info.stderr.strip()[:200]}"
    return None


def base_image() -> str:
    base = os.environ.get("NCS_DOCKER_BASE_IMAGE")
    if base:
        return base
    if docker("image", "inspect", LOCAL_BASE, check=False).returncode == 0:
        return LOCAL_BASE
    if os.geteuid() != 0 or shutil.which("debootstrap") is None:
        pytest.skip(f"no base image {LOCAL_BASE} and cannot make one (needs root and debootstrap; or set "
                    "NCS_DOCKER_BASE_IMAGE)")
    out = subprocess.run([str(REPO / "scripts" / "make_base_image.sh"), LOCAL_BASE], capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stdout + out.stderr
    return LOCAL_BASE


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def layers(image: str) -> list[str]:
    return json.loads(docker("image", "inspect", "-f", "{{json .RootFS.Layers}}", image).stdout)


@pytest.fixture(scope="module")
def built_image():
    problem = engine_problem()
    if problem:
        pytest.skip(problem)
    timings = {}
    t0 = time.monotonic()
    base = base_image()
    timings["base"] = time.monotonic() - t0
    t0 = time.monotonic()
    docker("build", "--network", "host", "--build-arg", f"BASE_IMAGE={base}", "-t", IMAGE, str(REPO))
    timings["build"] = time.monotonic() - t0
    print(f"docker timings (s): {timings}")
    return base, timings


def test_dependencies_are_a_layer_below_the_code(built_image, tmp_path):
    """Changing only the code rebuilds only the layers above the dependency install."""
    base, _ = built_image
    ctx = tmp_path / "ctx"
    shutil.copytree(REPO, ctx, ignore=shutil.ignore_patterns(".git", ".venv*", "__pycache__", "*.egg-info",
                                                              ".pytest_cache", "*.db"))
    with open(ctx / "solver" / "__init__.py", "a") as fh:
        fh.write(f"\n# code change {uuid.uuid4()}\n")
    tag = f"ncs-design:test-code-change-{uuid.uuid4().hex[:8]}"
    t0 = time.monotonic()
    docker("build", "--network", "host", "--build-arg", f"BASE_IMAGE={base}", "-t", tag, str(ctx))
    rebuild = time.monotonic() - t0
    try:
        old, new = layers(IMAGE), layers(tag)
        common = next((i for i, (a, b) in enumerate(zip(old, new)) if a != b), min(len(old), len(new)))
        n_base = len(layers(base))
        # base, venv + user, pyproject.toml, pip install of the dependencies: all reused
        assert common >= n_base + 3, (common, n_base, old, new)
        assert common < len(new)  # and the code layers were rebuilt
        print(f"rebuild after a code change: {rebuild:.1f} s, {common} of {len(new)} layers reused")
    finally:
        docker("rmi", "-f", tag, check=False)


def test_image_serves_a_design_as_non_root_with_a_data_volume(built_image):
    from app.client import Client
    from solver import PlantFamily, design

    name = f"ncs-design-test-{uuid.uuid4().hex[:8]}"
    volume = f"{name}-data"
    port = free_port()
    t0 = time.monotonic()
    docker("run", "-d", "--name", name, "-p", f"127.0.0.1:{port}:8000", "-v", f"{volume}:/data",
           "-e", "NCS_WORKERS=1", "-e", "NCS_SYNC_WORKERS=1", IMAGE)
    try:
        with Client(f"http://127.0.0.1:{port}", timeout=30) as client:
            deadline = time.monotonic() + 120
            while not client.ready():
                state = docker("inspect", "-f", "{{.State.Status}}", name).stdout.strip()
                assert state == "running", docker("logs", name, check=False).stdout[-3000:]
                assert time.monotonic() < deadline, "no /readyz in 120 s:\n" + docker("logs", name).stderr[-3000:]
                time.sleep(0.5)
            ready = time.monotonic() - t0
            fam = PlantFamily.dc_motor([0.03, 0.05], 0.1)
            res = client.design(fam, n_drop=3, wait=120)
            assert res.outcome == "stabilized" and res.certificate["verified"] is True
            np.testing.assert_allclose(res.gains, design(fam, 3).gains, rtol=1e-5, atol=1e-8)
            assert [j.id for j in client.jobs()] == [res.job_id]
        uid = docker("exec", name, "id", "-u").stdout.strip()
        assert uid != "0" and uid == "10001"
        mounts = json.loads(docker("inspect", "-f", "{{json .Mounts}}", name).stdout)
        assert [(m["Type"], m["Name"], m["Destination"]) for m in mounts] == [("volume", volume, "/data")]
        listing = docker("exec", name, "ls", "-ln", "/data").stdout
        assert "ncs.db" in listing and " 10001 " in listing  # the job database lives on the volume
        print(f"container ready in {ready:.1f} s")
    finally:
        docker("rm", "-f", "-v", name, check=False)
        docker("volume", "rm", "-f", volume, check=False)
