"""Compiled-simulator cache (issue #7, item 2): verified before dlopen, rebuilt on mismatch, never poisoned.

Each case runs a short level-A (or C) simulation in a fresh subprocess, as a
user's next command would, against a private cache folder, and compares with
a clean run.  Before this fix: the truncated library killed the process with
SIGBUS, a foreign one gave another level's numbers for a level-A run with exit 0,
the empty file from a broken compiler poisoned every later run, and an
unwritable cache failed the run after a successful compile.
"""

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(shutil.which(os.environ.get("CC", "gcc")) is None and shutil.which("cc") is None,
                                reason="needs a C compiler")

_PROBE = textwrap.dedent("""
    import sys, json
    from thsa_control import (build_plant, default_parameters, load_design, nominal_design_path, get_scenario,
                              Simulator, SimulationSettings)
    p = default_parameters()
    plant = build_plant(sys.argv[1], [], params=p)
    res = Simulator(plant, SimulationSettings()).run(get_scenario("cold_ramp"), load_design(nominal_design_path()), p)
    c = res.info["compile"]
    print(json.dumps({"compiled": c["compiled"], "cached": c["cached"], "cache": c.get("cache", ""),
                      "path": c.get("path", ""), "x": float(res["nut_position"][-1]),
                      "i": float(abs(res["motor_current"]).max())}))
""")


def run_probe(level, cache, **env):
    e = {**os.environ, "THSA_CACHE_DIR": str(cache),
         "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]), **env}
    proc = subprocess.run([sys.executable, "-c", _PROBE, level], capture_output=True, text=True, env=e, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1]), proc.stderr


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Clean compiled runs of levels A and C (the foreign model), and their cache files."""
    cache = tmp_path_factory.mktemp("ref_cache")
    a, _ = run_probe("A", cache)
    libs_a = set(cache.glob("*.so"))
    c, _ = run_probe("C", cache)
    lib_c, = set(cache.glob("*.so")) - libs_a
    assert a["compiled"] and c["compiled"] and not a["cached"]
    assert abs(a["x"] - c["x"]) > 1e-4  # the two models differ visibly: a swap would show
    return {"A": a, "C": c, "lib_A": libs_a.pop(), "lib_C": lib_c}


def _same(r, ref):
    return abs(r["x"] - ref["x"]) < 1e-9 and abs(r["i"] - ref["i"]) < 1e-9


def _seed(cache, reference, level="A"):
    cache.mkdir(exist_ok=True)
    lib = reference[f"lib_{level}"]
    shutil.copy(lib, cache / lib.name)
    shutil.copy(lib.with_suffix(".json"), cache / lib.with_suffix(".json").name)
    return cache / lib.name


def test_cached_library_is_reused(tmp_path, reference):
    _seed(tmp_path / "c", reference)
    r, err = run_probe("A", tmp_path / "c")
    assert r["cached"] and _same(r, reference["A"]) and err == ""


def test_truncated_library_is_rebuilt(tmp_path, reference):
    lib = _seed(tmp_path / "c", reference)
    data = lib.read_bytes()
    lib.write_bytes(data[: len(data) // 3])
    r, _ = run_probe("A", tmp_path / "c")
    assert r["compiled"] and not r["cached"] and _same(r, reference["A"])
    assert lib.read_bytes() == data or lib.stat().st_size > len(data) // 2  # republished whole


@pytest.mark.parametrize("how", ["library_only", "library_and_manifest", "forged_manifest"])
def test_foreign_library_under_the_right_name_is_rejected(tmp_path, reference, how):
    cache = tmp_path / "c"
    lib = _seed(cache, reference, "A")
    foreign = reference["lib_C"]
    shutil.copy(foreign, lib)
    manifest = lib.with_suffix(".json")
    if how == "library_and_manifest":
        shutil.copy(foreign.with_suffix(".json"), manifest)
    elif how == "forged_manifest":  # the manifest claims level A's source but describes C's library
        meta = json.loads(manifest.read_text())
        meta.update(json.loads(foreign.with_suffix(".json").read_text()),
                    source_sha256=json.loads(manifest.read_text())["source_sha256"])
        manifest.write_text(json.dumps(meta))
    r, _ = run_probe("A", cache)
    assert not r["cached"] and _same(r, reference["A"])  # level-A numbers, not level C's


def test_compiler_writing_an_empty_file_does_not_poison_the_cache(tmp_path, reference):
    fake = tmp_path / "bin" / "fakecc"
    fake.parent.mkdir()
    fake.write_text('#!/bin/sh\nwhile [ $# -gt 0 ]; do if [ "$1" = "-o" ]; then : > "$2"; fi; shift; done\nexit 0\n')
    fake.chmod(0o755)
    cache = tmp_path / "c"
    r, err = run_probe("A", cache, CC=str(fake))
    assert not r["compiled"] and _same(r, reference["A"])  # interpreter, same numbers
    assert err.count("note:") == 1 and "interpreter" in err
    assert list(cache.glob("*.so")) == []  # nothing published
    r2, err2 = run_probe("A", cache)  # a real compiler afterwards: builds, not poisoned
    assert r2["compiled"] and not r2["cached"] and _same(r2, reference["A"]) and err2 == ""


def test_no_compiler_falls_back_to_interpreter_with_one_note(tmp_path, reference):
    empty = tmp_path / "nobin"
    empty.mkdir()
    r, err = run_probe("A", tmp_path / "c", CC=str(tmp_path / "nocc"), PATH=str(empty))
    assert not r["compiled"] and _same(r, reference["A"])
    assert err.count("note:") == 1 and "no C compiler" in err


def test_unwritable_cache_falls_back_to_temporary_folder(tmp_path, reference):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    r, err = run_probe("A", blocker / "cache")  # cannot be created
    assert r["compiled"] and r["cache"] == "private" and _same(r, reference["A"])
    assert err.count("note:") == 1 and "temporary folder" in err
    if os.geteuid() != 0:  # an existing read-only folder (root writes anyway)
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        r, err = run_probe("A", ro)
        assert r["compiled"] and r["cache"] == "private" and _same(r, reference["A"])
        assert "not writable" in err


def test_inline_min_max_return_libm_bits():
    """The generated code's inline fmin/fmax (``codegen._INLINE_MINMAX``) return libm's bits for every pair of
    special values (signed zeros, infinities, NaNs, subnormals), so the compiled simulator's results do not
    change with them."""
    import ctypes
    import ctypes.util
    import math
    import struct

    from thsa_control.sim.codegen import _INLINE_MINMAX

    assert [new for _, new in _INLINE_MINMAX] == ["  return x>y ? x : (y==y ? y : x);",
                                                  "  return x<y ? x : (y==y ? y : x);"]
    libm = ctypes.CDLL(ctypes.util.find_library("m"))
    for name in ("fmin", "fmax"):
        getattr(libm, name).restype = ctypes.c_double
        getattr(libm, name).argtypes = [ctypes.c_double, ctypes.c_double]
    values = [0.0, -0.0, 1.0, -1.0, math.inf, -math.inf, math.nan, -math.nan, 2.2250738585072014e-308, 5e-324,
              -5e-324, 1e300, 2.5]
    bits = lambda v: struct.pack("<d", v)  # noqa: E731
    for x in values:
        for y in values:
            assert bits(libm.fmax(x, y)) == bits(x if x > y else (y if y == y else x)), (x, y)
            assert bits(libm.fmin(x, y)) == bits(x if x < y else (y if y == y else x)), (x, y)


def test_two_processes_needing_the_same_library_build_it_once(tmp_path, reference):
    """On a fresh machine two processes (pytest-xdist workers, fit processes) that need the same library at the
    same time: one compiles, the other waits for it and loads the published file (verified like any cached
    one); both give the clean run's numbers.  The compiler here is a wrapper that logs each call and holds
    the build until the second process waits for it: where the kernel lists its file locks (``/proc/locks``,
    Linux), until a process is blocked on the build's lock file (logged, and asserted: the waiting path is
    the one taken), else for 4 s."""
    real = shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")
    log = tmp_path / "cc.log"
    slow = tmp_path / "bin" / "slowcc"
    slow.parent.mkdir()
    cache = tmp_path / "c"
    locks = Path("/proc/locks")
    watch = locks.is_file() and os.access(locks, os.R_OK) and shutil.which("stat") and shutil.which("find")
    hold = (  # a blocked flock reads "N: -> FLOCK ... MAJ:MIN:INODE ..." in /proc/locks; at most 30 s
        f'i=0\nwhile [ $i -lt 600 ]; do\n'
        f'  for f in $(find "{cache}" -name ".*.lock" 2>/dev/null); do\n'
        f'    if grep -q -- "-> FLOCK .*:$(stat -c %i "$f") " /proc/locks; then echo waiter >> "{log}"; '
        f'exec "{real}" "$@"; fi\n'
        f'  done\n  sleep 0.05; i=$((i+1))\ndone\n') if watch else "sleep 4\n"
    slow.write_text(f'#!/bin/sh\necho build >> "{log}"\n{hold}exec "{real}" "$@"\n')
    slow.chmod(0o755)
    e = {**os.environ, "THSA_CACHE_DIR": str(cache), "CC": str(slow),
         "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    procs = [subprocess.Popen([sys.executable, "-c", _PROBE, "A"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env=e) for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
    res = [json.loads(o[0].strip().splitlines()[-1]) for o in outs]
    assert log.read_text().count("build") == 1, log.read_text()
    if watch:
        assert "waiter" in log.read_text(), "the second process never waited for the build's lock"
    assert sorted(r["cached"] for r in res) == [False, True] and all(r["compiled"] for r in res)
    assert all(_same(r, reference["A"]) for r in res)
