"""`make bench`: run every benchmark module, write reports/bench.json and reports/bench.md.

Speed targets live here, never in unit tests. ``python -m benchmarks.run NAME ...`` runs some modules and prints;
``--update NAME ...`` also replaces their sections of the published files (each such section carries its ``run`` date). Each module exposes ``run() -> dict``; a figure that is a dict with
``median``/``min``/``max`` is an alternated timing (benchmarks/timing.py) and is printed as ``median [min-max]``. A
benchmark that fails is reported with its traceback (and ``make bench`` exits 1), the others still run.

The process runs with BLAS at one thread and glibc's malloc settings of :data:`benchmarks.timing.MALLOC_ENV`, both
set before numpy is first imported (the script re-executes itself with them when they are missing), so every timing
says which threads it had.
"""

from __future__ import annotations

import importlib
import json
import os
import platform
import sys
import time
import traceback
from pathlib import Path

#: BLAS pools fixed at one thread before numpy's first import (benchmarks pin OpenCV and BLAS again per timing)
THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
MODULES = (
    "bench_render",
    "bench_detect",
    "bench_calibrate",
    "bench_lens",
    "bench_startup",
    "bench_validate",
    "bench_study",
    "bench_trust",
    "bench_refine_board",
    "bench_lens_auto",
    "bench_rig",
)
REPORTS = Path(__file__).resolve().parents[1] / "reports"


def _environment_ready() -> bool:
    from benchmarks.timing import MALLOC_ENV

    return all(os.environ.get(k) == v for k, v in {**THREAD_ENV, **MALLOC_ENV}.items())


def _fmt(v) -> str:
    if isinstance(v, dict) and {"median", "min", "max"} <= set(v):
        return f"{v['median']:.4g} [{v['min']:.4g}-{v['max']:.4g}]"
    if isinstance(v, dict):
        return ", ".join(f"{k}={_fmt(x)}" for k, x in v.items())
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def main(argv: list[str]) -> int:
    from benchmarks.timing import MALLOC_ENV

    if not _environment_ready():
        os.execve(
            sys.executable, [sys.executable, "-m", "benchmarks.run", *argv], {**os.environ, **THREAD_ENV, **MALLOC_ENV}
        )
    update = bool(argv) and argv[0] == "--update"
    if update:
        argv = argv[1:]
    names = argv or list(MODULES)
    results: dict = {
        "machine": {"python": sys.version.split()[0], "platform": platform.platform(), "cpus": os.cpu_count()},
        "environment": {**THREAD_ENV, **MALLOC_ENV},
        "started": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    failed = False
    for name in names:
        mod = importlib.import_module(f"benchmarks.{name}")
        print(f"[bench] {name} ...", flush=True)
        t0 = time.perf_counter()
        try:
            results[name] = mod.run()
        except Exception as exc:  # noqa: BLE001 - a failing benchmark is reported with its traceback
            failed = True
            results[name] = {
                "status": "failed",
                "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(),
            }
        results[name]["bench_wall_s"] = round(time.perf_counter() - t0, 1)  # the module's own run, to plan a rerun
        for k, v in results[name].items():
            if k != "traceback":
                print(f"    {k}: {_fmt(v)}")
    if argv and not update:  # a partial run prints, it does not replace the published file
        return 1 if failed else 0
    from circcal import atomic

    if update:  # the named modules' sections replace theirs in the published file, each dated by its own run
        published = json.loads((REPORTS / "bench.json").read_text())
        for name in names:
            published[name] = {**results[name], "run": results["started"]}
        results, names = published, [m for m in MODULES if m in published]
    atomic.write_text(REPORTS / "bench.json", json.dumps(results, indent=1) + "\n")
    lines = [
        "# Benchmarks",
        "",
        f"Run {results['started']} on {results['machine']['platform']}, Python {results['machine']['python']}, "
        f"{results['machine']['cpus']} CPUs. Every ratio is timed alternately in one process (A B A B ..., at "
        "least 9 repeats) and given as median [min-max] of the per-round ratios; BLAS and OpenCV threads are "
        "pinned and stated per benchmark; glibc malloc runs with "
        + ", ".join(f"{k}={v}" for k, v in MALLOC_ENV.items())
        + " for both tools alike "
        "(benchmarks/timing.py), except where a figure says it ran under glibc's defaults "
        "(bench_detect's default_malloc, bench_calibrate's default_malloc memory: what a user's process has).",
        "",
        "The summary quoted by the README, dated by its run: [bench-summary.md](bench-summary.md).",
        "",
    ]
    for name in names:
        lines += [f"## {name}", "", "| metric | value |", "|---|---|"]
        lines += [f"| {k} | {_fmt(v)} |" for k, v in results[name].items() if k != "traceback"]
        lines.append("")
    atomic.write_text(REPORTS / "bench.md", "\n".join(lines))
    print(f"[bench] wrote {REPORTS / 'bench.md'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
