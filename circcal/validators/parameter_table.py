"""The per-parameter verdict of a calibrator under test: each parameter's value and its difference to circcal's
solve and to the truth, in its unit and in stated sigmas.
"""

from __future__ import annotations

import numpy as np

from circcal.formatting import fmt_number
from circcal.model import Camera, param_names


def parameter_table(
    camera: Camera,
    std: dict[str, float] | None,
    circcal_camera: Camera,
    circcal_std: dict[str, float] | None,
    truth: Camera,
) -> dict[str, dict[str, float]]:
    """Per parameter: the calibrator's value, its difference to circcal's solve and to the truth, in its unit and in
    stated sigmas.

    Parameters
    ----------
    camera : circcal.model.Camera
        The calibrator's camera.
    std : dict of str to float, or None
        Its stated standard deviations; where one is missing or 0, circcal's on the same observations is used.
    circcal_camera : circcal.model.Camera
        circcal's solve with the same model on the same observations.
    circcal_std : dict of str to float, or None
        Its standard deviations.
    truth : circcal.model.Camera
        The true camera (a coefficient the model has and the truth lacks is 0 in the truth).

    Returns
    -------
    dict
        ``{name: {"value", "sigma", "vs_circcal", "vs_circcal_sigmas", "vs_truth", "vs_truth_sigmas"}}`` for every
        parameter of ``camera``'s lens model; fx, fy, cx, cy in px, distortion coefficients unitless. ``sigma`` is
        NaN for a held parameter (the sigma columns are then NaN).
    """
    names = param_names(camera.lens)
    mine = dict(zip(names, camera.intrinsics))
    circ = dict(zip(param_names(circcal_camera.lens), circcal_camera.intrinsics))
    true = dict(zip(param_names(truth.lens), truth.intrinsics)) if truth.model.pinhole == camera.model.pinhole else {}
    out = {}
    for n in names:
        s = float((std or {}).get(n) or 0.0)
        if not (np.isfinite(s) and s > 0):
            s = float((circcal_std or {}).get(n) or 0.0)
        s = s if np.isfinite(s) and s > 0 else float("nan")
        d_c = float(mine[n] - circ.get(n, np.nan))
        d_t = float(mine[n] - true.get(n, 0.0)) if true else float("nan")
        out[n] = {
            "value": float(mine[n]),
            "sigma": s,
            "vs_circcal": d_c,
            "vs_circcal_sigmas": d_c / s,
            "vs_truth": d_t,
            "vs_truth_sigmas": d_t / s,
        }
    return out


def format_parameter_table(table: dict[str, dict[str, float]]) -> list[str]:
    """Lines of :func:`parameter_table`: one per parameter, largest difference to circcal's solve first.

    Parameters
    ----------
    table : dict
        :func:`parameter_table`'s result.

    Returns
    -------
    list of str
    """

    def unit(n: str) -> str:
        return " px" if n in ("fx", "fy", "cx", "cy") else ""

    def sig(x: float) -> str:
        return "held" if not np.isfinite(x) else f"{x:+.2f} sigma"

    order = sorted(table, key=lambda n: -abs(np.nan_to_num(table[n]["vs_circcal_sigmas"], nan=0.0)))
    lines = ["parameter: value (sigma) | - circcal's solve, same model and points | - truth"]
    for n in order:
        r = table[n]
        lines.append(
            f"  {n:>3}: {r['value']:.6g}{unit(n)} ({fmt_number(r['sigma'], '.3g')}) | "
            f"{r['vs_circcal']:+.4g}{unit(n)} ({sig(r['vs_circcal_sigmas'])}) | "
            f"{r['vs_truth']:+.4g}{unit(n)} ({sig(r['vs_truth_sigmas'])})"
        )
    return lines


def largest_difference(table: dict[str, dict[str, float]]) -> str:
    """The parameter farthest from circcal's solve, in stated sigmas, as words ("" for an empty table).

    Parameters
    ----------
    table : dict
        :func:`parameter_table`'s result.

    Returns
    -------
    str
        e.g. "cx differs by +0.5 px (+1.49 sigma) from circcal's solve".
    """
    ranked = [n for n in table if np.isfinite(table[n]["vs_circcal_sigmas"])]
    if not ranked:
        return ""
    n = max(ranked, key=lambda k: abs(table[k]["vs_circcal_sigmas"]))
    r = table[n]
    u = " px" if n in ("fx", "fy", "cx", "cy") else ""
    return f"{n} differs by {r['vs_circcal']:+.4g}{u} ({r['vs_circcal_sigmas']:+.2f} sigma) from circcal's solve"
