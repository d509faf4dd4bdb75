# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Tracing a residual to the missing effect
#
# The loop the workbench's users asked for: fit the declared model, look at what is left, try every
# effect of the library the model lacks, keep the one that explains the residual on data the fit did
# not see (and more than it explains on a null run of the same scenario), repeat.
#
# 1. a **plain screw drive** (level A without its ideal no-back, no load) whose truth holds a Coulomb
#    friction and a constant axial force offset that the declared model does not;
# 2. the same tracer on the **shared example run** of `../shared/rig-data/examples/`, written by an
#    independent simulator of the rig, whose description names the effect it holds.
#
# Candidates are restricted here to keep the notebook short; `thsa trace` tries every library effect.
# In a notebook the fits run in the kernel itself (`workers=1`): a forked kernel does not survive.

# %%
import tempfile
from pathlib import Path

import thsa_control as thsa
from thsa_control.data.rigdata import read_run
from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs
from thsa_control.loops.design import derive_gains
from thsa_control.report.trace import format_trace_summary, plot_residual_before_after
from thsa_control.trace import TraceSettings, trace

params = thsa.default_parameters()
truth = params.replace({"drive.coulomb_torque": 0.1, "drive.axial_force_offset": 600.0})
rig = derive_gains(params, current_bandwidth_hz=150, velocity_crossover_hz=10, velocity_pi_zero_ratio=5,
                   position_bandwidth_hz=1, control_period_s=1e-3, name="rig_1kHz")
tmp = Path(tempfile.mkdtemp())
VirtualRig(None, effects=("coulomb_friction", "force_offset"), params=truth, design=rig,
           noise={"motor_speed_rpm": 2.0, "nut_position_mm": 0.005, "motor_current_A": 0.02}, seed=1).record(
    excitation_inputs(2.5, bipolar=True, load=0.0, control_period=1e-3), tmp / "plain")
run = read_run(tmp / "plain.csv")

# %%
result = trace(run, "A", remove=["noback_ideal"], params=params,
               settings=TraceSettings(candidates=("coulomb_friction", "force_offset", "cogging_torque"), max_nfev=30,
                                      workers=1),
               progress=print)
print(format_trace_summary(result.to_dict()))

# %%
fig = plot_residual_before_after(result.fits["before"], result.fits["after"], run.name)
fig

# %% [markdown]
# The truth was 0.1 N m of Coulomb friction and 600 N of offset; the table above gives the identified
# values with their 95 % intervals, and the error before and after each step.
#
# ## The shared example run
#
# Its description names `noback_quadrant_friction`.  Level A (with its ideal no-back) is the declared
# model; we let the tracer choose between the no-back's disks and two generic drive effects.

# %%
import os

shared = Path(os.environ.get("THSA_SHARED_DIR", Path("..").resolve().parent / "shared"))
example = shared / "rig-data" / "examples" / "excitation_tensile_12kN.csv"
if not example.exists():  # the copy shipped with the tests
    example = Path("..").resolve() / "tests" / "data" / "rig-data" / "examples" / "excitation_tensile_12kN.csv"
if example.exists():
    ex = read_run(example)
    res_ex = trace(ex, "A", params=params, settings=TraceSettings(
        candidates=("noback_quadrant_friction", "coulomb_friction", "force_offset"), max_effects=1, max_nfev=30,
        workers=1),
        progress=print)
    print(format_trace_summary(res_ex.to_dict()))
else:
    print(f"shared example not found at {example}")
