"""The compiled kernels of :mod:`trivsel.decimation`: geometry, corner segments, half-edge
collapses, the queue and the drivers, on the flat arrays of :class:`~trivsel.decimation.State`.

The method, its drawings and its invariants are described in :mod:`trivsel.decimation`, which
is the Python face of these kernels and imports this module only when it runs them with
numba's just-in-time compiler; otherwise :mod:`trivsel.aot` loads the same functions compiled
ahead of time (:func:`aot_exports` names them), and this module and numba are never imported.

The functions called once per candidate or per point of a star (``_cost``, ``_locate_star``,
``_value_moved``) are inlined by numba (``inline='always'``): a call passes each array argument
as several machine words, the state ``S`` as a few hundred, which costs more than the
arithmetic of the call.  The rare ends of a walk (a point on a face, an edge or a vertex:
``_on_boundary``, ``_scan``) stay calls, so that the inlined copies stay small.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import C_FLOAT, C_HN, C_KEPT, C_LAST, C_LAZY, C_LM, C_LROW, C_MAXKEY, C_NREM, C_NV, C_PTOP, INF, LOCK_ALL, LOCK_MESH, \
    QUEUE_ARITY
from ..predicates import orient3d_robust, orient3d_value

# ----------------------------------------------------------------------------- geometry


@njit(cache=True, _nrt=False)
def _orient(P, flt, a, b, c, d):
    """Six times the signed volume of (a, b, c, d), with the exact sign: exact on integer
    grid coordinates; on float coordinates (``flt``, a mesh) the float determinant whose
    sign is decided by the robust predicate (:func:`trivsel.predicates.orient3d_robust`)."""
    if flt:
        return orient3d_robust(float(P[a, 0]), float(P[a, 1]), float(P[a, 2]), float(P[b, 0]), float(P[b, 1]),
                               float(P[b, 2]), float(P[c, 0]), float(P[c, 1]), float(P[c, 2]), float(P[d, 0]),
                               float(P[d, 1]), float(P[d, 2]))
    return float(orient3d_value(P[a, 0], P[a, 1], P[a, 2], P[b, 0], P[b, 1], P[b, 2],
                                P[c, 0], P[c, 1], P[c, 2], P[d, 0], P[d, 1], P[d, 2]))


@njit(cache=True, _nrt=False)
def _has(T, t, w):
    """Whether row t of ``T`` (a tet's four vertices) holds vertex w."""
    return T[t, 0] == w or T[t, 1] == w or T[t, 2] == w or T[t, 3] == w


@njit(cache=True, _nrt=False)
def _planes(P, Q, sc, n, G):
    """For each of v's corners ``sc[i]`` (slot s of tet ``Q[i]``), the orientation of that tet
    as an affine function of the point x in slot s: ``orient = G[i, :3] . x + G[i, 3]``, so
    that moving v onto any w is tested with one dot product per tet.

    With a, b, c the other three vertices in order, ``orient(x, a, b, c) = -N . (x - a)``
    for ``N = (b - a) x (c - a)``, and moving x from slot 0 to slot s is s transpositions."""
    for i in range(n):
        s = sc[i] & 3
        a = Q[i, 1] if s == 0 else Q[i, 0]
        b = Q[i, 2] if s <= 1 else Q[i, 1]
        c = Q[i, 3] if s <= 2 else Q[i, 2]
        ux, uy, uz = P[b, 0] - P[a, 0], P[b, 1] - P[a, 1], P[b, 2] - P[a, 2]
        vx, vy, vz = P[c, 0] - P[a, 0], P[c, 1] - P[a, 1], P[c, 2] - P[a, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        sign = -1 if s % 2 == 0 else 1
        G[i, 0], G[i, 1], G[i, 2] = sign * nx, sign * ny, sign * nz
        G[i, 3] = -sign * (nx * P[a, 0] + ny * P[a, 1] + nz * P[a, 2])


@njit(cache=True, _nrt=False)
def _gather(S, sc, n, Q):
    """Copy the star's tets (corners ``sc[:n]``) into ``Q`` and mark their neighbours across
    faces (``S.X``, ``_across``) as not yet looked for."""
    T, X = S.T, S.X
    for i in range(n):
        t = sc[i] >> 2
        Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3] = T[t, 0], T[t, 1], T[t, 2], T[t, 3]
        X[i, 0], X[i, 1], X[i, 2], X[i, 3] = -2, -2, -2, -2


@njit(cache=True, _nrt=False)
def _gather_points(S, sc, n):
    """Copy the points of the star's buckets (corners ``sc[:n]``) into ``S.pbuf``
    (``S.phome``: the star index of each point's tet), in star order; returns their number
    and the sum of their squared residuals."""
    phead, pnext, res, pbuf, phome = S.phead, S.pnext, S.res, S.pbuf, S.phome
    m = 0
    old = 0.0
    for i in range(n):
        p = phead[sc[i] >> 2]
        while p >= 0:
            old += res[p] * res[p]
            pbuf[m] = p
            phome[m] = i
            m += 1
            p = pnext[p]
    return m, old


@njit(cache=True, _nrt=False)
def _where(z0, z1, z2, z3):
    """Where a point lies in a tet that holds it, from which of its four weights are zero:
    -1 strictly inside, ``-2 - j`` on the face opposite slot j only, ``-6 - 4 j - k`` on
    the edge opposite slots j < k, -22 on a vertex."""
    nz = int(z0) + int(z1) + int(z2) + int(z3)
    if nz == 0:
        return -1
    if nz == 1:
        return -2 if z0 else (-3 if z1 else (-4 if z2 else -5))
    if nz == 2:
        j = 0 if z0 else (1 if z1 else 2)
        k = 3 if z3 else (2 if z2 else 1)
        return -6 - 4 * j - k
    return -22


@njit(cache=True, _nrt=False, inline='always')
def _value_moved(P, flt, f, Q, G, sc, i, w, p):
    r"""Whether p lies in star tet ``Q[i]`` with v's slot holding w, and the linear
    interpolant of the vertex values there (eq. 13): ``(where, L)``, ``where`` -1 if p is
    strictly inside, less if on its boundary (``_where`` says where), else the slot whose weight is negative (the tet's face opposite it
    separates p from the tet).

    On grid coordinates (``G``: the far faces' planes of ``_planes``) it takes two
    orientations instead of four.  p's weight in v's slot s is the far face's plane at p,
    which does not depend on w, and a tet's four weights sum to its orientation, the
    plane at w, so the last weight is what the other three leave::

              w (slot s)            l_s = G[i] . p + G[i, 3]     (p for w)
             /|\                    D   = G[i] . w + G[i, 3]     (the tet)
            / | \                   l_j = orient(p for q_j), for two slots j != s
           /  p  \                  the last = D - l_s - the two
          a---|---c
           \  |  /                  All integers on the grid, so exactly the four
            \ | /                   orientations with p in each slot in turn.
              b
    """
    s = sc[i] & 3
    q0 = w if s == 0 else Q[i, 0]
    q1 = w if s == 1 else Q[i, 1]
    q2 = w if s == 2 else Q[i, 2]
    q3 = w if s == 3 else Q[i, 3]
    if flt:
        l0 = _orient(P, flt, p, q1, q2, q3)
        if l0 < 0:
            return 0, 0.0
        l1 = _orient(P, flt, q0, p, q2, q3)
        if l1 < 0:
            return 1, 0.0
        l2 = _orient(P, flt, q0, q1, p, q3)
        if l2 < 0:
            return 2, 0.0
        l3 = _orient(P, flt, q0, q1, q2, p)
        if l3 < 0:
            return 3, 0.0
        D = l0 + l1 + l2 + l3
        return _where(l0 == 0, l1 == 0, l2 == 0, l3 == 0), (l0 * f[q0] + l1 * f[q1] + l2 * f[q2] + l3 * f[q3]) / D
    ls = G[i, 0] * P[p, 0] + G[i, 1] * P[p, 1] + G[i, 2] * P[p, 2] + G[i, 3]
    if ls < 0:
        return s, 0.0
    D = G[i, 0] * P[w, 0] + G[i, 1] * P[w, 1] + G[i, 2] * P[w, 2] + G[i, 3]
    # the first two slots other than s by orientation, the last other one (jc) by difference
    ja = 1 if s == 0 else 0
    jb = 2 if s <= 1 else 1
    jc = 2 if s == 3 else 3
    la = _orient(P, False, p, q1, q2, q3) if ja == 0 else _orient(P, False, q0, p, q2, q3)
    if la < 0:
        return ja, 0.0
    lb = _orient(P, False, q0, p, q2, q3) if jb == 1 else _orient(P, False, q0, q1, p, q3)
    if lb < 0:
        return jb, 0.0
    lc = D - ls - la - lb
    if lc < 0:
        return jc, 0.0
    # the weights by slot: s holds ls, ja and jb their own, jc lc
    l0 = float(ls if s == 0 else (la if ja == 0 else lc))
    l1 = float(ls if s == 1 else (la if ja == 1 else (lb if jb == 1 else lc)))
    l2 = float(ls if s == 2 else (lb if jb == 2 else lc))
    l3 = float(ls if s == 3 else lc)
    return _where(l0 == 0, l1 == 0, l2 == 0, l3 == 0), (l0 * f[q0] + l1 * f[q1] + l2 * f[q2] + l3 * f[q3]) / (l0 + l1 + l2 + l3)


@njit(cache=True, _nrt=False)
def _across(Q, sc, X, n, i, j):
    """The star tet on the other side of star tet i's face opposite its slot j (a face
    through v, ``j != sc[i] & 3``): the other tet of v's that holds that face's two other
    vertices, or -1 (the face is on the box or the mesh's boundary).  Found once per star
    and kept in ``X[i, j]`` (-2: not yet looked for)."""
    k = X[i, j]
    if k != -2:
        return k
    s = sc[i] & 3
    a = 0
    while a == s or a == j:
        a += 1
    b = a + 1
    while b == s or b == j:
        b += 1
    x, y = Q[i, a], Q[i, b]
    k = -1
    for m in range(n):
        if m != i and _has(Q, m, x) and _has(Q, m, y):
            k = m
            break
    X[i, j] = k
    return k


@njit(cache=True, _nrt=False, inline='always')
def _locate_star(P, flt, f, Q, G, sc, kw, X, n, w, p, hint):
    """Where p lies once v has moved onto w: ``(i, L)`` for the star tet ``Q[i]`` that keeps
    w (``kw[i]`` false) and holds p, ``(-1, 0)`` if none does.  The tet is the one a scan
    finds first, trying star index ``hint`` first and then the others in order; the same
    tet is reached by walking from the hint across the face that separates p (``_across``)::

        hint -> across the face p is beyond -> ... -> a tet that holds p

    A tet that holds p strictly inside is the only one that does (the moved star is a
    tetrahedralisation: every moved tet was checked to keep a positive volume), so the walk
    ends there; p on a face is also in the tets beyond it, and the first of them in scan
    order is taken.  A walk that leaves the star or reaches a vanishing tet gives way to
    the scan itself."""
    i, j = hint, -1
    if hint >= 0 and not kw[hint]:
        j, val = _value_moved(P, flt, f, Q, G, sc, hint, w, p)
        if j < 0:
            return hint, val
    elif hint >= 0:
        # the hint vanishes with the edge vw: start past its face opposite w
        s = 0
        while Q[hint, s] != w:
            s += 1
        i = _across(Q, sc, X, n, hint, s)
    else:
        # v itself (no hint): from past a vanishing tet's face opposite w (beyond v from w)
        i = 0
        while i < n and not kw[i]:
            i += 1
        if i < n:
            s = 0
            while Q[i, s] != w:
                s += 1
            i = _across(Q, sc, X, n, i, s)
        else:
            i = -1
    for _ in range(n):
        if i < 0 or kw[i]:
            break
        if j >= 0:
            if j == sc[i] & 3:
                break
            i = _across(Q, sc, X, n, i, j)
            if i < 0 or kw[i]:
                break
        j, val = _value_moved(P, flt, f, Q, G, sc, i, w, p)
        if j == -1:
            return i, val
        if j < -1:
            return _on_boundary(P, flt, f, Q, G, sc, kw, X, n, w, p, hint, i, j, val)
    return _scan(P, flt, f, Q, G, sc, kw, n, w, p, hint)


@njit(cache=True, _nrt=False)
def _on_boundary(P, flt, f, Q, G, sc, kw, X, n, w, p, hint, i, j, val):
    """The end of ``_locate_star``'s walk where it reached star tet i with p on its boundary
    (``j < -1``, as ``_where`` says)."""
    if j < -5 and j > -22:
        # on the edge opposite slots a < b: every tet of the edge holds p, the first in
        # scan order is taken (an edge through w: every moved tet with its other end)
        a = (-6 - j) >> 2
        b = (-6 - j) & 3
        s = sc[i] & 3
        c = 0
        while c == a or c == b or c == s:
            c += 1
        x = Q[i, c]
        y = -1
        if a == s or b == s:
            d = c + 1
            while d == a or d == b or d == s:
                d += 1
            y = Q[i, d]
        for k in range(i):
            if k != hint and not kw[k] and _has(Q, k, x) and (y < 0 or _has(Q, k, y)):
                where, v2 = _value_moved(P, flt, f, Q, G, sc, k, w, p)
                if where < 0:
                    return k, v2
        return i, val
    if j > -6:
        # on one face: the tet across it (if that face is not the star's boundary) holds p too
        j = -2 - j
        if j != sc[i] & 3:
            k = _across(Q, sc, X, n, i, j)
            if 0 <= k < i and not kw[k]:
                where, v2 = _value_moved(P, flt, f, Q, G, sc, k, w, p)
                if where < 0:
                    return k, v2
        return i, val
    # on a vertex: the scan finds the first of its tets (i at the latest)
    return _scan(P, flt, f, Q, G, sc, kw, n, w, p, hint)


@njit(cache=True, _nrt=False)
def _scan(P, flt, f, Q, G, sc, kw, n, w, p, hint):
    """``_locate_star``'s scan: the first star tet, the hint excepted, that keeps w and holds p."""
    for i in range(n):
        if i == hint or kw[i]:
            continue
        j, val = _value_moved(P, flt, f, Q, G, sc, i, w, p)
        if j < 0:
            return i, val
    return -1, 0.0


# ----------------------------------------------------------------------------- links


@njit(cache=True, _nrt=False)
def _link(S, v, c):
    """Add corner c to vertex v's corners, as the newest.  A full segment moves to the top of
    the pool with twice the room (``_run`` makes sure the pool has it)::

        cpool  [ v: c9 c4 c1 . . | u: c7 c2 . | ... | top ]   c1 newest of v
    """
    d = S.deg[v]
    if d == S.vcap[v]:
        top = S.ctr[C_PTOP]
        cap = max(2 * d, 8)
        a = S.vstart[v]
        for k in range(d):
            S.cpool[top + k] = S.cpool[a + k]
        S.vstart[v] = top
        S.vcap[v] = cap
        S.ctr[C_PTOP] = top + cap
    S.cpool[S.vstart[v] + d] = c
    S.deg[v] = d + 1


@njit(cache=True, _nrt=False)
def _unlink(S, v, c):
    """Take corner c out of vertex v's corners, the others keeping their order."""
    a = S.vstart[v]
    d = S.deg[v]
    k = 0
    while S.cpool[a + k] != c:
        k += 1
    for k in range(k, d - 1):
        S.cpool[a + k] = S.cpool[a + k + 1]
    S.deg[v] = d - 1


@njit(cache=True, _nrt=False)
def _star(S, v, out):
    """The corners of vertex v (tet ``c >> 2``, slot ``c & 3``), newest first, into ``out``;
    their count, or -1 if there are more than ``out`` holds (v then does not move)."""
    n = S.deg[v]
    if n > out.shape[0]:
        return -1
    a = S.vstart[v] + n - 1
    for k in range(n):
        out[k] = S.cpool[a - k]
    return n


# ----------------------------------------------------------------------------- collapses


@njit(cache=True, _nrt=False)
def _boundary_faces(Q, sc, n, v, B):
    """The boundary triangles ``(v, B[k, 0], B[k, 1])`` around a vertex v of a mesh: the faces
    of v's tets (``Q[:n]``, v in slot ``sc[i] & 3``) that contain v and no other tet of v
    shares.  Returns their count, or -1 if ``B`` cannot hold them (v then does not move)."""
    nb = 0
    for i in range(n):
        s = sc[i] & 3
        for j in range(4):
            if j == s:
                continue
            # the face of v's tet i without its slot j: v and the two others
            a = Q[i, 0 if (0 != s and 0 != j) else (1 if (1 != s and 1 != j) else 2)]
            b = Q[i, 3 if (3 != s and 3 != j) else (2 if (2 != s and 2 != j) else 1)]
            shared = False
            for k in range(n):
                if k != i and _has(Q, k, a) and _has(Q, k, b):
                    shared = True
                    break
            if not shared:
                if nb == B.shape[0]:
                    return -1
                B[nb, 0], B[nb, 1] = a, b
                nb += 1
    return nb


@njit(cache=True, _nrt=False)
def _allowed(S, v, w, B, nb):
    """The domain constraint.  On a grid, the box: w is on every box face that v is on.
    On a mesh, a boundary vertex v (its boundary triangles ``(v, B[k, 0], B[k, 1])``,
    ``k < nb``) moves only along a boundary edge vw, onto a w in the plane of every one of
    them (exactly): within its flat patch, along its crease, and a corner never."""
    lk = S.lock[v]
    if lk & LOCK_ALL:
        return False
    if lk & LOCK_MESH:
        if nb < 0:
            return False
        on_edge = False
        for k in range(nb):
            a, b = B[k, 0], B[k, 1]
            if a == w or b == w:
                on_edge = True
            elif _orient(S.P, S.ctr[C_FLOAT] != 0, v, a, b, w) != 0.0:
                return False
        return on_edge
    for a in range(3):
        if (lk >> a) & 1 and S.P[w, a] != S.P[v, a]:
            return False
    return True


@njit(cache=True, _nrt=False, inline='always')
def _moved_star(P, flt, Q, G, sc, kw, n, w, r):
    """Whether v may move onto w (v's star gathered: tets ``Q[:n]``, their planes ``G``):
    ``(shared, r)``, ``shared`` the number of v's tets that contain w (they vanish), or -1 if
    another tet would not keep a positive volume with w in v's slot.  Sets ``kw`` (which
    tets contain w) up to the first tet that fails.

    On a grid, star tet r is tried first (the caller passes the tet that turned its last
    neighbour away: it often turns this one away too, and saves the scan up to its place),
    and a tet that fails is returned as the next r.  The answer does not depend on the
    order."""
    shared = 0
    if flt:  # float coordinates: the robust predicate on each tet as it would be
        for i in range(n):
            h = _has(Q, i, w)
            kw[i] = h
            if h:
                shared += 1
                continue
            s = sc[i] & 3
            if _orient(P, True, w if s == 0 else Q[i, 0], w if s == 1 else Q[i, 1], w if s == 2 else Q[i, 2],
                       w if s == 3 else Q[i, 3]) <= 0.0:
                return -1, r
        return shared, r
    # on the grid, the far face's plane at w first: zero for every tet that holds w (w is
    # on its far face), so only a zero needs the look at the tet's vertices
    wx, wy, wz = P[w, 0], P[w, 1], P[w, 2]
    if 0 <= r < n:
        o = G[r, 0] * wx + G[r, 1] * wy + G[r, 2] * wz + G[r, 3]
        if o < 0 or (o == 0 and not _has(Q, r, w)):
            return -1, r
    for i in range(n):
        o = G[i, 0] * wx + G[i, 1] * wy + G[i, 2] * wz + G[i, 3]
        if o > 0:
            kw[i] = False
        elif o < 0 or not _has(Q, i, w):
            return -1, i
        else:
            kw[i] = True
            shared += 1
    return shared, r


@njit(cache=True, _nrt=False, inline='always')
def _cost(S, v, w, sc, Q, G, kw, n, m, tol_inf, old, bound, use_max, row):
    """``(key, delta)`` if v moves onto w, a move ``_moved_star`` allowed (``kw[:n]`` set by
    it; the star's bucket points ``S.pbuf[:m]``, the sum of their squared residuals ``old``):
    ``delta`` the change of the squared-residual sum, ``key`` that change or, with the max
    criterion, the largest |residual| of the points that move (v and its buckets' points);
    the key is inf if a point is in no moved tet, takes a residual above ``tol_inf``
    (negative: no limit) or cannot beat ``bound``.  Row ``row`` of ``S.LT``, ``S.LR`` gets
    each point's tet and residual, when they hold all ``m + 1``."""
    P, f, pbuf, phome, LT, LR = S.P, S.f, S.pbuf, S.phome, S.LT, S.LR
    flt = S.ctr[C_FLOAT] != 0
    keep = m < LT.shape[1]
    i, val = _locate_star(P, flt, f, Q, G, sc, kw, S.X, n, w, v, -1)
    if i < 0:
        return INF, INF
    r = f[v] - val
    if 0.0 <= tol_inf < abs(r):
        return INF, INF
    if keep:
        LT[row, 0] = sc[i] >> 2
        LR[row, 0] = r
    new = r * r
    mx = abs(r)
    for k in range(m):
        # the rest only adds: no better than the best so far
        if (mx if use_max else new - old) > bound:
            return INF, INF
        p = pbuf[k]
        i, val = _locate_star(P, flt, f, Q, G, sc, kw, S.X, n, w, p, phome[k])
        if i < 0:
            return INF, INF
        r = f[p] - val
        if 0.0 <= tol_inf < abs(r):
            return INF, INF
        if keep:
            LT[row, k + 1] = sc[i] >> 2
            LR[row, k + 1] = r
        new += r * r
        mx = max(mx, abs(r))
    return (mx if use_max else new - old), new - old


@njit(cache=True, _nrt=False)
def _best(S, v, sc, G, mark, tol_inf):
    """v's cheapest valid collapse ``(key, w, tets of w after, change of the squared-residual
    sum)`` over its neighbours w (ties: fewer tets around w, then the smaller w);
    ``(inf, -1, 0, inf)`` if none.  The star's bucket points are gathered only once a
    neighbour passes ``_moved_star``: most vertices with no valid collapse never need them.
    The cheapest collapse's point places are kept (``S.LT``, ``S.LR``, ``ctr[C_LAST]`` = v)
    for ``_collapse``, which often follows at once."""
    n = _star(S, v, sc)
    best, bw, be, bd = INF, -1, 0, INF
    S.ctr[C_LAST] = -1
    if n < 0:
        return best, bw, be, bd
    Q, kw, P = S.Q, S.kw, S.P
    flt = S.ctr[C_FLOAT] != 0
    _gather(S, sc, n, Q)
    m, old = -1, 0.0  # the squared residuals that the collapse replaces (v's own is 0), once gathered
    nb = 0
    if S.lock[v] & LOCK_MESH:  # on a mesh's boundary: its boundary triangles (``_allowed``)
        nb = _boundary_faces(Q, sc, n, v, S.B)
    if not flt:
        _planes(P, Q, sc, n, G)
    use_max = S.ctr[C_MAXKEY] != 0
    S.stamp[0] += 1
    stamp = S.stamp[0]
    mark[v] = stamp
    # v's last target first: it is often still the best, and a good first bound prunes the
    # others early (the argmin, ties included, does not depend on the order)
    first = S.htgt[v]
    free = S.lock[v] == 0  # a grid's interior point: every neighbour is allowed
    row, brow = 0, 0  # the row of S.LT, S.LR being costed, and the best candidate's
    fails = -1  # the star tet that turned the last neighbour away (``_moved_star``)
    for i in range(-1, n):
        for j in range(1 if i < 0 else 4):
            w = first if i < 0 else Q[i, j]
            if w < 0 or mark[w] == stamp:
                continue
            mark[w] = stamp
            # a star tet's vertices are vertices; the last target may have been removed since
            if i < 0 and not S.isv[w]:
                continue
            if not free and not _allowed(S, v, w, S.B, nb):
                continue
            shared, fails = _moved_star(P, flt, Q, G, sc, kw, n, w, fails)
            if shared <= 0:
                continue
            if m < 0:
                m, old = _gather_points(S, sc, n)
            c, delta = _cost(S, v, w, sc, Q, G, kw, n, m, tol_inf, old, best, use_max, row)
            if c == INF:
                continue
            e = S.deg[w] + n - 2 * shared
            if c < best or (c == best and (e < be or (e == be and w < bw))):
                best, bw, be, bd = c, w, e, delta
                brow, row = row, 1 - row
    if bw >= 0 and m < S.LT.shape[1]:
        S.ctr[C_LAST], S.ctr[C_LROW], S.ctr[C_LM] = v, brow, m
    return best, bw, be, bd


@njit(cache=True, _nrt=False)
def _collapse(S, v, w, sc, n):
    """Move v onto w (v's corners ``sc[:n]``): drop the tets of edge vw, give w the others
    and put v and the points of v's buckets into the tets that now hold them, located as
    ``_cost`` located them.  When the last evaluation was v's and nothing has changed since
    (``ctr[C_LAST]`` = v), its gathered star and the places it kept for w are taken as they
    are: the same tets and residuals, found once."""
    T, P, f, Q, kw, pbuf, res = S.T, S.P, S.f, S.Q, S.kw, S.pbuf, S.res
    kept = S.ctr[C_LAST] == v and S.htgt[v] == w
    S.ctr[C_LAST] = -1
    if kept:  # Q, pbuf (and sc) as ``_best`` gathered them
        S.ctr[C_KEPT] += 1
        m, row = S.ctr[C_LM], S.ctr[C_LROW]
        for i in range(n):
            kw[i] = _has(Q, i, w)
        for k in range(-1, m):
            p = v if k < 0 else pbuf[k]
            S.ptet[p] = S.LT[row, k + 1]
            r = S.LR[row, k + 1]
            S.acc[0] += r * r - res[p] * res[p]
            res[p] = r
    else:
        _gather(S, sc, n, Q)
        m, _ = _gather_points(S, sc, n)
        flt = S.ctr[C_FLOAT] != 0
        if not flt:
            _planes(P, Q, sc, n, S.G)
        for i in range(n):
            kw[i] = _has(Q, i, w)
        # locate with the tets still as they were (``_locate_star`` reads v's slot as w)
        for k in range(-1, m):
            p = v if k < 0 else pbuf[k]
            i, val = _locate_star(P, flt, f, Q, S.G, sc, kw, S.X, n, w, p, -1 if k < 0 else S.phome[k])
            S.ptet[p] = sc[i] >> 2  # i >= 0: the collapse was checked by _cost
            r = f[p] - val
            S.acc[0] += r * r - res[p] * res[p]
            res[p] = r
    for i in range(n):
        c = sc[i]
        t = c >> 2
        S.phead[t] = -1
        if kw[i]:
            S.alive[t] = False
            for j in range(4):
                if T[t, j] != v:
                    _unlink(S, T[t, j], 4 * t + j)
        else:
            T[t, c & 3] = w
            _link(S, w, c)
    S.deg[v] = 0
    S.isv[v] = False
    for k in range(-1, m):
        p = v if k < 0 else pbuf[k]
        t = S.ptet[p]
        S.pnext[p] = S.phead[t]
        S.phead[t] = p


# ----------------------------------------------------------------------------- the queue


@njit(cache=True, _nrt=False, inline='always')
def _before(ka, da, a, kb, db, b):
    """Whether the entry (key ``ka``, degree ``da``, vertex a) comes before (kb, db, b): by
    key, then by the target's tets after the collapse, then by vertex.  A strict total order
    (the vertices differ), so the queue's head, and every collapse made, does not depend on
    how the heap holds its entries."""
    if ka != kb:
        return ka < kb
    return da < db or (da == db and a < b)


@njit(cache=True, _nrt=False)
def _put(S, i, k, d, x):
    """Entry (key k, degree d, vertex x) into heap slot i."""
    S.hv[i] = x
    S.qkey[i] = k
    S.qdeg[i] = d
    S.hpos[x] = i


@njit(cache=True, _nrt=False)
def _sift_up(S, i):
    hv, qkey, qdeg = S.hv, S.qkey, S.qdeg
    x, k, d = hv[i], qkey[i], qdeg[i]
    while i > 0:
        u = (i - 1) // QUEUE_ARITY
        if not _before(k, d, x, qkey[u], qdeg[u], hv[u]):
            break
        _put(S, i, qkey[u], qdeg[u], hv[u])
        i = u
    _put(S, i, k, d, x)


@njit(cache=True, _nrt=False)
def _sift_down(S, i):
    """Move slot i's entry down to its place: a heap of ``QUEUE_ARITY`` children a slot,
    whose keys lie side by side (``S.qkey``), so that the children of a slot are compared
    within a cache line or two, not through the vertices' own arrays::

        slot u:        children QUEUE_ARITY u + 1 ... QUEUE_ARITY u + QUEUE_ARITY
        qkey  [ k0 | k1 k2 k3 k4 | k5 ... k8 | ... ]   hv, qdeg alike; hpos[hv[i]] = i
    """
    hv, qkey, qdeg, nh = S.hv, S.qkey, S.qdeg, S.ctr[C_HN]
    x, k, d = hv[i], qkey[i], qdeg[i]
    while True:
        a = QUEUE_ARITY * i + 1
        if a >= nh:
            break
        c = a
        for j in range(a + 1, min(a + QUEUE_ARITY, nh)):
            if _before(qkey[j], qdeg[j], hv[j], qkey[c], qdeg[c], hv[c]):
                c = j
        if not _before(qkey[c], qdeg[c], hv[c], k, d, x):
            break
        _put(S, i, qkey[c], qdeg[c], hv[c])
        i = c
    _put(S, i, k, d, x)


@njit(cache=True, _nrt=False)
def _queue(S, v, key, w, d, delta):
    """Set v's cheapest collapse (onto w, leaving w with d tets); an inf key takes v out
    of the queue."""
    i = S.hpos[v]
    if key == INF:
        if i >= 0:
            nh = S.ctr[C_HN] - 1
            S.ctr[C_HN] = nh
            S.hpos[v] = -1
            if i < nh:
                x = S.hv[nh]
                _put(S, i, S.qkey[nh], S.qdeg[nh], x)
                _sift_up(S, i)
                _sift_down(S, S.hpos[x])
        return
    S.hkey[v] = key
    S.hsse[v] = delta
    S.htgt[v] = w
    new = i < 0
    if new:  # a new entry, at the end: it can only move up
        i = S.ctr[C_HN]
        S.ctr[C_HN] = i + 1
    _put(S, i, key, d, v)
    _sift_up(S, i)
    if not new:
        _sift_down(S, S.hpos[v])


# ----------------------------------------------------------------------------- drivers


@njit(cache=True, _nrt=False)
def _link_all(S):
    """Corner lists from the tets."""
    M = S.T.shape[0]
    for t in range(M - 1, -1, -1):
        for j in range(3, -1, -1):
            _link(S, S.T[t, j], 4 * t + j)


@njit(cache=True, _nrt=False)
def _init(S, tol_inf):
    """Corner lists from the tets, then every vertex's cheapest collapse."""
    _link_all(S)
    N = S.P.shape[0]
    for v in range(N):
        S.aff[v] = v
    _evaluate(S, S.aff, N, tol_inf)


@njit(cache=True, _nrt=False)
def _grid_template(S, v0, D, O, L, SH):
    """The first evaluation of an interior vertex of a fresh Kuhn split, taken from one of
    them, v0: every interior vertex's star is v0's moved by an index offset, its tets in the
    same star order, and no point lies in a tet yet.  For each neighbour w of v0 (``D[k] =
    w - v0``), as ``_cost`` finds it: ``SH[k] = -1`` if v0 may not move onto w (a moved tet
    would not keep a positive volume), else the count of v0's tets that contain w, with the
    tet of the moved star that holds v0 (its corners as offsets ``O[k]`` from v0, w in v0's
    slot) and v0's integer weights in it ``L[k]`` (the orientations with v0 in each slot).
    Returns the number of neighbours."""
    P, f, Q, G, kw, sc, mark = S.P, S.f, S.Q, S.G, S.kw, S.sc, S.mark
    n = _star(S, v0, sc)
    _gather(S, sc, n, Q)
    _planes(P, Q, sc, n, G)
    S.stamp[0] += 1
    stamp = S.stamp[0]
    mark[v0] = stamp
    K = 0
    for i in range(n):
        for j in range(4):
            w = Q[i, j]
            if mark[w] == stamp:
                continue
            mark[w] = stamp
            D[K] = w - v0
            SH[K] = -1
            shared, _ = _moved_star(P, False, Q, G, sc, kw, n, w, -1)
            if shared > 0:
                t, _ = _locate_star(P, False, f, Q, G, sc, kw, S.X, n, w, v0, -1)
                if t >= 0:
                    s = sc[t] & 3
                    q0 = w if s == 0 else Q[t, 0]
                    q1 = w if s == 1 else Q[t, 1]
                    q2 = w if s == 2 else Q[t, 2]
                    q3 = w if s == 3 else Q[t, 3]
                    O[K, 0], O[K, 1], O[K, 2], O[K, 3] = q0 - v0, q1 - v0, q2 - v0, q3 - v0
                    L[K, 0] = _orient(P, False, v0, q1, q2, q3)
                    L[K, 1] = _orient(P, False, q0, v0, q2, q3)
                    L[K, 2] = _orient(P, False, q0, q1, v0, q3)
                    L[K, 3] = _orient(P, False, q0, q1, q2, v0)
                    SH[K] = shared
            K += 1
    return K


@njit(cache=True, _nrt=False)
def _best_by_template(S, v, K, D, O, L, SH, tol_inf):
    """``_best`` of an interior vertex v of a fresh Kuhn split from v0's template
    (``_grid_template``): the same interpolated value (eq. 13, the same weights in the same
    slot order), key, tie rule and degrees, without gathering v's star."""
    f, deg = S.f, S.deg
    use_max = S.ctr[C_MAXKEY] != 0
    n = deg[v]
    best, bw, be, bd = INF, -1, 0, INF
    for k in range(K):
        if SH[k] < 0:
            continue
        w = v + D[k]
        l0, l1, l2, l3 = L[k, 0], L[k, 1], L[k, 2], L[k, 3]
        val = (l0 * f[v + O[k, 0]] + l1 * f[v + O[k, 1]] + l2 * f[v + O[k, 2]] + l3 * f[v + O[k, 3]]) \
            / (l0 + l1 + l2 + l3)
        r = f[v] - val
        if 0.0 <= tol_inf < abs(r):
            continue
        delta = r * r - 0.0
        c = abs(r) if use_max else delta
        e = deg[w] + n - 2 * SH[k]
        if c < best or (c == best and (e < be or (e == be and w < bw))):
            best, bw, be, bd = c, w, e, delta
    return best, bw, be, bd


@njit(cache=True)
def _init_grid(S, tol_inf, nx, ny, nz):
    """``_init`` of a fresh Kuhn split of an ``nx x ny x nz`` grid (points in C order): the
    interior vertices that may move are evaluated from one template (``_grid_template``),
    the others by ``_best``; the same queue."""
    _link_all(S)
    N = S.P.shape[0]
    D = np.zeros(64, np.int64)
    O = np.zeros((64, 4), np.int64)
    L = np.zeros((64, 4))  # integers, held exactly
    SH = np.zeros(64, np.int64)
    K = -1
    v0 = (ny + 1) * nz + 1
    if nx >= 3 and ny >= 3 and nz >= 3 and S.deg[v0] == 24:  # the Kuhn split's star: 24 tets, 14 neighbours
        K = _grid_template(S, v0, D, O, L, SH)
    for v in range(N):
        i, j, k = v // (ny * nz), (v // nz) % ny, v % nz
        if K >= 0 and 0 < i < nx - 1 and 0 < j < ny - 1 and 0 < k < nz - 1 and S.lock[v] == 0:
            key, x, d, delta = _best_by_template(S, v, K, D, O, L, SH, tol_inf)
        else:
            key, x, d, delta = _best(S, v, S.sc, S.G, S.mark, tol_inf)
        _queue(S, v, key, x, d, delta)


@njit(cache=True, _nrt=False)
def _run(S, stop_count, sse_max, key_max, tol_inf):
    """Collapse until ``stop_count`` vertices remain (0), the cheapest collapse would take the
    squared-residual sum above ``sse_max`` or has a key above ``key_max`` (2), or no valid
    collapse is left (1).  With lazy updates, a marked vertex at the head of the queue is
    re-evaluated before anything else."""
    sc, aff, mark = S.sc, S.aff, S.mark
    S.ctr[C_LAST] = -1  # whatever the caller did between two runs, no kept places are trusted
    while S.ctr[C_NV] > stop_count:
        if S.ctr[C_HN] == 0:
            return 1
        v = S.hv[0]
        if S.dirty[v]:
            S.dirty[v] = False
            key, x, d, delta = _best(S, v, sc, S.G, mark, tol_inf)
            _queue(S, v, key, x, d, delta)
            continue
        w = S.htgt[v]
        if S.acc[0] + S.hsse[v] > sse_max or S.hkey[v] > key_max:
            return 2
        if S.ctr[C_PTOP] + 4 * (S.deg[w] + S.deg[v]) + 16 > S.cpool.shape[0]:
            # w's corners may move (twice, from a small segment) and the pool lacks the room
            return 3
        n = _star(S, v, sc)
        # the vertices whose tets change: their collapses are evaluated again
        S.stamp[0] += 1
        stamp = S.stamp[0]
        mark[v] = stamp
        na = 0
        for i in range(n):
            t = sc[i] >> 2
            for j in range(4):
                u = S.T[t, j]
                if mark[u] != stamp:
                    mark[u] = stamp
                    aff[na] = u
                    na += 1
        _collapse(S, v, w, sc, n)
        _queue(S, v, INF, -1, 0, INF)
        S.removed[S.ctr[C_NREM]] = v
        S.into[S.ctr[C_NREM]] = w
        S.ctr[C_NREM] += 1
        S.ctr[C_NV] -= 1
        if S.ctr[C_LAZY]:
            na = _mark_queued(S, aff, na)
        _evaluate(S, aff, na, tol_inf)
    return 0


@njit(cache=True, _nrt=False)
def _replay(S, vs, ws, start):
    """Make the collapses ``vs[k] -> ws[k]``, from ``k = start`` on, in order: collapses that
    an earlier run made from the same start (each valid when it was made), so no cost is
    computed and no queue kept.  Returns how many are made in all: fewer than ``len(vs)``
    when the corner pool lacks room (compact it and call again from there)."""
    sc = S.sc
    S.ctr[C_LAST] = -1
    for k in range(start, vs.shape[0]):
        v, w = vs[k], ws[k]
        if S.ctr[C_PTOP] + 4 * (S.deg[w] + S.deg[v]) + 16 > S.cpool.shape[0]:
            return k
        n = _star(S, v, sc)
        _collapse(S, v, w, sc, n)
        S.removed[S.ctr[C_NREM]] = v
        S.into[S.ctr[C_NREM]] = w
        S.ctr[C_NREM] += 1
        S.ctr[C_NV] -= 1
    return vs.shape[0]


@njit(cache=True, _nrt=False)
def _mark_queued(S, verts, m):
    """Lazy updates: mark the queued vertices of ``verts[:m]`` and move the others (which may
    now have a valid collapse) to the front; returns their number, to evaluate at once."""
    k = 0
    for i in range(m):
        u = verts[i]
        if S.hpos[u] >= 0:
            S.dirty[u] = True
        elif not S.lock[u] & LOCK_ALL:
            verts[k] = u
            k += 1
    return k


@njit(cache=True, _nrt=False)
def _flush(S, tol_inf):
    """Re-evaluate every marked vertex (in index order) and clear the marks."""
    m = 0
    for v in range(S.P.shape[0]):
        if S.dirty[v]:
            S.dirty[v] = False
            S.aff[m] = v
            m += 1
    _evaluate(S, S.aff, m, tol_inf)


@njit(cache=True, _nrt=False)
def _evaluate(S, verts, m, tol_inf):
    """Queue the cheapest collapses of ``verts[:m]``."""
    for i in range(m):
        key, x, d, delta = _best(S, verts[i], S.sc, S.G, S.mark, tol_inf)
        _queue(S, verts[i], key, x, d, delta)


@njit(cache=True)
def _weights(S):
    """For every point, the 4 vertices and barycentric weights of the tet that holds it
    (a vertex: itself with weight 1)."""
    N = S.P.shape[0]
    flt = S.ctr[C_FLOAT] != 0
    verts = np.empty((N, 4), np.int64)
    w = np.zeros((N, 4))
    for p in range(N):
        t = S.ptet[p]
        if S.isv[p] or t < 0:
            verts[p, :] = p
            w[p, 0] = 1.0
            continue
        q0, q1, q2, q3 = S.T[t, 0], S.T[t, 1], S.T[t, 2], S.T[t, 3]
        l0 = _orient(S.P, flt, p, q1, q2, q3)
        l1 = _orient(S.P, flt, q0, p, q2, q3)
        l2 = _orient(S.P, flt, q0, q1, p, q3)
        l3 = _orient(S.P, flt, q0, q1, q2, p)
        D = l0 + l1 + l2 + l3
        verts[p, 0], verts[p, 1], verts[p, 2], verts[p, 3] = q0, q1, q2, q3
        w[p, 0], w[p, 1], w[p, 2], w[p, 3] = l0 / D, l1 / D, l2 / D, l3 / D
    return verts, w


def aot_exports(state_type):
    """The kernels that :class:`~trivsel.decimation.Decimation` calls from Python, by the
    names it calls them (``init``, ``init_grid``, ``link``, ``run``, ``replay``, ``flush``, ``weights``), each with its signature
    for ``state_type`` (the numba type of a :class:`~trivsel.decimation.State`); everything
    else is compiled into their machine code."""
    from numba import types as nt

    f8, i8 = nt.float64, nt.int64
    return {"init": (_init, nt.none(state_type, f8)),
            "init_grid": (_init_grid, nt.none(state_type, f8, i8, i8, i8)),
            "link": (_link_all, nt.none(state_type)),
            "replay": (_replay, i8(state_type, i8[::1], i8[::1], i8)),
            "run": (_run, i8(state_type, i8, f8, f8, f8)),
            "flush": (_flush, nt.none(state_type, f8)),
            "weights": (_weights, nt.Tuple((nt.int64[:, ::1], nt.float64[:, ::1]))(state_type))}
