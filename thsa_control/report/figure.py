"""Figures made with matplotlib's object API: no backend chosen, no pyplot state.

Every plotting function of :mod:`thsa_control.report` builds its figure here.
A :class:`ReportFigure` is a plain :class:`matplotlib.figure.Figure` that is
not registered with pyplot, so

* a command-line run needs no GUI backend and leaves the user's backend alone
  (``plt.show()`` in a user's script keeps working after importing the
  package);
* a Jupyter notebook or IPython shows it as a PNG when it is the value of a
  cell (``_repr_png_``), whatever backend the kernel uses;
* figures are freed with the object: nothing accumulates in pyplot's figure
  manager over a long report run.

To show one in a script's window, draw it onto a pyplot figure:
``plt.figure(); ...`` or save it with ``fig.savefig("name.png")``.
"""

from __future__ import annotations

import io
import os

import matplotlib
from matplotlib.figure import Figure

__all__ = ["ReportFigure", "new_figure", "subplots", "colormap", "png_bytes", "render_pngs"]


class ReportFigure(Figure):
    """A figure outside pyplot that IPython/Jupyter display as a PNG."""

    def _repr_png_(self) -> bytes:
        return png_bytes(self, dpi=90)


def new_figure(figsize=(8.0, 6.0), *, constrained_layout: bool = True, **kwargs) -> ReportFigure:
    """An empty :class:`ReportFigure` (``layout="constrained"`` by default)."""
    return ReportFigure(figsize=figsize, layout="constrained" if constrained_layout else None, **kwargs)


def subplots(nrows: int = 1, ncols: int = 1, *, figsize=(8.0, 6.0), constrained_layout: bool = True,
             **kwargs):
    """``(fig, axes)`` like :func:`matplotlib.pyplot.subplots`, on a :class:`ReportFigure`."""
    fig = new_figure(figsize, constrained_layout=constrained_layout)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def colormap(name: str):
    """A registered colormap by name (no pyplot)."""
    return matplotlib.colormaps[name]


def png_bytes(fig: Figure, *, dpi: int = 100) -> bytes:
    """The figure as PNG bytes (Agg canvas, whatever the session's backend)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


#: The figure jobs of the current :func:`render_pngs` call, read by the forked processes (nothing is pickled).
_JOBS: list = []


def _build_png(fn, args, dpi: int) -> bytes:
    fig = fn(*args)
    data = png_bytes(fig, dpi=dpi)
    fig.clear()
    return data


def _render(job: tuple[int, int]) -> bytes:
    i, dpi = job
    return _build_png(*_JOBS[i], dpi)


def _default_processes() -> int:
    """``$THSA_FIGURE_PROCESSES`` if set (1: draw in-process), else the cores this process may use."""
    env = os.environ.get("THSA_FIGURE_PROCESSES", "").strip()
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            raise ValueError(f"THSA_FIGURE_PROCESSES = {env!r} must be a whole number >= 1") from None
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def render_pngs(jobs, *, dpi: int = 100, processes: int | None = None, done=None) -> list[bytes]:
    """PNG bytes of the figures that ``jobs`` build, in order; each job is ``(function, args)`` returning a figure.

    Building and drawing a report's figures is most of the time of writing it, and each figure is
    independent: they are drawn in up to ``processes`` forked processes (default: ``$THSA_FIGURE_PROCESSES``,
    else the cores this process may use), each figure once.  The PNGs are the same bytes as drawn in-process.  Without ``fork`` (Windows),
    with one core or one figure, they are drawn here, one after the other.  ``done(i)`` (optional) is called
    in this process as figure ``i`` is ready, in order (progress lines).
    """
    import multiprocessing as mp

    jobs = list(jobs)
    if processes is None:
        processes = _default_processes()
    processes = min(processes, len(jobs))
    out: list[bytes] = []
    if processes <= 1 or "fork" not in mp.get_all_start_methods():
        for fn, args in jobs:
            out.append(_build_png(fn, args, dpi))
            if done is not None:
                done(len(out) - 1)
        return out
    _JOBS[:] = jobs
    try:
        with mp.get_context("fork").Pool(processes) as pool:
            for png in pool.imap(_render, [(i, dpi) for i in range(len(jobs))], chunksize=1):
                out.append(png)
                if done is not None:
                    done(len(out) - 1)
    finally:
        _JOBS.clear()
    return out
