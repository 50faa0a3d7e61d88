"""What runs inside a Dask worker process (see ``app.jobs.dask_executor`` for the service side).

Kept lean on purpose: it imports no web framework and needs no database access;
a Dask worker only needs this package installed (``pip install ncs-design``).

* :func:`run_job` is the task. It reports ``Started`` (worker address and pid) and
  throttled ``Progress`` through Dask's structured events (``Worker.log_event``:
  fire-and-forget, batched, forwarded by the scheduler to the subscribed service;
  the messages travel as plain dicts, ``messages.to_event``),
  and returns the same outcome as a local worker process (``app.compute.worker.execute``)
  carrying the last progress record.
* :func:`request_cancel` is run on the worker by the service (``Client.run``) to
  cancel a running job cooperatively: it sets a flag that the solver callback reads
  at its next iteration, which costs nothing per iteration (no scheduler round trip).
"""

from __future__ import annotations

import dataclasses
import os
import threading
import time
from typing import Any

from app.compute.messages import JobOutcome, Progress, Started, to_event

START_TOPIC = "ncs-design-start"
PROGRESS_TOPIC = "ncs-design-progress"
PROGRESS_EVERY = 0.1  # seconds between progress events of one job

_cancelled: set[str] = set()
_lock = threading.Lock()


def request_cancel(job_id: str) -> bool:
    with _lock:
        _cancelled.add(job_id)
    return True


def _is_cancelled(job_id: str) -> bool:
    with _lock:
        return job_id in _cancelled


def run_job(job_id: str, key: str, request: dict[str, Any]) -> JobOutcome:
    from distributed import get_worker

    from app.compute import tasks
    from app.compute.worker import execute

    worker = get_worker()
    worker.log_event(START_TOPIC, to_event(key, Started(job_id, os.getpid(), worker.address)))
    state: dict[str, Any] = {"last": None, "sent": 0.0}

    def callback(record) -> bool:
        progress = tasks.record_to_dict(record)
        state["last"] = progress
        now = time.monotonic()
        if now - state["sent"] >= PROGRESS_EVERY:
            state["sent"] = now
            worker.log_event(PROGRESS_TOPIC, to_event(key, Progress(job_id, progress)))
        return _is_cancelled(job_id)

    try:
        reply = execute(job_id, request, callback, lambda: _is_cancelled(job_id))
    finally:
        with _lock:
            _cancelled.discard(job_id)
    return dataclasses.replace(reply, progress=state["last"])
