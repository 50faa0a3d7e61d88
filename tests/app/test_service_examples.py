"""The service examples of README and docs/service.md really run, and README's settings table is complete."""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import pytest
import scipy.io

from app.settings import Settings

from .conftest import REPO, doc_block

README = (REPO / "README.md").read_text()


def _run(block: str, server, tmp_path) -> str:
    script = tmp_path / "example.sh"
    script.write_text("set -euo pipefail\n" + block)
    env = {**os.environ, "BASE": server.base}
    out = subprocess.run(["bash", str(script)], capture_output=True, text=True, timeout=180, env=env, cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


@pytest.mark.skipif(shutil.which("curl") is None, reason="curl is not installed")
def test_readme_and_service_curl_examples_run(db_url, start_server, tmp_path):
    server = start_server(db_url, NCS_WORKERS=1)
    # README, "A first design / Over HTTP"
    text = _run(doc_block("readme-example", "bash")[1], server, tmp_path)
    assert "HTTP 201" in text
    assert re.search(r"^succeeded stabilized \w+ K_1 = \[\[", text, re.M), text
    assert "PNG: True MAT: b'MATLAB'" in text
    assert scipy.io.loadmat(tmp_path / "gains.mat")["K"].shape == (3, 1, 2)
    # docs/service.md, "Example session"
    text = _run(doc_block("service-example", "bash")[1], server, tmp_path)
    assert "202 Accepted" in text
    assert "201 Created" in text and "preference-applied: wait=30" in text
    assert "event: end" in text
    assert "succeeded stabilized" in text
    assert "stable: True" in text
    assert '"pointer":"/plant/sampling_period"' in text
    assert "x(100) =" in text
    assert "PNG: True" in text
    assert "largest n_drop with a stabilizing lmi design" in text or "up to the largest n_drop tried" in text


def test_readme_settings_table_lists_every_setting():
    for name in Settings.model_fields:
        assert f"`NCS_{name.upper()}`" in README, name


def test_readme_has_exactly_two_setup_commands():
    setup = README.split("<!-- BEGIN SETUP (owned by: service) -->", 1)[1].split("<!-- END SETUP -->", 1)[0]
    blocks = re.findall(r"```bash\n(.*?)```", setup, re.S)
    assert len(blocks) == 2 and all(len(b.strip().splitlines()) == 1 for b in blocks)
    assert "ncs-design serve" in blocks[0] and "pytest" in blocks[1]
