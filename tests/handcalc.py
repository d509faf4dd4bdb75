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
    loaded one preload + |F|, light one max(preload - |F|, 0)).  The gearbox
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
        normal = max(P("noback.preload") + load_N, 0) if w < 0 else max(P("noback.preload") - load_N, 0)
        mu = P(f"noback.mu_coulomb_{sfx}") + (P(f"noback.mu_static_{sfx}") - P(f"noback.mu_coulomb_{sfx}")) * math.exp(
            -((ws / P(f"noback.stribeck_speed_{sfx}")) ** 2))
        screw += math.copysign(mu * normal / N, w)
    eta_g = P("gear.efficiency")
    motor = screw / eta_g if screw * w > 0 else screw * eta_g
    return (motor + P("motor.bearing_viscous_friction") * w) / kt
