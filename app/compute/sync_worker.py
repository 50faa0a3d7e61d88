"""A process of the synchronous pool (``app.jobs.sync_pool``): analyses, simulations, traces, plots."""

from __future__ import annotations

import logging
from typing import Any

from app.compute.messages import SyncFailed, SyncInvalid, SyncOutcome, SyncOverMemory, SyncResult
from app.compute.process import apply_memory_limit, die_with_parent, limit_blas_threads

log = logging.getLogger("app.compute.sync_worker")

SYNC_TASKS = {"simulation": "run_simulation", "analysis": "run_analysis", "trace": "run_trace_json",
              "trace_plot": "run_trace_plot", "margin_plot": "run_margin_plot", "gains_file": "run_gains_file",
              "controller_zip": "run_controller_zip", "problem_sdpa": "run_problem_sdpa",
              "channel": "run_channel"}

_memory_mb = 0  # this process's cap (NCS_WORKER_MEMORY_MB), named in an over-cap answer


def init_sync_worker(parent_pid: int, memory_mb: int = 0) -> None:
    global _memory_mb
    limit_blas_threads()
    from app.compute import tasks

    die_with_parent(parent_pid)
    tasks.warm_up()
    apply_memory_limit(memory_mb)
    _memory_mb = memory_mb


def call_sync(task: str, *args: Any) -> SyncOutcome:
    """Entry point of the synchronous pool: never raises for a solver error."""
    from solver import InvalidInput

    from app.compute import tasks

    try:
        return SyncResult(getattr(tasks, SYNC_TASKS[task])(*args))
    except InvalidInput as exc:
        return SyncInvalid(tuple(getattr(exc, "field", ()) or ()), str(exc))
    except MemoryError:  # over the worker's address-space cap (NCS_WORKER_MEMORY_MB)
        return SyncOverMemory(_memory_mb)
    except Exception as exc:  # a genuine solver crash: the details go to the log, a short reason to the caller
        log.exception("the %s task failed", task)
        return SyncFailed(f"the solver stopped with {type(exc).__name__}")
