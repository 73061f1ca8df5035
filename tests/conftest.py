"""Shared test setup: a per-session fixture cache (unless CIRCCAL_CACHE is set) and paths to shared data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
REALDATA = SHARED / "data" / "realdata"
MULTIVIEW = SHARED / "data" / "multiview"


@pytest.fixture(scope="session")
def realdata() -> Path:
    if not REALDATA.is_dir():
        pytest.skip(f"real data not found at {REALDATA} (expected ../shared beside the repository)")
    return REALDATA


@pytest.fixture(scope="session")
def multiview() -> Path:
    """OpenCV's real multi-camera test observations (../shared/data/multiview, its README)."""
    if not MULTIVIEW.is_dir():
        pytest.skip(f"multiview data not found at {MULTIVIEW} (expected ../shared beside the repository)")
    return MULTIVIEW


def skip_unless_available(cal) -> None:
    """Skip a reference's test when it is not installed, with its reason; under CI (CI=true), where `make test`
    installs every reference, a missing one fails instead, so a broken install step cannot hide behind a skip."""
    ok, why = cal.available()
    if ok:
        return
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(f"{cal.name} unavailable under CI: {why}")
    pytest.skip(f"{cal.name} unavailable: {why}")


def pytest_report_header(config):
    return [f"circcal fixture cache: {os.environ.get('CIRCCAL_CACHE', Path.home() / '.cache' / 'circcal')}"]


@pytest.fixture
def cv2_single_thread():
    """OpenCV at one thread for the test: its parallel reductions make calibrateCamera and cv2.fisheye.calibrate
    vary by ~1e-7..1e-6 between runs; one thread is repeatable."""
    import cv2

    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    yield
    cv2.setNumThreads(n)


#: Modules holding the longest tests or module fixtures (15-35 s each, measured with --durations): collected first, so
#: that `make test`'s two workers start them early instead of one worker finishing on one of them alone.
LONG_MODULES = (
    "tests/test_outputs_faults.py",
    "tests/test_verdict.py",
    "tests/detector/test_kernels.py",
    "tests/test_study_cluster.py",
    "tests/test_calreport.py",
    "tests/test_study_geometry_cache.py",
    "tests/test_report.py",
)


def pytest_collection_modifyitems(config, items):
    """Longest modules first (:data:`LONG_MODULES`); each module's tests stay together and in their order."""
    rank = {m: k for k, m in enumerate(LONG_MODULES)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))  # stable: the rest keep their order


@pytest.fixture
def earlier_output():
    """Write a file as an earlier circcal run would have (committed and recorded: a later run may replace it; a
    file the user wrote is never replaced, circcal.outputs)."""
    from circcal.outputs import Outputs

    def write(path: Path, text: str) -> None:
        with Outputs() as out:
            out.file(path, "--out").write_text(text)
            out.commit()

    return write
