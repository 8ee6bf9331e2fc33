"""Bottom-up selection (beyond the paper): half-edge collapses from the full grid.

Start from every grid point and remove, one at a time, the vertex whose removal by a
half-edge collapse onto a neighbouring point raises the sum of squared residuals
(the numerator of E_RMS, eq. 19) least, until the count, fraction or tolerance is
reached (:mod:`trivsel.decimation`).  The vertices stay data points: the result is a
true selection, with the data values at its vertices (or fitted ones with
``values="fit"``).  Aims at E_RMS, or with ``criterion="max"`` at E_inf (the
collapse that leaves the smallest largest residual first).  On a grid it starts from
the Kuhn split; on scattered points from their Delaunay tetrahedralisation, and on a mesh
read with its cells from those cells, keeping the domain's boundary exactly (the
collapses are decided by robust predicates on the float coordinates).  The options of
curvature, ranking and swapping do not apply.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from ..exceptions import InputError
from .protocol import MethodRun, requested_fractions, unreached

NAME = "decimate"
#: No insertion and no swapping: the swap options do not apply (they stay None).
DEFAULTS = {"criterion": "sse"}
#: The collapses start from the full grid's Kuhn split; a prescribed boundary is not supported.
PRESCRIBED_BOUNDARY = False
#: Its own stages in blocks (``trivsel blocks --method decimate``), which ``--block`` runs in one process.
BLOCK_STAGES = "trivsel.blocks.decimate"
#: Peak bytes per point of a grid's decimation in one piece (the Kuhn split's 6 tets per point
#: with their corner lists, the buckets and the queue), and more with fitted values (the points'
#: weights and the normal equations' assembly: about 75 measured on the 129^3 T1 crop).  Whole
#: processes with fitted values, the interpreter included: 1.27 GB for the 129^3 T1 crop (2.1 M
#: points, 590 bytes a point), 4.21 GB for the whole 1 mm T1 (8.7 M, 485 bytes a point; docs/notes).
BYTES_PER_POINT = 500
FIT_BYTES_PER_POINT = 150
#: Peak bytes per point of one block's or region's decimation with ``block`` (a region's mesh
#: state holds its points and tetrahedra; the jobs' own figures are in trivsel.blocks.decimate).
PIECE_BYTES_PER_POINT = 1000
#: Peak bytes per tetrahedron of a decimation that starts from a tetrahedral mesh read from a
#: file (its reading, checks and mesh state; about 6.7 tetrahedra a point): 1.44 GB for 1 M
#: points and 6.75 M tetrahedra with fitted values, 0.54 GB for 0.3 M and 2.0 M, whole processes
#: (docs/notes).  Such meshes have more tetrahedra a point than a grid's Kuhn split, and each
#: costs more than a grid's.
MESH_BYTES_PER_TET = 200
#: With ``block``, bytes per point of the whole volume besides one block's or region's decimation:
#: the values, each point's tetrahedron and vertex flag, its grid coordinates in a pass, the mesh.
BLOCKED_BYTES_PER_POINT = 100


def check_options(options):
    """The criterion orders the collapses: ``sse`` (the default) by the change of the squared
    error, ``max`` by the largest residual of the points that move; not ``rms``."""
    if options.criterion == "rms":
        raise InputError("method 'decimate' orders collapses by criterion 'sse' (E_RMS) or 'max' (E_inf), "
                         "got 'rms'")


def check(data, options):
    """Any data: a grid, scattered points or a tetrahedral mesh."""


def memory(data, options):
    """Peak memory, as ``[(bytes, what), ...]``."""
    from ..resources import DELAUNAY_BYTES_PER_POINT

    N = data.n_points
    fit = FIT_BYTES_PER_POINT if "fit" in options.values else 0
    if options.block and data.is_grid:  # one block or region at a time, and the whole as owners
        piece = min(float(2 * options.block + 1) ** 3, float(N))
        return [(BLOCKED_BYTES_PER_POINT * float(N) + PIECE_BYTES_PER_POINT * piece + fit * float(N),
                 f"decimating {N} points in blocks of {options.block}")]
    if getattr(data, "tets", None) is not None:  # a mesh's own tetrahedra set its size
        M = len(data.tets)
        return [(MESH_BYTES_PER_TET * float(M) + fit * float(N), f"decimating a mesh of {N} points and {M} tetrahedra")]
    per_point = BYTES_PER_POINT + fit
    need = [(per_point * float(N), f"decimating {N} points")]
    if not data.is_grid and data.tets is None:
        need.append((DELAUNAY_BYTES_PER_POINT * float(N), f"the Delaunay tetrahedra of {N} scattered points"))
    return need


def block_stages():
    """The stages of ``decimate`` in blocks (:mod:`trivsel.decimation.blocked`): what the jobs of
    ``trivsel blocks --method decimate`` (``BLOCK_STAGES``) and ``--block`` run."""
    from ..decimation import blocked

    return blocked


def compile_kernels(part=None):
    """Compile (or load) the decimation's kernels; every part compiles all of them (they are small)."""
    from ..decimation import compile_kernels as compile_decimation

    return compile_decimation()


def run(problem):
    """The run goes down from the full grid (:func:`trivsel.decimation.reduce_by_collapse`)."""
    from ..decimation import EXACT_WITHIN, reduce_by_collapse
    from ..triangulation import cube_corners

    data, opts, stop = problem.data, problem.options, problem.stop
    if problem.boundary is not None:
        raise InputError("method 'decimate' cannot take a prescribed boundary; use 'greedy' or 'paper'")
    check_blocks(data, opts, stop)
    N = data.n_points
    start = None
    if data.is_grid:
        interior = data.interior_mask()
    else:  # the start mesh's boundary is the domain's (for scattered points, their hull)
        from ..decimation.tetmesh import start_interior_mask, start_mesh

        start = start_mesh(data)
        interior = start_interior_mask(data.points, *start)
    if opts.candidates == "interior":
        n_fixed = int(np.sum(~interior))
    else:  # the box's corners; off the grid, at least one tetrahedron
        n_fixed = 8 if data.is_grid else 4
    targets = problem.targets()
    for m in targets:
        if m < n_fixed:
            raise InputError(f"target of {m} points is fewer than the {n_fixed} points that decimation keeps "
                             f"(candidates {opts.candidates!r}, N = {N}): give --count {n_fixed} or more")
    if not targets:  # tolerance only: as far down as the tolerance allows
        targets = [n_fixed]
    logging.getLogger("trivsel").info("decimating %d points down to %d", N, targets[0])
    if opts.block:
        return _run_in_blocks(problem, interior, targets)
    snaps, selected, stats, t_errors = reduce_by_collapse(
        data, targets, tol_rms=stop["tol_rms"], tol_inf=stop["tol_inf"], candidates=opts.candidates,
        key="max" if opts.criterion == "max" else "sse",
        exact_within=EXACT_WITHIN if opts.lazy_queue else float("inf"),
        values=opts.values, interior=interior, check=problem.check, progress=problem.progress,
        t_start=problem.t_start, start=start)
    requested_fractions(snaps, stop["fractions"], N)
    notes = unreached(stop, N, snaps[0].n_selected, stats.pop("stopped"), up=False)
    t_total = time.perf_counter() - problem.t_start
    timings = {"curvature": 0.0, "selection": t_total - t_errors, "errors": t_errors, "total": t_total}
    if opts.candidates == "interior":
        fixed = ~interior
    elif data.is_grid:
        fixed = np.isin(np.arange(N), cube_corners(data.shape))
    else:  # the vertices no collapse could remove
        fixed = np.zeros(N, bool)
        fixed[selected[:snaps[0].n_selected]] = True
    order = selected[~fixed[selected]]
    return MethodRun(snapshots=snaps, selected=snaps[-1].selected, curvature=None, order=order,
                     timings=timings, stats=stats, notes=notes)


def check_blocks(data, options, stop):
    """What ``block`` takes: a grid and its stops (one count or fraction, tol_rms, tol_inf),
    ordered by the squared error over every point (:mod:`trivsel.decimation.blocked`)."""
    if not options.block:
        return
    if not data.is_grid:
        raise InputError("option block applies to grids; scattered points and meshes are decimated in one piece")
    if options.criterion == "max" or options.candidates == "interior":
        what = "criterion 'max'" if options.criterion == "max" else "candidates 'interior'"
        raise InputError(f"option block orders collapses by criterion 'sse' over all candidates, not {what}")
    if (stop["count"] is not None) + len(stop["fractions"] or ()) > 1:
        raise InputError("option block takes one count or fraction, got several")


def _run_in_blocks(problem, interior, targets):
    """The run in blocks (:func:`trivsel.decimation.blocked.reduce_in_blocks`)."""
    from ..decimation.blocked import quality_note, reduce_in_blocks

    data, opts, stop = problem.data, problem.options, problem.stop
    N = data.n_points
    target = targets[0] if (stop["fractions"] or stop["count"] is not None) else None
    snaps, selected, stats, t_errors = reduce_in_blocks(
        data, target, block=opts.block, tol_rms=stop["tol_rms"], tol_inf=stop["tol_inf"], values=opts.values, interior=interior,
        threads=problem.threads, progress=problem.progress, t_start=problem.t_start)
    requested_fractions(snaps, stop["fractions"], N)
    notes = unreached(stop, N, snaps[0].n_selected, stats.pop("stopped"), up=False)
    note = quality_note(N, target, opts.block)
    if note:
        notes.append(note)
        logging.getLogger("trivsel").warning("note: %s", note)
    t_total = time.perf_counter() - problem.t_start
    timings = {"curvature": 0.0, "selection": t_total - t_errors, "errors": t_errors, "total": t_total}
    return MethodRun(snapshots=snaps, selected=selected, curvature=None, order=selected, timings=timings,
                     stats=stats, notes=notes)
