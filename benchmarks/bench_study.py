"""The study runner (`circcal study`): throughput with 1 and 2 embedded workers, the runner's overhead per run, and
batched solves (kornia, CPU; CUDA where present) against a loop of cv2.calibrateCamera on the same problems.

Throughput: an observations study (the `paper` views, perfect centres + 0.0146 px noise, circcal's solver, tasks of
``BATCH`` runs) through :func:`circcal.study.run_study` on a warm embedded LocalCluster of 1 and of 2
single-threaded workers, and the same tasks executed in this process without Dask (one BLAS and OpenCV thread),
alternated (benchmarks/timing.py), each timing a whole call: planning, submitting, gathering and writing the rows.
``runner_overhead_fraction`` = runner with 1 worker / in-process - 1: the runner's cost per run as a share of a run's
own time (goal < 0.05). ``throughput_ratio_2_over_1_workers`` = time with 1 worker / time with 2 (2 = perfect; on a
2-core machine the client shares the cores). Cluster start-up and the first task's imports are one-time costs,
reported apart.

Batched solves: ``N_BATCH`` problems (the same views, different noise draws, float32-representable points) as one
kornia batch, against cv2.calibrateCamera on each in turn (one OpenCV thread, 500 iterations / eps 1e-16 as the
OpenCV adapter), alternated; solves per second and the batch's largest projection difference to circcal's solver.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.timing import MIN_REPEATS, alternate, pinned, ratio, summary

#: Runs per throughput timing: ~3 s of solving on one core, long against the runner's per-call costs.
N_RUNS = 200
#: Runs per task, as studies/*.yaml use for observations cells (circcal.study.spec.DEFAULT_BATCH).
BATCH = 20
#: Problems per kornia batch.
N_BATCH = 32
SIGMA_PX = 0.0146


def _spec(n_runs: int):
    from circcal.study import parse_spec

    return parse_spec(
        {
            "name": "bench",
            "cells": [
                {
                    "kind": "observations",
                    "scenario": "paper",
                    "noise_px": [SIGMA_PX],
                    "seeds": n_runs,
                    "calibrators": ["circcal"],
                    "batch": BATCH,
                }
            ],
        }
    )


def _throughput() -> dict:
    from dask.distributed import Client, LocalCluster

    from circcal.study import run_study
    from circcal.study.execute import execute
    from circcal.study.plan import plan

    spec = _spec(N_RUNS)
    tasks = plan(spec)
    clusters, startup = {}, {}

    def direct():
        for t in tasks:
            execute(t)

    def runner(n: int):
        with tempfile.TemporaryDirectory() as d:
            res = run_study(spec, Path(d), client=clusters[n][1], progress=False)
        assert res.complete and res.n_computed == N_RUNS

    try:
        for n in (1, 2):
            t0 = time.perf_counter()
            cluster = LocalCluster(
                n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=40
            )
            clusters[n] = (cluster, Client(cluster))
            startup[n] = time.perf_counter() - t0
        with pinned(1) as threads:
            t = alternate({"inprocess": direct, "runner_1": lambda: runner(1), "runner_2": lambda: runner(2)})
    finally:
        for cluster, client in clusters.values():
            client.close()
            cluster.close()
    return {
        "study_runs": N_RUNS,
        "study_runs_per_task": BATCH,
        "repeats": MIN_REPEATS,
        **threads,
        "inprocess_s": summary(t["inprocess"]),
        "runner_1_worker_s": summary(t["runner_1"]),
        "runner_2_workers_s": summary(t["runner_2"]),
        "inprocess_ms_per_run": 1e3 * summary(t["inprocess"])["median"] / N_RUNS,
        "runs_per_s_1_worker": N_RUNS / summary(t["runner_1"])["median"],
        "runs_per_s_2_workers": N_RUNS / summary(t["runner_2"])["median"],
        "throughput_ratio_2_over_1_workers": ratio(t["runner_1"], t["runner_2"]),
        "runner_over_inprocess_ratio": ratio(t["runner_1"], t["inprocess"]),
        "runner_overhead_fraction": {k: v - 1.0 for k, v in ratio(t["runner_1"], t["inprocess"]).items()},
        "runner_overhead_goal": 0.05,
        "cluster_start_s_1_worker": startup[1],
        "cluster_start_s_2_workers": startup[2],
        "note": "the first (warm-up) round pays each worker's imports; the timed rounds are warm",
    }


def _problems():
    from circcal.fixtures.scenarios import get_scenario
    from circcal.model import project

    sc = get_scenario("paper")
    obj = sc.board.object_points()
    ideal = [project(obj, r, t, sc.camera) for r, t in sc.poses()]
    draws = []
    for s in range(N_BATCH):
        rng = np.random.default_rng(s)
        # float32-representable, so OpenCV (float32 only) and kornia solve exactly the same points
        draws.append([(p + rng.normal(0.0, SIGMA_PX, p.shape)).astype(np.float32).astype(np.float64) for p in ideal])
    return [obj] * len(ideal), draws, (sc.camera.width, sc.camera.height)


def _batched() -> dict:
    import cv2
    import torch

    from circcal.analysis.compare import projection_diff
    from circcal.model import Camera
    from circcal.solver import calibrate
    from circcal.study.batched import solve_batch

    obj, draws, size = _problems()
    obj32 = [o.astype(np.float32) for o in obj]
    img32 = [[p.astype(np.float32) for p in img] for img in draws]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-16)
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    results: dict = {}

    def kornia(d: str):
        def go():
            results[d] = solve_batch(obj, draws, size, device=d)

        return go

    def cv2_loop():
        for img in img32:
            cv2.calibrateCamera(obj32, img, size, None, None, criteria=crit)

    with pinned(1) as threads:
        t = alternate({**{f"kornia_{d}": kornia(d) for d in devices}, "cv2_loop": cv2_loop})
    out = {
        "batch_problems": N_BATCH,
        "batch_views": len(obj),
        "torch_threads": torch.get_num_threads(),
        **threads,
        "cv2_calibrateCamera_solves_per_s": N_BATCH / summary(t["cv2_loop"])["median"],
    }
    for d in devices:
        worst = 0.0
        for img, r in zip(draws, results[d]):
            assert r.ok, r.message
            ref = calibrate(obj, img, size).camera
            worst = max(worst, projection_diff(ref, Camera.from_intrinsics(*size, r.camera.intrinsics))["max_px"])
        out[f"kornia_batch_{d}_s"] = summary(t[f"kornia_{d}"])
        out[f"kornia_batch_{d}_solves_per_s"] = N_BATCH / summary(t[f"kornia_{d}"])["median"]
        out[f"kornia_batch_{d}_over_cv2_loop_time"] = ratio(t[f"kornia_{d}"], t["cv2_loop"])
        out[f"kornia_batch_{d}_max_px_vs_circcal_solver"] = worst
    if "cuda" not in devices:
        out["kornia_batch_cuda"] = "not measured: no CUDA device here"
    return out


def run() -> dict:
    return {**_throughput(), **_batched()}


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2))
