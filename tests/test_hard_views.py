"""Issue 13's bars on the hard views, against the truth of rendered fixtures: boards in the image corners (15-40 % of
the dot grid out of frame), occluded by a bar and a hand, ROS-I's origin dot, 60 blobs of clutter, a second board, a
dot logo, dots over 80 px, strong perspective on a 3x6 asymmetric grid, the partial scenario.

On every view: the board is found; at least :data:`MIN_LABELLED` of the dots that are truly visible and clear of
any occluder (truth.json ``clear``) are labelled; none is mislabelled (a wrong ID is worse than a missing one); the
centres, with the true camera model given, are within :data:`EXACT_RMS_PX` RMS of the truth on the renders without
blur or noise (the ``clean`` and ``exact-*`` variants, the occluders' own) and within :data:`NOISY_RMS_PX` on the
others. Beside it: wherever OpenCV's findCirclesGrid (plain or CLUSTERING) finds the grid, circcal does too.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from circcal.detector import detect
from circcal.fixtures.cache import fixture_dir
from circcal.fixtures.scenarios import SCENARIOS
from circcal.fixtures.truth import load_truth

HARD = ("markers", "occluded", "distractors", "origin", "large-dots", "asym-perspective", "partial")
MIN_LABELLED = 0.95
"""Share of the clear dots (truly visible, rim >= CLEAR_PX from an occluder) a view must label (issue 13)."""
EXACT_RMS_PX = 0.005
"""Centre RMS against the truth on renders without blur or noise, the true model given (issue 13: as on full
views)."""
NOISY_RMS_PX = 0.012
"""... and on the variants with blur and noise (sigma 0.005 of the range; measured <= 0.0075 px)."""
MISLABEL_PX = 1.0
"""A labelled dot further than this from its true position carries another dot's ID (a lattice step is >= 10 px
on every fixture; centres err by < 0.05 px)."""


def _exact(steps: list[dict]) -> bool:
    """No blur, noise or JPEG in a variant's perturbations: the centres can be held to the render's accuracy."""
    return not any(s["kind"] in ("gaussian_blur", "noise", "jpeg", "defocus", "motion_blur") for s in steps)


def _params(names):
    return [(n, v) for n in names for v in SCENARIOS[n].variants]


def _opencv_finds(img: np.ndarray, board) -> tuple[bool, bool]:
    """(plain, CLUSTERING): whether cv2.findCirclesGrid finds the grid."""
    g = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if g.dtype != np.uint8:
        g = cv2.convertScaleAbs(g, alpha=255.0 / max(float(g.max()), 1.0))
    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if board.layout == "asymmetric" else cv2.CALIB_CB_SYMMETRIC_GRID
    return (
        bool(cv2.findCirclesGrid(g, board.pattern_size, flags=flags)[0]),
        bool(cv2.findCirclesGrid(g, board.pattern_size, flags=flags | cv2.CALIB_CB_CLUSTERING)[0]),
    )


def labelled_errors(board, centres: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((N,) |detected - true| px, NaN where not labelled; (N,) the truth's point of each board point) under the
    board's symmetry that fits best (the identity alone on a marker board: its labels are absolute)."""
    seen = np.all(np.isfinite(centres), axis=1)
    best = None
    for s in board.symmetries():
        e = np.full(len(centres), np.nan)
        e[seen] = np.linalg.norm(centres[seen] - truth[s.perm][seen], axis=1)
        if best is None or np.nanmedian(e) < np.nanmedian(best[0]):
            best = (e, s.perm)
    return best


@pytest.mark.parametrize("name,variant", _params(HARD))
def test_hard_views_labelled_right_and_accurate(name, variant):
    tr = load_truth(fixture_dir(name, variant))
    exact = _exact(SCENARIOS[name].variants[variant])
    bound = EXACT_RMS_PX if exact else NOISY_RMS_PX
    lines, failures = [], []
    for k, v in enumerate(tr.views):
        img = cv2.imread(str(v.image), cv2.IMREAD_UNCHANGED)
        d = detect(img, tr.board, tr.camera)
        ocv = _opencv_finds(img, tr.board)
        if not d.found:
            failures.append(f"view {k} ({v.kind}): not found: {d.reason}")
            continue
        e, perm = labelled_errors(tr.board, d.centres, v.centres)
        clear = v.clear[perm]
        seen = np.isfinite(e)
        share = float(np.sum(seen & clear)) / max(int(clear.sum()), 1)
        wrong = int(np.sum(e[seen] > MISLABEL_PX))
        rms = float(np.sqrt(np.mean(e[seen] ** 2)))
        lines.append(
            f"view {k:2d} ({v.kind:6s}): {int(seen.sum()):3d} labelled, {share:6.1%} of {int(clear.sum())} "
            f"clear, {wrong} wrong, RMS {rms:.4f} px, {d.n_dropped} dropped; OpenCV plain/clustering "
            f"{ocv[0]}/{ocv[1]}"
        )
        if share < MIN_LABELLED:
            failures.append(f"view {k}: {share:.1%} of the clear dots labelled (dropped: {d.dropped})")
        if wrong:
            failures.append(f"view {k}: {wrong} dots mislabelled")
        if rms > bound:
            failures.append(f"view {k}: centre RMS {rms:.4f} px > {bound}")
    print(f"\n{name}/{variant} ({'exact' if exact else 'blur + noise'} renders, true model):\n  " + "\n  ".join(lines))
    assert not failures, "\n".join(failures)


def _views(name: str, variant: str, n: int | None):
    tr = load_truth(fixture_dir(name, variant))
    return tr, tr.views if n is None else tr.views[:n]


def _parity(name: str, variant: str, n: int | None) -> None:
    tr, views = _views(name, variant, n)
    rows, missed = [0, 0, 0], []
    for k, v in enumerate(views):
        img = cv2.imread(str(v.image), cv2.IMREAD_UNCHANGED)
        plain, clus = _opencv_finds(img, tr.board)
        d = detect(img, tr.board)
        rows[0] += plain
        rows[1] += clus
        rows[2] += d.found
        if (plain or clus) and not d.found:
            missed.append(f"view {k}: {d.reason}")
        elif d.found:  # a found grid is the right one, every dot with its own ID (perspective-only correction,
            # no lens model: up to 0.6 px off on the partial scenario's large dots near the corners of a k1 -0.15 lens)
            e, _ = labelled_errors(tr.board, d.centres, v.centres)
            assert np.nanmax(e) < MISLABEL_PX, f"view {k}: a found grid off the truth by {np.nanmax(e):.2f} px"
    print(f"\n{name}/{variant}: {len(views)} views; OpenCV plain {rows[0]}, CLUSTERING {rows[1]}; circcal {rows[2]}")
    assert not missed, "OpenCV finds the grid, circcal does not:\n" + "\n".join(missed)


PARITY = ("paper", "wide", "tilted-large-dots", "asymmetric", "small-noisy")
"""The calibration scenarios held beside OpenCV (the hard views are, in the test above, view by view)."""


@pytest.mark.parametrize("name,variant", _params(PARITY))
def test_circcal_finds_the_grid_wherever_opencv_does(name, variant):
    _parity(name, variant, 3)


@pytest.mark.slow
@pytest.mark.parametrize("name,variant", _params(PARITY + HARD))
def test_circcal_finds_the_grid_wherever_opencv_does_every_view(name, variant):
    _parity(name, variant, None)


def test_opencv_parity_on_the_test_renders():
    # the renders of tests/detector/test_find.py's accuracy bars (4x5 board, dots 7-30 px, tilts 0-60 deg) and its
    # larger frames: wherever OpenCV finds the grid, circcal finds it, at the true positions
    from circcal.board import Board
    from circcal.fixtures.poses import pose_looking_at
    from circcal.fixtures.render import render_view, to_uint
    from circcal.model import Camera, project

    cam = Camera(1280, 960, 1600.0, 1600.0, 639.5, 479.5)
    board = Board(4, 5, 10.0, 5.0)
    both = 0
    for radius in (7, 15, 30):
        for tilt in (0, 30, 45, 60):
            rvec, tvec = pose_looking_at(
                cam,
                board,
                distance_mm=cam.fx * board.radius_mm / radius,
                tilt_deg=tilt,
                tilt_axis_deg=30.0,
                roll_deg=10.0,
                target_px=(700.0, 500.0),
            )
            img = to_uint(render_view(cam, board, rvec, tvec), 8)
            plain, clus = _opencv_finds(img, board)
            d = detect(img, board)
            if plain or clus:
                both += 1
                assert d.found, f"R={radius} tilt={tilt}: {d.reason}"
            if d.found:
                truth = project(board.object_points(), rvec, tvec, cam)
                assert np.nanmax(labelled_errors(board, d.centres, truth)[0]) < 0.05
    assert both >= 6  # OpenCV finds most of them: the comparison is not empty


@pytest.mark.parametrize(
    "folder,board_args",
    [
        ("boofcv_sony_hx5v_circle_asym_4x5", (5, 4, 30.0, 20.0, "asymmetric")),
        ("boofcv_sony_hx5v_circle_regular_10x8", (8, 10, 25.0, 15.0, "symmetric")),
    ],
)
def test_opencv_parity_on_the_real_photographs(realdata, folder, board_args):
    from circcal.board import Board

    board = Board(*board_args)
    paths = sorted((realdata / folder).glob("*.jpg"))
    assert paths
    counts = [0, 0, 0]
    for p in paths:
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        plain, clus = _opencv_finds(img, board)
        d = detect(img, board)
        counts = [counts[0] + plain, counts[1] + clus, counts[2] + d.found]
        assert d.found, f"{p.name}: {d.reason} (OpenCV plain/clustering {plain}/{clus})"
    print(
        f"\n{folder}: {len(paths)} photographs; OpenCV plain {counts[0]}, CLUSTERING {counts[1]}; circcal {counts[2]}"
    )
