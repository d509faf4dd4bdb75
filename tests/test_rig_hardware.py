"""The declared model completed from the runs' own rig description (a second rotor carried along)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from thsa_control.data.rigdata import read_run
from thsa_control.fit.replay import check_run_model, rig_declared_effects
from thsa_control.model import build_plant, resolve_effects
from thsa_control.trace import TraceSettings

DATA = Path(__file__).resolve().parent / "data"


def _run(name: str):
    return read_run(DATA / "rigsim" / f"{name}.csv")


def test_two_motor_rig_declares_the_standby_rotor():
    run = _run("rig_coulomb")  # rig-sim: rig.motors = 2, the standby channel never enabled
    assert run.metadata["rig"]["motors"] == 2
    assert not np.any(np.asarray(run.signals["standby_enable"]) > 0.5)
    got = rig_declared_effects([run])
    assert list(got) == ["standby_motor"] and "rig.motors = 2" in got["standby_motor"]
    # the same warning the replay gives without it, none with it
    assert check_run_model(run, build_plant(None, resolve_effects("A")), mode="open_loop")
    assert not check_run_model(run, build_plant(None, resolve_effects("A", add=["standby_motor"])), mode="open_loop")


def test_one_motor_rig_or_runs_that_disagree_declare_nothing():
    one = read_run(DATA / "rig-data" / "examples" / "excitation_tensile_12kN.csv")
    assert one.metadata["rig"]["motors"] == 1
    assert rig_declared_effects([one]) == {}
    two = _run("rig_coulomb")
    assert rig_declared_effects([two, one]) == {}  # disagreeing runs: the declared model stays, replay warns per run
    # a one-motor description whose standby channel is enabled still carries the second rotor
    sig = dict(one.signals)
    sig["standby_enable"] = np.ones_like(np.asarray(sig["standby_enable"], dtype=float))
    assert list(rig_declared_effects([dataclasses.replace(one, signals=sig)])) == ["standby_motor"]


def test_trace_settings_carry_the_switch():
    assert TraceSettings().rig_hardware is True
    assert TraceSettings(rig_hardware=False).rig_hardware is False


@pytest.mark.parametrize("flag, expected", [([], True), (["--no-rig-hardware"], False)])
def test_cli_switch(flag, expected):
    from thsa_control.cli import build_parser

    args = build_parser().parse_args(["trace", "x.csv", "--model", "A", "--out", "o", *flag])
    assert args.no_rig_hardware is (not expected)
