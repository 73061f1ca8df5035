"""``circcal convert IN OUT``: convert a camera model between circcal, OpenCV, mrcal, COLMAP and ROS files."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``circcal convert`` subcommand, its arguments and its ``func`` (:func:`run`) to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The command line's subparsers.
    """
    from circcal.formats import FORMATS

    p = sub.add_parser(
        "convert",
        help="convert a camera model file to another format",
        description="Convert a camera model. Formats by extension (and, for input, content): .json (circcal "
        "model.json / truth.json), .yaml/.yml/.xml (OpenCV FileStorage; ROS camera_info when the name "
        "contains 'camera_info'), .cameramodel (mrcal), .txt (COLMAP cameras.txt; cx, cy shift by "
        "+0.5 px into COLMAP's pixel convention).",
    )
    p.add_argument("input", type=Path, help="camera file to read")
    p.add_argument("output", type=Path, help="camera file to write")
    p.add_argument("--from", dest="from_fmt", choices=FORMATS, help="input format (default: detected)")
    p.add_argument("--to", dest="to_fmt", choices=FORMATS, help="output format (default: from the extension)")
    p.add_argument(
        "--colmap-model",
        default="auto",
        choices=("auto", "OPENCV", "FULL_OPENCV"),
        help="COLMAP camera model (auto: OPENCV when k3 = 0, else FULL_OPENCV)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Convert the input camera file to the output's format.

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
    ModelFileError
        The input cannot be read.
    InputError
        The output's format cannot hold the camera, or a bad output path.
    """
    from circcal.formats import detect_format, read_model
    from circcal.outputs import Outputs

    with Outputs(inputs=[args.input]) as outputs:
        staged = outputs.file(args.output, "output")
        to_fmt = args.to_fmt or detect_format(args.output)
        camera, document = read_model(args.input, args.from_fmt)
        fmt, note = _write(staged, camera, document, to_fmt, args.colmap_model)
        outputs.commit()
    print(
        f"{args.input} -> {args.output} ({fmt}{note}): {camera.width}x{camera.height} fx={camera.fx:.6g} "
        f"fy={camera.fy:.6g} cx={camera.cx:.6g} cy={camera.cy:.6g} dist={[round(float(v), 8) for v in camera.dist]}"
    )
    return 0


def _write(path, camera, document, to_fmt: str, colmap_model: str) -> tuple[str, str]:
    """Write ``camera`` to ``path`` in ``to_fmt``; (the format written, a note on what it holds)."""
    from circcal.formats import write_camera

    note = ""
    if to_fmt == "mrcal":  # with mrcal's optimisation inputs, built from the model.json's views' observations
        from circcal import atomic
        from circcal.formats.cameramodel_export import cameramodel_text, document_views

        text, info = cameramodel_text(camera, document_views(document))
        atomic.write_text(path, text)
        note = (
            " with mrcal's optimisation inputs"
            if info["optimization_inputs"]
            else f" without optimisation inputs ({info['why']})"
        )
        return "mrcal", note
    # json -> json keeps the whole model.json (std, errors, poses); its camera block is the checked camera's
    return write_camera(
        path, camera, to_fmt, document=document if to_fmt == "json" else None, colmap_model=colmap_model
    ), note
