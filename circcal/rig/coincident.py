"""Cameras of a rig at one point: a baseline too short to triangulate, and the same images given for two cameras.

A rig calibrated from one camera's images given twice (a wrong folder on the command line) solves to a baseline of
~0 within its noise and otherwise looks healthy; so does a beam-splitter pair that shares one centre by design. The
check names both and tells them apart by the points: identical image points at every shared instant are the same
images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from circcal.rig.calibrate import RigCalibration

__all__ = ["COINCIDENT_SHARE", "SAME_POINT_PX", "CoincidentCameras", "coincident_cameras"]

#: Two cameras whose centres are closer than this share of the board's median distance sit at one point: rays from
#: both meet a board point at under 0.06 deg, and no depth can be triangulated from them.
COINCIDENT_SHARE = 1e-3
#: Image points this close (px) are the same point: one image's centres, re-corrected in each camera's own loop,
#: differ by rounding (3e-13 px measured); two cameras never see every point of every instant this close.
SAME_POINT_PX = 1e-6


@dataclass(frozen=True)
class CoincidentCameras:
    """Two cameras of a rig at one point (:func:`coincident_cameras`).

    Attributes
    ----------
    a, b : str
        Camera names.
    baseline_mm : float
        The distance between their centres, mm.
    distance_mm : float
        The board's median distance from the reference camera, mm.
    same_points : bool
        Both saw the same image points (within :data:`SAME_POINT_PX`) at every instant they share: the same images
        given twice.
    """

    a: str
    b: str
    baseline_mm: float
    distance_mm: float
    same_points: bool

    def lines(self) -> list[str]:
        """What it means and what to do.

        Returns
        -------
        list of str
        """
        where = (
            f"cameras {self.a!r} and {self.b!r} sit at one point (baseline {self.baseline_mm:.3g} mm, "
            f"{100 * self.baseline_mm / self.distance_mm:.2g}% of the board's distance {self.distance_mm:.4g} mm): "
            f"no depth can be triangulated from them"
        )
        if self.same_points:
            return [
                f"{where}; they saw identical points at every instant they share: the same images were given for both",
                "what to do: give each camera its own images (--camera NAME=FOLDER, one folder per camera)",
            ]
        return [
            where,
            "what to do: nothing if they share one centre by design (a beam splitter); otherwise check that each "
            "camera was given its own images",
        ]


def coincident_cameras(cal: RigCalibration, share: float = COINCIDENT_SHARE) -> list[CoincidentCameras]:
    """Pairs of cameras whose centres are closer than ``share`` of the board's median distance.

    Parameters
    ----------
    cal : RigCalibration
    share : float
        Of the median distance of the board from the reference camera over the instants.

    Returns
    -------
    list of CoincidentCameras
        In camera order.
    """
    rig = cal.rig
    if not cal.board_poses:
        return []
    distance = float(np.median([np.linalg.norm(t) for _, t in cal.board_poses.values()]))
    out = []
    for i in range(rig.n_cameras):
        for j in range(i + 1, rig.n_cameras):
            baseline = float(np.linalg.norm(rig.pair(i, j)[1]))
            if baseline >= share * distance:
                continue
            a, b = cal.observations.get(rig.names[i], {}), cal.observations.get(rig.names[j], {})
            shared = [v for v in a if v in b]
            same = bool(shared) and all(
                a[v][1].shape == b[v][1].shape and np.allclose(a[v][1], b[v][1], rtol=0, atol=SAME_POINT_PX)
                for v in shared
            )
            out.append(CoincidentCameras(rig.names[i], rig.names[j], baseline, distance, same))
    return out
