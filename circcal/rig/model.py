"""A calibrated rig of cameras: every camera's intrinsics and its pose in the rig (camera 0 the reference).

Conventions (written once; ARCHITECTURE.md and docs/rigs.md point here)
------------------------------------------------------------------------
* Camera 0 is the reference: the rig frame is camera 0's frame (OpenCV's camera frame: x right, y down, z forward).
* Camera ``i``'s pose ``(R_i, T_i)`` maps a point from the rig frame into camera ``i``'s frame:
  ``X_i = R_i X_0 + T_i``. For a pair this is OpenCV's ``stereoCalibrate`` convention (``X_2 = R X_1 + T``) and
  mrcal's ``extrinsics_rt_fromref``. Camera 0's pose is the identity.
* ``T`` is in the board's unit, mm (the pitch's unit); the OpenCV stereo YAML writes ``T`` in the pitch's unit too.
* A board pose per instant ``(rvec, tvec)`` maps board points into the rig frame: ``X_0 = R(rvec) P + tvec``.
* Instants are matched across cameras by image file name (the same name = the same instant;
  :mod:`circcal.rig.instants`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from circcal.errors import InputError
from circcal.formats.limits import check_camera, number
from circcal.model import Camera
from circcal.rotation import rodrigues

__all__ = ["RigModel", "relative_pose"]


#: Bounds of a rig model file's poses and noise: far outside any rig (a rotation vector's components are at most
#: pi for a rotation written the usual way; 1000 km; 1e6 px), they keep a damaged file from reaching the math.
MAX_RVEC = 1e3
MAX_TVEC_MM = 1e9
MAX_RMS_PX = 1e6
#: Relative rounding a covariance read back may carry (to_dict writes a symmetric matrix in full precision).
COVARIANCE_RTOL = 1e-9


@dataclass(frozen=True)
class RigModel:
    """Cameras with their intrinsics and their poses in the rig.

    Parameters
    ----------
    names : sequence of str
        One distinct name per camera; ``names[0]`` is the reference camera.
    cameras : sequence of Camera
        Each camera's intrinsics (any image size and lens model).
    rvecs, tvecs : array_like, shape (n_cameras, 3)
        Camera ``i``'s pose in the rig: ``X_i = R(rvecs[i]) X_0 + tvecs[i]`` (rad, mm); row 0 is zero.
    covariance : ndarray, shape (n, n), optional
        First-order covariance of the state ``state_vector()`` (every camera's intrinsics in
        ``Camera.intrinsics()`` order, then every camera's ``rvec, tvec`` but camera 0's); None when not computed.
    rms_px : float, optional
        RMS reprojection error per point over every camera (2-D norm, OpenCV's convention), px.

    Raises
    ------
    InputError
        Names repeated or empty, lengths that differ, non-finite poses, or a reference camera whose pose is not the
        identity.

    Examples
    --------
    >>> cam = Camera(640, 480, 500.0, 500.0, 319.5, 239.5)
    >>> rig = RigModel(["left", "right"], [cam, cam], [[0, 0, 0], [0, 0, 0]], [[0, 0, 0], [-60, 0, 0]])
    >>> rig.baseline_mm()
    60.0
    """

    names: tuple[str, ...]
    cameras: tuple[Camera, ...]
    rvecs: np.ndarray
    tvecs: np.ndarray
    covariance: np.ndarray | None = field(default=None, compare=False)
    rms_px: float | None = None

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.names)
        cams = tuple(self.cameras)
        if len(names) < 1 or len(names) != len(cams):
            raise InputError(f"a rig needs one name per camera, got {len(names)} names for {len(cams)} cameras")
        if len(set(names)) != len(names) or any(not n for n in names):
            raise InputError(f"rig camera names must be distinct and non-empty, got {list(names)}")
        r = np.asarray(self.rvecs, dtype=np.float64).reshape(-1, 3)
        t = np.asarray(self.tvecs, dtype=np.float64).reshape(-1, 3)
        if len(r) != len(cams) or len(t) != len(cams):
            raise InputError(f"a rig needs one pose per camera, got {len(r)} rotations and {len(t)} translations")
        if not (np.isfinite(r).all() and np.isfinite(t).all()):
            raise InputError("rig camera poses must be finite")
        if np.any(r[0] != 0) or np.any(t[0] != 0):
            raise InputError(f"the reference camera {names[0]!r} must have the identity pose")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "cameras", cams)
        object.__setattr__(self, "rvecs", r)
        object.__setattr__(self, "tvecs", t)

    @property
    def n_cameras(self) -> int:
        """The number of cameras."""
        return len(self.cameras)

    def index(self, name: str) -> int:
        """The index of the camera named ``name``.

        Parameters
        ----------
        name : str

        Returns
        -------
        int

        Raises
        ------
        InputError
            No camera of that name.
        """
        if name not in self.names:
            raise InputError(f"no camera {name!r} in the rig (cameras: {', '.join(self.names)})")
        return self.names.index(name)

    def pose(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Camera ``i``'s rotation matrix and translation: ``X_i = R X_0 + T``.

        Parameters
        ----------
        i : int

        Returns
        -------
        R : ndarray, shape (3, 3)
        T : ndarray, shape (3,)
            mm.
        """
        return rodrigues(self.rvecs[i]), self.tvecs[i].copy()

    def pair(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """The relative pose from camera ``i`` to camera ``j``: ``X_j = R X_i + T`` (OpenCV's stereo ``R, T``).

        Parameters
        ----------
        i, j : int

        Returns
        -------
        R : ndarray, shape (3, 3)
        T : ndarray, shape (3,)
            mm.
        """
        Ri, Ti = self.pose(i)
        Rj, Tj = self.pose(j)
        return relative_pose(Ri, Ti, Rj, Tj)

    def baseline_mm(self, i: int = 0, j: int = 1) -> float:
        """The distance between the optical centres of cameras ``i`` and ``j``.

        Parameters
        ----------
        i, j : int

        Returns
        -------
        float
            mm.
        """
        return float(np.linalg.norm(self.pair(i, j)[1]))

    def state_vector(self) -> np.ndarray:
        """Every camera's intrinsics, then every camera's pose but the reference's (rvec, tvec).

        Returns
        -------
        ndarray, shape (sum(n_intrinsics) + 6 (n_cameras - 1),)
            The order of ``covariance``'s rows.
        """
        parts = [c.intrinsics for c in self.cameras]
        parts += [np.concatenate([self.rvecs[i], self.tvecs[i]]) for i in range(1, self.n_cameras)]
        return np.concatenate(parts)

    def to_dict(self) -> dict[str, Any]:
        """circcal's rig model JSON (``calibrate-rig --out rig.json``).

        Returns
        -------
        dict
            ``format`` ("circcal-rig"), ``version`` 1, ``cameras``: a list of ``{name, camera, rvec, tvec}`` (the
            camera block of model.json; the pose ``X_i = R(rvec) X_0 + tvec``, rad and mm), ``rms_px`` and
            ``covariance`` (the state's, or null).
        """
        return {
            "format": "circcal-rig",
            "version": 1,
            "convention": "X_camera = R(rvec) X_reference + tvec; camera 0 is the reference; mm",
            "cameras": [
                {"name": n, "camera": c.to_dict(), "rvec": self.rvecs[i].tolist(), "tvec": self.tvecs[i].tolist()}
                for i, (n, c) in enumerate(zip(self.names, self.cameras))
            ],
            "rms_px": self.rms_px,
            "covariance": None if self.covariance is None else np.asarray(self.covariance).tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RigModel:
        """Read :meth:`to_dict`'s form.

        Parameters
        ----------
        d : dict

        Returns
        -------
        RigModel

        Raises
        ------
        InputError
            Not a circcal rig, a missing field (named), or a value the rig or a camera refuses.
        """
        if not isinstance(d, dict) or d.get("format") != "circcal-rig":
            raise InputError("not a circcal rig model (its 'format' must be 'circcal-rig')")
        cams = d.get("cameras")
        if not isinstance(cams, list) or not cams:
            raise InputError("a rig model's 'cameras' must be a non-empty list")
        for k, c in enumerate(cams):
            if not isinstance(c, dict) or not {"name", "camera", "rvec", "tvec"} <= set(c):
                raise InputError(f"rig camera {k} must hold name, camera, rvec and tvec")
        if d.get("version", 1) != 1:
            raise InputError(f"rig model version {d.get('version')!r}: this circcal reads version 1")
        cov = d.get("covariance")
        rms = d.get("rms_px")
        if rms is not None and number(rms, "rig rms_px", 0.0, MAX_RMS_PX, " px") <= 0:
            raise InputError("rig rms_px must be a positive number of px, got 0")
        rvecs, tvecs = _vectors([c["rvec"] for c in cams], "rvec"), _vectors([c["tvec"] for c in cams], "tvec")
        for k in range(len(cams)):
            if np.max(np.abs(rvecs[k])) > MAX_RVEC or np.max(np.abs(tvecs[k])) > MAX_TVEC_MM:
                raise InputError(
                    f"rig camera {k}: rvec components must be within {MAX_RVEC:g} rad and tvec's within "
                    f"{MAX_TVEC_MM:g} mm, got {rvecs[k].tolist()}, {tvecs[k].tolist()}"
                )
        rig = cls(
            [c["name"] for c in cams],
            [check_camera(Camera.from_dict(c["camera"])) for c in cams],
            rvecs,
            tvecs,
            None if cov is None else _matrix(cov),
            None if rms is None else float(rms),
        )
        if rig.covariance is not None and rig.covariance.shape != (len(rig.state_vector()),) * 2:
            raise InputError(f"rig covariance must be {len(rig.state_vector())} x {len(rig.state_vector())}")
        return rig


def relative_pose(Ri: np.ndarray, Ti: np.ndarray, Rj: np.ndarray, Tj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pose of camera ``j`` relative to camera ``i``, both given in one frame (``X_k = R_k X + T_k``).

    Parameters
    ----------
    Ri, Rj : ndarray, shape (3, 3)
    Ti, Tj : ndarray, shape (3,)

    Returns
    -------
    R : ndarray, shape (3, 3)
        ``X_j = R X_i + T``.
    T : ndarray, shape (3,)
    """
    R = Rj @ Ri.T
    return R, Tj - R @ Ti


def _vectors(rows: Sequence[Any], what: str) -> np.ndarray:
    """(n, 3) finite floats from a list of 3-lists, or InputError naming ``what``."""
    try:
        a = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"rig {what}s must be lists of 3 numbers") from None
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"rig {what}s must be lists of 3 numbers, got shape {a.shape}")
    return a


def _matrix(rows: Any) -> np.ndarray:
    """A covariance: a finite, symmetric square float matrix, variances >= 0 and correlations within +-1 (what a
    covariance must be; not a full test of positive semi-definiteness), or InputError."""
    try:
        a = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("rig covariance must be a square matrix of numbers") from None
    if a.ndim != 2 or a.shape[0] != a.shape[1] or not np.isfinite(a).all():
        raise InputError("rig covariance must be a square matrix of finite numbers")
    scale = float(np.max(np.abs(np.diag(a)))) if a.size else 0.0
    if np.any(np.diag(a) < 0) or not np.allclose(a, a.T, rtol=COVARIANCE_RTOL, atol=COVARIANCE_RTOL * scale):
        raise InputError("rig covariance must be symmetric with a non-negative diagonal (a covariance)")
    # positive semi-definite up to rounding: its variances scale the correlations' bound |C_ij| <= sqrt(C_ii C_jj)
    sd = np.sqrt(np.diag(a))
    if np.any(np.abs(a) > np.outer(sd, sd) * (1 + COVARIANCE_RTOL) + COVARIANCE_RTOL * scale):
        raise InputError("rig covariance is not a covariance: a correlation beyond +-1")
    return a
