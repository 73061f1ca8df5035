"""What a report run covers (:class:`ReportConfig`, :data:`FULL`, :data:`QUICK`), the paper's published numbers,
where the real photographs live, and the pixel grid every projection difference is measured on."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "CONDITIONS",
    "FULL",
    "PAPER_PUBLISHED",
    "PROJECTION_GRID_WIDTH",
    "QUICK",
    "REALDATA_ENV",
    "ReportConfig",
    "STUDIES_ENV",
    "realdata_root",
    "studies_root",
]

#: The paper's four illumination conditions, in the order its tables use (the ``paper`` scenario's variants).
CONDITIONS = ("normal", "uneven", "strong", "weak")

#: Chen et al. 2023, Table 7: mean reprojection error (px) per illumination condition (no "normal" column there).
PAPER_PUBLISHED: dict[str, dict[str, float]] = {
    "circles": {"uneven": 0.1087, "strong": 0.1016, "weak": 0.1199},
    "checkerboard": {"uneven": 0.135, "strong": 0.157, "weak": 0.160},
}

#: Projection differences ("vs truth", the heatmaps) are taken over a grid this many points wide across the image
#: (rows in proportion): mrcal's projection_diff default, fine enough that the RMS no longer moves with it.
PROJECTION_GRID_WIDTH = 60

#: Environment variable naming the folder of real photographs (one sub-folder per set).
REALDATA_ENV = "CIRCCAL_REALDATA"
#: Environment variable naming the folder of finished studies (``circcal study ... --out DIR/<name>``).
STUDIES_ENV = "CIRCCAL_STUDIES"


@dataclass(frozen=True)
class ReportConfig:
    """What a report run covers.

    Attributes
    ----------
    name : str
        "full" or "quick".
    conditions, checkerboard_conditions : tuple of str
        Illumination conditions (variants) of the paper and checkerboard studies.
    n_views : int or None
        First N views of each fixture (None: all of them).
    references : tuple of str
        Names for :func:`circcal.validators.validate.run_validation`.
    bias_tilts_deg, bias_diameters_px : tuple of float
        The clean-render grid of the bias study (tilt in degrees, dot diameter in px at the board centre).
    realdata : tuple of str
        Folder names under :func:`realdata_root`.
    heldout : bool
        Run the leave-one-view-out checks on the real photographs.
    studies : tuple of str
        Folder names under :func:`studies_root` of finished studies (``circcal study``) whose summaries the report
        shows.
    """

    name: str = "full"
    conditions: tuple[str, ...] = CONDITIONS
    checkerboard_conditions: tuple[str, ...] = CONDITIONS
    n_views: int | None = None
    references: tuple[str, ...] = ("all",)
    bias_tilts_deg: tuple[float, ...] = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0)
    bias_diameters_px: tuple[float, ...] = (14.0, 20.0, 30.0, 45.0, 60.0)
    realdata: tuple[str, ...] = ("boofcv_sony_hx5v_circle_asym_4x5", "boofcv_sony_hx5v_circle_regular_10x8")
    heldout: bool = True
    studies: tuple[str, ...] = ("monte-carlo", "paper-2000", "paper-2000-subset", "markers-noise", "solver-batched")


FULL = ReportConfig()
QUICK = ReportConfig(
    name="quick",
    conditions=("normal",),
    checkerboard_conditions=("normal",),
    n_views=8,
    bias_tilts_deg=(0.0, 30.0, 60.0),
    bias_diameters_px=(20.0, 45.0),
    realdata=("boofcv_sony_hx5v_circle_asym_4x5",),
)


def realdata_root() -> Path:
    """The folder of real photographs.

    ``$CIRCCAL_REALDATA`` when set, else ``../shared/data/realdata`` beside the repository this package was loaded from.
    It may not exist (an installed package, a checkout without the data): the report then marks each set "missing".

    Returns
    -------
    Path
    """
    env = os.environ.get(REALDATA_ENV)
    if env:
        return Path(env).expanduser()
    return Path(__file__).resolve().parents[2].parent / "shared" / "data" / "realdata"


def studies_root() -> Path:
    """The folder of finished studies.

    ``$CIRCCAL_STUDIES`` when set, else ``reports/studies`` of the repository this package was loaded from (where
    ``make study-reports`` writes them).

    Returns
    -------
    Path
    """
    env = os.environ.get(STUDIES_ENV)
    if env:
        return Path(env).expanduser()
    return Path(__file__).resolve().parents[2] / "reports" / "studies"
