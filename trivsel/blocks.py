"""Reduction of a large grid in blocks whose seams conform by construction.

The box is cut by planes into blocks that share their faces.  The method starts from
prescribed boundary triangles (section 3, Definition 1), so each block can be reduced
on its own once its boundary is fixed, one dimension at a time::

    lines    every cut line (where two cut planes meet, the box's edges included) is
             reduced as 1-D data to the tolerance, segment by segment between the
             cut points (the segments' end points are kept);
    faces    every face of a cut plane between cut lines is reduced as 2-D data with
             its border fixed by the lines' kept points: greedy insertion with
             data-dependent flips (:func:`trivsel.faces.reduce_face`);
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
region of the volume it needs (:func:`trivsel.regions.open_volume`; the whole
volume is never loaded), the results of the stages it depends on, and writes one
file.  The Snakemake workflow of ``trivsel blocks`` (``trivsel/blocks.smk``) runs them
as jobs: locally with ``-c N`` or on a cluster through an executor.

Point numbering: the stages' files hold global point indices, the C-order index over
``(i, j, k)`` of the volume's grid as trivsel reads it; the ``.vtu`` pieces' and the
merged mesh's ``original_index`` is the input's own point id, as ``trivsel reduce``
writes it (:meth:`trivsel.regions.Volume.file_ids`).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import slurm
from .exceptions import InputError

__all__ = ["Plan", "plan_blocks", "reduce_line", "reduce_plane", "reduce_block", "reduce_in_blocks", "merge_blocks",
           "check_tetrahedra", "job_resources",
           "group_components"]

#: The volume's source, as :func:`trivsel.regions.open_volume` takes it.
SOURCE_KEYS = ("input", "function", "n", "array", "volume")


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
        raise InputError(f"blocks need a 3-D grid of at least 3 points per axis, got shape {shape}")
    sizes = np.broadcast_to(np.asarray(block), (3,))
    if sizes.dtype.kind not in "iu" or np.any(sizes < 2):
        raise InputError(f"block size must be an integer >= 2 (grid intervals per block), got {block!r}")
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
    from . import reduce
    from .data import grid_from_array

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
#: (about 8 s on a single-node SLURM), so plane and block jobs smaller than this are run several
#: to a cluster job (Snakemake's group jobs; :func:`group_components`).
MIN_CLUSTER_JOB_POINTS = 2_000_000


def group_components(plan, *, min_points=MIN_CLUSTER_JOB_POINTS):
    """How many jobs of each group of the blocked workflow one cluster job runs, as Snakemake's
    ``--group-components`` takes them: ``{"planes": P, "blocks": B}``, enough jobs for their
    points to reach ``min_points`` (at most all of them, at least one), evened out over the
    cluster jobs."""
    planes = [plan.shape[u] * plan.shape[v] for u, v in (_others(a) for a, _ in plan.planes())]
    blocks = [int(np.prod([r[1] - r[0] for r in plan.block_region(b)])) for b in plan.blocks()]
    out = {}
    for name, n in (("planes", planes), ("blocks", blocks)):
        per_job = min(len(n), max(1, int(np.ceil(min_points / np.mean(n)))))
        out[name] = int(np.ceil(len(n) / np.ceil(len(n) / per_job)))
    return out


# ----------------------------------------------------------------------------- jobs (files)
#
# The folder of a blocked run:
#   blocks.json                   the configuration and the plan
#   lines/A.npz                   kept positions of each cut line along axis A (key "A_B_C"),
#                                 and their error sums
#   planes/A_I.npz                triangles of each cut plane's faces, and their error sums
#   pieces/X_Y_Z.npz, .vtu        each block's tetrahedra, and the block as a ParaView piece
#   mesh.pvtu, mesh.vtu           the pieces as one partitioned dataset; the merged mesh
#   summary.json                  E_RMS, E_inf, vertices, tetrahedra, points

CONFIG = "blocks.json"


def item_name(item):
    return "_".join(str(int(i)) for i in item)


def parse_item(name):
    return tuple(int(s) for s in name.split("_"))


def write_config(out, config):
    """Check a blocked run's configuration, add its plan, and write ``out/blocks.json``.

    ``config``: the source (``input`` path, or ``function`` and ``n``; ``array``,
    ``volume``), ``block`` (grid intervals per block), ``tol_inf``, ``method``.  The
    volume is opened (its header only) for its shape.  Returns the full configuration.
    """
    from .methods import get_method
    from .regions import open_volume

    cfg = {k: config.get(k) for k in SOURCE_KEYS}
    tol = config.get("tol_inf")
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not np.isfinite(tol) or tol < 0:
        raise InputError(f"tol_inf must be a finite number >= 0, got {tol!r}")
    method = config.get("method", "greedy")
    get_method(method)
    vol = _open(cfg)
    plan = plan_blocks(vol.shape, config.get("block"))
    if cfg["input"] is not None:
        cfg["input"] = str(Path(cfg["input"]).resolve())
    full = {**cfg, "block": config.get("block"), "tol_inf": float(tol), "method": method,
            "merged": bool(config.get("merged", True)), "plan": plan.to_dict(),
            "origin": [float(x) for x in vol.origin], "spacing": [float(x) for x in vol.spacing]}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / CONFIG
    new = json.dumps(full, indent=1)
    if path.exists() and path.read_text() != new:
        raise InputError(f"{out} holds a blocked run with another configuration ({path}); "
                         f"choose a new folder or remove it")
    _atomic_write_text(path, new)
    return full


def _open(cfg):
    from .regions import open_volume

    return open_volume(cfg.get("input"), function=cfg.get("function"), n=cfg.get("n"), array=cfg.get("array"),
                       volume=cfg.get("volume"))


def read_config(out):
    with open(Path(out) / CONFIG) as fh:
        cfg = json.load(fh)
    return cfg, Plan.from_dict(cfg["plan"])


def _atomic_write_text(path, text):
    tmp = Path(str(path) + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _atomic_savez(path, **arrays):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    os.replace(tmp, path)


def _stats(d):
    return {k: float(d[k]) for k in ("sse", "max", "count")}


def run_job(out, kind, name):
    """Run one job of the blocked run in folder ``out``: ``kind`` is "kernels", "lines",
    "plane", "block" or "merge"; ``name`` the item (the axis ``A`` for the lines along
    it, ``A_I`` for a plane, ``X_Y_Z`` for a block, ignored otherwise)."""
    cfg, plan = read_config(out)
    out = Path(out)
    tol = cfg["tol_inf"]
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
    :meth:`trivsel.regions.Volume.file_ids`)."""
    from .pieces import write_piece

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
    """The merge: ``mesh.pvtu`` over the pieces, the merged ``mesh.vtu`` (global
    numbering; if the configuration asks for it) and ``summary.json`` (E_RMS over all
    points from every stage's squared residuals, E_inf, vertices, tetrahedra)."""
    from .pieces import merge_pieces, write_pvtu

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
    write_pvtu(out / "mesh.pvtu", pieces, overwrite=True)
    if cfg.get("merged", True):
        merge_pieces(pieces, out / "mesh.vtu", overwrite=True)
    N = plan.n_points()
    summary = {"points": N, "vertices": n_vertices, "fraction": n_vertices / N, "tetrahedra": n_tets,
               "E_rms": float(np.sqrt(sse / N)), "E_inf": mx, "tol_inf": cfg["tol_inf"],
               "blocks": len(plan.blocks()), "planes": len(plan.planes()), "lines": len(plan.lines()),
               "owned_points": own}
    _atomic_write_text(out / "summary.json", json.dumps(summary, indent=1))
    return summary


SNAKEFILE = Path(__file__).with_name("workflows") / "blocks.smk"
_RUN_LOCK = ".trivsel-blocks.lock"


def run_workflow(out, config, *, cores="all", snakemake_args=(), dry_run=False):
    """Write ``out/blocks.json`` (:func:`write_config`) and run the blocked workflow on it.

    Snakemake runs ``trivsel/workflows/blocks.smk`` in ``out``: locally on ``cores``, or
    on a cluster with ``snakemake_args`` such as ``("--executor", "slurm",
    "--workflow-profile", "workflow/profiles/slurm")``.  Run again, it does only the jobs
    whose files are missing or incomplete: a killed run resumes where it stopped (the
    lock a killed run leaves is removed first when no other ``trivsel blocks`` holds the
    folder).  Returns Snakemake's exit status.
    """
    import fcntl
    import importlib.util
    import subprocess
    import sys

    if importlib.util.find_spec("snakemake") is None:
        raise InputError("trivsel blocks runs on Snakemake, which is not installed: "
                         "pip install 'trivsel[workflow]'")
    plan = Plan.from_dict(write_config(out, config)["plan"])
    out = Path(out).resolve()
    base = [sys.executable, "-m", "snakemake", "--snakefile", str(SNAKEFILE), "--directory", str(out)]
    # batch small jobs on a cluster; name the SLURM jobs after the folder, so that they can be
    # found and cancelled (Snakemake's arguments given after `--` come later and win)
    extra = ["--group-components", *(f"{k}={v}" for k, v in group_components(plan).items())]
    prefix = slurm.job_prefix(out) if importlib.util.find_spec("snakemake_executor_plugin_slurm") else None
    if prefix:
        extra += ["--slurm-jobname-prefix", prefix]
    with open(out / _RUN_LOCK, "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise InputError(f"another trivsel blocks run is working in {out}") from None
        if any((out / ".snakemake" / "locks").glob("*")):  # left by a killed run
            subprocess.run(base + ["--unlock"], capture_output=True, check=False)
        cmd = base + ["--cores", str(cores), "--rerun-incomplete", *(["--dry-run"] if dry_run else []), *extra,
                      *snakemake_args]
        if dry_run or not prefix:
            return subprocess.run(cmd, check=False).returncode
        return _run_with_slurm_jobs(cmd, out, prefix)


def _run_with_slurm_jobs(cmd, out, prefix):
    """Run Snakemake (``cmd``) in ``out`` where its jobs may go to SLURM as ``prefix_*``: first
    cancel the jobs a killed earlier run in the folder left queued or running (this run holds
    the folder, so no live run owns them); cancel this run's jobs when it is interrupted; and
    after a failed run, name its first SLURM job that ended without success, in one line."""
    import subprocess
    import sys
    import time

    stale = slurm.cancel_jobs(prefix)
    if stale:
        print(f"trivsel: cancelled {len(stale)} SLURM job(s) left by an earlier run in {out}: "
              f"{' '.join(stale)}", file=sys.stderr)
    started = time.time()
    try:
        rc = subprocess.run(cmd, check=False).returncode
    except KeyboardInterrupt:
        slurm.cancel_jobs(prefix)
        raise
    failed = slurm.failed_jobs(prefix, started) if rc else []
    if failed:
        job, state, comment = failed[0]
        logs = sorted((out / ".snakemake" / "slurm_logs").rglob(f"{job}.log"))
        print(f"trivsel: error: SLURM job {job}{f' ({comment})' if comment else ''} ended {state}"
              f"{f', log {logs[0]}' if logs else ''}"
              f"{f' ({len(failed) - 1} more failed)' if len(failed) > 1 else ''}; "
              f"run the same command again to resume", file=sys.stderr)
    return rc


def main(argv=None):
    """``python -m trivsel.blocks KIND OUT [ITEM]``: one job of a blocked run (the workflow's rules)."""
    import sys

    from .exceptions import one_line

    args = sys.argv[1:] if argv is None else argv
    if len(args) not in (2, 3):
        print("usage: python -m trivsel.blocks {kernels,lines,plane,block,merge} OUT [ITEM]", file=sys.stderr)
        return 2
    try:
        run_job(args[1], args[0], args[2] if len(args) == 3 else "")
    except InputError as exc:
        print(f"trivsel: error: {one_line(exc)}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
