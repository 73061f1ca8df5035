"""The joint rig solve beside ``cv2.stereoCalibrate`` (issue 37: <= 0.7x, linear in instants).

The rig: the ``two`` scenario of :mod:`circcal.fixtures.rig` with its right camera given an ``opencv5`` lens of the
same size and focal length (``stereoCalibrate`` fits one distortion model for both cameras), observations projected
with 0.1 px of Gaussian noise. Both tools get the same observations: per instant both cameras saw, the board points
both saw, rounded to float32 (what ``stereoCalibrate`` takes; circcal gets the same numbers as float64), and the same
start: each camera's intrinsics from a single-camera calibration of its own views (circcal's, not timed).

* ``circcal``: what :func:`circcal.rig.calibrate_rig_points` does with the intrinsics given (``initial=`` a camera
  per name) after checking its input: each view's board pose in closed form with the intrinsics held
  (:func:`circcal.rig.start.given_camera_starts`: IPPE, as ``stereoCalibrate`` solves its own by PnP), the rig's
  start from them (pairwise consensus, spanning tree) and the joint Levenberg-Marquardt solve with its covariance
  (``circcal.rig.calibrate._calibrate``). Timed beside: the public call itself with its input checks
  (``given_intrinsics_s``), and without given intrinsics (``calibrate_rig_points_s``: each camera calibrated alone
  first).
* ``opencv``: ``cv2.stereoCalibrate(..., CALIB_USE_INTRINSIC_GUESS)`` from the same intrinsics, OpenCV's default
  termination criteria, one thread.

Alternated A B A B in one process, BLAS and OpenCV at one thread (:func:`benchmarks.timing.pinned`); the ratio is the
median of the per-round ratios with their spread. Both solutions are compared (rotation deg, translation mm, RMS) to
show they reach one minimum. Growth: the same rig with 10, 20, 40 and 80 shared instants (board poses drawn by the
``two`` scenario's generator, ``circcal.fixtures.rig._board_poses``, with more poses; the scenario has no instant
count of its own), both tools timed the same way, and the slope of log(time) on log(instants) fitted to the
medians and to the minima (1 = linear; called linear up to
:data:`LINEAR_SLOPE`: the iteration count is constant, the remainder is load on a shared machine).
"""

from __future__ import annotations

import numpy as np

from benchmarks.timing import alternate, pinned, ratio, summary
from circcal.rotation import rotation_angle_deg

#: Issue 37's bar: the joint solve at most this fraction of stereoCalibrate's time.
RATIO_BAR = 0.7
NOISE_PX = 0.1
GROWTH = (10, 20, 40, 80)
#: The largest log-log slope of time on instants called linear.
LINEAR_SLOPE = 1.15


def _scenario(n_poses: int | None = None):
    """The ``two`` rig with an opencv5 right camera; ``n_poses`` board poses from its generator (None: its own)."""
    from circcal.fixtures.rig import RigScenario, _board_poses, rig_scenario
    from circcal.model import Camera
    from circcal.rig.model import RigModel

    s = rig_scenario("two")
    right = Camera(512, 384, 450.0, 449.0, 253.1, 195.6, [-0.08, 0.05, 2e-4, 5e-4, -0.01])
    rig = RigModel(s.rig.names, [s.rig.cameras[0], right], s.rig.rvecs, s.rig.tvecs)
    rv, tv = s.board_rvecs, s.board_tvecs
    if n_poses is not None:
        rv, tv = _board_poses(n_poses, 11, (330.0, 520.0), 90.0, 40.0)
        tv[:, 0] += 45.0  # centred between the two cameras, as the scenario's
    return RigScenario("two-opencv5", rig, s.board, tuple(f"{k:03d}.png" for k in range(len(rv))), rv, tv)


def _shared(scenario, limit: int | None = None) -> tuple[list[str], dict]:
    """(instants, views): the points both cameras saw at each instant both saw, rounded to float32."""
    from circcal.fixtures.rig import rig_observations
    from circcal.validators.rig import shared_points

    obs = rig_observations(scenario, NOISE_PX, 0)
    a, b = scenario.rig.names
    views: dict = {a: {}, b: {}}
    for v in scenario.instants:
        if v not in obs[a] or v not in obs[b]:
            continue
        o, pa, pb = shared_points(obs[a][v], obs[b][v])
        if len(o) < 12:
            continue
        o = o.astype(np.float32).astype(np.float64)
        views[a][v] = (o, pa.astype(np.float32).astype(np.float64))
        views[b][v] = (o, pb.astype(np.float32).astype(np.float64))
        if limit is not None and len(views[a]) == limit:
            break
    return list(views[a]), views


class _Pair:
    """One rig problem, its start intrinsics, and the two timed solves (each keeps its last result)."""

    def __init__(self, scenario, limit: int | None = None):
        import cv2

        from circcal.rig.start import camera_starts
        from circcal.solver import CalibrationOptions

        self.names = list(scenario.rig.names)
        self.instants, self.views = _shared(scenario, limit)
        self.sizes = [(c.width, c.height) for c in scenario.rig.cameras]
        self.opts = [CalibrationOptions()] * 2
        self.cameras, _ = camera_starts(self.names, [self.views[n] for n in self.names], self.sizes, self.opts)
        a, b = self.names
        self.obj = [self.views[a][v][0].astype(np.float32).reshape(-1, 1, 3) for v in self.instants]
        self.p = [[self.views[n][v][1].astype(np.float32).reshape(-1, 1, 2) for v in self.instants] for n in (a, b)]
        self.flags = cv2.CALIB_USE_INTRINSIC_GUESS
        self.result: dict = {}

    def circcal(self) -> None:
        from circcal.rig.calibrate import _calibrate
        from circcal.rig.start import given_camera_starts

        vs = [self.views[n] for n in self.names]
        cameras, poses = given_camera_starts(self.names, self.cameras, vs)
        _, sol, rc = _calibrate(self.names, vs, self.opts, None, cameras, poses)
        self.result["circcal"] = (rc.rig.pose(1), rc.rig.rms_px, sol.iterations)

    def given(self) -> None:
        from circcal.rig import calibrate_rig_points

        calibrate_rig_points(self.views, dict(zip(self.names, self.sizes)), initial=dict(zip(self.names, self.cameras)))

    def opencv(self) -> None:
        import cv2

        c0, c1 = self.cameras
        rms, _, _, _, _, R, T, _, _ = cv2.stereoCalibrate(
            self.obj, self.p[0], self.p[1], c0.K.copy(), c0.dist.copy(), c1.K.copy(), c1.dist.copy(),
            self.sizes[0], flags=self.flags,
        )  # fmt: skip
        self.result["opencv"] = ((R, np.ravel(T)), float(rms))

    def whole(self) -> None:
        from circcal.rig import calibrate_rig_points

        calibrate_rig_points(self.views, dict(zip(self.names, self.sizes)))


def _agreement(pair: _Pair) -> dict:
    """How far the two solutions are apart (they should reach one minimum)."""
    (Rc, Tc), rms_c, iters = pair.result["circcal"]
    (Ro, To), rms_o = pair.result["opencv"]
    return {
        "rotation_apart_deg": float(rotation_angle_deg(Rc.T @ Ro)),
        "translation_apart_mm": float(np.linalg.norm(Tc - To)),
        "circcal_rms_px": rms_c,
        "opencv_rms_px": rms_o,
        "circcal_iterations": iters,
    }


def run() -> dict:
    out: dict = {}
    pair = _Pair(_scenario())
    out["instants"] = len(pair.instants)
    out["points"] = int(sum(len(o) for o in pair.obj))
    with pinned(1) as threads:
        t = alternate({"circcal": pair.circcal, "opencv": pair.opencv, "given": pair.given, "whole": pair.whole})
    out["threads"] = threads
    out["circcal_joint_s"] = summary(t["circcal"])
    out["opencv_stereo_s"] = summary(t["opencv"])
    out["circcal_to_opencv_time"] = ratio(t["circcal"], t["opencv"])
    out["given_intrinsics_s"] = summary(t["given"])
    out["given_intrinsics_to_opencv_time"] = ratio(t["given"], t["opencv"])
    out["calibrate_rig_points_s"] = summary(t["whole"])
    out["calibrate_rig_points_to_opencv_time"] = ratio(t["whole"], t["opencv"])
    out.update(_agreement(pair))

    scenario = _scenario(240)
    times: dict = {"circcal": [], "opencv": []}
    fastest: dict = {"circcal": [], "opencv": []}
    for n in GROWTH:
        p = _Pair(scenario, n)
        if len(p.instants) < n:
            raise RuntimeError(f"only {len(p.instants)} shared instants of 240 poses, wanted {n}")
        with pinned(1):
            tn = alternate({"circcal": p.circcal, "opencv": p.opencv})
        for k in times:
            s = summary(tn[k])
            times[k].append(s["median"])
            fastest[k].append(s["min"])
            out[f"growth_{n}_{k}_s"] = s
        out[f"growth_{n}_circcal_to_opencv_time"] = ratio(tn["circcal"], tn["opencv"])
        out[f"growth_{n}_circcal_iterations"] = p.result["circcal"][2]
    for k, ts in times.items():
        out[f"{k}_loglog_slope"] = float(np.polyfit(np.log(GROWTH), np.log(ts), 1)[0])
        out[f"{k}_loglog_slope_of_minima"] = float(np.polyfit(np.log(GROWTH), np.log(fastest[k]), 1)[0])
    r = out["circcal_to_opencv_time"]["median"]
    slope = out["circcal_loglog_slope"]
    out["verdict"] = (
        f"joint solve {r:.2f}x stereoCalibrate (bar {RATIO_BAR:g}x): {'met' if r <= RATIO_BAR else 'NOT met'}; "
        f"time ~ instants^{slope:.2f} ({'linear' if slope <= LINEAR_SLOPE else 'NOT linear'}; "
        f"stereoCalibrate ~ instants^{out['opencv_loglog_slope']:.2f})"
    )
    return out
