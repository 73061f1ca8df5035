"""The conformance suite's hooks and fixtures come from the ``circcal`` pytest plug-in (validators/pytest_plugin.py,
entry point ``pytest11``). Should the installed metadata predate that entry point (a checkout updated without
``make setup``), register the plug-in here so the suite still runs; ``--calibrator`` then needs the install."""

from __future__ import annotations

import pytest


def pytest_configure(config: pytest.Config) -> None:
    from circcal.validators import pytest_plugin

    pm = config.pluginmanager
    if not pm.has_plugin("circcal") and not pm.is_registered(pytest_plugin):
        pm.register(pytest_plugin, "circcal")
