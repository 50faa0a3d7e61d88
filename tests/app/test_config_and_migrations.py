"""Settings from the environment, Alembic migrations (the only way the schema is made), CLI."""

from __future__ import annotations

import subprocess
import sys

from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import create_engine, inspect

from app.jobs.database import run_migrations
from app.examples import PAPER_GAINS_H01, PAPER_PLANT
from app.jobs.tables import Base
from app.settings import Settings

from .conftest import REPO, assert_problem, running_client


def test_settings_from_environment(monkeypatch):
    monkeypatch.setenv("NCS_DATABASE_URL", "sqlite:////tmp/x.db")
    monkeypatch.setenv("NCS_WORKERS", "3")
    monkeypatch.setenv("NCS_API_KEYS", "a, b,,c")
    monkeypatch.setenv("NCS_JOB_TIME_LIMIT", "12.5")
    s = Settings()
    assert s.database_url == "sqlite:////tmp/x.db" and s.workers == 3
    assert s.api_keys == ["a", "b", "c"] and s.job_time_limit == 12.5


def test_defaults(monkeypatch):
    for var in ("NCS_DATABASE_URL", "NCS_WORKERS", "NCS_API_KEYS"):
        monkeypatch.delenv(var, raising=False)
    s = Settings()
    assert s.database_url == "sqlite:///./ncs.db"
    assert s.workers >= 1 and s.api_keys == []


def test_migrations_create_exactly_the_models_schema_and_are_idempotent(db_url):
    run_migrations(db_url)
    run_migrations(db_url)  # a second start changes nothing
    engine = create_engine(db_url)
    try:
        with engine.connect() as conn:
            assert {"jobs", "alembic_version"} <= set(inspect(conn).get_table_names())
            diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
            assert diff == [], diff
    finally:
        engine.dispose()


def test_cli_help_and_migrate(db_url):
    out = subprocess.run([sys.executable, "-m", "app.cli", "--help"], capture_output=True, text=True, cwd=REPO)
    assert out.returncode == 0 and "serve" in out.stdout
    env = {"NCS_DATABASE_URL": db_url, "PATH": "/usr/bin:/bin"}
    out = subprocess.run([sys.executable, "-m", "app.cli", "migrate"], capture_output=True, text=True, cwd=REPO,
                         env=env)
    assert out.returncode == 0, out.stderr
    assert "up to date" in out.stdout


def test_synchronous_time_limit_is_a_503_problem_and_the_pool_recovers(db_url):
    body = {"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01}
    with running_client(db_url, run_dispatcher=False, sync_time_limit=0.01) as client:
        assert_problem(client.post("/v1/analyses", json=body), 503)
        client.app.state.sync_pool.time_limit = 60
        assert client.post("/v1/analyses", json=body).json()["stable"] is True
