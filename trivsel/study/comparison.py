"""Every method side by side at matched vertex counts ("how good is it").

One harness, :func:`compare_methods`, runs for one data set (a Table-1 function
on the ``(n+1)^3`` grid, or any :class:`~trivsel.data.PointData`) and a list of
fractions:

=====================  ========  ==========================================================
method                 values    what
=====================  ========  ==========================================================
``greedy``             data/fit  error-driven insertion, largest residual first (default key
                                 ``max``), data-dependent swapping (``reduce(method="greedy")``)
``greedy-sse``         data/fit  the same with ``greedy_key="sse"`` (worst point of the tet
                                 with the largest squared error: aims at E_RMS)
``paper``              data/fit  Hamann & Chen (1994): curvature order, data-dependent swapping
``decimate``           data/fit  bottom-up: half-edge collapses from the full grid, cheapest
                                 increase of the squared error first (``reduce(method="decimate")``;
                                 grids)
``vtk``                free      VTK's ``vtkUnstructuredGridQuadricDecimation``, vertex
                                 positions and values chosen by VTK; median of ``vtk_runs``
                                 runs (seeds ``seed .. seed + runs - 1``), min/max spread
``random-delaunay``    data      random subset (corners kept) + Delaunay; mean of
                                 ``random_seeds`` seeds, min/max spread
``curvature-delaunay`` data      the paper's curvature order + *plain* Delaunay: beside
                                 ``paper`` it isolates what data-dependent swapping is worth
=====================  ========  ==========================================================

Matched counts: for each fraction the target is ``count_for_fraction(fraction,
N)`` points, fixed corners included (the count ``reduce`` stops at).  ``paper``,
``greedy``, the Delaunay baselines land on it exactly (greedy stops earlier only
when every residual is zero); VTK lands within ``vtk_tol_points`` at or below
it in every run (:func:`trivsel.study.baselines.vtk_matched`).  ``n_target`` is in
every row, so the match can be checked.

Errors are eqs. (19)-(20) at every original point.  VTK moves vertices: points
outside its hull take the value at the nearest boundary point (nothing is
dropped) and are counted (``n_outside``, median over runs; ``max_outside_distance``).

``seconds`` is what one run costs to reach that count:

* ``paper`` / ``greedy``: wall time from the start of ``reduce()`` to the snapshot
  (one run produces every fraction, so times accumulate; curvature, swapping,
  the error evaluation and, for both value modes, the least-squares fit of every
  earlier snapshot are included; the ``data`` and ``fit`` rows share it);
* ``vtk``: building VTK's input grid (Kuhn split, once) plus the median filter
  time of one decimation to the count;
* ``random-delaunay``: the Delaunay triangulation (mean over seeds);
* ``curvature-delaunay``: the curvature estimate plus the Delaunay triangulation.

The table helpers (:func:`methods_table`, :func:`target_check`,
:func:`methods_markdown`) and the plot (:func:`methods_figure`) turn the rows of
one or more runs into ``results/report/methods.csv``, ``methods.md`` and the
log-log figures of the workflow (``workflow/rules/methods.smk``).
"""

from __future__ import annotations

import time

import numpy as np

from .baselines import ERROR_KEYS, curvature_delaunay, random_delaunay, tet_grid, vtk_matched
from ..data import PointData, sample_grid
from ..functions import resolve_function
from ..selection import count_for_fraction, validate_fractions

__all__ = [
    "METHODS",
    "COLUMNS",
    "compare_methods",
    "methods_table",
    "target_check",
    "methods_markdown",
    "methods_figure",
]

#: Method names in display order.
METHODS = ("greedy", "greedy-sse", "paper", "decimate", "vtk", "random-delaunay", "curvature-delaunay")
_VALUES_ORDER = ("data", "fit", "free")

#: Columns of methods.csv: the ten that define the comparison first (n and the matching columns beside them),
#: then the spread over runs / seeds and the outside-hull bookkeeping.
COLUMNS = [
    "method", "values", "function", "n", "fraction", "n_target", "n_selected",
    "E_rms", "E_rms_interior", "E_inf", "E_inf_interior", "seconds",
    "runs", "n_selected_min", "n_selected_max",
    "E_rms_min", "E_rms_max", "E_inf_min", "E_inf_max",
    "n_outside", "max_outside_distance",
]

_SPREAD_KEYS = ("E_rms", "E_inf")


def _row(method, values, data, fraction, n_target, n_selected, errors, seconds, **extra):
    row = {
        "method": method,
        "values": values,
        "function": data.name,
        "n": data.meta.get("n", (data.shape[0] - 1) if data.shape else ""),
        "fraction": float(fraction),
        "n_target": int(n_target),
        "n_selected": int(n_selected),
        **{k: float(errors[k]) for k in ERROR_KEYS},
        "seconds": float(seconds),
        "runs": 1,
        "n_selected_min": int(n_selected),
        "n_selected_max": int(n_selected),
        **{f"{k}_{s}": float(errors[k]) for k in _SPREAD_KEYS for s in ("min", "max")},
        "n_outside": float(errors.get("n_outside", 0)),
        "max_outside_distance": float(errors.get("max_outside_distance", 0.0)),
    }
    row.update(extra)
    return row


def _n_vertices(tets):
    """Vertices actually used by a mesh's tetrahedra (a point Delaunay skipped would not count)."""
    return int(np.unique(np.asarray(tets)).size)


def compare_methods(data, fractions=(0.5, 0.2, 0.1), *, n=16, methods=METHODS, vtk_runs=5,
                    random_seeds=3, vtk_tol_points=3, seed=0, progress=None):
    """Run every method at matched vertex counts; one row per (method, values, fraction).

    Parameters
    ----------
    data : PointData, int or str
        The data; a Table-1 function number or name is sampled on the ``(n+1)^3`` grid.
    fractions : sequence of float in (0, 1]
        Target fractions of all points (corners included, rounded half up).
    n : int
        Grid intervals when ``data`` names a function.
    methods : sequence of str
        A subset of :data:`METHODS`.  ``curvature-delaunay`` needs ``paper``'s
        ranking and runs the curvature estimate itself if ``paper`` is left out.
    vtk_runs : int
        VTK runs per count (median and spread; at least 5 for a fair median).
    random_seeds : int
        Seeds of the random subset (mean and spread).
    vtk_tol_points : int
        VTK's vertex count must land in ``[n_target - vtk_tol_points, n_target]``.
    seed : int
        Base seed of VTK's C ``rand()`` and of the random subsets.
    progress : callable, optional
        Called with one line of text after each method (for logs).

    Returns
    -------
    pandas.DataFrame
        Columns :data:`COLUMNS`, ordered by :func:`methods_table`.
    """
    from ..reduction import reduce

    if not isinstance(data, PointData):
        data = sample_grid(resolve_function(data), n)
    unknown = set(methods) - set(METHODS)
    if unknown:
        raise ValueError(f"unknown methods {sorted(unknown)}: choose from {', '.join(METHODS)}")
    fractions = sorted(validate_fractions(fractions), reverse=True)
    N = data.n_points
    targets = {f: count_for_fraction(f, N) for f in fractions}
    say = progress or (lambda msg: None)
    rows = []

    # --- the selection methods: one run each reaches every fraction (snapshots)
    order = None
    curvature_seconds = None
    runs = [("paper", dict(method="paper")), ("greedy", dict(method="greedy", greedy_key="max")),
            ("greedy-sse", dict(method="greedy", greedy_key="sse"))]
    if data.is_grid:
        runs.append(("decimate", dict(method="decimate")))
    for name, kw in runs:
        if name not in methods and not (name == "paper" and "curvature-delaunay" in methods):
            continue
        t0 = time.perf_counter()
        r = reduce(data, fractions=fractions, values=["data", "fit"], **kw)
        if name == "paper":
            order, curvature_seconds = r.order, r.timings["curvature"]
            if name not in methods:  # only needed for the ranking
                continue
        for s in r.snapshots:
            f = min(fractions, key=lambda x: abs(targets[x] - s.n_selected) + abs(x - s.fraction))
            n_vert = _n_vertices(s.tets)  # counted in the mesh itself, not taken from the run
            for mode, err in (("data", s.errors), ("fit", s.fit["errors"])):
                rows.append(_row(name, mode, data, f, targets[f], n_vert, err, s.seconds))
        say(f"{name}: {time.perf_counter() - t0:.2f} s for {len(r.snapshots)} counts")

    # --- VTK: the same count for every run, median and spread
    if "vtk" in methods:
        t0 = time.perf_counter()
        grid = tet_grid(data)
        build = time.perf_counter() - t0
        for f in fractions:
            v = vtk_matched(data, targets[f], runs=vtk_runs, tol_points=vtk_tol_points, seed=seed)
            nv = np.asarray(v["n_vertices"])
            err = {k: v[k] for k in ERROR_KEYS}
            rows.append(_row("vtk", "free", data, f, targets[f], int(np.median(nv)), err,
                             build + v["seconds_median"], runs=int(vtk_runs),
                             n_selected_min=int(nv.min()), n_selected_max=int(nv.max()),
                             **{f"{k}_{s}": v[f"{k}_{s}"] for k in _SPREAD_KEYS for s in ("min", "max")},
                             n_outside=v["n_outside_median"],
                             max_outside_distance=float(np.max(v["max_outside_distance"])),
                             converged=bool(v["converged"])))
        say(f"vtk: {time.perf_counter() - t0:.2f} s for {len(fractions)} counts x {vtk_runs} runs")

    # --- random subset + Delaunay: mean over seeds and spread
    if "random-delaunay" in methods:
        t0 = time.perf_counter()
        for f in fractions:
            res = [random_delaunay(data, targets[f], seed=seed + k) for k in range(int(random_seeds))]
            err = {k: float(np.mean([s.errors[k] for s in res])) for k in ERROR_KEYS}
            err["n_outside"] = float(np.median([s.errors["n_outside"] for s in res]))
            err["max_outside_distance"] = float(max(s.errors["max_outside_distance"] for s in res))
            nv = [_n_vertices(s.tets) for s in res]
            rows.append(_row("random-delaunay", "data", data, f, targets[f], int(np.median(nv)), err,
                             float(np.mean([s.seconds for s in res])), runs=int(random_seeds),
                             n_selected_min=min(nv), n_selected_max=max(nv),
                             **{f"{k}_{fn.__name__}": float(fn([s.errors[k] for s in res]))
                                for k in _SPREAD_KEYS for fn in (np.min, np.max)}))
        say(f"random-delaunay: {time.perf_counter() - t0:.2f} s")

    # --- the paper's curvature order + plain Delaunay
    if "curvature-delaunay" in methods:
        t0 = time.perf_counter()
        for f in fractions:
            s = curvature_delaunay(data, order, targets[f])
            rows.append(_row("curvature-delaunay", "data", data, f, targets[f], _n_vertices(s.tets), s.errors,
                             curvature_seconds + s.seconds))
        say(f"curvature-delaunay: {time.perf_counter() - t0:.2f} s")

    return methods_table(rows)


# --------------------------------------------------------------------------- tables


def methods_table(rows):
    """Rows (dicts or a DataFrame) as one table with :data:`COLUMNS` first, in display order:
    n, function, fraction descending, then :data:`METHODS` and data/fit/free."""
    import pandas as pd

    df = pd.DataFrame(rows).copy()
    if df.empty:
        return pd.DataFrame(columns=COLUMNS)
    for c in COLUMNS:
        if c not in df:
            df[c] = np.nan
    m_rank = {m: i for i, m in enumerate(METHODS)}
    v_rank = {v: i for i, v in enumerate(_VALUES_ORDER)}
    df["_m"] = df["method"].map(lambda m: m_rank.get(m, len(m_rank)))
    df["_v"] = df["values"].map(lambda v: v_rank.get(v, len(v_rank)))
    df["_f"] = df["function"].astype(str)
    df = df.sort_values(["n", "_f", "fraction", "_m", "method", "_v"],
                        ascending=[True, True, False, True, True, True], kind="stable")
    extra = [c for c in df.columns if c not in COLUMNS and not c.startswith("_")]
    return df[COLUMNS + extra].reset_index(drop=True)


def _pick(df, method, values):
    sub = df[(df["method"] == method) & (df["values"] == values)]
    return sub.set_index(["n", "function", "fraction"])


def target_check(df, fractions=None, method="greedy"):
    """The comparison's target, cell by cell: one row per (n, function, fraction).

    ``holds_inf``: ``method`` with data values has a lower E_inf than VTK's median;
    ``holds_rms``: ``method`` with fit values has a lower E_RMS than VTK's median;
    both at equal or fewer vertices (``count_ok``: VTK's every run at or below the
    count and ``method`` not above it).  ``fractions`` restricts the cells
    (e.g. the Table-1 fractions 0.5, 0.2, 0.1).
    """
    import pandas as pd

    df = methods_table(df)
    if fractions is not None:
        keep = np.zeros(len(df), bool)
        for f in fractions:
            keep |= np.isclose(df["fraction"].astype(float), float(f))
        df = df[keep]
    gd, gf, vk = _pick(df, method, "data"), _pick(df, method, "fit"), _pick(df, "vtk", "free")
    out = []
    for key in gd.index:
        if key not in gf.index or key not in vk.index:
            continue
        a, b, v = gd.loc[key], gf.loc[key], vk.loc[key]
        count_ok = bool(v["n_selected_max"] <= v["n_target"] and a["n_selected"] <= a["n_target"]
                        and b["n_selected"] <= b["n_target"])
        out.append({
            "n": key[0], "function": key[1], "fraction": key[2], "n_target": int(a["n_target"]),
            "n_selected": int(a["n_selected"]), "vtk_n_selected_min": int(v["n_selected_min"]),
            "vtk_n_selected_max": int(v["n_selected_max"]),
            "greedy_data_E_inf": a["E_inf"], "vtk_E_inf": v["E_inf"],
            "vtk_E_inf_min": v["E_inf_min"], "vtk_E_inf_max": v["E_inf_max"],
            "holds_inf": bool(a["E_inf"] < v["E_inf"] and count_ok),
            "greedy_fit_E_rms": b["E_rms"], "vtk_E_rms": v["E_rms"],
            "greedy_fit_E_rms_interior": b["E_rms_interior"], "vtk_E_rms_interior": v["E_rms_interior"],
            "vtk_E_rms_min": v["E_rms_min"], "vtk_E_rms_max": v["E_rms_max"],
            "holds_rms": bool(b["E_rms"] < v["E_rms"] and count_ok),
            "greedy_seconds": a["seconds"], "vtk_seconds": v["seconds"], "vtk_n_outside": v["n_outside"],
            "count_ok": count_ok,
        })
    cols = ["n", "function", "fraction", "n_target", "n_selected", "vtk_n_selected_min", "vtk_n_selected_max",
            "greedy_data_E_inf", "vtk_E_inf", "vtk_E_inf_min", "vtk_E_inf_max", "holds_inf",
            "greedy_fit_E_rms", "vtk_E_rms", "vtk_E_rms_min", "vtk_E_rms_max", "holds_rms",
            "greedy_fit_E_rms_interior", "vtk_E_rms_interior",
            "greedy_seconds", "vtk_seconds", "vtk_n_outside", "count_ok"]
    res = pd.DataFrame(out, columns=cols)
    if len(res):
        res["_f"] = res["function"].astype(str)
        res = res.sort_values(["n", "_f", "fraction"], ascending=[True, True, False]).drop(columns="_f")
    return res.reset_index(drop=True)


def _g(x, digits=2):
    """A number with ``digits`` significant digits, in plain notation where sensible."""
    if x is None or not np.isfinite(x):
        return "-"
    if x == 0:
        return "0"
    if abs(x) >= 1e-3:
        return f"{x:.{max(digits - 1 - int(np.floor(np.log10(abs(x)))), 0)}f}"
    return f"{x:.{digits - 1}e}"


def _pct(f):
    return f"{100 * float(f):g} %"


def _func_label(function):
    from ..functions import FUNCTIONS

    try:
        num = int(function)
    except (TypeError, ValueError):
        return str(function)
    if num in FUNCTIONS:
        return f"{num}. {FUNCTIONS[num][0]}"
    return str(function)


def _seconds(x):
    if not np.isfinite(x):
        return "-"
    return f"{x:.2f}" if x < 10 else f"{x:.1f}"


def methods_markdown(df, fractions=None, *, figures=None):
    """The Markdown summary ``results/report/methods.md``.

    Its first part (up to the first ``## `` heading) is the short summary the
    README's "How good is it" section shows: the target check cell by
    cell.  Then every method side by side for each function and fraction, and a
    note on how each number was obtained.

    Parameters
    ----------
    df : DataFrame or rows
        Rows of :func:`compare_methods` (one or more functions / n).
    fractions : sequence of float, optional
        The fractions of the target check (the Table-1 columns); default all.
    figures : dict, optional
        ``{(n, function): relative path}`` of the log-log plots to link.
    """
    df = methods_table(df)
    chk = target_check(df, fractions)
    L = ["# How good is it: trivsel against VTK's tetrahedral decimation", ""]
    ns = sorted(set(df["n"]))
    for n in ns:
        c = chk[chk["n"] == n]
        npts = (int(n) + 1) ** 3 if str(n).isdigit() else None
        grid = f"the {int(n) + 1}^3 grid ({npts} points)" if npts else f"n = {n}"
        L += [
            f"Every method at the same number of vertices on {grid}: `greedy` (error-driven "
            "insertion, trivsel's `--method greedy`) against VTK's `vtkUnstructuredGridQuadricDecimation` "
            f"(median of {int(df[df['method'] == 'vtk']['runs'].max()) if (df['method'] == 'vtk').any() else 0} "
            "runs; min-max over the runs in brackets). Like for like: "
            "**E_inf** with `greedy`'s *data* values (a true selection, interpolating its points) and "
            "**E_RMS** with *fit* values (least-squares vertex values on the same mesh; VTK also chooses its "
            "vertex values freely). ✅ = greedy lower, ❌ = VTK lower. Times: one run to that count, "
            "seconds.",
            "",
            "| Function | kept | points (greedy / VTK) | E_inf greedy+data | E_inf VTK | | "
            "E_RMS greedy+fit | E_RMS VTK | | s greedy | s VTK |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for _, r in c.iterrows():
            vn = (f"{r['vtk_n_selected_min']}" if r["vtk_n_selected_min"] == r["vtk_n_selected_max"]
                  else f"{r['vtk_n_selected_min']}-{r['vtk_n_selected_max']}")
            L.append(
                f"| {_func_label(r['function'])} | {_pct(r['fraction'])} | {r['n_selected']} / {vn} | "
                f"{_g(r['greedy_data_E_inf'])} | {_g(r['vtk_E_inf'])} "
                f"({_g(r['vtk_E_inf_min'])}-{_g(r['vtk_E_inf_max'])}) | {'✅' if r['holds_inf'] else '❌'} | "
                f"{_g(r['greedy_fit_E_rms'])} | {_g(r['vtk_E_rms'])} "
                f"({_g(r['vtk_E_rms_min'])}-{_g(r['vtk_E_rms_max'])}) | {'✅' if r['holds_rms'] else '❌'} | "
                f"{_seconds(r['greedy_seconds'])} | {_seconds(r['vtk_seconds'])} |")
        k = len(c)
        hi, hr = int(c["holds_inf"].sum()), int(c["holds_rms"].sum())
        L += ["", f"**E_inf: greedy lower in {hi} of {k} cells; E_RMS: greedy lower in {hr} of {k} cells.**"]
        fails = c[~c["holds_rms"]]
        if len(fails):
            L.append("E_RMS cells where VTK is lower (greedy+fit vs VTK; split into the interior points and "
                     "the boundary-face points): " + "; ".join(
                         f"{_func_label(r['function'])} at {_pct(r['fraction'])} "
                         f"({_g(r['greedy_fit_E_rms'], 3)} vs {_g(r['vtk_E_rms'], 3)}, "
                         f"{100 * (r['greedy_fit_E_rms'] / r['vtk_E_rms'] - 1):+.0f} %{_split(r, n)})"
                         for _, r in fails.iterrows()) + ".")
            inside = fails[fails["greedy_fit_E_rms_interior"] < fails["vtk_E_rms_interior"]]
            if len(inside):
                L.append(f"In {len(inside)} of these {len(fails)} cells greedy+fit is lower on the interior "
                         "points: VTK wins them on the boundary faces.")
        fails = c[~c["holds_inf"]]
        if len(fails):
            L.append("E_inf cells where VTK is lower: " + "; ".join(
                f"{_func_label(r['function'])} at {_pct(r['fraction'])} "
                f"({_g(r['greedy_data_E_inf'], 3)} vs {_g(r['vtk_E_inf'], 3)})" for _, r in fails.iterrows()) + ".")
        alt = target_check(df[df["n"] == n], fractions, method="greedy-sse")
        if len(alt):
            L.append(f"With the E_RMS-aimed key (`--greedy-key sse`, method `greedy-sse`): E_RMS lower "
                     f"in {int(alt['holds_rms'].sum())} of {len(alt)} cells, E_inf in {int(alt['holds_inf'].sum())}.")
        dec = target_check(df[df["n"] == n], fractions, method="decimate")
        if len(dec):
            L.append(f"With bottom-up decimation (`--method decimate`, fitted values): E_RMS lower in "
                     f"{int(dec['holds_rms'].sum())} of {len(dec)} cells, E_inf (data values) in "
                     f"{int(dec['holds_inf'].sum())}.")
        sp = _speed_line(df[df["n"] == n], fractions)
        if sp:
            L.append(sp)
        L.append("")
    L += ["Details, every method and the plots: `results/report/methods.md` "
          "(`snakemake -c all --configfile config/methods.yaml`).", ""]

    # --- side by side
    L += ["## Every method side by side", "",
          "E_RMS / E_inf over all grid points, \\* without the boundary (eqs. 19-20). `values`: "
          "`data` = the selected points' own values, `fit` = least-squares vertex values on the same "
          "mesh, `free` = VTK's own positions and values. Spread: min-max over VTK's runs or the random "
          "seeds. `outside`: data points outside VTK's hull (median over runs), evaluated at the nearest "
          "boundary point. `s`: seconds for one run to that count (see the notes).", ""]
    for n in ns:
        for fn in sorted(set(df[df["n"] == n]["function"]), key=str):
            d = df[(df["n"] == n) & (df["function"] == fn)]
            L += [f"### Function {_func_label(fn)}, n = {n}", ""]
            if figures and (n, fn) in figures:
                L += [f"![E_RMS and E_inf against the vertex count, function {fn}]({figures[(n, fn)]})", ""]
            L += ["| kept | method | values | points | E_RMS | E_RMS\\* | E_inf | E_inf\\* | spread E_RMS | "
                  "spread E_inf | outside | s |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
            for f in sorted(set(d["fraction"]), reverse=True):
                if fractions is not None and not any(np.isclose(f, x) for x in fractions):
                    continue
                for _, r in d[d["fraction"] == f].iterrows():
                    pts = (f"{int(r['n_selected'])}" if r["n_selected_min"] == r["n_selected_max"]
                           else f"{int(r['n_selected_min'])}-{int(r['n_selected_max'])}")
                    spread = int(r["runs"]) > 1
                    L.append(
                        f"| {_pct(f)} | {r['method']} | {r['values']} | {pts} | {_g(r['E_rms'], 3)} | "
                        f"{_g(r['E_rms_interior'], 3)} | {_g(r['E_inf'], 3)} | {_g(r['E_inf_interior'], 3)} | "
                        + (f"{_g(r['E_rms_min'])}-{_g(r['E_rms_max'])} | {_g(r['E_inf_min'])}-{_g(r['E_inf_max'])}"
                           if spread else " | ")
                        + f" | {_outside(r)} | {_seconds(r['seconds'])} |")
            L.append("")
    L += ["## Notes", "",
          "* Matched counts: the target is the fraction of all points, corners included, rounded half up "
          "(the count `trivsel reduce` stops at). `paper`, `greedy` and the Delaunay baselines keep exactly "
          "that many points; VTK collapses edges until it lands within a few vertices at or below it, in "
          "every run (`points` shows its range).",
          "* `greedy` uses the largest residual (`--greedy-key max`, the default), `greedy-sse` the worst "
          "point of the tetrahedron with the largest squared error; both with the `sse` swap criterion "
          "(the greedy default). `paper` is the reproduction of Table 1 (curvature order, `rms` criterion).",
          "* `curvature-delaunay` keeps the same points as `paper` at each count but triangulates them by "
          "plain Delaunay: the difference to `paper`+`data` is what the data-dependent swapping is worth.",
          "* Times: `paper` and `greedy` run once, to the largest count, with snapshots on the way, so the time of a count is the wall time from the start of the "
          "run to that snapshot (curvature, swapping, errors and the least-squares fits of the smaller "
          "counts included). VTK: building its input grid plus the median filter time of one decimation "
          "to that count. Delaunay baselines: the triangulation (plus the curvature estimate for "
          "`curvature-delaunay`); the selection itself is free.",
          ""]
    return "\n".join(L)


def _split(r, n):
    """'; interior a vs b, faces c vs d' for a grid of n intervals (face RMS from the pair E_RMS, E_RMS*)."""
    from ..norms import face_residual_rms

    try:
        n = int(n)
    except (TypeError, ValueError):
        return ""
    N, Ni = (n + 1) ** 3, (n - 1) ** 3
    fg = face_residual_rms(r["greedy_fit_E_rms"], r["greedy_fit_E_rms_interior"], N, Ni)
    fv = face_residual_rms(r["vtk_E_rms"], r["vtk_E_rms_interior"], N, Ni)
    return (f"; interior {_g(r['greedy_fit_E_rms_interior'], 3)} vs {_g(r['vtk_E_rms_interior'], 3)}, "
            f"faces {_g(fg, 2)} vs {_g(fv, 2)}")


def _outside(r):
    if r["method"] != "vtk":
        return "0" if not r["n_outside"] else f"{r['n_outside']:g}"
    if not r["n_outside"]:
        return "0"
    d = r["max_outside_distance"]
    return f"{r['n_outside']:g} (≤ {_g(d)} away)" if np.isfinite(d) and d > 0 else f"{r['n_outside']:g}"


def _speed_line(df, fractions):
    g = df[(df["method"] == "greedy") & (df["values"] == "data")]
    v = df[df["method"] == "vtk"]
    if g.empty or v.empty:
        return ""
    if fractions is not None:
        g = g[np.isclose(g["fraction"].values[:, None], np.asarray(fractions, float)[None, :]).any(axis=1)]
        v = v[np.isclose(v["fraction"].values[:, None], np.asarray(fractions, float)[None, :]).any(axis=1)]
    return (f"Time per run: greedy {g['seconds'].min():.2f}-{g['seconds'].max():.2f} s, "
            f"VTK {v['seconds'].min():.2f}-{v['seconds'].max():.2f} s.")


# --------------------------------------------------------------------------- figure

_STYLE = {
    "greedy": ("C0", "o"),
    "greedy-sse": ("C9", "v"),
    "paper": ("C3", "s"),
    "decimate": ("C4", "P"),
    "vtk": ("k", "D"),
    "random-delaunay": ("C2", "^"),
    "curvature-delaunay": ("C1", "x"),
}
_LINE = {"data": "-", "fit": "--", "free": "-"}


def methods_figure(df, out_png, function=None, n=None, dpi=110):
    """Log-log plot of E_RMS (left) and E_inf (right) against the vertex count, one line per
    (method, values); VTK's and the random subsets' min-max spread as a band."""
    from .figures import _function_title, _pyplot, _save_png

    plt = _pyplot()
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator

    df = methods_table(df)
    if function is not None:
        df = df[df["function"].astype(str) == str(function)]
    if n is not None:
        df = df[df["n"].astype(str) == str(n)]
    if df.empty:
        raise ValueError(f"no rows for function {function!r}, n {n!r}")
    fig, axes = plt.subplots(1, 2, figsize=(12.5, 6.0))
    N = (int(df["n"].iloc[0]) + 1) ** 3 if str(df["n"].iloc[0]).isdigit() else None
    for ax, key, label in ((axes[0], "E_rms", "E_RMS (all points, eq. 19)"),
                           (axes[1], "E_inf", "E_inf (all points, eq. 20)")):
        for (m, v), d in df.groupby(["method", "values"], sort=False):
            d = d.sort_values("n_target")
            color, marker = _STYLE.get(m, ("C7", "."))
            x = d["n_selected"].astype(float).values
            ax.plot(x, d[key].values, _LINE.get(v, "-"), color=color, marker=marker, ms=5, lw=1.6,
                    mfc="none" if v == "fit" else color, label=f"{m} ({v})" + (" median" if m == "vtk" else
                                                                                " mean" if m == "random-delaunay"
                                                                                else ""))
            if (d["runs"] > 1).any():
                ax.fill_between(x, d[f"{key}_min"].values, d[f"{key}_max"].values, color=color, alpha=0.15,
                                lw=0)
        ax.set_xscale("log")
        ax.set_yscale("log")
        counts = np.sort(df["n_target"].astype(float).unique())
        ax.set_xlim(counts[0] / 1.25, counts[-1] * 1.25)
        ax.xaxis.set_major_locator(FixedLocator(counts))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda c, _: f"{c:.0f}"))
        ax.xaxis.set_minor_locator(NullLocator())
        ax.set_xlabel("vertices kept (matched count; VTK at or up to a few below)")
        ax.set_ylabel(label)
        ax.grid(True, which="major", alpha=0.35)
        ax.grid(True, which="minor", axis="y", alpha=0.12)
        if N:
            sec = ax.secondary_xaxis("top", functions=(lambda c: 100 * c / N, lambda p: p * N / 100))
            sec.xaxis.set_major_locator(FixedLocator(100 * counts / N))
            sec.xaxis.set_major_formatter(FuncFormatter(lambda p, _: f"{p:.2g} %"))
            sec.xaxis.set_minor_locator(NullLocator())
            sec.set_xlabel(f"fraction of the {N} grid points")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=5, fontsize=8.5, frameon=False)
    fn = df["function"].iloc[0]
    try:
        title = _function_title(int(fn), df["n"].iloc[0])
    except (TypeError, ValueError):
        title = f"{fn}, n = {df['n'].iloc[0]}"
    fig.suptitle(title + " - every method at matched vertex counts", fontsize=11)
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    return _save_png(fig, out_png, dpi)
