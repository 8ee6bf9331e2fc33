r"""``method="decimate"`` in blocks: one cost threshold cut across the blocks' recorded
collapse sequences, then the seams freed in regions of whole vertex stars, then a quota step.

Bottom-up decimation (:mod:`trivsel.decimation`) starts from every grid point, so it cannot
take the prescribed faces that the inserting methods take in blocks.  Here the box is cut
into blocks that share their faces (the *seams*)::

    costs    every block is decimated on its own, its seam points locked, and its
             sequence of collapse costs recorded (Hoppe's progressive meshes: the
             collapses in the order made, each with its cost), down to a floor under
             its share of the count (``RECORD_FLOOR``; on while the rest is cheap,
             ``RECORD_TAIL``; again to its end where the cut compares a cost past the
             record's: ``short_blocks``)
    cut      one cost threshold tau for all the blocks, from the sequences' running
             maxima: the blocks' points left at tau, and the seams' at the blocks'
             density, come to the cut's aim: 1.2 times the count asked for, more
             where the seams are wide against the count (``aim``)
    blocks   every block's recorded collapses replayed up to its first that costs more
             than tau (no cost computed again): the prefix of its recorded sequence
             (without a count, tau is inf and every block runs to ``tol_inf``)
    regions  a grid of regions of 2 x 2 x 2 blocks, cut through the blocks' middles, so
             that the seams run inside them.  Every vertex is a candidate; it is *free*
             in its region when every tetrahedron around it has its candidates in that
             region only.  A region's tetrahedra are the stars of its free vertices: two
             regions never share a tetrahedron, and what one changes the others never
             see.  Its other vertices are locked, and it is decimated (exact queue) down
             to tau.  The vertices near a region's cut are not free; two more grids, cut
             elsewhere, free them
    quota    the vertices still over the count are taken from the regions of four more
             grids: each region records its cheapest collapses, and the cheapest of all
             in a grid, a prefix of each region's sequence, are made.  With a count, none
             above one cost (``quota_limit``): the cost at which the first grid's regions
             remove their share of what is left (the part of the vertices they free), so
             that the grids share it by cost and no grid takes it alone
    rest     what that cost left of the count, from the regions of four grids again,
             the cheapest first

With ``tol_rms`` the squared error is a budget, ``tol_rms^2 N``, that the stages share without
ever exceeding it.  Every recorded sequence carries its running squared error (the exact
change of each collapse, summed; section 5's eq. 19), and the squared errors of disjoint
pieces add up: the cut takes tau where the blocks' errors, projected over the seams, come to
``SSE_SHARE`` of the budget; each pass after it records its regions' sequences within what is
left and makes the cheapest collapses across its regions while their errors fit in it.  So
the merged mesh's E_RMS is within ``tol_rms`` by construction, and the quota passes spend the
rest of the budget on the cheapest collapses of all (as one piece's queue would).

      blocks (pass 1)      regions (cuts through the blocks' middles)
      +-----+-----+            :     :
      |     |     |        ....:.....:....     o free: its whole star in the region
      +-----+-----+            :  o  :         x locked: a tetrahedron around it has a
      |     |     |        ....:.....:....       candidate in another region
      +-----+-----+            :  x  :

Every collapse is one of :mod:`trivsel.decimation` (exact integer predicates, the cost
the exact change of the squared residuals over the original points, section 5's eq. 19),
so the merged mesh is a conforming tetrahedralisation of the box whose vertices are data
points.  Each block reads only its block, each region only its region's points and the
tetrahedra of the blocks it overlaps; the whole volume is held here only as the owner of
each point (one integer) and the mesh.  Blocks must be large against the tetrahedra near
the stop: with blocks of 8 intervals and tetrahedra as large, few vertices are free in any
region, and the error grows (``docs/notes``).
"""

from __future__ import annotations

import time

import numpy as np

from ..selection import count_for_fraction
from . import EXACT_WITHIN, INF, LOCK_ALL, Decimation, lattice_interpolant, lattice_weights, new_mesh_state, new_state
from .streamcut import RUNS as STREAM_RUNS
from .streamcut import streamed_cut_counts, streamed_cut_quota, streamed_kth_cost, streamed_threshold

__all__ = ["block_cuts", "block_list", "passes", "region_grid", "block_costs", "block_mesh", "aim", "threshold",
           "short_blocks", "threshold_of_whole_records", "cut_counts", "tied_counts", "streamed_threshold",
           "streamed_cut_counts", "streamed_cut_quota", "streamed_kth_cost",
           "index_type", "sse_budget", "running_sse", "sse_at", "assemble", "pass_plan", "region_input",
           "region_decimate", "cost_caps", "record_caps", "derives_limit", "short_regions", "record_ends",
           "limit_of_whole_records", "cut_quota", "quota_limit", "free_share", "pass_limit", "record_limit",
           "merge_pass",
           "decimate_in_blocks", "pass_runs",
           "stop_reason", "quality_note", "point_weights", "point_weights_of", "reduce_in_blocks"]

#: The edge of a region of the passes after the blocks, in blocks
REGION = 2
#: The shifts of the seam passes' region grids, in blocks: their cuts run through the blocks' middles,
#: away from the seams, and cross each other's only at lines
SEAM_SHIFTS = (0.5, 1.5, 0.25)
#: The shifts of the quota passes' region grids, in blocks
QUOTA_SHIFTS = (0.0, 1.0, 0.5, 1.5)
#: The shifts of the grids of the passes that take what the quota passes left of a count (their cost limit,
#: :func:`quota_limit`, may leave some), in blocks
REST_SHIFTS = (0.0, 1.0, 0.5, 1.5)
#: The cut aims above the count asked for (:func:`aim`), so that the seam passes end above it and the quota
#: passes take the rest, spread over their four grids by one cost (:func:`quota_limit`): OVERSHOOT times the
#: count, more where the seams are wide against the count.  The regions free every vertex and remove more than
#: the blocks' sequences show, about a band of vertices along the seams that the blocks kept: with an aim of
#: 1.2 times, blocks of 16 on a T1 crop reached a count of 2 % in the seam passes, before their last grid had
#: freed the seams, at 2.9 times one piece's E_RMS (measured: docs/notes)
OVERSHOOT = 1.2
#: The aim grows by BAND_GROWTH times the seams' band (:func:`aim`) over BAND_FREE, up to MAX_OVERSHOOT times the
#: count, and never beyond the count plus AIM_SHARE of the points over it
BAND_GROWTH, BAND_FREE, MAX_OVERSHOOT, AIM_SHARE = 2.0, 0.3, 2.0, 0.2
#: With ``tol_rms``, the cut aims the blocks' squared error (projected over the seams) at this share of the
#: budget, so that the region passes end within it and the quota passes spend the rest: the share of the
#: error that 1.2 times the count leaves, the squared error of a trilinear fit growing about as m^(-4/3)
#: with m vertices.  A larger share runs the seam passes out of budget before their last grid has freed the
#: seams, a smaller one leaves the quota passes more than they spend well (measured: docs/notes)
SSE_SHARE = OVERSHOOT ** (-4.0 / 3.0)
#: Pass 1 records a block's collapses down to its seam points and this part of its share of the count, and
#: those of cost 0 after it, not to its last: the cut needs each block's costs up to the threshold only, and
#: the collapses far below a block's share cost far above it (on a smooth volume, a third of pass 1: measured,
#: docs/notes).  A block whose record ends at or below a cost the cut compared is recorded again to its end
#: (:func:`short_blocks`), so the threshold, and the mesh, are those of whole records
RECORD_FLOOR = 0.25
#: Past the floor a block's record goes on while that takes at most this part of the time it took to the floor
#: (in steps of TAIL_STEP collapses): where the rest is cheap (a real volume's blocks: their records end near the
#: floor, or in a background) the record is whole and the cut need not record it again
RECORD_TAIL, TAIL_STEP = 0.1, 256
#: A block's record takes its collapses with exact costs from EXACT_WITHIN times its share of the count down to
#: this part of its share, and with the lazy queue again below it: only the blocks that the threshold takes past
#: their share use that part of the record, and it is the costliest part to take exactly (the trade of error
#: against time is measured in docs/notes)
RECORD_EXACT_TO = 1.0
#: The first quota pass, which derives the quota passes' cost limit (:func:`quota_limit`), records each region
#: up to this many times its share of the surplus (the later ones: up to twice it, and the limit).  A region
#: whose record stops there at or below the limit derived is recorded again to twice its share
#: (:func:`limit_of_whole_records`), so the limit, and the mesh, are those of records to twice the share.  A
#: trade: regions whose records end below the limit (a volume's background) are recorded twice (docs/notes)
FIRST_QUOTA_RECORD = 1
#: The budget is ``tol_rms^2 N`` less this relative margin, for the rounding of sums taken in another order
SSE_MARGIN = 1e-9
#: A count's run in blocks keeps about one piece's errors down to this fraction of the points in blocks of
#: FAITHFUL_BLOCK intervals and more; below either, it was measured well above one piece's E_RMS on real
#: volumes (docs/methods.md), and its run says so (:func:`quality_note`)
FAITHFUL_FRACTION = 0.05
FAITHFUL_BLOCK = 32

def block_cuts(n, block):
    """The grid indices where blocks of ``block`` intervals meet along an axis of ``n``
    points: ``0, block, 2 block, ..., n - 1`` (a last block shorter than half a block is
    joined to the one before)."""
    cuts = list(range(0, n - 1, block)) + [n - 1]
    if len(cuts) > 2 and cuts[-1] - cuts[-2] < block // 2:
        del cuts[-2]
    return np.asarray(cuts, np.int64)


def block_list(shape, block):
    """The cuts of every axis and the blocks as ``(lo, hi)`` grid index bounds (inclusive), in
    C order of their block indices."""
    cuts = [block_cuts(int(m), int(block)) for m in shape]
    bounds = [([int(cuts[0][i]), int(cuts[1][j]), int(cuts[2][k])],
               [int(cuts[0][i + 1]), int(cuts[1][j + 1]), int(cuts[2][k + 1])])
              for i in range(len(cuts[0]) - 1) for j in range(len(cuts[1]) - 1) for k in range(len(cuts[2]) - 1)]
    return cuts, bounds


def passes(block):
    """The passes after the blocks, in order, as ``(kind, offset)``: the seam passes
    (``"seams"``, down to the threshold), the quota passes (``"quota"``; with a count, none
    above one cost, :func:`quota_limit`) and, with a count, the passes that take what they
    left (``"rest"``, cheapest first), each on the grid of regions of edge ``REGION * block``
    whose cuts are at ``offset + k REGION block``."""
    return ([("seams", round(s * block)) for s in SEAM_SHIFTS]
            + [("quota", round(s * block)) for s in QUOTA_SHIFTS]
            + [("rest", round(s * block)) for s in REST_SHIFTS])


def region_grid(shape, offset, size):
    """Regions per axis of the pass grid of edge ``size`` cut at ``offset + k size``, and the
    shift that puts its first cut at 0."""
    shift = size - offset % size
    return (np.asarray(shape, np.int64) - 1 + shift) // size + 1, shift


def _block_state(values, lo, shape, seam_axes):
    """The decimation state of the block of ``values`` (its samples, ``[i, j, k]``) whose
    first point is ``lo`` in the grid of ``shape``, its seam points locked, and the global
    point index of each of its points."""
    bshape = values.shape
    ijk = np.indices(bshape).reshape(3, -1).T
    n = np.asarray(shape, np.int64)
    g = ijk + np.asarray(lo, np.int64)
    gid = (g[:, 0] * n[1] + g[:, 1]) * n[2] + g[:, 2]
    S = new_state(ijk, bshape, np.asarray(values, np.float64).ravel(), lock="box", key="sse", lazy=True)
    seam = _on_seam(g, seam_axes)
    S.lock[seam] |= LOCK_ALL
    return S, gid, seam


def _on_seam(g, seam_axes):
    """Whether grid points ``g`` lie on a seam (``seam_axes[a]``: the cut indices of axis a
    inside the box)."""
    on = np.zeros(len(g), bool)
    for a in range(3):
        on |= np.isin(g[:, a], seam_axes[a])
    return on


def _block_run(values, lo, shape, seam_axes, fraction, tol_inf, key_max, tol_rms=None, floor=0.0):
    """The block decimated lazily down to its seam points and twice its share of the target
    (``fraction`` of its points off the seams) and, with ``tol_rms``, while its E_RMS is below
    ``tol_rms / EXACT_WITHIN``, then with exact costs (as
    :func:`trivsel.decimation.reduce_by_collapse` does near its stop) down to
    :data:`RECORD_EXACT_TO` times its share (with ``tol_rms``: on to its end), then lazily
    again, until the first collapse that costs more than ``key_max``: the same sequence every
    time.  With a ``floor`` (and a count), the run stops at its seam points and ``floor`` times
    its share, and goes on past it while that takes at most :data:`RECORD_TAIL` of the time
    spent so far, and then through collapses of cost 0 only: a prefix of that sequence (which
    prefix depends on the clock; the mesh never does, :func:`short_blocks`).  Returns the
    decimation, the points' global indices, the seam flags and whether the floor cut the
    sequence short (a collapse of a positive cost was left)."""
    start = time.perf_counter()
    S, gid, seam = _block_state(values, lo, shape, seam_axes)
    dec = Decimation(None, None, None, tol_inf=tol_inf, state=S, grid=values.shape)
    share = (~seam).sum() * fraction  # its locked seam points stay
    near_sse = INF if tol_rms is None else float(tol_rms) ** 2 * len(gid) / EXACT_WITHIN ** 2
    if dec.run(int(seam.sum() + EXACT_WITHIN * share), sse_max=near_sse, key_max=key_max) == 1:
        return dec, gid, seam, False
    dec.lazy = False
    exact_to = int(seam.sum() + RECORD_EXACT_TO * share) if share > 0 and tol_rms is None else 0

    def to(count, key_max):  # exact down to exact_to, lazy after it, wherever the run stops on the way
        if not dec.lazy and count < exact_to:
            code = dec.run(exact_to, key_max=key_max)
            if code != 0:
                return code
            dec.lazy = True
        return dec.run(count, key_max=key_max)

    stop = int(seam.sum() + floor * share) if floor > 0 and share > 0 else 0
    if to(stop, key_max) != 0 or stop == 0:
        return dec, gid, seam, False
    spent = time.perf_counter() - start
    tail = time.perf_counter()
    while time.perf_counter() - tail <= RECORD_TAIL * spent:  # the rest while it is cheap, in steps
        if to(max(dec.n_vertices - TAIL_STEP, 0), key_max) != 0:
            return dec, gid, seam, False
    return dec, gid, seam, to(0, min(key_max, 0.0)) == 2


def sse_budget(tol_rms, n_points):
    """The squared error that a run to ``tol_rms`` over ``n_points`` may spend in all
    (``tol_rms^2 N`` less :data:`SSE_MARGIN`); inf without ``tol_rms``."""
    return INF if tol_rms is None else float(tol_rms) ** 2 * n_points * (1.0 - SSE_MARGIN)


def running_sse(deltas):
    """The squared error a sequence of collapses has added after each of them (``deltas``:
    their exact changes, in the order made), as a bound that never falls: the running maxima
    of the cumulative sums, from 0."""
    d = np.asarray(deltas, np.float64)
    return np.maximum.accumulate(np.maximum(np.cumsum(d), 0.0)) if len(d) else d.copy()


def sse_at(sse, counts):
    """The squared error the sequences (:func:`running_sse`) add when each is cut to its count."""
    return float(sum(s[c - 1] for s, c in zip(sse, counts) if c > 0))


def block_costs(values, lo, shape, seam_axes, *, fraction, tol_inf=None, tol_rms=None, floor=RECORD_FLOOR):
    """Pass 1 on one block: the running maxima of its collapse costs in the order made, its
    number of points off the seams, the collapses themselves (the points removed and the
    vertices they moved onto, block indices) for pass 2 to replay, the squared error they
    add (:func:`running_sse`; a block starts at error 0, every point a vertex), and whether
    the record stops at ``floor`` times the block's share of the count (:data:`RECORD_FLOOR`;
    0: every collapse recorded) with collapses of a positive cost left."""
    dec, gid, seam, short = _block_run(values, lo, shape, seam_axes, fraction, tol_inf, INF, tol_rms, floor)
    removed = dec.removed()
    keys = dec.S.hkey[removed]
    runmax = np.maximum.accumulate(keys) if len(keys) else keys.copy()
    return (runmax, int((~seam).sum()), (removed.astype(np.int32), dec.into().astype(np.int32)),
            running_sse(dec.S.hsse[removed]), short)


def block_mesh(values, lo, shape, seam_axes, *, fraction, tau, tol_inf=None, recorded=None):
    """Pass 2 on one block, down to the threshold ``tau``: its tetrahedra (global point
    indices), the points inside them with their rows, and the number of collapses.  With
    ``recorded`` (pass 1's collapses up to ``tau``: :func:`block_costs`' third item, cut to
    its count at ``tau``), those collapses are replayed, not costed again: the same mesh."""
    if recorded is None:
        dec, gid, seam, _ = _block_run(values, lo, shape, seam_axes, fraction, tol_inf, tau)
    else:
        S, gid, seam = _block_state(values, lo, shape, seam_axes)
        dec = Decimation(None, None, None, tol_inf=tol_inf, state=S, queue=False)
        dec.replay(*recorded)
    row = np.cumsum(dec.S.alive) - 1
    inside = np.flatnonzero(~dec.S.isv)
    return gid[dec.tetrahedra()], gid[inside], row[dec.S.ptet[inside]], len(dec.removed())


def aim(target, n_points, seam_points):
    """The count the blocks' cut aims at for a count of ``target`` of ``n_points`` points
    (None: none), ``seam_points`` of them on the seams.  The seams' *band*, the vertices that
    a vertex spacing on each side of them holds against the count, is
    ``seam_points / n_points * (n_points / target)^(1/3)``; the aim is :data:`OVERSHOOT`
    times the count, plus :data:`BAND_GROWTH` times the band over :data:`BAND_FREE`, at most
    :data:`MAX_OVERSHOOT` times the count and the count plus :data:`AIM_SHARE` of the points
    over it."""
    if target is None:
        return None
    band = seam_points / n_points * (n_points / max(target, 1)) ** (1.0 / 3.0)
    factor = min(OVERSHOOT + BAND_GROWTH * max(0.0, band - BAND_FREE), MAX_OVERSHOOT)
    return min(factor * target, target + AIM_SHARE * (n_points - target))


def threshold(runmax, inner, seam_points, target, sse=None, budget=INF):
    """The cost threshold tau at which the blocks' points left (their sequences' running
    maxima cut at tau), plus the seams' points at the blocks' density, come nearest to
    ``target``; with a ``budget`` (:func:`sse_budget`), at most the tau at which the squared
    error the blocks add (``sse``, :func:`running_sse` of each), projected over the seams at
    the blocks' density, is ``SSE_SHARE`` of it.  Inf with neither.

    Returns ``(tau, decided)``: ``decided`` is the largest cost whose counts the choice
    compared (inf where it needed every collapse), so that sequences recorded only up to a
    cost above it (:func:`short_blocks`) give the same tau as whole ones."""
    if target is None and budget == INF:
        return INF, INF
    total = sum(inner)
    cand = np.unique(np.concatenate([r for r in runmax if len(r)] or [np.zeros(0)]))
    if not len(cand):
        return INF, INF

    def counts(t):
        return [int(np.searchsorted(r, t, side="right")) for r in runmax]

    def left(t):
        kept = total - sum(counts(t))
        return kept + seam_points * kept / max(total, 1)

    def first(ok):  # the smallest index whose candidate is ok (ok holds from it on); len(cand) if none
        lo, hi = 0, len(cand)
        while lo < hi:
            mid = (lo + hi) // 2
            if ok(cand[mid]):
                hi = mid
            else:
                lo = mid + 1
        return lo

    def at(k):  # the k-th candidate; inf past the last
        return float(cand[k]) if k < len(cand) else INF

    tau = decided = INF
    if target is not None:  # left() falls as tau grows: the smallest tau with left <= target, or every collapse
        k = first(lambda t: left(t) <= target)
        tau, decided = float(cand[min(k, len(cand) - 1)]), at(k)
    if budget < INF:  # the projected error grows with tau: the largest tau within the share
        scale = (total + seam_points) / max(total, 1)
        k = first(lambda t: sse_at(sse, counts(t)) * scale > SSE_SHARE * budget)
        t = float(cand[k - 1]) if k > 0 else float(np.nextafter(cand[0], -INF))
        if t < tau:  # the budget binds before the count: decided by the first candidate past it
            tau, decided = t, at(k)
    return tau, decided


def cut_counts(runmax, tau, inner=None, seam_points=0, target=None):
    """Each block's collapses at the threshold ``tau`` (:func:`threshold`): every collapse whose
    running maximum lies at or below tau, but of those at tau (a tie: symmetric data, flat
    regions), in block order, only as many as keep :func:`threshold`'s projected count (the
    blocks' points left, ``inner`` of them off the seams, plus the ``seam_points`` at their
    density) at ``target`` or above: taking them all could take the count below the target,
    which no later pass gives back.  Without a target, every collapse at tau."""
    hi = [int(np.searchsorted(r, tau, side="right")) for r in runmax]
    if target is None or not runmax:
        return hi
    return tied_counts(hi, [int(np.searchsorted(r, tau, side="left")) for r in runmax], inner, seam_points, target)


def tied_counts(hi, lo, inner, seam_points, target):
    """:func:`cut_counts` of the blocks' counts at or below the threshold (``hi``) and below it
    (``lo``): the collapses tied at it taken in block order while the projected count stays at
    ``target`` or above."""
    if target is None:
        return list(hi)
    total = sum(inner)

    def left(kept):
        return kept + seam_points * kept / max(total, 1)

    kept = min(total, max(0, int(target * total / max(total + seam_points, 1))))  # then exactly by left()
    while kept > 0 and left(kept - 1) >= target:
        kept -= 1
    while kept < total and left(kept) < target:
        kept += 1
    extra = total - kept - sum(lo)  # the tied collapses the target leaves room for
    counts = []
    for a, h in zip(lo, hi):
        take = min(h - a, max(extra, 0))
        extra -= take
        counts.append(a + take)
    return counts


def short_blocks(runmax, short, decided):
    """The blocks whose record (:func:`block_costs`) stopped at its floor (``short``) at or below
    the cost ``decided`` (:func:`threshold`): recorded again to their last collapse, the cut
    is that of whole records (every cost it compares lies below every record's end)."""
    return [i for i, (r, s) in enumerate(zip(runmax, short)) if s and (not len(r) or r[-1] <= decided)]


def threshold_of_whole_records(runmax, inner, seam_points, target, sse, budget, short, record_again):
    """:func:`threshold`'s tau of records cut at their floor, as of whole ones: the blocks that
    :func:`short_blocks` names are recorded again by ``record_again(blocks)`` (an iterable of
    each one's running maxima and squared errors, in order; ``runmax``, ``sse`` and ``short``
    are updated in place), and tau is taken again; once at most, since whole records are never
    short and tau only falls.  Returns tau and the blocks recorded again."""
    again_all = []
    while True:
        tau, decided = threshold(runmax, inner, seam_points, target, sse, budget)
        again = short_blocks(runmax, short, decided)
        if not again:
            return tau, again_all
        for i, (r, e) in zip(again, record_again(again)):
            runmax[i], sse[i], short[i] = r, e, False
        again_all += again


def index_type(n):
    """The integer type of indices below ``n``: int32 while they fit (the whole-grid arrays of
    the passes, point ids and tetrahedron rows, take half the memory), else int64."""
    return np.int32 if n < 2**31 else np.int64


def coordinate_type(shape):
    """The integer type of grid coordinates in a grid of ``shape`` (the tiles' boxes of their
    tetrahedra): int16 while every coordinate fits, else int32."""
    return np.int16 if max(int(n) for n in shape) - 1 <= np.iinfo(np.int16).max else np.int32


def assemble(N, meshes, runmax=None, names=None):
    """The blocks' meshes (``(tets, inside, rows, n_removed)`` each, :func:`block_mesh`) as one
    mesh state: tetrahedra ``T``, each point's row of ``T`` (``owner``, -1 for vertices) and
    the vertex flags (indices of :func:`index_type`; a grid has fewer than 6 N tetrahedra).
    ``meshes`` is read once, one block at a time.  With ``runmax``, each block's collapse count
    is checked against its recorded sequence cut at the threshold (passed as ``runmax[i]``'s
    count)."""
    tets, owner, isv = [], np.full(N, -1, index_type(6 * N)), np.ones(N, bool)
    base = 0
    for i, (T, inside, rows, n_removed) in enumerate(meshes):
        if runmax is not None and n_removed != runmax[i]:
            raise RuntimeError(f"block {names[i] if names else i} did not repeat its recorded collapses")
        owner[inside] = base + rows
        isv[inside] = False
        tets.append(np.asarray(T, index_type(N)))
        base += len(T)
    return np.concatenate(tets), owner, isv


#: Rows of the mesh that :func:`pass_plan` takes at a time for its per-tetrahedron temporaries
PLAN_CHUNK = 1 << 20


def pass_plan(shape, T, owner, isv, cand, offset, size):
    """The regions of one pass: the grid of edge ``size`` cut at ``offset + k size``.  A
    candidate vertex is free in its region when every tetrahedron around it has its
    candidates in that region only; a region's tetrahedra are the stars of its free
    vertices.  Returns a dict: ``free`` (per point), ``left`` (candidates not free, for the
    next pass), ``order`` (rows of ``T`` by region), ``starts``/``ends`` (each region's run of
    ``order``), ``region`` (each run's region id in the grid), ``pts``/``pkeys`` (the points
    inside the regions' tetrahedra, by region), ``row_of`` (a tetrahedron's row in its region),
    ``nfree`` (free vertices per run) and ``dims`` (regions per axis)."""
    dims, shift = region_grid(shape, offset, size)
    c = np.flatnonzero(cand)
    r3 = (np.stack(np.unravel_index(c, shape), axis=1) + shift) // size  # the candidates' regions per axis
    rid = np.full(len(isv), -1, index_type(int(np.prod(dims))))
    rid[c] = (r3[:, 0] * dims[1] + r3[:, 1]) * dims[2] + r3[:, 2]
    del c, r3
    # each tetrahedron's least and greatest region of its candidates (-1: none), a chunk of rows at a time
    rmin, rmax = np.empty(len(T), rid.dtype), np.empty(len(T), rid.dtype)
    for s in range(0, len(T), PLAN_CHUNK):
        R = rid[T[s:s + PLAN_CHUNK]]
        rmax[s:s + PLAN_CHUNK] = R.max(axis=1)
        R[R < 0] = np.iinfo(rid.dtype).max
        rmin[s:s + PLAN_CHUNK] = R.min(axis=1)
    conflict = (rmax >= 0) & (rmin != rmax)
    del rmin
    blocked = np.zeros(len(isv), bool)
    blocked[T[conflict].ravel()] = True
    del conflict
    free = cand & ~blocked
    treg = rmax  # the region of a tetrahedron around a free vertex, else -1
    for s in range(0, len(T), PLAN_CHUNK):
        treg[s:s + PLAN_CHUNK][~free[T[s:s + PLAN_CHUNK]].any(axis=1)] = -1
    order = np.flatnonzero(treg >= 0)
    order = order[np.argsort(treg[order], kind="stable")]
    starts = np.flatnonzero(np.r_[True, np.diff(treg[order]) != 0]) if len(order) else np.zeros(0, np.int64)
    ends = np.r_[starts[1:], len(order)].astype(np.int64)
    region = treg[order][starts] if len(order) else np.zeros(0, np.int64)
    # the points inside each region's tetrahedra, by region
    pts = np.flatnonzero(~isv).astype(index_type(len(isv)))
    pts = pts[treg[owner[pts]] >= 0]
    pts = pts[np.argsort(treg[owner[pts]], kind="stable")]
    pkeys = treg[owner[pts]]
    row_of = np.full(len(T), -1, index_type(len(T)))  # a tetrahedron's row in its region
    for s, e in zip(starts, ends):
        row_of[order[s:e]] = np.arange(e - s)
    nfree = np.bincount(np.searchsorted(region, rid[free]), minlength=len(starts))
    return {"free": free, "left": cand & blocked, "order": order, "starts": starts, "ends": ends, "region": region,
            "pts": pts, "pkeys": pkeys, "row_of": row_of, "nfree": nfree, "dims": dims}


def region_input(plan, T, owner, k):
    """Run ``k`` of a pass (:func:`pass_plan`) as a mesh of its own: ``local`` (global point
    indices: its vertices first, then the points inside its tetrahedra), ``tets`` (local
    indices), ``located`` (each inside point's tetrahedron, -1 for vertices) and ``locked``
    (the vertices that are not free, which stay)."""
    rows = plan["order"][plan["starts"][k]:plan["ends"][k]]
    reg = plan["region"][k]
    a, z = np.searchsorted(plan["pkeys"], reg, side="left"), np.searchsorted(plan["pkeys"], reg, side="right")
    inside = plan["pts"][a:z]
    tg = T[rows]
    verts = np.unique(tg)
    local = np.concatenate([verts, inside])  # vertices first (sorted), then the points inside
    tl = np.searchsorted(verts, tg)  # a corner's place among the vertices is its local index
    located = np.full(len(local), -1, np.int64)
    located[len(verts):] = plan["row_of"][owner[inside]]
    return {"local": local, "tets": tl, "located": located, "locked": ~plan["free"][local]}


def region_decimate(inp, shape, values, *, tau, tol_inf=None, quota=None, costs=False, budget=INF, recorded=None):
    """Decimate one region (:func:`region_input`; ``values`` at its ``local`` points) on the
    grid's lattice (exact integer predicates), its free vertices the only ones that move, down
    to ``tau``, by at most ``quota`` vertices and, with a ``budget``, while the squared error of
    its points grows by at most that.  Returns the points it removed, its new tetrahedra, and
    the points inside them with their rows (global indices); with ``costs``, the running maxima
    of its collapse costs in the order made, the squared error they add (:func:`running_sse`)
    and the collapses themselves (the points removed and the vertices they moved onto, local
    indices) first, and that result: the one a run whose quota is all of these collapses gives
    (:func:`cut_quota` then reuses it).  With ``recorded`` (those collapses, the first
    ``quota`` of them), they are replayed, not costed again: the same result as the run."""
    local = inp["local"]
    St = new_mesh_state(np.stack(np.unravel_index(local, shape), axis=1), inp["tets"],
                        np.asarray(values, np.float64), located=inp["located"], key="sse", lazy=False)
    St.lock[inp["locked"]] |= LOCK_ALL
    dec = Decimation(None, None, None, tol_inf=tol_inf, state=St, queue=recorded is None)
    if recorded is not None:
        dec.replay(recorded[0][:quota], recorded[1][:quota])
    else:
        dec.run(0 if quota is None else dec.n_vertices - int(quota), sse_max=dec.sse + budget, key_max=tau)
    if not costs and quota is not None and len(dec.removed()) != quota:
        raise RuntimeError("a region did not repeat its recorded collapses")
    alive_row = np.cumsum(dec.S.alive) - 1
    nonv = np.flatnonzero(~dec.S.isv)
    removed = dec.removed()
    result = local[removed], local[dec.tetrahedra()], local[nonv], alive_row[dec.S.ptet[nonv]]
    if costs:
        keys = dec.S.hkey[removed]
        return ((np.maximum.accumulate(keys) if len(keys) else keys.copy()), running_sse(dec.S.hsse[removed]),
                (removed.astype(np.int32), dec.into().astype(np.int32)), result)
    return result


def cost_caps(plan, surplus, share_cap, times=2):
    """The most collapses each region records for the quota cut: all its free vertices, or
    with ``share_cap`` (the quota passes, no threshold) and a ``surplus`` (None: no count) at
    most ``times`` (an integer) its share of ``surplus`` by free vertices, and 16."""
    nfree = plan["nfree"]
    if not share_cap or surplus is None:
        return nfree
    return np.minimum(nfree, int(times) * -(-surplus * nfree // max(int(nfree.sum()), 1)) + 16)


def record_caps(plan, surplus, kind, limit):
    """``(caps, whole)``: the most collapses each region of a pass of ``kind`` records
    (:func:`cost_caps`), and the most that the pass's cut may need, to which a region is recorded
    again (:func:`limit_of_whole_records`).  The same but in the first quota pass (a count, and no
    ``limit`` derived yet), which records :data:`FIRST_QUOTA_RECORD` times the share."""
    whole = cost_caps(plan, surplus, share_cap=kind != "seams")
    if derives_limit(kind, surplus, limit):
        return cost_caps(plan, surplus, True, times=FIRST_QUOTA_RECORD), whole
    return whole, whole


def derives_limit(kind, surplus, limit):
    """Whether a pass of ``kind`` derives the quota passes' cost limit (:func:`pass_limit`): the
    first quota pass of a count (``surplus`` not None), while none is (``limit`` None)."""
    return kind == "quota" and surplus is not None and limit is None


def short_regions(ends, caps, whole, limit):
    """The regions whose record stopped at its cap (``caps``) short of the ``whole`` one, at or
    below the cost ``limit`` (``ends``: each record's length and last running maximum, None for
    an empty one): past a record's end every cost is at least its last, so the others' longer
    records would add only costs above the limit."""
    return [k for k, ((n, last), c, w) in enumerate(zip(ends, caps, whole))
            if c < w and n == c and (last is None or last <= limit)]


def record_ends(read):
    """Each record's length and last running maximum (None for an empty one), for
    :func:`short_regions`, from ``read()`` (one ``(runmax, sse)`` per region)."""
    return [(len(r), float(r[-1]) if len(r) else None) for r, _ in read()]


def limit_of_whole_records(read, surplus, share, caps, whole, record_again):
    """:func:`quota_limit` of records cut at ``caps`` as of records to ``whole``: the regions that
    :func:`short_regions` names are recorded again by ``record_again(regions)``, after which
    ``read()`` (one ``(runmax, sse)`` per region, in order, each time it is called) yields their
    new records, and the limit is taken again; once at most, since the limit only falls.
    Returns the limit and the regions recorded again."""
    caps, again_all = list(caps), []
    while True:
        limit = quota_limit(read, surplus, share)
        again = short_regions(record_ends(read), caps, whole, limit)
        if not again:
            return limit, again_all
        record_again(again)
        for j in again:
            caps[j] = whole[j]
        again_all += again


def cut_quota(runmax, surplus, sse=None, budget=INF, limit=INF):
    """How many vertices each region removes: the cheapest of the regions' recorded costs
    (their running maxima), ties by region, none above ``limit`` (:func:`quota_limit`),
    ``surplus`` at most (None: no count) and, with a ``budget``, as many as the squared error
    they add (``sse``, :func:`running_sse` of each region) fits in: one threshold across the
    regions, as across the blocks, so each region's count is a prefix of its own sequence.
    Returns the counts and the squared error they add (each region's at its count, summed in
    region order; 0.0 without ``sse``).  The quota job finds the same, to the bit, from the
    regions' records read one at a time
    (:func:`~trivsel.decimation.streamcut.streamed_cut_quota`, which this calls)."""
    errors = sse if sse is not None else [np.zeros(len(r)) for r in runmax]
    counts, spent = streamed_cut_quota(lambda: zip(runmax, errors), surplus, budget if sse is not None else INF,
                                       limit)
    return np.asarray(counts, np.int64), (spent if sse is not None else 0.0)


def quota_limit(read, surplus, share):
    """The cost up to which the quota passes remove vertices, from the first quota pass's
    recorded costs (``read()``: each region's ``(runmax, sse)``, its running maxima, read a
    region at a time): the ``ceil(share * surplus)``-th cheapest of them
    (:func:`~trivsel.decimation.streamcut.streamed_kth_cost`), ``share`` the part of the mesh's
    vertices that its regions free.  Where costs are alike across the grid, that is the cost at
    which the passes together remove the ``surplus``, each from its own grid's free vertices, so
    that no grid takes the count alone; the rest passes take what is left, cheapest first.  Inf
    where the pass recorded fewer (every pass may then take its cheapest)."""
    return streamed_kth_cost(read, int(np.ceil(float(share) * int(surplus))))


def free_share(plan, isv):
    """The part of the mesh's vertices (``isv``) that the regions of a pass (:func:`pass_plan`) free."""
    return float(plan["nfree"].sum()) / max(int(isv.sum()), 1)


def pass_limit(kind, surplus, limit, read, share):
    """``(cut, kept)``: the cost limit of a pass's quota cut (:func:`cut_quota`) and the one the
    passes after it inherit.  With a count (``surplus`` not None) a ``"quota"`` pass cuts at the
    inherited ``limit``, or, while none is (None), derives it from its own recorded costs
    (``read()``: one ``(runmax, sse)`` per region) and its regions' ``share`` of the vertices
    (:func:`quota_limit`, :func:`free_share`); every other pass cuts without one and hands the
    inherited limit on."""
    if derives_limit(kind, surplus, limit):
        limit = quota_limit(read, surplus, share)
    elif kind != "quota" or surplus is None:
        return INF, limit
    return limit, limit


def record_limit(kind, tau, limit):
    """The cost above which a pass's regions stop recording: ``tau`` for a ``"seams"`` pass; for
    a ``"quota"`` pass the passes' cost limit once one of them has derived it (``limit``, not
    None: :func:`pass_limit`), since its cut takes nothing above it; inf otherwise.  A record
    stopped there is the prefix the cut keeps of a longer one, so the pass is the same."""
    if kind == "seams":
        return tau
    return limit if kind == "quota" and limit is not None else INF


def merge_pass(T, owner, isv, plan, results, *, in_place=False):
    """The mesh after a pass: every region's tetrahedra replaced by its new ones
    (:func:`region_decimate`'s result for run ``k`` of ``plan``, the k-th of ``results()``, a
    callable that yields them in order each time it is called: they are read twice, one at a
    time, and never held together).  Returns ``T``, ``owner``, ``isv`` and the number of points
    removed.

    With ``in_place``, the caller gives up ``T`` and ``owner``: the kept rows move up within
    ``T``, a chunk at a time, and the new ones follow them (the result is a view of its first
    rows, where the merged mesh fits), and ``owner`` is rewritten where its type holds the new
    rows.  The same arrays either way, without a second copy of the mesh::

        T   [ k k x k x x k k | ... ]      k kept, x a region's (taken)
        ->  [ k k k k k | new ... ]        the kept rows in order, then each region's new ones
    """
    keep = np.ones(len(T), bool)
    isv = isv.copy()
    removed = base = 0
    for k, (rem, nt, _, _) in enumerate(results()):  # what goes, and how many tetrahedra come
        removed += len(rem)
        isv[rem] = False
        base += len(nt)
        keep[plan["order"][plan["starts"][k]:plan["ends"][k]]] = False
    kept_rows = np.cumsum(keep, dtype=index_type(len(T) + 1)) - 1
    nkeep = int(kept_rows[-1]) + 1 if len(T) else 0
    M = nkeep + base
    owner = owner.astype(index_type(M), copy=not in_place)
    moved = ~isv & (owner >= 0)
    owner[moved] = kept_rows[owner[moved]]  # points of unchanged tetrahedra: their new rows
    del kept_rows, moved
    if in_place and M <= len(T):
        at = 0
        for s in range(0, len(T), PLAN_CHUNK):  # rows only move up, past what is still to be read
            rows = np.flatnonzero(keep[s:s + PLAN_CHUNK]) + s
            T[at:at + len(rows)] = T[rows]
            at += len(rows)
        T2 = T[:M]
    else:
        T2 = np.empty((M, 4), T.dtype)
        np.compress(keep, T, axis=0, out=T2[:nkeep])
    at = nkeep
    for _, nt, nonv, rows in results():  # the new tetrahedra after the kept ones, and their points
        T2[at:at + len(nt)] = nt
        owner[nonv] = at + rows
        at += len(nt)
    return T2, owner, isv, removed


def decimate_in_blocks(volume, block, *, count=None, fraction=None, tol_rms=None, tol_inf=None, threads=1,
                       progress=None):
    """Decimate the grid ``volume`` (a 3-D array) in blocks of ``block`` intervals per axis.

    Stops at ``count`` vertices (or ``fraction`` of the points; above it only where too few
    vertices are free in any region), where the squared error left would take E_RMS above
    ``tol_rms`` (a budget the stages share: the module's docstring), or where no collapse
    keeps every residual within ``tol_inf``.  Returns a dict: ``vertices`` (global point
    indices, C order), ``tets`` (``(M, 4)`` global point indices, positively oriented), ``ptet``
    (for every point, the row of ``tets`` that holds it; -1 for the vertices), ``tau`` (the
    cost threshold) and ``stats`` (counts per pass; ``sse_bound``, the squared error the
    collapses may have added, at most the budget; ``recorded_again``, the blocks whose pass 1
    record was taken again to its end: :func:`short_blocks`).  ``progress(count)`` is called with the vertex
    count after every block and every pass.  ``threads`` processes decimate blocks, and the
    regions of a pass, side by side (forked: the same results as one).  The stages are the
    functions the jobs of ``trivsel blocks --method decimate`` call (:mod:`trivsel.blocks.decimate`),
    so both give the same mesh.
    """
    vol = np.asarray(volume)
    shape = vol.shape
    N = int(np.prod(shape))
    cuts, bounds = block_list(shape, block)
    seam_axes = [c[1:-1] for c in cuts]
    say = progress or (lambda count: None)
    if count is None and fraction is None and tol_rms is None and tol_inf is None:
        raise ValueError("decimate_in_blocks needs a stop: count, fraction, tol_rms or tol_inf")
    target = None
    if count is not None or fraction is not None:
        target = int(count) if count is not None else count_for_fraction(fraction, N)
    budget = sse_budget(tol_rms, N)
    costed = target is not None or budget < INF  # the stages record costs and cut them

    _SHARED.clear()
    _SHARED.update(vol=vol, bounds=bounds, seam_axes=seam_axes, tol_inf=tol_inf, tol_rms=tol_rms,
                   fraction=0.0 if target is None else target / N, floor=RECORD_FLOOR)

    # pass 1: every block's costs, cheapest first, as running maxima, and the squared error they add
    runmax, inner, recorded, sse, short = [], [], [], [], []
    if costed:
        for r, n_inner, seq, e, s in _map(_block_costs, range(len(bounds)), threads):
            runmax.append(r)
            inner.append(n_inner)
            recorded.append(seq)
            sse.append(e)
            short.append(s)

    def record_again(blocks):  # to their end
        _SHARED["floor"] = 0.0
        for i, (r, _, seq, e, _) in zip(blocks, _map(_block_costs, blocks, threads)):
            recorded[i] = seq
            yield r, e

    tau, again = threshold_of_whole_records(runmax, inner, N - sum(inner), aim(target, N, N - sum(inner)), sse,
                                            budget, short, record_again)

    # pass 2: every block to tau (the prefix of its sequence, replayed)
    counts = cut_counts(runmax, tau, inner, N - sum(inner), target) if runmax else None
    spent = sse_at(sse, counts) if counts else 0.0
    _SHARED["tau"] = tau
    _SHARED["recorded"] = [(v[:c], w[:c]) for (v, w), c in zip(recorded, counts)] if counts else None
    del recorded

    def meshes():
        left = N
        for m in _map(_block_mesh, range(len(bounds)), threads):
            left -= len(m[1])
            say(left)
            yield m

    T, owner, isv = assemble(N, meshes(), counts, [tuple(lo) for lo, _ in bounds])
    _SHARED.pop("recorded")
    stats = {"blocks": len(bounds), "tau": float(tau), "after_blocks": int(isv.sum()), "seam_passes": [],
             "recorded_again": len(again)}

    # the seams, region by region (every vertex a candidate, down to tau); then the quota
    # passes: the vertices over the target, or the budget left, the cheapest across the regions,
    # with a count none above one cost (quota_limit, from the first of them); then what they left
    cand = isv.copy()
    limit = None  # the quota passes' cost limit, once the first of them has derived it
    for kind, offset in passes(int(block)):
        if kind == "quota" and "after_seams" not in stats:
            stats["after_seams"] = int(isv.sum())
        if kind != "seams" and not costed:
            break
        c = cand if kind == "seams" else isv.copy()
        surplus = None if target is None else int(isv.sum()) - target  # never below the count
        if not pass_runs(c, surplus, budget - spent, kind):
            continue
        T, owner, isv, left, st = _region_pass(shape, T, owner, isv, c, offset, REGION * int(block),
                                               record_limit(kind, tau, limit), surplus, tol_inf, threads,
                                               costed=costed, budget=budget - spent, kind=kind, limit=limit)
        limit = st["limit_after"]
        spent += st["sse"]
        if kind == "seams":
            cand = left
        stats["seam_passes"].append(st)
        say(int(isv.sum()))
    stats.setdefault("after_seams", int(isv.sum()))
    stats["vertices"] = int(isv.sum())
    stats["sse_bound"] = spent
    owner[isv] = -1
    _SHARED.clear()
    return {"vertices": np.flatnonzero(isv), "tets": T, "ptet": owner, "tau": float(tau), "stats": stats}


#: What the workers of a run read (set before they fork, so that nothing large is sent to them)
_SHARED = {}


def _map(fn, items, threads):
    """``fn`` over ``items``, in order: here, or in ``threads`` forked processes that read
    :data:`_SHARED` as it was when they started."""
    items = list(items)
    if threads <= 1 or len(items) <= 1:
        yield from map(fn, items)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=min(threads, len(items)),
                             mp_context=multiprocessing.get_context("fork")) as pool:
        yield from pool.map(fn, items)


def _block_values(i):
    lo, hi = _SHARED["bounds"][i]
    return _SHARED["vol"][lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1], lo


def _block_costs(i):
    values, lo = _block_values(i)
    return block_costs(values, lo, _SHARED["vol"].shape, _SHARED["seam_axes"], fraction=_SHARED["fraction"],
                       tol_inf=_SHARED["tol_inf"], tol_rms=_SHARED["tol_rms"], floor=_SHARED["floor"])


def _block_mesh(i):
    values, lo = _block_values(i)
    rec = _SHARED["recorded"]
    return block_mesh(values, lo, _SHARED["vol"].shape, _SHARED["seam_axes"], fraction=_SHARED["fraction"],
                      tau=_SHARED["tau"], tol_inf=_SHARED["tol_inf"], recorded=None if rec is None else rec[i])


def pass_runs(cand, surplus, left, kind="seams"):
    """Whether a pass (of ``kind``) after the blocks runs: some vertex is a candidate, a count
    (``surplus`` vertices over it; None: no count) is not yet met, squared error is ``left``
    to spend and, for a ``"rest"`` pass, there is a count."""
    return (bool(cand.any()) and (surplus is None or surplus > 0) and left >= 0
            and (kind != "rest" or surplus is not None))


def _region_pass(shape, T, owner, isv, cand, offset, size, tau, surplus, tol_inf, threads=1, *, costed,
                 budget=INF, kind="seams", limit=None):
    """One pass over the regions of edge ``size`` cut at ``offset + k size``
    (:func:`pass_plan`), each decimated down to ``tau`` and, when ``costed`` (a ``surplus``
    vertices over the count, or a ``budget`` of squared error), the regions together by at
    most that many vertices and that error, the cheapest (:func:`cut_quota`): returns the new
    mesh, owners, vertex flags, the candidates left (not free in any region of this grid) and
    the pass's counts (``sse``: the squared error it may have added; ``limit``: the cost above
    which its quota took nothing, and ``limit_after``: the quota passes' limit after it, both
    :func:`pass_limit` of the pass ``kind`` and the inherited ``limit``)."""
    plan = pass_plan(shape, T, owner, isv, cand, offset, size)
    runs = range(len(plan["starts"]))
    _SHARED["region"] = sh = dict(plan=plan, T=T, owner=owner, tau=tau, tol_inf=tol_inf, quota=None, caps=None,
                                  budget=budget, recorded={})
    whole = {}  # the regions whose quota is every collapse they recorded: that run's result
    spent, cut, again = 0.0, INF, []
    if costed:
        sh["caps"], whole_caps = record_caps(plan, surplus, kind, limit)
        recorded = list(_map(_region_costs, runs, threads))

        def records():  # each region's running maxima and squared error, in order
            return ((r, e) for r, e, _, _ in recorded)

        if derives_limit(kind, surplus, limit):  # from records as long as the later passes' (whole_caps)
            def record_again(regions):
                sh["caps"] = whole_caps
                for k, rec in zip(regions, _map(_region_costs, regions, threads)):
                    recorded[k] = rec

            limit, again = limit_of_whole_records(records, surplus, free_share(plan, isv), sh["caps"], whole_caps,
                                                  record_again)
        cut, limit = pass_limit(kind, surplus, limit, records, free_share(plan, isv))
        sh["quota"], spent = cut_quota([r for r, _ in records()], surplus, [e for _, e in records()], budget, cut)
        whole = {k: res for k, (r, _, _, res) in enumerate(recorded) if sh["quota"][k] == len(r)}
        sh["recorded"] = {k: seq for k, (_, _, seq, _) in enumerate(recorded) if k not in whole}
        del recorded
    todo = [k for k in runs if k not in whole]
    done = dict(zip(todo, _map(_region_apply, todo, threads)))
    T2, owner2, isv2, removed = merge_pass(T, owner, isv, plan,
                                           lambda: (whole[k] if k in whole else done[k] for k in runs))
    del _SHARED["region"]
    return T2, owner2, isv2, plan["left"], {"offset": offset, "regions": len(runs), "free": int(plan["free"].sum()),
                                            "removed": removed, "not_free": int(plan["left"].sum()), "sse": spent,
                                            "limit": cut, "limit_after": limit, "recorded_again": len(again)}


def _region(k):
    sh = _SHARED["region"]
    inp = region_input(sh["plan"], sh["T"], sh["owner"], k)
    return sh, inp, _SHARED["vol"].reshape(-1)[inp["local"]]


def _region_costs(k):
    sh, inp, values = _region(k)
    return region_decimate(inp, _SHARED["vol"].shape, values, tau=sh["tau"], tol_inf=sh["tol_inf"],
                           quota=sh["caps"][k], costs=True, budget=sh["budget"])


def _region_apply(k):
    sh, inp, values = _region(k)
    return region_decimate(inp, _SHARED["vol"].shape, values, tau=sh["tau"], tol_inf=sh["tol_inf"],
                           quota=None if sh["quota"] is None else sh["quota"][k],
                           recorded=sh["recorded"].get(k))


def stop_reason(vertices, target, tol_inf, block, tol_rms=None):
    """Why a run in blocks stopped with ``vertices`` vertices (asked for ``target``, or None)."""
    if target is not None and vertices <= target:
        return "the count was reached"
    if tol_rms is not None:
        return "the next collapses would raise E_RMS above tol_rms"
    if tol_inf is not None:
        return "no collapse was left that keeps every residual within tol_inf"
    # the tetrahedra grew as large as the regions: few of their vertices were free in any
    return (f"no more vertices were free in the regions of blocks of {block}: a larger block (or one piece) "
            "reaches the count")


def quality_note(n_points, target, block):
    """What a run in blocks of ``block`` intervals to ``target`` of ``n_points`` points (None: no
    count) should tell its user: where a count's run in blocks was measured to lose against one
    piece (blocks under :data:`FAITHFUL_BLOCK`, or fewer than :data:`FAITHFUL_FRACTION` of the
    points: the blocks cannot come near the count, and the seam passes reach it before they
    have freed every seam), a one-line note; None elsewhere."""
    if target is None or (int(block) >= FAITHFUL_BLOCK and target >= FAITHFUL_FRACTION * n_points):
        return None
    return (f"decimate in blocks of {int(block)} to {100 * target / n_points:.3g} % of the points: below "
            f"{100 * FAITHFUL_FRACTION:g} % or in blocks under {FAITHFUL_BLOCK}, runs in blocks were measured above "
            f"one piece's E_RMS (docs/methods.md); use larger blocks, or one piece where it fits")


def point_weights(shape, tets, ptet, values=None):
    """For every point of the grid ``shape``, the 4 vertices of the tetrahedron that holds it
    (``tets[ptet[p]]``) and its barycentric weights there, from integer determinants (a
    vertex, ``ptet`` -1: itself with weight 1), as :meth:`Decimation.point_weights` gives them;
    with ``values``, also the interpolant there (:func:`point_weights_of`)."""
    return point_weights_of(shape, tets, ptet, np.arange(int(np.prod(shape)), dtype=np.int64), values)


def point_weights_of(shape, tets, ptet, points, values=None):
    """:func:`point_weights` of the grid points ``points`` only (global indices), so that a
    caller can go through the grid in chunks: the integer weights of
    :func:`~trivsel.decimation.lattice_weights`, and with ``values`` (the grid's, flat) also
    the interpolant there as the collapse kernel computes it
    (:func:`~trivsel.decimation.lattice_interpolant`), so that a residual the kernel kept
    within an E_inf tolerance is the same number here, to the bit.
    """
    points = np.asarray(points, np.int64)
    return weights_in(shape, tets, np.asarray(ptet)[points], points,
                      None if values is None else (lambda p: np.asarray(values)[p]))


def weights_in(shape, tets, rows, points, value_of=None):
    """:func:`point_weights_of` with each point's tetrahedron given (``rows``: a row of
    ``tets``, or -1 for a vertex) and the values, where asked for, as a function of point
    indices (``value_of``), so that a caller needs neither over the whole grid."""
    points = np.asarray(points, np.int64)
    rows = np.asarray(rows)
    verts = np.repeat(points[:, None], 4, axis=1)
    w = np.zeros((len(points), 4))
    w[:, 0] = 1.0
    value = None if value_of is None else np.asarray(value_of(points)).astype(np.float64)
    inside = np.flatnonzero(rows >= 0)
    for part in np.array_split(inside, max(1, len(inside) // 2**20)):  # bounded temporaries
        corners = tets[rows[part]]
        lam = lattice_weights(_grid_coordinates(points[part], shape),
                              _grid_coordinates(corners.astype(np.int64, copy=False), shape))
        verts[part] = corners
        w[part] = lam / lam.sum(axis=1, keepdims=True)
        if value is not None:
            value[part] = lattice_interpolant(lam, value_of(corners))
    return (verts, w) if value_of is None else (verts, w, value)


#: Rings of tetrahedra around a tile whose vertices its least-squares fit solves for beside
#: its own (:func:`tile_fit`): the difference to the whole mesh's fit falls by several times a
#: ring, and three make it vanish (``docs/notes/2026-12-07-tile-fit.md``).
FIT_RINGS = 3
#: The least margin, in grid intervals, by which a tile's solve reaches past the tile (half the
#: tile's size where that is more): it bounds the solve where the rings' tetrahedra are large.
FIT_MARGIN = 16


def tile_of(ijk, cuts):
    """The tile (block, C order) of each grid point (``ijk``: three int64 arrays): along each
    axis the block whose cuts enclose it, a point on a cut in the block above it (the last
    block takes the last cut).  Every point has exactly one tile."""
    t = np.zeros(len(ijk[0]), index_type(np.prod([len(c) - 1 for c in cuts])))
    for a in range(3):
        c = np.asarray(cuts[a], np.int64)
        t *= len(c) - 1
        t += np.clip(np.searchsorted(c, ijk[a], side="right") - 1, 0, len(c) - 2).astype(t.dtype)
    return t


def tile_box(shape, cuts, t):
    """The grid points of tile ``t`` (:func:`tile_of`) as the box ``lo`` to ``hi`` (both
    included, int64 arrays): along each axis from its lower cut to the point before its upper
    cut, the last tile to the last cut."""
    at = np.unravel_index(int(t), [len(c) - 1 for c in cuts])
    lo = np.array([int(cuts[a][i]) for a, i in enumerate(at)], np.int64)
    hi = np.array([int(cuts[a][i + 1]) - (i + 2 < len(cuts[a])) for a, i in enumerate(at)], np.int64)
    return lo, np.minimum(hi, np.asarray(shape, np.int64) - 1)


def fit_reach(shape, cuts, t):
    """The box (``lo``, ``hi``, both included) that bounds tile ``t``'s least-squares solve
    (:func:`tile_fit`): the block widened by half its size on each side, at least
    :data:`FIT_MARGIN` intervals, within the grid."""
    at = np.unravel_index(int(t), [len(c) - 1 for c in cuts])
    half = np.array([max((int(cuts[a][i + 1]) - int(cuts[a][i])) // 2, FIT_MARGIN) for a, i in enumerate(at)])
    lo = np.maximum(np.array([int(cuts[a][i]) for a, i in enumerate(at)]) - half, 0)
    hi = np.minimum(np.array([int(cuts[a][i + 1]) for a, i in enumerate(at)]) + half, np.asarray(shape) - 1)
    return lo.astype(np.int64), hi.astype(np.int64)


def tet_extent(shape, tets, chunk=1 << 20):
    """The longest extent of a tetrahedron of ``tets`` (global point indices) along a grid
    axis, in intervals: a tetrahedron with a corner in a box has its lowest corner in the box
    widened by this much below, and all its corners in the box widened by this much."""
    ext = 0
    for s in range(0, len(tets), chunk):
        bmin, bmax = tet_boxes(shape, tets[s:s + chunk])
        ext = max(ext, int((bmax - bmin).max()))
    return ext


def _tile_span(shape, cuts, tets):
    """For each tetrahedron, along each axis, the first and last tile its corners' box meets:
    ``(lo, hi)``, two (k, 3) arrays."""
    bmin, bmax = tet_boxes(shape, tets)
    lo, hi = [], []
    for a in range(3):
        c = np.asarray(cuts[a], np.int64)
        lo.append(np.clip(np.searchsorted(c, bmin[:, a], side="right") - 1, 0, len(c) - 2))
        hi.append(np.clip(np.searchsorted(c, bmax[:, a], side="right") - 1, 0, len(c) - 2))
    return np.stack(lo, axis=1), np.stack(hi, axis=1)


def mesh_tiles(shape, cuts, tets, ptet, chunk=1 << 20):
    """A mesh kept by tile, each tile in turn (a generator, in tile order):
    ``(tets, rows, owner)``: the tetrahedra whose corners' box meets the tile's box
    (:func:`tile_box`; a large tetrahedron is kept by every tile it meets), in the order of
    ``tets``, their rows in ``tets``, and ``ptet`` over the tile's box (C order).  Every
    point is in exactly one tile, and so is every tetrahedron's lowest corner."""
    counts = [len(c) - 1 for c in cuts]
    n = int(np.prod(counts))
    tile_ids, row_ids = [], []
    for s in range(0, len(tets), chunk):  # (tile, row) for every tile a tetrahedron meets
        lo, hi = _tile_span(shape, cuts, tets[s:s + chunk])
        width = hi - lo + 1
        k = width.prod(axis=1)
        row = np.repeat(np.arange(s, s + len(lo), dtype=np.int64), k)
        first = np.repeat(np.cumsum(k) - k, k)
        j = np.arange(len(row), dtype=np.int64) - first  # the j-th tile of its tetrahedron's span
        w, l0 = width[row - s], lo[row - s]
        iz = j % w[:, 2]
        iy = (j // w[:, 2]) % w[:, 1]
        ix = j // (w[:, 2] * w[:, 1])
        tile_ids.append((((l0[:, 0] + ix) * counts[1] + l0[:, 1] + iy) * counts[2] + l0[:, 2] + iz).astype(
            index_type(n)))
        row_ids.append(row.astype(index_type(len(tets))))
    tile = np.concatenate(tile_ids) if tile_ids else np.zeros(0, index_type(n))
    rows = np.concatenate(row_ids) if row_ids else np.zeros(0, index_type(len(tets)))
    del tile_ids, row_ids
    order = np.argsort(tile, kind="stable")
    bounds = np.searchsorted(tile[order], np.arange(n + 1))
    del tile
    grid = np.asarray(ptet).reshape(tuple(shape))
    for t in range(n):
        lo, hi = tile_box(shape, cuts, t)
        r = rows[order[bounds[t]:bounds[t + 1]]]
        yield tets[r], r, grid[tuple(slice(int(a), int(b) + 1) for a, b in zip(lo, hi))].ravel()


def tiles_meeting(cuts, lo, hi):
    """The tiles whose boxes (:func:`tile_box`) meet the box ``lo`` to ``hi`` (both
    included), in tile order."""
    along = []
    for a, c in enumerate(cuts):
        c = np.asarray(c, np.int64)
        tlo, thi = c[:-1], np.append(c[1:-1] - 1, c[-1])
        along.append(np.flatnonzero((tlo <= hi[a]) & (thi >= lo[a])))
    n = [len(c) - 1 for c in cuts]
    return [int((i * n[1] + j) * n[2] + k) for i in along[0] for j in along[1] for k in along[2]]


def tet_boxes(shape, tets):
    """The box of each tetrahedron's corners (global point indices): ``(lo, hi)``, two (k, 3)
    int64 arrays of grid coordinates."""
    x = np.stack(_grid_coordinates(np.asarray(tets, np.int64).ravel(), shape), axis=1).reshape(-1, 4, 3)
    return x.min(axis=1), x.max(axis=1)


def mesh_meeting(shape, lo, hi, tiles):
    """The part of a mesh kept by tile (:func:`mesh_tiles`) that meets the box ``lo`` to
    ``hi`` (both included), for a job that holds one tile's surroundings, not the whole grid.

    ``tiles`` are the tiles that meet the box (:func:`tiles_meeting`), each ``(tets, rows,
    owner, tlo, thi, boxes)``: what :func:`mesh_tiles` gives for it, its box (:func:`tile_box`)
    and its tetrahedra's boxes (:func:`tet_boxes`).  Returns ``(tets, rows, ptet, extent)``:
    the tetrahedra whose corners' box meets the box (global point indices, in the order of
    their rows), their rows in the whole mesh, each of the box's points' tetrahedron (C order
    of the box; a row of the returned ``tets``, -1 for a vertex), and the longest extent of
    those tetrahedra along an axis (:func:`tet_extent`).  Every tetrahedron that holds a point
    of the box or has a corner in it is there."""
    lo, hi = np.asarray(lo, np.int64), np.asarray(hi, np.int64)
    dims = hi - lo + 1
    ptet = np.full(int(np.prod(dims)), -2, np.int64)
    keep_t, keep_r, ext = [], [], 0
    for tets, rows, owner, tlo, thi, (bmin, bmax) in tiles:
        meets = np.all((bmin <= hi) & (bmax >= lo), axis=1)
        keep_t.append(np.asarray(tets)[meets])
        keep_r.append(np.asarray(rows, np.int64)[meets])
        if meets.any():
            ext = max(ext, int((bmax[meets] - bmin[meets]).max()))
        a0, a1 = np.maximum(tlo, lo), np.minimum(thi, hi)  # the tile's points in the box
        if np.any(a0 > a1):
            continue
        src = np.asarray(owner).reshape(tuple(np.asarray(thi) - tlo + 1))
        sub = src[tuple(slice(int(x - t), int(y - t) + 1) for x, y, t in zip(a0, a1, tlo))]
        ptet.reshape(tuple(dims))[tuple(slice(int(x - o), int(y - o) + 1) for x, y, o in zip(a0, a1, lo))] = sub
    rows = np.concatenate(keep_r) if keep_r else np.zeros(0, np.int64)
    rows, first = np.unique(rows, return_index=True)  # a tetrahedron kept by several tiles once
    tets = (np.concatenate(keep_t) if keep_t else np.zeros((0, 4), np.int64))[first]
    inside = ptet >= 0  # a row of the whole mesh, to its place among those kept
    ptet[inside] = np.searchsorted(rows, ptet[inside])
    return tets, rows, ptet, ext


class _TileSolver:
    """The least-squares solve of one tile at a time (:func:`tile_fit`) over a mesh given by
    its tetrahedra (global point indices), its vertices (ascending) with their data values,
    and lookups by global point index: ``col_of`` a vertex's place among the vertices (-1
    for another point), ``ptet_of`` a point's tetrahedron (-1 for a vertex) and ``f_of`` its
    data value.  The lookups are asked only for points in the box the solve may reach
    (:func:`fit_reach`) and, ``col_of``, for the corners of the tetrahedra."""

    def __init__(self, shape, cuts, tets, vertices, vertex_values, col_of, ptet_of, f_of, ext=None, columns=None):
        self.shape, self.cuts, self.tets = shape, cuts, tets
        self.columns = columns  # the corners' places among the vertices, if known: no lookups for them
        self.vertices, self.fv = vertices, np.asarray(vertex_values, np.float64)
        self.col_of, self.ptet_of, self.f_of = col_of, ptet_of, f_of
        self.vijk = np.stack(_grid_coordinates(vertices, shape), axis=1)
        # the tetrahedra by their lowest corner (a point index, so C order: x first), and the
        # longest extent of a tetrahedron along an axis: a tetrahedron with a corner in a box
        # has its lowest corner in the box widened by that extent below it
        lowest = tets.min(axis=1)
        self.by_lowest = np.argsort(lowest, kind="stable").astype(index_type(len(tets)))
        self.lowest = lowest[self.by_lowest]
        self.ext = tet_extent(shape, tets) if ext is None else int(ext)
        self.touched = np.zeros(len(tets), bool)  # both reset after each tile
        self.unknown = np.zeros(len(vertices), bool)
        self.loc = np.full(len(vertices), -1, np.int64)

    def corner_columns(self, rows):
        """The places among the vertices of the corners of the tetrahedra ``rows``, (k, 4) int64."""
        if self.columns is not None:
            return np.asarray(self.columns[rows], np.int64)
        return np.asarray(self.col_of(self.tets[rows]), np.int64).reshape(-1, 4)

    def around(self, lo, hi):
        """The tetrahedra with a corner in the box [lo, hi], and maybe some more."""
        shape, yz = self.shape, int(self.shape[1]) * int(self.shape[2])
        lo = np.maximum(lo - self.ext, 0)
        a, b = np.searchsorted(self.lowest, np.array([lo[0] * yz, (hi[0] + 1) * yz], self.lowest.dtype))
        _, y, z = _grid_coordinates(self.lowest[a:b], shape)
        return self.by_lowest[a:b][(y >= lo[1]) & (y <= hi[1]) & (z >= lo[2]) & (z <= hi[2])]

    def solve(self, b, own, rings):
        """The fitted values of the vertices ``own`` (places among the vertices: tile ``b``'s)."""
        import scipy.sparse as sp

        from ..fitting import solve_normal_equations

        shape, tets, vijk, unknown, touched, loc = self.shape, self.tets, self.vijk, self.unknown, self.touched, \
            self.loc
        unknown[own] = True
        u = own
        cap_lo, cap_hi = fit_reach(shape, self.cuts, b)
        rows = np.zeros(0, np.int64)  # the tetrahedra looked at so far, their corners' columns
        ct = np.zeros((0, 4), np.int64)
        for ring in range(rings + 1):
            box = vijk[u].min(axis=0), vijk[u].max(axis=0)
            more = self.around(*box)  # the window grows with the rings: only its new tetrahedra are read
            touched[rows] = True
            more = more[~touched[more]]
            touched[rows] = False
            rows = np.concatenate([rows, more])
            ct = np.concatenate([ct, self.corner_columns(more)])
            hit = unknown[ct].any(axis=1)
            if ring == rings:
                rows = rows[hit]
                break
            new = np.unique(ct[hit][~unknown[ct[hit]]])
            new = new[np.all((vijk[new] >= cap_lo) & (vijk[new] <= cap_hi), axis=1)]
            unknown[new] = True
            u = np.concatenate([u, new])
        del ct
        u = np.sort(u)
        touched[rows] = True
        # the grid points in those tetrahedra: within their corners' box
        ijk = _grid_coordinates(tets[rows].ravel().astype(np.int64), shape)
        box = [np.arange(max(int(x.min()), int(cap_lo[a])), min(int(x.max()), int(cap_hi[a])) + 1)
               for a, x in enumerate(ijk)]
        del ijk
        pts = ((box[0][:, None, None] * shape[1] + box[1][None, :, None]) * shape[2]
               + box[2][None, None, :]).ravel()
        owner = np.asarray(self.ptet_of(pts), np.int64)
        inside = owner >= 0
        keep = np.zeros(len(pts), bool)
        keep[inside] = touched[owner[inside]]
        vcol = np.asarray(self.col_of(pts[~inside]), np.int64)  # the vertices among the points
        keep[~inside] = unknown[vcol]
        vcol = vcol[keep[~inside]]
        pts, owner = pts[keep], owner[keep]
        touched[rows] = False
        loc[u] = np.arange(len(u))
        _, w = weights_in(shape, tets, owner, pts)
        cv = np.empty((len(pts), 4), np.int64)  # the columns of each point's weights
        inside = owner >= 0
        cv[inside] = self.corner_columns(owner[inside])
        cv[~inside] = vcol[:, None]
        lc = loc[cv]
        fixed = (lc < 0) & (w > 0)
        rhs = self.f_of(pts) - np.einsum("ij,ij->i", np.where(fixed, w, 0.0), self.fv[cv])
        use = (lc >= 0) & (w > 0)
        r = np.broadcast_to(np.arange(len(pts))[:, None], lc.shape)
        A = sp.csr_matrix((w[use], (r[use], lc[use])), shape=(len(pts), len(u)))
        x, _ = solve_normal_equations((A.T @ A).tocsr(), A.T @ rhs, self.fv[u])
        x = x[loc[own]]
        unknown[u] = False
        loc[u] = -1
        return x


def _sorted_lookup(keys, missing=-1):
    """A lookup of the places of point indices among ``keys`` (ascending): ``missing`` for
    those not among them."""
    def at(p):
        p = np.asarray(p, np.int64)
        i = np.minimum(np.searchsorted(keys, p), max(len(keys) - 1, 0))
        found = keys[i] == p if len(keys) else np.zeros(p.shape, bool)
        return np.where(found, i, missing)

    return at


def fit_tile(shape, cuts, t, tets, ptet, lo, hi, values, vertices, vertex_values, *, rings=FIT_RINGS, extent=None,
             columns=None):
    """Tile ``t``'s least-squares vertex values as :func:`tile_fit` solves them, from its
    surroundings alone: the tetrahedra that meet the box its solve may reach
    (:func:`fit_reach`; ``tets``, global point indices), each point's tetrahedron (``ptet``,
    a row of ``tets``, -1 for a vertex) and the data ``values`` over that box ``lo`` to
    ``hi``, and the vertices of ``tets`` (ascending) with their data values; ``extent``, the
    longest extent of ``tets`` along an axis, if known (:func:`mesh_meeting`), and the places
    of their corners among ``vertices`` (``columns``, the shape of ``tets``; the inverse of
    :func:`numpy.unique`), if known.  The same values as the whole mesh's :func:`tile_fit`, to
    the bit.  Returns the tile's vertices (ascending) and their fitted values."""
    lo, hi = np.asarray(lo, np.int64), np.asarray(hi, np.int64)
    dims = hi - lo + 1
    vertices = np.asarray(vertices, np.int64)

    def in_box(p):
        i, j, k = _grid_coordinates(np.asarray(p, np.int64), shape)
        return ((i - lo[0]) * dims[1] + j - lo[1]) * dims[2] + k - lo[2]

    values = np.asarray(values, np.float64).reshape(-1)
    solver = _TileSolver(shape, cuts, tets, vertices, vertex_values, _sorted_lookup(vertices),
                         lambda p: ptet[in_box(p)], lambda p: values[in_box(p)], extent, columns)
    own = np.flatnonzero(tile_of(tuple(solver.vijk.T), cuts) == t)
    if len(own) == 0:
        return vertices[own], np.zeros(0)
    return vertices[own], solver.solve(t, own, rings)


def tile_fit(shape, cuts, tets, ptet, vertices, values, *, rings=FIT_RINGS, tiles=None):
    """Least-squares vertex values (section 5's eq. 19 minimised over the vertex values, as
    :func:`trivsel.fitting.fit_vertex_values` does over the whole mesh), solved tile by tile
    so that no solve holds more than a tile and its surroundings.

    A tile is a block of ``cuts`` (:func:`tile_of`).  Its unknowns are its own vertices and
    those of ``rings`` rings of tetrahedra around them; its equations are the grid points in
    the tetrahedra that have an unknown vertex, and the unknown vertices themselves; the
    vertices beyond the rings keep their data values there.  No solve reaches past the tile
    widened by half its size on each side (at least :data:`FIT_MARGIN` intervals): beyond
    that, vertices stay fixed and points give no equation, which bounds a tile's solve where
    the tetrahedra are large.  Each tile keeps the values of its own vertices only, so every
    vertex has one value, and neighbouring tiles agree on the seams by construction.  The
    rings make the difference to the whole mesh's fit vanish: the influence of a fixed value
    decays by several times each ring (:data:`FIT_RINGS`).

    Parameters
    ----------
    shape : tuple of 3 int
        The grid.
    cuts : 3 sequences of int
        The blocks' cuts along each axis (:func:`block_cuts`).
    tets : (M, 4) int
        The mesh, over global point indices (every corner a vertex).
    ptet : (N,) int
        The tetrahedron holding each point (:func:`point_weights`), -1 for the vertices.
    vertices : (m,) int
        The mesh's vertices, ascending.
    values : (N,) float
        The grid's values, flat.
    rings : int
        Rings of tetrahedra around a tile whose vertices are solved for with it.
    tiles : iterable of int, optional
        The tiles to solve (all by default).  :func:`fit_tile` solves one from its
        surroundings alone, to the same values.

    Returns
    -------
    (m,) float
        The fitted values at ``vertices`` (NaN at those of the tiles not solved).
    """
    from ..fitting import column_map

    f = np.asarray(values, np.float64).reshape(-1)
    vertices = np.asarray(vertices, np.int64)
    m = len(vertices)
    col = column_map(f.shape[0], vertices)
    counts = [len(c) - 1 for c in cuts]
    solver = _TileSolver(shape, cuts, tets, vertices, f[vertices], col.__getitem__, ptet.__getitem__, f.__getitem__)
    vt = tile_of(tuple(solver.vijk.T), cuts)
    vorder = np.argsort(vt, kind="stable")
    vbounds = np.searchsorted(vt[vorder], np.arange(int(np.prod(counts)) + 1))
    del vt
    fitted = np.full(m, np.nan)
    for b in (range(int(np.prod(counts))) if tiles is None else tiles):
        own = vorder[vbounds[b]:vbounds[b + 1]]
        if len(own):
            fitted[own] = solver.solve(b, own, rings)
    return fitted


def _grid_coordinates(p, shape):
    """The grid coordinates (three int64 arrays) of the C-order point indices ``p``."""
    yz = int(shape[1]) * int(shape[2])
    i, r = np.divmod(p, yz)
    j, k = np.divmod(r, int(shape[2]))
    return i, j, k


def reduce_in_blocks(data, target, *, block, tol_rms=None, tol_inf=None, values=("data",), interior=None,
                     threads=1, progress=None, t_start=None):
    """The whole run of ``method="decimate"`` with ``block`` for :func:`trivsel.reduce`: grid
    data decimated by :func:`decimate_in_blocks` to ``target`` points (None: no count), within
    ``tol_rms`` and ``tol_inf``.
    Returns ``(snapshots, selected, stats, seconds)`` as
    :func:`trivsel.decimation.reduce_by_collapse` does, with one snapshot."""
    import time

    from ..norms import error_norms
    from ..result import Snapshot

    t_start = time.perf_counter() if t_start is None else t_start
    N = data.n_points
    interior = data.interior_mask() if interior is None else interior
    vol = np.asarray(data.values, np.float64).reshape(data.shape)

    def say(count):
        if progress is not None:
            progress(count, target or 0, float("nan"), float("nan"), time.perf_counter() - t_start)

    say(N)
    out = decimate_in_blocks(vol, block, count=target, tol_rms=tol_rms, tol_inf=tol_inf, threads=threads,
                             progress=say)
    te = time.perf_counter()
    f = vol.reshape(-1)
    verts, w, value = point_weights(data.shape, out["tets"], out["ptet"], f)
    r = f - value  # as the kernels computed the residuals they kept within tol_inf
    del value
    fit = None
    if "fit" in values:  # tile by tile, as the last jobs of ``trivsel blocks`` fit
        from ..fitting import column_map

        fitted = tile_fit(data.shape, block_list(data.shape, block)[0], out["tets"], out["ptet"], out["vertices"], f)
        fr = f - np.einsum("ij,ij->i", w, fitted[column_map(N, out["vertices"])[verts]])
        fit = {"vertices": out["vertices"], "values": fitted, "residuals": fr, "errors": error_norms(fr, interior)}
    del verts, w
    m = len(out["vertices"])
    shot = Snapshot(fraction=m / N, n_selected=m, selected=out["vertices"], tets=out["tets"], residuals=r,
                    errors=error_norms(r, interior), seconds=time.perf_counter() - t_start, fit=fit)
    if progress is not None:
        progress(m, target or m, shot.errors["E_rms"], shot.errors["E_inf"], time.perf_counter() - t_start)
    st = out["stats"]
    stats = {"collapses": N - m, "tets": int(len(out["tets"])),
             "stopped": stop_reason(m, target, tol_inf, block, tol_rms), "blocks": st["blocks"], "cost_threshold": st["tau"], "after_blocks": st["after_blocks"],
             "after_regions": st["after_seams"]}
    return [shot], out["vertices"], stats, time.perf_counter() - te
