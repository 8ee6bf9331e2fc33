"""Top-down selection, shared by the insertion methods (``paper``, ``greedy``).

Section 3 and 4 of the paper, put together for any method that inserts points:

1. fixed points (the convex hull's vertices; the 8 corners of a grid; or the vertices
   of prescribed boundary triangles) and the triangulation of the boundary
   (section 3, Definition 1);
2. the candidates ranked by the method (the paper's by absolute curvature, sections
   2-3; ``greedy`` chooses them as it goes);
3. insertion into a tetrahedral mesh (:mod:`trivsel.mesh`) with data-dependent swapping
   after each insertion (section 4), until a count, a fraction or an error tolerance;
4. snapshots at the requested counts with E_RMS and E_inf, with and without the
   boundary points (section 5, eqs. 19-20), and optionally least-squares vertex
   values on the same mesh.

A method module that inserts defines ``GREEDY_QUEUE``, ``needs_curvature``, ``rank``,
``start`` and ``advance`` (:mod:`trivsel.methods`) and runs with :func:`run_insertion`.
"""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import replace

import numpy as np

from ..exceptions import InputError, one_line
from ..norms import error_norms
from ..resources import interruptible
from ..result import Snapshot
from ..selection import candidate_points
from ..triangulation import (box_tetrahedra, boundary_cone, check_closed_surface, cube_corners, delaunay_tetrahedra,
                             hull_triangles, scattered_start)
from .protocol import MethodRun, requested_fractions, unreached

__all__ = ["run_insertion", "insertion_memory", "insertion_protocol", "check_domain"]

log = logging.getLogger("trivsel")


def check_domain(name, data):
    """Insertion starts from the convex hull of the points: a mesh read with its cells, whose
    domain may not be convex, is refused rather than silently re-triangulated."""
    if getattr(data, "tets", None) is not None:
        raise InputError(f"method {name!r} triangulates the points' convex hull and would drop the mesh's "
                         f"{len(data.tets)} tetrahedra: use method 'decimate' (or 'auto') for a mesh")


def insertion_memory(method, data, options):
    """The peak memory of an insertion run, as ``[(bytes, what), ...]`` for the memory check."""
    from ..resources import DELAUNAY_BYTES_PER_POINT, MESH_BYTES_PER_POINT

    N = data.n_points
    need = [(MESH_BYTES_PER_POINT * float(N), f"reducing {N} points")]
    if not data.is_grid and method.needs_curvature(options):
        need.append((DELAUNAY_BYTES_PER_POINT * float(N), f"the Delaunay tetrahedra of {N} scattered points"))
    return need


def insertion_protocol(module_name):
    """``run``, ``memory`` and ``compile_kernels`` of the insertion method defined in the
    module ``module_name``: the top-down run of :mod:`trivsel.methods.insertion` with the
    module's ``rank``, ``start`` and ``advance``, and the kernels of :mod:`trivsel.mesh`."""
    def run(problem):
        """The whole run (:func:`trivsel.methods.insertion.run_insertion`)."""
        return run_insertion(sys.modules[module_name], problem)

    def memory(data, options):
        """Peak memory, as ``[(bytes, what), ...]`` (:func:`~trivsel.methods.insertion.insertion_memory`)."""
        return insertion_memory(sys.modules[module_name], data, options)

    def compile_kernels(part=None):
        """Compile (or load) the method's kernels (:func:`trivsel.mesh.compile_kernels`)."""
        from ..mesh import compile_kernels as compile_mesh

        return compile_mesh(sys.modules[module_name].NAME, part)

    return run, memory, compile_kernels


def run_insertion(method, problem):
    """Run the insertion ``method`` (a module of :mod:`trivsel.methods`) on ``problem``
    (:class:`~trivsel.methods.protocol.Problem`); returns a
    :class:`~trivsel.methods.protocol.MethodRun`."""
    data, opts, stop, boundary = problem.data, problem.options, problem.stop, problem.boundary
    N = data.n_points

    # --- fixed points and the initial triangulation (section 3)
    if boundary is not None:
        if not data.is_grid:
            raise InputError("a prescribed boundary needs grid data (a .vti, NIfTI, NRRD or array volume)")
        boundary = _boundary_on_box(data, boundary)
        fixed = np.unique(boundary)
        all_tets = start_tets = None  # the cone, once its apex is known
        opts = replace(opts, boundary_flips=False)
    elif data.is_grid:
        fixed = cube_corners(data.shape)
        start_tets = box_tetrahedra(data.shape, opts.boundary_diagonals)
        all_tets = None  # grids: the curvature graph comes from the Kuhn stencil
    else:
        from scipy.spatial import QhullError

        try:
            # Qhull runs for minutes on millions of points: interruptible keeps Ctrl-C prompt
            log.info("convex hull and start mesh of %d points", N)
            _, fixed = interruptible(hull_triangles, data.points)
            start_tets, fixed = interruptible(scattered_start, data.points, fixed)
            all_tets = None
            if method.needs_curvature(opts):
                log.info("Delaunay tetrahedra of %d points (the curvature fit's neighbours)", N)
                all_tets = interruptible(delaunay_tetrahedra, data.points)
        except QhullError as exc:
            raise InputError(f"Qhull cannot triangulate these points: {one_line(exc, first=True)}") from None
    interior = interruptible(data.interior_mask)

    # --- targets
    # a prescribed boundary: only interior points are candidates, and the first of
    # them (the apex of the start) is fixed too
    cand = candidate_points(N, fixed, interior, "interior" if boundary is not None else opts.candidates)
    if boundary is not None and not len(cand):
        raise InputError(f"a prescribed boundary needs an interior point; the grid {data.shape} has none")
    n_fixed = len(fixed) + (boundary is not None)
    targets = problem.targets()
    n_max = len(fixed) + len(cand)
    for m in targets:
        if m < n_fixed:
            raise InputError(f"target of {m} points is fewer than the {n_fixed} fixed points "
                             f"(fractions {problem.stop['fractions']}, N = {N}): the smallest fraction is "
                             f"{n_fixed / N:.3g}, or give --count {n_fixed} or more")
        if m > n_max:
            raise InputError(f"target of {m} points exceeds the {n_max} selectable points "
                             f"({n_fixed} fixed + {len(cand)} candidates of set {opts.candidates!r})")
    if not targets:  # tolerance only
        targets = [n_max]

    # --- ranking (sections 2-3)
    t0 = time.perf_counter()
    if method.needs_curvature(opts):
        log.info("curvature of %d points (%s)", N, opts.curvature)
    K, order = interruptible(method.rank, data, cand, opts, tets=all_tets, threads=problem.threads)
    if boundary is not None:
        apex = int(order[0]) if K is not None else _nearest_centre(data, cand)
        start_tets = boundary_cone(data.ijk, boundary, apex)
        fixed = np.append(fixed, apex)
        order = order[order != apex]
    log.info("inserting up to %d of %d points", targets[-1], N)
    t_curv = time.perf_counter() - t0

    # --- insertion with data-dependent swapping (section 4); the mesh grows its
    # capacities and starts again when a run outgrows them
    run = _Run(data, method, opts, stop, fixed, order, interior, problem.check, problem.progress,
               problem.t_start, prescribed=boundary is not None)
    from ..mesh import MeshError

    for _ in range(4):
        try:
            run.execute(start_tets, targets)
            break
        except MeshError as exc:
            if not run.grow(exc.code):
                raise
        except ZeroDivisionError:  # the kernels' weights in a tetrahedron whose volume rounds to zero
            raise InputError(f"the points are too near a plane or a line for {method.NAME!r}: a tetrahedron of "
                             "their mesh has no volume in floating point; --method decimate takes them") from None
    else:  # pragma: no cover - capacities doubled 4 times
        raise RuntimeError("mesh capacity could not be satisfied")
    t_total = time.perf_counter() - problem.t_start
    timings = {"curvature": t_curv, "selection": t_total - t_curv - run.t_errors, "errors": run.t_errors,
               "total": t_total}
    inserted = np.asarray(run.inserted, np.int64)
    last = run.snapshots[-1]  # errors and tolerances both in the units of the data
    if stop["tol_rms"] is not None and last.errors["E_rms"] <= stop["tol_rms"]:
        reason = "E_RMS <= tol_rms was met"
    elif stop["tol_inf"] is not None and last.errors["E_inf"] <= stop["tol_inf"]:
        reason = "E_inf <= tol_inf was met"
    elif last.n_selected == n_max:
        reason = "every selectable point was inserted"
    else:
        reason = "no candidate was left to insert"
    notes = unreached(stop, N, last.n_selected, reason, up=True)
    return MethodRun(snapshots=run.snapshots, selected=run.snapshots[-1].selected, curvature=K, notes=notes,
                     order=order if K is not None else inserted, timings=timings, stats=run.stats)


def _boundary_on_box(data, boundary):
    """The prescribed boundary, checked: a closed surface (:func:`check_closed_surface`)
    of points on the box's surface whose triangles tile it (their areas, projected on
    each face's axis, sum to the box's surface area: no gap, no overlap)."""
    tris = check_closed_surface(boundary, data.n_points)
    inside = np.any(data.interior_mask()[tris], axis=1)
    if inside.any():
        bad = tris[np.flatnonzero(inside)[0]]
        raise InputError(f"boundary triangle {tuple(int(v) for v in bad)} has a vertex inside the box, "
                         f"not on its surface")
    # each triangle in one face of the box: a triangle across an edge (cutting a corner
    # off) can tile the surface's projected area and still leave a grid point outside
    ijk = data.ijk[tris]  # (m, 3 vertices, 3 axes)
    hi = np.asarray(data.shape) - 1
    on_face = np.any(np.all(ijk == 0, axis=1) | np.all(ijk == hi, axis=1), axis=1)
    if not on_face.all():
        bad = tris[np.flatnonzero(~on_face)[0]]
        raise InputError(f"boundary triangle {tuple(int(v) for v in bad)} does not lie in one face of the box "
                         f"(its vertices are on different faces): it would leave grid points outside the mesh")
    c = data.ijk.astype(float)
    area2 = np.abs(np.cross(c[tris[:, 1]] - c[tris[:, 0]], c[tris[:, 2]] - c[tris[:, 0]])).sum()
    nx, ny, nz = (s - 1 for s in data.shape)
    if area2 != 4.0 * (nx * ny + ny * nz + nx * nz):
        raise InputError(f"the boundary triangles cover {area2 / 2:g} of the box surface's "
                         f"{2 * (nx * ny + ny * nz + nx * nz)} (grid units): gaps, overlaps or slanted triangles")
    return tris


def _nearest_centre(data, candidates):
    """The candidate nearest the centre of the grid (ties: the smallest index)."""
    centre2 = np.asarray(data.shape, np.int64) - 1  # twice the centre, in grid units
    d = np.sum((2 * data.ijk[candidates] - centre2) ** 2, axis=1)
    return int(candidates[np.argmin(d)])


#: Target wall time of one call into the compiled insertion loop (see ``_Run.execute``).
CHUNK_SECONDS = 0.25
#: A fixed number of insertions per call instead (tests: the result must not depend on it).
CHUNK_STEP = None


class _Run:
    """One insertion run to the targets: the mesh, its snapshots and counters."""

    def __init__(self, data, method, opts, stop, fixed, order, interior, check, progress, t_start, prescribed=False):
        self.data, self.method, self.opts, self.stop = data, method, opts, stop
        self.prescribed = prescribed
        self.fixed, self.order, self.interior = fixed, order, interior
        self.check, self.progress, self.t_start = check, progress, t_start
        self.tet_cap = self.pool_cap = None

    def grow(self, code):
        """Double the capacity that ran out; False for any other mesh error."""
        from .. import mesh as _mesh

        N = self.data.n_points
        if code == _mesh.ERR_TETCAP:
            self.tet_cap = 2 * (self.tet_cap or 8 * N + 1024)
        elif code == _mesh.ERR_POOLCAP:
            self.pool_cap = 2 * (self.pool_cap or 24 * N + 4096)
        else:
            return False
        return True

    def _mesh(self):
        from .. import mesh as _mesh

        o, data = self.opts, self.data
        return _mesh.TetMesh(data.points, data.values, data.ijk, criterion=o.criterion,
                             vertices_in_error=o.vertices_in_error, rel_tol=o.rel_tol, tol_inf=self.stop["tol_inf"],
                             first_improving=o.first_improving, tet_capacity=self.tet_cap,
                             pool_capacity=self.pool_cap, greedy=self.method.GREEDY_QUEUE, greedy_key=o.greedy_key,
                             candidates=self.order, boundary_flips=o.boundary_flips,
                             max_rounds=o.max_flips or _mesh.UNLIMITED_ROUNDS, swap_memory=o.swap_memory)

    def _tolerance_met(self, tm):
        tol_rms, tol_inf = self.stop["tol_rms"], self.stop["tol_inf"]
        if tol_rms is None and tol_inf is None:
            return False
        e = error_norms(tm.residuals()[0], self.interior)
        return (tol_rms is not None and e["E_rms"] <= tol_rms) or (tol_inf is not None and e["E_inf"] <= tol_inf)

    def _compiled_tolerance_met(self, tm, stop_tol):
        """The compiled loops' own stopping test, on their running sums."""
        if stop_tol >= 0.0 and np.sqrt(max(tm.sse_sum, 0.0) / float(self.data.n_points)) <= stop_tol:
            return True
        return self.stop["tol_inf"] is not None and tm.n_above_tol_inf == 0

    def execute(self, start_tets, targets):
        data, N, method, order = self.data, self.data.n_points, self.method, self.order
        tm = self._mesh()
        start_ids = tm.start(start_tets)
        if self.prescribed:
            # the cone from the first interior point is section 3's first
            # triangulation: swap it as after an insertion (section 4)
            tm.swap(start_ids)
            if self.check is not None:
                self.check(tm)
        n_fixed = len(self.fixed)
        stop_tol = -1.0 if self.stop["tol_rms"] is None else float(self.stop["tol_rms"])
        pos = 0  # candidates inserted so far
        inserted = []
        self.t_errors = 0.0
        self.snapshots = []
        reached_tol = self._tolerance_met(tm)
        last = targets[-1] - n_fixed
        # The compiled loop runs in chunks of about CHUNK_SECONDS, so that Ctrl-C (which
        # Python sees only between chunks) stops the run promptly and a progress display
        # updates.  A run's result does not depend on where the chunks end.
        # with a progress display, also at least about 200 updates
        cap = max(1, last // 200) if self.progress is not None else last + 16
        step = min(CHUNK_STEP or 16, cap)
        for target in targets:
            need = target - n_fixed
            if pos < need and not reached_tol:
                if pos == 0 and not self.prescribed:
                    pos = method.start(tm, order)
                    inserted.extend(order[:pos].tolist())
                    if pos and self.check is not None:
                        self.check(tm)
                while pos < need:
                    chunk_end = min(need, pos + step)
                    t_chunk = time.perf_counter()
                    new_pos, new = method.advance(tm, order, pos, chunk_end, stop_tol, n_fixed)
                    if not CHUNK_STEP:
                        took = time.perf_counter() - t_chunk
                        step = int(min(max(step * CHUNK_SECONDS / max(took, 1e-6), 16), 4 * step, cap))
                    inserted.extend(np.asarray(new).tolist())
                    # tolerance met, or nothing left to improve (the paper's loop tests the
                    # tolerance after an insertion, so a chunk's last one is tested here)
                    stalled = new_pos < chunk_end or self._compiled_tolerance_met(tm, stop_tol)
                    pos = new_pos
                    if self.progress is not None:
                        self.progress(n_fixed + pos, n_fixed + last, float(np.sqrt(max(tm.sse_sum, 0.0) / N)),
                                      float(np.max(np.abs(tm.resid))), time.perf_counter() - self.t_start)
                    if stalled:
                        reached_tol = True
                        break
                reached_tol = reached_tol or self._tolerance_met(tm)
            self.snapshots.append(self._snapshot(tm, n_fixed + pos, inserted))
            if reached_tol:
                break
        requested_fractions(self.snapshots, self.stop["fractions"], N)
        self.inserted = inserted
        self.stats = {"flips": tm.flips, "cases": tm.cases, "evaluations": tm.evaluations,
                      "tets": int(len(tm.live_ids())), "round_cap_hits": tm.round_cap_hits}

    def _snapshot(self, tm, m, inserted):
        te = time.perf_counter()
        data, interior = self.data, self.interior
        snap_mesh = tm
        if self.opts.final_pass:
            snap_mesh = tm.copy()
            snap_mesh.global_pass()
        if self.check is not None:
            self.check(snap_mesh)
        r, _ = snap_mesh.residuals()
        fit = None
        if "fit" in self.opts.values:
            from ..fitting import fit_on_mesh

            fit = fit_on_mesh(snap_mesh, data.values, interior)
        snap = Snapshot(fraction=m / data.n_points, n_selected=m,
                        selected=np.concatenate([self.fixed, np.asarray(inserted, np.int64)]),
                        tets=snap_mesh.tetrahedra(), residuals=r, errors=error_norms(r, interior),
                        seconds=time.perf_counter() - self.t_start, flips=snap_mesh.flips, fit=fit)
        self.t_errors += time.perf_counter() - te
        return snap
