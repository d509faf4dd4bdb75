"""Per-test processor time of a pytest run, from the opt-in plugin of tests/conftest.py.

    THSA_TEST_CPU=/tmp/cpu.tsv python -m pytest -m "not slow"
    python bench/suite_cpu.py /tmp/cpu.tsv [--top 20] [--compare /tmp/before.tsv]

Prints the longest tests by processor time (wall in brackets), the sum per worker and in all; with
``--compare`` the same tests' time in the earlier file beside it.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import defaultdict
from pathlib import Path


def read(path: Path) -> dict[str, tuple[float, float, str, float]]:
    """nodeid -> (cpu_s, wall_s, worker, end); ``end`` is NaN in files of the first, four-field form."""
    rows = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        parts = line.split("\t")
        if len(parts) not in (4, 5):
            sys.exit(f"{path}, line {n}: expected 4 or 5 tab-separated fields, got {len(parts)}")
        rows[parts[0]] = (float(parts[1]), float(parts[2]), parts[3], float(parts[4]) if len(parts) == 5 else math.nan)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file", type=Path)
    ap.add_argument("--top", type=int, default=20)
    ap.add_argument("--compare", type=Path, help="an earlier file of the same format")
    ap.add_argument("--match", default="", help="only test ids containing this text")
    a = ap.parse_args(argv)
    rows = {k: v for k, v in read(a.file).items() if a.match in k}
    old = read(a.compare) if a.compare else {}
    ranked = sorted(rows.items(), key=lambda kv: -kv[1][0])
    for nodeid, (cpu, wall, *_) in ranked[: a.top]:
        before = f"{old[nodeid][0]:7.1f} -> " if nodeid in old else ""
        print(f"{before}{cpu:7.1f} s CPU ({wall:6.1f} s wall)  {nodeid}")
    per_worker, last = defaultdict(float), defaultdict(lambda: -math.inf)
    for cpu, _, worker, end in rows.values():
        per_worker[worker] += cpu
        last[worker] = max(last[worker], end)
    print("per worker: " + ", ".join(f"{w} {t:.1f} s" for w, t in sorted(per_worker.items())))
    ends = {w: t for w, t in last.items() if math.isfinite(t)}
    if len(ends) > 1:  # the tail: how long the other workers idled while the last one finished its tests
        t_end = max(ends.values())
        print("idle at the end: " + ", ".join(f"{w} {t_end - t:.1f} s" for w, t in sorted(ends.items())))
    total = sum(v[0] for v in rows.values())
    line = f"sum over {len(rows)} tests: {total:.1f} s CPU"
    if old:
        common = [k for k in rows if k in old]
        line += (f"; the {len(common)} tests in both files: {sum(old[k][0] for k in common):.1f} -> "
                 f"{sum(rows[k][0] for k in common):.1f} s")
    print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
