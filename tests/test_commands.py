"""The command-line commands' shared rules (:mod:`circcal.commands`)."""

from __future__ import annotations

import numpy as np
import pytest


def test_cli_board_rule_is_the_same_for_every_command():
    from circcal.commands.args import board_from_args

    asym = board_from_args((11, 4), 10.0, None, True)
    assert asym.layout == "asymmetric" and (asym.rows, asym.cols) == (11, 4)
    assert asym.diameter_mm == pytest.approx(5.0 * np.sqrt(2.0))  # half the nearest-dot spacing, sqrt(2) pitches
    assert board_from_args((7, 7), 10.0, None, False).diameter_mm == 5.0
    assert board_from_args((7, 7), 10.0, 4.0, True).diameter_mm == 4.0
