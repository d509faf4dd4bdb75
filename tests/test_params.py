"""Parameter set: the papers' values, sources, bounds, TOML round trip."""

import math

import pytest

from thsa_control.errors import ParameterError
from thsa_control.model.params import Parameter, ParameterSet, load_parameters


def test_papers_values_and_torque_constant(params):
    # issue #2 quotes the papers: Kt = 1.5 * 3 * 0.072 = 0.324 N m/A
    kt = 1.5 * params.value("motor.pole_pairs") * params.value("motor.flux_linkage")
    assert kt == pytest.approx(0.324, rel=1e-12)
    assert params.value("gear.ratio") == 65.61
    assert params.value("screw.lead") == 0.012
    # 17.62 rpm and 8.57 deg converted to SI in the file
    assert params.value("noback.stribeck_speed_pos") == pytest.approx(17.62 * 2 * math.pi / 60, rel=1e-6)
    assert params.value("noback.pawl_pitch") == pytest.approx(math.radians(8.57), rel=1e-5)


def test_every_parameter_has_a_source_and_assumed_ones_a_reason(params):
    for p in params.values():
        assert p.source.strip(), p.name
        if p.source.lower().startswith("assumed"):
            reason = p.source.split(":", 1)[1].strip()
            assert len(reason) > 20, f"{p.name}: assumed value needs a real reason"
        assert p.min <= p.value <= p.max


def test_out_of_bounds_names_the_parameter(params):
    with pytest.raises(ParameterError, match="motor.resistance.*outside its bounds"):
        params.replace({"motor.resistance": -1.0})
    with pytest.raises(ParameterError, match="unknown"):
        params.replace({"motor.no_such_thing": 1.0})


def test_toml_round_trip_and_overrides(params, tmp_path):
    path = params.save(tmp_path / "p.toml")
    again = load_parameters(path)
    assert again == params
    over = tmp_path / "over.toml"
    over.write_text("[motor]\nresistance = 1.5\n")
    p2 = load_parameters(over, base=params)
    assert p2.value("motor.resistance") == 1.5 and p2["motor.resistance"].source == params["motor.resistance"].source
    bad = tmp_path / "bad.toml"
    bad.write_text("[motor]\nresistnce = 1.5\n")
    with pytest.raises(ParameterError, match="motor.resistnce.*bad.toml"):
        load_parameters(bad, base=params)
    worse = tmp_path / "worse.toml"
    worse.write_text("[motor]\nresistance = -2\n")
    with pytest.raises(ParameterError, match="motor.resistance"):
        load_parameters(worse, base=params)


def test_parameter_validation():
    with pytest.raises(ParameterError, match="reason"):
        Parameter("x", 1.0, "m", "assumed")
    with pytest.raises(ParameterError, match="not finite"):
        Parameter("x", float("nan"), "m", "papers")
    with pytest.raises(ParameterError, match="defined twice"):
        ParameterSet((Parameter("x", 1.0, "m", "papers"), Parameter("x", 2.0, "m", "papers")))
