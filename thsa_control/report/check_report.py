"""The verdict of ``thsa check`` (and of ``thsa report --check``) as JSON and an HTML page.

Tables only, from a :class:`thsa_control.verdict.Verdict`: every requirement
with its kind (linear grid / simulated validation runs / measured runs), worst
point, value, limit and status; measured runs beside the model's prediction.
"""

from __future__ import annotations

import html
import math
from pathlib import Path

from .build import atomic_folder, write_json

__all__ = ["verdict_section", "check_page", "write_check_report"]


def _f(x) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    if isinstance(x, float) and math.isinf(x):
        return "never"
    return f"{x:.4g}" if isinstance(x, (int, float)) else html.escape(str(x))


def verdict_section(verdict, measured=()) -> str:
    """HTML section: the verdict, one row per requirement, and the measured runs beside the prediction."""
    word = "PASS" if verdict.passed else "FAIL"
    parts = [f"<h2 id='verdict'>Verdict on every requirement: {word}</h2>",
             f"<p>{html.escape(verdict.design)}: {len(verdict.rows)} requirements, "
             f"{len(verdict.failures)} not met or not evaluated (an error counts as a failure).</p>",
             '<table id="table-verdict"><tr><th>status</th><th>requirement</th><th>judged on</th><th>worst value</th>'
             "<th>unit</th><th>limit</th><th>worst point</th><th>failing / judged</th><th>note</th></tr>"]
    for r in verdict.rows:
        parts.append(f"<tr class='{r.status}'><td><b>{r.status.upper()}</b></td><td>{html.escape(r.requirement)}</td>"
                     f"<td>{html.escape(r.kind)}</td><td>{_f(r.value)}</td><td>{html.escape(r.unit)}</td>"
                     f"<td>{_f(r.limit)}</td><td>{html.escape(r.worst_point)}</td><td>{r.failed} / {r.checked}</td>"
                     f"<td>{html.escape(r.detail or r.origin)}</td></tr>")
    parts.append("</table>")
    if measured:
        keys = ("speed_error_percent", "ise", "overshoot_percent", "settling_time_s", "current_peak_A")
        parts.append("<h3>Measured runs beside the model's prediction (same command, load, temperature)</h3>")
        parts.append('<table id="table-measured"><tr><th>run</th><th>T [degC]</th>'
                     + "".join(f"<th>{k} measured / predicted</th>" for k in keys)
                     + "<th>oscillation [%] measured / predicted</th></tr>")
        for m in measured:
            pm = m.predicted.as_dict() if m.predicted is not None else {}
            mm = m.measured.as_dict()
            parts.append(f"<tr><td>{html.escape(m.name)}</td><td>{_f(m.temperature)}</td>"
                         + "".join(f"<td>{_f(mm[k])} / {_f(pm.get(k))}</td>" for k in keys)
                         + f"<td>{_f(m.oscillation_percent)} / {_f(m.predicted_oscillation_percent)}</td></tr>")
        parts.append("</table>")
    return "\n".join(parts)


def check_page(verdict, measured=()) -> str:
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>thsa check</title><style>"
            "body{font-family:sans-serif;max-width:1400px;margin:auto}table{border-collapse:collapse;font-size:12px}"
            "td,th{border:1px solid #bbb;padding:2px 5px}tr.fail td,tr.error td{background:#fdd}</style></head><body>"
            "<h1>thsa check</h1>" + verdict_section(verdict, measured) + "</body></html>\n")


def write_check_report(verdict, out_dir, *, measured=(), force: bool = False, inputs=()) -> Path:
    """Write ``check.json`` and ``check.html`` into ``out_dir`` (atomically; nothing on failure)."""
    doc = verdict.as_dict()
    doc["measured_runs"] = [m.as_dict() for m in measured]
    with atomic_folder(out_dir, force=force, inputs=inputs, command="thsa check") as tmp:
        write_json(tmp / "check.json", doc)
        (tmp / "check.html").write_text(check_page(verdict, measured), encoding="utf-8")
    return Path(out_dir).resolve()
