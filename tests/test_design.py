"""Design files: the nominal gains follow from its stated bandwidths; bad files are named."""

import pytest

from thsa_control.loops.design import derive_gains, load_design
from thsa_control.errors import DesignError


def test_nominal_gains_follow_from_bandwidths(design, params):
    d = design.derivation
    derived = derive_gains(params, current_bandwidth_hz=d["current_bandwidth_hz"],
                           velocity_crossover_hz=d["velocity_crossover_hz"],
                           velocity_pi_zero_ratio=d["velocity_pi_zero_ratio"],
                           position_bandwidth_hz=d["position_bandwidth_hz"], rotors=d["rotors"])
    # the file rounds to 5 significant digits
    for name in ("current_kp", "current_ki", "velocity_kp", "velocity_ki", "position_kp"):
        assert getattr(design, name) == pytest.approx(getattr(derived, name), rel=2e-4), name


def test_current_pi_cancels_the_stator_pole(design, params):
    # zero of kp + ki/s at ki/kp = R/L
    assert design.current_ki / design.current_kp == pytest.approx(
        params.value("motor.resistance") / params.value("motor.inductance"), rel=1e-3)


@pytest.mark.parametrize("text, match", [
    ("control_period_s = 1e-4\n[current_loop]\nkp_V_per_A = 1\n", "missing current_loop.ki_V_per_A_s"),
    ("control_period_s = 1e-4\n[current_loop]\nkp_V_per_A = 1\nki_V_per_A_s = 1\n[velocity_loop]\nkp_A_per_rad_s = -0.1\n"
     "ki_A_per_rad = 1\ncurrent_limit_A = 15\n[position_loop]\nkp_per_s = 1\n", "kp_A_per_rad_s = -0.1 must be positive"),
    ("control_period_s = 1e-4\n[current_loop]\nkp_V_per_A = 1\nki_V_per_A_s = 1\nkd = 3\n", r"unknown key\(s\) \['kd'\]"),
    ("control_period_s = 1e-4\n[curent_loop]\n", "unknown key"),
    ("this is = not toml [", "not valid TOML"),
])
def test_bad_design_files_are_named(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(DesignError, match=match) as exc:
        load_design(path)
    assert "bad.toml" in str(exc.value)


def test_design_asking_more_current_than_the_motor_has(design, params):
    from dataclasses import replace

    with pytest.raises(DesignError, match="current_limit_A = 20 exceeds motor.max_current = 15"):
        replace(design, current_limit=20.0).check_against(params)
