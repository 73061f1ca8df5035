"""The bias test of a calibrator under test across the conformance cases: per parameter, the mean truth-normalised
error and its excess over circcal's solve on the same points and model.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from circcal.validators.checks import TRUTH_PARAMS


@dataclass
class Bias:
    """One parameter's bias over a calibrator's checked cases.

    Two tests of the mean truth-normalised error (error / the calibrator's stated sigma; standard error
    max(1, sample SD) / sqrt(n): 1 is the SD honest sigmas give, so understated sigmas only widen it): the
    calibrator's own against the truth, and its excess over circcal's solve on the same points and model. The excess
    is the verdict: a bias the observations carry (circcal's centres) is shared by every least-squares calibrator and
    shows in circcal's solve as well, so it is reported beside, not held against the calibrator.

    Attributes
    ----------
    label : str
        The calibrator.
    param : str
        The parameter.
    n : int
        Cases.
    mean : float
        Mean error against the truth, in the parameter's unit (px for fx, fy, cx, cy).
    mean_se : float
        Its standard error (NaN for one case).
    mean_sigmas : float
        Mean truth-normalised error.
    t : float
        Its t value.
    circcal_t : float
        The same t of circcal's solve on the same observations and model (same sigmas).
    vs_circcal : float
        Mean difference to circcal's solve, in the parameter's unit.
    excess_sigmas : float
        Mean difference to circcal's solve in stated sigmas (the calibrator's truth-normalised error less circcal's).
    excess_t : float
        Its t value: what :attr:`biased` tests.
    bound : float
        |excess_t| above this is a bias.
    """

    label: str
    param: str
    n: int
    mean: float
    mean_se: float
    mean_sigmas: float
    t: float
    circcal_t: float
    vs_circcal: float
    excess_sigmas: float
    excess_t: float
    bound: float

    @property
    def biased(self) -> bool:
        return bool(np.isfinite(self.excess_t) and abs(self.excess_t) > self.bound)

    def words(self) -> str:
        """One line: the bias relative to circcal's solve on the same points (named "biased by" beyond the bound)
        and against the truth, with circcal's solve's own.

        Returns
        -------
        str
        """
        u = " px" if self.param in ("fx", "fy", "cx", "cy") else ""
        se = f" +- {self.mean_se:.2g}" if np.isfinite(self.mean_se) else ""
        cases = f"{self.n} case{'s' if self.n != 1 else ''}"
        head = "biased by" if self.biased else "differs by"
        return (
            f"{self.param} {head} {self.vs_circcal:+.3g}{u} from circcal's solve on the same points (t = "
            f"{self.excess_t:+.2f}, bound {self.bound:.2f}; {self.excess_sigmas:+.2f} sigma, mean over {cases}); "
            f"vs the truth {self.mean:+.2f}{u}{se} (t = {self.t:+.2f}; circcal's solve t = {self.circcal_t:+.2f})"
        )


def _t(z: np.ndarray) -> float:
    """Mean / (max(1, sample SD) / sqrt(n))."""
    n = len(z)
    sd = float(np.std(z, ddof=1)) if n > 1 else 1.0
    return float(z.mean() / (max(1.0, sd) / np.sqrt(n)))


def bias_tests(records: Iterable[dict], bound: float, params: Sequence[str] = TRUTH_PARAMS) -> list[Bias]:
    """The bias tests of each calibrator and parameter over its checked cases (see :class:`Bias`).

    Parameters
    ----------
    records : iterable of dict
        One per case: ``{"label": str, "status": str, "params": parameter_table}`` (only "checked" ones count, and
        within them the parameters with a finite truth-normalised error).
    bound : float
        |t| bound (:data:`circcal.validators.bounds.BIAS_T`).
    params : sequence of str
        The parameters tested.

    Returns
    -------
    list of Bias
        Per label, per parameter with at least one case.
    """
    by: dict[tuple[str, str], list[dict]] = {}
    labels: list[str] = []
    for r in records:
        if r.get("status") != "checked":
            continue
        if r["label"] not in labels:
            labels.append(r["label"])
        for p in params:
            row = (r.get("params") or {}).get(p)
            if row and np.isfinite(row["vs_truth_sigmas"]) and np.isfinite(row["vs_circcal_sigmas"]):
                by.setdefault((r["label"], p), []).append(row)
    out = []
    for label in labels:
        for p in params:
            rows = by.get((label, p), [])
            if not rows:
                continue
            e = np.array([r["vs_truth"] for r in rows])
            z = np.array([r["vs_truth_sigmas"] for r in rows])
            d = np.array([r["vs_circcal_sigmas"] for r in rows])
            n = len(rows)
            out.append(
                Bias(
                    label,
                    p,
                    n,
                    float(e.mean()),
                    float(np.std(e, ddof=1) / np.sqrt(n)) if n > 1 else float("nan"),
                    float(z.mean()),
                    _t(z),
                    _t(z - d),
                    float(np.mean([r["vs_circcal"] for r in rows])),
                    float(d.mean()),
                    _t(d),
                    bound,
                )
            )
    return out
