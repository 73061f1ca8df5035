"""The time budget of one image: a deadline the detector's loops check, so that no image, however hostile (dense
texture, thousands of dot-like blobs), holds a batch for longer than the budget.

The detector's search is about linear in the number of candidate dots (:mod:`circcal.detector.locate.lattice`), so the
budget is a backstop, not the design: past it an image is reported not found with
:attr:`~circcal.detector.Reason.TIME_BUDGET`.

The bound: an image with a budget of ``B`` seconds returns within ``1.5 B`` (wall and CPU time, compile time aside).
The deadline is checked in every loop and stage whose cost grows with the image or the candidate count: at each
scale of the search before its shrink and stretch (:mod:`circcal.detector.locate.search`), after each mask and after its
contours, before each cluster window searched again, after the lattice seeds, at each wave of a lattice's growth,
every few dozen tries of merging patches (:mod:`circcal.detector.locate.lattice`), before each patch labelled
(:mod:`circcal.detector.locate.recognise`), and after the dots are measured (:mod:`circcal.detector.find`). So an image
overruns its budget by at most the one step running when the deadline passes: one mask, one contour search or one
lattice growth wave, O(pixels) or O(candidates) each, measured at most ~0.2 s of CPU on the most hostile 12 MP images
of :mod:`circcal.fixtures.fuzz` (dense dots, leaves, stripes, checkers; ~0.7 s at 48 MP by the same rate), well
within ``0.5 B`` for the default budget (tested with ``B = 0.3`` s on a 6 MP image, plus that step:
tests/detector/test_budget.py). Nothing in the search holds memory quadratic in the candidates (the neighbour grid of
:mod:`circcal.detector.locate.neighbours` answers every distance query): a 12 MP hostile image peaks below 0.5 GB of
resident memory in all, the interpreter and its libraries included (reports/fuzz.md).
"""

from __future__ import annotations

import time

from circcal.detector.kernels.jit import compile_seconds

__all__ = ["DEFAULT_TIME_BUDGET_S", "BudgetExceeded", "Deadline"]

DEFAULT_TIME_BUDGET_S = 10.0
"""Seconds one image may take by default: ~500x a clean 1920x1080 image (~17 ms) and ~20x the most hostile images
measured (2,000 dot-like blobs, dense stripes: ~0.3-0.5 s), so it only ends a search that went wrong, on a slow or
heavily shared machine included."""


class BudgetExceeded(Exception):
    """The image's time budget ran out (caught by :func:`circcal.detector.detect`, never seen by a caller)."""


class Deadline:
    """A point in time ``budget_s`` seconds from construction (monotonic clock), pushed back by the time numba
    spends compiling kernels meanwhile (:func:`circcal.detector.kernels.jit.compile_seconds`: the first image of a process
    without the ahead-of-time build, or of a type it lacks, would otherwise spend its budget on the compiler).
    ``None`` or ``inf``: no limit."""

    def __init__(self, budget_s: float | None = DEFAULT_TIME_BUDGET_S) -> None:
        if budget_s is not None and not budget_s > 0:
            raise ValueError(f"time budget must be positive (s), got {budget_s!r}")
        self.budget_s = float("inf") if budget_s is None else float(budget_s)
        self.start = time.monotonic()
        self.end = self.start + self.budget_s
        self._compiled_at_start = compile_seconds()

    def _now(self) -> float:
        """The monotonic clock less the compile time since construction."""
        return time.monotonic() - (compile_seconds() - self._compiled_at_start)

    def expired(self) -> bool:
        """Whether the deadline has passed (the clock less the compile time since construction).

        Returns
        -------
        bool
            ``True`` past the deadline; never for a deadline without limit.

        Examples
        --------
        >>> Deadline(None).expired()
        False
        """
        return self._now() > self.end

    def check(self) -> None:
        """Raise :class:`BudgetExceeded` when the deadline has passed."""
        if self._now() > self.end:
            raise BudgetExceeded(f"time budget of {self.budget_s:g} s exceeded")

    def elapsed(self) -> float:
        """Seconds since construction on the monotonic clock (compile time included: what the image really took).

        Returns
        -------
        float
            Elapsed time, s.
        """
        return time.monotonic() - self.start
