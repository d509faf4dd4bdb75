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
# # The linear workflow: operating points, loop margins over temperature, requirements
#
# The cascade of the rig (10 kHz current PI, velocity PI, position P loop) is
# designed on linear models taken around operating points: trim speed, air
# load (aiding or opposing) and temperature.  This notebook walks through the
# steps that `thsa report` runs for a whole grid:
#
# 1. wrap the plant for linearisation and linearise at one point (AD, with a
#    finite-difference cross-check), and see what a zero-speed point gives;
# 2. analyse the three discrete loops over a grid and name the worst points;
# 3. check the design's requirements;
# 4. look at the friction (Stribeck) and at describing-function limit cycles;
# 5. compare the primary-active and standby-active configurations.

# %%
import numpy as np

import thsa_control as thsa
from thsa_control.loops.linear import format_linear_model
from thsa_control.report.analysis_report import plot_loop_bode, plot_margin_maps, plot_steps

params = thsa.default_parameters()
design = thsa.load_design(thsa.nominal_design_path())
print(design.description)
print("requirements:", design.requirements)

# %% [markdown]
# ## 1. One operating point
#
# The plant of level B (no-back friction disks) with the temperature law.  The
# nut position drifts in a steady motion: it is excluded from the linear model
# (the position loop gets it back as an integrator of the nut speed).

# %%
model = thsa.plant_model("B", ["temperature_friction"], params)
print(model.describe())
point = thsa.linearize_conditions(model, [thsa.OperatingCondition(5e-3, 20e3, -30.0)])
print(format_linear_model(point))

# %% [markdown]
# At level A with linear friction the current-to-speed transfer function is
# `Kt / (J s + b)`, with `J` the inertia of rotor, screw, load-path and surface
# masses at the motor shaft:

# %%
lin_a = thsa.linearize_conditions(thsa.plant_model("A", (), params), [thsa.OperatingCondition(5e-3, 20e3, 25.0)])
tf = thsa.current_driven(lin_a[0]).transfer_function("motor_current", "motor_speed", minimal=True)
kt = 1.5 * params.value("motor.pole_pairs") * params.value("motor.flux_linkage")
print(tf)
print(f"Kt / J = {kt / lin_a.inertia[0]:.6g} 1/(A s^2), b / J = {lin_a.net_damping[0] / lin_a.inertia[0]:.6g} 1/s")

# %% [markdown]
# A point at zero speed sits on the friction discontinuity: it is reported
# invalid with the reason, not silently linearised.

# %%
stop = thsa.linearize_conditions(model, [thsa.OperatingCondition(0.0, 20e3, -30.0)])
print(stop.valid[0])
for reason in stop.reasons[0]:
    print("-", reason[:160])

# %% [markdown]
# ## 2. The loops over a grid
#
# One `linearize_batch` call for the whole grid, then batched ZOH, frequency
# responses and margins of the current, velocity and position loops.

# %%
settings = thsa.AnalysisSettings(nut_speeds=(0.0, 1e-3, 2e-3, 5e-3, 15e-3), load_forces=(-55e3, 0.0, 55e3),
                                 temperatures=(-55.0, -30.0, 25.0, 70.0))
analysis = thsa.analyse_loops(design, params, settings=settings)
print(f"{len(analysis)} points, {int(analysis.valid.sum())} valid")
for w in analysis.worst_points():
    if w.metric in ("phase_margin_deg", "gain_margin_db", "ms", "overshoot_percent"):
        print(w.text())

# %%
fig = plot_loop_bode(analysis, "velocity_loop")
fig

# %%
fig = plot_margin_maps(analysis)
fig

# %%
fig = plot_steps(analysis)
fig

# %% [markdown]
# Points without a small-signal loop are listed with their reason: zero speed,
# and the slowest motions against 55 kN of aiding load when cold, whose steady
# state needs more than the 15 A current limit (the no-back's loaded disk brakes
# them, and the cold drag rises at low speed).

# %%
for cond, reasons in analysis.invalid_points():
    if cond.nut_speed != 0:
        print(cond.label(), "->", reasons[0][:90])

# %% [markdown]
# ## 3. Requirements

# %%
check = thsa.check_requirements(analysis)
print(check.summary())
for row in check.rows:
    if row.loop == "velocity_loop":
        print(f"{row.requirement:24s} limit {row.limit:8.4g}  worst {row.worst_value:8.4g}  "
              f"at {row.worst_condition.label()}")

# %% [markdown]
# ## 4. Friction: Stribeck region and describing functions
#
# At low speed the no-back disks and the cold drag fall with speed (Stribeck):
# a negative friction slope removes damping, and under an aiding load it makes
# the mechanical mode unstable (the velocity loop is then conditionally
# stable: a negative, lower gain margin).

# %%
lin = analysis.linearization
for k in np.flatnonzero(analysis.valid & lin.stribeck)[:6]:
    print(f"{analysis.conditions[k].label():38s} friction slope {lin.friction_slope[k] * 1e3:7.3f} mN m s/rad, "
          f"net damping {lin.net_damping[k] * 1e3:7.3f}, velocity GM "
          f"{analysis.metric('velocity_loop', 'gain_margin_db')[k]:6.1f} dB")

# %%
for cycle in thsa.describing_functions(design, params, settings=settings, temperatures=(-55.0,), loads=(55e3,)):
    print(cycle.loop, cycle.nonlinearity, cycle.condition.label(), "->", cycle.note)

# %% [markdown]
# ## 5. Active/standby configurations
#
# Both plants carry the two rotors; the design, derived for one rotor, sees
# about twice the inertia, so the velocity crossover drops.

# %%
conf = thsa.analyse_configurations(design, params, settings=settings, temperatures=(25.0,), loads=(20e3,))
for name, a in (("primary active", conf.primary), ("standby active", conf.standby)):
    m = a.loops["velocity_loop"].margins
    print(f"{name}: velocity crossover {m.crossover_hz[0]:.1f} Hz, PM {m.phase_margin_deg[0]:.1f} deg, "
          f"bandwidth {m.bandwidth_hz[0]:.1f} Hz")
