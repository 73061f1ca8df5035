"""The ahead-of-time build of the detector's kernels (``make setup`` runs ``python -m circcal.detector.kernels.build``):
every kernel module compiled with ``numba.pycc`` into ``circcal/detector/_aot/`` for the argument types detection
gives it (see :mod:`circcal.detector.kernels.jit`). A tool, not a runtime module: nothing the detector runs imports it.
"""

from __future__ import annotations

import json
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from circcal.board import Board
from circcal.detector.kernels import jit
from circcal.detector.kernels.jit import AOT_DIR, TARGET_CPU, _aot_name, _host_cpu, _jit_module, _registry, _spec_of

__all__ = ["build", "synthetic_board"]


def synthetic_board() -> tuple[np.ndarray, Board]:
    """The synthetic board image :func:`build` runs the detector on.

    A 5x6 symmetric board (dots 5 mm on a 10 mm pitch) in perspective, drawn at 8x and area-averaged.

    Returns
    -------
    image : numpy.ndarray
        (480, 640) uint8: dark dots (30) on a bright board (230).
    board : circcal.board.Board
        The board drawn.

    Examples
    --------
    >>> image, board = synthetic_board()
    >>> image.shape, image.dtype
    ((480, 640), dtype('uint8'))
    """
    import cv2

    board = Board(5, 6, 10.0, 5.0)
    obj = board.object_points()[:, :2]
    w, h = obj.max(axis=0) + 10.0
    H = cv2.getPerspectiveTransform(
        np.float32([[0, 0], [w, 0], [w, h], [0, h]]), np.float32([[180, 120], [470, 140], [450, 380], [170, 360]])
    )
    big = np.full((480 * 8, 640 * 8), 230, np.uint8)
    for x, y in obj:
        px, py = cv2.perspectiveTransform(np.float64([[[x + 5.0, y + 5.0]]]), H)[0, 0]
        cv2.circle(big, (int(px * 8), int(py * 8)), int(2.5 * 290.0 / w * 8), 30, -1)
    return cv2.resize(big, (640, 480), interpolation=cv2.INTER_AREA), board


def _exercise() -> None:
    """Run the detector on :func:`synthetic_board` as uint8 (clean and noisy), uint16, float32 and float64 images
    (what image files and numpy callers give it: a float64 image is what a renderer hands over), so that numba
    compiles each kernel for the argument types detection gives it."""
    from circcal.detector.find import detect, recorrect
    from circcal.detector.locate.segment import GUIDED_EPS, GUIDED_MIN_RADIUS, guided_filter, shrink
    from circcal.model import Camera

    img, board = synthetic_board()
    noisy = np.clip(img + np.random.default_rng(0).normal(0.0, 8.0, img.shape), 0, 255).astype(np.uint8)
    # the guided filter runs on noisy images whose plain Otsu mask shows no board (not this one): called as the
    # segmentation calls it
    guided_filter(noisy, GUIDED_MIN_RADIUS, GUIDED_EPS, np.zeros(256, np.int64))
    # the lattice search's neighbour queries (an asymmetric board, clutter: not this board's direct ordering) and
    # the small dots' clusters
    from circcal.detector.locate.neighbours import NeighbourGrid, linked_clusters

    NeighbourGrid(np.random.default_rng(0).uniform(0.0, 100.0, (20, 2))).query(np.zeros((3, 2)), k=2)
    linked_clusters(np.random.default_rng(0).uniform(0.0, 100.0, (20, 2)), 2.5)
    for im in (img, noisy, img.astype(np.uint16) * 257, img.astype(np.float32) / 255.0, img.astype(np.float64) / 255.0):
        d = detect(im, board, time_budget_s=None)  # numba compiles inside this call: no budget for that
        if not d.found:
            raise RuntimeError(f"kernel build: the synthetic board was not found ({d.reason})")
    # a calibration re-corrects the centres under each new distortion estimate (the ellipses refitted in Python)
    recorrect(d, board, Camera(640, 480, 600.0, 600.0, 319.5, 239.5, np.array([-0.1, 0.01, 0.0, 0.0, 0.0])))
    shrink(np.repeat(np.repeat(img, 3, axis=0), 3, axis=1), 3)  # frames of 720 px and more are segmented shrunk


def build(out_dir: Path = AOT_DIR, force: bool = False) -> dict[str, list[str]]:
    """Compile every kernel module ahead of time (``numba.pycc``) into a folder.

    Runs the detector on :func:`synthetic_board` (:func:`_exercise`) so that numba compiles each kernel for the
    argument types detection gives it, then exports every signature numba compiled (see the module docstring).
    Modules whose current source is built already are skipped (unless ``force``); builds of older sources are
    removed. The curvature shift table is stored beside them
    (:func:`~circcal.detector.measure.curvature.store_table`). Each module's build is moved in whole: a reader never
    sees half a build. Needs numba and a C compiler (pycc compiles the module's C glue).

    Parameters
    ----------
    out_dir : pathlib.Path
        The folder to write to (default: :data:`~circcal.detector.kernels.jit.AOT_DIR`; modules are skipped as
        current only there).
    force : bool
        Rebuild modules whose current source is built already.

    Returns
    -------
    dict of str to list of str
        Kernel module -> the kernels exported (``["(current)"]`` for a module skipped as built already).

    Raises
    ------
    RuntimeError
        The detector did not find the synthetic board (a detector change broke the build's exercise).
    ImportError
        numba is not installed.
    OSError
        ``out_dir`` cannot be written.

    Examples
    --------
    >>> build()  # doctest: +SKIP
    {'circcal.detector.image': ['_histogram_kernel'], ...}
    """
    import tempfile

    import numba.pycc.compiler as pycc_compiler
    from numba.pycc import CC

    import circcal.detector.find  # noqa: F401 - registers every kernel module the detector uses

    jit._told = True  # the build is the compiling; the first-run notice is for the detector's users
    for module in list(_registry):
        _jit_module(module)
    _exercise()

    class _NoGilFlags(pycc_compiler.Flags):  # pycc's wrappers would hold the GIL; numba's nogil kernels do not
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            self.release_gil = True

    pycc_compiler.Flags = _NoGilFlags
    # a kernel's own compile options that change its code (numba's njit takes them per function; pycc compiles all
    # exports of a module with one set of flags): ``error_model="numpy"`` (a float division without Python's zero
    # check, which keeps a loop from vectorising) is applied to that kernel's exports alone
    models = {
        k.py_func: k.options["error_model"] for ks in _registry.values() for k in ks if "error_model" in k.options
    }
    compile_extra = pycc_compiler.compile_extra

    def _compile_extra(typingctx, targetctx, func, args, return_type, flags, locals, **kw):
        if func in models:
            flags = flags.copy()
            flags.error_model = models[func]
        return compile_extra(typingctx, targetctx, func, args, return_type, flags, locals, **kw)

    pycc_compiler.compile_extra = _compile_extra
    out_dir.mkdir(parents=True, exist_ok=True)
    done: dict[str, list[str]] = {}
    from circcal.detector.measure.curvature import (
        store_table,  # the curvature model's table: no scipy import at start-up
    )

    store_table(out_dir)
    for module, kernels in _registry.items():
        name = _aot_name(module)
        if not force and out_dir == AOT_DIR and (out_dir / f"{name}.json").is_file():
            done[module] = ["(current)"]
            continue
        cc = CC(name)
        cc.verbose = False
        if "flags=" in _host_cpu() or "Features=" in _host_cpu():  # the CPU is known to the build's name
            cc.target_cpu = TARGET_CPU
        manifest: dict[str, list] = {}
        for k in kernels:
            for i, sig in enumerate(k._jit.signatures):
                specs = [_spec_of(t) for t in sig]
                if any(s is None for s in specs):
                    continue
                symbol = f"{k.__name__}__{i}"
                ret = k._jit.overloads[sig].signature.return_type
                cc.export(symbol, ret(*sig))(k.py_func)
                manifest.setdefault(k.__name__, []).append({"symbol": symbol, "args": specs})
        if not manifest:
            continue
        with tempfile.TemporaryDirectory(dir=out_dir) as tmp:  # moved in whole: a reader never sees half a build
            cc.output_dir = tmp
            with warnings.catch_warnings():  # pycc's own pending-deprecation notice: stated in the module docstring
                warnings.simplefilter("ignore")
                cc.compile()
            for old in out_dir.glob(f"{module.rsplit('.', 1)[-1]}_*"):
                old.unlink()
            for f in Path(tmp).iterdir():
                os.replace(f, out_dir / f.name)
            manifest_tmp = Path(tmp) / "manifest"
            manifest_tmp.write_text(json.dumps(manifest, indent=1) + "\n")
            os.replace(manifest_tmp, out_dir / f"{name}.json")
        done[module] = sorted(manifest)
    return done


if __name__ == "__main__":
    print("kernels:", build())
    sys.exit(0)
