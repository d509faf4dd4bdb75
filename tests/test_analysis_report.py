"""The analysis report: every named figure and table is there, analysis.json validates against
docs/analysis_schema.json, a failing design says where and by how much, the CLI writes atomically."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from thsa_control.loops.analysis import AnalysisSettings, analyse_design
from thsa_control.cli import main
from thsa_control.loops.design import parse_design
from thsa_control.report.analysis_report import FIGURES, TABLES, write_analysis_report
from thsa_control.loops.switching import analyse_switchover

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = json.loads((ROOT / "docs" / "analysis_schema.json").read_text())
jsonschema = pytest.importorskip("jsonschema")  # in the test extra
jsonschema.Draft202012Validator.check_schema(SCHEMA)
VALIDATOR = jsonschema.Draft202012Validator(SCHEMA)
SMALL = AnalysisSettings(nut_speeds=(0.0, 1e-3, 2e-3, 10e-3), load_forces=(-55e3, 0.0, 55e3),
                         temperatures=(-55.0, 25.0, 70.0))


def validate(doc) -> list[str]:
    """Errors of ``doc`` against docs/analysis_schema.json (empty list: valid), by jsonschema."""
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in VALIDATOR.iter_errors(doc)]


def _definition(name: str):
    return jsonschema.Draft202012Validator({"$defs": SCHEMA["$defs"], **SCHEMA["$defs"][name]})


def test_the_schema_rejects_what_it_forbids():
    assert validate({"format": "thsa-analysis/1"})  # everything else missing
    metric = _definition("metric")
    assert all(metric.is_valid(v) for v in (1.5, None, "inf", "-inf"))
    assert not metric.is_valid("nan") and not metric.is_valid([1.0])
    cond = _definition("condition")
    c = {"nut_speed_mm_s": 1.0, "load_N": 0.0, "temperature_C": 25.0, "active": "primary", "label": "x"}
    assert cond.is_valid(c) and not cond.is_valid({**c, "extra": 1}) and not cond.is_valid({**c, "active": "both"})


# ------------------------------------------------------------------------------------------------
# the report of the nominal design (small grid, fewer switch-over delays: the same code paths)
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def switching(design, params):
    return analyse_switchover(design, params, level="B", delays_s=(0.005, 0.015, 0.05))


@pytest.fixture(scope="module")
def nominal_result(design, params, switching):
    return analyse_design(design, params, settings=SMALL, switching=switching)


@pytest.fixture(scope="module")
def nominal_report(nominal_result, tmp_path_factory):
    out = tmp_path_factory.mktemp("reports") / "nominal"
    write_analysis_report(nominal_result, out)
    return out


def test_report_has_every_figure_and_table(nominal_report):
    html = (nominal_report / "report.html").read_text()
    for name in FIGURES:
        pattern = rf"<figure id='fig-{name}'><img alt='{name}' src='data:image/png;base64,[A-Za-z0-9+/]{{2000,}}"
        assert re.search(pattern, html), name
        assert (nominal_report / "figures" / f"{name}.png").stat().st_size > 20_000, name
    for name in TABLES:
        assert f'<table id="table-{name}">' in html, name
    assert "Requirements at every valid grid point: <span class='pass'>PASS</span>" in html
    # the margins table marks the worst point; the invalid-points table says why
    assert "class='worstrow'" in html and "zero speed (stick)" in html and "current limit 15 A" in html
    assert "src='http" not in html and "<script" not in html  # self-contained


def test_analysis_json_validates_and_holds_every_loop_and_point(nominal_report, nominal_result):
    doc = json.loads((nominal_report / "analysis.json").read_text())
    assert validate(doc) == []
    n = len(nominal_result.loops)
    assert doc["grid"]["n_points"] == n == len(doc["points"]) == 36
    for loop in ("current_loop", "velocity_loop", "position_loop"):
        rows = doc["loops"][loop]["points"]
        assert len(rows) == n
        for key in ("crossover_hz", "phase_margin_deg", "gain_margin_db", "delay_margin_s", "bandwidth_hz", "ms",
                    "valid", "step"):
            assert all(key in r for r in rows)
        assert all(set(r["step"]) >= {"rise_time_s", "settling_time_s", "overshoot_percent"} for r in rows)
    invalid = [p for p in doc["points"] if not p["valid"]]
    assert len(invalid) == 10 and all(p["invalid_reasons"] for p in invalid)  # 9 at zero speed, 1 saturated
    worst = doc["loops"]["velocity_loop"]["worst"]["phase_margin_deg"]
    assert worst["condition"]["label"] == nominal_result.loops.worst("velocity_loop", "phase_margin_deg").condition.label()
    assert worst["condition"]["label"] == "2 mm/s, -55 kN (aiding), -55 degC"
    assert doc["passed"] is True and doc["requirement_check"]["violations"] == []
    assert {c["delay_s"] for c in doc["switching"]["cases"]} == {0.005, 0.015, 0.05}
    assert len(doc["configurations"]) > 0 and len(doc["limit_cycles"]) > 0


@pytest.mark.slow
def test_failing_design_is_reported_with_point_and_value(nominal_result, tmp_path):
    doc = nominal_result.design.to_toml_dict()
    doc["requirements"] = {"velocity_loop": {"max_overshoot_percent": 20.0}}
    strict = parse_design(doc, source="strict.toml")
    from thsa_control.loops.analysis import check_requirements

    loops = replace(nominal_result.loops, design=strict)
    result = replace(nominal_result, design=strict, loops=loops, requirements=check_requirements(loops))
    write_analysis_report(result, tmp_path / "strict")
    data = json.loads((tmp_path / "strict" / "analysis.json").read_text())
    assert validate(data) == []
    assert data["passed"] is False
    worst = max(data["requirement_check"]["violations"], key=lambda v: v["value"])
    assert worst["condition"]["label"] == nominal_result.loops.worst("velocity_loop", "overshoot_percent").condition.label()
    assert worst["value"] > 25 and worst["limit"] == 20.0
    row = data["loops"]["velocity_loop"]["points"][worst["index"]]
    assert row["passed"] is False and row["failed_requirements"] == ["max_overshoot_percent"]
    html = (tmp_path / "strict" / "report.html").read_text()
    assert "<span class='failtxt'>FAIL</span>" in html
    assert f"worst overshoot_percent = {worst['value']:.4g} at {worst['condition']['label']}" in html
    assert "td class='fail" in html


@pytest.mark.slow
def test_cli_report_writes_the_report(tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["report", "--design", str(ROOT / "designs" / "nominal.toml"), "--out", str(out), "--check"]) == 0
    text = capsys.readouterr().out
    assert "requirements: PASS" in text and "worst velocity_loop phase_margin_deg" in text
    # --check also writes the verdict of thsa check on every requirement (issue #20)
    assert {p.name for p in out.iterdir()} == {"report.html", "analysis.json", "check.json", "figures", ".thsa-output"}
    assert json.loads((out / "check.json").read_text())["passed"] is True and "verdict: PASS" in text
    doc = json.loads((out / "analysis.json").read_text())
    assert validate(doc) == []
    assert doc["grid"]["n_points"] == 175 and doc["switching"] is not None


def test_cli_report_bad_input_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("control_period_s = 1e-4\n[current_loop]\nkp_V_per_A = 14\nki_V_per_A_s = 7700\n"
                   "[velocity_loop]\nkp_A_per_rad_s = 0.1\nki_A_per_rad = 4\ncurrent_limit_A = 15\n"
                   "[position_loop]\nkp_per_s = 10\n[requirements.velocity_loop]\nmin_phase_margin = 45\n")
    out = tmp_path / "out"
    assert main(["report", "--design", str(bad), "--out", str(out)]) == 2
    assert "unknown key 'min_phase_margin'" in capsys.readouterr().err
    assert main(["report", "--level", "Z", "--out", str(out)]) == 2
    assert "unknown model level 'Z'" in capsys.readouterr().err
    assert not out.exists()


# ------------------------------------------------------------------------------------------------
# readability (issue 7, item 9)
# ------------------------------------------------------------------------------------------------
def test_both_gain_margins_and_conditional_stability_are_reported(nominal_report, nominal_result):
    doc = json.loads((nominal_report / "analysis.json").read_text())
    rows = doc["loops"]["velocity_loop"]["points"]
    worst = doc["loops"]["velocity_loop"]["worst"]
    k = worst["gain_margin_db"]["index"]
    # at the cold aiding point the loop is conditionally stable: the lower margin is kept, and the upper one too
    assert rows[k]["gain_margin_lower_db"] == rows[k]["gain_margin_db"] < 0
    assert rows[k]["gain_margin_upper_db"] > 20
    assert worst["gain_margin_db"]["note"].startswith("conditionally stable (lower gain margin -13")
    m = nominal_result.loops.loops["velocity_loop"].margins
    assert rows[k]["gain_margin_upper_db"] == pytest.approx(float(m.gain_margin_upper_db[k]))
    # the current loop has only an upper one (at Nyquist): its lower one is -inf, and not a worst point
    cur = doc["loops"]["current_loop"]
    assert all(r["gain_margin_lower_db"] in ("-inf", None) for r in cur["points"])
    assert "gain_margin_lower_db" not in cur["worst"] and "gain_margin_upper_db" in cur["worst"]
    assert worst["load_step_peak"]["unit"] == "m/s of nut speed per N of load"
    assert doc["loops"]["position_loop"]["worst"]["load_step_peak"]["unit"] == "m of nut position per N of load"
    html = (nominal_report / "report.html").read_text()
    assert "lower gain margin [dB]" in html and "upper gain margin [dB]" in html
    assert "sensitivity peak Ms" in html and "ms [-]" not in html
    # the requirements table gives both gain margins, the lower one named (issue #18: "lower -13.4 dB / upper +29 dB")
    assert (f"lower {rows[k]['gain_margin_lower_db']:+.1f} dB / upper {rows[k]['gain_margin_upper_db']:+.1f} dB "
            "(lower: conditionally stable)") in html
    # tables in display units (data/units.py): load-step peaks per kN, times in ms; the JSON stays SI
    assert "load-step peak [mm/s per kN]" in html and "load-step peak [um per kN]" in html
    assert "delay margin [ms]" in html


def test_invalid_points_never_say_stable(nominal_report):
    doc = json.loads((nominal_report / "analysis.json").read_text())
    for loop in ("current_loop", "velocity_loop", "position_loop"):
        for r in doc["loops"][loop]["points"]:
            assert (r["stable"] is None) == (not r["valid"])
    invalid = [r for r in doc["configurations"] if not r["valid"]]
    assert invalid and all(r["stable"] is None for r in invalid)
    assert all(isinstance(r["stable"], bool) for r in doc["configurations"] if r["valid"])
    html = (nominal_report / "report.html").read_text()
    table = html[html.index('<table id="table-configurations">'):]
    table = table[:table.index("</table>")]
    for row in re.findall(r"<tr class='invalid'>(.*?)</tr>", table):
        assert ">yes<" not in row  # neither 'stable: yes' nor anything else claimed at an invalid point


def test_long_tables_are_collapsible_with_the_reason_in_front(nominal_report):
    html = (nominal_report / "report.html").read_text()
    for loop in ("current_loop", "velocity_loop", "position_loop"):
        start = html.index(f'<table id="table-margins_{loop}">')
        opening = html.rfind("<details", 0, start)
        assert opening > html.rfind("</details>", 0, start) and not html[opening:start].startswith("<details open")
        header = html[start:html.index("</tr>", start)]
        cols = re.findall(r"<th[^>]*>(.*?)</th>", header)
        assert cols.index("invalid because") == 4 < cols.index("stable")  # before the 12 metric columns
    for name in ("invalid_points", "configurations"):
        start = html.index(f'<table id="table-{name}">')
        assert html.rfind("<details", 0, start) > html.rfind("</details>", 0, start), name
    assert "overflow-x:auto" in html  # wide tables scroll inside the page


def test_bode_phase_is_on_a_readable_branch(nominal_result):
    from thsa_control.report.analysis_plots import _phase_branches, _phase_crossings, plot_loop_bode

    a = nominal_result.loops
    for loop in ("current_loop", "velocity_loop", "position_loop"):
        m = a.loops[loop].margins
        f = m.omega / (2 * np.pi)
        ph = _phase_branches(m.L, f, m.crossover_hz)
        for k in np.flatnonzero(a.valid):
            # the phase margin reads off the plotted curve as phase + 180 at the crossover
            pc = np.interp(np.log(m.crossover_hz[k]), np.log(f), ph[k])
            assert pc + 180 == pytest.approx(m.phase_margin_deg[k], abs=0.5), (loop, k)
            assert np.nanmax(np.abs(np.diff(ph[k]))) < 30  # no jump, at Nyquist either
        fig = plot_loop_bode(a, loop)
        lo, hi = fig.axes[1].get_ylim()
        assert lo >= -405 and hi <= 45
        import matplotlib.pyplot as plt

        plt.close(fig)
    # the worst velocity point has two -180 deg crossings: the lower and the upper gain margin
    k = a.worst("velocity_loop", "phase_margin_deg").index
    m = a.loops["velocity_loop"].margins
    gms = np.array([gm for _, gm in _phase_crossings(m.L[k], m.omega / (2 * np.pi))])
    assert gms[gms < 0].max() == pytest.approx(m.gain_margin_lower_db[k], abs=0.05)
    assert gms[gms > 0].min() == pytest.approx(m.gain_margin_upper_db[k], abs=0.05)


@pytest.mark.slow
def test_report_grid_from_the_command_line_and_the_design_file(tmp_path, capsys, design):
    doc = design.to_toml_dict()
    doc["analysis"] = {"nut_speeds_mm_s": [2.0, 10.0], "loads_kN": [-55.0, 20.0], "temperatures_C": [25.0]}
    import tomli_w

    path = tmp_path / "grid.toml"
    path.write_bytes(tomli_w.dumps(doc).encode())
    out = tmp_path / "r"
    assert main(["report", "--design", str(path), "--temperature", "70", "--no-switching", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    # the loaded no-back disk's Stribeck drop (55 kN on it) makes the loop conditionally stable at 2 mm/s aided
    assert "velocity_loop gain_margin_db: conditionally stable (lower gain margin -14.0 dB, upper +" in text
    assert not re.search(r"gain_margin_db = -", text)  # never a bare negative margin next to PASS
    grid = json.loads((out / "analysis.json").read_text())["grid"]
    assert grid["nut_speeds_mm_s"] == [2.0, 10.0] and grid["load_forces_N"] == [-55e3, 20e3]
    assert grid["temperatures_C"] == [70.0] and grid["n_points"] == 4  # the command line wins
    assert main(["report", "--design", str(path), "--speeds", "5", "--loads=0,20", "--temperatures", "0,70",
                 "--no-switching", "--out", str(out)]) == 0
    grid = json.loads((out / "analysis.json").read_text())["grid"]
    assert grid["nut_speeds_mm_s"] == [5.0] and grid["temperatures_C"] == [0.0, 70.0] and grid["n_points"] == 4
    capsys.readouterr()
    doc["analysis"] = {"temperature_C": [25.0]}
    path.write_bytes(tomli_w.dumps(doc).encode())
    assert main(["report", "--design", str(path), "--out", str(tmp_path / "bad")]) == 2
    assert "unknown key 'temperature_C' in [analysis]" in capsys.readouterr().err
    assert main(["report", "--temperatures", "-60", "--out", str(tmp_path / "bad")]) == 2
    assert "-60 degC is outside -55..70 degC" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
