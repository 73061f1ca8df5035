"""A kill or an interrupt at every write step of ``calibrate --report`` and ``detect --json --overlay`` (issue 31):
the earlier outputs survive intact, or the new ones are complete; never a mix once the next run has started.

Each run is a fresh ``circcal`` process whose file-system calls (``open`` for writing, ``os.replace``, ``rename``,
``link``, ``unlink``, ``mkdir``, ``rmdir`` and the folder exchange) are counted (``WRAPPER``); the signal is sent at
the k-th step touching the outputs' folder. Between a step and the next, Python delivers SIGINT at once, SIGKILL
ends the process where it stands. ``make test`` kills at every step of the commit (where old and new meet) and at
the first, middle and last step of the staging (where nothing final is touched, by construction), and interrupts
at the staging steps and the commit's first and last (the commit holds SIGINT back, so its steps are alike for
it); ``make study`` does both at every step.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from circcal.commit import MARKER, recover
from circcal.outputs import folder_manifest

WRAPPER = r"""
import builtins, io, json, os, signal, sys
import circcal.commit as C
import circcal.outputs as O
plan = json.loads(os.environ["CIRCCAL_FAULT"])
count = [0]
log = []
state = {"commit": False}
def step(kind, path):
    p = os.fsdecode(path) if isinstance(path, (str, bytes, os.PathLike)) else ""
    if not p.startswith(plan["root"]):
        return
    count[0] += 1
    log.append([kind, p, state["commit"]])
    if count[0] == plan["at"]:
        os.kill(os.getpid(), getattr(signal, "SIG" + plan["signal"]))
def wrap(real, name):
    def f(*a, **k):
        step(name, a[0] if a else "")
        return real(*a, **k)
    return f
for name in ("replace", "rename", "link", "unlink", "mkdir", "rmdir"):
    setattr(os, name, wrap(getattr(os, name), name))
real_open = builtins.open
def open_(file, mode="r", *a, **k):
    if any(c in mode for c in "wax+"):
        step("open", file)
    return real_open(file, mode, *a, **k)
builtins.open = io.open = open_
C._exchange = wrap(C._exchange, "exchange")
real_commit = O.Outputs.commit
def commit(self):
    state["commit"] = True
    try:
        return real_commit(self)
    finally:
        state["commit"] = False
O.Outputs.commit = commit
from circcal.cli import main
try:
    code = main(sys.argv[1:])
finally:
    if plan.get("log"):
        with real_open(plan["log"], "w") as f:
            json.dump(log, f)
sys.exit(code)
"""


def _run(root: Path, args: list[str], at: int = -1, signal: str = "KILL", log: Path | None = None):
    env = dict(
        os.environ,
        CIRCCAL_FAULT=json.dumps({"root": str(root), "at": at, "signal": signal, "log": str(log) if log else ""}),
    )
    return subprocess.run(
        [sys.executable, "-c", WRAPPER, *args], cwd=root, env=env, capture_output=True, text=True, timeout=300
    )


def _state(root: Path, file: str, folder: str) -> tuple[bytes | None, dict | None]:
    """The file's bytes and the folder's manifest (None where missing; the manifest checked against its marker)."""
    f = root / file
    d = root / folder
    data = f.read_bytes() if f.is_file() else None
    if not d.is_dir():
        return data, None
    marker = json.loads((d / MARKER).read_text())
    assert marker["files"] == folder_manifest(d), "a folder output differs from its own manifest: half-written"
    return data, marker["files"]


def _sweep(
    tmp_path: Path, before: list[str], args: list[str], file: str, folder: str, steps: str, signals=("KILL", "INT")
):
    """Make the earlier outputs (``before``: a run on other images, so old and new differ), count the steps of a
    run of ``args``, then fault it at each chosen step and check."""
    base = tmp_path / "base"
    base.mkdir()
    first = _run(base, before)
    assert first.returncode in (0, 1), first.stderr
    old = _state(base, file, folder)
    assert old[0] is not None and old[1], "the first run wrote no outputs"
    log = tmp_path / "log.json"
    new_run = tmp_path / "count"
    shutil.copytree(base, new_run, symlinks=True)
    counted = _run(new_run, args, log=log)
    assert counted.returncode in (0, 1), counted.stderr
    new = _state(new_run, file, folder)
    assert new != old
    kinds = json.loads(log.read_text())
    commit = [i + 1 for i, k in enumerate(kinds) if k[2]]
    staging = [i + 1 for i, k in enumerate(kinds) if not k[2]]
    assert commit and staging
    # the commit's steps up to the journal's removal and one after it (the rest removes the earlier folder, like it)
    end = next(i for i in commit if kinds[i - 1][0] == "unlink" and ".circcal-commit-" in kinds[i - 1][1])
    renames = [i for i in commit if i <= end + 1]
    chosen = sorted(
        set(range(1, len(kinds) + 1))
        if steps == "all"
        else set(renames) | {staging[0], staging[len(staging) // 2], staging[-1]}
    )
    # SIGINT and SIGTERM are held back for the whole commit (delivered after it): every commit step behaves alike
    # for them, so the fast sweep interrupts at the staging steps and the commit's first and last; SIGKILL, which
    # nothing holds back, at every chosen step
    interrupted = chosen if steps == "all" else sorted({*chosen[:3], renames[0], renames[-1], *chosen[-1:]})
    outcomes = {"old": 0, "new": 0}
    for sig in signals:
        for k in interrupted if sig == "INT" else chosen:
            work = tmp_path / f"{sig}-{k}"
            shutil.copytree(base, work, symlinks=True)
            run = _run(work, args, at=k, signal=sig)
            got = _state(work, file, folder)
            if sig == "INT":
                assert run.returncode in (130, 0, 1), (k, run.returncode, run.stderr[-6000:])
                assert "Traceback" not in run.stderr, (k, run.stderr[-2000:])
            else:
                assert run.returncode == -9, (k, run.returncode, run.stderr[-6000:])
            # each output on its own is the old one or the new one, complete
            assert got[0] in (old[0], new[0]) or _same_model(got[0], new[0]), (sig, k, kinds[k - 1])
            assert got[1] in (old[1], new[1], None) or _same_figures(got[1], new[1]), (sig, k, kinds[k - 1])
            recover(work)  # what the next run's planning does first
            got = _state(work, file, folder)
            is_old = got == old
            is_new = got[1] is not None and got[0] is not None and (got[0] == new[0] or _same_model(got[0], new[0]))
            assert is_old or is_new, (sig, k, kinds[k - 1])
            outcomes["old" if is_old else "new"] += 1
            left = sorted(p.name for p in work.iterdir() if ".circcal-" in p.name)
            assert not left or (sig == "KILL" and not any("commit" in n for n in left)), (sig, k, left)
    assert outcomes["old"] and outcomes["new"], outcomes  # both ends of the commit were exercised


def _same_model(a: bytes | None, b: bytes | None) -> bool:
    """Two runs on the same input write the same model (its date or run time aside)."""
    if a is None or b is None:
        return False
    try:
        da, db = json.loads(a), json.loads(b)
    except ValueError:
        return False
    return (
        isinstance(da, dict)
        and da.get("camera") == db.get("camera")
        or isinstance(da, dict)
        and da.get("images") == db.get("images")
    )


def _same_figures(a: dict | None, b: dict | None) -> bool:
    return a is not None and b is not None and set(a) == set(b)


def _calibrate_args(views: slice) -> list[str]:
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth

    truth = load_truth(fixture_dir("small-noisy"))
    b = truth.board
    return [
        "calibrate",
        *[str(v.image) for v in truth.views[views]],
        "--grid",
        f"{b.rows}x{b.cols}",
        "--pitch",
        f"{b.pitch_mm}mm",
        "--diameter",
        f"{b.diameter_mm}mm",
        "--no-progress",
        "--no-cross-validate",
        "--report",
        "rep",
        "--out",
        "model.json",
    ]


def _detect_args(views: slice) -> list[str]:
    from circcal.fixtures.cache import fixture_dir
    from circcal.fixtures.truth import load_truth

    truth = load_truth(fixture_dir("small-noisy"))
    b = truth.board
    return [
        "detect",
        *[str(v.image) for v in truth.views[views]],
        "--grid",
        f"{b.rows}x{b.cols}",
        "--pitch",
        f"{b.pitch_mm}mm",
        "--diameter",
        f"{b.diameter_mm}mm",
        "--quiet",
        "--jobs",
        "1",
        "--json",
        "detections.json",
        "--overlay",
        "overlays",
    ]


def test_calibrate_report_killed_or_interrupted_at_each_commit_step(tmp_path):
    _sweep(tmp_path, _calibrate_args(slice(6, 12)), _calibrate_args(slice(0, 6)), "model.json", "rep", "commit")


def test_detect_overlay_killed_or_interrupted_at_each_commit_step(tmp_path):
    _sweep(tmp_path, _detect_args(slice(3, 5)), _detect_args(slice(0, 3)), "detections.json", "overlays", "commit")


@pytest.mark.slow
def test_calibrate_report_killed_or_interrupted_at_every_write_step(tmp_path):
    _sweep(tmp_path, _calibrate_args(slice(6, 12)), _calibrate_args(slice(0, 6)), "model.json", "rep", "all")


@pytest.mark.slow
def test_detect_overlay_killed_or_interrupted_at_every_write_step(tmp_path):
    _sweep(tmp_path, _detect_args(slice(3, 5)), _detect_args(slice(0, 3)), "detections.json", "overlays", "all")
