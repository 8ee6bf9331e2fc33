"""Scaling study: wall time and peak memory against the number of points.

One measurement reduces Table-1 function 4 (by default) on the ``(n+1)^3`` grid to
10 % of its points with trivsel's ``paper`` or ``greedy`` method, or decimates the
same grid with VTK's ``vtkUnstructuredGridQuadricDecimation`` to the same vertex
count (:func:`trivsel.study.baselines.vtk_quadric_decimation`), in a **fresh Python
process** (``python -m trivsel.study.scaling``), so that every measurement starts from
the same state and its peak memory is its own:

1. import trivsel (and VTK for ``vtk``);
2. warm-up: one untimed run of the same method on the tiny ``5^3`` grid, which
   loads (or, the first time in an environment, compiles) the numba kernels and
   VTK's libraries, so compile time never enters the timing;
3. sample the grid (untimed); the peak resident memory so far is ``base_mb``;
4. the timed run: ``seconds`` is its wall time (``time.perf_counter``).

``peak_mb`` is the peak resident set size of the child during the timed run:
after the warm-up the child resets its peak mark (Linux: ``5`` to
``/proc/self/clear_refs``), so the memory of compiling the kernels does not
count, and ``ru_maxrss`` of the child (``os.wait4``, ``getrusage`` of that one
child) and its ``VmHWM`` then cover the timed run.  Without that reset (other
systems) ``peak_mb`` is the peak of the whole process.  Either way it includes
the interpreter, the libraries and the input data (``base_mb``, about 0.2 GB);
``peak_mb - base_mb`` is what the run itself added.

:func:`fit_slopes` fits ``log(y) = a + b log(points)`` per method (``b``: how
the cost grows with the work), :func:`scaling_figure` draws time and memory
against points on log-log axes with the fitted slope in the legend, and
:func:`scaling_markdown` writes the summary with the ratios trivsel/VTK and the
the scaling targets.

Command line (one measurement in this process; the parent side is :func:`measure`)::

    python -m trivsel.study.scaling --method greedy --n 32        # prints one JSON line
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pandas as pd

__all__ = [
    "SCALE_COLUMNS",
    "SCALE_METHODS",
    "TARGETS",
    "run_here",
    "measure",
    "fit_power_law",
    "fit_slopes",
    "ratios",
    "target_lines",
    "scaling_table",
    "scaling_figure",
    "scaling_markdown",
    "scale_mem_mb",
    "scale_runtime",
]

#: columns of ``results/report/scaling.csv`` (then ``base_mb``, ``warmup_seconds``)
SCALE_COLUMNS = ["method", "n", "n_points", "n_selected", "seconds", "peak_mb"]
#: measured methods: trivsel's two selection methods and VTK's decimation
SCALE_METHODS = ("paper", "greedy", "vtk")
#: the scaling targets
TARGETS = {"ratio_n": 64, "ratio_max": 1.0, "big_n": 128, "big_method": "greedy", "big_seconds": 600.0,
           "big_mb": 8 * 1024.0}
#: marks the result line of the child process
_RESULT_TAG = "TRIVSEL_SCALING_RESULT "


def _maxrss_mb(ru_maxrss):
    """``ru_maxrss`` in MiB (kilobytes on Linux, bytes on macOS)."""
    return ru_maxrss / (1024.0 * 1024.0) if sys.platform == "darwin" else ru_maxrss / 1024.0


def _self_peak_mb():
    import resource

    return _maxrss_mb(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


def _proc_status_mb(key):
    """``VmHWM`` / ``VmRSS`` of this process from /proc (MiB), or None where unavailable."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def _reset_peak():
    """Reset this process's peak-RSS mark (Linux >= 4.0: ``5`` to /proc/self/clear_refs).

    Afterwards ``VmHWM`` (and ``ru_maxrss``) is the peak from now on, so the warm-up's
    memory (e.g. numba compiling the kernels) does not count.  Returns whether it worked.
    """
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        return False
    hwm, rss = _proc_status_mb("VmHWM"), _proc_status_mb("VmRSS")
    return hwm is not None and rss is not None and hwm <= rss + 1.0


def _one_run(method, data, fraction, seed, threads=1):
    """One run of ``method`` on ``data``; returns the number of points kept."""
    from ..selection import count_for_fraction

    if method == "vtk":
        from .baselines import vtk_quadric_decimation

        n_keep = count_for_fraction(fraction, data.n_points)
        dm = vtk_quadric_decimation(data, n_edges=data.n_points - n_keep, seed=seed)
        return dm.n_vertices
    from .. import reduce

    res = reduce(data, fractions=[fraction], method=method, threads=threads)
    return int(res.snapshots[0].n_selected)


def run_here(method, n, *, function=4, fraction=0.1, warmup_n=4, seed=1, threads=1) -> dict:
    """Warm up, then time one run of ``method`` on the ``(n+1)^3`` grid, in this process.

    Parameters
    ----------
    method : {"paper", "greedy", "vtk"}
        trivsel's selection method, or VTK's tetrahedral quadric decimation to the
        same vertex count (``N - round_half_up(fraction * N)`` edge collapses).
    n : int
        Grid intervals per axis; the data are ``(n+1)^3`` points.
    function : int
        Table-1 function (4, the exponential, by default).
    fraction : float
        Fraction of the points to keep.
    warmup_n : int
        Grid of the untimed warm-up run (numba kernels loaded or compiled, VTK
        loaded); 0 skips the warm-up.
    seed : int
        Seed of C ``rand()`` for VTK's random edge candidates.
    threads : int
        trivsel's ``threads`` (the curvature fits; VTK's filter is single-threaded).

    Returns
    -------
    dict
        ``method, n, n_points, n_selected, seconds`` (wall time of the timed run),
        ``base_mb`` (resident memory just before it: interpreter, libraries and
        input data), ``run_peak_mb`` (peak resident memory during the timed run,
        ``VmHWM`` after resetting the mark; None where /proc cannot reset it),
        ``peak_reset``, ``warmup_peak_mb`` (peak before the timed run, e.g. numba
        compiling), ``warmup_seconds``, ``function``, ``fraction``.
    """
    from ..data import sample_grid

    if method not in SCALE_METHODS:
        raise ValueError(f"method must be one of {SCALE_METHODS}, got {method!r}")
    t0 = time.perf_counter()
    if warmup_n:
        _one_run(method, sample_grid(function, int(warmup_n)), fraction, seed, threads)
    warmup = time.perf_counter() - t0
    data = sample_grid(function, int(n))
    warmup_peak = _self_peak_mb()
    reset = _reset_peak()
    # the mark just set (the resident size at the reset): the run's peak can only be above it
    base = _proc_status_mb("VmHWM") if reset else warmup_peak
    t0 = time.perf_counter()
    n_sel = _one_run(method, data, fraction, seed, threads)
    seconds = time.perf_counter() - t0
    # VmHWM is the kernel's lazily kept high-water mark: pages returned with madvise (malloc
    # trimming) and per-thread RSS counters can leave it a few MiB below the mark read at the
    # reset, although the peak of the run cannot be lower than the size it started at
    run_peak = max(_proc_status_mb("VmHWM"), base) if reset else None
    return dict(method=method, n=int(n), n_points=int(data.n_points), n_selected=int(n_sel), seconds=seconds,
                base_mb=base, run_peak_mb=run_peak, peak_reset=reset, warmup_peak_mb=warmup_peak,
                warmup_seconds=warmup, function=function, fraction=float(fraction), threads=int(threads))


def measure(method, n, *, function=4, fraction=0.1, warmup_n=4, seed=1, threads=1, timeout=None, log=None,
            python=None) -> dict:
    """One measurement (see :func:`run_here`) in a fresh Python process.

    Parameters
    ----------
    method, n, function, fraction, warmup_n, seed, threads
        As for :func:`run_here`.
    timeout : float, optional
        Kill the child after this many seconds (then ``RuntimeError``).
    log : callable, optional
        Called with each line the child prints (progress, warnings).
    python : str, optional
        Interpreter of the child; default ``sys.executable``.

    Returns
    -------
    dict
        :func:`run_here`'s dict plus ``process_peak_mb``, the child's peak
        resident set size from ``os.wait4`` (that one child's ``getrusage``;
        unlike ``RUSAGE_CHILDREN`` it is not the maximum over earlier children),
        and ``peak_mb``: the peak during the timed run (``run_peak_mb``) where
        the child could reset its peak mark after the warm-up (Linux), else
        ``process_peak_mb``.  Both include the resident baseline ``base_mb``.

    Raises
    ------
    RuntimeError
        If the child fails or times out; the message ends with its last output.
    """
    cmd = [python or sys.executable, "-m", "trivsel.study.scaling", "--method", str(method), "--n", str(int(n)),
           "--function", str(function), "--fraction", repr(float(fraction)), "--warmup-n", str(int(warmup_n)),
           "--seed", str(int(seed)), "--threads", str(int(threads))]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    timer = threading.Timer(timeout, proc.kill) if timeout else None
    if timer:
        timer.start()
    lines, result = [], None
    try:
        for line in proc.stdout:
            line = line.rstrip("\n")
            if line.startswith(_RESULT_TAG):
                result = json.loads(line[len(_RESULT_TAG):])
                continue
            lines.append(line)
            if log:
                log(line)
        proc.stdout.close()
        _, status, usage = os.wait4(proc.pid, 0)
    finally:
        if timer:
            timer.cancel()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0 or result is None:
        tail = "\n".join(lines[-20:])
        raise RuntimeError(f"{' '.join(cmd)} failed (exit status {proc.returncode}"
                           f"{', killed after the timeout' if proc.returncode < 0 and timeout else ''}):\n{tail}")
    # resetting the high-water mark for the timed run also lowers what the kernel reports as
    # the child's maximum resident size, so the peaks read before and after the reset count too
    result["process_peak_mb"] = max(_maxrss_mb(usage.ru_maxrss), result.get("warmup_peak_mb") or 0.0,
                                    result.get("run_peak_mb") or 0.0, result.get("base_mb") or 0.0)
    result["peak_mb"] = result["run_peak_mb"] if result.get("run_peak_mb") else result["process_peak_mb"]
    return result


# --------------------------------------------------------------------------- fitting


def fit_power_law(x, y):
    """Least-squares fit of ``log y = log c + b log x``.

    Parameters
    ----------
    x, y : array_like
        Positive values; pairs with a non-positive or non-finite value are dropped.

    Returns
    -------
    tuple of float
        ``(b, c, r2)``: the exponent (slope on log-log axes), the prefactor and
        the coefficient of determination of the fit in log space; NaN when fewer
        than two distinct ``x`` remain.
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    lx, ly = np.log(x[ok]), np.log(y[ok])
    if np.unique(lx).size < 2:
        return float("nan"), float("nan"), float("nan")
    b, a = np.polyfit(lx, ly, 1)
    resid = ly - (a + b * lx)
    ss = float(((ly - ly.mean()) ** 2).sum())
    r2 = 1.0 - float((resid**2).sum()) / ss if ss > 0 else 1.0
    return float(b), float(math.exp(a)), r2


def fit_slopes(table, quantities=("seconds", "peak_mb"), x="n_points") -> pd.DataFrame:
    """Slope of ``log(quantity)`` against ``log(points)`` for each method.

    Parameters
    ----------
    table : pandas.DataFrame
        Rows with ``method``, ``x`` and the quantities (:data:`SCALE_COLUMNS`).
    quantities : sequence of str
        Columns to fit; ``"extra_mb"`` is ``peak_mb - base_mb`` (memory the run
        added), computed when asked for.
    x : str
        The abscissa column.

    Returns
    -------
    pandas.DataFrame
        One row per method and quantity: ``method, quantity, slope, prefactor,
        r2, points_min, points_max, n_fit`` (rows fitted), and ``slope_last``,
        the slope between the two largest sizes (the growth at the large end,
        where fixed costs matter least).
    """
    df = table.copy()
    if "extra_mb" in quantities and "extra_mb" not in df:
        df["extra_mb"] = df["peak_mb"] - df["base_mb"]
    rows = []
    for method, d in df.groupby("method", sort=False):
        d = d.sort_values(x)
        for q in quantities:
            ok = (d[x] > 0) & (d[q] > 0)
            b, c, r2 = fit_power_law(d.loc[ok, x], d.loc[ok, q])
            dd = d[ok]
            last = (fit_power_law(dd[x].values[-2:], dd[q].values[-2:])[0] if len(dd) >= 2 else float("nan"))
            rows.append(dict(method=method, quantity=q, slope=b, prefactor=c, r2=r2,
                             points_min=int(dd[x].min()) if len(dd) else 0,
                             points_max=int(dd[x].max()) if len(dd) else 0, n_fit=int(len(dd)), slope_last=last))
    return pd.DataFrame(rows, columns=["method", "quantity", "slope", "prefactor", "r2", "points_min", "points_max",
                                       "n_fit", "slope_last"])


def scaling_table(rows) -> pd.DataFrame:
    """The rows of the measurements as the table ``scaling.csv``.

    Parameters
    ----------
    rows : iterable of dict or pandas.DataFrame
        Measurements (:func:`measure`); the median is taken where a (method, n)
        appears more than once.

    Returns
    -------
    pandas.DataFrame
        :data:`SCALE_COLUMNS`, then ``base_mb`` and ``warmup_seconds`` when
        present, sorted by method (paper, greedy, vtk, others) and n.
    """
    df = pd.DataFrame(rows).copy()
    missing = [c for c in SCALE_COLUMNS if c not in df]
    if missing:
        raise ValueError(f"scaling rows lack the columns {missing}")
    extra = [c for c in ("base_mb", "warmup_seconds") if c in df]
    df = df[SCALE_COLUMNS + extra]
    num = [c for c in df.columns if c != "method"]
    df = df.groupby(["method", "n"], sort=False, as_index=False)[[c for c in num if c != "n"]].median()
    order = {m: i for i, m in enumerate(SCALE_METHODS)}
    df["_o"] = df["method"].map(lambda m: order.get(m, len(order)))
    df = df.sort_values(["_o", "method", "n"]).drop(columns="_o").reset_index(drop=True)
    for c in ("n", "n_points", "n_selected"):
        df[c] = df[c].round().astype(int)
    return df[SCALE_COLUMNS + extra]


def ratios(table, reference="vtk") -> pd.DataFrame:
    """Time and memory of each trivsel method over the reference's, per n.

    Returns
    -------
    pandas.DataFrame
        ``method, n, n_points, seconds, ref_seconds, ratio_seconds, peak_mb,
        ref_peak_mb, ratio_peak_mb`` for every method other than ``reference``
        at every n the reference was measured at.
    """
    ref = table[table["method"] == reference].set_index("n")
    rows = []
    for _, r in table[table["method"] != reference].iterrows():
        if r["n"] not in ref.index:
            continue
        rr = ref.loc[r["n"]]
        rows.append(dict(method=r["method"], n=int(r["n"]), n_points=int(r["n_points"]), seconds=r["seconds"],
                         ref_seconds=rr["seconds"], ratio_seconds=r["seconds"] / rr["seconds"],
                         peak_mb=r["peak_mb"], ref_peak_mb=rr["peak_mb"], ratio_peak_mb=r["peak_mb"] / rr["peak_mb"]))
    return pd.DataFrame(rows, columns=["method", "n", "n_points", "seconds", "ref_seconds", "ratio_seconds",
                                       "peak_mb", "ref_peak_mb", "ratio_peak_mb"])


# --------------------------------------------------------------------------- figure and summary

_STYLE = {"paper": ("C0", "o"), "greedy": ("C3", "s"), "vtk": ("C2", "^")}
_LABEL = {"paper": "trivsel paper", "greedy": "trivsel greedy", "vtk": "VTK decimation"}


def scaling_figure(table, out_png, dpi=110, title=None):
    """Log-log plot of wall time (left) and peak memory (right) against the number of points.

    Parameters
    ----------
    table : pandas.DataFrame
        :func:`scaling_table` rows.
    out_png : str or path
        Output file.
    dpi : int
        Resolution.
    title : str, optional
        Figure title; default names the function and fraction generically.

    Returns
    -------
    str or path
        ``out_png``.  Each method is drawn with markers; the dashed line of its
        colour is the fitted power law, its exponent in the legend.
    """
    from .figures import _pyplot, _save_png

    plt = _pyplot()
    if table.empty:
        raise ValueError("no scaling rows to plot")
    slopes = fit_slopes(table, ("seconds", "peak_mb")).set_index(["method", "quantity"])
    fig, axes = plt.subplots(1, 2, figsize=(11.5, 4.8))
    xs = np.sort(table["n_points"].astype(float).unique())
    xfit = np.geomspace(xs[0], xs[-1], 50)
    for ax, q, ylabel in ((axes[0], "seconds", "wall time of one run (s)"),
                          (axes[1], "peak_mb", "peak memory of the process (MiB)")):
        for m, d in table.groupby("method", sort=False):
            d = d.sort_values("n_points")
            color, marker = _STYLE.get(m, ("C7", "."))
            s = slopes.loc[(m, q)]
            label = _LABEL.get(m, m) + (f": slope {s['slope']:.2f}" if np.isfinite(s["slope"]) else "")
            ax.plot(d["n_points"], d[q], marker=marker, color=color, ls="none", ms=6, label=label)
            if np.isfinite(s["slope"]):
                ax.plot(xfit, s["prefactor"] * xfit ** s["slope"], "--", color=color, lw=1.3)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("grid points (n+1)^3")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=8.5, title="fitted slope of log y vs log points", title_fontsize=8)
    fig.suptitle(title or "Cost against the number of points (fresh process per run, after a warm-up)",
                 fontsize=11)
    fig.tight_layout()
    return _save_png(fig, out_png, dpi)


def _fmt(x, nd=3):
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "-"
    return f"{x:.{nd}g}"


def scaling_markdown(table, *, function=4, fraction=0.1, figure=None, targets=None) -> str:
    """The summary ``scaling.md``: measurements, fitted slopes, ratios trivsel/VTK, targets.

    Parameters
    ----------
    table : pandas.DataFrame
        :func:`scaling_table` rows.
    function, fraction : int, float
        What was reduced (for the text).
    figure : str, optional
        Relative path of the figure, linked when given.
    targets : dict, optional
        Overrides of :data:`TARGETS`.

    Returns
    -------
    str
        Markdown.
    """
    t = dict(TARGETS, **(targets or {}))
    slopes = fit_slopes(table, ("seconds", "peak_mb", "extra_mb") if "base_mb" in table else
                        ("seconds", "peak_mb"))
    rat = ratios(table)
    out = [f"# Scaling: time and memory against the number of points \n",
           f"Function {function} on the (n+1)^3 grid reduced to {100 * fraction:g} % of its points: trivsel's "
           f"`paper` and `greedy` methods (`trivsel.reduce(sample_grid({function}, n), fractions=[{fraction:g}], "
           f"method=...)`) and VTK's `vtkUnstructuredGridQuadricDecimation` to the same vertex count "
           f"(`trivsel.study.baselines.vtk_quadric_decimation`; input grid built inside the timing). Each run is a "
           f"fresh Python process (`trivsel.study.scaling.measure`): one untimed warm-up run of the same method on "
           f"the 5^3 grid first (loads the cached numba kernels, or compiles them on the first run in an "
           f"environment, and loads VTK), so no compile time is counted. `seconds`: wall time of the timed "
           f"run; `peak MiB`: peak resident memory of the child during the timed run (its peak mark is reset "
           f"after the warm-up, so compiling does not count), including the interpreter, the libraries and "
           f"the input (`base MiB`: resident just before the timed run). Measured one job at a time.\n"]
    if figure:
        out.append(f"![time and memory against points]({figure})\n")
    out.append("| method | n | points | kept | seconds | peak MiB | base MiB |")
    out.append("|---|---|---|---|---|---|---|")
    for _, r in table.iterrows():
        out.append(f"| {r['method']} | {r['n']} | {r['n_points']} | {r['n_selected']} | {_fmt(r['seconds'])} | "
                   f"{r['peak_mb']:.0f} | {_fmt(r.get('base_mb', float('nan')), 4)} |")
    out.append("\n## Fitted slopes (log y against log points, least squares over every n)\n")
    out.append("`slope_last`: between the two largest grids (fixed costs such as process start-up and "
               "library memory flatten the slope at small n). `extra_mb` = peak - base: the memory the run "
               "itself added.\n")
    out.append("| method | quantity | slope | slope_last | r^2 | points |")
    out.append("|---|---|---|---|---|---|")
    for _, s in slopes.iterrows():
        out.append(f"| {s['method']} | {s['quantity']} | {_fmt(s['slope'])} | {_fmt(s['slope_last'])} | "
                   f"{_fmt(s['r2'])} | {s['points_min']}-{s['points_max']} ({s['n_fit']} sizes) |")
    out.append("\n## Ratios trivsel / VTK per n (> 1: trivsel slower or larger)\n")
    if rat.empty:
        out.append("VTK was not measured at any of these n.\n")
    else:
        out.append("| method | n | points | seconds | VTK seconds | time ratio | peak MiB | VTK peak MiB | "
                   "memory ratio |")
        out.append("|---|---|---|---|---|---|---|---|---|")
        for _, r in rat.iterrows():
            out.append(f"| {r['method']} | {r['n']} | {r['n_points']} | {_fmt(r['seconds'])} | "
                       f"{_fmt(r['ref_seconds'])} | {r['ratio_seconds']:.2f} | {r['peak_mb']:.0f} | "
                       f"{r['ref_peak_mb']:.0f} | {r['ratio_peak_mb']:.2f} |")
    out.append("\n## Targets\n")
    out += target_lines(table, slopes, rat, t)
    return "\n".join(out) + "\n"


def target_lines(table, slopes, rat, t=None):
    """Markdown bullet lines, one per target, each MET / NOT MET / not measured."""
    t = dict(TARGETS, **(t or {}))
    lines = []
    n0 = t["ratio_n"]
    for m in ("paper", "greedy"):
        r = rat[(rat["method"] == m) & (rat["n"] == n0)]
        if r.empty:
            lines.append(f"- {(n0 + 1)}^3 to 10 %, {m} no slower than VTK (ratio <= {t['ratio_max']:g}): "
                         f"not measured")
        else:
            v = float(r["ratio_seconds"].iloc[0])
            lines.append(f"- {(n0 + 1)}^3 to 10 %, {m} no slower than VTK (ratio <= {t['ratio_max']:g}): "
                         f"ratio {v:.2f} ({float(r['seconds'].iloc[0]):.3g} s vs "
                         f"{float(r['ref_seconds'].iloc[0]):.3g} s): **{'MET' if v <= t['ratio_max'] else 'NOT MET'}**")
    nb, mb = t["big_n"], t["big_method"]
    r = table[(table["method"] == mb) & (table["n"] == nb)]
    head = (f"- {(nb + 1)}^3 to 10 % with {mb} under {t['big_seconds'] / 60:g} minutes and "
            f"{t['big_mb'] / 1024:g} GiB")
    if r.empty:
        lines.append(head + ": not measured")
    else:
        s, p = float(r["seconds"].iloc[0]), float(r["peak_mb"].iloc[0])
        ok = s < t["big_seconds"] and p < t["big_mb"]
        lines.append(head + f": {s:.0f} s, {p / 1024:.2f} GiB: **{'MET' if ok else 'NOT MET'}**")
    sl = slopes[slopes["quantity"] == "seconds"].set_index("method")
    if "vtk" in sl.index and np.isfinite(sl.loc["vtk", "slope"]):
        v = float(sl.loc["vtk", "slope"])
        for m in ("paper", "greedy"):
            if m in sl.index and np.isfinite(sl.loc[m, "slope"]):
                b = float(sl.loc[m, "slope"])
                lines.append(f"- time slope of {m} no worse than VTK's: {b:.2f} vs {v:.2f}: "
                             f"**{'MET' if b <= v else 'NOT MET'}**")
    else:
        lines.append("- time slope no worse than VTK's: not measured (VTK needs two or more sizes)")
    return lines


# --------------------------------------------------------------------------- workflow resources


def _n_points(wildcards):
    return (int(wildcards.n) + 1) ** 3


def scale_mem_mb(wildcards, attempt):
    """Memory (MB) of one ``scale_run`` job: 0.6 GB (the interpreter and libraries, with a
    margin) plus 2 KB per grid point, more on a retry (benchmarks/README.md has the peaks
    behind these constants)."""
    return int(600 + 0.002 * _n_points(wildcards)) * attempt


def scale_runtime(wildcards, attempt):
    """Minutes of one ``scale_run`` job: 5 plus 0.6 ms per grid point, more on a retry (a wide
    margin over the times in benchmarks/README.md)."""
    return int(5 + _n_points(wildcards) / 100_000) * attempt


# --------------------------------------------------------------------------- child process


def main(argv=None):
    """Child side of :func:`measure`: one measurement, printed as a tagged JSON line."""
    ap = argparse.ArgumentParser(prog="python -m trivsel.study.scaling", description=__doc__.split("\n\n")[0])
    ap.add_argument("--method", required=True, choices=SCALE_METHODS)
    ap.add_argument("--n", type=int, required=True)
    ap.add_argument("--function", type=int, default=4)
    ap.add_argument("--fraction", type=float, default=0.1)
    ap.add_argument("--warmup-n", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    res = run_here(a.method, a.n, function=a.function, fraction=a.fraction, warmup_n=a.warmup_n, seed=a.seed,
                   threads=a.threads)
    print(_RESULT_TAG + json.dumps(res), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
