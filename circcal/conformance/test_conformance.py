"""The conformance matrix as one pytest test: every case of :func:`circcal.validators.case_matrix.cases`, against the
``--calibrator`` calibrators when given, else circcal and every registered reference (the ``circcal`` plug-in
parametrises ``conformance_case`` and runs it: :func:`circcal.validators.pytest_plugin.conformance_run`)."""

from __future__ import annotations

import pytest

# kornia's import triggers torch's own deprecation notice for torch.jit.script: not ours to fix
pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:DeprecationWarning")


def test_conformance(conformance_case, conformance_run):
    """One case: its checks pass, or it is skipped with the reason (a model that cannot represent the truth)."""
    conformance_run(conformance_case)
