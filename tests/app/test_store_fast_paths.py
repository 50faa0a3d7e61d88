"""The store's per-job shortcuts keep their guarantees: JSON columns written by pydantic-core read back as
``json`` would have written them; a PostgreSQL connection is pinged only after sitting idle, and a dead one
still costs a retry, not an error; the dispatcher's wake-up pipe carries one byte per sleep."""

from __future__ import annotations

import json
import os

import pytest
from sqlalchemy import select

from app.jobs import database as database_module
from app.jobs import store
from app.jobs.database import Database, json_text, run_migrations
from app.jobs.tables import Job
from tests.app.conftest import PG_URL, make_settings

DOCUMENTS = [
    {"outcome": "stabilized", "gains": [[[-4.061099088092997, 0.10104535115220498]]], "margin": 1e-06,
     "label": "Motorprüfstand λ", "tiny": 5e-324, "big": 10**30, "flag": True, "none": None},
    {"nan": float("nan"), "inf": float("inf"), "ninf": -float("inf")},
    {1: "int key", 2.5: "float key"},
]


@pytest.mark.parametrize("doc", DOCUMENTS)
def test_json_text_is_the_document_json_writes(doc):
    ours, theirs = json.loads(json_text(doc)), json.loads(json.dumps(doc))
    assert json.dumps(ours, sort_keys=True) == json.dumps(theirs, sort_keys=True)  # NaN compares as text here


def test_json_columns_round_trip_through_the_database(db_url):
    run_migrations(db_url)
    db = Database(db_url)
    try:
        request = {"plant": {"kind": "dc_motor"}, "n_drop": 3, "method": "lmi", "label": "Prüfstand"}
        sub = store.prepare("design", request, 3)
        answers, _, claimed = store.write_batch(db, "me", [sub], [], 60, [None])
        assert claimed and claimed[0].request == request
        result = DOCUMENTS[0]
        _, ended, _ = store.write_batch(db, "me", [], [store.Ending(sub.row.id, "succeeded", result=result)], 60, [])
        assert ended[0] is not None and ended[0].result == result
        with db.read() as s:
            stored = s.execute(select(Job.result, Job.request).where(Job.id == sub.row.id)).one()
        assert stored.result == json.loads(json.dumps(result)) and stored.request == request
    finally:
        db.dispose()


def test_one_wake_byte_per_sleep(db_url):
    from app.jobs.dispatcher import make_dispatcher

    run_migrations(db_url)
    db = Database(db_url)
    try:
        disp = make_dispatcher(db, make_settings(db_url))  # not started: the pipe is read only by _sleep
        for _ in range(50):
            disp.notify()
        assert os.read(disp._wake_r, 4096) == b"x"
        disp._sleep()  # sees nothing more to read (times out after poll_interval): the flag is still set
        disp._wake_pending = False  # as _sleep leaves it after reading the byte
        disp.notify()
        disp._sleep()  # returns at once: the new byte is there
        assert not disp._wake_pending
        disp.notify()
        assert disp._wake_pending and os.read(disp._wake_r, 4096) == b"x"
    finally:
        for fd in (disp._wake_r, disp._wake_w):
            os.close(fd)
        db.dispose()


def test_a_submission_racing_the_pipe_read_keeps_later_wake_ups(db_url, monkeypatch):
    """A caller that writes its byte while the dispatcher empties the pipe must not leave the flag set over an
    empty pipe: every later caller would then skip its byte, and the dispatcher slept a whole poll interval
    with submissions waiting (seen as 250 ms queue waits at 4 clients)."""
    from app.jobs import dispatcher as dispatcher_module
    from app.jobs.dispatcher import make_dispatcher

    run_migrations(db_url)
    db = Database(db_url)
    disp = make_dispatcher(db, make_settings(db_url))  # not started: the pipe is read only by _sleep
    real_read = os.read
    raced = []

    def read_while_a_caller_notifies(fd, n):
        if fd == disp._wake_r and not raced:
            raced.append(True)
            disp.notify()  # another thread hands a submission over right now
        return real_read(fd, n)

    try:
        disp.notify()
        monkeypatch.setattr(dispatcher_module.os, "read", read_while_a_caller_notifies)
        disp._sleep()  # reads both bytes; the racing caller's submission is seen by the tick that follows
        monkeypatch.setattr(dispatcher_module.os, "read", real_read)
        assert raced
        disp.notify()  # a later submission: its byte must be in the pipe
        assert real_read(disp._wake_r, 4096) == b"x"
    finally:
        for fd in (disp._wake_r, disp._wake_w):
            os.close(fd)
        db.dispose()


@pytest.mark.skipif(not PG_URL, reason="needs PostgreSQL (NCS_TEST_DATABASE_URL)")
def test_postgres_pings_only_idle_connections_and_survives_a_dead_one(db_url, monkeypatch):
    from bench.harness import terminate_backends

    run_migrations(db_url)
    db = Database(db_url)
    pings = []
    real_ping = db.engine.dialect.do_ping
    monkeypatch.setattr(db.engine.dialect, "do_ping", lambda conn: pings.append(1) or real_ping(conn))
    try:
        for _ in range(5):  # back-to-back, on a path that retries on a dead connection: no ping
            assert store.finished_among(db, []) == set()
        assert pings == []
        store.queue_depth(db)  # a path that does not retry: pinged as with pool_pre_ping
        assert len(pings) == 1
        monkeypatch.setattr(database_module, "PING_IDLE", 0.0)  # every connection counts as idle
        store.finished_among(db, [])
        assert len(pings) == 2
        monkeypatch.setattr(database_module, "PING_IDLE", 3600.0)  # no pings on retried paths: a dead one is used
        sub = store.prepare("design", {"plant": {}, "n_drop": 3, "method": "lmi"}, 3)
        assert terminate_backends(db_url) >= 1
        answers, _, _ = store.write_batch(db, "me", [sub], [], 60, [])  # retried once on a fresh connection
        assert answers[0].job.id == sub.row.id
        assert terminate_backends(db_url) >= 1
        assert store.get(db, "design", sub.row.id).status == "queued"
        assert len(pings) == 2
    finally:
        db.dispose()



def test_job_watch_asks_the_database_only_about_jobs_its_dispatcher_does_not_hold():
    import asyncio
    import threading

    from app.jobs.watch import JobWatch

    asked: list[list[str]] = []
    finished_elsewhere: set[str] = set()
    held = {"mine"}

    def finished_among(ids):
        asked.append(list(ids))
        return [i for i in ids if i in finished_elsewhere]

    watch = JobWatch(finished_among, poll_interval=0.01, held=lambda ids: [i for i in ids if i in held])

    async def scenario():
        mine = asyncio.ensure_future(watch.wait("mine", 5.0))
        other = asyncio.ensure_future(watch.wait("other", 5.0))
        await asyncio.sleep(0.1)
        assert asked and all(ids == ["other"] for ids in asked)  # "mine" is never asked about
        finished_elsewhere.add("other")  # another replica finished it: the reader finds it
        assert await asyncio.wait_for(other, 2.0) == (True, None)
        assert not mine.done()
        threading.Thread(target=watch.finished, args=("mine", {"status": "succeeded"})).start()  # the dispatcher
        assert await asyncio.wait_for(mine, 2.0) == (True, {"status": "succeeded"})
        held.clear()  # a dispatcher whose thread ended holds nothing: its jobs are asked about again
        late = asyncio.ensure_future(watch.wait("late", 5.0))
        await asyncio.sleep(0.1)
        assert ["late"] in asked
        late.cancel()

    asyncio.run(scenario())
