"""Several parameter files merged in order; an identified parameters.toml replays alone (issue #11)."""

import pytest

from thsa_control.errors import ParameterError
from thsa_control.model.params import default_parameters, load_parameters


def test_files_merge_in_order(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text('[gear]\nratio = 10.0\n[screw]\nlead = 0.005\n[drive]\ncoulomb_torque = 0.1\n')
    ident = tmp_path / "identified.toml"
    ident.write_text('[drive]\ncoulomb_torque = { value = 0.12, source = "identified: test" }\n')
    p = load_parameters([rig, ident], base=default_parameters())
    assert p.value("gear.ratio") == 10.0 and p.value("screw.lead") == 0.005
    assert p.value("drive.coulomb_torque") == 0.12 and p["drive.coulomb_torque"].source == "identified: test"
    assert p.value("motor.resistance") == default_parameters().value("motor.resistance")
    with pytest.raises(ParameterError, match="no parameter file"):
        load_parameters([], base=default_parameters())


def test_a_saved_full_set_reloads_unchanged(tmp_path):
    p = default_parameters().replace({"drive.axial_force_offset": 250.0})
    path = p.save(tmp_path / "full.toml")
    back = load_parameters(path, base=default_parameters())
    assert all(back.value(n) == p.value(n) for n in p.names)
