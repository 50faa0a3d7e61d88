"""Database engine, sessions and migrations.

SQLite gets WAL mode, a busy timeout and explicit transactions: read
sessions begin ``DEFERRED``; write sessions begin ``IMMEDIATE`` so that a
transaction that reads before it writes can never fail with "database is
locked" on a stale snapshot (it waits for the write lock instead, up to the
busy timeout). PostgreSQL uses the same code with its default isolation.
"""

from __future__ import annotations

import os
import sqlite3
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pydantic_core import to_json
from sqlalchemy import create_engine, event, text
from sqlalchemy.engine import Connection, Engine, make_url
from sqlalchemy.exc import DBAPIError, DisconnectionError, OperationalError
from sqlalchemy.orm import Session, sessionmaker

SQLITE_BUSY_TIMEOUT_MS = 30_000
#: How long a PostgreSQL connection attempt may take before the server counts as unreachable (s).
PG_CONNECT_TIMEOUT = 10
#: How long the readiness write probe waits for the write lock (s), and how long its answer is reused.
PROBE_TIMEOUT = 1.0
PROBE_EVERY = 1.0
#: A PostgreSQL connection idle in the pool this long (s) is pinged before use even by a path that retries on
#: a dead connection (see make_engine); other paths ping every time (pool_pre_ping).
PING_IDLE = 1.0


def is_sqlite(url: str) -> bool:
    return url.startswith("sqlite")


class _Retried(threading.local):
    active = False  # this thread runs inside Database.retry_on_disconnect


_RETRIED = _Retried()


def json_text(value) -> str:
    """The text of a JSON column (request, progress, result): pydantic-core's encoder, the same document as
    ``json.dumps`` writes (NaN as ``NaN``, other keys as strings) in a tenth of its time (a design's result:
    0.01 instead of 0.1 ms, on the dispatcher's thread of every job); compact, non-ASCII kept as UTF-8."""
    return to_json(value).decode()


def make_engine(url: str, busy_timeout_ms: int = SQLITE_BUSY_TIMEOUT_MS) -> Engine:
    if is_sqlite(url):
        engine = create_engine(
            url,
            json_serializer=json_text,
            connect_args={"timeout": busy_timeout_ms / 1000, "check_same_thread": False},
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
            cur.execute(f"PRAGMA busy_timeout={busy_timeout_ms}")
            cur.execute("PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()

        @event.listens_for(engine, "begin")
        def _on_begin(conn):
            options = conn.get_execution_options()
            if options.get("ncs_write"):
                # A write transaction whose submitters have less than the busy timeout left waits only that
                # long for the write lock (then "database is locked"): no submission waits past its bound.
                busy_ms = options.get("ncs_busy_ms") or busy_timeout_ms
                info = conn.connection.info  # kept with the DBAPI connection in the pool
                if info.get("ncs_busy_ms", busy_timeout_ms) != busy_ms:
                    conn.exec_driver_sql(f"PRAGMA busy_timeout={int(busy_ms)}")
                    info["ncs_busy_ms"] = busy_ms
                conn.exec_driver_sql("BEGIN IMMEDIATE")
            else:
                conn.exec_driver_sql("BEGIN")

        return engine
    connect_args = {"connect_timeout": PG_CONNECT_TIMEOUT} if "psycopg" in url.split(":", 1)[0] else {}
    engine = create_engine(url, pool_size=10, max_overflow=40, pool_timeout=60, connect_args=connect_args,
                           json_serializer=json_text)

    # pool_pre_ping, except for the store's paths that run once more on a fresh connection when theirs is dead
    # (Database.retry_on_disconnect: submit, the dispatcher's write, get, the waiters' reads) while the
    # connection sat in the pool for less than PING_IDLE: under load every connection comes back within
    # milliseconds, and a ping per checkout was one round trip (and a server process's CPU) per transaction.
    # A connection that died meanwhile fails its statement, SQLAlchemy replaces every connection of the pool
    # older than the failure, and the retry runs on a fresh one.
    @event.listens_for(engine, "connect")
    def _on_pg_connect(_dbapi_conn, record):
        record.info["ncs_idle_since"] = time.monotonic()

    @event.listens_for(engine, "checkin")
    def _on_checkin(_dbapi_conn, record):
        if record is not None:
            record.info["ncs_idle_since"] = time.monotonic()

    @event.listens_for(engine, "checkout")
    def _on_checkout(dbapi_conn, record, _proxy):
        if _RETRIED.active and time.monotonic() - record.info.get("ncs_idle_since", -PING_IDLE) < PING_IDLE:
            return
        try:
            alive = engine.dialect.do_ping(dbapi_conn)
        except Exception:  # noqa: BLE001 - any failure: the pool discards it and checks out another
            alive = False
        if not alive:
            raise DisconnectionError("connection found dead by the checkout ping")

    return engine


def unavailable(message: str) -> OperationalError:
    """A database failure raised without a statement (the files refuse writes, a submission's wait ran out),
    answered like any other: 503 with :func:`database_reason` of ``message``."""
    return OperationalError(None, None, sqlite3.OperationalError(message))


def sqlite_files(url: str) -> list[Path]:
    """The files of an SQLite database (the database, its WAL and its WAL index): [] for a memory database."""
    database = make_url(url).database
    if not database or database == ":memory:" or database.startswith("file:"):
        return []
    path = Path(database)
    return [path, Path(f"{path}-wal"), Path(f"{path}-shm")]


def unwritable_file(files: list[Path]) -> Path | None:
    """The first existing file of ``files`` this process cannot write (read-only mode, or immutable: the
    kernel refuses writes to an immutable file even to root, and ``access(W_OK)`` says so), else None."""
    for f in files:
        if not os.access(f, os.W_OK) and f.exists():
            return f
    return None


#: Below this many free bytes on an SQLite database's file system, readiness says "full": a probe that changes
#: nothing succeeds on a full disk (SQLite writes nothing for it), while every real write fails.
MIN_FREE_BYTES = 1 << 20


def free_bytes(path: Path) -> int:
    """Bytes this process may still write on the file system holding ``path`` (root may use the reserve)."""
    st = os.statvfs(path)
    return st.f_frsize * (st.f_bfree if os.geteuid() == 0 else st.f_bavail)


def database_reason(exc: BaseException) -> str:
    """A short, safe reason for a database failure (no SQL, no parameters, no credentials)."""
    text = str(getattr(exc, "orig", None) or exc).splitlines()[0] if str(exc) else type(exc).__name__
    low = text.lower()
    if "full" in low or "no space" in low or "quota" in low:
        return "the database is full (no space left for writes)"
    if "readonly" in low or "read-only" in low or "read only" in low or "permission" in low:
        return "the database is read-only"
    if "locked" in low or "busy" in low:
        return "the database is locked (another writer holds it)"
    if "timeout" in low or "timed out" in low:
        return "the database is busy (timed out)"
    return "the database is unreachable (connection failed)"


class Database:
    """Engine plus two session factories, ``read()`` and ``write()``, and the same two as plain Core
    connections, ``read_conn()`` and ``write_conn()``, for the store's hot paths (a constant Core statement
    with bound parameters is compiled once; the ORM's unit of work and its per-call statement building cost
    more than the query)."""

    def __init__(self, url: str, busy_timeout: float = SQLITE_BUSY_TIMEOUT_MS / 1000):
        self.url = url
        #: SQLite: how long a write waits for the write lock before "database is locked" (s).
        self.busy_timeout = busy_timeout
        self.engine = make_engine(url, int(busy_timeout * 1000))
        self._write_engine = self.engine.execution_options(ncs_write=True)
        # PostgreSQL: a read_conn() read is one statement, its own transaction: no BEGIN and ROLLBACK round trips
        # around it (three round trips became one; each costs the service and a server process CPU).
        self._read_engine = self.engine if is_sqlite(url) else self.engine.execution_options(
            isolation_level="AUTOCOMMIT")
        self._read = sessionmaker(self.engine, expire_on_commit=False)
        self._write = sessionmaker(self._write_engine, expire_on_commit=False)
        self._files = sqlite_files(url) if is_sqlite(url) else []
        self._probe_lock = threading.Lock()
        self._probe: tuple[float, str | None] = (-1e9, None)

    @property
    def sqlite(self) -> bool:
        return is_sqlite(self.url)

    def guard(self) -> None:
        """Refuse to touch the database while an SQLite file cannot be written (read-only or immutable).

        SQLite maps its WAL index (``-shm``) into memory and writes to it even to read; a write to the
        mapping of a file that became immutable is a SIGBUS that ends the process. So no connection is used
        (nor closed: closing checkpoints) until the files are writable again; every caller gets a
        "read-only" OperationalError instead, a 503. Three ``access`` calls, a few microseconds."""
        if self._files:
            bad = unwritable_file(self._files)
            if bad is not None:
                raise unavailable(f"attempt to write a readonly database ({bad.name} is read-only or immutable)")

    @contextmanager
    def write(self) -> Iterator[Session]:
        """A short write transaction: commits on success, rolls back on error."""
        self.guard()
        with self._write() as session:
            with session.begin():
                yield session

    @contextmanager
    def write_conn(self, busy_timeout: float | None = None) -> Iterator[Connection]:
        """A short write transaction on a Core connection (``BEGIN IMMEDIATE`` on SQLite): commits on
        success, rolls back on error. ``busy_timeout`` (s, SQLite): wait at most this long for the write lock
        (default: the database's ``busy_timeout``)."""
        self.guard()
        engine = self._write_engine
        if busy_timeout is not None and self.sqlite:
            engine = engine.execution_options(ncs_busy_ms=max(1, min(int(self.busy_timeout * 1000),
                                                                     int(busy_timeout * 1000))))
        with engine.begin() as conn:
            yield conn

    @contextmanager
    def read_conn(self) -> Iterator[Connection]:
        """A read of ONE statement on a Core connection (on PostgreSQL in autocommit mode: the statement is its
        own transaction), ended like :meth:`end_read` ends a session: a connection that died after the answer
        was read is discarded, not raised."""
        self.guard()
        conn = self._read_engine.connect()
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
        self.guard()
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
        outer, _RETRIED.active = _RETRIED.active, True  # a dead connection costs a retry: no ping needed
        try:
            for i in range(attempts):
                try:
                    return fn()
                except DBAPIError as exc:
                    if not exc.connection_invalidated or i == attempts - 1:
                        raise
        finally:
            _RETRIED.active = outer

    def ping(self) -> None:
        self.guard()
        with self.engine.connect() as conn:
            conn.execute(text("SELECT 1"))
            conn.rollback()

    def write_problem(self) -> str | None:
        """Why the database cannot take a write now (:func:`database_reason`: locked, read-only, unreachable,
        ...), or None when it can. A real write transaction that changes nothing: the write lock within
        :data:`PROBE_TIMEOUT` on SQLite, an UPDATE that a read-only PostgreSQL refuses. The answer is reused
        for :data:`PROBE_EVERY` s, so a load balancer polling ``/readyz`` does not add to a contended lock."""
        with self._probe_lock:
            at, answer = self._probe
            if time.monotonic() - at < PROBE_EVERY:
                return answer
            try:
                def probe() -> None:
                    with self.write_conn(PROBE_TIMEOUT) as conn:
                        if not self.sqlite:
                            conn.exec_driver_sql(f"SET LOCAL statement_timeout = {int(PROBE_TIMEOUT * 1000)}")
                        conn.exec_driver_sql("UPDATE jobs SET id = id WHERE 1 = 0")

                self.retry_on_disconnect(probe)
                answer = None
                if self._files:
                    free = free_bytes(self._files[0].parent)
                    if free < MIN_FREE_BYTES:
                        answer = (f"the database is full (no space left for writes: {free} bytes free on its "
                                  f"file system, under {MIN_FREE_BYTES})")
            except Exception as exc:  # noqa: BLE001 - every failure is a reason not to be ready
                answer = database_reason(exc)
            self._probe = (time.monotonic(), answer)
            return answer

    def dispose(self) -> None:
        if self._files and unwritable_file(self._files) is not None:
            return  # closing would checkpoint into files that refuse writes (SIGBUS): the OS closes them
        self.engine.dispose()


class DatabaseSettingError(Exception):
    """NCS_DATABASE_URL names no usable database; the message is one line naming the setting and the cause."""


def check_database_url(url: str, alembic_dir: Path | None = None) -> None:
    """Connect to the database of ``url`` and migrate it, or raise :class:`DatabaseSettingError` saying in one
    line why not (bad scheme, unreachable server, missing database, unwritable SQLite file), never the
    password."""
    try:
        shown = make_url(url).render_as_string(hide_password=True)
    except Exception:  # noqa: BLE001 - not a URL at all
        raise DatabaseSettingError(f"NCS_DATABASE_URL={url!r} is not a database URL (e.g. sqlite:///./ncs.db or "
                                   "postgresql+psycopg://user@host:5432/db)") from None
    try:
        engine = make_engine(url)
    except Exception as exc:  # noqa: BLE001 - unknown dialect or driver
        cause = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DatabaseSettingError(f"NCS_DATABASE_URL={shown}: unsupported database URL ({cause}); use "
                                   "sqlite:///path or postgresql+psycopg://user@host:5432/db") from None
    try:
        raw = engine.raw_connection()
        try:
            cur = raw.cursor()
            if is_sqlite(url):
                cur.execute("BEGIN IMMEDIATE")  # the file must take writes, not only open
                cur.execute("ROLLBACK")
            else:
                cur.execute("SELECT 1")
            cur.close()
        finally:
            raw.close()
        run_migrations(url, alembic_dir)
    except (DBAPIError, engine.dialect.loaded_dbapi.Error) as exc:
        orig = getattr(exc, "orig", None) or exc
        cause = str(orig).strip().splitlines()
        cause = " ".join(line.strip() for line in cause[:2]) if cause else type(orig).__name__
        hint = " (does the directory exist, and is it writable?)" if is_sqlite(url) else ""
        raise DatabaseSettingError(f"NCS_DATABASE_URL={shown}: cannot use the database: {cause}{hint}") from None
    finally:
        engine.dispose()


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
