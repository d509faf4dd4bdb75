"""``thsa faults``: the fault report (detection times, loads, recovery, false-alarm margins, sweep).

Registered in ``thsa_control/cli/__init__.py`` with ``add_parser(subparsers)``; the
handler parses, calls :func:`thsa_control.faults.analysis.analyse_faults`,
writes the report (``report/faults.py``) and prints the key numbers.
"""

from __future__ import annotations

import math
from pathlib import Path

__all__ = ["add_parser", "run"]


def _floats(text: str, what: str) -> tuple[float, ...]:
    from ..errors import ThsaError

    try:
        vals = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise ThsaError(f"--{what} {text!r}: expected comma-separated numbers") from None
    if not vals or not all(math.isfinite(v) and v >= 0 for v in vals):
        raise ThsaError(f"--{what} {text!r}: expected finite numbers >= 0")
    return vals


def add_parser(subparsers) -> None:
    """Add the ``faults`` subcommand."""
    p = subparsers.add_parser("faults", help="fault report: detection times, loads, recovery, false-alarm margins, sweep")
    p.add_argument("--design", help="design TOML (default designs/nominal.toml)")
    p.add_argument("--params", help="parameter TOML overriding the embedded actuator")
    p.add_argument("--scales", default="0.5,0.75,1,1.5,2", help="threshold scales of the sweep (default 0.5,0.75,1,1.5,2)")
    p.add_argument("--delays", default="0,5,10,20", help="take-over delays of the sweep [ms] (default 0,5,10,20)")
    p.add_argument("--no-sweep", action="store_true", help="skip the sweep")
    p.add_argument("--out", required=True,
                   help="output folder: new, empty, or written by thsa before (then replaced atomically)")
    p.add_argument("--force", action="store_true",
                   help="also replace a folder not written by thsa (never one holding an input file)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(fn=run)


def _ms(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{v * 1e3:.1f} ms"


def run(args) -> int:
    """Handler of ``thsa faults``; returns the exit status."""
    from .common import load_params_design, out_options, preflight_out, progress_for

    preflight_out(args)  # refuse a foreign output folder before the long computation
    scales = _floats(args.scales, "scales")
    delays = tuple(d * 1e-3 for d in _floats(args.delays, "delays"))
    progress = progress_for(args, "thsa faults")
    progress.phase("loading the model")
    with progress.heartbeat():
        from ..faults.analysis import analyse_faults
        from ..report.faults import write_fault_report

        params, design = load_params_design(args)
    with progress.heartbeat():
        a = analyse_faults(design, params, scales=scales, delays_s=delays, sweep=not args.no_sweep, progress=progress)
    progress.phase("writing the report")
    with progress.heartbeat():
        write_fault_report(a, params, args.out, progress=progress, **out_options(args))
    progress.done()
    print(a.report())  # the cases by plant as in the HTML, the margins, the sweep (display units)
    print(f"wrote {Path(args.out).resolve() / 'report.html'}")
    return 0
