"""A study's results on disk: Parquet parts under ``DIR/rows/``, appended atomically in batches.

Only the client writes (the workers return rows). Each batch becomes one new part, written through a temporary
file and a rename (:func:`circcal.atomic.write_bytes`), so a reader, a crash or a killed process sees whole parts
only: every run in a part is finished and kept. A run is done when its key is in some part; :func:`RowStore.read`
drops a key seen twice (the first copy wins), so compaction (:meth:`RowStore.compact`: write the merged part,
then delete the old ones) is safe to interrupt.
"""

from __future__ import annotations

import os
import time
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from circcal import atomic
from circcal.study.rows import schema

__all__ = ["RowStore"]

PART_GLOB = "part-*.parquet"


class RowStore:
    """The rows of the study in a folder (its ``rows/`` subfolder).

    Parameters
    ----------
    folder : str or Path
        The study folder.
    """

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.rows_dir = self.folder / "rows"

    def parts(self) -> list[Path]:
        """The Parquet parts, oldest first (their names start with the time they were written).

        Returns
        -------
        list of Path
        """
        return sorted(self.rows_dir.glob(PART_GLOB)) if self.rows_dir.is_dir() else []

    def done_keys(self) -> set[str]:
        """Keys of every stored run.

        Returns
        -------
        set of str
        """
        import pyarrow.parquet as pq

        keys: set[str] = set()
        for p in self.parts():
            keys.update(pq.read_table(p, columns=["key"]).column("key").to_pylist())
        return keys

    def append(self, rows: Sequence[dict[str, Any]]) -> Path | None:
        """Write rows as one new part (atomically).

        Parameters
        ----------
        rows : sequence of dict
            :func:`circcal.study.rows.make_row` rows.

        Returns
        -------
        Path or None
            The part; None for no rows.
        """
        if not rows:
            return None
        import pyarrow as pa

        return self._write(pa.Table.from_pylist(list(rows), schema=schema()))

    def _write(self, table: Any) -> Path:
        import pyarrow as pa
        import pyarrow.parquet as pq

        self.rows_dir.mkdir(parents=True, exist_ok=True)
        sink = pa.BufferOutputStream()
        pq.write_table(table, sink)
        path = self.rows_dir / f"part-{time.time_ns():020d}-{uuid.uuid4().hex[:8]}.parquet"
        atomic.write_bytes(path, sink.getvalue().to_pybytes())
        return path

    def read(self) -> Any:
        """Every stored row as one pyarrow Table (a key stored twice counts once), in the order written.

        Returns
        -------
        pyarrow.Table
        """
        import pyarrow as pa
        import pyarrow.parquet as pq

        parts = self.parts()
        if not parts:
            return schema().empty_table()
        table = pa.concat_tables([pq.read_table(p, schema=schema()) for p in parts])
        keys = table.column("key").to_pylist()
        seen: set[str] = set()
        first = []
        for i, k in enumerate(keys):
            if k not in seen:
                seen.add(k)
                first.append(i)
        return table if len(first) == len(keys) else table.take(first)

    def compact(self) -> Path | None:
        """Merge every part into one.

        Written first, then the old parts removed: an interruption leaves duplicates, which :meth:`read` drops.

        Returns
        -------
        Path or None
            The merged part; None when there is at most one.
        """
        parts = self.parts()
        if len(parts) <= 1:
            return None
        merged = self._write(self.read())
        for p in parts:
            os.unlink(p)
        return merged
