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
    from ..faults.analysis import analyse_faults
    from ..report.faults import monitor_display, write_fault_report
    from .common import out_options, preflight_out

    preflight_out(args)  # refuse a foreign output folder before the long computation
    from .common import load_params_design

    params, design = load_params_design(args)
    scales = _floats(args.scales, "scales")
    delays = tuple(d * 1e-3 for d in _floats(args.delays, "delays"))
    from ..progress import Progress

    progress = Progress("thsa faults", enabled=not getattr(args, "quiet", False))
    a = analyse_faults(design, params, scales=scales, delays_s=delays, sweep=not args.no_sweep, progress=progress)
    progress.phase("writing the report")
    write_fault_report(a, params, args.out, **out_options(args))
    progress.done()
    print(f"plant: level {a.level} + {', '.join(a.effects)}")
    heading = None
    for c in a.cases + a.rigid_cases:
        if c.label != heading:  # the sections of the HTML report
            heading = c.label
            print(f"-- {heading} --")
        det = ", ".join(f"{m} {_ms(t)}" for m, t in c.detection_s.items() if math.isfinite(t)) or "no trip"
        how = " (scheduled by the scenario; the monitors only watch)" if c.takeover_source == "schedule" else ""
        name = c.scenario if c.label == "fault plant" else c.title  # the rigid-drive cases repeat scenario names
        line = (f"{name}: {', '.join(c.faults)} at {c.fault_time_s:g} s; trips: {det}; "
                f"take-over {_ms(c.takeover_s)}{how}, safed {_ms(c.safed_s)}")
        if not math.isnan(c.recovery_s):
            line += f", recovery {_ms(c.recovery_s)}"
        print(line)
        print(f"    peaks after the fault: load path {c.peaks['loadpath'] / 1e3:.1f} kN, upper gimbal "
              f"{c.peaks['primary_attachment'] / 1e3:.1f} kN, secondary {c.peaks['secondary_path'] / 1e3:.1f} kN, "
              f"jam {c.peaks['jam'] / 1e3:.1f} kN, limiter {c.peaks['limiter_torque']:.0f} N m (slip "
              f"{c.limiter_slip_rad:.3f} rad); surface moved {c.surface_displacement_m * 1e3:.2f} mm; "
              f"energy residual {c.energy_residual * 100:.3f} %")
    for m in sorted({x.monitor for x in a.margins}):
        worst = min((x for x in a.margins if x.monitor == m), key=lambda x: x.margin)
        du = monitor_display(m)
        print(f"false-alarm margin {m}: {a.min_margin(m):.2f} (threshold {du.to_display(worst.threshold):g} {du.unit} / "
              f"{du.to_display(worst.persisted):.4g} {du.unit} held on {worst.scenario})")
    for p in a.sweep:
        if p.normal_trips:
            print(f"sweep: thresholds x {p.scale:g} trip on {', '.join(p.normal_trips)}")
    missed = sorted({(p.scale, n) for p in a.sweep for n, t in p.detection_s.items() if not math.isfinite(t)})
    for scale, n in missed:
        print(f"sweep: thresholds x {scale:g} miss {n}")
    print(f"wrote {Path(args.out).resolve() / 'report.html'}")
    return 0
