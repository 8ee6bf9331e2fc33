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
from .cache import njit

from .criteria import _cannot_beat, _evaluate_at
from .flips import FLIP22, FLIP23, FLIP32, FLIP44, _config22_at, _config23_at, _edge_ring, quads32, quads44
from .geometry import EDGES, _positive_at
from .state import C_ERROR, C_EVALS, C_FLIP22, C_FLIP23, C_MEMHITS, C_OSTAMP, C_ROUNDCAP, KEYLEN
from .storage import _copy1, _copy2, _replace

_KEYLEN = KEYLEN  # words of a configuration's key
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


@njit(cache=True)
def swap(S, seed, nseed, with_neighbours, max_rounds):
    """Data-dependent swapping after an insertion (section 4, steps i-iv).

    O = the seed tets (the new ones) and, if ``with_neighbours``, their face
    neighbours (Definition 3).  In each round every configuration 1 (2-3 over each
    interior face, 3-2 around each degree-3 edge; Fig. 2), configuration 2 (4-4
    around each degree-4 edge, both other diagonals; Fig. 3) and, with
    ``boundary_flips``, boundary 2-2 flip found in O is considered; the admissible alternative (all new tets strictly
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
    I_ = S.ijk
    P_ = S.points
    alive = S.alive
    ctr = S.ctr
    opt = S.opt
    ui_ = opt.use_int
    om = S.omark
    reltol = opt.rel_tol
    abstol = opt.abs_tol
    first = opt.first_improving
    bflip = opt.boundary_flips
    tver = S.tver
    tsse = S.tsse
    tmax = S.tmax
    tcnt = S.tcnt
    crit = opt.criterion
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
        best_gain = 0.0
        best_kind = -1
        best_nold = 0
        best_nnew = 0
        done = False
        for oi in range(no):
            t = O[oi]
            if not alive[t] or om[t] != st:
                continue
            # the configurations of t, each from its smallest tet in O: c < 4 the 2-3 flip
            # over face c; c >= 4 those around edge c - 4 (2-2 on the hull, 3-2 around a
            # degree-3 edge, 4-4 with either new diagonal around a degree-4 edge)
            for c in range(10):
                a = -1
                b = -1
                nalt = 1
                if c < 4:
                    u = nbr[t, c]
                    if u < 0 or (om[u] == st and u < t):
                        continue
                    _config23_at(tets, nbr, t, c, old, newq)
                    kind = FLIP23
                    nold = 2
                    nnew = 3
                else:
                    a = tets[t, EDGES[c - 4, 0]]
                    b = tets[t, EDGES[c - 4, 1]]
                    k = _edge_ring(tets, nbr, om, st, t, a, b, old, ring)
                    if k == -1:
                        if not bflip or not _config22_at(S, om, st, t, a, b, old, old2, ring, newq):
                            continue
                        kind = FLIP22
                        nold = 2
                        nnew = 2
                    elif k == 3 or k == 4:
                        skip = False
                        for j in range(k):
                            if old[j] < t and om[old[j]] == st and alive[old[j]]:
                                skip = True
                        if skip:
                            continue
                        kind = FLIP32 if k == 3 else FLIP44
                        nold = k
                        nnew = 2 if k == 3 else 4
                        nalt = 1 if k == 3 else 2
                    else:
                        continue
                gathered = False  # an evaluation of these old tets left their points in S.wbuf
                for alt in range(nalt):
                    d0 = -1
                    d1 = -1
                    if kind == FLIP32:
                        quads32(a, b, ring, newq)
                    elif kind == FLIP44:
                        quads44(a, b, ring, alt, newq)
                        d0 = ring[alt]
                        d1 = ring[(alt + 2) % 4]
                    # the one place where a flip is checked, remembered or evaluated, and kept
                    if not _positive_at(I_, P_, ui_, newq, nnew):
                        continue
                    _config_key(tver, kind, d0, d1, old, nold, key)
                    slot, found = _cache_slot(hkey, key, probes)
                    if found:
                        before, after = hval[slot, 0], hval[slot, 1]
                        ctr[C_MEMHITS] += 1
                    elif kind != FLIP22 and _cannot_beat(crit, tsse, tmax, tcnt, old, nold, best_gain):
                        continue  # cannot beat this round's best: left for a later round
                    else:
                        before, after = _evaluate_at(S, srt, old, nold, newq, nnew, reltol, abstol, gathered)
                        ctr[C_EVALS] += 1
                        gathered = True
                        hn = _cache_store(hkey, hval, hn, slot, key, before, after)
                    gain = before - after
                    if gain > reltol * before + abstol and gain > best_gain:
                        best_gain = gain
                        best_kind = kind
                        best_nold = nold
                        best_nnew = nnew
                        _copy1(best_old, old, nold)
                        _copy2(best_new, newq, nnew)
                        if first:
                            done = True
                            break
                if done:
                    break
            if done:
                break
        if best_kind < 0:
            break
        ids = _replace(S, best_old, best_nold, best_new, best_nnew, best_kind == FLIP22)
        if ctr[C_ERROR] != 0:
            return nflips
        if best_kind == FLIP22:
            ctr[C_FLIP22] += 1
        else:
            ctr[C_FLIP23 + best_kind] += 1
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
