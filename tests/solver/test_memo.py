"""solver.memo.BoundedCache: LRU order, the bound, threads, one computation per key."""

import threading
import time

import pytest

from solver.memo import BoundedCache


def run_threads(worker, n_threads):
    """Run ``worker(t)`` for t = 0..n_threads-1 in threads, and wait for all of them."""
    threads = [threading.Thread(target=worker, args=(t,)) for t in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()


def test_least_recently_used_is_dropped_first():
    cache = BoundedCache(3)
    for key in "abc":
        cache.put(key, key.upper())
    assert cache.get("a") == "A"  # a is now the most recent: b is the oldest
    cache.put("d", "D")
    assert cache.keys() == ["c", "a", "d"]
    assert cache.get("b") is None and cache.get("b", 0) == 0
    cache.put("c", "C2")  # re-storing refreshes the entry and replaces its value
    cache.put("e", "E")
    assert cache.keys() == ["d", "c", "e"] and cache.get("c") == "C2"


def test_the_bound_holds_and_is_positive():
    cache = BoundedCache(5)
    for i in range(100):
        cache.put(i, i * i)
        assert len(cache) == min(i + 1, 5)
    assert cache.keys() == [95, 96, 97, 98, 99] and 94 not in cache and 99 in cache
    with pytest.raises(ValueError):
        BoundedCache(0)


def test_lookup_reports_hits_and_caches_none():
    cache = BoundedCache(2)
    calls = []

    def compute(tag, value):
        return lambda: calls.append(tag) or value

    assert cache.lookup("x", compute("x", None)) == (None, False)
    assert cache.lookup("x", compute("x", None)) == (None, True)  # a stored None is a hit, not a miss
    assert cache.get_or_compute("y", compute("y", 1)) == 1
    assert cache.get_or_compute("y", compute("y", 2)) == 1
    assert calls == ["x", "y"] and (cache.hits, cache.misses) == (2, 2)


def test_a_failed_computation_stores_nothing():
    cache = BoundedCache(2)

    def fail():
        raise KeyError("no")

    with pytest.raises(KeyError):
        cache.get_or_compute("k", fail)
    assert "k" not in cache
    assert cache.get_or_compute("k", lambda: 3) == 3


def test_a_computation_may_ask_for_its_own_key():
    cache = BoundedCache(2)
    outer = cache.get_or_compute("k", lambda: cache.get_or_compute("k", lambda: 1) + 1)
    assert outer == 2 and cache.get("k") == 2


def test_threads_compute_each_key_once():
    cache = BoundedCache(64)
    n_threads, keys = 8, 16
    counts = {k: 0 for k in range(keys)}
    count_lock = threading.Lock()
    start = threading.Barrier(n_threads)
    wrong = []

    def compute(k):
        def run():
            with count_lock:
                counts[k] += 1
            time.sleep(0.001)  # widens the window in which another thread asks for the same key
            return k * 10
        return run

    def worker(offset):
        start.wait()
        for i in range(200):
            k = (i + offset) % keys
            if cache.get_or_compute(k, compute(k)) != k * 10:
                wrong.append(k)

    run_threads(worker, n_threads)
    assert not wrong
    assert counts == {k: 1 for k in range(keys)}  # never computed twice, however the threads interleave
    assert cache.misses == keys and cache.hits == n_threads * 200 - keys


def test_threads_keep_the_bound_and_lru_consistent():
    cache = BoundedCache(7)
    n_threads = 6
    start = threading.Barrier(n_threads)
    wrong = []

    def worker(t):
        start.wait()
        for i in range(2000):
            key = (t * 7 + i) % 23
            cache.put(key, -key)
            got = cache.get(key, -key)  # evicted by another thread meanwhile: the default, same value
            if got != -key:
                wrong.append((key, got))
            if len(cache) > 7:
                wrong.append(("size", len(cache)))

    run_threads(worker, n_threads)
    assert not wrong
    keys = cache.keys()
    assert len(keys) == 7 == len(set(keys)) and all(cache.get(k) == -k for k in keys)
