"""The study runner (`circcal study`): throughput with 1 and 2 embedded workers, the runner's overhead per run, and
batched solves (kornia, CPU; CUDA where present) against a loop of cv2.calibrateCamera on the same problems.

Throughput: an observations study (the `paper` views, perfect centres + 0.0146 px noise, circcal's solver, tasks of
``BATCH`` runs) on a warm embedded LocalCluster of 1 and of 2 single-threaded workers, and the same tasks executed
in this process without Dask; the three timed alternately, ``REPEATS`` times, medians. ``runner_overhead_fraction``:
(runner wall time with 1 worker - in-process time) / in-process time, i.e. the runner's cost per run as a share of a
run's own time (goal < 0.05). Cluster start-up and the first task's imports are one-time costs, reported apart.
Every process has one BLAS/OpenMP thread (benchmarks/run.py; Dask's workers start with one); the 2-worker ratio
on a 2-core machine also shares the cores with the client process.

Batched solves: ``N_BATCH`` problems (the same views, different noise draws) as one kornia batch, against
cv2.calibrateCamera on each in turn (float32 points, one OpenCV thread, 500 iterations / eps 1e-16 as the OpenCV
adapter), alternately; solves per second and the batch's largest projection difference to circcal's solver.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

#: Runs per throughput timing: ~6 s of solving on one core, long enough that a timing is not start-up noise.
N_RUNS = 400
#: Runs per task, as studies/*.yaml use for observations cells (circcal.study.spec.DEFAULT_BATCH).
BATCH = 20
#: Alternating repeats of each timing (fewer than the 9 of benchmarking.md: each repeat is a whole study).
REPEATS = 3
#: Problems per kornia batch.
N_BATCH = 32
SIGMA_PX = 0.0146


def _spec(n_runs: int):
    from circcal.study import parse_spec

    return parse_spec({"name": "bench", "cells": [{
        "kind": "observations", "scenario": "paper", "noise_px": [SIGMA_PX], "seeds": n_runs,
        "calibrators": ["circcal"], "batch": BATCH}]})


def _throughput() -> dict:
    from dask.distributed import Client, LocalCluster

    from circcal.study import run_study
    from circcal.study.execute import execute
    from circcal.study.plan import plan

    spec = _spec(N_RUNS)
    tasks = plan(spec)
    execute(tasks[0])  # this process warm, as the workers are below
    clusters, startup = {}, {}
    try:
        for n in (1, 2):
            t0 = time.perf_counter()
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                                   silence_logs=40)
            client = Client(cluster)
            startup[n] = time.perf_counter() - t0
            t0 = time.perf_counter()
            client.gather(client.map(execute, tasks[:n], pure=False))  # the first task's imports, once per worker
            startup[f"warm{n}"] = time.perf_counter() - t0
            clusters[n] = (cluster, client)
        times: dict = {"direct": [], 1: [], 2: []}
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            for t in tasks:
                execute(t)
            times["direct"].append(time.perf_counter() - t0)
            for n in (1, 2):
                with tempfile.TemporaryDirectory() as d:
                    res = run_study(spec, Path(d), client=clusters[n][1], progress=False)
                assert res.complete and res.n_computed == N_RUNS
                times[n].append(res.wall_s)
    finally:
        for cluster, client in clusters.values():
            client.close()
            cluster.close()
    direct, w1, w2 = (float(np.median(times[k])) for k in ("direct", 1, 2))
    return {
        "study_runs": N_RUNS, "study_runs_per_task": BATCH,
        "inprocess_s_per_run": direct / N_RUNS,
        "runs_per_s_1_worker": N_RUNS / w1, "runs_per_s_2_workers": N_RUNS / w2,
        "throughput_ratio_2_over_1_workers": w1 / w2,
        "runner_overhead_s_per_run": (w1 - direct) / N_RUNS,
        "runner_overhead_fraction": (w1 - direct) / direct, "runner_overhead_goal": 0.05,
        "cluster_start_s_1_worker": startup[1], "cluster_start_s_2_workers": startup[2],
        "first_task_warmup_s": startup["warm1"],
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

    from circcal.model import Camera
    from circcal.solver import calibrate
    from circcal.study.batched import solve_batch
    from circcal.validators.compare import projection_diff

    obj, draws, size = _problems()
    obj32 = [o.astype(np.float32) for o in obj]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-16)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    times: dict = {"cv2": [], **{d: [] for d in devices}}
    results = {}
    try:
        for d in devices:
            solve_batch(obj, draws[:2], size, device=d)  # warm-up (torch.func tracing, CUDA context)
        for _ in range(REPEATS):
            for d in devices:
                t0 = time.perf_counter()
                results[d] = solve_batch(obj, draws, size, device=d)
                times[d].append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            for img in draws:
                cv2.calibrateCamera(obj32, [p.astype(np.float32) for p in img], size, None, None, criteria=crit)
            times["cv2"].append(time.perf_counter() - t0)
    finally:
        cv2.setNumThreads(threads)
    out = {"batch_problems": N_BATCH, "batch_views": len(obj), "torch_threads": torch.get_num_threads(),
           "cv2_calibrateCamera_solves_per_s": N_BATCH / float(np.median(times["cv2"]))}
    for d in devices:
        rate = N_BATCH / float(np.median(times[d]))
        worst = 0.0
        for img, r in zip(draws, results[d]):
            assert r.ok, r.message
            ref = calibrate(obj, img, size).camera
            worst = max(worst, projection_diff(ref, Camera.from_intrinsics(*size, r.camera.intrinsics))["max_px"])
        out[f"kornia_batch_{d}_solves_per_s"] = rate
        out[f"kornia_batch_{d}_vs_cv2_ratio"] = rate / out["cv2_calibrateCamera_solves_per_s"]
        out[f"kornia_batch_{d}_max_px_vs_circcal_solver"] = worst
    if "cuda" not in devices:
        out["kornia_batch_cuda"] = "not measured: no CUDA device here"
    return out


def run() -> dict:
    return {**_throughput(), **_batched()}


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2))
