#!/usr/bin/env python
"""Scaling targets: trivsel's paper and greedy methods against VTK's decimation as the grid grows.

Function 4 (exponential) reduced to 10 % of its points:

* 17^3, 33^3 and 65^3: trivsel ``paper``, trivsel ``greedy`` and VTK's
  ``vtkUnstructuredGridQuadricDecimation`` to the same vertex count, each the
  median of ``--repeats`` measurements (repeats interleaved over the methods),
  with the ratio trivsel/VTK of time and of peak memory;
* 129^3: ``greedy`` once (skipped with ``--quick``), against the target of
  10 minutes and 8 GiB;
* the fitted slopes of log(time) and log(peak memory) against log(points).

Every measurement is :func:`trivsel.study.scaling.measure`: a fresh Python process
that first does an untimed warm-up run of the same method on the 5^3 grid (so
numba compilation and VTK loading are not timed), then times one run; peak
memory is the peak resident set size of that process during the timed run
(interpreter and libraries included).

Prints a table and the targets, writes ``benchmarks/results/bench_scale_<timestamp>.csv``.

Usage::

    python benchmarks/bench_scale.py --quick       # 17^3 to 65^3 only (a few minutes)
    python benchmarks/bench_scale.py               # plus greedy on 129^3
    python benchmarks/bench_scale.py --repeats 5
    python benchmarks/bench_scale.py --quick --threads 2   # curvature fits on 2 threads
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import pandas as pd

import trivsel
from trivsel.study.scaling import TARGETS, fit_slopes, measure, ratios, scaling_table, target_lines

RESULTS = Path(__file__).resolve().parent / "results"
METHODS = ("paper", "greedy", "vtk")


def _load():
    try:
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="skip greedy on 129^3")
    ap.add_argument("--repeats", type=int, default=3, help="measurements per method and size (median; default 3)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[16, 32, 64],
                    help="grid intervals n of the method comparison (default 16 32 64)")
    ap.add_argument("--big-n", type=int, default=TARGETS["big_n"], help="grid of the single greedy run (128)")
    ap.add_argument("--function", type=int, default=4)
    ap.add_argument("--fraction", type=float, default=0.1)
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds before a measurement is killed")
    ap.add_argument("--threads", type=int, default=1,
                    help="trivsel's --threads (curvature fits; default 1, like VTK's single-threaded filter)")
    args = ap.parse_args(argv)

    import numba
    import vtk

    print(f"python {platform.python_version()}  numpy {__import__('numpy').__version__}  numba {numba.__version__}"
          f"  vtk {vtk.vtkVersion.GetVTKVersion()}  trivsel {trivsel.__version__}  cpus {os.cpu_count()}")
    print(f"function {args.function} to {100 * args.fraction:g} %; trivsel threads {args.threads}; "
          f"each cell: median of {args.repeats} fresh "
          f"processes (untimed warm-up run on 5^3 first); peak = resident peak of the timed run\n")

    rows = []
    t_start = time.perf_counter()
    try:
        for n in args.sizes:
            for rep in range(args.repeats):
                for m in METHODS:
                    load = _load()
                    r = measure(m, n, function=args.function, fraction=args.fraction, timeout=args.timeout,
                                threads=args.threads)
                    r.update(repeat=rep, loadavg_1min=load)
                    rows.append(r)
                    print(f"  {m:>6} {n + 1}^3 run {rep + 1}/{args.repeats}: {r['seconds']:8.3f} s "
                          f"{r['peak_mb']:7.0f} MiB  (load {load:.2f})", flush=True)
        if not args.quick:
            n = args.big_n
            load = _load()
            print(f"  greedy {n + 1}^3 (once) ...", flush=True)
            r = measure("greedy", n, function=args.function, fraction=args.fraction, timeout=args.timeout,
                        threads=args.threads)
            r.update(repeat=0, loadavg_1min=load)
            rows.append(r)
            print(f"  greedy {n + 1}^3: {r['seconds']:8.1f} s {r['peak_mb']:7.0f} MiB  (load {load:.2f})")
    except RuntimeError as exc:
        print(f"ERROR: {exc}", file=sys.stderr)
        return 1

    raw = pd.DataFrame(rows)
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / f"bench_scale_{time.strftime('%Y%m%d_%H%M%S')}.csv"
    raw.to_csv(out, index=False, float_format="%.6g")

    table = scaling_table(raw)
    spread = raw.groupby(["method", "n"])["seconds"].agg(["min", "max"])
    rat = ratios(table).set_index(["method", "n"])
    print(f"\n{'grid':>6} {'points':>9} {'method':>7} {'kept':>7} {'seconds [min-max]':>26} {'peak MiB':>9} "
          f"{'time/VTK':>9} {'mem/VTK':>8}")
    for _, r in table.iterrows():
        lo, hi = spread.loc[(r["method"], r["n"])]
        key = (r["method"], r["n"])
        tr = f"{rat.loc[key, 'ratio_seconds']:.2f}" if key in rat.index else "-"
        mr = f"{rat.loc[key, 'ratio_peak_mb']:.2f}" if key in rat.index else "-"
        print(f"{r['n'] + 1:>4}^3 {r['n_points']:>9} {r['method']:>7} {r['n_selected']:>7} "
              f"{r['seconds']:>10.3f} [{lo:.3f}-{hi:.3f}] {r['peak_mb']:>9.0f} {tr:>9} {mr:>8}")

    # slopes over the sizes every method was measured at (like for like), and greedy with 129^3
    common = table[table["n"].isin(args.sizes)]
    slopes = fit_slopes(common, ("seconds", "peak_mb", "extra_mb"))
    print(f"\nfitted slopes of log y against log points over {', '.join(f'{n + 1}^3' for n in args.sizes)} "
          f"(slope_last: between the two largest):")
    wide = slopes.pivot(index="method", columns="quantity", values="slope").reindex(METHODS)
    last = slopes.pivot(index="method", columns="quantity", values="slope_last").reindex(METHODS)
    print(f"{'method':>8} {'time':>6} {'(last)':>7} {'peak mem':>9} {'mem above base':>15}")
    for m in METHODS:
        if m in wide.index and pd.notna(wide.loc[m, "seconds"]):
            print(f"{m:>8} {wide.loc[m, 'seconds']:>6.2f} {last.loc[m, 'seconds']:>7.2f} "
                  f"{wide.loc[m, 'peak_mb']:>9.2f} {wide.loc[m, 'extra_mb']:>15.2f}")
    if not args.quick:
        g = fit_slopes(table[table["method"] == "greedy"], ("seconds", "peak_mb")).set_index("quantity")
        print(f"  greedy including {args.big_n + 1}^3: time {g.loc['seconds', 'slope']:.2f} "
              f"(last {g.loc['seconds', 'slope_last']:.2f}), peak memory {g.loc['peak_mb', 'slope']:.2f} "
              f"(last {g.loc['peak_mb', 'slope_last']:.2f})")

    print("\ntargets:")
    for line in target_lines(table, slopes, ratios(table)):
        print("  " + line.replace("**", "").lstrip("- "))
    print(f"\n{len(raw)} measurements in {time.perf_counter() - t_start:.0f} s; load average now "
          f"{_load():.2f}; wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
