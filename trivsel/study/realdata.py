"""trivsel against VTK's tetrahedral decimation on real volumes, like for like.

The volumes: three real ones that ship inside the nilearn and dipy wheels (read from the
installed packages, never imported; ``pip install -e '.[realdata]'``) and two synthetic hard
signals (:data:`VOLUMES`, :func:`load_volume`):

* ``icbm152``: the ICBM152 2009a T1 template (nilearn), central 48^3 crop, 1 mm, 0-255;
* ``statmap``: nilearn's ``image_10426.nii.gz``, a signed statistical map, 53x63x46, 3 mm;
* ``aniso``: dipy's ``aniso_vox.nii.gz``, an anatomical scan, 58x58x24, 4x4x5 mm, with an oblique
  affine (laid out along its voxel axes, :func:`load_nifti`);
* ``chirp`` and ``steps``: :func:`synthetic`, an oscillatory and a sharp-edged signal on 48^3.

Two more real volumes are held out (:data:`HELD_OUT`, not in the default set): methods are tuned on
the five above and checked on these, which they never saw:

* ``gm``: the ICBM152 2009a grey-matter probability map (nilearn), central 48^3 crop, 1 mm, 0-255;
* ``piesno``: dipy's ``test_piesno.nii.gz``, a noisy MR scan, 96x96x14, 1 mm.

:func:`measure` gives every number of one (volume, fraction) row: VTK's
``vtkUnstructuredGridQuadricDecimation`` run the way that favours it (:func:`run_vtk`: both tet
splits, several weights of the value in its quadric, the median of several seeds), VTK's meshes with
least-squares vertex values (*VTK + refit*), trivsel's methods at VTK's vertex count with data and
fitted values, the vertex ratio (:func:`vertex_ratio`: how many vertices a method needs to reach
VTK + refit's E_RMS, over VTK's count) and plain Delaunay + fit on the same points.
:func:`tables` prints the rows as Markdown.  :func:`curves` gives E_RMS and E_inf against the vertex
count for every method over a list of fractions; :func:`target_check`, :func:`realdata_markdown` and
:func:`curves_figure` are the workflow's report (stage ``realdata``, ``config/realdata.yaml``).

Every error is over all original voxels: E_RMS and E_inf of the piecewise-linear interpolant
(eqs. 19-20), a voxel outside VTK's decimated mesh taking the value of the mesh at the closest point
of its boundary surface (:func:`mesh_operator`).  The command line is
``benchmarks/bench_realdata.py``.
"""

from __future__ import annotations

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
from trivsel.study.baselines import _locate, closest_on_boundary, errors_at_points, tet_grid, vtk_quadric_decimation
from trivsel.triangulation import delaunay_tetrahedra

__all__ = [
    "REAL", "SYNTHETIC", "HELD_OUT", "VOLUMES", "ALL_VOLUMES", "SPLITS", "SCALES", "QUICK_SIZE", "METHODS", "RATIO_METHODS",
    "CURVE_COLUMNS", "TARGETS", "MissingExtra",
    "package_file", "missing_packages", "missing_message", "central_crop", "load_nifti", "synthetic",
    "load_volume", "mesh_operator", "least_squares_values", "score", "vtk_input", "absolute_scale",
    "vtk_run", "run_vtk", "run_trivsel", "delaunay_fit", "vertex_ratio", "measure", "warm_up", "curves",
    "tables", "write_csv", "target_check", "realdata_markdown", "curves_figure",
]

#: volume name -> (package, path inside the package, central crop edge or None for the whole volume)
REAL = {
    "icbm152": ("nilearn", "datasets/data/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz", 48),
    "statmap": ("nilearn", "datasets/data/image_10426.nii.gz", None),
    "aniso": ("dipy", "data/files/aniso_vox.nii.gz", None),
    "gm": ("nilearn", "datasets/data/mni_icbm152_gm_tal_nlin_sym_09a_converted.nii.gz", 48),
    "piesno": ("dipy", "data/files/test_piesno.nii.gz", None),
}
SYNTHETIC = ("chirp", "steps")
#: real volumes that the methods were not tuned on (run them by name)
HELD_OUT = ("gm", "piesno")
#: the default volumes
VOLUMES = tuple(v for v in REAL if v not in HELD_OUT) + SYNTHETIC
#: every volume :func:`load_volume` knows
ALL_VOLUMES = VOLUMES + HELD_OUT
SPLITS = ("pv5", "kuhn6")
#: weights of the value in VTK's quadric: "raw" = the values as they are; a number r = values scaled so
#: that their range is r times the largest extent of the domain
SCALES = ("raw", 1.0, 0.3, 0.1, 0.03)
#: edge of the crops of ``quick`` runs (smoke tests)
QUICK_SIZE = 16
METHODS = ("decimate", "greedy", "paper")
#: the methods whose vertex ratio (vertices to reach VTK + refit's E_RMS) is searched
RATIO_METHODS = ("decimate", "greedy")
#: columns of :func:`curves`
CURVE_COLUMNS = ["volume", "method", "values", "fraction", "n_target", "n_vertices", "E_rms", "E_inf", "seconds"]
#: the targets of :func:`target_check`: column -> what it checks
TARGETS = {
    "fit_le_vtk": "fit E_RMS <= VTK's",
    "fit_le_refit": "fit E_RMS <= VTK + refit's",
    "inf_le_vtk": "data-value E_inf <= VTK's",
    "time_le_2vtk": "time <= 2x VTK's",
    "ratio_le_1": "vertex ratio <= 1",
}


class MissingExtra(RuntimeError):
    """A real volume's package (nilearn, dipy) is not installed; the message is one line."""


# --------------------------------------------------------------------------- volumes


def package_file(package, relpath):
    """Path of a data file inside an installed package, without importing the package.

    Parameters
    ----------
    package : str
        Top-level package name, e.g. ``"nilearn"``.
    relpath : str
        Path of the file relative to the package's folder.

    Returns
    -------
    pathlib.Path or None
        The file, or None when the package is not installed or lacks the file.
    """
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        return None
    p = Path(list(spec.submodule_search_locations)[0]) / relpath
    return p if p.exists() else None


def missing_packages(volumes):
    """The packages (sorted) that the real volumes among ``volumes`` need and that are not installed."""
    need = sorted({REAL[v][0] for v in volumes if v in REAL})
    return [p for p in need if importlib.util.find_spec(p) is None]


def missing_message(volumes, alternative="run only the synthetic volumes " + " ".join(SYNTHETIC)):
    """One line naming the missing packages and the extra to install, or None when nothing is missing.

    Parameters
    ----------
    volumes : sequence of str
        Volume names (:data:`VOLUMES`).
    alternative : str
        What else the user can do, appended after ``or``.
    """
    missing = missing_packages(volumes)
    if not missing:
        return None
    real = [v for v in volumes if v in REAL and REAL[v][0] in missing]
    subject = f"the real volumes {', '.join(real)} need" if len(real) > 1 else f"the real volume {real[0]} needs"
    return f"{subject} {' and '.join(missing)} (not installed): pip install -e '.[realdata]', or {alternative}"


def central_crop(data, size):
    """The central block of grid data, geometry kept.

    Parameters
    ----------
    data : PointData
        Grid data.
    size : int or None
        Edge of the block: each axis is cropped to at most ``size`` points; None keeps the volume.

    Returns
    -------
    PointData
        The block with its origin moved to the block's first voxel.
    """
    if size is None:
        return data
    a = data.values.reshape(data.shape)
    start = [max((s - size) // 2, 0) for s in data.shape]
    block = a[tuple(slice(b, b + size) for b in start)]
    return grid_from_array(block, data.origin + np.asarray(start) * data.spacing, data.spacing, name=data.name)


def load_nifti(path, name):
    """A NIfTI volume as grid data.

    ``trivsel.load`` (exact world geometry) when it accepts the file; an oblique affine that is a
    rotation times a diagonal is laid out along the voxel axes with the diagonal as spacing, a rigid
    motion of the world frame, so distances and errors are unchanged.  ``meta["frame"]`` says which.

    Parameters
    ----------
    path : path-like
        The ``.nii`` or ``.nii.gz`` file.
    name : str
        Name given to the data.

    Returns
    -------
    PointData

    Raises
    ------
    ValueError
        When the affine is sheared (no rigid layout exists).
    """
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
            raise ValueError(f"{path} has a sheared affine; it cannot be laid out rigidly") from None
        d = grid_from_array(np.asarray(img.get_fdata(dtype=np.float64)), (0.0, 0.0, 0.0), zooms)
        d.meta["frame"] = "voxel axes (oblique affine's rotation removed)"
    d.name = name
    return d


def synthetic(name, n=48):
    """One of the two synthetic hard signals on the n^3 grid over [-1, 1]^3.

    * ``chirp`` (oscillatory): ``sin(5 pi |x|^2)``, up to about 2.3 radians per sample at the corners
      of the 48^3 grid;
    * ``steps`` (sharp edges): a box turned about an oblique axis, a ball overlapping it and an oblique
      planar cut through the ball (steps of +1, +1 and -1.5, no face aligned with the grid) on the
      smooth background ``0.3 sin(2.5 x + 1.1) cos(2 y - 0.4) cos(1.7 z + 0.3)``.  Without the
      background, or with grid-aligned faces, both trivsel and VTK reproduce such a volume exactly (to
      float32 rounding) from 5-10 % of its points, which measures nothing.

    Parameters
    ----------
    name : {"chirp", "steps"}
    n : int
        Grid points per axis.

    Returns
    -------
    PointData
    """
    t = np.linspace(-1.0, 1.0, n)
    x, y, z = np.meshgrid(t, t, t, indexing="ij")
    if name == "chirp":
        f = np.sin(5.0 * np.pi * (x * x + y * y + z * z))
    elif name == "steps":
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
    """A volume of :data:`VOLUMES` as grid data.

    Parameters
    ----------
    name : str
        ``icbm152``, ``statmap``, ``aniso`` (real), ``chirp`` or ``steps`` (synthetic).
    quick : bool
        The central :data:`QUICK_SIZE`^3 crop (synthetic: the QUICK_SIZE^3 grid), for smoke tests.

    Returns
    -------
    PointData

    Raises
    ------
    MissingExtra
        When the real volume's package is not installed (one line naming the extra).
    """
    if name in SYNTHETIC:
        return synthetic(name, QUICK_SIZE if quick else 48)
    if name not in REAL:
        raise ValueError(f"unknown volume {name!r}; choose from {', '.join(ALL_VOLUMES)}")
    package, rel, crop = REAL[name]
    path = package_file(package, rel)
    if path is None:
        raise MissingExtra(f"{rel} not found in an installed {package}; "
                           "install the extra: pip install -e '.[realdata]'")
    return central_crop(load_nifti(path, name), QUICK_SIZE if quick else crop)


# --------------------------------------------------------------------------- evaluation as a matrix


def mesh_operator(mesh_points, tets, query_points, bary_tol=1e-9):
    """The mesh's piecewise-linear interpolant at the queries as a sparse matrix.

    A query outside the mesh gets the interpolant at the closest point of the boundary surface, as
    :func:`trivsel.study.baselines.evaluate_mesh_at_points` evaluates it.

    Parameters
    ----------
    mesh_points : (m, 3) float
    tets : (t, 4) int
    query_points : (q, 3) float
    bary_tol : float
        Tolerance of the barycentric inside test.

    Returns
    -------
    A : scipy.sparse.csr_matrix, (q, m)
        ``A @ vertex_values`` is the interpolant at the queries.
    outside : (q,) bool
        Queries outside the mesh.
    distance : (q,) float
        Distance of each query to the point it was evaluated at (0 inside).
    """
    P = np.asarray(mesh_points, float)
    T = np.asarray(tets, np.int64)
    Q = np.asarray(query_points, float)
    tet, bary, inside = _locate(P, T, Q, bary_tol)
    ins = np.flatnonzero(inside)
    rows, cols, vals = [np.repeat(ins, 4)], [T[tet[ins]].ravel()], [bary[ins].ravel()]
    out = np.flatnonzero(~inside)
    dist = np.zeros(Q.shape[0])
    if out.size:
        idx, w, d = closest_on_boundary(P, T, Q[out])
        rows.append(np.repeat(out, 3))
        cols.append(idx.ravel())
        vals.append(w.ravel())
        dist[out] = d
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(Q.shape[0], P.shape[0]))
    return A, ~inside, dist


def least_squares_values(A, f, v0):
    """Vertex values minimising ``|A v - f|^2`` (normal equations, sparse direct solve).

    A vertex no query depends on keeps its value in ``v0``; a ridge of 1e-12 of the largest diagonal
    entry toward ``v0`` keeps a rank-deficient system solvable without moving the solution measurably.

    Parameters
    ----------
    A : sparse (q, m)
        From :func:`mesh_operator`.
    f : (q,) float
        The data at the queries.
    v0 : (m,) float
        Fallback vertex values.

    Returns
    -------
    (m,) float
    """
    AtA = (A.T @ A).tocsc()
    rhs = A.T @ np.asarray(f, float)
    lam = 1e-12 * max(float(AtA.diagonal().max()), 1e-300)
    return spsolve(AtA + lam * sp.identity(AtA.shape[0], format="csc"), rhs + lam * np.asarray(v0, float))


def score(A, f, v):
    """``{"E_rms", "E_inf"}`` of the vertex values ``v`` against the data ``f`` through ``A``."""
    e = errors_at_points(f, A @ v)
    return {"E_rms": e["E_rms"], "E_inf": e["E_inf"]}


# --------------------------------------------------------------------------- VTK


def vtk_input(data, split, scale):
    """VTK's input mesh with the values times ``scale`` as scalars ``f``.

    Parameters
    ----------
    data : PointData
        Grid data.
    split : {"pv5", "kuhn6", "cells"}
        pyvista's ``ImageData.triangulate()`` (5 tets per cell) or the Kuhn split (6) of a grid;
        ``"cells"``: the tetrahedra of a mesh (``data.tets``), or the Delaunay tetrahedra of
        scattered points.
    scale : float
        Weight of the value in VTK's quadric.
    """
    if split == "kuhn6":
        return tet_grid(data, scalar_scale=scale)
    if split == "cells":
        return tet_grid(data, tets=data.tets, scalar_scale=scale)
    import pyvista as pv

    img = pv.ImageData(dimensions=data.shape, spacing=tuple(data.spacing), origin=tuple(data.origin))
    img.point_data["f"] = data.values.reshape(data.shape).ravel(order="F") * scale  # VTK order: x fastest
    grid = img.triangulate()
    grid.point_data.active_scalars_name = "f"
    return grid


def absolute_scale(data, scale):
    """The multiplier of the values for a weight of :data:`SCALES` (``"raw"``: 1)."""
    if scale == "raw":
        return 1.0
    rng = float(np.ptp(data.values))
    return float(scale) * float(np.ptp(data.points, axis=0).max()) / rng if rng > 0 else 1.0


def vtk_run(data, grid, K, fraction, scale, seed, stop, refit=False):
    """One decimation, scored at every voxel (and refitted).

    Parameters
    ----------
    data : PointData
    grid : pyvista.UnstructuredGrid
        From :func:`vtk_input`.
    K : int
        Vertex count aimed at.
    fraction : float
        Kept fraction (``stop="target"``).
    scale : float
        The multiplier of the values in ``grid``.
    seed : int
        Seed of VTK's random numbers.
    stop : {"edges", "target"}
        ``SetNumberOfEdgesToDecimate(N - K)`` or ``SetTargetReduction(1 - fraction)``.
    refit : bool
        Also the errors with least-squares vertex values (``refit_E_rms``, ``refit_E_inf``).

    Returns
    -------
    dict
        ``seed, n_vertices, n_orphans, seconds, n_outside, max_outside_distance, E_rms, E_inf``.
    """
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


def _silent(_msg):
    pass


def run_vtk(data, fraction, *, repeats=3, splits=SPLITS, scales=SCALES, stop="edges", seed=0, say=None):
    """VTK's best setting for one volume and fraction.

    Every split is screened with every weight at ``seed``; each split keeps its best weight and is run
    again with seeds ``seed + 1 .. seed + repeats - 1``; the split with the lower median E_RMS is kept.
    In ``edges`` mode a setting competes only if VTK reached the count (within 1 %, at least 3): a run
    that stops early, when no further collapse is allowed, keeps more vertices and would win on that
    alone.

    Parameters
    ----------
    data : PointData
    fraction : float
        Kept fraction; VTK aims at ``count_for_fraction(fraction, N)`` vertices.
    repeats : int
        Runs (seeds) of the kept setting of each split.
    splits, scales : sequences
        Subsets of :data:`SPLITS` and :data:`SCALES`.
    stop : {"edges", "target"}
        See :func:`vtk_run`.
    seed : int
        First seed.
    say : callable, optional
        Progress lines.

    Returns
    -------
    dict
        The kept split's medians (``E_rms, E_inf, refit_E_rms, refit_E_inf, seconds, n_vertices,
        n_outside, max_outside_distance``), ``split, scale, abs_scale, runs, n_vertices_all,
        raw_E_rms``, and ``K_nominal``, ``splits`` (every split's summary), ``screen`` (every screened run).
    """
    say = say or _silent
    K = count_for_fraction(fraction, data.n_points)

    def landed(n):
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
    """``trivsel.reduce(count=...)`` with data and fitted values, timed.

    The time is the median over ``repeats`` calls of the total minus the error evaluation and fits
    (curvature, start mesh, insertion and swapping remain); the results are deterministic and taken
    from the first call.

    Returns
    -------
    dict
        ``n_selected, selected, tets, E_rms, E_inf, fit_E_rms, fit_E_inf, seconds, seconds_all``.
    """
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
    """``{"E_rms", "E_inf"}`` of plain Delaunay tetrahedra of the selected points with least-squares values."""
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
    """How many vertices ``method`` (fitted values) needs to reach E_RMS <= ``target``, over ``K``.

    One run with snapshots at ``K * cap^(j/steps)`` (or ``K / cap^(j/steps)`` when the method already
    reaches the target at K), then one run with ``steps`` snapshots inside the bracket that the first
    crossing fell in; the smallest count of that grid that reaches the target.

    Parameters
    ----------
    data : PointData
    K : int
        The reference count (VTK's).
    target : float
        The E_RMS to reach (VTK + refit's).
    e_at_K : float
        The method's fitted E_RMS at K.
    cap : float
        Search range: K / cap .. K * cap.
    steps : int
        Snapshots per search run.
    method : str

    Returns
    -------
    ratio : float
        ``count / K``; ``inf`` above ``cap``, 0 below ``1 / cap``.
    count : int or None
    errors : dict
        Count -> fitted E_RMS of every count tried.
    """
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
            stop="edges", seed=0, cap=4.0, say=None):
    """Every measurement of one (volume, fraction) row.

    VTK first (:func:`run_vtk`); then each trivsel method at VTK's median vertex count with data and
    fitted values, plain Delaunay + fit on the same points, and for :data:`RATIO_METHODS` the vertex
    ratio to VTK + refit's E_RMS (:func:`vertex_ratio`).

    Parameters
    ----------
    data : PointData
        The volume (its ``name`` goes into the row).
    fraction : float
        Kept fraction.
    repeats : int
        VTK seeds per split, and trivsel timing calls.
    methods : sequence of str
        A subset of :data:`METHODS`.
    splits, scales, stop, seed
        Passed to :func:`run_vtk`.
    cap : float
        Range of the vertex-ratio search.
    say : callable, optional
        Progress lines.

    Returns
    -------
    dict
        A flat row: the volume and VTK's numbers (``vtk_*``), then per method ``{m}_E_rms``,
        ``{m}_fit_E_rms``, ``{m}_E_inf``, ``{m}_s``, the ratios ``{m}_fit_over_vtk``,
        ``{m}_fit_over_refit``, ``{m}_inf_over_vtk``, ``{m}_time_over_vtk``,
        ``{m}_fit_over_delaunay_fit`` and ``{m}_vertex_ratio``.
    """
    say = say or _silent
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


def warm_up(methods=METHODS):
    """Load (or the first time compile) the numba kernels of ``methods`` on a tiny grid, so that no
    timing includes them."""
    for m in methods:
        trivsel.reduce(trivsel.sample_grid(4, 4), count=20, method=m, values=["data", "fit"])


# --------------------------------------------------------------------------- curves


def curves(data, fractions, *, methods=METHODS, repeats=3, splits=SPLITS, scales=SCALES, stop="edges",
           seed=0, say=None):
    """E_RMS and E_inf against the vertex count for every method, over a list of fractions.

    Each trivsel method is one ``trivsel.reduce(data, fractions=..., method=m, values=["data", "fit"])``
    call, its snapshots giving the rows (``values`` ``data`` and ``fit``; ``seconds``: the run's wall
    time from its start to that snapshot).  VTK is :func:`run_vtk` at each fraction (the split and
    weight it screens best at the fraction nearest 10 %, kept for the others; the median of ``repeats``
    runs): method ``vtk`` with values ``free`` (VTK's own
    optimised values) and ``fit`` (VTK + refit: least-squares values on VTK's meshes); both rows carry
    VTK's decimation time (the refit's solve is not timed).

    Parameters
    ----------
    data : PointData
    fractions : sequence of float in (0, 1]
    methods : sequence of str
        A subset of :data:`METHODS`.
    repeats, splits, scales, stop, seed
        Passed to :func:`run_vtk`.
    say : callable, optional
        Progress lines.

    Returns
    -------
    pandas.DataFrame
        :data:`CURVE_COLUMNS`: one row per (method, values, fraction); ``n_target`` is the count of the
        fraction, ``n_vertices`` the count reached (VTK: the median of its runs).
    """
    import pandas as pd

    say = say or _silent
    fractions = sorted({float(f) for f in fractions})
    N = data.n_points
    rows = []
    for m in methods:
        t0 = time.perf_counter()
        r = trivsel.reduce(data, fractions=fractions, method=m, values=["data", "fit"])
        for f, s in zip(fractions, r.snapshots):
            for values, e in (("data", s.errors), ("fit", s.fit["errors"])):
                rows.append({"volume": data.name, "method": m, "values": values, "fraction": f,
                             "n_target": count_for_fraction(f, N), "n_vertices": int(s.n_selected),
                             "E_rms": e["E_rms"], "E_inf": e["E_inf"], "seconds": float(s.seconds)})
        say(f"    curve {m}: {len(fractions)} snapshots in {time.perf_counter() - t0:.1f} s")
    # VTK's split and value weight are screened once, at the fraction nearest 10 %, and kept
    first = min(fractions, key=lambda f: abs(f - 0.1))
    v0 = run_vtk(data, first, repeats=repeats, splits=splits, scales=scales, stop=stop, seed=seed, say=say)
    for f in fractions:
        v = v0 if f == first else run_vtk(data, f, repeats=repeats, splits=(v0["split"],), scales=(v0["scale"],),
                                           stop=stop, seed=seed, say=say)
        for values, (e_rms, e_inf) in (("free", (v["E_rms"], v["E_inf"])),
                                       ("fit", (v["refit_E_rms"], v["refit_E_inf"]))):
            rows.append({"volume": data.name, "method": "vtk", "values": values, "fraction": f,
                         "n_target": count_for_fraction(f, N), "n_vertices": int(round(v["n_vertices"])),
                         "E_rms": e_rms, "E_inf": e_inf, "seconds": v["seconds"]})
    return pd.DataFrame(rows, columns=CURVE_COLUMNS)


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
    """The Markdown table of ratios and the table of details.

    Parameters
    ----------
    rows : sequence of dict
        Rows of :func:`measure`.
    methods : sequence of str
        The methods measured, in column order.
    cap : float
        The vertex-ratio search range (for ``>4`` / ``<0.25``).

    Returns
    -------
    ratios, details : str
    """
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
    """Write rows of :func:`measure` (dicts, the union of their keys as columns) to ``path``."""
    path = Path(path)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)


# --------------------------------------------------------------------------- the workflow's report


def _frame(rows):
    import pandas as pd

    return rows.copy() if isinstance(rows, pd.DataFrame) else pd.DataFrame(list(rows))


def target_check(rows, methods=METHODS):
    """The targets checked per (volume, fraction, method), as pass/fail.

    At VTK's vertex count: fit E_RMS <= VTK's (``fit_le_vtk``) and <= VTK + refit's
    (``fit_le_refit``), data-value E_inf <= VTK's (``inf_le_vtk``), time <= 2x VTK's
    (``time_le_2vtk``) and, for :data:`RATIO_METHODS`, vertex ratio <= 1 (``ratio_le_1``; ``n/a``
    for the others).  ``all`` passes when every target that applies does.

    Parameters
    ----------
    rows : DataFrame or sequence of dict
        Rows of :func:`measure` (e.g. read back from their CSV).
    methods : sequence of str
        The methods to check (those missing from the rows are left out).

    Returns
    -------
    pandas.DataFrame
        ``volume, fraction, n_vertices, method, fit_over_vtk, fit_over_refit, inf_over_vtk,
        time_over_vtk, vertex_ratio``, then one column per :data:`TARGETS` key and ``all``.
    """
    import pandas as pd

    df = _frame(rows)
    out = []
    for _, r in df.iterrows():
        for m in methods:
            if f"{m}_fit_over_vtk" not in df.columns:
                continue
            ratio = float(r[f"{m}_vertex_ratio"]) if m in RATIO_METHODS else float("nan")
            checks = {"fit_le_vtk": r[f"{m}_fit_over_vtk"] <= 1.0,
                      "fit_le_refit": r[f"{m}_fit_over_refit"] <= 1.0,
                      "inf_le_vtk": r[f"{m}_inf_over_vtk"] <= 1.0,
                      "time_le_2vtk": r[f"{m}_time_over_vtk"] <= 2.0,
                      "ratio_le_1": ratio <= 1.0 if m in RATIO_METHODS else None}
            verdict = {k: "n/a" if ok is None else "pass" if ok else "fail" for k, ok in checks.items()}
            verdict["all"] = "pass" if all(ok for ok in checks.values() if ok is not None) else "fail"
            out.append({"volume": r["volume"], "fraction": float(r["fraction"]), "n_vertices": int(r["n_vertices"]),
                        "method": m, **{k: float(r[f"{m}_{k}"]) for k in
                                        ("fit_over_vtk", "fit_over_refit", "inf_over_vtk", "time_over_vtk")},
                        "vertex_ratio": ratio, **verdict})
    return pd.DataFrame(out)


def realdata_markdown(rows, methods=METHODS, figures=None, cap=4.0):
    """The workflow's report: the target check per row, the ratio table and the details.

    Parameters
    ----------
    rows : DataFrame or sequence of dict
        Rows of :func:`measure`, every volume and fraction.
    methods : sequence of str
        The methods measured.
    figures : dict, optional
        ``{volume: relative path}`` of the curves figures to link.
    cap : float
        The vertex-ratio search range of the rows.

    Returns
    -------
    str
    """
    df = _frame(rows)
    methods = [m for m in methods if f"{m}_fit_over_vtk" in df.columns]
    chk = target_check(df, methods)
    L = ["# trivsel against VTK's tetrahedral decimation on real volumes", "",
         "Each row: one volume reduced to one fraction. VTK's `vtkUnstructuredGridQuadricDecimation` is run "
         "the way that favours it (best tet split and value weight, median of its runs); trivsel's methods "
         "run at VTK's vertex count. E_RMS and E_inf are over all voxels. *fit*: least-squares vertex values "
         "on the method's mesh; *VTK + refit*: the same on VTK's meshes. The vertex ratio is the number of "
         "vertices the method (fit) needs to reach VTK + refit's E_RMS, over VTK's count.", "",
         "## Targets", "",
         "Per row and method: " + "; ".join(f"`{k}`: {v}" for k, v in TARGETS.items()) +
         " (`n/a`: no vertex-ratio search for that method).", ""]
    head = ["volume", "kept", "n_vertices", "method", "fit/VTK", "fit/refit", "E_inf/VTK", "time/VTK",
            "vertex ratio", *TARGETS, "all"]
    L += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, c in chk.iterrows():
        ratio = _ratio_text(c["vertex_ratio"], cap) if c["method"] in RATIO_METHODS else "-"
        L.append("| " + " | ".join([
            str(c["volume"]), f"{100 * c['fraction']:g} %", str(c["n_vertices"]), c["method"],
            *[f"{c[k]:.2f}" for k in ("fit_over_vtk", "fit_over_refit", "inf_over_vtk", "time_over_vtk")],
            ratio, *[c[k] if c[k] != "fail" else "**fail**" for k in TARGETS],
            c["all"] if c["all"] == "pass" else "**fail**"]) + " |")
    for m in methods:
        mine = chk[chk["method"] == m]
        L.append("")
        L.append(f"`{m}` meets every target in {int((mine['all'] == 'pass').sum())} of {len(mine)} rows; " +
                 ", ".join(f"`{k}` {int((mine[k] == 'pass').sum())}" for k in TARGETS
                           if not (mine[k] == "n/a").all()) + ".")
    ratios, details = tables(df.to_dict("records"), methods, cap)
    L += ["", "## Ratios (trivsel / VTK at VTK's vertex count)", "", ratios, "", "## Details", "", details]
    if figures:
        L += ["", "## E_RMS against the vertex count", ""]
        L += [f"![{v}]({path})" for v, path in figures.items()]
    return "\n".join(L) + "\n"


_CURVE_STYLE = {"decimate": ("C2", "s"), "greedy": ("C0", "o"), "paper": ("C1", "^")}


def curves_figure(df, out_png, volume=None, dpi=110):
    """Log-log plot of E_RMS with fitted vertex values against the vertex count, one line per method,
    plus VTK (its own values) and VTK + refit.

    Parameters
    ----------
    df : DataFrame
        Rows of :func:`curves`.
    out_png : path-like
    volume : str, optional
        Plot only this volume's rows (default: the rows' first volume).
    dpi : int

    Returns
    -------
    out_png
    """
    from .figures import _pyplot, _save_png

    plt = _pyplot()
    df = _frame(df)
    volume = volume if volume is not None else df["volume"].iloc[0]
    df = df[df["volume"].astype(str) == str(volume)]
    if df.empty:
        raise ValueError(f"no curve rows for volume {volume!r}")
    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    lines = [(m, "fit", m + " (fit)") for m in df["method"].unique() if m != "vtk"]
    lines += [("vtk", "free", "VTK (own values)"), ("vtk", "fit", "VTK + refit")]
    for m, values, label in lines:
        d = df[(df["method"] == m) & (df["values"] == values)].sort_values("n_vertices")
        if d.empty:
            continue
        color, marker = _CURVE_STYLE.get(m, ("C3", "D") if values == "free" else ("C3", "d"))
        ax.plot(d["n_vertices"].astype(float), d["E_rms"], "--" if m == "vtk" and values == "fit" else "-",
                color=color, marker=marker, ms=5, lw=1.6, mfc="none" if m == "vtk" and values == "fit" else color,
                label=label)
    from matplotlib.ticker import FuncFormatter, NullFormatter

    ax.set_xscale("log")
    ax.set_yscale("log")
    plain = FuncFormatter(lambda v, _: f"{v:g}")  # 400 rather than 4 x 10^2
    # label the 1-2-5 ticks only, so that neighbouring labels do not run into each other
    sparse = FuncFormatter(lambda v, _: f"{v:g}" if f"{v:g}"[0] in "125" else "")
    ax.xaxis.set_major_formatter(plain)
    ax.xaxis.set_minor_formatter(sparse)
    ax.yaxis.set_major_formatter(plain)
    lo, hi = ax.get_ylim()
    ax.yaxis.set_minor_formatter(plain if hi < 10 * lo else NullFormatter())  # minor labels within a decade
    ax.set_xlabel("vertices kept")
    ax.set_ylabel("E_RMS over all voxels")
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=9)
    ax.set_title(f"{volume}: E_RMS with fitted vertex values against the vertex count", fontsize=10)
    fig.tight_layout()
    return _save_png(fig, out_png, dpi)
