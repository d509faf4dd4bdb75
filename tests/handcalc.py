"""Helpers shared by the tests: hand-written torque balances (independent of the model code),
the plant input vector by name, and the sensor noise of the virtual-rig runs of the measured-data tests."""

import math

import numpy as np

#: Sensor noise of the 1 kHz virtual-rig runs (the shared example's sensors; 0.02 A current).
RIG_NOISE = {"motor_speed_rpm": 2.0, "nut_position_mm": 0.005, "motor_current_A": 0.02, "screw_speed_rpm": 0.2}


def plant_inputs(plant, **kw):
    """The plant input vector, zero except the named inputs."""
    u = np.zeros(len(plant.inputs))
    for k, v in kw.items():
        u[plant.index("input", k)] = v
    return u


def hand_current(P, level, speed_mm_s, load_N):
    """Steady motor current from a hand-written torque balance (independent of the model code).

    Screw side, at the motor shaft: gear drag, the load through the screw
    efficiency of its power-flow direction, and the no-back (level A: the ideal
    Coulomb torque F r against load-aided motion; level B: the slipping disk,
    the flange balance: the loaded set takes its stiffness share s of the
    load change, the light one gives up 1 - s until it has lost its preload,
    then |F| and 0; equal sets, s = 0.5: preload +- |F|/2 up to 2 preload).  The gearbox
    divides what it passes by eta_g when the motor drives it and multiplies by
    eta_g when it is driven.  The motor bearing drag stays on the motor side.
    """
    N, lead = P("gear.ratio"), P("screw.lead")
    r = lead / (2 * math.pi * N)
    kt = 1.5 * P("motor.pole_pairs") * P("motor.flux_linkage")
    w = speed_mm_s * 1e-3 / r
    opposing = load_N * speed_mm_s > 0
    screw = P("gear.viscous_friction") * w + load_N * r * (
        1 / P("screw.efficiency_direct") if opposing else P("screw.efficiency_inverse"))
    if level == "A" and not opposing:
        screw += math.copysign(abs(load_N) * r, w)
    if level == "B":
        ws = w / N
        sfx = "pos" if w > 0 else "neg"
        # w < 0: the compressive-side disk slips; w > 0: the tensile-side one
        pre = P("noback.preload")
        # the flange between two preloaded disk sets: the loaded one takes its stiffness' share of the load change,
        # the light one gives up the rest, until it has lost its preload (equal sets: +-|F|/2 up to 2 preload)
        s = P("noback.load_share") if load_N > 0 else 1 - P("noback.load_share")  # the loaded set's share
        light = max(pre - (1 - s) * abs(load_N), 0.0)
        loaded = abs(load_N) + light
        compressive_side = loaded if load_N > 0 else light
        normal = compressive_side if w < 0 else (loaded if load_N < 0 else light)
        mu = P(f"noback.mu_coulomb_{sfx}") + (P(f"noback.mu_static_{sfx}") - P(f"noback.mu_coulomb_{sfx}")) * math.exp(
            -((ws / P(f"noback.stribeck_speed_{sfx}")) ** 2))
        screw += math.copysign(mu * normal / N, w)
    eta_g = P("gear.efficiency")
    motor = screw / eta_g if screw * w > 0 else screw * eta_g
    return (motor + P("motor.bearing_viscous_friction") * w) / kt


#: the no-back disk coefficients (both rotation directions)
DISK_COEFFICIENTS = ("noback.mu_static_pos", "noback.mu_coulomb_pos", "noback.mu_static_neg", "noback.mu_coulomb_neg")


def example_disk_law(params, load_N):
    """The shipped example's no-back in level B's parameters at its one constant load.

    The independent simulator that wrote ``excitation_tensile_12kN`` loads the slipping disk with preload + |F|
    (15 kN at its 12 kN: measured, this reproduces its segmented nut-position residual to 5e-6 relative, the load
    cell's noise the rest); level B's flange balance gives |F| beyond twice the preload.  At one load the two
    differ by the factor (preload + |F|) / |F| on the disk coefficients, the whole Stribeck curve scaled."""
    pre = params.value("noback.preload")
    assert abs(load_N) >= 2 * pre, "the factor holds where the light disk set is unloaded in both laws"
    return params.replace({k: params.value(k) * (pre + abs(load_N)) / abs(load_N) for k in DISK_COEFFICIENTS})
