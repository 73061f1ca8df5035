"""The joint rig solve: Levenberg-Marquardt on a :class:`~circcal.rig.problem.RigProblem` and the first-order
covariance of its intrinsics and extrinsics.

The solver is the single-camera one (:func:`circcal.solver.lm.levenberg_marquardt`): each damped step is solved
exactly by eliminating the 6x6 board-pose blocks, one per instant. The covariance is the single camera's
(:mod:`circcal.solver.covariance`): ``sigma^2 S^-1`` with ``S`` the Schur complement of the board-pose blocks in
``J^T J`` (board poses marginalised) and ``sigma^2 = SSR / (2N - n)`` the residual variance per coordinate, mapped
from the free parameters onto :meth:`circcal.rig.model.RigModel.state_vector`'s order (every camera's intrinsics in
``Camera.intrinsics`` order, then every camera's ``rvec, tvec`` but the reference's; a held parameter has zero
variance).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from circcal.errors import CalibrationError
from circcal.model import lens_model
from circcal.rig.problem import RigProblem
from circcal.solver.covariance import normalised_information
from circcal.solver.lm import levenberg_marquardt, schur_complement

if TYPE_CHECKING:  # annotations only
    from circcal.solver.problem import Problem

__all__ = [
    "RigSolution",
    "solve_rig",
    "state_covariance",
    "weakest_direction",
    "MAX_INFORMATION_CONDITION",
    "WEAKEST_SHARE",
]

#: The global information matrix (normalised to a unit diagonal) is taken as singular beyond this condition number,
#: as for one camera (:data:`circcal.solver.calibrate.MAX_INFORMATION_CONDITION`).
MAX_INFORMATION_CONDITION = 1e14


@dataclass(frozen=True)
class RigSolution:
    """A solved rig problem.

    Attributes
    ----------
    x : ndarray, shape (n,)
        The solution (:class:`~circcal.rig.problem.RigProblem`'s layout).
    residuals : ndarray, shape (N, 2)
        Projected - observed, px, camera by camera.
    sigma_px : float
        sqrt(SSR / (2N - n)): the per-coordinate noise estimate, px.
    covariance : ndarray or None
        (n_state, n_state) in ``RigModel.state_vector`` order, scaled by ``sigma_px^2``; None when the information on
        the global parameters is singular.
    iterations : int
    converged : bool
    message : str
    undetermined : tuple of (int, str)
        Where ``covariance`` is None: the parameters that carry the information's weakest direction
        (:func:`weakest_direction`), e.g. ``(1, "k4")``; empty otherwise.
    """

    x: np.ndarray
    residuals: np.ndarray
    sigma_px: float
    covariance: np.ndarray | None
    iterations: int
    converged: bool
    message: str
    undetermined: tuple[tuple[int, str], ...] = ()


def solve_rig(prob: RigProblem, x0: np.ndarray, max_iterations: int) -> RigSolution:
    """Solve ``prob`` from ``x0`` and estimate the covariance.

    Parameters
    ----------
    prob : RigProblem
    x0 : ndarray, shape (n,)
        The start (:func:`circcal.rig.start.rig_start`).
    max_iterations : int
        Jacobian evaluations at most.

    Returns
    -------
    RigSolution

    Raises
    ------
    CalibrationError
        Fewer residuals than parameters, a diverged solve (non-finite values, a non-positive focal length) or points
        a camera cannot see at the solution (named by camera and instant index).
    """
    m = 2 * prob.n_points
    if m <= prob.n:
        raise CalibrationError(f"{m} residuals for {prob.n} parameters: add instants or points")
    x, iterations, converged, message = levenberg_marquardt(cast("Problem", prob), x0, max_iterations, near=True)
    f = prob.residuals(x)[0]
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(f))):
        raise CalibrationError("the rig solve diverged (non-finite parameters or residuals)")
    for c in range(prob.n_cameras):
        p = prob.intrinsics(x, c)
        if p[0] <= 0 or p[1] <= 0:
            raise CalibrationError(f"the rig solve diverged: camera {c} has a non-positive focal length")
    bad = prob.outside(x)
    if bad:
        raise CalibrationError(
            "the rig solve diverged: board points behind a camera or beyond its field at (camera, instant) "
            + ", ".join(f"({c}, {v})" for c, v in bad[:10])
        )
    sigma2 = float(f @ f) / (m - prob.n)
    covariance = state_covariance(prob, x, sigma2)
    return RigSolution(
        x=x,
        residuals=f.reshape(-1, 2),
        sigma_px=float(np.sqrt(sigma2)),
        covariance=covariance,
        iterations=int(iterations),
        converged=bool(converged),
        message=message,
        undetermined=() if covariance is not None else tuple(weakest_direction(prob, x)),
    )


#: A parameter carrying at least this share of the weakest direction (unit vector, squared components) is named.
WEAKEST_SHARE = 0.05


def weakest_direction(prob: RigProblem, x: np.ndarray) -> list[tuple[int, str]]:
    """The global parameters that carry the weakest direction of the rig's information (board poses marginalised,
    normalised to a unit diagonal): what the views leave undetermined when the information is singular.

    Parameters
    ----------
    prob : RigProblem
    x : ndarray, shape (n,)

    Returns
    -------
    list of (int, str)
        (camera index, the lens model's parameter name or ``rvec``/``tvec`` of its pose in the rig) for each share
        of at least :data:`WEAKEST_SHARE`, largest first; empty where the information has no finite eigenvector.
    """
    A, _, B, D, _ = prob.normal_equations(x)[1]
    try:
        Sn = normalised_information(schur_complement(A, B, D)[0])[0]
        vec = np.linalg.eigh(0.5 * (Sn + Sn.T))[1][:, 0]
    except np.linalg.LinAlgError:
        return []
    if not np.all(np.isfinite(vec)):
        return []
    labels: list[tuple[int, str]] = [(0, "")] * prob.ng
    for c in range(prob.n_cameras):
        names = lens_model(prob.lenses[c]).param_names
        for j, col in enumerate(prob.intr_cols[c]):
            labels[int(col)] = (c, names[int(np.flatnonzero(prob.maps[c][:, j])[-1])])
        for j, col in enumerate(prob.pose_cols[c]):
            labels[int(col)] = (c, "rvec" if j < 3 else "tvec")
    share = vec**2
    order = np.argsort(-share)
    return [labels[i] for i in order if share[i] >= WEAKEST_SHARE]


def state_covariance(prob: RigProblem, x: np.ndarray, sigma2: float) -> np.ndarray | None:
    """The covariance of every camera's intrinsics and every camera's pose in the rig, board poses marginalised.

    Parameters
    ----------
    prob : RigProblem
    x : ndarray, shape (n,)
        The solution.
    sigma2 : float
        The residual variance per coordinate, px^2.

    Returns
    -------
    ndarray or None
        (n_state, n_state) in ``RigModel.state_vector`` order (intrinsics px and unitless, rvec rad, tvec mm); None
        when the information matrix is singular (condition beyond :data:`MAX_INFORMATION_CONDITION`).
    """
    A, _, B, D, _ = prob.normal_equations(x)[1]
    try:
        S = schur_complement(A, B, D)[0]
    except np.linalg.LinAlgError:
        return None
    Sn, scale, cond = normalised_information(S)
    if not cond <= MAX_INFORMATION_CONDITION:
        return None
    cov_free = sigma2 * np.linalg.inv(Sn) / np.outer(scale, scale)
    sizes = [len(b) for b in prob.base]
    n_state = sum(sizes) + 6 * (prob.n_cameras - 1)
    T = np.zeros((n_state, prob.ng))
    row = 0
    for c, size in enumerate(sizes):
        T[row : row + size, prob.intr_cols[c]] = prob.maps[c]
        row += size
    T[row:, prob.nf :] = np.eye(6 * (prob.n_cameras - 1))
    C = T @ cov_free @ T.T
    sym: np.ndarray = 0.5 * (C + C.T)
    return sym
