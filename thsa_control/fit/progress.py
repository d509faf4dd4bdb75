"""Progress of long fits on stderr: a line every few seconds, plain text (safe when not a TTY)."""

from __future__ import annotations

import sys
import time

__all__ = ["stderr_progress"]


def stderr_progress(label: str, *, quiet: bool = False, every_s: float = 2.0, stream=None):
    """A ``progress(nfev, cost, elapsed_s)`` callback printing at most every ``every_s`` seconds (None when quiet)."""
    if quiet:
        return None
    out = stream or sys.stderr
    state = {"last": -1e9}

    def progress(nfev: int, cost: float, elapsed: float) -> None:
        now = time.perf_counter()
        if now - state["last"] >= every_s:
            state["last"] = now
            print(f"{label}: {nfev} evaluations, best cost {cost:.6g}, {elapsed:.1f} s", file=out, flush=True)

    return progress
