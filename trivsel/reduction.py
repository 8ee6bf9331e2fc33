"""The whole method: :func:`reduce` (sections 2-5 put together).

1. curvature K of every point from a local least-squares quadratic (section 2);
2. fixed points and the ranked candidates (section 3);
3. the triangulation of the fixed points, the first candidate joined to every
   boundary triangle, then every further candidate inserted in order with
   data-dependent swapping after each insertion (section 4);
4. snapshots at the requested counts with E_RMS and E_inf, with and without the
   boundary points (section 5).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import mesh as _mesh
from .data import PointData, resolve_function, sample_grid
from .errors import error_norms
from .errors_input import InputError, check_threads
from .selection import TIE_ORDERS, candidate_points, count_for_fraction, rank_candidates, validate_fractions
from .triangulation import (box_tetrahedra, cube_corners, delaunay_tetrahedra, edge_neighbours, hull_triangles,
                            kuhn_edge_neighbours, kuhn_tetrahedra, neighbour_graph)

__all__ = ["reduce", "ReductionResult", "Snapshot", "DEFAULTS", "OPTION_DOCS"]

#: Flips after each greedy insertion (``max_flips``); measured on 65^3 (README, "Beyond the paper")
GREEDY_MAX_FLIPS = 6

#: The paper's open choices and our defaults (the README's options table is built from these).
DEFAULTS = {
    "method": "paper",
    "criterion": "rms",
    "candidates": "all",
    "tie_order": "index",
    "own_vertices": True,
    "final_pass": False,
    "first_improving": False,
    "boundary_diagonals": "mirrored",
    "curvature": "direct",
    "neighbourhood": "kuhn",
    "ranking": "curvature",
    "rel_tol": 1e-9,
    "quantum": 1e-9,
    "seed": 0,
    "swap_memory": "run",
}

OPTION_DOCS = {
    "criterion": "swap criterion: sum of tetrahedral RMS errors (eq. 14) 'rms', of max errors (eq. 15) 'max', "
                 "or squared residuals over the configuration's points 'sse'",
    "candidates": "'all' non-fixed points (face and edge points included; Table 1 needs them) or 'interior' only",
    "tie_order": "order among equal quantised curvatures: 'index', 'reverse', 'random' (seeded), 'centre'",
    "own_vertices": "a tet's error (eqs. 14-15) includes its own four vertices (zero residual) in N",
    "final_pass": "after reaching each snapshot count, swap over all tets (end of section 4); applied to a copy",
    "first_improving": "apply the first improving flip in O instead of the best one",
    "boundary_diagonals": "diagonals of the 12 initial boundary triangles of a box: 'kuhn' or 'mirrored'",
    "curvature": "curvature estimator: 'direct' least-squares quadratic in (x, y, z), or 'local-frame' "
                 "(Hamann 1994b: quadratic height function over the tangent space of an estimated 4-D normal)",
    "neighbourhood": "points of the curvature fit: 'kuhn' edge neighbours (2-ring where rank-deficient), "
                     "'two-ring' always, or 'box' (the 26 grid neighbours)",
    "ranking": "insertion order: 'curvature' (descending K, the paper), or the diagnostic orders 'ascending' "
               "(K ascending), 'random' (seeded) and 'analytic' (descending exact K of a Table-1 function)",
    "rel_tol": "a flip must lower the criterion sum by more than rel_tol * sum (plus 1e-12 of the value range)",
    "max_flips": "at most this many flips (swap rounds) after each insertion; default: unlimited for paper "
                 "(section 4 swaps until nothing improves), 6 for greedy (measured: README, \"Beyond the paper\")",
    "swap_memory": "how long swapping remembers evaluated configurations: 'run' (the whole run, a fixed table "
                   "of 2 N entries; greedy then evaluates about half as many) or 'call' (the swaps after one "
                   "insertion); identical results under 'rms' and 'max', rounding-level ties may differ under 'sse'",

    "quantum": "relative step to which K is rounded before sorting (rounding noise stays a tie)",
}


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
        Absolute curvature K of every point (eq. 10); None for ``method="greedy"``,
        which chooses points by their error and never ranks by curvature.
    order : (M,) int
        All candidates in ranked order.
    snapshots : list of Snapshot
        One per requested fraction/count, ascending by count.
    options : dict
        Every option used, defaults included.
    timings : dict
        Seconds for ``curvature``, ``selection`` (insertion and swapping),
        ``errors``, and ``total``.
    stats : dict
        Insertion cases and flip counts at the end of the run.
    """

    data: PointData
    selected: np.ndarray
    curvature: np.ndarray | None
    order: np.ndarray
    snapshots: list
    options: dict
    timings: dict
    stats: dict

    def snapshot(self, fraction):
        """The snapshot for ``fraction`` (nearest match)."""
        return min(self.snapshots, key=lambda s: abs(s.fraction - float(fraction)))

    def errors_frame(self):
        """One row per snapshot with the columns of ``errors.csv``."""
        import pandas as pd

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
                    "seconds": round(s.seconds, 4),
                })
        return pd.DataFrame(rows)


def _check_choice(name, value, choices):
    if value not in choices:
        raise InputError(f"unknown {name} {value!r}: choose one of {', '.join(map(str, choices))}")


def reduce(data, *, fractions=None, count=None, tol_rms=None, tol_inf=None, n=16, method="paper",
           criterion=None, candidates="all", tie_order="index", own_vertices=True, final_pass=False,
           first_improving=False, boundary_diagonals="mirrored", curvature="direct", ranking="curvature", rel_tol=1e-9,
           quantum=1e-9, seed=0, values="data", greedy_key="max", neighbourhood="kuhn", boundary_flips=None,
           max_flips=None, swap_memory="run", threads=1, check=None, progress=None):
    """Select points and build the data-dependent tetrahedral mesh (Hamann & Chen 1994).

    Parameters
    ----------
    data : PointData, int or str
        The data; a Table-1 function number or name is sampled on the ``(n+1)^3``
        grid of eq. (18).
    fractions : sequence of float in (0, 1], optional
        Stop at these fractions of all points (fixed points included, rounded half
        up).  One run goes to the largest; the others are snapshots on the way.
    count : int, optional
        Stop at this number of points instead.
    tol_rms, tol_inf : float, optional
        Stop as soon as E_RMS (eq. 19) or E_inf (eq. 20) over all points is at or
        below the tolerance (or when every candidate is inserted).
    method : {"paper", "greedy"}
        ``paper``: curvature-ranked selection with data-dependent swapping
        (sections 2-4).  ``greedy``: error-driven selection (Garland & Heckbert
        1995 lifted to 3-D): repeatedly insert the candidate with the largest
        residual |f - L|, with the same insertion and swapping; curvature and
        ranking options do not apply.
    boundary_flips : bool, optional
        Also flip an edge between two coplanar hull faces to the other diagonal of
        their planar quadrilateral (2-2 flip), so the boundary's triangulation
        adapts to the data too.  Not in the paper (its configurations 1 and 2 are
        interior); default False for ``paper``, True for ``greedy`` (measured: README).
    neighbourhood : {"kuhn", "two-ring", "box"}
        Points of the curvature fit (section 2): edge neighbours in the initial
        triangulation (widened to the 2-ring where rank-deficient), always the
        2-ring, or (grids) the 26 surrounding grid points.
    greedy_key : {"max", "sse"}
        Greedy only: insert the point with the largest residual overall ("max",
        aims at E_inf), or the worst point of the tet with the largest sum of
        squared residuals ("sse", aims at E_RMS).
    max_flips : int, optional
        At most this many flips after each insertion (each swap round of section 4
        applies the best flip of O; the search stops earlier when nothing
        improves).  Default: unlimited for ``paper`` (the paper swaps until no
        configuration improves), 6 for ``greedy``: on 65^3 it takes 11 % less
        time than unlimited at the same errors (README, "Beyond the paper").
    swap_memory : {"run", "call"}
        How long swapping remembers the configurations it evaluated (each is keyed
        by its tets, whose points never change): for the whole run (``"run"``, a
        fixed table of about 2 N entries of 56 bytes) or during the swaps after
        one insertion (``"call"``).  Under the ``rms`` and ``max`` criteria a
        remembered gain is the gain a new evaluation would compute, bit for bit,
        so the results are identical.  Under ``sse`` a configuration's sum uses
        the residuals stored per point, and a point on a face shared with a tet
        outside the configuration keeps the residual that tet computed, so a
        remembered sum can differ from a new one in the last bits: choices
        between gains equal up to rounding (symmetric configurations) may differ.
    criterion, candidates, tie_order, own_vertices, final_pass, first_improving,
    boundary_diagonals, curvature, rel_tol, quantum, seed
        The paper's open choices; see :data:`OPTION_DOCS` and the README.
    values : {"data", "fit"} or list of them
        Vertex values of the approximation: the selected points' own values (the
        paper; a true selection) and/or least-squares values over all points on the
        same mesh (:mod:`trivsel.fitting`).  With both, every snapshot has a row
        for each.
    threads : int
        Threads for the curvature fits (section 2), the only stage that runs in
        parallel; the result does not depend on it.  Insertion and swapping are
        sequential by nature (each flip decides the next), and the final error
        evaluation takes well under 1 % of a run.
    check : callable, optional
        Called as ``check(mesh)`` after the first insertion and at every snapshot
        (tests pass :func:`trivsel.mesh.check_mesh`).
    progress : callable, optional
        Called about 200 times during the run as ``progress(n_selected, n_target,
        e_rms, e_inf, seconds)`` with the current E_RMS and E_inf over all points
        (the CLI shows it as a progress line on a terminal).

    Returns
    -------
    ReductionResult

    Raises
    ------
    InputError
        For bad fractions, counts, tolerances or options, with a one-line message.
    """
    t_start = time.perf_counter()
    if not isinstance(data, PointData):
        data = sample_grid(resolve_function(data), n)
    _check_choice("method", method, ("paper", "greedy"))
    if criterion is None:  # measured best per method (README, "options")
        criterion = "sse" if method == "greedy" else "rms"
    if boundary_flips is None:
        boundary_flips = method == "greedy"
    if max_flips is None:
        max_flips = GREEDY_MAX_FLIPS if method == "greedy" else None
    if max_flips is not None and (isinstance(max_flips, bool) or not isinstance(max_flips, (int, np.integer))
                                  or max_flips < 1):
        raise InputError(f"max_flips must be a positive integer, got {max_flips!r}")
    _check_choice("swap memory", swap_memory, ("call", "run"))
    _check_choice("criterion", criterion, tuple(_mesh.CRITERIA))
    _check_choice("candidate set", candidates, ("all", "interior"))
    _check_choice("tie order", tie_order, TIE_ORDERS)
    _check_choice("greedy key", greedy_key, ("max", "sse"))
    _check_choice("neighbourhood", neighbourhood, ("kuhn", "two-ring", "box"))
    if neighbourhood == "box" and not data.is_grid:
        raise InputError("neighbourhood 'box' needs grid data")
    _check_choice("boundary diagonals", boundary_diagonals, ("kuhn", "mirrored"))
    _check_choice("curvature estimator", curvature, ("direct", "local-frame"))
    _check_choice("ranking", ranking, ("curvature", "ascending", "random", "analytic"))
    if ranking == "analytic" and not ("function" in data.meta):
        raise InputError("ranking 'analytic' needs a Table-1 function (--function), not a data file")
    threads = check_threads(threads)
    fractions = validate_fractions(fractions)
    values_modes = [values] if isinstance(values, str) else list(values)
    if not values_modes:
        raise InputError("values must name at least one of 'data', 'fit'")
    for v in values_modes:
        _check_choice("values", v, ("data", "fit"))
    N = data.n_points
    for name, tol in (("tol_rms", tol_rms), ("tol_inf", tol_inf)):
        if tol is not None and not (np.isfinite(tol) and tol >= 0):
            raise InputError(f"{name} must be a finite number >= 0, got {tol!r}")
    if count is not None and (isinstance(count, bool) or int(count) != count or not 1 <= count <= N):
        raise InputError(f"count must be an integer in [1, {N}], got {count!r}")
    if not fractions and count is None and tol_rms is None and tol_inf is None:
        raise InputError("give fractions, a count, or an error tolerance (tol_rms / tol_inf) to stop at")

    options = dict(method=method, criterion=criterion, candidates=candidates, tie_order=tie_order,
                   own_vertices=bool(own_vertices), final_pass=bool(final_pass),
                   first_improving=bool(first_improving), boundary_diagonals=boundary_diagonals,
                   curvature=curvature, ranking=ranking, greedy_key=greedy_key,
                   neighbourhood=neighbourhood, boundary_flips=bool(boundary_flips), rel_tol=float(rel_tol), quantum=float(quantum), seed=int(seed),
                   max_flips=None if max_flips is None else int(max_flips), swap_memory=swap_memory,
                   fractions=fractions, count=count, tol_rms=tol_rms, tol_inf=tol_inf, values=values_modes)

    # --- fixed points and initial triangulation of all points (section 3)
    if data.is_grid:
        fixed = cube_corners(data.shape)
        start_tets = box_tetrahedra(data.shape, boundary_diagonals)
        all_tets = None  # the Kuhn split; its edge graph comes from the stencil below
    else:
        _, fixed = hull_triangles(data.points)
        local = delaunay_tetrahedra(data.points[fixed])
        start_tets = fixed[local]
        all_tets = delaunay_tetrahedra(data.points) if method != "greedy" else None  # curvature's graph
    interior = data.interior_mask()

    # --- targets
    n_fixed = len(fixed)
    targets = sorted({count_for_fraction(f, N) for f in fractions} | ({int(count)} if count is not None else set()))
    cand = candidate_points(N, fixed, interior, candidates)
    n_max = n_fixed + len(cand)
    for m in targets:
        if m < n_fixed:
            raise InputError(f"target of {m} points is fewer than the {n_fixed} fixed points "
                             f"(fractions {fractions}, N = {N})")
        if m > n_max:
            raise InputError(f"target of {m} points exceeds the {n_max} selectable points "
                             f"({n_fixed} fixed + {len(cand)} candidates of set {candidates!r})")
    if not targets:  # tolerance only
        targets = [n_max]

    # --- curvature (section 2) and ranking (section 3); greedy picks by error, not by rank
    t0 = time.perf_counter()
    from .curvature import absolute_curvature

    if method == "greedy":
        K = None
        order = cand
    elif data.is_grid:
        graph = kuhn_edge_neighbours(data.shape)
        if curvature == "local-frame":  # needs the tets for its normals
            all_tets = kuhn_tetrahedra(data.shape)
    else:
        graph = edge_neighbours(all_tets, N)
    if method != "greedy":
        graph = neighbour_graph(*graph, shape=data.shape, kind=neighbourhood)
        fast = {"grid": True} if data.is_grid and curvature == "direct" else {}  # one SVD for the interior
        K = absolute_curvature(data.points, data.values, tets=all_tets, neighbours=graph, estimator=curvature,
                               threads=threads, **fast)
    t_curv = time.perf_counter() - t0
    if method != "greedy":
        key = K
        if ranking == "ascending":
            key = -K
        elif ranking == "random":
            key = np.random.default_rng(seed).random(N)
        elif ranking == "analytic":
            from .curvature import analytic_absolute_curvature

            key = analytic_absolute_curvature(data.meta["function"], data.points)
        order = rank_candidates(key, cand, tie_order=tie_order, points=data.points, seed=seed, quantum=quantum)

    # --- insertion with data-dependent swapping (section 4)
    t1 = time.perf_counter()
    tet_cap = None
    pool_cap = None
    for attempt in range(4):
        try:
            result = _run(data, fixed, start_tets, order, targets, options, interior, tol_rms, tol_inf,
                          check, progress, t_start, tet_cap, pool_cap)
            break
        except _mesh.MeshError as exc:
            if exc.code == _mesh.ERR_TETCAP:
                tet_cap = 2 * (tet_cap or 8 * N + 1024)
            elif exc.code == _mesh.ERR_POOLCAP:
                pool_cap = 2 * (pool_cap or 24 * N + 4096)
            else:
                raise
    else:  # pragma: no cover - capacities doubled 4 times
        raise RuntimeError("mesh capacity could not be satisfied")
    snapshots, stats, t_err = result
    t_total = time.perf_counter() - t_start
    timings = {"curvature": t_curv, "selection": t_total - t_curv - t_err - (t1 - t0 - t_curv),
               "errors": t_err, "total": t_total}
    selected = snapshots[-1].selected
    if method == "greedy":
        order = stats.pop("inserted")
    return ReductionResult(data=data, selected=selected, curvature=K, order=order, snapshots=snapshots,
                           options=options, timings=timings, stats=stats)


def _run(data, fixed, start_tets, order, targets, options, interior, tol_rms, tol_inf, check, progress,
         t_start, tet_cap, pool_cap):
    N = data.n_points
    greedy = options["method"] == "greedy"
    tm = _mesh.TetMesh(data.points, data.values, data.ijk, criterion=options["criterion"],
                       vertices_in_error=options["own_vertices"], rel_tol=options["rel_tol"], tol_inf=tol_inf,
                       first_improving=options["first_improving"], tet_capacity=tet_cap,
                       pool_capacity=pool_cap, greedy=greedy, greedy_key=options["greedy_key"], candidates=order,
                       boundary_flips=options["boundary_flips"],
                       max_rounds=options["max_flips"] or _mesh.UNLIMITED_ROUNDS, swap_memory=options["swap_memory"])
    tm.start(start_tets)
    n_fixed = len(fixed)
    pos = 0  # candidates inserted so far
    t_err = 0.0
    snapshots = []
    stop_tol = -1.0 if tol_rms is None else float(tol_rms)
    reached_tol = False

    def tolerance_met():
        r, _ = tm.residuals()
        e = error_norms(r, interior)
        return ((tol_rms is not None and e["E_rms"] <= tol_rms)
                or (tol_inf is not None and e["E_inf"] <= tol_inf))

    if (tol_rms is not None or tol_inf is not None) and tolerance_met():
        reached_tol = True
    inserted = []  # greedy: the points in the order they were chosen
    last = targets[-1] - n_fixed
    # the compiled loop runs in chunks so that a progress display can update
    step = max(1, last // 200) if progress is not None else max(last, 1)
    for target in targets:
        need = target - n_fixed
        if pos < need and not reached_tol:
            if not greedy and pos == 0:
                p = order[0]
                ids = tm.cone(p)  # join the first point to every boundary triangle
                if len(ids) == 0:  # not strictly inside: insert into the fixed points' mesh
                    _, ids = tm.insert(p)
                tm.swap(ids)
                pos = 1
                if check is not None:
                    check(tm)
            while pos < need:
                stop = min(need, pos + step)
                if greedy:
                    log = tm.run_greedy(n_fixed + stop, stop_tol)
                    inserted.extend(log.tolist())
                    new_pos = pos + len(log)
                else:
                    new_pos = tm.run(order, pos, stop, stop_tol)
                stalled = new_pos < stop  # tolerance met (or, greedy, nothing left to improve)
                pos = new_pos
                if progress is not None:
                    resid = tm.resid
                    progress(n_fixed + pos, n_fixed + last, float(np.sqrt(max(tm.sse_sum, 0.0) / N)),
                             float(np.max(np.abs(resid))), time.perf_counter() - t_start)
                if stalled:
                    reached_tol = True
                    break
            if tol_rms is not None or tol_inf is not None:
                reached_tol = reached_tol or tolerance_met()
        te = time.perf_counter()
        snap_mesh = tm
        if options["final_pass"]:
            snap_mesh = tm.copy()
            snap_mesh.global_pass()
        if check is not None:
            check(snap_mesh)
        r, worst = snap_mesh.residuals()
        errors = error_norms(r, interior)
        fit = None
        if "fit" in options["values"]:
            from .fitting import fit_vertex_values

            verts, w = snap_mesh.point_weights()
            vtx = snap_mesh.vertices()
            fv, fr = fit_vertex_values(verts, w, data.values, vtx)
            fit = {"vertices": vtx, "values": fv, "residuals": fr, "errors": error_norms(fr, interior)}
        m = n_fixed + pos
        chosen = np.asarray(inserted, np.int64) if greedy else order[:pos]
        snapshots.append(Snapshot(fraction=m / N, n_selected=m, selected=np.concatenate([fixed, chosen]),
                                  tets=snap_mesh.tetrahedra(), residuals=r, errors=errors,
                                  seconds=time.perf_counter() - t_start, flips=snap_mesh.flips, fit=fit))
        t_err += time.perf_counter() - te
        if reached_tol:
            break
    # fractions as requested (not m / N) for the rows that hit their target exactly
    req = {count_for_fraction(f, N): f for f in options["fractions"]}
    for s in snapshots:
        if s.n_selected in req:
            s.fraction = req[s.n_selected]
    stats = {"flips": tm.flips, "cases": tm.cases, "evaluations": tm.evaluations, "tets": int(len(tm.live_ids())),
             "round_cap_hits": tm.round_cap_hits}
    if greedy:
        stats["inserted"] = np.asarray(inserted, np.int64)
    return snapshots, stats, t_err
