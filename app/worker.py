"""Design worker process.

One long-lived process per pool slot, started with the ``spawn`` method.
It receives ``("run", job_id, request)`` on its pipe, runs the design and
sends back ``("progress", job_id, record)`` after every solver iteration
and finally ``("done", job_id, result)``, ``("cancelled", job_id)`` or
``("error", job_id, reason)``. A ``("cancel", job_id)`` message makes the
solver callback return True, which stops the design at its next iteration;
the dispatcher kills the process if that takes too long.
"""

from __future__ import annotations

import os
import signal
import sys
import traceback


def _die_with_parent(parent_pid: int) -> None:
    """Linux: get SIGKILL when the service process dies, so no orphan keeps solving."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            PR_SET_PDEATHSIG = 1
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        except Exception:  # pragma: no cover - best effort
            pass
    if os.getppid() != parent_pid:  # parent already gone before prctl took effect
        os._exit(1)


BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def limit_blas_threads() -> None:
    """One BLAS thread per process, unless the environment says otherwise; call before numpy is imported.

    A design works on tiny matrices, and the pool already runs one process per CPU: with
    OpenBLAS's default thread pool, the 3x3 ``expm`` of a zero-order hold took 1-8 ms
    instead of 7 us on a busy 2-core machine (its threads spin and wait for each other),
    two thirds of a paper-example design. Dask's nanny sets the same variables for its workers.
    """
    for var in BLAS_THREAD_VARS:
        os.environ.setdefault(var, "1")


def _address_space() -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:  # pragma: no cover - not Linux
        pass
    return 0


def apply_memory_limit(memory_mb: int) -> int | None:
    """Cap this process's address space (RLIMIT_AS) at its current size plus ``memory_mb`` MB: a job may
    allocate that much beyond the warmed-up worker (numpy, cvxpy and the solvers already mapped). An
    allocation over the cap raises MemoryError in the job (or aborts a native solver) instead of waking the
    OOM killer for the whole machine. Returns the limit in bytes (None when no cap)."""
    if memory_mb <= 0:
        return None
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return None
    limit = _address_space() + memory_mb * 2**20
    _soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    return limit


def memory_message(memory_mb: int, what: str = "job") -> str:
    cap = f"the {memory_mb} MB a worker process may allocate" if memory_mb else "the memory available"
    return f"memory limit exceeded: the {what} needed more than {cap} (NCS_WORKER_MEMORY_MB) and was stopped"


def execute(job_id: str, request: dict, callback, cancelled, memory_mb: int = 0) -> tuple:
    """Run one design; the reply ``("done", id, result)``, ``("cancelled", id)`` or ``("error", id, reason)``.

    Shared by the local worker processes and the Dask task (``app.dask_tasks``).
    """
    from app import tasks

    try:
        from solver import InvalidInput
    except ImportError:  # pragma: no cover
        InvalidInput = ValueError  # type: ignore[assignment]
    try:
        result = tasks.run_job(request, callback)
    except InvalidInput as exc:
        return ("error", job_id, f"invalid input at {'/'.join(map(str, getattr(exc, 'field', ()) or ()))}: {exc}")
    except MemoryError:
        return ("error", job_id, memory_message(memory_mb))
    except Exception as exc:
        tb = traceback.format_exc(limit=5)
        return ("error", job_id, f"solver error: {type(exc).__name__}: {exc}\n{tb}")
    return ("cancelled", job_id) if cancelled() else ("done", job_id, result)


def worker_main(conn, parent_pid: int, memory_mb: int = 0) -> None:
    _die_with_parent(parent_pid)
    # Ctrl-C or a SIGTERM sent to the whole process group is for the service: it shuts down
    # gracefully, gives running jobs back to the queue and then stops (or kills) its workers.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    limit_blas_threads()
    from app import tasks

    tasks.warm_up()
    apply_memory_limit(memory_mb)
    conn.send(("ready", os.getpid()))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg[0] == "stop":
            return
        if msg[0] != "run":
            continue  # a late cancel for a finished job
        _, job_id, request = msg
        state = {"cancel": False}

        def callback(record, job_id=job_id, state=state):
            try:
                while conn.poll():
                    m = conn.recv()
                    if m[0] == "stop" or (m[0] == "cancel" and m[1] == job_id):
                        state["cancel"] = True
                conn.send(("progress", job_id, tasks.record_to_dict(record)))
            except (EOFError, OSError):
                os._exit(0)  # the service is gone
            return state["cancel"]

        reply = execute(job_id, request, callback, lambda state=state: state["cancel"], memory_mb)
        try:
            conn.send(reply)
        except (EOFError, OSError):
            return
