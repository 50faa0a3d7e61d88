"""Service configuration, read from environment variables with the ``NCS_`` prefix.

Every field can be set as ``NCS_<FIELD_NAME>`` (case-insensitive), e.g.
``NCS_DATABASE_URL=postgresql+psycopg://user@host/db`` or ``NCS_WORKERS=4``.
The README's settings table is generated from the descriptions below.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict


def _default_workers() -> int:
    """The CPU count (the CPUs this process may run on, where the OS tells)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="NCS_", extra="ignore")

    database_url: str = Field(
        "sqlite:///./ncs.db",
        description="SQLAlchemy URL of the job database. Default: an SQLite file `ncs.db` in the "
        "working directory. PostgreSQL: `postgresql+psycopg://user@host:5432/db`.",
    )
    database_busy_timeout: float = Field(
        30.0, gt=0, le=600, description="SQLite: seconds a write waits for the database's write lock (held by "
        "another writer) before giving up with 503 \"locked\". A submission is answered within this plus 5 s.",
    )
    workers: int = Field(
        default_factory=_default_workers, ge=1, le=256,
        description="Number of design worker processes (default: CPU count).",
    )
    sync_workers: int = Field(
        1, ge=1, le=64,
        description="Worker processes that serve the synchronous endpoints "
        "(`/v1/analyses`, `/v1/simulations`, traces).",
    )
    job_time_limit: float = Field(
        300.0, gt=0, description="Wall-clock limit in seconds for one design attempt; a job "
        "over it is stopped and ends `failed`.",
    )
    sync_time_limit: float = Field(
        30.0, gt=0, description="Limit in seconds for one synchronous analysis/simulation.",
    )
    max_attempts: int = Field(
        3, ge=1, le=100,
        description="Attempts per job when its worker process dies or its service is killed; "
        "after that the job ends `failed`.",
    )
    lease_seconds: float = Field(
        15.0, gt=0, description="A running job's lease; the owning service renews it every "
        "lease/3 s. A job whose lease expired (its service died) is queued again.",
    )
    poll_interval: float = Field(
        0.25, gt=0, description="How often (s) the dispatcher looks for queued jobs and cancel requests.",
    )
    cancel_grace: float = Field(
        1.0, ge=0, description="Seconds a running job gets to stop cooperatively after a "
        "cancel before its worker process is killed.",
    )
    api_keys: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="Comma-separated API keys. When set, `/v1` requires `X-API-Key: <key>` "
        "or `Authorization: Bearer <key>`. Empty: no authentication.",
    )
    body_timeout: float = Field(
        20.0, ge=0, description="Seconds a request body may pause (none of it arriving) before the request is "
        "answered 408 and its connection closed; a slow body that keeps arriving is not limited. 0: no limit.",
    )
    max_body_bytes: int = Field(
        1_000_000, ge=1024, description="Largest accepted request body in bytes (413 above).",
    )
    keep_alive: float = Field(
        30.0, gt=0, le=3600, description="Seconds an idle keep-alive connection stays open. Above the clients' own "
        "idle expiry (httpx: 5 s), so a pooled connection is never reused just as the service closes it (at uvicorn's "
        "5 s a loaded client's POST met a closed connection).",
    )
    max_states: int = Field(
        60, ge=1, description="Largest number of states n (lmi designs n = 60, r = 5, n_drop = 10 in 44 s of CPU on "
        "a 2-core machine: README, Service settings).",
    )
    max_inputs: int = Field(20, ge=1, description="Largest number of inputs m.")
    max_modes: int = Field(20, ge=1, description="Largest number of plant modes r.")
    max_n_drop: int = Field(20, ge=1, description="Largest n_drop (bound on consecutive losses + 1).")
    max_lmi_size: int = Field(
        6000, ge=1, description="Largest total LMI size of a design (sum of the block sizes of "
        "all matrix inequalities with M interval modes, M = r n_drop (or r + r^2 + ... + r^n_drop "
        "with per-sample plant switching): `2 n M` for lmi, `2 n n_drop (M + 1)` for ccl, `2 n M^2` for switched).",
    )
    max_simulation_steps: int = Field(10_000, ge=1, description="Largest `steps` of a simulation or trace.")
    cache_max_bytes: int = Field(
        64 * 2**20, ge=0, description="Bytes the service keeps of recent traces, figures and exports (least "
        "recently used first out); an answer over a quarter of it is not kept. 0: keep nothing.",
    )
    max_channel_size: int = Field(
        20_000, ge=1, description="Largest second-moment operator of a channel analysis (`POST /v1/channels`): "
        "the sum over the jump-system modes (channel state, plant mode, buffer age) of the squared state "
        "dimension, at most `c r (n_drop + 1) (2 n)^2`.",
    )
    max_analysis_products: int = Field(
        200_000, ge=1,
        description="Budget of mode products per length that an analysis may enumerate.",
    )
    max_queue_depth: int = Field(
        10_000, ge=1, description="Back-pressure: a design submitted while this many jobs are queued is "
        "refused with 429 and `Retry-After` instead of growing the queue without bound.",
    )
    max_queued_per_owner: int = Field(
        1_000, ge=1, description="Per-owner quota: a job submitted while its API key (or, without keys, the "
        "service's one anonymous owner) has this many jobs queued is refused with 429 naming this limit; other "
        "keys still get in. Keep `NCS_MAX_QUEUE_DEPTH` at least keys x this quota so one key cannot fill the "
        "global queue.",
    )
    max_running_per_owner: int | None = Field(
        None, ge=1, description="Optional cap on the jobs of one API key running at a time over every service "
        "on the database (at most one claim batch more per replica while several claim at once). Empty: no "
        "cap; a key may use every idle worker.",
    )
    fair_scheduling: bool = Field(
        True, description="Claim queued jobs owner by owner in turn (round-robin over the API keys with "
        "queued work, weight 1 each, each key's oldest first). False: oldest first over all keys (one key's "
        "backlog delays everyone).",
    )
    retry_after: int = Field(
        5, ge=1, description="Seconds sent in `Retry-After` with a 429 (queue full) or a 503 (database "
        "unavailable).",
    )
    worker_memory_mb: int = Field(
        4096, ge=0, description="Memory (MB of address space) one job may allocate in a worker process "
        "on top of the warmed-up worker (`RLIMIT_AS`, design and synchronous workers); a design over it ends "
        "`failed` saying so, an analysis or simulation gets a 422. 0: no cap.",
    )
    alembic_dir: Path | None = Field(
        None, description="Directory of the Alembic migration environment (found automatically).",
    )
    dask_scheduler: str | None = Field(
        None, description="Address of a Dask distributed scheduler (e.g. `tcp://10.0.0.5:8786`). When set, "
        "design jobs run on that cluster's workers instead of local worker processes; the database stays "
        "the queue. Empty: the local pool of `NCS_WORKERS` processes.",
    )
    run_dispatcher: bool = Field(
        True, description="Run the job dispatcher and worker pool in this process.",
    )
    host: str = Field("127.0.0.1", description="`ncs-design serve` bind address.")
    port: int = Field(8000, description="`ncs-design serve` port.")

    @field_validator("api_keys", mode="before")
    @classmethod
    def _split_keys(cls, value):
        if value is None:
            return []
        if isinstance(value, str):
            return [k.strip() for k in value.split(",") if k.strip()]
        return value
