"""One bounded, thread-safe memo for the library's and the service's per-process caches.

Every cache of results that a later call may reuse (compiled cvxpy problems, the structured IPM's bases and
Schur plans, exact Lyapunov solutions, interval products, ...) is a :class:`BoundedCache`: least recently used
first out past ``maxsize`` entries, one lock, so the threads of a service worker may share it.  What each one
keeps, its bound, and why a hit is always the value a fresh computation would give: docs/design.md §6.1.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any, Callable, Hashable

_MISSING = object()


class _Pending:
    """A value one thread is computing; the other threads that ask for its key wait on ``done``."""

    __slots__ = ("owner", "done", "value", "ok")

    def __init__(self):
        self.owner = threading.get_ident()
        self.done = threading.Event()
        self.value: Any = None
        self.ok = False


class BoundedCache:
    """Least-recently-used cache of at most ``maxsize`` values, safe to share between threads.

    Parameters
    ----------
    maxsize : int
        Number of values kept (>= 1); storing one more drops the least recently used.

    Notes
    -----
    :meth:`lookup` and :meth:`get_or_compute` compute a missing value outside the lock (other keys stay
    readable meanwhile) and at most once per key at a time: threads asking for a key another thread is
    computing wait for that result instead of computing it again.  A computation that raises stores nothing
    (the next caller computes again).  Stored values are shared, not copied: callers keep them read-only.
    ``hits`` and ``misses`` count the lookups answered from the cache and those that computed.
    """

    def __init__(self, maxsize: int):
        if int(maxsize) < 1:
            raise ValueError(f"maxsize must be >= 1, got {maxsize}")
        self.maxsize = int(maxsize)
        self._items: OrderedDict[Hashable, Any] = OrderedDict()
        self._pending: dict[Hashable, _Pending] = {}
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def get(self, key: Hashable, default: Any = None) -> Any:
        """The value stored under ``key`` (now the most recently used), or ``default``."""
        with self._lock:
            value = self._items.get(key, _MISSING)
            if value is _MISSING:
                return default
            self._items.move_to_end(key)
            return value

    def put(self, key: Hashable, value: Any) -> None:
        """Store ``value`` under ``key`` as the most recently used, dropping the least recently used past the bound."""
        with self._lock:
            self._store(key, value)

    def lookup(self, key: Hashable, compute: Callable[[], Any]) -> tuple[Any, bool]:
        """``(value, was_cached)``: the stored value, or ``compute()``'s, stored.

        A thread that asks for a key another thread is computing waits for it (``was_cached`` True); a
        ``compute`` that asks for its own key again computes it without waiting (no deadlock).
        """
        while True:
            with self._lock:
                value = self._items.get(key, _MISSING)
                if value is not _MISSING:
                    self._items.move_to_end(key)
                    self.hits += 1
                    return value, True
                pending = self._pending.get(key)
                if pending is None:
                    pending = self._pending[key] = _Pending()
                    break
                reentered = pending.owner == threading.get_ident()
                if reentered:
                    self.misses += 1
            if reentered:  # asked from its own compute: waiting would never end
                return compute(), False
            pending.done.wait()
            if pending.ok:
                with self._lock:
                    self.hits += 1
                return pending.value, True
            # the computing thread raised: ask again (this thread may compute it)
        try:
            value = compute()
        except BaseException:
            with self._lock:
                del self._pending[key]
            pending.done.set()
            raise
        with self._lock:
            self.misses += 1
            self._store(key, value)
            del self._pending[key]
        pending.value, pending.ok = value, True
        pending.done.set()
        return value, False

    def get_or_compute(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        """The stored value, or ``compute()``'s, stored (:meth:`lookup` without the flag)."""
        return self.lookup(key, compute)[0]

    def _store(self, key: Hashable, value: Any) -> None:  # (lock held)
        self._items[key] = value
        self._items.move_to_end(key)
        while len(self._items) > self.maxsize:
            self._items.popitem(last=False)

    def clear(self) -> None:
        """Drop every value (the counters stay)."""
        with self._lock:
            self._items.clear()

    def keys(self) -> list:
        """The keys, least recently used first."""
        with self._lock:
            return list(self._items)

    def __contains__(self, key: Hashable) -> bool:
        with self._lock:
            return key in self._items

    def __len__(self) -> int:
        with self._lock:
            return len(self._items)
