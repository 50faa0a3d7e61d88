"""The synchronous pool: one caller's time limit costs no other caller its answer, and keys take turns.

Both replay the reported incidents deterministically on the pool itself (the worker entry points are stand-ins
from ``sync_pool_tasks``): the order of events is fixed by the queue, not by timing.
"""

from __future__ import annotations

import asyncio

import pytest

from app.jobs.job_errors import ComputeTimeLimit
from app.jobs.sync_pool import SyncPool
from tests.app import sync_pool_tasks


def _pool(workers: int, time_limit: float) -> SyncPool:
    return SyncPool(workers, time_limit, call=sync_pool_tasks.call, initializer=sync_pool_tasks.init)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_time_limit_reaches_only_its_own_request(workers):
    """Key A's heavy call reaches the limit while key B's three small calls wait (issue 33, item 1: they got 500s,
    a dropped connection or a cancelled future). B gets its three answers; A gets the time-limit error."""
    pool = _pool(workers, time_limit=3.0)

    async def scenario():
        # Start the pool's processes first, so the time limit is not spent on a cold start.
        assert await pool.run("echo", "warm", key="B") == "warm"
        heavy = [asyncio.create_task(pool.run("sleep", 3600, "A", key="A")) for _ in range(workers)]
        await asyncio.sleep(0)
        small = [asyncio.create_task(pool.run("echo", f"B{i}", key="B")) for i in range(3)]
        return await asyncio.gather(*heavy, return_exceptions=True), await asyncio.gather(*small,
                                                                                       return_exceptions=True)

    try:
        heavy, small = asyncio.run(scenario())
    finally:
        pool.shutdown()
    assert small == ["B0", "B1", "B2"], small
    assert all(isinstance(h, ComputeTimeLimit) for h in heavy), heavy


def test_keys_take_turns_for_the_slot():
    """Key A queues four calls, then key B one: B's call runs right after A's running call, not after A's backlog
    (issue 33, item 2: B waited 22 to 29 s behind A's channel analyses)."""
    pool = _pool(1, time_limit=60.0)
    done: list[str] = []

    async def one(kind, arg, tag, key):
        out = await pool.run(kind, *arg, key=key)
        done.append(out)

    async def scenario():
        await pool.run("echo", "warm", key="A")
        tasks = []
        for i in range(4):
            tasks.append(asyncio.create_task(one("sleep", (0.2, f"A{i}"), None, "A")))
            await asyncio.sleep(0)
        tasks.append(asyncio.create_task(one("echo", ("B0",), None, "B")))
        await asyncio.gather(*tasks)

    try:
        asyncio.run(scenario())
    finally:
        pool.shutdown()
    assert done == ["A0", "B0", "A1", "A2", "A3"], done


def test_a_cancelled_waiter_gives_its_turn_away():
    pool = _pool(1, time_limit=60.0)

    async def scenario():
        await pool.run("echo", "warm", key="A")
        running = asyncio.create_task(pool.run("sleep", 0.5, "A0", key="A"))
        await asyncio.sleep(0)
        gone = asyncio.create_task(pool.run("echo", "B0", key="B"))
        await asyncio.sleep(0)
        gone.cancel()
        after = asyncio.create_task(pool.run("echo", "C0", key="C"))
        assert pool.waiting() >= 1
        return await running, await after, pool.waiting(), len(pool._free)

    try:
        assert asyncio.run(scenario()) == ("A0", "C0", 0, 1)
    finally:
        pool.shutdown()
