"""A rig without covariance in words: the parameters its views leave free, and what to do.

The joint solve's information matrix (board poses marginalised) is singular when the views cannot separate some
combination of parameters: most often a rich lens model's coefficients trading off (a rational camera whose
numerator and denominator move together over the field its views cover), or poses and focal lengths that nearly
fronto-parallel views cannot tell apart. :func:`circcal.rig.solve.weakest_direction` names them; this says it.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["undetermined_lines"]

#: The intrinsics that are not a lens model's distortion coefficients.
_PINHOLE = ("fx", "fy", "cx", "cy")


def undetermined_lines(undetermined: Sequence[tuple[str, str]]) -> list[str]:
    """What a rig without covariance means, and what to do: per camera the parameters its views leave free.

    Parameters
    ----------
    undetermined : sequence of (str, str)
        (camera, parameter) pairs of the information's weakest direction; empty where none could be named.

    Returns
    -------
    list of str
    """
    per: dict[str, list[str]] = {}
    for cam, p in undetermined:
        per.setdefault(cam, []).append(p)
    out = [
        "no stated uncertainty: the rig's information matrix is singular (the views leave a combination of "
        + ("; ".join(f"{', '.join(ps)} of camera {c!r}" for c, ps in per.items()) or "its parameters")
        + " free)"
    ]
    lens_only = [c for c, ps in per.items() if all(p not in _PINHOLE and p not in ("rvec", "tvec") for p in ps)]
    if lens_only and len(lens_only) == len(per):
        out.append(
            f"what to do: camera(s) {', '.join(lens_only)}: fit a lens model with fewer coefficients (--lens "
            f"{lens_only[0]}=opencv5), or add views that reach the corners and edges of its image"
        )
    else:
        out.append(
            "what to do: add views (tilted by 20-40 deg, at several distances, filling each image, and shared "
            "between the cameras), or hold what the views cannot separate"
        )
    return out
