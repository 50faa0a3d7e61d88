"""The answer cache is bounded in bytes (NCS_CACHE_MAX_BYTES), and long traces are encoded in the pool's process.

Issue 33, item 3: the cache kept 128 answers of any size, and a 10,000-step trace of a 20-mode design (35-48 MB of
JSON, encoded on the event loop) grew the service by 180 MB in five requests and stalled /healthz.
"""

from __future__ import annotations

import json

from app.main import LRU
from app.compute import tasks
from app.jobs.store import canonical_json

from .conftest import running_client

PLANT = {"kind": "dc_motor", "inertias": [0.03, 0.05], "sampling_period": 0.1}
WAIT = {"Prefer": "wait=60"}


def test_lru_holds_at_most_max_bytes_and_evicts_least_recent_first():
    cache = LRU(size=128, max_bytes=1000)
    for i in range(10):
        cache.put(i, b"x" * 200)
        assert cache.nbytes <= 1000
    assert cache.nbytes == sum(len(cache.get(k) or b"") for k in range(10)) == 1000
    assert [k for k in range(10) if cache.get(k) is not None] == [5, 6, 7, 8, 9]
    cache.put("big", b"y" * 251)  # over a quarter: served, not kept (it would push out most of the cache)
    assert cache.get("big") is None and cache.nbytes == 1000
    cache.put(9, b"z" * 10)  # a replaced entry gives its bytes back
    assert cache.nbytes == 810


def test_trace_bytes_are_the_canonical_json_encoded_in_the_pool():
    gains = [[[-1.0, -1.0]], [[-1.0, -1.0]]]
    plant = {"kind": "dc_motor", "inertias": [0.03, 0.05], "sampling_period": 0.1}
    params = dict(seed=1, steps=30, x0=[1.0, 0.0], loss_model="paper", sensor_loss=0.0,
                  control_loss=0.0, plant_switching="per_interval", mode=None)
    body = tasks.run_trace_json(plant, gains, 2, params)
    assert isinstance(body, bytes)
    assert body == canonical_json(tasks.run_trace(plant, gains, 2, params)).encode()
    assert json.loads(body)["per_mode"]


def test_service_cache_stays_under_its_byte_bound(db_url):
    with running_client(db_url, workers=1, cache_max_bytes=400_000) as client:
        assert client.app.state.trace_cache.max_bytes == 400_000
        job = client.post("/v1/designs", json={"plant": PLANT, "n_drop": 3}, headers=WAIT).json()
        assert job["status"] == "succeeded", job
        sizes = []
        for seed in range(6):
            res = client.get(f"/v1/designs/{job['id']}/trace", params={"steps": 2000, "seed": seed})
            assert res.status_code == 200, res.text
            sizes.append(len(res.content))
            assert client.app.state.trace_cache.nbytes <= 400_000
        assert sum(sizes) > 400_000, sizes  # the bound was reached, not merely unused
        again = client.get(f"/v1/designs/{job['id']}/trace", params={"steps": 2000, "seed": 5})
        assert again.content == res.content
