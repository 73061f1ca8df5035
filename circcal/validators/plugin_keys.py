"""The keys the conformance plug-in keeps its state under: the calibrators under test and the recorded properties."""

from __future__ import annotations

import pytest

__all__ = ["USER_KEY", "SUMMARY_PROPERTY", "RECORD_PROPERTY"]

#: ``config.stash`` key of the loaded ``--calibrator`` objects (a list).
USER_KEY = pytest.StashKey[list]()
#: ``record_property`` name of a case's one-line summary.
SUMMARY_PROPERTY = "circcal_conformance"
#: ``record_property`` name of a case's record (label, case, status, failed, reason, params).
RECORD_PROPERTY = "circcal_conformance_record"
