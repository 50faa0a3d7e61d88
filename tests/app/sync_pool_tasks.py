"""Worker entry points for the synchronous pool's tests (importable by the pool's spawned processes)."""

from __future__ import annotations

import time

from app.compute.messages import SyncResult


def init(parent_pid: int, memory_mb: int = 0) -> None:
    pass


def call(task: str, *args):
    """``("sleep", s, tag)`` sleeps s seconds (a stand-in for a long analysis), ``("echo", tag)`` answers at once."""
    if task == "sleep":
        time.sleep(args[0])
        return SyncResult(args[1])
    return SyncResult(args[0])
