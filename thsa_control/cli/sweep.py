"""``thsa sweep SPEC.toml --out DIR [--scheduler ADDRESS | --scheduler-file FILE | --workers N]``: campaigns on Dask (issue #19).

Registered in ``thsa_control/cli/__init__.py`` with ``add_parser(subparsers, shared)``;
the handler calls :func:`thsa_control.sweep.command.sweep_command`, which runs
or resumes the sweep, writes the table and the report and prints the failure
probabilities.  Exit status 0; 1 with ``--check`` when a run misses a limit
of the spec; 2 for a bad spec, an output folder of another sweep or an
unreachable scheduler; 128+N when stopped by signal N (rerun to resume).
"""

from __future__ import annotations

__all__ = ["add_parser", "run"]


def add_parser(subparsers, shared) -> None:
    """Add the ``sweep`` subcommand."""
    p = subparsers.add_parser("sweep", parents=[shared],
                              help="campaigns (Monte Carlo, grids, fault timings) on the local cores or a Dask "
                                   "cluster: Parquet table, HTML + JSON report")
    p.add_argument("spec", help="sweep description (TOML; see examples/sweeps/)")
    p.add_argument("--out", required=True, help="results folder: new or empty, or the folder of the same sweep "
                   "(then it resumes where it stopped)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://host:8786 "
                       "(default: a local cluster on this machine's cores)")
    where.add_argument("--scheduler-file", metavar="FILE",
                       help="the file a Dask scheduler writes its address to ('dask scheduler --scheduler-file "
                            "FILE', the way batch systems start one on a shared file system); waited on for "
                            "seconds while it is missing or partly written")
    where.add_argument("--workers", type=int, help="worker processes of the local cluster (default: one per core)")
    p.add_argument("--force", action="store_true",
                   help="discard the results of another sweep in --out (only files thsa wrote)")
    p.add_argument("--check", action="store_true", help="exit with status 1 when a run misses a limit of the spec")
    p.set_defaults(fn=run)


def run(args) -> int:
    """Handler of ``thsa sweep``; returns the exit status."""
    from ..sweep.command import sweep_command

    return sweep_command(args.spec, args.out, scheduler=args.scheduler, scheduler_file=args.scheduler_file,
                         workers=args.workers, force=args.force,
                         check=args.check, quiet=getattr(args, "quiet", False),
                         command=" ".join(["thsa", *getattr(args, "argv", [])]))
