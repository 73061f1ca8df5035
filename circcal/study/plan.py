"""A study's runs and the Dask tasks that carry them, each run keyed by a content hash.

A run's key hashes everything that decides its row: the fixture (a seeded scenario's content key, which covers the
scenario spec, the renderer and perturbation versions) or the fixed views and noise, the seed, the calibrator
(name, mode, observations, plug-in), the lens model, circcal's version and :data:`circcal.study.rows.ROW_VERSION`.
The study's name is not part of it. A run whose key is already stored is skipped (:mod:`circcal.study.store`).

Tasks: an images cell gets one task per seed (the fixture is rendered once, every variant sharing its geometry,
and every calibrator runs on it); an observations cell gets tasks of ``batch`` seeds per (variant, calibrator,
lens model) (a solve takes milliseconds: one run per task would be mostly scheduling; a kornia task is one batched
solve).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any

import circcal
from circcal.study.rows import ROW_VERSION
from circcal.study.spec import CalibratorSpec, CellSpec, StudySpec

__all__ = ["Run", "Task", "geometry_identity", "plan"]

_NAN = float("nan")
#: Hex digits of a run key: 96 bits, no collision among 10^7 runs in practice.
KEY_HEX = 24


def _hash(obj: Any, n: int = KEY_HEX) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:n]


@dataclass(frozen=True)
class Run:
    """One row to be.

    Attributes
    ----------
    key : str
        The content hash (see the module docstring).
    cell : int
        Index of its cell.
    kind, scenario, variant : str
    seed : int
    calibrator : CalibratorSpec
    lens_model : str
    vary : str
        Images cells: "noise" or "scene".
    noise_px : float
        Observations cells: the noise sigma, px.
    """

    key: str
    cell: int
    kind: str
    scenario: str
    variant: str
    seed: int
    calibrator: CalibratorSpec
    lens_model: str
    vary: str = ""
    noise_px: float = _NAN


@dataclass(frozen=True)
class Task:
    """Runs computed together on one worker (see the module docstring).

    Attributes
    ----------
    study : str
        The study's name (for the rows).
    cell : CellSpec
    runs : tuple of Run
    cache : bool
        Keep rendered fixtures in the content-hash cache.
    key : str
        The Dask key: the same runs give the same key (so a task is never computed twice at once).
    """

    study: str
    cell: CellSpec
    runs: tuple[Run, ...]
    cache: bool = False

    @property
    def key(self) -> str:
        """The Dask key: the same runs give the same key (so a task is never computed twice at once)."""
        return f"circcal-study-{self.cell.kind}-{_hash(sorted(r.key for r in self.runs), 16)}"

    def without(self, done: set[str]) -> Task:
        """This task less the runs already done.

        Parameters
        ----------
        done : set of str
            Stored run keys.

        Returns
        -------
        Task
        """
        return replace(self, runs=tuple(r for r in self.runs if r.key not in done))


def geometry_identity(cell: CellSpec) -> dict[str, Any]:
    """What decides the fixed views of an observations cell.

    Parameters
    ----------
    cell : CellSpec

    Returns
    -------
    dict
        Its inline geometry, or its scenario's spec (camera, board, pose sampling; everything but the variants).
    """
    if cell.geometry is not None:
        return cell.geometry.identity()
    from circcal.fixtures.scenarios import get_scenario

    spec = get_scenario(cell.scenario).spec()
    return {k: v for k, v in spec.items() if k != "variants"}  # the variants decide pixels, not these points


def _base(cell: CellSpec, cal: CalibratorSpec, lens: str) -> dict[str, Any]:
    return {
        "row": ROW_VERSION,
        "circcal": circcal.__version__,
        "kind": cell.kind,
        "calibrator": cal.identity(),
        "lens_model": lens,
    }


def _image_tasks(study: StudySpec, cell: CellSpec) -> Iterable[Task]:
    from circcal.study.seeded import seeded_scenario

    for seed in cell.seeds:
        sc = seeded_scenario(cell.scenario, seed, cell.vary)
        runs = []
        for variant in cell.variants:
            fixture = sc.key(variant)
            for cal in cell.calibrators:
                for lens in cell.lens_models:
                    key = _hash(
                        {**_base(cell, cal, lens), "fixture": fixture, "scenario": cell.scenario, "variant": variant}
                    )
                    runs.append(Run(key, cell.index, cell.kind, cell.scenario, variant, seed, cal, lens, cell.vary))
        yield Task(study.name, cell, tuple(runs), study.cache)


def _observation_tasks(study: StudySpec, cell: CellSpec) -> Iterable[Task]:
    geometry = geometry_identity(cell)
    for variant, sigma in zip(cell.variants, cell.noise_px):
        for cal in cell.calibrators:
            for lens in cell.lens_models:
                base = {**_base(cell, cal, lens), "geometry": geometry, "noise_px": sigma}
                runs = [
                    Run(
                        _hash({**base, "seed": s}),
                        cell.index,
                        cell.kind,
                        cell.scenario,
                        variant,
                        s,
                        cal,
                        lens,
                        noise_px=sigma,
                    )
                    for s in cell.seeds
                ]
                for i in range(0, len(runs), cell.batch):
                    yield Task(study.name, cell, tuple(runs[i : i + cell.batch]), study.cache)


def plan(study: StudySpec) -> list[Task]:
    """Every task of a study, cell by cell (cells in spec order).

    Parameters
    ----------
    study : StudySpec

    Returns
    -------
    list of Task
    """
    tasks: list[Task] = []
    for cell in study.cells:
        tasks += _image_tasks(study, cell) if cell.kind == "images" else _observation_tasks(study, cell)
    return tasks
