"""mrcal's own tools on the ``.cameramodel`` circcal writes, judged by what they print and write, not by their exit
status (they exit 0 while printing ERROR or a traceback): ``mrcal-convert-lensmodel`` re-solves it as
LENSMODEL_OPENCV8 (it needs ``calobject_warp`` as an array, and lengths in metres or it warns the camera moved by
"0.8m"), ``mrcal-show-projection-uncertainty`` draws the uncertainty circcal computes up to the noise estimate's
degrees-of-freedom factor (its gnuplot script, ``--hardcopy x.gp``, holds the numbers), ``mrcal-show-residuals``
counts the residuals circcal fitted, and ``mrcal.cameramodel`` reads and writes the file back unchanged. Symmetric
and asymmetric boards; every mrcal present (skipped, saying so, where there is none)."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from circcal.board import Board
from circcal.fixtures.scenarios import get_scenario
from circcal.formats import read_camera
from circcal.formats.cameramodel_export import MRCAL_M_PER_MM, UNITS_NOTE, cameramodel_text, result_views
from circcal.model import project
from circcal.solver import calibrate
from circcal.solver.uncertainty import result_projection_stdev
from tests.mrcal_pythons import mrcal_pythons

PYTHONS = mrcal_pythons()
#: Limit for one mrcal tool run (s): about a second each here.
TOOL_TIMEOUT_S = 120
#: Per-coordinate noise added to the exact projections (px).
NOISE_PX = 0.1
#: The uncertainty grid asked of mrcal-show-projection-uncertainty (columns, rows).
GRIDN = (4, 3)


def _versions():
    return [pytest.param(label, py, tools, id=label) for label, py, tools in PYTHONS] or [
        pytest.param(None, None, None, marks=pytest.mark.skip(reason="mrcal not installed (apt-get install mrcal)"))
    ]


def _tool(tools: Path, python: str, name: str, *args: str, cwd: Path) -> str:
    """Run an mrcal tool by the interpreter it belongs to; its stdout + stderr, which must hold no error."""
    exe = tools / name
    cmd = [str(exe), *args] if str(tools) == "/usr/bin" else [python, str(exe), *args]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=TOOL_TIMEOUT_S, cwd=cwd)
    out = run.stdout + run.stderr
    assert run.returncode == 0, out
    for bad in ("ERROR", "Traceback", "WARNING", "MUST"):
        assert bad not in out, f"{name} printed {bad}:\n{out}"
    return out


def _written(tmp_path: Path, layout: str):
    """A calibration of noisy exact projections of a 7x7 board (``layout``) seen as the ``paper`` scenario's views
    (the points inside the image), written as circcal writes it (``calibrate --out x.cameramodel``); (path, result)."""
    sc = get_scenario("paper")
    board = Board(7, 7, 10.0, 5.0, layout=layout)
    obj = board.object_points()
    rng = np.random.default_rng(3)
    w, h = sc.camera.width, sc.camera.height
    objs, img = [], []
    for r, t in sc.poses():
        q = project(obj, r, t, sc.camera) + rng.normal(0.0, NOISE_PX, (len(obj), 2))
        inside = np.all((q > 0) & (q < [w - 1, h - 1]), axis=1)  # partial views where the board leaves the image
        objs.append(obj[inside])
        img.append(q[inside])
    res = calibrate(objs, img, (w, h))
    text, info = cameramodel_text(res.camera, result_views(res))
    assert info["optimization_inputs"], info["why"]
    path = tmp_path / f"{layout}.cameramodel"
    path.write_text(text)
    return path, res


def _residuals(res) -> np.ndarray:
    """circcal's residuals at its solution, every coordinate, (2N,) px."""
    return np.concatenate(
        [
            (project(o, r, t, res.camera) - q).ravel()
            for o, q, r, t in zip(res.object_points, res.image_points, res.rvecs, res.tvecs)
        ]
    )


def _gnuplot_matrix(script: str) -> np.ndarray:
    """The first data matrix of a gnuplotlib script (the lines after ``splot '-' matrix`` up to ``e``)."""
    lines = script.split("splot '-' matrix", 1)[1].splitlines()[1:]
    rows = []
    for line in lines:
        if line.strip() == "e":
            break
        if line.strip():
            rows.append([float(v) for v in line.split()])
    return np.array(rows)


@pytest.mark.parametrize("layout", ["symmetric", "asymmetric"])
@pytest.mark.parametrize("label,python,tools", _versions())
def test_mrcal_tools_take_circcals_cameramodel(label, python, tools, layout, tmp_path):
    model, res = _written(tmp_path, layout)
    assert UNITS_NOTE in model.read_text()
    rms = float(np.sqrt(np.mean(_residuals(res) ** 2)))

    # mrcal-convert-lensmodel re-solves from the file's inputs (board warp freed: it needs the array to seed it)
    out = _tool(tools, python, "mrcal-convert-lensmodel", "LENSMODEL_OPENCV8", model.name, cwd=tmp_path)
    m = re.search(r"RMS error of the solution: ([0-9.eE+-]+) pixels", out)
    assert m, out
    # 3 more coefficients, a warp and mrcal's outlier rejection: lower, but the same fit (not a lost solve)
    assert 0.5 * rms < float(m.group(1)) < 1.05 * rms, out
    shift = re.search(r"translation: \[([^\]]*)\] m", out)
    assert shift, out
    # the file is in metres: the refit camera moves by well under a millimetre, not "0.8m"
    assert np.linalg.norm([float(v) for v in shift.group(1).split()]) < 1e-3, out
    converted = tmp_path / f"{layout}-LENSMODEL_OPENCV8.cameramodel"
    assert "Wrote" in out and converted.exists()
    cam8 = read_camera(converted)
    assert cam8.lens == "rational" and abs(cam8.fx - res.camera.fx) < 0.01 * res.camera.fx

    # mrcal-show-projection-uncertainty: its numbers are circcal's times the ratio of the two noise estimates
    # (mrcal: the residuals' standard deviation; circcal: corrected for the fitted parameters)
    gp = tmp_path / "u.gp"
    _tool(
        tools,
        python,
        "mrcal-show-projection-uncertainty",
        "--gridn",
        *map(str, GRIDN),
        "--hardcopy",
        gp.name,
        model.name,
        cwd=tmp_path,
    )
    theirs = _gnuplot_matrix(gp.read_text())
    assert theirs.shape == (GRIDN[1], GRIDN[0])
    w, h = res.camera.width, res.camera.height
    uv = np.array([[x, y] for y in np.linspace(0, h - 1, GRIDN[1]) for x in np.linspace(0, w - 1, GRIDN[0])])
    ours = result_projection_stdev(res, uv, distance=None).reshape(theirs.shape)
    dof = np.std(_residuals(res)) / res.sigma_px
    assert dof < 1.0  # mrcal's noise estimate is the smaller one
    np.testing.assert_allclose(theirs, ours * dof, rtol=0.01)

    # mrcal-show-residuals: every residual circcal fitted, with circcal's spread
    hist = tmp_path / "r.gp"
    _tool(tools, python, "mrcal-show-residuals", "--histogram", "--hardcopy", hist.name, model.name, cwd=tmp_path)
    script = hist.read_bytes().decode("latin-1")
    n = re.search(r"record=(\d+)", script)
    assert n and int(n.group(1)) == sum(2 * len(q) for q in res.image_points), script[:2000]
    sd = re.search(r"observed stdev: ([0-9.]+) pixels", script)
    assert sd and float(sd.group(1)) == pytest.approx(np.std(_residuals(res)), abs=0.006)


@pytest.mark.parametrize("label,python,tools", _versions())
def test_cameramodel_round_trips_through_mrcal(label, python, tools, tmp_path):
    """mrcal.cameramodel reads circcal's file and writes it back: the same camera, the same inputs (metres), and
    mrcal's residuals at them are circcal's."""
    model, res = _written(tmp_path, "asymmetric")
    again = tmp_path / "again.cameramodel"
    script = f"""
import json, sys, numpy as np, mrcal
m = mrcal.cameramodel({str(model)!r})
m.write({str(again)!r})
oi = mrcal.cameramodel({str(again)!r}).optimization_inputs()
x = mrcal.optimizer_callback(**oi, no_jacobian=True, no_factorization=True)[1]
r = mrcal.residuals_chessboard(oi, residuals=x).ravel()
print(json.dumps({{"lensmodel": m.intrinsics()[0], "intrinsics": m.intrinsics()[1].tolist(),
    "spacing": float(oi["calibration_object_spacing"]), "t": oi["frames_rt_toref"][:, 3:].tolist(),
    "warp": np.asarray(oi["calobject_warp"]).tolist(), "rms": float(np.sqrt(np.mean(r * r)))}}))
"""
    run = subprocess.run([python, "-c", script], capture_output=True, text=True, timeout=TOOL_TIMEOUT_S)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["lensmodel"] == "LENSMODEL_OPENCV5"
    np.testing.assert_allclose(got["intrinsics"], res.camera.intrinsics, rtol=1e-8)
    assert got["spacing"] == pytest.approx(10.0 * MRCAL_M_PER_MM)  # the staggered lattice's pitch (10 mm), in m
    assert got["warp"] == [0.0, 0.0]
    # the board sits at the scenario's distance, in metres now (the paper scenario's boards are ~1-2 m away)
    assert 0.05 < float(np.median(np.linalg.norm(got["t"], axis=1))) < 20.0
    assert got["rms"] == pytest.approx(float(np.sqrt(np.mean(_residuals(res) ** 2))), rel=1e-6)
    back = read_camera(again)
    np.testing.assert_allclose(back.intrinsics, res.camera.intrinsics, rtol=1e-8)
