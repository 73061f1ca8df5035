"""The fisheye lens's starting point for :func:`circcal.solver.calibrate`: an equidistant guess whose focal length
is searched for, and poses from homographies fitted to rays.

Zhang's closed form (:mod:`circcal.solver.zhang`) needs a perspective image: a fisheye view 70-80 deg off axis is
far from one, and beyond 90 deg there is none. ``cv2.fisheye.calibrate`` starts from the equidistant lens
(``theta_d = theta``, k = 0) with ``f = max(w, h) / pi`` and the image centre, fits a homography per view to the
rays that lens gives, and leaves the rest to its Gauss-Newton. Its fixed ``f`` assumes a 180-deg image across the
frame's longer side; a narrower or wider lens starts far off. Here the same equidistant lens is used, but ``f`` is
chosen by the boards' apparent size: for each candidate ``f`` the rays are fitted by one plane pose per view (a
DLT homography on the rays, which holds in any direction, behind the camera too), and the ``f`` whose poses
reproject the observations best is kept (a log-spaced scan, then a bounded 1-D minimisation around the best
candidate). With the right ``f`` the equidistant lens is within a few percent of any real fisheye's
``theta_d(theta)``, and the joint refinement converges from there.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from circcal.errors import CalibrationError
from circcal.metrics import error_stats
from circcal.model import Camera, project, unproject
from circcal.model.rays import ray_homography
from circcal.solver.zhang import poses_from_homographies

__all__ = ["ray_homographies", "poses_from_rays", "fisheye_start"]

#: Candidate focal lengths scanned (log-spaced) between the one that puts the farthest observed point at 180 deg
#: and this many times the image's longer side.
_F_MAX_PER_SIDE = 20.0
_N_SCAN = 40


def ray_homographies(object_xy: Sequence[np.ndarray], rays: Sequence[np.ndarray]) -> np.ndarray:
    """Per view the homography (V, 3, 3) board mm -> rays of :func:`circcal.model.rays.ray_homography` (any
    direction; ``H (X, Y, 1)`` along the rays, ``|h1| + |h2| = 2``). Raises CalibrationError for fewer than 4 points
    or collinear ones."""
    out = []
    for a, d in zip(object_xy, rays):
        H = ray_homography(a, d)
        if H is None:
            raise CalibrationError("could not fit a plane homography: fewer than 4 points, or collinear ones")
        out.append(H)
    return np.stack(out)


def poses_from_rays(object_points: Sequence[np.ndarray], rays: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Board poses (rvecs (V, 3) rad, tvecs (V, 3) mm) from board points (N_v, 3) mm (z = 0) and the rays (N_v, 3)
    they are seen along: ``H = [r1 r2 t]`` of :func:`ray_homographies`, the rotation orthonormalised."""
    Hs = ray_homographies([np.asarray(o)[:, :2] for o in object_points], rays)
    return poses_from_homographies(Hs, np.eye(3), signed=True)


def _equidistant(f: float, image_size: tuple[int, int], centre: tuple[float, float], aspect: float) -> Camera:
    w, h = image_size
    return Camera(w, h, aspect * f, f, centre[0], centre[1], np.zeros(4), "fisheye")


def _reprojection_rms(obj, img, cam: Camera) -> tuple[float, np.ndarray, np.ndarray]:
    """RMS per coordinate (px) of the best plane poses under ``cam`` (inf where a ray or a fit fails)."""
    rays = [unproject(p, cam) for p in img]
    if not all(np.all(np.isfinite(r)) for r in rays):
        return float("inf"), None, None
    try:
        rv, tv = poses_from_rays(obj, rays)
    except CalibrationError:
        return float("inf"), None, None
    r = np.concatenate([project(o, a, b, cam) - p for o, p, a, b in zip(obj, img, rv, tv)])
    rms = error_stats(r)["rms_per_coord_px"] if np.all(np.isfinite(r)) else float("inf")
    return rms, rv, tv


def fisheye_start(object_points: Sequence[np.ndarray], image_points: Sequence[np.ndarray],
                  image_size: tuple[int, int], *, principal_point: tuple[float, float] | None = None,
                  aspect_ratio: float | None = None) -> tuple[Camera, np.ndarray, np.ndarray]:
    """The equidistant starting camera (``lens="fisheye"``, k = 0) and poses (see the module).

    ``object_points``: per view (N_v, 3) mm, z = 0; ``image_points``: per view (N_v, 2) px; ``image_size``:
    (width, height). ``principal_point``: (cx, cy) px (default the image centre ((w-1)/2, (h-1)/2));
    ``aspect_ratio``: fx / fy (default 1). Returns ``(camera, rvecs (V, 3), tvecs (V, 3))``. Raises
    CalibrationError when no focal length gives plane poses that reproject (inconsistent correspondences)."""
    from scipy.optimize import minimize_scalar

    w, h = image_size
    centre = principal_point if principal_point is not None else (0.5 * (w - 1), 0.5 * (h - 1))
    aspect = 1.0 if aspect_ratio is None else float(aspect_ratio)
    obj = [np.asarray(o, dtype=np.float64) for o in object_points]
    img = [np.asarray(p, dtype=np.float64) for p in image_points]
    allp = np.concatenate(img) - np.asarray(centre)
    r_max = float(np.max(np.hypot(allp[:, 0] / aspect, allp[:, 1])))
    f_lo = max(r_max / np.pi, 1e-3) * (1.0 + 1e-6)
    f_hi = max(f_lo * 2.0, _F_MAX_PER_SIDE * max(w, h))
    grid = np.geomspace(f_lo, f_hi, _N_SCAN)

    def cost(logf: float) -> float:
        return _reprojection_rms(obj, img, _equidistant(float(np.exp(logf)), (w, h), centre, aspect))[0]

    scan = np.array([cost(np.log(f)) for f in grid])
    if not np.any(np.isfinite(scan)):
        raise CalibrationError("no equidistant fisheye start reprojects these views: check the point "
                               "correspondences (board order, image_size) and the object points")
    i = int(np.nanargmin(np.where(np.isfinite(scan), scan, np.nan)))
    lo, hi = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, len(grid) - 1)])
    best = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    f = float(np.exp(best.x)) if best.fun <= scan[i] else float(grid[i])
    cam = _equidistant(f, (w, h), centre, aspect)
    _, rv, tv = _reprojection_rms(obj, img, cam)
    return cam, rv, tv
