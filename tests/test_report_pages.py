"""What an engineer sees (issue #18): display units, figures outside pyplot, report pages that read at a glance."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from thsa_control.data.units import DISPLAY_UNITS, from_display, label, signal_display, to_display
from thsa_control.report.display import gain_margins_text, requirement_status

ROOT = Path(__file__).resolve().parents[1]


# ---- the display-unit table ----------------------------------------------------------------------------

def test_the_display_unit_table_holds_the_issues_units():
    units = {u.unit for u in DISPLAY_UNITS.values()}
    assert {"mm", "mm/s", "kN", "N m", "rpm", "A", "V", "degC", "ms"} <= units
    # conversions that an engineer checks by hand
    assert to_display("force", -55e3) == -55.0 and to_display("nut_speed", 2e-3) == 2.0
    assert to_display("rotational_speed", 2 * math.pi) == pytest.approx(60.0)
    assert to_display("time", 0.015) == pytest.approx(15.0) and to_display("position", 1e-3) == pytest.approx(1.0)
    assert to_display("velocity_load_step", 3.1e-8) == pytest.approx(0.031)  # m/s per N -> mm/s per kN
    for q, u in DISPLAY_UNITS.items():
        assert u.factor > 0, q
        assert from_display(q, to_display(q, 1.2345)) == pytest.approx(1.2345), q
    assert label("load", "force") == "load [kN]" and signal_display("motor_speed").unit == "rpm"


def test_unit_conversions_live_only_in_units():
    """No module outside data/units.py multiplies by a bare 60 / (2 pi) (the rpm factor)."""
    offenders = []
    for path in (ROOT / "thsa_control").rglob("*.py"):
        if path.name == "units.py":
            continue
        text = path.read_text(encoding="utf-8")
        if re.search(r"60\s*/\s*\(\s*2\s*\*\s*(np\.|math\.)?pi\s*\)", text):
            offenders.append(str(path.relative_to(ROOT)))
    assert not offenders, offenders


# ---- figures: no backend forced, object API ---------------------------------------------------------------

def test_no_module_sets_the_matplotlib_backend():
    assert not [p for p in (ROOT / "thsa_control").rglob("*.py") if "matplotlib.use(" in p.read_text(encoding="utf-8")]
    code = ("import matplotlib; matplotlib.use('svg'); import thsa_control.report.analysis_report, "
            "thsa_control.report.faults, thsa_control.report.plots, thsa_control.report.identification, "
            "thsa_control.report.trace, thsa_control.report.tuning_report; print(matplotlib.get_backend())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "svg"  # the user's backend is left alone


def test_report_figures_are_outside_pyplot_and_show_in_notebooks():
    import matplotlib.pyplot as plt

    from thsa_control.report.figure import ReportFigure, subplots

    before = plt.get_fignums()
    fig, ax = subplots(1, 1, figsize=(3, 2))
    ax.plot([0, 1], [0, 1])
    assert isinstance(fig, ReportFigure) and plt.get_fignums() == before  # not registered with pyplot
    png = fig._repr_png_()  # what IPython/Jupyter display
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000


# ---- verdict colours and gain-margin wording ----------------------------------------------------------------

def _line_figure(n):
    from thsa_control.report.figure import subplots

    fig, ax = subplots(figsize=(3, 2))
    ax.plot(np.arange(10), np.arange(10) ** n)
    ax.set_title(f"power {n}")
    return fig


def test_figures_drawn_in_parallel_processes_are_the_same_pngs_in_order(monkeypatch):
    """render_pngs: forked processes give byte for byte the PNGs drawn in-process, in the jobs' order, and say
    each as it is ready; a bad THSA_FIGURE_PROCESSES is named."""
    from thsa_control.report.figure import png_bytes, render_pngs

    jobs = [(_line_figure, (n,)) for n in (1, 2, 3)]
    seen = []
    parallel = render_pngs(jobs, processes=2, done=seen.append)
    assert parallel == render_pngs(jobs, processes=1) == [png_bytes(_line_figure(n)) for n in (1, 2, 3)]
    assert seen == [0, 1, 2] and len(set(parallel)) == 3
    monkeypatch.setenv("THSA_FIGURE_PROCESSES", "two")
    with pytest.raises(ValueError, match="THSA_FIGURE_PROCESSES"):
        render_pngs(jobs)


def test_requirement_colours_are_relative_to_the_limit_not_to_the_data():
    # phase margin 68 deg against a 45 deg limit passes with room; 46 is close; 44 fails
    assert list(requirement_status([68.0, 46.0, 44.0], 45.0, ">=")) == [2, 1, 0]
    # Ms 1.0498 and 1.0508 against 1.5: the same colour (the old maps, auto-scaled, made them green and red)
    assert list(requirement_status([1.0498, 1.0508], 1.5, "<=")) == [2, 2]
    # gain margins by magnitude: a lower margin of -13.4 dB passes a 6 dB requirement
    assert list(requirement_status([-13.4, 5.0, np.nan], 6.0, "abs>=")) == [2, 0, 3]
    assert list(requirement_status([1.0], None, None)) == [3]  # no requirement
    assert gain_margins_text(-13.39, 29.04) == "lower -13.4 dB / upper +29.0 dB"


# ---- identification / residual pages: tables, figures first ----------------------------------------------

def test_residual_page_has_tables_in_display_units_and_figures_first(tmp_path):
    from thsa_control.fit.residuals import analyse_residuals
    from thsa_control.report.identification import residual_tables, write_html_report

    rng = np.random.default_rng(3)
    t = np.arange(0.0, 4.0, 1e-3)
    speed_cmd = np.where(t < 2.0, 3e-3, -3e-3)  # m/s
    e = np.where(speed_cmd > 0, 2.0, 0.3) * rng.standard_normal(t.size)  # rad/s, larger when extending
    a = analyse_residuals(t, {"motor_speed": e}, {"motor_speed": np.zeros(t.size)}, {"speed_cmd": speed_cmd},
                          {"speed_cmd": speed_cmd}, units={"motor_speed": "rad/s"})
    sections = residual_tables(a)
    first = sections[0][1]
    rms_rpm = a["motor_speed"].rms * 60 / (2 * math.pi)
    assert "<td>rpm</td>" in first.replace("<td class='l'>rpm</td>", "<td>rpm</td>") and f"{rms_rpm:.4g}" in first
    where = sections[1][1]
    assert ">3 mm/s<" in where and "0.003" not in where  # the extending half's bin, in mm/s (SI m/s inside)
    page = write_html_report(tmp_path / "r.html", title="t", sections=sections + [("text", "a < b")],
                             figures={"fig one": b"\x89PNG..."})
    text = page.read_text()
    assert text.index("<figure>") < text.index("<table>")  # the plots first
    assert "<nav>" in text and "href='#figures'" in text and "a &lt; b" in text


# ---- the rig-run format is in the repository ------------------------------------------------------------

def test_the_rig_format_page_describes_every_column_and_key_the_reader_knows():
    from thsa_control.data.rigformat import COLUMNS, FORMAT_TAG

    page = (ROOT / "docs" / "rig_format.md").read_text(encoding="utf-8")
    for name, spec in COLUMNS.items():
        assert f"`{name}` | {spec.unit.replace('degC', 'degC')} |" in page, name  # name and unit in the table
    keys = ("temperature_C", "sample_rate_hz", "kp_A_per_rad_s", "ki_A_per_rad", "current_limit_A", "kp_V_per_A",
            "ki_V_per_A_s", "voltage_limit_V", "control_period_s", "motor_disabled_when_cmd_zero", "screw_lead_mm",
            "gear_ratio", "position_loop", "current_feedforward", "computation_delay_samples")
    for key in keys:
        assert key in page, key
    assert FORMAT_TAG in page and "compressive" in page and "What the reader checks" in page
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "docs/rig_format.md" in readme
    # the repository never sends the reader to a folder outside it for the format
    assert "shared/rig-data/FORMAT.md" not in readme
