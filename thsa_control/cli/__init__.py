"""Command line of thsa-control: a thin argparse front end over the API.

Commands::

    thsa scenarios
    thsa levels    [--scenario NAME] [--levels A,B,C,D] [--effects E ...] [--design FILE]
                   [--params FILE] [--temperature T] --out DIR
    thsa simulate  --scenario NAME --level C [--effects E ...] [--design FILE] [--params FILE]
                   [--temperature T] [--output-period S] --out DIR
    thsa check-data RUN.csv
    thsa identify  RUN.csv [RUN2.csv ...] --model B --free PARAM,... [--effects E ...] [--params FILE] --out DIR
    thsa trace     RUN.csv [RUN2.csv ...] --model A [--effects E ...] [--params FILE ...] --out DIR
    thsa residual  RUN.csv --model A [--mode closed_loop|open_loop] [--segment S|whole] [--effects E ...]
                   [--remove E ...] [--params FILE] --out DIR
    thsa report    --design designs/nominal.toml --out DIR [--level B] [--effects E ...] [--params FILE]
                   [--no-switching] [--check]
    thsa sweep     SPEC.toml --out DIR [--scheduler ADDRESS | --scheduler-file FILE | --workers N] [--force] [--check]
    thsa linearize --level A --speed 5 --load 20 --temperature -30 [--effects E ...] [--active standby]
                   [--params FILE] [--save FILE.npz|FILE.mat]

Exit status: 0 success; 1 a requirement failed (``report --check``); 2 an
error of the input (unknown scenario, level or effect, bad design, parameter
or run file, bad option value, output folder that may not be replaced): one
line naming the culprit, nothing written; 3 an internal error (a bug: one
line, the traceback with ``THSA_DEBUG=1``); 128+N killed by signal N.

``--out`` replaces only a folder that thsa wrote itself (it carries a
``.thsa-output`` marker) or an empty one; ``--force`` replaces another folder
but never one that holds an input file.  Long commands print progress on
stderr (``--quiet`` silences it).  This module imports only the standard
library at import time, so that ``thsa --help`` is instant.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import ThsaError
from .common import EXIT_INTERNAL, EXIT_OK, EXIT_REQUIREMENT_FAILED, EXIT_USAGE

__all__ = ["main", "build_parser", "EXIT_OK", "EXIT_REQUIREMENT_FAILED", "EXIT_USAGE", "EXIT_INTERNAL"]


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__
    from . import analysis, data, faults, sim, sweep, trace, tuning

    shared = argparse.ArgumentParser(add_help=False)
    shared.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                        help="no progress lines on stderr")
    ap = argparse.ArgumentParser(prog="thsa", description="THSA control workbench", parents=[shared],
                                 epilog="Rig runs (RUN.csv + RUN.json): the format is docs/rig_format.md in the "
                                        "repository. Units: SI in the API and JSON; mm, mm/s, kN, rpm, ms on the "
                                        "command line and in reports (README, 'Units').")
    ap.add_argument("--version", action="version", version=f"thsa-control {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    # one module per command group, each registering its subcommands (the order is the help's)
    sim.add_parsers(sub, shared)
    data.add_parsers(sub, shared)
    analysis.add_parsers(sub, shared)
    faults.add_parser(sub)
    trace.add_parser(sub)
    tuning.add_parsers(sub)
    sweep.add_parser(sub, shared)
    return ap


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``thsa`` console script; returns the exit status.

    0 success, 1 requirement failed (``report --check``), 2 input or
    environment error (one line on stderr: bad input, disk full, permissions),
    3 internal error (one line; ``THSA_DEBUG=1`` shows the traceback).
    """
    import os

    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    try:
        return args.fn(args)
    except ThsaError as exc:
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # the environment, not a bug: disk full, permissions, a vanished file
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"error: {exc.strerror or exc}{where}", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError:
        print("error: out of memory (a grid, run or period too large for this machine)", file=sys.stderr)
        return EXIT_USAGE
    except Exception as exc:  # a bug: never a traceback for the user, but say how to get it
        if os.environ.get("THSA_DEBUG"):
            raise
        print(f"internal error ({type(exc).__name__}): {_one_line(exc)}; this is a bug in thsa-control, "
              "rerun with THSA_DEBUG=1 for the traceback and report it", file=sys.stderr)
        return EXIT_INTERNAL


def _one_line(exc: BaseException) -> str:
    return str(exc).strip() or type(exc).__name__
