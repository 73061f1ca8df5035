"""Running a study on Dask: an embedded LocalCluster by default, any Dask cluster when given its scheduler.

:func:`run_study` plans the runs (:mod:`circcal.study.plan`), drops those already stored
(:mod:`circcal.study.store`: resumable), submits the remaining tasks with ``Client.map`` and writes rows as tasks
finish, in batches, from the client only. Dask does all the scheduling, the placement and the recovery: a task
whose worker dies is re-run elsewhere by the scheduler (``distributed.scheduler.allowed-failures``), and a task
that fails is reported, its runs left missing for the next run of the same spec. Nothing here retries or queues.

Embedded: ``LocalCluster(n_workers=N, threads_per_worker=1, processes=True)``, N = ``workers`` or one per core.
Its workers start with one BLAS/OpenMP thread each (Dask's ``distributed.nanny.pre-spawn-environ``), as
``dask worker`` processes do on a cluster, so both give the same rows.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from circcal import atomic
from circcal.errors import InputError
from circcal.study.plan import Task, plan
from circcal.study.spec import StudySpec
from circcal.study.store import RowStore

__all__ = ["FLUSH_ROWS", "FLUSH_S", "StudyRun", "run_study", "study_keys"]

#: Rows held in the client before they are written as one Parquet part, and the most seconds a finished row waits:
#: a part costs ~5 ms, so 500 rows (a few seconds of work on a cluster) keep writing negligible, and 10 s bounds what
#: a killed client loses (nothing finished before the last write).
FLUSH_ROWS = 500
FLUSH_S = 10.0
#: Seconds to wait for the workers asked for on an external cluster before giving up.
WORKER_WAIT_S = 120.0
#: Seconds to keep trying to reach a scheduler before "cannot connect" (a cluster's scheduler answers in well under
#: a second once up; Dask retries within this time).
CONNECT_TIMEOUT_S = 30.0


@dataclass
class StudyRun:
    """What :func:`run_study` did.

    Attributes
    ----------
    spec : StudySpec
    folder : Path
    n_runs : int
        Distinct runs in the spec.
    n_done_before : int
        Already stored.
    n_computed : int
        Rows written now.
    errors : list of str
        One line per task that failed (its runs are still missing).
    wall_s : float
        Seconds from submitting the first task to the last row written (cluster start-up not included: ``startup_s``).
    workers : int
        Dask workers when the tasks were submitted.
    complete : bool
        Every run of the spec is stored.
    """

    spec: StudySpec
    folder: Path
    n_runs: int
    n_done_before: int
    n_computed: int = 0
    errors: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    startup_s: float = 0.0
    workers: int = 0

    @property
    def complete(self) -> bool:
        return self.n_done_before + self.n_computed >= self.n_runs and not self.errors


def study_keys(spec: StudySpec) -> set[str]:
    """The run keys of a spec.

    Parameters
    ----------
    spec : StudySpec

    Returns
    -------
    set of str
    """
    return {r.key for t in plan(spec) for r in t.runs}


@contextmanager
def _client(scheduler: str | None, workers: int | None, client: Any = None) -> Iterator[Any]:
    from dask.distributed import Client, LocalCluster

    if client is not None:  # the caller's: left open
        yield client
        return
    if scheduler:
        try:
            client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler {scheduler}: cannot connect ({type(exc).__name__}: {exc})") from None
        try:
            if workers:
                client.wait_for_workers(workers, timeout=WORKER_WAIT_S)
            yield client
        finally:
            client.close()
        return
    n = workers or os.cpu_count() or 1
    # dashboard_address ":0": its HTTP server (health, metrics) on a free port, so two studies on one machine coexist
    with (
        LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=logging.ERROR
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


def _pending(spec: StudySpec, done: set[str]) -> list[Task]:
    """The tasks still to run: each less its stored runs, and less runs an earlier task already carries (two cells
    may name the same run)."""
    seen = set(done)
    out = []
    for task in plan(spec):
        t = task.without(seen)
        seen.update(r.key for r in t.runs)
        if t.runs:
            out.append(t)
    return out


def run_study(
    spec: StudySpec,
    folder: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    flush_rows: int = FLUSH_ROWS,
    flush_s: float = FLUSH_S,
    client: Any = None,
) -> StudyRun:
    """Run every missing run of a spec and store its row under a folder (see the module docstring).

    Interrupting (Ctrl-C) writes the rows received so far, then re-raises.

    Parameters
    ----------
    spec : StudySpec
    folder : str or Path
        The study folder (rows under ``rows/``).
    scheduler : str, optional
        A Dask scheduler address (``tcp://host:8786``); None starts an embedded cluster of ``workers`` processes.
    workers : int, optional
        Embedded: processes (default one per core); with a scheduler: how many workers to wait for before submitting.
    progress : bool
    flush_rows : int
        Rows per Parquet part.
    flush_s : float
        Longest wait before a part is written, s.
    client : dask.distributed.Client, optional
        The caller's client to use instead (left open).

    Returns
    -------
    StudyRun

    Raises
    ------
    circcal.errors.InputError
        A scheduler that cannot be reached.

    Examples
    --------
    >>> run = run_study(load_spec("studies/monte-carlo.yaml"), "out/mc", workers=2)  # doctest: +SKIP
    >>> run.complete  # doctest: +SKIP
    True
    """
    from dask.distributed import as_completed
    from tqdm import tqdm

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if spec.source:
        atomic.write_text(folder / "study.yaml", spec.source)
    store = RowStore(folder)
    keys = study_keys(spec)  # two cells may name the same run: it is one row
    done = store.done_keys() & keys
    out = StudyRun(spec, folder, len(keys), len(done))
    tasks = _pending(spec, done)
    if not tasks:
        return out
    from circcal.study.execute import execute

    t_start = time.perf_counter()
    buffer: list[dict[str, Any]] = []
    last_write = time.perf_counter()

    def flush() -> None:
        nonlocal last_write
        store.append(buffer)
        out.n_computed += len(buffer)
        buffer.clear()
        last_write = time.perf_counter()

    with _client(scheduler, workers, client) as dask_client:
        out.workers = len(dask_client.nthreads())
        out.startup_s = time.perf_counter() - t_start
        t0 = time.perf_counter()
        futures = dask_client.map(execute, tasks, key=[t.key for t in tasks])
        by_key = {t.key: t for t in tasks}
        bar = tqdm(
            total=sum(len(t.runs) for t in tasks),
            unit="run",
            desc=f"study {spec.name}",
            disable=not progress,
            smoothing=0.05,
        )
        try:
            for fut in as_completed(futures):
                if fut.status == "finished":
                    rows = fut.result()
                    buffer.extend(rows)
                    bar.update(len(rows))
                else:  # "error" (the task raised, or its workers kept dying: KilledWorker) or "cancelled"
                    task = by_key[fut.key]
                    why = fut.status
                    if fut.status == "error":
                        exc = fut.exception()
                        why = f"{type(exc).__name__}: {exc}"
                    out.errors.append(
                        f"task {fut.key} ({len(task.runs)} runs, cell {task.cell.index}, "
                        f"{task.cell.scenario} seed {task.runs[0].seed}): {why}"
                    )
                fut.release()
                if len(buffer) >= flush_rows or (buffer and time.perf_counter() - last_write >= flush_s):
                    flush()
        finally:
            flush()
            bar.close()
        out.wall_s = time.perf_counter() - t0
    return out
