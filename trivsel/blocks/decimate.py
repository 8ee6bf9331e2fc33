"""``trivsel blocks --method decimate``: the stages of :mod:`trivsel.decimation.blocked` as
jobs that each read only their block or region of the volume.

The stages are the functions ``trivsel reduce --block B`` runs in one process, so both give
the same mesh; here each is a job of the workflow ``trivsel/blocks/decimate.smk``, and what
one stage hands the next is a file in the run's folder::

    costs/X.npz        pass 1, the blocks of x-slab X one after the other: each block's
                       recorded collapses (point and target), their costs (running
                       maxima) and the squared error they add, and its points off the seams
    tau.json           the cost threshold cut across every block's sequence, and the
                       squared error the blocks add up to it
    costs/whole.npz    the blocks whose record stopped short of a cost the cut compared,
                       recorded again to their end by the cut job (most runs: none)
    meshes/X.npz       pass 2, each block of slab X down to the threshold (its recorded
                       collapses replayed): its tetrahedra, the points inside them and their rows
    passes/P/state.npz the whole mesh before pass P: tetrahedra, each point's tetrahedron,
                       vertex flags, the seam candidates (a step job: 9 bytes a point and
                       32 a tetrahedron, not a decimation)
    passes/P/in/R.npz  the regions of x-slab R of pass P, each as a mesh of its own
    passes/P/costs/R.npz, passes/P/quota.npz
                       each region's recorded costs, and the collapses each makes: one
                       threshold across the regions, and the squared error spent so far
                       (runs with a count or tol_rms only)
    passes/P/out/R.npz each region of slab R decimated (its recorded collapses up to its
                       quota, replayed): the points it removed, its new tetrahedra, the
                       points inside them
    tiles/X.npz        after the last pass, the mesh kept by tile (a block of the plan) for
                       x-slab X of tiles: each tile's tetrahedra (every one that meets it),
                       their rows and corners' boxes, each of its points' tetrahedron,
                       and its vertices with their values; tiles/mesh.json the counts
    fit/X.npz          the fitted values of the vertices of slab X's tiles (with ``fit``)
    sums/X.npz         the errors at the points of slab X's tiles, as sums; beside it each
                       tile's piece (pieces/)
    merged/            the last step: mesh.vtu (vertices sorted by the input's point id),
                       mesh.pvtu over the pieces, summary.json

A block job reads its blocks' samples, a region job its regions' points (the bounding box
of each region's mesh) and of ``plan.npz`` only what names its regions (``PLAN_OF_REGIONS``);
the quota job reads the regions' costs, not their meshes. A slab's job takes its blocks or
regions one at a time: it reads each one's part of its input files (``_Members``) and writes
its file one block or region at a time (``_atomic_savez_each``), so that its memory is that of
one block or region, not of the slab. The cut job reads the blocks' records one block at a
time, a few times over, and keeps a bounded sample of their costs
(:mod:`trivsel.decimation.streamcut`); so does the quota job with the regions' records. The fit
and pieces jobs hold one tile's surroundings at a time: the samples of the box its solve may
reach (fit) or of the tile (pieces), the tetrahedra that meet that box and their corners'
values. Only the step and tiles jobs hold arrays over the whole grid (owners and flags per
point, the tetrahedra), never a decimation of it; the last job holds a few numbers a tile, and
the merged mesh when it writes one.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from ..methods import get_method
from . import (JOB_BASE_BYTES, SUGGESTED_BLOCKS, SUGGESTED_JOB_BYTES, Plan, _atomic_savez, _atomic_savez_each,
               _atomic_write_text, _open, check_item, check_tolerance, item_name, publish_results, read_config)

__all__ = ["plan_decimation", "make_config", "Stages", "run_job", "mesh_tets", "region_bytes", "job_resources",
           "jobs_memory", "check_job_memory"]

#: The stages themselves, from the method (through the registry, as every block stage reaches a method)
B = get_method("decimate").block_stages()
#: The folder of the mesh kept by tile after the last pass (``_tiles``)
TILES = "tiles"
#: Rows of a large mesh renumbered and written at a time (``_write_mesh``).
MESH_CHUNK = 1 << 20
INF = np.inf
#: The names of a region's result (:func:`trivsel.decimation.blocked.region_decimate`) in the files
RESULT = ("removed", "tets", "inside", "rows")
#: The workflow of these stages
SNAKEFILE = Path(__file__).with_name("decimate.smk")
#: What a value of ``values`` may be
VALUES = ("data", "fit")

#: Bytes per point of a block's decimation (as ``trivsel reduce`` estimates it)
DECIMATION_BYTES_PER_POINT = 1000
#: Bytes per point and per tetrahedron of a region's decimation (:func:`region_bytes`): the largest
#: rcosts jobs of f4 at 129^3 and 193^3 in blocks of 32 held about 360 a point and 390 a tetrahedron
#: above the interpreter (244,153 points and 83,164 tetrahedra at 5 %, 148 MB; 261,766 and 1,499,160
#: at 50 %, 734 MB: docs/notes), with room
REGION_BYTES_PER_POINT = 500
REGION_BYTES_PER_TET = 450
#: Bytes per grid point and per tetrahedron of the whole mesh, of a step job (owners and flags per point;
#: the tetrahedra, their regions and the pass plan's temporaries): measured on f4 at 129^3 in blocks of 32
#: to 5 % and 50 % with fitted values, about 11 and 60 above the interpreter's 55 MB (docs/notes), with room
STEP_BYTES_PER_POINT = 40
STEP_BYTES_PER_TET = 80
#: The tiles job holds a step job's arrays, and each tetrahedron once for every tile it meets; the
#: last job, with the merged mesh, its tetrahedra and vertices.  Measured alone (``/usr/bin/time``) on
#: f4 in blocks of 32 with fitted values: 212 and 191 MB (tiles, finish) at 129^3 to 5 %, 503 and 284 MB
#: at 97^3 to 50 %; the whole T1 in blocks of 48 to 5 %, 579 and 303 MB (docs/notes)
FINISH_BYTES_PER_TET = 100
TILES_BYTES_PER_TET = 110
#: Bytes per point of the box a ``fit`` or ``pieces`` job holds around a tile (the box its solve
#: may reach, or the tile), and per tetrahedron of the mesh the stop allows a point (:func:`mesh_tets`).
#: Measured as above: 126 and 60 MB (fit, pieces) at 129^3 to 5 %, 339 and 99 MB at 97^3 to 50 %, 367
#: and 113 MB on the whole T1
FIT_BYTES_PER_POINT = 100
FIT_BYTES_PER_TET = 150
PIECE_BYTES_PER_POINT = 60
PIECE_BYTES_PER_TET = 60
#: Seconds per point of a slab of blocks in pass 1 (``costs``, and ``mesh`` after it), for their runtime
#: requests (SLURM ends a job at its request): on f4 at 257^3 in blocks of 64 a slab of 4.2 M points took up to
#: 249 s (5.9e-5 a point) on a loaded machine and about 140 s on a quiet day (docs/notes); about 3x the larger
BLOCK_SECONDS_PER_POINT = 2e-4
#: Seconds per point of a slab of regions (``rcosts``, ``apply``), for their runtime requests: f4 at 129^3 in
#: blocks of 32 to 50 % took up to 41 s for a slab of 1.1 M points (3.8e-5 a point, the machine shared with
#: CI), to 5 % at 257^3 in blocks of 64 up to 63 s for 8.5 M (docs/notes); about 4x the larger
REGION_SECONDS_PER_POINT = 1.5e-4
#: Bytes per run of the cut job's sample of costs (:mod:`trivsel.decimation.streamcut`: at most twice
#: ``RUNS`` (``STREAM_RUNS`` of the block stages) runs of 40 bytes, with the temporaries of their sort)
CUT_SAMPLE_BYTES_PER_RUN = 160
#: Tetrahedra per vertex of a decimated grid (5.6-5.9 measured; a Kuhn split has 6 per cell)
TETS_PER_VERTEX = 6


def make_config(config, shape):
    """The keys of a run's configuration that ``decimate`` adds (the stop and the values), checked:
    ``count`` (8 to the points) or ``fraction`` (in (0, 1]), and/or ``tol_rms`` (a number >= 0) and
    ``tol_inf``; ``values``, a list of ``data`` and ``fit``.  Also the plan (the blocks of
    :func:`plan_decimation`).  ``block`` was checked by :func:`trivsel.blocks.make_config`."""
    from ..exceptions import InputError, shown

    N = int(np.prod(shape))
    count, fraction = config.get("count"), config.get("fraction")
    if count is not None and fraction is not None:
        raise InputError("give one of count and fraction, not both")
    if count is not None and (isinstance(count, bool) or not isinstance(count, (int, np.integer))
                              or not 8 <= count <= N):
        raise InputError(f"count must be a whole number from 8 (the box's corners) to the {N} points; "
                         f"got {shown(count)}")
    if fraction is not None and (isinstance(fraction, bool) or not isinstance(fraction, (int, float))
                                 or not 0 < fraction <= 1):
        raise InputError(f"fraction must be a number in (0, 1]; got {shown(fraction)}")
    tol_rms = config.get("tol_rms")
    check_tolerance("tol_rms", tol_rms)
    if count is None and fraction is None and tol_rms is None and config.get("tol_inf") is None:
        raise InputError("give a stop: --count, --fraction, --tol-rms or --tol-inf")
    values = config.get("values") or ["data"]
    if isinstance(values, str):
        values = [values]
    if not isinstance(values, (list, tuple)) or not values or any(v not in VALUES for v in values) \
            or len(set(values)) != len(values):
        raise InputError(f"values must be a list of {' and '.join(VALUES)} (each once); got {shown(values)}")
    return {"count": None if count is None else int(count), "fraction": None if fraction is None else float(fraction),
            "tol_rms": None if tol_rms is None else float(tol_rms), "values": list(values),
            "plan": plan_decimation(shape, int(config["block"])).to_dict()}


def check_job_memory(full):
    """One-line InputError when a job of this run, of any kind it has (:meth:`Stages.job_kinds`),
    needs more memory than is available here (a local run), naming a block size whose jobs all fit."""
    from ..exceptions import InputError
    from ..resources import available_bytes

    avail = available_bytes()
    if avail is None:
        return
    shape = Plan.from_dict(full["plan"]).shape
    need = jobs_memory(shape, full, int(full["block"]))
    kind = max(need, key=need.get)
    if need[kind] <= avail:
        return
    fits = [b for b in SUGGESTED_BLOCKS if b < int(full["block"]) and max(jobs_memory(shape, full, b).values()) <= avail]
    if fits:
        fix = f"use --block {fits[0]}"
    else:  # name the job that no block size brings within what is available
        least = jobs_memory(shape, full, min(SUGGESTED_BLOCKS + (int(full["block"]),)))
        kind = max((k for k in least if least[k] > avail), key=need.get, default=kind)
        fix = "the whole grid's arrays do not fit: run it on a larger machine or a cluster"
    article = "an" if kind[0] in "aeiou" else "a"
    raise InputError(f"{article} {kind} job of decimate in blocks of {full['block']} needs about "
                     f"{need[kind] / 2**30:.3g} GiB, more than the {avail / 2**30:.3g} GiB available: {fix}")


def jobs_memory(shape, cfg, block):
    """The memory (bytes) that each kind of job of a run on a grid of ``shape`` requests
    (:func:`job_resources`), with the stop and values of ``cfg``, in blocks of ``block``."""
    cfg = {**cfg, "block": int(block)}
    plan = plan_decimation(shape, int(block))
    return {k: job_resources(cfg, plan, k)[0] * 2**20 for k in Stages(cfg, plan).job_kinds()}


def block_for_memory(available, *, cores=2):
    """The largest block of :data:`~trivsel.blocks.SUGGESTED_BLOCKS` whose region jobs (2 x 2 x 2
    blocks, the largest decimations of a run) need at most ``SUGGESTED_JOB_BYTES`` and at most
    ``available / cores`` bytes."""
    bound = min(SUGGESTED_JOB_BYTES, float(available) / max(int(cores), 1))
    for b in SUGGESTED_BLOCKS:
        if JOB_BASE_BYTES + DECIMATION_BYTES_PER_POINT * float(B.REGION * b + 1) ** 3 <= bound:
            return b
    return SUGGESTED_BLOCKS[-1]


def plan_decimation(shape, block) -> Plan:
    """The blocks of ``decimate`` in blocks (:func:`trivsel.decimation.blocked.block_cuts`)."""
    return Plan(tuple(int(s) for s in shape),
                tuple(tuple(int(c) for c in B.block_cuts(int(n), int(block))) for n in shape))


class Stages:
    """The jobs of a run: the x-slabs of blocks, and each pass's kind, offset and x-slabs of
    regions, from the configuration alone (the workflow's rules are made from it).  ``costed``:
    the run has a count or ``tol_rms``, so its stages record their costs and cut them."""

    def __init__(self, cfg, plan):
        self.cfg, self.plan = cfg, plan
        self.block = int(cfg["block"])
        self.costed = any(cfg.get(k) is not None for k in ("count", "fraction", "tol_rms"))
        self.slabs = list(range(plan.counts[0]))
        self.passes = [(kind, off) for kind, off in B.passes(self.block) if self.costed or kind == "seams"]
        self.size = B.REGION * self.block

    def job_kinds(self):
        """The kinds of job this run has (the rules of ``decimate.smk`` it runs): ``cut``,
        ``rcosts`` and ``quota`` when it cuts recorded costs (:attr:`costed`), ``fit`` with
        fitted values, the others always."""
        kinds = ["kernels", "costs", "mesh", "step", "apply", "tiles", "pieces", "finish"]
        return kinds + (["fit"] if self.fit else []) + (["cut", "rcosts", "quota"] if self.costed else [])

    @property
    def fit(self):
        """Whether the run fits the vertex values by least squares."""
        return "fit" in (self.cfg.get("values") or ["data"])

    def budget(self):
        """The squared error the run may spend (:func:`trivsel.decimation.blocked.sse_budget`)."""
        return B.sse_budget(self.cfg.get("tol_rms"), self.plan.n_points())

    def target(self):
        if self.cfg.get("count") is not None:
            return int(self.cfg["count"])
        if self.cfg.get("fraction") is not None:
            from ..selection import count_for_fraction

            return count_for_fraction(float(self.cfg["fraction"]), self.plan.n_points())
        return None

    #: The job kinds with an item: a slab of blocks or of tiles, a pass, or slab R of pass P's regions ("P_R")
    ITEMS = ("costs", "mesh", "step", "quota", "rcosts", "apply", "fit", "pieces")

    def items(self, kind):
        """The names of the run's jobs of ``kind`` (one of ``ITEMS``), in order."""
        if kind in ("costs", "mesh", "fit", "pieces"):
            return [str(s) for s in self.slabs]
        if kind in ("step", "quota"):
            return [str(p) for p in range(len(self.passes))]
        return [f"{p}_{s}" for p in range(len(self.passes)) for s in self.region_slabs(p)]

    def region_dims(self, p):
        return B.region_grid(self.plan.shape, self.passes[p][1], self.size)[0]

    def region_slabs(self, p):
        return list(range(int(self.region_dims(p)[0])))

    def blocks_of(self, slab):
        """The blocks of x-slab ``slab``: their indices in the plan and ``(lo, hi)`` bounds."""
        nx, ny, nz = self.plan.counts
        cuts = self.plan.cuts
        out = []
        for j in range(ny):
            for k in range(nz):
                lo = [cuts[0][slab], cuts[1][j], cuts[2][k]]
                hi = [cuts[0][slab + 1], cuts[1][j + 1], cuts[2][k + 1]]
                out.append(((slab * ny + j) * nz + k, lo, hi))
        return out

    def seam_axes(self):
        return [np.asarray(c[1:-1], np.int64) for c in self.plan.cuts]

    def fraction(self):
        t = self.target()
        return 0.0 if t is None else t / self.plan.n_points()


def _read_box(vol, lo, hi):
    return vol.read(tuple((int(a), int(b) + 1) for a, b in zip(lo, hi)))


def _points_values(vol, shape, ids):
    """The values at global point indices ``ids``, read from their bounding box only."""
    if not len(ids):
        return np.zeros(0)
    ijk = np.stack(np.unravel_index(ids, shape), axis=1)
    lo, hi = ijk.min(axis=0), ijk.max(axis=0)
    box = _read_box(vol, lo, hi)
    return box[tuple((ijk - lo).T)]


def _load(path, keys=None):
    """The arrays of an .npz file, or only those ``keys`` names (a collection of names, or a
    predicate on a name): an .npz is read member by member, so a job holds only what it asks for."""
    with np.load(path, allow_pickle=False) as z:
        want = (lambda k: True) if keys is None else keys if callable(keys) else set(keys).__contains__
        return {k: z[k] for k in z.files if want(k)}


#: What a region or quota job reads of its pass's ``plan.npz``: the regions and the pass's figures, not
#: the layout of the whole mesh (``order``, ``left``: arrays over every tetrahedron and point) that
#: only the step jobs use
PLAN_OF_REGIONS = ("region", "ran", "surplus", "tau", "spent", "budget", "share", "limit", "caps", "whole_caps")


def _region_plan(folder):
    return _load(folder / "plan.npz", PLAN_OF_REGIONS)


class _Members:
    """The members of .npz files, each read when asked for (of the last file that has it): a
    job holds its slab's blocks or regions one at a time, not the whole file.  A context
    manager: the files are open inside it."""

    def __init__(self, *paths):
        self.paths = [Path(p) for p in paths]

    def __enter__(self):
        self.files = [np.load(p, allow_pickle=False) for p in self.paths]
        self.names = [set(z.files) for z in self.files]
        return self

    def __exit__(self, *exc):
        for z in self.files:
            z.close()

    def __contains__(self, name):
        return any(name in n for n in self.names)

    def __getitem__(self, name):
        for z, n in zip(reversed(self.files), reversed(self.names)):
            if name in n:
                return z[name]
        raise KeyError(name)

    def __iter__(self):
        return iter(sorted(set().union(*self.names)))


def _costs(out, st, slab):
    vol = _open(st.cfg)
    _atomic_savez_each(out / "costs" / f"{slab}.npz", (_block_record(vol, st, i, lo, hi, B.RECORD_FLOOR)
                                                       for i, lo, hi in st.blocks_of(slab)))


def _block_record(vol, st, i, lo, hi, floor):
    """Pass 1 on block ``i`` (:func:`trivsel.decimation.blocked.block_costs`) as the arrays of a
    costs file."""
    r, n_inner, (removed, into), sse, short = B.block_costs(
        _read_box(vol, lo, hi), lo, st.plan.shape, st.seam_axes(), fraction=st.fraction(),
        tol_inf=st.cfg.get("tol_inf"), tol_rms=st.cfg.get("tol_rms"), floor=floor)
    return {f"runmax_{i}": r, f"inner_{i}": np.int64(n_inner), f"removed_{i}": removed, f"into_{i}": into,
            f"sse_{i}": sse, f"short_{i}": np.bool_(short)}


def _records(folder, files, again):
    """The recorded costs of blocks or regions, one at a time: ``(runmax, sse)`` of each item
    of ``files`` (pairs of a costs file's name in ``folder`` and its items, in order), read from
    its own file where ``again`` names one (recorded again).  Of a costs file only those two
    arrays are read, not the meshes beside them; zeros stand in for the errors of a run begun
    before they were recorded (it has no budget)."""
    for name, items in files:
        with np.load(folder / f"{name}.npz", allow_pickle=False) as z:
            for i in items:
                if i in again:
                    rec = _load(again[i], (f"runmax_{i}", f"sse_{i}"))
                    yield rec[f"runmax_{i}"], rec[f"sse_{i}"]
                    continue
                r = z[f"runmax_{i}"]
                yield r, (z[f"sse_{i}"] if f"sse_{i}" in z.files else np.zeros(len(r)))


def _cut(out, st):
    """The threshold across the blocks' records, read one block at a time (each stream of
    :func:`trivsel.decimation.blocked.streamed_threshold` reads the costs files again): the job
    holds a number or two per block, one block's record and a bounded sample of costs, not
    every block's record.  The blocks whose record stopped short of a cost the cut compared are
    recorded again to their end here, one at a time, into ``costs/whole.npz`` (which the mesh
    jobs read before their slab's file)."""
    N = st.plan.n_points()
    target = st.target()
    if not st.costed:
        _atomic_write_text(out / "tau.json", json.dumps({"tau": _number(INF), "target": target, "counts": None,
                                                         "sse": 0.0, "recorded_again": 0}))
        return
    blocks = [i for slab in st.slabs for i, _, _ in st.blocks_of(slab)]
    inner, short = [], []
    for slab in st.slabs:
        z = _load(out / "costs" / f"{slab}.npz", lambda k: k.startswith(("inner_", "short_")))
        for i, _, _ in st.blocks_of(slab):
            inner.append(int(z[f"inner_{i}"]))
            # a run started before the floor was recorded has whole records
            short.append(bool(z[f"short_{i}"]) if f"short_{i}" in z else False)
    again_dir = out / "costs" / "again"
    again = {}  # block -> its record to its end, in a file of its own

    def read():  # every block's (runmax, sse) in block order, one block at a time
        return _records(out / "costs", [(slab, [i for i, _, _ in st.blocks_of(slab)]) for slab in st.slabs], again)

    seam_points = N - sum(inner)
    aim = B.aim(target, N, seam_points)
    vol, bounds = None, {i: (lo, hi) for slab in st.slabs for i, lo, hi in st.blocks_of(slab)}
    recorded_again = []
    while True:  # once more at most: whole records are never short, and tau only falls
        tau, decided = B.streamed_threshold(read, inner, seam_points, aim, st.budget(), share=B.SSE_SHARE)
        redo = B.short_blocks([r[-1:] for r, _ in read()], short, decided) if any(short) else []
        if not redo:
            break
        vol = _open(st.cfg) if vol is None else vol
        for k in redo:  # to their end, one at a time
            i = blocks[k]
            path = again_dir / f"{i}.npz"
            _atomic_savez(path, **_block_record(vol, st, i, *bounds[i], 0.0))
            again[i], short[k] = path, False
            recorded_again.append(k)
    # the blocks recorded again (most runs: none), one at a time into the file the mesh jobs read
    _atomic_savez_each(out / "costs" / "whole.npz", (_load(again[i]) for i in sorted(again)))
    counts, sse = B.streamed_cut_counts(read, tau, inner, seam_points, target, B.tied_counts)
    _atomic_write_text(out / "tau.json", json.dumps({"tau": _number(tau), "target": target, "counts": counts,
                                                     "sse": sse, "recorded_again": len(recorded_again)}))
    shutil.rmtree(again_dir, ignore_errors=True)  # its own files (and a killed attempt's)


def _number(x):
    """A float for JSON, infinities as text."""
    return float(x) if np.isfinite(x) else ("inf" if x > 0 else "-inf")


def _tau(out):
    d = json.loads((Path(out) / "tau.json").read_text())
    return float(d["tau"]), d


def _spent(out, st, p):
    """The squared error the stages before pass ``p`` may have added (the blocks', then each
    pass's quota cut; 0 in a run begun by a version that recorded none, which had no budget)."""
    if p == 0:
        return float(_tau(out)[1].get("sse", 0.0))
    return float(_load(out / "passes" / str(p - 1) / "quota.npz").get("spent", 0.0))


def _limit(out, st, p):
    """The quota passes' cost limit as the passes before ``p`` left it
    (:func:`trivsel.decimation.blocked.pass_limit`): nan in the files while no quota pass has
    derived it (and in a run begun by a version that had none)."""
    if p == 0 or not st.costed:
        return float("nan")
    return float(_load(out / "passes" / str(p - 1) / "quota.npz").get("limit", float("nan")))


def _mesh(out, st, slab):
    vol, shape = _open(st.cfg), st.plan.shape
    tau, d = _tau(out)
    files = []
    if st.costed:  # pass 1's collapses, replayed: the blocks the cut recorded again from its file
        whole = out / "costs" / "whole.npz"  # (none in a run begun before the cut wrote it)
        files = [out / "costs" / f"{slab}.npz"] + ([whole] if whole.exists() else [])

    def meshes(recorded):
        for i, lo, hi in st.blocks_of(slab):
            rec = None
            if st.costed:
                c = d["counts"][i]
                rec = recorded[f"removed_{i}"][:c], recorded[f"into_{i}"][:c]
            T, inside, rows, n = B.block_mesh(_read_box(vol, lo, hi), lo, shape, st.seam_axes(),
                                              fraction=st.fraction(), tau=tau, tol_inf=st.cfg.get("tol_inf"),
                                              recorded=rec)
            yield {f"tets_{i}": T, f"inside_{i}": inside, f"rows_{i}": rows, f"removed_{i}": np.int64(n)}

    with _Members(*files) as recorded:
        _atomic_savez_each(out / "meshes" / f"{slab}.npz", meshes(recorded))


def _state(out, st, p):
    """The mesh before pass ``p``: the blocks' meshes (p = 0) or the state before pass p - 1
    with that pass's regions merged in."""
    N = st.plan.n_points()
    if p == 0:
        tau, d = _tau(out)
        names = [tuple(lo) for slab in st.slabs for _, lo, _ in st.blocks_of(slab)]

        def meshes():  # one block at a time
            for slab in st.slabs:
                with _Members(out / "meshes" / f"{slab}.npz") as z:
                    for i, _, _ in st.blocks_of(slab):
                        yield z[f"tets_{i}"], z[f"inside_{i}"], z[f"rows_{i}"], int(z[f"removed_{i}"])

        T, owner, isv = B.assemble(N, meshes(), d["counts"], names)
        return T, owner, isv, isv.copy()
    s = _load(out / "passes" / str(p - 1) / "state.npz")
    plan = _load(out / "passes" / str(p - 1) / "plan.npz")
    if not plan["ran"]:
        return s["T"], s["owner"], s["isv"], s["cand"]
    dims = st.region_dims(p - 1)

    def results():  # the pass's regions in order, one at a time
        for slab in st.region_slabs(p - 1):
            with _Members(out / "passes" / str(p - 1) / "out" / f"{slab}.npz") as z:
                for r in _slab_regions(plan, dims, slab):
                    yield tuple(z[f"{name}_{r}"] for name in RESULT)

    # the arrays this job read are its own: merged in place
    T, owner, isv, _ = B.merge_pass(s["T"], s["owner"], s["isv"], plan, results, in_place=True)
    cand = plan["left"] if st.passes[p - 1][0] == "seams" else s["cand"]
    return T, owner, isv, cand


def _slab_regions(plan, dims, slab):
    """The runs of ``plan`` (region ids) in x-slab ``slab`` of the region grid."""
    per = int(dims[1] * dims[2])
    return [int(r) for r in plan["region"] if r // per == slab]


def _step(out, st, p):
    """Merge pass p - 1 and plan pass p: its regions' meshes, one file per x-slab."""
    T, owner, isv, cand = _state(out, st, p)
    target = st.target()
    kind, offset = st.passes[p]
    c = cand if kind == "seams" else isv.copy()
    surplus = None if target is None else int(isv.sum()) - target
    spent = _spent(out, st, p) if st.costed else 0.0
    left = st.budget() - spent
    run = B.pass_runs(c, surplus, left, kind)
    folder = out / "passes" / str(p)
    _atomic_savez(folder / "state.npz", T=T, owner=owner, isv=isv, cand=cand)
    dims = st.region_dims(p)
    if run:
        plan = B.pass_plan(st.plan.shape, T, owner, isv, c, offset, st.size)
    else:
        plan = {k: np.zeros(0, np.int64) for k in ("order", "starts", "ends", "region", "nfree")}
        plan["left"] = cand
    tau, _ = _tau(out)
    limit = _limit(out, st, p)
    tau_p = B.record_limit(kind, tau, None if np.isnan(limit) else limit)
    caps, whole_caps = B.record_caps(plan, surplus, kind, None if np.isnan(limit) else limit) \
        if run and st.costed else (None, None)
    _atomic_savez(folder / "plan.npz", order=plan["order"], starts=plan["starts"], ends=plan["ends"],
                  region=plan["region"], left=plan["left"], ran=np.bool_(run),
                  surplus=np.int64(-1 if surplus is None else surplus), tau=np.float64(tau_p),
                  spent=np.float64(spent), budget=np.float64(left), share=np.float64(B.free_share(plan, isv)),
                  limit=np.float64(limit), caps=np.asarray(caps if caps is not None else [], np.int64),
                  whole_caps=np.asarray(whole_caps if whole_caps is not None else [], np.int64))
    per = int(dims[1] * dims[2])

    def inputs(slab):  # the slab's regions one at a time, each written before the next is made
        for k in np.flatnonzero(plan["region"] // per == slab) if run else ():
            r = int(plan["region"][k])
            yield {f"{name}_{r}": a for name, a in B.region_input(plan, T, owner, int(k)).items()}

    for slab in st.region_slabs(p):
        _atomic_savez_each(folder / "in" / f"{slab}.npz", inputs(slab))


def _region_inputs(z):
    regions = sorted({int(k.split("_")[1]) for k in z if k.startswith("local_")})
    return regions, lambda r: {n: z[f"{n}_{r}"] for n in ("local", "tets", "located", "locked")}


def _region_costs(out, st, p, slab):
    vol = _open(st.cfg)
    folder = out / "passes" / str(p)
    plan = _region_plan(folder)
    cap = dict(zip(plan["region"].tolist(), plan["caps"].tolist()))
    with _Members(folder / "in" / f"{slab}.npz") as z:
        regions, inp = _region_inputs(z)
        _atomic_savez_each(folder / "costs" / f"{slab}.npz",
                           (_region_record(vol, st, plan, inp(r), r, int(cap[r])) for r in regions))


def _region_record(vol, st, plan, inp, r, cap):
    """Region ``r``'s record of up to ``cap`` collapses (``inp``: its :func:`region_input`), as
    the arrays its costs file holds."""
    shape = st.plan.shape
    runmax, sse, (lremoved, linto), result = B.region_decimate(
        inp, shape, _points_values(vol, shape, inp["local"]), tau=float(plan["tau"]), tol_inf=st.cfg.get("tol_inf"),
        quota=cap, costs=True, budget=float(plan.get("budget", INF)))
    res = {f"runmax_{r}": runmax, f"sse_{r}": sse}
    res[f"lremoved_{r}"], res[f"linto_{r}"] = lremoved, linto  # replayed where the quota is fewer
    res.update({f"{name}_{r}": a for name, a in zip(RESULT, result)})  # reused where the quota is all of them
    return res


def _quota(out, st, p):
    """The pass's quota cut, from the regions' records read one region at a time (each stream
    of :func:`trivsel.decimation.streamcut.streamed_cut_quota` reads the costs files again): the
    job holds a few numbers a region, one region's record and a bounded sample of costs, not
    every region's record.  The first quota pass derives the cost limit from its records; the
    regions whose record stopped at its cap at or below the limit are recorded again to the
    whole cap here, one at a time, each to a file of its own and then into ``again.npz`` (which
    the apply jobs read after their slab's costs file)."""
    folder = out / "passes" / str(p)
    plan = _region_plan(folder)
    dims = st.region_dims(p)
    regions = [int(r) for r in plan["region"]]
    again_dir = folder / "again"
    again = {}  # region -> its record to the whole cap, in a file of its own

    def read():  # every region's (runmax, sse) in the plan's order, one region at a time
        return _records(folder / "costs", [(slab, _slab_regions(plan, dims, slab)) for slab in st.region_slabs(p)],
                        again)

    q, added = np.zeros(0, np.int64), 0.0
    limit = float(plan.get("limit", float("nan")))
    limit = None if np.isnan(limit) else limit  # none derived yet
    if plan["ran"]:
        surplus = None if plan["surplus"] < 0 else int(plan["surplus"])
        kind, share = st.passes[p][0], float(plan.get("share", 1.0))
        if B.derives_limit(kind, surplus, limit) and len(plan.get("whole_caps", ())) == len(regions):

            def record_again(ks):  # to the whole cap, one at a time
                vol, per = _open(st.cfg), int(np.prod(dims[1:]))
                for k in ks:
                    r = regions[k]
                    z = _load(folder / "in" / f"{r // per}.npz", lambda name: name.endswith(f"_{r}"))  # its input
                    path = again_dir / f"{r}.npz"
                    _atomic_savez(path, **_region_record(vol, st, plan, _region_inputs(z)[1](r), r,
                                                         int(plan["whole_caps"][k])))
                    again[r] = path

            limit, _ = B.limit_of_whole_records(read, surplus, share, plan["caps"], plan["whole_caps"], record_again)
        cut, limit = B.pass_limit(kind, surplus, limit, read, share)
        q, added = B.streamed_cut_quota(read, surplus, float(plan.get("budget", INF)), cut)
    # the regions recorded again (most runs: none), one at a time into the file the apply jobs read
    _atomic_savez_each(folder / "again.npz", (_load(again[r]) for r in sorted(again)))
    _atomic_savez(folder / "quota.npz", region=np.asarray(regions, np.int64), quota=np.asarray(q, np.int64),
                  spent=np.float64(float(plan.get("spent", 0.0)) + added),
                  limit=np.float64(float("nan") if limit is None else limit))
    shutil.rmtree(again_dir, ignore_errors=True)  # its own files (and a killed attempt's)


def _region_apply(out, st, p, slab):
    vol, shape = _open(st.cfg), st.plan.shape
    folder = out / "passes" / str(p)
    plan = _region_plan(folder)
    quota, files = None, []
    if st.costed:
        q = _load(folder / "quota.npz")
        quota = dict(zip(q["region"].tolist(), q["quota"].tolist()))
        again = folder / "again.npz"  # the regions the quota job recorded again (none in older runs)
        files = [folder / "costs" / f"{slab}.npz"] + ([again] if again.exists() else [])

    def results(regions, inp, recorded):
        for r in regions:
            if quota is not None and quota[r] == len(recorded[f"runmax_{r}"]):  # every collapse it recorded
                result = [recorded[f"{name}_{r}"] for name in RESULT]
            else:
                i = inp(r)
                seq = None  # the first collapses it recorded, replayed (none in a run begun before they were kept)
                if quota is not None and f"lremoved_{r}" in recorded:
                    seq = recorded[f"lremoved_{r}"], recorded[f"linto_{r}"]
                result = B.region_decimate(i, shape, _points_values(vol, shape, i["local"]), tau=float(plan["tau"]),
                                           tol_inf=st.cfg.get("tol_inf"), quota=None if quota is None else quota[r],
                                           recorded=seq)
            yield {f"{name}_{r}": a for name, a in zip(RESULT, result)}

    with _Members(folder / "in" / f"{slab}.npz") as z, _Members(*files) as recorded:
        _atomic_savez_each(folder / "out" / f"{slab}.npz", results(*_region_inputs(z), recorded))


def _tiles(out, st):
    """Merge the last pass and keep the mesh by tile (a block of the plan,
    :func:`trivsel.decimation.blocked.mesh_tiles`), one file per x-slab of tiles: each tile's
    tetrahedra (every one whose corners' box meets the tile), their rows, their corners' boxes
    (:func:`trivsel.decimation.blocked.tet_boxes`, which the jobs after it filter by), the
    tetrahedron of each of its points (-1 for a vertex), and its vertices with their values
    (read tile by tile).  ``tiles/mesh.json`` holds the counts."""
    T, owner, isv, _ = _state(out, st, len(st.passes))
    plan = st.plan
    owner[isv] = -1
    del isv
    m = int(np.count_nonzero(owner < 0))
    vol = _open(st.cfg)
    tiles = enumerate(B.mesh_tiles(plan.shape, plan.cuts, T, owner))
    per = plan.counts[1] * plan.counts[2]
    box_type = B.coordinate_type(plan.shape)

    def slab_of_tiles():  # one tile at a time, as they come
        for _ in range(per):
            t, (tets, rows, own) = next(tiles)
            lo, hi = B.tile_box(plan.shape, plan.cuts, t)
            at = np.flatnonzero(own < 0)
            bmin, bmax = B.tet_boxes(plan.shape, tets)
            yield {f"tets_{t}": tets, f"rows_{t}": rows, f"owner_{t}": own,
                   f"bmin_{t}": bmin.astype(box_type), f"bmax_{t}": bmax.astype(box_type),
                   f"vertices_{t}": _box_ids(lo, hi, plan.shape)[at],
                   f"values_{t}": np.asarray(_read_box(vol, lo, hi), np.float64).reshape(-1)[at]}

    for slab in st.slabs:
        _atomic_savez_each(out / TILES / f"{slab}.npz", slab_of_tiles())
    _atomic_write_text(out / TILES / "mesh.json", json.dumps({"tetrahedra": int(len(T)), "vertices": m}))


def _neighbourhood(out, plan, lo, hi):
    """The tetrahedra that meet the box ``lo`` to ``hi``, their rows, each of the box's points'
    tetrahedron and their longest extent (:func:`trivsel.decimation.blocked.mesh_meeting`),
    read from the tiles that meet the box, one at a time."""
    ts = B.tiles_meeting(plan.cuts, lo, hi)
    per = plan.counts[1] * plan.counts[2]

    def tiles(z):
        for t in ts:
            tets = z[f"tets_{t}"]
            boxes = (z[f"bmin_{t}"], z[f"bmax_{t}"]) if f"bmin_{t}" in z else B.tet_boxes(plan.shape, tets)
            yield (tets, z[f"rows_{t}"], z[f"owner_{t}"], *B.tile_box(plan.shape, plan.cuts, t), boxes)

    with _Members(*(out / TILES / f"{x}.npz" for x in sorted({t // per for t in ts}))) as z:
        return B.mesh_meeting(plan.shape, lo, hi, tiles(z))


def _box_ids(lo, hi, shape):
    """The C-order indices, in a grid of ``shape``, of the points of the box ``lo`` to ``hi``."""
    ax = [np.arange(int(a), int(b) + 1, dtype=np.int64) for a, b in zip(lo, hi)]
    return ((ax[0][:, None, None] * shape[1] + ax[1][None, :, None]) * shape[2] + ax[2][None, None, :]).ravel()


def _vertex_values(out, plan, kind, vertices):
    """The values at ``vertices`` (ascending) that the ``tiles`` jobs (``kind`` "data") or the
    ``fit`` jobs ("fit") wrote, read from their tiles' tables one tile at a time."""
    tile = B.tile_of(np.unravel_index(vertices, plan.shape), plan.cuts)
    order = np.argsort(tile, kind="stable")  # the vertices grouped by tile, sorted once
    ts, starts = np.unique(tile[order], return_index=True)
    ends = np.append(starts[1:], len(order))
    del tile
    per = plan.counts[1] * plan.counts[2]
    folder, name = (out / TILES, "values") if kind == "data" else (out / "fit", "fitted")
    got = np.empty(len(vertices))
    with _Members(*(folder / f"{x}.npz" for x in sorted({int(t) // per for t in ts}))) as z:
        for t, a, b in zip(ts, starts, ends):
            mine = order[a:b]
            got[mine] = z[f"{name}_{t}"][np.searchsorted(z[f"vertices_{t}"], vertices[mine])]
    return got


def _surroundings(out, plan, lo, hi):
    """What a job needs around the box ``lo`` to ``hi``: the tetrahedra that meet it, each of
    its points' tetrahedron, their longest extent (:func:`_neighbourhood`), the corners of
    those tetrahedra, ascending, with their data values, and each corner's place among them
    (the shape of the tetrahedra)."""
    tets, _, ptet, ext = _neighbourhood(out, plan, lo, hi)
    verts, columns = np.unique(tets, return_inverse=True)
    return tets, ptet, ext, (verts, _vertex_values(out, plan, "data", verts)), columns.reshape(tets.shape)


def _fit(out, st, slab):
    """The least-squares values of the vertices of slab ``slab``'s tiles: each tile solved as
    :func:`trivsel.decimation.blocked.tile_fit` solves it, from the tetrahedra that meet the box
    its solve may reach and the samples of that box alone
    (:func:`trivsel.decimation.blocked.fit_tile`: the same values, to the bit)."""
    plan = st.plan
    vol = _open(st.cfg)

    def fits():
        for t, _, _ in st.blocks_of(slab):
            lo, hi = B.fit_reach(plan.shape, plan.cuts, t)
            tets, ptet, ext, (verts, values), columns = _surroundings(out, plan, lo, hi)
            own, fitted = B.fit_tile(plan.shape, plan.cuts, t, tets, ptet, lo, hi, _read_box(vol, lo, hi), verts,
                                     values, extent=ext, columns=columns)
            yield {f"vertices_{t}": own, f"fitted_{t}": fitted}

    _atomic_savez_each(out / "fit" / f"{slab}.npz", fits())


def _pieces(out, st, slab):
    """Slab ``slab``'s tiles: each one's piece of the mesh (the tetrahedra whose lowest corner
    lies in it, with the values and fitted values of their corners) and the errors at its
    points, as sums (:class:`trivsel.norms.ErrorSums`).  Each tile reads the tetrahedra that
    meet it, the samples of its box and the values of those tetrahedra's corners."""
    from ..norms import ErrorSums

    plan = st.plan
    shape = np.asarray(plan.shape, np.int64)
    vol = _open(st.cfg)

    def results():
        for t, _, _ in st.blocks_of(slab):
            lo, hi = B.tile_box(plan.shape, plan.cuts, t)
            tets, ptet, _, data_at, _ = _surroundings(out, plan, lo, hi)
            verts = data_at[0]
            pts = _box_ids(lo, hi, plan.shape)
            f = np.asarray(_read_box(vol, lo, hi), np.float64).reshape(-1)

            def value_of(p):  # the samples in the tile's box, the vertices' values beyond it
                p = np.asarray(p, np.int64)
                ijk = np.unravel_index(p, plan.shape)
                inbox = np.all([(x >= a) & (x <= b) for x, a, b in zip(ijk, lo, hi)], axis=0)
                got = data_at[1][np.minimum(np.searchsorted(verts, p), len(verts) - 1)]
                got[inbox] = f[np.ravel_multi_index(tuple(x[inbox] - a for x, a in zip(ijk, lo)), tuple(hi - lo + 1))]
                return got

            corners, w, value = B.weights_in(plan.shape, tets, ptet, pts, value_of)  # as the kernels interpolate
            ijk = np.stack(np.unravel_index(pts, plan.shape), axis=1)
            inner = np.all((ijk > 0) & (ijk < shape - 1), axis=1)
            del ijk
            data = ErrorSums()
            data.add(f - value, inner)
            got = {f"data_{t}": data.to_array()}
            fit_at = None
            if st.fit:
                fit_at = (verts, _vertex_values(out, plan, "fit", verts))
                sums = ErrorSums()
                sums.add(f - np.einsum("ij,ij->i", w, fit_at[1][np.searchsorted(verts, corners)]), inner)
                got[f"fit_{t}"] = sums.to_array()
            del corners, w, value
            mine = B.tile_of(np.unravel_index(tets.min(axis=1), plan.shape), plan.cuts) == t
            _write_mesh(out / "pieces" / f"{item_name(np.unravel_index(t, plan.counts))}.vtu", vol, plan.shape,
                        tets[mine], data_at, fit_at)
            yield got

    _atomic_savez_each(out / "sums" / f"{slab}.npz", results())


def _finish(out, st):
    """The run's results: the errors (and those of the fitted values) summed over the tiles,
    the pieces' ``mesh.pvtu``, the merged mesh (``mesh.vtu``: the tiles' tetrahedra in the
    order of the whole mesh's rows, with the vertices' values that the tiles' jobs wrote) and
    the summary.  Without the merged mesh it reads a few numbers a tile."""
    from ..io.pieces import write_pvtu
    from ..norms import ErrorSums
    from . import RESULTS, STAGED

    plan, cfg = st.plan, st.cfg
    N = plan.n_points()
    fit = st.fit
    data_sums, fit_sums = ErrorSums(), ErrorSums()
    for slab in st.slabs:
        with _Members(out / "sums" / f"{slab}.npz") as z:
            for t, _, _ in st.blocks_of(slab):
                data_sums.add_sums(z[f"data_{t}"])
                if fit:
                    fit_sums.add_sums(z[f"fit_{t}"])
    errors = data_sums.norms()
    with open(out / TILES / "mesh.json") as fh:
        mesh = json.load(fh)
    staged = out / STAGED
    pieces = [out / "pieces" / f"{item_name(b)}.vtu" for b in plan.blocks()]
    write_pvtu(staged / "mesh.pvtu", pieces, overwrite=True, relative_to=out)
    if cfg.get("merged", True):
        T = np.empty((mesh["tetrahedra"], 4), B.index_type(N))
        vertices, values = [], []
        for slab in st.slabs:  # each tile's tetrahedra back to their rows, its vertices with their values
            with _Members(out / TILES / f"{slab}.npz") as z:
                for t, _, _ in st.blocks_of(slab):
                    T[z[f"rows_{t}"]] = z[f"tets_{t}"]
                    vertices.append(z[f"vertices_{t}"])
                    values.append(z[f"values_{t}"])
        vertices = np.concatenate(vertices)
        order = np.argsort(vertices)  # the tiles partition the points: no vertex twice
        vertices, values = vertices[order], np.concatenate(values)[order]
        del order
        _write_mesh(staged / "mesh.vtu", _open(cfg), plan.shape, T, (vertices, values),
                    (vertices, _vertex_values(out, plan, "fit", vertices)) if fit else None)
        del T, vertices, values
    tau, _ = _tau(out)
    target = st.target()
    m = int(mesh["vertices"])
    why = B.stop_reason(m, target, cfg.get("tol_inf"), st.block, cfg.get("tol_rms"))
    summary = {"points": N, "vertices": m, "fraction": m / N, "tetrahedra": int(mesh["tetrahedra"]),
               "E_rms": errors["E_rms"], "E_inf": errors["E_inf"], "E_rms_interior": errors["E_rms_interior"],
               "E_inf_interior": errors["E_inf_interior"], "method": "decimate", "target": target,
               "tol_rms": cfg.get("tol_rms"), "tol_inf": cfg.get("tol_inf"), "stopped": why,
               "blocks": len(plan.blocks()), "cost_threshold": float(tau) if np.isfinite(tau) else None,
               "passes": len(st.passes)}
    if fit:
        summary["fit"] = {k: float(v) for k, v in fit_sums.norms().items()}
    note = B.quality_note(N, target, st.block)
    if note:
        summary["notes"] = [note]
    _atomic_write_text(staged / "summary.json", json.dumps(summary, indent=1))
    for name in RESULTS:
        if name == "mesh.vtu" and not cfg.get("merged", True):
            (staged / name).unlink(missing_ok=True)
    publish_results(out)
    return summary


def _write_mesh(path, vol, shape, tets, value_at, fit_at, chunk=MESH_CHUNK):
    """Tetrahedra over global point indices as a .vtu: their vertices sorted by the input's
    point id, with ``value`` and ``fitted_value`` (``value_at``, ``fit_at``: point indices,
    ascending, and the values there; every corner among them) and ``original_index``.  The
    cells are renumbered and written ``chunk`` rows at a time
    (:func:`trivsel.io.pieces.write_piece_in_chunks`): a large mesh (the merged one) takes its
    vertices and an index a vertex beside its cells, never a copy of its cells or an array
    over the grid."""
    from ..io.pieces import write_piece_in_chunks

    if len(tets) <= chunk:
        ids, corners = np.unique(tets, return_inverse=True)
    else:
        ids = np.unique(np.concatenate([np.unique(tets[s:s + chunk]) for s in range(0, len(tets), chunk)]))
    ijk = np.stack(np.unravel_index(ids, shape), axis=1)
    file_ids = vol.file_ids(ijk)
    order = np.argsort(file_ids, kind="stable")
    rank = np.empty(len(ids), B.index_type(len(ids)))
    rank[order] = np.arange(len(ids), dtype=rank.dtype)
    if len(tets) <= chunk:
        cells = lambda: [rank[corners.reshape(tets.shape)]]  # noqa: E731
    else:
        cells = lambda: (rank[np.searchsorted(ids, tets[s:s + chunk])] for s in range(0, len(tets), chunk))  # noqa: E731
    ids, file_ids = ids[order], file_ids[order]
    points = vol.coordinates(ijk[order])
    del ijk, order

    def at(pairs):
        return pairs[1][np.searchsorted(pairs[0], ids)]

    arrays = None if fit_at is None else {"fitted_value": at(fit_at)}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    write_piece_in_chunks(path, points, cells, len(tets), at(value_at), file_ids, overwrite=True, arrays=arrays)


def mesh_tets(cfg, plan):
    """The most tetrahedra the mesh over the whole grid has in a run (what the step and last jobs
    hold): TETS_PER_VERTEX a vertex, the vertices after the blocks at most the cut's aim
    (:func:`trivsel.decimation.blocked.aim`) and every seam point; without a count (a tolerance
    alone), the whole grid's."""
    N = plan.n_points()
    target = Stages(cfg, plan).target()
    if target is None:
        return TETS_PER_VERTEX * N
    inner = np.prod([n - max(len(c) - 2, 0) for n, c in zip(plan.shape, plan.cuts)])
    return TETS_PER_VERTEX * min(N, int(B.aim(target, N, int(N - inner))) + int(N - inner))


def region_bytes(cfg, plan, points):
    """The memory of one region's decimation of ``points`` points (a region job's, beside its
    interpreter): ``REGION_BYTES_PER_POINT`` a point and ``REGION_BYTES_PER_TET`` a tetrahedron, its
    tetrahedra ``TETS_PER_VERTEX`` a vertex.  Its vertices are twice the share of the mesh after the
    blocks (:func:`mesh_tets`: the cut's aim and every seam point, or every point without a
    count), at most all of its points: the regions lie across the seams, where the mesh is
    densest."""
    share = mesh_tets(cfg, plan) / TETS_PER_VERTEX / plan.n_points()
    return points * (REGION_BYTES_PER_POINT + REGION_BYTES_PER_TET * TETS_PER_VERTEX * min(1.0, 2.0 * share))


def job_resources(cfg, plan, kind):
    """``(mem_mb, runtime_minutes)`` to request for a job of ``kind``: "costs" and "mesh"
    (a slab of blocks, one at a time), "rcosts" and "apply" (a slab of regions), "cut" and
    "quota" (a sample of the blocks' or regions' costs), "step", "tiles", "finish" (arrays over
    the whole grid), "fit" and "pieces" (a slab of tiles), "kernels"."""
    N = plan.n_points()
    block = int(cfg["block"])
    slab_pts = float(np.prod([max(np.diff(c)) + 1 for c in plan.cuts]))
    region_pts = float(min(N, (B.REGION * block + 1) ** 3))
    region = region_bytes(cfg, plan, region_pts)
    if kind in ("costs", "mesh"):
        mem = JOB_BASE_BYTES + DECIMATION_BYTES_PER_POINT * slab_pts
        secs = 60 + BLOCK_SECONDS_PER_POINT * N / plan.counts[0]
    elif kind in ("rcosts", "apply"):  # a slab of regions is at most a region's width of x-planes
        slab_of_regions = min(plan.shape[0], B.REGION * block + 1) * plan.shape[1] * plan.shape[2]
        mem, secs = JOB_BASE_BYTES + region, 60 + REGION_SECONDS_PER_POINT * slab_of_regions
    elif kind == "step":
        mem = JOB_BASE_BYTES + STEP_BYTES_PER_POINT * N + STEP_BYTES_PER_TET * mesh_tets(cfg, plan)
        secs = 60 + 2e-6 * N
    elif kind == "tiles":
        mem = JOB_BASE_BYTES + STEP_BYTES_PER_POINT * N + TILES_BYTES_PER_TET * mesh_tets(cfg, plan)
        secs = 60 + 2e-6 * N
    elif kind in ("fit", "pieces"):  # a slab's tiles one at a time, each with the box around it
        width = np.array([max(np.diff(c)) for c in plan.cuts])
        reach = 2 * np.maximum(width // 2, B.FIT_MARGIN) if kind == "fit" else 0
        box = float(np.prod(np.minimum(width + reach + 1, plan.shape)))
        dense = mesh_tets(cfg, plan) / N
        mem = JOB_BASE_BYTES + box * (FIT_BYTES_PER_POINT + FIT_BYTES_PER_TET * dense if kind == "fit"
                                      else PIECE_BYTES_PER_POINT + PIECE_BYTES_PER_TET * dense)
        secs = 60 + 5e-6 * box * plan.counts[1] * plan.counts[2]
    elif kind == "finish":  # the merged mesh's cells and vertices; the errors' sums alone without it
        mem = JOB_BASE_BYTES + (FINISH_BYTES_PER_TET * mesh_tets(cfg, plan) if cfg.get("merged", True) else 0)
        secs = 60 + 1e-6 * N
    elif kind == "kernels":
        mem, secs = 2 * JOB_BASE_BYTES, 600
    elif kind == "cut":  # a sample of the blocks' costs, a few numbers a block, and a block recorded again
        mem = JOB_BASE_BYTES + CUT_SAMPLE_BYTES_PER_RUN * B.STREAM_RUNS + 64 * len(plan.blocks()) \
            + DECIMATION_BYTES_PER_POINT * slab_pts
        secs = 60 + BLOCK_SECONDS_PER_POINT * N / plan.counts[0] + 2e-7 * N  # the costs files read a few times over
    else:  # quota: a sample of the regions' costs, a few numbers a region, and a region recorded again
        mem = JOB_BASE_BYTES + CUT_SAMPLE_BYTES_PER_RUN * B.STREAM_RUNS + 64 * (len(plan.blocks()) + 8) + region
        secs = 60 + 5e-5 * N
    return int(np.ceil(mem / 2**20)), int(np.ceil(secs / 60))


def run_job(out, kind, item=""):
    """One job of a run in folder ``out`` (the rules of ``decimate.smk``): ``kind`` with its
    item (``X`` for a slab of blocks, ``P`` for a pass, ``P_R`` for slab R of pass P's regions)."""
    cfg, plan = read_config(out)
    out = Path(out)
    st = Stages(cfg, plan)
    if kind in st.ITEMS:
        check_item(kind, item, st.items(kind))
    if kind == "kernels":
        get_method("decimate").compile_kernels()
    elif kind == "costs":
        _costs(out, st, int(item))
    elif kind == "cut":
        _cut(out, st)
    elif kind == "mesh":
        _mesh(out, st, int(item))
    elif kind == "step":
        _step(out, st, int(item))
    elif kind in ("rcosts", "apply"):
        p, slab = (int(s) for s in item.split("_"))
        (_region_costs if kind == "rcosts" else _region_apply)(out, st, p, slab)
    elif kind == "quota":
        _quota(out, st, int(item))
    elif kind == "tiles":
        _tiles(out, st)
    elif kind == "fit":
        _fit(out, st, int(item))
    elif kind == "pieces":
        _pieces(out, st, int(item))
    elif kind == "finish":
        _finish(out, st)
    else:
        from ..exceptions import InputError

        raise InputError(f"unknown job kind {kind!r}")


def main(argv=None):
    """``python -m trivsel.blocks.decimate KIND OUT [ITEM]``: one job of the workflow."""
    from . import main as blocks_main

    return blocks_main(argv, job=run_job, prog="trivsel.blocks.decimate", usage="{kernels,costs,cut,mesh,step,rcosts,quota,apply,tiles,fit,pieces,finish} OUT [ITEM]",
                       batches=())


if __name__ == "__main__":
    raise SystemExit(main())
