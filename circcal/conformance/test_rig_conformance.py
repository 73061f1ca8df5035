"""The conformance matrix's rig axis: a rig calibrator (``--rig-calibrator MODULE:ATTR``, else circcal's rig solve)
against the truth of every rig scenario x variant (:func:`circcal.validators.rig_conformance.rig_cases`; the rendered
ones only with ``--conformance-full``): every camera's fx, fy, cx, cy and every pose's rvec, tvec within
:data:`~circcal.validators.rig_conformance.RIG_TRUTH_SIGMAS` stated sigmas (the calibrator's own covariance when it
returns one, else circcal's on the same views)."""

from __future__ import annotations

import pytest

from circcal.validators.rig_conformance import rig_cases, run_rig_case


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """Parametrise ``rig_case``: the fast cases, and the rendered ones with ``--conformance-full``.

    Parameters
    ----------
    metafunc : pytest.Metafunc
    """
    if "rig_case" in metafunc.fixturenames:
        full = metafunc.config.getoption("conformance_full", default=False)
        cases = [c for c in rig_cases() if full or not c.slow]
        metafunc.parametrize("rig_case", cases, ids=[f"rig-{c.id}" for c in cases])


def test_rig_conformance(rig_case, rig_calibrator):
    """One rig case: the calibrator's rig within the stated sigmas of the truth."""
    failures = run_rig_case(rig_case, rig_calibrator)
    assert not failures, "; ".join(failures)
