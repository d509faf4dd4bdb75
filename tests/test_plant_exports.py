"""What the plant exports beyond f and step: measurement map, kinematic ratio, torque constant, inertias.

Each is checked against the plant's own balances (not against a copy of the
sum the structure builds): the inertia against the speed's response to the
motor current at rest, the measurement map against the outputs and the
states, the ratio and the torque constant against the papers' formulas.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from thsa_control.model import SENSORS, build_plant, kinematic_ratio, torque_constant

SETS = [("A", ()), ("B", ()), ("C", ()), ("D", ()), ("B", ("standby_motor",)), ("B", ("drivetrain_compliance",)),
        ("D", ("drivetrain_compliance", "standby_motor", "temperature_friction"))]


def _u(plant, params, **kw):
    u = np.zeros(len(plant.inputs))
    u[plant.index("input", "enable_primary")] = 1.0
    u[plant.index("input", "temperature")] = params.value("friction.reference_temperature")
    for k, v in kw.items():
        u[plant.index("input", k)] = v
    return u


@pytest.mark.parametrize("level, effects", SETS)
def test_ratio_and_torque_constant_are_the_papers(params, level, effects):
    plant = build_plant(level, effects, params=params)
    P = params.value
    assert plant.kinematic_ratio(params) == pytest.approx(P("screw.lead") / (2 * math.pi * P("gear.ratio")), rel=1e-15)
    assert plant.torque_constant(params) == pytest.approx(1.5 * P("motor.pole_pairs") * P("motor.flux_linkage"),
                                                          rel=1e-15)
    assert plant.kinematic_ratio(params) == kinematic_ratio(params)
    assert plant.torque_constant(params) == torque_constant(params)
    # the nut moves r times the motor speed in the plant's own rates (rigid load path)
    x = plant.initial_state(params)
    x[plant.index("state", "motor_speed")] = 100.0
    xdot = np.asarray(plant.f(x, _u(plant, params), plant.p_vector(params))[0]).ravel()
    assert xdot[plant.index("state", "nut_position")] == pytest.approx(100.0 * plant.kinematic_ratio(params))


@pytest.mark.parametrize("level, effects", SETS)
def test_inertia_is_what_the_current_accelerates(params, level, effects):
    """At rest, no load, the motor-sensor body's acceleration per amp is Kt / J_motor; with a compliant drive
    train the twist's torque accelerates the main body by 1 / J_main per N m."""
    plant = build_plant(level, effects, params=params)
    p = plant.p_vector(params)
    u = _u(plant, params)
    j_main, j_motor = plant.inertia(params)
    x = plant.initial_state(params)
    k_w = plant.index("state", plant.sensor_state("motor_speed"))
    base = float(plant.f(x, u, p)[0][k_w])
    x[plant.index("state", "motor_current")] = 1.0
    slope = float(plant.f(x, u, p)[0][k_w]) - base
    assert plant.torque_constant(params) / slope == pytest.approx(j_motor, rel=1e-12)
    rotor = params.value("motor.rotor_inertia") * (2 if "standby_motor" in effects else 1)
    if "drivetrain_compliance" in effects:
        assert j_motor == pytest.approx(rotor, rel=1e-15) and j_main < j_motor  # the gear side at the motor shaft
    else:
        assert j_main == j_motor > rotor


@pytest.mark.parametrize("level, effects", SETS)
def test_measurement_map_reads_the_outputs_and_the_states(params, level, effects, rng):
    plant = build_plant(level, effects, params=params)
    p = plant.p_vector(params)
    for _ in range(5):
        x = plant.initial_state(params, load_force=rng.normal(0, 1e4), nut_position=rng.normal(0, 0.02))
        for s in ("motor_speed", "rotor_speed"):
            if s in plant.state_names:
                x[plant.index("state", s)] = rng.normal(0, 200.0)
        x[plant.index("state", "motor_current")] = rng.normal(0, 3.0)
        u = _u(plant, params, voltage_primary=rng.normal(0, 30.0))
        y = np.asarray(plant.f(x, u, p)[1]).ravel()
        m = np.asarray(plant.measure(x, u, p)).ravel()
        for k, c in enumerate(SENSORS):
            sensor = plant.sensors[c]
            assert m[k] == y[plant.index("output", sensor.output)]
            scale = float(sensor.scale(p)) if sensor.scale is not None else 1.0
            assert m[k] == pytest.approx(scale * x[plant.index("state", sensor.state)], rel=1e-12, abs=1e-15)
    assert plant.sensor_state("motor_speed") == ("rotor_speed" if "drivetrain_compliance" in effects
                                                 else "motor_speed")
    assert plant.sensor_state("nut_position") == ("surface_position" if level == "D" else "nut_position")
