"""The README's service examples really run, and its settings table is complete."""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import pytest

from app.settings import Settings

from .conftest import REPO

README = (REPO / "README.md").read_text()


def _example_block() -> str:
    section = README.split("<!-- readme-example: start -->", 1)[1].split("<!-- readme-example: end -->", 1)[0]
    match = re.search(r"```bash\n(.*?)```", section, re.S)
    assert match, "no bash block between the readme-example markers"
    return match.group(1)


@pytest.mark.skipif(shutil.which("curl") is None, reason="curl is not installed")
def test_readme_curl_examples_run(db_url, start_server, tmp_path):
    server = start_server(db_url, NCS_WORKERS=1)
    script = tmp_path / "example.sh"
    script.write_text("set -euo pipefail\n" + _example_block())
    env = {**os.environ, "BASE": server.base}
    out = subprocess.run(["bash", str(script)], capture_output=True, text=True, timeout=180, env=env, cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    text = out.stdout
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
