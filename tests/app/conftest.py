"""Fixtures for the service tests.

Every test database is fresh and migrated by Alembic (never create_all).
SQLite by default; set NCS_TEST_DATABASE_URL to a PostgreSQL URL (e.g.
``postgresql+psycopg://postgres@127.0.0.1:5432/test``) and each fixture
creates its own throw-away database on that server instead.
"""

from __future__ import annotations

import os
import re
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest

warnings.filterwarnings("ignore", message=".*httpx2.*")

from fastapi.testclient import TestClient  # noqa: E402

from app import create_app  # noqa: E402
from app.settings import Settings  # noqa: E402
from bench.harness import Server, free_port, fresh_database  # noqa: E402,F401 (free_port: for the test modules)

PG_URL = os.environ.get("NCS_TEST_DATABASE_URL") or None
REPO = Path(__file__).resolve().parents[2]
TERMINAL = ("succeeded", "failed", "cancelled")


def doc_block(name: str, fence: str) -> tuple[str, str]:
    """(file name, code) of the block fenced ```<fence> between ``<!-- name: start -->`` and ``<!-- name: end -->``.

    The markers may sit in README.md or any docs/*.md (docs move; the examples they mark must keep running), but in
    exactly one place.
    """
    found = []
    for path in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        text = path.read_text()
        for section in text.split(f"<!-- {name}: start -->")[1:]:
            body = section.split(f"<!-- {name}: end -->", 1)[0]
            match = re.search(rf"```{fence}\n(.*?)```", body, re.S)
            assert match, f"no ```{fence} block between the {name} markers of {path.name}"
            found.append((str(path.relative_to(REPO)), match.group(1)))
    assert len(found) == 1, f"the {name} example must be in exactly one place, found {[f for f, _ in found]}"
    return found[0]


@contextmanager
def fresh_database_url(tmp_dir: Path):
    """A URL of an empty database: an SQLite file, or a new PostgreSQL database (``NCS_TEST_DATABASE_URL``)."""
    with fresh_database(PG_URL or None, tmp_dir) as url:
        yield url


def make_settings(url: str, **overrides) -> Settings:
    base = dict(database_url=url, workers=1, lease_seconds=3.0, poll_interval=0.05, job_time_limit=120.0)
    base.update(overrides)
    return Settings(**base)


@contextmanager
def running_client(url: str, **overrides):
    app = create_app(make_settings(url, **overrides))
    with TestClient(app, raise_server_exceptions=False) as client:
        yield client


@pytest.fixture(scope="module")
def module_db(tmp_path_factory):
    with fresh_database_url(tmp_path_factory.mktemp("db")) as url:
        yield url


@pytest.fixture
def db_url(tmp_path):
    with fresh_database_url(tmp_path) as url:
        yield url


def wait_for(client, job_id: str, statuses=TERMINAL, timeout: float = 60.0) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        job = client.get(f"/v1/designs/{job_id}").json()
        if job["status"] in statuses:
            return job
        if time.monotonic() > deadline:
            raise AssertionError(f"job {job_id} still {job['status']} after {timeout} s: {job}")
        time.sleep(0.05)


def worker_pid_of(client, job_id: str, timeout: float = 30.0) -> int:
    """The pid of the process running ``job_id`` (a local worker or a Dask worker), once it started."""
    disp = client.app.state.dispatcher
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        pid = disp.worker_pid(job_id)
        if pid:
            return pid
        time.sleep(0.02)
    raise AssertionError(f"job {job_id} never started within {timeout} s")


def assert_problem(resp, status: int, pointer: str | None = None) -> dict:
    assert resp.status_code == status, resp.text
    assert resp.headers["content-type"].startswith("application/problem+json"), resp.headers
    body = resp.json()
    for key in ("type", "title", "status", "detail", "instance"):
        assert key in body, body
    assert body["status"] == status
    if pointer is not None:
        pointers = [e["pointer"] for e in body.get("errors") or []]
        assert any(p == pointer or p.startswith(pointer + "/") for p in pointers), (pointer, body)
    return body


# -- real server processes (bench/harness.py: the one "start a server, wait for /readyz") --------------

@pytest.fixture
def start_server(tmp_path):
    servers = []

    def start(url: str, **env) -> Server:
        s = Server(url, tmp_path / "server.log", **env)
        servers.append(s)
        s.wait_ready()
        return s

    yield start
    for s in servers:
        s.stop()
