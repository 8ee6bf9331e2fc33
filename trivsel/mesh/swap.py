"""Data-dependent swapping (section 4, steps i-iv; Definition 3) and its memory of evaluations.

After an insertion, :func:`swap` looks at the set O of the new tets and their
face neighbours.  Each round evaluates every flip configuration found in O
(:mod:`trivsel.mesh.flips`: 2-3 over each interior face, 3-2 around each
degree-3 edge, 4-4 around each degree-4 edge with both other diagonals, and
optionally the boundary 2-2 flip) under the swap criterion
(:mod:`trivsel.mesh.criteria`), applies the best improving one, adds the new
tets and their neighbours to O, and repeats until nothing improves::

    insert p -> O = new tets + neighbours
         |
         v
    round: evaluate every configuration of O --(none improves)--> done
         |                         ^
         v                         |
    apply the best flip, O += its tets and their neighbours

Memory of evaluations.  O only grows, so without a memory every round would
evaluate every unchanged configuration again.  A configuration's gain depends
only on its old tets and the new diagonal, and a tet's points never change while
it lives (``S.tver`` counts the reuses of a slot), so the key below identifies
it exactly.  Five words, injective for point ids below 2^30 (the int32 pool
bounds N far lower) and tet ids and versions below 2^31::

    key = (kind << 60 | (d0 + 1) << 30 | (d1 + 1),  ver0 << 32 | (id0 + 1),  ...,  ver3 << 32 | (id3 + 1))
           kind: 0 = 2-3, 1 = 3-2, 2 = 4-4 with new diagonal d0 < d1, 3 = boundary 2-2 (d = -1);
           tets sorted by id, 0 padded

The memory lasts the whole run (``swap_memory="run"``, the default: the fixed
table ``S.mkey``/``S.mval``, where a key looks at ``_RUN_PROBES`` slots and, if
none is free or its own, overwrites one) or one swap call (``"call"``: a table
that grows and never forgets).  Greedy's insertions are scattered, and most
configurations around a new point were already evaluated when their tets were
made.  A hit returns the value stored.  Under the RMS and max criteria that is
what a new evaluation computes, bit for bit; under SSE ``before`` sums the
residuals stored per point, and a point on a face shared with a tet outside the
configuration keeps the residual its owning tet computed, so a remembered sum
may differ from a new one in the last bits: decisions differ only between gains
equal up to rounding.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .criteria import _cannot_beat, _evaluate_at
from .flips import FLIP22, FLIP23, FLIP32, FLIP44, _config22_at, _config23_at, _edge_ring, quads32, quads44
from .geometry import EDGES, _positive_at
from .state import C_ERROR, C_EVALS, C_FLIP22, C_FLIP23, C_MEMHITS, C_OSTAMP, C_ROUNDCAP
from .storage import _copy1, _copy2, _replace

_KEYLEN = 5  # words of a configuration's key
_CACHE_MAX = 1 << 18  # entries of a call's table; a larger swap (the global pass) evaluates without caching
_RUN_PROBES = 8  # slots a key may occupy in the run-long table (a power of two)


@njit(cache=True)
def _push_unique(buf, n, v, om, stamp):
    """Append v to buf[:n] unless marked with stamp; returns the count.  The caller
    makes room first (:func:`_with_room`)."""
    if om[v] == stamp:
        return n
    om[v] = stamp
    buf[n] = v
    return n + 1


@njit(cache=True)
def _with_room(buf, n, extra):
    """buf, or a copy of buf[:n] with room for ``extra`` more entries."""
    if n + extra <= buf.shape[0]:
        return buf
    nb = np.empty(2 * (n + extra), np.int64)
    _copy1(nb, buf, n)
    return nb


@njit(cache=True, _nrt=False)
def _config_key(tver, kind, d0, d1, old, nold, key):
    """Fill ``key`` with the canonical key of a configuration (see the module notes)."""
    key[0] = (kind << 60) | ((min(d0, d1) + 1) << 30) | (max(d0, d1) + 1)
    for k in range(4):
        key[1 + k] = 0
    for k in range(nold):  # insertion sort of at most four ids
        t = old[k]
        w = (tver[t] << 32) | (t + 1)
        j = k
        while j > 0 and (key[j] & 0xFFFFFFFF) > t + 1:
            key[1 + j] = key[j]
            j -= 1
        key[1 + j] = w


@njit(cache=True, _nrt=False)
def _cache_slot(hkey, key, probes):
    """Open-addressing lookup: (slot, found) of ``key`` in the table ``hkey`` (column 0 =
    -1: empty), looking at most at ``probes`` slots.  Not found: the first empty slot,
    or, if all ``probes`` are taken, one of them chosen by the hash (to overwrite)."""
    mask = hkey.shape[0] - 1
    h = key[0]
    for i in range(1, _KEYLEN):
        h = (h * 1000003) ^ key[i]
    h ^= h >> 31
    s = h & mask
    for q in range(probes):
        if hkey[s, 0] == -1:
            return s, False
        same = True
        for i in range(_KEYLEN):
            if hkey[s, i] != key[i]:
                same = False
                break
        if same:
            return s, True
        s = (s + 1) & mask
    return (h + ((h >> 40) & (probes - 1))) & mask, False


@njit(cache=True)
def _cache_grow(hkey, hval, need):
    """The table, doubled until ``need`` entries fill at most half of it, rehashed."""
    n2 = hkey.shape[0]
    while 2 * need > n2:
        n2 *= 2
    k2 = np.empty((n2, _KEYLEN), np.int64)
    k2[:, 0] = -1
    v2 = np.empty((n2, hval.shape[1]), np.float64)
    for s in range(hkey.shape[0]):
        if hkey[s, 0] != -1:
            s2, _ = _cache_slot(k2, hkey[s], n2)
            for c in range(_KEYLEN):
                k2[s2, c] = hkey[s, c]
            for c in range(hval.shape[1]):
                v2[s2, c] = hval[s, c]
    return k2, v2


@njit(cache=True, _nrt=False)
def _cache_store(hkey, hval, hn, slot, key, before, after):
    """Store an evaluation at the empty ``slot`` (from :func:`_cache_slot`); returns the
    new count.  :func:`swap` makes room for a whole round beforehand (:func:`_cache_grow`)."""
    if hn >= _CACHE_MAX:
        return hn
    for c in range(_KEYLEN):
        hkey[slot, c] = key[c]
    hval[slot, 0] = before
    hval[slot, 1] = after
    return hn + 1


@njit(cache=True, _nrt=False)
def _consider(S, hkey, hval, probes, hn, key, srt, best_gain, best_cfg, best_old, best_new, kind, d0, d1,
              old, nold, newq, nnew, bound, reuse):
    """Consider one flip for this round of :func:`swap`: the one place where a
    configuration is checked, looked up in the memory or evaluated, and kept if it
    is the best so far.

    The flip replaces ``old[:nold]`` by ``newq[:nnew]`` (its ``kind`` and new
    diagonal ``d0``-``d1`` make its key, see the module notes).  It is admissible
    if every new tet has positive volume.  A remembered (before, after) is used
    as it is; otherwise, if ``bound``, a flip that surely cannot beat the round's
    best (:func:`~trivsel.mesh.criteria._cannot_beat`) is left for a later round,
    and any other is evaluated (``reuse``: the points of ``old`` are still in
    ``S.wbuf`` from the previous evaluation) and remembered.  The flip improves
    if it lowers the criterion sum by more than ``rel_tol * before + abs_tol``
    (gains at rounding level could otherwise cycle); if it also beats
    ``best_gain[0]``, it becomes the round's best: ``best_cfg`` = (kind, nold,
    nnew), ``best_old``, ``best_new``.

    Compiled without reference counting and allocating nothing, as it runs for
    every configuration of every round.

    Returns
    -------
    (bool, int, bool)
        Whether it became the best, the new count of stored evaluations, and
        whether it was evaluated (its points are now in ``S.wbuf``).
    """
    opt = S.opt
    if not _positive_at(S.ijk, S.points, opt.use_int, newq, nnew):
        return False, hn, False
    _config_key(S.tver, kind, d0, d1, old, nold, key)
    slot, found = _cache_slot(hkey, key, probes)
    evaluated = False
    if found:
        before, after = hval[slot, 0], hval[slot, 1]
        S.ctr[C_MEMHITS] += 1
    elif bound and _cannot_beat(opt.criterion, S.tsse, S.tmax, S.tcnt, old, nold, best_gain[0]):
        return False, hn, False  # cannot beat this round's best: left for a later round
    else:
        before, after = _evaluate_at(S, srt, old, nold, newq, nnew, opt.rel_tol, opt.abs_tol, reuse)
        S.ctr[C_EVALS] += 1
        hn = _cache_store(hkey, hval, hn, slot, key, before, after)
        evaluated = True
    gain = before - after
    if gain > opt.rel_tol * before + opt.abs_tol and gain > best_gain[0]:
        best_gain[0] = gain
        best_cfg[0] = kind
        best_cfg[1] = nold
        best_cfg[2] = nnew
        _copy1(best_old, old, nold)
        _copy2(best_new, newq, nnew)
        return True, hn, evaluated
    return False, hn, evaluated


@njit(cache=True)
def swap(S, seed, nseed, with_neighbours, max_rounds):
    """Data-dependent swapping after an insertion (section 4, steps i-iv).

    O = the seed tets (the new ones) and, if ``with_neighbours``, their face
    neighbours (Definition 3).  In each round every configuration 1 (2-3 over each
    interior face, 3-2 around each degree-3 edge; Fig. 2), configuration 2 (4-4
    around each degree-4 edge, both other diagonals; Fig. 3) and, with
    ``boundary_flips``, boundary 2-2 flip found in O is considered
    (:func:`_consider`); the admissible alternative (all new tets strictly
    positive) with the largest decrease of the criterion sum is applied if that
    decrease exceeds ``rel_tol * before + abs_tol``.  With ``first_improving``
    the first such flip is applied instead.  O is then updated with the new tets
    and their neighbours and the search repeats until nothing improves, or for at
    most ``max_rounds`` flips.  Each configuration is considered once per round,
    from its smallest tet id in O.

    Parameters
    ----------
    S : MeshState
    seed : int64 array
        The tets to start from, ``seed[:nseed]``.
    nseed : int
    with_neighbours : bool
        Add the seed tets' face neighbours to O.
    max_rounds : int
        Flips at most (``UNLIMITED_ROUNDS``: until nothing improves).

    Returns
    -------
    int
        The number of flips made.
    """
    tets = S.tets
    nbr = S.nbr
    alive = S.alive
    ctr = S.ctr
    opt = S.opt
    om = S.omark
    first = opt.first_improving
    bflip = opt.boundary_flips
    ctr[C_OSTAMP] += 1
    st = ctr[C_OSTAMP]
    O = np.empty(64 + 5 * nseed, np.int64)
    no = 0
    for k in range(nseed):
        t = seed[k]
        no = _push_unique(O, no, t, om, st)
    if with_neighbours:
        for k in range(nseed):
            for i in range(4):
                u = nbr[seed[k], i]
                if u >= 0:
                    no = _push_unique(O, no, u, om, st)
    old = np.empty(4, np.int64)
    ring = np.empty(5, np.int64)
    newq = np.empty((4, 4), np.int64)
    # the round's best flip: its gain, (kind, old tets, new tets) and the tets themselves
    best_gain = np.empty(1, np.float64)
    best_cfg = np.empty(3, np.int64)
    best_old = np.empty(4, np.int64)
    best_new = np.empty((4, 4), np.int64)
    # evaluated configurations: keys and (before, after) (see the module notes)
    if opt.run_memory:
        hkey = S.mkey
        hval = S.mval
        probes = _RUN_PROBES
        grow = False
    else:
        hkey = np.empty((256, _KEYLEN), np.int64)
        hkey[:, 0] = -1
        hval = np.empty((256, 2), np.float64)
        probes = hkey.shape[0]  # the table is never more than half full: no key is turned away
        grow = True
    hn = 0
    key = np.empty(_KEYLEN, np.int64)
    srt = np.empty(4, np.int64)
    old2 = np.empty(2, np.int64)
    nflips = 0
    for rnd in range(max_rounds):
        # room for all the configurations this round can store (at most 16 per tet of
        # O), so that the table is never replaced inside the loops below: an array
        # variable reassigned in a loop costs reference counting on every iteration
        if grow and hn < _CACHE_MAX and 2 * (hn + 16 * no) > hkey.shape[0]:
            hkey, hval = _cache_grow(hkey, hval, min(hn + 16 * no, _CACHE_MAX))
            probes = hkey.shape[0]
        best_gain[0] = 0.0
        best_cfg[0] = -1
        done = False
        for oi in range(no):
            t = O[oi]
            if not alive[t] or om[t] != st:
                continue
            # configuration 1 as two tets: 2 -> 3 over each interior face
            for i in range(4):
                u = nbr[t, i]
                if u < 0 or (om[u] == st and u < t):
                    continue
                _config23_at(tets, nbr, t, i, old, newq)
                better, hn, _ = _consider(S, hkey, hval, probes, hn, key, srt, best_gain, best_cfg, best_old,
                                          best_new, FLIP23, -1, -1, old, 2, newq, 3, True, False)
                if better and first:
                    done = True
                    break
            if done:
                break
            # configurations around edges: 3 -> 2 and 4 -> 4, and 2 -> 2 on the hull
            for e in range(6):
                a = tets[t, EDGES[e, 0]]
                b = tets[t, EDGES[e, 1]]
                k = _edge_ring(tets, nbr, om, st, t, a, b, old, ring)
                if k == -1 and bflip:
                    if _config22_at(S, om, st, t, a, b, old, old2, ring, newq):
                        better, hn, _ = _consider(S, hkey, hval, probes, hn, key, srt, best_gain, best_cfg,
                                                  best_old, best_new, FLIP22, -1, -1, old, 2, newq, 2, False, False)
                        if better and first:
                            done = True
                            break
                    continue
                if k != 3 and k != 4:
                    continue
                # evaluate each edge once: from its smallest tet id that is in O
                skip = False
                for j in range(k):
                    if old[j] < t and om[old[j]] == st and alive[old[j]]:
                        skip = True
                if skip:
                    continue
                gathered = False  # an evaluation of this ring left its points in S.wbuf
                for alt in range(1 if k == 3 else 2):
                    if k == 3:
                        quads32(a, b, ring, newq)
                        better, hn, ev = _consider(S, hkey, hval, probes, hn, key, srt, best_gain, best_cfg,
                                                   best_old, best_new, FLIP32, -1, -1, old, 3, newq, 2, True,
                                                   gathered)
                    else:
                        quads44(a, b, ring, alt, newq)
                        better, hn, ev = _consider(S, hkey, hval, probes, hn, key, srt, best_gain, best_cfg,
                                                   best_old, best_new, FLIP44, ring[alt], ring[(alt + 2) % 4],
                                                   old, 4, newq, 4, True, gathered)
                    gathered = gathered or ev
                    if better and first:
                        done = True
                        break
                if done:
                    break
            if done:
                break
        kind = best_cfg[0]
        if kind < 0:
            break
        ids = _replace(S, best_old, best_cfg[1], best_new, best_cfg[2], kind == FLIP22)
        if ctr[C_ERROR] != 0:
            return nflips
        if kind == FLIP22:
            ctr[C_FLIP22] += 1
        else:
            ctr[C_FLIP23 + kind] += 1
        nflips += 1
        O = _with_room(O, no, 5 * ids.shape[0])
        for k in range(ids.shape[0]):
            no = _push_unique(O, no, ids[k], om, st)
        for k in range(ids.shape[0]):
            for i in range(4):
                u = nbr[ids[k], i]
                if u >= 0:
                    no = _push_unique(O, no, u, om, st)
        # drop dead entries now and then to keep O small
        if no > 256:
            w = 0
            for r in range(no):
                if alive[O[r]]:
                    O[w] = O[r]
                    w += 1
                else:
                    om[O[r]] = 0  # a recycled id must be able to re-enter O
            no = w
        if rnd == max_rounds - 1:
            ctr[C_ROUNDCAP] += 1
    return nflips
