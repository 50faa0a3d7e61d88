"""The claim's running cap per owner (``NCS_MAX_RUNNING_PER_OWNER``): counted over every dispatcher on the
database, an owner at its cap is skipped (its jobs stay queued, other owners' jobs are claimed), and a finished
job frees its place. SQLite, or PostgreSQL with NCS_TEST_DATABASE_URL."""

from __future__ import annotations

from app.jobs import store
from app.jobs.database import Database, run_migrations

REQUEST = {"plant": {"kind": "dc_motor"}, "n_drop": 3, "method": "lmi"}


def _queue(db: Database, owner: str, n: int) -> list[str]:
    subs = [store.prepare("design", REQUEST, 3, owner=owner) for _ in range(n)]
    answers, _, _ = store.write_batch(db, "nobody", subs, [], 60, [])
    assert all(isinstance(a, store.Submitted) for a in answers), answers
    return [s.row.id for s in subs]


def _owners(claimed: list[store.Claimed], ids: dict[str, list[str]]) -> list[str]:
    return sorted(o for c in claimed for o, mine in ids.items() if c.id in mine)


def test_running_cap_per_owner_holds_over_every_dispatcher(db_url):
    run_migrations(db_url)
    db = Database(db_url)
    try:
        ids = {"a": _queue(db, "a", 5), "b": _queue(db, "b", 2)}
        capped = store.ClaimPolicy(store.OwnerTurns(), max_running_per_owner=2)
        # Four free slots: two of a's (its cap), two of b's.
        _, _, first = store.write_batch(db, "dispatcher-1", [], [], 60, [None] * 4, policy=capped)
        assert _owners(first, ids) == ["a", "a", "b", "b"]
        # Another dispatcher on the same database: a is at its cap there too, b has nothing queued.
        _, _, second = store.write_batch(db, "dispatcher-2", [], [], 60, [None] * 4,
                                         policy=store.ClaimPolicy(store.OwnerTurns(), max_running_per_owner=2))
        assert second == []
        # Without the cap the same dispatcher would take a's queued jobs: the cap, not an empty queue, held them.
        assert store.has_queued(db)
        # One of a's jobs ends: its place goes to a's next job, claimed in the same transaction.
        done = next(c.id for c in first if c.id in ids["a"])
        _, ended, third = store.write_batch(db, "dispatcher-1", [], [store.Ending(done, "succeeded", result={})],
                                            60, [None] * 4, policy=capped)
        assert ended[0] is not None and _owners(third, ids) == ["a"]
        # A cap without turns still skips the owner at its cap.
        uncapped_turns = store.ClaimPolicy(None, max_running_per_owner=3)
        _, _, fourth = store.write_batch(db, "dispatcher-2", [], [], 60, [None] * 4, policy=uncapped_turns)
        assert _owners(fourth, ids) == ["a"]
        _, _, fifth = store.write_batch(db, "dispatcher-2", [], [], 60, [None] * 4, policy=uncapped_turns)
        assert fifth == [] and store.has_queued(db)  # a's fifth job waits: 3 running
    finally:
        db.dispose()
