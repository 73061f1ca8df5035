"""The per-parameter verdict of a calibrator under test: each parameter's value and its difference to circcal's
solve and to the truth, in its unit and in stated sigmas.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

import numpy as np

from circcal.formatting import fmt_number
from circcal.model import Camera, param_names

#: The start of :func:`stated_sigmas`' notes (the end-of-run table shows them on the case's line:
#: :func:`circcal.validators.case_report.summary_line`).
STD_NOTE = "std: "


def stated_sigmas(
    std: Any, lens: str, held: Collection[str], fallback: Mapping[str, float] | None
) -> tuple[dict[str, float], list[str], list[str]]:
    """The standard deviations a calibrator's camera is held to: those it states, circcal's where it states none.

    A stated value must be a finite number >= 0 (a Python or NumPy scalar); 0 means held, and for a parameter the
    calibrator fits it counts as not stated. A key that is missing or None is not stated; keys that are not
    parameters of ``lens`` are ignored, and a note says so.

    Parameters
    ----------
    std : dict or None
        The calibrator's ``std`` as returned (None: it states none).
    lens : str
        The lens model of its camera.
    held : collection of str
        The parameters it holds (:func:`circcal.validators.user_case.declared_model`).
    fallback : dict of str to float, or None
        circcal's standard deviations on the same observations and model.

    Returns
    -------
    sigmas : dict of str to float
        One per parameter of ``lens``.
    from_circcal : list of str
        The fitted parameters whose sigma is circcal's.
    notes : list of str
        One line each: fitted parameters without a stated sigma (when ``std`` is a dict), unknown keys.

    Raises
    ------
    ValueError
        ``std`` not a dict, or a value that is not a finite number >= 0: one line naming the key, e.g.
        "std['fx'] must be a finite number >= 0, got 'abc'".
    """
    names = param_names(lens)
    fallback = fallback or {}
    if std is not None and not isinstance(std, Mapping):
        raise ValueError(f"std must be a dict keyed {', '.join(names)}, or None; got {type(std).__name__}")
    stated = dict(std or {})
    sigmas, missing, zero = {}, [], []
    for n in names:
        v = _sigma(n, stated.get(n))
        if v is not None and (v > 0 or n in held):
            sigmas[n] = v
            continue
        sigmas[n] = float(fallback.get(n, np.nan))
        if n not in held:
            (missing if v is None else zero).append(n)
    notes = []
    if std is not None and (missing or zero):
        why = ([f"{', '.join(missing)} (not stated)"] if missing else []) + (
            [f"{', '.join(zero)} (stated 0 for a fitted parameter)"] if zero else []
        )
        notes.append(f"{STD_NOTE}circcal's sigmas on the same observations and model used for {'; '.join(why)}")
    unknown = [k for k in stated if k not in names]
    if unknown:
        notes.append(
            f"{STD_NOTE}unknown key(s) {', '.join(repr(k) for k in unknown)} ignored (the {lens} model's parameters are "
            f"{', '.join(names)})"
        )
    return sigmas, [n for n in names if n in missing or n in zero], notes


def _sigma(name: str, value: Any) -> float | None:
    """A stated standard deviation as a float (None: not stated); ValueError naming the key when it is not a
    finite number >= 0."""
    if value is None:
        return None
    if isinstance(value, (bool, str, bytes)) or np.ndim(value) != 0:
        shown = f"{type(value).__name__} of shape {np.shape(value)}" if np.ndim(value) else repr(value)
        raise ValueError(f"std[{name!r}] must be a finite number >= 0, got {shown}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"std[{name!r}] must be a finite number >= 0, got {value!r}") from None
    if not np.isfinite(v) or v < 0:
        raise ValueError(f"std[{name!r}] must be a finite number >= 0, got {v:g}")
    return v


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
