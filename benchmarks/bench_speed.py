#!/usr/bin/env python
"""Speed of trivsel.reduce beside VTK's tetrahedral quadric decimation.

Cases (same grid, same vertex budget, same process):

* the five Table-1 functions on the paper's 17^3 grid (n = 16) reduced to 50 %;
* f4 (exponential) on 33^3 (n = 32) and 65^3 (n = 64) reduced to 10 %
  (skipped with ``--quick``).

trivsel: one warm-up call per case (the very first one includes numba JIT
compilation, reported separately), then the median of ``--repeats`` timed calls
of ``trivsel.reduce(sample_grid(f, n), fractions=[fraction])``.

VTK: ``vtkUnstructuredGridQuadricDecimation`` of the Kuhn tetrahedralisation of
the same grid, asked for ``N - n_selected`` edge collapses so it keeps about as
many vertices as trivsel selected; one warm-up, then the median of ``--repeats``
runs (seeds 1, 2, ...).  VTK time = building the input grid + the filter.

Prints a table and writes ``benchmarks/results/bench_speed_<timestamp>.csv``.

Usage::

    python benchmarks/bench_speed.py            # all cases
    python benchmarks/bench_speed.py --quick    # 17^3 only
    python benchmarks/bench_speed.py --repeats 5
    python benchmarks/bench_speed.py --vtk-only # VTK half alone (budget = fraction * N)
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import statistics
import sys
import time
import traceback
from pathlib import Path

import numpy as np

import trivsel
from trivsel.study.baselines import tet_grid, vtk_quadric_decimation
from trivsel.data import sample_grid

TARGET_17 = 15.0  # seconds, all five functions on 17^3 to 50 %
RESULTS = Path(__file__).resolve().parent / "results"


class TrivselFailed(RuntimeError):
    pass


def run_trivsel(data, fraction):
    """One timed call of trivsel.reduce; returns (wall seconds, n_selected, timings dict)."""
    t0 = time.perf_counter()
    try:
        res = trivsel.reduce(data, fractions=[fraction])
    except Exception as exc:  # noqa: BLE001 - report any failure clearly, then stop
        raise TrivselFailed(f"trivsel.reduce(sample_grid({data.name}, {data.meta.get('n')}), "
                            f"fractions=[{fraction}]) raised {type(exc).__name__}: {exc}") from exc
    wall = time.perf_counter() - t0
    try:
        snap = res.snapshots[0]
        n_sel = int(snap.n_selected)
        timings = dict(getattr(res, "timings", {}) or {})
    except Exception as exc:  # noqa: BLE001
        raise TrivselFailed(f"trivsel.reduce returned an object without the expected "
                            f".snapshots[0].n_selected / .timings: {type(exc).__name__}: {exc}") from exc
    return wall, n_sel, timings


def run_vtk(data, n_target, repeats):
    """VTK decimation to about n_target vertices: warm-up + repeats; returns per-run lists."""
    n_edges = data.n_points - int(n_target)
    vtk_quadric_decimation(data, n_edges=n_edges, seed=0)  # warm-up
    totals, filt, verts = [], [], []
    for r in range(repeats):
        t0 = time.perf_counter()
        grid = tet_grid(data)
        build = time.perf_counter() - t0
        dm = vtk_quadric_decimation(data, n_edges=n_edges, seed=r + 1, grid=grid)
        totals.append(build + dm.seconds)
        filt.append(dm.seconds)
        verts.append(dm.n_vertices)
    return totals, filt, verts


def fmt(x, nd=3):
    return "-" if x is None else f"{x:.{nd}f}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="only the five functions on 17^3")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per case (median reported; default 3)")
    ap.add_argument("--vtk-only", action="store_true",
                    help="skip trivsel (VTK budget = round(fraction * N)); for checking the VTK half")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error("--repeats must be >= 1")

    cases = [(f, 16, 0.5) for f in range(1, 6)]
    if not args.quick:
        cases += [(4, 32, 0.1), (4, 64, 0.1)]

    import vtk

    print(f"# bench_speed  python {platform.python_version()}  numpy {np.__version__}  "
          f"vtk {vtk.vtkVersion.GetVTKVersion()}  trivsel {trivsel.__version__}  "
          f"cpus {os.cpu_count()}  load {os.getloadavg()[0]:.2f}  repeats {args.repeats}")

    rows = []
    first_call = None
    try:
        for f, n, frac in cases:
            data = sample_grid(f, n)
            N = data.n_points
            row = dict(function=f, n=n, grid=f"{n + 1}^3", n_points=N, fraction=frac,
                       loadavg_1min=round(os.getloadavg()[0], 2))
            if args.vtk_only:
                n_sel = int(round(frac * N))
                row.update(n_selected=n_sel, trivsel_s=None, trivsel_min_s=None, trivsel_max_s=None,
                           trivsel_warmup_s=None)
            else:
                warm, n_sel, _ = run_trivsel(data, frac)
                if first_call is None:
                    first_call = (warm, f, n)
                walls, tims = [], []
                for _ in range(args.repeats):
                    w, n_sel, tm = run_trivsel(data, frac)
                    walls.append(w)
                    tims.append(tm)
                row.update(n_selected=n_sel, trivsel_s=statistics.median(walls), trivsel_min_s=min(walls),
                           trivsel_max_s=max(walls), trivsel_warmup_s=warm)
                for key in sorted({k for tm in tims for k in tm}):
                    vals = [tm[key] for tm in tims if isinstance(tm.get(key), (int, float))]
                    if vals:
                        row[f"trivsel_timing_{key}_s"] = statistics.median(vals)
            totals, filt, verts = run_vtk(data, row["n_selected"], args.repeats)
            row.update(vtk_s=statistics.median(totals), vtk_min_s=min(totals), vtk_max_s=max(totals),
                       vtk_filter_s=statistics.median(filt), vtk_n_vertices=int(statistics.median(verts)))
            row["ratio_trivsel_over_vtk"] = (row["trivsel_s"] / row["vtk_s"]) if row["trivsel_s"] else None
            rows.append(row)
            print(f"  done f{f} {n + 1}^3 -> {frac:.0%}", file=sys.stderr, flush=True)
    except TrivselFailed as exc:
        print(f"\nERROR: {exc}", file=sys.stderr)
        traceback.print_exception(exc.__cause__, file=sys.stderr, limit=-3)
        print("The trivsel half of the benchmark cannot run; `--vtk-only` times VTK alone.", file=sys.stderr)
        return 1

    # table
    head = (f"{'case':<14}{'N':>8}{'frac':>6}{'n_sel':>7}  {'trivsel s':>10} {'[min-max]':>15}"
            f"  {'VTK n':>6} {'VTK s':>8} {'[min-max]':>15}  {'trivsel/VTK':>11}")
    print(head)
    print("-" * len(head))
    for r in rows:
        tr = (f"{fmt(r['trivsel_s']):>10} [{fmt(r['trivsel_min_s'])}-{fmt(r['trivsel_max_s'])}]"
              if r["trivsel_s"] is not None else f"{'-':>10} {'':>15}")
        ratio = f"{r['ratio_trivsel_over_vtk']:.1f}x" if r["ratio_trivsel_over_vtk"] else "-"
        print(f"{'f%d %s' % (r['function'], r['grid']):<14}{r['n_points']:>8}{r['fraction']:>6.0%}"
              f"{r['n_selected']:>7}  {tr:>26}  {r['vtk_n_vertices']:>6} {fmt(r['vtk_s']):>8} "
              f"[{fmt(r['vtk_min_s'])}-{fmt(r['vtk_max_s'])}]  {ratio:>11}")
    print()
    paper = [r for r in rows if r["n"] == 16]
    vtk_total = sum(r["vtk_s"] for r in paper)
    if not args.vtk_only:
        total = sum(r["trivsel_s"] for r in paper)
        verdict = "OK" if total <= TARGET_17 else "OVER TARGET"
        print(f"all five functions on 17^3 to 50%: trivsel {total:.2f} s (target {TARGET_17:.0f} s: {verdict}), "
              f"VTK {vtk_total:.3f} s")
        if first_call is not None:
            warm, f, n = first_call
            steady = next(r["trivsel_s"] for r in rows if r["function"] == f and r["n"] == n)
            print(f"first trivsel call (f{f} {n + 1}^3, includes numba JIT compile): {warm:.2f} s; "
                  f"compile overhead ~ {warm - steady:.2f} s (excluded from the medians)")
    else:
        print(f"all five functions on 17^3 to 50%: VTK {vtk_total:.3f} s (trivsel skipped: --vtk-only)")
    print("ratio = median trivsel wall time / median VTK time (input grid build + filter); "
          ">1 means trivsel is slower")

    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / f"bench_speed_{time.strftime('%Y%m%d-%H%M%S')}.csv"
    keys = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow(r)
    if first_call is not None:
        with open(out, "a") as fh:
            fh.write(f"# first_call_s={first_call[0]:.4f} (f{first_call[1]}, n={first_call[2]}, includes JIT)\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
