"""``circcal report [--out reports/] [--quick]``: the published comparison report (paper's Table 7 on rendered
fixtures, per-view errors, the centre-bias study, projection-difference maps, parameters, real photographs)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal report`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "report",
        help="write the comparison report (markdown + self-contained HTML + figures + report.json)",
        description="Run circcal and the reference calibrators on the paper's rendered fixtures (four illumination "
        "conditions, plus a rendered checkerboard), a centre-bias study on clean renders and the real "
        "photographs in ../shared/data/realdata ($CIRCCAL_REALDATA overrides; a set not found is "
        "marked missing), and write OUT/latest/ (index.md, index.html, PNG figures, report.json, "
        "timings.json) atomically, plus the index OUT/README.md. Takes ~10-15 minutes on 2 cores; "
        "--quick runs a reduced set in well under a minute (not the published numbers).",
    )
    p.add_argument("--out", type=Path, default=Path("reports"), help="reports folder (default: reports/)")
    p.add_argument(
        "--quick", action="store_true", help="reduced run: one condition, 8 views, a 3x2 bias grid, one real set"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Build the published comparison report into ``--out``.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: 0.

    Raises
    ------
    InputError
        A bad argument or input file (the CLI prints it and exits 2).
    """
    from circcal.report import generate

    folder = generate(args.out, quick=args.quick, progress=not args.no_progress)
    print(f"report: {folder / 'index.md'} ({folder / 'index.html'})")
    return 0
