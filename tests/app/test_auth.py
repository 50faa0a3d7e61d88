"""Access control: API keys on every /v1 endpoint, jobs visible only to their creator (404 for others),
constant-time comparison, keys never stored or logged, random ids, loopback by default without keys."""

from __future__ import annotations

import logging
import uuid

import httpx
import pytest
from sqlalchemy import select

from app.cli import access_notice
from app.jobs.database import Database
from app.api.deps import match_key, owner_of
from app.examples import PAPER_GAINS_H01, PAPER_PLANT
from app.jobs.tables import Job

from .conftest import assert_problem, running_client, wait_for

KEY_A = "alpha-" + uuid.uuid4().hex
KEY_B = "bravo-" + uuid.uuid4().hex
A = {"X-API-Key": KEY_A}
B = {"Authorization": f"Bearer {KEY_B}"}
DESIGN = {"plant": PAPER_PLANT, "n_drop": 3, "method": "lmi"}
ANALYSIS = {"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01}
SIM = {**ANALYSIS, "x0": [-3.0, 2.0], "steps": 20}


@pytest.fixture(scope="module")
def client(module_db):
    with running_client(module_db, workers=1, api_keys=f"{KEY_A},{KEY_B}") as c:
        yield c


def _operations(client):
    spec = client.get("/openapi.json").json()
    for path, ops in spec["paths"].items():
        for method in ops:
            yield path, method.upper()


def test_every_endpoint_but_health_and_docs_needs_a_key(client):
    fake = str(uuid.uuid4())
    checked = 0
    for path, method in _operations(client):
        url = path.replace("{job_id}", fake).replace("{fmt}", "svg")
        if path in ("/healthz", "/readyz"):
            assert client.request(method, url).status_code in (200, 503)  # 503: workers still starting
            continue
        if path.startswith("/problems"):  # the pages problem types point at: documentation, open to all
            assert client.request(method, url.replace("{slug}", "not-found")).status_code == 200
            continue
        assert path.startswith("/v1/"), path
        for headers in ({}, {"X-API-Key": "wrong"}, {"Authorization": "Bearer wrong"},
                        {"X-API-Key": KEY_A[:-1]}, {"X-API-Key": ""}):
            body = assert_problem(client.request(method, url, headers=headers, json={}), 401)
            assert KEY_A not in str(body)
        checked += 1
    assert checked >= 8
    for path in ("/docs", "/redoc", "/openapi.json"):
        assert client.get(path).status_code == 200
    spec = client.get("/openapi.json").json()
    assert "APIKeyHeader" in spec["components"]["securitySchemes"]
    assert "401" in spec["paths"]["/v1/designs"]["post"]["responses"]


def test_jobs_are_visible_only_to_the_key_that_created_them(client):
    resp = client.post("/v1/designs", json=DESIGN, headers=A)
    assert resp.status_code == 202, resp.text
    job_id = resp.json()["id"]
    assert uuid.UUID(job_id).version == 4
    client.headers.update(A)  # wait_for polls as the owner
    try:
        assert wait_for(client, job_id)["status"] == "succeeded"
    finally:
        del client.headers["X-API-Key"]
    # The owner sees it everywhere ...
    assert client.get(f"/v1/designs/{job_id}/trace?steps=20", headers=A).status_code == 200
    assert [j["id"] for j in client.get("/v1/designs", headers=A).json()["items"]] == [job_id]
    # ... another key gets exactly what an unknown id gets: 404, not 403.
    unknown = str(uuid.uuid4())
    for suffix, method in (("", "GET"), ("/trace", "GET"), ("/events", "GET"), ("/cancel", "POST")):
        theirs = assert_problem(client.request(method, f"/v1/designs/{job_id}{suffix}", headers=B), 404)
        nothing = assert_problem(client.request(method, f"/v1/designs/{unknown}{suffix}", headers=B), 404)
        assert theirs["title"] == nothing["title"] and theirs["type"] == nothing["type"]
    listing = client.get("/v1/designs", headers=B).json()
    assert listing["total"] == 0 and listing["items"] == []
    assert client.get("/v1/designs?status=succeeded", headers=B).json()["total"] == 0
    # B's cancel did nothing.
    assert client.get(f"/v1/designs/{job_id}", headers=A).json()["cancel_requested"] is False
    # Synchronous endpoints accept either key.
    assert client.post("/v1/analyses", json=ANALYSIS, headers=B).status_code == 200
    assert client.post("/v1/simulations", json=SIM, headers=A).status_code == 200


def test_idempotency_keys_are_per_api_key(client):
    h = {"Idempotency-Key": "shared-" + uuid.uuid4().hex}
    a1 = client.post("/v1/designs", json=DESIGN, headers={**A, **h}).json()["id"]
    a2 = client.post("/v1/designs", json=DESIGN, headers={**A, **h}).json()["id"]
    b1 = client.post("/v1/designs", json=DESIGN, headers={**B, **h})
    assert b1.status_code == 202 and a1 == a2 and b1.json()["id"] != a1
    assert "idempotent-replayed" not in b1.headers


def test_ids_are_random_uuid4(client):
    ids = [client.post("/v1/designs", json=DESIGN, headers=A).json()["id"] for _ in range(5)]
    assert all(uuid.UUID(i).version == 4 for i in ids)
    assert len({i[:8] for i in ids}) == 5  # not sequential, not time-ordered prefixes


def test_keys_are_stored_hashed_and_never_logged(client, module_db, caplog):
    caplog.set_level(logging.DEBUG)
    client.post("/v1/designs", json=DESIGN, headers=A)
    client.get("/v1/designs", headers={"X-API-Key": KEY_B + "x"})
    client.get("/v1/designs/not-a-job", headers=B)
    db = Database(module_db)
    try:
        with db.read() as s:
            owners = set(s.execute(select(Job.owner)).scalars())
            keys = set(s.execute(select(Job.idempotency_key)).scalars())
    finally:
        db.dispose()
    assert owner_of(KEY_A) in owners and owner_of(KEY_B) in owners
    stored = " ".join(str(x) for x in owners | keys)
    assert KEY_A not in stored and KEY_B not in stored
    assert KEY_A not in caplog.text and KEY_B not in caplog.text


def test_constant_time_comparison_checks_every_key(monkeypatch):
    import hmac

    calls = []
    real = hmac.compare_digest

    def spy(a, b):
        calls.append((len(a), len(b)))
        return real(a, b)

    monkeypatch.setattr(hmac, "compare_digest", spy)
    keys = ["k1", "a-much-longer-key", "k3"]
    assert match_key("k1", keys) is True          # a match on the first key still compares all of them
    assert len(calls) == 3 and {c for c in calls} == {(32, 32)}  # equal-length digests: length does not leak
    calls.clear()
    assert match_key("k", keys) is False and len(calls) == 3


def test_without_keys_everything_is_open_and_serve_says_loopback(db_url):
    with running_client(db_url, run_dispatcher=False) as c:
        assert c.get("/v1/designs").status_code == 200
    notice = access_notice([], "127.0.0.1")
    assert "no API keys" in notice and "loopback" in notice
    assert "WARNING" in access_notice([], "0.0.0.0")
    assert KEY_A not in access_notice([KEY_A], "0.0.0.0")


def test_real_server_defaults_to_loopback_and_says_so(db_url, start_server, monkeypatch):
    from app.settings import Settings

    monkeypatch.delenv("NCS_HOST", raising=False)
    assert Settings().host == "127.0.0.1"
    server = start_server(db_url, NCS_WORKERS=1)
    assert httpx.get(server.base + "/healthz", timeout=5).status_code == 200
    with open(server.log.name, "rb") as f:
        text = f.read().decode()
    assert "no API keys configured" in text and "loopback only (127.0.0.1)" in text


def test_real_server_with_keys_never_logs_them(db_url, start_server):
    server = start_server(db_url, NCS_WORKERS=1, NCS_API_KEYS=f"{KEY_A},{KEY_B}")
    with httpx.Client(base_url=server.base, timeout=10) as c:
        assert c.post("/v1/designs", json=DESIGN, headers=A).status_code == 202
        assert c.get("/v1/designs", headers={"X-API-Key": KEY_B[:-1]}).status_code == 401
        assert c.get("/v1/designs/x", headers=B).status_code == 404
    server.stop()
    with open(server.log.name, "rb") as f:
        text = f.read().decode()
    assert "API keys configured (2)" in text
    assert KEY_A not in text and KEY_B not in text and KEY_B[:-1] not in text
