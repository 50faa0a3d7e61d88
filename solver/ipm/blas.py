"""OpenBLAS thread count and glibc heap reuse around a solve (docs/design.md, "The structured interior-point solver")."""

from __future__ import annotations

import contextlib
import ctypes

__all__ = ["blas_threads", "heap_reuse"]


_BLAS = None


def _blas_controls() -> list:
    """(get, set) pairs of every OpenBLAS loaded in this process (numpy's and scipy's are separate)."""
    global _BLAS
    if _BLAS is not None:
        return _BLAS
    _BLAS = []
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({ln.split()[-1] for ln in fh if "openblas" in ln.lower() and ln.split()[-1].startswith("/")})
    except OSError:
        paths = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for suffix in ("64_", "", "_"):
            for stem in ("scipy_openblas", "openblas"):
                try:
                    get = getattr(lib, f"{stem}_get_num_threads{suffix}")
                    set_ = getattr(lib, f"{stem}_set_num_threads{suffix}")
                except AttributeError:
                    continue
                get.restype = ctypes.c_int
                set_.argtypes = [ctypes.c_int]
                _BLAS.append((get, set_))
                break
            else:
                continue
            break
    return _BLAS


@contextlib.contextmanager
def blas_threads(n: int | None):
    """Run a block with ``n`` OpenBLAS threads (None: leave as is), restoring them after.

    The IPM's BLAS calls are many and small (k = 2n <= 64): on a loaded
    2-core machine OpenBLAS's threads spin against each other and one
    solve took 10-20x longer than single-threaded (measured: n = 12,
    11.5 s vs 0.7 s), so the solver runs single-threaded by default.
    """
    controls = _blas_controls() if n is not None else []
    saved = [get() for get, _ in controls]
    for _, set_ in controls:
        set_(int(n))
    try:
        yield
    finally:
        for (_, set_), old in zip(controls, saved):
            set_(old)


_LIBC = None
#: glibc ``mallopt`` parameters (malloc.h).
_M_TRIM_THRESHOLD, _M_MMAP_MAX = -1, -4


def _libc():
    global _LIBC
    if _LIBC is None:
        try:
            lib = ctypes.CDLL("libc.so.6")
            lib.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
            lib.malloc_trim.argtypes = [ctypes.c_size_t]
            _LIBC = lib
        except (OSError, AttributeError):
            _LIBC = False
    return _LIBC


@contextlib.contextmanager
def heap_reuse(enabled: bool = True):
    """Keep freed large arrays in the heap for the block's duration, then hand them back.

    glibc serves arrays above its mmap threshold (128 kB to 32 MB) by fresh ``mmap`` and unmaps them on
    free, so every iteration's temporaries (the Schur matrix, the Kronecker pieces: tens of MB at
    n = 50) fault in their pages again: at n = 50, r = 5, n_drop = 10 that was 456 000 page faults and
    a third of the CPU time, as system time.  Inside this block large allocations come from the heap
    and freed memory stays there for the next iteration; ``malloc_trim`` returns it at the end.
    A no-op where glibc is absent.
    """
    lib = _libc() if enabled else False
    if not lib:
        yield
        return
    lib.mallopt(_M_MMAP_MAX, 0)
    lib.mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)
    try:
        yield
    finally:
        lib.mallopt(_M_MMAP_MAX, 65536)  # glibc's default
        lib.mallopt(_M_TRIM_THRESHOLD, 128 * 1024)
        lib.malloc_trim(0)
