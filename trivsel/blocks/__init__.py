"""Reduction of a large grid in blocks whose seams conform by construction.

The box is cut by planes into blocks that share their faces.  The method starts from
prescribed boundary triangles (section 3, Definition 1), so each block can be reduced
on its own once its boundary is fixed, one dimension at a time::

    lines    every cut line (where two cut planes meet, the box's edges included) is
             reduced as 1-D data to the tolerance, segment by segment between the
             cut points (the segments' end points are kept);
    faces    every face of a cut plane between cut lines is reduced as 2-D data with
             its border fixed by the lines' kept points: greedy insertion with
             data-dependent flips (:func:`trivsel.blocks.faces.reduce_face`);
    blocks   every block is reduced in 3-D with its six faces' triangles prescribed:
             the first interior point joined to every boundary triangle (section 3),
             then insertion and interior flips only (:func:`trivsel.reduce` with
             ``boundary=``);
    merge    the blocks' tetrahedra, over the global point numbering.

A shared face is triangulated once, so the two blocks on its sides have the same
triangles there: the merged mesh is conforming.  Every grid point lies on one line,
in one face or inside one block, and that stage interpolates it within the E_inf
tolerance, so the merged mesh does too.

Each stage is a function of a :class:`Plan` and a folder (``out``): it reads the
region of the volume it needs (:func:`trivsel.io.regions.open_volume`; the whole
volume is never loaded), the results of the stages it depends on, and writes one
file.  The Snakemake workflow of ``trivsel blocks`` (``trivsel/blocks/workflow.smk``) runs them
as jobs: locally with ``-c N`` or on a cluster through an executor.

Point numbering: the stages' files hold global point indices, the C-order index over
``(i, j, k)`` of the volume's grid as trivsel reads it; the ``.vtu`` pieces' and the
merged mesh's ``original_index`` is the input's own point id, as ``trivsel reduce``
writes it (:meth:`trivsel.io.regions.Volume.file_ids`).
"""

from __future__ import annotations

import json
import numbers
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..exceptions import InputError, check_tolerance, shown
from . import slurm

__all__ = ["Plan", "plan_blocks", "reduce_line", "reduce_plane", "reduce_block", "reduce_in_blocks", "merge_blocks",
           "check_tetrahedra", "job_resources",
           "group_components", "job_batches"]

#: The volume's source, as :func:`trivsel.io.regions.open_volume` takes it.
SOURCE_KEYS = ("input", "function", "n", "array", "volume")
#: The largest block size (grid intervals per block) a run takes
MAX_BLOCK = 2**31 - 1
#: Stops besides ``tol_inf``, for methods with stages of their own in blocks (``BLOCK_STAGES``)
STOP_KEYS = ("count", "fraction", "tol_rms", "values")


@dataclass(frozen=True)
class Plan:
    """The cut planes of a blocked reduction.

    Attributes
    ----------
    shape : tuple of 3 int
        Points per axis of the whole grid.
    cuts : tuple of 3 tuples of int
        The grid indices of the cut planes normal to each axis, from 0 to
        ``shape[a] - 1``: block ``(ix, iy, iz)`` spans ``cuts[0][ix] .. cuts[0][ix + 1]``
        (both included) along x, and so on.
    """

    shape: tuple
    cuts: tuple

    @property
    def counts(self):
        """Blocks per axis."""
        return tuple(len(c) - 1 for c in self.cuts)

    def lines(self):
        """Every cut line as ``(axis, ib, ic)``: along ``axis``, through the cut planes
        ``ib`` and ``ic`` of the two other axes (in increasing axis order)."""
        out = []
        for a in range(3):
            b, c = _others(a)
            out += [(a, ib, ic) for ib in range(len(self.cuts[b])) for ic in range(len(self.cuts[c]))]
        return out

    def planes(self):
        """Every cut plane as ``(axis, ia)``: normal to ``axis`` at ``cuts[axis][ia]``."""
        return [(a, ia) for a in range(3) for ia in range(len(self.cuts[a]))]

    def blocks(self):
        """Every block as ``(ix, iy, iz)``."""
        nx, ny, nz = self.counts
        return [(ix, iy, iz) for ix in range(nx) for iy in range(ny) for iz in range(nz)]

    def block_region(self, block):
        """The block's region: ``((i0, i1), (j0, j1), (k0, k1))``, stop exclusive."""
        return tuple((self.cuts[a][i], self.cuts[a][i + 1] + 1) for a, i in enumerate(block))

    def n_points(self):
        return int(np.prod(self.shape))

    def to_dict(self):
        return {"shape": list(self.shape), "cuts": [list(c) for c in self.cuts]}

    @classmethod
    def from_dict(cls, d):
        return cls(tuple(int(s) for s in d["shape"]), tuple(tuple(int(v) for v in c) for c in d["cuts"]))


def _others(a):
    return [b for b in range(3) if b != a]


def plan_blocks(shape, block) -> Plan:
    """Cut a grid of ``shape`` points into blocks of ``block`` intervals per axis.

    The last block along an axis takes the remainder; a remainder of fewer than 2
    intervals is joined to the block before it (a block needs an interior point for
    the start of section 3).

    Parameters
    ----------
    shape : 3 ints
        Points per axis (each at least 3).
    block : int or 3 ints
        Grid intervals per block along each axis (at least 2).
    """
    shape = tuple(int(s) for s in shape)
    if len(shape) != 3 or min(shape) < 3:
        raise InputError(f"blocks need a 3-D grid of at least 3 points per axis, got shape {shape} (one process "
                         "takes any grid: trivsel reduce; so does --method decimate in blocks)")
    sizes = np.broadcast_to(np.asarray(block), (3,))
    if sizes.dtype.kind not in "iu" or np.any(sizes < 2):
        raise InputError(f"block size must be an integer >= 2 (grid intervals per block), got {shown(block)}")
    cuts = []
    for n, b in zip(shape, sizes.tolist()):
        c = list(range(0, n - 1, b)) + [n - 1]
        if len(c) > 2 and c[-1] - c[-2] < 2:
            del c[-2]
        cuts.append(tuple(c))
    return Plan(shape, tuple(cuts))


# ----------------------------------------------------------------------------- stages

def reduce_line(volume, plan, line, *, tol_inf):
    """The 1-D stage: one cut line, reduced to ``tol_inf`` segment by segment.

    Returns a dict: ``kept`` (sorted positions along the axis), and the squared
    residual sum ``sse``, the largest ``|residual|`` ``max`` and the number of points
    ``count`` of the points it owns (those of the line that are not cut points; cut
    points are kept, residual 0).
    """
    from .faces import reduce_polyline

    a, ib, ic = line
    b, c = _others(a)
    region = [None, None, None]
    region[a] = (0, plan.shape[a])
    region[b] = (plan.cuts[b][ib], plan.cuts[b][ib] + 1)
    region[c] = (plan.cuts[c][ic], plan.cuts[c][ic] + 1)
    f = np.asarray(volume.read(tuple(region)), float).reshape(-1)
    kept, sse, mx = [], 0.0, 0.0
    cuts = plan.cuts[a]
    for s0, s1 in zip(cuts[:-1], cuts[1:]):
        seg = f[s0:s1 + 1]
        k = np.asarray(reduce_polyline(seg, tol_inf=tol_inf), np.int64)
        r = seg - np.interp(np.arange(len(seg)), k, seg[k])
        sse += float(np.dot(r[1:-1], r[1:-1]))
        mx = max(mx, float(np.max(np.abs(r))))
        kept.append(s0 + k[:-1])
    kept.append(np.array([cuts[-1]], np.int64))
    n_own = plan.shape[a] - len(cuts)
    return {"kept": np.concatenate(kept), "sse": sse, "max": mx, "count": n_own}


def _line_name(line):
    return "{}_{}_{}".format(*line)


def reduce_plane(volume, plan, plane, lines, *, tol_inf):
    """The 2-D stage: every face of one cut plane, with borders from the lines' kept points.

    ``lines`` maps a line ``(axis, ib, ic)`` to its ``kept`` positions (only the lines
    in this plane are used).  Returns a dict: ``triangles`` ((m, 3) global point
    indices, counter-clockwise in the plane's two axes in increasing order) and
    ``sse``, ``max``, ``count`` over the faces' own points (not on a line).
    """
    from .faces import face_residuals, reduce_face

    a, ia = plane
    u, v = _others(a)
    pos = plan.cuts[a][ia]
    region = [None, None, None]
    region[a] = (pos, pos + 1)
    region[u] = (0, plan.shape[u])
    region[v] = (0, plan.shape[v])
    f = np.asarray(volume.read(tuple(region)), float).reshape(plan.shape[u], plan.shape[v])
    cu, cv = plan.cuts[u], plan.cuts[v]
    tris, sse, mx, count = [], 0.0, 0.0, 0
    for ju in range(len(cu) - 1):
        for jv in range(len(cv) - 1):
            u0, u1, v0, v1 = cu[ju], cu[ju + 1], cv[jv], cv[jv + 1]
            vals = f[u0:u1 + 1, v0:v1 + 1]
            border = np.zeros(vals.shape, bool)
            # the lines along u lie at the cut planes of v, and those along v at the cuts of u
            for jj, col in ((jv, 0), (jv + 1, -1)):
                k = _line_kept(lines, u, a, v, ia, jj)
                border[k[(k >= u0) & (k <= u1)] - u0, col] = True
            for jj, row in ((ju, 0), (ju + 1, -1)):
                k = _line_kept(lines, v, a, u, ia, jj)
                border[row, k[(k >= v0) & (k <= v1)] - v0] = True
            verts, t = reduce_face(vals, border, tol_inf=tol_inf)
            r = face_residuals(vals, verts, t)[1:-1, 1:-1]
            sse += float(np.sum(r * r))
            mx = max(mx, float(r.max()) if r.size else 0.0)
            count += r.size
            # face-local (ru, rv) -> global grid index
            ru, rv = np.divmod(np.asarray(t, np.int64), vals.shape[1])
            ijk = [None, None, None]
            ijk[a] = np.full(ru.shape, pos, np.int64)
            ijk[u] = ru + u0
            ijk[v] = rv + v0
            tris.append((ijk[0] * plan.shape[1] + ijk[1]) * plan.shape[2] + ijk[2])
    return {"triangles": np.concatenate(tris).astype(np.int64), "sse": sse, "max": mx, "count": count}


def _line_kept(lines, axis, a, b, ia, ib):
    """The kept positions of the line along ``axis`` through cut ``ia`` of axis ``a`` and
    cut ``ib`` of axis ``b``."""
    key = {a: ia, b: ib}
    o1, o2 = _others(axis)
    return np.asarray(lines[(axis, key[o1], key[o2])], np.int64)


def reduce_in_blocks(volume, plan, *, tol_inf, method="greedy", blocks=None):
    """Every stage in this process, in the workflow's order (tests, benchmarks, the kernels
    job); ``blocks`` limits the 3-D stage to those blocks (default all).

    Returns ``(tets, stages)``: the blocks' tetrahedra (global indices) and each stage's
    results, ``stages["lines"]`` and ``stages["planes"]`` (dicts by item, as
    :func:`reduce_line` and :func:`reduce_plane` return them) and ``stages["blocks"]`` (the
    blocks' stats, in order)."""
    lines = {ln: reduce_line(volume, plan, ln, tol_inf=tol_inf) for ln in plan.lines()}
    kept = {ln: r["kept"] for ln, r in lines.items()}
    planes = {p: reduce_plane(volume, plan, p, kept, tol_inf=tol_inf) for p in plan.planes()}
    faces = {p: r["triangles"] for p, r in planes.items()}
    done = [reduce_block(volume, plan, b, faces, tol_inf=tol_inf, method=method)
            for b in (plan.blocks() if blocks is None else blocks)]
    return np.concatenate([t for t, _ in done]), {"lines": lines, "planes": planes,
                                                  "blocks": [st for _, st in done]}


def block_faces(plan, block):
    """The six faces of a block as ``(plane, (ju, jv))``: plane ``(axis, ia)`` and the
    face's position among the plane's faces."""
    out = []
    for a in range(3):
        u, v = _others(a)
        for ia in (block[a], block[a] + 1):
            out.append(((a, ia), (block[u], block[v])))
    return out


def reduce_block(volume, plan, block, faces, *, tol_inf, method="greedy", options=None, check=None):
    """The 3-D stage: one block, with its six faces' triangles prescribed.

    ``faces`` maps a plane ``(axis, ia)`` to its triangles (global indices, as
    :func:`reduce_plane` returns them).  Returns ``(tets, stats)``: the tetrahedra
    as global point indices, and a dict with ``sse``, ``count`` over the block's
    interior points, ``max`` over all its points, ``n_vertices``, ``seconds``.
    """
    from .. import reduce
    from ..data import grid_from_array

    region = plan.block_region(block)
    vals = np.asarray(volume.read(region), float)
    data = grid_from_array(vals, name=f"block {block}")
    lo = np.array([r[0] for r in region], np.int64)
    shp = np.array(vals.shape, np.int64)
    boundary = []
    for plane, _ in block_faces(plan, block):
        tri = _face_triangles(plan, faces[plane], plane, region)
        g = np.stack(np.unravel_index(tri, plan.shape), axis=-1) - lo  # (m, 3, 3) local ijk
        loc = (g[..., 0] * shp[1] + g[..., 1]) * shp[2] + g[..., 2]
        # counter-clockwise in the plane's axes (u < v) faces +a for a = 0, 2 and -a for
        # a = 1; outward is -a on the block's low face and +a on its high face
        a, ia = plane
        outward = 1 if plan.cuts[a][ia] == region[a][1] - 1 else -1
        if (1 if a != 1 else -1) != outward:
            loc = loc[:, [0, 2, 1]]
        boundary.append(loc)
    res = reduce(data, tol_inf=tol_inf, boundary=np.concatenate(boundary), method=method,
                 **(options or {}), check=check)
    snap = res.snapshots[-1]
    local = np.stack(np.unravel_index(snap.tets, vals.shape), axis=-1) + lo
    tets = (local[..., 0] * plan.shape[1] + local[..., 1]) * plan.shape[2] + local[..., 2]
    interior = data.interior_mask()
    r = snap.residuals[interior]
    stats = {"sse": float(np.dot(r, r)), "count": int(interior.sum()),
             "max": float(np.max(np.abs(snap.residuals))), "n_vertices": int(snap.n_selected),
             "seconds": float(res.timings["total"])}
    return tets.astype(np.int64), stats


def _face_triangles(plan, tris, plane, region):
    """The triangles of ``plane`` that lie on the block ``region``'s face."""
    a, _ = plane
    u, v = _others(a)
    g = np.stack(np.unravel_index(tris, plan.shape), axis=-1)
    inside = np.all((g[..., u] >= region[u][0]) & (g[..., u] < region[u][1])
                    & (g[..., v] >= region[v][0]) & (g[..., v] < region[v][1]), axis=1)
    return tris[inside]


# ----------------------------------------------------------------------------- checks

def check_tetrahedra(shape, tets):
    """Check a tetrahedral mesh of the grid box of ``shape`` points (global indices).

    Every tetrahedron has positive volume (exact, on integer grid coordinates); every
    face is shared by exactly two tetrahedra, or lies on the box's surface and is in
    one; the volumes sum to the box's.  Raises AssertionError naming the first failure.
    """
    tets = np.asarray(tets, np.int64)
    ijk = np.stack(np.unravel_index(tets, shape), axis=-1)  # (T, 4, 3)
    d = ijk[:, 1:] - ijk[:, :1]
    vol6 = (d[:, 0, 0] * (d[:, 1, 1] * d[:, 2, 2] - d[:, 1, 2] * d[:, 2, 1])
            - d[:, 0, 1] * (d[:, 1, 0] * d[:, 2, 2] - d[:, 1, 2] * d[:, 2, 0])
            + d[:, 0, 2] * (d[:, 1, 0] * d[:, 2, 1] - d[:, 1, 1] * d[:, 2, 0]))
    if np.any(vol6 <= 0):
        t = np.flatnonzero(vol6 <= 0)[0]
        raise AssertionError(f"tetrahedron {t} {tuple(tets[t])} has volume {vol6[t] / 6} <= 0")
    box6 = 6 * int(np.prod(np.asarray(shape, np.int64) - 1))
    if int(vol6.sum()) != box6:
        raise AssertionError(f"the tetrahedra fill {vol6.sum() / 6} of the box's {box6 / 6}")
    faces = np.sort(np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 2, 3]], tets[:, [0, 1, 3]],
                                    tets[:, [0, 1, 2]]]), axis=1)
    u, cnt = np.unique(faces, axis=0, return_counts=True)
    if np.any(cnt > 2):
        raise AssertionError(f"face {tuple(u[np.flatnonzero(cnt > 2)[0]])} is in {cnt.max()} tetrahedra")
    once = u[cnt == 1]
    g = np.stack(np.unravel_index(once, shape), axis=-1)  # (F, 3, 3)
    hi = np.asarray(shape) - 1
    on_surface = np.zeros(len(once), bool)
    for a in range(3):
        on_surface |= np.all(g[..., a] == 0, axis=1) | np.all(g[..., a] == hi[a], axis=1)
    if not on_surface.all():
        raise AssertionError(f"face {tuple(once[np.flatnonzero(~on_surface)[0]])} is in one tetrahedron but "
                             f"not on the box's surface (a gap or a non-conforming seam)")


# ----------------------------------------------------------------------------- resources

#: Peak resident bytes of a block job per point of the block, and the fixed part (the
#: interpreter, numpy, numba and the loaded kernels), for the jobs' memory requests.
BLOCK_BYTES_PER_POINT = 1200
JOB_BASE_BYTES = 400 * 2**20
#: Seconds per point of a block job's reduction, for the jobs' runtime requests (generous:
#: a cluster kills a job that overruns its request).
BLOCK_SECONDS_PER_POINT = 1e-4
PLANE_SECONDS_PER_POINT = 2e-5


#: Block sizes (grid intervals per axis) that :func:`block_for_memory` chooses from, largest first.
SUGGESTED_BLOCKS = (128, 96, 64, 48, 32, 16)
#: The most memory a block job of a suggested command line asks for.
SUGGESTED_JOB_BYTES = 1.5 * 2**30


def block_for_memory(available, *, cores=2):
    """The largest block of :data:`SUGGESTED_BLOCKS` whose 3-D job (:func:`job_resources`)
    needs at most :data:`SUGGESTED_JOB_BYTES` and at most ``available / cores`` bytes."""
    bound = min(SUGGESTED_JOB_BYTES, float(available) / max(int(cores), 1))
    for b in SUGGESTED_BLOCKS:
        if JOB_BASE_BYTES + BLOCK_BYTES_PER_POINT * float(b + 1) ** 3 <= bound:
            return b
    return SUGGESTED_BLOCKS[-1]


def job_resources(plan, kind, item=None, *, merged=True):
    """``(mem_mb, runtime_minutes)`` to request for a job of ``kind`` ("kernels", "lines",
    "plane", "block", "merge"); ``merged``: the merge writes the merged mesh, whose memory
    grows with the whole grid (without it, the merge reads one piece at a time)."""
    if kind == "block":
        n = int(np.prod([r[1] - r[0] for r in plan.block_region(item)]))
        mem, secs = JOB_BASE_BYTES + BLOCK_BYTES_PER_POINT * n, 60 + BLOCK_SECONDS_PER_POINT * n
    elif kind == "plane":
        a, _ = item
        u, v = _others(a)
        n = plan.shape[u] * plan.shape[v]
        mem, secs = JOB_BASE_BYTES + 200 * n, 60 + PLANE_SECONDS_PER_POINT * n
    elif kind == "merge":
        n = plan.n_points()
        # the merged mesh: its tetrahedra, about 5 per vertex, the vertices up to about 10 %
        # of the points (measured: 0.6 GB for 8.7 M points reduced to 8 %)
        mem, secs = JOB_BASE_BYTES + (40 * n if merged else 2 * n), 60 + 4e-6 * n
    elif kind == "lines":  # every line along one axis, read one at a time
        b, c = _others(item)
        n = plan.shape[item] * len(plan.cuts[b]) * len(plan.cuts[c])
        mem, secs = JOB_BASE_BYTES + 64 * plan.shape[item] + 100 * 2**20, 60 + 1e-4 * n
    elif kind == "kernels":
        mem, secs = 2 * JOB_BASE_BYTES, 600  # numba's compiler
    else:
        mem, secs = JOB_BASE_BYTES, 60
    return int(np.ceil(mem / 2**20)), int(np.ceil(secs / 60))


#: Grid points a cluster job should hold at least: a cluster spends seconds scheduling each job
#: (about 8 s on a single-node SLURM), and each job starts Snakemake and Python, so planes and
#: blocks smaller than this are reduced several to a cluster job (:func:`group_components`).
MIN_CLUSTER_JOB_POINTS = 2_000_000


def group_components(plan, *, min_points=MIN_CLUSTER_JOB_POINTS):
    """How many planes and how many blocks one cluster job reduces (one after the other, in
    one process: the workflow's rules ``planes_K`` and ``blocks_K``), ``{"planes": P, "blocks":
    B}``: enough for their points to reach ``min_points`` (at most all of them, at least one),
    evened out over the cluster jobs.  ``trivsel blocks`` gives them to a cluster run as
    ``--config planes_per_job=P blocks_per_job=B``."""
    planes = [plan.shape[u] * plan.shape[v] for u, v in (_others(a) for a, _ in plan.planes())]
    blocks = [int(np.prod([r[1] - r[0] for r in plan.block_region(b)])) for b in plan.blocks()]
    out = {}
    for name, n in (("planes", planes), ("blocks", blocks)):
        per_job = min(len(n), max(1, int(np.ceil(min_points / np.mean(n)))))
        out[name] = int(np.ceil(len(n) / np.ceil(len(n) / per_job)))
    return out


def job_batches(items, per_job):
    """``items`` (the plan's planes or blocks, in plan order) in consecutive runs of
    ``per_job``: the items one cluster job reduces (neighbours, so that its reads are near
    one another)."""
    items = list(items)
    per_job = max(int(per_job), 1)
    return [items[i:i + per_job] for i in range(0, len(items), per_job)]


# ----------------------------------------------------------------------------- jobs (files)
#
# The folder of a blocked run:
#   blocks.json                   the configuration and the plan
#   lines/A.npz                   kept positions of each cut line along axis A (key "A_B_C"),
#                                 and their error sums
#   planes/A_I.npz                triangles of each cut plane's faces, and their error sums
#   pieces/X_Y_Z.npz, .vtu        each block's tetrahedra, and the block as a ParaView piece
#   merged/                       the merge job's results, linked to the top when complete:
#   mesh.pvtu, mesh.vtu           the pieces as one partitioned dataset; the merged mesh
#   summary.json                  E_RMS, E_inf, vertices, tetrahedra, points

CONFIG = "blocks.json"


def item_name(item):
    return "_".join(str(int(i)) for i in item)


def parse_item(name):
    return tuple(int(s) for s in name.split("_"))


#: The most jobs a blocked run plans: beyond it, Snakemake's plan alone (even a dry run)
#: takes minutes and memory that grow with the job count.  A larger block size has fewer jobs.
MAX_JOBS = 20000


def plan_counts(shape, block):
    """Blocks per axis of :func:`plan_blocks` ``(shape, block)``, by arithmetic (no cut list is
    built, so a hostile size costs nothing).  ``block``: an int or 3 ints >= 2."""
    counts = []
    for n, b in zip(shape, np.broadcast_to(np.asarray(block, np.int64), (3,)).tolist()):
        k = -(-(int(n) - 1) // b)  # len(range(0, n - 1, b))
        cuts = k + 1 - (k + 1 > 2 and (int(n) - 1) - (k - 1) * b < 2)  # a short remainder is joined
        counts.append(cuts - 1)
    return tuple(counts)


def job_count(counts) -> int:
    """The jobs of a plan with ``counts`` blocks per axis: kernels, the lines of three axes,
    every cut plane and block, the merge."""
    return 5 + sum(c + 1 for c in counts) + int(np.prod(counts, dtype=object))


def _smallest_block(shape, most=MAX_JOBS):
    """The smallest block size (the same along every axis) whose plan has at most ``most`` jobs."""
    lo, hi = 2, max(2, max(shape) - 1)
    while lo < hi:
        mid = (lo + hi) // 2
        if job_count(plan_counts(shape, mid)) <= most:
            hi = mid
        else:
            lo = mid + 1
    return lo


def check_plan_size(shape, block):
    """One-line InputError when cutting ``shape`` into blocks of ``block`` makes more than
    :data:`MAX_JOBS` jobs, naming the count and the smallest block size that has few enough.
    Call it after :func:`plan_blocks`'s own checks of ``block`` or with a valid one."""
    counts = plan_counts(shape, block)
    n = job_count(counts)
    if n > MAX_JOBS:
        raise InputError(f"block size {block} cuts the grid of {tuple(shape)} points into "
                         f"{int(np.prod(counts, dtype=object)):,} blocks ({n:,} jobs), more than the {MAX_JOBS:,} "
                         f"a run plans: use --block {_smallest_block(shape)} or more")


def check_job_memory(plan, *, merged=True):
    """One-line InputError when one job of the plan needs more memory than this machine has
    available (a local run: the jobs run here): the largest block (naming a block size
    that fits) or the merged mesh (naming --no-merged)."""
    from ..resources import available_bytes

    avail = available_bytes()
    if avail is None:
        return
    biggest = tuple(int(np.argmax(np.diff(c))) for c in plan.cuts)  # the longest block along each axis
    kinds = [("block", biggest, "a smaller --block")] + [("plane", (a, 0), "a smaller grid") for a in range(3)]
    kinds.append(("merge", None, "--no-merged (the pieces and mesh.pvtu only)"))
    for kind, item, fix in kinds:
        mb = job_resources(plan, kind, item, merged=merged)[0]
        if kind == "merge" and not merged:
            continue
        if mb * 2**20 > avail:
            what = f"block {item_name(item)}" if kind == "block" else ("the merged mesh" if kind == "merge"
                                                                        else f"the planes normal to {'xyz'[item[0]]}")
            raise InputError(f"a job of {what} needs about {mb / 1024:.3g} GiB, more than the "
                             f"{avail / 2**30:.3g} GiB of memory available: use {fix}")


def input_stamp(path):
    """What tells a changed input: size and modification time (ns) of the file (and of a
    detached NRRD header's data file), or of every file in a folder input (a Zarr store: the
    file count, total size and latest time)."""
    p = Path(path)
    if not p.is_dir():
        st = p.stat()
        stamp = [int(st.st_size), int(st.st_mtime_ns)]
        data = _detached_data_file(p)
        if data is not None:  # a .nhdr's samples are in another file: a change there is a change too
            st = data.stat()
            stamp += [int(st.st_size), int(st.st_mtime_ns)]
        return stamp
    count, size, latest = 0, 0, 0
    for root, _, files in os.walk(p):
        for f in files:
            st = os.stat(os.path.join(root, f))
            count, size, latest = count + 1, size + st.st_size, max(latest, st.st_mtime_ns)
    return [count, size, latest]


def _detached_data_file(p):
    """The data file a NRRD header names (``data file``, relative to its folder), or None."""
    if p.suffix.lower() != ".nhdr":
        return None
    import nrrd

    try:
        with open(p, "rb") as fh:
            header = nrrd.read_header(fh)
        name = header.get("data file", header.get("datafile"))
    except Exception:  # an unreadable header is refused, naming it, when the volume is opened
        return None
    data = None if name is None else p.parent / str(name)
    return data if data is not None and data.is_file() else None


#: Bytes of float64 samples :func:`check_values` reads at a time.
CHECK_READ_BYTES = 64 * 2**20


def check_values(vol):
    """Read a volume through once, slab by slab, before any job: a non-finite value, or an
    integer that float64 cannot hold exactly (beyond 2^53), is refused naming it and its grid
    index (:meth:`trivsel.io.regions.Volume.read` checks each slab), and so is a file that
    cannot be read to its end (truncated, a damaged chunk), so that no job fails on it after
    others have run.  Integers of up to 32 bits are exact and finite, but they are read too: a
    file's damage shows only when it is read."""
    from ..resources import check_memory

    axis = vol.slab_axis
    per_slice = int(np.prod(vol.shape)) // vol.shape[axis]
    step = max(1, CHECK_READ_BYTES // (8 * per_slice))
    # a slab as stored and as float64, and the check's temporaries
    check_memory(24.0 * per_slice * step, f"checking {vol.source!r} in slabs of {step} x {per_slice} values")
    for start in range(0, vol.shape[axis], step):
        region = [(0, n) for n in vol.shape]
        region[axis] = (start, min(vol.shape[axis], start + step))
        vol.read(tuple(region))


def check_new_input(out, full):
    """Before the first run in ``out`` (no ``blocks.json`` yet), read the input's values
    through once (:func:`check_values`).  A rerun's input has the stamp of the run that
    checked it (:func:`check_run_folder`), so it is not read again."""
    if full.get("input") is not None and not (Path(out) / CONFIG).exists():
        check_values(_open(full))


def check_types(config):
    """One-line InputError when ``input`` or ``array`` of a run's configuration is not a
    non-empty string (a YAML value may be of any type)."""
    for key, what in (("input", "a path"), ("array", "an array's name")):
        v = config.get(key)
        if v is not None and (not isinstance(v, str) or not v):
            raise InputError(f"{key} must be {what} (a non-empty string), got {shown(v)}")


def make_config(config):
    """Check a blocked run's configuration and complete it (no file is written).

    ``config``: the source (``input`` path, or ``function`` and ``n``; ``array``,
    ``volume``), ``block`` (grid intervals per block), ``tol_inf``, ``method``, ``merged``.
    The volume is opened (its header only) for its shape and geometry; the plan's job count
    is checked (:func:`check_plan_size`); its values are not read (:func:`check_new_input`).
    Returns the full configuration, with the plan and the input's :func:`input_stamp`.
    """
    from ..methods import METHODS, get_method

    check_types(config)
    block = config.get("block")
    if isinstance(block, bool) or not isinstance(block, numbers.Integral) or not 2 <= block <= MAX_BLOCK:
        raise InputError(f"block must be an integer from 2 to {MAX_BLOCK} (grid intervals per block), "
                         f"got {shown(block)}")
    cfg = {k: config.get(k) for k in SOURCE_KEYS}
    method = config.get("method", "greedy")
    stages = getattr(get_method(method), "BLOCK_STAGES", None)  # a method's own stages in blocks
    tol = config.get("tol_inf")
    if tol is None and not stages:  # the inserting methods stop in blocks at tol_inf only
        raise InputError(f"tol_inf must be a finite number >= 0, got {shown(tol)}")
    check_tolerance("tol_inf", tol)
    if not get_method(method).PRESCRIBED_BOUNDARY and not stages:  # the 3-D stage starts from prescribed triangles
        able = [name for name, m in METHODS.items() if m.PRESCRIBED_BOUNDARY or getattr(m, "BLOCK_STAGES", None)]
        raise InputError(f"method {method!r} cannot take the blocks' prescribed faces: choose {' or '.join(able)}")
    merged = config.get("merged", True)
    if not isinstance(merged, bool):
        raise InputError(f"merged must be true or false, got {merged!r}")
    for key in STOP_KEYS:
        if config.get(key) is not None and not stages:
            if key == "values":  # not a stop: the values written, which are the data's in these blocks
                if list(config[key]) == ["data"]:
                    continue
                raise InputError(f"method {method!r} writes the data values in blocks, not {shown(config[key])}: "
                                 "--values applies to --method decimate")
            raise InputError(f"method {method!r} stops in blocks at tol_inf only, not at {key}: use --tol-inf "
                             "(or --method decimate)")
    vol = _open(cfg)
    plan_blocks((3, 3, 3), config.get("block"))  # the block size's own checks, on a grid of one block
    if stages:
        import importlib

        extra = importlib.import_module(stages).make_config(config, vol.shape)
        plan = Plan.from_dict(extra["plan"])
    else:
        extra = {}
        check_plan_size(vol.shape, config.get("block"))
        plan = plan_blocks(vol.shape, config.get("block"))
    if cfg["input"] is not None:
        cfg["input"] = str(Path(cfg["input"]).resolve())
    return {**cfg, "block": config.get("block"), "tol_inf": None if tol is None else float(tol), "method": method,
            "merged": merged, **extra, "plan": plan.to_dict(),
            "origin": [float(x) for x in vol.origin], "spacing": [float(x) for x in vol.spacing],
            "input_stamp": None if cfg["input"] is None else input_stamp(cfg["input"])}


def _is_run_config(path):
    """Whether ``path`` is a blocks.json that ``trivsel blocks`` wrote."""
    try:
        d = json.loads(Path(path).read_text())
        Plan.from_dict(d["plan"])
        return isinstance(d, dict) and {"tol_inf", "method", "block"} <= set(d)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


#: The names ``trivsel blocks`` writes at the top of its folder.
RUN_NAMES = (CONFIG, "kernels.done", "lines", "planes", "pieces", "merged", "logs", "benchmarks", "mesh.pvtu",
             "mesh.vtu", "summary.json", ".snakemake", "costs", "tau.json", "meshes", "passes")


def check_run_folder(out, full=None):
    """Refuse a folder where this run would overwrite what it did not write.

    A folder without a ``blocks.json`` of an earlier blocked run must not hold any of the
    names a run writes (:data:`RUN_NAMES`); one with it must hold the same configuration
    ``full`` (:func:`make_config`): other settings, or an input changed since, are refused
    naming the difference (a rerun never reports the old results as the new ones).
    """
    out = Path(out)
    path = out / CONFIG
    if not out.is_dir():
        return
    if not (path.exists() or path.is_symlink()):
        for name in RUN_NAMES:
            if (out / name).exists() or (out / name).is_symlink():
                raise InputError(f"{str(out / name)!r} was not written by trivsel blocks (the folder has no "
                                 f"{CONFIG} of a blocked run): choose another --out; trivsel never overwrites it")
        return
    if not _is_run_config(path) or path.is_symlink():
        raise InputError(f"{str(path)!r} is not the configuration of a trivsel blocks run: choose another --out; "
                         "trivsel never overwrites it")
    if full is None:
        return
    old = json.loads(path.read_text())
    for key in full:
        if old.get(key) != json.loads(json.dumps(full[key])):
            if key == "input_stamp" and old.get("input") == full["input"]:
                raise InputError(f"the input {full['input']!r} changed since the blocked run in {str(out)!r} "
                                 "(its size or modification time): choose a new folder or remove it")
            raise InputError(f"{str(out)!r} holds a blocked run with another configuration ({key}: "
                             f"{json.dumps(old.get(key))[:60]} there, {json.dumps(full[key])[:60]} now): "
                             "choose a new folder or remove it")


def write_config(out, config):
    """Check a blocked run's configuration (:func:`make_config`), check the folder
    (:func:`check_run_folder`) and write ``out/blocks.json``.  Returns the full configuration."""
    full = make_config(config)
    out = Path(out)
    check_run_folder(out, full)
    check_new_input(out, full)
    out.mkdir(parents=True, exist_ok=True)
    _atomic_write_text(out / CONFIG, json.dumps(full, indent=1))
    return full


def _open(cfg):
    from ..io.regions import open_volume

    return open_volume(cfg.get("input"), function=cfg.get("function"), n=cfg.get("n"), array=cfg.get("array"),
                       volume=cfg.get("volume"))


def read_config(out):
    """A run folder's configuration and plan; a one-line InputError when ``out`` is not one."""
    path = Path(out) / CONFIG
    if not path.is_file():
        raise InputError(f"not the folder of a blocked run (no {CONFIG}): {shown(str(out))}")
    with open(path) as fh:
        cfg = json.load(fh)
    return cfg, Plan.from_dict(cfg["plan"])


def check_item(kind, item, items):
    """A one-line InputError unless ``item`` names one of the run's jobs of ``kind`` (``items``,
    their names in order)."""
    if item not in items:
        some = ", ".join(items[:4]) + (f", ... ({len(items)} in all)" if len(items) > 4 else "")
        raise InputError(f"no {kind} job {shown(item)} in this run: its {kind} jobs are {some or 'none'}")


def _atomic_write_text(path, text):
    from ..io.pieces import _atomic_write

    _atomic_write(path, lambda tmp: Path(tmp).write_text(text), overwrite=True)


def _atomic_savez(path, **arrays):
    _atomic_savez_each(path, [arrays])


def _atomic_savez_each(path, groups):
    """An .npz file (as :func:`numpy.savez` writes one) of the arrays of each dict of the
    iterable ``groups`` in turn, each group written as it comes: a job that makes its blocks' or
    regions' arrays one at a time holds one at a time.  Written beside ``path`` and moved onto
    it when complete (:func:`trivsel.io.pieces._atomic_write`)."""
    import zipfile

    from ..io.pieces import _atomic_write

    def write(tmp):
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            for arrays in groups:
                for name, a in arrays.items():
                    with zf.open(name + ".npy", "w", force_zip64=True) as fh:
                        np.lib.format.write_array(fh, np.asanyarray(a), allow_pickle=False)

    _atomic_write(path, write, overwrite=True)


def _stats(d):
    return {k: float(d[k]) for k in ("sse", "max", "count")}


def run_job(out, kind, name):
    """Run one job of the blocked run in folder ``out``: ``kind`` is "kernels", "lines",
    "plane", "block" or "merge"; ``name`` the item (the axis ``A`` for the lines along
    it, ``A_I`` for a plane, ``X_Y_Z`` for a block, ignored otherwise)."""
    cfg, plan = read_config(out)
    out = Path(out)
    tol = cfg["tol_inf"]
    items = {"lines": sorted({str(ln[0]) for ln in plan.lines()}), "plane": [item_name(q) for q in plan.planes()],
             "block": [item_name(b) for b in plan.blocks()]}
    if kind in items:
        check_item(kind, name, items[kind])
    if kind == "lines":
        # every cut line along one axis (1-D work is small: one job per axis)
        axis = int(name)
        vol = _open(cfg)
        res = {item_name(ln): reduce_line(vol, plan, ln, tol_inf=tol) for ln in plan.lines() if ln[0] == axis}
        _atomic_savez(out / "lines" / f"{axis}.npz", **{k: r["kept"] for k, r in res.items()},
                      **{f"_{k}": np.sum([r[k] for r in res.values()]) for k in ("sse", "count")},
                      _max=np.max([r["max"] for r in res.values()]))
    elif kind == "plane":
        a, ia = parse_item(name)
        lines = {}
        for axis in _others(a):
            with np.load(out / "lines" / f"{axis}.npz") as z:
                lines.update({ln: z[item_name(ln)] for ln in plan.lines()
                              if ln[0] == axis and line_in_plane(ln, (a, ia))})
        r = reduce_plane(_open(cfg), plan, (a, ia), lines, tol_inf=tol)
        _atomic_savez(out / "planes" / f"{name}.npz", triangles=r["triangles"], **_stats(r))
    elif kind == "block":
        block = parse_item(name)
        faces = {p: np.load(out / "planes" / f"{item_name(p)}.npz")["triangles"]
                 for p, _ in block_faces(plan, block)}
        vol = _open(cfg)
        tets, st = reduce_block(vol, plan, block, faces, tol_inf=tol, method=cfg["method"])
        write_block_piece(out / "pieces" / f"{name}.vtu", plan, tets, vol)
        _atomic_savez(out / "pieces" / f"{name}.npz", tets=tets, n_vertices=st["n_vertices"],
                      seconds=st["seconds"], **_stats(st))
    elif kind == "merge":
        merge_blocks(out)
    elif kind == "kernels":
        compile_kernels(cfg["method"])
    else:
        raise InputError(f"unknown job kind {kind!r}: choose kernels, lines, plane, block or merge")


def compile_kernels(method):
    """Compile (or load from numba's cache) every kernel a blocked run uses: the 1-D and 2-D
    stages' on a small face, and the 3-D reduction's on a small block."""
    from .faces import reduce_face, reduce_polyline

    x = np.linspace(0.0, 1.0, 5)
    f = np.sin(3 * x[:, None, None] + 2 * x[None, :, None] - x[None, None, :])
    reduce_polyline(f[:, 0, 0], tol_inf=0.0)
    border = np.zeros((5, 5), bool)
    border[[0, -1], :] = border[:, [0, -1]] = True
    reduce_face(f[:, :, 0], border, tol_inf=0.0)
    plan = plan_blocks(f.shape, 4)

    class _Array:
        shape, origin, spacing = f.shape, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)

        def read(self, region):
            return f[tuple(slice(*r) for r in region)]

    reduce_in_blocks(_Array(), plan, tol_inf=0.0, method=method, blocks=[(0, 0, 0)])


def line_in_plane(line, plane):
    """Whether the cut line lies in the cut plane (its cut on the plane's axis is the plane's)."""
    a, ib, ic = line
    pa, ia = plane
    b, c = _others(a)
    return (b == pa and ib == ia) or (c == pa and ic == ia)


def write_block_piece(path, plan, tets, volume):
    """One block's tetrahedra as a .vtu piece: the vertices' coordinates (bit for bit the
    whole grid's), point arrays ``value`` and ``original_index`` (the input's point id,
    :meth:`trivsel.io.regions.Volume.file_ids`)."""
    from ..io.pieces import write_piece

    ids, local = np.unique(tets, return_inverse=True)
    ijk = np.stack(np.unravel_index(ids, plan.shape), axis=1)
    region = tuple(zip(ijk.min(axis=0).tolist(), (ijk.max(axis=0) + 1).tolist()))
    pts, rijk = volume.points(region)
    vals = np.asarray(volume.read(region), float).ravel()
    rshape = [b - a for a, b in region]
    at = np.ravel_multi_index(tuple((ijk - ijk.min(axis=0)).T), rshape)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    write_piece(path, pts[at], local.reshape(tets.shape), vals[at], volume.file_ids(rijk[at]), overwrite=True)


def merge_blocks(out):
    """The merge, into ``merged/`` and then linked to the top (:func:`publish_results`):
    ``mesh.pvtu`` over the pieces, the merged ``mesh.vtu`` (global
    numbering; if the configuration asks for it) and ``summary.json`` (E_RMS over all
    points from every stage's squared residuals, E_inf, vertices, tetrahedra)."""
    from ..io.pieces import merge_pieces, write_pvtu

    cfg, plan = read_config(out)
    out = Path(out)
    sse, mx, own = 0.0, 0.0, 0
    for axis in range(3):
        with np.load(out / "lines" / f"{axis}.npz") as z:
            sse, mx, own = sse + float(z["_sse"]), max(mx, float(z["_max"])), own + int(z["_count"])
    for folder, items in (("planes", plan.planes()), ("pieces", plan.blocks())):
        for it in items:
            with np.load(out / folder / f"{item_name(it)}.npz") as z:
                sse, mx, own = sse + float(z["sse"]), max(mx, float(z["max"])), own + int(z["count"])
    pieces = [out / "pieces" / f"{item_name(b)}.vtu" for b in plan.blocks()]
    n_tets, verts = 0, []
    for b in plan.blocks():
        with np.load(out / "pieces" / f"{item_name(b)}.npz") as z:
            n_tets += len(z["tets"])
            verts.append(np.unique(z["tets"]))
    n_vertices = int(len(np.unique(np.concatenate(verts))))
    staged = out / STAGED
    write_pvtu(staged / "mesh.pvtu", pieces, overwrite=True, relative_to=out)
    if cfg.get("merged", True):
        merge_pieces(pieces, staged / "mesh.vtu", overwrite=True)
    N = plan.n_points()
    summary = {"points": N, "vertices": n_vertices, "fraction": n_vertices / N, "tetrahedra": n_tets,
               "E_rms": float(np.sqrt(sse / N)), "E_inf": mx, "tol_inf": cfg["tol_inf"],
               "blocks": len(plan.blocks()), "planes": len(plan.planes()), "lines": len(plan.lines()),
               "owned_points": own}
    _atomic_write_text(staged / "summary.json", json.dumps(summary, indent=1))
    publish_results(out)
    return summary


#: The merge job's own folder: Snakemake deletes a job's outputs before it runs the job again,
#: so the results a user opens (:data:`RESULTS`, at the top of the run's folder) are hard links
#: to these, replaced only once a merge is complete (:func:`publish_results`).
STAGED = "merged"
RESULTS = ("summary.json", "mesh.pvtu", "mesh.vtu")


def publish_results(out):
    """Link the merge's complete results (``merged/``) to the top of the run's folder, each by
    an atomic replace, with SIGINT and SIGTERM held until all are in place (a signal then
    takes effect after), so the folder never shows results of two merges.  A result the
    configuration does not produce (``mesh.vtu`` with ``merged: false``) is removed."""
    import signal
    import threading

    from ..io import TMP_PREFIX

    out = Path(out)
    names = [n for n in RESULTS if (out / STAGED / n).is_file()]
    held = {signal.SIGINT, signal.SIGTERM}
    main = threading.current_thread() is threading.main_thread()
    if main:
        signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        for name in names:
            if (out / name).exists() and os.path.samefile(out / STAGED / name, out / name):
                continue  # published already (a rename onto the same file would do nothing)
            tmp = out / f"{TMP_PREFIX}{name}"
            tmp.unlink(missing_ok=True)
            os.link(out / STAGED / name, tmp)
            os.replace(tmp, out / name)
        for name in set(RESULTS) - set(names):
            (out / name).unlink(missing_ok=True)
    finally:
        if main:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, held)


SNAKEFILE = Path(__file__).with_name("workflow.smk")
#: Runs Snakemake in the run's process group and stops the group when ``trivsel blocks`` dies.
SUPERVISE = Path(__file__).with_name("supervise.py")
#: Seconds the stopped jobs of an interrupted run get to remove their temporary files
#: before they are killed.
STOP_SECONDS = 30


class JobFailed(Exception):
    """A blocked run that ended without its results: a job failed, or Snakemake did.  The
    message is one line (the failing job's own message and where its log is); ``status``
    is the exit status for it: 2 when the job refused its input, else 1; ``own``: whether the
    message is the job's own (from its log), which says more than a cluster's job state."""

    def __init__(self, message, status=1, *, own=False):
        super().__init__(message)
        self.status = status
        self.own = own


def check_cores(cores):
    """``cores`` as Snakemake takes it: ``"all"`` or an integer >= 1 (``0`` would wait for ever)."""
    if str(cores) == "all":
        return "all"
    try:
        n = int(str(cores))
    except ValueError:
        n = 0
    if n < 1:
        raise InputError(f"cores (-c) must be 'all' or an integer >= 1, got {cores!r}")
    return n


#: Snakemake's options that would move the run out of its folder, run another workflow, mark
#: results done without computing them, or drop the lock and records a rerun relies on.
REFUSED_SNAKEMAKE_ARGS = ("--directory", "-d", "--snakefile", "-s", "--touch", "-t", "--nolock", "--unlock",
                          "--delete-all-output", "--delete-temp-output", "--cleanup-metadata", "--cores", "-c",
                          "--dry-run", "-n", "--dryrun", "--configfile", "--configfiles", "--config", "-C",
                          "--ignore-incomplete", "--ii")


def check_snakemake_args(snakemake_args):
    """One-line InputError for a Snakemake argument after ``--`` that would break the output
    contract (:data:`REFUSED_SNAKEMAKE_ARGS`), naming it and what to use instead."""
    for a in snakemake_args:
        name = a.split("=")[0]
        if name in REFUSED_SNAKEMAKE_ARGS:
            instead = {"--cores": "-c before '--'", "-c": "-c before '--'", "--dry-run": "-n before '--'",
                       "-n": "-n before '--'", "--dryrun": "-n before '--'"}.get(name, "")
            raise InputError(f"Snakemake's {name} cannot be passed after '--': trivsel blocks sets where and "
                             f"what it runs{'; use ' + instead if instead else ''}")


def _runs_locally(snakemake_args):
    """Whether the jobs run on this machine (no executor or profile among Snakemake's arguments)."""
    remote = ("--executor", "-e", "--profile", "--workflow-profile", "--cluster", "--slurm", "--kubernetes")
    return not any(a.split("=")[0] in remote for a in snakemake_args)


def _lock_folder(out):
    """An open descriptor of the folder ``out`` holding its exclusive lock (``flock``): the lock
    ends when every process holding the descriptor has closed it or ended, so none is left
    behind in the folder.  Another run that holds it is refused with one line."""
    import fcntl

    fd = os.open(out, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise InputError(f"another trivsel blocks run is working in {str(out)!r}: wait for it to end") from None
    return fd


def _start_session():
    """In the supervisor's process (:data:`SUPERVISE`), before it starts: a session (and
    process group) of its own, which Snakemake and its jobs share, so that stopping the run
    stops every one of them; and SIGTERM, until the supervisor sets its own signal, when the
    ``trivsel blocks`` process that started it dies, however it dies (Linux)."""
    import ctypes
    import signal

    os.setsid()
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _stop_group(proc):
    """Stop Snakemake and its jobs (its process group): SIGTERM, which the jobs answer by
    removing their temporary files, then SIGKILL for what still runs after
    :data:`STOP_SECONDS`.  Further SIGINT and SIGTERM wait meanwhile."""
    import signal
    import threading
    import time

    main = threading.current_thread() is threading.main_thread()
    saved = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)} if main else {}
    try:
        for sig, wait in ((signal.SIGTERM, STOP_SECONDS), (signal.SIGKILL, 10)):
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                break
            deadline = time.monotonic() + wait
            while time.monotonic() < deadline:
                proc.poll()  # reaps Snakemake: a zombie would keep the group alive
                try:
                    os.killpg(proc.pid, 0)
                except ProcessLookupError:
                    break
                time.sleep(0.05)
            else:
                continue
            break
        proc.wait()
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)


def _remove_run_temporaries(out):
    from ..io import remove_temporaries

    for folder in (out, out / "lines", out / "planes", out / "pieces"):
        if folder.is_dir():
            remove_temporaries(folder)


_STEPS = re.compile(r"^(\d+) of (\d+) steps \(\d+%\) done")
_ERROR_RULE = re.compile(r"^Error in rule (\w+):")
_LOG = re.compile(r"^\s+log: ([^\s,]+)")  # on a cluster the scheduler's log follows, after a comma


def _job_message(log):
    """``(text, bad_input, own)``: a failed job's one-line message from its log, whether it was
    bad input, and whether the log said anything: its ``trivsel: error:`` line (bad input),
    else the last line (a traceback's exception), else why there is none (not its own)."""
    try:
        lines = [x.strip() for x in Path(log).read_text(errors="replace").splitlines() if x.strip()]
    except OSError:
        return "its log is missing", False, False
    for line in reversed(lines):
        if line.startswith("trivsel: error: "):
            return line[len("trivsel: error: "):], True, True
    return (lines[-1], False, True) if lines else ("its log is empty", False, False)


def _follow(proc, out, show):
    """Read Snakemake's output: one progress line over the jobs on stderr (``show``: a
    self-overwriting line on a terminal), and what a failure needs.  Returns
    ``(jobs_done, failure)``: ``failure`` is None or a :class:`JobFailed`."""
    import collections
    import sys

    tail = collections.deque(maxlen=50)
    done = 0
    rule = log = None
    for line in proc.stdout:
        line = line.rstrip("\n")
        tail.append(line)
        m = _STEPS.match(line)
        if m:
            done, total = int(m.group(1)), int(m.group(2))
            if show:
                width = 24
                bar = "#" * (width * done // max(total, 1))
                sys.stderr.write(f"\rtrivsel blocks [{bar:<{width}}] {done}/{total} jobs")
                sys.stderr.flush()
        elif _ERROR_RULE.match(line) and rule is None:
            rule = _ERROR_RULE.match(line).group(1)
        elif rule is not None and log is None and _LOG.match(line):
            log = _LOG.match(line).group(1)
    if show and done:
        sys.stderr.write("\n")
    if proc.wait() == 0:
        return done, None
    # a full disk leaves a job's log empty, and Snakemake cannot record its jobs
    full_disk = (f"no space left on the device of {str(out)!r}; free some and run the same command again to resume"
                 if any("No space left on device" in x for x in tail) else None)
    if rule is not None:
        where = f" (its log: {out / log})" if log else ""
        text, bad_input, own = _job_message(out / log) if log else ("no log", False, False)
        item = f" {Path(log).stem}" if log and Path(log).parent.name == rule else ""  # logs/RULE/ITEM.log
        if not bad_input and full_disk:
            return done, JobFailed(f"job {rule}{item} failed: {full_disk}")
        return done, JobFailed(f"job {rule}{item} failed: {text}{where}; --verbose shows Snakemake's log",
                               2 if bad_input else 1, own=own)
    if full_disk:
        return done, JobFailed(f"Snakemake failed: {full_disk}")
    errors = [x.strip() for x in tail if "error" in x.lower() and x.strip()]
    last = errors[-1] if errors else next((x.strip() for x in reversed(tail) if x.strip()), "no output")
    return done, JobFailed(f"Snakemake failed (exit status {proc.returncode}): {last}")


def run_workflow(out, config, *, cores="all", snakemake_args=(), dry_run=False, verbose=False, show=False,
                 job_points=None):
    """Run the blocked workflow in the folder ``out`` (:data:`SNAKEFILE`), keeping the output
    contract of ``trivsel reduce``.

    Snakemake runs ``trivsel/blocks/workflow.smk`` in ``out``: locally on ``cores``, or on a
    cluster with ``snakemake_args`` such as ``("--executor", "slurm", "--workflow-profile",
    "workflow/profiles/slurm")``.  Run again, it does only the jobs whose files are missing
    or incomplete: a killed run resumes where it stopped.

    * ``out`` and the configuration are checked before any work (:func:`trivsel.io.check_output_dir`,
      :func:`make_config`): an input inside it, or it inside an input, is refused; so are
      files that no blocked run wrote (:func:`check_run_folder`), another configuration, an
      input changed since the run there, a plan of more than :data:`MAX_JOBS` jobs, and
      (local runs) a job larger than the memory available;
    * one run at a time holds the folder (a lock on the folder itself, gone with the run);
    * ``dry_run`` shows the jobs and creates nothing (a new folder is planned in a temporary one),
      after the checks above and the lock of a folder that is there: it refuses what the run
      would before its first job;
    * an interruption (KeyboardInterrupt, which the CLI raises on SIGTERM too) stops
      Snakemake and every job it started (their process group), removes their temporary
      files and raises again; finished jobs are kept for the next run.

    ``job_points``: planes and blocks of fewer grid points are reduced several to a job
    (:func:`group_components`); default :data:`MIN_CLUSTER_JOB_POINTS` on a cluster, 0 (one job
    per plane and block) on a local run.  The results do not depend on it.

    ``verbose`` passes Snakemake's own output through; otherwise ``show`` prints one progress
    line over the jobs.  Returns the number of Snakemake's steps done (None with ``verbose``;
    Snakemake's exit status for a dry run); raises :class:`JobFailed` when the run ends without
    its results.
    """
    import importlib.util
    import shutil
    import subprocess
    import sys
    import tempfile
    import time

    from ..io import check_output_dir

    if importlib.util.find_spec("snakemake") is None:
        raise InputError("trivsel blocks runs on Snakemake, which is not installed: "
                         "pip install 'trivsel[workflow]'")
    cores = check_cores(cores)
    check_snakemake_args(snakemake_args)
    if job_points is None:
        job_points = 0 if _runs_locally(snakemake_args) else MIN_CLUSTER_JOB_POINTS
    if isinstance(job_points, bool) or not isinstance(job_points, (int, np.integer)) or job_points < 0:
        raise InputError(f"--job-points must be a whole number of grid points, 0 or more; got {job_points!r}")
    source = [config["input"]] if config.get("input") is not None else []
    out = check_output_dir(out, source)
    full = make_config(config)
    stages = _stages(full)
    if _runs_locally(snakemake_args):
        if stages:
            stages.check_job_memory(full)
        else:
            check_job_memory(Plan.from_dict(full["plan"]), merged=full["merged"])
    check_run_folder(out, full)
    check_new_input(out, full)
    # batch small jobs on a cluster; name the SLURM jobs after the folder, so that they can be
    # found and cancelled (Snakemake's arguments given after `--` come later and win)
    batch = [] if job_points == 0 or stages else ["--config", *(
        f"{k}_per_job={v}" for k, v in group_components(Plan.from_dict(full["plan"]), min_points=job_points).items())]
    prefix = slurm.job_prefix(out) if importlib.util.find_spec("snakemake_executor_plugin_slurm") else None
    if prefix:
        batch += ["--slurm-jobname-prefix", prefix]
    on_slurm = prefix is not None and not _runs_locally(snakemake_args) and slurm.available()

    def command(folder, *extra):
        snakefile = SNAKEFILE if stages is None else stages.SNAKEFILE
        return [sys.executable, "-m", "snakemake", "--snakefile", str(snakefile), "--directory", str(folder),
                "--cores", str(cores), *extra, *batch, *snakemake_args]

    if dry_run:  # in the folder of an earlier run of this configuration, else in a temporary one
        # whether a file system takes the folder, check_output_dir has tried (a folder made in
        # its nearest parent); what is left of the run's own checks is the lock of a folder
        # that is there, which another run may hold
        if out.is_dir():
            os.close(_lock_folder(out))
        plan_in = out if (out / CONFIG).exists() else Path(tempfile.mkdtemp(prefix="trivsel-blocks-plan-"))
        try:
            if plan_in != out:
                _atomic_write_text(plan_in / CONFIG, json.dumps(full, indent=1))
            return subprocess.run(command(plan_in, "--dry-run"), check=False).returncode
        finally:
            if plan_in != out:
                shutil.rmtree(plan_in, ignore_errors=True)

    made = _make_run_folder(out)
    lock = _lock_folder(out)
    fresh = False
    try:
        check_run_folder(out, full)  # again, now that no other run can change it
        if not (out / CONFIG).exists():
            _atomic_write_text(out / CONFIG, json.dumps(full, indent=1))
            fresh = True
        _remove_run_temporaries(out)
        if any((out / ".snakemake" / "locks").glob("*")):  # left by a killed run; no run holds the folder
            subprocess.run(command(out, "--unlock"), capture_output=True, check=False)
        pipe = {} if verbose else {"stdout": subprocess.PIPE, "stderr": subprocess.STDOUT, "text": True,
                                   "errors": "replace"}
        if on_slurm:  # jobs a killed earlier run left queued or running: this run holds the folder
            stale = slurm.cancel_jobs(prefix)
            if stale:
                print(f"trivsel: cancelled {len(stale)} SLURM job(s) left by an earlier run in {out}: "
                      f"{' '.join(stale)}", file=sys.stderr)
        started = time.time()
        # Snakemake runs under a supervisor that holds the folder's lock until every job has
        # ended, and stops them all if this process is killed outright (supervise.py)
        proc = subprocess.Popen([sys.executable, str(SUPERVISE), str(os.getpid()), str(STOP_SECONDS),
                                 *command(out, "--rerun-incomplete")],
                                preexec_fn=_start_session, pass_fds=(lock,), **pipe)
        try:
            if verbose:
                done, failure = None, None
                if proc.wait() != 0:
                    failure = JobFailed(f"Snakemake failed (exit status {proc.returncode}); its log is above")
            else:
                done, failure = _follow(proc, out, show)
        except BaseException:
            _stop_group(proc)
            if on_slurm:
                slurm.cancel_jobs(prefix)
            raise
        finally:
            _remove_run_temporaries(out)
        if failure is None:
            publish_results(out)  # again: a result deleted at the top since the merge is linked anew
            missing = [n for n in RESULTS if (n != "mesh.vtu" or full["merged"]) and not (out / n).is_file()]
            if missing:
                failure = JobFailed(f"Snakemake ended without writing {', '.join(missing)} in {str(out)!r} "
                                    "(its arguments after '--' may have limited the run)")
        if failure is not None and on_slurm:
            failure = _slurm_failure(prefix, started, out, failure)
        if failure is not None:
            if fresh and not any((out / d).exists() for d in ("logs", "benchmarks")):
                _remove_unstarted_run(out, made)  # Snakemake stopped before any job (its arguments)
            raise failure
        return done
    finally:
        os.close(lock)


def _remove_unstarted_run(out, made):
    """Take back what a run that ended before any job began wrote: its configuration and
    Snakemake's folder, and the folders it made (``made``, deepest first), if empty then."""
    import shutil

    (out / CONFIG).unlink(missing_ok=True)
    shutil.rmtree(out / ".snakemake", ignore_errors=True)
    _remove_empty_folders(made)


def _make_run_folder(out):
    """Make the run's folder ``out`` and its missing parents; returns the folders made (deepest
    first, for :func:`_remove_empty_folders`).  One-line InputError when the file system refuses
    (a system folder, a read-only or full file system), with what it made removed."""
    made = [d for d in (out, *out.parents) if not os.path.exists(d)]  # the folders this run makes
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        from ..exceptions import one_line

        _remove_empty_folders(made)
        raise InputError(f"cannot create the output folder {str(out)!r}: {one_line(exc)}") from None
    return made


def _remove_empty_folders(made):
    """Remove the folders a run made (``made``, deepest first) while they are empty."""
    for d in made:
        try:
            d.rmdir()
        except FileNotFoundError:  # never made: a mkdir that failed part way
            continue
        except OSError:  # not empty, and so none above it is
            break


def _stages(full):
    """The module of the method's own stages in blocks (``BLOCK_STAGES``), or None."""
    import importlib

    from ..methods import get_method

    name = getattr(get_method(full["method"]), "BLOCK_STAGES", None)
    return None if name is None else importlib.import_module(name)


def _slurm_failure(prefix, since, out, failure):
    """The run's ``failure`` as SLURM saw it: the first SLURM job named ``prefix_*`` submitted
    since ``since`` that ended without success, as a :class:`JobFailed` in one line (its
    state and log); but ``failure`` itself when no job ended so, or when the job merely FAILED
    (its command's exit status) and ``failure`` is that job's own message (bad input, say,
    which a rerun would not mend).  A job that ran out of time (TIMEOUT) would run out of it again
    in a rerun with the same limit: the line says how to raise it."""
    failed = slurm.failed_jobs(prefix, since)
    if not failed:
        return failure
    job, state, comment = failed[0]
    if state.split(" ")[0] == "FAILED" and failure.own:
        return failure
    slurm_logs = Path(out) / ".snakemake" / "slurm_logs"
    logs = sorted(slurm_logs.rglob(f"{job}.log"))
    todo = "run the same command again to resume"
    if state.split(" ")[0] == "TIMEOUT":  # a rule's job logs to slurm_logs/rule_RULE/, a group's to group_.../
        folder = logs[0].relative_to(slurm_logs).parts[0] if logs else ""
        rule = folder[len("rule_"):] if folder.startswith("rule_") else "RULE"
        todo = (f"it ran past its time limit: raise its runtime (after '--': --set-resources {rule}:runtime=MINUTES) "
                f"and {todo}")
    return JobFailed(f"SLURM job {job}{f' ({comment})' if comment else ''} ended {state}"
                     f"{f', log {logs[0]}' if logs else ''}"
                     f"{f' ({len(failed) - 1} more failed)' if len(failed) > 1 else ''}; {todo}")


def main(argv=None, *, job=None, prog="trivsel.blocks", usage="{kernels,lines,plane,block,merge} OUT [ITEM ...]",
         batches=("plane", "block")):
    """``python -m trivsel.blocks KIND OUT [ITEM ...]``: one job of a blocked run (the workflow's
    rules); planes and blocks several at once (a cluster job's batch).  ``job``: the function
    that runs a job (default :func:`run_job`), for a method's own stages."""
    import signal
    import sys

    from ..exceptions import one_line

    run_job_ = run_job if job is None else job
    args = sys.argv[1:] if argv is None else argv
    if len(args) < 2 or (len(args) > 3 and args[0] not in batches):
        print(f"usage: python -m {prog} {usage}", file=sys.stderr)
        return 2
    def stop(signum, frame):
        raise KeyboardInterrupt

    # stopped with its run (SIGTERM to the process group): the atomic writers remove their
    # temporary files on the way out
    signal.signal(signal.SIGTERM, stop)
    items = args[2:] or [""]
    item = items[0]
    try:
        for item in items:  # a batch: one after the other, in this process
            run_job_(args[1], args[0], item)
    except InputError as exc:
        where = f"{args[0]} {item}: " if len(items) > 1 else ""
        print(f"trivsel: error: {where}{one_line(exc)}", file=sys.stderr)
        return 2
    except FileNotFoundError as exc:  # a job run by hand before the jobs that write its inputs
        print(f"trivsel: error: job {args[0]} {item}: a file it reads is missing (have the jobs before it run?): "
              f"{exc.filename}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("trivsel: error: stopped by a signal", file=sys.stderr)
        return 130
    return 0

