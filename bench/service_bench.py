"""Service benchmark: the real server over HTTP on loopback, driven by a load generator.

``python -m bench.service_bench`` (or ``python -m bench service``) starts
``python -m app.cli serve`` (= ``ncs-design serve``) on a free loopback port with the
default worker pool, once on a fresh SQLite file and once on a fresh PostgreSQL
database (if ``--pg-url`` is reachable), and prints one table with a column per
database. The workload is the paper example with ``lmi`` (``n_drop = 3``).

Measured per database:

* **latency, one client**: one job at a time, POST -> the job observed ``succeeded``;
  p50 / p95 over ``--latency-jobs``;
* **sustained**: ``--clients`` concurrent clients (asyncio + httpx), each submitting its
  next job as soon as its previous one succeeded (closed loop), ``--jobs`` jobs in all,
  bounded by ``--time-limit``; designs per second = jobs / wall time from the first POST
  to the last observed success, plus the latency p50 / p95 under that load;
* **open loop**: jobs submitted at a fixed rate (``--rate``, default the 50/s target)
  for ``--open-seconds``; achieved designs/s and latency p50 / p95. This is the direct
  check of "50 designs/s with p50 < 50 ms";
* **server-side latency**: ``finished_at - created_at`` of the same jobs from the API
  (no observation delay);
* resident memory (RSS, /proc via psutil) of the service process and of the service
  plus its worker processes: idle (after start) and peak under load (sampled every 0.1 s);
* CPU seconds used during the sustained run by the service process and by its
  workers, which says what bounds the throughput.

``--dask`` adds a column for the Dask backend (``NCS_DASK_SCHEDULER``) against a
``LocalCluster`` started by the benchmark (its worker processes are not children of the
service, so the RSS and CPU rows of that column cover the service process only).

Completion is observed without polling: each client submits with ``Prefer: wait=30``
(RFC 7240), so the POST itself answers 201 with the finished job as soon as it ends; a job
still unfinished after that is awaited with ``GET /v1/designs/{id}`` and the same header.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from datetime import datetime
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TERMINAL = ("succeeded", "failed", "cancelled")
DEFAULT_PG = "postgresql+psycopg://postgres@127.0.0.1:5432/test"


def _paper_lmi() -> bytes:
    import json

    sys.path.insert(0, str(REPO))
    from app.examples import PAPER_PLANT

    # the plain stability design (one SDP), as measured before the default became decay_rate="auto"
    return json.dumps({"plant": PAPER_PLANT, "n_drop": 3, "method": "lmi", "options": {"decay_rate": None}}).encode()


def machine_reference(jobs: int = 200) -> str:
    """How fast this machine runs the workers' job: ``run_design`` of the paper example in a child process
    with one BLAS thread, as the service's workers run it (median wall time, after a warm-up). Service
    figures taken on different machines compare through it: on one 2-core machine this was 5.5 ms, on
    another 2.2 ms, and the service's CPU per design moved by the same factor."""
    code = ("import json, statistics, sys, time; from app.examples import PAPER_PLANT; "
            "from app.compute.tasks import run_design; "
            "req = {'plant': PAPER_PLANT, 'n_drop': 3, 'method': 'lmi', 'options': {'decay_rate': None}}; "
            "[run_design(req) for _ in range(30)]; "
            "ts = []\nfor _ in range(int(sys.argv[1])):\n t = time.perf_counter(); run_design(req); "
            "ts.append(time.perf_counter() - t)\nprint(json.dumps(statistics.median(ts) * 1e3))")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    out = subprocess.run([sys.executable, "-c", code, str(jobs)], capture_output=True, text=True, env=env,
                         cwd=REPO, check=True).stdout
    cpu = "?"
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), "?")
    except OSError:
        pass
    return f"cpu {cpu}; the workers' job in one process (run_design, paper example): {float(out):.2f} ms median"


def pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    v = sorted(values)
    return v[min(len(v) - 1, max(0, round(q / 100 * (len(v) - 1))))]


# -- databases -----------------------------------------------------------------------
class PgDatabase:
    """A throw-away database on the PostgreSQL server of ``url``."""

    def __init__(self, url: str):
        import psycopg
        from sqlalchemy.engine import make_url

        self.u = make_url(url)
        self.name = "ncs_bench_" + uuid.uuid4().hex[:10]
        self._connect = lambda: psycopg.connect(host=self.u.query.get("host") or self.u.host or "127.0.0.1",
                                                port=self.u.port or 5432, user=self.u.username,
                                                password=self.u.password, dbname=self.u.database, autocommit=True)
        with self._connect() as conn:
            conn.execute(f'CREATE DATABASE "{self.name}"')
        self.url = self.u.set(database=self.name).render_as_string(hide_password=False)

    def drop(self) -> None:
        with self._connect() as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{self.name}" WITH (FORCE)')


def pg_reachable(url: str) -> bool:
    try:
        import psycopg
        from sqlalchemy.engine import make_url

        u = make_url(url)
        psycopg.connect(host=u.query.get("host") or u.host or "127.0.0.1", port=u.port or 5432, user=u.username,
                        password=u.password, dbname=u.database, connect_timeout=3).close()
        return True
    except Exception:
        return False


# -- the server: bench/harness.py --------------------------------------------------------
def start_server(db_url: str, workers: int | None, log_path: Path, extra_env: dict[str, str]):
    from bench.harness import Server

    env = dict(extra_env)
    if workers:
        env["NCS_WORKERS"] = str(workers)
    return Server(db_url, log_path, **env)


class Memory:
    """RSS of the service process and its process tree; peak sampling in a thread."""

    def __init__(self, pid: int):
        import psutil

        self.proc = psutil.Process(pid)
        self.peak = (0.0, 0.0)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def now(self) -> tuple[float, float, int]:
        import psutil

        main = self.proc.memory_info().rss / 2**20
        total, n = main, 1
        for c in self.proc.children(recursive=True):
            try:
                total += c.memory_info().rss / 2**20
                n += 1
            except psutil.Error:
                pass
        return main, total, n

    def cpu(self) -> tuple[float, float]:
        """CPU seconds (user + system) of the service process and of its children."""
        import psutil

        t = self.proc.cpu_times()
        main = t.user + t.system
        kids = 0.0
        for c in self.proc.children(recursive=True):
            try:
                ct = c.cpu_times()
                kids += ct.user + ct.system
            except psutil.Error:
                pass
        return main, kids

    def start_sampling(self) -> None:
        def loop():
            while not self._stop.is_set():
                m, t, _ = self.now()
                self.peak = (max(self.peak[0], m), max(self.peak[1], t))
                time.sleep(0.1)

        self._thread = threading.Thread(target=loop, daemon=True)
        self._thread.start()

    def stop_sampling(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()


# -- the load generator ----------------------------------------------------------------
WAIT = {"Prefer": "wait=30"}


class LeanClient:
    """A minimal HTTP/1.1 keep-alive client on asyncio streams, for the load only.

    At 100 designs/s the load generator shares the two cores with the service and its workers; httpx costs
    ~4 ms of CPU per request here (its transport, headers and response models), as much as the service
    itself, so it measured mostly itself. This one writes a request with one ``write`` and reads a response
    by ``Content-Length`` (the service never answers these requests chunked): ~0.3 ms a request.
    Idle connections are reused, at most ``max_connections`` open."""

    def __init__(self, base: str, max_connections: int = 200):
        from urllib.parse import urlsplit

        u = urlsplit(base)
        self.host, self.port = u.hostname, u.port or 80
        self._idle: list = []
        self._slots = asyncio.Semaphore(max_connections)

    async def request(self, method: str, path: str, body: bytes = b"", headers: dict | None = None):
        """(status, headers with lower-case names, body) of one request; ConnectionError if the connection
        dropped before a full answer (the caller retries with the same Idempotency-Key)."""
        head = [f"{method} {path} HTTP/1.1", f"Host: {self.host}:{self.port}"]
        if body:
            head += ["Content-Type: application/json", f"Content-Length: {len(body)}"]
        head += [f"{k}: {v}" for k, v in (headers or {}).items()]
        raw = ("\r\n".join(head) + "\r\n\r\n").encode() + body
        async with self._slots:
            conn = self._idle.pop() if self._idle else await asyncio.open_connection(self.host, self.port)
            reader, writer = conn
            try:
                writer.write(raw)
                status_and_headers = await reader.readuntil(b"\r\n\r\n")
                lines = status_and_headers.decode("latin-1").split("\r\n")
                status = int(lines[0].split(" ", 2)[1])
                hdrs = {}
                for line in lines[1:]:
                    if line:
                        k, _, v = line.partition(":")
                        hdrs[k.strip().lower()] = v.strip()
                content = await reader.readexactly(int(hdrs.get("content-length", "0")))
            except (asyncio.IncompleteReadError, ConnectionError, OSError) as exc:
                writer.close()
                raise ConnectionError(str(exc)) from None
            if hdrs.get("connection", "").lower() == "close":
                writer.close()
            else:
                self._idle.append(conn)
        return status, hdrs, content

    async def aclose(self) -> None:
        for _, writer in self._idle:
            writer.close()
        self._idle.clear()


async def _submit_and_wait(client: LeanClient, body: bytes, out: list) -> None:
    import json

    t0 = time.perf_counter()
    key = uuid.uuid4().hex  # makes a retry after a dropped keep-alive connection safe
    for attempt in range(3):
        try:
            status, headers, content = await client.request("POST", "/v1/designs", body,
                                                            {"Idempotency-Key": key, **WAIT})
            break
        except ConnectionError:
            if attempt == 2:
                raise
    if status not in (201, 202):
        raise RuntimeError(f"POST returned {status}: {content[:300]!r}")
    item = json.loads(content)
    while item["status"] not in TERMINAL:
        try:
            _, _, content = await client.request("GET", headers["location"], headers=WAIT)
            item = json.loads(content)
        except ConnectionError:
            continue  # a dropped keep-alive connection: ask again
    out.append((time.perf_counter() - t0, item))


async def _with_client(base: str, fn):
    client = LeanClient(base)
    try:
        return await fn(client)
    finally:
        await client.aclose()


def sequential(base: str, body: bytes, n: int) -> list:
    async def fn(client):
        out: list = []
        for _ in range(n):
            await _submit_and_wait(client, body, out)
        return out

    return asyncio.run(_with_client(base, fn))


def closed_loop(base: str, body: bytes, clients: int, jobs: int, time_limit: float):
    async def fn(client):
        out: list = []
        counter = iter(range(jobs))
        deadline = time.perf_counter() + time_limit

        async def one_client():
            for _ in counter:
                if time.perf_counter() > deadline:
                    return
                await _submit_and_wait(client, body, out)

        t0 = time.perf_counter()
        await asyncio.gather(*(one_client() for _ in range(clients)))
        return out, time.perf_counter() - t0

    return asyncio.run(_with_client(base, fn))


def open_loop(base: str, body: bytes, rate: float, seconds: float, time_limit: float):
    async def fn(client):
        out: list = []
        tasks = []
        t0 = time.perf_counter()
        n = int(rate * seconds)
        for i in range(n):
            delay = t0 + i / rate - time.perf_counter()
            if delay > 0:
                await asyncio.sleep(delay)
            tasks.append(asyncio.create_task(_submit_and_wait(client, body, out)))
        done, pending = await asyncio.wait(tasks, timeout=time_limit)
        for t in pending:
            t.cancel()
        return out, time.perf_counter() - t0, n

    return asyncio.run(_with_client(base, fn))


def _server_latency(items: list[dict]) -> list[float]:
    out = []
    for it in items:
        if it.get("finished_at") and it.get("created_at"):
            f = datetime.fromisoformat(it["finished_at"].replace("Z", "+00:00"))
            c = datetime.fromisoformat(it["created_at"].replace("Z", "+00:00"))
            out.append((f - c).total_seconds())
    return out


# -- profile ---------------------------------------------------------------------------
IDLE_LEAVES = ("Condition.wait", "select (selectors", "Queue.get", "_recv (multiprocessing", "_poll (multiprocessing",
               "wait (multiprocessing", "Event.wait", "sleep")
ROLES = (("worker processes: design (run_job)", "worker_main"),
         ("service: dispatcher thread", "Dispatcher._run"),
         ("service: request handlers (threadpool)", "_run_sync_endpoint"),
         ("service: event loop (uvicorn, routing, JSON)", "run_forever"))


def start_profile(pid: int, seconds: float, out: Path) -> subprocess.Popen | None:
    import shutil

    exe = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(exe).exists():
        print("(py-spy not installed: no profile; pip install py-spy)")
        return None
    return subprocess.Popen([exe, "record", "--pid", str(pid), "--subprocesses", "--nonblocking", "--format", "raw",
                             "--rate", "250", "--duration", str(int(seconds)), "--output", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def summarize_profile(path: Path, top: int = 12) -> list[str]:
    """Busy samples by role, and the functions with most busy samples (inclusive) in the service."""
    from collections import Counter

    roles: Counter = Counter()
    funcs: Counter = Counter()
    busy = 0
    for line in path.read_text().splitlines():
        stack, _, n = line.rpartition(" ")
        if not n.isdigit():
            continue
        frames = stack.split(";")
        if any(frames[-1].startswith(p) or p in frames[-1] for p in IDLE_LEAVES):
            continue
        n = int(n)
        busy += n
        role = next((name for name, marker in ROLES if any(marker in f for f in frames)), "other")
        roles[role] += n
        if role != ROLES[0][0]:
            for f in set(frames[1:]):
                if "app/" in f or "sqlalchemy/engine/default.py" in f or "solver/" in f or "pydantic" in f \
                        or "json/" in f or "expm" in f:
                    funcs[f.split(" (")[0] + " (" + f.split(" (")[-1]] += n
    if not busy:
        return ["(no busy samples)"]
    out = [f"busy samples: {busy} (idle waits excluded)"]
    out += [f"  {n / busy * 100:5.1f}%  {r}" for r, n in roles.most_common()]
    out.append("service process, inclusive share of all busy samples:")
    out += [f"  {n / busy * 100:5.1f}%  {f}" for f, n in funcs.most_common(top)]
    return out


# -- one database ---------------------------------------------------------------------
profiles: list[tuple[str, list[str]]] = []


def measure(db_label: str, db_url: str, a, extra_env: dict[str, str] | None = None) -> dict[str, str]:
    body = _paper_lmi()
    tmp = Path(tempfile.mkdtemp(prefix="ncs-service-bench-"))
    server = start_server(db_url, a.workers, tmp / "server.log", extra_env or {})
    rows: dict[str, str] = {}
    try:
        ready_s = server.wait_ready(120)
        ready = server.readyz
        rows["worker processes (default pool)"] = str(ready["workers"]["configured"])
        rows["start -> ready"] = f"{ready_s:.1f} s"
        mem = Memory(server.proc.pid)
        sequential(server.base, body, 3)  # warm: the workers compile the problem once
        time.sleep(1.0)
        m, t, n = mem.now()
        rows["RSS idle: service process"] = f"{m:.0f} MiB"
        rows["RSS idle: service + workers"] = f"{t:.0f} MiB ({n} processes)"

        lat = sequential(server.base, body, a.latency_jobs)
        obs = [x for x, _ in lat]
        srv = _server_latency([it for _, it in lat])
        rows["latency, 1 client: p50 / p95 (observed)"] = f"{pct(obs, 50) * 1e3:.1f} / {pct(obs, 95) * 1e3:.1f} ms"
        rows["latency, 1 client: p50 / p95 (server side)"] = f"{pct(srv, 50) * 1e3:.1f} / {pct(srv, 95) * 1e3:.1f} ms"

        mem.start_sampling()
        spy = None
        if a.profile:
            prof_path = Path(a.profile).with_suffix(f".{db_label.lower()}.txt")
            spy = start_profile(server.proc.pid, a.profile_seconds, prof_path)
        cpu0, wall0, own0 = mem.cpu(), time.perf_counter(), time.process_time()
        out, wall = closed_loop(server.base, body, a.clients, a.jobs, a.time_limit)
        cpu1, wall1, own1 = mem.cpu(), time.perf_counter(), time.process_time()
        if spy is not None:
            spy.wait()
            profiles.append((db_label, summarize_profile(prof_path)))
        ok = [x for x, it in out if it["status"] == "succeeded"]
        rows[f"sustained, {a.clients} clients closed loop: designs/s"] = (
            f"{len(ok) / wall:.1f} ({len(ok)} jobs in {wall:.1f} s)")
        rows["  latency under that load: p50 / p95"] = f"{pct(ok, 50) * 1e3:.0f} / {pct(ok, 95) * 1e3:.0f} ms"
        span = wall1 - wall0
        rows["  CPU during it: service process / workers"] = (
            f"{(cpu1[0] - cpu0[0]) / span * 100:.0f}% / {(cpu1[1] - cpu0[1]) / span * 100:.0f}% of one core")
        if out:
            # CPU seconds / jobs: what bounds the rate on a machine with few cores (the load client is this
            # process: its asyncio clients and the memory sampler).
            rows["  CPU per design: service / workers / load client"] = (
                f"{(cpu1[0] - cpu0[0]) / len(out) * 1e3:.1f} / {(cpu1[1] - cpu0[1]) / len(out) * 1e3:.1f} / "
                f"{(own1 - own0) / len(out) * 1e3:.1f} ms")

        out, wall, n = open_loop(server.base, body, a.rate, a.open_seconds, a.time_limit)
        ok = [x for x, it in out if it["status"] == "succeeded"]
        srv = _server_latency([it for _, it in out])
        rows[f"open loop, {a.rate:g}/s offered for {a.open_seconds:g} s: designs/s"] = (
            f"{len(ok) / wall:.1f} ({len(ok)} of {n} in {wall:.1f} s)")
        rows["  latency: p50 / p95 (observed)"] = f"{pct(ok, 50) * 1e3:.0f} / {pct(ok, 95) * 1e3:.0f} ms"
        rows["  latency: p50 / p95 (server side)"] = f"{pct(srv, 50) * 1e3:.0f} / {pct(srv, 95) * 1e3:.0f} ms"
        mem.stop_sampling()
        rows["RSS peak under load: service process"] = f"{mem.peak[0]:.0f} MiB"
        rows["RSS peak under load: service + workers"] = f"{mem.peak[1]:.0f} MiB"
    finally:
        server.stop()
    return rows



def fresh_databases(db: str, pg_url: str, sqlite_dir: str) -> list:
    """``(label, url, PgDatabase or None)`` per backend asked for (``"sqlite"``, ``"postgresql"``, ``"both"``).

    SQLite: a new file in ``sqlite_dir``; PostgreSQL: a throw-away database on the server of ``pg_url``
    (skipped with a line when ``db="both"`` and the server is not reachable).
    """
    dbs: list[tuple[str, str, PgDatabase | None]] = []
    if db in ("sqlite", "both"):
        dbs.append(("SQLite", f"sqlite:///{sqlite_dir}/ncs.db", None))
    if db in ("postgresql", "both"):
        if pg_reachable(pg_url):
            pg = PgDatabase(pg_url)
            dbs.append(("PostgreSQL", pg.url, pg))
        elif db == "postgresql":
            raise SystemExit(f"PostgreSQL at {pg_url} is not reachable")
        else:
            print(f"(PostgreSQL at {pg_url} not reachable: SQLite only)")
    return dbs

def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.service_bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--db", choices=["sqlite", "postgresql", "both"], default="both")
    p.add_argument("--pg-url", default=os.environ.get("NCS_BENCH_PG_URL", DEFAULT_PG),
                   help="PostgreSQL server to create a throw-away database on (default %(default)s)")
    p.add_argument("--workers", type=int, default=None, help="NCS_WORKERS (default: the service default, CPU count)")
    p.add_argument("--clients", type=int, default=16)
    p.add_argument("--jobs", type=int, default=600, help="jobs of the sustained run (default %(default)s)")
    p.add_argument("--latency-jobs", type=int, default=50)
    p.add_argument("--rate", type=float, default=100.0, help="open-loop offered rate, jobs/s (default %(default)s)")
    p.add_argument("--open-seconds", type=float, default=10.0)
    p.add_argument("--time-limit", type=float, default=120.0, help="cap of each loaded run, seconds")
    p.add_argument("--quick", action="store_true", help="fewer jobs (about 30 s per database)")
    p.add_argument("--compare-fairness", action="store_true",
                   help="measure each database twice in this run: claims oldest first over all owners "
                        "(NCS_FAIR_SCHEDULING=false) and owner by owner in turn (the default)")
    p.add_argument("--dask", action="store_true",
                   help="also measure the Dask backend: a LocalCluster (worker processes, as many as the "
                        "default pool, 1 thread each) and the server with NCS_DASK_SCHEDULER, on SQLite")
    p.add_argument("--profile", metavar="FILE", default=None,
                   help="record the service and its workers with py-spy during the sustained run (raw stacks to "
                        "FILE.<db>.txt) and print where the busy time goes")
    p.add_argument("--profile-seconds", type=float, default=8.0)
    a = p.parse_args(argv)
    if a.quick:
        a.jobs, a.latency_jobs, a.open_seconds = 200, 20, 4.0

    dbs = fresh_databases(a.db, a.pg_url, tempfile.mkdtemp(prefix="ncs-bench-db-"))

    load = os.getloadavg()
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             cwd=REPO).stdout.strip()
    except OSError:
        rev = "?"
    print(f"service benchmark: commit {rev}, python {sys.version.split()[0]}, {os.cpu_count()} cpus, "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; paper example, lmi (plain stability), n_drop = 3", flush=True)
    print(f"machine: {machine_reference()}", flush=True)
    results: list[tuple[str, dict[str, str]]] = []
    t0 = time.perf_counter()
    try:
        for label, url, pg in dbs:
            if not a.compare_fairness:
                results.append((label, measure(label, url, a)))
                continue
            for fair in ("false", "true"):
                run_url = url
                if pg is None:  # a fresh SQLite file per run; PostgreSQL: the same database, emptied by the run
                    run_url = f"sqlite:///{tempfile.mkdtemp(prefix='ncs-bench-db-')}/ncs.db"
                results.append((f"{label}, {'fair' if fair == 'true' else 'FIFO'}",
                                measure(label, run_url, a, {"NCS_FAIR_SCHEDULING": fair})))
        if a.dask:
            from distributed import LocalCluster

            from app.settings import _default_workers

            pythonpath = os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
            with LocalCluster(n_workers=a.workers or _default_workers(), threads_per_worker=1, processes=True,
                              dashboard_address=None, env={"PYTHONPATH": pythonpath}) as cluster:
                url = f"sqlite:///{tempfile.mkdtemp(prefix='ncs-bench-db-')}/ncs.db"
                results.append(("SQLite + Dask", measure("dask", url, a,
                                                         {"NCS_DASK_SCHEDULER": cluster.scheduler_address})))
    finally:
        for _, _, pg in dbs:
            if pg is not None:
                pg.drop()
    keys = list(results[0][1])
    width = max(len(k) for k in keys)
    cols = [max(len(label), *(len(r.get(k, "")) for k in keys)) for label, r in results]
    print()
    print("| " + "measure".ljust(width) + " | " + " | ".join(l.ljust(c) for (l, _), c in zip(results, cols)) + " |")
    print("|-" + "-" * width + "-|-" + "-|-".join("-" * c for c in cols) + "-|")
    for k in keys:
        print("| " + k.ljust(width) + " | " + " | ".join(r.get(k, "").ljust(c) for (_, r), c in zip(results, cols)) + " |")
    print(f"\n(targets: >= 100 designs/s sustained with 16 clients, 1-client p50 <= 15 ms; total {time.perf_counter() - t0:.0f} s)")
    for label, lines in profiles:
        print(f"\nProfile ({label}, py-spy, {a.profile_seconds:g} s of the sustained run):")
        for line in lines:
            print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
