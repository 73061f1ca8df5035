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

from collections.abc import Sequence

import numpy as np

from circcal.errors import CalibrationError
from circcal.model import Camera
from circcal.model import rays as model_rays
from circcal.rotation import rodrigues
from circcal.solver.zhang import poses_from_homographies

__all__ = ["ray_homographies", "poses_from_rays", "fisheye_start", "pinhole_start"]

#: Candidate focal lengths scanned (log-spaced) between the one that puts the farthest observed point at 180 deg
#: and this many times the image's longer side.
_F_MAX_PER_SIDE = 20.0
_N_SCAN = 16


def _by_count(n_points: Sequence[int]) -> list[np.ndarray]:
    """Indices of the views grouped by their number of points (each group is one batched solve)."""
    counts = np.asarray(n_points)
    return [np.flatnonzero(counts == n) for n in np.unique(counts)]


def ray_homographies(object_xy: Sequence[np.ndarray], rays: Sequence[np.ndarray]) -> np.ndarray:
    """Per view the homography board -> rays of :func:`circcal.model.rays.ray_homography`, views of equal point counts
    batched.

    Parameters
    ----------
    object_xy : sequence of ndarray
        Per view (N_v, 2) mm.
    rays : sequence of ndarray
        Per view (N_v, 3) ray directions (any direction).

    Returns
    -------
    ndarray
        (V, 3, 3) with ``H (X, Y, 1)`` along the rays and ``|h1| + |h2| = 2``.

    Raises
    ------
    CalibrationError
        Fewer than 4 points, or collinear ones.
    """
    H = np.empty((len(object_xy), 3, 3))
    for idx in _by_count([len(o) for o in object_xy]):
        H[idx] = model_rays.ray_homographies(
            np.stack([np.asarray(object_xy[i], float)[:, :2] for i in idx]),
            np.stack([np.asarray(rays[i], float) for i in idx]),
        )
    if not np.all(np.isfinite(H)):
        raise CalibrationError("could not fit a plane homography: fewer than 4 points, or collinear ones")
    return H


def poses_from_rays(object_points: Sequence[np.ndarray], rays: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Board poses from board points and the rays they are seen along.

    ``H = [r1 r2 t]`` of :func:`ray_homographies`, the rotation orthonormalised.

    Parameters
    ----------
    object_points : sequence of ndarray
        Per view (N_v, 3) mm, z = 0.
    rays : sequence of ndarray
        Per view (N_v, 3).

    Returns
    -------
    rvecs : ndarray
        (V, 3) rad.
    tvecs : ndarray
        (V, 3) mm.

    Raises
    ------
    CalibrationError
        Fewer than 4 points, or collinear ones.
    """
    Hs = ray_homographies([np.asarray(o)[:, :2] for o in object_points], rays)
    return poses_from_homographies(Hs, np.eye(3), signed=True)


def _equidistant_rays(uv: np.ndarray, f: float, aspect: float, centre: tuple[float, float]) -> np.ndarray:
    """Pixels (..., 2) -> unit rays (..., 3) of the equidistant lens (k = 0, ``theta = r``: closed form)."""
    x = (uv[..., 0] - centre[0]) / (aspect * f)
    y = (uv[..., 1] - centre[1]) / f
    th = np.hypot(x, y)
    s = np.where(th > 0, np.sin(th) / np.where(th > 0, th, 1.0), 1.0)
    return np.stack([x * s, y * s, np.cos(th)], axis=-1)


def _equidistant_pixels(Xc: np.ndarray, f: float, aspect: float, centre: tuple[float, float]) -> np.ndarray:
    """Camera-frame points (..., 3) -> pixels (..., 2) of the equidistant lens (k = 0)."""
    rho = np.hypot(Xc[..., 0], Xc[..., 1])
    th = np.arctan2(rho, Xc[..., 2])
    s = np.where(rho > 0, th / np.where(rho > 0, rho, 1.0), 1.0 / Xc[..., 2])
    return np.stack([aspect * f * s * Xc[..., 0] + centre[0], f * s * Xc[..., 1] + centre[1]], axis=-1)


def _pinhole_rays(uv: np.ndarray, f: float, aspect: float, centre: tuple[float, float]) -> np.ndarray:
    """Pixels (..., 2) -> rays (..., 3) of the distortion-free pinhole (z = 1)."""
    x = (uv[..., 0] - centre[0]) / (aspect * f)
    y = (uv[..., 1] - centre[1]) / f
    return np.stack([x, y, np.ones_like(x)], axis=-1)


def _pinhole_pixels(Xc: np.ndarray, f: float, aspect: float, centre: tuple[float, float]) -> np.ndarray:
    """Camera-frame points (..., 3) -> pixels (..., 2) of the distortion-free pinhole (inf behind the camera)."""
    z = np.where(Xc[..., 2] > 0, Xc[..., 2], np.nan)
    uv = np.stack([aspect * f * Xc[..., 0] / z + centre[0], f * Xc[..., 1] / z + centre[1]], axis=-1)
    return np.where(np.isfinite(uv), uv, np.inf)


#: The lenses the focal search can start from: (pixels -> rays, camera points -> pixels).
_PROJECTIONS = {
    "equidistant": (_equidistant_rays, _equidistant_pixels),
    "pinhole": (_pinhole_rays, _pinhole_pixels),
}


def _fit(
    groups: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
    f: float,
    aspect: float,
    centre: tuple[float, float],
    projection: str = "equidistant",
) -> tuple[float, np.ndarray | None, np.ndarray | None]:
    """RMS per coordinate (px) of the plane poses that best fit the rays of the ``projection`` lens of focal length
    ``f``, with those poses (rvecs, tvecs per view); inf (and None) where a homography is not determined."""
    to_rays, to_pixels = _PROJECTIONS[projection]
    V = sum(len(idx) for idx, _, _ in groups)
    rv, tv = np.empty((V, 3)), np.empty((V, 3))
    ssr, n = 0.0, 0
    for idx, Ob, P in groups:
        H = model_rays.ray_homographies(Ob[..., :2], to_rays(P, f, aspect, centre))
        if not np.all(np.isfinite(H)):
            return float("inf"), None, None
        r, t = poses_from_homographies(H, np.eye(3), signed=True)
        Xc = Ob @ rodrigues(r).transpose(0, 2, 1) + t[:, None, :]
        res = to_pixels(Xc, f, aspect, centre) - P
        ssr += float(np.sum(res * res))
        n += res.size
        rv[idx], tv[idx] = r, t
    rms = np.sqrt(ssr / n)
    return (float(rms), rv, tv) if np.isfinite(rms) else (float("inf"), None, None)


def fisheye_start(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    *,
    principal_point: tuple[float, float] | None = None,
    aspect_ratio: float | None = None,
) -> tuple[Camera, np.ndarray, np.ndarray]:
    """The equidistant starting camera (``lens="fisheye"``, k = 0) and poses (see the module).

    Parameters
    ----------
    object_points : sequence of ndarray
        Per view (N_v, 3) mm, z = 0.
    image_points : sequence of ndarray
        Per view (N_v, 2) px.
    image_size : tuple of int
        (width, height) px.
    principal_point : tuple of float or None
        (cx, cy) px (default the image centre ((w-1)/2, (h-1)/2)).
    aspect_ratio : float or None
        fx / fy (default 1).

    Returns
    -------
    camera : Camera
    rvecs : ndarray
        (V, 3) rad.
    tvecs : ndarray
        (V, 3) mm.

    Raises
    ------
    CalibrationError
        No focal length gives plane poses that reproject (inconsistent correspondences).
    """
    (w, h), centre, aspect, f, rv, tv = _focal_search(
        object_points, image_points, image_size, principal_point, aspect_ratio, "equidistant"
    )
    return Camera(w, h, aspect * f, f, centre[0], centre[1], np.zeros(4), "fisheye"), rv, tv


def pinhole_start(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    *,
    principal_point: tuple[float, float] | None = None,
    aspect_ratio: float | None = None,
) -> tuple[Camera, np.ndarray, np.ndarray]:
    """A distortion-free pinhole start by the same focal search: where Zhang's closed form finds no positive-definite
    conic although the boards are tilted (distortion and noise on nearly fronto-parallel views: OpenCV's
    ``initCameraMatrix2D`` then takes the absolute value of its focal estimate), the focal length whose plane poses
    reproject the views best.

    Parameters
    ----------
    object_points : sequence of ndarray
        Per view (N_v, 3) mm, z = 0.
    image_points : sequence of ndarray
        Per view (N_v, 2) px.
    image_size : tuple of int
        (width, height) px.
    principal_point : tuple of float or None
        (cx, cy) px (default the image centre).
    aspect_ratio : float or None
        fx / fy (default 1).

    Returns
    -------
    camera : Camera
        ``opencv5`` with zero distortion.
    rvecs, tvecs : ndarray
        (V, 3) rad, mm.

    Raises
    ------
    CalibrationError
        No focal length gives plane poses in front of the camera that reproject.
    """
    (w, h), centre, aspect, f, rv, tv = _focal_search(
        object_points, image_points, image_size, principal_point, aspect_ratio, "pinhole"
    )
    return Camera(w, h, aspect * f, f, centre[0], centre[1], np.zeros(5)), rv, tv


def _focal_search(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    principal_point: tuple[float, float] | None,
    aspect_ratio: float | None,
    projection: str,
) -> tuple[tuple[int, int], tuple[float, float], float, float, np.ndarray, np.ndarray]:
    """The scan and bounded minimisation of the module docstring: (size, centre, aspect, f, rvecs, tvecs)."""
    from scipy.optimize import minimize_scalar

    w, h = image_size
    centre = principal_point if principal_point is not None else (0.5 * (w - 1), 0.5 * (h - 1))
    aspect = 1.0 if aspect_ratio is None else float(aspect_ratio)
    obj = [np.asarray(o, dtype=np.float64) for o in object_points]
    img = [np.asarray(p, dtype=np.float64) for p in image_points]
    groups = [
        (idx, np.stack([obj[i] for i in idx]), np.stack([img[i] for i in idx]))
        for idx in _by_count([len(o) for o in obj])
    ]
    allp = np.concatenate(img) - np.asarray(centre)
    r_max = float(np.max(np.hypot(allp[:, 0] / aspect, allp[:, 1])))
    # equidistant: from the focal that puts the farthest point at 180 deg; pinhole: at 85 deg
    f_lo = max(r_max / (np.pi if projection == "equidistant" else np.tan(np.radians(85.0))), 1e-3) * (1.0 + 1e-6)
    f_hi = max(f_lo * 2.0, _F_MAX_PER_SIDE * max(w, h))
    grid = np.geomspace(f_lo, f_hi, _N_SCAN)

    def cost(logf: float) -> float:
        return _fit(groups, float(np.exp(logf)), aspect, centre, projection)[0]

    scan = np.array([cost(np.log(f)) for f in grid])
    if not np.any(np.isfinite(scan)):
        raise CalibrationError(
            f"no {projection} start reprojects these views: check the point "
            "correspondences (board order, image_size) and the object points"
        )
    i = int(np.nanargmin(np.where(np.isfinite(scan), scan, np.nan)))
    lo, hi = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, len(grid) - 1)])
    best = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    f = float(np.exp(best.x)) if best.fun <= scan[i] else float(grid[i])
    _, rv, tv = _fit(groups, f, aspect, centre, projection)
    if rv is None or tv is None:  # the chosen f reprojects (its cost is finite): not reached
        raise CalibrationError(f"the {projection} start found no poses at its own focal length")
    return (int(w), int(h)), (float(centre[0]), float(centre[1])), aspect, f, rv, tv
