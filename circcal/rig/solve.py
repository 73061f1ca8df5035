"""The joint rig solve: Levenberg-Marquardt on a :class:`~circcal.rig.problem.RigProblem` and the first-order
covariance of its intrinsics and extrinsics.

The solver is the single-camera one (:func:`circcal.solver.lm.levenberg_marquardt`): each damped step is solved
exactly by eliminating the 6x6 board-pose blocks, one per instant. The covariance is the single camera's
(:mod:`circcal.solver.covariance`): ``sigma^2 S^-1`` with ``S`` the Schur complement of the board-pose blocks in
``J^T J`` (board poses marginalised) and ``sigma^2 = SSR / (2N - n)`` the residual variance per coordinate, mapped
from the free parameters onto :meth:`circcal.rig.model.RigModel.state_vector`'s order (every camera's intrinsics in
``Camera.intrinsics`` order, then every camera's ``rvec, tvec`` but the reference's; a held parameter has zero
variance). Where the information is singular only in some directions (a rational camera's coefficients trading
off), :func:`determined_covariance` still gives the parameters independent of those directions their marginal
covariance (the pseudo-inverse's), NaN for the others.
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
    "determined_covariance",
    "marginal_covariance",
    "weakest_direction",
    "NULL_SHARE",
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
    return _to_state(prob, cov_free)


def _to_state(prob: RigProblem, cov_free: np.ndarray) -> np.ndarray:
    """The covariance of the free global parameters mapped onto ``RigModel.state_vector``'s order (held: 0); a
    free parameter's NaN row and column (undetermined) makes NaN the rows and columns of what it maps onto."""
    sizes = [len(b) for b in prob.base]
    n_state = sum(sizes) + 6 * (prob.n_cameras - 1)
    T = np.zeros((n_state, prob.ng))
    row = 0
    for c, size in enumerate(sizes):
        T[row : row + size, prob.intr_cols[c]] = prob.maps[c]
        row += size
    T[row:, prob.nf :] = np.eye(6 * (prob.n_cameras - 1))
    unknown = np.isnan(np.diag(cov_free))
    C = T @ (np.where(unknown[:, None] | unknown[None, :], 0.0, cov_free) if unknown.any() else cov_free) @ T.T
    sym: np.ndarray = 0.5 * (C + C.T)
    if unknown.any():  # 0 x NaN would be NaN for a held parameter too: only what the NaN ones map onto
        rows = np.any(T[:, unknown] != 0, axis=1)
        sym[rows, :] = np.nan
        sym[:, rows] = np.nan
    return sym


#: Where the information is singular: a parameter whose direction (in the information normalised to a unit
#: diagonal) has at most this share of its square in the null space is independent of it and keeps its marginal
#: variance: the free combination would have to move by 1000 of its own sigmas (conditional, normalised) to move the
#: parameter by one of its own. Rounding leaves components far below it (1e-7 at most, a share of 1e-13, on the
#: rational camera of tests/test_rig_undetermined.py), and the parameters the null space is made of are far above
#: (a share of 0.02-0.3 each); a rendered toe-in rig's opencv5 + rational pair puts its two cx and the rotation
#: about y above it (components 1.5-3.7e-3: a principal point shifting with a turn), its T and focal lengths below.
NULL_SHARE = 1e-6


def determined_covariance(prob: RigProblem, x: np.ndarray, sigma2: float) -> np.ndarray | None:
    """:func:`state_covariance`, and where the information is singular only in some directions, the marginal
    covariance of the parameters independent of those directions, NaN for the others.

    The null space is the eigenvectors of the normalised information whose eigenvalues are below the largest over
    :data:`MAX_INFORMATION_CONDITION` (the rule that makes :func:`state_covariance` None) or below the magnitude of
    its most negative one (an information matrix has none: rounding made it, and nothing smaller is told from 0); a
    parameter with a share above :data:`NULL_SHARE` of its direction there is undetermined (its row and column
    NaN). The others' covariance is the pseudo-inverse's: the covariance of the estimable functions, which does not
    depend on how the undetermined combination is pinned.

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
        (n_state, n_state) in ``RigModel.state_vector`` order: :func:`state_covariance`'s where the information is
        regular (the same array), else with NaN rows and columns for the undetermined parameters (a held one
        keeps 0); None where no eigen-decomposition is possible (non-finite information).
    """
    full = state_covariance(prob, x, sigma2)
    if full is not None:
        return full
    A, _, B, D, _ = prob.normal_equations(x)[1]
    try:
        S = schur_complement(A, B, D)[0]
    except np.linalg.LinAlgError:
        return None
    cov_free = marginal_covariance(S, sigma2)
    return None if cov_free is None else _to_state(prob, cov_free)


def marginal_covariance(S: np.ndarray, sigma2: float) -> np.ndarray | None:
    """``sigma2 S^-1`` of an information matrix singular in some directions, for the parameters independent of them.

    Parameters
    ----------
    S : ndarray, shape (k, k)
        The information (``J^T J``, board poses marginalised), symmetric positive semi-definite.
    sigma2 : float
        The residual variance per coordinate, px^2.

    Returns
    -------
    ndarray or None
        (k, k): ``sigma2`` times the pseudo-inverse of ``S`` (eigenvalues of its unit-diagonal form below the
        largest over :data:`MAX_INFORMATION_CONDITION`, or below the magnitude of the most negative one, dropped),
        with NaN rows and columns for each parameter whose direction has more than :data:`NULL_SHARE` of its square
        in the dropped eigenvectors; None where ``S`` is not finite or has a non-positive diagonal entry (no
        direction can be told from another).
    """
    S = 0.5 * (S + S.T)
    d = np.diag(S)
    if not (np.all(np.isfinite(S)) and np.all(d > 0)):
        return None
    scale = np.sqrt(d)
    Sn = S / np.outer(scale, scale)
    try:
        w, V = np.linalg.eigh(0.5 * (Sn + Sn.T))
    except np.linalg.LinAlgError:
        return None
    null = w <= max(w[-1] / MAX_INFORMATION_CONDITION, -w[0])  # below rounding's negative eigenvalues: noise
    kept = ~null
    pinv = (V[:, kept] / w[kept]) @ V[:, kept].T
    cov = sigma2 * pinv / np.outer(scale, scale)
    free = np.sum(V[:, null] ** 2, axis=1) > NULL_SHARE
    cov[free, :] = np.nan
    cov[:, free] = np.nan
    out: np.ndarray = cov
    return out
