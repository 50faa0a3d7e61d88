"""A design request whose input limit no design meets answers "infeasible" with its certificate (not a 500)."""

from __future__ import annotations

import pytest

from app.examples import PAPER_PLANT

from .conftest import running_client, wait_for


@pytest.fixture(scope="module")
def client(module_db):
    with running_client(module_db, workers=1) as c:
        yield c


def test_tiny_input_limit_is_infeasible_over_http(client):
    body = {"plant": PAPER_PLANT, "n_drop": 3, "options": {"decay_rate": 0.5}, "u_max": [0.01], "x0": [-3, 2]}
    resp = client.post("/v1/designs", json=body)
    assert resp.status_code == 202, resp.text
    done = wait_for(client, resp.json()["id"])
    assert done["status"] == "succeeded", done
    res = done["result"]
    assert res["outcome"] == "infeasible" and res["gains"] is None
    cert = res["certificate"]
    assert cert["kind"] == "farkas_limits" and cert["verified"] and cert["any_margin"]
    assert cert["statement"] in res["message"] and "u_max" in cert["statement"]
    assert len(cert["limit_multipliers"]["inputs"]) == 3
    text = client.get(f"/v1/designs/{resp.json()['id']}").text
    assert "farkas_limits" in text
