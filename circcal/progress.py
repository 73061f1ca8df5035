"""Progress bars, written once: :func:`progress_bar` is a tqdm bar when it is shown and a do-nothing stand-in when it
is not, so a run with progress off (``--no-progress``, a test, a worker) does not import tqdm (~0.03 s of a
process's start-up, most of it ``importlib.metadata``)."""

from __future__ import annotations

from typing import Any

__all__ = ["progress_bar"]


class _Hidden:
    """What code that drives a tqdm bar calls on it (``update``, ``set_postfix_str``, ``write``, ``close``), doing
    nothing; usable as a context manager like tqdm."""

    def update(self, n: int = 1) -> None:
        pass

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        pass

    def write(self, s: str) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self) -> _Hidden:
        return self

    def __exit__(self, *exc: Any) -> None:
        pass


def progress_bar(total: int, desc: str, unit: str, shown: bool, **kwargs: Any) -> Any:
    """A progress bar, or a silent stand-in.

    Parameters
    ----------
    total : int
        Steps in all.
    desc : str
        What is counted (shown before the bar).
    unit : str
        The unit of a step (``"img"``, ``"run"``).
    shown : bool
        Whether to show it (``--no-progress`` makes it False; tqdm is then not imported).
    **kwargs
        Passed on to ``tqdm``.

    Returns
    -------
    tqdm.tqdm or object
        ``tqdm(total=total, desc=desc, unit=unit, **kwargs)`` when ``shown``, else a stand-in with the same
        ``update`` / ``set_postfix_str`` / ``write`` / ``close`` methods that does nothing.
    """
    if not shown:
        return _Hidden()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, **kwargs)
