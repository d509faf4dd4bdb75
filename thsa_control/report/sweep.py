"""The sweep report: ``report.html`` (self-contained), ``report.json``, figures and replay files.

Draws :class:`~thsa_control.sweep.analysis.SweepAnalysis`; computes no
physics.  For every worst case, ``replay/run_N_scenario.toml`` and
``replay/run_N_params.toml`` hold the run's scenario (temperature, load,
fault times applied) and its parameter set, and the report gives the
``thsa simulate`` command that runs it alone.  Written in a hidden folder
renamed at the end (nothing half-written).
"""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np
import tomli_w

from .build import atomic_folder, write_json
from .figure import subplots
from .identification import Html, figure_png, html_table, write_html_report

__all__ = ["plot_against_input", "plot_distribution", "plot_sensitivity", "write_sweep_report"]


def _fmt(x) -> str:
    if isinstance(x, float):
        return f"{x:.4g}" if math.isfinite(x) else str(x)
    return str(x)


def _table(head, rows) -> Html:
    return html_table(head, [[c if isinstance(c, Html) else _fmt(c) for c in row] for row in rows])


def plot_distribution(analysis, metric: str, limits=()):
    """Histogram of ``metric`` per design x scenario group (all runs when there is one group), limits marked."""
    from ..sweep.metrics import metric_unit

    groups = [s for s in analysis.summaries if s.metric == metric]
    shown = [s for s in groups if s.group != "all"] or groups
    fig, ax = subplots(figsize=(8, 3.6))
    finite = [s.values[np.isfinite(s.values)] for s in shown]
    allv = np.concatenate(finite) if finite else np.zeros(0)
    if allv.size:
        bins = np.histogram_bin_edges(allv, bins=min(40, max(5, int(np.sqrt(allv.size)) + 1)))
        for s, v in zip(shown, finite):
            ax.hist(v, bins=bins, histtype="step", lw=1.4, label=f"{s.group} (n = {v.size})")
    for lim in limits:
        for x in (lim.min, lim.max):
            if math.isfinite(x):
                ax.axvline(x, color="r", ls="--", lw=1)
    ax.set_xlabel(f"{metric} [{metric_unit(metric)}]")
    ax.set_ylabel("runs")
    n_inf = sum(int(np.isinf(s.values).sum()) for s in shown)
    ax.set_title(metric + (f" ({n_inf} runs at inf not shown)" if n_inf else ""), fontsize=10)
    if shown:
        ax.legend(fontsize=8)
    return fig


def plot_sensitivity(analysis, metric: str, group: str, top: int = 10):
    """Bars of the rank correlations (and Sobol' indices when computed) of ``metric`` in ``group``."""
    rows = [s for s in analysis.sensitivity if s.metric == metric and s.group == group][:top]
    fig, ax = subplots(figsize=(8, 0.4 * max(len(rows), 2) + 1.2))
    y = np.arange(len(rows))
    ax.barh(y - 0.2, [s.spearman for s in rows], height=0.4, label="Spearman rank correlation")
    if any(math.isfinite(s.total) for s in rows):
        ax.barh(y + 0.2, [s.total for s in rows], height=0.4, label="Sobol' total index")
    ax.set_yticks(y, [s.input for s in rows], fontsize=8)
    ax.invert_yaxis()
    ax.axvline(0, color="k", lw=0.5)
    ax.set_title(f"{metric}: {group}", fontsize=10)
    ax.legend(fontsize=8)
    return fig


def plot_against_input(analysis, metric: str, name: str, limits=()):
    """``metric`` of every run against the varied quantity ``name``, one colour per design x scenario group."""
    from ..sweep.metrics import metric_unit

    y = next(s.values for s in analysis.summaries if s.metric == metric and s.group == "all")
    x = analysis.inputs[name]
    fig, ax = subplots(figsize=(8, 3.6))
    groups = list(dict.fromkeys(analysis.groups.tolist()))
    for g in groups:
        m = analysis.groups == g
        ax.plot(x[m], y[m], ".", ms=5, label=g if len(groups) > 1 else None)
    for lim in limits:
        for v in (lim.min, lim.max):
            if math.isfinite(v):
                ax.axhline(v, color="r", ls="--", lw=1)
    ax.set_xlabel(name)
    ax.set_ylabel(f"{metric} [{metric_unit(metric)}]")
    ax.set_title(f"{metric} against {name}", fontsize=10)
    if len(groups) > 1:
        ax.legend(fontsize=8)
    return fig


def _replay_files(spec, run: int, folder: Path) -> tuple[str, str]:
    from ..sim.scenarios import scenario_to_dict
    from ..sweep.engine import run_inputs

    rs, = spec.run_specs([run])
    _, scenario, params = run_inputs(spec, rs)
    sc = folder / f"run_{run}_scenario.toml"
    pf = folder / f"run_{run}_params.toml"
    sc.write_text(tomli_w.dumps(scenario_to_dict(scenario)), encoding="utf-8")
    params.save(pf)
    return sc.name, pf.name


def write_sweep_report(spec, analysis, out_dir, **folder_options) -> Path:
    """Write ``report.json``, ``report.html``, figures and ``replay/`` into ``out_dir`` (atomically)."""
    from ..sweep.analysis import replay_command

    out_dir = Path(out_dir)
    data = analysis.to_dict()
    with atomic_folder(out_dir, **folder_options) as tmp:
        replay = tmp / "replay"
        replay.mkdir()
        commands = {}
        for w in analysis.worst:
            if w.run not in commands:
                sc, pf = _replay_files(spec, w.run, replay)
                commands[w.run] = replay_command(spec, w.run, str(out_dir.resolve() / "replay" / sc),
                                                 str(out_dir.resolve() / "replay" / pf))
        for item in data["worst_cases"]:
            item["replay"] = commands[item["run"]]
        write_json(tmp / "report.json", data)

        figs = []
        for m in spec.metrics:
            lims = [lim for lim in spec.limits if lim.metric == m]
            figs.append((f"dist_{m.replace(':', '_')}.png", plot_distribution(analysis, m, lims), f"distribution of {m}"))
        for m in spec.metrics:  # against the quantity it is most sensitive to (first group's ranking)
            top = next((x for x in analysis.sensitivity if x.metric == m and math.isfinite(x.spearman)), None)
            if top is not None:
                lims = [lim for lim in spec.limits if lim.metric == m]
                figs.append((f"vs_{m.replace(':', '_')}.png", plot_against_input(analysis, m, top.input, lims),
                             f"{m} against {top.input} (its strongest rank correlation, {top.group})"))
        groups = sorted({s.group for s in analysis.sensitivity})
        if spec.input_columns:
            for m in spec.metrics:
                for g in groups:
                    if any(math.isfinite(s.spearman) for s in analysis.sensitivity if s.metric == m and s.group == g):
                        name = f"sens_{m.replace(':', '_')}_{len(figs)}.png"
                        figs.append((name, plot_sensitivity(analysis, m, g), f"sensitivity of {m}, {g}"))
        s = data["spec"]
        lead = (f"{analysis.runs} runs ({analysis.failed_runs} failed to simulate): level {html.escape(s['level'])}"
                f" + {html.escape(', '.join(s['effects']) or 'no added effects')}; designs "
                f"{html.escape(', '.join(s['designs']))}; scenarios {html.escape(', '.join(s['scenarios']))}; "
                f"{html.escape(s['sampling'])} sampling, {s['samples']} samples x {s['grid_points']} grid points, "
                f"seed {s['seed']}; parameters: {html.escape(s['params'])}; spec SHA-256 {s['spec_sha256'][:16]}. "
                f"{html.escape(s['description'])}")
        sections = [
            ("What varies", _table(["quantity", "kind", "distribution"],
                                   [[v["name"], v["kind"], v["distribution"]] for v in s["variables"]])
             if s["variables"] else Html("<p>nothing (one deterministic run per design and scenario)</p>")),
            ("Failure probabilities (exact Clopper-Pearson 95 % intervals)", Html(
                "<p class='note'>A run that failed to simulate, or whose metric is not a number, counts as a "
                "failure.</p>" + _table(["requirement", "group", "failures", "runs", "probability", "95 % interval"],
                                        [[f.requirement, f.group, f.failures, f.runs, f.probability,
                                          f"[{f.interval[0]:.4g}, {f.interval[1]:.4g}]"] for f in analysis.failures]))),
            ("Metric distributions", _table(
                ["metric", "group", "runs", "finite", "mean", "sd", "5 %", "median", "95 %", "min", "max"],
                [[x.metric, x.group, x.n, x.finite, x.mean, x.sd, x.p05, x.p50, x.p95, x.min, x.max]
                 for x in analysis.summaries])),
            ("Worst cases", Html(
                _table(["metric", "rank", "run", "design", "scenario", "value", "varied values", "error"],
                       [[w.metric, w.rank, w.run, w.design, w.scenario, w.value,
                         ", ".join(f"{k} = {v:.6g}" for k, v in w.inputs.items()), w.error] for w in analysis.worst])
                + "<p>Replay one run alone (its scenario and parameters are in <code>replay/</code>):</p><ul>"
                + "".join(f"<li>run {r}: <code>{html.escape(c)}</code></li>" for r, c in commands.items()) + "</ul>")),
            ("Sensitivity ranking", _table(
                ["metric", "group", "input", "Spearman rho", "p-value", "Sobol' S1", "Sobol' ST"],
                [[x.metric, x.group, x.input, x.spearman, x.p_value, x.first_order, x.total]
                 for x in analysis.sensitivity]) if analysis.sensitivity else Html("<p>nothing varies</p>")),
        ]
        if analysis.errors:
            sections.append(("Runs that failed to simulate (first 20)",
                             _table(["run", "error"], [list(e) for e in analysis.errors])))
        pngs = {}
        for name, fig, caption in figs:
            png = figure_png(fig)
            (tmp / name).write_bytes(png)
            pngs[caption] = png
        write_html_report(tmp / "report.html", title=f"Sweep {s['name']}", sections=sections, figures=pngs,
                          figures_first=False, lead=lead)
    return out_dir
