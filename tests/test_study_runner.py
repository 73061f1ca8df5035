"""The study runner on the embedded cluster: one row per run with every column, resumable (a rerun computes
nothing), rows written atomically in batches, summary and figures, the CLI; and the worker-side computation of a
run (rendered images and observations-only) without a cluster."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from circcal.cli import main
from circcal.model import PARAM_NAMES
from circcal.study import RowStore, parse_spec, run_study, summarise, write_summary
from circcal.study.execute import execute
from circcal.study.plan import plan
from circcal.study.rows import COLUMNS

OBS = {
    "kind": "observations",
    "scenario": "paper",
    "noise_px": [0.0146, 0.05],
    "seeds": 6,
    "calibrators": ["circcal", "opencv"],
    "batch": 4,
}


def test_observations_study_embedded_is_resumable(tmp_path):
    spec = parse_spec({"name": "obs", "cells": [OBS]}, source="name: obs\n")
    first = run_study(spec, tmp_path, workers=2, progress=False, flush_rows=5)
    assert first.complete and first.n_computed == spec.n_runs == 24 and first.workers == 2
    store = RowStore(tmp_path)
    assert len(store.parts()) >= 2  # written in batches as tasks finished, not once at the end
    table = store.read()
    assert table.num_rows == 24 and table.column_names == [n for n, _ in COLUMNS]
    rows = table.to_pylist()
    assert {r["status"] for r in rows} == {"ok"} and len({r["key"] for r in rows}) == 24
    for r in rows:
        assert r["n_views"] == 14 and r["n_points"] == 14 * 49 and r["lens_model"] == "opencv5"
        # the three residual conventions: per coordinate = per point / sqrt(2), mean 2-D in between
        assert r["rms_per_coord_px"] == pytest.approx(r["rms_per_point_px"] / np.sqrt(2), rel=1e-12)
        assert r["rms_per_coord_px"] < r["mean_2d_px"] < r["rms_per_point_px"]
        assert all(np.isfinite(r[f"std_{p}"]) and r[f"std_{p}"] > 0 for p in PARAM_NAMES)
        assert r["err_fx"] == pytest.approx(r["est_fx"] - r["true_fx"]) and r["truth_rms_px"] < 1.0
        assert r["time_s"] > 0 and '"numpy"' in r["versions"] and r["calibrator_version"]
    # the same noise draw for both calibrators: OpenCV's solve equals circcal's (float32 points aside)
    by = {(r["variant"], r["seed"], r["calibrator"]): r for r in rows}
    for (v, s, c), r in by.items():
        if c == "opencv":
            assert abs(r["est_fx"] - by[(v, s, "circcal")]["est_fx"]) < 0.05 * r["std_fx"]
    parts = store.parts()
    again = run_study(spec, tmp_path, workers=2, progress=False)
    assert again.n_done_before == 24 and again.n_computed == 0 and store.parts() == parts
    # a larger spec computes only what is new
    bigger = parse_spec({"name": "obs", "cells": [{**OBS, "seeds": 8}]})
    more = run_study(bigger, tmp_path, workers=1, progress=False)
    assert more.n_done_before == 24 and more.n_computed == 8
    assert store.compact() is not None and len(store.parts()) == 1 and store.read().num_rows == 32


def test_summary_tables_and_figures(tmp_path):
    spec = parse_spec(
        {"name": "obs", "cells": [{**OBS, "calibrators": ["circcal"]}]},
        source="name: obs\ncells:\n- {kind: observations, scenario: paper, noise_px: [0.0146, 0.05], "
        "seeds: 6, calibrators: [circcal], batch: 4}\n",
    )
    rows = [row for t in plan(spec) for row in execute(t)]
    RowStore(tmp_path).append(rows)
    (tmp_path / "study.yaml").write_text(spec.source)
    md = write_summary(tmp_path).read_text()
    assert "Sigma honesty" in md and "paper/noise0.0146px/circcal" in md and "ratio.png" in md
    for f in ("ratio.png", "bias.png", "pass_rate.png"):
        assert (tmp_path / "figures" / f).stat().st_size > 1000
    assert (tmp_path / "summary.json").exists()
    cells = summarise(RowStore(tmp_path).read())
    assert [c.label for c in cells] == ["paper/noise0.0146px/circcal", "paper/noise0.05px/circcal"]
    for c in cells:
        fx = c.params["fx"]
        assert c.n_ok == 6 and fx.n == 6 and fx.ratio_ci[0] < fx.ratio < fx.ratio_ci[1]
        assert fx.ratio == pytest.approx(fx.spread / fx.stated) and 0 < c.pass_rate <= 1
    # the same noise draws scaled: the error grows with the noise (one seed's draw, two sigmas)
    assert cells[1].params["fx"].stated == pytest.approx(cells[0].params["fx"].stated * 0.05 / 0.0146, rel=0.02)


def test_images_task_renders_on_the_worker_and_runs_every_calibrator():
    spec = parse_spec(
        {
            "name": "img",
            "cells": [
                {
                    "kind": "images",
                    "scenario": "small-noisy",
                    "variants": ["noisy"],
                    "seeds": [1],
                    "calibrators": ["circcal", "opencv", {"name": "opencv", "observations": "circcal"}],
                }
            ],
        }
    )
    (task,) = plan(spec)
    rows = {r["calibrator"]: r for r in execute(task)}
    assert set(rows) == {"circcal", "opencv", "opencv-on-circcal"}
    c = rows["circcal"]
    assert c["status"] == "ok" and c["images_total"] == 14 and c["images_used"] >= 12 and c["fixture_s"] > 0
    for name in ("fx", "fy", "cx", "cy"):
        assert abs(c[f"err_{name}"]) < 4 * c[f"std_{name}"], name
    shared = rows["opencv-on-circcal"]
    assert shared["status"] == "ok" and shared["n_points"] == c["n_points"]
    assert abs(shared["est_fx"] - c["est_fx"]) < 0.01 * c["std_fx"]  # the same centres (float32) and estimator
    assert rows["opencv"]["status"] in ("ok", "failed") and rows["opencv"]["images_total"] == 14


def test_cli_study_and_summary_only(tmp_path, capsys, monkeypatch):
    from circcal.study import engine

    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 2.0)
    spec = tmp_path / "s.yaml"
    spec.write_text(
        "name: cli\ncells:\n- {kind: observations, scenario: paper, noise_px: 0.0146, seeds: 3, "
        "calibrators: [circcal], batch: 3}\n"
    )
    out = tmp_path / "out"
    assert main(["study", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "computed 3 runs" in text and (out / "summary.md").exists() and (out / "study.yaml").exists()
    assert main(["study", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    assert "nothing to run: all 3 runs were done before" in capsys.readouterr().out
    assert main(["study", str(spec), "--out", str(out), "--summary-only"]) == 0
    assert main(["study", str(tmp_path / "nope.yaml"), "--out", str(out)]) == 2
    assert "file not found" in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    assert main(["study", str(spec), "--out", str(tmp_path / "file")]) == 2
    assert (
        main(["study", str(spec), "--out", str(tmp_path / "o2"), "--scheduler", "tcp://127.0.0.1:1", "--no-progress"])
        == 2
    )
    assert "cannot connect" in capsys.readouterr().err


class Broken:
    """A user's calibrator with a bug that escapes it (no run_safely around it): its task fails."""

    name = "broken"
    version = "0"

    def available(self):
        return True, ""

    def calibrate_observations(self, *args, **kwargs):
        raise RuntimeError("a bug in the calibrator")


def test_a_failing_task_is_reported_and_the_other_runs_are_kept(tmp_path):
    plugin = f"{Path(__file__).resolve()}:Broken"
    spec = parse_spec(
        {
            "name": "broken",
            "cells": [{**OBS, "noise_px": [0.0146], "seeds": 2, "calibrators": ["circcal", {"plugin": plugin}]}],
        }
    )
    res = run_study(spec, tmp_path, workers=1, progress=False)
    assert not res.complete and res.n_computed == 2 and len(res.errors) == 1
    assert "RuntimeError: a bug in the calibrator" in res.errors[0]
    assert {r["calibrator"] for r in RowStore(tmp_path).read().to_pylist()} == {"circcal"}
    again = run_study(spec, tmp_path, workers=1, progress=False)  # the failed runs are retried, the rest skipped
    assert again.n_done_before == 2 and again.n_computed == 0 and len(again.errors) == 1
