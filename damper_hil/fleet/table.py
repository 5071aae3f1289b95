r"""The fleet's results table: one row per damper, as ``results.csv`` and
``results.parquet`` (docs/fleet.md "Results").

Columns come first in :data:`LEADING` order, then every other column any row has, sorted.
A column's type is the first non-null value's (string, float, integer or boolean); a
missing value is empty in the CSV and null in the Parquet file.  Text from names that are
not UTF-8 (a damper folder named ``café`` in Latin-1) is written escaped, ``caf\xe9``
(:func:`~damper_emulator.errors.printable`).  The caller writes both through
:class:`~damper_emulator.outputs.Outputs`, so that a reader never sees half a table.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from damper_emulator.errors import ESCAPE, printable

#: the columns every row has, first
LEADING = ("id", "status", "reason", "flags", "wall_s", "worker")


def columns(rows: Sequence[dict[str, Any]]) -> list[str]:
    """:data:`LEADING`, then every other column of ``rows``, sorted."""
    rest = sorted({k for r in rows for k in r} - set(LEADING))
    return [*LEADING, *rest]


def write_csv(rows: Sequence[dict[str, Any]], path: Path) -> Path:
    """``rows`` as CSV (header row; empty cells for missing values)."""
    with path.open("w", newline="", encoding="utf-8", errors=ESCAPE) as f:
        writer = csv.DictWriter(f, fieldnames=columns(rows), restval="")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: ("" if v is None else v) for k, v in r.items()})
    return path


def _arrow_type(values: Sequence[Any]) -> Any:
    import pyarrow as pa

    for v in values:
        if v is None:
            continue
        if isinstance(v, bool):
            return pa.bool_()
        if isinstance(v, int):
            return pa.int64() if all(isinstance(w, int) and not isinstance(w, bool)
                                     for w in values if w is not None) else pa.float64()
        if isinstance(v, float):
            return pa.float64()
        return pa.string()
    return pa.string()


def write_parquet(rows: Sequence[dict[str, Any]], path: Path) -> Path:
    """``rows`` as a Parquet file (one typed column each)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    names = columns(rows)
    arrays = []
    for name in names:
        values = [r.get(name) for r in rows]
        kind = _arrow_type(values)
        if kind == pa.float64():
            values = [None if v is None else float(v) for v in values]
        elif kind == pa.string():
            values = [None if v is None else printable(str(v)) for v in values]
        arrays.append(pa.array(values, type=kind))
    pq.write_table(pa.Table.from_arrays(arrays, names=names), path)
    return path
