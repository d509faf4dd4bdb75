"""Tests of :mod:`thsa_control.data.rigdata` (``thsa-rig-run/1`` reader, writer, summary).

Oracles:

* the shared example run, written by an independent reference simulator of the
  rig (``shared/rig-data/examples``), must read as is;
* a synthetic run built here from the rig kinematics of FORMAT.md (1 mm/s nut =
  5 rpm screw = 328.05 rpm motor), with seeded sensor noise of the size the
  example declares (2 rpm, 0.2 rpm, 0.005 mm, 50 N rms), is the valid baseline;
  each malformed case changes one thing in a copy of it, in ``tmp_path``.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np
import pytest

from thsa_control.errors import RigDataError
from thsa_control.data.rigdata import (
    FORMAT_TAG,
    RigRun,
    read_run,
    to_columns,
    write_run,
)
from thsa_control.data.rigsummary import SummarySettings, format_summary, summarize_run
from thsa_control.data.units import mm_to_m, rpm_to_rad_s

MOTOR_RPM_PER_MM_S = 328.05  # FORMAT.md: 12 mm lead, gear ratio 65.61
SCREW_RPM_PER_MM_S = 5.0


def _shared_rig_data() -> Path:
    """``rig-data``: from $THSA_SHARED_DIR (the ``shared`` folder) when set, else the copy in tests/data."""
    env = os.environ.get("THSA_SHARED_DIR")
    base = Path(env) if env else Path(__file__).resolve().parent / "data"
    return base / "rig-data"


EXAMPLE = _shared_rig_data() / "examples" / "excitation_tensile_12kN.csv"
needs_example = pytest.mark.skipif(
    not EXAMPLE.is_file(),
    reason=f"shared example run not found at {EXAMPLE} (set THSA_SHARED_DIR to the shared/ folder)")


# ---------------------------------------------------------------- helpers
def synthetic_columns(rng: np.random.Generator, n: int = 2000) -> dict[str, np.ndarray]:
    """A plausible 2 s run at 1 kHz in FORMAT units.

    Speed command: 0 until 0.2 s, +3 mm/s until 1.0 s, -2 mm/s until 1.6 s,
    then 0.  Load +5 kN compressive: it opposes the extension and aids the
    retraction.
    """
    t = np.arange(n) * 1e-3
    cmd = np.where(t < 0.2, 0.0, np.where(t < 1.0, 3.0, np.where(t < 1.6, -2.0, 0.0)))
    travel = np.concatenate(([0.0], np.cumsum(0.5 * (cmd[1:] + cmd[:-1]) * np.diff(t))))
    return {
        "time_s": t,
        "speed_cmd_mm_s": cmd,
        "load_force_N": 5000.0 + 50.0 * rng.standard_normal(n),
        "motor_speed_rpm": MOTOR_RPM_PER_MM_S * cmd + 2.0 * rng.standard_normal(n),
        "motor_current_A": 2.0 + 0.05 * rng.standard_normal(n),
        "nut_position_mm": travel + 0.005 * rng.standard_normal(n),
        "screw_speed_rpm": SCREW_RPM_PER_MM_S * cmd + 0.2 * rng.standard_normal(n),
    }


META = {
    "format": FORMAT_TAG,
    "name": "synthetic",
    "temperature_C": 25.0,
    "sample_rate_hz": 1000.0,
    "controller": {
        "velocity_loop": {"kp_A_per_rad_s": 0.05, "ki_A_per_rad": 1.0, "current_limit_A": 15.0},
        "current_loop": {"kp_V_per_A": 10.0, "ki_V_per_A_s": 5000.0, "voltage_limit_V": 270.0},
        "control_period_s": 0.0001,
    },
    "motor_disabled_when_cmd_zero": True,
    "operator": "free metadata, kept",
}


@pytest.fixture
def rng():
    return np.random.default_rng(20240611)


@pytest.fixture
def valid_run(tmp_path, rng) -> Path:
    """A valid run written with write_run; returns the CSV path."""
    csv_path, _ = write_run(tmp_path / "run", synthetic_columns(rng), META)
    return csv_path


def read_table(csv_path: Path) -> tuple[list[str], list[list[str]]]:
    with open(csv_path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def write_table(csv_path: Path, header: list[str], rows: list[list[str]]) -> None:
    csv_path.write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n")


def set_cell(csv_path: Path, column: str, row: int, value: str) -> None:
    """Overwrite one cell; ``row`` counts data rows from 1 as RigDataError does."""
    header, rows = read_table(csv_path)
    rows[row - 1][header.index(column)] = value
    write_table(csv_path, header, rows)


def set_column(csv_path: Path, column: str, transform) -> None:
    header, rows = read_table(csv_path)
    j = header.index(column)
    for r in rows:
        r[j] = f"{transform(float(r[j])):.9g}"
    write_table(csv_path, header, rows)


def drop_column(csv_path: Path, column: str) -> None:
    header, rows = read_table(csv_path)
    j = header.index(column)
    write_table(csv_path, header[:j] + header[j + 1:], [r[:j] + r[j + 1:] for r in rows])


def add_column(csv_path: Path, column: str, cells: list[str]) -> None:
    header, rows = read_table(csv_path)
    write_table(csv_path, header + [column], [r + [c] for r, c in zip(rows, cells)])


def insert_row(csv_path: Path, row: int, cells: list[str]) -> None:
    header, rows = read_table(csv_path)
    write_table(csv_path, header, rows[:row - 1] + [cells] + rows[row - 1:])


def edit_json(csv_path: Path, **changes) -> None:
    path = csv_path.with_suffix(".json")
    meta = json.loads(path.read_text())
    for key, value in changes.items():
        if value is None:
            meta.pop(key, None)
        else:
            meta[key] = value
    path.write_text(json.dumps(meta))


def problem_for(exc: RigDataError, column: str, row: int | None = None):
    """The problem of ``exc`` on ``column`` (and ``row``), failing with all problems shown."""
    for problem in exc.problems:
        if problem[0] == column and (row is None or problem[1] == row):
            return problem
    raise AssertionError(f"no problem for column {column!r} row {row!r} in:\n{exc}")


# ----------------------------------------------------------- shared example
@needs_example
def test_example_reads_in_si():
    run = read_run(EXAMPLE)
    assert run.name == "excitation_tensile_12kN"
    assert run.warnings == ()
    assert run.time.size == 10001
    assert run.duration_s == pytest.approx(10.0)
    assert run.sample_rate_hz == 1000.0
    # Largest sample of motor_speed_rpm in the file is 1364.065 rpm (checked by hand).
    assert np.nanmax(run.signals["motor_speed"]) == pytest.approx(rpm_to_rad_s(1364.065))
    assert np.max(run.signals["nut_position"]) == pytest.approx(mm_to_m(26.23615))
    assert set(run.signals) >= {"speed_cmd", "load_force", "motor_speed", "motor_current",
                                "nut_position", "screw_speed", "temperature",
                                "primary_enable", "standby_enable"}
    assert not run.has("position_cmd")
    assert np.all(run.signals["temperature"] == 25.0)  # from the JSON
    assert np.all(run.signals["primary_enable"] == 1) and np.all(run.signals["standby_enable"] == 0)
    assert run.controller.velocity_loop.kp == 0.1
    assert run.controller.current_loop.voltage_limit == 155.885
    assert "note" in run.controller.current_loop.extra
    assert run.metadata["sensors_noise_rms"]["load_force_N"] == 50.0  # extra keys kept
    assert run.motor_disabled_when_cmd_zero is True
    assert run.gear_ratio == 65.61 and run.screw_lead == pytest.approx(0.012)
    with pytest.raises(ValueError):
        run.time[0] = 1.0  # read-only


@needs_example
def test_example_summary_says_load_aids_the_motion():
    summary = summarize_run(read_run(EXAMPLE))
    # The JSON: 12 kN tensile (negative) load applied at 0.1-0.3 s, motion at +3 mm/s
    # from 0.5 s to 9.3 s, so the load aids the extension for ~8.8 s and never opposes it.
    assert summary.opposing_duration_s == 0.0
    assert summary.aiding_duration_s == pytest.approx(8.8, abs=0.05)
    (phase,) = summary.load_phases
    assert (phase.kind, phase.direction) == ("aiding", "extend")
    assert phase.mean_speed_cmd_mm_s == pytest.approx(3.0, abs=0.05)
    assert phase.mean_load_force_N == pytest.approx(-12000.0, rel=0.01)
    # motor_disabled_when_cmd_zero: off while the command is exactly 0 (t < 0.501 s, t > 9.299 s)
    assert [round(i.start_s, 3) for i in summary.motor_off] == [0.0, 9.3]
    assert summary.reversals == ()
    text = format_summary(summary)
    assert "load aids the +3 mm/s motion (extend)" in text
    assert "opposes 0 s" in text
    assert "gaps: none" in text


@needs_example
def test_example_round_trips_exactly(tmp_path):
    run = read_run(EXAMPLE)
    csv_path, json_path = write_run(tmp_path / "copy", to_columns(run), run.metadata)
    again = read_run(csv_path)
    # The example has at most 7 significant digits per cell, fewer than the 9 written.
    np.testing.assert_array_equal(again.time, run.time)
    for name, values in run.signals.items():
        np.testing.assert_array_equal(again.signals[name], values, err_msg=name)
    assert json.loads(json_path.read_text()) == run.metadata


# ------------------------------------------------------------ valid synthetic
def test_synthetic_run_reads(valid_run):
    run = read_run(valid_run)
    assert isinstance(run, RigRun)
    assert run.warnings == ()
    assert run.metadata["operator"] == "free metadata, kept"
    assert run.json_path == valid_run.with_suffix(".json")
    assert run.source_columns["motor_speed"] == "motor_speed_rpm"


def test_synthetic_summary(valid_run):
    summary = summarize_run(read_run(valid_run))
    kinds = [(p.kind, p.direction) for p in summary.load_phases]
    # +5 kN compressive: opposes +3 mm/s (0.2-1.0 s), aids -2 mm/s (1.0-1.6 s).
    assert kinds == [("opposing", "extend"), ("aiding", "retract")]
    assert summary.opposing_duration_s == pytest.approx(0.8, abs=2e-3)
    assert summary.aiding_duration_s == pytest.approx(0.6, abs=2e-3)
    assert [(r.direction, r.row) for r in summary.reversals] == [("retract", 1001)]
    assert [(round(i.start_s, 3), round(i.end_s, 3)) for i in summary.motor_off] == \
        [(0.0, 0.2), (1.6, 2.0)]
    text = format_summary(summary)
    assert "load opposes the +3 mm/s motion (extend)" in text
    assert "to retract at 1 s (row 1001)" in text


def test_summary_settings_validate(valid_run):
    with pytest.raises(ValueError, match="force_deadband"):
        summarize_run(read_run(valid_run), SummarySettings(force_deadband=-1.0))


# ----------------------------------------------------------- malformed runs
MALFORMED = {
    # kind: (mutation of the valid run, culprit column, culprit row, message fragment)
    "missing required column": (lambda p: drop_column(p, "load_force_N"),
                                "load_force_N", 0, "missing required column"),
    "non-increasing time": (lambda p: set_cell(p, "time_s", 50, "0.048"),
                            "time_s", 50, "does not strictly increase"),
    "NaN": (lambda p: set_cell(p, "load_force_N", 30, "nan"), "load_force_N", 30, "not allowed"),
    "inf": (lambda p: set_cell(p, "speed_cmd_mm_s", 31, "inf"), "speed_cmd_mm_s", 31,
            "not allowed"),
    "non-numeric": (lambda p: set_cell(p, "motor_current_A", 12, "1.2x"), "motor_current_A", 12,
                    "not a number"),
    "gap of 2 samples": (lambda p: [set_cell(p, "motor_current_A", r, "") for r in (100, 101)],
                         "motor_current_A", 100, "gap of 2 samples"),
    "empty required cell": (lambda p: set_cell(p, "speed_cmd_mm_s", 7, ""), "speed_cmd_mm_s", 7,
                            "missing value"),
    "rpm given in rad/s": (lambda p: set_column(p, "motor_speed_rpm", lambda x: x * 2 * np.pi / 60),
                           "motor_speed_rpm", 201, "looks like rad/s"),
    "screw rpm given in rad/s": (lambda p: set_column(p, "screw_speed_rpm",
                                                      lambda x: x * 2 * np.pi / 60),
                                 "screw_speed_rpm", 201, "looks like rad/s"),
    "position in metres": (lambda p: set_column(p, "nut_position_mm", lambda x: x / 1000),
                           "nut_position_mm", 1, "looks like metres"),
    "speed command in m/s": (lambda p: set_column(p, "speed_cmd_mm_s", lambda x: x / 1000),
                             "speed_cmd_mm_s", None, "looks like m/s"),
    "temperature in K": (lambda p: add_column(p, "temperature_C", ["298.15"] * 2000),
                         "temperature_C", 1, "looks like kelvin"),
    "enable not 0/1": (lambda p: add_column(p, "primary_enable", ["1"] * 9 + ["2"] + ["1"] * 1990),
                       "primary_enable", 10, "must be 0 or 1"),
    "duplicate column": (lambda p: add_column(p, "load_force_N", ["0"] * 2000),
                         "load_force_N", 0, "duplicate column"),
    "ragged row": (lambda p: insert_row(p, 5, ["1", "2"]), None, 5, "has 2 field(s), the header"),
    "no speed measurement": (lambda p: [drop_column(p, c) for c in ("motor_speed_rpm",
                                                                    "screw_speed_rpm")],
                             "motor_speed_rpm", 0, "one of motor_speed_rpm, screw_speed_rpm"),
}


@pytest.mark.parametrize("kind", list(MALFORMED))
def test_malformed_csv_is_rejected_naming_file_column_row(valid_run, kind):
    mutate, column, row, fragment = MALFORMED[kind]
    mutate(valid_run)
    with pytest.raises(RigDataError) as info:
        read_run(valid_run)
    exc = info.value
    assert exc.file == str(valid_run)
    problem = problem_for(exc, column, row)
    assert fragment in problem[2]
    text = str(exc)
    assert str(valid_run) in text
    if column is not None:
        assert f"column '{column}'" in text
    if problem[1] is not None:
        assert f"row {problem[1]}" in text


MALFORMED_JSON = {
    "wrong format tag": ({"format": "thsa-rig-run/2"}, "format", "expected 'thsa-rig-run/1'"),
    "no format": ({"format": None}, "format", "missing"),
    "no temperature": ({"temperature_C": None}, "temperature_C", "required"),
    "temperature in K": ({"temperature_C": 298.15}, "temperature_C", "looks like kelvin"),
    "negative gain": ({"controller": {**META["controller"], "velocity_loop": {
        "kp_A_per_rad_s": -0.05, "ki_A_per_rad": 1.0, "current_limit_A": 15.0}}},
        "controller.velocity_loop.kp_A_per_rad_s", ">= 0"),
    "non-numeric gain": ({"controller": {**META["controller"], "current_loop": {
        "kp_V_per_A": "ten", "ki_V_per_A_s": 5000.0, "voltage_limit_V": 270.0}}},
        "controller.current_loop.kp_V_per_A", "finite number"),
    "missing period": ({"controller": {k: v for k, v in META["controller"].items()
                                       if k != "control_period_s"}},
                       "controller.control_period_s", "positive number"),
    "flag not boolean": ({"motor_disabled_when_cmd_zero": "yes"}, "motor_disabled_when_cmd_zero",
                         "true or false"),
    "bad sample rate": ({"sample_rate_hz": 0}, "sample_rate_hz", "positive"),
    "bad kinematics": ({"rig": {"screw_lead_mm": -12}}, "rig.screw_lead_mm", "positive"),
}


@pytest.mark.parametrize("kind", list(MALFORMED_JSON))
def test_malformed_json_is_rejected_naming_file_and_key(valid_run, kind):
    changes, key, fragment = MALFORMED_JSON[kind]
    edit_json(valid_run, **changes)
    with pytest.raises(RigDataError) as info:
        read_run(valid_run)
    json_path = valid_run.with_suffix(".json")
    assert info.value.file == str(json_path)
    problem = problem_for(info.value, f"{json_path.name}:{key}")
    assert fragment in problem[2]
    assert str(json_path) in str(info.value)


def test_missing_and_unparsable_files(valid_run, tmp_path):
    with pytest.raises(RigDataError, match="CSV file not found") as info:
        read_run(tmp_path / "nothing.csv")
    assert any("JSON file not found" in p[2] for p in info.value.problems)  # both reported
    valid_run.with_suffix(".json").write_text("{not json")
    with pytest.raises(RigDataError, match="malformed JSON"):
        read_run(valid_run)
    valid_run.with_suffix(".json").write_text('{"format": "thsa-rig-run/1", "x": NaN}')
    with pytest.raises(RigDataError, match="NaN is not valid JSON"):
        read_run(valid_run)
    valid_run.write_text("")
    with pytest.raises(RigDataError, match="no header"):
        read_run(valid_run)


def test_time_in_milliseconds_is_detected_from_sample_rate(valid_run):
    set_column(valid_run, "time_s", lambda x: 1000 * x)
    with pytest.raises(RigDataError, match="looks like milliseconds") as info:
        read_run(valid_run)
    assert len(info.value.problems) == 1  # kinematic checks are not run on a wrong time base


def test_all_violations_are_reported_at_once(valid_run):
    set_cell(valid_run, "load_force_N", 30, "nan")
    set_cell(valid_run, "time_s", 50, "0.048")
    set_cell(valid_run, "motor_current_A", 5, "")
    set_cell(valid_run, "motor_current_A", 6, "")
    set_column(valid_run, "motor_speed_rpm", lambda x: x * 2 * np.pi / 60)
    add_column(valid_run, "standby_enable", ["0.5"] + ["0"] * 1999)
    edit_json(valid_run, format="thsa-rig-run/0")
    with pytest.raises(RigDataError) as info:
        read_run(valid_run)
    exc = info.value
    assert exc.file == str(valid_run)  # the CSV has problems: the run's file is named
    problem_for(exc, "load_force_N", 30)
    problem_for(exc, "time_s", 50)
    problem_for(exc, "motor_current_A", 5)
    problem_for(exc, "motor_speed_rpm")
    problem_for(exc, "standby_enable", 1)
    problem_for(exc, "run.json:format")
    assert len(exc.problems) == 6


def test_repeated_problem_is_listed_then_counted(valid_run):
    header, rows = read_table(valid_run)
    j = header.index("load_force_N")
    for r in rows:
        r[j] = "nan"
    write_table(valid_run, header, rows)
    with pytest.raises(RigDataError, match="1990 more row") as info:
        read_run(valid_run)
    assert len(info.value.problems) == 11


# ------------------------------------------- plausible runs are never rejected
def _stalled(c, rng):
    # velocity loop saturated against a hard stop: no speed, no travel, only noise
    c["motor_speed_rpm"] = 2.0 * rng.standard_normal(c["time_s"].size)
    c["screw_speed_rpm"] = 0.2 * rng.standard_normal(c["time_s"].size)
    c["nut_position_mm"] = 0.005 * rng.standard_normal(c["time_s"].size)


def _backdriven(c, rng):
    # no command at all, the load drives the nut back through the no-back
    c["speed_cmd_mm_s"] = np.zeros_like(c["time_s"])
    c["motor_speed_rpm"] = -20.0 + 2.0 * rng.standard_normal(c["time_s"].size)


def _lagging(c, rng):
    # 40 ms late response to the steps of the command
    c["motor_speed_rpm"] = np.concatenate((np.zeros(40), c["motor_speed_rpm"][:-40]))


def _slow(c, rng):
    # 0.05 mm/s creep: 16 rpm at the motor against 2 rpm noise
    for name in ("speed_cmd_mm_s", "motor_speed_rpm", "screw_speed_rpm", "nut_position_mm"):
        c[name] = c[name] / 60.0


def _unloaded_cold(c, rng):
    # no load (tens of newtons read like kilonewtons would: not decidable, not rejected)
    c["load_force_N"] = 30.0 * rng.standard_normal(c["time_s"].size)
    c["temperature_C"] = np.full(c["time_s"].size, -40.0)


@pytest.mark.parametrize("variant", [_stalled, _backdriven, _lagging, _slow, _unloaded_cold])
def test_plausible_runs_are_read(tmp_path, rng, variant):
    columns = synthetic_columns(rng)
    variant(columns, rng)
    meta = dict(META)
    if "temperature_C" in columns:  # a JSON temperature far from the column is a contradiction (issue #7)
        meta["temperature_C"] = float(np.median(columns["temperature_C"]))
    csv_path, _ = write_run(tmp_path / "plausible", columns, meta)
    assert read_run(csv_path).warnings == ()


def test_rig_kinematics_come_from_json(tmp_path, rng):
    # A rig with gear ratio 30: 1 mm/s nut = 150 rpm motor.
    columns = synthetic_columns(rng)
    columns["motor_speed_rpm"] = columns["motor_speed_rpm"] * 30.0 / 65.61
    csv_path, _ = write_run(tmp_path / "geared", columns, {**META, "rig": {"gear_ratio": 30.0}})
    run = read_run(csv_path)
    assert run.warnings == () and run.gear_ratio == 30.0
    edit_json(csv_path, rig=None)  # seed kinematics: 328.05 rpm per mm/s
    (warning,) = read_run(csv_path).warnings
    assert "0.4572 x the kinematic prediction (328.05 rpm per mm/s" in warning


def test_reversed_sign_is_a_warning(valid_run):
    set_column(valid_run, "screw_speed_rpm", lambda x: -x)
    (warning,) = read_run(valid_run).warnings
    assert warning.startswith("column 'screw_speed_rpm': -1 x") and "sign" in warning


# ------------------------------------------------------------ gaps and extras
def test_single_gap_in_measured_column_is_a_warning_not_interpolated(valid_run):
    set_cell(valid_run, "nut_position_mm", 500, "")
    run = read_run(valid_run)
    assert run.warnings == ("column 'nut_position_mm', row 500: single missing sample, "
                            "kept as NaN (not interpolated)",)
    assert np.isnan(run.signals["nut_position"][499])
    assert np.isfinite(np.delete(run.signals["nut_position"], 499)).all()
    summary = summarize_run(run)
    assert [(g.column, g.row, g.length) for g in summary.gaps] == [("nut_position_mm", 500, 1)]
    assert "nut_position_mm row 500" in format_summary(summary)


def test_unknown_extra_columns_are_kept(valid_run):
    add_column(valid_run, "bus_voltage_V", [f"{270 + i % 3}" for i in range(2000)])
    add_column(valid_run, "operator_note", ["ok"] * 1999 + ["stop"])
    run = read_run(valid_run)
    assert list(run.extra) == ["bus_voltage_V", "operator_note"]
    assert run.extra["bus_voltage_V"][:4].tolist() == [270.0, 271.0, 272.0, 270.0]
    assert run.extra["operator_note"][-1] == "stop"
    assert run.has("bus_voltage_V")
    assert "bus_voltage_V" in format_summary(summarize_run(run))


# -------------------------------------------------------------- column map
RIG_NAMES = {"t": "time_s", "v_cmd": "speed_cmd_mm_s", "F": "load_force_N",
             "n_mot": "motor_speed_rpm"}


def rename_columns(csv_path: Path, mapping: dict[str, str]) -> None:
    header, rows = read_table(csv_path)
    inverse = {v: k for k, v in mapping.items()}
    write_table(csv_path, [inverse.get(h, h) for h in header], rows)


def test_column_map_reads_other_names(valid_run):
    reference = read_run(valid_run)
    rename_columns(valid_run, RIG_NAMES)
    with pytest.raises(RigDataError, match="missing required column"):
        read_run(valid_run)
    run = read_run(valid_run, column_map=RIG_NAMES)
    np.testing.assert_array_equal(run.time, reference.time)
    np.testing.assert_array_equal(run.signals["load_force"], reference.signals["load_force"])
    assert run.source_columns["load_force"] == "F"
    assert "n_mot" not in run.extra


def test_column_map_errors_name_the_original_column(valid_run):
    rename_columns(valid_run, RIG_NAMES)
    set_cell(valid_run, "F", 30, "nan")
    set_column(valid_run, "n_mot", lambda x: x * 2 * np.pi / 60)
    with pytest.raises(RigDataError) as info:
        read_run(valid_run, column_map={**RIG_NAMES, "absent": "temperature_C", "x": "bogus"})
    problem_for(info.value, "F (as load_force_N)", 30)
    problem_for(info.value, "n_mot (as motor_speed_rpm)", 201)
    assert "column 'F (as load_force_N)', row 30" in str(info.value)
    problem_for(info.value, "absent", 0)  # a mapped column the CSV does not have
    problem_for(info.value, "x", 0)  # a target that is not a FORMAT column


def test_column_map_duplicate_is_reported(valid_run):
    with pytest.raises(RigDataError, match="duplicate column") as info:
        read_run(valid_run, column_map={"screw_speed_rpm": "motor_speed_rpm"})
    problem_for(info.value, "motor_speed_rpm", 0)


# ------------------------------------------------------------------ writer
def test_writer_round_trip_is_exact_to_written_precision(tmp_path, rng):
    columns = synthetic_columns(rng)
    columns["position_cmd_mm"] = np.cumsum(columns["speed_cmd_mm_s"]) * 1e-3
    columns["standby_enable"] = np.zeros(2000)
    columns["zz_extra"] = rng.standard_normal(2000)
    columns["aa_extra"] = np.linspace(0.0, 1.0, 2000)
    csv_path, json_path = write_run(tmp_path / "rt", columns, META)
    assert (csv_path, json_path) == (tmp_path / "rt.csv", tmp_path / "rt.json")
    header = csv_path.read_text().splitlines()[0].split(",")
    # standard columns in FORMAT.md order, then extras in the order given
    assert header == ["time_s", "speed_cmd_mm_s", "load_force_N", "motor_speed_rpm",
                      "motor_current_A", "nut_position_mm", "screw_speed_rpm",
                      "position_cmd_mm", "standby_enable", "zz_extra", "aa_extra"]
    run = read_run(csv_path)
    back = to_columns(run)
    assert list(back) == header
    for name, values in columns.items():
        written = np.array([float(f"{v:.9g}") for v in values])
        # exact at the written precision; the SI round trip (rpm -> rad/s -> rpm) costs ulps
        rtol = 0 if name in ("time_s", "load_force_N", "motor_current_A") or "extra" in name \
            else 1e-15
        np.testing.assert_allclose(back[name], written, rtol=rtol, atol=0, err_msg=name)
        np.testing.assert_allclose(back[name], values, rtol=5e-9, atol=1e-300, err_msg=name)
    meta = json.loads(json_path.read_text())
    assert meta == {**META}
    assert list(meta)[0] == "format"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rt.csv", "rt.json"]  # no temp dir left


def test_writer_sets_format_and_name(tmp_path, rng):
    csv_path, json_path = write_run(tmp_path / "bare", synthetic_columns(rng),
                                    {"temperature_C": 20.0})
    meta = json.loads(json_path.read_text())
    assert meta["format"] == FORMAT_TAG and meta["name"] == "bare"
    assert read_run(csv_path).name == "bare"


def test_writer_keeps_time_increasing_beyond_9_digits(tmp_path, rng):
    columns = synthetic_columns(rng)
    columns["time_s"] = 1.0e6 + columns["time_s"]  # 1000000.001 needs 10 digits
    csv_path, _ = write_run(tmp_path / "late", columns, META)
    assert csv_path.read_text().splitlines()[2].startswith("1000000.001")
    np.testing.assert_array_equal(read_run(csv_path).time, columns["time_s"])


@pytest.mark.parametrize("change, column, row, fragment", [
    (lambda c: c["load_force_N"].__setitem__(7, np.nan), "load_force_N", 8, "not finite"),
    (lambda c: c["time_s"].__setitem__(20, 0.0), "time_s", 21, "does not strictly increase"),
    (lambda c: c.__setitem__("motor_current_A", np.ones(5)), "motor_current_A", None,
     "has 5 samples"),
    (lambda c: c.__setitem__("primary_enable", np.full(2000, 0.5)), "primary_enable", 1,
     "0 or 1"),
    (lambda c: c.pop("speed_cmd_mm_s"), "speed_cmd_mm_s", 0, "missing required column"),
    (lambda c: c.__setitem__("bad,name", np.zeros(2000)), "bad,name", 0, "column name"),
])
def test_writer_rejects_bad_input_and_leaves_nothing(tmp_path, rng, change, column, row, fragment):
    columns = synthetic_columns(rng)
    change(columns)
    with pytest.raises(RigDataError) as info:
        write_run(tmp_path / "bad", columns, META)
    problem = problem_for(info.value, column, row)
    assert fragment in problem[2]
    assert info.value.file == str(tmp_path / "bad.csv")
    assert list(tmp_path.iterdir()) == []


def test_writer_failure_on_read_back_leaves_nothing_and_keeps_old_files(tmp_path, rng):
    columns = synthetic_columns(rng)
    csv_path, json_path = write_run(tmp_path / "run", columns, META)
    before = (csv_path.read_bytes(), json_path.read_bytes())
    rad_s = dict(columns, motor_speed_rpm=columns["motor_speed_rpm"] * 2 * np.pi / 60)
    with pytest.raises(RigDataError, match="looks like rad/s") as info:
        write_run(tmp_path / "run", rad_s, META)
    assert info.value.file == str(csv_path)
    no_temperature = {k: v for k, v in META.items() if k != "temperature_C"}
    with pytest.raises(RigDataError, match="temperature_C"):
        write_run(tmp_path / "run", columns, no_temperature)
    with pytest.raises(RigDataError, match="expected 'thsa-rig-run/1'"):
        write_run(tmp_path / "run", columns, {**META, "format": "other"})
    with pytest.raises(RigDataError, match="not JSON serialisable"):
        write_run(tmp_path / "run", columns, {**META, "obj": object()})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv", "run.json"]
    assert (csv_path.read_bytes(), json_path.read_bytes()) == before
    with pytest.raises(FileExistsError):
        write_run(tmp_path / "run", columns, META, overwrite=False)


@pytest.mark.parametrize("values", [
    np.array([0.1, -2.5e-7, 123456789.123, np.nan, 0.0, -0.0, 1e300, 5e-324, np.inf]),
    np.arange(-3, 1000, 7),
    (np.arange(50) / 7).astype(np.float32),
    np.array([True, False, True]),
])
def test_cells_are_numpy_s_printf_text(values):
    """The CSV cells are what ``np.char.mod`` gives (``%`` on each value), NaN an empty cell: the faster
    formatting of write_run changes no byte."""
    from thsa_control.data.rigdata import _format

    for fmt in ("%.9g", "%.17g", "%.3g"):
        expected = np.char.mod(fmt, values)
        expected[np.isnan(values)] = ""
        assert _format(values, fmt) == expected.tolist()
