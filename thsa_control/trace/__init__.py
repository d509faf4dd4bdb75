"""Trace a residual to the effect the model lacks (numerics only; the report is thsa_control.report.trace)."""

from .engine import CANDIDATES, DEFAULT_UNCERTAIN, TRACE_FORMAT, TraceResult, TraceSettings, candidate_specs, trace

__all__ = ["trace", "TraceSettings", "TraceResult", "CANDIDATES", "DEFAULT_UNCERTAIN", "TRACE_FORMAT",
           "candidate_specs"]
