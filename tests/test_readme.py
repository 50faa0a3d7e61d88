"""Every ```python block of README.md and of docs/*.md runs as printed.

One test per file, so a failure names the file (and the block's first line number).  Each block
runs on its own (a fresh namespace: a reader copies one block), in a temporary working directory.  Blocks fenced
```py need a running service and are run by the service tests (tests/app/test_cli.py,
tests/app/test_exports_and_listings.py); a ```python block preceded by the line
``<!-- not-run -->`` is skipped (keep that rare: say in the text why it cannot run).
"""

from __future__ import annotations

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)
NOT_RUN = "<!-- not-run -->"


def python_blocks(path: pathlib.Path) -> list[tuple[int, str]]:
    """(line number of the block's first code line, code) of every runnable python block."""
    text = path.read_text()
    blocks = []
    for match in BLOCK.finditer(text):
        before = text[:match.start()].rstrip("\n").rsplit("\n", 1)[-1].strip()
        if before != NOT_RUN:
            blocks.append((text.count("\n", 0, match.start(1)) + 1, match.group(1)))
    return blocks


def test_readme_has_python_examples():
    assert python_blocks(ROOT / "README.md"), "README has no python example"


def test_not_run_marker_skips_only_its_block(tmp_path):
    doc = tmp_path / "x.md"
    doc.write_text("a\n```python\nx = 1\n```\n<!-- not-run -->\n```python\nraise SystemExit\n```\n\n```python\ny = 2\n```\n")
    assert python_blocks(doc) == [(3, "x = 1\n"), (11, "y = 2\n")]


@pytest.mark.parametrize("path", [p for p in DOCS if python_blocks(p)], ids=lambda p: str(p.relative_to(ROOT)))
def test_python_examples_run(path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for line, code in python_blocks(path):
        # padded so that a traceback points at the markdown file's own line numbers
        exec(compile("\n" * (line - 1) + code, str(path), "exec"), {"__name__": "__main__"})
