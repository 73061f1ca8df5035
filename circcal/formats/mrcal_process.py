"""mrcal run out of process: the interpreter that can import it, one run of the worker, and mrcal's board lattice.

mrcal cannot be imported beside numpy 2 on Python 3.11, so the worker script :mod:`circcal.formats.mrcal_worker`
(started by its file path, :data:`WORKER`; it imports nothing from circcal) runs under another interpreter:
``$CIRCCAL_MRCAL_PYTHON`` if set, else ``/usr/bin/python3`` if it can ``import mrcal`` (Debian's
``python3-mrcal``). JSON goes in on stdin and comes back on stdout. Two callers share this plumbing: the written
``.cameramodel`` with mrcal's optimisation inputs (:mod:`circcal.formats.cameramodel_export`) and mrcal as a
validation reference (:mod:`circcal.validators.mrcal`).

Lens models (:data:`LENSMODELS`): ``LENSMODEL_OPENCV5`` / ``OPENCV8`` / ``OPENCV12`` for circcal's ``opencv5`` /
``rational`` / ``thin-prism``, the same parameters in the same order (OpenCV's); ``fisheye`` has none
(:data:`UNSUPPORTED_LENSES`).

mrcal's board model is a full W x H lattice per image (points (j s, i s, 0), row-major): :func:`board_lattice` maps
each view's board points onto the lattice they span (missing points get weight -1 in mrcal's observations). One rule
for both callers: an asymmetric (staggered) grid maps onto the full lattice with every other point missing, which
mrcal leaves out exactly, so the export and the mrcal reference both take it (measured on the 9-view asymmetric real
set: mrcal's fair solve 3e-8 px from circcal's; mrcal-show-projection-uncertainty, mrcal-show-residuals and
mrcal-convert-lensmodel run on the exported file).
"""

from __future__ import annotations

import json
import os
import subprocess
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from circcal.formats.mrcal import MRCAL_LENSMODELS

__all__ = [
    "WORKER",
    "ENV_VAR",
    "DEFAULT_PYTHON",
    "NOT_FOUND_MESSAGE",
    "LENSMODELS",
    "UNSUPPORTED_LENSES",
    "UnsupportedLayout",
    "mrcal_python",
    "run_worker",
    "board_lattice",
]

#: circcal lens -> mrcal lens model (the same parameters in the same order: OpenCV's); the table the file writer
#: uses (:data:`circcal.formats.mrcal.MRCAL_LENSMODELS`).
LENSMODELS: dict[str, str] = MRCAL_LENSMODELS
#: circcal lens -> why mrcal has no model of it: the mrcal reference's ``unsupported_lenses``
#: (:mod:`circcal.validators.mrcal`) and the export's refusal (:mod:`circcal.formats.cameramodel_export`).
UNSUPPORTED_LENSES: dict[str, str] = {
    "fisheye": "mrcal has no equidistant (Kannala-Brandt) fisheye model: mrcal 2.2's supported_lensmodels() are "
    "PINHOLE, STEREOGRAPHIC, LONLAT, LATLON, OPENCV4/5/8/12, CAHVOR, CAHVORE and "
    "SPLINED_STEREOGRAPHIC, none of them cv2.fisheye's theta polynomial"
}

#: The worker script, run by its file path under mrcal's interpreter.
WORKER = Path(__file__).with_name("mrcal_worker.py")
#: The environment variable naming mrcal's interpreter.
ENV_VAR = "CIRCCAL_MRCAL_PYTHON"
#: The interpreter tried when :data:`ENV_VAR` is not set (Debian's python3-mrcal).
DEFAULT_PYTHON = "/usr/bin/python3"
NOT_FOUND_MESSAGE = (
    "mrcal not found: as root run `apt-get install -y mrcal python3-mrcal`, or set "
    "CIRCCAL_MRCAL_PYTHON to a Python that can import mrcal"
)


@lru_cache(maxsize=8)
def _probe(python: str) -> tuple[bool, str, dict[str, Any]]:
    """Whether ``python`` runs the worker's ``--probe``: ``(ok, why not, {"version", "api", "python"})``; cached
    per interpreter."""
    try:
        out = subprocess.run([python, str(WORKER), "--probe"], capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.SubprocessError) as exc:
        return False, f"{type(exc).__name__}: {exc}", {}
    try:
        info = json.loads(out.stdout.strip().splitlines()[-1])
    except (json.JSONDecodeError, IndexError):
        return False, f"probe printed no JSON (exit {out.returncode}): {out.stderr.strip()[-300:]}", {}
    if out.returncode != 0 or "error" in info:
        return False, info.get("error", f"exit {out.returncode}"), info
    return True, "", info


def mrcal_python() -> tuple[str | None, str, dict[str, Any]]:
    """The interpreter that runs mrcal: ``$CIRCCAL_MRCAL_PYTHON`` if set, else ``/usr/bin/python3`` if it can
    import mrcal.

    Returns
    -------
    tuple
        ``(interpreter, "", probe info {"version", "api", "python"})``, or ``(None, reason, {})`` when there is
        none (the reason starts with :data:`NOT_FOUND_MESSAGE`).
    """
    env = os.environ.get(ENV_VAR)
    if env:
        ok, why, info = _probe(env)
        if ok:
            return env, "", info
        return None, f"{NOT_FOUND_MESSAGE} ({ENV_VAR}={env}: {why})", {}
    if Path(DEFAULT_PYTHON).exists():
        ok, why, info = _probe(DEFAULT_PYTHON)
        if ok:
            return DEFAULT_PYTHON, "", info
        return None, f"{NOT_FOUND_MESSAGE} ({DEFAULT_PYTHON}: {why})", {}
    return None, NOT_FOUND_MESSAGE, {}


def run_worker(python: str, request: dict[str, Any], timeout_s: float) -> dict[str, Any]:
    """One run of :mod:`circcal.formats.mrcal_worker` under ``python``.

    Parameters
    ----------
    python : str
        An interpreter that can import mrcal (:func:`mrcal_python`).
    request : dict
        The request (the worker's protocol), sent as JSON on stdin.
    timeout_s : float
        Limit for the run (s).

    Returns
    -------
    dict
        The worker's JSON reply.

    Raises
    ------
    RuntimeError
        With the worker's (mrcal's) words when it times out, crashes or fails.
    """
    try:
        proc = subprocess.run(
            [python, str(WORKER)], input=json.dumps(request), capture_output=True, text=True, timeout=timeout_s
        )
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"mrcal worker ran past {timeout_s:g} s") from None
    try:
        reply: dict[str, Any] = json.loads(proc.stdout)  # the worker replies with one JSON object
    except json.JSONDecodeError:
        raise RuntimeError(
            f"mrcal worker crashed (exit {proc.returncode}): {(proc.stderr or proc.stdout).strip()[-500:]}"
        ) from None
    if proc.returncode != 0 or "error" in reply:
        raise RuntimeError(f"mrcal failed: {reply.get('error', proc.returncode)}")
    return reply


class UnsupportedLayout(NotImplementedError):
    """Board points that mrcal's rectangular lattice cannot hold (off a square lattice).

    Not an input error: the caller says why mrcal cannot take part (the message holds the reason).
    """


def board_lattice(object_points: list[np.ndarray], *, rel_tol: float = 1e-6) -> dict[str, Any]:
    """Map per-view board points onto mrcal's rectangular lattice.

    Parameters
    ----------
    object_points : list of (N_v, 3) array
        Each view's board points (mm).
    rel_tol : float
        How far off the lattice a point may lie, relative to the largest coordinate. An asymmetric (staggered) grid
        maps onto the full lattice with every other point missing (the module).

    Returns
    -------
    dict
        ``{"spacing" (mm), "origin" (3,) mm, "width_n", "height_n", "ij": [(N_v, 2) int (row i, column j)]}``.

    Raises
    ------
    UnsupportedLayout
        (a ``NotImplementedError``) for points off a square lattice.
    ValueError
        For duplicated points in a view.
    """
    allp = np.concatenate(object_points)
    xs = np.unique(np.round(allp[:, 0], 9))
    ys = np.unique(np.round(allp[:, 1], 9))
    d = np.concatenate([np.diff(xs), np.diff(ys)])
    d = d[d > 0]
    if d.size == 0:
        raise UnsupportedLayout("board points do not span a 2-D lattice")
    s = float(d.min())
    origin = np.array([xs.min(), ys.min(), 0.0])
    scale = max(1.0, float(np.max(np.abs(allp))))
    ij = []
    for v, o in enumerate(object_points):
        j = (o[:, 0] - origin[0]) / s
        i = (o[:, 1] - origin[1]) / s
        ji, ii = np.round(j), np.round(i)
        if np.max(np.abs(j - ji)) * s > rel_tol * scale or np.max(np.abs(i - ii)) * s > rel_tol * scale:
            raise UnsupportedLayout(
                f"view {v}: board points are not on a square lattice of pitch {s:g} (mrcal's board model is a "
                "rectangular grid of equally spaced points)"
            )
        a = np.stack([ii, ji], -1).astype(int)
        if len(np.unique(a, axis=0)) != len(a):
            raise ValueError(f"view {v}: duplicated board points")
        ij.append(a)
    cat = np.concatenate(ij)
    return {
        "spacing": s,
        "origin": origin,
        "width_n": int(cat[:, 1].max()) + 1,
        "height_n": int(cat[:, 0].max()) + 1,
        "ij": ij,
    }
