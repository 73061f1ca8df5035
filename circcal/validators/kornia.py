"""kornia/torch as a reference: Zhang initialisation + Levenberg-Marquardt on kornia's own projection.

kornia has no calibration routine, so this adapter is a small, independent calibrator built only from kornia/torch
pieces (float64 throughout); it deliberately does not import circcal's solver. "fair" and "default" are the same
estimator (plain least squares). The model, initialisation, refinement and standard deviations are described in
docs/references.md ("How the adapters work: kornia").
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from circcal.model import LENS_MODELS, Camera, param_names
from circcal.observations import check_observations
from circcal.validators.base import BaseCalibrator
from circcal.validators.divergence import check_divergence
from circcal.validators.reference_result import ReferenceResult
from circcal.validators.seeds import FISHEYE_FOCAL_SWEEP

__all__ = ["KorniaCalibrator", "Problem"]

Problem = dict  # {"object_points": [...], "image_points": [...], "image_size": (w, h), "initial": Camera | None}

#: kornia's lens models: circcal's name -> what computes it (see the module docstring).
KORNIA_LENSES: dict[str, str] = {
    "opencv5": "kornia.geometry.calibration.distort_points with 5 coefficients",
    "rational": "kornia.geometry.calibration.distort_points with 8 coefficients",
    "thin-prism": "kornia.geometry.calibration.distort_points with 12 coefficients",
    "fisheye": "kornia.geometry.camera.distort_points_kannala_brandt (points on the z = 1 plane: under 90 deg)",
}


#: CPU solves of at most this many observed points (summed over the batch) run on one torch thread: their tensors
#: are small, and torch's intra-op threads only add synchronisation (the 14-view paper solve: 0.77 s on one thread
#: against 2.0 s on two, alternated on the shared 2-core machine).
SINGLE_THREAD_BELOW_POINTS = 20_000


def n_intrinsics(lens: str) -> int:
    """The number of intrinsics of a lens model: fx, fy, cx, cy and its distortion coefficients.

    Parameters
    ----------
    lens : str
        A :data:`circcal.model.LENS_MODELS` name.

    Returns
    -------
    int

    Raises
    ------
    KeyError
        An unknown lens model.
    """
    return 4 + len(LENS_MODELS[lens].dist_names)


def _torch():
    import torch

    return torch


# ------------------------------------------------------------------------------------------------------------------
# model
# ------------------------------------------------------------------------------------------------------------------
def _view_residual(intr, pose, obj, img, w, lens: str = "opencv5"):
    """One view: intr (4 + ndist,) [fx, fy, cx, cy, *dist of ``lens``], pose (6,) axis-angle + translation,
    obj (N,3), img (N,2), w (N,) -> (2N,) weighted residuals, projected - observed (px)."""
    torch = _torch()
    from kornia.geometry.calibration import distort_points
    from kornia.geometry.conversions import axis_angle_to_rotation_matrix

    R = axis_angle_to_rotation_matrix(pose[None, :3])[0]
    Xc = obj @ R.T + pose[3:]
    xn = Xc[:, :2] / Xc[:, 2:3]
    if lens == "fisheye":
        from kornia.geometry.camera import distort_points_kannala_brandt

        q = distort_points_kannala_brandt(xn, intr)
        return torch.where(w[:, None] > 0, (q - img) * w[:, None], torch.zeros_like(q)).reshape(-1)
    zero, one = torch.zeros_like(intr[0]), torch.ones_like(intr[0])
    K = torch.stack(
        [torch.stack([intr[0], zero, intr[2]]), torch.stack([zero, intr[1], intr[3]]), torch.stack([zero, zero, one])]
    )
    eye = torch.eye(3, dtype=intr.dtype, device=intr.device)
    q = distort_points(xn, K, intr[4:], new_K=eye)
    # where, not a product: a padded point must give 0 even if its projection is not finite
    return torch.where(w[:, None] > 0, (q - img) * w[:, None], torch.zeros_like(q)).reshape(-1)


def _residuals_and_jacobian(theta, obj, img, w, *, jacobian: bool = True, lens: str = "opencv5"):
    """Batched problems: theta (B, n+6V) with n = :func:`n_intrinsics` (``lens``), obj (B,V,N,3), img (B,V,N,2),
    w (B,V,N).

    Returns r (B, V*2N) and, with ``jacobian``, the dense J (B, V*2N, n+6V) assembled from per-view blocks (each
    view depends on the n intrinsics and its own 6 pose parameters: n + 6 forward-mode tangents instead of n+6V).
    """
    import functools

    torch = _torch()
    from torch.func import jacfwd, vmap

    B, V, N, _ = obj.shape
    n_intr = n_intrinsics(lens)
    intr = theta[:, :n_intr]
    poses = theta[:, n_intr:].reshape(B, V, 6)
    view_residual = functools.partial(_view_residual, lens=lens)
    per_view = vmap(view_residual, in_dims=(None, 0, 0, 0, 0))
    r = vmap(per_view)(intr, poses, obj, img, w).reshape(B, V * 2 * N)
    if not jacobian:
        return r, None
    jac_view = vmap(jacfwd(view_residual, argnums=(0, 1)), in_dims=(None, 0, 0, 0, 0))
    Ji, Jp = vmap(jac_view)(intr, poses, obj, img, w)  # (B,V,2N,n), (B,V,2N,6)
    eye = torch.eye(V, dtype=theta.dtype, device=theta.device)
    Jpose = (Jp[:, :, :, None, :] * eye[None, :, None, :, None]).reshape(B, V * 2 * N, V * 6)
    J = torch.cat([Ji.reshape(B, V * 2 * N, n_intr), Jpose], dim=-1)
    return r, J


def _rotation_to_axis_angle(R):
    from kornia.geometry.conversions import rotation_matrix_to_axis_angle

    return rotation_matrix_to_axis_angle(R)


# ------------------------------------------------------------------------------------------------------------------
# Zhang initialisation (batched over problems)
# ------------------------------------------------------------------------------------------------------------------
def _homographies(obj, dst, w, vmask):
    """Board (z = 0) to ``dst`` homographies per view: obj (B,V,N,3), dst (B,V,N,2), w (B,V,N), vmask (B,V) ->
    (B,V,3,3), Frobenius-normalised. Padded views reuse view 0 (their rows are masked by the callers)."""
    torch = _torch()
    from kornia.geometry.homography import find_homography_dlt

    B, V, N, _ = obj.shape
    src = torch.where(vmask[..., None, None], obj[..., :2], obj[:, :1, :, :2].expand(B, V, N, 2))
    dst = torch.where(vmask[..., None, None], dst, dst[:, :1].expand(B, V, N, 2))
    ww = torch.where(vmask[..., None], w, w[:, :1].expand(B, V, N))
    H = find_homography_dlt(src.reshape(B * V, N, 2), dst.reshape(B * V, N, 2), ww.reshape(B * V, N))
    H = H.reshape(B, V, 3, 3)
    return H / torch.linalg.norm(H, dim=(-2, -1), keepdim=True)


def _poses_from_homographies(H, Kn):
    """Board-to-camera poses from homographies H (B,V,3,3) of the board onto the image with intrinsics Kn (B,3,3):
    [r1 r2 t] ~ Kn^-1 H, the rotation made orthonormal (SVD), the board in front. Returns (B,V,6) [rvec, t]."""
    torch = _torch()
    B, V = H.shape[:2]
    M = torch.linalg.solve(Kn[:, None].expand(B, V, 3, 3), H)
    scale = 1.0 / torch.linalg.norm(M[..., :, 0], dim=-1)
    M = M * scale[..., None, None]
    M = M * torch.sign(M[..., 2:3, 2:3])  # board in front of the camera
    r1, r2, t = M[..., :, 0], M[..., :, 1], M[..., :, 2]
    R = torch.stack([r1, r2, torch.linalg.cross(r1, r2)], -1)
    U, _, Vt = torch.linalg.svd(R)
    d = torch.sign(torch.linalg.det(U @ Vt))
    U = torch.cat([U[..., :2], U[..., 2:] * d[..., None, None]], -1)
    R = U @ Vt
    rv = _rotation_to_axis_angle(R.reshape(-1, 3, 3)).reshape(B, V, 3)
    return torch.cat([rv, t], -1)


def _fisheye_init(obj, img, w, vmask, sizes):
    """Kannala-Brandt start (batched): principal point at the image centre ((w - 1) / 2, (h - 1) / 2), k = 0, and the
    equidistant focal length f of :data:`FISHEYE_FOCAL_SWEEP` whose poses (from homographies of the board onto the
    observations lifted to the z = 1 plane, x = tan(r / f) (u - c) / r) reproject best. obj (B,V,N,3), img (B,V,N,2),
    w (B,V,N), vmask (B,V), sizes (B,2). Returns theta0 (B, 8+6V)."""
    torch = _torch()
    B, V, N, _ = obj.shape
    dt = obj.dtype
    c = torch.stack([(sizes[:, 0] - 1) / 2, (sizes[:, 1] - 1) / 2], -1)  # (B,2)
    d = img - c[:, None, None, :]
    r = torch.linalg.norm(d, dim=-1)
    eye = torch.eye(3, dtype=dt, device=obj.device).expand(B, 3, 3)
    wv = w * vmask[..., None].to(dt)
    best_cost = torch.full((B,), float("inf"), dtype=dt, device=obj.device)
    best = torch.zeros(B, 8 + 6 * V, dtype=dt, device=obj.device)
    for rel in FISHEYE_FOCAL_SWEEP:
        f = rel * sizes.max(dim=1).values / torch.pi  # (B,)
        theta = torch.clamp(r / f[:, None, None], max=torch.pi / 2 * 0.98)  # a start cannot see beyond 90 deg
        lift = torch.where(r > 0, torch.tan(theta) / torch.clamp(r, min=1e-12), 1.0 / f[:, None, None])
        xn = d * lift[..., None]
        poses = _poses_from_homographies(_homographies(obj, xn, w, vmask), eye)
        intr = torch.cat([f[:, None], f[:, None], c, torch.zeros(B, 4, dtype=dt, device=obj.device)], -1)
        theta0 = torch.cat([intr, poses.reshape(B, -1)], -1)
        res, _ = _residuals_and_jacobian(theta0, obj, img, wv, jacobian=False, lens="fisheye")
        cost = torch.nan_to_num((res * res).sum(-1), nan=float("inf"))
        better = cost < best_cost
        best = torch.where(better[:, None], theta0, best)
        best_cost = torch.where(better, cost, best_cost)
    return best, torch.isfinite(best_cost)


def _zhang_init(obj, img, w, vmask, sizes, ndist: int = 5):
    """obj (B,V,N,3), img (B,V,N,2), w (B,V,N) 0/1, vmask (B,V) bool, sizes (B,2). Returns theta0 (B, 4+ndist+6V)
    (distortion 0) and whether Zhang's closed form held (B,)."""
    torch = _torch()

    B, V, N, _ = obj.shape
    dt = obj.dtype
    # pixel normalisation for conditioning: u' = (u - w/2) / s, s = max(w, h)
    s = sizes.max(dim=1).values  # (B,)
    Nrm = torch.zeros(B, 3, 3, dtype=dt, device=obj.device)
    Nrm[:, 0, 0] = 1.0 / s
    Nrm[:, 1, 1] = 1.0 / s
    Nrm[:, 0, 2] = -0.5 * sizes[:, 0] / s
    Nrm[:, 1, 2] = -0.5 * sizes[:, 1] / s
    Nrm[:, 2, 2] = 1.0
    imgn = (img - torch.stack([0.5 * sizes[:, 0], 0.5 * sizes[:, 1]], -1)[:, None, None, :]) / s[:, None, None, None]
    # padded views: reuse view 0 so the DLT stays well posed (their rows are masked below)
    H = _homographies(obj, imgn, w, vmask)

    def vrow(h, i, j):  # Zhang's v_ij without the skew column: (B11, B22, B13, B23, B33)
        hi, hj = h[..., :, i], h[..., :, j]
        return torch.stack(
            [
                hi[..., 0] * hj[..., 0],
                hi[..., 1] * hj[..., 1],
                hi[..., 2] * hj[..., 0] + hi[..., 0] * hj[..., 2],
                hi[..., 2] * hj[..., 1] + hi[..., 1] * hj[..., 2],
                hi[..., 2] * hj[..., 2],
            ],
            -1,
        )

    A = torch.cat([vrow(H, 0, 1), vrow(H, 0, 0) - vrow(H, 1, 1)], dim=1)  # (B, 2V, 5)
    m = torch.cat([vmask, vmask], dim=1).to(dt)
    A = A * m[..., None]
    _, _, Vh = torch.linalg.svd(A, full_matrices=False)
    b = Vh[:, -1, :]
    b = b * torch.sign(b[:, 0:1])
    B11, B22, B13, B23, B33 = b.unbind(-1)
    v0 = -B23 / B22
    lam = B33 - (B13**2 - v0 * B11 * B23) / B11
    fxn = torch.sqrt(lam / B11)
    fyn = torch.sqrt(lam / B22)
    u0 = -B13 * fxn**2 / lam
    # fallback: principal point at the centre (0 in normalised pixels), solve 1/fx^2, 1/fy^2 by least squares
    h = H
    a1 = torch.stack([h[..., 0, 0] * h[..., 0, 1], h[..., 1, 0] * h[..., 1, 1]], -1)
    c1 = -h[..., 2, 0] * h[..., 2, 1]
    a2 = torch.stack([h[..., 0, 0] ** 2 - h[..., 0, 1] ** 2, h[..., 1, 0] ** 2 - h[..., 1, 1] ** 2], -1)
    c2 = -(h[..., 2, 0] ** 2 - h[..., 2, 1] ** 2)
    AA = torch.cat([a1, a2], 1) * m[..., None]
    cc = torch.cat([c1, c2], 1) * m
    ab = torch.linalg.lstsq(AA, cc[..., None]).solution[..., 0]
    fx_c = 1.0 / torch.sqrt(torch.clamp(ab[:, 0], min=1e-12))
    fy_c = 1.0 / torch.sqrt(torch.clamp(ab[:, 1], min=1e-12))
    ok = (
        torch.isfinite(fxn)
        & torch.isfinite(fyn)
        & (fxn > 0)
        & (fyn > 0)
        & (u0.abs() < 0.5)
        & (v0.abs() < 0.5)
        & ((fxn / fyn - 1).abs() < 0.5)
    )
    fxn = torch.where(ok, fxn, fx_c)
    fyn = torch.where(ok, fyn, fy_c)
    u0 = torch.where(ok, u0, torch.zeros_like(u0))
    v0 = torch.where(ok, v0, torch.zeros_like(v0))
    Kn = torch.zeros(B, 3, 3, dtype=dt, device=obj.device)
    Kn[:, 0, 0], Kn[:, 1, 1], Kn[:, 0, 2], Kn[:, 1, 2], Kn[:, 2, 2] = fxn, fyn, u0, v0, 1.0
    K = torch.linalg.solve(Nrm, Kn)  # pixel intrinsics
    # poses from H (normalised pixels); padded views hold view 0's data, hence a valid pose (they stay fixed)
    poses = _poses_from_homographies(H, Kn)
    intr = torch.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], -1)
    intr = torch.cat([intr, torch.zeros(B, ndist, dtype=dt, device=obj.device)], -1)
    return torch.cat([intr, poses.reshape(B, -1)], -1), ok


# ------------------------------------------------------------------------------------------------------------------
# Levenberg-Marquardt (batched)
# ------------------------------------------------------------------------------------------------------------------
def _lm(theta, obj, img, w, free, *, max_iter: int = 200, tol: float = 1e-20, lens: str = "opencv5"):
    """theta (B,P), free (B,P) bool; ``lens``: the model of theta's intrinsics. Returns (theta, J (B,M,P) at the solution, residuals (B,M), iterations,
    converged (B,))."""
    torch = _torch()
    B, P = theta.shape
    freef = free.to(theta.dtype)
    r, _ = _residuals_and_jacobian(theta, obj, img, w, jacobian=False, lens=lens)
    cost = (r * r).sum(-1)
    lam = torch.full((B,), 1e-3, dtype=theta.dtype, device=theta.device)
    done = torch.zeros(B, dtype=torch.bool, device=theta.device)
    gn_steps = torch.zeros(B, dtype=torch.int64, device=theta.device)
    it = 0
    J = None
    for it in range(1, max_iter + 1):  # noqa: B007 - `it` is returned: the iterations done
        _, J = _residuals_and_jacobian(theta, obj, img, w, lens=lens)
        J = J * freef[:, None, :]
        A = J.transpose(1, 2) @ J
        g = (J.transpose(1, 2) @ r[..., None])[..., 0]
        dA = torch.diagonal(A, dim1=1, dim2=2)
        dA = torch.where(free, dA, torch.ones_like(dA))
        fixed_diag = (~free).to(theta.dtype)
        # converged when even the undamped Gauss-Newton step would lower the cost by < tol relative: in a flat
        # valley a small damped step is not a sign of convergence, this is
        # (singular where two parameters are collinear at the start, e.g. k1 and k4 of the rational model at 0:
        # no Gauss-Newton step there, only damped ones)
        gn, info = torch.linalg.solve_ex(A + torch.diag_embed(fixed_diag + 1e-30 * dA), g[..., None])
        gn = gn[..., 0] * freef
        gn_ok = (info == 0) & torch.isfinite(gn).all(-1)
        gn = torch.where(gn_ok[:, None], gn, torch.zeros_like(gn))
        pred = torch.where(gn_ok, (g * gn).sum(-1), torch.full_like(cost, float("inf")))
        done = done | (pred.abs() <= tol * cost) | (cost == 0) | (gn_steps >= 3)
        if bool(done.all()):
            break
        # in the quadratic basin the cost can no longer resolve progress (flat valleys: 1e-14 relative in the cost is
        # still ~1e-6 px in the model), so finish with plain Gauss-Newton steps, which follow the gradient instead
        basin = (pred.abs() <= 1e-10 * cost) & ~done
        if bool(basin.any()):
            theta = torch.where(basin[:, None], theta - gn, theta)
            gn_steps = gn_steps + basin.to(gn_steps.dtype)
            r_b, _ = _residuals_and_jacobian(theta, obj, img, w, jacobian=False, lens=lens)
            r = torch.where(basin[:, None], r_b, r)
            cost = torch.where(basin, (r_b * r_b).sum(-1), cost)
            if bool((basin | done).all()):
                continue
        Ad = A + torch.diag_embed(lam[:, None] * dA + fixed_diag)
        delta = -torch.linalg.solve(Ad, g[..., None])[..., 0] * freef
        cand = theta + delta
        r_new, _ = _residuals_and_jacobian(cand, obj, img, w, jacobian=False, lens=lens)
        cost_new = (r_new * r_new).sum(-1)
        better = torch.isfinite(cost_new) & (cost_new < cost) & ~done & ~basin
        theta = torch.where(better[:, None], cand, theta)
        r = torch.where(better[:, None], r_new, r)
        cost = torch.where(better, cost_new, cost)
        lam = torch.where(better, torch.clamp(lam / 10, min=1e-15), torch.where(done | basin, lam, lam * 10))
        stalled = lam > 1e16  # no step lowers the cost any more: at the minimum to rounding
        done = done | stalled
    _, J = _residuals_and_jacobian(theta, obj, img, w, lens=lens)
    return theta, J * freef[:, None, :], r, it, done


class KorniaCalibrator(BaseCalibrator):
    """Reference built from kornia's projection and a torch Levenberg-Marquardt.

    Parameters
    ----------
    lens : str
        The lens model fitted (:data:`KORNIA_LENSES`: every circcal model).
    fix_k3 : bool
        Hold k3 at its initial value (0).
    device : {"cpu", "cuda"} or None
        Where :meth:`calibrate_batch` runs; None: CUDA when available. Single problems run on CPU.
    max_iter : int
        LM iterations.

    Raises
    ------
    ValueError
        An unknown lens model.
    """

    name = "kornia"
    modes = ("fair",)
    lenses = tuple(KORNIA_LENSES)

    def __init__(
        self, *, lens: str = "opencv5", fix_k3: bool = False, device: str | None = None, max_iter: int = 200
    ) -> None:
        if lens not in LENS_MODELS:
            raise ValueError(f"unknown lens model {lens!r}; expected one of {', '.join(LENS_MODELS)}")
        self.lens = lens
        self.fix_k3 = bool(fix_k3)
        self.device = device
        self.max_iter = int(max_iter)

    def _version(self) -> str:
        import kornia
        import torch

        return f"{kornia.__version__} (torch {torch.__version__})"

    def _available(self) -> tuple[bool, str]:
        try:
            import kornia  # noqa: F401
            import torch  # noqa: F401
        except ImportError as exc:
            return False, f"kornia/torch not importable ({exc}); pip install torch==2.13.0 kornia (CPU wheel)"
        return True, ""

    def _calibrate(
        self,
        object_points: list[np.ndarray],
        image_points: list[np.ndarray],
        image_size: tuple[int, int],
        *,
        mode: str,
        initial: Camera | None,
    ) -> ReferenceResult:
        problem = {
            "object_points": object_points,
            "image_points": image_points,
            "image_size": image_size,
            "initial": initial,
        }
        out = self._solve([problem], mode=mode, device="cpu" if self.device is None else self.device)[0]
        if isinstance(out, Exception):
            raise out
        return out

    def calibrate_batch(self, problems: Sequence[Problem], *, mode: str = "fair") -> list[ReferenceResult]:
        """Solve many problems at once (vectorised LM); never raises.

        Problems may differ in views and points (padded with zero weights). A problem whose observations fail
        :func:`circcal.observations.check_observations` gets status "failed" with the reason; the others are still
        solved.

        Parameters
        ----------
        problems : sequence of dict
            Each with "object_points" (per view (N_v, 3) mm), "image_points" (per view (N_v, 2) px), "image_size"
            (w, h) px and optional "initial" (:class:`circcal.model.Camera`).
        mode : str
            "fair" (the only estimator here).

        Returns
        -------
        list of ReferenceResult
            One per problem, in order.
        """
        ok, why = self.available()
        if not ok:
            return [self.result(mode, "unavailable", why) for _ in problems]
        try:
            self._check_lens()
        except NotImplementedError as exc:
            return [self.result(mode, "unsupported", str(exc)) for _ in problems]
        checked: list[Any] = []
        for p in problems:
            try:
                obj, img, size = check_observations(p["object_points"], p["image_points"], p["image_size"])
                checked.append(
                    {"object_points": obj, "image_points": img, "image_size": size, "initial": p.get("initial")}
                )
            except Exception as exc:  # noqa: BLE001
                checked.append(exc)
        good = [c for c in checked if not isinstance(c, Exception)]
        device = self.device
        if device is None:
            device = "cuda" if _torch().cuda.is_available() else "cpu"
        try:
            solved = iter(self._solve(good, mode=mode, device=device)) if good else iter(())
        except Exception as exc:  # noqa: BLE001  (the batch solve itself broke: every problem failed with it)
            msg = f"{type(exc).__name__}: {exc}"
            return [
                self.result(mode, "failed", msg if not isinstance(c, Exception) else f"{type(c).__name__}: {c}")
                for c in checked
            ]
        out = []
        for c in checked:
            if isinstance(c, Exception):
                out.append(self.result(mode, "failed", f"{type(c).__name__}: {c}"))
            else:
                r = next(solved)
                out.append(r if isinstance(r, ReferenceResult) else self.result(mode, "failed", f"{r}"))
        return out

    def _solve(self, problems: list[Problem], *, mode: str, device: str) -> list[ReferenceResult]:
        torch = _torch()
        n_obs = sum(sum(len(o) for o in p["object_points"]) for p in problems)
        if str(device) == "cpu" and n_obs <= SINGLE_THREAD_BELOW_POINTS and torch.get_num_threads() > 1:
            before = torch.get_num_threads()
            torch.set_num_threads(1)
            try:
                return self._solve(problems, mode=mode, device=device)
            finally:
                torch.set_num_threads(before)
        t0 = time.perf_counter()
        dt = torch.float64
        B = len(problems)
        V = max(len(p["object_points"]) for p in problems)
        N = max(max(len(o) for o in p["object_points"]) for p in problems)
        obj = np.zeros((B, V, N, 3))
        img = np.zeros((B, V, N, 2))
        w = np.zeros((B, V, N))
        vmask = np.zeros((B, V), dtype=bool)
        sizes = np.zeros((B, 2))
        for b, p in enumerate(problems):
            sizes[b] = p["image_size"]
            for v, (o, q) in enumerate(zip(p["object_points"], p["image_points"])):
                n = len(o)
                obj[b, v, :n], img[b, v, :n], w[b, v, :n] = o, q, 1.0
                obj[b, v, n:] = o[0]
                img[b, v, n:] = q[0]
                vmask[b, v] = True
            for v in range(len(p["object_points"]), V):  # padded views: a harmless copy of view 0 at weight 0
                obj[b, v], img[b, v] = obj[b, 0], img[b, 0]
        T = lambda a: torch.as_tensor(a, dtype=dt, device=device)  # noqa: E731
        obj_t, img_t, w_t, sizes_t = T(obj), T(img), T(w), T(sizes)
        vmask_t = torch.as_tensor(vmask, device=device)
        obj_t[..., 2] = 0.0
        lens = self.lens
        names = param_names(lens)
        n_intr = len(names)
        if lens == "fisheye":
            theta0, zhang_ok = _fisheye_init(obj_t, img_t, w_t, vmask_t, sizes_t)
        else:
            theta0, zhang_ok = _zhang_init(obj_t, img_t, w_t, vmask_t, sizes_t, ndist=n_intr - 4)
        free = torch.ones_like(theta0, dtype=torch.bool)
        if self.fix_k3:
            free[:, names.index("k3")] = False
        free[:, n_intr:] = vmask_t[:, :, None].expand(B, V, 6).reshape(B, -1)
        for b, p in enumerate(problems):
            if p.get("initial") is not None:
                if p["initial"].lens != lens:
                    raise ValueError(f"initial camera has lens {p['initial'].lens!r}, this reference fits {lens!r}")
                theta0[b, :n_intr] = T(p["initial"].intrinsics)
        # poses first with the intrinsics held (as OpenCV does), then everything
        free_pose = free.clone()
        free_pose[:, :n_intr] = False
        theta, _, _, it0, _ = _lm(theta0, obj_t, img_t, w_t, free_pose, max_iter=30, lens=lens)
        if len(names) > 9:  # rational / thin prism: OpenCV's 5 coefficients first, from the distortion-free start
            free_five = free.clone()
            free_five[:, [i for i, n in enumerate(names) if i >= 4 and n not in ("k1", "k2", "p1", "p2", "k3")]] = False
            theta, _, _, _, _ = _lm(theta, obj_t, img_t, w_t, free_five, max_iter=self.max_iter, lens=lens)
        theta, J, r, iters, conv = _lm(theta, obj_t, img_t, w_t, free, max_iter=self.max_iter, lens=lens)
        elapsed = time.perf_counter() - t0
        out: list[ReferenceResult] = []
        for b, p in enumerate(problems):
            try:
                nv = len(p["object_points"])
                th = theta[b].detach().cpu().numpy()
                cam = Camera.from_intrinsics(int(sizes[b, 0]), int(sizes[b, 1]), th[:n_intr], lens=lens)
                poses = th[n_intr:].reshape(V, 6)[:nv]
                if lens == "fisheye":
                    _check_in_front(poses, p["object_points"])
                fr = free[b].cpu().numpy()
                Jb = J[b].detach().cpu().numpy()[:, fr]
                rb = r[b].detach().cpu().numpy()
                n_obs = int(w[b].sum()) * 2
                n_free = int(fr.sum())
                sigma2 = float(rb @ rb) / max(n_obs - n_free, 1)
                cov = np.linalg.inv(Jb.T @ Jb) * sigma2
                sd_free = np.sqrt(np.clip(np.diag(cov), 0, None))
                sd = np.zeros(len(fr))
                sd[fr] = sd_free
                std = {n: float(sd[i]) for i, n in enumerate(names)}
                res = self.finish(
                    mode,
                    cam,
                    poses[:, :3],
                    poses[:, 3:],
                    p["object_points"],
                    p["image_points"],
                    t0,
                    std=std,
                    fixed=["k3"] if self.fix_k3 else [],
                    iterations=int(iters),
                    lens=lens,
                    kornia_model=KORNIA_LENSES[lens],
                    converged=bool(conv[b]),
                    zhang_closed_form=bool(zhang_ok[b]),
                    device=str(device),
                    batch_size=B,
                )
                res.time_s = elapsed / B
                if not bool(conv[b]):
                    res.message = f"LM stopped after {iters} iterations without meeting its tolerance"
                out.append(check_divergence(res))
            except NotImplementedError as exc:
                out.append(self.result(mode, "unsupported", str(exc)))
            except Exception as exc:  # noqa: BLE001
                out.append(self.result(mode, "failed", f"{type(exc).__name__}: {exc}"))
        return out


def _check_in_front(poses: np.ndarray, object_points: list[np.ndarray]) -> None:
    """``NotImplementedError`` when a board point of the solution lies at or beyond 90 deg off axis (z <= 0 in the
    camera frame): kornia's Kannala-Brandt takes points on the z = 1 plane and cannot represent it. poses (V, 6)."""
    from circcal.rotation import rodrigues

    for v, (pose, o) in enumerate(zip(poses, object_points)):
        z = (np.asarray(o) @ rodrigues(pose[:3]).T + pose[3:])[:, 2]
        if np.any(z <= 0):
            raise NotImplementedError(
                f"view {v}: {int(np.sum(z <= 0))} board point(s) at or beyond 90 deg off axis; kornia's "
                "distort_points_kannala_brandt takes points on the z = 1 plane and cannot represent them"
            )
