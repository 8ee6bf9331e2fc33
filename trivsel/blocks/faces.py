"""The lower-dimensional stages of a block reduction: block edges (1-D) and block faces (2-D).

A volume reduced in blocks that share faces stays conforming, and its global E_inf
tolerance holds, if every shared piece is reduced once and then held fixed:

1. each shared block *edge* as 1-D data (:func:`reduce_polyline`);
2. each shared block *face* as 2-D data, with the kept points of its four edges
   as fixed border vertices (:func:`reduce_face`);
3. each block in 3-D, with its faces' triangles as fixed boundary (elsewhere).

A face is reduced by greedy insertion of its worst interior point into a
triangulation of the grid rectangle, in integer grid coordinates (u, v) (u the
first array axis): exact int64 orientation tests, linear interpolation on each
triangle.  It starts from the boundary, as the tetrahedral method does
(Hamann & Chen (1994), section 3): the interior point nearest the centre is
joined to every border segment.  After every insertion the edges around the new
point are swapped when that lowers the squared error: the data-dependent
swapping of Hamann & Chen (1994), section 4, on triangles.

The mesh is kept in flat arrays: triangle ``t`` has half-edges ``3t, 3t+1, 3t+2``;
half-edge ``e`` runs from ``tv[e]`` to ``tv[_nxt(e)]`` (vertices are flat grid
indices, counter-clockwise); ``adj[e]`` is the opposite half-edge in the
neighbouring triangle, -1 on the rectangle's border.  Each triangle's bucket is
the set of grid points in the closed triangle, rasterised row by row with exact
integer bounds; a max-heap orders the triangles by the worst candidate in their
bucket.
"""

from __future__ import annotations

import numbers

import numba
import numpy as np

from ..exceptions import InputError, shown

__all__ = ["reduce_polyline", "reduce_face", "check_face_mesh", "face_residuals"]

#: a swap must lower the squared error of its quadrilateral by this fraction ...
_REL_DECREASE = 1e-12
#: ... and by more than (this * max|f|)^2 per grid point: rounding noise (planar data) decides no swap
_NOISE = 1e-9


# --- input checks -------------------------------------------------------------------------

def _check_tol(tol_inf) -> float:
    if isinstance(tol_inf, bool) or not isinstance(tol_inf, numbers.Real) or not np.isfinite(tol_inf) \
            or tol_inf < 0:
        raise InputError(f"tol_inf must be a finite number >= 0, got {shown(tol_inf)}")
    return float(tol_inf)


def _check_values(values, ndim: int) -> np.ndarray:
    """``values`` as a C-contiguous float64 array of ``ndim`` dimensions, each of length >= 2."""
    a = np.asarray(values)
    if a.dtype.kind not in "biuf":
        raise InputError(f"values must be real numbers, got dtype {a.dtype}")
    if a.ndim != ndim or min(a.shape, default=0) < 2:
        raise InputError(f"values must be a {ndim}-D array with at least 2 points along each axis, "
                         f"got shape {a.shape}")
    a = np.ascontiguousarray(a, dtype=np.float64)
    bad = np.argwhere(~np.isfinite(a))
    if bad.size:
        where = tuple(int(i) for i in bad[0])
        raise InputError(f"values has a non-finite value {a[where]} at index {where if ndim > 1 else where[0]}")
    return a


def _border_ring(shape, border) -> np.ndarray:
    """The border points of ``border`` as flat indices, counter-clockwise in (u, v) from (0, 0):
    along v = 0, u = nu - 1, v = nv - 1 (backwards), u = 0 (backwards)."""
    nu, nv = shape
    b = np.asarray(border)
    if b.dtype != np.bool_ or b.shape != (nu, nv):
        raise InputError(f"border must be a boolean array of shape {(nu, nv)}, got {b.dtype} {b.shape}")
    for corner in ((0, 0), (nu - 1, 0), (nu - 1, nv - 1), (0, nv - 1)):
        if not b[corner]:
            raise InputError(f"border must include every corner, got False at {corner}")
    inner = np.argwhere(b[1:-1, 1:-1])
    if inner.size:
        raise InputError(f"border must be False off the rectangle's border, got True at "
                         f"{tuple(int(i) + 1 for i in inner[0])}")
    u = np.arange(nu)
    v = np.arange(nv)
    sides = [u[:-1] * nv,                         # v = 0, u rising
             (nu - 1) * nv + v[:-1],              # u = nu - 1, v rising
             u[:0:-1] * nv + nv - 1,              # v = nv - 1, u falling
             v[:0:-1]]                            # u = 0, v falling
    ring = np.concatenate(sides)
    return ring[b.ravel()[ring]].astype(np.int64)


# --- 1-D: block edges ---------------------------------------------------------------------

def reduce_polyline(values, *, tol_inf) -> np.ndarray:
    """Greedy point selection on a 1-D signal sampled at 0, 1, ..., n - 1.

    Parameters
    ----------
    values : array_like of float, shape (n,)
        The samples, n >= 2, all finite.
    tol_inf : float
        Absolute tolerance (>= 0) of every sample's interpolation error.

    Returns
    -------
    numpy.ndarray of int64
        The sorted indices kept, 0 and n - 1 always among them.  Linear
        interpolation between consecutive kept indices is within ``tol_inf``
        (``<=``) of every sample.

    Raises
    ------
    ValueError
        For a non-finite value, fewer than two samples or a bad ``tol_inf``.

    Notes
    -----
    Greedy insertion of the worst point (ties: the smallest index).  Inserting a
    point changes only the segment that contains it, so the order in which
    segments are refined does not matter: each segment is split at its worst
    point until all are within the tolerance, which is the greedy result.
    """
    f = _check_values(values, 1)
    tol = _check_tol(tol_inf)
    n = f.size
    keep = [0, n - 1]
    todo = [(0, n - 1)]
    while todo:
        i, j = todo.pop()
        if j - i < 2:
            continue
        t = np.arange(1, j - i) / (j - i)
        r = np.abs(f[i + 1:j] - (f[i] + (f[j] - f[i]) * t))
        k = int(np.argmax(r))
        if r[k] > tol:
            k += i + 1
            keep.append(k)
            todo += [(i, k), (k, j)]
    return np.array(sorted(keep), dtype=np.int64)


# --- 2-D: the compiled kernel -------------------------------------------------------------

@numba.njit(cache=True)
def _nxt(e):
    return e - e % 3 + (e + 1) % 3


@numba.njit(cache=True)
def _prv(e):
    return e - e % 3 + (e + 2) % 3


@numba.njit(cache=True)
def _orient(a, b, c, nv):
    """Twice the signed area of grid points a, b, c (flat indices): > 0 counter-clockwise in (u, v)."""
    au, av = a // nv, a % nv
    return (b // nv - au) * (c % nv - av) - (b % nv - av) * (c // nv - au)


@numba.njit(cache=True)
def _span(u, a, b, c, nv):
    """The v-range [lo, hi] of the closed counter-clockwise triangle (a, b, c) on row u
    (empty: lo > hi).

    Each edge p -> q keeps the points x with orient(p, q, x) >= 0, i.e.
    ``(qu - pu) (v - pv) >= (qv - pv) (u - pu)``: a bound on v, exact in integers.
    """
    lo = min(min(a % nv, b % nv), c % nv)
    hi = max(max(a % nv, b % nv), c % nv)
    p = a
    for q in (b, c, a):
        pu, pv = p // nv, p % nv
        du = q // nv - pu
        r = (q % nv - pv) * (u - pu)
        if du > 0:
            lo = max(lo, pv - (-r) // du)   # v - pv >= ceil(r / du)
        elif du < 0:
            hi = min(hi, pv + r // du)      # v - pv <= floor(r / du)
        elif r > 0:
            hi = lo - 1
        p = q
    return lo, hi


@numba.njit(cache=True)
def _plane(f, a, b, c, nv):
    """The linear interpolant on triangle (a, b, c) as ``f[a] + gu (u - au) + gv (v - av)``:
    returns (f[a], gu, gv)."""
    au, av = a // nv, a % nv
    bu, bv = b // nv - au, b % nv - av
    cu, cv = c // nv - au, c % nv - av
    fa = f[au, av]
    db = f[b // nv, b % nv] - fa
    dc = f[c // nv, c % nv] - fa
    det = float(bu * cv - bv * cu)
    return fa, (db * cv - dc * bv) / det, (dc * bu - db * cu) / det


@numba.njit(cache=True)
def _row_sse(f, u, a, b, c, nv, skip_lo, skip_hi):
    """Squared residuals on row u of the closed triangle (a, b, c), leaving out v in
    [skip_lo, skip_hi]: returns (sum, count, lo, hi), [lo, hi] the triangle's span."""
    lo, hi = _span(u, a, b, c, nv)
    fa, gu, gv = _plane(f, a, b, c, nv)
    base = fa + gu * (u - a // nv) - gv * (a % nv)
    s = 0.0
    n = 0
    for v in range(lo, hi + 1):
        if skip_lo <= v <= skip_hi:
            continue
        r = f[u, v] - (base + gv * v)
        s += r * r
        n += 1
    return s, n, lo, hi


@numba.njit(cache=True)
def _swap_sse(f, a, b, c, d, nv):
    """Squared error of the quadrilateral a d b c before and after swapping its diagonal
    a-b for c-d, each closed grid point counted once: returns (before, after, points)."""
    before = 0.0
    after = 0.0
    npts = 0
    for u in range(min(min(a, b), min(c, d)) // nv, max(max(a, b), max(c, d)) // nv + 1):
        s0, n0, lo, hi = _row_sse(f, u, a, b, c, nv, nv, nv)      # v < nv: nothing left out
        s1, n1, _, _ = _row_sse(f, u, b, a, d, nv, lo, hi)
        s2, _, lo, hi = _row_sse(f, u, a, d, c, nv, nv, nv)
        s3, _, _, _ = _row_sse(f, u, d, b, c, nv, lo, hi)
        before += s0 + s1
        after += s2 + s3
        npts += n0 + n1
    return before, after, npts


@numba.njit(cache=True)
def _worst(f, isv, tv, t, nv):
    """Triangle t's worst candidate: the interior non-vertex grid point of the closed
    triangle farthest from the interpolant (ties: smallest flat index), and |residual|;
    (-1, 0.0) when it has none."""
    nu = f.shape[0]
    a, b, c = tv[3 * t], tv[3 * t + 1], tv[3 * t + 2]
    fa, gu, gv = _plane(f, a, b, c, nv)
    au, av = a // nv, a % nv
    best = -1
    worst = 0.0
    for u in range(max(min(min(a, b), c) // nv, 1), min(max(max(a, b), c) // nv, nu - 2) + 1):
        lo, hi = _span(u, a, b, c, nv)
        base = fa + gu * (u - au) - gv * av
        for v in range(max(lo, 1), min(hi, nv - 2) + 1):
            k = u * nv + v
            r = abs(f[u, v] - (base + gv * v))
            if not isv[k] and (best < 0 or r > worst):
                best = k
                worst = r
    return best, worst


@numba.njit(cache=True)
def _above(err, best, s, t):
    """Heap order: triangle s before t (larger error; ties: smaller point index)."""
    return err[s] > err[t] or (err[s] == err[t] and best[s] < best[t])


@numba.njit(cache=True)
def _requeue(heap, hpos, err, best, t, n):
    """Put triangle t (or take it out, when it has no candidate) at its place in the
    max-heap ``heap[:n]`` (``hpos``: each triangle's slot, -1 outside); returns the new n."""
    i = hpos[t]
    if best[t] < 0:
        if i < 0:
            return n
        hpos[t] = -1
        n -= 1
        if i == n:
            return n
        t = heap[n]                      # the last entry fills the hole
    elif i < 0:
        i = n
        n += 1
    while i > 0 and _above(err, best, t, heap[(i - 1) // 2]):
        s = heap[(i - 1) // 2]
        heap[i] = s
        hpos[s] = i
        i = (i - 1) // 2
    while 2 * i + 1 < n:
        c = 2 * i + 1
        if c + 1 < n and _above(err, best, heap[c + 1], heap[c]):
            c += 1
        if not _above(err, best, heap[c], t):
            break
        heap[i] = heap[c]
        hpos[heap[c]] = i
        i = c
    heap[i] = t
    hpos[t] = i
    return n


@numba.njit(cache=True)
def _link(adj, e, g):
    """Make half-edges e and g opposite each other (g = -1: e is on the border)."""
    adj[e] = g
    if g >= 0:
        adj[g] = e


@numba.njit(cache=True)
def _fan(tv, adj, p, ids, ring, outer, k):
    """Triangles ``ids[i] = (ring[i], ring[i+1], p)`` around p, ring closed, counter-clockwise;
    edge ring[i] -> ring[i+1] opposite ``outer[i]``.  Serves the start cone, the 1 -> 3
    split (ring a b c) and the 2 -> 4 split (ring c a d b, p on a-b)::

              c                          c
             /|\\                        /|\\
            / | \\                      / | \\
           /  p  \\                    a--p--b     (p on edge a-b)
          / /   \\ \\                   \\ | /
         a ------- b                    \\|/
                                         d
    """
    for i in range(k):
        t = ids[i]
        tv[3 * t] = ring[i]
        tv[3 * t + 1] = ring[(i + 1) % k]
        tv[3 * t + 2] = p
        _link(adj, 3 * t, outer[i])
    for i in range(k):
        _link(adj, 3 * ids[i] + 1, 3 * ids[(i + 1) % k] + 2)


@numba.njit(cache=True)
def _flip(tv, adj, e):
    """Swap the diagonal a-b of the quadrilateral a d b c (e = a -> b in (a, b, c), its twin
    in (b, a, d)) for c-d: the triangles become (c, a, d) and (d, b, c), same slots::

              c                 c
             / \\               /|\\
            /   \\             / | \\
           a-----b    ->     a  |  b
            \\   /             \\ | /
             \\ /               \\|/
              d                 d
    """
    g = adj[e]
    t0, t1 = e // 3, g // 3
    a, b, c, d = tv[e], tv[_nxt(e)], tv[_prv(e)], tv[_prv(g)]
    ca, bc, ad, db = adj[_prv(e)], adj[_nxt(e)], adj[_nxt(g)], adj[_prv(g)]
    tv[3 * t0], tv[3 * t0 + 1], tv[3 * t0 + 2] = c, a, d
    tv[3 * t1], tv[3 * t1 + 1], tv[3 * t1 + 2] = d, b, c
    _link(adj, 3 * t0, ca)
    _link(adj, 3 * t0 + 1, ad)
    _link(adj, 3 * t1, db)
    _link(adj, 3 * t1 + 1, bc)
    _link(adj, 3 * t0 + 2, 3 * t1 + 2)


@numba.njit(cache=True)
def _pushed(stack, n, x):
    """``stack`` with x at ``stack[n]``, grown when full."""
    if n == stack.size:
        grown = np.empty(2 * n, np.int64)
        for i in range(n):                 # a loop: slice assignment compiles numba's string code
            grown[i] = stack[i]
        stack = grown
    stack[n] = x
    return stack


@numba.njit(cache=True)
def _greedy(f, ring, start, tol, max_vertices, noise2, tv, adj, err, isv, verts, work):
    """Greedy insertion on the face ``f`` from the cone of ``start`` over the border ``ring``.

    The caller allocates the arrays (numba's array constructors would add to the
    compile time): ``tv`` and ``adj`` (3 per triangle, ``adj`` all -1), ``err`` (per
    triangle), ``isv`` (per grid point, all False), ``verts`` (room for every vertex)
    and ``work`` (8 rows of at least as many entries as triangles and border
    vertices, all -1).  Fills ``verts`` in insertion order and ``tv`` with the
    triangles; returns their counts.
    """
    nv = f.shape[1]
    nb = ring.size
    best, heap, hpos = work[0], work[1], work[2]
    stamp = work[3]                               # vertex count when the triangle last changed
    touched, ids, ring4, outer = work[4], work[5], work[6], work[7]
    stack = np.empty(64, np.int64)

    # the cone from the start point over every border segment (section 3)
    for i in range(nb):
        verts[i] = ring[i]
        isv[ring[i]] = True
        touched[i] = i
        ids[i] = i
        stamp[i] = nb + 1
    _fan(tv, adj, start, ids, ring, outer, nb)
    nt = nb
    ntouch = nb
    p = start
    nvert = nb
    hn = np.int64(0)      # typed, not a literal: the helpers get one signature each
    while True:
        isv[p] = True
        verts[nvert] = p
        nvert += 1
        # legalise every edge of the new triangles: swap where the squared error drops
        # (section 4), passing the new quadrilateral's outer edges on to the same test.
        # Every swap lowers the total, so this ends, and then no edge whose triangles
        # changed can lower it by a swap.
        ns = np.int64(0)
        for i in range(3 * ntouch):
            stack = _pushed(stack, ns, 3 * touched[i // 3] + i % 3)
            ns += 1
        while ns > 0:
            ns -= 1
            e = stack[ns]
            g = adj[e]
            if g < 0:
                continue
            a, b, c, d = tv[e], tv[_nxt(e)], tv[_prv(e)], tv[_prv(g)]
            if _orient(a, d, c, nv) <= 0 or _orient(d, b, c, nv) <= 0:
                continue                          # not strictly convex
            before, after, npts = _swap_sse(f, a, b, c, d, nv)
            if before - after <= _REL_DECREASE * before + npts * noise2:
                continue                          # ties keep the present diagonal
            _flip(tv, adj, e)
            for t in (e // 3, g // 3):
                if stamp[t] != nvert:
                    stamp[t] = nvert
                    touched[ntouch] = t
                    ntouch += 1
                for h in (3 * t, 3 * t + 1):
                    stack = _pushed(stack, ns, h)
                    ns += 1
        for i in range(ntouch):
            t = touched[i]
            best[t], err[t] = _worst(f, isv, tv, t, nv)
            hn = _requeue(heap, hpos, err, best, t, hn)

        # the next point: the worst candidate of the worst triangle
        if hn == 0 or nvert >= max_vertices or err[heap[0]] <= tol:
            break
        t = heap[0]
        p = best[t]
        on = 3
        for k in range(3):
            if _orient(tv[3 * t + k], tv[_nxt(3 * t + k)], p, nv) == 0:
                on = k                            # on an edge, never a border one: p is interior
        if on == 3:                               # inside t: 1 -> 3
            k = 3
            for i in range(3):
                ring4[i] = tv[3 * t + i]
                outer[i] = adj[3 * t + i]
            ids[0], ids[1], ids[2] = t, nt, nt + 1
            nt += 2
        else:                                     # on edge a-b shared with (b, a, d): 2 -> 4
            k = 4
            e = 3 * t + on
            g = adj[e]
            ring4[0], ring4[1], ring4[2], ring4[3] = tv[_prv(e)], tv[e], tv[_prv(g)], tv[_nxt(e)]
            outer[0], outer[1], outer[2], outer[3] = adj[_prv(e)], adj[_nxt(g)], adj[_prv(g)], adj[_nxt(e)]
            ids[0], ids[1], ids[2], ids[3] = t, g // 3, nt, nt + 1
            nt += 2
        _fan(tv, adj, p, ids, ring4, outer, k)
        ntouch = k
        for i in range(k):
            touched[i] = ids[i]
            stamp[ids[i]] = nvert + 1
    return nvert, nt


# --- 2-D: block faces ---------------------------------------------------------------------

def _canonical(tri) -> np.ndarray:
    """Triangles (m, 3), each turned to start at its smallest index (orientation kept),
    in lexicographic order: one spelling of a mesh."""
    tri = np.asarray(tri, np.int64).reshape(-1, 3)
    first = np.argmin(tri, axis=1)
    tri = tri[np.arange(len(tri))[:, None], (first[:, None] + np.arange(3)) % 3]
    return tri[np.lexsort(tri.T[::-1])]


def _area2(nv, tri) -> np.ndarray:
    """Twice the signed area of each triangle (m, 3) of flat indices, exact (int64)."""
    u, v = np.divmod(np.asarray(tri, np.int64), nv)
    return (u[:, 1] - u[:, 0]) * (v[:, 2] - v[:, 0]) - (v[:, 1] - v[:, 0]) * (u[:, 2] - u[:, 0])


def _strip(shape, border) -> np.ndarray:
    """A face without interior points (nu == 2 or nv == 2): walk along the two long sides,
    each step joining the next border point with the smaller coordinate (ties: the first
    side) to the current point of the other side.  No grid point lies off the border edges,
    so the choice changes no residual."""
    nu, nv = shape
    b = np.asarray(border)
    if nu == 2:
        sides = [np.flatnonzero(b[0]), np.flatnonzero(b[1]) + nv]
        along = [sides[0], sides[1] - nv]
    else:
        sides = [np.flatnonzero(b[:, 0]) * nv, np.flatnonzero(b[:, 1]) * nv + 1]
        along = [sides[0] // nv, sides[1] // nv]
    i = j = 0
    tri = []
    while i + 1 < len(sides[0]) or j + 1 < len(sides[1]):
        if j + 1 == len(sides[1]) or (i + 1 < len(sides[0]) and along[0][i + 1] <= along[1][j + 1]):
            tri.append((sides[0][i], sides[0][i + 1], sides[1][j]))
            i += 1
        else:
            tri.append((sides[1][j], sides[1][j + 1], sides[0][i]))
            j += 1
    tri = np.array(tri, np.int64)
    neg = _area2(nv, tri) < 0
    tri[neg] = tri[neg][:, ::-1]
    return tri


def reduce_face(values, border, *, tol_inf, max_vertices=None):
    """Greedy point selection on a block face, its border vertices fixed.

    Parameters
    ----------
    values : array_like of float, shape (nu, nv)
        The face's samples on a regular grid, nu, nv >= 2, all finite.  Work is in
        integer grid coordinates (u, v), u along the first axis: an affine map of the
        grid changes no linear interpolation error, so the spacing does not matter.
    border : array_like of bool, shape (nu, nv)
        True exactly at the border points that must be vertices (the kept points of
        the four edges, e.g. from :func:`reduce_polyline`); every corner True, every
        interior point False.
    tol_inf : float
        Absolute tolerance (>= 0) of the interpolation error at every point.
    max_vertices : int, optional
        Stop when the face has this many vertices (border ones included); at least
        the border vertices plus the start point.  Default: no limit.

    Returns
    -------
    vertices : numpy.ndarray of int64, shape (k,)
        Sorted flat (C-order) indices of the vertices into the face grid.
    triangles : numpy.ndarray of int64, shape (m, 3)
        Flat indices, counter-clockwise in (u, v), each row starting at its smallest
        index, rows in lexicographic order.  They cover the rectangle exactly, are
        conforming, and the edges on the rectangle's border are exactly the segments
        between consecutive border vertices, so that a neighbouring block sees the
        same edges.

    Raises
    ------
    ValueError
        For non-finite values, a bad ``border`` mask (a corner False, an interior
        point True), a bad ``tol_inf`` or too small a ``max_vertices``.

    Notes
    -----
    Only interior points are candidates: border points are never inserted, and
    the tolerance holds at them only if it holds along each border segment on its
    own (as :func:`reduce_polyline` with the same ``tol_inf`` ensures).

    With interior points the face starts from the boundary (Hamann & Chen (1994),
    section 3): the interior point nearest the centre (ties: the smallest flat
    index) is joined to every border segment, a cone valid since the rectangle is
    convex.  The start point is always inserted, even when the border alone meets
    the tolerance.  Then the interior point farthest from the interpolant (ties:
    the smallest flat index) is inserted until every point is within ``tol_inf``
    or ``max_vertices`` is reached: inside a triangle it splits it in three, on an
    edge it splits both triangles of that edge.

    After each insertion (the start's cone included) every edge of the new
    triangles is legalised by data-dependent swapping (Hamann & Chen (1994),
    section 4): an interior edge whose two triangles form a strictly convex
    quadrilateral is swapped if that lowers the sum of squared residuals of the
    grid points in the closed quadrilateral by more than a relative 1e-12 (and by
    more than the rounding noise, (1e-9 max|f|)^2 a point); a tie keeps the present
    edge.  Each swap passes the new quadrilateral's outer edges on to the same
    test; border edges are never swapped.  So the result is locally optimal: no
    single swap lowers the squared error by more than that margin.

    A face without interior points (nu == 2 or nv == 2) is triangulated as a strip
    between its two long sides.
    """
    f = _check_values(values, 2)
    tol = _check_tol(tol_inf)
    nu, nv = f.shape
    ring = _border_ring(f.shape, border)
    nint = (nu - 2) * (nv - 2)
    if max_vertices is not None:
        least = ring.size + (nint > 0)
        if isinstance(max_vertices, bool) or not isinstance(max_vertices, numbers.Integral) \
                or max_vertices < least:
            raise InputError(f"max_vertices must be an integer >= {least} (the border vertices and "
                             f"the start point), got {shown(max_vertices)}")
    if nint == 0:
        return np.sort(ring), _canonical(_strip(f.shape, border))
    u, v = np.divmod(np.arange(nu * nv), nv)
    d2 = (2 * u - (nu - 1)) ** 2 + (2 * v - (nv - 1)) ** 2    # 4 x squared distance to the centre
    d2[(u == 0) | (u == nu - 1) | (v == 0) | (v == nv - 1)] = d2.max() + 1
    start = int(np.argmin(d2))
    limit = ring.size + nint if max_vertices is None else int(max_vertices)
    noise2 = (_NOISE * float(np.abs(f).max())) ** 2
    tmax = ring.size + 2 * nint                   # 2 V - nb - 2 triangles for V vertices
    tv = np.empty(3 * tmax, np.int64)
    verts = np.empty(ring.size + nint, np.int64)
    nvert, nt = _greedy(f, ring, start, tol, limit, noise2, tv, np.full(3 * tmax, -1, np.int64),
                        np.zeros(tmax), np.zeros(nu * nv, np.bool_), verts, np.full((8, tmax), -1, np.int64))
    return np.sort(verts[:nvert]), _canonical(tv[:3 * nt])


def check_face_mesh(shape, vertices, triangles, border) -> None:
    """Check a face mesh as :func:`reduce_face` promises it (pure numpy).

    Parameters
    ----------
    shape : tuple of int
        (nu, nv), the face's grid.
    vertices : array_like of int
        Sorted flat indices of the vertices.
    triangles : array_like of int, shape (m, 3)
        Flat indices, counter-clockwise in (u, v).
    border : array_like of bool, shape (nu, nv)
        The border vertices the mesh must have.

    Raises
    ------
    AssertionError
        Unless every triangle has positive area, the areas add up to
        (nu - 1)(nv - 1), every interior edge is shared by exactly two triangles
        with opposite orientations, every border edge lies on the rectangle's
        boundary between consecutive points of ``border``, and the vertices on the
        boundary are exactly those of ``border``.
    ValueError
        For a bad ``border`` mask.
    """
    nu, nv = shape
    ring = _border_ring((nu, nv), border)
    verts = np.asarray(vertices, np.int64)
    tri = np.asarray(triangles, np.int64)

    def at(k):
        return f"({k // nv}, {k % nv})"

    assert tri.ndim == 2 and tri.shape[1] == 3 and len(tri), f"triangles must be (m, 3), m >= 1, got {tri.shape}"
    assert tri.min() >= 0 and tri.max() < nu * nv, f"triangle index outside the {nu}x{nv} grid"
    assert np.all(np.diff(verts) > 0), "vertices are not sorted and distinct"
    used = np.unique(tri)
    assert np.array_equal(used, verts), \
        f"triangle corners and vertices differ: {np.setxor1d(used, verts)[:5].tolist()} ..."
    area2 = _area2(nv, tri)
    if np.any(area2 <= 0):
        k = int(np.argmax(area2 <= 0))
        raise AssertionError(f"triangle {k} {' '.join(at(i) for i in tri[k])} has area {area2[k] / 2} <= 0")
    assert area2.sum() == 2 * (nu - 1) * (nv - 1), \
        f"triangles cover area {area2.sum() / 2}, the rectangle {(nu - 1) * (nv - 1)}"
    a = tri.ravel()
    b = tri[:, [1, 2, 0]].ravel()
    n = nu * nv
    key = a * n + b
    uniq, count = np.unique(key, return_counts=True)
    if np.any(count > 1):
        k = int(uniq[np.argmax(count > 1)])
        raise AssertionError(f"edge {at(k // n)} -> {at(k % n)} is in {count.max()} triangles the same way round")
    lone = np.sort(key[~np.isin(b * n + a, key)])
    la, lb = np.divmod(lone, n)
    (au, av), (bu, bv) = np.divmod(la, nv), np.divmod(lb, nv)
    off = ~(((au == bu) & ((au == 0) | (au == nu - 1))) | ((av == bv) & ((av == 0) | (av == nv - 1))))
    if np.any(off):
        k = int(np.argmax(off))
        raise AssertionError(f"edge {at(la[k])} -> {at(lb[k])} has one triangle but is not on the "
                             f"rectangle's boundary")
    on_edge = np.isin(verts // nv, (0, nu - 1)) | np.isin(verts % nv, (0, nv - 1))
    extra = np.setxor1d(verts[on_edge], ring)
    assert not extra.size, f"boundary vertices differ from border at {', '.join(at(k) for k in extra[:5])}"
    segments = np.sort(ring * n + np.roll(ring, -1))
    assert np.array_equal(lone, segments), \
        "border edges are not the segments between consecutive border points, counter-clockwise"


def face_residuals(values, vertices, triangles) -> np.ndarray:
    """|f - linear interpolant| at every point of the face (pure numpy).

    Parameters
    ----------
    values : array_like of float, shape (nu, nv)
        The face's samples.
    vertices : array_like of int
        Flat indices of the vertices; every triangle corner must be one.
    triangles : array_like of int, shape (m, 3)
        Flat indices, counter-clockwise in (u, v), covering the rectangle.

    Returns
    -------
    numpy.ndarray of float, shape (nu, nv)
        The absolute residuals; a point on several closed triangles gets the last
        one's (they agree up to rounding).

    Raises
    ------
    ValueError
        If a triangle corner is not a vertex or some point lies in no triangle.
    """
    f = _check_values(values, 2)
    nu, nv = f.shape
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    if not np.all(np.isin(tri, np.asarray(vertices, np.int64))):
        raise InputError("triangles use a point that is not among the vertices")
    # rasterise every closed triangle row by row (t: the triangle of each row, then of each point)
    u, v = np.divmod(tri, nv)
    u0 = u.min(axis=1)
    height = u.max(axis=1) - u0 + 1
    t = np.repeat(np.arange(len(tri)), height)
    row = u0[t] + np.arange(t.size) - np.repeat(np.cumsum(height) - height, height)
    lo, hi = v.min(axis=1)[t], v.max(axis=1)[t]
    for i in range(3):                            # edge p -> q keeps du (v - pv) >= dv (row - pu)
        pu, pv = u[t, i], v[t, i]
        du, r = u[t, (i + 1) % 3] - pu, (v[t, (i + 1) % 3] - pv) * (row - pu)
        step = np.where(du == 0, 1, du)
        lo = np.where(du > 0, np.maximum(lo, pv - (-r) // step), lo)
        hi = np.where(du < 0, np.minimum(hi, pv + r // step), hi)
        hi = np.where((du == 0) & (r > 0), lo - 1, hi)
    count = np.maximum(hi - lo + 1, 0)
    k = np.repeat(np.arange(t.size), count)
    col = lo[k] + np.arange(k.size) - np.repeat(np.cumsum(count) - count, count)
    t, row = t[k], row[k]
    # the interpolant by exact integer barycentric weights
    w = [(u[t, (i + 1) % 3] - row) * (v[t, (i + 2) % 3] - col) - (v[t, (i + 1) % 3] - col) * (u[t, (i + 2) % 3] - row)
         for i in range(3)]
    fv = f.ravel()[tri[t]]
    fit = (fv[:, 0] * w[0] + fv[:, 1] * w[1] + fv[:, 2] * w[2]) / (w[0] + w[1] + w[2])
    res = np.full(nu * nv, np.nan)
    res[row * nv + col] = np.abs(f[row, col] - fit)
    res = res.reshape(nu, nv)
    if np.isnan(res).any():
        k = tuple(int(i) for i in np.argwhere(np.isnan(res))[0])
        raise InputError(f"the triangles do not cover point {k}")
    return res
