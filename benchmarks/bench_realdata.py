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
import csv
import importlib.util
import os
import statistics
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

import trivsel
from trivsel.data import grid_from_array
from trivsel.selection import count_for_fraction
from trivsel.study.baselines import _locate, errors_at_points, tet_grid, vtk_quadric_decimation
from trivsel.triangulation import delaunay_tetrahedra

#: volume name -> (package, path inside the package, central crop edge or None for the whole volume)
REAL = {
    "icbm152": ("nilearn", "datasets/data/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz", 48),
    "statmap": ("nilearn", "datasets/data/image_10426.nii.gz", None),
    "aniso": ("dipy", "data/files/aniso_vox.nii.gz", None),
}
SYNTHETIC = ("chirp", "steps")
VOLUMES = tuple(REAL) + SYNTHETIC
SPLITS = ("pv5", "kuhn6")
#: weights of the value in VTK's quadric: "raw" = the values as they are; a number r = values scaled so
#: that their range is r times the largest extent of the domain
SCALES = ("raw", 1.0, 0.3, 0.1, 0.03)
QUICK_SIZE = 16
METHODS = ("decimate", "greedy", "paper")
#: the methods whose vertex ratio (vertices to reach VTK + refit's E_RMS) is searched
RATIO_METHODS = ("decimate", "greedy")


# --------------------------------------------------------------------------- volumes


def package_file(package, relpath):
    """Path of a data file inside an installed package, without importing the package (None if absent)."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        return None
    p = Path(list(spec.submodule_search_locations)[0]) / relpath
    return p if p.exists() else None


def missing_packages(volumes):
    need = sorted({REAL[v][0] for v in volumes if v in REAL})
    return [p for p in need if importlib.util.find_spec(p) is None]


def central_crop(data, size):
    """The central ``size``^3 block of grid data (each axis cropped to at most ``size``), geometry kept."""
    if size is None:
        return data
    a = data.values.reshape(data.shape)
    start = [max((s - size) // 2, 0) for s in data.shape]
    block = a[tuple(slice(b, b + size) for b in start)]
    return grid_from_array(block, data.origin + np.asarray(start) * data.spacing, data.spacing, name=data.name)


def load_nifti(path, name):
    """A NIfTI volume as grid data: ``trivsel.load`` (exact world geometry) when it accepts the file;
    an oblique affine that is a rotation times a diagonal is laid out along the voxel axes with the
    diagonal as spacing (a rigid motion of the world frame: distances and errors are unchanged)."""
    import nibabel as nib

    try:
        d = trivsel.load(path)
        d.meta["frame"] = "world"
    except trivsel.InputError as exc:
        if "oblique" not in str(exc):
            raise
        img = nib.load(str(path))
        A = np.asarray(img.affine, float)[:3, :3]
        zooms = np.linalg.norm(A, axis=0)
        if np.abs((A / zooms).T @ (A / zooms) - np.eye(3)).max() > 1e-5:
            raise SystemExit(f"bench_realdata: {path} has a sheared affine; it cannot be laid out rigidly")
        d = grid_from_array(np.asarray(img.get_fdata(dtype=np.float64)), (0.0, 0.0, 0.0), zooms)
        d.meta["frame"] = "voxel axes (oblique affine's rotation removed)"
    d.name = name
    return d


def synthetic(name, n=48):
    """The two synthetic hard signals on an n^3 grid over [-1, 1]^3."""
    t = np.linspace(-1.0, 1.0, n)
    x, y, z = np.meshgrid(t, t, t, indexing="ij")
    if name == "chirp":
        f = np.sin(5.0 * np.pi * (x * x + y * y + z * z))
    elif name == "steps":
        # a box turned about an oblique axis, a ball overlapping it and an oblique planar cut through
        # the ball (steps +1, +1, -1.5), on a smooth background that needs vertices of its own
        R = np.array([[0.8660254, -0.4330127, 0.25], [0.5, 0.75, -0.4330127], [0.0, 0.5, 0.8660254]])
        u = np.einsum("ij,j...->i...", R, np.stack([x + 0.05, y - 0.03, z + 0.02]))
        box = (np.abs(u[0]) < 0.6) & (np.abs(u[1]) < 0.5) & (np.abs(u[2]) < 0.45)
        ball = (x - 0.25) ** 2 + (y + 0.2) ** 2 + (z - 0.15) ** 2 < 0.42 ** 2
        cut = ball & (0.6 * x - 0.5 * y + 0.62 * z > 0.12)
        smooth = 0.3 * np.sin(2.5 * x + 1.1) * np.cos(2.0 * y - 0.4) * np.cos(1.7 * z + 0.3)
        f = smooth + box + ball - 1.5 * cut
    else:
        raise ValueError(f"unknown synthetic volume {name!r}")
    return grid_from_array(f, (-1.0, -1.0, -1.0), np.full(3, 2.0 / (n - 1)), name=name)


def load_volume(name, quick=False):
    if name in SYNTHETIC:
        return synthetic(name, QUICK_SIZE if quick else 48)
    package, rel, crop = REAL[name]
    path = package_file(package, rel)
    if path is None:
        raise SystemExit(f"bench_realdata: {rel} not found in the installed {package}; "
                         "install the extra: pip install -e '.[realdata]'")
    return central_crop(load_nifti(path, name), QUICK_SIZE if quick else crop)


# --------------------------------------------------------------------------- evaluation as a matrix


def _nearest_boundary_weights(P, T, Q):
    """Vertices and weights of the closest point of the mesh's boundary surface, and its distance
    (as ``trivsel.study.baselines.evaluate_mesh_at_points`` evaluates outside points)."""
    from trivsel.study.baselines import closest_on_boundary

    return closest_on_boundary(P, T, Q)


def mesh_operator(mesh_points, tets, query_points, bary_tol=1e-9):
    """Sparse ``A`` (queries x vertices) with ``A @ vertex_values`` = the mesh's piecewise-linear
    interpolant at the queries; a query outside the mesh gets the interpolant at the closest point
    of the boundary surface.  Returns ``(A, outside_mask, distance)``."""
    P = np.asarray(mesh_points, float)
    T = np.asarray(tets, np.int64)
    Q = np.asarray(query_points, float)
    tet, bary, inside = _locate(P, T, Q, bary_tol)
    ins = np.flatnonzero(inside)
    rows, cols, vals = [np.repeat(ins, 4)], [T[tet[ins]].ravel()], [bary[ins].ravel()]
    out = np.flatnonzero(~inside)
    dist = np.zeros(Q.shape[0])
    if out.size:
        idx, w, d = _nearest_boundary_weights(P, T, Q[out])
        rows.append(np.repeat(out, 3))
        cols.append(idx.ravel())
        vals.append(w.ravel())
        dist[out] = d
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(Q.shape[0], P.shape[0]))
    return A, ~inside, dist


def least_squares_values(A, f, v0):
    """Vertex values minimising ``|A v - f|^2`` (normal equations, sparse direct solve).  A vertex no
    query depends on keeps its value in ``v0``; a ridge of 1e-12 of the largest diagonal entry toward
    ``v0`` keeps a rank-deficient system solvable without moving the solution measurably."""
    AtA = (A.T @ A).tocsc()
    rhs = A.T @ np.asarray(f, float)
    lam = 1e-12 * max(float(AtA.diagonal().max()), 1e-300)
    return spsolve(AtA + lam * sp.identity(AtA.shape[0], format="csc"), rhs + lam * np.asarray(v0, float))


def score(A, f, v):
    e = errors_at_points(f, A @ v)
    return {"E_rms": e["E_rms"], "E_inf": e["E_inf"]}


# --------------------------------------------------------------------------- VTK


def vtk_input(data, split, scale):
    """VTK's input mesh with the values times ``scale`` as scalars ``f``."""
    if split == "kuhn6":
        return tet_grid(data, scalar_scale=scale)
    import pyvista as pv

    img = pv.ImageData(dimensions=data.shape, spacing=tuple(data.spacing), origin=tuple(data.origin))
    img.point_data["f"] = data.values.reshape(data.shape).ravel(order="F") * scale  # VTK order: x fastest
    grid = img.triangulate()
    grid.point_data.active_scalars_name = "f"
    return grid


def absolute_scale(data, scale):
    if scale == "raw":
        return 1.0
    rng = float(np.ptp(data.values))
    return float(scale) * float(np.ptp(data.points, axis=0).max()) / rng if rng > 0 else 1.0


def vtk_run(data, grid, K, fraction, scale, seed, stop, refit=False):
    """One decimation, scored at every voxel (and refitted)."""
    if stop == "edges":
        dm = vtk_quadric_decimation(data, n_edges=data.n_points - K, grid=grid, seed=seed, scalar_scale=scale)
    else:
        dm = vtk_quadric_decimation(data, target_reduction=1.0 - fraction, grid=grid, seed=seed,
                                    scalar_scale=scale)
    A, out, dist = mesh_operator(dm.points, dm.tets, data.points)
    r = {"seed": seed, "n_vertices": dm.n_vertices, "n_orphans": dm.n_orphans, "seconds": dm.seconds,
         "n_outside": int(out.sum()), "max_outside_distance": float(dist.max()), **score(A, data.values, dm.values)}
    if refit:
        v = least_squares_values(A, data.values, dm.values)
        e = score(A, data.values, v)
        r.update(refit_E_rms=e["E_rms"], refit_E_inf=e["E_inf"])
    return r


def run_vtk(data, fraction, *, repeats=3, splits=SPLITS, scales=SCALES, stop="edges", seed=0, say=print):
    """VTK's best setting for this row: per split the best value weight (seed 0), then ``repeats`` seeds."""
    K = count_for_fraction(fraction, data.n_points)

    def landed(n):
        """In edges mode a setting competes only if VTK reached the count (a run that stops early,
        when no further collapse is allowed, keeps more vertices and would win on that alone)."""
        return stop != "edges" or n <= K + max(3, 0.01 * K)

    per_split = {}
    screen = []
    for split in splits:
        tried = []
        for s in scales:
            abs_s = absolute_scale(data, s)
            grid = vtk_input(data, split, abs_s)
            r = vtk_run(data, grid, K, fraction, abs_s, seed, stop, refit=True)
            r.update(split=split, scale=s, abs_scale=abs_s, grid=grid)
            tried.append(r)
            screen.append({k: v for k, v in r.items() if k != "grid"})
        best = min([r for r in tried if landed(r["n_vertices"])] or tried, key=lambda r: r["E_rms"])
        runs = [best] + [vtk_run(data, best["grid"], K, fraction, best["abs_scale"], seed + k, stop, refit=True)
                         for k in range(1, int(repeats))]
        med = {k: float(np.median([r[k] for r in runs])) for k in
               ("E_rms", "E_inf", "refit_E_rms", "refit_E_inf", "seconds", "n_vertices", "n_outside",
                "max_outside_distance")}
        raw = next((r for r in tried if r["scale"] == "raw"), None)
        per_split[split] = {**med, "split": split, "scale": best["scale"], "abs_scale": best["abs_scale"],
                            "runs": len(runs), "n_vertices_all": [r["n_vertices"] for r in runs],
                            "raw_E_rms": raw["E_rms"] if raw else float("nan")}
        say(f"    vtk {split}: weight {best['scale']} ({best['abs_scale']:.3g}), median of {len(runs)}: "
            f"{int(med['n_vertices'])} vertices, E_RMS {med['E_rms']:.4g} (refit {med['refit_E_rms']:.4g}), "
            f"E_inf {med['E_inf']:.4g}, {med['seconds']:.2f} s, {int(med['n_outside'])} voxels outside; "
            "screen " + ", ".join(f"{r['scale']}: {r['E_rms']:.4g}" for r in tried))
    splits_ok = [r for r in per_split.values() if landed(r["n_vertices"])] or list(per_split.values())
    best = min(splits_ok, key=lambda r: r["E_rms"])
    return {**best, "K_nominal": K, "splits": per_split, "screen": screen}


# --------------------------------------------------------------------------- trivsel


def run_trivsel(data, method, count, repeats=3):
    """``reduce(count=...)`` with data and fitted values; the time is the median over ``repeats`` calls of
    the total minus the error evaluation and fits (results are deterministic: taken from the first)."""
    times, first = [], None
    for k in range(max(1, int(repeats))):
        r = trivsel.reduce(data, count=int(count), method=method, values=["data", "fit"] if k == 0 else ["data"])
        times.append(r.timings["total"] - r.timings["errors"])
        first = first or r
    s = first.snapshots[-1]
    return {"n_selected": int(s.n_selected), "selected": np.asarray(s.selected), "tets": np.asarray(s.tets),
            "E_rms": s.errors["E_rms"], "E_inf": s.errors["E_inf"],
            "fit_E_rms": s.fit["errors"]["E_rms"], "fit_E_inf": s.fit["errors"]["E_inf"],
            "seconds": float(statistics.median(times)), "seconds_all": times}


def delaunay_fit(data, selected):
    """E_RMS and E_inf of plain Delaunay tetrahedra of the selected points with least-squares values."""
    sel = np.unique(np.asarray(selected, np.int64))
    P = data.points[sel]
    A, _, _ = mesh_operator(P, delaunay_tetrahedra(P), data.points)
    return score(A, data.values, least_squares_values(A, data.values, data.values[sel]))


def _fit_errors(data, method, counts):
    counts = sorted({int(c) for c in counts})
    r = trivsel.reduce(data, count=counts[-1], fractions=[c / data.n_points for c in counts[:-1]],
                       method=method, values=["fit"])
    return {int(s.n_selected): s.fit["errors"]["E_rms"] for s in r.snapshots}


def vertex_ratio(data, K, target, e_at_K, cap=4.0, steps=8, method="greedy"):
    """Smallest count (over the search grid) at which ``method`` with fitted values reaches E_RMS <= target,
    divided by K; ``inf`` above ``cap``, 0 below ``1 / cap``.  Returns ``(ratio, count, grid errors)``."""
    N = data.n_points
    lo_limit = 9  # above the 8 corners
    if e_at_K <= target:
        down = [max(lo_limit, round(K * cap ** (-j / steps))) for j in range(1, steps + 1)]
        e = _fit_errors(data, method, down)
        e[K] = e_at_K
        grid = sorted(e, reverse=True)
        fail = next((c for c in grid if e[c] > target), None)
        if fail is None:
            return 0.0, None, e
        hi = min(c for c in grid if c > fail)
        lo = fail
    else:
        up = [min(N, round(K * cap ** (j / steps))) for j in range(1, steps + 1)]
        e = _fit_errors(data, method, up)
        e[K] = e_at_K
        grid = sorted(e)
        hit = next((c for c in grid if e[c] <= target), None)
        if hit is None:
            return float("inf"), None, e
        hi = hit
        lo = max(c for c in grid if c < hit)
    inner = sorted({int(round(lo + (hi - lo) * j / (steps + 1))) for j in range(1, steps + 1)} - {lo, hi})
    if inner:
        e.update(_fit_errors(data, method, inner))
    for c in sorted(c for c in e if lo < c <= hi):
        if e[c] <= target:
            return c / K, c, e
    return hi / K, hi, e  # pragma: no cover - hi met the target


# --------------------------------------------------------------------------- one row


def _div(a, b):
    """a / b, with 0 / 0 = 1 (both exact) and a / 0 = inf."""
    if b == 0:
        return 1.0 if a == 0 else float("inf")
    return a / b


def measure(data, fraction, *, repeats=3, methods=METHODS, splits=SPLITS, scales=SCALES,
            stop="edges", seed=0, cap=4.0, say=print):
    """Every measurement of one (volume, fraction) row as a flat dict."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    t0 = time.perf_counter()
    v = run_vtk(data, fraction, repeats=repeats, splits=splits, scales=scales, stop=stop, seed=seed, say=say)
    count = int(round(v["n_vertices"]))
    row = {"volume": data.name, "shape": "x".join(map(str, data.shape)),
           "spacing": "x".join(f"{s:g}" for s in data.spacing), "n_points": data.n_points, "fraction": fraction,
           "loadavg_1min": load, "n_vertices": count, "vtk_stop": stop, "vtk_split": v["split"],
           "vtk_scale": v["scale"], "vtk_abs_scale": v["abs_scale"], "vtk_runs": v["runs"],
           "vtk_E_rms": v["E_rms"], "vtk_E_inf": v["E_inf"], "vtk_refit_E_rms": v["refit_E_rms"],
           "vtk_refit_E_inf": v["refit_E_inf"], "vtk_s": v["seconds"], "vtk_n_outside": v["n_outside"],
           "vtk_max_outside_distance": v["max_outside_distance"], "vtk_raw_E_rms": v["raw_E_rms"],
           "vtk_n_vertices_runs": " ".join(str(n) for n in v["n_vertices_all"])}
    for split, s in v["splits"].items():
        row[f"vtk_{split}_E_rms"] = s["E_rms"]
        row[f"vtk_{split}_scale"] = s["scale"]
    say(f"    vtk: {time.perf_counter() - t0:.0f} s; kept {v['split']} at weight {v['scale']}")
    for m in methods:
        t1 = time.perf_counter()
        r = run_trivsel(data, m, count, repeats)
        dl = delaunay_fit(data, r["selected"])
        row.update({f"{m}_n_selected": r["n_selected"], f"{m}_E_rms": r["E_rms"], f"{m}_E_inf": r["E_inf"],
                    f"{m}_fit_E_rms": r["fit_E_rms"], f"{m}_fit_E_inf": r["fit_E_inf"], f"{m}_s": r["seconds"],
                    f"{m}_delaunay_fit_E_rms": dl["E_rms"],
                    f"{m}_fit_over_vtk": _div(r["fit_E_rms"], v["E_rms"]),
                    f"{m}_fit_over_refit": _div(r["fit_E_rms"], v["refit_E_rms"]),
                    f"{m}_inf_over_vtk": _div(r["E_inf"], v["E_inf"]),
                    f"{m}_time_over_vtk": _div(r["seconds"], v["seconds"]),
                    f"{m}_fit_over_delaunay_fit": _div(r["fit_E_rms"], dl["E_rms"])})
        if m in RATIO_METHODS:
            ratio, c, grid = vertex_ratio(data, count, v["refit_E_rms"], r["fit_E_rms"], cap=cap, method=m)
            row[f"{m}_vertex_ratio"] = ratio
            row[f"{m}_vertices_to_match_refit"] = c if c is not None else ""
            row[f"{m}_ratio_search"] = " ".join(f"{k}:{grid[k]:.4g}" for k in sorted(grid))
        say(f"    {m}: E_RMS {r['E_rms']:.4g} (fit {r['fit_E_rms']:.4g}, Delaunay+fit {dl['E_rms']:.4g}), "
            f"E_inf {r['E_inf']:.4g}, {r['seconds']:.2f} s" +
            (f"; vertex ratio {_ratio_text(row[f'{m}_vertex_ratio'], cap)}" if m in RATIO_METHODS else "") +
            f" ({time.perf_counter() - t1:.0f} s)")
    return row


# --------------------------------------------------------------------------- output


def _ratio_text(x, cap=4.0):
    if x == float("inf"):
        return f">{cap:g}"
    if x == 0.0:
        return f"<{1 / cap:.2g}"
    return f"{x:.2f}"


def _g(x):
    return f"{x:.3g}"


def tables(rows, methods, cap=4.0):
    """The markdown table of ratios and the table of details."""
    head = ["volume", "kept", "n_vertices", "VTK E_RMS", "VTK+refit E_RMS"]
    for m in methods:
        head += [f"{m} fit/VTK", f"{m} fit/refit", f"{m} E_inf/VTK", f"{m} time/VTK"]
        if m in RATIO_METHODS:
            head.append(f"{m} vertex ratio")
        head.append(f"{m} fit/Del+fit")
    L = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["volume"], f"{100 * r['fraction']:g} %", str(r["n_vertices"]), _g(r["vtk_E_rms"]),
                 _g(r["vtk_refit_E_rms"])]
        for m in methods:
            cells += [f"{r[f'{m}_fit_over_vtk']:.2f}", f"{r[f'{m}_fit_over_refit']:.2f}",
                      f"{r[f'{m}_inf_over_vtk']:.2f}", f"{r[f'{m}_time_over_vtk']:.2f}"]
            if m in RATIO_METHODS:
                cells.append(_ratio_text(r[f"{m}_vertex_ratio"], cap))
            cells.append(f"{r[f'{m}_fit_over_delaunay_fit']:.2f}")
        L.append("| " + " | ".join(cells) + " |")
    D = ["| volume | grid (spacing) | kept | VTK split, value weight | VTK E_RMS pv5 / kuhn6 | VTK E_RMS, raw values |"
         " VTK E_inf | voxels outside VTK | VTK s | " + " | ".join(f"{m} E_RMS data / fit" for m in methods) +
         " | " + " | ".join(f"{m} s" for m in methods) + " |"]
    D.append("|" + "---|" * (9 + 2 * len(methods)))
    for r in rows:
        D.append("| " + " | ".join([
            r["volume"], f"{r['shape']} ({r['spacing']})", f"{100 * r['fraction']:g} %",
            f"{r['vtk_split']}, {r['vtk_scale']}",
            " / ".join(_g(r.get(f"vtk_{s}_E_rms", float("nan"))) for s in SPLITS),
            _g(r["vtk_raw_E_rms"]), _g(r["vtk_E_inf"]), f"{int(r['vtk_n_outside'])}", f"{r['vtk_s']:.2f}",
            *[f"{_g(r[f'{m}_E_rms'])} / {_g(r[f'{m}_fit_E_rms'])}" for m in methods],
            *[f"{r[f'{m}_s']:.2f}" for m in methods]]) + " |")
    return "\n".join(L), "\n".join(D)


def write_csv(rows, path):
    keys = list(dict.fromkeys(k for r in rows for k in r))
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--volumes", nargs="+", default=list(VOLUMES), choices=VOLUMES)
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.1, 0.05])
    ap.add_argument("--repeats", type=int, default=3, help="VTK seeds per split; trivsel timing calls (default 3)")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--vtk-stop", choices=["edges", "target"], default="edges",
                    help="SetNumberOfEdgesToDecimate(N - K) (default) or SetTargetReduction(1 - fraction)")
    ap.add_argument("--quick", action="store_true", help=f"{QUICK_SIZE}^3 crops of every volume (smoke test)")
    ap.add_argument("--out", type=Path, default=None, help="CSV path (default benchmarks/results/...)")
    a = ap.parse_args(argv)
    missing = missing_packages(a.volumes)
    if missing:
        raise SystemExit(f"bench_realdata: the real volumes need {' and '.join(missing)} (not installed): "
                         "pip install -e '.[realdata]', or run only --volumes " + " ".join(SYNTHETIC))
    for m in a.methods:  # warm-up: load (or compile) the numba kernels before any timing
        trivsel.reduce(trivsel.sample_grid(4, 4), count=20, method=m, values=["data", "fit"])
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out = a.out or Path(__file__).resolve().parent / "results" / f"bench_realdata_{stamp}.csv"
    rows = []
    t0 = time.perf_counter()
    for name in a.volumes:
        data = load_volume(name, a.quick)
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
