"""What a seed means: a seeded variant of a catalogue scenario, renderable anywhere from its name and seed.

A :class:`circcal.fixtures.scenarios.Scenario` draws its poses (``sample_poses(..., seed)``) and every view's
perturbation seed (``sha256(f"{seed}/{variant}/{view}")``) from one ``seed``. A study seed ``s`` gives

* ``vary: scene``: the scenario with ``seed = s`` (new poses and new noise);
* ``vary: noise``: new perturbation seeds from ``s``, the poses of the scenario's own seed
  (:class:`SeededScenario` keeps them in ``pose_seed``).

Either way the seed equal to the scenario's own reproduces its catalogue fixture exactly (the same content key, so
:func:`circcal.fixtures.cache.fixture_dir`'s cache applies). Rendering needs only the catalogue, which every
worker has with circcal installed: no shared file system. :func:`rendered` renders into a private temporary folder,
or, with ``cache``, into the content-hash cache (``cache_root()/study``), once per machine.

The seeds of a ``vary: noise`` cell differ only in their noise: each worker process renders the views' noise-free
images once (:func:`geometry`, an ``lru_cache`` of :data:`GEOMETRY_CACHE_SIZE` geometries keyed by
:meth:`circcal.fixtures.scenarios.Scenario.geometry_spec`) and adds every seed's perturbations to them, the same draw
as before, so the images are the same bit for bit (tests/test_study_geometry_cache.py; what it saves: docs/studies.md).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from filelock import FileLock

from circcal.fixtures.cache import ViewGeometry, cache_root, fixture_dir, render_fixture, render_geometry
from circcal.fixtures.scenarios import Scenario, get_scenario
from circcal.study.spec import VARY

__all__ = ["GEOMETRY_CACHE", "GEOMETRY_CACHE_SIZE", "SeededScenario", "geometry", "rendered", "seeded_scenario"]


@dataclass(frozen=True)
class SeededScenario(Scenario):
    """A scenario whose poses come from ``pose_seed`` (None: from ``seed``, as in the catalogue) while ``seed`` decides
    the perturbations.
    """

    pose_seed: int | None = None

    def poses(self):
        """The views' poses, drawn from ``pose_seed`` (or ``seed``).

        Returns
        -------
        list of (ndarray, ndarray)
            (rvec (3,) rad, tvec (3,) mm) per view.
        """
        if self.pose_seed is None or self.pose_seed == self.seed:
            return super().poses()
        return Scenario.poses(dataclasses.replace(self, seed=self.pose_seed, pose_seed=None))

    def spec(self) -> dict[str, Any]:
        """The catalogue spec, plus ``pose_seed`` where it differs from ``seed`` (so an unchanged scenario keeps its
        catalogue key).

        Returns
        -------
        dict
        """
        out = super().spec()
        if self.pose_seed is not None and self.pose_seed != self.seed:
            out["pose_seed"] = self.pose_seed
        return out

    def geometry_spec(self) -> dict[str, Any]:
        """The catalogue's geometry spec with the seed the poses come from.

        So every seed of a ``vary: noise`` cell has the same one: one noise-free render serves them all.

        Returns
        -------
        dict
        """
        out = super().geometry_spec()
        out.pop("pose_seed", None)
        out["seed"] = self.seed if self.pose_seed is None else self.pose_seed
        return out


#: Noise-free renders (:func:`circcal.fixtures.cache.render_geometry`) kept per worker process, most recently
#: used first: a ``vary: noise`` cell's seeds share one (the paper's 14 views at 1920x1080: ~0.26 GB), so two
#: cells' scenarios interleaved on a worker each keep theirs.
GEOMETRY_CACHE_SIZE = 2
#: Whether :func:`rendered` uses :func:`geometry` (False: every seed renders its views again; the same images).
GEOMETRY_CACHE = True


class _GeometryKey:
    """A scenario, hashed and compared by its geometry spec (what :func:`_geometry` is cached on)."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.key = json.dumps(scenario.geometry_spec(), sort_keys=True, default=str)

    def __hash__(self) -> int:
        return hash(self.key)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _GeometryKey) and other.key == self.key


@lru_cache(maxsize=GEOMETRY_CACHE_SIZE)
def _geometry(key: _GeometryKey) -> tuple[ViewGeometry, ...]:
    return render_geometry(key.scenario)


def geometry(scenario: Scenario) -> tuple[ViewGeometry, ...]:
    """The noise-free render of a scenario's views, rendered once per worker process and geometry spec.

    :data:`GEOMETRY_CACHE_SIZE` are kept; ``geometry.cache_clear()`` / ``cache_info()`` reach the cache.

    Parameters
    ----------
    scenario : Scenario

    Returns
    -------
    tuple of ViewGeometry
    """
    return _geometry(_GeometryKey(scenario))


geometry.cache_clear = _geometry.cache_clear  # type: ignore[attr-defined]
geometry.cache_info = _geometry.cache_info  # type: ignore[attr-defined]


def seeded_scenario(name: str, seed: int, vary: str = "noise") -> SeededScenario:
    """A catalogue scenario under a study seed (see the module docstring).

    Parameters
    ----------
    name : str
        A catalogue scenario.
    seed : int
        The study seed.
    vary : {"noise", "scene"}
        What the seed changes.

    Returns
    -------
    SeededScenario

    Raises
    ------
    circcal.errors.InputError
        An unknown scenario.
    ValueError
        An unknown ``vary``.
    """
    if vary not in VARY:
        raise ValueError(f"vary must be one of {', '.join(VARY)}, got {vary!r}")
    base = get_scenario(name)
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(Scenario)}
    fields["seed"] = int(seed)
    return SeededScenario(**fields, pose_seed=base.seed if vary == "noise" else None)


@contextmanager
def rendered(scenario: SeededScenario, variants: Sequence[str], *, cache: bool = False) -> Iterator[dict[str, Path]]:
    """Folders of a seeded scenario's variants, rendered on this machine.

    Without ``cache``: a temporary folder, removed when the block ends. With ``cache``: the catalogue's cache when the
    seeded scenario is the catalogue's own, else ``cache_root()/study/<name>-<variant>-<key>`` (rendered once per
    machine under a lock, folders placed atomically). A ``vary: noise`` scenario (poses pinned by ``pose_seed``)
    starts from its noise-free render kept in this process (:func:`geometry`, when :data:`GEOMETRY_CACHE`): the same
    images, bit for bit, without rendering the views again for every seed.

    Parameters
    ----------
    scenario : SeededScenario
    variants : sequence of str
    cache : bool

    Yields
    ------
    dict of str to Path
        Variant -> folder with the images and truth.json.
    """
    variants = list(variants)

    def render(out: Path, which: list[str]) -> dict[str, Path]:
        reuse = GEOMETRY_CACHE and scenario.pose_seed is not None
        return render_fixture(scenario, out, which, progress=False, geometry=geometry(scenario) if reuse else None)

    if not cache:
        tmp = Path(tempfile.mkdtemp(prefix=f"circcal-study-{scenario.name}-"))
        try:
            yield render(tmp, variants)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return
    base = get_scenario(scenario.name)
    if all(scenario.key(v) == base.key(v) for v in variants):
        yield {v: fixture_dir(scenario.name, v) for v in variants}
        return
    root = cache_root() / "study"
    root.mkdir(parents=True, exist_ok=True)
    dirs = {v: root / f"{scenario.name}-{v}-{scenario.key(v)}" for v in variants}
    with FileLock(root / f".{scenario.name}-{scenario.seed}.lock"):
        missing = [v for v in variants if not (dirs[v] / "truth.json").exists()]
        if missing:  # rendered together (the geometry is shared), each folder then renamed into place whole
            tmp = Path(tempfile.mkdtemp(prefix=f".{scenario.name}-", dir=root))
            try:
                for v, d in render(tmp, missing).items():
                    shutil.rmtree(dirs[v], ignore_errors=True)
                    d.replace(dirs[v])
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
    yield dirs
