"""The one harness that starts a real service (``python -m app.cli serve`` on a free loopback port) and waits
for /readyz, shared by the tests (tests/app/conftest.py), the benchmark (bench/service_bench.py) and the
scripts (scripts/fault_injection.py, scripts/load_test.py); plus fresh databases, job polling, memory.

Everything here talks to 127.0.0.1 only, and every wait is bounded.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from contextlib import contextmanager
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from app.examples import PAPER_PLANT  # noqa: E402

TERMINAL = ("succeeded", "failed", "cancelled")
FAST = {"plant": PAPER_PLANT, "n_drop": 3, "method": "lmi"}           # ~0.1 s
SLOW = {"plant": PAPER_PLANT, "n_drop": 5, "method": "ccl", "options": {"solver": "CLARABEL"}}           # ~2 s


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss_kib(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError):
        pass
    return 0


def process_tree(pid: int) -> list[int]:
    out = [pid]
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            for child in f.read().split():
                out += process_tree(int(child))
    except (FileNotFoundError, ProcessLookupError):
        pass
    return out


def memory_mib(pid: int) -> tuple[float, float]:
    """(service process RSS MiB, service + worker processes RSS MiB)."""
    pids = process_tree(pid)
    return rss_kib(pid) / 1024, sum(rss_kib(p) for p in pids) / 1024


def _pg_admin(url: str):
    import psycopg
    from sqlalchemy.engine import make_url

    u = make_url(url)
    host = u.query.get("host") or u.host or "127.0.0.1"
    return psycopg.connect(host=host, port=u.port or 5432, user=u.username, password=u.password,
                           dbname=u.database, autocommit=True), u


@contextmanager
def fresh_database(base_url: str | None, tmp: Path | None = None):
    """A new empty database: an SQLite file (base_url None or sqlite) or a throw-away PostgreSQL database
    created on the server of ``base_url`` and dropped afterwards."""
    if not base_url or base_url.startswith("sqlite"):
        with tempfile.TemporaryDirectory(dir=tmp) as d:
            yield f"sqlite:///{Path(d) / 'ncs.db'}"
        return
    name = "ncs_fault_" + uuid.uuid4().hex[:12]
    conn, u = _pg_admin(base_url)
    with conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield u.set(database=name).render_as_string(hide_password=False)
    finally:
        conn, _ = _pg_admin(base_url)
        with conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def terminate_backends(url: str) -> int:
    """pg_terminate_backend on every other connection to the database of ``url``: a connection loss."""
    conn, u = _pg_admin(url)
    with conn:
        rows = conn.execute("SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                            "WHERE datname = %s AND pid <> pg_backend_pid()", (u.database,)).fetchall()
    return sum(1 for (ok,) in rows if ok)


def _pg_cluster() -> list[str]:
    """``pg_ctlcluster <version> main``: the local PostgreSQL server of the fault scenarios."""
    versions = sorted(os.listdir("/etc/postgresql"))
    return ["pg_ctlcluster", "--skip-systemctl-redirect", versions[-1], "main"]


def restart_postgres() -> float:
    """Restart the PostgreSQL server (every connection is lost, new ones are refused meanwhile); the seconds
    the restart took."""
    t0 = time.monotonic()
    subprocess.run([*_pg_cluster(), "restart"], check=True, capture_output=True, timeout=120)
    return time.monotonic() - t0


def ensure_postgres_running() -> None:
    """Leave the server up whatever happened (a restart that failed half-way, an interrupted test)."""
    if subprocess.run([*_pg_cluster(), "status"], capture_output=True, timeout=30).returncode != 0:
        subprocess.run([*_pg_cluster(), "start"], check=True, capture_output=True, timeout=120)


class Server:
    """``python -m app.cli serve`` (= ``ncs-design serve``) on a free loopback port."""

    def __init__(self, url: str, log_path: Path, **env):
        self.url = url
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        environ = {k: v for k, v in os.environ.items() if not k.startswith("NCS_")}
        environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p)
        environ.update({"NCS_DATABASE_URL": url, "NCS_PORT": str(self.port), "NCS_HOST": "127.0.0.1"})
        environ.update({k: str(v) for k, v in env.items()})
        self.env = environ
        self.log_path = log_path
        self.log = open(log_path, "ab")
        self.proc = subprocess.Popen([sys.executable, "-m", "app.cli", "serve", "--log-level", "warning"],
                                     env=environ, cwd=str(REPO), stdout=self.log, stderr=subprocess.STDOUT)

    def wait_ready(self, timeout: float = 90.0) -> float:
        """Seconds until /readyz answers 200 (its body is kept in ``self.readyz``)."""
        t0 = time.monotonic()
        deadline = t0 + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}; log: {self.log_path}")
            try:
                r = httpx.get(self.base + "/readyz", timeout=2)
                if r.status_code == 200:
                    self.readyz = r.json()
                    return time.monotonic() - t0
            except httpx.HTTPError:
                pass
            time.sleep(0.05)
        raise RuntimeError(f"server not ready after {timeout} s; log: {self.log_path}")

    def worker_pids(self) -> list[int]:
        return process_tree(self.proc.pid)[1:]

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait(10)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.log.close()

    def log_text(self) -> str:
        if not self.log.closed:
            self.log.flush()
        return self.log_path.read_bytes().decode(errors="replace")


def statuses(c: httpx.Client, ids: list[str]) -> dict[str, dict]:
    return {i: c.get(f"/v1/designs/{i}").json() for i in ids}


def wait_all(c: httpx.Client, ids: list[str], timeout: float) -> dict[str, dict]:
    """Poll until every job is terminal (bounded by ``timeout``); returns the last view of every job."""
    deadline = time.monotonic() + timeout
    done: dict[str, dict] = {}
    while True:
        for job_id in ids:
            if job_id not in done:
                try:
                    r = c.get(f"/v1/designs/{job_id}")
                except httpx.HTTPError:
                    continue
                if r.status_code == 200 and r.json()["status"] in TERMINAL:
                    done[job_id] = r.json()
        if len(done) == len(ids) or time.monotonic() > deadline:
            return done
        time.sleep(0.1)


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    k = (len(s) - 1) * q
    lo, hi = int(k), min(int(k) + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (k - lo)
