"""The analysis report: every named figure and table is there, analysis.json validates against
docs/analysis_schema.json, a failing design says where and by how much, the CLI writes atomically."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import pytest

from thsa_control.loops.analysis import AnalysisSettings, analyse_design
from thsa_control.cli import main
from thsa_control.loops.design import parse_design
from thsa_control.report.analysis_report import FIGURES, TABLES, write_analysis_report
from thsa_control.loops.switching import analyse_switchover

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = json.loads((ROOT / "docs" / "analysis_schema.json").read_text())
SMALL = AnalysisSettings(nut_speeds=(0.0, 1e-3, 2e-3, 10e-3), load_forces=(-55e3, 0.0, 55e3),
                         temperatures=(-55.0, 25.0, 70.0))


# ------------------------------------------------------------------------------------------------
# a small JSON Schema validator (the keywords docs/analysis_schema.json uses), so that the check
# does not depend on an optional package; jsonschema, when installed, is run as well
# ------------------------------------------------------------------------------------------------
def _type_ok(value, kind: str) -> bool:
    return {
        "object": isinstance(value, dict), "array": isinstance(value, list), "string": isinstance(value, str),
        "boolean": isinstance(value, bool), "null": value is None,
        "integer": isinstance(value, int) and not isinstance(value, bool),
        "number": isinstance(value, (int, float)) and not isinstance(value, bool),
    }[kind]


def validate(value, schema, root=SCHEMA, path="$") -> list[str]:
    """Errors of ``value`` against ``schema`` (empty list: valid)."""
    if "$ref" in schema:
        node = root
        for part in schema["$ref"].lstrip("#/").split("/"):
            node = node[part]
        return validate(value, node, root, path)
    errors = []
    if "const" in schema and value != schema["const"]:
        errors.append(f"{path}: {value!r} != {schema['const']!r}")
    if "enum" in schema and value not in schema["enum"]:
        errors.append(f"{path}: {value!r} not in {schema['enum']}")
    if "type" in schema:
        kinds = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
        if not any(_type_ok(value, k) for k in kinds):
            return errors + [f"{path}: {type(value).__name__} is not {kinds}"]
    if "oneOf" in schema:
        n_ok = sum(not validate(value, sub, root, path) for sub in schema["oneOf"])
        if n_ok != 1:
            errors.append(f"{path}: matches {n_ok} of the oneOf alternatives")
    if "minimum" in schema and _type_ok(value, "number") and value < schema["minimum"]:
        errors.append(f"{path}: {value} < {schema['minimum']}")
    if isinstance(value, dict):
        props = schema.get("properties", {})
        for key in schema.get("required", []):
            if key not in value:
                errors.append(f"{path}: missing {key!r}")
        for key, item in value.items():
            if key in props:
                errors += validate(item, props[key], root, f"{path}.{key}")
            elif schema.get("additionalProperties") is False:
                errors.append(f"{path}: unexpected key {key!r}")
            elif isinstance(schema.get("additionalProperties"), dict):
                errors += validate(item, schema["additionalProperties"], root, f"{path}.{key}")
    if isinstance(value, list) and "items" in schema:
        for i, item in enumerate(value):
            errors += validate(item, schema["items"], root, f"{path}[{i}]")
    return errors


def test_the_validator_rejects_what_the_schema_forbids():
    good = {"format": "thsa-analysis/1"}
    assert validate(good["format"], SCHEMA["properties"]["format"]) == []
    assert validate("thsa-analysis/2", SCHEMA["properties"]["format"])
    metric = {"$ref": "#/$defs/metric"}
    assert validate(1.5, metric) == [] and validate(None, metric) == [] and validate("inf", metric) == []
    assert validate("nan", metric) and validate([1.0], metric)
    assert any("missing 'format'" in e for e in validate({}, SCHEMA))
    cond = {"nut_speed_mm_s": 1.0, "load_N": 0.0, "temperature_C": 25.0, "active": "primary", "label": "x"}
    assert validate(cond, {"$ref": "#/$defs/condition"}) == []
    assert validate({**cond, "extra": 1}, {"$ref": "#/$defs/condition"})
    assert validate({**cond, "active": "both"}, {"$ref": "#/$defs/condition"})


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
    assert validate(doc, SCHEMA) == []
    try:
        import jsonschema
    except ImportError:  # pragma: no cover - jsonschema comes with nbformat (test extra)
        pass
    else:
        jsonschema.validate(doc, SCHEMA)
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
    assert len(invalid) == 13 and all(p["invalid_reasons"] for p in invalid)  # 9 at zero speed, 4 saturated
    worst = doc["loops"]["velocity_loop"]["worst"]["phase_margin_deg"]
    assert worst["condition"]["label"] == nominal_result.loops.worst("velocity_loop", "phase_margin_deg").condition.label()
    assert worst["condition"]["label"] == "2 mm/s, -55 kN (aiding), 70 degC"
    assert doc["passed"] is True and doc["requirement_check"]["violations"] == []
    assert {c["delay_s"] for c in doc["switching"]["cases"]} == {0.005, 0.015, 0.05}
    assert len(doc["configurations"]) > 0 and len(doc["limit_cycles"]) > 0


def test_failing_design_is_reported_with_point_and_value(nominal_result, tmp_path):
    doc = nominal_result.design.to_toml_dict()
    doc["requirements"] = {"velocity_loop": {"max_overshoot_percent": 20.0}}
    strict = parse_design(doc, source="strict.toml")
    from thsa_control.loops.analysis import check_requirements

    loops = replace(nominal_result.loops, design=strict)
    result = replace(nominal_result, design=strict, loops=loops, requirements=check_requirements(loops))
    write_analysis_report(result, tmp_path / "strict")
    data = json.loads((tmp_path / "strict" / "analysis.json").read_text())
    assert validate(data, SCHEMA) == []
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


def test_cli_report_writes_the_report(tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["report", "--design", str(ROOT / "designs" / "nominal.toml"), "--out", str(out), "--check"]) == 0
    text = capsys.readouterr().out
    assert "requirements: PASS" in text and "worst velocity_loop phase_margin_deg" in text
    assert {p.name for p in out.iterdir()} == {"report.html", "analysis.json", "figures", ".thsa-output"}
    doc = json.loads((out / "analysis.json").read_text())
    assert validate(doc, SCHEMA) == []
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
