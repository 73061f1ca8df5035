"""How a calibration is made: :class:`CalibrationOptions`, one frozen object that goes from the command line to the
pipeline, the solver, the cross-validation and the validators unchanged (each one reads the fields it needs).

It is checked once, when it is built (:meth:`CalibrationOptions.__post_init__`): an unknown lens model, a parameter
the lens model does not have (``fixed=("p1",)`` with the fisheye), an unknown solver or a bad number is an
:class:`~circcal.errors.InputError` naming the option, before any image is read. Variants are derived, never
edited: ``options.replace(refine_board=True)`` (:func:`dataclasses.replace`, checked again).

Holds are parameter names (:func:`circcal.model.param_names` of the lens: ``fx, fy, cx, cy`` and the distortion
coefficients) plus the relation ``"aspect_ratio"`` (fx / fy held; fx is then ``aspect * fy``, so it cannot be held
by itself as well). ``"tangential"`` and ``"principal_point"`` name the pairs (p1, p2) and (cx, cy). The value a
parameter is held at is the initial camera's (``calibrate(initial=...)``), else its default: 0 for a distortion
coefficient, the image centre ((w-1)/2, (h-1)/2) for cx and cy, 1 for the aspect ratio; fx and fy have no default
and are held only with an initial camera. With a held aspect ratio, neither fx nor fy can be held as well. The command line's flags map onto holds through :data:`FLAG_HOLDS`
(:meth:`CalibrationOptions.from_flags`).
"""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Literal

from circcal.errors import InputError
from circcal.model import DEFAULT_LENS, lens_model
from circcal.solver.outliers import OutlierRule

__all__ = ["ASPECT_RATIO", "FLAG_HOLDS", "GROUPS", "MAX_ITERATIONS", "SOLVERS", "CalibrationOptions", "Solver"]

#: The least-squares solvers: ``"schur"`` (Levenberg-Marquardt with Schur-complement steps,
#: :func:`circcal.solver.lm.levenberg_marquardt`) and ``"scipy"`` (``scipy.optimize.least_squares``, a cross-check).
SOLVERS: tuple[str, ...] = ("schur", "scipy")
Solver = Literal["schur", "scipy"]
#: The relation fx / fy, held by name beside the parameters.
ASPECT_RATIO = "aspect_ratio"
#: Names of pairs of parameters held together.
GROUPS: dict[str, tuple[str, ...]] = {"tangential": ("p1", "p2"), "principal_point": ("cx", "cy")}
#: The command line's ``--fix-*`` flags (keywords of :meth:`CalibrationOptions.from_flags`) -> what each holds.
FLAG_HOLDS: dict[str, tuple[str, ...]] = {
    "fix_k2": ("k2",),
    "fix_k3": ("k3",),
    "fix_tangential": GROUPS["tangential"],
    "fix_aspect_ratio": (ASPECT_RATIO,),
    "fix_principal_point": GROUPS["principal_point"],
}
#: Jacobian evaluations a solve may take by default.
MAX_ITERATIONS = 200


def _is_int(x: Any) -> bool:
    return isinstance(x, numbers.Integral) and not isinstance(x, bool)


@dataclass(frozen=True)
class CalibrationOptions:
    """How a calibration is made (see the module); frozen: derive variants with :meth:`replace`.

    Parameters
    ----------
    lens : str
        The lens model fitted: a :data:`circcal.model.LENS_MODELS` name (default ``"opencv5"``: OpenCV's pinhole +
        ``[k1, k2, p1, p2, k3]``).
    fixed : iterable of str
        Parameters held during the solve, by name: the lens model's :func:`~circcal.model.param_names`,
        ``"aspect_ratio"`` (fx / fy held), ``"tangential"`` (p1, p2), ``"principal_point"`` (cx, cy). Stored
        expanded, without repeats, in the order ``aspect_ratio`` then the lens model's parameter order (a tuple).
    refine_board : bool
        Also estimate the 3-D position of every board point (the object-releasing method, like
        ``cv2.calibrateCameraRO``); see :func:`circcal.solver.calibrate`.
    board_warp : bool
        Also estimate mrcal's 2-parameter board warp (``calobject_warp``: a parabolic sag along the board's x and y
        axes, :func:`circcal.solver.problem.warp_basis`); not with ``refine_board`` (which frees every point).
    board_gauge : tuple of 3 int or None
        With ``refine_board``: the indices of the three board points (in order of first appearance across the
        views) that fix the board's frame and scale; None chooses them (see :func:`circcal.solver.calibrate`).
    solver : {"schur", "scipy"}
        The least-squares solver (:data:`SOLVERS`).
    max_iterations : int
        Jacobian evaluations a solve may take (> 0); reaching it warns and returns ``converged=False``.
    outlier_rule : OutlierRule or None
        Reject outlying points and views by this rule (:class:`circcal.solver.outliers.OutlierRule`; the pipeline
        then also leaves out the detector's bad dots); None fits every observation, as every reference does.

    Raises
    ------
    InputError
        One line naming the option: an unknown lens model, a hold the lens model does not have, fx or fy held
        together with the aspect ratio, ``fixed`` not names, ``board_warp`` with ``refine_board``, an unknown solver, a non-positive ``max_iterations``, a ``board_gauge`` that
        is not three point indices, an ``outlier_rule`` that is not an :class:`OutlierRule`.
    """

    lens: str = DEFAULT_LENS
    fixed: tuple[str, ...] = ()
    refine_board: bool = False
    board_warp: bool = False
    board_gauge: tuple[int, int, int] | None = None
    solver: Solver = "schur"
    max_iterations: int = MAX_ITERATIONS
    outlier_rule: OutlierRule | None = None

    def __post_init__(self) -> None:
        model = lens_model(self.lens)  # InputError naming the known models
        object.__setattr__(self, "fixed", _holds(self.fixed, self.lens, model.param_names))
        if not isinstance(self.refine_board, bool):
            raise InputError(f"refine_board must be True or False, got {self.refine_board!r}")
        if not isinstance(self.board_warp, bool):
            raise InputError(f"board_warp must be True or False, got {self.board_warp!r}")
        if self.board_warp and self.refine_board:
            raise InputError(
                "board_warp and refine_board: the refined board frees every point's position, the warp is its "
                "2-parameter special case; give one of them"
            )
        if self.board_gauge is not None:
            g = self.board_gauge
            if (
                isinstance(g, (str, bytes))
                or not hasattr(g, "__len__")
                or len(g) != 3
                or not all(_is_int(i) and i >= 0 for i in g)
            ):
                raise InputError(f"board_gauge must be three board point indices (non-negative integers), got {g!r}")
            object.__setattr__(self, "board_gauge", tuple(int(i) for i in g))
        if self.solver not in SOLVERS:
            raise InputError(f"solver must be one of {', '.join(SOLVERS)}, got {self.solver!r}")
        if not (_is_int(self.max_iterations) and self.max_iterations > 0):
            raise InputError(f"max_iterations must be a positive integer, got {self.max_iterations!r}")
        if self.outlier_rule is not None and not isinstance(self.outlier_rule, OutlierRule):
            raise InputError(f"outlier_rule must be an OutlierRule or None, got {type(self.outlier_rule).__name__}")

    @classmethod
    def from_flags(
        cls,
        *,
        fix_k2: bool = False,
        fix_k3: bool = False,
        fix_tangential: bool = False,
        fix_aspect_ratio: bool = False,
        fix_principal_point: bool = False,
        spell: Callable[[str], str] = str,
        **options: Any,
    ) -> CalibrationOptions:
        """The options of the command line's flags.

        Parameters
        ----------
        fix_k2, fix_k3, fix_tangential, fix_aspect_ratio, fix_principal_point : bool
            Each that is true holds what :data:`FLAG_HOLDS` says.
        spell : callable, str -> str
            How an error names a flag (e.g. ``fix_k3`` -> ``--fix-k3``).
        **options
            The other fields (``lens``, ``refine_board``, ...).

        Returns
        -------
        CalibrationOptions

        Raises
        ------
        InputError
            A flag that holds what the lens model does not have (``fix_tangential`` with the fisheye), named by the
            flag; or any field's error (see the class).

        Examples
        --------
        >>> CalibrationOptions.from_flags(fix_k3=True, lens="opencv5").holds("k3")
        True
        """
        flags = dict(
            fix_k2=fix_k2,
            fix_k3=fix_k3,
            fix_tangential=fix_tangential,
            fix_aspect_ratio=fix_aspect_ratio,
            fix_principal_point=fix_principal_point,
        )
        lens = options.get("lens", DEFAULT_LENS)
        names = lens_model(lens).param_names
        fixed: list[str] = []
        for flag, on in flags.items():
            if not on:
                continue
            missing = [n for n in FLAG_HOLDS[flag] if n != ASPECT_RATIO and n not in names]
            if missing:
                raise InputError(f"{spell(flag)}: the {lens} lens model has no {', '.join(missing)} to hold fixed")
            fixed += FLAG_HOLDS[flag]
        return cls(fixed=tuple(fixed), **options)

    def replace(self, **changes: Any) -> CalibrationOptions:
        """A copy with ``changes`` (:func:`dataclasses.replace`), checked like a new one.

        Parameters
        ----------
        **changes
            Field -> value.

        Returns
        -------
        CalibrationOptions

        Raises
        ------
        InputError
            A field's error (see the class).
        """
        return dataclasses.replace(self, **changes)

    def holds(self, name: str) -> bool:
        """Whether a parameter is held.

        Parameters
        ----------
        name : str
            A parameter name of the lens model, or ``"aspect_ratio"``.

        Returns
        -------
        bool
        """
        return name in self.fixed

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary.

        Returns
        -------
        dict
            ``lens``, ``fixed``, ``refine_board``, ``board_warp``, ``board_gauge``, ``solver``, ``max_iterations``, ``outlier_rule`` (the
            rule's numbers, or None).
        """
        r = self.outlier_rule
        return {
            "lens": self.lens,
            "fixed": list(self.fixed),
            "refine_board": self.refine_board,
            "board_warp": self.board_warp,
            "board_gauge": None if self.board_gauge is None else list(self.board_gauge),
            "solver": self.solver,
            "max_iterations": self.max_iterations,
            "outlier_rule": None if r is None else dataclasses.asdict(r),
        }


def _holds(fixed: Iterable[str] | str, lens: str, names: tuple[str, ...]) -> tuple[str, ...]:
    """``fixed`` expanded (:data:`GROUPS`), checked against the lens model's parameter ``names`` and ordered:
    ``aspect_ratio`` first, then ``names``' order."""
    if isinstance(fixed, str):
        fixed = (fixed,)
    try:
        given = list(fixed)
    except TypeError:
        raise InputError(f"fixed must be parameter names, got {type(fixed).__name__}") from None
    for name in given:
        if not isinstance(name, str):
            raise InputError(f"fixed must be parameter names, got {name!r}")
    expanded = [n for name in given for n in GROUPS.get(name, (name,))]
    unknown = [n for n in dict.fromkeys(expanded) if n != ASPECT_RATIO and n not in names]
    if unknown:
        raise InputError(
            f"fixed: the {lens} lens model has no {', '.join(n if n.isidentifier() else repr(n) for n in unknown)} to hold "
            f"fixed; it has "
            f"{', '.join(names)}, {', '.join(_named_groups(names))}"
        )
    wanted = set(expanded)
    if ASPECT_RATIO in wanted and wanted & {"fx", "fy"}:
        raise InputError(
            f"fixed: {ASPECT_RATIO} ties fx to fy (fx = aspect * fy) and cannot be held together with "
            f"{' or '.join(sorted(wanted & {'fx', 'fy'}))}"
        )
    return tuple(n for n in (ASPECT_RATIO, *names) if n in wanted)


def _named_groups(names: tuple[str, ...]) -> list[str]:
    """``aspect_ratio`` and the :data:`GROUPS` whose every parameter is among ``names``."""
    return [ASPECT_RATIO] + [g for g, members in GROUPS.items() if all(n in names for n in members)]
