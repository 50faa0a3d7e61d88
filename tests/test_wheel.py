"""The wheel, installed outside the clone: ``ncs-design serve`` from an empty directory migrates its database
(the migrations travel in the wheel as ``app/migrations``), reaches /readyz and designs.

The wheel is built with ``pip wheel --no-deps`` and installed with ``--no-deps`` into a new venv; the
dependencies come from this interpreter's site directories (a ``.pth`` lists them, so their own ``.pth``
files, like this clone's editable install, are not processed): the test checks that the service imports the
installed copy, never the clone.
"""

from __future__ import annotations

import json
import os
import signal
import site
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def http(method: str, url: str, body: dict | None = None, headers: dict | None = None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method,
                                 headers={"Content-Type": "application/json", **(headers or {})})
    try:
        with urllib.request.urlopen(req, timeout=90) as resp:
            return resp.status, resp.read()
    except urllib.error.HTTPError as err:
        return err.code, err.read()


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """A venv holding only the wheel (its dependencies reachable through a .pth); returns its bin dir."""
    work = tmp_path_factory.mktemp("wheel")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NCS_", "PYTHON"))}
    out = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(work / "dist"),
                          str(REPO)], capture_output=True, text=True, timeout=600, env=env, cwd=work)
    assert out.returncode == 0, out.stderr[-3000:]
    wheel = next((work / "dist").glob("ncs_design-*.whl"))
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
    page = {f"app/web/static/{p.name}" for p in (REPO / "app" / "web" / "static").iterdir()}
    assert page <= names, page - names  # the design page's files are package data
    venv = work / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    purelib = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True).stdout.strip()
    dirs = [p for p in dict.fromkeys(site.getsitepackages() + sys.path)
            if p and Path(p).is_dir() and Path(p).name in ("site-packages", "dist-packages")]
    (Path(purelib) / "zz_test_dependencies.pth").write_text("\n".join(dirs) + "\n")
    out = subprocess.run([str(py), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)],
                         capture_output=True, text=True, timeout=300, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    return venv / "bin", env


def test_serve_from_an_empty_directory_migrates_and_designs(installed, tmp_path):
    bindir, env = installed
    where = subprocess.run([str(bindir / "python"), "-c", "import app, solver, app.jobs.database as d; "
                            "print(app.__file__); print(solver.__file__); print(d.find_alembic_dir())"],
                           capture_output=True, text=True, cwd=tmp_path, env=env, check=True).stdout.split("\n")
    venv = bindir.parent
    for path in where[:3]:
        assert Path(path).resolve().is_relative_to(venv.resolve()), (path, where)  # the installed copy
    assert Path(where[2]).name == "migrations"
    port = free_port()
    log = (tmp_path / "server.log").open("w")
    proc = subprocess.Popen([str(bindir / "ncs-design"), "serve", "--port", str(port)], cwd=tmp_path,
                            stdout=log, stderr=subprocess.STDOUT, env={**env, "NCS_WORKERS": "1"})
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                if http("GET", base + "/readyz")[0] == 200:
                    break
            except OSError:
                pass
            assert proc.poll() is None, (tmp_path / "server.log").read_text()[-3000:]
            assert time.monotonic() < deadline, (tmp_path / "server.log").read_text()[-3000:]
            time.sleep(0.2)
        plant = {"kind": "dc_motor", "inertias": [0.03, 0.05], "sampling_period": 0.1}
        status, body = http("POST", base + "/v1/designs", {"plant": plant, "n_drop": 3}, {"Prefer": "wait=60"})
        job = json.loads(body)
        assert 200 <= status < 300 and job["status"] == "succeeded", job
        assert job["result"]["outcome"] == "stabilized"
        status, body = http("GET", base + f"/v1/designs/{job['id']}/controller.zip")
        assert status == 200 and body[:2] == b"PK"
        assert (tmp_path / "ncs.db").is_file()  # the default database, in the working directory
        # The design page and every file it loads come from the installed wheel (no network, no clone).
        status, body = http("GET", base + "/")
        assert status == 200 and b'id="design"' in body
        for asset in ("page.js", "page.css", "examples.json"):
            status, body = http("GET", base + f"/static/page/{asset}")
            assert status == 200 and body, asset
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()
