"""A study's solver-only cells solved in batches through kornia (CPU here; CUDA when present, untested without a
GPU) equal circcal's solver on the same noise draws to 1e-6 px."""

from __future__ import annotations

import pytest

from circcal.analysis.compare import projection_diff
from circcal.model import PARAM_NAMES, Camera
from circcal.study import parse_spec
from circcal.study.execute import execute
from circcal.study.plan import plan
from circcal.validators.checks import SOLVER_PX

pytest.importorskip("kornia")


def test_batched_kornia_equals_circcals_solver():
    spec = parse_spec(
        {
            "name": "batched",
            "cells": [
                {
                    "kind": "observations",
                    "scenario": "paper",
                    "noise_px": [0.0146],
                    "seeds": 4,
                    "calibrators": ["circcal", "kornia"],
                    "batch": 4,
                    "device": "cpu",
                }
            ],
        }
    )
    tasks = plan(spec)
    assert [len(t.runs) for t in tasks] == [4, 4]
    circcal_rows, kornia_rows = (execute(t) for t in tasks)
    for a, b in zip(circcal_rows, kornia_rows):
        assert a["seed"] == b["seed"] and a["status"] == b["status"] == "ok"
        assert b["device"] == "cpu" and b["batch_size"] == 4
        cams = [Camera.from_intrinsics(1920, 1080, [r[f"est_{p}"] for p in PARAM_NAMES]) for r in (a, b)]
        assert projection_diff(*cams)["max_px"] <= SOLVER_PX
        assert b["std_fx"] == pytest.approx(a["std_fx"], rel=1e-4)
