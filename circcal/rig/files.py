"""A rig in other tools' files, each written and read back: OpenCV's stereo YAML, a ROS camera_info pair, one mrcal
``.cameramodel`` per camera, Kalibr's camchain YAML.

Conventions, per format (the rig's own: :mod:`circcal.rig.model`, ``X_i = R_i X_0 + T_i``, mm)
----------------------------------------------------------------------------------------------
* **OpenCV stereo YAML** (:func:`opencv_stereo_text`), as OpenCV's ``samples/cpp/stereo_calib.cpp`` writes its
  intrinsics.yml and extrinsics.yml, in one ``cv2.FileStorage`` file: ``M1, D1, M2, D2`` (camera matrices and
  distortion vectors: 1xN of the pinhole models, the 4x1 ``D`` of cv2.fisheye), ``R, T`` with ``X_2 = R X_1 + T``
  (``stereoCalibrate``'s), ``T`` in the pitch's unit (mm); ``E = [T]x R`` and ``F = K2^-T E K1^-1`` scaled to
  ``F[2, 2] = 1`` (``stereoCalibrate``'s); ``R1, R2, P1, P2, Q`` of :func:`circcal.rig.rectify.rectify_pair`.
  circcal adds what the sample leaves out and a reader needs: ``image_width1``, ``image_height1``,
  ``image_width2``, ``image_height2``, ``camera_name1``, ``camera_name2`` and ``fisheye_model1`` /
  ``fisheye_model2`` (1 for a cv2.fisheye camera, as OpenCV's calibration sample marks one).
* **ROS camera_info pair** (:func:`ros_camera_info_pair`): camera_calibration_parsers' YAML of each camera
  (:func:`circcal.formats.camera_to_ros_yaml`) with ``rectification_matrix`` R1 / R2 and ``projection_matrix``
  P1 / P2 of the rectification. ROS lengths are metres (REP 103): P2's last column, ``Tx = -fx' B``, is in px m
  (OpenCV's P2 with its mm made metres), as stereo_image_proc expects.
* **mrcal** (:func:`mrcal_cameramodel_texts`): one ``.cameramodel`` per camera, ``extrinsics`` = ``rt_cam_ref``
  (``rt_fromref``: ``X_cam = R(r) X_ref + t``, the rig's convention, camera 0 the reference), ``t`` in metres
  (mrcal's convention, as :mod:`circcal.formats.cameramodel_export`). ``LENSMODEL_OPENCV5/8/12``; mrcal has no
  cv2.fisheye model, so a rig with a fisheye is refused (:data:`circcal.formats.mrcal.MRCAL_LENSMODELS`).
  :func:`circcal.formats.camera_to_cameramodel` writes identity extrinsics only, so the file is written here in its
  layout. Reading takes any reference: the cameras are re-referenced to the first one given.
* **Kalibr camchain** (:func:`kalibr_camchain_text`): ``cam0 .. camN``, each with ``camera_model: pinhole``,
  ``intrinsics [fu, fv, pu, pv]``, ``distortion_model`` ``radtan`` (``[k1, k2, r1, r2]``: OpenCV's ``k1, k2, p1,
  p2``) or ``equidistant`` (``[k1, k2, k3, k4]``: cv2.fisheye's), ``distortion_coeffs``, ``resolution [w, h]``
  and, for n >= 1, ``T_cn_cnm1`` (4x4: camera n-1's frame -> camera n's, ``X_n = T X_{n-1}``), metres
  (Kalibr's). A pinhole camera with k3 (or k4..k6, s1..s4) nonzero has no Kalibr model and is refused.

Readers check every value and raise :class:`~circcal.errors.ModelFileError` naming the field.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from circcal.errors import InputError, ModelFileError
from circcal.formats import camera_from_cameramodel, camera_from_K_dist, camera_from_ros_yaml, camera_to_ros_yaml
from circcal.formats.limits import (
    MAX_MODEL_FILE_BYTES,
    integer,
    load_yaml,
    matrix,
    number_list,
    show,
)
from circcal.formats.mrcal import MRCAL_LENSMODELS, MRCAL_UNSUPPORTED, parse_cameramodel
from circcal.formats.opencv import open_filestorage
from circcal.jsonio import read_text
from circcal.rig.model import RigModel, relative_pose
from circcal.rig.rectify import Rectification, rectify_pair
from circcal.rotation import rodrigues, skew

__all__ = [
    "M_PER_MM",
    "essential_fundamental",
    "opencv_stereo_text",
    "opencv_stereo_from_text",
    "read_opencv_stereo",
    "ros_camera_info_pair",
    "read_ros_pair",
    "mrcal_cameramodel_texts",
    "read_mrcal_cameramodels",
    "kalibr_camchain_text",
    "read_kalibr_camchain",
]

#: The rig's mm in the metres of ROS, mrcal and Kalibr.
M_PER_MM = 1e-3
#: How far a file's rotation matrix may be from orthonormal (max |R^T R - I|): files carry ~9 digits at least.
_ROTATION_TOL = 1e-6


def essential_fundamental(rig: RigModel, i: int = 0, j: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The essential and fundamental matrices of the pair ``(i, j)``, as ``cv2.stereoCalibrate`` returns them.

    Parameters
    ----------
    rig : RigModel
    i, j : int
        OpenCV's first and second camera (``X_j = R X_i + T``).

    Returns
    -------
    E : ndarray, shape (3, 3)
        ``[T]x R`` (T in mm): ``x_j^T E x_i = 0`` for normalised undistorted coordinates.
    F : ndarray, shape (3, 3)
        ``K_j^-T E K_i^-1`` scaled to ``F[2, 2] = 1`` (unscaled when that entry is 0): ``u_j^T F u_i = 0`` for
        undistorted pixels.
    """
    R, T = rig.pair(i, j)
    E = skew(T) @ R
    F = np.linalg.inv(rig.cameras[j].K).T @ E @ np.linalg.inv(rig.cameras[i].K)
    if F[2, 2] != 0:
        F = F / F[2, 2]
    return E, F


def _rig_index(rig: RigModel, k: int, what: str) -> int:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < rig.n_cameras:
        raise InputError(f"{what} must be a camera index 0..{rig.n_cameras - 1} of the rig, got {k!r}")
    return int(k)


def opencv_stereo_text(rig: RigModel, i: int = 0, j: int = 1, alpha: float = -1.0) -> str:
    """OpenCV's stereo YAML of the pair ``(i, j)`` (see the module for its nodes).

    Parameters
    ----------
    rig : RigModel
    i, j : int
        The file's cameras 1 and 2.
    alpha : float
        The rectification's free scaling (:func:`~circcal.rig.rectify.rectify_pair`).

    Returns
    -------
    str
        ``cv2.FileStorage`` YAML.

    Raises
    ------
    InputError
        Cameras that are not two different ones of the rig, or a rectification refused (see ``rectify_pair``).
    """
    import cv2

    i, j = _rig_index(rig, i, "camera i"), _rig_index(rig, j, "camera j")
    rect = rectify_pair(rig, i, j, alpha)
    R, T = rig.pair(i, j)
    E, F = essential_fundamental(rig, i, j)
    fs = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    for n, k in ((1, i), (2, j)):
        cam = rig.cameras[k]
        fs.write(f"M{n}", cam.K)
        fs.write(f"D{n}", cam.dist.reshape(1, -1) if cam.model.pinhole else cam.dist.reshape(-1, 1))
    for key, value in (("R", R), ("T", T.reshape(3, 1)), ("E", E), ("F", F)):
        fs.write(key, value)
    for key in ("R1", "R2", "P1", "P2", "Q"):
        fs.write(key, np.asarray(getattr(rect, key), dtype=np.float64))
    for n, k in ((1, i), (2, j)):
        cam = rig.cameras[k]
        fs.write(f"image_width{n}", int(cam.width))
        fs.write(f"image_height{n}", int(cam.height))
        fs.write(f"camera_name{n}", rig.names[k])
        if not cam.model.pinhole:
            fs.write(f"fisheye_model{n}", 1)
    return str(fs.releaseAndGetString())


def _fs_mat(fs: Any, key: str, shapes: tuple[tuple[int, int], ...]) -> np.ndarray:
    """The FileStorage matrix ``key`` of one of ``shapes``, finite; ModelFileError naming it otherwise."""
    node = fs.getNode(key)
    if node.empty():
        raise ModelFileError(f"OpenCV stereo file: no {key} node")
    m = node.mat()
    if m is None or not isinstance(m, np.ndarray):
        raise ModelFileError(f"OpenCV stereo file: {key} must be an opencv-matrix")
    m = np.asarray(m, dtype=np.float64)
    if m.ndim == 1:
        m = m.reshape(-1, 1)
    if m.ndim != 2 or m.shape not in shapes:
        raise ModelFileError(
            f"OpenCV stereo file: {key} must be {' or '.join(f'{r}x{c}' for r, c in shapes)}, got {m.shape}"
        )
    if not np.isfinite(m).all():
        raise ModelFileError(f"OpenCV stereo file: {key} must hold finite numbers")
    return m


def _fs_value(fs: Any, key: str) -> Any:
    """A FileStorage scalar (number or string), or None when the node is missing."""
    node = fs.getNode(key)
    if node.empty():
        return None
    if node.isInt() or node.isReal():
        return node.real()
    if node.isString():
        return node.string()
    return "<not a scalar>"


def _rotation(R: np.ndarray, field: str) -> np.ndarray:
    """``R`` checked to be a rotation matrix (orthonormal, det +1) within :data:`_ROTATION_TOL`."""
    if R.shape != (3, 3) or not np.isfinite(R).all():
        raise ModelFileError(f"{field} must be a 3x3 matrix of finite numbers")
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if err > _ROTATION_TOL or np.linalg.det(R) <= 0:
        raise ModelFileError(f"{field} is not a rotation matrix (|R^T R - I| = {err:.2g}, det {np.linalg.det(R):.6g})")
    return R


def _rvec(R: np.ndarray) -> np.ndarray:
    """The axis-angle vector of a rotation matrix (rad)."""
    import cv2

    return np.asarray(cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0], dtype=np.float64).ravel()


def opencv_stereo_from_text(text: str) -> RigModel:
    """The two-camera rig of OpenCV's stereo YAML (:func:`opencv_stereo_text`'s, or the stereo_calib sample's with
    the image sizes added).

    The rig is ``M1, D1, M2, D2, R, T`` (``X_2 = R X_1 + T``, T in mm) and the image sizes; E, F and the
    rectification are derived from them, and ignored here.

    Parameters
    ----------
    text : str
        ``cv2.FileStorage`` YAML (or XML).

    Returns
    -------
    RigModel
        Cameras named by ``camera_name1`` / ``camera_name2`` (default ``camera1``, ``camera2``).

    Raises
    ------
    ModelFileError
        A missing node or image size, a matrix of the wrong shape, a value that is not finite, an R that is not a
        rotation, or a camera :func:`circcal.formats.camera_from_K_dist` refuses.
    """
    fs = open_filestorage(text)
    try:
        cams, names = [], []
        for n in (1, 2):
            K = _fs_mat(fs, f"M{n}", ((3, 3),))
            fisheye = _fs_value(fs, f"fisheye_model{n}")
            fish = fisheye is not None and integer(fisheye, f"fisheye_model{n}", 0, 1) == 1
            D = _fs_mat(fs, f"D{n}", tuple((1, s) for s in range(0, 15)) + tuple((s, 1) for s in range(1, 15)))
            w, h = _fs_value(fs, f"image_width{n}"), _fs_value(fs, f"image_height{n}")
            if w is None or h is None:
                raise ModelFileError(
                    f"OpenCV stereo file: no image_width{n} / image_height{n} (camera {n}'s image size is needed)"
                )
            cams.append(
                camera_from_K_dist(w, h, K, D.ravel(), f"OpenCV stereo camera {n}", lens="fisheye" if fish else None)
            )
            name = _fs_value(fs, f"camera_name{n}")
            names.append(name if isinstance(name, str) and name else f"camera{n}")
        R = _rotation(_fs_mat(fs, "R", ((3, 3),)), "OpenCV stereo file: R")
        T = _fs_mat(fs, "T", ((3, 1), (1, 3))).ravel()
    finally:
        fs.release()
    if names[0] == names[1]:
        names = [f"{names[0]}1", f"{names[1]}2"]
    return RigModel(names, cams, [np.zeros(3), _rvec(R)], [np.zeros(3), T])


def read_opencv_stereo(path: str | Path) -> RigModel:
    """:func:`opencv_stereo_from_text` of a file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    RigModel

    Raises
    ------
    InputError
        The file missing or unreadable; :class:`ModelFileError` (naming the file) for its content.
    """
    text = read_text(path, "OpenCV stereo file", max_bytes=MAX_MODEL_FILE_BYTES)
    try:
        return opencv_stereo_from_text(text)
    except InputError as exc:  # the file's checks, and a camera's own (a focal length that is not positive)
        raise ModelFileError(f"{path}: {exc}") from None


def ros_camera_info_pair(
    rig: RigModel, i: int = 0, j: int = 1, alpha: float = -1.0, *, rect: Rectification | None = None
) -> tuple[str, str]:
    """ROS camera_info YAML of the pair's two cameras with the rectification (see the module).

    Parameters
    ----------
    rig : RigModel
    i, j : int
        The left (first) and right (second) camera.
    alpha : float
        The rectification's free scaling (:func:`~circcal.rig.rectify.rectify_pair`).
    rect : Rectification, optional
        A rectification of ``(i, j)`` already made (``alpha`` is then unused).

    Returns
    -------
    left, right : str
        camera_calibration_parsers YAML texts.

    Raises
    ------
    InputError
        A thin-prism camera (ROS has no such model), or a rectification refused.
    """
    import yaml

    i, j = _rig_index(rig, i, "camera i"), _rig_index(rig, j, "camera j")
    rect = rect if rect is not None else rectify_pair(rig, i, j, alpha)
    if (rect.i, rect.j) != (i, j):
        raise InputError(f"the rectification given is of cameras ({rect.i}, {rect.j}), not ({i}, {j})")
    texts = []
    for k, Rk, Pk in ((i, rect.R1, rect.P1), (j, rect.R2, rect.P2)):
        doc = yaml.safe_load(camera_to_ros_yaml(rig.cameras[k], rig.names[k]))
        P = np.array(Pk, dtype=np.float64)
        P[:, 3] *= M_PER_MM
        doc["rectification_matrix"]["data"] = [float(v) for v in np.ravel(Rk)]
        doc["projection_matrix"]["data"] = [float(v) for v in P.ravel()]
        texts.append(str(yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)))
    return texts[0], texts[1]


def _ros_matrix(d: Any, key: str, msg_key: str, shape: tuple[int, int], which: str) -> np.ndarray:
    """A matrix of a ROS camera_info document in either layout."""
    field = f"ROS camera_info ({which}) {key}"
    v = d.get(key, d.get(msg_key))
    if v is None:
        raise ModelFileError(f"{field}: missing (the rectification needs it)")
    if isinstance(v, dict):
        if "data" not in v:
            raise ModelFileError(f"{field} has no data")
        return matrix(v["data"], field, shape, v.get("rows"), v.get("cols"))
    return matrix(v, field, shape)


def read_ros_pair(left: str, right: str) -> RigModel:
    """The two-camera rig of a ROS camera_info pair (:func:`ros_camera_info_pair`'s, or any rectified pair).

    The pose from the rectification: ``X_2 = R2^T (R1 X_1 + b)``, ``b = P2[:, 3] / P2[0, 0]`` (metres, made mm),
    with ``P1[:, 3] = 0``.

    Parameters
    ----------
    left, right : str
        camera_info YAML texts.

    Returns
    -------
    RigModel
        Cameras named by ``camera_name`` (default ``left``, ``right``).

    Raises
    ------
    ModelFileError
        A text :func:`circcal.formats.camera_from_ros_yaml` refuses, a missing or malformed R or P, R that are not
        rotations, a left P with a translation, or a P with no focal length.
    """
    cams, names, Rs, Ps = [], [], [], []
    for text, which in ((left, "left"), (right, "right")):
        cams.append(camera_from_ros_yaml(text))
        d = load_yaml(text)
        name = d.get("camera_name")
        names.append(name if isinstance(name, str) and name else which)
        Rs.append(_rotation(_ros_matrix(d, "rectification_matrix", "R", (3, 3), which), f"ROS camera_info ({which}) R"))
        Ps.append(_ros_matrix(d, "projection_matrix", "P", (3, 4), which))
    if np.any(Ps[0][:, 3] != 0):
        raise ModelFileError(f"ROS camera_info (left) P: its last column must be 0, got {Ps[0][:, 3].tolist()}")
    f = Ps[1][0, 0]
    if not f > 0:
        raise ModelFileError(f"ROS camera_info (right) P: fx' must be positive, got {f}")
    b = Ps[1][:, 3] / f / M_PER_MM
    R = Rs[1].T @ Rs[0]
    T = Rs[1].T @ b
    if names[0] == names[1]:
        names = ["left", "right"]
    return RigModel(names, cams, [np.zeros(3), _rvec(R)], [np.zeros(3), T])


def mrcal_cameramodel_texts(rig: RigModel) -> dict[str, str]:
    """One mrcal ``.cameramodel`` per camera, with its extrinsics (``rt_cam_ref``, metres; see the module).

    Parameters
    ----------
    rig : RigModel

    Returns
    -------
    dict
        Camera name -> ``.cameramodel`` text.

    Raises
    ------
    InputError
        A camera of a lens model mrcal lacks (the fisheye), with the reason.
    """
    out = {}
    for k, (name, cam) in enumerate(zip(rig.names, rig.cameras)):
        if cam.lens not in MRCAL_LENSMODELS:
            raise InputError(
                f"cannot write camera {name!r} ({cam.lens}) as a mrcal .cameramodel: {MRCAL_UNSUPPORTED[cam.lens]}"
            )
        intr = ", ".join(repr(float(v)) for v in cam.intrinsics)
        rt = ", ".join(repr(float(v)) for v in np.concatenate([rig.rvecs[k], rig.tvecs[k] * M_PER_MM]))
        out[name] = (
            f"# generated by circcal: camera {name!r} of a rig of {rig.n_cameras}; the reference is "
            f"{rig.names[0]!r}\n"
            "# intrinsics are fx,fy,cx,cy,distortion0,distortion1,....\n"
            "# extrinsics are rt_fromref (X_cam = R(r) X_ref + t), t in metres\n"
            "{\n"
            f"    'lensmodel':  '{MRCAL_LENSMODELS[cam.lens]}',\n"
            f"    'intrinsics': [ {intr},],\n"
            f"    'extrinsics': [ {rt},],\n"
            f"    'imagersize': [ {int(cam.width)}, {int(cam.height)} ],\n"
            "}\n"
        )
    return out


def read_mrcal_cameramodels(texts: Mapping[str, str]) -> RigModel:
    """The rig of mrcal ``.cameramodel`` files with extrinsics (``rt_fromref``, metres), re-referenced to the first.

    Parameters
    ----------
    texts : mapping
        Camera name -> ``.cameramodel`` text, the reference camera first.

    Returns
    -------
    RigModel

    Raises
    ------
    ModelFileError
        A file :func:`circcal.formats.camera_from_cameramodel` refuses, or extrinsics that are not 6 finite numbers.
    InputError
        No files.
    """
    if not texts:
        raise InputError("a rig needs at least one .cameramodel")
    names, cams, Rs, ts = [], [], [], []
    for name, text in texts.items():
        try:
            cams.append(camera_from_cameramodel(text))
            d = parse_cameramodel(text)
            rt = number_list(d.get("extrinsics", [0.0] * 6), "'extrinsics'", 6)
        except ModelFileError as exc:
            raise ModelFileError(f"camera {name!r}: {exc}") from None
        names.append(name)
        Rs.append(rodrigues(rt[:3]))
        ts.append(rt[3:] / M_PER_MM)
    rvecs, tvecs = [np.zeros(3)], [np.zeros(3)]
    for k in range(1, len(cams)):
        R, T = relative_pose(Rs[0], ts[0], Rs[k], ts[k])
        rvecs.append(_rvec(R))
        tvecs.append(T)
    return RigModel(names, cams, rvecs, tvecs)


#: circcal's lens -> Kalibr's distortion model.
_KALIBR_MODELS = {"fisheye": "equidistant"}


def kalibr_camchain_text(rig: RigModel) -> str:
    """Kalibr's camchain YAML of the rig (see the module).

    Parameters
    ----------
    rig : RigModel

    Returns
    -------
    str

    Raises
    ------
    InputError
        A camera Kalibr cannot represent: a pinhole lens with k3 or a higher coefficient nonzero (radtan holds k1, k2,
        p1, p2 only).
    """
    import yaml

    doc: dict[str, Any] = {}
    beyond = {
        name: {n: float(v) for n, v in zip(cam.model.dist_names[4:], cam.dist[4:]) if v != 0}
        for name, cam in zip(rig.names, rig.cameras)
        if cam.model.pinhole
    }
    blocks = [
        f"camera {name!r} has {', '.join(f'{n} = {v:.6g}' for n, v in e.items())}" for name, e in beyond.items() if e
    ]
    if blocks:  # every camera that blocks it, at once
        raise InputError(
            f"Kalibr's radtan model holds k1, k2, p1, p2 only: {'; '.join(blocks)} (calibrate each as opencv5 with "
            f"k3 held at 0: calibrate-rig's --lens NAME=opencv5 --fix-k3 NAME)"
        )
    for k, (name, cam) in enumerate(zip(rig.names, rig.cameras)):
        if cam.model.pinhole:
            model, coeffs = "radtan", cam.dist[:4]
        else:
            model, coeffs = _KALIBR_MODELS[cam.lens], cam.dist
        entry: dict[str, Any] = {}
        if k > 0:
            R, T = rig.pair(k - 1, k)
            M = np.eye(4)
            M[:3, :3], M[:3, 3] = R, T * M_PER_MM
            entry["T_cn_cnm1"] = [[float(v) for v in row] for row in M]
        entry.update(
            {
                "camera_model": "pinhole",
                "intrinsics": [float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)],
                "distortion_model": model,
                "distortion_coeffs": [float(v) for v in coeffs],
                "resolution": [int(cam.width), int(cam.height)],
                "rostopic": f"/{name}/image_raw",
            }
        )
        doc[f"cam{k}"] = entry
    return str(yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))


def read_kalibr_camchain(text: str) -> RigModel:
    """The rig of a Kalibr camchain YAML (pinhole cameras, ``radtan`` or ``equidistant``).

    Parameters
    ----------
    text : str

    Returns
    -------
    RigModel
        Cameras named ``cam0``, ``cam1``, ... (the file's keys), chained by ``T_cn_cnm1`` (metres, made mm).

    Raises
    ------
    ModelFileError
        Not a camchain (no ``cam0``, or keys out of order), a camera model other than pinhole, a distortion model
        other than radtan / equidistant, a missing or malformed field (named), or a ``T_cn_cnm1`` that is not a
        rigid transform.
    """
    d = load_yaml(text)
    if not isinstance(d, dict) or "cam0" not in d:
        raise ModelFileError("Kalibr camchain: expected a mapping of cam0, cam1, ...")
    keys = [k for k in d if isinstance(k, str) and k.startswith("cam") and k[3:].isdigit()]
    if keys != [f"cam{n}" for n in range(len(keys))]:
        raise ModelFileError(f"Kalibr camchain: cameras must be cam0, cam1, ... in order, got {show(keys)}")
    cams, rvecs, tvecs = [], [np.zeros(3)], [np.zeros(3)]
    R_prev, t_prev = np.eye(3), np.zeros(3)
    for n, key in enumerate(keys):
        c = d[key]
        if not isinstance(c, dict):
            raise ModelFileError(f"Kalibr camchain {key}: expected a mapping")
        missing = [f for f in ("intrinsics", "distortion_model", "distortion_coeffs", "resolution") if f not in c]
        if missing:
            raise ModelFileError(f"Kalibr camchain {key}: no {', '.join(missing)}")
        if c.get("camera_model", "pinhole") != "pinhole":
            raise ModelFileError(
                f"Kalibr camchain {key}: camera_model {show(c.get('camera_model'))} has no circcal model (pinhole only)"
            )
        model = c["distortion_model"]
        if model not in ("radtan", "equidistant"):
            raise ModelFileError(
                f"Kalibr camchain {key}: distortion_model {show(model)} has no circcal model (radtan, equidistant)"
            )
        fu, fv, pu, pv = number_list(c["intrinsics"], f"Kalibr camchain {key} intrinsics", 4)
        D = number_list(c["distortion_coeffs"], f"Kalibr camchain {key} distortion_coeffs", 4)
        res = c["resolution"]
        if not isinstance(res, list) or len(res) != 2:
            raise ModelFileError(f"Kalibr camchain {key} resolution must be [width, height], got {show(res)}")
        K = np.array([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]])
        fish = model == "equidistant"
        cams.append(
            camera_from_K_dist(
                res[0],
                res[1],
                K,
                D if fish else np.concatenate([D, [0.0]]),
                f"Kalibr camchain {key}",
                lens="fisheye" if fish else None,
            )
        )
        if n == 0:
            continue
        if "T_cn_cnm1" not in c:
            raise ModelFileError(f"Kalibr camchain {key}: no T_cn_cnm1 (its pose relative to cam{n - 1})")
        rows = c["T_cn_cnm1"]
        M = matrix(
            [v for row in rows for v in row]
            if isinstance(rows, list) and all(isinstance(r, list) for r in rows)
            else rows,
            f"Kalibr camchain {key} T_cn_cnm1",
            (4, 4),
        )
        if np.max(np.abs(M[3] - (0.0, 0.0, 0.0, 1.0))) > _ROTATION_TOL:
            raise ModelFileError(f"Kalibr camchain {key} T_cn_cnm1: its last row must be [0, 0, 0, 1]")
        R = _rotation(M[:3, :3], f"Kalibr camchain {key} T_cn_cnm1")
        R_prev, t_prev = R @ R_prev, R @ t_prev + M[:3, 3] / M_PER_MM
        rvecs.append(_rvec(R_prev))
        tvecs.append(t_prev)
    return RigModel(keys, cams, rvecs, tvecs)
