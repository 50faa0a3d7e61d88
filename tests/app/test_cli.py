"""The ncs-design CLI run as a subprocess: design / analyze / simulate, outputs read back, exit codes."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from solver import PlantFamily, design

from .conftest import doc_block

MOTOR = {"kind": "dc_motor", "inertias": [0.03, 0.05], "sampling_period": 0.1}


def ncs(*args, cwd, timeout=180):
    env = {k: v for k, v in os.environ.items() if not k.startswith("NCS_")}
    return subprocess.run([sys.executable, "-m", "app.cli", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env={**env, "PYTHONPATH": os.getcwd()})


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    (d / "motor.json").write_text(json.dumps(MOTOR))
    return d


def test_version_and_help(workdir):
    out = ncs("--version", cwd=workdir)
    assert out.returncode == 0 and re.fullmatch(r"ncs-design \d+\.\d+\.\d+\S*\n", out.stdout)
    out = ncs("--help", cwd=workdir)
    for cmd in ("serve", "migrate", "design", "analyze", "simulate"):
        assert cmd in out.stdout


@pytest.fixture(scope="module")
def gain_files(workdir):
    """gains.mat, gains.m and gains.json written by `ncs-design design` (in-process)."""
    for name in ("gains.mat", "gains.m", "gains.json"):
        out = ncs("design", "motor.json", "--n-drop", 3, "--output", name, cwd=workdir)
        assert out.returncode == 0, out.stderr
        assert "stabilized" in out.stdout and "omega (rad/s)" in out.stdout and f"wrote {name}" in out.stdout
    return workdir


def test_design_in_process_writes_mat_m_and_json(gain_files):
    workdir = gain_files
    ref = design(PlantFamily.dc_motor([0.03, 0.05], 0.1), 3)
    d = scipy.io.loadmat(workdir / "gains.mat")
    np.testing.assert_allclose(d["K"], ref.gains, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(d["P"], ref.certificate.P, rtol=1e-6, atol=1e-9)
    assert str(d["outcome"][0]) == "stabilized" and int(d["n_drop"][0, 0]) == 3
    text = (workdir / "gains.m").read_text()
    k1 = re.search(r"^K1 = \[(.*)\];$", text, flags=re.M).group(1)
    np.testing.assert_allclose([float(v) for v in k1.split()], ref.gains[0].ravel(), rtol=1e-6)
    result = json.loads((workdir / "gains.json").read_text())
    np.testing.assert_allclose(result["gains"], ref.gains, rtol=1e-6, atol=1e-9)
    assert np.asarray(result["F"]).shape == (2, 2, 2)


def test_analyze_and_simulate_the_written_gains(workdir, gain_files):
    out = ncs("analyze", "motor.json", "--gains", "gains.mat", cwd=workdir)
    assert out.returncode == 0 and "stable (certified)" in out.stdout, out.stderr
    out = ncs("simulate", "motor.json", "--gains", "gains.json", "--x0", "1,-1", "--steps", 40,
              "--plot", "run.png", "--output", "run.json", cwd=workdir)
    assert out.returncode == 0, out.stderr
    assert (workdir / "run.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    run = json.loads((workdir / "run.json").read_text())
    assert len(run["t"]) == 41 and run["x"][0] == [1.0, -1.0]


def test_mat_plant_with_sampling_period_option(workdir):
    fam = PlantFamily.paper_example(0.1)
    scipy.io.savemat(workdir / "paper.mat", {"A": np.moveaxis(fam.A, 0, -1), "B": np.moveaxis(fam.B, 0, -1)})
    out = ncs("design", "paper.mat", "--n-drop", 2, cwd=workdir)
    assert out.returncode == 2 and "--sampling-period" in out.stderr and "Traceback" not in out.stderr
    out = ncs("design", "paper.mat", "--n-drop", 2, "--sampling-period", 0.1, "-o", "paper.json", cwd=workdir)
    assert out.returncode == 0, out.stderr
    np.testing.assert_allclose(json.loads((workdir / "paper.json").read_text())["gains"], design(fam, 2).gains,
                               rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("plant, args, words", [
    ({"kind": "discrete", "F": [[1.0, 0.0], [0.0, 1.0]], "G": [[1.0], [0.0]]}, ["--n-drop", 2], "F=[F]"),
    (MOTOR, ["--n-drop", 0], "n_drop"),
    (MOTOR, ["--n-drop", 2, "--output", "gains.txt"], ".json, .mat or .m"),
    (MOTOR, ["--n-drop", 2, "--decay-rate", "fast"], "--decay-rate"),
    ("not json", ["--n-drop", 2], "not valid JSON"),
])
def test_bad_input_is_one_line_and_exit_2(workdir, plant, args, words):
    (workdir / "bad.json").write_text(plant if isinstance(plant, str) else json.dumps(plant))
    out = ncs("design", "bad.json", *args, cwd=workdir)
    assert out.returncode == 2
    assert words in out.stderr and "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_infeasible_exits_1(workdir):
    (workdir / "unstab.json").write_text(json.dumps({"kind": "discrete", "F": [[[2.0, 0.0], [0.0, 2.0]]],
                                                     "G": [[[0.0], [0.0]]]}))
    out = ncs("design", "unstab.json", "--n-drop", 2, cwd=workdir)
    assert out.returncode == 1 and "infeasible" in out.stdout


def test_design_against_a_server(workdir, gain_files, db_url, start_server):
    server = start_server(db_url, NCS_WORKERS=1, NCS_SYNC_WORKERS=1)
    out = ncs("design", "motor.json", "--n-drop", 3, "--server", server.base, "-o", "remote.mat", cwd=workdir)
    assert out.returncode == 0, out.stderr
    np.testing.assert_allclose(scipy.io.loadmat(workdir / "remote.mat")["K"],
                               scipy.io.loadmat(workdir / "gains.mat")["K"], rtol=1e-6, atol=1e-9)
    out = ncs("analyze", "motor.json", "--gains", "remote.mat", "--server", server.base, cwd=workdir)
    assert out.returncode == 0 and "stable (certified)" in out.stdout, out.stderr
    out = ncs("design", "motor.json", "--n-drop", 3, "--method", "nope", "--server", server.base, cwd=workdir)
    assert out.returncode == 2 and "422" in out.stderr and "Traceback" not in out.stderr


def test_readme_cli_example_runs(tmp_path):
    bindir = tmp_path / "bin"  # `ncs-design` on PATH, from this checkout
    bindir.mkdir()
    (bindir / "ncs-design").write_text(f"#!/bin/sh\nexec {sys.executable} -m app.cli \"$@\"\n")
    (bindir / "ncs-design").chmod(0o755)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NCS_")}
    env.update(PATH=f"{bindir}:{env['PATH']}", PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    out = subprocess.run(["bash", "-euo", "pipefail", "-c", doc_block("cli-example", "bash")[1]], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300, env=env)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "stabilized" in out.stdout and "stable (certified)" in out.stdout and "ncs-design " in out.stdout
    assert (tmp_path / "run.png").stat().st_size > 10_000
    assert scipy.io.loadmat(tmp_path / "gains.mat")["K"].shape == (3, 1, 2)


def test_readme_client_example_runs(db_url, start_server, capsys, monkeypatch):
    server = start_server(db_url, NCS_WORKERS=1, NCS_SYNC_WORKERS=1)
    monkeypatch.setenv("NCS_URL", server.base)
    monkeypatch.delenv("NCS_API_KEY", raising=False)
    path, code = doc_block("client-example", "py")
    exec(compile(code, path, "exec"), {})
    printed = capsys.readouterr().out.splitlines()
    assert printed[:3] == ["stabilized (3, 1, 2)", "True", "(51, 2) 2"]
    assert printed[3] == "InvalidInput ('F',)", printed[3]  # a single matrix: the library's error, before sending
    assert printed[4] == "422 /n_drop", printed[4]  # over NCS_MAX_N_DROP: the service's problem


def test_design_summary_reports_settling_and_a_too_big_design_is_refused(workdir):
    """issue 22: the default loop's certified settling time, its rate in 1/s and the simulated run's settling are
    in the summary; a cart-pole with n_drop = 1000 is one line on stderr (exit 2), not an OOM."""
    from solver.result import certified_settling, metric_condition

    from tests.solver.cartpole import cartpole

    fam = cartpole()
    plant = {"kind": "continuous", "A": fam.A.tolist(), "B": fam.B.tolist(), "sampling_period": 0.02,
             "state_names": list(fam.state_names), "input_names": ["F"], "units": fam.units}
    (workdir / "cartpole.json").write_text(json.dumps(plant))
    out = ncs("design", "cartpole.json", "--n-drop", 3, cwd=workdir)
    assert out.returncode == 0, out.stderr
    ref = design(fam, 3)
    settle = certified_settling(ref.decay_rate, metric_condition(ref.certificate, ref.scaling), 0.02)
    assert (f"certified settling time to 2 % of |x0|, worst case over every allowed loss and switching sequence: "
            f"{settle['samples']} samples = {settle['seconds']:.3g} s") in out.stdout
    assert f"exponential rate {settle['exponential_rate']:.3g} 1/s" in out.stdout
    assert re.search(r"^simulated settling to 2 % of \|x0\| \(seed 42, .*\): \d+ samples = [\d.]+ s$", out.stdout, re.M)
    big = ncs("design", "cartpole.json", "--n-drop", 1000, cwd=workdir)
    assert big.returncode == 2 and big.stdout.count("\n") <= 1, big.stdout
    assert "GiB of solver memory" in big.stderr and "NCS_SOLVER_MAX_MEMORY" in big.stderr
    assert "Traceback" not in big.stderr and len(big.stderr.strip().splitlines()) == 1


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("url,cause", [
    (f"postgresql+psycopg://postgres:secret@127.0.0.1:{_free_port()}/ncs", "Connection refused"),
    ("postgresql+psycopg://postgres:secret@127.0.0.1:5432/no_such_database_ncs", "does not exist"),
    ("mysqlx://user@host/db", "unsupported database URL"),
    ("not a url", "is not a database URL"),
    ("sqlite:////proc/no/such/dir/ncs.db", "unable to open database file"),
])
def test_wrong_database_url_exits_with_one_line_naming_the_setting(tmp_path, url, cause):
    """Issue 20: a wrong NCS_DATABASE_URL was a 75-154-line traceback."""
    if "5432" in url and not os.environ.get("NCS_TEST_DATABASE_URL"):
        pytest.skip("needs the PostgreSQL server of NCS_TEST_DATABASE_URL")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NCS_")}
    proc = subprocess.run([sys.executable, "-m", "app.cli", "serve", "--port", str(_free_port())], cwd=tmp_path,
                          capture_output=True, text=True, timeout=60,
                          env={**env, "PYTHONPATH": os.getcwd(), "NCS_DATABASE_URL": url})
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("ncs-design serve: NCS_DATABASE_URL") and cause in lines[0], lines
    assert "secret" not in proc.stderr and "Traceback" not in proc.stderr


def test_a_request_file_is_honoured_field_by_field(workdir):
    """Issue 33, item 12: a whole design request (cost objective, weights, a solver) ran as a plain stability
    design and exited 0 without a word. Now every field is honoured (flags override the file's) and the result
    is the library's for the same call."""
    req = {"plant": MOTOR, "n_drop": 3, "objective": "cost", "weights": {"Q": [[1, 0], [0, 2]], "R": [[1]]},
           "options": {"solver": "CLARABEL", "decay_rate": None}}
    (workdir / "req.json").write_text(json.dumps(req))
    out = ncs("design", "req.json", "--n-drop", "4", "-o", "req_out.json", cwd=workdir)
    assert out.returncode == 0, out.stderr
    got = json.loads((workdir / "req_out.json").read_text())
    assert got["n_drop"] == 4 and got["objective"] == "cost" and got["solver"] == "CLARABEL", got.get("objective")
    ref = design(PlantFamily.from_dict(MOTOR), 4, objective="cost", weights=([[1, 0], [0, 2]], [[1]]),
                 solver="CLARABEL", decay_rate=None)
    assert got["performance"]["upper"] == pytest.approx(ref.performance.upper, rel=1e-6)
    assert "objective cost" in out.stdout and "solver CLARABEL" in out.stdout


def test_a_request_field_the_cli_cannot_take_is_refused_by_name(workdir):
    req = {"plant": MOTOR, "n_drop": 3, "weigths": {"Q": [[1, 0], [0, 1]], "R": [[1]]}, "options": {"solvr": "IPM"}}
    (workdir / "typo.json").write_text(json.dumps(req))
    out = ncs("design", "typo.json", cwd=workdir)
    assert out.returncode == 2, out.stdout
    assert "weigths is not a field" in out.stderr and "options.solvr is not a field" in out.stderr, out.stderr


def test_solver_flag(workdir):
    out = ncs("design", "motor.json", "--n-drop", "3", "--solver", "clarabel", "-o", "clarabel.json", cwd=workdir)
    assert out.returncode == 0, out.stderr
    assert json.loads((workdir / "clarabel.json").read_text())["solver"] == "CLARABEL"
    out = ncs("design", "motor.json", cwd=workdir)
    assert out.returncode == 2 and "--n-drop is required" in out.stderr


def test_the_cli_summary_names_what_certified_the_upper_end():
    """The summary line says which certificate gave ``upper`` (docs/design.md §8.4, §11.3): a look-ahead over the
    next intervals (with the prefix tree on its matrices when ``upper`` is below their own bound), a network's next or
    last transitions, or the prefix tree on the common P."""
    from app.cli_commands import performance_summary

    base = {"lower": 120.7, "certificate_upper": 521.5, "witness": [[0, 1]]}
    ahead = performance_summary(dict(base, kind="cost", upper=120.8, mode_certificate=[[[120.8]]]), "cost")[0]
    assert "(one re-checked matrix per sequence of the next intervals; the common certificate alone: 521.5)" in ahead
    tree_ahead = performance_summary(dict(base, kind="cost", upper=120.8, mode_certificate=[[[1.0, 0], [0, 130]]],
                                          x0=[0.0, 1.0]), "cost")[0]
    assert "prefix tree on one re-checked matrix per sequence of the next intervals, whose bound alone is 130" \
        in tree_ahead
    net = dict(base, upper=120.8, mode_certificate=[[[1.0]]], start_nodes=[0], memory=3)
    assert "sequence of the next 3 transitions" in performance_summary(dict(net, kind="cost"), "cost")[0]
    assert "sequence of the last 3 transitions" in performance_summary(dict(net, kind="hinf"), "l2 gain")[0]
    tree = performance_summary(dict(base, kind="cost", upper=180.0), "cost")[0]
    assert "prefix tree on the re-checked certificate, whose bound alone is 521.5" in tree


def test_serve_keeps_idle_connections_past_the_clients_expiry(monkeypatch, tmp_path):
    """uvicorn's own keep-alive (5 s) equals httpx's pool expiry: a loaded client reused a connection just as the
    service closed it (test_200_concurrent_submissions: "Server disconnected without sending a response").  `serve`
    passes NCS_KEEP_ALIVE (default 30 s, above the clients' expiry) to uvicorn."""
    import uvicorn

    from app import cli
    from app.settings import Settings

    seen = {}
    monkeypatch.setattr(uvicorn, "run", lambda app, **kw: seen.update(kw))
    monkeypatch.setenv("NCS_DATABASE_URL", f"sqlite:///{tmp_path / 'k.db'}")
    assert cli.main(["serve", "--port", "0"]) == 0
    assert seen["timeout_keep_alive"] == Settings().keep_alive == 30.0 > 5.0
    monkeypatch.setenv("NCS_KEEP_ALIVE", "75")
    assert cli.main(["serve", "--port", "0"]) == 0
    assert seen["timeout_keep_alive"] == 75.0
