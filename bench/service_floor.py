"""The service against its in-process floor: ``python -m bench service-floor``.

In one run:

1. **the floor**: N warm processes (N = the service's worker count, one per CPU by default), each running
   ``solver.design()`` of the benchmark's request in a loop (one BLAS thread, the family built once, as a
   warm worker has it), in bursts of ``--seconds`` right before and after every service run; a row's floor
   is the mean of its two bursts (designs/s over all processes), so the floor and the service see the same
   machine. ``run_design`` (the worker's whole job: the request validated, the result as JSON) is measured
   once at the start;
2. per database (a fresh SQLite file; a throw-away PostgreSQL database when ``--pg-url`` is reachable):
   ``ncs-design serve`` on a free loopback port, driven by ``wrk`` (its own process, one thread) at 1, 4, 16
   and 64 connections for ``--seconds`` each. Every request is ``POST /v1/designs`` with ``Prefer: wait=30``;
   wrk's Lua script counts the answers that are not 2xx and the 2xx answers whose job is not ``succeeded``
   (both printed; a run with either is flagged). Printed per row: designs/s (succeeded answers / wall time),
   the floor and the ratio, p50 / p99 latency (wrk's), CPU milliseconds per design of the service's event
   loop (main thread) and its other threads, its workers, wrk and the PostgreSQL server processes (psutil,
   rusage), and the CPU-bound ratio: the floor's CPU per design over that sum.

The request is the plain stability design of the paper example (``method = "lmi"``, ``n_drop = 3``,
``decay_rate = null``: one SDP), the one ``bench/service_bench.py`` measures; ``--request auto`` takes the
default design (``decay_rate = "auto"``, ~10-12 SDPs) instead, for the floor and the service alike.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_PG = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
CLIENTS = (1, 4, 16, 64)
TARGETS = {"SQLite": 0.6, "PostgreSQL": 0.4}


def request_body(kind: str) -> dict:
    sys.path.insert(0, str(REPO))
    from app.examples import PAPER_PLANT

    body = {"plant": PAPER_PLANT, "n_drop": 3, "method": "lmi"}
    if kind == "plain":
        body["options"] = {"decay_rate": None}
    return body


# -- the floor -------------------------------------------------------------------------
FLOOR_CHILD = textwrap.dedent("""
    import json, sys, time
    req = json.loads(sys.argv[1]); what = sys.argv[2]
    from solver import design
    from app.compute.requests import DesignRequest
    from app.compute.tasks import build_family, design_options, run_design
    r = DesignRequest.model_validate(req)
    fam = build_family(r.plant.model_dump())
    kwargs = dict(n_drop=r.n_drop, method=r.method, **design_options(r.options), **r.performance_kwargs())
    one = (lambda: design(fam, **kwargs)) if what == "design" else (lambda: run_design(req))
    for _ in range(20):
        one()
    print("ready", flush=True)
    for line in sys.stdin:  # "<start at (time.time())> <seconds>": one burst
        start_at, seconds = map(float, line.split())
        while time.time() < start_at:
            time.sleep(0.002)
        t0, c0, n = time.perf_counter(), time.process_time(), 0
        while time.perf_counter() - t0 < seconds:
            one(); n += 1
        print(json.dumps({"n": n, "wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}), flush=True)
""")


class Floor:
    """``processes`` warm processes running ``what`` (``design``: ``solver.design()``; ``run_design``: the
    worker's whole job) of the request in a loop, in bursts on demand, all at once: the floor is measured
    right before and after every service run, so both see the same machine (the other load of a shared
    machine changes by the minute)."""

    def __init__(self, req: dict, processes: int, what: str = "design"):
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
               "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
        self.procs = [subprocess.Popen([sys.executable, "-c", FLOOR_CHILD, json.dumps(req), what],
                                       stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=REPO)
                      for _ in range(processes)]
        for p in self.procs:
            if p.stdout.readline().strip() != "ready":
                raise RuntimeError("a floor process did not start")

    def burst(self, seconds: float) -> dict:
        """designs/s over all processes and CPU ms per design, of one burst of ``seconds``."""
        start_at = time.time() + 0.2
        for p in self.procs:
            p.stdin.write(f"{start_at} {seconds}\n")
            p.stdin.flush()
        outs = [json.loads(p.stdout.readline()) for p in self.procs]
        n = sum(o["n"] for o in outs)
        return {"rate": n / max(o["wall"] for o in outs), "cpu_ms": sum(o["cpu"] for o in outs) / n * 1e3, "n": n}

    def close(self) -> None:
        for p in self.procs:
            p.stdin.close()
            p.wait(10)


# -- wrk -----------------------------------------------------------------------------------
LUA = """
wrk.method = "POST"
wrk.headers["Content-Type"] = "application/json"
wrk.headers["Prefer"] = "wait=30"
wrk.body = io.open(os.getenv("NCS_BENCH_BODY"), "r"):read("*a")
local threads = {}
function setup(thread) table.insert(threads, thread) end
function init(args) succeeded = 0; unfinished = 0; non2xx = 0 end
function response(status, headers, body)
  if status < 200 or status > 299 then non2xx = non2xx + 1
  elseif string.find(body, '"status":"succeeded"', 1, true) then succeeded = succeeded + 1
  else unfinished = unfinished + 1 end
end
function done(summary, latency, requests)
  local s, u, x = 0, 0, 0
  for _, t in ipairs(threads) do
    s = s + t:get("succeeded"); u = u + t:get("unfinished"); x = x + t:get("non2xx")
  end
  local e = summary.errors
  io.write(string.format(
    'NCS_RESULT {"requests": %d, "duration_us": %d, "succeeded": %d, "not_succeeded": %d, "non2xx": %d, ' ..
    '"socket_errors": %d, "p50_us": %d, "p99_us": %d}\\n',
    summary.requests, summary.duration, s, u, x, e.connect + e.read + e.write + e.timeout,
    latency:percentile(50), latency:percentile(99)))
end
"""


def run_wrk(base: str, body_path: Path, lua_path: Path, connections: int, seconds: float) -> tuple[dict, float]:
    """wrk's summary of one run and the CPU seconds wrk used."""
    env = {**os.environ, "NCS_BENCH_BODY": str(body_path)}
    before = os.times()
    out = subprocess.run(["wrk", "-t1", f"-c{connections}", f"-d{seconds:g}s", "--timeout", "40s", "-s",
                          str(lua_path), base + "/v1/designs"], capture_output=True, text=True, env=env,
                         check=True).stdout
    after = os.times()
    match = re.search(r"NCS_RESULT (\{.*\})", out)
    if match is None:
        raise RuntimeError(f"wrk printed no result:\n{out}")
    cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    return json.loads(match.group(1)), cpu


def cpu_split(pid: int) -> dict[str, float]:
    """CPU seconds (user + system) so far: the service's event loop (its main thread), its other threads
    (dispatcher, thread pool, job watch), its child processes (the workers) and every PostgreSQL server
    process of the machine (the database's share of the work; 0 on SQLite)."""
    import psutil

    proc = psutil.Process(pid)
    threads = {t.id: t.user_time + t.system_time for t in proc.threads()}
    main = threads.pop(pid, 0.0)
    kids = 0.0
    for c in proc.children(recursive=True):
        try:
            kids += sum(c.cpu_times()[:2])
        except psutil.Error:
            pass
    pg = 0.0
    for q in psutil.process_iter(["name"]):
        if (q.info["name"] or "").startswith("postgres"):
            try:
                pg += sum(q.cpu_times()[:2])
            except psutil.Error:
                pass
    return {"loop": main, "threads": sum(threads.values()), "workers": kids, "postgres": pg}


def measure(label: str, url: str, body: dict, a, floor: Floor, tmp: Path) -> list[dict]:
    """One server on ``url``, wrk at every client count, each run bracketed by floor bursts."""
    from bench.harness import Server
    from bench.service_bench import sequential

    body_path, lua_path = tmp / "body.json", tmp / "post.lua"
    body_path.write_text(json.dumps(body))
    lua_path.write_text(LUA)
    env = {"NCS_WORKERS": str(a.workers)} if a.workers else {}
    server = Server(url, tmp / f"server-{label}.log", **env)
    rows = []
    try:
        server.wait_ready(120)
        sequential(server.base, json.dumps(body).encode(), 10)  # warm: every worker has designed it
        before = floor.burst(a.seconds)
        for clients in a.clients:
            cpu0 = cpu_split(server.proc.pid)
            res, wrk_cpu = run_wrk(server.base, body_path, lua_path, clients, a.seconds)
            cpu1 = cpu_split(server.proc.pid)
            after = floor.burst(a.seconds)
            floor_rate = (before["rate"] + after["rate"]) / 2
            floor_cpu = (before["cpu_ms"] + after["cpu_ms"]) / 2
            n = max(1, res["succeeded"])
            rate = res["succeeded"] / (res["duration_us"] / 1e6)
            ms = {k: (cpu1[k] - cpu0[k]) / n * 1e3 for k in cpu0}
            ms["wrk"] = wrk_cpu / n * 1e3
            total = sum(ms.values())
            rows.append({"db": label, "clients": clients, "rate": rate, "floor": floor_rate, "ratio": rate / floor_rate,
                         "floor_cpu": floor_cpu, "cpu_ratio": floor_cpu / total, "total_ms": total, **ms,
                         "p50": res["p50_us"] / 1e3, "p99": res["p99_us"] / 1e3,
                         "non2xx": res["non2xx"], "not_succeeded": res["not_succeeded"],
                         "socket_errors": res["socket_errors"], "jobs": res["succeeded"], "load": os.getloadavg()[0]})
            print(f"  {label}, {clients} clients: {rate:.1f} designs/s, floor {floor_rate:.1f}/s "
                  f"({rows[-1]['ratio']:.2f}); {total:.1f} ms CPU per design against the floor's {floor_cpu:.2f}; "
                  f"non-2xx {res['non2xx']}, not succeeded {res['not_succeeded']}, load {rows[-1]['load']:.1f}",
                  flush=True)
            before = after
    finally:
        server.stop()
    return rows


def table(rows: list[dict], target: float) -> str:
    out = ["| clients | designs/s | floor designs/s | / floor | CPU-bound / floor | p50 / p99 latency "
           "| CPU ms per design: event loop + other threads / workers / wrk / PostgreSQL | not 2xx / not succeeded |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['clients']} | {r['rate']:.1f} | {r['floor']:.1f} | {r['ratio']:.2f} | {r['cpu_ratio']:.2f} "
                   f"| {r['p50']:.1f} / {r['p99']:.1f} ms | {r['loop']:.2f} + {r['threads']:.2f} / {r['workers']:.2f} "
                   f"/ {r['wrk']:.2f} / {r['postgres']:.2f} | {r['non2xx']} / {r['not_succeeded']} |")
    rates = [r["rate"] for r in rows]
    monotonic = all(b >= a * 0.97 for a, b in zip(rates, rates[1:]))  # within 3 %: the noise of a shared machine
    at16 = next((r["ratio"] for r in rows if r["clients"] == 16), None)
    verdict = [f"designs/s monotonic in clients (within 3 %): {'yes' if monotonic else 'NO'}"]
    if at16 is not None:
        verdict.append(f"16 clients: {at16:.2f} of the floor (target >= {target:g}): "
                       f"{'met' if at16 >= target else 'NOT met'}")
    return "\n".join(out) + "\n" + "; ".join(verdict)


def main(argv=None) -> int:
    from bench.service_bench import fresh_databases

    p = argparse.ArgumentParser(prog="python -m bench service-floor", description=__doc__.split("\n\n")[0])
    p.add_argument("--db", choices=["sqlite", "postgresql", "both"], default="both")
    p.add_argument("--pg-url", default=os.environ.get("NCS_BENCH_PG_URL", DEFAULT_PG))
    p.add_argument("--workers", type=int, default=None, help="NCS_WORKERS (default: the service's, one per CPU)")
    p.add_argument("--clients", default=",".join(map(str, CLIENTS)), help="wrk connections, comma-separated")
    p.add_argument("--seconds", type=float, default=10.0, help="length of each wrk run and of each floor burst")
    p.add_argument("--request", choices=["plain", "auto"], default="plain",
                   help="plain: decay_rate null (one SDP, default); auto: the default design")
    a = p.parse_args(argv)
    a.clients = [int(c) for c in a.clients.split(",")]
    if shutil.which("wrk") is None:
        raise SystemExit("wrk is not installed (apt-get install wrk)")
    sys.path.insert(0, str(REPO))
    from app.settings import _default_workers

    workers = a.workers or _default_workers()
    body = request_body(a.request)
    load = os.getloadavg()
    rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=REPO).stdout.strip()
    print(f"service vs floor: commit {rev}, {os.cpu_count()} cpus, {workers} workers, load average "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; request: paper example, lmi, n_drop = 3, "
          f"decay_rate {'null' if a.request == 'plain' else 'auto'}", flush=True)
    job = Floor(body, workers, "run_design")
    fr = job.burst(a.seconds)
    job.close()
    floor = Floor(body, workers)
    tmp = Path(tempfile.mkdtemp(prefix="ncs-service-floor-"))
    dbs = fresh_databases(a.db, a.pg_url, str(tmp))
    results = []
    try:
        for label, url, _ in dbs:
            results.append((label, measure(label, url, body, a, floor, tmp)))
    finally:
        floor.close()
        for _, _, pg in dbs:
            if pg is not None:
                pg.drop()
    load = os.getloadavg()
    print(f"\nfloor: {workers} processes of design() in a loop, measured right before and after every row (the "
          f"mean); the worker's whole job, run_design(), {fr['cpu_ms']:.2f} ms CPU per design at the start. "
          f"CPU-bound / floor: design()'s CPU per design over the sum of the row's CPU per design (what the "
          f"ratio is when the CPU is all that limits it).")
    for label, rows in results:
        print(f"\n{label}:\n")
        print(table(rows, TARGETS[label]))
    print(f"\n(load average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f})")
    bad = sum(r["non2xx"] + r["not_succeeded"] + r["socket_errors"] for _, rows in results for r in rows)
    if bad:
        print(f"WARNING: {bad} answers were not 2xx + succeeded, or failed on the socket")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
