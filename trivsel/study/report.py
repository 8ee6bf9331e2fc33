"""Table 1 of the paper, ours beside the published numbers.

:func:`assemble_table1` joins the rows of one or more ``errors.csv`` files (as
written by ``trivsel reduce``) with the published values of Table 1
(``trivsel/study/table1_published.csv``, copied from Hamann & Chen 1994, Table 1)
into the table the workflow writes as ``results/report/table1.csv``::

    function,fraction,n_selected,E_rms,E_rms_interior,E_inf,E_inf_interior,
    published_E_rms,published_E_rms_interior,ratio_E_rms,ratio_E_rms_interior

:func:`table1_markdown` renders it in the paper's layout (functions by fractions,
each cell "ours / published" with the deviation, flagged when outside a
tolerance, +-10 % by default), followed by the maximum errors, point counts, run
times and the options used; every cell outside the tolerance gets a short,
measured explanation (:func:`explain_deviations`: the split of the error into
its face and interior parts, and the closest variant of an ablation when one is
given).  :func:`collect_runs` stacks the error tables of a
parameter sweep into one long table with the options as columns.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from ..functions import FUNCTIONS
from ..options import applies, option_fields
from . import ablation as _abl
from .published import PUBLISHED_SOURCE, function_label, load_published
from ..norms import face_residual_rms

__all__ = [
    "TABLE1_COLUMNS",
    "OPTION_KEYS",
    "load_published",
    "read_errors",
    "assemble_table1",
    "table1_markdown",
    "write_table1",
    "collect_runs",
    "function_label",
    "corners_only_face_rms",
    "face_points_selected",
    "explain_deviations",
]

TABLE1_COLUMNS = [
    "function", "fraction", "n_selected", "E_rms", "E_rms_interior", "E_inf", "E_inf_interior",
    "published_E_rms", "published_E_rms_interior", "ratio_E_rms", "ratio_E_rms_interior",
]

#: Reduction options recorded per run (the workflow's sweepable keys).
OPTION_KEYS = [f.name for f in option_fields()]
_OPTION_NAMES = set(OPTION_KEYS)

def read_errors(paths) -> pd.DataFrame:
    """Concatenate ``errors.csv`` files (one per function) into one DataFrame."""
    if isinstance(paths, (str, Path)):
        paths = [paths]
    frames = [pd.read_csv(p) for p in paths]
    if not frames:
        raise ValueError("no errors.csv files given")
    return pd.concat(frames, ignore_index=True)


def _fkey(x) -> float:
    return round(float(x), 9)


def assemble_table1(errors: pd.DataFrame, published: pd.DataFrame | None = None) -> pd.DataFrame:
    """Join our errors with the published Table 1 (one row per function and fraction).

    ``errors`` needs the columns function, fraction, n_selected, E_rms,
    E_rms_interior, E_inf, E_inf_interior (extra columns are ignored).  Rows are
    sorted by function, then by decreasing fraction as in the paper.  Published
    values missing for a (function, fraction) are NaN, and so are the ratios.
    """
    need = ["function", "fraction", "n_selected", "E_rms", "E_rms_interior", "E_inf", "E_inf_interior"]
    missing = [c for c in need if c not in errors.columns]
    if missing:
        raise ValueError(f"errors table lacks column(s) {missing}; has {list(errors.columns)}")
    if published is None:
        published = load_published()
    ours = errors[need].copy()
    ours["function"] = ours["function"].astype(int)
    ours["fraction"] = ours["fraction"].astype(float)
    ours["_key"] = ours["fraction"].map(_fkey)
    dup = ours.duplicated(["function", "_key"])
    if dup.any():
        bad = ours.loc[dup, ["function", "fraction"]].to_dict("records")
        raise ValueError(f"more than one error row for {bad}: pass the runs of one (n, options) at a time")
    pub = published[["function", "fraction", "E_rms", "E_rms_interior"]].rename(
        columns={"E_rms": "published_E_rms", "E_rms_interior": "published_E_rms_interior"})
    pub = pub.assign(_key=pub["fraction"].map(_fkey)).drop(columns="fraction")
    table = ours.merge(pub, on=["function", "_key"], how="left").drop(columns="_key")
    table["ratio_E_rms"] = table["E_rms"] / table["published_E_rms"]
    table["ratio_E_rms_interior"] = table["E_rms_interior"] / table["published_E_rms_interior"]
    table["n_selected"] = table["n_selected"].astype(int)
    table = table.sort_values(["function", "fraction"], ascending=[True, False]).reset_index(drop=True)
    return table[TABLE1_COLUMNS]


def _pct(fraction: float) -> str:
    return f"{100 * fraction:g} %"


def _cell(ours, pub, ratio, tol, star=""):
    if ours is None or (isinstance(ours, float) and math.isnan(ours)):
        return "n/a"
    s = f"{ours:.3f}{star}"
    if pub is None or (isinstance(pub, float) and math.isnan(pub)):
        return f"{s} / -"
    dev = 100.0 * (ratio - 1.0)
    flag = abs(ratio - 1.0) > tol
    s = f"{s} / {pub:.3f}{star} ({dev:+.1f} %)"
    return f"**{s} ⚠**" if flag else s


def _fmt_value(v):
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt_value(x) for x in v)
    return str(v)


def table1_markdown(table: pd.DataFrame, tol: float = 0.10, n: int | None = None,
                    options: dict | None = None, timings: pd.DataFrame | None = None,
                    title: str | None = None, note: str | None = None, explain: bool = True,
                    face_points: dict | None = None, ablation: pd.DataFrame | None = None) -> str:
    """Render :func:`assemble_table1`'s output in the paper's layout as Markdown.

    Parameters
    ----------
    table : DataFrame with :data:`TABLE1_COLUMNS`.
    tol : relative tolerance for flagging a cell (0.10 = +-10 %).
    n : grid resolution of our runs (stated in the title; a note is added when it is not 16).
    options : the reduction options used (printed as a list).
    timings : DataFrame with columns function and seconds (and optionally more numeric columns).
    explain : add a section with a measured explanation of every cell outside ``tol``
        (:func:`explain_deviations`; ``face_points`` and ``ablation`` are passed on).
    """
    fractions = sorted(table["fraction"].unique(), reverse=True)
    functions = sorted(table["function"].unique())
    by = {(int(r.function), _fkey(r.fraction)): r for r in table.itertuples(index=False)}
    lines = []
    lines.append(f"# {title or 'Table 1: total RMS errors'}" + (f", n = {n}" if n is not None else ""))
    lines.append("")
    lines.append("Reproduction of Table 1 of Hamann & Chen (1994). Each cell: **ours / published** "
                 "(deviation of ours from the published value). The first line of each function is "
                 "E_RMS over all grid points; the second line, marked \"\\*\", is E_RMS without the boundary "
                 f"(interior grid points only). Cells outside ±{100 * tol:g} % of the published value are "
                 "marked ⚠ and set in bold.")
    if n is not None and n != 16:
        lines.append("")
        lines.append(f"Note: the published values are for n = 16; this run uses n = {n}, so the "
                     "deviations are not like-for-like.")
    if note:
        lines += ["", note]
    lines.append("")
    lines.append("| Function | " + " | ".join(_pct(f) for f in fractions) + " |")
    lines.append("|---|" + "---|" * len(fractions))
    n_in = n_all = 0
    for fn in functions:
        row1, row2 = [], []
        for fr in fractions:
            r = by.get((int(fn), _fkey(fr)))
            if r is None:
                row1.append("n/a")
                row2.append("n/a")
                continue
            row1.append(_cell(r.E_rms, r.published_E_rms, r.ratio_E_rms, tol))
            row2.append(_cell(r.E_rms_interior, r.published_E_rms_interior, r.ratio_E_rms_interior, tol, "\\*"))
            for ratio in (r.ratio_E_rms, r.ratio_E_rms_interior):
                if not (isinstance(ratio, float) and math.isnan(ratio)):
                    n_all += 1
                    n_in += abs(ratio - 1.0) <= tol
        lines.append(f"| {function_label(fn)} | " + " | ".join(row1) + " |")
        lines.append("| (without boundary) | " + " | ".join(row2) + " |")
    lines.append("")
    if n_all:
        lines.append(f"**{n_in} of {n_all}** published cells are reproduced within ±{100 * tol:g} %.")
        lines.append("")
    if explain and n_in < n_all:
        diag = options.get("boundary_diagonals", "kuhn") if isinstance(options, dict) else "kuhn"
        diag = diag if diag in ("kuhn", "mirrored") else "kuhn"
        notes = explain_deviations(table, tol=tol, n=n, face_points=face_points, ablation=ablation, diagonals=diag)
        if notes:
            lines.append(f"## Cells outside ±{100 * tol:g} %: what the numbers say")
            lines.append("")
            lines.append("Measured for each flagged cell. On the grid, E_RMS^2 over all points is the point-weighted "
                         "mean of the squared RMS on the interior points (E_RMS\\*) and on the boundary points, so "
                         "each pair (ours, and the paper's) implies a face RMS; comparing the two parts shows "
                         "whether a deviation sits on the faces or inside."
                         + (" The ablation's closest variants are from `results/report/ablation.csv`."
                            if ablation is not None else ""))
            lines.append("")
            lines += [f"- {d['text']}" for d in notes]
            lines.append("")

    # maximum errors and point counts (not published)
    lines.append("## Maximum errors and selected points (ours; not in the paper)")
    lines.append("")
    lines.append("Each cell: E_inf / E_inf without boundary (\\*), and the number of selected points.")
    lines.append("")
    lines.append("| Function | " + " | ".join(_pct(f) for f in fractions) + " |")
    lines.append("|---|" + "---|" * len(fractions))
    for fn in functions:
        cells = []
        for fr in fractions:
            r = by.get((int(fn), _fkey(fr)))
            cells.append("n/a" if r is None else
                         f"{r.E_inf:.3f} / {r.E_inf_interior:.3f}\\* ({int(r.n_selected)} points)")
        lines.append(f"| {int(fn)} | " + " | ".join(cells) + " |")
    lines.append("")

    if timings is not None and len(timings):
        lines.append("## Run times")
        lines.append("")
        cols = [c for c in timings.columns if c != "function"]
        lines.append("| Function | " + " | ".join(cols) + " |")
        lines.append("|---|" + "---|" * len(cols))
        for d in timings.sort_values("function").to_dict("records"):
            vals = [f"{d[c]:.2f}" if isinstance(d[c], (float, np.floating)) else str(d[c]) for c in cols]
            lines.append(f"| {int(d['function'])} | " + " | ".join(vals) + " |")
        total = timings[[c for c in cols if pd.api.types.is_numeric_dtype(timings[c])]].sum()
        if len(total):
            lines.append("| total | " + " | ".join(
                f"{total[c]:.2f}" if c in total.index else "" for c in cols) + " |")
        lines.append("")

    if options:
        lines.append("## Options used")
        lines.append("")
        method = options.get("method")
        for k, v in options.items():
            if method is None or k not in _OPTION_NAMES or applies(k, method):  # not those of other methods
                lines.append(f"- `{k}`: {_fmt_value(v)}")
        lines.append("")

    lines.append("## Source of the published values")
    lines.append("")
    lines.append(f"{PUBLISHED_SOURCE}; stored as `trivsel/study/table1_published.csv`.")
    lines.append("")
    return "\n".join(lines)


# --------------------------------------------------------------------------- explanations
def _grid_counts(n: int):
    """(all points, interior points) of the (n+1)^3 grid: 4913 and 3375 for n = 16."""
    return (n + 1) ** 3, (n - 1) ** 3


def corners_only_face_rms(function, n: int, diagonals: str) -> float:
    """RMS residual on the boundary points when the faces are interpolated from the 8 corners
    alone (the 12 initial boundary triangles, ``diagonals`` as in :func:`trivsel.reduce`):
    what the face error would be if no face point were selected."""
    from ..data import sample_grid
    from ..triangulation import box_tetrahedra

    d = sample_grid(function, n)
    tets = box_tetrahedra(d.shape, diagonals)
    bnd = np.flatnonzero(~d.interior_mask())
    p = d.points[bnd]
    value = np.full(len(bnd), np.nan)
    for t in tets:
        v = d.points[t]
        m = np.linalg.inv((v[1:] - v[0]).T)
        lam = (p - v[0]) @ m.T
        bary = np.column_stack([1 - lam.sum(axis=1), lam])
        inside = np.isnan(value) & (bary.min(axis=1) >= -1e-9)
        value[inside] = bary[inside] @ d.values[t]
    return float(np.sqrt(np.mean((d.values[bnd] - value) ** 2)))


def face_points_selected(result: dict) -> dict:
    """From a run's ``result.json`` (grid data): {n_selected: number of boundary points among
    the first n_selected selected points} for every snapshot."""
    data = result.get("data") or {}
    sel = result.get("selected")
    shape = data.get("shape")
    if not data.get("grid") or sel is None or not shape:
        return {}
    sx, sy, sz = (int(v) for v in shape)
    sel = np.asarray(sel, np.int64)
    i, rem = np.divmod(sel, sy * sz)
    j, k = np.divmod(rem, sz)
    on_face = (i == 0) | (i == sx - 1) | (j == 0) | (j == sy - 1) | (k == 0) | (k == sz - 1)
    csum = np.concatenate([[0], np.cumsum(on_face)])
    return {int(s["n_selected"]): int(csum[min(int(s["n_selected"]), len(sel))])
            for s in result.get("snapshots", []) if "n_selected" in s}


def _rel(a, b):
    return 100.0 * (a / b - 1.0) if b and math.isfinite(a) and math.isfinite(b) else float("nan")


def _where(d_face, d_int):
    """Which part carries a deviation, from the relative deviations of faces and interior."""
    if not (math.isfinite(d_face) and math.isfinite(d_int)):
        return ""
    if abs(d_int) >= 2 * abs(d_face):
        return "the deviation sits inside"
    if abs(d_face) >= 2 * abs(d_int):
        return "the deviation sits on the faces"
    same = (d_face > 0) == (d_int > 0)
    return "faces and interior deviate alike" + ("" if same else ", in opposite directions")


def _g(v):
    return f"{v:.3g}" if math.isfinite(v) else "n/a"


def _p0(v):
    """Signed whole per cent without a negative zero."""
    r = round(v) if math.isfinite(v) else v
    return f"{r + 0:+.0f}" if math.isfinite(v) else "n/a"


def explain_deviations(table: pd.DataFrame, tol: float = 0.10, n: int | None = None, face_points=None,
                       ablation: pd.DataFrame | None = None, diagonals: str = "kuhn") -> list:
    """A short, measured explanation of every cell outside ``tol`` of the published value.

    One entry per (function, fraction) with a flagged cell.  The face-residual
    identity ``E_rms^2 N = E_rms*^2 N_int + e_face^2 (N - N_int)`` (4913 = 3375 +
    1538 for n = 16) splits each pair, ours and the paper's, into the RMS on the
    boundary points (``e_face``) and on the interior ones, so it tells whether a
    deviation sits on the faces or inside.  ``face_points`` ({(function,
    n_selected): boundary points selected}) adds how many face points our run
    selected, with the face RMS the 8 corners alone would give; ``ablation`` (the
    long table of :mod:`trivsel.study.ablation`, same n) adds, per flagged cell, the
    closest variant overall, the closest that keeps the curvature order, and the
    best consistent set's value.

    Returns a list of dicts: function, fraction, columns (the flagged cells), text.
    """
    n_eff = 16 if n is None else int(n)
    n_all, n_int = _grid_counts(n_eff)
    p_all, p_int = _grid_counts(16)
    n_face = n_all - n_int
    closest, best = None, None
    if ablation is not None and len(ablation):
        abl = ablation
        if "n" in abl.columns:
            abl = abl[abl["n"].astype(int) == n_eff]
        if len(abl) and (abl["variant"] == "default").any():
            raw = abl[[c for c in ("variant", "n", "function", "fraction", "n_selected", "E_rms",
                                   "E_rms_interior") if c in abl.columns]]
            summ = _abl.summarise(raw, tol=tol)
            best = _abl.best_consistent(summ)["variant"]
            closest = _abl.closest_variants(raw, best=best, tol=tol)
    corners = {}
    out = []
    label = {"E_rms": "E_RMS", "E_rms_interior": "E_RMS*"}
    for r in table.itertuples(index=False):
        pe, pi = float(r.published_E_rms), float(r.published_E_rms_interior)
        if not (math.isfinite(pe) and math.isfinite(pi)):
            continue
        flagged = [c for c, ratio in (("E_rms", r.ratio_E_rms), ("E_rms_interior", r.ratio_E_rms_interior))
                   if math.isfinite(ratio) and abs(ratio - 1.0) > tol + 1e-12]
        if not flagged:
            continue
        fn = int(r.function)
        head = f"**{fn}, {_pct(r.fraction)}** (" + ", ".join(
            f"{label[c]} {getattr(r, c):.3f} / {(pe if c == 'E_rms' else pi):.3f}, "
            f"{_rel(getattr(r, c), pe if c == 'E_rms' else pi):+.1f} %" for c in flagged) + "): "
        parts = []
        f_ours = face_residual_rms(r.E_rms, r.E_rms_interior, n_all, n_int)
        f_pub = face_residual_rms(pe, pi, p_all, p_int)  # the published values are for n = 16
        if math.isfinite(f_pub):
            d_face, d_int = _rel(f_ours, f_pub), _rel(r.E_rms_interior, pi)
            how = (f"E_rms^2 * {n_all} - E_rms*^2 * {n_int}, over the {n_face} boundary points" if n_eff == 16
                   else f"over the boundary points: ours of the {n_eff + 1}^3 grid, the paper's of 17^3")
            s = (f"face RMS ({how}) ours {_g(f_ours)} vs the paper's {_g(f_pub)} ({_p0(d_face)} %), interior "
                 f"{_g(r.E_rms_interior)} vs {_g(pi)} ({_p0(d_int)} %): {_where(d_face, d_int)}")
            if n_eff == 16 and "E_rms" in flagged and (r.E_rms ** 2 - pe ** 2):
                share = 100 * (r.E_rms_interior ** 2 - pi ** 2) * n_int / ((r.E_rms ** 2 - pe ** 2) * n_all)
                if 0 <= share <= 100:
                    s += f" ({round(share) + 0:.0f} % of the squared-error gap is inside)"
            parts.append(s)
        else:
            parts.append(f"the published pair cannot be split (E_rms^2 * {p_all} < E_rms*^2 * {p_int}: a negative "
                         f"face sum)")
        if face_points is not None and (fn, int(r.n_selected)) in face_points:
            if (fn, diagonals) not in corners:
                try:
                    corners[(fn, diagonals)] = corners_only_face_rms(fn, n_eff, diagonals)
                except Exception:  # noqa: BLE001 - a missing reference only drops a phrase
                    corners[(fn, diagonals)] = float("nan")
            co = corners[(fn, diagonals)]
            s = f"our run selected {face_points[(fn, int(r.n_selected))]} of the {n_face} boundary points"
            if math.isfinite(co):
                s += f" (the 8 corners alone: face RMS {_g(co)})"
            parts.append(s)
        if closest is not None:
            for c in flagged:
                row = closest[(closest.function == fn) & np.isclose(closest.fraction, r.fraction)
                              & (closest.column == c)]
                if not len(row):
                    continue
                a = row.iloc[0]
                s = (f"ablation, {label[c]}: closest `{a.closest_variant}` {a.closest_value:.3f} "
                     f"({a.closest_dev_pct:+.1f} %)")
                if a.consistent_variant != a.closest_variant:
                    s += (f", keeping the curvature order `{a.consistent_variant}` {a.consistent_value:.3f} "
                          f"({a.consistent_dev_pct:+.1f} %)")
                if best is not None and "best_value" in a and math.isfinite(a.best_value):
                    s += f", best consistent set `{best}` {a.best_value:.3f} ({a.best_dev_pct:+.1f} %)"
                if a.reachable == "diagnostic only":
                    s += ": only a diagnostic (non-paper) order comes within tolerance"
                elif a.reachable == "no":
                    s += ": no variant comes within tolerance"
                parts.append(s)
        out.append({"function": fn, "fraction": float(r.fraction), "columns": flagged,
                    "text": head + "; ".join(p for p in parts if p) + "."})
    return out


def _timings(results: list[dict]) -> pd.DataFrame:
    """Per-function run times from result.json: the reduce time (the largest 'seconds'
    of its snapshots; errors.csv has no times, so that two runs compare equal) and its
    numeric top-level timings."""
    rows = {}
    for res in results:
        fn = res.get("function")
        if fn is None:
            continue
        seconds = [s["seconds"] for s in res.get("snapshots", []) if isinstance(s, dict) and "seconds" in s]
        if seconds:
            rows.setdefault(int(fn), {})["reduce seconds"] = float(max(seconds))
        t = res.get("timings")
        if not isinstance(t, dict):
            continue
        for k, v in t.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                rows.setdefault(int(fn), {})[f"{k} (s)"] = float(v)
    if not rows:
        return pd.DataFrame()
    df = pd.DataFrame.from_dict(rows, orient="index")
    df.index.name = "function"
    return df.reset_index()


def _options_from_results(results: list[dict]) -> dict | None:
    opts = [res.get("options") for res in results if isinstance(res.get("options"), dict)]
    if not opts:
        return None
    merged = {}
    for o in opts:
        for k, v in o.items():
            if k in ("function", "fractions", "out"):
                continue
            merged.setdefault(k, [])
            if v not in merged[k]:
                merged[k].append(v)
    return {k: (v[0] if len(v) == 1 else v) for k, v in merged.items()}


def write_table1(errors_csvs, out_csv, out_md, result_jsons=(), tol: float = 0.10,
                 published_csv=None, options: dict | None = None, title: str | None = None,
                 ablation_csv=None) -> pd.DataFrame:
    """Assemble Table 1 from ``errors.csv`` files and write the CSV and the Markdown.

    ``result_jsons`` (the runs' ``result.json``) supply run times, the options
    used and the selected points (how many lie on the faces); ``options`` (e.g.
    the workflow's variant) is printed instead when given.  ``ablation_csv`` (the
    ablation's long table, ``results/report/ablation.csv``) adds the closest
    variant to the explanation of each deviating cell.  Returns the table.
    """
    errors = read_errors(errors_csvs)
    published = load_published(published_csv)
    table = assemble_table1(errors, published)
    results = []
    for p in result_jsons:
        with open(p) as fh:
            res = json.load(fh)
        if "function" not in res:
            # fall back on the run's errors.csv sitting next to it
            sib = Path(p).with_name("errors.csv")
            if sib.is_file():
                res["function"] = int(pd.read_csv(sib)["function"].iloc[0])
        results.append(res)
    n = None
    if "n" in errors.columns:
        ns = sorted(set(int(v) for v in errors["n"]))
        n = ns[0] if len(ns) == 1 else None
    face_points = {}
    for res in results:
        if "function" in res:
            try:
                fn = int(res["function"])
            except (TypeError, ValueError):
                continue
            face_points.update({(fn, k): v for k, v in face_points_selected(res).items()})
    ablation = pd.read_csv(ablation_csv) if ablation_csv else None
    md = table1_markdown(table, tol=tol, n=n, options=options or _options_from_results(results),
                         timings=_timings(results), title=title, face_points=face_points or None,
                         ablation=ablation)
    out_csv, out_md = Path(out_csv), Path(out_md)
    out_csv.parent.mkdir(parents=True, exist_ok=True)
    out_md.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(out_csv, index=False, float_format="%.10g")
    out_md.write_text(md)
    return table


def collect_runs(runs) -> pd.DataFrame:
    """Stack the error tables of several runs with their options as columns.

    ``runs`` is an iterable of ``(errors_csv, info)`` where ``info`` is a dict of
    columns to add (``n``, ``variant``, option values...).  Published values are
    joined on (function, fraction) with ``published_*`` and ``ratio_*`` columns.
    """
    frames = []
    for path, info in runs:
        df = pd.read_csv(path)
        for k, v in info.items():
            if k in df.columns and k in ("function", "n"):
                continue
            df[k] = v
        frames.append(df)
    if not frames:
        raise ValueError("no runs given")
    allruns = pd.concat(frames, ignore_index=True)
    pub = load_published()[["function", "fraction", "E_rms", "E_rms_interior"]].rename(
        columns={"E_rms": "published_E_rms", "E_rms_interior": "published_E_rms_interior"})
    pub["_key"] = pub["fraction"].map(_fkey)
    allruns["_key"] = allruns["fraction"].map(_fkey)
    allruns = allruns.merge(pub.drop(columns="fraction"), on=["function", "_key"], how="left").drop(columns="_key")
    allruns["ratio_E_rms"] = allruns["E_rms"] / allruns["published_E_rms"]
    allruns["ratio_E_rms_interior"] = allruns["E_rms_interior"] / allruns["published_E_rms_interior"]
    return allruns
