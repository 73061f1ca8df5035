"""`make bench`: run every benchmark module, write reports/bench.json and reports/bench.md.

Speed targets live here, never in unit tests. Each module exposes ``run() -> dict``; a benchmark that fails is
reported with its traceback (and ``make bench`` exits 1), the others still run.
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

# one core, as the targets are stated per core
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

MODULES = ("bench_render", "bench_detect", "bench_calibrate", "bench_validate", "bench_study")
REPORTS = Path(__file__).resolve().parents[1] / "reports"


def _fmt(v):
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def main() -> int:
    results = {"machine": {"python": sys.version.split()[0], "platform": platform.platform(),
                           "cpus": os.cpu_count()}, "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    failed = False
    for name in MODULES:
        mod = importlib.import_module(f"benchmarks.{name}")
        print(f"[bench] {name} ...", flush=True)
        try:
            results[name] = mod.run()
        except Exception as exc:  # a failing benchmark is reported, the others still run
            failed = True
            results[name] = {"status": "failed", "error": f"{type(exc).__name__}: {exc}",
                             "traceback": traceback.format_exc()}
        for k, v in results[name].items():
            if k != "traceback":
                print(f"    {k}: {_fmt(v)}")
    REPORTS.mkdir(exist_ok=True)
    tmp = REPORTS / "bench.json.tmp"
    tmp.write_text(json.dumps(results, indent=1))
    tmp.replace(REPORTS / "bench.json")
    lines = ["# Benchmarks", "", f"Run {results['started']} on {results['machine']['platform']}, Python "
             f"{results['machine']['python']}, {results['machine']['cpus']} CPUs (one thread per timing).", ""]
    for name in MODULES:
        lines += [f"## {name}", "", "| metric | value |", "|---|---|"]
        lines += [f"| {k} | {_fmt(v)} |" for k, v in results[name].items() if k != "traceback"]
        lines.append("")
    tmp = REPORTS / "bench.md.tmp"
    tmp.write_text("\n".join(lines))
    tmp.replace(REPORTS / "bench.md")
    print(f"[bench] wrote {REPORTS / 'bench.md'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
