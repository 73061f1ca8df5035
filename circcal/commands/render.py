"""``circcal render SCENARIO --out DIR``: write a scenario's images and truth.json."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from circcal.errors import InputError


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal render`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "render",
        help="render a fixture scenario (images + truth.json)",
        description="Render a named fixture scenario: images and truth.json with the exact camera, "
        "poses and centre projections. `--list` shows the catalogue.",
    )
    p.add_argument("scenario", nargs="?", help="scenario name (see --list)")
    p.add_argument(
        "--variant",
        action="append",
        help="variant to render (repeatable; default: all variants, each in OUT/<variant>/)",
    )
    p.add_argument("--out", type=Path, help="output folder")
    p.add_argument("--list", action="store_true", help="list scenarios and their variants")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Render the scenario's images and truth.json into ``--out``; or list the scenarios.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: 0; 2 when no scenario was named (the list is printed).

    Raises
    ------
    InputError
        A bad argument or input file (the CLI prints it and exits 2).
    """
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.scenarios import SCENARIOS, get_scenario

    if args.list or not args.scenario:
        for s in SCENARIOS.values():
            print(
                f"{s.name:20s} v{s.version}  {s.camera.width}x{s.camera.height} fx={s.camera.fx:g}  "
                f"{s.board.rows}x{s.board.cols} {s.board.layout}, {s.n_views} views"
            )
            print(f"{'':22s}variants: {', '.join(s.variants)}")
            print(f"{'':22s}{s.description}")
        return 0 if args.list else 2
    if args.out is None:
        raise InputError("--out DIR is required")
    from circcal.outputs import Outputs

    sc = get_scenario(args.scenario)
    variants = args.variant or list(sc.variants)
    lines = []
    with Outputs() as outputs:  # a new folder, or one circcal rendered before: committed whole at the end
        staged = outputs.folder(args.out, "--out", kind="fixtures")
        for v in variants:
            src = fixture_dir(sc.name, v, progress=True)  # cached by content hash
            sub = Path(v) if (len(variants) > 1 or not args.variant) else Path()
            (staged / sub).mkdir(parents=True, exist_ok=True)
            for f in src.iterdir():
                shutil.copy2(f, staged / sub / f.name)
            n = sum(1 for f in (staged / sub).iterdir() if f.name != "truth.json")
            lines.append(f"{sc.name}/{v}: {n} images + truth.json -> {args.out / sub}")
        outputs.commit()
    print("\n".join(lines))
    return 0
