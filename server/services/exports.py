"""A pass's telemetry as CSV or Parquet: every value of the pass's frame layout
(:class:`telemetry.layout.FrameLayout`: ``seq``, ``generation_time_ns``, the joints, their
targets, the attitude, rates, wheels, ACS and buffer values, ``reception_time_ns``), one row
per stored frame in time order, with each column's unit.

- **CSV**: one header line of the column names, each with its unit in brackets where it
  has one (``j1 [rad]``, ``wx [rad/s]``, ``generation_time_ns [ns]``; a quaternion's
  components ``[1]``); floats as Python's shortest round-trip text (the same numbers as the
  REST JSON), flags ``true``/``false``, an empty cell where a value is absent (nothing
  queued: ``buffer_next_execute_time_ns``). Produced page by page (:data:`PAGE_ROWS`), so a
  long pass streams in bounded memory.
- **Parquet** (arro3, zstd): the bare column names, typed (int64, float64, utf8, bool);
  each field's unit as its ``unit`` metadata, and the file's key-value metadata
  ``hikoboshi.units`` (JSON: column -> unit), ``hikoboshi.pass_id``, ``hikoboshi.pass_name``
  and ``hikoboshi.layout``, the same on the stored Arrow schema (what pyarrow shows as the
  table's metadata) with ``PANDAS_ATTRS`` (pandas' ``DataFrame.attrs``: the pass id, name
  and units). Written whole (a Parquet footer follows the data), into a spooled
  file.

Rows are read in pages on the caller's session factory, each page its own short read
(keyset on ``(generation_time_ns, seq)``): frames stored while an export runs may or may
not be in it.
"""

from __future__ import annotations

import csv
import io
import json
import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import IO, Any, Final

from sqlalchemy.orm import Session

from server.storage import repository as repo
from server.storage.errors import NotFound
from telemetry.layout import FrameLayout

__all__ = [
    "FORMATS",
    "PAGE_ROWS",
    "TelemetryExport",
    "csv_header",
    "open_export",
    "parquet_file",
]

#: Frames read per page (our choice: about 2 MB of rows in Python, a few ms of SQL).
PAGE_ROWS: Final = 5000
#: The export formats and their media types.
FORMATS: Final = {"csv": "text/csv; charset=utf-8", "parquet": "application/vnd.apache.parquet"}

#: Columns that are not floats, by their Arrow type; every other column is float64.
_TYPED: Final = {
    "seq": "int64",
    "generation_time_ns": "int64",
    "acs_mode": "utf8",
    "acs_feedforward": "bool",
    "buffer_queued": "int64",
    "buffer_next_execute_time_ns": "int64",
    "buffer_last_executed_seq": "int64",
    "reception_time_ns": "int64",
}

Row = tuple[Any, ...]


@dataclass(frozen=True)
class TelemetryExport:
    """What an export of pass ``pass_id`` holds: its layout's columns and their units."""

    pass_id: str
    name: str
    layout: FrameLayout

    @property
    def columns(self) -> tuple[str, ...]:
        return self.layout.columns

    @property
    def units(self) -> dict[str, str]:
        return self.layout.units


def open_export(session: Session, pass_id: str) -> TelemetryExport:
    """The export of a stored pass (``NotFound`` for an unknown one): its canonical id,
    name and layout. Cheap: nothing of the telemetry is read yet."""
    record = repo.get_pass(session=session, pass_id=pass_id)
    layout = repo.get_pass_layout(session=session, pass_id=record.id)
    return TelemetryExport(pass_id=record.id, name=record.name, layout=layout)


def pages(
    sessions: Callable[[], Session], export: TelemetryExport, page_rows: int | None = None
) -> Iterator[list[Row]]:
    """The pass's frames in time order, ``page_rows`` (:data:`PAGE_ROWS`) at a time, each
    page read on a new session of ``sessions`` (rows of :attr:`FrameLayout.columns`)."""
    page_rows = PAGE_ROWS if page_rows is None else page_rows
    fields = export.layout.fields
    t0 = 0
    last: tuple[int, int] | None = None
    while True:
        with sessions() as session:
            try:
                found = repo.telemetry_range(
                    session=session,
                    pass_id=export.pass_id,
                    t0_ns=t0,
                    t1_ns=2**63 - 1,
                    fields=fields,
                    limit=page_rows,
                )
            except NotFound:
                return  # deleted while exported: what was read stands
        rows: list[Row] = [tuple(r) for r in found]
        fresh = [r for r in rows if last is None or (r[1], r[0]) > last]
        if fresh:
            yield fresh
        if len(rows) < page_rows:
            return
        if fresh:
            last = (fresh[-1][1], fresh[-1][0])
            t0 = last[0]
        else:  # a whole page at one instant: go past it (never seen; 5000 frames in 1 ns)
            t0 += 1


def next_page(
    sessions: Callable[[], Session], export: TelemetryExport, page_rows: int | None = None
) -> Callable[[], list[Row] | None]:
    """:func:`pages` one call at a time (None when done): for a caller that reads each page
    on a worker thread."""
    it = pages(sessions, export, page_rows)
    return lambda: next(it, None)


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    return value


def csv_header(export: TelemetryExport) -> bytes:
    """The header line: each column's name, with `` [unit]`` where it has a unit."""
    units = export.units
    names = [f"{c} [{units[c]}]" if units[c] else c for c in export.columns]
    return _csv_lines([names])


def csv_rows(rows: Sequence[Row]) -> bytes:
    """Rows as CSV lines (see the module doc for how values are written)."""
    return _csv_lines([[_cell(v) for v in row] for row in rows])


def _csv_lines(rows: Sequence[Sequence[Any]]) -> bytes:
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    return out.getvalue().encode("utf-8")


def csv_chunks(sessions: Callable[[], Session], export: TelemetryExport) -> Iterator[bytes]:
    """The whole CSV, the header then one chunk per page."""
    yield csv_header(export)
    for page in pages(sessions, export):
        yield csv_rows(page)


def parquet_file(
    sessions: Callable[[], Session], export: TelemetryExport
) -> tuple[IO[bytes], int, int]:
    """The whole Parquet file, spooled (in memory up to 16 MB, then on disk), rewound; its
    size in bytes and its number of rows. The caller closes it."""
    from arro3.core import Array, DataType, Field, RecordBatch, Schema, Table
    from arro3.io import write_parquet

    types = {
        "int64": DataType.int64(),
        "utf8": DataType.utf8(),
        "bool": DataType.bool(),
        "float64": DataType.float64(),
    }
    units = export.units
    fields = [
        Field(
            name,
            types[_TYPED.get(name, "float64")],
            nullable=True,
            metadata={"unit": units[name]} if units[name] else None,
        )
        for name in export.columns
    ]
    column_units = {c: units[c] for c in export.columns}
    about = {
        "hikoboshi.pass_id": export.pass_id,
        "hikoboshi.pass_name": export.name,
        "hikoboshi.layout": str(export.layout),
        "hikoboshi.units": json.dumps(column_units),
    }
    # on the schema as well as the file: pyarrow (and pandas through it) read a table's
    # metadata from the Arrow schema stored in the file, pandas its ``attrs`` from there
    attrs = {"pass_id": export.pass_id, "pass_name": export.name, "units": column_units}
    schema = Schema(fields, metadata={**about, "PANDAS_ATTRS": json.dumps(attrs)})
    batches = []
    for page in pages(sessions, export):
        columns = list(zip(*page, strict=True))
        arrays = [
            Array(list(values), type=field.type)
            for values, field in zip(columns, fields, strict=True)
        ]
        batches.append(RecordBatch.from_arrays(arrays, schema=schema))
    table = Table.from_batches(batches, schema=schema)
    out = tempfile.SpooledTemporaryFile(max_size=16 * 1024 * 1024)  # noqa: SIM115
    write_parquet(
        table,
        out,
        compression="zstd(3)",
        key_value_metadata=about,
    )
    size = out.tell()
    out.seek(0)
    return out, size, table.num_rows
