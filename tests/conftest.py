"""Shared fixtures: the default actuator, the nominal design, memoised runs, figure clean-up."""

from __future__ import annotations

import os

if os.environ.get("PYTEST_XDIST_WORKER"):
    # One BLAS thread per pytest-xdist worker: the workers already fill every core (``-n auto``), and OpenBLAS's
    # own threads (one per core by default, spinning while they wait) would oversubscribe the machine, more so
    # with the tracer's fit processes.  Before numpy is imported; a value the user set is kept.
    # Likewise the report's figures are drawn in this process, not in forked ones (report.figure.render_pngs;
    # tests/test_report_pages.py draws with two processes explicitly).
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "THSA_FIGURE_PROCESSES"):
        os.environ.setdefault(_var, "1")

from pathlib import Path

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")

from thsa_control.loops.design import load_design  # noqa: E402
from thsa_control.model import build_plant  # noqa: E402
from thsa_control.model.params import default_parameters  # noqa: E402
from thsa_control.sim.scenarios import get_scenario  # noqa: E402
from thsa_control.sim.simulate import SimulationSettings, Simulator  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def params():
    return default_parameters()


@pytest.fixture(scope="session")
def rig_1khz(params):
    """The virtual rig's 1 kHz cascade of the measured-data tests (identification, residual, trace)."""
    from thsa_control.loops.design import derive_gains

    return derive_gains(params, current_bandwidth_hz=150, velocity_crossover_hz=10, velocity_pi_zero_ratio=5,
                        position_bandwidth_hz=1, control_period_s=1e-3, name="rig_1kHz")


@pytest.fixture(scope="session")
def design():
    return load_design(ROOT / "designs" / "nominal.toml")


@pytest.fixture(scope="session")
def run(params, design):
    """``run(scenario, level, effects=(), substeps=1, output_period=1e-3, params=None)``, memoised per session."""
    cache = {}

    def _run(scenario, level, effects=(), substeps=1, output_period=1e-3, params_override=None, compiled=True,
             remove=()):
        p = params_override or params
        key = (scenario, level, tuple(effects), substeps, output_period, id(params_override), compiled, tuple(remove))
        if key not in cache:
            sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
            eff = tuple(effects) + tuple(e for e in sc.required_effects if e not in effects)
            sim = Simulator(build_plant(level, eff, remove=remove, params=p),
                            SimulationSettings(substeps=substeps, output_period=output_period, compiled=compiled))
            cache[key] = sim.run(sc, design, p)
        return cache[key]

    return _run


def pytest_collection_modifyitems(config, items):
    """The tests marked slow first, each part in collection order (modules stay together).

    With ``--dist worksteal`` (pyproject's addopts) each pytest-xdist worker starts on its half of this list
    and an idle worker takes the tail of the other's: the long tests start early and the short ones fill the
    end, instead of one long test running alone at the end while the other core idles.  Order only: which
    tests run, and what they check, is unchanged.
    """
    items[:] = sorted(items, key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    import matplotlib.pyplot as plt

    plt.close("all")


@pytest.fixture
def rng(request):
    return np.random.default_rng(abs(hash(request.node.name)) % (2**32))

def _rusage_cpu():
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Opt-in per-test processor time: ``THSA_TEST_CPU=FILE python -m pytest ...``.

    Appends ``nodeid<TAB>cpu_s<TAB>wall_s<TAB>worker<TAB>end`` per test to ``FILE`` (one line per test, written
    with one ``write`` so the xdist workers' lines do not interleave; ``end``: the wall clock [s since the epoch]
    when the test ended, to see how long a worker idled at the end).  The processor time is this process's user + system
    time plus that of the children it waited for (fit processes, CLI subprocesses, notebook kernels) over the
    test's setup, call and teardown; a session fixture's cost lands on the first test that uses it.
    ``python bench/suite_cpu.py FILE`` prints the table.
    """
    out = os.environ.get("THSA_TEST_CPU")
    if not out:
        yield
        return
    import time

    c0, w0 = _rusage_cpu(), time.perf_counter()
    yield
    cpu, wall = _rusage_cpu() - c0, time.perf_counter() - w0
    line = f"{item.nodeid}\t{cpu:.3f}\t{wall:.3f}\t{os.environ.get('PYTEST_XDIST_WORKER', 'main')}\t{time.time():.3f}\n"
    with open(out, "a") as f:
        f.write(line)


#: The scripts beside the committed test data (they regenerate it from rig-sim) are not test modules.
collect_ignore = ["data"]
