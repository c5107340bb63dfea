"""An append-only CSV of finished runs, so an interrupted evaluation resumes where it stopped.

Each run is appended as one line the moment it finishes (one write, flushed): a killed
process loses at most the runs in flight. A kill can still cut the last line short; a file
that does not end with a newline has its last record dropped (never read as a shorter
number), and so are records with missing fields or unreadable numbers. Before appending,
such a file is rewritten atomically without them. A file with other columns is not read.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any, TextIO

from ngpm_runtime.errors import NgpmError

from ngpm_compiler.evaluation.runs import write_csv
from ngpm_compiler.progress import Log

INTS = ("n", "repeat", "seed", "primitives")  # columns that must read as numbers
FLOATS = ("similarity", "seconds")


def read_runs(path: str | Path, fields: tuple[str, ...], log: Log = print) -> list[dict[str, str]]:
    """The readable rows of `path` (none if it is missing), whose columns must be `fields`,
    after rewriting the file if it holds a torn or bad line."""
    path = Path(path)
    if not path.is_file():
        write_csv(path, [], fields)
        return []
    data = path.read_bytes()
    torn = bool(data) and not data.endswith(b"\n")
    if torn:  # a write cut short: everything after the last newline
        data = data[: data.rfind(b"\n") + 1]
    try:
        records = list(csv.reader(io.StringIO(data.decode("utf-8"), newline="")))
    except (UnicodeDecodeError, csv.Error) as err:
        raise NgpmError(f"{path}: not a readable runs file ({err}); move it away") from None
    if not records:  # empty, or only a torn header
        write_csv(path, [], fields)
        return []
    if tuple(records[0]) != fields:
        raise NgpmError(
            f"{path}: not a runs file (its columns are not {','.join(fields)}); move it away"
        )
    rows = [r for r in (_row(rec, fields) for rec in records[1:]) if r is not None]
    dropped = len(records) - 1 - len(rows) + torn
    if dropped:
        log(
            f"{path}: dropped {dropped} unreadable line(s) (a run cut off by an "
            "interrupt, or an edit)"
        )
        write_csv(path, rows, fields)
    return rows


def _row(record: list[str], fields: tuple[str, ...]) -> dict[str, str] | None:
    """One record as {field: text}, or None if it has the wrong length or bad numbers."""
    if len(record) != len(fields):
        return None
    got = dict(zip(fields, record, strict=True))
    try:
        for f in INTS:
            if f in got:
                int(got[f])
        for f in FLOATS:
            if f in got:
                float(got[f])
    except ValueError:
        return None
    return got


def csv_line(row: dict[str, Any], fields: tuple[str, ...]) -> str:
    """One CSV line of `row` (as write_csv writes it), ending with a newline."""
    buf = io.StringIO()
    csv.DictWriter(buf, fieldnames=list(fields), lineterminator="\n").writerow(
        {f: row.get(f, "") for f in fields}
    )
    return buf.getvalue()


def append_run(fh: TextIO, row: dict[str, Any], fields: tuple[str, ...]) -> dict[str, str]:
    """Append `row` to the open runs file `fh` as one flushed write; returns the row as the
    file holds it (every value a string)."""
    fh.write(csv_line(row, fields))
    fh.flush()
    return {f: str(row.get(f, "")) for f in fields}
