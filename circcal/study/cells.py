"""A study summary's cells, the data that the summary (:mod:`circcal.study.summary`: statistics, Markdown,
summary.json) and its figures (:mod:`circcal.study.figures`) both use; a module of its own so that neither imports
the other back.

A *cell* is (kind, scenario, variant, calibrator, lens model): the rows that differ only by seed; what its numbers
mean: :mod:`circcal.study.summary`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["CELL_COLUMNS", "TABLE_PARAMS", "CellSummary", "ParamSummary"]

#: The columns whose values identify a summary cell.
CELL_COLUMNS = ("kind", "scenario", "variant", "calibrator", "lens_model")
#: Parameters shown in the Markdown tables and figures (all nine are in summary.json).
TABLE_PARAMS = ("fx", "fy", "cx", "cy", "k1")


@dataclass
class ParamSummary:
    """One parameter of one cell, in the parameter's units (what each number is: :mod:`circcal.study.summary`).

    Attributes
    ----------
    n : int
        Ok runs.
    bias, bias_ci : float, (float, float)
        mean(estimate - truth) and its interval.
    spread, spread_ci : float, (float, float)
        Standard deviation of the estimates and its interval.
    stated : float
        Mean stated sigma.
    ratio, ratio_ci : float, (float, float)
        spread / stated and its interval.
    bias_sigmas, bias_sigmas_ci : float, (float, float)
        bias / stated and its interval.
    """

    n: int
    bias: float
    bias_ci: tuple[float, float]
    spread: float
    spread_ci: tuple[float, float]
    stated: float
    ratio: float
    ratio_ci: tuple[float, float]
    bias_sigmas: float
    bias_sigmas_ci: tuple[float, float]


@dataclass
class CellSummary:
    """One cell: its identity, run counts, per-parameter summaries, the truth-check pass rate and the distributions of
    the projection difference to the truth (px) and of the run time (s).

    Attributes
    ----------
    kind, scenario, variant, calibrator, lens_model : str
        The cell's identity.
    n_runs, n_ok : int
        Runs, and those with status "ok".
    params : dict of str to ParamSummary
    pass_rate : float
        Share of runs passing the truth check, with ``pass_ci`` (Wilson).
    pass_expected : float
        What an honest Gaussian estimator gets.
    truth_rms_median_px, truth_rms_p95_px : float
        px.
    time_median_s : float
        s.
    statuses : dict of str to int
        Runs per status.
    """

    kind: str
    scenario: str
    variant: str
    calibrator: str
    lens_model: str
    n_runs: int
    n_ok: int
    params: dict[str, ParamSummary] = field(default_factory=dict)
    pass_rate: float = float("nan")
    pass_ci: tuple[float, float] = (float("nan"), float("nan"))
    pass_expected: float = float("nan")
    truth_rms_median_px: float = float("nan")
    truth_rms_p95_px: float = float("nan")
    time_median_s: float = float("nan")
    statuses: dict[str, int] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CellSummary:
        """Inverse of ``dataclasses.asdict`` (what summary.json holds; JSON turns tuples into lists).

        Parameters
        ----------
        d : dict

        Returns
        -------
        CellSummary
        """

        def params(v: dict[str, Any]) -> ParamSummary:
            return ParamSummary(**{k: tuple(x) if isinstance(x, list) else x for k, x in v.items()})

        fields = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k != "params"}
        return cls(**fields, params={k: params(v) for k, v in (d.get("params") or {}).items()})

    @property
    def label(self) -> str:
        """The cell's name in tables and figures: scenario/variant/calibrator, and the lens model unless opencv5."""
        return f"{self.scenario}/{self.variant}/{self.calibrator}" + (
            "" if self.lens_model == "opencv5" else f"/{self.lens_model}"
        )
