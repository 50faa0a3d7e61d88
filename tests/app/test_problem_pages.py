"""Problem ``type`` URIs resolve to pages the service serves, saying what happened and how to fix it."""

from __future__ import annotations

import pytest

from app.api.problems import PROBLEM_TYPES

from .conftest import running_client


@pytest.fixture(scope="module")
def client(module_db):
    with running_client(module_db, workers=1) as c:
        yield c


def _follow(client, body: dict) -> str:
    url = body["type"]
    assert ".invalid" not in url and url.startswith("http://testserver/problems/"), url
    page = client.get(url.replace("http://testserver", ""))
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "How to fix it" in page.text
    return page.text


def test_error_answers_point_at_served_pages(client):
    bad = client.post("/v1/designs", json={"plant": {"kind": "dc_motor", "inertias": [0.03], "sampling_period": 0}})
    assert "pointer" in _follow(client, bad.json())
    missing = client.get("/v1/designs/00000000-0000-0000-0000-000000000000")
    assert missing.status_code == 404 and "API key" in _follow(client, missing.json())
    text = client.post("/v1/designs", content=b"x", headers={"Content-Type": "text/plain"})
    assert text.status_code == 415 and "Content-Type: application/json" in _follow(client, text.json())
    broken = client.post("/v1/designs", content=b"{", headers={"Content-Type": "application/json"})
    assert broken.status_code == 422 and _follow(client, broken.json())


def test_every_problem_type_has_a_page_and_an_index(client):
    index = client.get("/problems")
    assert index.status_code == 200
    for slug, (title, _, _) in PROBLEM_TYPES.items():
        assert f"/problems/{slug}" in index.text
        assert title in client.get(f"/problems/{slug}").text
    unknown = client.get("/problems/nope")
    assert unknown.status_code == 404 and unknown.headers["content-type"] == "application/problem+json"
