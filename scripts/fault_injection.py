"""Fault injection against the real service: every scenario counts jobs accepted, finished and lost
(lost must be 0) and measures the time to recover.

    python scripts/fault_injection.py [--database-url URL] [--jobs 100] [--only worker_kill,...]

Scenarios (each on a fresh database: an SQLite file, or a throw-away PostgreSQL database on the server of
``--database-url``):

* ``worker_kill``   SIGKILL a design worker process mid-job (3 times); the job is retried on a new worker.
* ``service_kill``  SIGKILL the service with ``--jobs`` jobs queued and running, restart it on the same database.
* ``disk_full``     (SQLite) ``PRAGMA max_page_count`` pinned to the current size on every connection: writes fail
                    with 503 problem+json + Retry-After, reads go on, nothing half-written; then space returns.
* ``read_only``     every connection read-only (SQLite ``PRAGMA query_only``; PostgreSQL
                    ``default_transaction_read_only``): same expectations as a full disk.
* ``pg_loss``       (PostgreSQL) ``pg_terminate_backend`` on all of the service's connections, 3 times, while
                    clients submit and poll; the pool reconnects (pool_pre_ping).
* ``pg_restart``    (PostgreSQL, local server, needs root) the PostgreSQL server restarted twice
                    (``pg_ctlcluster ... restart``) under the same load: requests meanwhile get 503 problem+json,
                    no accepted job is lost, the service recovers without a restart.

Only loopback traffic; every loop is bounded in count and time. The tests in tests/app/test_faults.py run
short variants of the same functions.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.harness import (FAST, SLOW, TERMINAL, Server, ensure_postgres_running, fresh_database,  # noqa: E402
                     restart_postgres, terminate_backends, wait_all)

from sqlalchemy import event, func, select, text  # noqa: E402

from app.jobs.database import Database  # noqa: E402
from app.jobs.tables import Job  # noqa: E402


def local_postgres() -> bool:
    """Whether the PostgreSQL server can be restarted from here (pg_ctlcluster, as root)."""
    return os.path.isdir("/etc/postgresql") and os.geteuid() == 0 and bool(os.listdir("/etc/postgresql"))


def _counts(url: str) -> dict[str, int]:
    db = Database(url)
    try:
        with db.read() as s:
            return dict(s.execute(select(Job.status, func.count()).group_by(Job.status)).all())
    finally:
        db.dispose()


def _summary(accepted: list[str], done: dict[str, dict]) -> dict:
    statuses = [j["status"] for j in done.values()]
    return {"accepted": len(accepted), "finished": len(done), "succeeded": statuses.count("succeeded"),
            "failed": statuses.count("failed"), "lost": len(accepted) - len(done)}


# -- 1. SIGKILL a worker mid-job --------------------------------------------------------------------------------

def worker_kill(url: str, workdir: Path, kills: int = 3, fast_jobs: int = 10) -> dict:
    server = Server(url, workdir / "worker_kill.log", NCS_WORKERS=2, NCS_MAX_ATTEMPTS=kills + 1,
                    NCS_POLL_INTERVAL=0.05)
    try:
        server.wait_ready()
        db = Database(url)
        recover: list[float] = []
        with httpx.Client(base_url=server.base, timeout=30) as c:
            slow = c.post("/v1/designs", json=SLOW).json()["id"]
            accepted = [slow] + [c.post("/v1/designs", json=FAST).json()["id"] for _ in range(fast_jobs)]
            for k in range(kills):
                deadline = time.monotonic() + 60
                while True:  # the slow job running on a known worker process, attempt k + 1
                    with db.read() as s:
                        row = s.get(Job, slow)
                        pid, attempts, status = row.worker_pid, row.attempts, row.status
                    if status == "running" and pid and attempts == k + 1:
                        break
                    if time.monotonic() > deadline:
                        raise RuntimeError(f"slow job not running (attempt {k + 1}): {status}")
                    time.sleep(0.02)
                os.kill(pid, signal.SIGKILL)
                t_kill = time.monotonic()
                while True:  # until the job runs again on a fresh worker (or finished)
                    with db.read() as s:
                        row = s.get(Job, slow)
                        status, attempts, new_pid = row.status, row.attempts, row.worker_pid
                    if (status == "running" and attempts == k + 2 and new_pid and new_pid != pid) \
                            or status in TERMINAL:
                        recover.append(time.monotonic() - t_kill)
                        break
                    if time.monotonic() - t_kill > 60:
                        raise RuntimeError("killed job never restarted")
                    time.sleep(0.02)
            done = wait_all(c, accepted, timeout=180)
        db.dispose()
        out = _summary(accepted, done)
        out.update(kills=kills, slow_job_attempts=done.get(slow, {}).get("attempts"),
                   recover_s_max=round(max(recover), 2), recover_s_mean=round(sum(recover) / len(recover), 2))
        return out
    finally:
        server.stop()


# -- 2. SIGKILL the service with jobs queued and running, restart -------------------------------------------------

def service_kill(url: str, workdir: Path, jobs: int = 100, slow_jobs: int = 4) -> dict:
    env = dict(NCS_WORKERS=2, NCS_LEASE_SECONDS=2, NCS_POLL_INTERVAL=0.05)
    server = Server(url, workdir / "service_kill.log", **env)
    try:
        server.wait_ready()
        with httpx.Client(base_url=server.base, timeout=30) as c:
            accepted = [c.post("/v1/designs", json=SLOW if i < slow_jobs else FAST).json()["id"]
                        for i in range(jobs)]
        at_kill = _counts(url)
        children = server.worker_pids()
        server.kill()  # SIGKILL: no shutdown handler runs
        t_kill = time.monotonic()
    finally:
        server.stop()
    deadline = time.monotonic() + 10
    while any(os.path.exists(f"/proc/{p}") and open(f"/proc/{p}/stat").read().split()[2] != "Z"
              for p in children if os.path.exists(f"/proc/{p}/stat")) and time.monotonic() < deadline:
        time.sleep(0.05)
    again = Server(url, workdir / "service_kill_restart.log", **env)
    try:
        ready_s = again.wait_ready()
        t_ready = time.monotonic()
        with httpx.Client(base_url=again.base, timeout=30) as c:
            done = wait_all(c, accepted, timeout=300)
        t_all = time.monotonic()
    finally:
        again.stop()
    out = _summary(accepted, done)
    out.update(at_kill={k: v for k, v in at_kill.items()}, retried=sum(1 for j in done.values() if j["attempts"] > 1),
               restart_to_ready_s=round(ready_s, 2), kill_to_all_finished_s=round(t_all - t_kill, 2),
               ready_to_all_finished_s=round(t_all - t_ready, 2))
    return out


# -- 3/4. full disk, read-only database -----------------------------------------------------------------------

class DatabaseFault:
    """Makes every connection of a service's engine refuse writes until ``clear()``: SQLite's max_page_count
    pinned to the file's current size ("full"), or a read-only connection ("read_only")."""

    def __init__(self, engine, kind: str):
        self.engine, self.kind, self.active = engine, kind, False
        self.sqlite = engine.dialect.name == "sqlite"
        self.default_pages: int | None = None
        event.listen(engine, "checkout", self._on_checkout)

    def _on_checkout(self, dbapi_conn, _record, _proxy):
        cur = dbapi_conn.cursor()
        try:
            if self.kind == "full":
                if self.default_pages is None:
                    cur.execute("PRAGMA max_page_count")
                    self.default_pages = cur.fetchone()[0]
                # Asking for 1 page pins the limit to the current number of pages: no new page can be added.
                cur.execute(f"PRAGMA max_page_count = {1 if self.active else self.default_pages}")
            elif self.sqlite:
                cur.execute(f"PRAGMA query_only = {1 if self.active else 0}")
            else:
                cur.execute(f"SET default_transaction_read_only = {'on' if self.active else 'off'}")
                dbapi_conn.commit()
        finally:
            cur.close()

    def set(self) -> None:
        self.active = True

    def clear(self) -> None:
        self.active = False

    def remove(self) -> None:
        event.remove(self.engine, "checkout", self._on_checkout)


def _is_problem(r: httpx.Response) -> bool:
    try:
        body = r.json()
    except ValueError:
        return False
    return (r.headers.get("content-type", "").startswith("application/problem+json")
            and body.get("status") == r.status_code and "title" in body)


def database_fault(url: str, kind: str, submissions: int = 40, baseline: int = 5) -> dict:
    """In-process service (real dispatcher and worker processes) with a database that stops taking writes."""
    from fastapi.testclient import TestClient

    from app import create_app
    from app.settings import Settings

    settings = Settings(database_url=url, workers=1, poll_interval=0.05, lease_seconds=5)
    app = create_app(settings)
    with TestClient(app, raise_server_exceptions=False) as c:
        accepted = [c.post("/v1/designs", json=FAST).json()["id"] for _ in range(baseline)]
        wait_all(c, accepted, timeout=120)
        fault = DatabaseFault(app.state.db.engine, kind)
        accepted.append(c.post("/v1/designs", json=SLOW).json()["id"])  # running (or queued) when the fault hits
        fault.set()
        t_fault = time.monotonic()
        refused, bad, reads_ok, other = 0, [], 0, []
        for i in range(submissions):
            r = c.post("/v1/designs", json=FAST)
            if r.status_code == 202:
                accepted.append(r.json()["id"])
            elif r.status_code == 503 and _is_problem(r) and r.headers.get("retry-after"):
                refused += 1
            else:
                bad.append((r.status_code, r.text[:200]))
            g = c.get(f"/v1/designs/{accepted[0]}")
            reads_ok += g.status_code == 200
        detail = None
        r = c.post("/v1/designs", json=FAST)
        if r.status_code == 503:
            detail = r.json()["detail"]
        elif r.status_code == 202:
            accepted.append(r.json()["id"])
        time.sleep(1.0)  # the dispatcher meets the fault too (claims, progress, results)
        # Nothing half-written: the table holds exactly the accepted jobs, and the file is intact.
        with app.state.db.engine.connect() as conn:
            rows = conn.execute(select(func.count()).select_from(Job)).scalar_one()
            ids = set(conn.execute(select(Job.id)).scalars())
            integrity = (conn.execute(text("PRAGMA integrity_check")).scalar_one()
                         if fault.sqlite else "n/a (PostgreSQL)")
            conn.rollback()
        readyz_during = c.get("/readyz").json()
        fault.clear()
        t_clear = time.monotonic()
        while True:  # time until a write is accepted again
            r = c.post("/v1/designs", json=FAST)
            if r.status_code == 202:
                accepted.append(r.json()["id"])
                break
            if time.monotonic() - t_clear > 60:
                raise RuntimeError(f"no recovery: {r.status_code} {r.text}")
            time.sleep(0.05)
        write_recovered_s = time.monotonic() - t_clear
        done = wait_all(c, accepted, timeout=180)
        all_done_s = time.monotonic() - t_clear
        fault.remove()
    out = _summary(accepted, done)
    out.update(kind=kind, fault_seconds=round(t_clear - t_fault, 2), refused_503=refused, unexpected=bad,
               reads_ok_during_fault=f"{reads_ok}/{submissions}", rows_match_accepted=(ids == set(accepted[:-1]))
               and rows == len(accepted) - 1, integrity=integrity, detail=detail,
               readyz_during=readyz_during.get("workers", {}).get("last_error"),
               write_recovered_s=round(write_recovered_s, 3), clear_to_all_finished_s=round(all_done_s, 2))
    return out


# -- 5. PostgreSQL connection loss ---------------------------------------------------------------------------

def pg_loss(url: str, workdir: Path, terminations: int = 3, interval: float = 2.0, clients: int = 4,
            restart: bool = False) -> dict:
    """Connections lost while clients submit and poll: ``pg_terminate_backend`` on every connection of the
    service, or (``restart``) the whole PostgreSQL server restarted, which also refuses connections for a
    while (those requests get 503 problem+json; none may get anything else, no accepted job may be lost)."""
    server = Server(url, workdir / ("pg_restart.log" if restart else "pg_loss.log"), NCS_WORKERS=2,
                    NCS_POLL_INTERVAL=0.05)
    try:
        server.wait_ready()
        accepted: list[str] = []
        codes: dict[int, int] = {}
        non_problem: list[str] = []
        ok_times: list[float] = []  # monotonic time of every successful write
        lock = threading.Lock()
        stop = threading.Event()

        def client_loop():
            with httpx.Client(base_url=server.base, timeout=30) as c:
                for _ in range(2000):  # bounded
                    if stop.is_set():
                        return
                    try:
                        r = c.post("/v1/designs", json=FAST)
                    except httpx.HTTPError as exc:
                        with lock:
                            non_problem.append(f"POST: {type(exc).__name__}: {exc}")
                        continue
                    with lock:
                        codes[r.status_code] = codes.get(r.status_code, 0) + 1
                        if r.status_code == 202:
                            accepted.append(r.json()["id"])
                            ok_times.append(time.monotonic())
                        elif not _is_problem(r):
                            non_problem.append(r.text[:200])
                    if accepted:
                        try:
                            g = c.get(f"/v1/designs/{accepted[-1]}")
                        except httpx.HTTPError as exc:
                            with lock:
                                non_problem.append(f"GET: {type(exc).__name__}: {exc}")
                            continue
                        with lock:
                            codes[g.status_code] = codes.get(g.status_code, 0) + 1
                    time.sleep(0.02)

        threads = [threading.Thread(target=client_loop) for _ in range(clients)]
        for t in threads:
            t.start()
        time.sleep(interval)
        kills, recover = [], []
        for _ in range(terminations):
            t0 = time.monotonic()
            kills.append(round(restart_postgres(), 2) if restart else terminate_backends(url))
            if restart:
                t0 = time.monotonic()  # recovery counts from the moment the server accepts connections again
            deadline = t0 + 30
            while time.monotonic() < deadline:
                with lock:
                    if any(t > t0 for t in ok_times):
                        recover.append(min(t for t in ok_times if t > t0) - t0)
                        break
                time.sleep(0.01)
            time.sleep(interval)
        stop.set()
        for t in threads:
            t.join(60)
        with httpx.Client(base_url=server.base, timeout=30) as c:
            done = wait_all(c, accepted, timeout=180)
            ready = c.get("/readyz").status_code
        out = _summary(accepted, done)
        errors = sum(v for k, v in codes.items() if k >= 500 and not (restart and k == 503)) + len(non_problem)
        out.update(terminations=terminations, backends_terminated=kills, status_codes=codes,
                   errors_5xx=errors, non_problem_errors=non_problem,
                   recover_s_max=round(max(recover), 3) if recover else None, readyz_after=ready,
                   log_tracebacks=server.log_text().count("Traceback"),
                   log_unhandled=sum(server.log_text().count(m) for m in ("unhandled error",
                                                                           "Exception in ASGI application")))
        return out
    finally:
        server.stop()
        if restart:
            ensure_postgres_running()


SCENARIOS = ("worker_kill", "service_kill", "disk_full", "read_only", "pg_loss", "pg_restart")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--database-url", default=None, help="PostgreSQL server URL (a fresh database is made on it); "
                    "default: SQLite files")
    ap.add_argument("--jobs", type=int, default=100, help="jobs queued and running when the service is killed")
    ap.add_argument("--only", default=",".join(SCENARIOS))
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    args = ap.parse_args()
    pg = bool(args.database_url) and not args.database_url.startswith("sqlite")
    results = {}
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        for name in args.only.split(","):
            if name == "disk_full" and pg:
                continue
            if name in ("pg_loss", "pg_restart") and not pg:
                continue
            with fresh_database(args.database_url, work) as url:
                t0 = time.monotonic()
                if name == "worker_kill":
                    res = worker_kill(url, work)
                elif name == "service_kill":
                    res = service_kill(url, work, jobs=args.jobs)
                elif name == "disk_full":
                    res = database_fault(url, "full")
                elif name == "read_only":
                    res = database_fault(url, "read_only")
                elif name == "pg_loss":
                    res = pg_loss(url, work)
                elif name == "pg_restart":
                    res = pg_loss(url, work, terminations=2, restart=True)
                else:
                    raise SystemExit(f"unknown scenario {name}")
                res["scenario_s"] = round(time.monotonic() - t0, 1)
            results[name] = res
            if not args.json:
                print(f"{name}: " + json.dumps(res), flush=True)
    if args.json:
        print(json.dumps(results, indent=2))
    lost = sum(r["lost"] for r in results.values())
    print(f"== database: {'PostgreSQL' if pg else 'SQLite'}; jobs lost in all scenarios: {lost}")
    return 1 if lost else 0


if __name__ == "__main__":
    sys.exit(main())
