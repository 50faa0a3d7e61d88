"""Bounded load test of the real service on loopback, and its back-pressure.

    python scripts/load_test.py [--submissions 1000] [--clients 50] [--database-url URL] [--workers N]

Load: ``--clients`` concurrent clients (threads, one keep-alive connection each) share ``--submissions`` design
submissions (the paper's example, lmi); after each submission a client polls its job (GET) until it is finished,
and every 5th client asks for the job's trace (seeded simulation in the synchronous pool; 10 different seeds, so
some hit the trace cache). Every response must be the expected one (202, 200, 304): anything else, or a
transport error, is an error (must be 0). Reports p50/p95/p99 latency per request kind, request and job
throughput, and the peak resident memory of the service process and of the service plus its workers.

Back-pressure: a second server with NCS_MAX_QUEUE_DEPTH=20 and one worker gets a burst of 200 submissions from
20 clients: every answer is 202 or 429 + Retry-After (problem+json), the queue never grows past its depth (plus
the submissions in flight), and once it drains submissions are accepted again.

Everything is bounded (``--max-seconds``) and talks to 127.0.0.1 only.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.harness import FAST, TERMINAL, Server, fresh_database, memory_mib, percentile, wait_all  # noqa: E402


class Recorder:
    def __init__(self):
        self.lock = threading.Lock()
        self.latency: dict[str, list[float]] = defaultdict(list)
        self.errors: list[str] = []
        self.count = 0

    def call(self, kind: str, fn, expected: tuple[int, ...]):
        t0 = time.perf_counter()
        try:
            r = fn()
        except httpx.HTTPError as exc:
            with self.lock:
                self.errors.append(f"{kind}: {type(exc).__name__}: {exc}")
                self.count += 1
            return None
        dt = time.perf_counter() - t0
        with self.lock:
            self.count += 1
            self.latency[kind].append(dt)
            if r.status_code not in expected:
                self.errors.append(f"{kind}: {r.status_code} {r.text[:200]}")
        return r


class MemorySampler(threading.Thread):
    def __init__(self, pid: int, every: float = 0.2):
        super().__init__(daemon=True)
        self.pid, self.every = pid, every
        self.peak_service = self.peak_total = 0.0
        self._halt = threading.Event()

    def run(self):
        while not self._halt.is_set():
            svc, total = memory_mib(self.pid)
            self.peak_service, self.peak_total = max(self.peak_service, svc), max(self.peak_total, total)
            self._halt.wait(self.every)

    def stop(self):
        self._halt.set()
        self.join(5)


def load(url: str, workdir: Path, submissions: int = 1000, clients: int = 50, workers: int = 2,
         max_seconds: float = 600.0, poll_interval: float = 0.05) -> dict:
    server = Server(url, workdir / "load.log", NCS_WORKERS=workers)
    try:
        server.wait_ready()
        mem = MemorySampler(server.proc.pid)
        mem.start()
        rec = Recorder()
        ids: list[str] = []
        next_index = iter(range(submissions))
        index_lock = threading.Lock()
        deadline = time.monotonic() + max_seconds

        def client(cid: int):
            limits = httpx.Limits(max_connections=1, max_keepalive_connections=1)
            with httpx.Client(base_url=server.base, timeout=60, limits=limits) as c:
                while time.monotonic() < deadline:
                    with index_lock:
                        i = next(next_index, None)
                    if i is None:
                        return
                    r = rec.call("submit", lambda: c.post("/v1/designs", json=FAST), (202,))
                    if r is None or r.status_code != 202:
                        continue
                    job_id = r.json()["id"]
                    with rec.lock:
                        ids.append(job_id)
                    status = r.json()["status"]
                    for _ in range(int(120 / poll_interval)):  # bounded polling
                        if status in TERMINAL or time.monotonic() > deadline:
                            break
                        time.sleep(poll_interval)
                        g = rec.call("poll", lambda: c.get(f"/v1/designs/{job_id}"), (200,))
                        if g is not None and g.status_code == 200:
                            status = g.json()["status"]
                    if status == "succeeded" and cid % 5 == 0:
                        rec.call("trace", lambda: c.get(f"/v1/designs/{job_id}/trace",
                                                        params={"seed": i % 10, "steps": 100}), (200,))

        t0 = time.monotonic()
        with ThreadPoolExecutor(max_workers=clients) as pool:
            list(pool.map(client, range(clients)))
        elapsed = time.monotonic() - t0
        with httpx.Client(base_url=server.base, timeout=60) as c:
            done = wait_all(c, ids, timeout=max(10.0, deadline - time.monotonic()))
            ready = c.get("/readyz").status_code
        t_all = time.monotonic() - t0
        mem.stop()
        statuses = [j["status"] for j in done.values()]
        out = {
            "submissions": submissions, "clients": clients, "workers": workers,
            "accepted": len(ids), "finished": len(done), "succeeded": statuses.count("succeeded"),
            "lost": len(ids) - len(done), "requests": rec.count, "errors": len(rec.errors),
            "error_samples": rec.errors[:5], "seconds": round(elapsed, 1),
            "requests_per_s": round(rec.count / elapsed, 1), "submissions_per_s": round(len(ids) / elapsed, 1),
            "jobs_per_s": round(statuses.count("succeeded") / t_all, 1),
            "latency_ms": {k: {"n": len(v), "p50": round(percentile(v, 0.50) * 1e3, 1),
                               "p95": round(percentile(v, 0.95) * 1e3, 1),
                               "p99": round(percentile(v, 0.99) * 1e3, 1)} for k, v in rec.latency.items()},
            "peak_rss_mib": {"service": round(mem.peak_service), "service_and_workers": round(mem.peak_total)},
            "readyz_after": ready,
            "log_tracebacks": server.log_text().count("Traceback"),
        }
        all_lat = [x for v in rec.latency.values() for x in v]
        out["latency_ms"]["all"] = {"n": len(all_lat), "p50": round(percentile(all_lat, 0.50) * 1e3, 1),
                                    "p95": round(percentile(all_lat, 0.95) * 1e3, 1),
                                    "p99": round(percentile(all_lat, 0.99) * 1e3, 1)}
        return out
    finally:
        server.stop()


def back_pressure(url: str, workdir: Path, depth: int = 20, burst: int = 200, clients: int = 20,
                  retry_after: int = 2) -> dict:
    server = Server(url, workdir / "backpressure.log", NCS_WORKERS=1, NCS_MAX_QUEUE_DEPTH=depth,
                    NCS_RETRY_AFTER=retry_after)
    try:
        server.wait_ready()
        codes: dict[int, int] = defaultdict(int)
        bad: list[str] = []
        accepted: list[str] = []
        max_queued = 0
        lock = threading.Lock()
        with httpx.Client(base_url=server.base, timeout=60,
                          limits=httpx.Limits(max_connections=clients)) as c:
            def submit(_):
                r = c.post("/v1/designs", json={**FAST, "method": "ccl", "n_drop": 4, "options": {"solver": "CLARABEL"}})  # ~0.5-1 s each
                with lock:
                    codes[r.status_code] += 1
                    if r.status_code == 202:
                        accepted.append(r.json()["id"])
                    elif not (r.status_code == 429 and r.headers.get("retry-after") == str(retry_after)
                              and r.headers.get("content-type", "").startswith("application/problem+json")):
                        bad.append(f"{r.status_code} {dict(r.headers)} {r.text[:200]}")
                return r.status_code

            stop = threading.Event()

            def watch():
                nonlocal max_queued
                with httpx.Client(base_url=server.base, timeout=30) as w:
                    while not stop.is_set():
                        q = w.get("/v1/designs", params={"status": "queued", "limit": 1}).json()["total"]
                        max_queued = max(max_queued, q)
                        stop.wait(0.02)

            watcher = threading.Thread(target=watch, daemon=True)
            watcher.start()
            with ThreadPoolExecutor(max_workers=clients) as pool:
                list(pool.map(submit, range(burst)))
            stop.set()
            watcher.join(10)
            # Drain, then the service takes work again.
            for job_id in list(accepted):
                c.post(f"/v1/designs/{job_id}/cancel")
            t0 = time.monotonic()
            while True:
                r = c.post("/v1/designs", json=FAST)
                if r.status_code == 202:
                    accepted.append(r.json()["id"])
                    break
                if time.monotonic() - t0 > 60:
                    bad.append(f"never accepted again: {r.status_code}")
                    break
                time.sleep(0.1)
            accepted_again_s = time.monotonic() - t0
            done = wait_all(c, accepted, timeout=120)
        return {"depth": depth, "burst": burst, "clients": clients, "status_codes": dict(codes),
                "unexpected": bad[:5], "max_queued_seen": max_queued, "accepted": len(accepted),
                "finished": len(done), "lost": len(accepted) - len(done),
                "accepted_again_after_drain_s": round(accepted_again_s, 2)}
    finally:
        server.stop()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--submissions", type=int, default=1000)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--database-url", default=None, help="PostgreSQL server URL (a fresh database is made on it)")
    ap.add_argument("--max-seconds", type=float, default=600.0)
    ap.add_argument("--skip-back-pressure", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        with fresh_database(args.database_url, work) as url:
            res = load(url, work, args.submissions, args.clients, args.workers, args.max_seconds)
        print("load: " + json.dumps(res), flush=True)
        bp = None
        if not args.skip_back_pressure:
            with fresh_database(args.database_url, work) as url:
                bp = back_pressure(url, work)
            print("back_pressure: " + json.dumps(bp), flush=True)
    ok = res["errors"] == 0 and res["lost"] == 0 and (bp is None or (not bp["unexpected"] and bp["lost"] == 0))
    print("== " + ("PASS" if ok else "FAIL") + f": {res['errors']} errors in {res['requests']} requests")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
