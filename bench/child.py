"""One measurement in a child process of its own, under a memory cap (``RLIMIT_AS``), and the time format."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time


def rss_mb() -> float:
    """This process's resident memory (MiB)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def run_child(setup: str, call: str, mem_gb: float, timeout: float, note_chars: int = 100) -> dict:
    """``print(json.dumps(call))`` after ``setup`` in a fresh interpreter capped at ``mem_gb`` GiB.

    Returns the child's last JSON line, or ``{"note": ...}`` saying why there is none (time-out or failure).
    """
    cmd = [sys.executable, "-c",
           f"import json, resource; {setup}; cap = int({mem_gb} * 2**30); "
           f"resource.setrlimit(resource.RLIMIT_AS, (cap, cap)); print(json.dumps({call}))"]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=os.getcwd())
    except subprocess.TimeoutExpired:
        return {"note": f"> {timeout:g} s wall"}
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        return {"note": f"failed after {time.perf_counter() - t0:.0f} s: {tail[0][:note_chars]}"}
    return json.loads(lines[-1])


def fmt(sec: float) -> str:
    """Seconds for a table: ms below 1 s, '-' for NaN."""
    if sec != sec:
        return "-"
    if sec < 1e-2:
        return f"{sec * 1e3:.2f} ms"
    if sec < 1:
        return f"{sec * 1e3:.0f} ms"
    return f"{sec:.2f} s"
