"""Storage of the mesh: tet slots, point buckets, symmetric links and the one primitive.

Every change of the mesh - the three insertion cases (i)-(iii) of section 4, the
2-3 / 3-2 flips of configuration 1 (Fig. 2), the 4-4 flip of configuration 2
(Fig. 3) and the boundary 2-2 flip - is "replace these old tets by these new
quadruples" and goes through one primitive, :func:`_replace`, which matches
faces to keep neighbour links symmetric (:func:`_link`, the analogue of
delaunator's ``_link``), redistributes the old tets' points to the new tets
(:func:`_fill_tets`) and updates the per-tet errors (eqs. 14-15) and the global
residuals.  Nothing else writes ``nbr`` once the mesh is started.

Tet slots come from a free list or the high-water mark (:func:`_alloc`); the
point buckets are appended at the top of one pool, which is compacted in place
when full (:func:`_compact_pool`).
"""

from __future__ import annotations

import numpy as np
from .cache import njit

from .geometry import _locate_at, _tet_data
from .heap import _set_best
from .state import (A_SSE, C_ABOVE, C_ERROR, C_HW, C_NFREE, C_POOLTOP, C_STAMP, ERR_LINK,
                    ERR_POOLCAP, ERR_TETCAP, ERR_UNCOVERED)

NEED_ROOM = -1  # _fill_tets: more room for (point, tet) memberships needed


@njit(cache=True)
def _alloc(S):
    """A tet slot from the free list or the high-water mark; -1 if full."""
    ctr = S.ctr
    if ctr[C_NFREE] > 0:
        ctr[C_NFREE] -= 1
        t = S.free[ctr[C_NFREE]]
    else:
        if ctr[C_HW] >= S.tets.shape[0]:
            ctr[C_ERROR] = ERR_TETCAP
            return -1
        t = ctr[C_HW]
        ctr[C_HW] += 1
    S.alive[t] = 1
    S.blen[t] = 0
    S.tver[t] += 1
    S.tbest[t] = -1
    S.tbestr[t] = 0.0
    return t


@njit(cache=True)
def _kill(S, t):
    ctr = S.ctr
    S.alive[t] = 0
    S.free[ctr[C_NFREE]] = t
    ctr[C_NFREE] += 1


@njit(cache=True)
def _compact_pool(S):
    """Move the live tets' point buckets to the front of the pool (in place)."""
    ctr = S.ctr
    alive = S.alive
    bstart = S.bstart
    blen = S.blen
    pool = S.pool
    hw = ctr[C_HW]
    # live buckets in the order of their starts: buckets are disjoint, so each start
    # has at most one owner (a scan instead of a sort)
    owner = np.full(ctr[C_POOLTOP], -1, np.int64)
    for t in range(hw):
        if alive[t] and blen[t] > 0:
            owner[bstart[t]] = t
    top = 0
    for s in range(owner.shape[0]):
        t = owner[s]
        if t < 0:
            continue
        L = blen[t]
        for j in range(L):
            pool[top + j] = pool[s + j]
        bstart[t] = top
        top += L
    ctr[C_POOLTOP] = top


@njit(cache=True)
def _gather(S, old, nold):
    """Points of the old tets' buckets, each once, into S.wbuf; returns their count."""
    return _gather_at(S.ctr, S.mark, S.wbuf, S.pool, S.bstart, S.blen, old, nold)


@njit(cache=True, _nrt=False)
def _gather_at(ctr, mark, buf, pool, bstart, blen, old, nold):
    """:func:`_gather` on the arrays it reads (no reference counting: see the module notes)."""
    ctr[C_STAMP] += 1
    st = ctr[C_STAMP]
    m = 0
    for k in range(nold):
        t = old[k]
        s = bstart[t]
        for j in range(blen[t]):
            p = pool[s + j]
            if mark[p] != st:
                mark[p] = st
                buf[m] = p
                m += 1
    return m


@njit(cache=True, _nrt=False, inline="always")
def _other_index(tets, u, a, b, c):
    """Local index of the vertex of tet u that is not a, b or c."""
    for j in range(4):
        v = tets[u, j]
        if v != a and v != b and v != c:
            return j
    return -1


@njit(cache=True)
def _sorted3(a, b, c):
    if a > b:
        a, b = b, a
    if b > c:
        b, c = c, b
    if a > b:
        a, b = b, a
    return a, b, c


@njit(cache=True)
def _copy1(dst, src, n):
    """``dst[:n] = src[:n]`` as a loop: an array assignment makes numba compile its
    shape-mismatch error message (string formatting, slow to compile)."""
    for j in range(n):
        dst[j] = src[j]


@njit(cache=True)
def _copy2(dst, src, n):
    """``dst[:n] = src[:n]`` on 2-D arrays (rows), as a loop (see :func:`_copy1`)."""
    for j in range(n):
        for c in range(src.shape[1]):
            dst[j, c] = src[j, c]


@njit(cache=True, _nrt=False)
def _sort_into(a, n, out):
    """``out[:n] = np.sort(a[:n])`` for the few ids of a configuration (insertion sort;
    numba's quicksort is slow to compile)."""
    for i in range(n):
        v = a[i]
        j = i
        while j > 0 and out[j - 1] > v:
            out[j] = out[j - 1]
            j -= 1
        out[j] = v


@njit(cache=True)
def _link(S, t, i, u):
    """Make t (across its face i) and u neighbours, symmetrically; u may be -1 (hull)."""
    tets = S.tets
    nbr = S.nbr
    nbr[t, i] = u
    if u >= 0:
        a = tets[t, (i + 1) % 4]
        b = tets[t, (i + 2) % 4]
        c = tets[t, (i + 3) % 4]
        j = _other_index(tets, u, a, b, c)
        nbr[u, j] = t


@njit(cache=True)
def _fill_tets(S, m, ids, nnew, best, bestr, pair_cap):
    """Fill the tets ``ids[:nnew]`` with the points ``S.wbuf[:m]``: the one bucket fill.

    Serves both :func:`_replace` (step 5: the cavity's points into the new tets)
    and :func:`fill_buckets` (all points into the initial mesh).  Sets each tet's
    bucket, its error terms (eqs. 14-15: squared-residual sum, max |residual| and
    count, the own vertices included if ``vertices_in_error``) and worst candidate
    (``best``, ``bestr``), and each point's residual f - L (eq. 16) and owner.

    The points are taken one by one, each tested against the tets in order until
    one holds it strictly inside (open interiors are disjoint, so no other tet
    holds it): each point's data is read once, not once per tet, which matters
    because the points of a large cavity are spread over memory.  Everything
    comes out as from filling tet after tet, to the last bit: each tet's bucket
    lists its points in the order of ``S.wbuf`` and its sums run in that order; a
    point's residual and owner come from the first tet (in order) that holds it;
    and the global squared-residual sum ``S.acc[A_SSE]`` gets its changes tet by
    tet, in point order within a tet.  The buckets go to the top of the pool,
    which is compacted first if they do not fit (their exact size is known only
    here: a bound such as points x tets would make large cavities fail for want
    of room they do not need).

    ``pair_cap`` bounds the (point, tet) memberships held while the buckets are
    built; ``m * nnew`` always suffices.

    Returns
    -------
    int
        0; ``ERR_UNCOVERED`` if a point lies in no tet; ``ERR_POOLCAP`` if the
        pool is full; or ``NEED_ROOM`` if ``pair_cap`` was too small (then the
        tets are not filled, and points' residuals and owners may have changed).
    """
    I_ = S.ijk
    P_ = S.points
    F_ = S.values
    tets = S.tets
    buf = S.wbuf
    pool = S.pool
    cand = S.cand
    isvert = S.isvert
    resid = S.resid
    owner = S.owner
    ctr = S.ctr
    opt = S.opt
    ui_ = opt.use_int
    ownvert = opt.vertices_in_error
    tolinf = opt.tol_inf
    # the new tets' vertices, face planes, vertex coordinates and values
    Q = np.empty((nnew, 4), np.int64)
    PL = np.empty((nnew, 16), np.int64)
    QF = np.empty((nnew, 12), np.float64)
    FQ = np.empty((nnew, 4), np.float64)
    for k in range(nnew):
        t = ids[k]
        for c in range(4):
            Q[k, c] = tets[t, c]
        pl, qf, fq = _tet_data(I_, P_, F_, Q[k, 0], Q[k, 1], Q[k, 2], Q[k, 3])
        for c in range(16):
            PL[k, c] = pl[c]
        for c in range(12):
            QF[k, c] = qf[c]
        for c in range(4):
            FQ[k, c] = fq[c]
    L = np.zeros(nnew, np.int64)
    sse = np.zeros(nnew, np.float64)
    mx = np.zeros(nnew, np.float64)
    cnt = np.zeros(nnew, np.int64)
    for k in range(nnew):
        best[k] = -1
        bestr[k] = 0.0
    # (point, tet) memberships in point order, and each point's covering tet and residual change
    pj = np.empty(pair_cap, np.int32)
    pk = np.empty(pair_cap, np.int32)
    cov = np.empty(m, np.int32)
    delta = np.empty(m, np.float64)
    npairs = 0
    for j in range(m):
        if npairs + nnew > pair_cap:
            return NEED_ROOM
        p = buf[j]
        # only what the test needs: every array read here is a likely cache miss
        pi = (I_[p, 0], I_[p, 1], I_[p, 2])
        pf = (0.0, 0.0, 0.0) if ui_ else (P_[p, 0], P_[p, 1], P_[p, 2])
        fp = F_[p]
        cov[j] = -1
        for k in range(nnew):
            q0, q1, q2, q3 = Q[k, 0], Q[k, 1], Q[k, 2], Q[k, 3]
            inside, nz, val = _locate_at(ui_, pi, pf,
                                         (PL[k, 0], PL[k, 1], PL[k, 2], PL[k, 3], PL[k, 4], PL[k, 5], PL[k, 6],
                                          PL[k, 7], PL[k, 8], PL[k, 9], PL[k, 10], PL[k, 11], PL[k, 12],
                                          PL[k, 13], PL[k, 14], PL[k, 15]),
                                         (QF[k, 0], QF[k, 1], QF[k, 2], QF[k, 3], QF[k, 4], QF[k, 5], QF[k, 6],
                                          QF[k, 7], QF[k, 8], QF[k, 9], QF[k, 10], QF[k, 11]),
                                         (FQ[k, 0], FQ[k, 1], FQ[k, 2], FQ[k, 3]), p, q0, q1, q2, q3)
            if not inside:
                continue
            pj[npairs] = j
            pk[npairs] = k
            npairs += 1
            L[k] += 1
            r = fp - val
            ar = abs(r)
            if ar > bestr[k] and cand[p] and not isvert[p]:
                best[k] = p
                bestr[k] = ar
            if ownvert or (p != q0 and p != q1 and p != q2 and p != q3):
                sse[k] += r * r
                if ar > mx[k]:
                    mx[k] = ar
                cnt[k] += 1
            if cov[j] < 0:  # the first new tet that holds p covers it
                cov[j] = k
                old_r = resid[p]
                delta[j] = r * r - old_r * old_r
                if tolinf >= 0.0:
                    if abs(old_r) > tolinf:
                        ctr[C_ABOVE] -= 1
                    if ar > tolinf:
                        ctr[C_ABOVE] += 1
                resid[p] = r
                owner[p] = ids[k]
            if nz == 0:
                break  # strictly inside: in no other new tet
        if cov[j] < 0:
            return ERR_UNCOVERED
    # buckets: tet after tet from the top of the pool, each in point order
    if ctr[C_POOLTOP] + npairs > pool.shape[0]:
        _compact_pool(S)
        if ctr[C_POOLTOP] + npairs > pool.shape[0]:
            return ERR_POOLCAP
    top = ctr[C_POOLTOP]
    off = np.empty(nnew, np.int64)
    s = top
    for k in range(nnew):
        t = ids[k]
        off[k] = s
        S.bstart[t] = s
        S.blen[t] = L[k]
        S.tsse[t] = sse[k]
        S.tmax[t] = mx[k]
        S.tcnt[t] = cnt[k]
        s += L[k]
    ctr[C_POOLTOP] = s
    # each pair to its tet's bucket; the covering pairs' residual changes in that same
    # (tet, then point) order: the order in which filling tet after tet summed them
    dslot = np.zeros(npairs, np.float64)
    covers = np.zeros(npairs, np.bool_)
    for i in range(npairs):
        k = pk[i]
        j = pj[i]
        o = off[k]
        pool[o] = buf[j]
        if cov[j] == k:
            covers[o - top] = True
            dslot[o - top] = delta[j]
        off[k] = o + 1
    acc = S.acc
    for i in range(npairs):
        if covers[i]:
            acc[A_SSE] += dslot[i]
    return 0


@njit(cache=True)
def fill_buckets(S, ids):
    """Buckets, errors and residuals of a fresh mesh whose tets are ``ids`` (all points).

    The bucket fill of :func:`_replace` (:func:`_fill_tets`) over every point, in
    index order; then the global squared-residual sum and the count of points
    above the E_inf tolerance are summed afresh over the points in index order.
    Sets ``S.ctr[C_ERROR]`` on failure.
    """
    N = S.values.shape[0]
    ctr = S.ctr
    buf = S.wbuf
    for p in range(N):
        buf[p] = p
    nnew = ids.shape[0]
    best = np.empty(nnew, np.int64)
    bestr = np.empty(nnew, np.float64)
    # room for the memberships: a point is in one tet unless it lies on a face, an
    # edge or a vertex, so a few per point, doubled while it is not enough
    full = N * nnew
    pair_cap = min(full, 8 * N + 4 * nnew)
    while True:
        err = _fill_tets(S, N, ids, nnew, best, bestr, pair_cap)
        if err != NEED_ROOM:
            break
        pair_cap = min(2 * pair_cap, full)
    if err != 0:
        ctr[C_ERROR] = err
        return
    for k in range(nnew):
        _set_best(S, ids[k], best[k], bestr[k])
    resid = S.resid
    acc = S.acc
    acc[A_SSE] = 0.0
    tolinf = S.opt.tol_inf
    ctr[C_ABOVE] = 0
    for p in range(N):
        acc[A_SSE] += resid[p] * resid[p]
        if tolinf >= 0.0 and abs(resid[p]) > tolinf:
            ctr[C_ABOVE] += 1


@njit(cache=True)
def _replace(S, old, nold, newq, nnew, new_hull):
    """Replace tets ``old[:nold]`` by the quadruples ``newq[:nnew]`` (same region).

    Links the new tets to each other and to the outside neighbours of the old
    ones, moves the old tets' points into the new tets that contain them (closed
    containment), recomputes their errors and the global residuals.  A new face
    that matches no face is an error, unless ``new_hull`` (insertion on a hull face
    or edge splits hull faces): then it becomes a hull face.

    Returns
    -------
    int64 array
        The new tet ids, in the order of ``newq``; empty, with ``S.ctr[C_ERROR]``
        set, on failure (``ERR_TETCAP``, ``ERR_LINK``, ``ERR_UNCOVERED``,
        ``ERR_POOLCAP``).
    """
    tets = S.tets
    nbr = S.nbr
    ctr = S.ctr
    # 1. outer faces of the cavity: sorted key and the outside tet
    okey = np.empty((4 * nold, 3), np.int64)
    oout = np.empty(4 * nold, np.int64)
    no = 0
    for k in range(nold):
        t = old[k]
        for i in range(4):
            u = nbr[t, i]
            inside = False
            for kk in range(nold):
                if old[kk] == u:
                    inside = True
                    break
            if inside:
                continue
            a, b, c = _sorted3(tets[t, (i + 1) % 4], tets[t, (i + 2) % 4], tets[t, (i + 3) % 4])
            okey[no, 0] = a
            okey[no, 1] = b
            okey[no, 2] = c
            oout[no] = u
            no += 1
    # 2. points of the cavity
    m = _gather(S, old, nold)
    for k in range(nold):
        _kill(S, old[k])
    # 3. new tets
    ids = np.empty(nnew, np.int64)
    for k in range(nnew):
        t = _alloc(S)
        if t < 0:
            return ids[:0]
        ids[k] = t
        for j in range(4):
            tets[t, j] = newq[k, j]
    # 4. links: internal faces pairwise, outer faces to the outside
    for k in range(nnew):
        t = ids[k]
        for i in range(4):
            a, b, c = _sorted3(tets[t, (i + 1) % 4], tets[t, (i + 2) % 4], tets[t, (i + 3) % 4])
            found = False
            for k2 in range(nnew):
                if k2 == k:
                    continue
                t2 = ids[k2]
                j = _other_index(tets, t2, a, b, c)
                if j >= 0:
                    a2, b2, c2 = _sorted3(tets[t2, (j + 1) % 4], tets[t2, (j + 2) % 4], tets[t2, (j + 3) % 4])
                    if a2 == a and b2 == b and c2 == c:
                        nbr[t, i] = t2
                        found = True
                        break
            if not found:
                for f in range(no):
                    if okey[f, 0] == a and okey[f, 1] == b and okey[f, 2] == c:
                        _link(S, t, i, oout[f])
                        found = True
                        break
            if not found:
                if new_hull:
                    nbr[t, i] = -1
                else:
                    ctr[C_ERROR] = ERR_LINK
                    return ids[:0]
    # 5. buckets, per-tet errors, residuals
    best = np.empty(nnew, np.int64)
    bestr = np.empty(nnew, np.float64)
    err = _fill_tets(S, m, ids, nnew, best, bestr, m * nnew)
    if err != 0:
        ctr[C_ERROR] = err
        return ids[:0]
    for k in range(nnew):
        _set_best(S, ids[k], best[k], bestr[k])
    return ids
