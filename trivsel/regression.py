"""Golden-table regression: compare a freshly produced error table with a committed one.

The workflow writes ``results/report/table1.csv``; CI keeps a copy produced by an
earlier run of our own code (``tests/golden/table1.csv``) and checks that no
number has moved beyond a tolerance::

    trivsel compare results/report/table1.csv tests/golden/table1.csv --rtol 1e-6

Rows are matched on their key columns (``function``, ``n``, ``input``, ``fraction``
and option columns, whichever both tables have; empty cells match empty cells), not
on their order, so a reordered table still passes.  Every numeric column of the golden table other than the
keys and the wall-clock columns (``seconds`` ...) is compared cell by cell with
``|new - golden| <= atol + rtol * |golden|`` (NaN equals NaN); integer columns
(point counts such as ``n_selected``) must match exactly.  Missing or extra rows
and missing columns are offending cells too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from .options import option_fields

__all__ = ["Mismatch", "compare_tables", "compare_frames", "format_mismatches", "KEY_COLUMNS", "IGNORED_COLUMNS"]

#: Columns that identify a row (used when present in both tables).
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
    reason: str       # "value", "missing row", "extra row", "missing column", ...

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


def compare_frames(new: pd.DataFrame, golden: pd.DataFrame, rtol: float = 1e-6, atol: float = 0.0,
                   keys=None, columns=None) -> list[Mismatch]:
    """Compare two tables already loaded as DataFrames; see :func:`compare_tables`."""
    if rtol < 0 or atol < 0:
        raise ValueError(f"tolerances must be >= 0, got rtol={rtol}, atol={atol}")
    out: list[Mismatch] = []
    if keys is None:
        keys = [k for k in KEY_COLUMNS if k in golden.columns and k in new.columns]
    keys = list(keys)
    if columns is None:
        columns = [c for c in golden.columns
                   if c not in keys and c not in IGNORED_COLUMNS and pd.api.types.is_numeric_dtype(golden[c])]
    columns = list(columns)
    for c in columns:
        if c not in new.columns:
            out.append(Mismatch("<table>", c, None, "present", "missing column"))
    present = [c for c in columns if c in new.columns]

    new_keys = _key_tuple(new, keys) if keys else [()] * len(new)
    gold_keys = _key_tuple(golden, keys) if keys else [()] * len(golden)
    if not keys and len(new) != len(golden):
        out.append(Mismatch("<table>", "<row>", len(new), len(golden), "row count differs"))
    if keys:
        for label, ks in (("new", new_keys), ("golden", gold_keys)):
            seen = set()
            for k in ks:
                if k in seen:
                    out.append(Mismatch(_row_label(keys, k), "<row>", None, None, f"duplicate key in {label} table"))
                seen.add(k)
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


def compare_tables(new_csv, golden_csv, rtol: float = 1e-6, atol: float = 0.0,
                   keys=None, columns=None) -> list[Mismatch]:
    """Compare the CSV table ``new_csv`` with ``golden_csv``; return the offending cells.

    Parameters
    ----------
    new_csv, golden_csv : path-like
        Tables with a header row (e.g. ``results/report/table1.csv``).
    rtol, atol : float
        A cell passes when ``|new - golden| <= atol + rtol * |golden|``; cells of
        integer columns (counts) must be equal.
    keys : list of str, optional
        Columns identifying a row; default: those of :data:`KEY_COLUMNS` present in both.
    columns : list of str, optional
        Columns to compare; default: every numeric golden column except keys and
        :data:`IGNORED_COLUMNS`.

    Returns
    -------
    list of :class:`Mismatch`
        Empty when the tables agree.  ``str(m)`` is a one-line description.
    """
    new_csv, golden_csv = Path(new_csv), Path(golden_csv)
    for p in (new_csv, golden_csv):
        if not p.is_file():
            raise FileNotFoundError(f"no such table: {p}")
    return compare_frames(pd.read_csv(new_csv), pd.read_csv(golden_csv), rtol=rtol, atol=atol,
                          keys=keys, columns=columns)


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
