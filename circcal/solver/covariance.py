"""The covariance of the whole solve state (intrinsics, board coordinates and every board pose), not only the
intrinsics block: what projection uncertainty needs (:mod:`circcal.solver.uncertainty`), since a pose's noise moves
the board frames through which a pixel's ray is followed back into the image.

State layout (:class:`circcal.solver.problem.Problem`): the ``ng`` global parameters (the ``nf`` free intrinsics,
then the ``nb`` free board coordinates of board refinement), then 6 pose parameters per view (rvec rad, tvec mm).
With per-coordinate noise sigma the first-order covariance of the least-squares estimate is ``sigma^2 (J^T J)^-1``
(no regularisation: every residual is an observation, mrcal's simple case ``Var(b) = sigma^2 inv(J^T J)``). It is
kept in the factored form the solver's Schur blocks give, never as a dense (ng + 6V)^2 matrix (1000 views would
make that 290 MB): with ``S`` the Schur complement of the pose blocks ``D_v`` and ``M_v = D_v^-1 B_v^T`` (6, ng)::

    C_gg = S^-1,   C_gp_v = -S^-1 M_v^T,   C_pp_vw = delta_vw D_v^-1 + M_v S^-1 M_w^T

so that for any linear function ``G = [G_g, G_p]`` of the state (:meth:`StateCovariance.quadratic`)::

    G C G^T = (G_g - sum_v G_pv M_v) S^-1 (G_g - sum_v G_pv M_v)^T + sum_v G_pv D_v^-1 G_pv^T
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # annotations only
    from circcal.solver.problem import Problem


def normalised_information(S: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """An information matrix scaled to a unit diagonal, and how well it is conditioned.

    Parameters
    ----------
    S : ndarray, shape (k, k)
        The information on the global parameters (the Schur complement of the pose blocks in ``J^T J``).

    Returns
    -------
    Sn : ndarray, shape (k, k)
        ``S / outer(scale, scale)``, symmetrised.
    scale : ndarray, shape (k,)
        ``sqrt(diag(S))``, floored at 1e-150.
    condition : float
        Of ``Sn``; inf where it is not positive definite: a diagonal entry not positive, a value not finite (board
        poses whose own blocks are near singular make such a complement), or no eigenvalues found.
    """
    S = 0.5 * (S + S.T)
    d = np.diag(S)
    scale = np.sqrt(np.maximum(d, 1e-300))
    Sn = S / np.outer(scale, scale)
    if not (np.all(d > 0) and np.all(np.isfinite(Sn))):
        return Sn, scale, float("inf")
    try:
        ev = np.linalg.eigvalsh(Sn)
    except np.linalg.LinAlgError:
        return Sn, scale, float("inf")
    return Sn, scale, float(ev[-1] / ev[0]) if ev[0] > 0 else float("inf")


__all__ = ["StateCovariance", "state_covariance", "normalised_information"]


@dataclass(frozen=True)
class StateCovariance:
    """First-order covariance of a solve's whole state, per unit of per-coordinate noise, in factored form.

    Multiply by ``sigma_px^2`` for the covariance.

    Attributes
    ----------
    S_inv : ndarray, shape (ng, ng)
        The global block ``S^-1``.
    M : ndarray, shape (V, 6, ng)
        ``D_v^-1 B_v^T``.
    D_inv : ndarray, shape (V, 6, 6)
    intrinsics_map : ndarray, shape (4 + n_dist, nf)
        d(intrinsics) / d(free intrinsics) (a held parameter has a zero row; a held aspect ratio puts ``a`` in fx's
        row).
    n_board : int
        Free board coordinates (0 without board refinement).
    sigma_px : float
        The per-coordinate noise estimate of the solve, sqrt(SSR / (2N - n)), px.
    n_views : int
        V (property).
    n_global : int
        ng = nf + nb (property).
    """

    S_inv: np.ndarray
    M: np.ndarray
    D_inv: np.ndarray
    intrinsics_map: np.ndarray
    n_board: int
    sigma_px: float

    @property
    def n_intrinsics(self) -> int:
        """Free intrinsics (nf)."""
        return int(self.intrinsics_map.shape[1])

    @property
    def n_views(self) -> int:
        """The number of views V."""
        return int(self.M.shape[0])

    @property
    def n_global(self) -> int:
        """Global parameters (ng = nf + nb)."""
        return int(self.S_inv.shape[0])

    def quadratic(self, G_global: np.ndarray, G_pose: np.ndarray) -> np.ndarray:
        """``G C_unit G^T`` for N linear functions of the state; cost O(N k V ng), no dense state matrix.

        Parameters
        ----------
        G_global : ndarray, shape (N, k, ng)
            The functions' derivatives with respect to the global parameters (see the module).
        G_pose : ndarray, shape (N, k, V, 6)
            Their derivatives with respect to each view's pose.

        Returns
        -------
        ndarray, shape (N, k, k)
            Per unit of per-coordinate noise (multiply by ``sigma_px^2``).
        """
        H = G_global - np.einsum("nkvj,vjg->nkg", G_pose, self.M)
        out: np.ndarray = np.einsum("nag,gh,nbh->nab", H, self.S_inv, H) + np.einsum(
            "navi,vij,nbvj->nab", G_pose, self.D_inv, G_pose
        )
        return out

    @property
    def unit(self) -> np.ndarray:
        """The dense (n, n) ``(J^T J)^-1`` (for inspection and tests; O(n^2) memory)."""
        ng, V = self.n_global, self.n_views
        Mf = self.M.reshape(6 * V, ng)
        C = np.empty((ng + 6 * V, ng + 6 * V))
        C[:ng, :ng] = self.S_inv
        C[:ng, ng:] = -self.S_inv @ Mf.T
        C[ng:, :ng] = C[:ng, ng:].T
        C_pp = Mf @ self.S_inv @ Mf.T
        for v in range(V):
            C_pp[6 * v : 6 * v + 6, 6 * v : 6 * v + 6] += self.D_inv[v]
        C[ng:, ng:] = C_pp
        return 0.5 * (C + C.T)


def state_covariance(
    prob: Problem, x: np.ndarray, cov_global_unit: np.ndarray, sigma_px: float
) -> StateCovariance | None:
    """The :class:`StateCovariance` of ``prob`` at its solution.

    Parameters
    ----------
    prob : Problem
    x : ndarray
        (n,) the solution.
    cov_global_unit : ndarray
        (ng, ng) ``S^-1``, the unit covariance of the global parameters the solver already inverted.
    sigma_px : float
        The solve's per-coordinate noise estimate, px.

    Returns
    -------
    StateCovariance or None
        None when ``cov_global_unit`` is not finite (the information matrix was singular).
    """
    if not np.all(np.isfinite(cov_global_unit)):
        return None
    _, _, B, D, _ = prob.normal_equations(x)[1]
    D_inv = np.linalg.inv(D)  # (V, 6, 6)
    return StateCovariance(
        S_inv=cov_global_unit,
        M=D_inv @ np.transpose(B, (0, 2, 1)),
        D_inv=D_inv,
        intrinsics_map=prob.T.copy(),
        n_board=int(prob.nb),
        sigma_px=float(sigma_px),
    )
