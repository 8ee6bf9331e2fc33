#!/usr/bin/env python
r"""A study, not a product path: decimation (``method="decimate"``) in blocks by passes
whose seams are locked, then freed by regions shifted half a block, and what it keeps.

    python benchmarks/study_blocked_decimate.py      # about 3 minutes

Prints, for Table-1 functions and the 48^3 T1 crop cut into 2^3 or 3^3 blocks, the vertices
and E_RMS of the unblocked ``decimate`` at an E_inf tolerance, those of the passes (also
with a halo of locked points around every cut, and with looser tolerances in the first
passes), the merged mesh's E_RMS and E_inf (each mesh checked as a conforming
tetrahedralisation of the box, its errors evaluated independently), and the unblocked
run's E_RMS at the blocked run's vertex count.  The finding and
why is in docs/notes/2026-12-04-meshes-and-blocks.md.

Bottom-up decimation cannot start from prescribed faces as the inserting methods do
(:mod:`trivsel.blocks`): it starts from every grid point.  So the blocks conform the other
way round (out-of-core simplification that locks block boundaries, then simplifies the
regions around the old seams in a second pass: Borodin, Guthe and Klein 2003; Cignoni et
al. 2003)::

    pass 1 (blocks)     every block is decimated on its own, its points on a seam (a cut
                        plane inside the box) locked: the two blocks on a seam both keep
                        every grid point there and the Kuhn split's triangles between
                        them, so their meshes conform.  Points on the box's surface move
                        within it as in an unblocked run.
    pass 2 (regions)    the box is cut again, half way through the blocks, into regions
                        that each hold one crossing of seams in their middle.  A region is
                        the set of pass-1 tetrahedra whose centroid lies in its box (a
                        jagged domain); its boundary inside the box is locked, and every
                        other vertex, the old seams' included, may be removed.  Regions
                        share only locked faces, so the merged mesh conforms.

    block cuts   |     :     |     :     |         | seams of pass 1 (locked, then freed)
    region cuts  :     |     :     |     :         : cuts of pass 2, mid-block

Both passes stop when no collapse keeps every residual within ``tol_inf`` (an E_inf
tolerance is local: the merged mesh meets it when every pass does).  Each job reads only
the grid region it needs and the pass-1 results of the blocks it overlaps.  The kernels
are those of :mod:`trivsel.decimation`: the grid's in pass 1, the mesh's (on the grid's
lattice, so with exact integer predicates) in pass 2.

Point numbering is global, as in :mod:`trivsel.blocks`: the C-order index over ``(i, j, k)``
of the volume's grid.
"""

from __future__ import annotations

import time

import numpy as np

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from trivsel.decimation import LOCK_ALL, Decimation, new_mesh_state, new_state  # noqa: E402

#: Passes over the box: the blocks, then two sets of regions (``pass_cuts``).
PASSES = 3


def pass_cuts(plan):
    """The grid indices that bound the regions of each pass, per axis.

    Pass 1 cuts at the blocks' seams ``c``.  Pass 2 cuts half way through every block
    (``m``), so that each seam is inside a region.  Where a pass-2 cut crosses a seam, the
    seam's points lie on the cut (locked): a line of them stays.  Pass 3 cuts between each
    seam and the next pass-2 cut, so that every seam and every pass-2 cut is inside a region
    and only the points where three cuts of different passes meet stay locked to the end::

        pass 1   c0 ----------- c1 ----------- c2 ----------- c3
        pass 2   c0 ---- m0 ----------- m1 ----------- m2 ---- c3
        pass 3   c0 --------------- q1 ------------ q2 ------- c3
                       m0    c1        m1    c2         m2

    Every region of every pass spans at most about one block along each axis."""
    p1, p2, p3 = [], [], []
    for c in plan.cuts:
        k = len(c) - 1
        m = [(c[i] + c[i + 1]) // 2 for i in range(k)]
        p1.append(tuple(c))
        p2.append(tuple(sorted({c[0], *m, c[-1]})))
        q = [(c[i] + m[i]) // 2 for i in range(1, k)]
        p3.append(tuple(sorted({c[0], *q, c[-1]})))
    return [tuple(p1), tuple(p2), tuple(p3)]


def regions(cuts):
    """Every region between ``cuts`` (one pass's) as ``(ix, iy, iz)``."""
    return [tuple(int(x) for x in r) for r in np.ndindex(*[len(c) - 1 for c in cuts])]


def overlapping(cuts, region, extents):
    """The earlier regions whose tetrahedra may have a centroid in ``region``'s box: those
    whose extent (``{region: (lo, hi)}``, the bounding box of their tetrahedra, which after
    collapses may reach past their own box) overlaps it."""
    lo = np.array([cuts[a][j] for a, j in enumerate(region)])
    hi = np.array([cuts[a][j + 1] for a, j in enumerate(region)])
    return [r for r, (a, b) in extents.items() if np.all(np.asarray(a) <= hi) and np.all(np.asarray(b) >= lo)]


def _in_region(cuts, region, centroid):
    """Whether each centroid (global grid coordinates) lies in ``region``'s box: ``[lo, hi)``
    per axis, the last region closed, so that every centroid is in exactly one region."""
    ok = np.ones(len(centroid), bool)
    for a, j in enumerate(region):
        lo, hi = cuts[a][j], cuts[a][j + 1]
        last = j == len(cuts[a]) - 2
        ok &= (centroid[:, a] >= lo) & ((centroid[:, a] <= hi) if last else (centroid[:, a] < hi))
    return ok


def _decimate(dec):
    """Collapse until no collapse keeps every residual within the tolerance."""
    dec.run(1)
    return dec


def collapse_block(volume, plan, block, *, tol_inf, halo=0):
    """Pass 1: one block decimated to ``tol_inf`` with its seam points locked.

    Returns a dict: ``tets`` (the block's tetrahedra, global indices), ``loose`` (the
    block's points that are no vertex, global) and ``loose_tet`` (the row of ``tets`` that
    holds each), ``extent`` (the lowest and highest grid coordinates of its vertices),
    ``sse``, ``max``, ``n_vertices``, ``seconds``.
    """
    t0 = time.perf_counter()
    region = plan.block_region(block)
    vals = np.asarray(volume.read(region), float)
    shape = vals.shape
    ijk = np.stack(np.unravel_index(np.arange(vals.size), shape), axis=-1).astype(np.int64)
    S = new_state(ijk, shape, vals.ravel(), lock="box")
    for a in range(3):  # a block face inside the box is a seam: its points never move
        if region[a][0] > 0:
            S.lock[ijk[:, a] <= halo] |= LOCK_ALL
        if region[a][1] < plan.shape[a]:
            S.lock[ijk[:, a] >= shape[a] - 1 - halo] |= LOCK_ALL
    dec = _decimate(Decimation(None, None, None, tol_inf=tol_inf, state=S))
    return _result(dec, plan, np.array([r[0] for r in region], np.int64), shape, t0)


def _result(dec, plan, lo, shape, t0, ids=None):
    """The tetrahedra and the loose points of a finished decimation, over global indices
    (local points: grid coordinates ``ijk + lo`` of a ``shape`` region, or ``ids``)."""
    if dec is None:
        e = np.zeros(0, np.int64)
        return {"tets": e.reshape(0, 4), "loose": e, "loose_tet": e, "extent": ([0, 0, 0], [-1, -1, -1]),
                "sse": 0.0, "max": 0.0, "n_vertices": 0, "seconds": time.perf_counter() - t0}
    S = dec.S
    alive = S.alive
    row = np.cumsum(alive) - 1  # a live tet's row among the live ones
    tets = S.T[alive].astype(np.int64)
    loose = np.flatnonzero(~S.isv)
    if ids is None:
        ids = np.ravel_multi_index(tuple((np.stack(np.unravel_index(np.arange(S.P.shape[0]), shape), -1)
                                          + lo).T), plan.shape)
    r = S.res
    g = np.stack(np.unravel_index(ids[np.unique(tets)], plan.shape), axis=-1)
    return {"tets": ids[tets], "loose": ids[loose], "loose_tet": row[S.ptet[loose].astype(np.int64)],
            "extent": (g.min(axis=0).tolist(), g.max(axis=0).tolist()),
            "sse": float(np.dot(r, r)), "max": float(np.max(np.abs(r))) if len(r) else 0.0,
            "n_vertices": int(S.isv.sum()), "seconds": time.perf_counter() - t0}


def collapse_region(volume, plan, cuts, region, earlier, *, tol_inf, halo=0):
    """Pass 2 or 3: one region (between ``cuts``) decimated to ``tol_inf``, its boundary
    inside the box locked.

    ``earlier`` maps each region of the previous pass that may hold tetrahedra of this one
    (:func:`overlapping`) to its result.  Returns the same fields as :func:`collapse_block`
    (``sse`` and ``max`` over the points the region owns: those in its tetrahedra that are no
    vertex).
    """
    t0 = time.perf_counter()
    tets, loose, loose_tet = [], [], []
    base = 0
    for r in earlier.values():
        g = np.stack(np.unravel_index(r["tets"], plan.shape), axis=-1)  # (m, 4, 3)
        keep = _in_region(cuts, region, g.mean(axis=1))
        row = np.cumsum(keep) - 1
        tets.append(r["tets"][keep])
        mine = keep[r["loose_tet"]]
        loose.append(r["loose"][mine])
        loose_tet.append(row[r["loose_tet"][mine]] + base)
        base += int(keep.sum())
    tets, loose, loose_tet = np.concatenate(tets), np.concatenate(loose), np.concatenate(loose_tet)
    if len(tets) == 0:  # a thin region at the box's end may hold no centroid
        return _result(None, plan, None, None, t0)
    ids, inv = np.unique(np.concatenate([tets.ravel(), loose]), return_inverse=True)
    local_tets = inv[:tets.size].reshape(-1, 4)
    ijk = np.stack(np.unravel_index(ids, plan.shape), axis=-1)
    lo, hi = ijk.min(axis=0), ijk.max(axis=0) + 1
    vals = np.asarray(volume.read(tuple(zip(lo.tolist(), hi.tolist()))), float)
    values = vals[tuple((ijk - lo).T)]
    located = np.full(len(ids), -1, np.int64)
    located[inv[tets.size:]] = loose_tet
    S = new_mesh_state(ijk.astype(np.float64), local_tets, values, located=located)
    S.lock[_inner_boundary_vertices(local_tets, ijk, plan.shape)] |= LOCK_ALL
    if halo:
        for a, j in enumerate(region):
            for c in (cuts[a][j], cuts[a][j + 1]):
                if 0 < c < plan.shape[a] - 1:
                    S.lock[np.abs(ijk[:, a] - c) <= halo] |= LOCK_ALL
    dec = _decimate(Decimation(None, None, None, tol_inf=tol_inf, state=S))
    return _result(dec, plan, None, None, t0, ids=ids)


def _inner_boundary_vertices(tets, ijk, shape):
    """The vertices of the boundary triangles of ``tets`` that do not lie in one face of the
    box of ``shape`` points: the region's boundary with its neighbours."""
    from trivsel.triangulation import boundary_triangles

    tri = boundary_triangles(tets)
    g = ijk[tri]  # (m, 3, 3)
    hi = np.asarray(shape) - 1
    on_box = np.zeros(len(tri), bool)
    for a in range(3):
        on_box |= np.all(g[..., a] == 0, axis=1) | np.all(g[..., a] == hi[a], axis=1)
    return np.unique(tri[~on_box])


def decimate_in_blocks(volume, plan, *, tol_inf, halo=0, schedule=(1.0, 1.0, 1.0)):
    """Every pass in this process (tests, benchmarks).  Returns ``(tets, stats)``: the
    merged mesh's tetrahedra (global indices) and, per pass, the regions' results without
    their arrays; the last pass's ``sse`` add up to the merged mesh's sum of squared
    residuals."""
    cuts = pass_cuts(plan)
    done = {b: collapse_block(volume, plan, b, tol_inf=tol_inf * schedule[0], halo=halo) for b in plan.blocks()}
    stats = [done]
    for p in range(1, PASSES):
        extents = {r: d["extent"] for r, d in done.items()}
        done = {r: collapse_region(volume, plan, cuts[p], r, {e: done[e] for e in overlapping(cuts[p], r, extents)},
                                   tol_inf=tol_inf * schedule[p], halo=halo if p < PASSES - 1 else 0)
                for r in regions(cuts[p])}
        stats.append(done)
    drop = ("tets", "loose", "loose_tet")
    return np.concatenate([r["tets"] for r in done.values()]), [
        [{k: v for k, v in r.items() if k not in drop} for r in d.values()] for d in stats]


class ArrayVolume:
    """An in-memory volume with the region reader's interface."""

    def __init__(self, values):
        self.values = values

    def read(self, region):
        return self.values[tuple(slice(*r) for r in region)]


def main():
    from trivsel import reduce, sample_grid
    from trivsel.blocks import check_tetrahedra, plan_blocks
    from trivsel.mesh import TetMesh, check_mesh
    from trivsel.study.realdata import load_volume

    print("| data | block | E_inf tol | variant | unblocked at tol: vertices, E_RMS | blocked: vertices (ratio), "
          "E_RMS, E_inf | unblocked at the blocked count: E_RMS |")
    print("|---|---|---|---|---|---|---|")
    cases = [("f2 25^3", lambda: sample_grid(2, 24), 8, 0.05, [(0, (1, 1, 1)), (1, (1, 1, 1)), (2, (1, 1, 1)),
                                                               (0, (0.5, 0.75, 1)), (0, (0.7, 0.85, 1))]),
             ("f4 49^3", lambda: sample_grid(4, 48), 16, 0.02, [(0, (1, 1, 1))]),
             ("T1 48^3", lambda: load_volume("icbm152"), 16, 40.0, [(0, (1, 1, 1))]),
             ("T1 48^3", lambda: load_volume("icbm152"), 24, 40.0, [(0, (1, 1, 1))]),
             ("T1 48^3", lambda: load_volume("icbm152"), 16, 20.0, [(0, (1, 1, 1))]),
             ("T1 48^3", lambda: load_volume("icbm152"), 24, 20.0, [(0, (1, 1, 1))])]
    for label, make, block, tol, variants in cases:
        d = make()
        f = d.values.reshape(d.shape)
        plan = plan_blocks(f.shape, block)
        s = reduce(d, tol_inf=tol, method="decimate").snapshots[-1]
        for halo, schedule in variants:
            tets, _ = decimate_in_blocks(ArrayVolume(f), plan, tol_inf=tol, halo=halo, schedule=schedule)
            check_tetrahedra(f.shape, tets)
            tm = TetMesh(d.points, d.values, d.ijk)
            tm.start(tets)
            check_mesh(tm)
            r = tm.residuals()[0]
            nv = len(np.unique(tets))
            same = reduce(d, count=nv, method="decimate").snapshots[-1]
            print(f"| {label} | {block} | {tol:g} | halo {halo}, tolerances x {schedule} | {s.n_selected}, "
                  f"{s.errors['E_rms']:.4g} | {nv} ({nv / s.n_selected:.2f}), {np.sqrt(np.mean(r * r)):.4g}, "
                  f"{np.max(np.abs(r)):.4g} | {same.errors['E_rms']:.4g} |", flush=True)


if __name__ == "__main__":
    main()
