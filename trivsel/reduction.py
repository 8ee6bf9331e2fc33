"""The whole method: :func:`reduce` (sections 2-5 put together).

1. fixed points (the convex hull's vertices; the 8 corners of a grid) and the
   triangulation of the boundary (section 3, Definition 1);
2. the candidates ranked by the method (:mod:`trivsel.methods`): the paper's by
   absolute curvature (sections 2-3);
3. insertion into a tetrahedral mesh with data-dependent swapping after each
   insertion (section 4), until a count, a fraction or an error tolerance;
4. snapshots at the requested counts with E_RMS and E_inf, with and without the
   boundary points (section 5, eqs. 19-20), and optionally least-squares vertex
   values on the same mesh.
"""

from __future__ import annotations

import inspect
import math
import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .data import PointData, sample_grid
from .functions import resolve_function
from .exceptions import InputError, check_threads, one_line, shown
from .methods import get_method
from .norms import error_norms
from .options import Options, check_applicable, option_fields
from .resources import interruptible
from .selection import candidate_points, count_for_fraction, validate_fractions
from .triangulation import (box_tetrahedra, boundary_cone, check_closed_surface, cube_corners, delaunay_tetrahedra,
                            hull_triangles, scattered_start)

__all__ = ["reduce", "ReductionResult", "Snapshot"]

#: Stage messages (INFO) of long runs: the command line shows them on a terminal.
log = logging.getLogger("trivsel")


@dataclass
class Snapshot:
    """The mesh when ``n_selected`` points are selected.

    ``tets`` index the original points; ``errors`` holds E_rms, E_rms_interior,
    E_inf, E_inf_interior; ``seconds`` is the wall time from the start of the run
    until this snapshot (curvature included).
    """

    fraction: float
    n_selected: int
    selected: np.ndarray
    tets: np.ndarray
    residuals: np.ndarray
    errors: dict
    seconds: float
    flips: dict = field(default_factory=dict)
    fit: dict | None = None  # values="fit": {"values": (m,) at sorted vertices, "residuals", "errors"}


@dataclass
class ReductionResult:
    """What :func:`reduce` returns.

    Attributes
    ----------
    data : PointData
    selected : (m,) int
        Selected point indices in insertion order: fixed points first, then the
        candidates as inserted (``selected[:k]`` is the selection of size k).
    curvature : (N,) float or None
        Absolute curvature K of every point (eq. 10); None for a method that does
        not rank by curvature (``greedy`` chooses points by their error).
    order : (M,) int
        The candidates in ranked order (``greedy``: the points as inserted).
    snapshots : list of Snapshot
        One per requested fraction/count, ascending by count.
    options : dict
        Every option used (:class:`~trivsel.options.Options`, method defaults
        resolved) and the stopping rule (``fractions``, ``count``, ``tol_rms``,
        ``tol_inf``).
    timings : dict
        Seconds for ``curvature``, ``selection`` (insertion and swapping),
        ``errors``, and ``total``.
    stats : dict
        Insertion cases and flip counts at the end of the run.
    notes : list of str
        What the run could not do as asked: each requested fraction or count that it
        did not reach (a tolerance stopped it first, or no point was left to insert or
        remove), with the count it stopped at.  Also logged as warnings.
    """

    data: PointData
    selected: np.ndarray
    curvature: np.ndarray | None
    order: np.ndarray
    snapshots: list
    options: dict
    timings: dict
    stats: dict
    notes: list = field(default_factory=list)

    def snapshot(self, fraction):
        """The snapshot for ``fraction`` (nearest match)."""
        return min(self.snapshots, key=lambda s: abs(s.fraction - float(fraction)))

    def errors_frame(self):
        """One row per snapshot with the columns of ``errors.csv``, as a pandas DataFrame.

        No wall times: two runs with the same input and options give the same table
        (the times are in ``result.json``: ``snapshots[*].seconds`` and ``timings``)."""
        import pandas as pd

        return pd.DataFrame(self.error_rows())

    def error_rows(self):
        """The rows of :meth:`errors_frame` as a list of dicts (column order kept)."""
        rows = []
        for mode in self.options.get("values", ["data"]):
            for s in self.snapshots:
                err = s.errors if mode == "data" else s.fit["errors"]
                rows.append({
                    "function": self.data.name,
                    "n": self.data.meta.get("n", (self.data.shape[0] - 1) if self.data.shape else ""),
                    "method": self.options["method"],
                    "values": mode,
                    "fraction": s.fraction,
                    "n_selected": s.n_selected,
                    **{k: err[k] for k in ("E_rms", "E_rms_interior", "E_inf", "E_inf_interior")},
                })
        return rows


_STOP_PARAMS = """    data : PointData, int or str
        The data; a Table-1 function number or name is sampled on the ``(n+1)^3``
        grid of eq. (18).
    fractions : sequence of float in (0, 1], optional
        Stop at these fractions of all points (fixed points included, rounded half
        up: 50 % of 4913 is 2457).  One run goes to the largest; the others are
        snapshots on the way.
    count : int, optional
        Stop at this number of points instead (also a snapshot).
    tol_rms, tol_inf : float, optional
        Error tolerances of E_RMS (eq. 19) and E_inf (eq. 20) over all points.  The
        inserting methods (``paper``, ``greedy``) stop as soon as the error is at or
        below the tolerance (or when every candidate is inserted); ``decimate`` stops
        before a removal would raise the error above it (or when no removal is
        left).  A fraction or count that the run does not reach first is noted in
        :attr:`ReductionResult.notes` and logged as a warning.
    n : int
        Grid intervals per axis when ``data`` is a Table-1 function (the paper: 16).
    boundary : (m, 3) int array, optional
        Prescribed boundary triangles of grid data (indices of its points): a closed,
        consistently oriented triangulation of the box's surface.  Section 3's start
        with these triangles instead of the 12 of the box: their vertices are fixed,
        the first interior point (the paper: the largest curvature; greedy: the one
        nearest the centre) is joined to every triangle, only interior points are
        inserted and no flip changes the boundary.  A neighbouring box given the same
        triangles on a shared face meets this mesh conformingly
        (:mod:`trivsel.blocks`).
    options : Options, optional
        Every choice of the method at once; the keyword options below override its
        fields.
    threads : int
        Threads for the curvature fits (section 2), the only stage that runs in
        parallel; the result does not depend on it.
    check : callable, optional
        Called as ``check(mesh)`` after the first insertion and at every snapshot
        (tests pass :func:`trivsel.mesh.check_mesh`).
    progress : callable, optional
        Called about 200 times as ``progress(n_selected, n_target, e_rms, e_inf,
        seconds)`` with the current E_RMS and E_inf over all points; ``n_target`` is
        the count the run goes to (up by insertion; ``decimate`` counts down to it
        from the full grid, and calls first with the full grid's count)."""


def reduce(data, *, fractions=None, count=None, tol_rms=None, tol_inf=None, n=16, boundary=None, options=None,
           threads=1, check=None, progress=None, **option_overrides):
    t_start = time.perf_counter()
    opts = _options(options, option_overrides)
    method = get_method(opts.method)
    if not isinstance(data, PointData):
        data = sample_grid(resolve_function(data), n)
    method.check(data, opts)
    threads = check_threads(threads)
    fractions = validate_fractions(fractions)
    N = data.n_points
    for name, tol in (("tol_rms", tol_rms), ("tol_inf", tol_inf)):
        if tol is not None and not (np.isfinite(tol) and tol >= 0):
            raise InputError(f"{name} must be a finite number >= 0, got {shown(tol)}")
    if count is not None and (isinstance(count, bool) or int(count) != count or not 1 <= count <= N):
        raise InputError(f"count must be an integer in [1, {N}], got {shown(count)}")
    if not fractions and count is None and tol_rms is None and tol_inf is None:
        raise InputError("give fractions, a count, or an error tolerance (tol_rms / tol_inf) to stop at")
    stop = dict(fractions=fractions, count=count, tol_rms=tol_rms, tol_inf=tol_inf)
    from .resources import DELAUNAY_BYTES_PER_POINT, MESH_BYTES_PER_POINT, check_memory

    check_memory(MESH_BYTES_PER_POINT * float(N), f"reducing {N} points")
    if not data.is_grid and method.needs_curvature(opts):
        check_memory(DELAUNAY_BYTES_PER_POINT * float(N), f"the Delaunay tetrahedra of {N} scattered points")
    user_data, user_stop = data, stop
    data, scaling = _safe_scale(data)
    stop = scaling.stop_in(stop)
    if getattr(method, "DECIMATES", False):
        return _decimate(data, user_data, scaling, stop, user_stop, opts, boundary, check, progress, t_start)

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
    targets = _target_counts(fractions, count, N)
    n_max = len(fixed) + len(cand)
    for m in targets:
        if m < n_fixed:
            raise InputError(f"target of {m} points is fewer than the {n_fixed} fixed points "
                             f"(fractions {fractions}, N = {N}): the smallest fraction is "
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
    K, order = interruptible(method.rank, data, cand, opts, tets=all_tets, threads=threads)
    if boundary is not None:
        apex = int(order[0]) if K is not None else _nearest_centre(data, cand)
        start_tets = boundary_cone(data.ijk, boundary, apex)
        fixed = np.append(fixed, apex)
        order = order[order != apex]
    log.info("inserting up to %d of %d points", targets[-1], N)
    t_curv = time.perf_counter() - t0

    # --- insertion with data-dependent swapping (section 4); the mesh grows its
    # capacities and starts again when a run outgrows them
    run = _Run(data, method, opts, stop, fixed, order, interior, check, scaling.progress_out(progress), t_start,
               prescribed=boundary is not None)
    from .mesh import MeshError

    for _ in range(4):
        try:
            run.execute(start_tets, targets)
            break
        except MeshError as exc:
            if not run.grow(exc.code):
                raise
    else:  # pragma: no cover - capacities doubled 4 times
        raise RuntimeError("mesh capacity could not be satisfied")
    t_total = time.perf_counter() - t_start
    timings = {"curvature": t_curv, "selection": t_total - t_curv - run.t_errors, "errors": run.t_errors,
               "total": t_total}
    inserted = np.asarray(run.inserted, np.int64)
    last = run.snapshots[-1]  # errors and tolerances both scaled (see _Scaling)
    if stop["tol_rms"] is not None and last.errors["E_rms"] <= stop["tol_rms"]:
        reason = "E_RMS <= tol_rms was met"
    elif stop["tol_inf"] is not None and last.errors["E_inf"] <= stop["tol_inf"]:
        reason = "E_inf <= tol_inf was met"
    elif last.n_selected == n_max:
        reason = "every selectable point was inserted"
    else:
        reason = "no candidate was left to insert"
    notes = _unreached(fractions, count, N, last.n_selected, reason, up=True)
    return ReductionResult(data=user_data, selected=run.snapshots[-1].selected, curvature=scaling.curvature_out(K),
                           order=order if K is not None else inserted,
                           snapshots=[scaling.snapshot_out(s) for s in run.snapshots],
                           options={**opts.to_dict(), **user_stop}, timings=timings, stats=run.stats, notes=notes)


def _unreached(fractions, count, N, stopped_at, reason, *, up):
    """One note, logged as a warning, per requested fraction or count that a run stopping
    at ``stopped_at`` points did not reach (counting ``up`` by insertion, else down)."""
    asked = [(f"fraction {f:g} ({count_for_fraction(f, N)} points)", count_for_fraction(f, N)) for f in fractions]
    if count is not None:
        asked.append((f"count {int(count)}", int(count)))
    notes = []
    for what, m in asked:
        if (m > stopped_at) if up else (m < stopped_at):
            notes.append(f"{what} not reached: the run stopped at {stopped_at} points ({reason})")
            log.warning("warning: %s", notes[-1])
    return notes


def _target_counts(fractions, count, N):
    """The point counts to stop at, ascending: each fraction's (rounded half up) and ``count``."""
    return sorted({count_for_fraction(f, N) for f in fractions} | ({int(count)} if count is not None else set()))


def _requested_fractions(snapshots, fractions, N):
    """Label the snapshots that hit a requested fraction's count with that fraction as
    requested (not m / N)."""
    req = {count_for_fraction(f, N): f for f in fractions}
    for s in snapshots:
        if s.n_selected in req:
            s.fraction = req[s.n_selected]


def _decimate(data, user_data, scaling, stop, user_stop, opts, boundary, check, progress, t_start):
    """``method="decimate"``: the run goes down from the full grid (:mod:`trivsel.decimation`)."""
    from .decimation import EXACT_WITHIN, reduce_by_collapse
    from .resources import check_memory

    if boundary is not None:
        raise InputError("method 'decimate' cannot take a prescribed boundary; use 'greedy' or 'paper'")
    N = data.n_points
    check_memory(DECIMATION_BYTES_PER_POINT * float(N), f"decimating {N} points")
    interior = data.interior_mask()
    n_fixed = int(np.sum(~interior)) if opts.candidates == "interior" else 8
    targets = _target_counts(stop["fractions"], stop["count"], N)
    for m in targets:
        if m < n_fixed:
            raise InputError(f"target of {m} points is fewer than the {n_fixed} points that decimation keeps "
                             f"(candidates {opts.candidates!r}, N = {N}): give --count {n_fixed} or more")
    if not targets:  # tolerance only: as far down as the tolerance allows
        targets = [n_fixed]
    log.info("decimating %d points down to %d", N, targets[0])
    snaps, selected, stats, t_errors = reduce_by_collapse(
        data, targets, tol_rms=stop["tol_rms"], tol_inf=stop["tol_inf"], candidates=opts.candidates,
        key="max" if opts.criterion == "max" else "sse",
        exact_within=EXACT_WITHIN if opts.lazy_queue else math.inf,
        values=opts.values, interior=interior, check=check, progress=scaling.progress_out(progress),
        t_start=t_start)
    _requested_fractions(snaps, stop["fractions"], N)
    notes = _unreached(stop["fractions"], stop["count"], N, snaps[0].n_selected, stats.pop("stopped"), up=False)
    t_total = time.perf_counter() - t_start
    timings = {"curvature": 0.0, "selection": t_total - t_errors, "errors": t_errors, "total": t_total}
    fixed = ~interior if opts.candidates == "interior" else np.isin(np.arange(N), cube_corners(data.shape))
    order = selected[~fixed[selected]]
    return ReductionResult(data=user_data, selected=snaps[-1].selected, curvature=None, order=order,
                           snapshots=[scaling.snapshot_out(s) for s in snaps],
                           options={**opts.to_dict(), **user_stop}, timings=timings, stats=stats, notes=notes)


#: Peak bytes per point of a decimation (the Kuhn split's 6 tets per point with their
#: corner lists, the buckets and the queue), for the memory check.
DECIMATION_BYTES_PER_POINT = 1000


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


#: Coordinate extents within 2**+-SAFE_COORD_EXPONENT (orientation determinants are
#: cubic in them) and value magnitudes within 2**+-SAFE_VALUE_EXPONENT (sums of squared
#: residuals) are used as given; others are scaled by a power of two first.
SAFE_COORD_EXPONENT = 100
SAFE_VALUE_EXPONENT = 400


class _Scaling:
    """Exact power-of-two scale factors for coordinates (``c``) and values (``v``).

    Squares and products of values near the float limits overflow or underflow (E_RMS
    becomes inf or 0, every curvature 0, no flip changes an error), and so do the
    orientation determinants of extreme coordinates.  Multiplying by a power of two
    is exact, and the method is invariant under it: the curvature ranking (eq. 10
    scales by ``v / c**2``), the flips (section 4: sums of squared residuals scale by
    ``v**2``) and the selection are those of the unscaled data, and the errors and
    fitted values are scaled back exactly.
    """

    def __init__(self, c=1.0, v=1.0):
        self.c, self.v = float(c), float(v)

    def stop_in(self, stop):
        tol = {k: (None if stop[k] is None else stop[k] * self.v) for k in ("tol_rms", "tol_inf")}
        return {**stop, **tol}

    def progress_out(self, progress):
        if progress is None or self.v == 1.0:
            return progress
        return lambda m, target, e_rms, e_inf, seconds: progress(m, target, e_rms / self.v, e_inf / self.v, seconds)

    def curvature_out(self, K):
        return K if K is None or (self.c == 1.0 and self.v == 1.0) else K * (self.c * self.c / self.v)

    def snapshot_out(self, s):
        if self.v == 1.0:
            return s
        s.residuals = s.residuals / self.v
        s.errors = {k: e / self.v for k, e in s.errors.items()}
        if s.fit is not None:
            s.fit = {**s.fit, "values": s.fit["values"] / self.v, "residuals": s.fit["residuals"] / self.v,
                     "errors": {k: e / self.v for k, e in s.fit["errors"].items()}}
        return s


def _exponent(size):
    """``round(log2(size))``, or None for 0 (and non-finite) sizes."""
    return int(np.round(np.log2(size))) if np.isfinite(size) and size > 0.0 else None


def _safe_scale(data):
    """``data`` with coordinates and values scaled into the safe range (a copy, when
    needed), and the :class:`_Scaling` that maps the results back.

    One common factor when it brings both the coordinate extent and the values into
    the safe range: the graph of ``f`` then only changes in size, so every curvature
    of section 2 scales alike and the ranking is that of the unscaled data.  Otherwise
    (say coordinates near 1e300 and values near 1e-300) each gets its own factor.
    """
    extent = float(np.max(np.ptp(data.points, axis=0))) if data.n_points else 0.0
    ec = _exponent(extent)
    ev = _exponent(float(np.max(np.abs(data.values))) if data.n_points else 0.0)

    def safe(shift=0):
        return ((ec is None or abs(ec - shift) <= SAFE_COORD_EXPONENT)
                and (ev is None or abs(ev - shift) <= SAFE_VALUE_EXPONENT))

    if safe():
        return data, _Scaling()
    shift = ec if ec is not None and abs(ec) > SAFE_COORD_EXPONENT else ev
    if safe(shift):
        c = v = float(np.ldexp(1.0, -shift))
    else:
        c = float(np.ldexp(1.0, -ec)) if ec is not None and abs(ec) > SAFE_COORD_EXPONENT else 1.0
        v = float(np.ldexp(1.0, -ev)) if ev is not None and abs(ev) > SAFE_VALUE_EXPONENT else 1.0
    changes = {}
    if c != 1.0:
        changes["points"] = data.points * c
        if data.is_grid:
            changes["origin"] = np.asarray(data.origin, float) * c
            changes["spacing"] = np.asarray(data.spacing, float) * c
    if v != 1.0:
        changes["values"] = data.values * v
    return replace(data, **changes), _Scaling(c, v)


def _options(options, overrides):
    """One validated, method-resolved :class:`Options` from ``options`` and keyword overrides."""
    if options is None:
        options = Options()
    elif not isinstance(options, Options):
        raise InputError(f"options must be a trivsel.Options, got {type(options).__name__}")
    unknown = sorted(set(overrides) - {f.name for f in option_fields()})
    if unknown:
        raise TypeError(f"reduce() got an unexpected keyword argument {unknown[0]!r}")
    merged = replace(options, **overrides) if overrides else options
    # a keyword given is a setting, even at its default value
    check_applicable([k for k, v in overrides.items() if v is not None], merged.method)
    return merged.resolve()


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
        from . import mesh as _mesh

        N = self.data.n_points
        if code == _mesh.ERR_TETCAP:
            self.tet_cap = 2 * (self.tet_cap or 8 * N + 1024)
        elif code == _mesh.ERR_POOLCAP:
            self.pool_cap = 2 * (self.pool_cap or 24 * N + 4096)
        else:
            return False
        return True

    def _mesh(self):
        from . import mesh as _mesh

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
        _requested_fractions(self.snapshots, self.stop["fractions"], N)
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
            from .fitting import fit_on_mesh

            fit = fit_on_mesh(snap_mesh, data.values, interior)
        snap = Snapshot(fraction=m / data.n_points, n_selected=m,
                        selected=np.concatenate([self.fixed, np.asarray(inserted, np.int64)]),
                        tets=snap_mesh.tetrahedra(), residuals=r, errors=error_norms(r, interior),
                        seconds=time.perf_counter() - self.t_start, flips=snap_mesh.flips, fit=fit)
        self.t_errors += time.perf_counter() - te
        return snap


def _option_docs():
    """The numpydoc entries of the option keywords, generated from :class:`Options` and
    grouped by the methods they apply to (:func:`~trivsel.options.option_groups`)."""
    from .options import _choices, _default_text, group_title, option_groups

    out = []
    for methods, group in option_groups():
        for f in group:
            meta = f.metadata
            kind = ("{" + ", ".join(repr(c) for c in _choices(f)) + "}" if meta["kind"] == "choice"
                    else meta["kind"])
            if meta["sequence"]:
                kind = f"list of {kind}"
            ref = f" ({meta['paper']})" if meta["paper"] else ""
            out.append(f"    {f.name} : {kind}, default {_default_text(f)}; {group_title(methods)}\n"
                       f"        {meta['doc']}{ref}.")
    return "\n".join(out)


reduce.__doc__ = f"""Select points and build the data-dependent tetrahedral mesh (Hamann & Chen 1994).

    Parameters
    ----------
{_STOP_PARAMS}

    Other Parameters
    ----------------
{_option_docs()}

    Returns
    -------
    ReductionResult

    Raises
    ------
    InputError
        For bad data, fractions, counts, tolerances or options, with a one-line
        message naming the value.

    Notes
    -----
    Each option applies to the methods named after its default ("every method",
    "method paper only", ...); giving it for another method raises InputError.
    """


def _signature():
    params = [p for p in inspect.signature(reduce).parameters.values() if p.kind != p.VAR_KEYWORD]
    params += [inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default)
               for f in option_fields()]
    return inspect.Signature(params)


reduce.__signature__ = _signature()
