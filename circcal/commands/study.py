"""``circcal study SPEC --out DIR``: a Monte-Carlo study or conformance matrix on Dask (an embedded cluster, or any
cluster given its scheduler); resumable, one Parquet row per run, summary tables and figures in DIR."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from circcal import atomic
from circcal.commands.args import positive_int
from circcal.errors import EXIT_FAILED, EXIT_OK


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal study`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "study",
        help="run a study (scenarios x variants x seeds x calibrators x lens models) on Dask",
        description="Run every missing run of a study spec (YAML, see circcal.study.spec) and write one Parquet row "
        "per run under OUT/rows, then OUT/summary.md, summary.json and figures. Runs already stored are "
        "skipped, so an interrupted study finishes by running the same command again. Exit status 1 "
        "when some tasks failed (their runs are missing: rerun), 2 on bad input.",
    )
    p.add_argument("spec", type=Path, help="study spec, e.g. studies/paper-2000.yaml")
    p.add_argument("--out", type=Path, required=True, help="results folder (created; reused to resume)")
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="a running Dask scheduler, e.g. tcp://host:8786 (default: an embedded LocalCluster)",
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        help="embedded: worker processes (default one per core, one thread each); with --scheduler: "
        "workers to wait for before starting",
    )
    p.add_argument(
        "--flush-rows",
        type=positive_int,
        default=None,
        metavar="N",
        help="rows per Parquet part written as runs finish (default 500, or every 10 s); a killed client "
        "loses only rows not yet written, and a rerun computes them again",
    )
    p.add_argument("--summary-only", action="store_true", help="write the summary of the rows stored, run nothing")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run (or resume) the study of the spec and write its summary into ``--out``.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: :data:`~circcal.errors.EXIT_OK`; :data:`~circcal.errors.EXIT_FAILED` when tasks failed (their runs are
        missing: the same command finishes them).

    Raises
    ------
    InputError
        A bad argument or input file (the CLI prints it and exits 2).
    """
    from circcal.study import load_spec, run_study, write_summary

    spec = load_spec(args.spec)
    _check_study_folder(args.out)
    if args.summary_only:
        if not (args.out / "study.yaml").exists():
            args.out.mkdir(parents=True, exist_ok=True)
            atomic.write_text(args.out / "study.yaml", spec.source)
        print(f"summary: {write_summary(args.out)}")
        return EXIT_OK
    print(f"study {spec.name}: {spec.n_runs} runs in {len(spec.cells)} cells -> {args.out}")
    res = run_study(
        spec,
        args.out,
        scheduler=args.scheduler,
        workers=args.workers,
        progress=not args.no_progress,
        **({} if args.flush_rows is None else {"flush_rows": args.flush_rows}),
    )
    if res.n_done_before < res.n_runs:
        rate = res.n_computed / res.wall_s if res.wall_s > 0 else float("nan")
        print(
            f"computed {res.n_computed} runs in {res.wall_s:.1f} s on {res.workers} workers ({rate:.3g} runs/s; "
            f"cluster start {res.startup_s:.1f} s); {res.n_done_before} were done before"
        )
    else:
        print(f"nothing to run: all {res.n_runs} runs were done before")
    for line in res.errors:
        print(f"task failed: {line}")
    if res.complete:
        from circcal.study.store import RowStore

        RowStore(args.out).compact()
    print(f"summary: {write_summary(args.out)}")
    if res.errors:
        print(f"{len(res.errors)} tasks failed: their runs are missing; run the same command again to finish them")
        return EXIT_FAILED
    return EXIT_OK


def _check_study_folder(folder: Path) -> None:
    """A study's folder grows as runs finish (resumable), so it is not staged: it must be new, empty, or an
    earlier study's (its study.yaml); anything else is refused before any work, naming the folder."""
    from circcal.errors import InputError
    from circcal.outputs import check_writable_place

    if folder.exists():
        if not folder.is_dir():
            raise InputError(f"--out {folder}: not a folder")
        entries = os.listdir(folder)
        if entries and "study.yaml" not in entries:
            raise InputError(
                f"--out {folder}: it holds files of no circcal study ({', '.join(sorted(entries)[:3])}"
                f"{', ...' if len(entries) > 3 else ''}); give a new or empty folder"
            )
    check_writable_place(folder / "study.yaml", "--out")
