"""Stereo rectification of a pair of the rig's cameras: ``cv2.stereoRectify``'s R1, R2, P1, P2, Q and valid ROIs,
the rectification maps, and a rectified side-by-side overlay.

Conventions (OpenCV's, ``stereoRectify`` in calib3d's calibration.cpp)
-----------------------------------------------------------------------
* The pair ``(i, j)`` is OpenCV's (first, second) camera: ``X_j = R X_i + T`` (:meth:`RigModel.pair`), ``T`` in mm.
* ``R1`` (``R2``) rotates camera i's (j's) frame into its rectified frame; ``P1 = [[f, 0, cx1, 0], [0, f, cy1, 0],
  [0, 0, 1, 0]]`` and ``P2`` the same with ``cx2, cy2`` and ``P2[idx, 3] = f * b`` (``b`` the baseline along the
  rectified axis, mm; ``idx`` 0 for a horizontal pair, 1 for a vertical one). ``Q`` maps ``(u, v, disparity, 1)``
  to a homogeneous point in camera i's rectified frame, mm. ``alpha`` is OpenCV's free scaling: -1 (or any
  negative value) the default scaling, 0 only valid pixels, 1 every source pixel kept. ``zero_disparity``
  (``CALIB_ZERO_DISPARITY``, OpenCV's default) gives both rectified images the same principal point.
* ROIs are ``(x, y, width, height)`` of the rectangle inside each rectified image where every pixel is valid.

Which implementation (``Rectification.method``)
-----------------------------------------------
* Two pinhole cameras (``opencv5``, ``rational``, ``thin-prism``) of one image size: ``cv2.stereoRectify`` itself.
* Two fisheye cameras of one image size: ``cv2.fisheye.stereoRectify`` (its ``balance`` is ``alpha``, 0 when
  negative; ``fov_scale`` 1). OpenCV's fisheye returns no ROIs: they are computed here as for the pinhole cameras
  (the inner rectangle of the rectified image border).
* Otherwise -- cameras of different image sizes, or a pinhole with a fisheye -- OpenCV has no answer:
  ``stereoRectify`` takes ONE ``imageSize`` for both cameras and uses it for each camera's image corners (which
  centre the rectified images) and for the valid rectangles, so a camera of another size gets a principal point and
  ROI computed from corners that are not its own. circcal then runs OpenCV's algorithm itself (:func:`_rectify_own`:
  the same rotations, focal length, centring, alpha scaling and ROIs) with each camera's own image corners, circcal's
  unprojection of any lens (:func:`circcal.model.unproject`), and one rectified image size for both (the larger
  width and height of the two, or ``new_size``): rectified rows must line up, and stereo matchers take two images
  of one size. For two cameras of one size this equals ``cv2.stereoRectify`` (OpenCV's corners and grid are float32:
  within 0.05 px; tests/test_rig_rectify.py). A fisheye whose image reaches beyond what a perspective image can hold
  is taken within the largest frame, shrunk about its principal point, whose every ray is within
  :data:`MAX_RECTIFIED_ANGLE_DEG` of the rectified optical axis (a perspective image cannot hold 90 deg and more);
  for every pinhole camera (and most fisheyes) that frame is the whole image, as OpenCV's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from circcal import atomic
from circcal.detector import read_image
from circcal.errors import ImageError, InputError
from circcal.model import Camera, unproject
from circcal.rig.model import RigModel
from circcal.rotation import rodrigues

__all__ = [
    "Rectification",
    "rectify_pair",
    "rectification_maps",
    "rectified_overlay",
    "write_rectified_overlay",
    "MAX_RECTIFIED_ANGLE_DEG",
]

#: The points per side of the grid over each image whose rectified positions bound the valid rectangles (OpenCV's).
_GRID = 9
#: circcal's own rectification (different sizes, a fisheye with a pinhole) takes each image within the largest frame
#: about its principal point whose rays are at most this far from the rectified optical axis, deg.
MAX_RECTIFIED_ANGLE_DEG = 80.0


@dataclass(frozen=True)
class Rectification:
    """The rectification of the pair ``(i, j)`` of a rig (OpenCV's ``stereoRectify`` outputs).

    Attributes
    ----------
    i, j : int
        The cameras (OpenCV's first and second).
    R1, R2 : ndarray, shape (3, 3)
        Camera i's (j's) frame -> its rectified frame.
    P1, P2 : ndarray, shape (3, 4)
        Projection matrices of the rectified cameras (px; ``P2``'s last column px mm).
    Q : ndarray, shape (4, 4)
        Disparity-to-depth: ``Q (u, v, d, 1)`` is homogeneous, mm, in camera i's rectified frame.
    roi1, roi2 : tuple of int
        ``(x, y, width, height)``: every pixel valid inside, px.
    image_size : tuple of int
        ``(width, height)`` of both rectified images, px.
    alpha : float
        The free scaling asked for.
    method : str
        ``"cv2.stereoRectify"``, ``"cv2.fisheye.stereoRectify"`` or ``"circcal"`` (OpenCV's algorithm with each
        camera's own image size; see the module).
    """

    i: int
    j: int
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    roi1: tuple[int, int, int, int]
    roi2: tuple[int, int, int, int]
    image_size: tuple[int, int]
    alpha: float
    method: str

    @property
    def vertical(self) -> bool:
        """True when the epipolar lines are columns (the cameras stacked vertically), False for rows."""
        return bool(abs(self.P2[1, 3]) > abs(self.P2[0, 3]))


def rectify_pair(
    rig: RigModel,
    i: int = 0,
    j: int = 1,
    alpha: float = -1.0,
    *,
    new_size: tuple[int, int] | None = None,
    zero_disparity: bool = True,
) -> Rectification:
    """OpenCV's stereo rectification of the rig's cameras ``i`` and ``j``.

    Parameters
    ----------
    rig : RigModel
    i, j : int
        Two different cameras of the rig: OpenCV's first and second (``X_j = R X_i + T``).
    alpha : float
        OpenCV's free scaling: negative for its default, else in [0, 1] (0: only valid pixels, 1: every pixel).
    new_size : tuple of int, optional
        ``(width, height)`` of the rectified images, px; default the cameras' common size (the larger width and
        height when they differ).
    zero_disparity : bool
        ``CALIB_ZERO_DISPARITY`` (OpenCV's default): one principal point for both rectified images.

    Returns
    -------
    Rectification

    Raises
    ------
    InputError
        ``i`` or ``j`` not a camera of the rig or equal, ``alpha`` out of range, a ``new_size`` that is not two
        positive integers, cameras at the same place (no baseline), or image corners that no rectified camera sees.
    """
    n = rig.n_cameras
    for name, k in (("i", i), ("j", j)):
        if not isinstance(k, (int, np.integer)) or isinstance(k, bool) or not 0 <= k < n:
            raise InputError(f"rectification camera {name} must be an index 0..{n - 1} of the rig, got {k!r}")
    if i == j:
        raise InputError(f"rectification needs two different cameras, got i = j = {i}")
    a = float(alpha)
    if not math.isfinite(a) or a > 1.0:
        raise InputError(f"rectification alpha must be negative (OpenCV's default) or in [0, 1], got {alpha!r}")
    if new_size is not None:
        if len(new_size) != 2 or any(
            isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0 for v in new_size
        ):
            raise InputError(f"rectified image size must be two positive integers (width, height), got {new_size!r}")
        new_size = (int(new_size[0]), int(new_size[1]))
    c1, c2 = rig.cameras[i], rig.cameras[j]
    R, T = rig.pair(i, j)
    if not np.linalg.norm(T) > 0:
        raise InputError(f"cameras {rig.names[i]!r} and {rig.names[j]!r} are at the same place: no stereo baseline")
    same_size = (c1.width, c1.height) == (c2.width, c2.height)
    if same_size and c1.model.pinhole and c2.model.pinhole:
        return _rectify_opencv(c1, c2, R, T, i, j, a, new_size, zero_disparity)
    if same_size and not c1.model.pinhole and not c2.model.pinhole:
        return _rectify_fisheye(c1, c2, R, T, i, j, a, new_size, zero_disparity)
    return _rectify_own(c1, c2, R, T, i, j, a, new_size, zero_disparity)


def _rectify_opencv(
    c1: Camera,
    c2: Camera,
    R: np.ndarray,
    T: np.ndarray,
    i: int,
    j: int,
    alpha: float,
    new_size: tuple[int, int] | None,
    zero_disparity: bool,
) -> Rectification:
    """``cv2.stereoRectify`` of two pinhole cameras of one image size."""
    import cv2

    size = (c1.width, c1.height)
    R1, R2, P1, P2, Q, roi1, roi2 = cv2.stereoRectify(
        c1.K,
        c1.dist,
        c2.K,
        c2.dist,
        size,
        R,
        T.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY if zero_disparity else 0,
        alpha=alpha,
        newImageSize=new_size or (0, 0),
    )
    return Rectification(
        i, j, R1, R2, P1, P2, Q, tuple(roi1), tuple(roi2), new_size or size, alpha, "cv2.stereoRectify"
    )


def _rectify_fisheye(
    c1: Camera,
    c2: Camera,
    R: np.ndarray,
    T: np.ndarray,
    i: int,
    j: int,
    alpha: float,
    new_size: tuple[int, int] | None,
    zero_disparity: bool,
) -> Rectification:
    """``cv2.fisheye.stereoRectify`` of two fisheye cameras of one image size; the ROIs computed here."""
    import cv2

    size = (c1.width, c1.height)
    out = new_size or size
    R1, R2, P1, P2, Q = cv2.fisheye.stereoRectify(
        c1.K,
        c1.dist.reshape(4, 1),
        c2.K,
        c2.dist.reshape(4, 1),
        size,
        R,
        T.reshape(3, 1),
        cv2.CALIB_ZERO_DISPARITY if zero_disparity else 0,
        newImageSize=out,
        balance=max(alpha, 0.0),
        fov_scale=1.0,
    )
    roi1 = _roi(_rectangles(c1, R1, P1, _frame(c1, R1))[0], (0.0, 0.0), (0.0, 0.0), 1.0, out)
    roi2 = _roi(_rectangles(c2, R2, P2, _frame(c2, R2))[0], (0.0, 0.0), (0.0, 0.0), 1.0, out)
    return Rectification(i, j, R1, R2, P1, P2, Q, roi1, roi2, out, alpha, "cv2.fisheye.stereoRectify")


def _rectify_own(
    c1: Camera,
    c2: Camera,
    R: np.ndarray,
    T: np.ndarray,
    i: int,
    j: int,
    alpha: float,
    new_size: tuple[int, int] | None,
    zero_disparity: bool,
) -> Rectification:
    """OpenCV's ``stereoRectify`` algorithm with each camera's own image corners and any lens (see the module)."""
    import cv2

    size = (max(c1.width, c2.width), max(c1.height, c2.height))  # plays OpenCV's one imageSize
    new = new_size or size
    r_r = rodrigues(-0.5 * cv2.Rodrigues(R)[0].ravel())  # half the rotation each way
    t = r_r @ T
    idx = 0 if abs(t[0]) > abs(t[1]) else 1
    c, nt = t[idx], float(np.linalg.norm(t))
    uu = np.zeros(3)
    uu[idx] = 1.0 if c > 0 else -1.0
    ww = np.cross(t, uu)
    nw = float(np.linalg.norm(ww))
    if nw > 0:
        ww *= math.acos(min(abs(c) / nt, 1.0)) / nw
    wR = rodrigues(ww)
    Rk = (wR @ r_r.T, wR @ r_r)
    t_idx = float((Rk[1] @ T)[idx])
    ratio = (new[0] / size[0] if idx == 1 else new[1] / size[1]) / 2.0
    other = idx ^ 1
    fc = (c1.K[other, other] + c2.K[other, other]) * ratio
    cams = (c1, c2)
    frames = [_frame(cams[k], Rk[k]) for k in range(2)]
    cc = []
    for k in range(2):
        uv = _rectified_px(cams[k], Rk[k], fc, (0.0, 0.0), _grid(cams[k], frames[k], 2))
        avg = uv.mean(axis=0)
        cc.append([(size[0] - 1) / 2.0 - avg[0], (size[1] - 1) / 2.0 - avg[1]])
    cc_arr = np.array(cc)
    if zero_disparity:
        cc_arr[:] = cc_arr.mean(axis=0)
    else:
        cc_arr[:, other] = cc_arr[:, other].mean()
    P = [np.zeros((3, 4)) for _ in range(2)]
    for k in range(2):
        P[k][0, 0] = P[k][1, 1] = fc
        P[k][:2, 2] = cc_arr[k]
        P[k][2, 2] = 1.0
    rects = [_rectangles(cams[k], Rk[k], P[k], frames[k]) for k in range(2)]
    c0 = [tuple(cc_arr[k]) for k in range(2)]
    cn = [(new[0] * cc_arr[k, 0] / size[0], new[1] * cc_arr[k, 1] / size[1]) for k in range(2)]
    s = 1.0
    if alpha >= 0:
        s0 = max(_scale(rects[k][0], c0[k], cn[k], new, max) for k in range(2))
        s1 = min(_scale(rects[k][1], c0[k], cn[k], new, min) for k in range(2))
        s = s0 * (1.0 - alpha) + s1 * alpha
    fc *= s
    for k in range(2):
        P[k][0, 0] = P[k][1, 1] = fc
        P[k][:2, 2] = cn[k]
    P[1][idx, 3] = t_idx * fc
    rois = [_roi(rects[k][0], c0[k], cn[k], s, new) for k in range(2)]
    Q = np.array(
        [
            [1.0, 0.0, 0.0, -cn[0][0]],
            [0.0, 1.0, 0.0, -cn[0][1]],
            [0.0, 0.0, 0.0, fc],
            [0.0, 0.0, -1.0 / t_idx, (cn[0][idx] - cn[1][idx]) / t_idx],
        ]
    )
    return Rectification(i, j, Rk[0], Rk[1], P[0], P[1], Q, rois[0], rois[1], new, alpha, "circcal")


def _rectified_px(camera: Camera, Rk: np.ndarray, f: float, c: tuple[float, float], uv: np.ndarray) -> np.ndarray:
    """Pixels of ``camera`` -> the rectified camera (``Rk``, focal ``f``, centre ``c``); NaN behind it."""
    X = unproject(uv, camera) @ Rk.T
    z = np.where(X[:, 2] > 0, X[:, 2], np.nan)
    return np.stack([f * X[:, 0] / z + c[0], f * X[:, 1] / z + c[1]], axis=1)


def _grid(camera: Camera, frame: float, n: int) -> np.ndarray:
    """(n * n, 2) pixels: an n x n grid over the image (row-major, OpenCV's order), shrunk by ``frame`` about the
    principal point."""
    xs = np.arange(n) * (camera.width - 1) / (n - 1)
    ys = np.arange(n) * (camera.height - 1) / (n - 1)
    gx, gy = np.meshgrid(xs, ys)  # [row y, column x]
    if frame != 1.0:
        gx = camera.cx + frame * (gx - camera.cx)
        gy = camera.cy + frame * (gy - camera.cy)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def _frame(camera: Camera, Rk: np.ndarray) -> float:
    """The largest shrink factor in (0, 1] of the image about its principal point whose grid rays are all within
    :data:`MAX_RECTIFIED_ANGLE_DEG` of the rectified axis (1 for the whole image)."""
    cos_max = math.cos(math.radians(MAX_RECTIFIED_ANGLE_DEG))

    def inside(frame: float) -> bool:
        X = unproject(_grid(camera, frame, _GRID), camera) @ Rk.T
        with np.errstate(invalid="ignore"):
            return bool(np.all(X[:, 2] > cos_max * np.linalg.norm(X, axis=1)))

    if inside(1.0):
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if inside(mid) else (lo, mid)
    if lo <= 0.0:
        raise InputError("a camera's principal ray points away from the rectified cameras: no rectification")
    return lo


def _rectangles(
    camera: Camera, Rk: np.ndarray, P: np.ndarray, frame: float = 1.0
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """OpenCV's ``getUndistortRectangles``: the inner and outer ``(x, y, w, h)`` of the rectified image border (of
    the image shrunk by ``frame``, :func:`_frame`)."""
    uv = _rectified_px(camera, Rk, P[0, 0], (P[0, 2], P[1, 2]), _grid(camera, frame, _GRID))
    u, v = uv[:, 0].reshape(_GRID, _GRID), uv[:, 1].reshape(_GRID, _GRID)
    if not np.isfinite(uv).all():
        raise InputError("part of a camera's image is behind its rectified camera: no valid rectangle")
    ix0, ix1 = u[:, 0].max(), u[:, -1].min()
    iy0, iy1 = v[0, :].max(), v[-1, :].min()
    ox0, ox1, oy0, oy1 = u.min(), u.max(), v.min(), v.max()
    return (ix0, iy0, ix1 - ix0, iy1 - iy0), (ox0, oy0, ox1 - ox0, oy1 - oy0)


def _scale(
    rect: tuple[float, ...], c0: tuple[float, float], cn: tuple[float, float], new: tuple[int, int], pick: object
) -> float:
    """OpenCV's scale that maps ``rect`` (centred on ``c0``) onto the new image (centred on ``cn``): ``pick`` (max
    for the inner rectangle, min for the outer) of its four sides' ratios."""
    x, y, w, h = rect
    ratios = (
        cn[0] / (c0[0] - x),
        cn[1] / (c0[1] - y),
        (new[0] - 1 - cn[0]) / (x + w - c0[0]),
        (new[1] - 1 - cn[1]) / (y + h - c0[1]),
    )
    return float(pick(ratios))  # type: ignore[operator]


def _roi(
    inner: tuple[float, ...], c0: tuple[float, float], cn: tuple[float, float], s: float, new: tuple[int, int]
) -> tuple[int, int, int, int]:
    """OpenCV's valid ROI: the inner rectangle scaled by ``s`` about the centre, intersected with the image."""
    x0 = math.ceil((inner[0] - c0[0]) * s + cn[0])
    y0 = math.ceil((inner[1] - c0[1]) * s + cn[1])
    x1 = min(x0 + math.floor(inner[2] * s), new[0])
    y1 = min(y0 + math.floor(inner[3] * s), new[1])
    x0, y0 = max(x0, 0), max(y0, 0)
    if x1 <= x0 or y1 <= y0:
        return (0, 0, 0, 0)
    return (x0, y0, x1 - x0, y1 - y0)


def rectification_maps(
    rig: RigModel, rect: Rectification
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """``cv2.initUndistortRectifyMap`` (``cv2.fisheye``'s for a fisheye) of both cameras of ``rect``.

    Parameters
    ----------
    rig : RigModel
    rect : Rectification
        Of this rig (:func:`rectify_pair`).

    Returns
    -------
    tuple
        ``((map1x, map1y), (map2x, map2y))``: float32 arrays of shape (height, width) of ``rect.image_size``; the
        source pixel of each rectified pixel (for ``cv2.remap``).
    """
    import cv2

    maps = []
    for k, Rk, Pk in ((rect.i, rect.R1, rect.P1), (rect.j, rect.R2, rect.P2)):
        cam = rig.cameras[k]
        if cam.model.pinhole:
            mx, my = cv2.initUndistortRectifyMap(cam.K, cam.dist, Rk, Pk, rect.image_size, cv2.CV_32FC1)
        else:
            mx, my = cv2.fisheye.initUndistortRectifyMap(
                cam.K, cam.dist.reshape(4, 1), Rk, Pk, rect.image_size, cv2.CV_32FC1
            )
        maps.append((mx, my))
    return maps[0], maps[1]


def _as_bgr_u8(image: np.ndarray, what: str) -> np.ndarray:
    """An image as (H, W, 3) uint8 BGR (other depths stretched to their range)."""
    import cv2

    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)) or a.size == 0:
        raise ImageError(f"{what}: expected a grey or BGR(A) image, got an array of shape {a.shape}")
    if a.dtype != np.uint8:
        f = np.nan_to_num(a.astype(np.float64))
        lo, hi = float(f.min()), float(f.max())
        a = np.zeros(f.shape, np.uint8) if hi <= lo else ((f - lo) * (255.0 / (hi - lo))).astype(np.uint8)
    if a.ndim == 2:
        return cv2.cvtColor(a, cv2.COLOR_GRAY2BGR)
    return a[:, :, :3].copy()


def rectified_overlay(
    rig: RigModel,
    image_i: np.ndarray,
    image_j: np.ndarray,
    rect: Rectification | None = None,
    *,
    line_every: int = 32,
) -> np.ndarray:
    """The two images rectified side by side (one above the other for a vertical pair) with epipolar lines drawn.

    Parameters
    ----------
    rig : RigModel
    image_i, image_j : ndarray
        The images of cameras ``rect.i`` and ``rect.j`` (grey or BGR(A), any depth), each of its camera's size.
    rect : Rectification, optional
        Default :func:`rectify_pair` of cameras 0 and 1.
    line_every : int
        A line every this many px of the rectified images (rows; columns for a vertical pair).

    Returns
    -------
    ndarray, shape (H, 2 W, 3) or (2 H, W, 3)
        uint8 BGR.

    Raises
    ------
    ImageError
        An image that is not of its camera's size, or not an image.
    InputError
        ``line_every`` not a positive integer.
    """
    import cv2

    if isinstance(line_every, bool) or not isinstance(line_every, (int, np.integer)) or line_every <= 0:
        raise InputError(f"line_every must be a positive integer (px), got {line_every!r}")
    rect = rect or rectify_pair(rig)
    out = []
    for k, img, maps in zip((rect.i, rect.j), (image_i, image_j), rectification_maps(rig, rect)):
        cam, name = rig.cameras[k], rig.names[k]
        bgr = _as_bgr_u8(img, f"camera {name!r}'s image")
        if bgr.shape[:2] != (cam.height, cam.width):
            raise ImageError(
                f"camera {name!r}'s image is {bgr.shape[1]}x{bgr.shape[0]} px, its camera {cam.width}x{cam.height}"
            )
        out.append(cv2.remap(bgr, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT))
    vertical = rect.vertical
    both = np.vstack(out) if vertical else np.hstack(out)
    w, h = rect.image_size
    colour = (0, 255, 0)
    if vertical:
        for x in range(0, w, int(line_every)):
            both[:, x] = colour
    else:
        for y in range(0, h, int(line_every)):
            both[y, :] = colour
    return both


def write_rectified_overlay(
    path: str | Path,
    rig: RigModel,
    image_i: str | Path,
    image_j: str | Path,
    rect: Rectification | None = None,
    *,
    line_every: int = 32,
) -> Path:
    """:func:`rectified_overlay` of two image files, written as PNG atomically (parent folders created).

    Parameters
    ----------
    path : str or Path
        The PNG to write.
    rig : RigModel
    image_i, image_j : str or Path
        Image files of cameras ``rect.i`` and ``rect.j``.
    rect : Rectification, optional
        Default :func:`rectify_pair` of cameras 0 and 1.
    line_every : int
        px between the epipolar lines.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ImageError
        An image file missing, unreadable as an image, or not of its camera's size.
    OSError
        ``path`` cannot be written.
    """
    import cv2

    images = []
    for f in (image_i, image_j):
        img = read_image(Path(f))
        if img is None:
            raise ImageError(f"{f}: no image (missing, empty, or not an image file)")
        images.append(img)
    vis = rectified_overlay(rig, images[0], images[1], rect, line_every=line_every)
    ok, png = cv2.imencode(".png", vis)
    if not ok:
        raise RuntimeError(f"OpenCV could not encode the rectified overlay for {path}")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_bytes(out, png.tobytes())
    return out
