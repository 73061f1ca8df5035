"""``njit`` for the detector's compiled loops (:mod:`circcal.detector.edges`, :mod:`circcal.detector.levels`,
:mod:`circcal.detector.ellipse`).

numba's ``njit`` when numba can be imported (a dependency of circcal; compiled code is cached on disk). Without it
(an install with ``--no-deps``, a Python numba does not support yet) the same functions run as plain Python: the
same results, the detector ~50x slower (~1 s for a 1920x1080 image); a warning says so once, on import.

Compiled with ``cache=True``: numba keys its on-disk cache on the kernel's own source file only, so a kernel calls
only kernels of its own module and reads only that module's constants (anything else it needs comes as an
argument); a change elsewhere would otherwise leave a stale cached kernel.
"""
from __future__ import annotations

import warnings

__all__ = ["njit", "COMPILED"]

try:
    from numba import njit
    COMPILED = True
except ImportError:  # pragma: no cover - exercised by tests/test_detect.py in a subprocess
    COMPILED = False
    warnings.warn("numba is not installed: circcal's detector runs its per-pixel loops in plain Python (same "
                  "results, ~50x slower); `pip install numba` restores the speed", RuntimeWarning, stacklevel=2)

    def njit(*args, **kwargs):
        """Identity decorator with numba's signature (``@njit`` and ``@njit(...)``)."""
        if len(args) == 1 and callable(args[0]) and not kwargs:
            return args[0]
        return lambda fn: fn
