"""Levenberg-Marquardt for a :class:`~circcal.solver.problem.Problem`, each damped step solved exactly by
eliminating the 6x6 pose blocks (Schur complement), as OpenCV's calibrateCamera does; ``scipy.optimize.least_squares``
(TRF, sparse Jacobian, LSMR) on the same residuals and Jacobian as an independent cross-check (:func:`solve`).

The normal equations ``J^T J`` split into the global block A (intrinsics and board coordinates), the per-view
coupling B_v and the pose blocks D_v; ``S = A - sum B_v D_v^-1 B_v^T`` is also the information on the global
parameters with the poses marginalised (the covariance uses it).
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # annotations only
    from circcal.solver.problem import Problem

__all__ = [
    "schur_complement",
    "global_information",
    "schur_step",
    "quadratic_form",
    "levenberg_marquardt",
    "geometric_extension",
    "solve",
    "is_sane",
]

#: Marquardt damping ``lambda`` (times diag(J^T J)) at the start; measured best here: the closed-form start is near
#: the minimum, so the first steps are nearly Gauss-Newton's (22 -> 11-13 evaluations on 14 views).
LAMBDA_START = 1e-4
#: lambda at a start near the minimum (``near``: the rig's), its first steps nearly Gauss-Newton's: measured on the
#: rendered rigs (3 noise levels each) and the real 3-camera data, the same minima (1e-9 deg) in 1-3 fewer
#: evaluations than from LAMBDA_START (bench_rig's 16 instants: 6, not 8). 1e-8 sent the `two` rig's rational
#: camera down its coefficients' valley at 0.3 px noise (not converged in 200), 1e-7 cost it 60 evaluations, not 42.
#: A first step rejected goes on from LAMBDA_START at once.
LAMBDA_NEAR = 1e-6
#: Factor by which lambda grows after a rejected step and shrinks after an accepted one.
LAMBDA_FACTOR = 10.0
#: Bounds of lambda: below LAMBDA_MIN it does not matter; beyond LAMBDA_MAX no step lowers the cost ("stalled").
LAMBDA_MIN = 1e-12
LAMBDA_MAX = 1e12
#: At or below this lambda the damped step is Gauss-Newton's to ~1e-5: the quadratic model may be trusted.
LAMBDA_GAUSS_NEWTON = 1e-5
#: The quadratic model is trusted once a step's predicted decrease is below this share of the cost (the cost's own
#: rounding, ~1e-16 relative on sums of ~10^3 squares, can no longer rank such steps).
TRUST_MODEL_REL = 1e-10
#: A trusted step predicting less than this share of the cost is the last: nothing left above rounding.
FINAL_STEP_REL = 1e-18
#: A trusted step may raise the cost by this share (its rounding) and still be taken.
COST_ROUNDING_REL = 1e-12
#: After this many trial steps taken in a row the next trial is evaluated with its Jacobian (it is likely taken
#: too); otherwise by its residuals alone (rejections come in runs while lambda searches).
ACCEPTED_RUN = 2
#: Two steps one after the other whose directions (scaled by sqrt(diag J^T J)) agree to this cosine, the second
#: shorter by q < 1, are taken as a geometric sequence (damped steps crawling along a narrow valley, or
#: Gauss-Newton's linear rate near a minimum with residuals: each step covers the same share of what is left) and
#: the step is extended to the sequence's limit, ``step / (1 - q)``, at most EXTRAPOLATE_MAX times.
EXTRAPOLATE_COS = 0.99
EXTRAPOLATE_MAX = 2.0
#: Converged when every gradient component, scaled by the sqrt of its J^T J diagonal, is within
#: GRADIENT_TOL * sqrt(cost) + GRADIENT_FLOOR (a stalled solve that is not at a minimum fails this).
GRADIENT_TOL = 1e-6
GRADIENT_FLOOR = 1e-12


def schur_complement(
    A: np.ndarray, B: np.ndarray, D: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eliminate the 6x6 pose blocks: ``S = A - sum_v B_v D_v^-1 B_v^T``.

    The 6x6 blocks are inverted, as OpenCV's solver does (one batched inverse and product: half the time of a batched
    solve with ng + 1 right-hand sides).

    Parameters
    ----------
    A : ndarray
        (ng, ng) global block of ``J^T J`` (:meth:`Problem.normal_equations`).
    B : ndarray
        (V, ng, 6) per-view coupling blocks.
    D : ndarray
        (V, 6, 6) pose blocks.

    Returns
    -------
    S : ndarray
        (ng, ng) the Schur complement.
    D_inv : ndarray
        (V, 6, 6) ``D_v^-1``.
    Dinv_Bt : ndarray
        (V, 6, ng) ``D_v^-1 B_v^T``.
    Bf : ndarray
        (ng, 6V) ``[B_1 ... B_V]``, for the back-substitution.

    Raises
    ------
    numpy.linalg.LinAlgError
        A singular pose block.
    """
    ng, V = A.shape[0], len(D)
    D_inv = np.linalg.inv(D)
    Dinv_Bt = D_inv @ np.transpose(B, (0, 2, 1))
    Bf = np.transpose(B, (1, 0, 2)).reshape(ng, 6 * V)
    return A - Bf @ Dinv_Bt.reshape(6 * V, ng), D_inv, Dinv_Bt, Bf


def global_information(prob: Problem, x: np.ndarray) -> np.ndarray:
    """The information on the global parameters with the poses marginalised.

    Parameters
    ----------
    prob : Problem
    x : ndarray
        (n,) the parameter vector (:class:`~circcal.solver.problem.Problem`'s layout).

    Returns
    -------
    ndarray
        (ng, ng) the symmetrised Schur complement of the pose blocks in ``J^T J`` at ``x`` (free intrinsics, then
        any board coordinates).
    """
    A, _, B, D, _ = prob.normal_equations(x)[1]
    S = schur_complement(A, B, D)[0]
    sym: np.ndarray = 0.5 * (S + S.T)
    return sym


def schur_step(A: np.ndarray, gi: np.ndarray, B: np.ndarray, D: np.ndarray, gp: np.ndarray, lam: float) -> np.ndarray:
    """Solve ``(J^T J + lam diag(J^T J)) step = -J^T f`` by eliminating the 6x6 pose blocks.

    Parameters
    ----------
    A, gi, B, D, gp : ndarray
        The blocks of :meth:`Problem.normal_equations`: A (ng, ng), gi (ng,), B (V, ng, 6), D (V, 6, 6), gp (V, 6).
    lam : float
        Marquardt damping (times the diagonal); 0 for Gauss-Newton.

    Returns
    -------
    ndarray
        (ng + 6V,) the step: global part, then each view's (rvec, tvec); all NaN when the reduced system is singular.
    """
    if lam:
        A = A + lam * np.diag(np.diag(A))
        D = D + lam * np.diagonal(D, axis1=1, axis2=2)[:, :, None] * np.eye(6)
    S, D_inv, Dinv_Bt, Bf = schur_complement(A, B, D)
    Dinv_g = (D_inv @ gp[:, :, None])[:, :, 0]  # (V, 6)
    r = gi - Bf @ Dinv_g.ravel()
    try:
        di = -np.linalg.solve(S, r)
    except np.linalg.LinAlgError:
        return np.full(A.shape[0] + 6 * len(D), np.nan)
    dp = -Dinv_g - np.einsum("vab,b->va", Dinv_Bt, di)
    return np.concatenate([di, dp.ravel()])


def quadratic_form(A: np.ndarray, B: np.ndarray, D: np.ndarray, di: np.ndarray, dp: np.ndarray) -> float:
    """``s^T (J^T J) s`` of a step from the blocks of ``J^T J``.

    Parameters
    ----------
    A, B, D : ndarray
        (ng, ng), (V, ng, 6), (V, 6, 6) blocks (:meth:`Problem.normal_equations`).
    di : ndarray
        (ng,) the step's global part.
    dp : ndarray
        (V, 6) the step's pose part.

    Returns
    -------
    float
        px^2.
    """
    return float(di @ A @ di + 2.0 * np.einsum("a,vab,vb->", di, B, dp) + np.einsum("va,vab,vb->", dp, D, dp))


def levenberg_marquardt(
    prob: Problem, x0: np.ndarray, max_iterations: int, near: bool = False
) -> tuple[np.ndarray, int, bool, str]:
    """Levenberg-Marquardt on ``prob`` with exact Schur-complement solves of the damped normal equations.

    Each iteration forms ``J^T J`` blockwise, damps its diagonal (Marquardt: ``lambda * diag(J^T J)``, scale invariant
    like ``x_scale='jac'``), eliminates the poses and back-substitutes (:func:`schur_step`). A trial step is judged by
    its cost alone (a rejected one costs no Jacobian) unless the :data:`ACCEPTED_RUN` steps before it were taken. A
    step continuing the one before it as a geometric sequence is also tried extended towards the sequence's limit
    (:func:`geometric_extension`). Once the damping is negligible and the predicted decrease is below
    :data:`TRUST_MODEL_REL` of the cost, the quadratic model is trusted (the cost can no longer rank steps) until a step
    predicts less than :data:`FINAL_STEP_REL`; the parameters then sit ~1e-9 of their own standard deviations from the
    minimum. A solve that can no longer lower the cost otherwise ends "stalled" and is judged by its gradient. The
    design in detail: docs/solver.md.

    Parameters
    ----------
    prob : Problem
    x0 : ndarray
        (n,) start.
    max_iterations : int
        Jacobian evaluations at most.
    near : bool
        ``x0`` is near the minimum (its first steps are taken): the damping starts at :data:`LAMBDA_NEAR` (back to
        :data:`LAMBDA_START` if the first trial is rejected) and every trial from the first is evaluated with its
        Jacobian, as after :data:`ACCEPTED_RUN` steps taken.

    Returns
    -------
    x : ndarray
        (n,) the solution.
    iterations : int
    converged : bool
        The scaled gradient is within :data:`GRADIENT_TOL` sqrt(cost) + :data:`GRADIENT_FLOOR`.
    message : str
        ``"converged"``, the iteration limit, or why it stalled.
    """
    ng = prob.ng
    x = x0.copy()
    f = (prob.normal_equations(x) if near else prob.residuals(x))[0]  # near: the first iteration's pass
    cost = float(f @ f)
    lam = LAMBDA_NEAR if near else LAMBDA_START
    first = near  # no step taken yet from a start near the minimum
    it = 0
    done = stalled = False
    last_trusted = np.inf
    run = ACCEPTED_RUN if near else 0  # trial steps taken in a row
    last_step: np.ndarray | None = None  # the last step taken (before any extension), scaled by sqrt(diag J^T J)
    while it < max_iterations and not (done or stalled):
        it += 1
        A, gi, B, D, gp = blocks = prob.normal_equations(x)[1]
        scale = np.sqrt(np.concatenate([np.diag(A), np.diagonal(D, axis1=1, axis2=2).ravel()]))
        while True:
            step = schur_step(*blocks, lam)
            if not np.all(np.isfinite(step)):
                lam *= LAMBDA_FACTOR
                if lam > LAMBDA_MAX:
                    stalled = True
                    break
                continue
            di, dp = step[:ng], step[ng:].reshape(-1, 6)
            # cost(x + s) ~ cost + 2 g.s + s^T J^T J s
            predicted = -(2.0 * (gi @ di + np.sum(gp * dp)) + quadratic_form(A, B, D, di, dp))
            # Near the minimum the cost can no longer rank steps (its rounding is ~1e-16 relative) but the
            # quadratic model can: there a step that does not raise the cost beyond rounding is taken.
            trusted = lam <= LAMBDA_GAUSS_NEWTON and predicted <= TRUST_MODEL_REL * cost
            # last step: at rounding level, or the model's decrease stopped shrinking (no progress left to make)
            final = trusted and (predicted <= FINAL_STEP_REL * cost or predicted >= last_trusted)
            extension = 1.0 if last_step is None else geometric_extension(last_step, step * scale)
            # where the cost can rank steps the extension is a second trial, taken if lower; where it cannot
            # (trusted) the geometric sequence is followed
            x_new = x + (extension if trusted else 1.0) * step
            # the cost only (a rejected trial costs no Jacobian), but after ACCEPTED_RUN steps taken in a row the
            # next is likely taken too: its Jacobian pass gives the same residuals and is not repeated
            f_new = (
                prob.normal_equations(x_new)
                if run >= ACCEPTED_RUN and (trusted or extension == 1.0)
                else prob.residuals(x_new)
            )[0]
            cost_new = _cost(f_new)
            if extension > 1.0 and not trusted:
                x_ext = x + extension * step
                f_ext = prob.residuals(x_ext)[0]
                if _cost(f_ext) < cost_new:
                    x_new, f_new, cost_new = x_ext, f_ext, _cost(f_ext)
            if cost_new < cost or (trusted and cost_new <= cost * (1.0 + COST_ROUNDING_REL)):
                x, f, cost = x_new, f_new, cost_new
                last_step = step * scale
                run += 1
                lam = max(lam / LAMBDA_FACTOR, LAMBDA_MIN)
                last_trusted = predicted if trusted else np.inf
                done = final
                first = False
                break
            lam = max(lam * LAMBDA_FACTOR, LAMBDA_START) if first else lam * LAMBDA_FACTOR
            first = False
            run = 0
            if lam > LAMBDA_MAX:
                stalled = True
                break
    if not (done or stalled):
        return x, it, False, f"iteration limit {max_iterations} reached"
    # Converged if the scaled gradient is negligible at the final point.
    A, gi, B, D, gp = prob.normal_equations(x)[1]
    scale = np.sqrt(np.concatenate([np.diag(A), np.diagonal(D, axis1=1, axis2=2).ravel()]))
    g = np.concatenate([gi, gp.ravel()]) / np.maximum(scale, 1e-300)
    ok = bool(np.max(np.abs(g)) <= GRADIENT_TOL * np.sqrt(cost) + GRADIENT_FLOOR)
    return x, it, ok, ("converged" if ok else "stalled: no step lowers the cost but the gradient is not small")


def _cost(f: np.ndarray) -> float:
    """The sum of squares of residuals ``f``; inf where any is not finite."""
    return float(f @ f) if np.all(np.isfinite(f)) else np.inf


def geometric_extension(previous: np.ndarray, step: np.ndarray) -> float:
    """The factor that takes ``step`` to the limit of the geometric sequence it continues.

    Parameters
    ----------
    previous, step : ndarray
        (n,) the last step taken and this one, in the same scaled units.

    Returns
    -------
    float
        ``1 / (1 - q)`` (at most :data:`EXTRAPOLATE_MAX`) when ``step`` points along ``previous`` (cosine >=
        :data:`EXTRAPOLATE_COS`) and is shorter by q < 1; else 1.
    """
    n_prev, n_step = np.linalg.norm(previous), np.linalg.norm(step)
    if not n_step < n_prev or previous @ step < EXTRAPOLATE_COS * n_prev * n_step:
        return 1.0
    return min(float(1.0 / (1.0 - n_step / n_prev)), EXTRAPOLATE_MAX)


def solve(prob: Problem, x0: np.ndarray, max_iterations: int, solver: str) -> tuple[np.ndarray, int, bool, str]:
    """Run the chosen least-squares solver.

    Parameters
    ----------
    prob : Problem
    x0 : ndarray
        (n,) start.
    max_iterations : int
        Jacobian (``"schur"``) or function (``"scipy"``) evaluations at most.
    solver : str
        ``"schur"`` (:func:`levenberg_marquardt`) or ``"scipy"`` (``scipy.optimize.least_squares``, TRF with a sparse
        Jacobian and LSMR: an independent cross-check).

    Returns
    -------
    tuple
        ``(x (n,), iterations, converged, message)``.

    Raises
    ------
    ValueError
        Another ``solver`` (the options check names it first).
    """
    if solver == "schur":
        return levenberg_marquardt(prob, x0, max_iterations)
    if solver != "scipy":
        raise ValueError(f"unknown solver {solver!r}; expected 'schur' or 'scipy'")
    from scipy.optimize import least_squares

    with warnings.catch_warnings():  # LSMR's own tolerance notices at 1e-15; the result is judged by its status
        warnings.simplefilter("ignore", RuntimeWarning)
        sol = least_squares(
            prob.fun,
            x0,
            jac=prob.jac,
            method="trf",
            x_scale="jac",
            ftol=1e-15,
            xtol=1e-15,
            gtol=1e-15,
            max_nfev=max_iterations,
            tr_solver="lsmr",
            tr_options={"atol": 1e-15, "btol": 1e-15, "maxiter": 10 * prob.n},
        )
    return sol.x, int(sol.njev if sol.njev is not None else sol.nfev), bool(sol.status > 0), str(sol.message)


def is_sane(prob: Problem, x: np.ndarray, converged: bool) -> bool:
    """Whether a solve is worth keeping.

    Parameters
    ----------
    prob : Problem
    x : ndarray
        (n,) the solution.
    converged : bool
        The solver's verdict.

    Returns
    -------
    bool
        Converged, finite, positive focal lengths and every point in front of the camera.
    """
    if not converged or not np.all(np.isfinite(x)):
        return False
    f, Xc = prob.residuals(x)
    p = prob.intrinsics(x)
    return bool(np.all(np.isfinite(f)) and p[0] > 0 and p[1] > 0 and np.all(Xc[:, 2] > 0))
