r"""Bottom-up selection by half-edge collapse (``method="decimate"``), beyond the paper.

The paper builds its mesh top-down: from the hull points, insert points in curvature
order (sections 3-4).  Decimation goes the other way.  Start from every grid point,
tetrahedralised by the Kuhn split (6 tetrahedra per cell around its main diagonal),
and repeatedly remove the vertex whose removal raises the squared error least::

        u                 u            a vertex v is removed by moving it onto a
       /|\               /|            neighbour w (a half-edge collapse v -> w):
      / | \             / |            the tetrahedra around the edge vw vanish,
     a--v--w   --->    a--+--w         the others around v get w instead of v
      \ | /             \ |
       \|/               \|
        d                 d

Because w is an original point, the vertices stay a subset of the data: the result
is a true selection with the data values at its vertices, as in the paper (section
5's E_RMS and E_inf, eqs. 19-20, score it).  Every original point that is not a
vertex lies in one tetrahedron (its *bucket*); its residual is ``f - L`` with ``L``
the linear interpolant of eq. 13 there.

* **Cost** of a collapse: the exact change of the sum of squared residuals over the
  original points (eq. 19's numerator).  Only the points in v's tetrahedra and v itself
  change tetrahedron, so the cost is computed from those buckets.
* **Validity**: every tetrahedron that gets w keeps a positive volume (exact integer
  orientation test on grid coordinates).  The region of v's star is then the cone from
  w over its far faces, so the mesh still fills the box.  A point on the box keeps the
  box: a corner never moves, a point on an edge of the box moves only along that edge,
  and a point on a face only within that face.
* **Order**: an indexed priority queue holds each vertex's cheapest valid collapse
  (ties: fewer tetrahedra around the target, then the smaller vertex index); after a
  collapse the vertices of the changed tetrahedra are re-evaluated.  *Lazily*, a
  queued vertex whose tetrahedra changed is only marked, keeps its queued cost, and is
  re-evaluated when it reaches the head of the queue (then queued again, or collapsed
  if still the cheapest).  That saves most evaluations (about 13 vertices change per
  collapse) but lets some changed vertices wait behind their stale cost, so
  :func:`reduce_by_collapse` collapses lazily only while far from where it stops, and
  in the exact greedy order near it.
* **Stop**: at a vertex count, before the collapse that would take E_RMS above a
  tolerance, or when no collapse keeps every residual within an E_inf tolerance.

Geometry is on integer grid coordinates: barycentric weights are unchanged by the
grid's spacing and origin (an affine map), so the interpolant, the residuals and
the validity are those of the grid in world coordinates.
"""

from __future__ import annotations

from itertools import permutations
from typing import NamedTuple

import numpy as np
from numba import njit

from .predicates import orient3d_value

__all__ = ["grid_tetrahedra", "Decimation"]

INF = np.inf

# lock bits of a point: bit a (a = 0, 1, 2) set when the point is on the box's low or high
# face normal to axis a; LOCK_ALL when it may not move at all
LOCK_ALL = 8
#: Corners (4 per tet) below which the mesh's indices are int32 (above, int64; the same results)
INT32_CORNERS = 2**31
#: Room in the corner pool, over the corners' segments (``_segments``);
#: when a segment must move and the pool is full, it is compacted (``Decimation._compact``)
POOL_ROOM = 1.5
#: The most tetrahedra around one vertex that a collapse considers (a vertex with more stays)
STAR_CAPACITY = 1 << 16


def grid_tetrahedra(shape):
    """The Kuhn split of the grid ``shape``: 6 positively oriented tetrahedra per cell,
    each a monotone path from the cell's low corner to its high corner, so that
    neighbouring cells split their shared faces alike.  Returns ``(M, 4)`` int64
    indices of the points in C order."""
    n = np.asarray(shape, np.int64)
    if np.any(n < 2):
        raise ValueError(f"a grid needs at least 2 points per axis, got {tuple(shape)}")
    step = np.array([n[1] * n[2], n[2], 1], np.int64)
    i, j, k = np.meshgrid(*(np.arange(m - 1) for m in n), indexing="ij")
    base = ((i * n[1] + j) * n[2] + k).ravel()
    out = []
    for perm in permutations(range(3)):
        a = base
        b = a + step[perm[0]]
        c = b + step[perm[1]]
        d = c + step[perm[2]]
        # the path's orientation is the sign of the permutation
        inv = sum(perm[x] > perm[y] for x in range(3) for y in range(x + 1, 3)) % 2
        out.append(np.stack([b, a, c, d] if inv else [a, b, c, d], axis=1))
    # a cell's 6 tets side by side: a vertex's tets lie close together in memory
    return np.stack(out, axis=1).reshape(-1, 4)


class State(NamedTuple):
    """The flat arrays of a decimation (numba compiles field access statically)::

        P[p]          integer grid coordinates of point p
        f[p]          its value
        T[t]          the 4 vertices of tet t (orient3d > 0) while alive[t]
        corner c = 4 t + s is slot s of tet t; the corners of vertex v are the segment
        cpool[vstart[v]:vstart[v] + deg[v]] (capacity vcap[v]), newest last: reading a
        star is one contiguous read, not a chain of cache misses (see ``_link``)
        phead[t]      first point in the bucket of tet t; pnext[p] the next; ptet[p] the tet
        (indices into the mesh are int32 while the corners fit, see ``INT32_CORNERS``)
        res[p]        f - L at p (0 at vertices); isv[p] whether p is a vertex
        dirty[v]      v is queued with a cost from before its tets last changed (lazy)
        lock[p]       the box constraint (bits above)
        heap          hv[0:hn] vertices by (hkey, vertex); hpos[v] their slots (-1: not
                      queued); htgt[v] the target of v's cheapest collapse
        acc[0]        the sum of squared residuals; ctr: [n_vertices, n_removed, heap size,
                      the max criterion, lazy updates, the corner pool's top]
        scratch       sc a star's corners, Q their tets' vertices, G their far faces'
                      planes, kw whether each holds the target being tried; pbuf
                      the points of the star's buckets, phome the star index of each;
                      mark stamps of points (stamp[0] the last)
    """

    P: np.ndarray
    f: np.ndarray
    T: np.ndarray
    alive: np.ndarray
    cpool: np.ndarray
    vstart: np.ndarray
    vcap: np.ndarray
    phead: np.ndarray
    pnext: np.ndarray
    ptet: np.ndarray
    res: np.ndarray
    isv: np.ndarray
    lock: np.ndarray
    hv: np.ndarray
    hpos: np.ndarray
    hkey: np.ndarray
    hsse: np.ndarray
    htgt: np.ndarray
    mark: np.ndarray
    deg: np.ndarray
    hdeg: np.ndarray
    removed: np.ndarray
    dirty: np.ndarray
    sc: np.ndarray
    Q: np.ndarray
    G: np.ndarray
    kw: np.ndarray
    stamp: np.ndarray
    pbuf: np.ndarray
    phome: np.ndarray
    aff: np.ndarray
    acc: np.ndarray
    ctr: np.ndarray


C_NV, C_NREM, C_HN, C_MAXKEY, C_LAZY, C_PTOP = 0, 1, 2, 3, 4, 5

# ----------------------------------------------------------------------------- geometry


@njit(cache=True, _nrt=False)
def _orient(P, a, b, c, d):
    """Six times the signed volume of (a, b, c, d): exact on integer coordinates."""
    return orient3d_value(P[a, 0], P[a, 1], P[a, 2], P[b, 0], P[b, 1], P[b, 2],
                          P[c, 0], P[c, 1], P[c, 2], P[d, 0], P[d, 1], P[d, 2])


@njit(cache=True, _nrt=False)
def _value_in(P, f, q0, q1, q2, q3, p):
    """``(inside, L)``: whether p is in the closed tet (q0, q1, q2, q3) and, if so, the
    linear interpolant of the vertex values there (eq. 13)."""
    l0 = _orient(P, p, q1, q2, q3)
    if l0 < 0:
        return False, 0.0
    l1 = _orient(P, q0, p, q2, q3)
    if l1 < 0:
        return False, 0.0
    l2 = _orient(P, q0, q1, p, q3)
    if l2 < 0:
        return False, 0.0
    l3 = _orient(P, q0, q1, q2, p)
    if l3 < 0:
        return False, 0.0
    D = float(l0 + l1 + l2 + l3)
    return True, (l0 * f[q0] + l1 * f[q1] + l2 * f[q2] + l3 * f[q3]) / D


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
    """Copy the star's tets (corners ``sc[:n]``) into ``Q`` and its buckets' points into
    ``S.pbuf`` (``S.phome``: the star index of each point's tet), in star order; returns the
    number of points and the sum of their squared residuals."""
    T, phead, pnext, res, pbuf, phome = S.T, S.phead, S.pnext, S.res, S.pbuf, S.phome
    m = 0
    old = 0.0
    for i in range(n):
        t = sc[i] >> 2
        Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3] = T[t, 0], T[t, 1], T[t, 2], T[t, 3]
        p = phead[t]
        while p >= 0:
            old += res[p] * res[p]
            pbuf[m] = p
            phome[m] = i
            m += 1
            p = pnext[p]
    return m, old


@njit(cache=True, _nrt=False)
def _value_moved(P, f, Q, sc, i, w, p):
    """``_value_in`` for star tet ``Q[i]`` with v's slot holding w."""
    s = sc[i] & 3
    return _value_in(P, f, w if s == 0 else Q[i, 0], w if s == 1 else Q[i, 1], w if s == 2 else Q[i, 2],
                     w if s == 3 else Q[i, 3], p)


@njit(cache=True, _nrt=False)
def _locate_star(P, f, Q, sc, kw, n, w, p, hint):
    """Where p lies once v has moved onto w: ``(i, L)`` for the star tet ``Q[i]`` that keeps
    w (``kw[i]`` false), trying star index ``hint`` first; ``(-1, 0)`` if none holds p."""
    if hint >= 0 and not kw[hint]:
        ok, val = _value_moved(P, f, Q, sc, hint, w, p)
        if ok:
            return hint, val
    for i in range(n):
        if i == hint or kw[i]:
            continue
        ok, val = _value_moved(P, f, Q, sc, i, w, p)
        if ok:
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
def _allowed(S, v, w):
    """The box constraint: w is on every box face that v is on."""
    lk = S.lock[v]
    if lk & LOCK_ALL:
        return False
    for a in range(3):
        if (lk >> a) & 1 and S.P[w, a] != S.P[v, a]:
            return False
    return True


@njit(cache=True, _nrt=False)
def _cost(S, v, w, sc, Q, G, kw, n, m, tol_inf, old, bound, use_max):
    """``(key, delta, shared)`` if v moves onto w (v's star gathered by ``_gather``: tets
    ``Q[:n]``, their planes ``G``, bucket points ``S.pbuf[:m]``): ``delta`` the change of the
    squared-residual sum, ``key`` that change or, with the max criterion, the largest
    |residual| of the points that move (v and its buckets' points); the key is inf if the
    collapse is invalid (a tet would not keep a positive volume), takes a residual above
    ``tol_inf`` (negative: no limit) or cannot beat ``bound``.  ``shared``: the number of
    v's tets that contain w.  Sets ``kw[:n]`` (which tets contain w)."""
    P, f, pbuf, phome = S.P, S.f, S.pbuf, S.phome
    shared = 0
    wx, wy, wz = P[w, 0], P[w, 1], P[w, 2]
    for i in range(n):
        h = _has(Q, i, w)
        kw[i] = h
        if h:
            shared += 1
            continue
        if G[i, 0] * wx + G[i, 1] * wy + G[i, 2] * wz + G[i, 3] <= 0:
            return INF, INF, shared
    if shared == 0:
        return INF, INF, shared
    i, val = _locate_star(P, f, Q, sc, kw, n, w, v, -1)
    if i < 0:
        return INF, INF, shared
    r = f[v] - val
    if 0.0 <= tol_inf < abs(r):
        return INF, INF, shared
    new = r * r
    mx = abs(r)
    for k in range(m):
        # the rest only adds: no better than the best so far
        if (mx if use_max else new - old) > bound:
            return INF, INF, shared
        p = pbuf[k]
        i, val = _locate_star(P, f, Q, sc, kw, n, w, p, phome[k])
        if i < 0:
            return INF, INF, shared
        r = f[p] - val
        if 0.0 <= tol_inf < abs(r):
            return INF, INF, shared
        new += r * r
        mx = max(mx, abs(r))
    return (mx if use_max else new - old), new - old, shared


@njit(cache=True, _nrt=False)
def _best(S, v, sc, G, mark, tol_inf):
    """v's cheapest valid collapse ``(key, w, tets of w after, change of the squared-residual
    sum)`` over its neighbours w (ties: fewer tets around w, then the smaller w);
    ``(inf, -1, 0, inf)`` if none."""
    n = _star(S, v, sc)
    best, bw, be, bd = INF, -1, 0, INF
    if n < 0:
        return best, bw, be, bd
    Q, kw = S.Q, S.kw
    # the squared residuals that the collapse replaces (v's own is 0)
    m, old = _gather(S, sc, n, Q)
    _planes(S.P, Q, sc, n, G)
    use_max = S.ctr[C_MAXKEY] != 0
    S.stamp[0] += 1
    stamp = S.stamp[0]
    mark[v] = stamp
    # v's last target first: it is often still the best, and a good first bound prunes the
    # others early (the argmin, ties included, does not depend on the order)
    first = S.htgt[v]
    for i in range(-1, n):
        for j in range(1 if i < 0 else 4):
            w = first if i < 0 else Q[i, j]
            if w < 0 or mark[w] == stamp:
                continue
            mark[w] = stamp
            if not S.isv[w] or not _allowed(S, v, w):
                continue
            c, delta, shared = _cost(S, v, w, sc, Q, G, kw, n, m, tol_inf, old, best, use_max)
            if c == INF:
                continue
            e = S.deg[w] + n - 2 * shared
            if c < best or (c == best and (e < be or (e == be and w < bw))):
                best, bw, be, bd = c, w, e, delta
    return best, bw, be, bd


@njit(cache=True, _nrt=False)
def _collapse(S, v, w, sc, n):
    """Move v onto w (v's corners ``sc[:n]``): drop the tets of edge vw, give w the others
    and put v and the points of v's buckets into the tets that now hold them, located as
    ``_cost`` located them."""
    T, P, f, Q, kw, pbuf, res = S.T, S.P, S.f, S.Q, S.kw, S.pbuf, S.res
    m, _ = _gather(S, sc, n, Q)
    for i in range(n):
        kw[i] = _has(Q, i, w)
    # locate with the tets still as they were (``_locate_star`` reads v's slot as w)
    for k in range(-1, m):
        p = v if k < 0 else pbuf[k]
        i, val = _locate_star(P, f, Q, sc, kw, n, w, p, -1 if k < 0 else S.phome[k])
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


@njit(cache=True, _nrt=False)
def _before(S, a, b):
    ka, kb = S.hkey[a], S.hkey[b]
    if ka != kb:
        return ka < kb
    da, db = S.hdeg[a], S.hdeg[b]
    return da < db or (da == db and a < b)


@njit(cache=True, _nrt=False)
def _put(S, i, x):
    """Vertex x into heap slot i."""
    S.hv[i] = x
    S.hpos[x] = i


@njit(cache=True, _nrt=False)
def _sift_up(S, i):
    x = S.hv[i]
    while i > 0 and _before(S, x, S.hv[(i - 1) >> 1]):
        _put(S, i, S.hv[(i - 1) >> 1])
        i = (i - 1) >> 1
    _put(S, i, x)


@njit(cache=True, _nrt=False)
def _sift_down(S, i):
    hv, nh = S.hv, S.ctr[C_HN]
    x = hv[i]
    while 2 * i + 1 < nh:
        j = 2 * i + 1
        if j + 1 < nh and _before(S, hv[j + 1], hv[j]):
            j += 1
        if not _before(S, hv[j], x):
            break
        _put(S, i, hv[j])
        i = j
    _put(S, i, x)


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
                _put(S, i, x)
                _sift_up(S, i)
                _sift_down(S, S.hpos[x])
        return
    S.hkey[v] = key
    S.hsse[v] = delta
    S.htgt[v] = w
    S.hdeg[v] = d
    if i < 0:
        i = S.ctr[C_HN]
        S.ctr[C_HN] = i + 1
        _put(S, i, v)
        _sift_up(S, i)
    else:
        _sift_up(S, i)
        _sift_down(S, S.hpos[v])


# ----------------------------------------------------------------------------- drivers


@njit(cache=True, _nrt=False)
def _init(S, tol_inf):
    """Corner lists from the tets, then every vertex's cheapest collapse."""
    M = S.T.shape[0]
    for t in range(M - 1, -1, -1):
        for j in range(3, -1, -1):
            _link(S, S.T[t, j], 4 * t + j)
    N = S.P.shape[0]
    for v in range(N):
        S.aff[v] = v
    _evaluate(S, S.aff, N, tol_inf)


@njit(cache=True, _nrt=False)
def _run(S, stop_count, sse_max, tol_inf):
    """Collapse until ``stop_count`` vertices remain (0), the cheapest collapse would take the
    squared-residual sum above ``sse_max`` (2), or no valid collapse is left (1).  With lazy
    updates, a marked vertex at the head of the queue is re-evaluated before anything else."""
    sc, aff, mark = S.sc, S.aff, S.mark
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
        if S.acc[0] + S.hsse[v] > sse_max:
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
        S.ctr[C_NREM] += 1
        S.ctr[C_NV] -= 1
        if S.ctr[C_LAZY]:
            na = _mark_queued(S, aff, na)
        _evaluate(S, aff, na, tol_inf)
    return 0


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
    verts = np.empty((N, 4), np.int64)
    w = np.zeros((N, 4))
    for p in range(N):
        t = S.ptet[p]
        if S.isv[p] or t < 0:
            verts[p, :] = p
            w[p, 0] = 1.0
            continue
        q0, q1, q2, q3 = S.T[t, 0], S.T[t, 1], S.T[t, 2], S.T[t, 3]
        l0 = _orient(S.P, p, q1, q2, q3)
        l1 = _orient(S.P, q0, p, q2, q3)
        l2 = _orient(S.P, q0, q1, p, q3)
        l3 = _orient(S.P, q0, q1, q2, p)
        D = float(l0 + l1 + l2 + l3)
        verts[p, 0], verts[p, 1], verts[p, 2], verts[p, 3] = q0, q1, q2, q3
        w[p, 0], w[p, 1], w[p, 2], w[p, 3] = l0 / D, l1 / D, l2 / D, l3 / D
    return verts, w


def _segments(deg):
    """Capacities and starts of consecutive corner segments for vertices of degrees ``deg``:
    each with half its count again as room, plus 4."""
    cap = deg + deg // 2 + 4
    return cap, np.cumsum(cap) - cap


def _aligned_empty(shape, dtype, line=64):
    """An empty C-order array whose data starts on a cache-line boundary, so that rows of a
    size that divides ``line`` never straddle two lines."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape)) * dtype.itemsize
    buf = np.empty(nbytes + line, np.uint8)
    off = -buf.ctypes.data % line
    return buf[off:off + nbytes].view(dtype).reshape(shape)


class Decimation:
    """A decimation in progress on grid data (integer coordinates ``ijk``, C-order points).

    ``run(count, sse_max)`` collapses down to ``count`` vertices (or to the tolerance);
    between calls the state is kept, so one run passes several counts.  ``lock`` is
    ``"box"`` (corners fixed; edge and face points move along their edge or face) or
    ``"all"`` (every box point fixed: only interior points are removed).  ``key`` orders
    the collapses: ``"sse"`` by the change of the squared-residual sum (aims at E_RMS),
    ``"max"`` by the largest |residual| of the points that move (aims at E_inf).  ``lazy``
    starts with lazy updates of the queue (the module's docstring); :attr:`lazy` switches.
    """

    def __init__(self, ijk, shape, values, *, tol_inf=None, lock="box", key="sse", lazy=False):
        P = np.ascontiguousarray(ijk, np.int64)
        N = P.shape[0]
        Tg = grid_tetrahedra(shape)
        M = Tg.shape[0]
        # indices as int32 while they fit (and counts and lock bits smaller still): the queue
        # visits the volume in cost order, so a collapse reads these arrays at random, and
        # the smaller they are the more of them stays in cache
        ix = np.int32 if 4 * M < INT32_CORNERS else np.int64
        T = _aligned_empty((M, 4), ix)
        T[...] = Tg
        deg = np.bincount(Tg.ravel(), minlength=N)
        del Tg
        cap, vstart = _segments(deg)
        hi = np.asarray(shape, np.int64) - 1
        on = (P == 0) | (P == hi)
        lk = (on[:, 0] * 1 + on[:, 1] * 2 + on[:, 2] * 4).astype(np.int64)
        lk[on.all(axis=1)] |= LOCK_ALL
        if lock == "all":
            lk[on.any(axis=1)] |= LOCK_ALL
        self.tol_inf = -1.0 if tol_inf is None else float(tol_inf)
        self.S = State(P=P, f=np.ascontiguousarray(values, np.float64), T=T, alive=np.ones(M, np.bool_),
                       cpool=np.full(int(cap.sum() * POOL_ROOM), -1, ix), vstart=vstart, vcap=cap.astype(np.int32),
                       phead=np.full(M, -1, ix),
                       pnext=np.full(N, -1, ix), ptet=np.full(N, -1, ix), res=np.zeros(N),
                       isv=np.ones(N, np.bool_), lock=lk.astype(np.int8), hv=np.zeros(N, ix), hpos=np.full(N, -1, ix),
                       hkey=np.full(N, INF), hsse=np.full(N, INF), htgt=np.full(N, -1, ix), hdeg=np.zeros(N, np.int32),
                       deg=np.zeros(N, np.int32), mark=np.zeros(N, np.int64),
                       removed=np.zeros(N, np.int64), dirty=np.zeros(N, np.bool_), sc=np.zeros(STAR_CAPACITY, np.int64),
                       Q=np.zeros((STAR_CAPACITY, 4), np.int64), G=np.zeros((STAR_CAPACITY, 4), np.int64),
                       kw=np.zeros(STAR_CAPACITY, np.bool_), stamp=np.zeros(1, np.int64),
                       pbuf=np.zeros(N, np.int64), phome=np.zeros(N, np.int64), aff=np.zeros(N, np.int64), acc=np.zeros(1),
                       ctr=np.array([N, 0, 0, key == "max", bool(lazy), cap.sum()], np.int64))
        self.compactions = 0
        _init(self.S, self.tol_inf)

    @property
    def n_vertices(self):
        return int(self.S.ctr[C_NV])

    @property
    def lazy(self):
        """Whether the queue is updated lazily; setting it false re-evaluates every marked
        vertex, so that the queue holds exact costs again."""
        return bool(self.S.ctr[C_LAZY])

    @lazy.setter
    def lazy(self, on):
        if self.lazy and not on:
            _flush(self.S, self.tol_inf)
        self.S.ctr[C_LAZY] = bool(on)

    @property
    def sse(self):
        return float(self.S.acc[0])

    def run(self, count, sse_max=INF):
        """Collapse to ``count`` vertices; returns 0 (reached), 1 (no valid collapse left)
        or 2 (the next collapse would exceed ``sse_max``)."""
        while True:
            code = int(_run(self.S, int(count), float(sse_max), self.tol_inf))
            if code != 3:
                return code
            self._compact()

    def _compact(self):
        """Copy every vertex's corners, in order, into a new pool, each segment with half its
        count again as room, and above the segments as much room as they take, and at least
        what ``_run`` asks for any collapse (so that it never asks twice in a row)."""
        S = self.S
        v = np.flatnonzero(S.deg > 0)
        d = S.deg[v].astype(np.int64)
        cap, start = _segments(d)
        room = max(int(cap.sum() * (max(POOL_ROOM, 2.0) - 1.0)), 8 * int(d.max()) + 16)
        pool = np.full(int(cap.sum()) + room, -1, S.cpool.dtype)
        k = np.arange(d.sum()) - np.repeat(np.cumsum(d) - d, d)
        pool[np.repeat(start, d) + k] = S.cpool[np.repeat(S.vstart[v], d) + k]
        S.vstart[v] = start
        S.vcap[:] = 0
        S.vcap[v] = cap
        S.ctr[C_PTOP] = cap.sum()
        self.S = S._replace(cpool=pool)
        self.compactions += 1

    def removed(self):
        """The removed points, in order of removal."""
        return self.S.removed[: self.S.ctr[C_NREM]].copy()

    def vertices(self):
        return np.flatnonzero(self.S.isv)

    def tetrahedra(self):
        return self.S.T[self.S.alive].astype(np.int64)

    def residuals(self):
        return self.S.res.copy()

    def point_weights(self):
        return _weights(self.S)


#: Target wall time of one call into the compiled loop, so that Ctrl-C stops a run promptly.
CHUNK_SECONDS = 0.25
#: Default of ``exact_within``: lazy updates while more than twice the target count of
#: vertices remain (or E_RMS, E_inf below half their tolerances).
EXACT_WITHIN = 2.0


def _far(dec, target, exact_within, tol_rms, tol_inf, N):
    """Whether the decimation is far enough from its stop for lazy updates: more than
    ``exact_within`` times ``target`` vertices, E_RMS below ``tol_rms / exact_within`` and
    E_inf below ``tol_inf / exact_within``."""
    if not dec.n_vertices > exact_within * target:
        return False
    if tol_rms is not None and dec.sse * exact_within ** 2 >= float(tol_rms) ** 2 * N:
        return False
    return tol_inf is None or float(np.max(np.abs(dec.S.res))) * exact_within < float(tol_inf)


def reduce_by_collapse(data, targets, *, tol_rms=None, tol_inf=None, candidates="all", key="sse",
                       exact_within=EXACT_WITHIN, values=("data",), interior=None, check=None, progress=None,
                       t_start=None):
    """The whole run of ``method="decimate"`` for :func:`trivsel.reduce`.

    Collapses from the full grid down through ``targets`` (counts, visited in
    descending order), or until E_RMS would exceed ``tol_rms`` or no collapse keeps
    every residual within ``tol_inf``.  The queue is updated lazily while more than
    ``exact_within`` times the target count of vertices remain and E_RMS and E_inf are
    below ``tol_rms`` and ``tol_inf`` over ``exact_within``; nearer the stop, and for
    every stopping decision, it holds exact costs (``inf``: exact throughout).  Returns ``(snapshots, selected, stats,
    seconds)``: the snapshots ascending by count (:class:`trivsel.reduction.Snapshot`),
    the points in the order in which a selection grows (the final vertices in index
    order, then the removed points from last to first: ``selected[:k]`` is the
    selection of a snapshot with ``k`` points), the counters, and the seconds spent on
    the snapshots' errors and fits.
    """
    import math
    import time

    from .norms import error_norms
    from .reduction import Snapshot

    t_start = time.perf_counter() if t_start is None else t_start
    N = data.n_points
    interior = data.interior_mask() if interior is None else interior
    dec = Decimation(data.ijk, data.shape, data.values, tol_inf=tol_inf,
                     lock="all" if candidates == "interior" else "box", key=key)
    sse_max = INF if tol_rms is None else float(tol_rms) ** 2 * N * (1.0 + 1e-12)
    shots, t_errors, step, stopped, near = [], 0.0, 4096, False, False
    for target in sorted(set(int(t) for t in targets), reverse=True):
        while not stopped and dec.n_vertices > target:
            stop_at = max(target, dec.n_vertices - step)
            dec.lazy = not near and _far(dec, target, exact_within, tol_rms, tol_inf, N)
            if dec.lazy:
                stop_at = max(stop_at, math.floor(exact_within * target))
            t0 = time.perf_counter()
            code = dec.run(stop_at, sse_max)
            took = time.perf_counter() - t0
            step = int(min(max(step * CHUNK_SECONDS / max(took, 1e-6), 256), 4 * step))
            if code != 0 and dec.lazy:
                near = True  # a stop is decided with exact costs only
                continue
            stopped = code != 0
            if progress is not None:
                r = dec.S.res
                progress(dec.n_vertices, target, float(np.sqrt(max(dec.sse, 0.0) / N)), float(np.max(np.abs(r))),
                         time.perf_counter() - t_start)
        te = time.perf_counter()
        if check is not None:
            check(dec)
        r = dec.residuals()
        fit = None
        if "fit" in values:
            from .fitting import fit_on_mesh

            fit = fit_on_mesh(dec, data.values, interior)
        m = dec.n_vertices
        shots.append(Snapshot(fraction=m / N, n_selected=m, selected=None, tets=dec.tetrahedra(), residuals=r,
                              errors=error_norms(r, interior), seconds=time.perf_counter() - t_start, fit=fit))
        t_errors += time.perf_counter() - te
        if stopped:
            break
    removed = dec.removed()
    selected = np.concatenate([dec.vertices(), removed[::-1]])
    snaps = shots[::-1]
    for s in snaps:
        s.selected = selected[: s.n_selected].copy()
    stats = {"collapses": int(len(removed)), "tets": int(dec.S.alive.sum())}
    return snaps, selected, stats, t_errors


def compile_kernels():
    """Compile (or load from numba's cache) every kernel of a decimation, with a run on a
    3 x 3 x 3 grid (lazy updates, then exact ones); returns the number of entry kernels
    (the others are compiled into them)."""
    g = np.indices((3, 3, 3)).reshape(3, -1).T
    dec = Decimation(g, (3, 3, 3), np.arange(27.0) % 5, lazy=True)
    dec.run(16)
    dec.lazy = False
    dec.run(8)
    dec.point_weights()
    return sum(1 for f in (_init, _run, _flush, _weights) if f.signatures)
