"""The same study on an external Dask cluster (a `dask scheduler` and two `dask worker` processes on localhost, as a
user starts them on a cluster) gives the embedded cluster's rows; killing a worker mid-study loses no finished run
(Dask re-runs its task elsewhere); killing the client mid-study keeps every row written, and rerunning computes
exactly the rest."""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import ExitStack, contextmanager
from pathlib import Path

import pytest

from circcal.study import RowStore, parse_spec, run_study
from circcal.study.engine import study_keys
from circcal.study.rows import TIME_COLUMNS

REPO = Path(__file__).resolve().parents[1]
DASK = Path(sys.executable).with_name("dask")
#: Seconds one run of the slow calibrator below sleeps, so a study lasts long enough to be interrupted mid-way.
SLOW_S = 0.25
#: Longest wait (s) for a cluster to come up or a study to reach the point where the test interrupts it.
WAIT_S = 120.0


def slow_opencv(object_points, image_points, image_size):
    """A user's calibrator (the pytest plug-in's function interface): OpenCV, after a pause."""
    from circcal.validators.opencv import OpenCVCalibrator

    time.sleep(SLOW_S)
    return OpenCVCalibrator().calibrate_observations(object_points, image_points, image_size)


SLOW_PLUGIN = f"slow={Path(__file__).resolve()}:slow_opencv"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    """End a process started here in its own session, and its children (its process group), by its id."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(15)


@contextmanager
def external_cluster(logs: Path, n_workers: int = 2):
    """``(address, worker processes)`` of a scheduler and ``n_workers`` single-threaded workers on localhost."""
    address = f"tcp://127.0.0.1:{_free_port()}"
    logs.mkdir(parents=True, exist_ok=True)
    procs: list[subprocess.Popen] = []
    with ExitStack() as files:

        def start(args: list[str], log: str) -> subprocess.Popen:
            out = files.enter_context(open(logs / log, "w"))
            procs.append(
                subprocess.Popen(
                    [str(DASK), *args], cwd=REPO, start_new_session=True, stdout=out, stderr=subprocess.STDOUT
                )
            )
            return procs[-1]

        try:
            start(
                ["scheduler", "--host", "127.0.0.1", "--port", address.rsplit(":", 1)[1], "--no-dashboard"],
                "scheduler.log",
            )
            workers = [
                start(
                    ["worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard", "--name", f"w{i}"],
                    f"worker{i}.log",
                )
                for i in range(n_workers)
            ]
            yield address, workers
        finally:
            for p in reversed(procs):
                _stop(p)


def _rows_by_key(folder: Path) -> dict[str, dict]:
    """Stored rows by key, without the time columns, NaN as "nan" (so equal rows compare equal)."""

    def value(v):
        return "nan" if isinstance(v, float) and math.isnan(v) else v

    return {
        r["key"]: {k: value(v) for k, v in r.items() if k not in TIME_COLUMNS}
        for r in RowStore(folder).read().to_pylist()
    }


def _wait_for_rows(store: RowStore, n: int, alive) -> int:
    t0 = time.monotonic()
    while time.monotonic() - t0 < WAIT_S and alive():
        done = len(store.done_keys())
        if done >= n:
            return done
        time.sleep(0.05)
    raise AssertionError(f"fewer than {n} rows stored within {WAIT_S} s")


def test_external_cluster_gives_the_embedded_clusters_rows(tmp_path):
    spec = parse_spec(
        {
            "name": "same",
            "cells": [
                {
                    "kind": "observations",
                    "scenario": "paper",
                    "noise_px": [0.0146, 0.05],
                    "seeds": 4,
                    "calibrators": ["circcal", "opencv"],
                    "batch": 2,
                },
                {
                    "kind": "images",
                    "scenario": "small-noisy",
                    "variants": ["noisy"],
                    "seeds": [1],
                    "calibrators": ["circcal"],
                },
            ],
        }
    )
    embedded = run_study(spec, tmp_path / "embedded", workers=2, progress=False)
    with external_cluster(tmp_path / "logs") as (address, _):
        external = run_study(spec, tmp_path / "external", scheduler=address, workers=2, progress=False)
    assert embedded.complete and external.complete and external.workers == 2
    a, b = _rows_by_key(tmp_path / "embedded"), _rows_by_key(tmp_path / "external")
    assert len(a) == spec.n_runs == 17 and a == b


def test_killing_a_worker_mid_study_loses_no_finished_run(tmp_path):
    spec = parse_spec(
        {
            "name": "kill-worker",
            "cells": [
                {
                    "kind": "observations",
                    "scenario": "paper",
                    "noise_px": [0.0146],
                    "seeds": 24,
                    "calibrators": [{"plugin": SLOW_PLUGIN}],
                    "batch": 1,
                }
            ],
        }
    )
    folder, store = tmp_path / "study", RowStore(tmp_path / "study")
    with external_cluster(tmp_path / "logs") as (address, workers):
        result: dict = {}
        thread = threading.Thread(
            target=lambda: result.update(
                run=run_study(spec, folder, scheduler=address, workers=2, progress=False, flush_rows=1)
            )
        )
        thread.start()
        _wait_for_rows(store, 4, thread.is_alive)
        before = {p: p.read_bytes() for p in store.parts()}
        os.killpg(workers[0].pid, signal.SIGKILL)
        thread.join(WAIT_S)
        assert not thread.is_alive()
    run = result["run"]
    assert run.complete and run.errors == [] and len(before) < spec.n_runs
    assert all(p.read_bytes() == data for p, data in before.items())  # every row written before the kill is kept
    rows = store.read().to_pylist()
    assert len(rows) == spec.n_runs and {r["key"] for r in rows} == study_keys(spec)
    assert {r["status"] for r in rows} == {"ok"} and {r["calibrator"] for r in rows} == {"slow"}


def test_killing_the_study_mid_way_keeps_its_rows_and_a_rerun_finishes_the_rest(tmp_path):
    spec_file = tmp_path / "s.yaml"
    spec_file.write_text(
        f"name: kill-client\ncells:\n- kind: observations\n  scenario: paper\n  noise_px: [0.0146]\n"
        f"  seeds: 24\n  batch: 1\n  calibrators: [{{plugin: '{SLOW_PLUGIN}'}}]\n"
    )
    folder, store = tmp_path / "study", RowStore(tmp_path / "study")
    with open(tmp_path / "study.log", "w") as log:
        proc = subprocess.Popen(
            [
                str(Path(sys.executable).with_name("circcal")),
                "study",
                str(spec_file),
                "--out",
                str(folder),
                "--workers",
                "2",
                "--flush-rows",
                "1",
                "--no-progress",
            ],
            cwd=REPO,
            start_new_session=True,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            _wait_for_rows(store, 4, lambda: proc.poll() is None)
            os.killpg(proc.pid, signal.SIGKILL)  # the client and its embedded cluster, mid-study
            proc.wait(30)
        finally:
            _stop(proc)
    kept = _rows_by_key(folder)
    assert 4 <= len(kept) < 24
    from circcal.study import load_spec

    again = run_study(load_spec(spec_file), folder, workers=2, progress=False)
    assert again.n_done_before == len(kept) and again.n_computed == 24 - len(kept) and again.complete
    final = _rows_by_key(folder)
    assert len(final) == 24 and all(final[k] == v for k, v in kept.items())


if not DASK.exists():  # pragma: no cover - dask[distributed] is a dependency
    pytest.skip("the dask command is not installed", allow_module_level=True)
