"""HTML report and ``trace.json`` of a residual trace (:func:`thsa_control.trace.trace`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np  # noqa: E402

from .build import write_json  # noqa: E402
from .figure import subplots  # noqa: E402
from .identification import figure_png, write_html_report  # noqa: E402

__all__ = ["write_trace_folder", "format_trace_summary", "plot_residual_before_after"]


def _num(x, fmt=".4g"):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def plot_residual_before_after(before: dict, after: dict, run_name: str, channel: str = "motor_speed"):
    """Segment residual of ``channel`` before and after the added effects."""
    from ..data.rigformat import COLUMNS

    spec = next((c for c in COLUMNS.values() if c.signal == channel), None)  # the rig format's unit (rpm, mm)
    fig, ax = subplots(figsize=(10, 3.2))
    for label, fit, kw in (("declared model", before, {"color": "0.6"}), ("with added effects", after, {"color": "C3"})):
        p = fit["predictions"][run_name]
        if channel not in p["measured"]:
            continue
        e = np.asarray(p["measured"][channel]) - np.asarray(p["simulated"][channel])
        ax.plot(p["time"][:e.size], spec.from_si(e) if spec else e, lw=0.7, label=label, **kw)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{channel} residual [{spec.unit if spec else 'SI'}]")
    ax.set_title(f"{run_name}: {channel} residual of the multiple-shooting segments")
    ax.legend(loc="upper right")
    return fig


def format_trace_summary(doc: dict) -> str:
    """Console / report text: what was added, the ranking, the errors, the signature."""
    lines = [f"declared model: {doc['base_model']} ({', '.join(doc['declared_effects']) or 'functional'}), "
             f"uncertain set fitted: {', '.join(doc['uncertain_parameters'])}"]
    for step, e in enumerate(doc["effects_added"], 1):
        lines.append(f"step {step}: added {e['name']} (score {_num(e['score'], '.3f')}, AIC drop {_num(e['aic_drop'], '.1f')}, "
                     f"BIC drop {_num(e['bic_drop'], '.1f')})")
        for n, p in e["parameters"].items():
            ci = p["ci95"]
            lines.append(f"    {n} = {_num(p['value'])} {p['unit']}" + (f"  95 % CI [{_num(ci[0])}, {_num(ci[1])}]" if ci else "")
                         + (" (profiled)" if p.get("profiled") else ""))
        for c, red in e["error_reduction"].items():
            b, a = e["error_before"].get(c, {}), e["error_after"].get(c, {})
            lines.append(f"    {c}: RMS {_num(b.get('rms'))} -> {_num(a.get('rms'))} ({100 * red:+.1f} % drop)")
    for a in doc.get("ambiguous", []):
        drops = ", ".join(f"{n} {_num(v, '.4g')}" for n, v in a["holdout_chi2_drop"].items())
        lines.append(f"not named (round {a['round']}): {', '.join(a['candidates'])} explain the same part of the "
                     f"residual; held-out chi2 drops {drops} differ by less than {_num(a['indistinct_below'], '.3g')}. "
                     f"The data cannot tell them apart (another speed, load or direction would).")
    if not doc["effects_added"] and not doc.get("ambiguous"):
        lines.append("no candidate effect is significant")
    for r in doc["rounds"]:
        lines.append(f"round {r['round']} (model: {', '.join(r['model']) or 'functional'}): candidates")
        for c in r["candidates"]:
            if "error" in c:
                lines.append(f"    {c['name']:<26} fit failed: {c['error']}")
                continue
            flag = "SIGNIFICANT" if c["significant"] else ("implausible: " + "; ".join(c["implausible_because"])
                                                           if not c["plausible"] else "not significant")
            lines.append(f"    {c['name']:<26} held-out chi2 drop {_num(c['holdout_chi2_drop'], '.4g'):>10} "
                         f"(threshold {_num(c['chi2_threshold'], '.3g')}, null {_num(c.get('null_chi2_drop'), '.3g')}), "
                         f"score {_num(c['score'], '.3f')}  {flag}")
        for s in r["skipped"]:
            lines.append(f"    {s['name']:<26} skipped: {s['reason']}")
    lines.append("error before -> after (all samples):")
    for c, b in doc["error_before"].items():
        a = doc["error_after"][c]
        lines.append(f"    {c}: RMS {_num(b['rms'])} -> {_num(a['rms'])} [{b['unit']}], fit {_num(b['fit_percent'], '.2f')} -> "
                     f"{_num(a['fit_percent'], '.2f')} %")
    sig = doc["residual_signature"]
    lines.append(f"unexplained: {doc['unexplained']}" + (f" (structured in: {', '.join(sig['structured'])})"
                                                         if doc["unexplained"] else ""))
    for t in sig["tests"][:6] + sig["sensors"]:
        extra = ""
        if t["kind"] == "periodic":
            extra = f", dominant harmonic {t['dominant_harmonic']} per revolution"
        elif t["kind"] == "local":
            extra = f", peak in {1e3 * t['peak_bin'][0]:.1f}..{1e3 * t['peak_bin'][1]:.1f} mm"
        elif t["kind"] == "redundant_sensors":
            extra = f", gain {t['gain']:.4f}, lag {1e3 * t['lag_s']:.1f} ms"
        lines.append(f"    {t['variable']:<40} size {_num(t['size'], '.3g')} {t['unit']}, p {_num(t['p_value'], '.2g')}"
                     f"{extra}{'  <- STRUCTURED' if t['significant'] else ''}")
    return "\n".join(lines)


def write_trace_folder(folder: str | Path, result) -> dict:
    """``trace.json`` and ``report.html`` in ``folder`` (built inside an atomic folder by the caller)."""
    folder = Path(folder)
    doc = result.to_dict()
    write_json(folder / "trace.json", doc, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    figs = {}
    before, after = result.fits["before"], result.fits["after"]
    for run in doc["datasets"]:
        for ch in ("motor_speed", "nut_position"):
            if ch in before["predictions"][run["name"]]["measured"]:
                figs[f"{run['name']}: {ch} residual before and after"] = figure_png(
                    plot_residual_before_after(before, after, run["name"], ch))
    write_html_report(folder / "report.html", title=f"Residual trace: {', '.join(d['name'] for d in doc['datasets'])}",
                      sections=[("Summary", format_trace_summary(doc))], figures=figs)
    return doc
