"""Table of tracer outcomes on rig-sim runs (issue #21 notes): truth against what ``thsa trace`` added.

Reads trace folders written by ``thsa trace RUN.csv --model A --out DIR`` and the ``.truth.json`` beside each
run's CSV (the truth is read here, by the judge, never by the tracer), and prints a markdown table: truth,
base corrections, effects added in order (implied ones marked), window error drops, held parameters,
unexplained and the structured signature; then the rates (right first physical effect, nulls clean).

Run: ``python bench/trace_rigsim_table.py OUT_DIR [OUT_DIR ...]``
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from thsa_control.trace.engine import CANDIDATES

#: the judge's catalogue, shared with tests/test_trace_foreign.py
DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "rigsim"
CATALOGUE = json.loads((DATA / "catalogue.json").read_text())
LIBRARY = CATALOGUE["library"]
EXPLAINERS = {n for n, s in CANDIDATES.items() if s.base_correction}
FOREIGN = {k: tuple(v) for k, v in CATALOGUE["foreign"].items()}
#: a sensor effect's signature follows the channel it is planted on (the truth's ``channel`` parameter)
SENSOR_CHANNEL = {k: tuple(v) for k, v in CATALOGUE.get("foreign_sensor_channel", {}).items()}
BASE_CONTENT = set(CATALOGUE["base_content"])
BASE_COMPLIANCE = set(CATALOGUE["base_compliance"])
INVENTED = set(CATALOGUE["invented"])


def _at_bound(c: dict) -> bool:
    """At its plausible bound (as trace.scoring._at_edge; recomputed so that tables of older trace.json files
    flag an efficiency at its lower bound too)."""
    lo, hi = c["bound"]
    centre = c["value"] - c.get("change", c["value"])
    edge = 0.02 * (hi - lo)
    return bool(c["at_plausible_bound"]) or c["value"] >= hi - edge or (lo < centre and c["value"] <= lo + edge)


def row(folder: Path) -> dict | None:
    f = folder / "trace.json"
    if not f.is_file():
        return None
    doc = json.loads(f.read_text())
    csv = Path(doc["datasets"][0]["csv"])
    # beside the CSV; for a committed run traced from a checkout that is gone, the repository's copy
    here = [Path(str(csv)[:-4] + ".truth.json"), DATA / (csv.stem + ".truth.json")]
    found = next((t for t in here if t.exists()), None)
    if found is None:  # a CSV path relative to where the trace ran: run this from there
        raise SystemExit(f"trace_rigsim_table: {f}: no truth file for its run {csv} (tried "
                         + ", ".join(str(t) for t in here) + "; a relative CSV path is read from the current folder: "
                         "run this from the folder the traces were run in)")
    truth = json.loads(found.read_text())
    effs = list(truth.get("effects") or {})
    channel = next((p["channel"]["value"] for p in ((e or {}).get("params", {}) for e in (truth.get("effects") or
                                                                                         {}).values())
                    if isinstance(p.get("channel"), dict)), None)
    bc = doc.get("base_corrections") or {}
    corr = [f"{c['parameter'].split('.')[-1]}={c['value']:.3g}{'*' if _at_bound(c) else ''}"
            for c in bc.get("corrections", [])] if bc.get("accepted") else []
    added = []
    for e in doc["effects_added"]:
        tag = e["name"] + (f" (with {e['implied_by']})" if e.get("implied_by") else "") + \
            (" (beyond base)" if e.get("beyond_base_correction") else "")
        wr = e.get("window_reduction") or {}
        if wr and not e.get("implied_by"):
            tag += f" [{max(wr.values()):.0%}{' all samples' if e.get('window_on_all_samples') else ''}]"
        if e.get("round_added") and (doc.get("order") or {}).get("changed"):
            tag += f" (round {e['round_added']})"
        added.append(tag)
    added += [f"~~{r['name']}~~ (removed after round {r['removed_after_round']})" for r in doc.get("effects_removed") or []]
    held = [f"{h['parameter']}" for e in doc["effects_added"] for h in e.get("not_determined", [])]
    found = [e["name"] for e in doc["effects_added"] if not e.get("implied_by")]
    phys = [e["name"] for e in doc["effects_added"] if not e.get("implied_by") and not e.get("refines_declared")
            and e["name"] not in EXPLAINERS]
    return {"run": folder.name, "base": truth["base"], "scenario": truth["scenario"], "truth": effs, "found": found,
            "phys": phys, "corr": corr, "added": added, "held": held, "unexplained": doc["unexplained"],
            "structured": doc["residual_signature"]["structured"], "time": doc["timing"]["total_s"],
            "ambiguous": [a["candidates"] for a in doc.get("ambiguous", [])],
            "base_like": doc["residual_signature"].get("base_like", []),
            "windows": {e["name"]: max((e.get("window_reduction") or {0: 0.0}).values()) for e in doc["effects_added"]
                        if not e.get("implied_by")},
            # the same drop beyond the sensor noise (scoring._window_beyond_noise; None where nothing beyond it)
            "windows_bn": {e["name"]: max([v for v in (e.get("window_reduction_beyond_noise") or {}).values()
                                           if v is not None], default=0.0)
                           for e in doc["effects_added"] if not e.get("implied_by")},
            "beyond": [e["name"] for e in doc["effects_added"] if e.get("beyond_base_correction")],
            # the record's answer to "a constant torque beyond a plausible base?" (absent in older trace.json files)
            "answer": doc.get("beyond_plausible_base") or {},
            "channel": channel}


def _answer_text(a: dict) -> str:
    """The table's note of the record's answer beyond a plausible base (only where a joint lift passed)."""
    if a.get("status") not in ("named", "not_named", "no_carrier"):
        return ""
    names = [("base efficiencies" if c["base"] else c["name"]) for c in a.get("carriers") or []]
    return f" beyond base: {a['status'].replace('_', ' ')}" + (f" {names}" if names else "")


def main(argv=None) -> int:
    dirs = [Path(a) for a in (argv or sys.argv[1:])]
    rows = [r for d in dirs for r in ([row(d)] if (d / "trace.json").exists() else
                                      [row(x) for x in sorted(d.iterdir()) if x.is_dir() and not x.name.startswith(".")])
            if r]
    print("| run | base | scenario | truth | base corrections (* at bound) | added in order [window drop] | "
          "held (not determined) | unexplained: structured | time [s] |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    right = right_bn = lib = null_clean = nulls = 0
    first, clean, flagged, foreign, among = [], [], [], [], []
    for r in rows:
        print(f"| {r['run']} | {r['base']} | {r['scenario']} | {', '.join(r['truth']) or '-'} | "
              f"{', '.join(r['corr']) or '-'} | {'; '.join(r['added']) or '-'}"
              f"{' ambiguous ' + str(r['ambiguous']) if r['ambiguous'] else ''}"
              f"{_answer_text(r['answer'])} | {', '.join(r['held']) or '-'} | "
              f"{r['unexplained']}: {'; '.join(s[:40] for s in r['structured'][:4])}"
              f"{' (base-like: ' + str(len(r['base_like'])) + ')' if r['base_like'] else ''} | {r['time']:.0f} |")
        if len(r["truth"]) == 1 and r["truth"][0] in LIBRARY:
            lib += 1
            want = LIBRARY[r["truth"][0]]
            order = r["found"] if want in EXPLAINERS | BASE_CONTENT else r["phys"]
            if want in EXPLAINERS:
                order = [x for x in r["found"] if x not in BASE_CONTENT]
            if order and order[0] == want:
                first.append(r["run"])
                right += r["windows"].get(want, 0.0) >= 0.5  # the must-show's bar: its window error halves
                # the error beyond the sensor noise halves (an RMS that halves does: noise only lowers the RMS drop;
                # the beyond-noise drop is not computed where the window is at the noise)
                right_bn += max(r["windows"].get(want, 0.0), r["windows_bn"].get(want, 0.0)) >= 0.5
            # a constant torque the record cannot attribute: said so, the truth among its explanations
            a = r["answer"]
            if a.get("status") == "not_named" and want in [c["name"] for c in a.get("carriers") or []]:
                among.append(r["run"])
        if not r["truth"]:
            nulls += 1
            ok = set(r["found"]) <= BASE_CONTENT | BASE_COMPLIANCE | EXPLAINERS and not r["beyond"]
            null_clean += ok
            clean += [r["run"]] if ok else []
        if len(r["truth"]) == 1 and r["truth"][0] in FOREIGN:
            foreign.append(r["run"])
            want = SENSOR_CHANNEL.get(r["channel"], FOREIGN[r["truth"][0]]) if r["channel"] else FOREIGN[r["truth"][0]]
            if r["unexplained"] and any(v in x for v in want for x in r["structured"]) \
                    and not set(r["found"]) & INVENTED:
                flagged.append(r["run"])
    print(f"\nright first effect with its window error halved: {right} / {lib} library runs ({right_bn} with the "
          f"error beyond the sensor noise halved; first, any drop: "
          f"{len(first)}: {', '.join(first) or '-'}); nulls adding only what the base contains (the detailed no-back, "
          f"constant-torque explainers within their bounds): {null_clean} / {nulls} ({', '.join(clean) or '-'}); "
          f"out-of-library flagged with the right signature, nothing invented: {len(flagged)} / {len(foreign)} "
          f"({', '.join(flagged) or '-'}); library runs not named first where the record says a constant torque "
          f"beyond the base is present and not attributed, the truth among its explanations: {len(among)} "
          f"({', '.join(x for x in among if x not in first) or '-'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
