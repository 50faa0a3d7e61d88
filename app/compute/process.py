"""Setup of every worker process (local design workers, the synchronous pool): die with the service,
one BLAS thread, an address-space cap."""

from __future__ import annotations

import os
import signal
import sys


def die_with_parent(parent_pid: int) -> None:
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
