"""One source of truth for a run's kinematics: the run's ``rig`` block against the parameter set.

The screw lead and the gear ratio appear in two places: the run's JSON
(``rig.screw_lead_mm``, ``rig.gear_ratio``, optional) and the parameter set
(``screw.lead``, ``gear.ratio``).  The model needs the parameter set's (the
rotor inertia, the friction torques and every other motor-side value are
referred through them), so :func:`run_kinematics` decides once, before any
replay, identification or trace:

* the run states a value and it agrees with the parameter set (within
  :data:`KINEMATICS_RTOL`): fine;
* the run states a value and it differs: :class:`~thsa_control.errors.RigDataError`
  naming the JSON key, both values and the parameter.  The workbench does not
  override the parameter set for one run: the other parameters of the file
  were written for its kinematics, so a mismatch means a wrong parameter file
  (or a wrong JSON) and replaying either would be silently wrong.  Give the
  rig's kinematics in a parameter file (``--params rig.toml``);
* the run states nothing: the parameter set's values are the run's (the
  reader's FORMAT.md seed values, 12 mm and 65.61, are replaced).

Imports the standard library and the data/model records only.
"""

from __future__ import annotations

import dataclasses
import math

from ..data.rigdata import RigRun
from ..errors import RigDataError
from ..model.params import ParameterSet

__all__ = ["KINEMATICS_RTOL", "run_kinematics"]

#: Relative difference up to which the run's and the parameter set's kinematics agree (JSON rounding).
KINEMATICS_RTOL = 1e-4

# JSON key -> (RigRun attribute, parameter, JSON unit per SI unit)
_KEYS = {"screw_lead_mm": ("screw_lead", "screw.lead", 1e3), "gear_ratio": ("gear_ratio", "gear.ratio", 1.0)}


def run_kinematics(run: RigRun, params: ParameterSet) -> RigRun:
    """``run`` with the parameter set's kinematics, or an error when the run states others.

    Parameters
    ----------
    run : RigRun
    params : ParameterSet

    Returns
    -------
    RigRun
        ``run`` itself when nothing changes, else a copy whose ``screw_lead`` /
        ``gear_ratio`` are the parameter set's.

    Raises
    ------
    RigDataError
        The run's JSON states a lead or ratio that differs from the parameter
        set's by more than :data:`KINEMATICS_RTOL` (every mismatch listed,
        both values named).

    Examples
    --------
    >>> from thsa_control.model.params import default_parameters
    >>> p = default_parameters().replace({"gear.ratio": 2.0})
    >>> run = RigRun("r", None, None, {}, None, {})   # states no kinematics
    >>> run_kinematics(run, p).gear_ratio
    2.0
    """
    problems, updates = [], {}
    where = run.json_path.name if run.json_path is not None else "<run>"
    for key, (attr, name, factor) in _KEYS.items():
        value = params.value(name)
        if key in run.kinematics_stated:
            stated = getattr(run, attr)
            if not math.isclose(stated, value, rel_tol=KINEMATICS_RTOL):
                problems.append((f"{where}:rig.{key}", None,
                                 f"the run states {stated * factor:g} but the parameter set's {name} is "
                                 f"{value * factor:g}{' mm' if factor != 1 else ''} ({params[name].source}); "
                                 "the kinematics must agree: give the rig's in a parameter file (--params), "
                                 "or correct the run's JSON"))
        elif getattr(run, attr) != value:
            updates[attr] = value
    if problems:
        raise RigDataError(str(run.json_path), problems)
    return dataclasses.replace(run, **updates) if updates else run
