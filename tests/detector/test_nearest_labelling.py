"""A part of a board without markers placed by where the board's image is expected (a rig's other cameras):
:func:`circcal.detector.locate.labels.nearest_labelling`."""

from __future__ import annotations

import numpy as np

from circcal.board import Board
from circcal.detector.locate.labels import label_patch, nearest_labelling

BOARD = Board(8, 11, 15.0, 7.5)


def _part(rows: range):
    """The board points of ``rows``, their patch coordinates, and a synthetic image of the whole board (20 px
    pitch): what the detector sees of the part, and where every board point would be."""
    L = BOARD.lattice_coords()
    image = 20.0 * L.astype(np.float64) + 100.0
    part = np.flatnonzero(np.isin(L[:, 1], list(rows)))
    ab = L[part] - L[part].min(axis=0)
    return part, ab, image


def _same_place(chosen: np.ndarray, part: np.ndarray) -> bool:
    return any(np.array_equal(s.perm[chosen], part) for s in BOARD.symmetries(reflections=False))


def test_the_part_near_its_expected_image_is_chosen():
    part, ab, image = _part(range(1, 6))
    lab = label_patch(BOARD, ab)
    assert lab.status == "ambiguous" and len(lab.alternatives) == lab.placements >= 2
    pix = image[part] + np.random.default_rng(0).normal(0.0, 0.5, (len(part), 2))  # the rig's prediction error
    chosen = nearest_labelling(BOARD, lab.alternatives, pix, image)
    assert chosen is not None and _same_place(chosen, part)


def test_no_choice_where_the_expected_image_is_far_or_between_places():
    part, ab, image = _part(range(1, 6))
    lab = label_patch(BOARD, ab)
    pix = image[part]
    assert nearest_labelling(BOARD, lab.alternatives, pix + 10.0, image) is None  # half a pitch: between two places
    assert nearest_labelling(BOARD, lab.alternatives, pix + 500.0, image) is None  # nowhere near
    unknown = np.full_like(image, np.nan)
    assert nearest_labelling(BOARD, lab.alternatives, pix, unknown) is None  # nothing expected
