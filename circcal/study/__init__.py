"""Monte-Carlo studies and conformance matrices at scale: scenarios x variants x seeds x calibrators x lens models,
run on Dask (an embedded LocalCluster, or any cluster by its scheduler's address), one Parquet row per run,
resumable by content-hashed run keys, summarised as tables and figures.

Modules: the spec (:mod:`~circcal.study.spec`), what a seed means (:mod:`~circcal.study.seeded`), the lens-model
axis (:mod:`~circcal.study.lens`), runs and tasks (:mod:`~circcal.study.plan`), a row (:mod:`~circcal.study.rows`),
what a worker computes (:mod:`~circcal.study.execute`, :mod:`~circcal.study.batched`), the results on disk
(:mod:`~circcal.study.store`), the Dask runner (:mod:`~circcal.study.engine`), intervals
(:mod:`~circcal.study.stats`), the summary (:mod:`~circcal.study.summary`), its cells (:mod:`~circcal.study.cells`)
and its figures (:mod:`~circcal.study.figures`).
"""

from circcal.study.engine import StudyRun, run_study
from circcal.study.spec import StudySpec, load_spec, parse_spec
from circcal.study.store import RowStore
from circcal.study.summary import study_section, summarise, write_summary

__all__ = [
    "RowStore",
    "StudyRun",
    "StudySpec",
    "load_spec",
    "parse_spec",
    "read_rows",
    "run_study",
    "study_section",
    "summarise",
    "write_summary",
]


def read_rows(folder):
    """Every stored row of a study as a pyarrow Table (see :mod:`circcal.study.rows`).

    Parameters
    ----------
    folder : str or Path
        The study folder.

    Returns
    -------
    pyarrow.Table
    """
    return RowStore(folder).read()
