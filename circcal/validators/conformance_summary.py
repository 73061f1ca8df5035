"""The conformance plug-in's end-of-run summary (:class:`ConformanceSummary`): every case, the calibrators' counts
and bias tests; it fails the run for a calibrator checked on no case or biased."""

from __future__ import annotations

from typing import Any

import pytest

from circcal.validators.plugin_keys import RECORD_PROPERTY, SUMMARY_PROPERTY, USER_KEY
from circcal.validators.user_calibrator import calibrator_label

__all__ = ["ConformanceSummary"]


class ConformanceSummary:
    """Collects each case's summary line and record from the test reports (the controller's, under xdist); prints
    them, the calibrators' counts and bias tests; fails the run for a calibrator checked on no case or biased."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config
        self.lines: list[str] = []
        self.records: list[dict] = []
        self.verdict: list[str] = []
        self.biases: list[Any] = []

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        """pytest hook: keep a call report's summary line and record.

        Parameters
        ----------
        report : pytest.TestReport
        """
        if report.when != "call":
            return
        for key, value in getattr(report, "user_properties", ()):
            if key == SUMMARY_PROPERTY:
                self.lines.append(str(value))
            elif key == RECORD_PROPERTY:
                self.records.append(dict(value))

    def pytest_sessionfinish(self, session: pytest.Session) -> None:
        """pytest hook: run the bias tests and fail the run for a calibrator checked on no case or biased.

        Parameters
        ----------
        session : pytest.Session
        """
        config = self.config
        cals = config.stash.get(USER_KEY, [])
        if not cals or hasattr(config, "workerinput") or config.getoption("collectonly", default=False):
            return
        from circcal.validators.bias import bias_tests
        from circcal.validators.bounds import BIAS_T

        bound = config.getoption("bias_t", default=None)
        bound = BIAS_T if bound is None else float(bound)
        labels = [calibrator_label(c) for c in cals]
        mine = [r for r in self.records if r.get("label") in labels]
        self.biases = bias_tests(mine, bound)
        for label in labels:
            n = sum(1 for r in mine if r["label"] == label and r["status"] == "checked")
            if n == 0:
                self.verdict.append(
                    f"{label} was checked on 0 cases: nothing was verified (see each case's reason above; run "
                    "`python -m pytest --pyargs circcal.conformance --calibrator ...`)"
                )
        self.verdict += [f"{b.label}: {b.words()}" for b in self.biases if b.biased]
        if self.verdict and session.exitstatus == 0:
            session.exitstatus = pytest.ExitCode.TESTS_FAILED

    def pytest_terminal_summary(self, terminalreporter: Any) -> None:
        """pytest hook: print every case's line, each calibrator's counts and bias tests, and the verdict.

        Parameters
        ----------
        terminalreporter : _pytest.terminal.TerminalReporter
        """
        if self.lines:
            terminalreporter.section("circcal conformance: every case (key numbers; FAIL = a check failed)")
            for line in sorted(self.lines):
                terminalreporter.write_line(line)
        cals = self.config.stash.get(USER_KEY, [])
        if not cals or hasattr(self.config, "workerinput"):
            return
        terminalreporter.section("circcal conformance: calibrators under test")
        for label in (calibrator_label(c) for c in cals):
            counts: dict[str, int] = {}
            for r in self.records:
                if r.get("label") == label:
                    status = "FAIL" if r.get("failed") else r["status"]
                    counts[status] = counts.get(status, 0) + 1
            terminalreporter.write_line(
                f"{label}: " + (", ".join(f"{v} {k}" for k, v in sorted(counts.items())) or "no case ran")
            )
            mine = [b for b in self.biases if b.label == label]
            # the most telling first: a bias beyond the bound, then the largest difference to circcal's solve
            mine.sort(key=lambda b: (not b.biased, -abs(b.excess_t)))
            for b in mine:
                terminalreporter.write_line(f"  {b.words()}", red=b.biased)
            for r in self.records:
                if r.get("label") == label and r.get("reason"):
                    terminalreporter.write_line(f"  {r['status']} {r['case']}: {r['reason']}")
        for line in self.verdict:
            terminalreporter.write_line(f"FAILED: {line}", red=True, bold=True)
