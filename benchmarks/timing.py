"""How every benchmark times, so that no ratio can flatter (the facts behind each rule: shared/notes/benchmarking.md).

* Alternation: the tools compared run A B A B ... in one process (:func:`alternate`); timing one block of A, then one
  of B, moved a ratio by 2x between runs on this shared 2-core machine. At least :data:`MIN_REPEATS` repeats; each
  figure is the median with its spread (min-max), and a ratio is the median of the per-repeat ratios A_i / B_i with
  their min-max (:func:`ratio`), so a burst of load that hits one repeat hits both sides of it.
* Threads pinned and stated (:func:`pinned`): numpy's BLAS through threadpoolctl (it fixes its pool at import
  otherwise, so a "one-thread" run could silently use two) and OpenCV through ``cv2.setNumThreads``.
* glibc malloc: in some processes every ``cv2.findCirclesGrid`` call takes ~16,700 page faults (~65 MB of fresh
  pages), which makes OpenCV 3-4x slower; :data:`MALLOC_ENV` (set for the whole ``make bench`` process by
  ``benchmarks/run.py`` before anything is imported) removes it for both tools alike.
* Whole processes (:func:`alternate_processes`): what a user of the command line waits for, start-up included, beside
  the in-process figures; peak memory from ``wait4`` of each command, run by a small fresh launcher (a child's
  ``ru_maxrss`` starts at its parent's high-water mark, which in a benchmark process is large).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

__all__ = ["MIN_REPEATS", "MALLOC_ENV", "pinned", "alternate", "summary", "ratio", "alternate_processes", "fmt_spread"]

#: Repeats of every alternated timing at the least (medians of fewer swing with the machine's load).
MIN_REPEATS = 9
#: glibc's malloc kept from returning memory to the kernel between calls (see the module docstring).
MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": "33554432", "MALLOC_TRIM_THRESHOLD_": "17179869184"}


@contextmanager
def pinned(threads: int = 1) -> Iterator[dict]:
    """BLAS (threadpoolctl) and OpenCV limited to ``threads`` inside the block; yields what was set, to be stated
    beside the figures: ``{"blas_threads", "opencv_threads", "malloc_env"}``."""
    import cv2
    from threadpoolctl import threadpool_limits

    before = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    try:
        with threadpool_limits(limits=threads):
            yield {
                "blas_threads": threads,
                "opencv_threads": threads,
                "malloc_env": all(os.environ.get(k) == v for k, v in MALLOC_ENV.items()),
            }
    finally:
        cv2.setNumThreads(before)


def alternate(
    fns: dict[str, Callable[[], object]], repeats: int = MIN_REPEATS, warmup: int = 1
) -> dict[str, list[float]]:
    """Wall times (s) of each function, run in turn A B C A B C ... ``repeats`` times after ``warmup`` untimed
    rounds. Returns name -> the ``repeats`` samples, in order (sample i of every name comes from round i)."""
    if repeats < MIN_REPEATS:
        raise ValueError(f"at least {MIN_REPEATS} repeats, got {repeats}")
    out: dict[str, list[float]] = {k: [] for k in fns}
    for r in range(warmup + repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            dt = time.perf_counter() - t0
            if r >= warmup:
                out[name].append(dt)
    return out


def summary(samples: Sequence[float]) -> dict[str, float]:
    """``{"median", "min", "max"}`` of samples."""
    return {"median": float(statistics.median(samples)), "min": float(min(samples)), "max": float(max(samples))}


def ratio(a: Sequence[float], b: Sequence[float]) -> dict[str, float]:
    """The per-round ratios a_i / b_i of two alternated sample lists: ``{"median", "min", "max"}``."""
    return summary([x / y for x, y in zip(a, b)])


#: Runs one command (argv[2:]) and writes its wall time (s) and peak RSS (KiB) to the file argv[1]. A process's
#: ``ru_maxrss`` starts at its parent's memory high-water mark (Linux copies it across fork and exec), so the peak of
#: a child of a big benchmark process would read as that process's: this small, fresh launcher is the parent
#: instead, and it times the command itself (its own start-up is not counted).
_LAUNCHER = """\
import os, subprocess, sys, time
t0 = time.perf_counter()
proc = subprocess.Popen(sys.argv[2:])
_, status, usage = os.wait4(proc.pid, 0)
dt = time.perf_counter() - t0
with open(sys.argv[1], "w") as f:
    f.write(f"{dt} {usage.ru_maxrss} {os.waitstatus_to_exitcode(status)}")
"""


def alternate_processes(
    cmds: dict[str, Sequence[str]], repeats: int = MIN_REPEATS, env: dict | None = None, warmup: int = 1
) -> dict[str, dict[str, list[float]]]:
    """Whole-process wall times (s) and peak resident memory (MiB) of each command, run in turn like
    :func:`alternate`, each through a small launcher process (see :data:`_LAUNCHER`: the peak is the command's own).
    A command that fails raises ``RuntimeError`` with its output (a benchmark of a failing command measures
    nothing). Returns name -> ``{"wall_s": [...], "peak_mib": [...]}``."""
    import sys
    import tempfile

    if repeats < MIN_REPEATS:
        raise ValueError(f"at least {MIN_REPEATS} repeats, got {repeats}")
    out: dict[str, dict[str, list[float]]] = {k: {"wall_s": [], "peak_mib": []} for k in cmds}
    full_env = {**os.environ, **(env or {})}
    with tempfile.TemporaryDirectory() as tmp:
        result = os.path.join(tmp, "result")
        for r in range(warmup + repeats):
            for name, cmd in cmds.items():
                proc = subprocess.run(
                    [sys.executable, "-c", _LAUNCHER, result, *cmd],
                    stdout=subprocess.PIPE,
                    stderr=subprocess.STDOUT,
                    env=full_env,
                )
                output = proc.stdout.decode(errors="replace")
                if proc.returncode != 0 or not os.path.exists(result):
                    raise RuntimeError(
                        f"{name}: launcher for {' '.join(cmd)} exited {proc.returncode}:\n{output[-2000:]}"
                    )
                with open(result) as f:
                    dt, maxrss_kib, code = f.read().split()
                os.unlink(result)
                if int(code) != 0:
                    raise RuntimeError(f"{name}: {' '.join(cmd)} exited {code}:\n{output[-2000:]}")
                if r >= warmup:
                    out[name]["wall_s"].append(float(dt))
                    out[name]["peak_mib"].append(float(maxrss_kib) / 1024.0)  # Linux: KiB
    return out


def fmt_spread(s: dict[str, float], unit: str = "", digits: int = 3) -> str:
    """``median [min-max] unit`` of a :func:`summary` or :func:`ratio`."""
    return f"{s['median']:.{digits}g} [{s['min']:.{digits}g}-{s['max']:.{digits}g}]{(' ' + unit) if unit else ''}"
