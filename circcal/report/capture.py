"""Warnings raised while a study runs, kept with the study's results instead of silenced: the solver's "did not
converge", the re-correction loop's "did not settle" and numpy's numerical warnings belong in a published report.

:func:`study_warnings` records every warning issued inside its block, in any thread (``simplefilter("always")``:
repeats are counted, not hidden), and stores them, deduplicated with counts, under the study's key. Deprecation
warnings (:data:`PASSED_ON`) are about a library's API, not the numbers, and fire once per process when a module is
first imported, so recording them would make the results depend on what ran before; they are handed on to the
process's own warning filters after the block instead, neither recorded nor silenced. Nothing is filtered for the
process: the previous filters are restored when the block ends.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["PASSED_ON", "study_warnings", "summarise"]

#: Categories handed on to the process's filters rather than recorded.
PASSED_ON: tuple[type[Warning], ...] = (DeprecationWarning, PendingDeprecationWarning)


def summarise(caught: list[warnings.WarningMessage]) -> list[dict[str, object]]:
    """Caught warnings, deduplicated with counts.

    Parameters
    ----------
    caught : list of warnings.WarningMessage

    Returns
    -------
    list of dict
        One ``{"category", "message", "count"}`` per distinct (category, message), in the order first seen.
    """
    seen: dict[tuple[str, str], dict[str, object]] = {}
    for w in caught:
        key = (w.category.__name__, str(w.message))
        entry = seen.setdefault(key, {"category": key[0], "message": key[1], "count": 0})
        entry["count"] = int(entry["count"]) + 1
    return list(seen.values())


@contextmanager
def study_warnings(log: dict[str, list[dict[str, object]]], study: str) -> Iterator[None]:
    """Record the warnings issued inside the block into ``log[study]`` (see :func:`summarise`).

    The entry is written even when the block raises.

    Parameters
    ----------
    log : dict of str to list of dict
        Where the summary goes.
    study : str
        The study's key.

    Yields
    ------
    None

    Examples
    --------
    >>> import warnings
    >>> log = {}
    >>> with study_warnings(log, "paper"):
    ...     warnings.warn("did not converge", RuntimeWarning)
    >>> log["paper"][0]["count"]
    1
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            yield
        finally:
            log[study] = summarise([w for w in caught if not issubclass(w.category, PASSED_ON)])
    for w in caught:
        if issubclass(w.category, PASSED_ON):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
