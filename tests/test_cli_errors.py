"""No tracebacks (issue #7, item 3 and 6): one-line errors with exit 2, internal errors exit 3, fast --help.

Each case below raised a Python traceback on main before this fix (or, for
control periods, ran: 1e-12 s tried to allocate 21 TiB, 1.0 s gave -61,000
rpm for a +9 mm/s command; a rig JSON with a 1 s controller replayed to an
RMS of 2.8e12 with exit 0).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from thsa_control import cli
from thsa_control.cli import main

REPO = Path(__file__).resolve().parents[1]
SIM = ["simulate", "--scenario", "cold_ramp", "--level", "A", "--quiet"]
NOMINAL = (REPO / "designs" / "nominal.toml").read_text()


def _env():
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}


def one_line_error(capsys, *fragments):
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    for f in fragments:
        assert f in err, err
    return err


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory):
    """A closed-loop run (CSV + JSON with a controller block) written by `thsa simulate`."""
    d = tmp_path_factory.mktemp("run") / "sim"
    assert main(SIM + ["--out", str(d)]) == 0
    return d / "cold_ramp_A.csv"


def _copy_run(src: Path, dst_dir: Path, edit=None) -> Path:
    dst = dst_dir / "run.csv"
    dst.write_bytes(src.read_bytes())
    meta = json.loads(src.with_suffix(".json").read_text())
    if edit:
        edit(meta)
    dst.with_suffix(".json").write_text(json.dumps(meta))
    return dst


def test_non_utf8_design_and_parameter_files(tmp_path, capsys):
    bad = tmp_path / "latin1.toml"
    bad.write_bytes("name = \"d\u00e9sign\"\n".encode("latin-1"))
    assert main(SIM + ["--design", str(bad), "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, "latin1.toml", "not UTF-8")
    assert main(SIM + ["--params", str(bad), "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, "latin1.toml", "not UTF-8")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("mapping", ["{t: time_s}", "[1, 2]", '{"t": 3}', "[" * 100_000])
def test_bad_column_map(sim_run, capsys, mapping):
    assert main(["check-data", str(sim_run), "--column-map", mapping]) == 2
    one_line_error(capsys, "--column-map")


@pytest.mark.parametrize("period, fragment", [("0", "positive"), ("-1e-3", "positive"), ("nan", "positive"),
                                              ("1.5e-4", "whole multiple of the design's control period")])
def test_bad_output_period(tmp_path, capsys, period, fragment):
    assert main(SIM + [f"--output-period={period}", "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, "--output-period", fragment)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("period, fragment", [("1e-12", "below 1e-06 s"),
                                              ("1.0", "electrical time constant L/R = 1.83 ms")])
def test_control_period_validated_against_the_plant(tmp_path, capsys, period, fragment):
    design = tmp_path / "d.toml"
    text = NOMINAL.replace("control_period_s = 1e-4", f"control_period_s = {period}")
    assert text != NOMINAL
    design.write_text(text)
    assert main(SIM + ["--design", str(design), "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, "d.toml", "control_period_s", fragment)


def test_rig_controller_period_validated_against_the_plant(sim_run, tmp_path, capsys):
    def slow(meta):
        meta["controller"]["control_period_s"] = 1.0

    run = _copy_run(sim_run, tmp_path, slow)
    assert main(["residual", str(run), "--model", "A", "--quiet", "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, "run.json", "controller.control_period_s", "L/R")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("option, fragment", [(["--substeps", "0"], "--substeps 0"),
                                              (["--segment", "-1"], "--segment -1.0"),
                                              (["--segment", "0"], "--segment 0.0")])
def test_bad_identification_options(sim_run, tmp_path, capsys, option, fragment):
    assert main(["identify", str(sim_run), "--model", "A", "--free", "gear.viscous_friction", "--quiet",
                 "--out", str(tmp_path / "o")] + option) == 2
    one_line_error(capsys, fragment)


def test_deeply_nested_json_sidecar(sim_run, tmp_path, capsys):
    run = _copy_run(sim_run, tmp_path)
    run.with_suffix(".json").write_text('{"format": "thsa-rig-run/1", "x": ' + "[" * 100_000 + "]" * 100_000 + "}")
    assert main(["check-data", str(run)]) == 2
    err = capsys.readouterr().err
    assert "nested too deeply" in err and "Traceback" not in err


def test_output_under_a_file_is_refused(tmp_path, capsys):
    f = tmp_path / "file.txt"
    f.write_text("x")
    assert main(SIM + ["--out", str(f / "sub")]) == 2
    one_line_error(capsys, "is not a folder")


def test_internal_error_exit_3_one_line(monkeypatch, capsys):
    def boom(args):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr("thsa_control.cli.sim.cmd_scenarios", boom)
    monkeypatch.delenv("THSA_DEBUG", raising=False)
    assert main(["scenarios"]) == cli.EXIT_INTERNAL == 3
    err = capsys.readouterr().err
    assert err.startswith("internal error (ZeroDivisionError)") and err.count("\n") == 1
    assert "THSA_DEBUG=1" in err
    monkeypatch.setenv("THSA_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        main(["scenarios"])


def test_exit_codes_are_distinct():
    assert (cli.EXIT_OK, cli.EXIT_REQUIREMENT_FAILED, cli.EXIT_USAGE, cli.EXIT_INTERNAL) == (0, 1, 2, 3)


def test_help_imports_no_numerics_and_version():
    code = ("import sys\nfrom thsa_control.cli import build_parser\nbuild_parser().format_help()\n"
            "print(sorted(m for m in ('casadi', 'control', 'scipy', 'matplotlib', 'numpy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(), timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stderr
    proc = subprocess.run([sys.executable, "-m", "thsa_control.cli", "--version"], capture_output=True, text=True,
                          env=_env(), timeout=60)
    from thsa_control import __version__
    assert proc.returncode == 0 and proc.stdout.strip() == f"thsa-control {__version__}"
    proc = subprocess.run([sys.executable, "-m", "thsa_control.cli", "--help"], capture_output=True, text=True,
                          env=_env(), timeout=60)
    assert proc.returncode == 0 and "check-data" in proc.stdout


def test_help_and_a_bad_argument_answer_before_any_numerics_import():
    """``thsa --help`` and a usage error (exit 2) of a command whose work needs casadi import no numerics:
    they answer in start-up time (issue #17, item 5)."""
    code = ("import sys\nfrom thsa_control.cli import main\n"
            "for argv in (['--help'], ['faults', '--bogus'], ['levels', '--levels', 'A']):\n"
            "    try:\n        code = main(argv)\n    except SystemExit as exc:\n        code = exc.code\n"
            "    print('EXIT', code, sorted(m for m in ('casadi', 'control', 'scipy', 'matplotlib')\n"
            "                               if m in sys.modules), file=sys.stderr)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(), timeout=60)
    lines = [x for x in out.stderr.splitlines() if x.startswith("EXIT ")]
    assert lines == ["EXIT 0 []", "EXIT 2 []", "EXIT 2 []"], out.stderr[-2000:]


def test_public_names_still_importable_from_the_package():
    import thsa_control

    for name in thsa_control.__all__:
        assert getattr(thsa_control, name) is not None


def test_progress_on_stderr_and_quiet(tmp_path, capsys):
    argv = ["levels", "--levels", "A", "--scenario", "cold_ramp", "--out"]
    assert main(argv + [str(tmp_path / "a")]) == 0
    captured = capsys.readouterr()
    lines = [x for x in captured.err.splitlines() if x.startswith("thsa levels: ")]
    assert any("simulating cold_ramp at level A" in x for x in lines) and lines[-1].startswith("thsa levels: done in")
    assert "thsa levels:" not in captured.out
    assert main(argv + [str(tmp_path / "b"), "--quiet"]) == 0
    assert "thsa levels:" not in capsys.readouterr().err


def test_progress_heartbeat_fills_silences_and_stops_with_its_block():
    import io
    import threading
    import time

    from thsa_control.progress import Progress

    buf = io.StringIO()
    p = Progress("thsa demo", stream=buf)
    p.phase("fitting")
    with p.heartbeat(0.2):
        time.sleep(0.75)
    beats = [x for x in buf.getvalue().splitlines() if x.startswith("thsa demo: fitting ... (")]
    assert 2 <= len(beats) <= 4, buf.getvalue()
    # stopped with the block: its thread is gone (nothing can write any more), and nothing came after it over
    # three of its polling periods (0.05 s at every_s = 0.2)
    assert not [t for t in threading.enumerate() if t.name == "thsa demo heartbeat"]
    n = len(buf.getvalue())
    time.sleep(0.15)
    assert len(buf.getvalue()) == n
    cb = p.fit_callback(every_s=0.0)
    cb(7, 1.5, 0.1)
    assert buf.getvalue().splitlines()[-1] == "thsa demo: 7 evaluations, best cost 1.5, 0.1 s"
    quiet = Progress("thsa demo", stream=buf, enabled=False)
    assert quiet.fit_callback() is None
    with quiet.heartbeat(0.05):
        time.sleep(0.2)
    assert len(buf.getvalue().splitlines()) == len(beats) + 2
