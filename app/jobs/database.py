"""Database engine, sessions and migrations.

SQLite gets WAL mode, a busy timeout and explicit transactions: read
sessions begin ``DEFERRED``; write sessions begin ``IMMEDIATE`` so that a
transaction that reads before it writes can never fail with "database is
locked" on a stale snapshot (it waits for the write lock instead, up to the
busy timeout). PostgreSQL uses the same code with its default isolation.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sqlalchemy import create_engine, event, text
from sqlalchemy.engine import Connection, Engine
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session, sessionmaker

SQLITE_BUSY_TIMEOUT_MS = 30_000


def is_sqlite(url: str) -> bool:
    return url.startswith("sqlite")


def make_engine(url: str) -> Engine:
    if is_sqlite(url):
        engine = create_engine(
            url,
            connect_args={"timeout": SQLITE_BUSY_TIMEOUT_MS / 1000, "check_same_thread": False},
            pool_size=20,
            max_overflow=40,
            pool_timeout=60,
        )

        @event.listens_for(engine, "connect")
        def _on_connect(dbapi_conn, _record):
            # Take transaction control away from the sqlite3 module; we emit BEGIN ourselves.
            dbapi_conn.isolation_level = None
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()

        @event.listens_for(engine, "begin")
        def _on_begin(conn):
            if conn.get_execution_options().get("ncs_write"):
                conn.exec_driver_sql("BEGIN IMMEDIATE")
            else:
                conn.exec_driver_sql("BEGIN")

        return engine
    return create_engine(url, pool_size=10, max_overflow=40, pool_pre_ping=True, pool_timeout=60)


def database_reason(exc: BaseException) -> str:
    """A short, safe reason for a database failure (no SQL, no parameters, no credentials)."""
    text = str(getattr(exc, "orig", None) or exc).splitlines()[0] if str(exc) else type(exc).__name__
    low = text.lower()
    if "full" in low or "no space" in low or "quota" in low:
        return "the database is full (no space left for writes)"
    if "readonly" in low or "read-only" in low or "read only" in low or "permission" in low:
        return "the database is read-only"
    if "locked" in low or "timeout" in low or "timed out" in low:
        return "the database is busy"
    return "the database connection failed"


class Database:
    """Engine plus two session factories, ``read()`` and ``write()``, and the same two as plain Core
    connections, ``read_conn()`` and ``write_conn()``, for the store's hot paths (a constant Core statement
    with bound parameters is compiled once; the ORM's unit of work and its per-call statement building cost
    more than the query)."""

    def __init__(self, url: str):
        self.url = url
        self.engine = make_engine(url)
        self._write_engine = self.engine.execution_options(ncs_write=True)
        self._read = sessionmaker(self.engine, expire_on_commit=False)
        self._write = sessionmaker(self._write_engine, expire_on_commit=False)

    @property
    def sqlite(self) -> bool:
        return is_sqlite(self.url)

    @contextmanager
    def write(self) -> Iterator[Session]:
        """A short write transaction: commits on success, rolls back on error."""
        with self._write() as session:
            with session.begin():
                yield session

    @contextmanager
    def write_conn(self) -> Iterator[Connection]:
        """A short write transaction on a Core connection (``BEGIN IMMEDIATE`` on SQLite): commits on
        success, rolls back on error."""
        with self._write_engine.begin() as conn:
            yield conn

    @contextmanager
    def read_conn(self) -> Iterator[Connection]:
        """A read on a Core connection, ended like :meth:`end_read` ends a session: a connection that died
        after the answer was read is discarded, not raised."""
        conn = self.engine.connect()
        try:
            yield conn
        finally:
            try:
                conn.rollback()
            except DBAPIError:
                conn.invalidate()
            finally:
                conn.close()

    @contextmanager
    def read(self) -> Iterator[Session]:
        session = self._read()
        try:
            yield session
        finally:
            self.end_read(session)

    @staticmethod
    def end_read(session: Session) -> None:
        """End a read-only session. Its answer is already computed, so a connection that died meanwhile
        (e.g. the PostgreSQL backend was terminated) must not turn it into an error: the broken connection
        is discarded and the pool opens a new one."""
        try:
            session.rollback()
        except DBAPIError:
            session.invalidate()
        finally:
            session.close()

    def retry_on_disconnect(self, fn, attempts: int = 2):
        """Run ``fn()`` again (once) when its connection turned out to be dead: a database restart or a
        terminated backend costs a retry, not an error. Other errors propagate at once."""
        for i in range(attempts):
            try:
                return fn()
            except DBAPIError as exc:
                if not exc.connection_invalidated or i == attempts - 1:
                    raise

    def ping(self) -> None:
        with self.engine.connect() as conn:
            conn.execute(text("SELECT 1"))
            conn.rollback()

    def dispose(self) -> None:
        self.engine.dispose()


def find_alembic_dir(configured: Path | None = None) -> Path:
    """The migration environment: ``configured`` (NCS_ALEMBIC_DIR), else the installed package's
    ``app/migrations`` (setup.py maps the repository's ``alembic/`` there), else the source tree's
    ``alembic/``, else ``./alembic``."""
    candidates = []
    if configured is not None:
        candidates.append(Path(configured))
    package = Path(__file__).resolve().parent.parent  # app/
    candidates.append(package / "migrations")
    candidates.append(package.parent / "alembic")
    candidates.append(Path.cwd() / "alembic")
    for c in candidates:
        if (c / "env.py").is_file():
            return c
    raise RuntimeError(
        "Alembic migration directory not found (looked in: "
        + ", ".join(str(c) for c in candidates)
        + "); set NCS_ALEMBIC_DIR"
    )


def run_migrations(url: str, alembic_dir: Path | None = None) -> None:
    """Upgrade the database at ``url`` to the newest migration (idempotent)."""
    from alembic import command
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(find_alembic_dir(alembic_dir)))
    cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    cfg.attributes["configure_logger"] = False
    command.upgrade(cfg, "head")
