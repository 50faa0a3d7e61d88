"""Design worker process (the local executor, ``app.jobs.dispatcher``).

One long-lived process per pool slot, started with the ``spawn`` method. It receives
:class:`~app.compute.messages.Run` on its pipe, runs the job and sends back a
:class:`~app.compute.messages.Progress` after every solver iteration and finally a
``Succeeded``, ``Cancelled`` or ``Failed``. A ``Cancel`` makes the solver callback return
True, which stops the design at its next iteration; the dispatcher kills the process if that
takes too long.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import signal
import time

from app.compute.messages import (Cancel, Cancelled, Failed, JobOutcome, Lost, Progress, Ready, Run, Stop,
                                  Succeeded)
from app.compute.process import apply_memory_limit, die_with_parent, limit_blas_threads, memory_message

log = logging.getLogger("app.compute.worker")

#: Seconds between the Progress messages of one job (the dispatcher writes progress at most every 0.2 s);
#: the last record travels with the outcome, so a job shorter than this sends none.
PROGRESS_EVERY = 0.1


def failure_reason(exc: BaseException) -> str:
    """What failed, in words a user can act on; the traceback goes to the worker's log, never to the API."""
    first_line = (str(exc).strip().splitlines() or [""])[0][:300]
    from solver import SolverFailed

    if isinstance(exc, SolverFailed):  # the numerics gave up: usually scaling or size, which the user can change
        return (f"the conic solver gave up ({first_line}); try options.solver 'CLARABEL', a smaller n_drop, or the "
                "plant in units where states and inputs are of order 1")
    return (f"the solver stopped with an unexpected {type(exc).__name__}"
            + (f" ({first_line})" if first_line else "")
            + "; the request was valid, so this is a bug worth reporting with the job id")


def execute(job_id: str, request: dict, callback, cancelled, memory_mb: int = 0) -> JobOutcome:
    """Run one job (design or margin search). Shared by the local worker processes and the Dask task
    (``app.compute.dask_task``)."""
    from solver import InvalidInput

    from app.compute import tasks

    try:
        result = tasks.run_job(request, callback)
    except InvalidInput as exc:
        where = "/".join(map(str, getattr(exc, "field", ()) or ()))
        return Failed(job_id, f"invalid input at {where}: {exc}" if where else f"invalid input: {exc}")
    except MemoryError:
        return Failed(job_id, memory_message(memory_mb))
    except Exception as exc:
        log.exception("job %s failed", job_id)
        return Failed(job_id, failure_reason(exc))
    return Cancelled(job_id) if cancelled() else Succeeded(job_id, result)


def outcome_of_death(job_id: str, pid: int | None, exitcode: int | None, memory_mb: int) -> Failed | Lost:
    """What a worker process that died running ``job_id`` means for the job (both executors).

    SIGABRT under a memory cap is a native allocation that failed (e.g. the solver's KKT system): it would
    fail the same way again, so the job ends now, saying why. Any other death may be the machine's or an
    operator's doing: the job is ``Lost`` and may run again."""
    if exitcode == -signal.SIGABRT and memory_mb > 0:
        log.warning("worker process %s aborted running job %s (memory limit)", pid, job_id)
        return Failed(job_id, f"memory limit exceeded: the worker process aborted (exit code {exitcode}) when "
                              f"an allocation over the {memory_mb} MB a job may use (NCS_WORKER_MEMORY_MB) failed")
    log.warning("worker process %s died (exit %s) running job %s", pid, exitcode, job_id)
    return Lost(job_id, f"worker process died (exit code {exitcode})")


def worker_main(conn, parent_pid: int, memory_mb: int = 0) -> None:
    die_with_parent(parent_pid)
    # Ctrl-C or a SIGTERM sent to the whole process group is for the service: it shuts down
    # gracefully, gives running jobs back to the queue and then stops (or kills) its workers.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    limit_blas_threads()
    from app.compute import tasks

    tasks.warm_up()
    apply_memory_limit(memory_mb)
    conn.send(Ready(os.getpid()))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if isinstance(msg, Stop):
            return
        if not isinstance(msg, Run):
            continue  # a late cancel for a finished job
        job_id = msg.job_id
        state = {"cancel": False, "last": None, "sent": time.monotonic()}

        def callback(record, job_id=job_id, state=state):
            state["last"] = record
            try:
                while conn.poll():
                    m = conn.recv()
                    if isinstance(m, Stop) or (isinstance(m, Cancel) and m.job_id == job_id):
                        state["cancel"] = True
                now = time.monotonic()
                if now - state["sent"] >= PROGRESS_EVERY:
                    state["sent"] = now
                    conn.send(Progress(job_id, tasks.record_to_dict(record)))
            except (EOFError, OSError):
                os._exit(0)  # the service is gone
            return state["cancel"]

        reply = execute(job_id, msg.request, callback, lambda state=state: state["cancel"], memory_mb)
        if state["last"] is not None:
            reply = dataclasses.replace(reply, progress=tasks.record_to_dict(state["last"]))
        try:
            conn.send(reply)
        except (EOFError, OSError):
            return
