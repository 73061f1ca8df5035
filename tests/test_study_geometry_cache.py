"""The noise-free render kept per worker process (:func:`circcal.study.seeded.geometry`): the seeds of a
``vary: noise`` cell start from one render of their shared views and give the same images, bit for bit, and the
same rows as rendering every seed afresh."""

from __future__ import annotations

import math

import pytest

from circcal.fixtures.cache import render_fixture
from circcal.study import parse_spec, seeded
from circcal.study.execute import execute
from circcal.study.plan import plan
from circcal.study.rows import TIME_COLUMNS

VARIANTS = ["noisy", "very-noisy"]


@pytest.fixture
def fresh_cache():
    seeded.geometry.cache_clear()
    yield seeded.geometry
    seeded.geometry.cache_clear()


def test_noise_seeds_share_one_geometry_and_render_the_same_files(tmp_path, fresh_cache):
    one, two = seeded.seeded_scenario("small-noisy", 1), seeded.seeded_scenario("small-noisy", 2)
    assert one.geometry_spec() == two.geometry_spec() and one.key("noisy") != two.key("noisy")
    own = seeded.seeded_scenario("small-noisy", 3)  # the catalogue's own seed: its poses are the same ones
    assert own.geometry_spec() == one.geometry_spec()
    assert seeded.seeded_scenario("small-noisy", 2, "scene").geometry_spec() != one.geometry_spec()
    seeded.geometry(one)  # rendered for seed 1, then reused by seed 2
    reused = render_fixture(two, tmp_path / "reused", VARIANTS, progress=False, geometry=seeded.geometry(two))
    assert fresh_cache.cache_info().misses == 1 and fresh_cache.cache_info().hits == 1
    fresh = render_fixture(two, tmp_path / "fresh", VARIANTS, progress=False)
    for v in VARIANTS:
        names = sorted(p.name for p in fresh[v].iterdir())
        assert len(names) == 15 and names == sorted(p.name for p in reused[v].iterdir())  # 14 images, truth.json
        for name in names:
            assert (fresh[v] / name).read_bytes() == (reused[v] / name).read_bytes(), (v, name)
    g = seeded.geometry(two)
    assert len(g) == 14 and not g[0].clean.flags.writeable  # one render serves many: nobody may change it


def _same(a: dict, b: dict) -> list[str]:
    def eq(x, y):
        return x == y or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))

    return [c for c in a if c not in TIME_COLUMNS and not eq(a[c], b[c])]


def test_rows_with_and_without_the_geometry_cache_are_identical(monkeypatch, fresh_cache, cv2_single_thread):
    spec = parse_spec(
        {
            "name": "geometry-cache",
            "cells": [
                {
                    "kind": "images",
                    "scenario": "small-noisy",
                    "variants": ["noisy"],
                    "vary": "noise",
                    "seeds": [0, 1, 2],
                    "calibrators": ["circcal", "opencv"],
                }
            ],
        }
    )
    tasks = plan(spec)
    monkeypatch.setattr(seeded, "GEOMETRY_CACHE", False)
    uncached = [row for t in tasks for row in execute(t)]
    assert fresh_cache.cache_info().currsize == 0
    monkeypatch.setattr(seeded, "GEOMETRY_CACHE", True)
    cached = [row for t in tasks for row in execute(t)]
    assert fresh_cache.cache_info().misses == 1 and fresh_cache.cache_info().hits == 2  # one render, three seeds
    assert len(cached) == len(uncached) == 6 and {r["status"] for r in cached} == {"ok"}
    for a, b in zip(uncached, cached):
        assert a["key"] == b["key"] and _same(a, b) == [], (a["seed"], a["variant"], a["calibrator"])
