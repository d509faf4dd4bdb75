"""Trace a residual to the effect the model lacks (numerics only; the report is thsa_control.report.trace).

The names are imported lazily, so that ``thsa --help`` (which registers ``thsa trace`` from
:mod:`thsa_control.cli.trace`) loads no numerics.
"""

__all__ = ["trace", "TraceSettings", "TraceResult", "CANDIDATES", "DEFAULT_UNCERTAIN", "TRACE_FORMAT",
           "candidate_specs"]


def __getattr__(name):
    if name in __all__:
        from . import engine

        return getattr(engine, name)
    raise AttributeError(f"module 'thsa_control.trace' has no attribute {name!r}")
