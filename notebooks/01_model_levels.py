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
# # Model levels A–D on the papers' back-drive test
#
# A model level is a named set of physical effects over one functional
# structure.  This notebook builds the four levels, runs the papers'
# `backdrive_bipolar_ramp` scenario at each, and shows them side by side.
#
# * **A** functional: PMSM, rigid gearbox and ball screw with efficiencies, viscous drag.
# * **B** + the no-back's load- and quadrant-dependent friction disks.
# * **C** + the ratchet/pawl clearance.
# * **D** + the load-path backlash and preload compliance (surface as its own body).

# %%
import numpy as np

import thsa_control as thsa
from thsa_control.sim.metrics import backdrive_metrics
from thsa_control.report.plots import plot_levels

params = thsa.default_parameters()
design = thsa.load_design(thsa.nominal_design_path())
scenario = thsa.get_scenario("backdrive_bipolar_ramp")
print(scenario.description)

# %% [markdown]
# Each level is a plant built from the effect library; its states tell what
# the effects add.

# %%
plants = {level: thsa.build_plant(level) for level in "ABCD"}
for level, plant in plants.items():
    print(level, plant.effects, plant.state_names)

# %% [markdown]
# Closed-loop runs with the 10 kHz cascade of `designs/nominal.toml`.

# %%
results = {level: thsa.Simulator(plant).run(scenario, design, params) for level, plant in plants.items()}
for level, res in results.items():
    print(f"level {level}: 10 s simulated in {1e3 * res.info['wall_s']:.1f} ms")

# %%
fig = plot_levels(results)
fig

# %% [markdown]
# What the levels show:
#
# * **A** is the functional model with the papers' ideal no-back (paper 001,
#   model (a)): in the trim stops (grey, motors off) it holds the load; in the
#   aiding phase the motor drives with little current (the no-back takes the
#   load torque).  `thsa.build_plant("A", remove=["noback_ideal"])` is the
#   reversible screw, which back-drives in the stops.
# * **B** holds the load by stiction in the stops; in the aiding phase the motor
#   must drive against the loaded disk (current with the speed), with a breakaway
#   peak when it starts.
# * **C** adds the pawl clearance: at the first trim stop the screw is
#   back-driven until the pawl engages (papers: about 40 % of the command).
# * **D** adds the load-path compliance: the surface bounces while the load is
#   applied through the backlash.

# %%
for level in "ABCD":
    m = backdrive_metrics(results[level])
    print(f"{level}: aiding/opposing |I| = {m.aiding_to_opposing:.2f}, breakaway/opposing = {m.breakaway_to_opposing:.2f}, "
          f"back-drive at first stop = {100 * m.stop_backdrive_peak[1] / m.command_amplitude:.0f} % of command")

# %% [markdown]
# Removing an effect gives the level below exactly:

# %%
d_minus = thsa.build_plant("D", remove=["loadpath_compliance"])
print(d_minus.effects == plants["C"].effects)
same = thsa.Simulator(d_minus).run(scenario, design, params)
print(float(np.max(np.abs(same["motor_current"] - results["C"]["motor_current"]))))

# %% [markdown]
# Two headline numbers are set by values the papers do not give: the level-D
# overshoot by the disk-spring damping, the level-C back-drive by where the
# ratchets stopped before the run.  Over their plausible ranges:

# %%
from thsa_control.sim.assumptions import assumption_ranges, format_ranges

print(format_ranges(assumption_ranges(design, params)))

# %% [markdown]
# The drive train is rigid unless `drivetrain_compliance` is added: the motor
# rotors then sit on the gearbox and screw torsional spring (assumed stiffness,
# see the parameter file), and the motor sensor and the screw disagree by the
# twist rate.

# %%
soft = thsa.Simulator(thsa.build_plant("B", ["drivetrain_compliance"])).run(scenario, design, params)
gap = soft["motor_speed"] - params.value("gear.ratio") * soft["screw_speed"]
print(f"peak twist {1e3 * np.max(np.abs(soft['drivetrain_twist'])):.2f} mrad at the motor shaft, "
      f"peak motor-sensor minus screw speed {np.max(np.abs(gap)):.2f} rad/s")
