"""Baselines to compare the paper's point selection against.

Three references, all measured with the paper's error norms (eqs. 19-20) at
every original data point:

* :func:`vtk_quadric_decimation` / :func:`vtk_matched` - VTK's
  ``vtkUnstructuredGridQuadricDecimation`` (Vo et al. 2007, "Streaming
  simplification of tetrahedral meshes"), an edge-collapse decimator of
  tetrahedral meshes driven by Garland's generalised quadric error metric;
* :func:`random_delaunay` - a random subset of the points (plus the 8 grid
  corners), Delaunay-triangulated;
* :func:`curvature_delaunay` - the first points of a given ranking (e.g. the
  paper's curvature order) plus the corners, *plain* Delaunay-triangulated; set
  beside the paper's data-dependent mesh on the same points it isolates what the
  data-dependent swapping of section 4 is worth.

How VTK's decimator uses the scalar
-----------------------------------
``vtkUnstructuredGridQuadricDecimation`` needs exactly one point scalar (the
array named by ``ScalarsName``, else the active scalars, else an array called
``"scalars"``; without one it fails with "Can't simplify without scalars") and
there is no switch to leave it out: every vertex is the 4-vector
``(x, y, z, f)``, i.e. the mesh is treated as the graph of ``f`` in R^4, which is
exactly the paper's view of trivariate data.  Each tetrahedron adds to its four
vertices the quadric of squared distance (in R^4) to the 3-flat through its four
lifted vertices; each boundary triangle adds the quadric of squared distance to
its lifted 2-flat, weighted by its area and by ``BoundaryWeight`` (default 100:
"the larger the number, the better the boundary is preserved").  An edge collapse
places the merged vertex at the approximate 4-D minimiser of the summed quadric
(a few conjugate-gradient steps), so both the *position and the value* of the new
vertex are optimised; the output scalar (array ``"scalars"``) is that optimised
value, not a sample of ``f``.  Consequences, all handled here:

* the scalar is part of the metric with the same units as x, y, z, so its scale
  matters; ``scalar_scale`` multiplies ``f`` before decimation (and divides the
  output values after), default 1 (the plain graph metric);
* vertices move, including boundary vertices (the boundary quadric only
  penalises that), so some original points can fall outside the decimated mesh;
  :func:`evaluate_mesh_at_points` reports them;
* a collapse may leave a vertex without any tetrahedron; VTK still outputs it.
  Such orphans carry no approximant, so :func:`vtk_quadric_decimation` drops them
  and counts them (``n_orphans``);
* VTK stores coordinates and values as float32;
* edges are drawn at random with C ``rand()``, never seeded by VTK, so repeated
  runs in one process differ.  ``seed`` calls the C library's ``srand`` first,
  which makes a run reproducible (on platforms where ctypes can reach libc).  The
  filter's first run in a process still differs from its later runs with the same
  seed (on a 25^3 grid, other tetrahedra; on a 48^3 brain map, 11,018 vertices
  instead of 11,024), so :func:`vtk_quadric_decimation` first runs it once on a
  tiny grid (:func:`_warm_filter`), and every seeded run is then the same.

Output size: VTK stops on a tetrahedron count (``TargetReduction``, the fraction
of tetrahedra to remove, or ``NumberOfTetsOutput``) or after a number of
successful edge collapses (``NumberOfEdgesToDecimate``).  Every successful
collapse removes exactly one vertex, so the edge count controls the vertex count
exactly (up to orphans); :func:`vtk_matched` uses that by default and can also
bisect ``TargetReduction``.

Outside points
--------------
Errors at points outside a decimated mesh are evaluated at the *nearest point of
the mesh* (on its boundary surface), i.e. the approximant is extended by its
value at the closest boundary point.  So E_RMS still averages over all
``(n+1)^3`` points as eq. (19) requires, nothing is dropped, and the number of
outside points, their largest distance to the mesh and the largest error among
them are reported beside the norms.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import time
from dataclasses import dataclass, field

import numpy as np

from ..norms import error_norms
from ..triangulation import (
    boundary_triangles,
    cube_corners,
    delaunay_tetrahedra,
    hull_triangles,
    kuhn_tetrahedra,
)

__all__ = [
    "DecimatedMesh",
    "SubsetResult",
    "errors_at_points",
    "evaluate_mesh_at_points",
    "vtk_quadric_decimation",
    "vtk_matched",
    "random_delaunay",
    "curvature_delaunay",
    "ERROR_KEYS",
    "tet_grid",
]

#: keys of the error dictionaries (eqs. 19-20, all points and interior points)
ERROR_KEYS = ("E_rms", "E_rms_interior", "E_inf", "E_inf_interior")


# --------------------------------------------------------------------------- errors


def errors_at_points(values, approx, interior_mask=None) -> dict:
    """Total RMS and maximum errors of eqs. (19)-(20), via :func:`trivsel.norms.error_norms`.

    Parameters
    ----------
    values : (N,) array_like
        Original data values ``f_i``.
    approx : (N,) array_like
        Approximant at the same points, ``L(x_i)``.
    interior_mask : (N,) bool array_like, optional
        True for interior points (``PointData.interior_mask()``).  ``None``
        treats every point as interior.

    Returns
    -------
    dict
        ``E_rms`` = sqrt(mean d^2) over all points (normalised by N),
        ``E_rms_interior`` = the same over interior points only (normalised by
        their own count; the starred column of Table 1), ``E_inf`` = max |d|
        over all points, ``E_inf_interior`` = max |d| over interior points.
        Interior norms are NaN when there are no interior points.
    """
    f = np.asarray(values, dtype=float)
    a = np.asarray(approx, dtype=float)
    if f.shape != a.shape:
        raise ValueError(f"values {f.shape} and approx {a.shape} differ in shape")
    d = f - a
    mask = np.ones(d.shape, bool) if interior_mask is None else np.asarray(interior_mask, bool)
    res = error_norms(d, mask)  # the one formula of eqs. (19)-(20), shared with reduce()
    if not d.size:  # error_norms gives 0 on an empty set; here "no points" is NaN
        res.update(E_rms=float("nan"), E_inf=float("nan"))
    if not mask.any():
        res.update(E_rms_interior=float("nan"), E_inf_interior=float("nan"))
    return res


# --------------------------------------------------------------------------- evaluation


def _bucket_index(x, lo, h, nb):
    """Integer bucket coordinates, monotone in x (so bbox ranges contain points)."""
    return np.clip(np.floor((x - lo) / h).astype(np.int64), 0, nb - 1)


def _locate(mesh_points, tets, query_points, bary_tol):
    """Containing tetrahedron and barycentric coordinates of each query point.

    Tets are binned into a uniform grid of buckets by their bounding boxes; each
    query point is tested against every tet of its bucket, and the tet in which
    its smallest barycentric coordinate is largest wins (so a point on a shared
    face, edge or vertex gets one of the tets sharing it, any of which give the
    same value of a conforming piecewise-linear interpolant).

    Returns ``(tet, bary, inside)``: tet index (-1 if no candidate), (Q, 4)
    barycentric coordinates in that tet, and ``min(bary) >= -bary_tol``.
    """
    P = np.asarray(mesh_points, float)
    T = np.asarray(tets, np.int64)
    Q = np.asarray(query_points, float)
    nq = Q.shape[0]
    best_tet = np.full(nq, -1, np.int64)
    best_bary = np.full((nq, 4), np.nan)
    best_min = np.full(nq, -np.inf)
    if T.shape[0] == 0 or nq == 0:
        return best_tet, best_bary, np.zeros(nq, bool)

    v0 = P[T[:, 0]]
    E = np.stack([P[T[:, 1]] - v0, P[T[:, 2]] - v0, P[T[:, 3]] - v0], axis=2)  # columns e1 e2 e3
    det = np.linalg.det(E)
    scale = float(np.ptp(P, axis=0).max()) or 1.0
    good = np.abs(det) > 1e-13 * scale**3
    tet_ids = np.flatnonzero(good)
    if tet_ids.size == 0:
        return best_tet, best_bary, np.zeros(nq, bool)
    Einv = np.linalg.inv(E[good])
    v0 = v0[good]
    Tg = T[good]

    # bucket grid over the mesh bounding box
    lo = P.min(axis=0)
    hi = P.max(axis=0)
    m = tet_ids.size
    nb = int(np.clip(np.cbrt(m), 1, 256))
    h = np.maximum((hi - lo) / nb, 1e-300)
    pad = 1e-9 * scale
    tmin = P[Tg].min(axis=1) - pad
    tmax = P[Tg].max(axis=1) + pad
    blo = _bucket_index(tmin, lo, h, nb)
    bhi = _bucket_index(tmax, lo, h, nb)
    ext = bhi - blo + 1
    cnt = ext.prod(axis=1)
    owner = np.repeat(np.arange(m), cnt)
    k = np.arange(owner.size) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    eyz = (ext[:, 1] * ext[:, 2])[owner]
    ez = ext[owner, 2]
    bx = blo[owner, 0] + k // eyz
    by = blo[owner, 1] + (k % eyz) // ez
    bz = blo[owner, 2] + k % ez
    bucket = (bx * nb + by) * nb + bz
    order = np.argsort(bucket, kind="stable")
    b_tets = owner[order]
    b_ptr = np.zeros(nb**3 + 1, np.int64)
    np.cumsum(np.bincount(bucket, minlength=nb**3), out=b_ptr[1:])

    # query points inside the (padded) bounding box
    inbox = np.all((Q >= lo - pad) & (Q <= hi + pad), axis=1)
    qid = np.flatnonzero(inbox)
    qb = _bucket_index(Q[qid], lo, h, nb)
    qbucket = (qb[:, 0] * nb + qb[:, 1]) * nb + qb[:, 2]
    start = b_ptr[qbucket]
    ncand = b_ptr[qbucket + 1] - start
    keep = ncand > 0
    qid, start, ncand = qid[keep], start[keep], ncand[keep]

    # process in chunks of about 2M (query, tet) pairs
    csum = np.cumsum(ncand)
    chunk = 2_000_000
    s = 0
    while s < qid.size:
        base = csum[s - 1] if s else 0
        e = int(np.searchsorted(csum, base + chunk, side="right"))
        e = max(e, s + 1)
        q = qid[s:e]
        nc = ncand[s:e]
        st = start[s:e]
        pq = np.repeat(np.arange(q.size), nc)
        off = np.arange(pq.size) - np.repeat(np.cumsum(nc) - nc, nc)
        t = b_tets[np.repeat(st, nc) + off]
        lam = np.einsum("pij,pj->pi", Einv[t], Q[q[pq]] - v0[t])
        bary = np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)
        mins = bary.min(axis=1)
        firsts = np.cumsum(nc) - nc
        gmax = np.maximum.reduceat(mins, firsts)
        is_best = mins == gmax[pq]
        pos = np.where(is_best, np.arange(pq.size), pq.size)
        pick = np.minimum.reduceat(pos, firsts)
        best_tet[q] = tet_ids[t[pick]]
        best_bary[q] = bary[pick]
        best_min[q] = gmax
        s = e
    inside = best_min >= -bary_tol
    return best_tet, best_bary, inside


def closest_on_boundary(mesh_points, tets, query_points):
    """The closest point of a mesh's boundary surface to each query point, as a boundary
    triangle and barycentric weights in it.

    Returns ``(triangles, weights, distances)``: (Q, 3) vertex ids, (Q, 3) weights summing
    to 1, and (Q,) distances.
    """
    import pyvista as pv

    P = np.asarray(mesh_points, float)
    tris = boundary_triangles(np.asarray(tets, np.int64))
    faces = np.hstack([np.full((tris.shape[0], 1), 3, np.int64), tris]).ravel()
    Q = np.asarray(query_points, float)
    cell, closest = pv.PolyData(P, faces).find_closest_cell(Q, return_closest_point=True)
    cell = np.atleast_1d(cell)
    closest = np.atleast_2d(closest)
    a, b, c = (P[tris[cell, i]] for i in range(3))
    v0, v1, v2 = b - a, c - a, closest - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    den = np.where(den == 0, 1.0, den)
    w1 = (d11 * d20 - d01 * d21) / den
    w2 = (d00 * d21 - d01 * d20) / den
    w = np.stack([1.0 - w1 - w2, w1, w2], axis=1)
    return tris[cell], w, np.linalg.norm(closest - Q, axis=1)


def _nearest_on_boundary(mesh_points, tets, mesh_values, query_points):
    """Value of the interpolant at the closest point of the mesh's boundary surface.

    Returns ``(values, distances)``.
    """
    tri, w, dist = closest_on_boundary(mesh_points, tets, query_points)
    fv = np.asarray(mesh_values, float)
    vals = w[:, 0] * fv[tri[:, 0]] + w[:, 1] * fv[tri[:, 1]] + w[:, 2] * fv[tri[:, 2]]
    return vals, dist


def evaluate_mesh_at_points(mesh_points, tets, mesh_values, query_points, *, outside="nearest",
                            bary_tol=1e-9, return_distance=False):
    """Piecewise-linear interpolant of a tetrahedral mesh evaluated at query points.

    Parameters
    ----------
    mesh_points : (K, 3) array_like
        Mesh vertex coordinates.
    tets : (M, 4) int array_like
        Tetrahedra as indices into ``mesh_points`` (any orientation; tetrahedra
        of (numerically) zero volume are ignored).
    mesh_values : (K,) array_like
        Values at the vertices.
    query_points : (Q, 3) array_like
        Where to evaluate.
    outside : {"nearest", "nan"}
        Value given to points not in any tetrahedron: the interpolant at the
        closest point of the mesh's boundary surface (default), or NaN.
    bary_tol : float
        A point counts as inside a tetrahedron when all its barycentric
        coordinates are ``>= -bary_tol``; points on faces, edges and vertices
        are inside (up to rounding, which this tolerance absorbs).
    return_distance : bool
        Also return each point's distance to the mesh (0 inside).

    Returns
    -------
    values : (Q,) float ndarray
    outside_mask : (Q,) bool ndarray
        True for points outside the mesh (never silently dropped: count them).
    distance : (Q,) float ndarray
        Only with ``return_distance=True``.

    Notes
    -----
    Point location is exact in the sense needed here: every tetrahedron whose
    bounding box contains a query point is tested, and the one in which the
    point's smallest barycentric coordinate is largest is used.  For a point on
    a face shared by two tetrahedra both give the same value of a conforming
    mesh's interpolant.
    """
    if outside not in ("nearest", "nan"):
        raise ValueError(f"outside must be 'nearest' or 'nan', got {outside!r}")
    P = np.asarray(mesh_points, float)
    T = np.asarray(tets, np.int64)
    F = np.asarray(mesh_values, float)
    Q = np.asarray(query_points, float)
    if P.ndim != 2 or P.shape[1] != 3 or F.shape != (P.shape[0],):
        raise ValueError(f"mesh_points must be (K, 3) and mesh_values (K,), got {P.shape}, {F.shape}")
    if T.ndim != 2 or T.shape[1] != 4:
        raise ValueError(f"tets must be (M, 4), got {T.shape}")
    if Q.ndim != 2 or Q.shape[1] != 3:
        raise ValueError(f"query_points must be (Q, 3), got {Q.shape}")
    tet, bary, inside = _locate(P, T, Q, bary_tol)
    vals = np.full(Q.shape[0], np.nan)
    if inside.any():
        vals[inside] = np.einsum("ij,ij->i", bary[inside], F[T[tet[inside]]])
    out = ~inside
    dist = np.zeros(Q.shape[0])
    if out.any() and T.shape[0]:
        nv, nd = _nearest_on_boundary(P, T, F, Q[out])
        if outside == "nearest":
            vals[out] = nv
        dist[out] = nd
    elif out.any():
        dist[out] = np.inf
    if return_distance:
        return vals, out, dist
    return vals, out


def _evaluate_against(data, mesh_points, tets, mesh_values, outside="nearest") -> dict:
    """Errors of a mesh at all data points plus outside-hull bookkeeping."""
    approx, out, dist = evaluate_mesh_at_points(mesh_points, tets, mesh_values, data.points,
                                                outside=outside, return_distance=True)
    d = np.abs(data.values - approx)
    res = errors_at_points(data.values, approx, data.interior_mask())
    res["n_outside"] = int(out.sum())
    res["max_outside_distance"] = float(dist[out].max()) if out.any() else 0.0
    res["E_inf_outside"] = float(d[out].max()) if out.any() else 0.0
    return res


# --------------------------------------------------------------------------- VTK


def _libc():
    try:
        name = ctypes.util.find_library("c")
        return ctypes.CDLL(name) if name else ctypes.CDLL(None)
    except OSError:  # pragma: no cover - platform without a loadable C library
        return None


_LIBC = _libc()
#: Whether this process has run VTK's decimator once (:func:`_warm_filter`)
_WARM = False


def _warm_filter():
    """Run VTK's decimator once in this process, on a tiny grid, unless done: its first run
    in a process differs from later ones with the same seed, and no measured run should be
    that one."""
    global _WARM
    if _WARM:
        return
    from ..data import sample_grid

    _WARM = True  # before the call, which comes back here
    vtk_quadric_decimation(sample_grid(4, 6), target_reduction=0.5)


def _seed_c_rand(seed):
    """Seed C ``rand()`` (used by VTK's decimator); returns whether it worked.

    The seed is mixed first: glibc treats ``srand(0)`` and ``srand(1)`` alike.
    """
    if seed is None or _LIBC is None:
        return False
    mixed = (int(seed) * 0x9E3779B1 + 0x7F4A7C15) & 0xFFFFFFFF
    try:
        _LIBC.srand(ctypes.c_uint(mixed))
        return True
    except AttributeError:  # pragma: no cover
        return False


@dataclass
class DecimatedMesh:
    """Output of :func:`vtk_quadric_decimation`.

    Attributes
    ----------
    points : (K, 3) float64
        Vertex positions chosen by VTK (generally not original data points).
    tets : (M, 4) int64
        Tetrahedra, indices into ``points``.
    values : (K,) float64
        Vertex values chosen by VTK (optimised with the positions).
    seconds : float
        Wall time of the VTK filter's ``Update()`` alone.
    build_seconds : float
        Wall time to build the input ``UnstructuredGrid`` (Kuhn split + VTK arrays).
    n_orphans : int
        Vertices VTK returned without any tetrahedron; dropped from ``points``.
    params : dict
        The settings used (target_reduction, n_edges, boundary_weight, ...).
    """

    points: np.ndarray
    tets: np.ndarray
    values: np.ndarray
    seconds: float
    build_seconds: float = 0.0
    n_orphans: int = 0
    params: dict = field(default_factory=dict)

    @property
    def n_vertices(self) -> int:
        return int(self.points.shape[0])


def tet_grid(data, tets=None, scalar_scale=1.0):
    """``pyvista.UnstructuredGrid`` of the data's tetrahedralisation with the values as scalars.

    Grid data use the Kuhn split (:func:`~trivsel.triangulation.kuhn_tetrahedra`),
    scattered data their Delaunay tetrahedra, unless ``tets`` is given.  The
    values (times ``scalar_scale``) are the active point scalars, named ``"f"``.
    """
    import pyvista as pv

    if tets is None:
        tets = kuhn_tetrahedra(data.shape) if data.is_grid else delaunay_tetrahedra(data.points)
    tets = np.asarray(tets, np.int64)
    cells = np.hstack([np.full((tets.shape[0], 1), 4, np.int64), tets]).ravel()
    ctypes_ = np.full(tets.shape[0], pv.CellType.TETRA, np.uint8)
    grid = pv.UnstructuredGrid(cells, ctypes_, np.asarray(data.points, float))
    grid.point_data["f"] = np.asarray(data.values, float) * float(scalar_scale)
    grid.point_data.active_scalars_name = "f"
    return grid


def vtk_quadric_decimation(data, target_reduction=None, *, n_edges=None, boundary_weight=100.0,
                           n_candidates=8, scalar_scale=1.0, seed=None, tets=None,
                           grid=None) -> DecimatedMesh:
    """Decimate the tetrahedralised data with ``vtkUnstructuredGridQuadricDecimation``.

    Parameters
    ----------
    data : PointData
        Grid (Kuhn split) or scattered (Delaunay) data.
    target_reduction : float, optional
        Fraction of the *tetrahedra* to remove (VTK's ``TargetReduction``).
        Ignored when ``n_edges`` is given.
    n_edges : int, optional
        Number of edge collapses (VTK's ``NumberOfEdgesToDecimate``); each
        removes exactly one vertex, so the output has ``N - n_edges`` vertices
        (fewer if orphans appear).  Exactly one of ``target_reduction`` and
        ``n_edges`` must be given.
    boundary_weight : float
        VTK's ``BoundaryWeight`` (default 100, VTK's own default).
    n_candidates : int
        Random candidate edges per collapse (VTK's ``NumberOfCandidates``, default 8).
    scalar_scale : float
        The values are multiplied by this before decimation (their weight in the
        4-D quadric) and divided by it afterwards.
    seed : int, optional
        Seed for C ``rand()`` before the run (reproducible output); ``None``
        continues the process's random sequence.
    tets : (M, 4) int array_like, optional
        Input tetrahedralisation instead of the default one.
    grid : pyvista.UnstructuredGrid, optional
        A prebuilt input from :func:`tet_grid` (saves rebuilding it in loops);
        must have been built with the same ``scalar_scale``.

    Returns
    -------
    DecimatedMesh
        ``points``, ``tets``, ``values`` and ``seconds`` (the filter alone).
    """
    import pyvista as pv
    from vtkmodules.vtkFiltersCore import vtkUnstructuredGridQuadricDecimation

    if (target_reduction is None) == (n_edges is None):
        raise ValueError("give exactly one of target_reduction and n_edges")
    if target_reduction is not None and not 0.0 <= float(target_reduction) <= 1.0:
        raise ValueError(f"target_reduction must be in [0, 1], got {target_reduction!r}")
    if n_edges is not None and (int(n_edges) < 0 or int(n_edges) >= data.n_points):
        raise ValueError(f"n_edges must be in [0, {data.n_points - 1}], got {n_edges!r}")
    if not scalar_scale or not np.isfinite(scalar_scale):
        raise ValueError(f"scalar_scale must be finite and non-zero, got {scalar_scale!r}")

    t0 = time.perf_counter()
    if grid is None:
        grid = tet_grid(data, tets=tets, scalar_scale=scalar_scale)
    build = time.perf_counter() - t0

    _warm_filter()
    flt = vtkUnstructuredGridQuadricDecimation()
    flt.SetInputData(grid)
    flt.SetScalarsName("f")
    flt.SetBoundaryWeight(float(boundary_weight))
    flt.SetNumberOfCandidates(int(n_candidates))
    if n_edges is not None:
        # TargetReduction 0 makes the tet-count criterion void; the edge count rules
        flt.SetTargetReduction(0.0)
        flt.SetNumberOfEdgesToDecimate(int(n_edges))
    else:
        flt.SetTargetReduction(float(target_reduction))
        flt.SetNumberOfEdgesToDecimate(0)
    seeded = _seed_c_rand(seed)
    t0 = time.perf_counter()
    flt.Update()
    seconds = time.perf_counter() - t0

    out = pv.wrap(flt.GetOutput())
    if out is None or out.n_points == 0:
        raise RuntimeError("vtkUnstructuredGridQuadricDecimation produced no output "
                           "(missing scalars or non-tetrahedral input?)")
    cd = out.cells_dict
    if set(cd) - {pv.CellType.TETRA}:
        raise RuntimeError(f"unexpected cell types in VTK output: {sorted(cd)}")
    T = np.asarray(cd.get(pv.CellType.TETRA, np.zeros((0, 4))), np.int64).reshape(-1, 4)
    pts = np.asarray(out.points, float)
    vals = np.asarray(out.point_data["scalars"], float) / float(scalar_scale)
    used = np.unique(T)
    n_orphans = int(pts.shape[0] - used.size)
    if n_orphans:
        remap = np.full(pts.shape[0], -1, np.int64)
        remap[used] = np.arange(used.size)
        pts, vals, T = pts[used], vals[used], remap[T]
    params = dict(target_reduction=target_reduction, n_edges=n_edges, boundary_weight=boundary_weight,
                  n_candidates=n_candidates, scalar_scale=scalar_scale, seed=seed, seeded=seeded)
    return DecimatedMesh(points=pts, tets=T, values=vals, seconds=seconds, build_seconds=build,
                         n_orphans=n_orphans, params=params)


def _match_once(data, n_target, tol_points, control, seed, grid, max_iter, **kw):
    """One decimation landing in ``[n_target - tol_points, n_target]`` vertices."""
    N = data.n_points
    tries = 0
    if control == "edges":
        n_edges = N - n_target
        best = None
        for _ in range(max_iter):
            tries += 1
            dm = vtk_quadric_decimation(data, n_edges=n_edges, seed=seed, grid=grid, **kw)
            nv = dm.n_vertices
            if nv <= n_target and (best is None or nv > best.n_vertices):
                best = dm
            if n_target - tol_points <= nv <= n_target:
                return dm, tries, True
            # orphans (or a stuck run) took away vertices: collapse fewer edges
            n_edges = max(0, n_edges - (n_target - nv)) if nv < n_target else n_edges + (nv - n_target)
        return best, tries, False
    # bisection on TargetReduction (fraction of tets removed; vertex count decreases with it)
    lo, hi = 0.0, 1.0
    # first guess: vertex and tet counts scale alike
    tr = float(np.clip(1.0 - n_target / N, 0.0, 1.0))
    best = None
    for _ in range(max_iter):
        tries += 1
        dm = vtk_quadric_decimation(data, target_reduction=tr, seed=seed, grid=grid, **kw)
        nv = dm.n_vertices
        if nv <= n_target and (best is None or nv > best.n_vertices):
            best = dm
        if n_target - tol_points <= nv <= n_target:
            return dm, tries, True
        if nv > n_target:
            lo = tr
        else:
            hi = tr
        tr = 0.5 * (lo + hi)
    return best, tries, False


def vtk_matched(data, n_target, runs=5, tol_points=3, *, control="edges", seed=0, max_iter=40,
                outside="nearest", scalar_scale=1.0, **vtk_kwargs) -> dict:
    """VTK decimation matched to a vertex budget, repeated, with error statistics.

    VTK lands on its own vertex count and draws edges at random.  Each run
    finds a decimation with ``n_target - tol_points <= n_vertices <= n_target``
    and evaluates its interpolant at every data point.

    Parameters
    ----------
    data : PointData
    n_target : int
        Vertex budget (e.g. the number of points trivsel selected, corners included).
    runs : int
        Number of independent runs (run ``r`` seeds C ``rand()`` with ``seed + r``).
    tol_points : int
        Allowed shortfall below ``n_target``.
    control : {"edges", "bisect"}
        ``"edges"``: ask VTK for ``N - n_target`` edge collapses (exact up to
        orphaned vertices, corrected by retrying).  ``"bisect"``: bisect
        ``TargetReduction`` until the count lands in the window.
    seed : int or None
        Base seed; ``None`` leaves C ``rand()`` unseeded (runs then differ
        between processes too).
    max_iter : int
        Decimations allowed per run to land in the window; if none lands the
        closest count at or below ``n_target`` is used and ``converged`` is False.
    outside : {"nearest", "nan"}
        Policy for points outside the decimated mesh; see
        :func:`evaluate_mesh_at_points` ("nearest" keeps eq. 19 over all points).
    scalar_scale : float
        Weight of the values in VTK's 4-D quadric (see :func:`vtk_quadric_decimation`).
    **vtk_kwargs
        ``boundary_weight``, ``n_candidates``.

    Returns
    -------
    dict
        Medians ``E_rms, E_rms_interior, E_inf, E_inf_interior`` and for each
        of them ``<key>_min`` / ``<key>_max`` (the spread over runs);
        ``n_vertices``, ``n_outside``, ``max_outside_distance``, ``n_orphans``,
        ``seconds`` (VTK filter time of the accepted run) and ``tries`` as
        per-run lists; ``seconds_median``, ``n_outside_median``; ``converged``
        (all runs landed in the window) and ``runs_detail`` (one dict per run).
    """
    if control not in ("edges", "bisect"):
        raise ValueError(f"control must be 'edges' or 'bisect', got {control!r}")
    N = data.n_points
    n_target = int(n_target)
    if not 5 <= n_target <= N:
        raise ValueError(f"n_target must be in [5, {N}], got {n_target}")
    grid = tet_grid(data, scalar_scale=scalar_scale)
    detail = []
    for r in range(int(runs)):
        s = None if seed is None else int(seed) + r
        dm, tries, ok = _match_once(data, n_target, int(tol_points), control, s, grid, int(max_iter),
                                    scalar_scale=scalar_scale, **vtk_kwargs)
        if dm is None:
            raise RuntimeError(f"VTK never reached {n_target} vertices or fewer in {max_iter} tries")
        ev = _evaluate_against(data, dm.points, dm.tets, dm.values, outside=outside)
        ev.update(n_vertices=dm.n_vertices, n_tets=int(dm.tets.shape[0]), n_orphans=dm.n_orphans,
                  seconds=dm.seconds, build_seconds=dm.build_seconds, tries=tries, converged=ok,
                  seed=s, target_reduction=dm.params["target_reduction"], n_edges=dm.params["n_edges"])
        detail.append(ev)
    res = {"n_target": n_target, "n_points": N, "runs": int(runs), "control": control,
           "tol_points": int(tol_points), "outside_policy": outside, "scalar_scale": scalar_scale}
    for k in ERROR_KEYS:
        v = np.array([d[k] for d in detail], float)
        res[k] = float(np.median(v))
        res[k + "_min"] = float(v.min())
        res[k + "_max"] = float(v.max())
    for k in ("n_vertices", "n_tets", "n_outside", "max_outside_distance", "E_inf_outside", "n_orphans",
              "seconds", "tries"):
        res[k] = [d[k] for d in detail]
    res["seconds_median"] = float(np.median(res["seconds"]))
    res["n_outside_median"] = float(np.median(res["n_outside"]))
    res["converged"] = all(d["converged"] for d in detail)
    res["runs_detail"] = detail
    return res


# --------------------------------------------------------------------------- subsets + Delaunay


@dataclass
class SubsetResult:
    """A subset of the data points, Delaunay-triangulated, with its errors.

    Attributes
    ----------
    selected : (K,) int64
        Selected original point indices (sorted), corners included.
    tets : (M, 4) int64
        Delaunay tetrahedra as *original* point indices (like trivsel's snapshots).
    errors : dict
        ``E_rms, E_rms_interior, E_inf, E_inf_interior`` at all data points,
        plus ``n_outside``, ``max_outside_distance``, ``E_inf_outside``.
    seconds : float
        Triangulation time (selection excluded, evaluation excluded).
    """

    selected: np.ndarray
    tets: np.ndarray
    errors: dict
    seconds: float

    @property
    def n_selected(self) -> int:
        return int(self.selected.size)


def _corner_indices(data):
    """The 8 grid corners, or the convex-hull vertices of scattered data."""
    if data.is_grid:
        return cube_corners(data.shape)
    return hull_triangles(data.points)[1]


def _delaunay_subset(data, selected, outside="nearest") -> SubsetResult:
    sel = np.unique(np.asarray(selected, np.int64))
    t0 = time.perf_counter()
    local = delaunay_tetrahedra(data.points[sel])
    seconds = time.perf_counter() - t0
    tets = sel[local]
    ev = _evaluate_against(data, data.points, tets, data.values, outside=outside)
    return SubsetResult(selected=sel, tets=tets, errors=ev, seconds=seconds)


def _check_target(data, n_target, n_corners):
    n_target = int(n_target)
    if not max(n_corners, 5) <= n_target <= data.n_points:
        raise ValueError(f"n_target must be in [{max(n_corners, 5)}, {data.n_points}] "
                         f"(corners included), got {n_target}")
    return n_target


def random_delaunay(data, n_target, seed=0, *, outside="nearest") -> SubsetResult:
    """Random subset of ``n_target`` points, corners always included, plain Delaunay.

    Parameters
    ----------
    data : PointData
    n_target : int
        Total number of points kept, the 8 corners (hull vertices for scattered
        data) included.
    seed : int or numpy.random.Generator
        Random seed.
    outside : {"nearest", "nan"}
        Outside-point policy (the corners span the hull, so normally none).

    Returns
    -------
    SubsetResult
    """
    corners = _corner_indices(data)
    n_target = _check_target(data, n_target, corners.size)
    rng = np.random.default_rng(seed)
    rest = np.setdiff1d(np.arange(data.n_points), corners)
    pick = rng.choice(rest, size=n_target - corners.size, replace=False)
    return _delaunay_subset(data, np.concatenate([corners, pick]), outside=outside)


def curvature_delaunay(data, order, n_target, *, outside="nearest") -> SubsetResult:
    """The first points of a ranking plus the corners, plain Delaunay.

    Parameters
    ----------
    data : PointData
    order : (K,) int array_like
        Point indices, most important first (e.g. descending absolute
        curvature).  Corners in it are skipped (they are always kept);
        duplicates are ignored.
    n_target : int
        Total number of points kept, corners included: the corners plus the
        first ``n_target - 8`` non-corner points of ``order``.

    Returns
    -------
    SubsetResult
        Beside the paper's data-dependent mesh on the same points this isolates
        the value of the data-dependent swapping of section 4.
    """
    corners = _corner_indices(data)
    n_target = _check_target(data, n_target, corners.size)
    order = np.asarray(order, np.int64).ravel()
    if order.size and (order.min() < 0 or order.max() >= data.n_points):
        raise ValueError(f"order holds indices outside [0, {data.n_points - 1}]")
    _, first = np.unique(order, return_index=True)
    order = order[np.sort(first)]
    order = order[~np.isin(order, corners)]
    need = n_target - corners.size
    if order.size < need:
        raise ValueError(f"order has only {order.size} non-corner points, {need} needed for n_target={n_target}")
    return _delaunay_subset(data, np.concatenate([corners, order[:need]]), outside=outside)
