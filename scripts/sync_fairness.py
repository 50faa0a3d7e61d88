"""Per-key fairness of the synchronous pool, measured from outside (issue 33, item 2).

A real server with two API keys and one synchronous worker (NCS_SYNC_WORKERS=1). Key A keeps ``--heavy`` channel
analyses in flight (a 4-state, 3-mode cart-pole at n_drop = 8 on a Gilbert-Elliott link: a few seconds each);
once its backlog is queued, key B sends ``--small`` paper-example analyses one after another. Printed: A's
request times and B's waits. With the pool serving first come first served, B waited behind A's whole backlog.

    python scripts/sync_fairness.py [--database-url postgresql+psycopg://postgres@127.0.0.1:5432/test]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.examples import PAPER_GAINS_H01, PAPER_PLANT  # noqa: E402
from bench.harness import Server, fresh_database  # noqa: E402


def heavy_body() -> dict:
    from tests.solver.cartpole import cartpole

    fam = cartpole()
    A = [np.asarray(a).tolist() for a in fam.F]
    B = [np.asarray(b).tolist() for b in fam.G]
    gains = [[[1.0, 2.0, 25.0, 4.0]]] * 8
    return {"plant": {"kind": "discrete", "F": A, "G": B, "sampling_period": 0.02}, "n_drop": 8, "gains": gains,
            "channel": {"kind": "gilbert_elliott", "p_gb": 0.05, "p_bg": 0.3, "loss_good": 0.01, "loss_bad": 0.8}}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--database-url", default=None)
    ap.add_argument("--heavy", type=int, default=4, help="key A's concurrent heavy requests")
    ap.add_argument("--small", type=int, default=5, help="key B's small requests, one after another")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp, fresh_database(args.database_url, Path(tmp)) as url:
        server = Server(url, Path(tmp) / "server.log", NCS_API_KEYS="key-a,key-b", NCS_SYNC_WORKERS=1,
                        NCS_WORKERS=1, NCS_SYNC_TIME_LIMIT=120, NCS_MAX_CHANNEL_SIZE=100000)
        try:
            server.wait_ready()
            heavy, small = heavy_body(), {"plant": PAPER_PLANT, "n_drop": 3, "gains": PAPER_GAINS_H01}
            a_times: list[float] = []
            stop = threading.Event()

            def key_a():
                with httpx.Client(base_url=server.base, headers={"X-API-Key": "key-a"}, timeout=300) as c:
                    while not stop.is_set():
                        t0 = time.monotonic()
                        r = c.post("/v1/channels", json=heavy)
                        assert r.status_code == 200, r.text
                        a_times.append(time.monotonic() - t0)

            threads = [threading.Thread(target=key_a, daemon=True) for _ in range(args.heavy)]
            for t in threads:
                t.start()
            time.sleep(3.0)  # A's backlog is queued behind its running request
            waits = []
            with httpx.Client(base_url=server.base, headers={"X-API-Key": "key-b"}, timeout=300) as c:
                for _ in range(args.small):
                    t0 = time.monotonic()
                    r = c.post("/v1/analyses", json=small)
                    assert r.status_code == 200, r.text
                    waits.append(time.monotonic() - t0)
            stop.set()
            for t in threads:
                t.join()
        finally:
            server.stop()
    print(f"database: {'PostgreSQL' if args.database_url else 'SQLite'}; key A: {args.heavy} concurrent heavy "
          f"channel analyses")
    print(f"key A request time (s, queueing included): median {statistics.median(a_times):.2f}, "
          f"max {max(a_times):.2f} over {len(a_times)}")
    print(f"key B small analysis (s): {', '.join(f'{w:.2f}' for w in waits)}; max {max(waits):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
