"""Honest comparisons for the bench scripts: a ratio is printed only when both sides produced a result
and the results agree to a stated tolerance; anything else is reported as a failure and the script
exits non-zero (``Comparisons.exit_code``).

Usage::

    cmp = Comparisons()
    ours = cmp.side("thsa", lambda: run_ours())            # Side(ok, value, seconds, error)
    theirs = cmp.side("python-control", lambda: run_theirs(), cap_s=600)
    cmp.compare("level A vs python-control", ours, theirs, agree=lambda a, b: (dev(a, b), dev(a, b) <= 1e-3),
                tolerance="0.1 % of the peak")
    sys.exit(cmp.exit_code())
"""

from __future__ import annotations

import time
import traceback
from dataclasses import dataclass


@dataclass
class Side:
    """One side of a comparison: its result (``value``), wall time, and the error that stopped it, if any."""

    name: str
    ok: bool
    value: object = None
    seconds: float = float("nan")
    error: str = ""


class Comparisons:
    """Collects comparisons; ``exit_code()`` is 1 when any failed."""

    def __init__(self):
        self.failures: list[str] = []

    def side(self, name: str, fn, *, repeat: int = 1) -> Side:
        """Run ``fn`` (``repeat`` times, best wall time kept); an exception makes a failed side."""
        best, value = float("inf"), None
        try:
            for _ in range(repeat):
                t0 = time.perf_counter()
                value = fn()
                best = min(best, time.perf_counter() - t0)
        except Exception as exc:  # a side that errors is reported, never turned into a ratio
            return Side(name, False, None, float("nan"), f"{type(exc).__name__}: {exc}".strip()[:300]
                        or traceback.format_exc(limit=1))
        return Side(name, True, value, best)

    def fail(self, message: str) -> None:
        self.failures.append(message)
        print(f"FAILED: {message}", flush=True)

    def compare(self, title: str, ours: Side, theirs: Side, *, agree, tolerance: str, ratio_label: str = "faster"):
        """Print ``theirs.seconds / ours.seconds`` only when both sides finished and ``agree(ours.value,
        theirs.value)`` returns ``(measure_text, True)``; otherwise record a failure.  Returns the ratio or None."""
        for s in (ours, theirs):
            if not s.ok:
                self.fail(f"{title}: {s.name} did not produce a result ({s.error}); no ratio")
                return None
        try:
            measure, ok = agree(ours.value, theirs.value)
        except Exception as exc:
            self.fail(f"{title}: comparing the results raised {type(exc).__name__}: {exc}; no ratio")
            return None
        if not ok:
            self.fail(f"{title}: results disagree ({measure}; tolerance {tolerance}); no ratio")
            return None
        ratio = theirs.seconds / ours.seconds
        print(f"{title}: {ours.name} {_t(ours.seconds)} vs {theirs.name} {_t(theirs.seconds)} -> "
              f"{ratio:.1f}x {ratio_label}; agreement {measure} (tolerance {tolerance})", flush=True)
        return ratio

    def exit_code(self) -> int:
        if self.failures:
            print(f"{len(self.failures)} comparison(s) failed:", *self.failures, sep="\n  ", flush=True)
            return 1
        return 0


def _t(s: float) -> str:
    return f"{s * 1e3:.1f} ms" if s < 1 else f"{s:.2f} s"
