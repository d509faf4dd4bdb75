"""Fitting to measured data: replay, identification, component identification, residual analysis,
and the virtual rig that writes runs from any effect set."""
