"""``circcal`` command line: one subcommand per module in :mod:`circcal.commands`.

Each module there exposes ``add_parser(subparsers)``, which registers its subcommand and sets ``func`` (taking the
parsed ``argparse.Namespace`` and returning an exit code). Modules import their heavy dependencies lazily so
``circcal --help`` stays fast.
"""
from __future__ import annotations

import argparse
import importlib
import sys

# Order shown in --help. A module that is not there yet is skipped.
COMMANDS = ("demo", "render", "detect", "calibrate", "convert", "validate", "report")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="circcal",
        description="Circle-grid camera calibration with unbiased centres, and cross-validation against "
                    "reference calibrators. Reprojection errors name their convention: per point (2-D, "
                    "OpenCV's RMS), per coordinate (mrcal's RMS) or mean 2-D (the paper's).")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"circcal.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"circcal.commands.{name}":
                continue
            raise
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError) as exc:  # user-facing input errors: one clear line, no traceback
        print(f"circcal {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
