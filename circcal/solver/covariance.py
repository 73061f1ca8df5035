"""The covariance of the whole solve state (intrinsics, board coordinates and every board pose), not only the
intrinsics block: what projection uncertainty needs (:mod:`circcal.solver.uncertainty`), since a pose's noise moves
the board frames through which a pixel's ray is followed back into the image.

State layout (:class:`circcal.solver.problem.Problem`): the ``nf`` free intrinsics, the ``nb`` free board coordinates
(board refinement only), then 6 pose parameters per view (rvec rad, tvec mm). With per-coordinate noise sigma the
first-order covariance of the least-squares estimate is ``sigma^2 (J^T J)^-1`` (no regularisation: every residual is
an observation, mrcal's simple case ``Var(b) = sigma^2 inv(J^T J)``). It is assembled from the Schur blocks the solver
already forms: with ``C_gg = S^-1`` (S the Schur complement of the pose blocks)::

    C_gp_v = -C_gg B_v D_v^-1,   C_pp_vw = delta_vw D_v^-1 + D_v^-1 B_v^T C_gg B_w D_w^-1
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from circcal.solver.lm import normal_blocks

if TYPE_CHECKING:  # annotations only
    from circcal.solver.problem import Problem

__all__ = ["StateCovariance", "state_covariance"]


@dataclass(frozen=True)
class StateCovariance:
    """First-order covariance of a solve's whole state, per unit of per-coordinate noise.

    ``unit``: (n, n) ``(J^T J)^-1`` over the state (free intrinsics, free board coordinates, 6 per view: rvec rad,
    tvec mm); multiply by ``sigma_px^2`` for the covariance. ``intrinsics_map``: (9, nf), d(fx..k3) / d(free
    intrinsics) (a held parameter has a zero row; a held aspect ratio puts ``a`` in fx's row). ``n_board``: free
    board coordinates (0 without board refinement). ``n_views``: views. ``sigma_px``: the per-coordinate noise
    estimate of the solve, sqrt(SSR / (2N - n)).
    """

    unit: np.ndarray
    intrinsics_map: np.ndarray
    n_board: int
    n_views: int
    sigma_px: float

    @property
    def n_intrinsics(self) -> int:
        """Free intrinsics (nf)."""
        return int(self.intrinsics_map.shape[1])

    @property
    def pose_start(self) -> int:
        """Index of the first pose parameter in the state."""
        return self.n_intrinsics + self.n_board

    def without_board(self) -> tuple[np.ndarray, slice]:
        """The unit covariance of (free intrinsics, poses) with the board coordinates marginalised (rows and columns
        dropped: the marginal of a Gaussian), (nf + 6V, nf + 6V); and the slice of the intrinsics in it."""
        keep = np.r_[0:self.n_intrinsics, self.pose_start:self.unit.shape[0]]
        return self.unit[np.ix_(keep, keep)], slice(0, self.n_intrinsics)


def state_covariance(prob: Problem, x: np.ndarray, cov_global_unit: np.ndarray, sigma_px: float
                     ) -> StateCovariance | None:
    """The :class:`StateCovariance` of ``prob`` at its solution ``x``, from ``cov_global_unit`` = S^-1 (ng, ng)
    the solver already inverted (None when it is not finite: the information matrix was singular)."""
    if not np.all(np.isfinite(cov_global_unit)):
        return None
    f, _, Ji, Jp = prob.evaluate(x)
    starts = np.concatenate([[0], np.cumsum(prob.counts)[:-1]])
    _, _, B, D, _ = normal_blocks(prob, f, Ji, Jp, starts)
    ng, V = prob.ng, prob.n_views
    Dinv = np.linalg.inv(D)                                                     # (V, 6, 6)
    M = (Dinv @ np.transpose(B, (0, 2, 1))).reshape(6 * V, ng)                  # D_v^-1 B_v^T stacked
    C = np.empty((prob.n, prob.n))
    C[:ng, :ng] = cov_global_unit
    C_gp = -cov_global_unit @ M.T                                               # (ng, 6V)
    C[:ng, ng:] = C_gp
    C[ng:, :ng] = C_gp.T
    C_pp = M @ cov_global_unit @ M.T
    for v in range(V):
        C_pp[6 * v: 6 * v + 6, 6 * v: 6 * v + 6] += Dinv[v]
    C[ng:, ng:] = C_pp
    C = 0.5 * (C + C.T)
    return StateCovariance(unit=C, intrinsics_map=prob.T.copy(), n_board=int(prob.nb), n_views=int(V),
                           sigma_px=float(sigma_px))
