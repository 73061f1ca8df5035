"""The results tree's entries, built and read in one way: the error statistics an entry keeps, a failure as an
entry, a lookup through nested entries that tolerates missing levels, and the run's order of conditions and sets
(report.json stores its keys sorted, so order comes from the run's config, never from a dict)."""

from __future__ import annotations

from typing import Any

__all__ = [
    "ERROR_KEYS",
    "ROW_ORDER",
    "all_conditions",
    "calibrator_keys",
    "dig",
    "error_summary",
    "failure",
    "paper_conditions",
    "realdata_sets",
]

#: The calibrator rows of the paper study, in the order the report lists them, with whose centres each fits ("own":
#: its own detector); plug-in references follow by name.
ROW_ORDER = (
    ("circcal", "own"),
    ("opencv-pipeline", "own"),
    ("opencv-fair", "circcal"),
    ("mrcal-fair", "circcal"),
    ("mrcal-default", "circcal"),
    ("kornia-fair", "circcal"),
    ("pycolmap-fair", "circcal"),
)
#: The statistics of :func:`circcal.metrics.error_stats` an entry keeps (px; the key names the convention).
ERROR_KEYS = ("n_points", "mean_2d_px", "rms_per_point_px", "rms_per_coord_px", "max_2d_px")


def error_summary(stats: dict[str, Any] | None) -> dict[str, Any] | None:
    """The :data:`ERROR_KEYS` of an error-statistics dict.

    Parameters
    ----------
    stats : dict or None
        :func:`circcal.metrics.error_stats` output (px).

    Returns
    -------
    dict or None
        None for none.
    """
    if not stats:
        return None
    return {k: stats.get(k) for k in ERROR_KEYS}


def failure(exc: BaseException) -> dict[str, str]:
    """A failed entry of the results tree.

    Parameters
    ----------
    exc : BaseException

    Returns
    -------
    dict of str to str
        ``{"status": "failed", "message": "<ExceptionType>: <message>"}``.
    """
    return {"status": "failed", "message": f"{type(exc).__name__}: {exc}"}


def dig(tree: Any, *keys: str) -> Any:
    """``tree[k1][k2]...``, or None where a level is missing or not a dict.

    Parameters
    ----------
    tree : object
    *keys : str

    Returns
    -------
    object

    Examples
    --------
    >>> dig({"a": {"b": 1}}, "a", "b"), dig({"a": 1}, "a", "b")
    (1, None)
    """
    for k in keys:
        if not isinstance(tree, dict):
            return None
        tree = tree.get(k)
    return tree


def paper_conditions(results: dict[str, Any]) -> list[str]:
    """The illumination conditions of the paper study, in the run's order (report.json stores keys sorted).

    Parameters
    ----------
    results : dict
        The results tree.

    Returns
    -------
    list of str
    """
    return [c for c in results["config"]["conditions"] if c in results["paper"]]


def all_conditions(results: dict[str, Any]) -> list[str]:
    """Every condition of the paper and checkerboard studies, in the run's order.

    Parameters
    ----------
    results : dict
        The results tree.

    Returns
    -------
    list of str
    """
    cfg = results["config"]
    order = list(cfg["conditions"]) + list(cfg["checkerboard_conditions"])
    return [c for c in dict.fromkeys(order) if c in results["paper"] or c in results["checkerboard"]]


def calibrator_keys(results: dict[str, Any]) -> list[str]:
    """Every calibrator key of the paper study: :data:`ROW_ORDER` first, any others (plug-ins) by name.

    Parameters
    ----------
    results : dict
        The results tree.

    Returns
    -------
    list of str
    """
    present = {k for c in paper_conditions(results) for k in results["paper"][c]["rows"]}
    ordered = [k for k, _ in ROW_ORDER if k in present]
    return ordered + sorted(present - set(ordered))


def realdata_sets(results: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """Every real-data set, in the run's order.

    Parameters
    ----------
    results : dict
        The results tree.

    Returns
    -------
    list of (str, dict)
        (name, entry).
    """
    return [(n, results["realdata"][n]) for n in results["config"]["realdata"] if n in results["realdata"]]
