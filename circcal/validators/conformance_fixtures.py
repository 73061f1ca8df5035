"""The conformance plug-in's fixtures: circcal's observations (computed once per run), a case's calibrator, its
record for the summary, and ``conformance_run`` (the body of ``circcal.conformance``'s test)."""

from __future__ import annotations

import os
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from filelock import FileLock

from circcal import atomic
from circcal.validators.plugin_keys import RECORD_PROPERTY, SUMMARY_PROPERTY
from circcal.validators.plugin_options import user_calibrators
from circcal.validators.user_calibrator import calibrator_label

__all__ = [
    "ObservationCache",
    "conformance_observations",
    "conformance_calibrator",
    "conformance_record",
    "conformance_run",
    "solver_tolerance",
]


class ObservationCache:
    """circcal's observations per (scenario, variant, lens model), computed once.

    Under pytest-xdist the workers share a folder in the run's base temp directory (unique per run) and a file lock,
    so each scenario-variant is calibrated once per run, not once per worker. Call it as
    ``cache(scenario, variant, lens=None)`` (lens default: the scenario's own) to get an
    :class:`~circcal.validators.scenario_observations.Observations`.

    Parameters
    ----------
    shared : Path or None
        The shared folder; None: memory only.
    """

    def __init__(self, shared: Path | None) -> None:
        self.shared = shared
        self.memory: dict[tuple[str, str], Any] = {}

    def __call__(self, scenario: str, variant: str, lens: str | None = None):
        from circcal.validators.case_matrix import scenario_lens
        from circcal.validators.scenario_observations import observe

        lens = scenario_lens(scenario) if lens is None else lens
        key = (scenario, variant, lens)
        if key in self.memory:
            return self.memory[key]
        if self.shared is None:
            obs = observe(scenario, variant, lens)
        else:
            self.shared.mkdir(parents=True, exist_ok=True)
            f = self.shared / f"{scenario}--{variant}--{lens}.pkl"
            with FileLock(self.shared / f"{scenario}--{variant}--{lens}.lock"):
                if f.exists():
                    obs = pickle.loads(f.read_bytes())
                else:
                    obs = observe(scenario, variant, lens)
                    atomic.write_bytes(f, pickle.dumps(obs))
        self.memory[key] = obs
        return obs


@pytest.fixture(scope="session")
def conformance_observations(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> ObservationCache:
    """Session fixture: circcal's observations of a scenario-variant, computed once.

    Parameters
    ----------
    request : pytest.FixtureRequest
    tmp_path_factory : pytest.TempPathFactory

    Returns
    -------
    ObservationCache
        ``get(scenario, variant, lens=None) -> circcal.validators.scenario_observations.Observations`` (circcal's calibration
        with that lens model, default the scenario's own).
    """
    shared = None
    if hasattr(request.config, "workerinput"):  # a pytest-xdist worker: basetemp/.. is this run's, shared
        shared = tmp_path_factory.getbasetemp().parent / "circcal-conformance"
    return ObservationCache(shared)


@pytest.fixture(scope="session")
def conformance_calibrator(request: pytest.FixtureRequest) -> Callable[[Any], Any]:
    """Session fixture: the calibrator of a case.

    Parameters
    ----------
    request : pytest.FixtureRequest

    Returns
    -------
    callable
        ``get(case) -> ReferenceCalibrator``: the ``--calibrator`` object for a user case, else the registry's
        reference set up for the case's lens model (one instance per name and lens:
        :func:`circcal.validators.registry.get_for_lens`). A reference that cannot be loaded raises ``ImportError``
        with the cause.
    """
    from circcal.validators.registry import get_for_lens

    user = {calibrator_label(c): c for c in user_calibrators(request.config)}
    made: dict[tuple[str, str], Any] = {}

    def get(case: Any) -> Any:
        if case.user:
            return user[case.reference]
        key = (case.reference, case.lens)
        if key not in made:
            made[key] = get_for_lens(case.reference, case.lens)
        return made[key]

    return get


@pytest.fixture
def conformance_record(record_property: Callable[[str, Any], None]) -> Callable[[Any], None]:
    """Fixture: add a case's one-line summary to the end-of-run table (works under xdist).

    Parameters
    ----------
    record_property : callable
        pytest's ``record_property`` fixture.

    Returns
    -------
    callable
        ``record(outcome)``.
    """
    from circcal.validators.case_report import summary_line
    from circcal.validators.case_run import failed_checks

    def record(outcome: Any) -> None:
        record_property(SUMMARY_PROPERTY, summary_line(outcome))
        record_property(
            RECORD_PROPERTY,
            {
                "label": outcome.case.reference,
                "case": outcome.case.id,
                "status": outcome.status,
                "failed": bool(failed_checks(outcome)),
                "reason": outcome.skip_reason,
                "params": {k: {kk: float(vv) for kk, vv in v.items()} for k, v in outcome.params.items()},
            },
        )

    return record


def solver_tolerance(config: pytest.Config, case: Any) -> float | None:
    """The agreement bound for a case.

    Parameters
    ----------
    config : pytest.Config
    case : circcal.validators.case_matrix.Case

    Returns
    -------
    float or None
        px: ``--calibrator-tol`` for user calibrators (default 1e-6), else None (the module default,
        :func:`~circcal.validators.checks.solver_bound`).
    """
    if case.user:
        tol = config.getoption("calibrator_tol", default=None)
        return 1e-6 if tol is None else float(tol)
    return None


@pytest.fixture
def conformance_run(
    request: pytest.FixtureRequest,
    conformance_observations: ObservationCache,
    conformance_calibrator: Callable[[Any], Any],
    conformance_record: Callable[[Any], None],
) -> Callable[[Any], Any]:
    """Fixture: run one conformance case as a test (the body of ``circcal.conformance``'s test).

    Parameters
    ----------
    request : pytest.FixtureRequest
    conformance_observations, conformance_calibrator, conformance_record
        The fixtures above.

    Returns
    -------
    callable
        ``run(case) -> Outcome``: prints the case, records it for the summary, skips with the reason (no
        observations, a model that cannot represent the truth, an unavailable built-in reference outside CI) and
        fails with every check when one fails (a calibrator's exception: its traceback).
    """
    from circcal.validators.case_matrix import CIRCCAL
    from circcal.validators.case_report import format_outcome
    from circcal.validators.case_run import failed_checks, run_circcal_case, run_reference_case
    from circcal.validators.user_case import run_user_case

    config = request.config

    def run(case: Any) -> Any:
        obs = conformance_observations(case.scenario, case.variant, case.lens)
        if case.reference == CIRCCAL:
            outcome = run_circcal_case(case, obs)
        elif case.user:
            outcome = run_user_case(
                case,
                obs,
                conformance_calibrator(case),
                solver_px=solver_tolerance(config, case),
                allow_unavailable=bool(config.getoption("allow_unavailable", default=False)),
            )
        else:
            cal = conformance_calibrator(case)
            ok, why = cal.available()
            if not ok:  # a built-in reference that is not installed; under CI, where all are, a failure
                if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
                    pytest.fail(f"{cal.name} unavailable under CI: {why}")
                pytest.skip(f"{cal.name} unavailable: {why}")
            outcome = run_reference_case(case, obs, cal, solver_px=solver_tolerance(config, case))
        text = format_outcome(outcome)
        print(text)
        conformance_record(outcome)
        failed = failed_checks(outcome)
        if outcome.skip_reason and not failed:
            pytest.skip(f"{outcome.status}: {outcome.skip_reason}" if outcome.status != "skip" else outcome.skip_reason)
        assert not failed, text
        return outcome

    return run
