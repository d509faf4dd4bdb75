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
# # Identification on virtual-rig data
#
# The loop with measured data, on data whose truth we know:
#
# 1. the **virtual rig** writes a run in the rig format (`shared/rig-data/FORMAT.md`) from the level-B
#    model with sensor noise;
# 2. the **replay** drives a declared model with the run's inputs and the rig's controller (closed loop),
#    or drives its mechanics with the measured current (open loop);
# 3. the **identifier** fits chosen parameters by multiple shooting through the plant's own discrete map,
#    with standard errors, correlations and flags;
# 4. the **residual analysis** tells whether what is left is noise.

# %%
import tempfile
from pathlib import Path


import thsa_control as thsa
from thsa_control.fit.identify import IdentificationSettings, Identifier
from thsa_control.fit.replay import analyse_replay, replay
from thsa_control.report.identification import plot_overlay, plot_segments
from thsa_control.fit.residuals import format_residual_report
from thsa_control.data.rigdata import read_run
from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs

truth = thsa.default_parameters().replace({"noback.mu_coulomb_neg": 0.0050, "screw.efficiency_direct": 0.87})
work = Path(tempfile.mkdtemp())

# %% [markdown]
# ## 1. A virtual run with known truth
#
# A bipolar excitation: +3 mm/s then -3 mm/s plateaus with a multi-sine and a PRBS on top, under a constant
# 12 kN compressive load (it opposes the extension, then aids the retraction).  The rig's cascade here runs
# at 1 kHz, the rate the run is recorded at, so the replay sees the current the plant saw.

# %%
design = thsa.derive_gains(truth, current_bandwidth_hz=150, velocity_crossover_hz=10, velocity_pi_zero_ratio=5,
                           position_bandwidth_hz=1, control_period_s=1e-3, name="rig_1kHz")
rig = VirtualRig("B", params=truth, design=design, noise={"motor_speed_rpm": 2.0, "nut_position_mm": 0.005},
                 sample_rate_hz=1000.0, seed=1)
csv_path, _ = rig.record(excitation_inputs(6.0, bipolar=True, load=12e3, control_period=1e-3), work / "excitation")
run = read_run(csv_path)
print(run.metadata["description"])
print("truth:", {n: run.metadata["truth"]["parameters"][n] for n in ("noback.mu_coulomb_neg", "screw.efficiency_direct")})

# %% [markdown]
# ## 2. Replay with the default parameters
#
# The closed-loop replay uses the controller from the run's JSON.  The default actuator is not the truth, so
# the current needed in the aiding phase is off.

# %%
start = thsa.default_parameters()
before = replay(run, "B", params=start)
for c, f in before.fits.items():
    print(f"{c:14s} fit {f.fit_percent:7.2f} %  RMS {f.rms:.4g} {f.unit}")

# %% [markdown]
# ## 3. Identify
#
# Three parameters of level B.  Which ones the run can tell is physics: the 12 kN load exceeds twice the
# 3 kN no-back preload, so the light (tensile-side) disk set is unloaded and the (+)
# disk coefficient acts nowhere in this run; under a constant load the aided current is
# mu |F| / N - |F| r eta_i, so the (-) disk coefficient and the inverse efficiency are
# collinear.  The result reports each value with its standard error, flags pairs correlated above 0.95,
# and saves as a parameter TOML the models load.

# %%
free = ["motor.rotor_inertia", "screw.efficiency_direct", "noback.mu_coulomb_neg"]
result = Identifier("B", start, free, settings=IdentificationSettings(channels=("motor_speed", "nut_position"))).fit(run)
print(result.fit_report())

# %%
for n, e in result.estimates.items():
    lo, hi = e.interval(0.95)
    print(f"{n:26s} truth {truth.value(n):.5g}  95 % interval [{lo:.5g}, {hi:.5g}]  "
          f"{'holds' if lo <= truth.value(n) <= hi else 'MISSES'} the truth")

# %%
fig = plot_segments(result.predictions[run.name], title="multiple-shooting segments: initial and identified")
fig

# %% [markdown]
# ## 4. Replay and residuals with the identified parameters

# %%
path = result.save_parameters(work / "identified.toml")
identified = thsa.load_parameters(path, base=thsa.default_parameters())
after = replay(run, "B", params=identified)
for c in after.fits:
    print(f"{c:14s} fit {before.fits[c].fit_percent:7.2f} -> {after.fits[c].fit_percent:7.2f} %")
fig = plot_overlay(after.time, after.measured, {"default": before.simulated, "identified": after.simulated},
                   channels=["motor_current", "motor_speed"], title="closed-loop replay")
fig

# %%
analysis = analyse_replay(run, after)
print(format_residual_report(analysis, channels=["motor_speed"])[:2500])

# %% [markdown]
# ## 5. What the data cannot separate
#
# The motor bearings' and the gearbox's viscous friction act on the same speed: the data see only their sum.
# The identifier says so instead of returning two confident numbers.

# %%
pair = Identifier("B", start, ["motor.bearing_viscous_friction", "gear.viscous_friction"],
                  settings=IdentificationSettings(channels=("motor_speed", "nut_position"))).fit(run)
print(pair.high_correlations, pair.not_identifiable)
