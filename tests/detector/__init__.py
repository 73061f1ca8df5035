"""The detector's tests, one module per module or subpackage of circcal/detector (a package so that its
conftest does not shadow ``tests/conftest.py``, which tests/test_validators.py imports as ``conftest``)."""
