"""/docs renders offline in a real browser (headless Chromium), from the locally served Swagger UI."""

from __future__ import annotations

import shutil
import subprocess

import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (.ci/run installs it)")
def test_swagger_ui_renders_without_internet(db_url, start_server, tmp_path):
    server = start_server(db_url, NCS_WORKERS=1)
    cmd = [
        CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--disable-dev-shm-usage", f"--user-data-dir={tmp_path / 'chrome-profile'}",
        # Any request that leaves the machine fails: only 127.0.0.1 resolves.
        "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
        "--virtual-time-budget=15000", "--dump-dom", server.base + "/docs",
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    dom = out.stdout
    assert "swagger-ui" in dom, out.stderr[-2000:]
    # Swagger UI fetched /openapi.json and rendered the operations.
    assert "/v1/designs" in dom and "Submit a design job" in dom, dom[:2000]
    assert "ncs-design" in dom
    assert "Failed to load API definition" not in dom
