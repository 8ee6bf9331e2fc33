"""Golden-table regression: compare a freshly produced error table with a committed one.

The workflow writes ``results/report/table1.csv``; CI keeps a copy produced by an
earlier run of our own code (``tests/golden/table1.csv``) and checks that no
number has moved beyond a tolerance::

    trivsel compare results/report/table1.csv tests/golden/table1.csv --rtol 1e-6

Rows are matched on their key columns (``function``, ``n``, ``input``, ``fraction``
and option columns such as ``method`` and ``values``; empty cells match empty cells), not
on their order, so a reordered table still passes.  Every numeric column of the golden table other than the
keys and the wall-clock columns (``seconds`` ...) is compared cell by cell with
``|new - golden| <= atol + rtol * |golden|`` (NaN equals NaN); integer columns
(point counts such as ``n_selected``) must match exactly.  Missing or extra rows,
and columns (other than keys and wall-clock columns) that one table has and the other
lacks, are offending cells too.

Input that cannot be compared is an :class:`~trivsel.exceptions.InputError` naming the
table and the problem: a key column that one table has and the other lacks (rows
could not be matched), two rows with the same key, a file that is not a CSV table (binary
or XML content, a row with more or fewer fields than the header, a duplicate or empty
column name), a table without rows, and two tables without a column in common.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from .exceptions import InputError, one_line
from .options import option_fields

__all__ = ["Mismatch", "compare_tables", "compare_frames", "format_mismatches", "read_table", "KEY_COLUMNS",
           "IGNORED_COLUMNS"]

#: Columns that identify a row: a table that has one of them must share it with the other table.
KEY_COLUMNS = ("function", "n", "input", "variant", *(f.name for f in option_fields()), "fraction")
#: Columns never compared: wall-clock times vary from run to run.
IGNORED_COLUMNS = ("seconds", "wall_seconds", "reduce_seconds", "time", "timestamp")


@dataclass(frozen=True)
class Mismatch:
    """One offending cell (or a missing row/column) of a table comparison."""

    row: str          # e.g. "function=4, fraction=0.1"
    column: str       # column name, or "<row>" for a missing/extra row, "<table>" for table-level problems
    new: object
    golden: object
    reason: str       # "value", "missing row", "extra row", "missing column", "extra column", ...

    def __str__(self) -> str:
        if self.reason == "value":
            try:
                new, gold = float(self.new), float(self.golden)
                if gold != 0 and math.isfinite(new) and math.isfinite(gold):
                    rel = f" (rel. change {100.0 * (new - gold) / abs(gold):+.4g} %)"
                else:
                    rel = f" (abs. change {new - gold:+.6g})" if math.isfinite(new - gold) else ""
            except (TypeError, ValueError):
                rel = ""
            return f"[{self.row}] {self.column}: new {self.new!r} != golden {self.golden!r}{rel}"
        return f"[{self.row}] {self.column}: {self.reason} (new {self.new!r}, golden {self.golden!r})"


def _row_label(keys, values) -> str:
    return ", ".join(f"{k}={_fmt_key(v)}" for k, v in zip(keys, values) if v != "") or "<all>"


def _fmt_key(v):
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def _key_tuple(df: pd.DataFrame, keys) -> list:
    out = []
    for rec in df[list(keys)].itertuples(index=False, name=None):
        # round floats so that 0.1 written as 0.10 or 0.1000000001 match; an empty cell (NaN:
        # errors.csv leaves function and n empty for a file's run) matches an empty cell
        out.append(tuple(("" if v != v else round(v, 9)) if isinstance(v, float) else v for v in rec))
    return out


def _close(new, gold, rtol, atol) -> bool:
    try:
        a, b = float(new), float(gold)
    except (TypeError, ValueError):
        return str(new) == str(gold)
    if math.isnan(a) and math.isnan(b):
        return True
    if math.isnan(a) or math.isnan(b):
        return False
    if math.isinf(a) or math.isinf(b):
        return a == b
    return abs(a - b) <= atol + rtol * abs(b)


def _table(label, name) -> str:
    """``the golden table 'gold.csv'`` (or ``the golden table`` without a file name), for messages."""
    return f"the {label} table" + ("" if name is None else f" {str(name)!r}")


def compare_frames(new: pd.DataFrame, golden: pd.DataFrame, rtol: float = 1e-6, atol: float = 0.0,
                   keys=None, columns=None, names=(None, None)) -> list[Mismatch]:
    """Compare two tables already loaded as DataFrames; see :func:`compare_tables`.

    Parameters
    ----------
    new, golden : pandas.DataFrame
        The tables (e.g. from :func:`read_table`).
    rtol, atol, keys, columns
        As for :func:`compare_tables`.
    names : pair of str, optional
        The file names of ``new`` and ``golden``, for the messages.

    Returns
    -------
    list of :class:`Mismatch`
        Empty when the tables agree.

    Raises
    ------
    InputError
        When the tables cannot be compared: a table without rows or with a duplicate
        column name, no column in common, a key column that one table has and the other
        lacks, two rows of a table with the same key, or a golden table without a
        numeric column to compare.
    """
    if rtol < 0 or atol < 0:
        raise ValueError(f"tolerances must be >= 0, got rtol={rtol}, atol={atol}")
    tables = {"new": (new, _table("new", names[0])), "golden": (golden, _table("golden", names[1]))}
    for df, table in tables.values():
        twice = df.columns[df.columns.duplicated()]
        if len(twice):
            raise InputError(f"{table} has the column {twice[0]!r} twice")
        if len(df) == 0:
            raise InputError(f"{table} has no rows")
    if not set(new.columns) & set(golden.columns):
        raise InputError(f"{tables['new'][1]} has none of the columns of {tables['golden'][1]} (new: "
                         f"{', '.join(map(str, new.columns))}; golden: {', '.join(map(str, golden.columns))})")
    # Rows are matched on their keys, so a key that only one table has would match rows that
    # differ in it (or drop a difference unseen): both tables need every key column either has.
    if keys is None:
        keys = [k for k in KEY_COLUMNS if k in golden.columns or k in new.columns]
    keys = list(keys)
    for k in keys:
        for has, lacks in (("golden", "new"), ("new", "golden")):
            if k in tables[has][0].columns and k not in tables[lacks][0].columns:
                like = [c for c in tables[lacks][0].columns if str(c).strip().lower() == k.lower()]
                hint = f" (it has {like[0]!r})" if like else ""
                raise InputError(f"key column {k!r} of {tables[has][1]} is missing from {tables[lacks][1]}{hint}; "
                                 f"rows are matched on their key columns, so both tables need it")
    skip = set(keys) | set(IGNORED_COLUMNS)
    explicit = columns is not None
    if not explicit:
        columns = [c for c in golden.columns if c not in skip and pd.api.types.is_numeric_dtype(golden[c])]
        if not columns:
            raise InputError(f"{tables['golden'][1]} has no numeric column to compare (columns: "
                             f"{', '.join(map(str, golden.columns))})")
    columns = list(columns)
    out: list[Mismatch] = []
    # Columns that one table has and the other lacks are changes of the table (exit status 1
    # in the CLI), reported with the changed cells; keys and wall-clock columns are exempt.
    for c in (columns if explicit else [c for c in golden.columns if c not in skip]):
        if c not in new.columns:
            out.append(Mismatch("<table>", c, None, "present", "missing column"))
    if not explicit:
        for c in new.columns:
            if c not in golden.columns and c not in skip:
                out.append(Mismatch("<table>", c, "present", None, "extra column"))
    present = [c for c in columns if c in new.columns]

    new_keys = _key_tuple(new, keys) if keys else [()] * len(new)
    gold_keys = _key_tuple(golden, keys) if keys else [()] * len(golden)
    if not keys and len(new) != len(golden):
        out.append(Mismatch("<table>", "<row>", len(new), len(golden), "row count differs"))
    if keys:
        for label, ks in (("new", new_keys), ("golden", gold_keys)):
            first = {}
            for i, k in enumerate(ks):
                if k in first:
                    raise InputError(f"{tables[label][1]} has two rows with the key {_row_label(keys, k)} "
                                     f"(data rows {first[k] + 1} and {i + 1}); each key must be unique")
                first[k] = i
        new_index = {k: i for i, k in enumerate(new_keys)}
        gold_set = set(gold_keys)
        pairs = []
        for gi, k in enumerate(gold_keys):
            if k not in new_index:
                out.append(Mismatch(_row_label(keys, k), "<row>", None, "present", "missing row"))
            else:
                pairs.append((new_index[k], gi, k))
        for k in new_keys:
            if k not in gold_set:
                out.append(Mismatch(_row_label(keys, k), "<row>", "present", None, "extra row"))
    else:
        pairs = [(i, i, ()) for i in range(min(len(new), len(golden)))]

    exact = {c for c in present if pd.api.types.is_integer_dtype(golden[c])}
    for ni, gi, k in pairs:
        label = _row_label(keys, k) if keys else f"row {gi}"
        for c in present:
            a, b = new[c].iloc[ni], golden[c].iloc[gi]
            if not (_close(a, b, 0.0, 0.0) if c in exact else _close(a, b, rtol, atol)):
                out.append(Mismatch(label, c, _py(a), _py(b), "value"))
    return out


def _py(v):
    return v.item() if hasattr(v, "item") else v


def read_table(path) -> pd.DataFrame:
    """Read a comma-separated table with a header row, refusing what would be read wrongly.

    pandas reads a row with more fields than the header by shifting its cells into an
    index, renames a repeated column name (``value.1``) and reads an XML file as a
    one-column table; each of these is refused here instead.

    Parameters
    ----------
    path : path-like
        The table (UTF-8 text; blank lines are skipped).

    Returns
    -------
    pandas.DataFrame
        The table as ``pandas.read_csv`` reads it.

    Raises
    ------
    InputError
        ``cannot read table '<path>' as CSV: ...`` for binary, non-UTF-8 or XML content,
        an empty file, a header with an empty or repeated column name, or a line with
        more or fewer fields than the header; ``table '<path>' has no rows`` for a
        header without rows.
    """
    head = f"cannot read table {str(path)!r} as CSV"
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"{head}: {one_line(exc)}") from None
    nul = raw.find(b"\0")
    if nul >= 0:
        raise InputError(f"{head}: it holds binary data (a NUL byte at offset {nul})")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{head}: it is not UTF-8 text (byte {raw[exc.start]:#04x} at offset {exc.start})") from None
    if text.lstrip().startswith("<"):
        first = text.lstrip().splitlines()[0]
        raise InputError(f"{head}: it is XML, not comma-separated values (it begins {first[:60]!r})")
    reader = csv.reader(io.StringIO(text, newline=""))
    header, rows = None, 0
    try:
        for row in reader:
            if not row or (len(row) == 1 and not row[0].strip()):
                continue
            if header is None:
                header = row
                for i, name in enumerate(header):
                    if not name.strip():
                        raise InputError(f"{head}: column {i + 1} of the header has no name")
                    if name in header[:i]:
                        raise InputError(f"{head}: the header names column {name!r} twice (columns "
                                         f"{header.index(name) + 1} and {i + 1})")
            elif len(row) != len(header):
                raise InputError(f"{head}: line {reader.line_num} has {len(row)} fields, the header {len(header)}")
            else:
                rows += 1
    except csv.Error as exc:
        raise InputError(f"{head}: line {reader.line_num}: {one_line(exc)}") from None
    if header is None:
        raise InputError(f"{head}: the file is empty")
    if rows == 0:
        raise InputError(f"table {str(path)!r} has no rows, only the header {','.join(header)!r}")
    try:
        return pd.read_csv(io.StringIO(text))
    except (pd.errors.ParserError, ValueError) as exc:
        raise InputError(f"{head}: {one_line(exc, first=True)}") from None


def compare_tables(new_csv, golden_csv, rtol: float = 1e-6, atol: float = 0.0,
                   keys=None, columns=None) -> list[Mismatch]:
    """Compare the CSV table ``new_csv`` with ``golden_csv``; return the offending cells.

    Parameters
    ----------
    new_csv, golden_csv : path-like
        Tables with a header row (e.g. ``results/report/table1.csv``), read with
        :func:`read_table`.
    rtol, atol : float
        A cell passes when ``|new - golden| <= atol + rtol * |golden|``; cells of
        integer columns (counts) must be equal.
    keys : list of str, optional
        Columns identifying a row; default: those of :data:`KEY_COLUMNS` that either
        table has (both must have each).
    columns : list of str, optional
        Columns to compare; default: every numeric golden column except keys and
        :data:`IGNORED_COLUMNS`, and then a column other than those that one table
        lacks is a ``missing column`` or ``extra column`` mismatch.

    Returns
    -------
    list of :class:`Mismatch`
        Empty when the tables agree.  ``str(m)`` is a one-line description.

    Raises
    ------
    FileNotFoundError
        When a table does not exist.
    InputError
        When a table is not a CSV table or the two cannot be compared (see
        :func:`read_table` and :func:`compare_frames`).
    """
    new_csv, golden_csv = Path(new_csv), Path(golden_csv)
    for p in (new_csv, golden_csv):
        if not p.is_file():
            raise FileNotFoundError(f"no such table: {p}")
    return compare_frames(read_table(new_csv), read_table(golden_csv), rtol=rtol, atol=atol,
                          keys=keys, columns=columns, names=(new_csv, golden_csv))


def format_mismatches(mismatches, new_csv=None, golden_csv=None, rtol=None, atol=None) -> str:
    """Human-readable report of a comparison (what ``trivsel compare`` prints)."""
    head = ""
    if new_csv is not None:
        head = f"{new_csv} vs {golden_csv}"
        if rtol is not None:
            head += f" (rtol={rtol:g}, atol={atol or 0:g})"
        head += ": "
    if not mismatches:
        return head + "OK, all cells within tolerance"
    lines = [head + f"{len(mismatches)} offending cell(s)"]
    lines += ["  " + str(m) for m in mismatches]
    return "\n".join(lines)
