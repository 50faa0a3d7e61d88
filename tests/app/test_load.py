"""Short variants of scripts/load_test.py (the same code): concurrent clients submitting, polling and asking for
traces get no error at all, nothing is lost; a burst over NCS_MAX_QUEUE_DEPTH gets 429 + Retry-After and the
queue stays bounded. The figures in docs/service.md come from the full run (1,000 submissions from 50 clients)."""

from __future__ import annotations

import sys

from .conftest import REPO

sys.path.insert(0, str(REPO / "scripts"))
import load_test  # noqa: E402


def test_concurrent_submissions_polls_and_traces_have_no_errors(db_url, tmp_path):
    res = load_test.load(db_url, tmp_path, submissions=150, clients=20, workers=2, max_seconds=240)
    assert res["errors"] == 0, res["error_samples"]
    assert res["accepted"] == 150 and res["lost"] == 0 and res["succeeded"] == 150, res
    assert res["latency_ms"]["trace"]["n"] > 0 and res["latency_ms"]["poll"]["n"] > 0, res
    assert res["readyz_after"] == 200 and res["log_tracebacks"] == 0, res


def test_back_pressure_bounds_the_queue(db_url, tmp_path):
    res = load_test.back_pressure(db_url, tmp_path, depth=10, burst=80, clients=10)
    assert res["unexpected"] == [], res
    assert res["status_codes"].get(429, 0) > 0 and res["status_codes"].get(202, 0) >= 10, res
    # The depth check and the insert are separate statements: concurrent submissions may overshoot by at most
    # the number of requests in flight.
    assert res["max_queued_seen"] <= 10 + 10, res
    assert res["lost"] == 0, res
