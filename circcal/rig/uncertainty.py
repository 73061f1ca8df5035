"""Each rig camera's projection uncertainty from the joint solve's covariance.

The joint covariance (:attr:`circcal.rig.RigModel.covariance`, first order, board poses marginalised) holds every
camera's intrinsics block. A camera's projection uncertainty here is the spread of its projection of fixed rays at
infinity under its intrinsics' covariance, the rotation the intrinsics can trade with fitted out
(:func:`circcal.rig.crossval.rotation_free_stdev`: what :func:`circcal.analysis.diff.model_diff` compares two models
by). It leaves out the rig pose's own uncertainty (the extrinsics' sigmas are stated beside it); mrcal's definition
for one camera also propagates the board poses through the rays, which here the marginalised poses carry only
through the intrinsics' covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from circcal.rig.crossval import rotation_free_stdev
from circcal.rig.model import RigModel

__all__ = ["CameraUncertainty", "projection_uncertainty", "GRID"]

#: The grid of pixels (columns, rows) the uncertainty is evaluated on, corners included.
GRID = (16, 12)


@dataclass(frozen=True)
class CameraUncertainty:
    """One camera's projection uncertainty (1 sigma, worst direction), px.

    Attributes
    ----------
    name : str
    worst_px : float
        The largest over the grid.
    worst_uv : tuple of float
        Where, px.
    centre_px : float
        At the image centre.
    held : bool
        Every intrinsic held (given): no uncertainty is stated for them.
    undetermined : bool
        Some of its intrinsics are not determined by the views (the covariance given is NaN there): none stated.
    """

    name: str
    worst_px: float
    worst_uv: tuple[float, float]
    centre_px: float
    held: bool = False
    undetermined: bool = False

    def text(self) -> str:
        """One line.

        Returns
        -------
        str
        """
        if self.held:
            return f"projection uncertainty of {self.name}'s intrinsics: none stated (held at the ones given)"
        if self.undetermined:
            return (
                f"projection uncertainty of {self.name}'s intrinsics: none stated (its views leave some of them "
                f"undetermined: see the verdict)"
            )
        return (
            f"projection uncertainty of {self.name}'s intrinsics at infinity: worst {self.worst_px:.3g} px at "
            f"({self.worst_uv[0]:.0f}, {self.worst_uv[1]:.0f}), centre {self.centre_px:.3g} px (1 sigma, worst "
            f"direction, the implied rotation fitted out)"
        )


def projection_uncertainty(rig: RigModel, covariance: np.ndarray | None = None) -> list[CameraUncertainty]:
    """Every camera's projection uncertainty (see the module).

    Parameters
    ----------
    rig : RigModel
        With its covariance.
    covariance : ndarray, optional
        Of ``rig.state_vector()`` instead of ``rig.covariance``: e.g. a rig without one, the marginal covariance of
        what its views determine (:func:`circcal.rig.undetermined.determined_rig_covariance`, NaN for the rest).

    Returns
    -------
    list of CameraUncertainty
        One per camera (a camera with a NaN in its intrinsics' block: ``undetermined``); empty without a covariance.
    """
    full = rig.covariance if covariance is None else covariance
    if full is None:
        return []
    sizes = [len(c.intrinsics) for c in rig.cameras]
    start = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    out = []
    for k, (name, cam) in enumerate(zip(rig.names, rig.cameras)):
        cov = np.asarray(full)[start[k] : start[k + 1], start[k] : start[k + 1]]
        if np.isnan(cov).any():
            out.append(CameraUncertainty(name, float("nan"), (0.0, 0.0), float("nan"), undetermined=True))
            continue
        if not np.any(cov):
            out.append(CameraUncertainty(name, 0.0, (0.0, 0.0), 0.0, held=True))
            continue
        u, v = np.meshgrid(np.linspace(0, cam.width - 1, GRID[0]), np.linspace(0, cam.height - 1, GRID[1]))
        centre = np.array([[0.5 * (cam.width - 1), 0.5 * (cam.height - 1)]])
        uv = np.vstack([np.column_stack([u.ravel(), v.ravel()]), centre])
        s = rotation_free_stdev(cam, cov, uv)
        grid = s[:-1]
        i = int(np.nanargmax(grid)) if np.isfinite(grid).any() else 0
        out.append(CameraUncertainty(name, float(grid[i]), (float(uv[i, 0]), float(uv[i, 1])), float(s[-1])))
    return out
