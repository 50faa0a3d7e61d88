"""Measure the service: POST -> succeeded latency, designs/second, resident memory.

Starts a real server (``python -m app.cli serve``, i.e. ``ncs-design serve``) on a free
loopback port with a fresh SQLite database (or ``--database-url``) and the default pool
(NCS_WORKERS = CPU count unless ``--workers``), then prints a table.

    python scripts/measure_service.py [--jobs 100] [--latency-runs 10] [--workers N]
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from app.examples import PAPER_PLANT  # noqa: E402

TERMINAL = ("succeeded", "failed", "cancelled")


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
    except FileNotFoundError:
        pass
    return 0


def tree(pid: int) -> list[int]:
    out = [pid]
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            for child in f.read().split():
                out += tree(int(child))
    except FileNotFoundError:
        pass
    return out


def memory(pid: int) -> tuple[float, float, int]:
    """(service process MiB, service + worker processes MiB, number of processes)."""
    pids = tree(pid)
    return rss_kib(pid) / 1024, sum(rss_kib(p) for p in pids) / 1024, len(pids)


def wait_done(c: httpx.Client, job_id: str, poll: float = 0.005) -> dict:
    while True:
        job = c.get(f"/v1/designs/{job_id}").json()
        if job["status"] in TERMINAL:
            return job
        time.sleep(poll)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--jobs", type=int, default=100, help="jobs in the throughput run")
    ap.add_argument("--latency-runs", type=int, default=10)
    ap.add_argument("--workers", type=int, default=None, help="NCS_WORKERS (default: the service default)")
    ap.add_argument("--database-url", default=None)
    args = ap.parse_args()

    tmp = tempfile.mkdtemp(prefix="ncs-measure-")
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("NCS_")}
    env.update(NCS_DATABASE_URL=args.database_url or f"sqlite:///{tmp}/ncs.db", NCS_PORT=str(port))
    if args.workers:
        env["NCS_WORKERS"] = str(args.workers)
    log = open(Path(tmp) / "server.log", "wb")
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "serve", "--log-level", "warning"],
                            cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    rows: list[tuple[str, str]] = []
    try:
        c = httpx.Client(base_url=base, timeout=120,
                         limits=httpx.Limits(max_connections=64, max_keepalive_connections=64))
        t0 = time.monotonic()
        while True:
            try:
                r = c.get("/readyz")
                if r.status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() - t0 > 120:
                raise SystemExit("server did not become ready")
            time.sleep(0.05)
        ready = c.get("/readyz").json()
        workers = ready["workers"]["configured"]
        rows.append(("start -> ready (workers imported the solver)", f"{time.monotonic() - t0:.2f} s"))
        rows.append(("worker processes", str(workers)))
        time.sleep(1.0)
        main_mib, total_mib, nproc = memory(proc.pid)
        rows.append(("RSS idle: service process", f"{main_mib:.0f} MiB"))
        rows.append((f"RSS idle: service + {nproc - 1} child processes", f"{total_mib:.0f} MiB"))

        for method in ("lmi", "ccl"):
            body = {"plant": PAPER_PLANT, "n_drop": 3, "method": method}
            wait_done(c, c.post("/v1/designs", json=body).json()["id"])  # warm the compiled problem
            lat, solver_time = [], []
            for _ in range(args.latency_runs):
                t = time.perf_counter()
                job = wait_done(c, c.post("/v1/designs", json=body).json()["id"])
                lat.append(time.perf_counter() - t)
                assert job["status"] == "succeeded", job
                solver_time.append(sum(v for v in (job["result"].get("timings") or {}).values()
                                       if isinstance(v, (int, float))))
            lat.sort()
            rows.append((f"latency POST -> succeeded, paper example, {method} (median / min / max of {len(lat)})",
                         f"{statistics.median(lat) * 1000:.0f} / {lat[0] * 1000:.0f} / {lat[-1] * 1000:.0f} ms"))

        peak = [0.0, 0.0]
        stop = threading.Event()

        def sample():
            while not stop.is_set():
                m, t, _ = memory(proc.pid)
                peak[0], peak[1] = max(peak[0], m), max(peak[1], t)
                time.sleep(0.1)

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        for method in ("lmi", "ccl"):
            body = {"plant": PAPER_PLANT, "n_drop": 3, "method": method}
            t = time.perf_counter()
            with ThreadPoolExecutor(32) as pool:
                ids = list(pool.map(lambda _: c.post("/v1/designs", json=body).json()["id"], range(args.jobs)))
            submitted = time.perf_counter() - t
            with ThreadPoolExecutor(8) as pool:
                jobs = list(pool.map(lambda i: wait_done(c, i, poll=0.05), ids))
            elapsed = time.perf_counter() - t
            assert all(j["status"] == "succeeded" for j in jobs)
            rows.append((f"throughput, {args.jobs} concurrent paper-example {method} jobs, {workers} workers",
                         f"{args.jobs / elapsed:.1f} designs/s (all accepted in {submitted:.2f} s)"))
        stop.set()
        sampler.join()
        rows.append(("RSS under load (peak): service process", f"{peak[0]:.0f} MiB"))
        rows.append(("RSS under load (peak): service + workers", f"{peak[1]:.0f} MiB"))
    finally:
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()

    width = max(len(k) for k, _ in rows)
    print(f"{'measure'.ljust(width)} | value")
    print(f"{'-' * width}-|------")
    for k, v in rows:
        print(f"{k.ljust(width)} | {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
