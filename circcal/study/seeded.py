"""What a seed means: a seeded variant of a catalogue scenario, renderable anywhere from its name and seed.

A :class:`circcal.fixtures.scenarios.Scenario` draws its poses (``sample_poses(..., seed)``) and every view's
perturbation seed (``sha256(f"{seed}/{variant}/{view}")``) from one ``seed``. A study seed ``s`` gives

* ``vary: scene``: the scenario with ``seed = s`` (new poses and new noise);
* ``vary: noise``: new perturbation seeds from ``s``, the poses of the scenario's own seed
  (:class:`SeededScenario` keeps them in ``pose_seed``).

Either way the seed equal to the scenario's own reproduces its catalogue fixture exactly (the same content key, so
:func:`circcal.fixtures.scenarios.fixture_dir`'s cache applies). Rendering needs only the catalogue, which every
worker has with circcal installed: no shared file system. :func:`rendered` renders into a private temporary folder,
or, with ``cache``, into the content-hash cache (``cache_root()/study``), once per machine.
"""
from __future__ import annotations

import dataclasses
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from filelock import FileLock

from circcal.fixtures.scenarios import Scenario, cache_root, fixture_dir, get_scenario, render_fixture
from circcal.study.spec import VARY

__all__ = ["SeededScenario", "rendered", "seeded_scenario"]


@dataclass(frozen=True)
class SeededScenario(Scenario):
    """A scenario whose poses come from ``pose_seed`` (None: from ``seed``, as in the catalogue) while ``seed``
    decides the perturbations."""

    pose_seed: int | None = None

    def poses(self):
        if self.pose_seed is None or self.pose_seed == self.seed:
            return super().poses()
        return Scenario.poses(dataclasses.replace(self, seed=self.pose_seed, pose_seed=None))

    def spec(self) -> dict[str, Any]:
        """The catalogue spec, plus ``pose_seed`` where it differs from ``seed`` (so an unchanged scenario keeps
        its catalogue key)."""
        out = super().spec()
        if self.pose_seed is not None and self.pose_seed != self.seed:
            out["pose_seed"] = self.pose_seed
        return out


def seeded_scenario(name: str, seed: int, vary: str = "noise") -> SeededScenario:
    """Scenario ``name`` of the catalogue under study seed ``seed`` (see the module docstring)."""
    if vary not in VARY:
        raise ValueError(f"vary must be one of {', '.join(VARY)}, got {vary!r}")
    base = get_scenario(name)
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(Scenario)}
    fields["seed"] = int(seed)
    return SeededScenario(**fields, pose_seed=base.seed if vary == "noise" else None)


@contextmanager
def rendered(scenario: SeededScenario, variants: Sequence[str], *, cache: bool = False) -> Iterator[dict[str, Path]]:
    """Folders (variant -> folder with the images and truth.json) of ``scenario``'s ``variants``, rendered on this
    machine. Without ``cache``: a temporary folder, removed when the block ends. With ``cache``: the catalogue's
    cache when the seeded scenario is the catalogue's own, else ``cache_root()/study/<name>-<variant>-<key>``
    (rendered once per machine under a lock, folders placed atomically)."""
    variants = list(variants)
    if not cache:
        tmp = Path(tempfile.mkdtemp(prefix=f"circcal-study-{scenario.name}-"))
        try:
            yield render_fixture(scenario, tmp, variants, progress=False)
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
                for v, d in render_fixture(scenario, tmp, missing, progress=False).items():
                    shutil.rmtree(dirs[v], ignore_errors=True)
                    d.replace(dirs[v])
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
    yield dirs
