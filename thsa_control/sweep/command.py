"""What ``thsa sweep SPEC.toml --out DIR [--scheduler ADDRESS | --scheduler-file FILE | --workers N]`` does: run, resume, report.

:func:`sweep_command` is the whole command behind the parser: validate the
spec, run or resume it (``engine.run_sweep``), read the table, analyse it and
write ``DIR/report/`` (``report.html``, ``report.json``); it prints the
failure probabilities and the leading sensitivities.  Exit status 0, or 1
with ``check`` when a run misses a limit of the spec; errors of the input
(spec, folder, scheduler) raise :class:`~thsa_control.errors.ThsaError`
(exit 2 in the CLI).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

__all__ = ["sweep_command"]


def sweep_command(spec_path: str, out: str, *, scheduler: str | None = None, workers: int | None = None,
                  scheduler_file: str | None = None, force: bool = False, check: bool = False, quiet: bool = False,
                  command: str = "thsa sweep") -> int:
    """Run the command; see the module docstring.  Returns the exit status."""
    from ..errors import UsageError
    from ..progress import Progress
    from ..report.sweep import write_sweep_report
    from .analysis import analyse_sweep
    from .engine import read_results, run_sweep
    from .spec import load_spec

    if workers is not None and workers < 1:
        raise UsageError(f"--workers {workers}: must be an integer >= 1")
    progress = Progress("thsa sweep", enabled=not quiet)
    spec = load_spec(spec_path)
    progress.phase(f"{spec.name}: {spec.total_runs} runs in chunks of {spec.chunk_runs}")
    with progress.heartbeat():  # a line whenever a chunk or the warm-up keeps it silent for 2 s
        stats = run_sweep(spec, out, scheduler=scheduler, workers=workers, force=force, progress=progress,
                          command=command, scheduler_file=scheduler_file)
        progress.phase("analysing the table and writing the report")
        table = read_results(out)
        analysis = analyse_sweep(spec, table)
        report = write_sweep_report(spec, analysis, Path(out) / "report")
    progress.done()
    if stats.simulated:
        rate = stats.simulated / stats.compute_s if stats.compute_s > 0 else math.nan
        print(f"{stats.simulated} runs simulated in {stats.compute_s:.1f} s ({rate:.1f} runs/s on "
              f"{stats.workers} worker(s)); {stats.resumed} were already done")
    else:
        print(f"all {stats.total} runs were already done")
    if analysis.failed_runs:
        print(f"warning: {analysis.failed_runs} run(s) failed to simulate (listed in the report; counted as "
              "failures)", file=sys.stderr)
    for f in analysis.failures:
        if f.group == "all":
            lo, hi = f.interval
            print(f"{f.requirement}: {f.failures}/{f.runs} runs fail, probability {f.probability:.3g} "
                  f"(95 % interval {lo:.3g} .. {hi:.3g})")
    shown = set()
    for s in analysis.sensitivity:
        if (s.metric, s.group) not in shown and math.isfinite(s.spearman):
            shown.add((s.metric, s.group))
            print(f"{s.metric} ({s.group}): most sensitive to {s.input} (rank correlation {s.spearman:+.2f})")
    print(f"wrote {Path(out).resolve() / 'runs'} and {report.resolve() / 'report.html'}")
    failing = any(f.failures for f in analysis.failures if f.group == "all")
    return 1 if check and failing else 0
