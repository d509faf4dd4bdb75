"""Output safety (issue #7, item 1): --out replaces only what thsa wrote, never inputs, no leftovers.

Before this fix, each case here lost a user's files: ``--out`` on the run's
own folder deleted the input run, ``--out .`` emptied the current directory,
``--out file.txt`` turned the file into a folder, a foreign folder was
silently replaced, and hidden ``.NAME.XXXX`` folders (mode 0700) stayed
behind after SIGTERM.
"""

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from thsa_control.cli import main
from thsa_control.errors import OutputError
from thsa_control.report.build import MARKER, atomic_folder

SIM = ["simulate", "--scenario", "cold_ramp", "--level", "A", "--quiet"]
REPO = Path(__file__).resolve().parents[1]


def _hidden(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


@pytest.fixture(scope="module")
def own_run(tmp_path_factory):
    """A folder written by `thsa simulate` (marker inside) holding a run."""
    d = tmp_path_factory.mktemp("own") / "sim"
    assert main(SIM + ["--out", str(d)]) == 0
    return d


def test_input_inside_out_is_refused_even_with_force(own_run, tmp_path, capsys):
    d = tmp_path / "d"
    d.mkdir()
    (d / MARKER).write_text("{}")  # a folder thsa wrote, but it now holds the input run
    for suffix in (".csv", ".json"):
        (d / f"run{suffix}").write_bytes((own_run / f"cold_ramp_A{suffix}").read_bytes())
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    for extra in ([], ["--force"]):
        assert main(["residual", str(d / "run.csv"), "--model", "A", "--quiet", "--out", str(d)] + extra) == 2
        assert "holds the input file" in capsys.readouterr().err
        assert {p.name: p.read_bytes() for p in d.iterdir()} == before
    assert _hidden(tmp_path) == []


def test_out_dot_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    for extra in ([], ["--force"]):
        assert main(SIM + ["--out", "."] + extra) == 2
        assert "current directory" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]
    # a parent of the current directory is refused too
    sub = tmp_path / "a" / "b"
    sub.mkdir(parents=True)
    monkeypatch.chdir(sub)
    assert main(SIM + ["--out", str(tmp_path / "a"), "--force"]) == 2
    assert sub.is_dir()


def test_out_existing_file_is_refused(tmp_path, capsys):
    f = tmp_path / "existing_file.txt"
    f.write_text("precious")
    for extra in ([], ["--force"]):
        assert main(SIM + ["--out", str(f)] + extra) == 2
        assert "is an existing file" in capsys.readouterr().err
    assert f.is_file() and f.read_text() == "precious"
    assert _hidden(tmp_path) == []


def test_foreign_folder_refused_unless_force(tmp_path, capsys):
    d = tmp_path / "results"
    d.mkdir()
    (d / "thesis.tex").write_text("two years of work")
    assert main(SIM + ["--out", str(d)]) == 2
    err = capsys.readouterr().err
    assert "not written by thsa" in err and "--force" in err and err.count("\n") == 1
    assert (d / "thesis.tex").read_text() == "two years of work"
    assert main(SIM + ["--out", str(d), "--force"]) == 0
    assert (d / MARKER).is_file() and not (d / "thesis.tex").exists()
    assert _hidden(tmp_path) == []


def test_own_folder_replaced_with_normal_permissions(tmp_path):
    d = tmp_path / "sim"
    assert main(SIM + ["--out", str(d)]) == 0
    (d / "left_from_before.txt").write_text("x")
    assert main(SIM + ["--out", str(d)]) == 0  # own folder: replaced as a whole
    names = {p.name for p in d.iterdir()}
    assert MARKER in names and "cold_ramp_A.csv" in names and "left_from_before.txt" not in names
    umask = os.umask(0)
    os.umask(umask)
    assert d.stat().st_mode & 0o777 == 0o777 & ~umask
    assert (d / "summary.json").stat().st_mode & 0o777 == 0o666 & ~umask
    assert _hidden(tmp_path) == []


def test_empty_folder_is_fine(tmp_path):
    d = tmp_path / "empty"
    d.mkdir()
    with atomic_folder(d) as tmp:
        (tmp / "a.txt").write_text("a")
    assert (d / "a.txt").read_text() == "a"


def test_failure_keeps_old_folder_and_leaves_nothing(tmp_path):
    d = tmp_path / "out"
    with atomic_folder(d) as tmp:
        (tmp / "a.txt").write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_folder(d) as tmp:
            (tmp / "a.txt").write_text("new")
            raise RuntimeError("crash while writing")
    assert (d / "a.txt").read_text() == "old"
    assert _hidden(tmp_path) == []


def test_stale_hidden_folders_of_dead_processes_are_removed(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = [tmp_path / f".out.thsa-tmp-{dead.pid}", tmp_path / f".out.thsa-old-{dead.pid}",
             tmp_path / f".out.old.{dead.pid}"]  # the last: left by thsa-control before the marker
    for s in stale:
        s.mkdir()
        (s / "half.png").write_bytes(b"\x89PNG")
    alive = tmp_path / f".out.thsa-tmp-{os.getppid()}"  # a live process: not ours to remove
    alive.mkdir()
    foreign = tmp_path / ".out.keepme"  # not our naming pattern
    foreign.mkdir()
    with atomic_folder(tmp_path / "out") as tmp:
        (tmp / "a.txt").write_text("a")
    assert not any(s.exists() for s in stale)
    assert alive.is_dir() and foreign.is_dir()


def test_read_only_parent_is_refused(tmp_path, capsys):
    if os.geteuid() == 0:  # root writes anywhere: use a filesystem that refuses everyone
        if not os.path.isdir("/proc/self"):
            pytest.skip("no /proc")
        out = "/proc/thsa-test-out/run"
    else:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        out = str(ro / "run")
    assert main(SIM + ["--out", out]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: output folder") and err.count("\n") == 1


_SLOW_WRITER = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from thsa_control.report.build import atomic_folder
    with atomic_folder(sys.argv[1]) as tmp:
        for i in range(200):
            (tmp / f"part{i}.txt").write_text("new")
            time.sleep(0.01)
""")


def _env():
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}


def _wait_for(predicate, proc, timeout):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout and proc.poll() is None:
        if predicate():
            return True
        time.sleep(0.0005)
    return False


def test_sigterm_while_writing_keeps_old_folder(tmp_path):
    d = tmp_path / "out"
    with atomic_folder(d) as tmp:
        (tmp / "old.txt").write_text("old")
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_WRITER, str(d)], env=_env())
    assert _wait_for(lambda: any(p.name.startswith(".out.thsa-tmp-") for p in tmp_path.iterdir()), proc, 60)
    time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(30) == 128 + signal.SIGTERM
    assert sorted(p.name for p in d.iterdir()) == [MARKER, "old.txt"]
    assert _hidden(tmp_path) == []


@pytest.mark.slow
def test_sigterm_during_report_write_leaves_old_or_new_complete(tmp_path):
    """`thsa report`: SIGTERM as soon as its build folder appears; old or new complete folder, nothing else."""
    d = tmp_path / "rep"
    with atomic_folder(d) as tmp:
        (tmp / "old_report.html").write_text("old")
    proc = subprocess.Popen([sys.executable, "-m", "thsa_control.cli", "report", "--no-switching", "--quiet",
                             "--out", str(d)], env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    seen = _wait_for(lambda: any(p.name.startswith(".rep.thsa-tmp-") for p in tmp_path.iterdir()), proc, 600)
    if seen:
        proc.send_signal(signal.SIGTERM)
    code = proc.wait(120)
    names = sorted(p.name for p in d.iterdir())
    old = [MARKER, "old_report.html"]
    new = [MARKER, "analysis.json", "figures", "report.html"]
    assert names in (old, new), names
    if names == new:
        assert (d / "report.html").stat().st_size > 10_000 and len(list((d / "figures").iterdir())) >= 6
    assert code in (0, 128 + signal.SIGTERM)
    assert seen or code == 0
    assert _hidden(tmp_path) == []


def test_atomic_folder_api_refuses_foreign(tmp_path):
    d = tmp_path / "x"
    d.mkdir()
    (d / "y").write_text("y")
    with pytest.raises(OutputError, match="not written by thsa"):
        with atomic_folder(d):
            pass
    assert (d / "y").read_text() == "y"


def test_trace_refuses_before_fitting(own_run, tmp_path, capsys, monkeypatch):
    """`thsa trace` (minutes of fitting) refuses a foreign folder or one holding its input at once."""
    import thsa_control.trace.engine as engine

    def no_fit(*a, **k):
        raise AssertionError("trace ran before the output folder was checked")

    monkeypatch.setattr(engine, "trace", no_fit)
    run = own_run / "cold_ramp_A.csv"
    d = tmp_path / "results"
    d.mkdir()
    (d / "thesis.tex").write_text("two years of work")
    assert main(["trace", str(run), "--model", "A", "--quiet", "--out", str(d)]) == 2
    assert "not written by thsa" in capsys.readouterr().err
    assert main(["trace", str(run), "--model", "A", "--quiet", "--out", str(own_run), "--force"]) == 2
    assert "holds the input file" in capsys.readouterr().err
    assert (d / "thesis.tex").read_text() == "two years of work" and run.is_file()


def test_atomic_write_file_keeps_the_old_file_on_failure(tmp_path):
    """A writer that fails leaves the target as it was and no temporary file beside it."""
    from thsa_control.data.atomic import atomic_write_file

    target = tmp_path / "table.csv"
    atomic_write_file(target, lambda fh: fh.write("old\n"), text=True)

    def broken(fh):
        fh.write("half")
        raise RuntimeError("writer failed")

    with pytest.raises(RuntimeError, match="writer failed"):
        atomic_write_file(target, broken, text=True)
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.csv"]
    atomic_write_file(target, lambda fh: fh.write(b"\x00new"))
    assert target.read_bytes() == b"\x00new"
