"""The conformance matrix's rig axis with a user's rig calibrator: the truth check fails a biased calibrator, passes
a correct one without a covariance (circcal's sigmas then), calls a two-argument function, and runs from the installed
suite with --rig-calibrator."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from circcal.rig import RigModel
from circcal.validators.rig_conformance import RigCase, circcal_rig, rig_cases, run_rig_case

CASE = RigCase("chain", "noise", False)


def test_the_matrix_has_every_scenario_and_observation_variant_fast():
    fast = [c.id for c in rig_cases() if not c.slow]
    assert {"two-noise", "chain-flip", "fisheye-very-noisy"} <= set(fast)
    assert all(c.variant == "rendered-noise" for c in rig_cases() if c.slow)


def test_a_correct_calibrator_without_covariance_passes_in_circcals_sigmas():
    def no_cov(views, image_sizes, lenses, board):
        r = circcal_rig(views, image_sizes, lenses=lenses, board=board)
        return RigModel(r.names, r.cameras, r.rvecs, r.tvecs)

    assert run_rig_case(CASE, no_cov) == []


def test_a_biased_calibrator_fails_naming_the_parameter():
    def biased(views, image_sizes, lenses, board):
        r = circcal_rig(views, image_sizes, lenses=lenses, board=board)
        t = r.tvecs.copy()
        t[2, 0] += 2.0  # camera c 2 mm off: tens of its sigmas
        return RigModel(r.names, r.cameras, r.rvecs, t, r.covariance)

    out = run_rig_case(CASE, biased)
    assert len(out) == 1 and out[0].startswith("c.tx is ") and "stated sigmas from the truth" in out[0]


def test_a_two_argument_calibrator_is_called_without_the_keywords():
    seen = {}

    def plain(views, image_sizes):
        seen["sizes"] = dict(image_sizes)
        return RigModel(list(views), [], np.zeros((0, 3)), np.zeros((0, 3)))  # refused: no cameras

    out = run_rig_case(CASE, plain)
    assert seen["sizes"] == {"a": (640, 480), "b": (640, 480), "c": (512, 384)}
    assert out and "the calibrator failed: InputError" in out[0]


def test_the_installed_suite_runs_a_rig_calibrator_file(tmp_path):
    f = tmp_path / "mycal.py"
    f.write_text(
        "from circcal.validators.rig_conformance import circcal_rig\n"
        "def cal(views, image_sizes, **kw):\n"
        "    return circcal_rig(views, image_sizes, **kw)\n"
    )
    r = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider", "--pyargs", "circcal.conformance",
         "-k", "rig_conformance and chain", "--rig-calibrator", f"{f}:cal"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "4 passed" in r.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider", "--pyargs", "circcal.conformance",
         "-k", "rig_conformance", "--rig-calibrator", f"{f}:nothere"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert bad.returncode != 0 and "has no callable 'nothere'" in bad.stdout + bad.stderr


def test_a_calibrator_in_another_convention_is_told_which():
    """R, T inverted (each camera's pose in the reference frame) or T in metres: the failure says so, and circcal's
    convention; the same calibrator in circcal's convention passes (above), a biased one gets no such hint."""
    import cv2

    def converted(invert: bool, scale: float):
        def cal(views, image_sizes, lenses, board):
            r = circcal_rig(views, image_sizes, lenses=lenses, board=board)
            rv, tv = r.rvecs.copy(), r.tvecs.copy()
            for c in range(1, r.n_cameras):
                R, T = r.pose(c)
                if invert:
                    R, T = R.T, -R.T @ T
                rv[c], tv[c] = cv2.Rodrigues(R)[0].ravel(), T * scale
            return RigModel(r.names, r.cameras, rv, tv)

        return cal

    for invert, scale, words in [
        (True, 1.0, "read with R, T inverted (each camera's pose in the reference camera's frame, X_0 = R X_i + T)"),
        (False, 1e-3, "read with T in m:"),
        (True, 1e-3, "R, T inverted (each camera's pose in the reference camera's frame, X_0 = R X_i + T) and T in m"),
    ]:
        out = run_rig_case(CASE, converted(invert, scale))
        assert len(out) == 2 and "stated sigmas from the truth" in out[0], out
        assert words in out[1] and "circcal's convention is X_i = R_i X_0 + T_i with T in mm" in out[1], out
