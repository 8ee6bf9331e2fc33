#!/usr/bin/env python
"""trivsel against VTK's tetrahedral decimation on real volumes, like for like.

Rows: three real volumes that ship inside the nilearn and dipy wheels and two synthetic
hard signals, each reduced to 10 % and 5 % of its points.

* ``icbm152``: the ICBM152 2009a T1 template (nilearn), central 48^3 crop, 1 mm, 0-255;
* ``statmap``: nilearn's ``image_10426.nii.gz``, a signed statistical map, 53x63x46, 3 mm;
* ``aniso``: dipy's ``aniso_vox.nii.gz``, an anatomical scan, 58x58x24, 4x4x5 mm.  Its affine
  is a rotation times diag(4, 4, 5) (oblique, which ``trivsel.load`` refuses); the grid is
  laid out along the voxel axes with that spacing, a rigid motion of the scanner frame, so
  every distance, E_RMS and E_inf is what it would be in world coordinates;
* ``chirp`` (synthetic, oscillatory): ``sin(5 pi |x|^2)`` on the 48^3 grid over [-1, 1]^3,
  up to about 2.3 radians per sample at the corners;
* ``steps`` (synthetic, sharp edges): a box turned about an oblique axis, a ball overlapping it and
  an oblique planar cut through the ball (steps of +1, +1 and -1.5, no face aligned with the grid)
  on a smooth background ``0.3 sin(2.5 x + 1.1) cos(2 y - 0.4) cos(1.7 z + 0.3)``, on the 48^3 grid.
  (Without the background, or with grid-aligned faces, both trivsel and VTK reproduce such a volume
  exactly (to float32 rounding) from 5-10 % of its points, which measures nothing.)

For each row and kept fraction:

* **VTK** (``vtkUnstructuredGridQuadricDecimation``, :mod:`trivsel.study.baselines`) is run the way
  that favours it.  Both tet splits a user reaches for (pyvista's ``ImageData.triangulate()``, 5 tets
  per cell; the Kuhn split, 6) and several weights of the value in VTK's 4-D quadric (``scalar_scale``:
  the raw values, and the values rescaled so that their range is 1, 0.3, 0.1 or 0.03 times the
  domain's largest extent) are screened with seed 0; each split keeps its best weight and is run
  again with seeds 1 .. repeats-1; the split with the lower median E_RMS is kept.  VTK stops after
  ``N - K`` edge collapses (``SetNumberOfEdgesToDecimate``; ``--vtk-stop target``:
  ``SetTargetReduction(1 - fraction)``) so both splits land on the kept count (less any orphaned
  vertex) and are compared at equal size (a setting with which VTK stops more than 1 % above the
  count, when no further collapse is allowed, does not compete).  Points outside VTK's decimated
  mesh (its boundary moves in) take the value of the mesh at the nearest point of its boundary
  surface: nothing is dropped.  E_RMS and E_inf are over all original voxels; the medians of the
  runs are shown.
* **VTK + refit**: VTK's meshes with their vertex values refitted by least squares to all voxels
  (the same linear evaluation as above: barycentric weights in the containing tet, the nearest
  boundary triangle's weights outside), median over the runs.
* **trivsel** ``decimate``, ``greedy`` and ``paper`` at VTK's vertex count (``count=`` the median count
  of VTK's runs), with data values and with fitted values (``values=["data", "fit"]``); greedy stops
  earlier only if every residual is zero (``<method>_n_selected`` in the CSV).
* **vertex ratio** (``decimate`` and ``greedy``): the number of vertices the method (fit values) needs to
  reach VTK + refit's E_RMS, divided by VTK's count: one run with snapshots at K * 4^(j/8) (or
  K / 4^(j/8) when the method already wins at K), then one run with 8 snapshots inside the bracket that
  the first crossing fell in; the smallest count of that grid that reaches the target (resolution about
  2 % of the count).  Capped at 4 (">4"), floored at 1/4 ("<0.25").
* **Delaunay + fit**: the same selected points, plain Delaunay tetrahedra, fitted values, to show
  what the data-dependent mesh is worth under fitted values.

Times: trivsel's is ``reduce``'s total minus its error evaluation and fits (curvature, start mesh,
insertion and swapping), the median of ``--repeats`` calls after a warm-up; VTK's is the filter's
``Update()`` alone (building its input grid excluded), the median of its runs.

    python benchmarks/bench_realdata.py                        # all rows (about 30 min on 2 cores)
    python benchmarks/bench_realdata.py --quick                # 16^3 crops, for a smoke test
    python benchmarks/bench_realdata.py --volumes statmap chirp --fractions 0.1 --repeats 3

The real volumes need nilearn and dipy (``pip install -e '.[realdata]'``); the script reads the files
from the installed packages and never imports them.  Prints one markdown table of ratios and a table of
details; writes all measurements to ``benchmarks/results/bench_realdata_<timestamp>.csv``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

# The library part (volumes, VTK runs, scoring, tables) is trivsel.study.realdata; this file is
# the command line.
from trivsel.study.realdata import (
    ALL_VOLUMES,
    HELD_OUT,
    METHODS,
    QUICK_SIZE,
    SYNTHETIC,
    VOLUMES,
    MissingExtra,
    load_volume,
    measure,
    missing_message,
    tables,
    warm_up,
    write_csv,
)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--volumes", nargs="+", default=list(VOLUMES), choices=ALL_VOLUMES,
                    help=f"default: {' '.join(VOLUMES)}; held out (not tuned on): {' '.join(HELD_OUT)}")
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.1, 0.05])
    ap.add_argument("--repeats", type=int, default=3, help="VTK seeds per split; trivsel timing calls (default 3)")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--vtk-stop", choices=["edges", "target"], default="edges",
                    help="SetNumberOfEdgesToDecimate(N - K) (default) or SetTargetReduction(1 - fraction)")
    ap.add_argument("--quick", action="store_true", help=f"{QUICK_SIZE}^3 crops of every volume (smoke test)")
    ap.add_argument("--out", type=Path, default=None, help="CSV path (default benchmarks/results/...)")
    a = ap.parse_args(argv)
    missing = missing_message(a.volumes, "run only --volumes " + " ".join(SYNTHETIC))
    if missing:
        raise SystemExit(f"bench_realdata: {missing}")
    warm_up(a.methods)  # load (or compile) the numba kernels before any timing
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out = a.out or Path(__file__).resolve().parent / "results" / f"bench_realdata_{stamp}.csv"
    rows = []
    t0 = time.perf_counter()
    for name in a.volumes:
        try:
            data = load_volume(name, a.quick)
        except MissingExtra as exc:
            raise SystemExit(f"bench_realdata: {exc}") from None
        print(f"{name}: {data.shape} points, spacing {tuple(float(s) for s in data.spacing)}, "
              f"values {data.values.min():.4g} .. {data.values.max():.4g}"
              + (f", {data.meta['frame']}" if "frame" in data.meta else ""), flush=True)
        for f in sorted(a.fractions, reverse=True):
            print(f"  kept {100 * f:g} %", flush=True)
            rows.append(measure(data, f, repeats=a.repeats, methods=a.methods, stop=a.vtk_stop,
                                say=lambda s: print(s, flush=True)))
            write_csv(rows, out)
    ratios, details = tables(rows, a.methods)
    print(f"\nratios (trivsel / VTK at VTK's vertex count; E_RMS and E_inf over all voxels; "
          f"{time.perf_counter() - t0:.0f} s in all)\n")
    print(ratios)
    print("\ndetails\n")
    print(details)
    print(f"\nCSV: {out}")


if __name__ == "__main__":
    main()
