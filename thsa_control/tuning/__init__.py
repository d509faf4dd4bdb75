"""Gain tuning against nonlinear validation runs (casadi/IPOPT) and the validation check of designs.

validation.py (runs and metrics), objective.py (closed-loop cost with casadi
gradients), robust.py (margin constraints over temperature), optimize.py
(IPOPT multi-start), check.py (the validation check; the commands are in ``thsa_control/cli/tuning.py``).
"""
