"""``circcal demo``: the main job on the built-in default fixtures (what ``make demo`` runs).

Renders the default scenario (cached), prints what it holds and how large the centre bias is that a blob-centroid
detector would carry, then runs ``circcal validate`` on it against every reference that is installed (calibration
against ground truth and against each reference on identical observations); a reference that is not installed is
listed as such, with the pip line that installs it, and does not fail the demo.

With ``--require-all`` (``make demo`` gives it: ``make setup`` installs every reference) a reference that is not
installed fails the demo, as under ``circcal validate --against all``.
"""

from __future__ import annotations

import argparse

import numpy as np

from circcal.commands.args import plain


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal demo`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    p = sub.add_parser(
        "demo",
        help="render the default fixtures and run the main job on them",
        description=plain(" ".join((__doc__ or "").split("\n\n")[:2]))
        + " --require-all fails it instead, as `make demo` does (`make setup` installs them all).",
    )
    p.add_argument("--scenario", default=None, help="scenario (default: the built-in default, `paper`)")
    p.add_argument(
        "--require-all",
        action="store_true",
        help="fail when a built-in reference calibrator is not installed (`make demo` gives it; without it one "
        "not installed is listed with its pip line)",
    )
    p.set_defaults(func=run)


def summarize(name: str) -> None:
    """Print the scenario's camera, board and per-variant geometry: dot sizes, tilts, blob-centroid bias.

    Parameters
    ----------
    name : str
        The scenario.
    """
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.render import area_centroids
    from circcal.fixtures.scenarios import get_scenario
    from circcal.fixtures.truth import load_truth
    from circcal.model import project
    from circcal.rotation import rodrigues

    sc = get_scenario(name)
    cam, board = sc.camera, sc.board
    print(f"scenario {sc.name} v{sc.version}: {sc.description}")
    print(
        f"  camera {cam.width}x{cam.height}  fx={cam.fx:.1f} fy={cam.fy:.1f} cx={cam.cx:.1f} cy={cam.cy:.1f}  "
        f"dist(k1,k2,p1,p2,k3)={np.array2string(cam.dist, precision=4)}"
    )
    print(f"  board {board.rows}x{board.cols} {board.layout}, pitch {board.pitch_mm} mm, dots {board.diameter_mm} mm")
    for variant in sc.variants:
        d = fixture_dir(sc.name, variant, progress=True)
        truth = load_truth(d)
        print(f"  {variant:8s} {len(truth.views)} views in {d}")
    truth = load_truth(fixture_dir(sc.name, next(iter(sc.variants))))
    if board.layout == "checkerboard":
        return
    tilts, sizes, bias = [], [], []
    for v in truth.views:
        R = rodrigues(v.rvec)
        tilts.append(np.degrees(np.arccos(abs(R[2, 2]))))
        rim = board.object_points()[:1] + np.array([[board.radius_mm, 0, 0], [-board.radius_mm, 0, 0]])
        sizes.append(np.linalg.norm(np.diff(project(rim, v.rvec, v.tvec, cam), axis=0)))
        bias.append(np.linalg.norm(area_centroids(cam, board, v.rvec, v.tvec, n=4000) - v.centres, axis=1))
    b = np.concatenate(bias)
    print(
        f"  tilts {min(tilts):.0f}-{max(tilts):.0f} deg to the optical axis; dots {min(sizes):.0f}-"
        f"{max(sizes):.0f} px across"
    )
    print(
        f"  bias of a perfect blob centroid (exact area centroid vs true centre projection): "
        f"RMS {np.sqrt(np.mean(b**2)):.4f} px, max {b.max():.4f} px  <- what circcal removes"
    )


def run(args: argparse.Namespace) -> int:
    """Summarise the scenario, then run ``circcal validate SCENARIO --against all`` on it.

    Parameters
    ----------
    args : argparse.Namespace
        The arguments :func:`add_parser`'s parser parsed.

    Returns
    -------
    int
        The exit status: ``circcal validate``'s (with ``--allow-missing`` unless every reference is required).

    Raises
    ------
    InputError
        A bad argument or input file (the CLI prints it and exits 2).
    """
    from circcal.commands import validate
    from circcal.fixtures.scenarios import DEFAULT_SCENARIO

    name = args.scenario or DEFAULT_SCENARIO
    argv = ["validate", name, "--against", "all", *([] if args.require_all else ["--allow-missing"])]
    summarize(name)
    print("\ncirccal " + " ".join(argv))
    parser = argparse.ArgumentParser(prog="circcal")
    validate.add_parser(parser.add_subparsers())
    return validate.run(parser.parse_args(argv))
