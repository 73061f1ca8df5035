"""A study's specification: scenarios x variants x seeds x calibrators x lens models, read from YAML.

A study is a list of *cells*; each cell is one kind of run over its axes::

    name: paper-2000
    description: circcal and OpenCV's pipeline on 500 re-noised renders of `paper`, normal and weak light
    cache: false                  # optional: keep rendered fixtures in the content-hash cache (a speed-up only)
    cells:
      - kind: images              # render -> detect -> calibrate (the full pipeline), on the worker
        scenario: paper           # a name from circcal.fixtures.scenarios.SCENARIOS
        variants: [normal, weak]  # default: every variant of the scenario
        vary: noise               # what a seed changes: noise (the scenario's poses, new noise) or scene (both)
        seeds: {start: 0, count: 500}   # or an integer N (0..N-1) or a list of integers
        calibrators: [circcal, opencv]  # see below
        lens_models: [opencv5]    # default [opencv5], the only model today (circcal.study.lens)
      - kind: observations        # solver only: perfect centres of fixed views + Gaussian noise, no rendering
        scenario: paper           # its camera, board and poses; or `geometry:` (below) instead
        noise_px: [0.0023, 0.0146]      # per-coordinate sigma, px: the cell's variants
        seeds: 60                 # seed s draws the noise from numpy.random.default_rng(s)
        calibrators: [circcal, kornia]  # kornia solves each task's runs as one batch (CUDA when present)
        batch: 20                 # runs per task (default 20; observations only)
        device: auto              # kornia's batch device: auto (CUDA when present), cpu or cuda

``geometry`` (observations, instead of ``scenario``)::

    geometry: {name: f1500, camera: {width, height, fx, fy, cx, cy, dist}, board: {rows, cols, pitch_mm,
               diameter_mm, layout}, views: 14, pose_seed: 0, max_tilt_deg: 40}

A calibrator is ``circcal``, a registry name (``opencv``, ``mrcal``, ``kornia``, ``pycolmap``, a plug-in's) or a
mapping ``{name, mode: fair|default, observations: own|circcal}`` (images cells: ``own`` = the reference's own
detector, e.g. OpenCV's findCirclesGrid pipeline, ``circcal`` = circcal's final centres, float32-shared as
``circcal validate`` hands them out), or a user's calibrator ``{plugin: "[LABEL=]MODULE:ATTR"}`` loaded with
:func:`circcal.validators.user_calibrator.load_calibrator` (the interface of the pytest plug-in; use the module form
on a cluster: a file path must exist on every worker).

Every problem in a spec is an :class:`~circcal.errors.InputError` naming the cell and the field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from circcal.errors import InputError
from circcal.study.lens import DEFAULT_LENS_MODEL, check_lens_model

__all__ = [
    "CIRCCAL",
    "KINDS",
    "VARY",
    "CalibratorSpec",
    "CellSpec",
    "Geometry",
    "StudySpec",
    "load_spec",
    "noise_variant",
    "parse_spec",
]

CIRCCAL = "circcal"
KINDS = ("images", "observations")
#: What a seed changes in an images cell: ``noise`` keeps the scenario's own poses and draws new perturbation seeds;
#: ``scene`` draws new poses as well (the seed replaces :attr:`Scenario.seed`, which decides both).
VARY = ("noise", "scene")
DEVICES = ("auto", "cpu", "cuda")
OBSERVATIONS = ("own", "circcal")
#: Runs per task of an observations cell: one solve takes ~10-40 ms, a Dask task costs ~1-3 ms of scheduling and
#: transfer, so 20 runs keep the runner's share under 5 %; images runs are one task per (scenario, seed).
DEFAULT_BATCH = 20
#: A study larger than this is almost certainly a typo in ``seeds`` (10^7 rows of ~100 columns).
MAX_RUNS = 10_000_000


@dataclass(frozen=True)
class CalibratorSpec:
    """One calibrator of a cell.

    Attributes
    ----------
    name : str
        "circcal", a registry name, or a plug-in's label.
    mode : str
        "fair" or "default".
    observations : str
        Images cells only: "own" (its own detector) or "circcal" (circcal's final centres).
    plugin : str or None
        The ``load_calibrator`` spec of a user's calibrator (None for built-ins).
    label : str
        The calibrator's name in rows and tables: ``opencv``, ``mrcal_default``, ``opencv-on-circcal``.
    """

    name: str
    mode: str = "fair"
    observations: str = "own"
    plugin: str | None = None

    @property
    def label(self) -> str:
        """The calibrator's name in rows and tables: ``opencv``, ``mrcal_default``, ``opencv-on-circcal``."""
        out = self.name if self.mode == "fair" else f"{self.name}_{self.mode}"
        return out + ("-on-circcal" if self.observations == "circcal" and self.name != CIRCCAL else "")

    def identity(self) -> dict[str, Any]:
        """What decides this calibrator's results (part of a run's key).

        Returns
        -------
        dict
        """
        return {"name": self.name, "mode": self.mode, "observations": self.observations, "plugin": self.plugin}


@dataclass(frozen=True)
class Geometry:
    """Fixed views for observations cells.

    Attributes
    ----------
    name : str
    camera : dict
        ``circcal.model.Camera.to_dict`` form.
    board : dict
        ``circcal.board.Board.to_dict`` form.
    views : int
        Poses from ``sample_poses(..., pose_seed, ...)``.
    pose_seed : int
    max_tilt_deg, min_tilt_deg : float
        Degrees.
    """

    name: str
    camera: dict[str, Any]
    board: dict[str, Any]
    views: int
    pose_seed: int
    max_tilt_deg: float = 50.0
    min_tilt_deg: float = 0.0

    def identity(self) -> dict[str, Any]:
        """What decides the views (part of a run's key).

        Returns
        -------
        dict
        """
        return {
            "camera": self.camera,
            "board": self.board,
            "views": self.views,
            "pose_seed": self.pose_seed,
            "max_tilt_deg": self.max_tilt_deg,
            "min_tilt_deg": self.min_tilt_deg,
        }


@dataclass(frozen=True)
class CellSpec:
    """One cell of a study (see the module docstring).

    Attributes
    ----------
    index : int
        Position in the spec.
    kind : str
        "images" or "observations".
    scenario : str
    variants : tuple of str
        Scenario variants (images) or :func:`noise_variant` labels of ``noise_px`` (observations).
    seeds : tuple of int
    calibrators : tuple of CalibratorSpec
    lens_models : tuple of str
    vary : str
        Images: "noise" or "scene".
    noise_px : tuple of float
        Observations: per-coordinate sigmas, px.
    geometry : Geometry or None
    batch : int
        Runs per task (observations).
    device : str
        kornia's batch device: "auto", "cpu" or "cuda".
    n_runs : int
        Runs in the cell.
    """

    index: int
    kind: str
    scenario: str
    variants: tuple[str, ...]
    seeds: tuple[int, ...]
    calibrators: tuple[CalibratorSpec, ...]
    lens_models: tuple[str, ...] = (DEFAULT_LENS_MODEL,)
    vary: str = "noise"
    noise_px: tuple[float, ...] = ()
    geometry: Geometry | None = None
    batch: int = DEFAULT_BATCH
    device: str = "auto"

    @property
    def n_runs(self) -> int:
        return len(self.variants) * len(self.seeds) * len(self.calibrators) * len(self.lens_models)


@dataclass(frozen=True)
class StudySpec:
    """A parsed study.

    Attributes
    ----------
    name, description : str
    cells : tuple of CellSpec
    cache : bool
        Keep rendered fixtures in the content-hash cache.
    source : str
        The YAML text it came from (stored beside the results).
    n_runs : int
        Runs in every cell.
    """

    name: str
    description: str
    cells: tuple[CellSpec, ...]
    cache: bool = False
    source: str = field(default="", compare=False)

    @property
    def n_runs(self) -> int:
        return sum(c.n_runs for c in self.cells)


def noise_variant(sigma_px: float) -> str:
    """The variant label of an observations cell's noise level.

    Parameters
    ----------
    sigma_px : float
        Per-coordinate sigma, px.

    Returns
    -------
    str

    Examples
    --------
    >>> noise_variant(0.0023)
    'noise0.0023px'
    """
    return f"noise{sigma_px:g}px"


def load_spec(path: str | Path) -> StudySpec:
    """Read and check a study spec (YAML).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    StudySpec

    Raises
    ------
    circcal.errors.InputError
        Naming the file and the problem (missing, unreadable, not YAML, or a field of a cell).

    Examples
    --------
    >>> spec = load_spec("studies/monte-carlo.yaml")  # doctest: +SKIP
    >>> spec.n_runs  # doctest: +SKIP
    """
    import yaml

    p = Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise InputError(f"study spec {p}: file not found") from None
    except OSError as exc:
        raise InputError(f"study spec {p}: {exc.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InputError(f"study spec {p}: not valid YAML: {exc}") from None
    try:
        return parse_spec(data, source=text, default_name=p.stem)
    except InputError as exc:
        raise InputError(f"study spec {p}: {exc}") from None


def _require(d: dict, key: str, where: str) -> Any:
    if key not in d:
        raise InputError(f"{where}: missing {key!r}")
    return d[key]


def _int(v: Any, where: str, *, minimum: int | None = None) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise InputError(f"{where}: expected an integer, got {v!r}")
    if minimum is not None and v < minimum:
        raise InputError(f"{where}: must be at least {minimum}, got {v}")
    return v


def _seeds(v: Any, where: str) -> tuple[int, ...]:
    if isinstance(v, dict):
        unknown = set(v) - {"start", "count"}
        if unknown:
            raise InputError(f"{where}: unknown key(s) {', '.join(sorted(unknown))} (seeds take start, count)")
        start = _int(v.get("start", 0), f"{where}.start", minimum=0)
        count = _int(_require(v, "count", where), f"{where}.count", minimum=1)
        seeds = tuple(range(start, start + count))
    elif isinstance(v, list):
        seeds = tuple(_int(s, f"{where}[{i}]", minimum=0) for i, s in enumerate(v))
        if not seeds:
            raise InputError(f"{where}: empty list")
    else:
        seeds = tuple(range(_int(v, where, minimum=1)))
    if len(set(seeds)) != len(seeds):
        raise InputError(f"{where}: a seed is listed twice (each seed is one run)")
    return seeds


def _strings(v: Any, where: str) -> tuple[str, ...]:
    items = v if isinstance(v, list) else [v]
    if not items or not all(isinstance(x, str) and x for x in items):
        raise InputError(f"{where}: expected a name or a list of names, got {v!r}")
    if len(set(items)) != len(items):
        raise InputError(f"{where}: a name is listed twice")
    return tuple(items)


def _calibrator(v: Any, where: str, kind: str) -> CalibratorSpec:
    from circcal.validators import registry

    if isinstance(v, str):
        v = {"name": v}
    if not isinstance(v, dict):
        raise InputError(f"{where}: expected a name or a mapping, got {v!r}")
    unknown = set(v) - {"name", "mode", "observations", "plugin"}
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(sorted(unknown))} (name, mode, observations, plugin)")
    mode = v.get("mode", "fair")
    if mode not in ("fair", "default"):
        raise InputError(f"{where}.mode: expected fair or default, got {mode!r}")
    obs = v.get("observations", "own")
    if obs not in OBSERVATIONS:
        raise InputError(f"{where}.observations: expected own or circcal, got {obs!r}")
    plugin = v.get("plugin")
    if plugin is not None:
        from circcal.validators.user_calibrator import calibrator_label, load_calibrator

        try:
            cal = load_calibrator(str(plugin))
        except ValueError as exc:
            raise InputError(f"{where}.plugin: {exc}") from None
        name = str(v.get("name") or calibrator_label(cal))
        return CalibratorSpec(name, mode, obs, str(plugin))
    name = _require(v, "name", where)
    if name != CIRCCAL and name not in registry.names():
        raise InputError(
            f"{where}: unknown calibrator {name!r}; known: {CIRCCAL}, {', '.join(registry.names())} "
            "(or {plugin: MODULE:ATTR} for your own)"
        )
    if name == CIRCCAL and (mode != "fair" or obs != "own"):
        raise InputError(f"{where}: circcal has one mode (fair) and its own observations")
    if kind == "observations" and obs != "own":
        raise InputError(f"{where}.observations: an observations cell gives every calibrator the same points")
    return CalibratorSpec(str(name), mode, obs)


def _geometry(v: Any, where: str) -> Geometry:
    from circcal.board import Board
    from circcal.model import Camera

    if not isinstance(v, dict):
        raise InputError(f"{where}: expected a mapping")
    unknown = set(v) - {"name", "camera", "board", "views", "pose_seed", "max_tilt_deg", "min_tilt_deg"}
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    try:
        cam = Camera.from_dict(_require(v, "camera", where)).to_dict()
        board = Board.from_dict(_require(v, "board", where)).to_dict()
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{where}: {type(exc).__name__}: {exc}") from None
    return Geometry(
        str(v.get("name", "geometry")),
        cam,
        board,
        _int(_require(v, "views", where), f"{where}.views", minimum=3),
        _int(v.get("pose_seed", 0), f"{where}.pose_seed", minimum=0),
        float(v.get("max_tilt_deg", 50.0)),
        float(v.get("min_tilt_deg", 0.0)),
    )


_CELL_KEYS = {
    "kind",
    "scenario",
    "geometry",
    "variants",
    "vary",
    "seeds",
    "calibrators",
    "lens_models",
    "noise_px",
    "batch",
    "device",
}


def _cell(i: int, v: Any) -> CellSpec:
    from circcal.fixtures.scenarios import get_scenario

    where = f"cells[{i}]"
    if not isinstance(v, dict):
        raise InputError(f"{where}: expected a mapping")
    unknown = set(v) - _CELL_KEYS
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    kind = v.get("kind", "images")
    if kind not in KINDS:
        raise InputError(f"{where}.kind: expected images or observations, got {kind!r}")
    seeds = _seeds(_require(v, "seeds", where), f"{where}.seeds")
    cals = v.get("calibrators", [CIRCCAL])
    cals = cals if isinstance(cals, list) else [cals]
    calibrators = tuple(_calibrator(c, f"{where}.calibrators[{j}]", kind) for j, c in enumerate(cals))
    if not calibrators:
        raise InputError(f"{where}.calibrators: empty list")
    labels = [c.label for c in calibrators]
    if len(set(labels)) != len(labels):
        raise InputError(f"{where}.calibrators: a calibrator is listed twice ({', '.join(labels)})")
    lens = tuple(
        check_lens_model(m) for m in _strings(v.get("lens_models", [DEFAULT_LENS_MODEL]), f"{where}.lens_models")
    )
    if kind == "images":
        for k in ("geometry", "noise_px", "batch", "device"):
            if k in v:
                raise InputError(f"{where}.{k}: only for observations cells")
        sc = get_scenario(_require(v, "scenario", where))
        variants = _strings(v.get("variants", list(sc.variants)), f"{where}.variants")
        for name in variants:
            if name not in sc.variants:
                raise InputError(
                    f"{where}.variants: scenario {sc.name!r} has no variant {name!r}; variants: "
                    f"{', '.join(sc.variants)}"
                )
        vary = v.get("vary", "noise")
        if vary not in VARY:
            raise InputError(f"{where}.vary: expected noise or scene, got {vary!r}")
        return CellSpec(i, kind, sc.name, variants, seeds, calibrators, lens, vary)
    for k in ("variants", "vary"):
        if k in v:
            raise InputError(f"{where}.{k}: only for images cells (observations cells vary noise_px)")
    if ("scenario" in v) == ("geometry" in v):
        raise InputError(f"{where}: give a scenario or a geometry (one of them)")
    geometry = _geometry(v["geometry"], f"{where}.geometry") if "geometry" in v else None
    scenario = geometry.name if geometry is not None else get_scenario(v["scenario"]).name
    noise = v.get("noise_px")
    noise = noise if isinstance(noise, list) else [noise]
    try:
        sigmas = tuple(float(s) for s in noise)
    except (TypeError, ValueError):
        raise InputError(
            f"{where}.noise_px: expected a number or a list of numbers, got {v.get('noise_px')!r}"
        ) from None
    if not sigmas or not all(0 < s < float("inf") for s in sigmas) or len(set(sigmas)) != len(sigmas):
        raise InputError(f"{where}.noise_px: expected distinct finite numbers above 0 (px), got {v.get('noise_px')!r}")
    device = v.get("device", "auto")
    if device not in DEVICES:
        raise InputError(f"{where}.device: expected auto, cpu or cuda, got {device!r}")
    batch = _int(v.get("batch", DEFAULT_BATCH), f"{where}.batch", minimum=1)
    return CellSpec(
        i,
        kind,
        scenario,
        tuple(noise_variant(s) for s in sigmas),
        seeds,
        calibrators,
        lens,
        noise_px=sigmas,
        geometry=geometry,
        batch=batch,
        device=device,
    )


def parse_spec(data: Any, *, source: str = "", default_name: str = "study") -> StudySpec:
    """A :class:`StudySpec` from parsed YAML (see the module docstring).

    Parameters
    ----------
    data : object
        The parsed YAML.
    source : str
        The YAML text (stored in the spec).
    default_name : str
        The name when the spec gives none.

    Returns
    -------
    StudySpec

    Raises
    ------
    circcal.errors.InputError
        Naming the cell and the field of every problem.
    """
    if not isinstance(data, dict):
        raise InputError("expected a mapping with name and cells")
    unknown = set(data) - {"name", "description", "cache", "cells"}
    if unknown:
        raise InputError(f"unknown key(s) {', '.join(sorted(unknown))} (name, description, cache, cells)")
    cells = data.get("cells")
    if not isinstance(cells, list) or not cells:
        raise InputError("cells: expected a non-empty list")
    name = str(data.get("name", default_name))
    if not name or not all(ch.isalnum() or ch in "-_." for ch in name):
        raise InputError(f"name: letters, digits, '-', '_' and '.' only, got {name!r}")
    cache = data.get("cache", False)
    if not isinstance(cache, bool):
        raise InputError(f"cache: expected true or false, got {cache!r}")
    spec = StudySpec(
        name, str(data.get("description", "")), tuple(_cell(i, c) for i, c in enumerate(cells)), cache, source
    )
    if spec.n_runs > MAX_RUNS:
        raise InputError(f"{spec.n_runs} runs: more than {MAX_RUNS} (check seeds)")
    return spec
