"""Starting cameras for references that need one: a pinhole seed (:func:`seed_camera`) and a fisheye focal length."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from circcal.model import Camera, project

__all__ = ["seed_camera", "FISHEYE_FOCAL_SWEEP", "fisheye_seed_focal"]


def seed_camera(
    object_points: Sequence[np.ndarray],
    image_points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    lens: str = "opencv5",
) -> Camera:
    """A rough pinhole seed (no distortion), for references that need a starting focal length.

    From ``cv2.initCameraMatrix2D`` (Zhang with the principal point at the image centre); used for mrcal's
    ``focal_estimate`` and pycolmap's camera. Only a starting point: each reference then solves its own least-squares
    problem. A non-finite or non-positive focal length falls back to max(w, h).

    Parameters
    ----------
    object_points : sequence of ndarray, shape (N_v, 3)
        Board points per view, mm.
    image_points : sequence of ndarray, shape (N_v, 2)
        Centres per view, px.
    image_size : tuple of int
        (width, height) px.
    lens : str
        The model of the returned camera, its distortion all zero; for "fisheye" (where a pinhole seed means nothing)
        the equidistant focal length of :func:`fisheye_seed_focal`.

    Returns
    -------
    circcal.model.Camera
        Principal point at the image centre ((w - 1) / 2, (h - 1) / 2) px, zero distortion.
    """
    import cv2

    if lens == "fisheye":
        from circcal.model import LENS_MODELS

        w, h = int(image_size[0]), int(image_size[1])
        f = fisheye_seed_focal(object_points, image_points, image_size)
        return Camera(w, h, f, f, (w - 1) / 2.0, (h - 1) / 2.0, np.zeros(len(LENS_MODELS[lens].dist_names)), lens=lens)

    K = cv2.initCameraMatrix2D(
        [np.asarray(o, dtype=np.float32).reshape(-1, 1, 3) for o in object_points],
        [np.asarray(p, dtype=np.float32).reshape(-1, 1, 2) for p in image_points],
        (int(image_size[0]), int(image_size[1])),
    )
    w, h = int(image_size[0]), int(image_size[1])
    fx, fy = float(K[0, 0]), float(K[1, 1])
    if not (np.isfinite(fx) and np.isfinite(fy) and fx > 0 and fy > 0):
        fx = fy = float(max(w, h))
    if lens == "opencv5":
        return Camera(w, h, fx, fy, (w - 1) / 2.0, (h - 1) / 2.0, np.zeros(5))
    from circcal.model import LENS_MODELS

    return Camera(w, h, fx, fy, (w - 1) / 2.0, (h - 1) / 2.0, np.zeros(len(LENS_MODELS[lens].dist_names)), lens=lens)


#: Equidistant focal lengths tried by :func:`fisheye_seed_focal`, relative to max(w, h) / pi (cv2.fisheye's start).
FISHEYE_FOCAL_SWEEP: tuple[float, ...] = (0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.25, 1.4, 1.6)


def fisheye_seed_focal(
    object_points: Sequence[np.ndarray], image_points: Sequence[np.ndarray], image_size: tuple[int, int]
) -> float:
    """A starting equidistant focal length for a fisheye calibration.

    Of :data:`FISHEYE_FOCAL_SWEEP` x max(w, h) / pi, the one whose poses reproject the observations best, with the
    principal point at the image centre and k1-k4 = 0. Per candidate f the observations are lifted to the z = 1 plane
    (theta = r / f, clamped below 90 deg, x = tan(theta) (u - c) / r) and each view's pose comes from ``cv2.solvePnP``
    on them (IPPE for the planar board); the cost is the pixel residual through :func:`circcal.model.project` with
    that camera.

    Parameters
    ----------
    object_points : sequence of ndarray, shape (N_v, 3)
        Board points per view, mm, z = 0.
    image_points : sequence of ndarray, shape (N_v, 2)
        Centres per view, px.
    image_size : tuple of int
        (width, height) px.

    Returns
    -------
    float
        Focal length, px (max(w, h) / pi when no candidate gives a finite cost).
    """
    import cv2

    w, h = int(image_size[0]), int(image_size[1])
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    best_f, best_cost = float(max(w, h)) / np.pi, np.inf
    for rel in FISHEYE_FOCAL_SWEEP:
        f = rel * max(w, h) / np.pi
        cam = Camera(w, h, f, f, c[0], c[1], np.zeros(4), lens="fisheye")
        cost = 0.0
        for o, q in zip(object_points, image_points):
            d = np.asarray(q, dtype=np.float64) - c
            r = np.linalg.norm(d, axis=1)
            theta = np.minimum(r / f, 0.49 * np.pi)
            lift = np.where(r > 0, np.tan(theta) / np.maximum(r, 1e-12), 1.0 / f)
            ok, rv, tv = cv2.solvePnP(
                np.asarray(o, dtype=np.float64), d * lift[:, None], np.eye(3), None, flags=cv2.SOLVEPNP_IPPE
            )
            if not ok:
                cost = np.inf
                break
            cost += float(np.sum((project(o, rv.reshape(3), tv.reshape(3), cam) - q) ** 2))
        if np.isfinite(cost) and cost < best_cost:
            best_f, best_cost = f, cost
    return best_f
