"""The data-dependent tetrahedral mesh (section 4) as flat arrays and small named operations.

Storage (no object per element; preallocated, recycled through a free list)::

    tets[t]   = (v0, v1, v2, v3)     original point indices, orient3d > 0
    nbr[t, i] = tet across the face opposite v_i, or -1 on the hull
    pool[bstart[t] : bstart[t] + blen[t]]
              = the original points in the *closed* tet t (vertices and points on
                faces and edges included: a point on a shared face is in both tets)
    tsse, tmax, tcnt = squared-residual sum, max |residual| and point count of t

Every change of the mesh - the three insertion cases (i)-(iii) of section 4, the
2-3 / 3-2 flips of configuration 1 (Fig. 2) and the 4-4 flip of configuration 2
(Fig. 3) - is "replace these old tets by these new quadruples" and goes through
one primitive, :func:`_replace`, which matches faces to keep neighbour links
symmetric (the analogue of delaunator's ``_link``), redistributes the old tets'
points to the new tets and updates the per-tet errors (eqs. 14-15) and the global
residuals.  Nothing else writes ``nbr``.

The state is a tuple of arrays (see :func:`make_state`) so that the compiled
functions can be cached on disk; the Python class :class:`TetMesh` wraps it for
tests and for :mod:`trivsel.reduction`.

Speed rules learnt by sampling (``benchmarks/README.md``): numba increments and
decrements the reference count of every array an ordinary function receives (29
for the state tuple) and of every array variable reassigned in a loop.  So the
helpers of the swap loop (``*_at`` variants) allocate nothing and are compiled with
``_nrt=False``: no reference counting at all, whether they receive arrays or the
state tuple; and nothing in :func:`swap`'s inner loops rebinds an array.  Helpers are compiled for
one signature each (:func:`_pin_signatures`); :func:`compile_kernels` fills the
on-disk cache in two halves.
On grids a point-in-tet test is four dot products with the tet's integer face
planes (:func:`_tet_data`), the exact sub-volumes of eq. (13), computed once per tet
and loop rather than once per point.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .predicates import orient3d_float, orient3d_float_sign, orient3d_int

# indices into the state tuple
_P, _IC, _F, _TETS, _NBR, _ALIVE, _FREE, _BSTART, _BLEN, _POOL = range(10)
_TSSE, _TMAX, _TCNT, _MARK, _RESID, _OWNER, _ISVERT, _WBUF, _CTR, _FOPT, _ACC, _OMARK = range(10, 22)
# greedy selection: each tet's worst candidate point and a binary max-heap over tets
_TBEST, _TBESTR, _TVER, _HKEY, _HTET, _HVER, _CAND = range(22, 29)
# swap's memory of evaluated configurations when it lasts the whole run (see _config_key)
_MKEY, _MVAL = 29, 30

# counters (int64 array)
C_HW, C_NFREE, C_POOLTOP, C_NALIVE, C_STAMP, C_ERROR = 0, 1, 2, 3, 4, 5
C_FLIP23, C_FLIP32, C_FLIP44, C_NVERT, C_ABOVE, C_OSTAMP = 6, 7, 8, 9, 10, 11
C_CASE1, C_CASE2, C_CASE3, C_ROUNDCAP = 12, 13, 14, 15
C_HEAPN = 16
C_FLIP22 = 17
C_LASTM = 18  # points gathered by the last evaluation (see _evaluate_at's ``reuse``)
C_EVALS, C_MEMHITS = 19, 20  # configurations swap evaluated / found in its memory

#: Swap rounds (flips) per call that mean "until nothing improves" (``max_rounds``'s default)
UNLIMITED_ROUNDS = 100000

# float options
O_USEINT, O_CRIT, O_OWNVERT, O_RELTOL, O_ABSTOL, O_TOLINF, O_FIRST, O_MAXROUNDS, O_GREEDY, O_GKEY, O_BFLIP = range(11)
O_RUNMEM = 11

CRITERIA = {"rms": 0, "max": 1, "sse": 2}

# error codes
ERR_TETCAP, ERR_POOLCAP, ERR_LINK, ERR_UNCOVERED, ERR_DUPLICATE = 1, 2, 3, 4, 5

# Local face i is opposite local vertex i.  FACE_IN[i] lists the other three local
# vertices ordered so that vertex i lies on the positive side:
# orient3d(v[f0], v[f1], v[f2], v[i]) > 0 for a positively oriented tet.
FACE_IN = np.array([[1, 3, 2], [0, 2, 3], [0, 3, 1], [0, 1, 2]], dtype=np.int64)
# the six edges of a tet as local vertex pairs
EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)


def _edge_parities():
    """EDGE_EVEN[i, j]: whether the permutation (i, j, k, l) of local vertices, k < l the
    other two, is even, i.e. orient3d(v_i, v_j, v_k, v_l) has the tet's own sign."""
    even = np.zeros((4, 4), np.bool_)
    for i in range(4):
        for j in range(4):
            if i != j:
                perm = [i, j] + [m for m in range(4) if m not in (i, j)]
                inversions = sum(perm[p] > perm[q] for p in range(4) for q in range(p + 1, 4))
                even[i, j] = inversions % 2 == 0
    return even


EDGE_EVEN = _edge_parities()


# ----------------------------------------------------------------------------- predicates

@njit(cache=True, _nrt=False)
def _sign(I, P, ui, a, b, c, d):
    """Sign of orient3d of original points a, b, c, d: exact on the integer grid
    coordinates ``I`` when ``ui``, robust on the float coordinates ``P`` otherwise.

    The hot predicates take the coordinate arrays themselves, not the state tuple:
    pulling an array out of the tuple costs a reference-count update per call,
    which made a containment test about 30 times slower."""
    if ui:
        v = orient3d_int(I[a, 0], I[a, 1], I[a, 2], I[b, 0], I[b, 1], I[b, 2],
                         I[c, 0], I[c, 1], I[c, 2], I[d, 0], I[d, 1], I[d, 2])
        return 1 if v > 0 else (-1 if v < 0 else 0)
    return orient3d_float_sign(P[a, 0], P[a, 1], P[a, 2], P[b, 0], P[b, 1], P[b, 2],
                               P[c, 0], P[c, 1], P[c, 2], P[d, 0], P[d, 1], P[d, 2])


@njit(cache=True, _nrt=False)
def _vol(I, P, ui, a, b, c, d):
    """orient3d value as float: exact integer on grids, float determinant otherwise."""
    if ui:
        return float(orient3d_int(I[a, 0], I[a, 1], I[a, 2], I[b, 0], I[b, 1], I[b, 2],
                                  I[c, 0], I[c, 1], I[c, 2], I[d, 0], I[d, 1], I[d, 2]))
    return orient3d_float(P[a, 0], P[a, 1], P[a, 2], P[b, 0], P[b, 1], P[b, 2],
                          P[c, 0], P[c, 1], P[c, 2], P[d, 0], P[d, 1], P[d, 2])


@njit(cache=True, inline="always")
def _tet_data(I, P, F, q0, q1, q2, q3):
    """Face planes, float coordinates and values of tet (q0..q3) as tuples (for :func:`_locate_at`).

    The planes are the integer coefficients of the four sub-volumes of eq. (13) as
    linear functions of the point p: ``w_i(p) = A_i . p + B_i`` is orient3d of the
    tet with p in place of vertex i, ``det[b - a, c - a, d - a] = u . (v x w)``
    rearranged (for i = 0, ``(q1 - p) . ((q2 - q1) x (q3 - q1))``; for i > 0,
    ``(p - q0) . n_i`` with n_i the cross product of the other two edges from q0).
    Exact integer identities, so the weights are the same integers as
    :func:`~trivsel.predicates.orient3d_int` gives, at a dot product per face and
    point instead of a determinant.
    """
    x0, y0, z0 = I[q0, 0], I[q0, 1], I[q0, 2]
    x1, y1, z1 = I[q1, 0], I[q1, 1], I[q1, 2]
    ax, ay, az = x1 - x0, y1 - y0, z1 - z0  # q1 - q0
    bx, by, bz = I[q2, 0] - x0, I[q2, 1] - y0, I[q2, 2] - z0  # q2 - q0
    cx, cy, cz = I[q3, 0] - x0, I[q3, 1] - y0, I[q3, 2] - z0  # q3 - q0
    # w0: n0 = (q2 - q1) x (q3 - q1), w0 = n0 . q1 - n0 . p
    ex, ey, ez = bx - ax, by - ay, bz - az
    gx, gy, gz = cx - ax, cy - ay, cz - az
    n0x, n0y, n0z = ey * gz - ez * gy, ez * gx - ex * gz, ex * gy - ey * gx
    # w1: n1 = (q2 - q0) x (q3 - q0); w2: n2 = (q3 - q0) x (q1 - q0); w3: n3 = (q1 - q0) x (q2 - q0)
    n1x, n1y, n1z = by * cz - bz * cy, bz * cx - bx * cz, bx * cy - by * cx
    n2x, n2y, n2z = cy * az - cz * ay, cz * ax - cx * az, cx * ay - cy * ax
    n3x, n3y, n3z = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    pl = (-n0x, -n0y, -n0z, n0x * x1 + n0y * y1 + n0z * z1,
          n1x, n1y, n1z, -(n1x * x0 + n1y * y0 + n1z * z0),
          n2x, n2y, n2z, -(n2x * x0 + n2y * y0 + n2z * z0),
          n3x, n3y, n3z, -(n3x * x0 + n3y * y0 + n3z * z0))
    qf = (P[q0, 0], P[q0, 1], P[q0, 2], P[q1, 0], P[q1, 1], P[q1, 2],
          P[q2, 0], P[q2, 1], P[q2, 2], P[q3, 0], P[q3, 1], P[q3, 2])
    return pl, qf, (F[q0], F[q1], F[q2], F[q3])


@njit(cache=True, inline="always")
def _locate_at(ui, pi, pf, pl, qf, fq, p, q0, q1, q2, q3):
    """Closed containment of point p (integer coordinates ``pi``, float ``pf``) in the tet
    given by :func:`_tet_data`: (inside, n_zero_signs, interpolated value).

    The barycentric weights (eq. 13) are the four sub-volumes with p replacing one
    vertex; the interpolant is the linear polynomial L of eq. 16.  On grids the
    exact integer sub-volumes (from the face planes ``pl``) serve both as signs and
    as weights; on floats the
    signs are robust (:func:`orient3d_float_sign`).  Scalars and tuples only: it is
    inlined into the point loops, where every array argument of an inlined
    function cost a reference-count update per point (measured by sampling).
    """
    if ui:
        w0 = pl[0] * pi[0] + pl[1] * pi[1] + pl[2] * pi[2] + pl[3]
        if w0 < 0:
            return False, 0, 0.0
        w1 = pl[4] * pi[0] + pl[5] * pi[1] + pl[6] * pi[2] + pl[7]
        if w1 < 0:
            return False, 0, 0.0
        w2 = pl[8] * pi[0] + pl[9] * pi[1] + pl[10] * pi[2] + pl[11]
        if w2 < 0:
            return False, 0, 0.0
        w3 = pl[12] * pi[0] + pl[13] * pi[1] + pl[14] * pi[2] + pl[15]
        if w3 < 0:
            return False, 0, 0.0
        nz = (w0 == 0) + (w1 == 0) + (w2 == 0) + (w3 == 0)
        tot = float(w0 + w1 + w2 + w3)
        return True, nz, (w0 * fq[0] + w1 * fq[1] + w2 * fq[2] + w3 * fq[3]) / tot
    s0 = orient3d_float_sign(pf[0], pf[1], pf[2], qf[3], qf[4], qf[5], qf[6], qf[7], qf[8], qf[9], qf[10], qf[11])
    if s0 < 0:
        return False, 0, 0.0
    s1 = orient3d_float_sign(qf[0], qf[1], qf[2], pf[0], pf[1], pf[2], qf[6], qf[7], qf[8], qf[9], qf[10], qf[11])
    if s1 < 0:
        return False, 0, 0.0
    s2 = orient3d_float_sign(qf[0], qf[1], qf[2], qf[3], qf[4], qf[5], pf[0], pf[1], pf[2], qf[9], qf[10], qf[11])
    if s2 < 0:
        return False, 0, 0.0
    s3 = orient3d_float_sign(qf[0], qf[1], qf[2], qf[3], qf[4], qf[5], qf[6], qf[7], qf[8], pf[0], pf[1], pf[2])
    if s3 < 0:
        return False, 0, 0.0
    nz = (s0 == 0) + (s1 == 0) + (s2 == 0) + (s3 == 0)
    if p == q0:
        return True, nz, fq[0]
    if p == q1:
        return True, nz, fq[1]
    if p == q2:
        return True, nz, fq[2]
    if p == q3:
        return True, nz, fq[3]
    w0 = orient3d_float(pf[0], pf[1], pf[2], qf[3], qf[4], qf[5], qf[6], qf[7], qf[8], qf[9], qf[10], qf[11]) if s0 > 0 else 0.0
    w1 = orient3d_float(qf[0], qf[1], qf[2], pf[0], pf[1], pf[2], qf[6], qf[7], qf[8], qf[9], qf[10], qf[11]) if s1 > 0 else 0.0
    w2 = orient3d_float(qf[0], qf[1], qf[2], qf[3], qf[4], qf[5], pf[0], pf[1], pf[2], qf[9], qf[10], qf[11]) if s2 > 0 else 0.0
    w3 = orient3d_float(qf[0], qf[1], qf[2], qf[3], qf[4], qf[5], qf[6], qf[7], qf[8], pf[0], pf[1], pf[2]) if s3 > 0 else 0.0
    tot = w0 + w1 + w2 + w3
    return True, nz, (w0 * fq[0] + w1 * fq[1] + w2 * fq[2] + w3 * fq[3]) / tot


@njit(cache=True, inline="always")
def _locate(I, P, F, ui, q0, q1, q2, q3, p):
    """:func:`_locate_at` from the coordinate arrays (for loops that are not hot)."""
    pl, qf, fq = _tet_data(I, P, F, q0, q1, q2, q3)
    return _locate_at(ui, (I[p, 0], I[p, 1], I[p, 2]), (P[p, 0], P[p, 1], P[p, 2]), pl, qf, fq,
                      p, q0, q1, q2, q3)



@njit(cache=True)
def _orient(S, a, b, c, d):
    """:func:`_sign` on the state tuple (for checks and tests; not for inner loops)."""
    return _sign(S[_IC], S[_P], S[_FOPT][O_USEINT] > 0.0, a, b, c, d)


@njit(cache=True)
def _locate_in(S, q0, q1, q2, q3, p):
    """:func:`_locate` on the state tuple (for checks and tests; not for inner loops)."""
    return _locate(S[_IC], S[_P], S[_F], S[_FOPT][O_USEINT] > 0.0, q0, q1, q2, q3, p)


@njit(cache=True)
def _crit(c, sse, mx, cnt):
    """Per-tet error for swap criterion c: RMS (eq. 14) if 0, max (eq. 15) if 1, else SSE."""
    if c == 0.0:
        return np.sqrt(sse / cnt) if cnt > 0 else 0.0
    if c == 1.0:
        return mx
    return sse


@njit(cache=True, _nrt=False)
def _cannot_beat(crit, tsse, tmax, tcnt, old, nold, best_gain):
    """Whether a flip of the old tets surely cannot beat the round's ``best_gain``,
    from an upper bound of its gain that costs no point test: ``before`` itself
    (``after`` >= 0), the sum of the old tets' stored errors (criteria RMS and max,
    eqs. 14-15; :func:`_evaluate` sums the same terms in another order, hence
    :data:`_BOUND_MARGIN`).  Never for SSE, whose ``before`` sums the stored global
    residuals instead: equal in exact arithmetic, but not within a relative
    rounding margin where residuals are much smaller than the values."""
    if crit == 2.0 or best_gain <= 0.0:
        return False
    ub = 0.0
    for k in range(nold):
        t = old[k]
        ub += _crit(crit, tsse[t], tmax[t], tcnt[t])
    return ub * _BOUND_MARGIN <= best_gain


# Margin of :func:`_cannot_beat` against the rounding of the evaluated sums (a sum of m
# non-negative terms is exact to m * 2^-53 relative; m < 10^6 points per configuration)
_BOUND_MARGIN = 1.0 + 1e-9


# ----------------------------------------------------------------------------- storage

@njit(cache=True)
def _alloc(S):
    """A tet slot from the free list or the high-water mark; -1 if full."""
    ctr = S[_CTR]
    if ctr[C_NFREE] > 0:
        ctr[C_NFREE] -= 1
        t = S[_FREE][ctr[C_NFREE]]
    else:
        if ctr[C_HW] >= S[_TETS].shape[0]:
            ctr[C_ERROR] = ERR_TETCAP
            return -1
        t = ctr[C_HW]
        ctr[C_HW] += 1
    S[_ALIVE][t] = 1
    S[_BLEN][t] = 0
    S[_TVER][t] += 1
    S[_TBEST][t] = -1
    S[_TBESTR][t] = 0.0
    ctr[C_NALIVE] += 1
    return t


@njit(cache=True)
def _kill(S, t):
    ctr = S[_CTR]
    S[_ALIVE][t] = 0
    S[_FREE][ctr[C_NFREE]] = t
    ctr[C_NFREE] += 1
    ctr[C_NALIVE] -= 1


@njit(cache=True)
def _compact_pool(S):
    """Move the live tets' point buckets to the front of the pool (in place)."""
    ctr = S[_CTR]
    alive = S[_ALIVE]
    bstart = S[_BSTART]
    blen = S[_BLEN]
    pool = S[_POOL]
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
    """Points of the old tets' buckets, each once, into S[_WBUF]; returns their count."""
    return _gather_at(S[_CTR], S[_MARK], S[_WBUF], S[_POOL], S[_BSTART], S[_BLEN], old, nold)


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
    shape-mismatch error message (string formatting, about 2 s, once)."""
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
    numba's quicksort costs about a second of compilation)."""
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
    tets = S[_TETS]
    nbr = S[_NBR]
    nbr[t, i] = u
    if u >= 0:
        a = tets[t, (i + 1) % 4]
        b = tets[t, (i + 2) % 4]
        c = tets[t, (i + 3) % 4]
        j = _other_index(tets, u, a, b, c)
        nbr[u, j] = t


@njit(cache=True)
def _fill_tets(S, m, ids, nnew, best, bestr):
    """Step 5 of :func:`_replace`: each new tet's bucket from the cavity's points
    ``S[_WBUF][:m]``, its errors (eqs. 14-15) and worst candidate (``best``, ``bestr``),
    and the residuals of the points, point by point: each point's data is read
    once, not once per new tet.  The points of a large cavity are spread over
    memory, and filling one tet after the other re-read them from RAM for every
    new tet: the paper method on 129^3 spent most of its time there (sampled).

    A point is tested against the new tets in order until one holds it strictly
    inside (open interiors are disjoint, so no other tet holds it).  Everything
    comes out as from filling tet after tet, to the last bit: each tet's bucket
    lists its points in cavity order and its sums run in that order; a point's
    residual and owner come from the first tet (in order) that holds it; and the
    global squared-residual sum gets its changes tet by tet, in cavity order
    within a tet.  The buckets go to the top of the pool, which is compacted first
    if they do not fit (their exact size is known only here: a bound such as
    points x new tets made large cavities fail for want of room they did not need).
    Returns 0, or ERR_UNCOVERED if a point lies in no new tet, or ERR_POOLCAP.
    Called once per :func:`_replace`, so taking the arrays out of ``S`` here costs
    nothing per point.
    """
    I_ = S[_IC]
    P_ = S[_P]
    F_ = S[_F]
    tets = S[_TETS]
    buf = S[_WBUF]
    pool = S[_POOL]
    cand = S[_CAND]
    isvert = S[_ISVERT]
    resid = S[_RESID]
    owner = S[_OWNER]
    ctr = S[_CTR]
    fopt = S[_FOPT]
    ui_ = fopt[O_USEINT] > 0.0
    ownvert = fopt[O_OWNVERT] > 0.0
    tolinf = fopt[O_TOLINF]
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
    pj = np.empty(m * nnew, np.int32)
    pk = np.empty(m * nnew, np.int32)
    cov = np.empty(m, np.int32)
    delta = np.empty(m, np.float64)
    npairs = 0
    for j in range(m):
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
        S[_BSTART][t] = s
        S[_BLEN][t] = L[k]
        S[_TSSE][t] = sse[k]
        S[_TMAX][t] = mx[k]
        S[_TCNT][t] = cnt[k]
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
    acc = S[_ACC]
    for i in range(npairs):
        if covers[i]:
            acc[0] += dslot[i]
    return 0


# ----------------------------------------------------------------------------- the primitive

@njit(cache=True)
def _replace(S, old, nold, newq, nnew, new_hull):
    """Replace tets ``old[:nold]`` by the quadruples ``newq[:nnew]`` (same region).

    Links the new tets to each other and to the outside neighbours of the old
    ones, moves the old tets' points into the new tets that contain them (closed
    containment), recomputes their errors and the global residuals.  A new face
    that matches no face is an error, unless ``new_hull`` (insertion on a hull face
    or edge splits hull faces): then it becomes a hull face.  Returns the
    new tet ids (an empty array and S[_CTR][C_ERROR] set on failure).
    """
    tets = S[_TETS]
    nbr = S[_NBR]
    ctr = S[_CTR]
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
    err = _fill_tets(S, m, ids, nnew, best, bestr)
    if err != 0:
        ctr[C_ERROR] = err
        return ids[:0]
    for k in range(nnew):
        _set_best(S, ids[k], best[k], bestr[k])
    return ids


@njit(cache=True)
def _positive(S, newq, nnew):
    """Admissibility: every new tet has strictly positive volume."""
    return _positive_at(S[_IC], S[_P], S[_FOPT][O_USEINT] > 0.0, newq, nnew)


@njit(cache=True, _nrt=False)
def _positive_at(I_, P_, ui_, newq, nnew):
    """:func:`_positive` on the coordinate arrays (for :func:`swap`'s loop: every array
    taken out of the state tuple costs a reference-count update per call)."""
    for k in range(nnew):
        if _sign(I_, P_, ui_, newq[k, 0], newq[k, 1], newq[k, 2], newq[k, 3]) <= 0:
            return False
    return True


@njit(cache=True)
def _evaluate(S, old, nold, newq, nnew, reltol, abstol):
    """Criterion sums (before, after) of replacing old by newq, without changing the mesh.

    For RMS/max criteria these are sums of per-tet errors (eqs. 14-15) as in step
    (iii) of section 4; for SSE the sum of squared residuals over the points of the
    configuration, each counted once (the exact change of the global L2 error).

    ``after`` is a sum of non-negative terms, so its partial sums only grow: as
    soon as ``before - partial <= reltol * before + abstol`` the flip cannot pass
    :func:`swap`'s test for an improvement and the evaluation stops, returning
    the partial sum (a lower bound of ``after`` that decides the same).
    ``abstol = -inf`` evaluates in full.  (Stopping also when the flip cannot
    beat the best one found so far in the round was measured slower: such
    configurations must be evaluated again in the next round.)
    """
    return _evaluate_at(S, np.empty(4, np.int64), old, nold, newq, nnew, reltol, abstol, False)


@njit(cache=True, _nrt=False)
def _evaluate_at(S, srt, old, nold, newq, nnew, reltol, abstol, reuse):
    """:func:`_evaluate` with room ``srt`` for the sorted ids, allocating nothing, and
    compiled without reference counting: :func:`swap` calls it in its loop, where the
    29 arrays of the state tuple would otherwise be counted in and out per call
    (about a third of a greedy run on 65^3, sampled).

    ``reuse``: the previous call evaluated the same old tets (the other diagonal of a
    4-4 configuration), so their points are still in ``S[_WBUF]`` and, for SSE,
    their ``before`` in ``S[_ACC][1]``: no second gather.
    """
    I_ = S[_IC]
    P_ = S[_P]
    F = S[_F]
    fopt = S[_FOPT]
    ui_ = fopt[O_USEINT] > 0.0
    crit = fopt[O_CRIT]
    ownvert = fopt[O_OWNVERT] > 0.0
    # the old tets in ascending id order: the sums then do not depend on the tet the
    # configuration was found from, to the last bit (equal gains stay equal)
    _sort_into(old, nold, srt)
    ctr = S[_CTR]
    if reuse:
        m = ctr[C_LASTM]
    else:
        m = _gather_at(ctr, S[_MARK], S[_WBUF], S[_POOL], S[_BSTART], S[_BLEN], srt, nold)
        ctr[C_LASTM] = m
    buf = S[_WBUF]
    before = 0.0
    after = 0.0
    if crit == 2.0:
        if reuse:
            before = S[_ACC][1]
        else:
            resid = S[_RESID]
            for j in range(m):
                p = buf[j]
                before += resid[p] * resid[p]
            S[_ACC][1] = before
        thr = reltol * before + abstol
        # each point in the first new tet that contains it (2 to 4 tets; their data once)
        a0, a1, a2, a3 = newq[0, 0], newq[0, 1], newq[0, 2], newq[0, 3]
        b0, b1, b2, b3 = newq[1, 0], newq[1, 1], newq[1, 2], newq[1, 3]
        kc = min(2, nnew - 1)
        kd = min(3, nnew - 1)
        c0, c1, c2, c3 = newq[kc, 0], newq[kc, 1], newq[kc, 2], newq[kc, 3]
        d0, d1, d2, d3 = newq[kd, 0], newq[kd, 1], newq[kd, 2], newq[kd, 3]
        plA, qfA, fqA = _tet_data(I_, P_, F, a0, a1, a2, a3)
        plB, qfB, fqB = _tet_data(I_, P_, F, b0, b1, b2, b3)
        plC, qfC, fqC = _tet_data(I_, P_, F, c0, c1, c2, c3)
        plD, qfD, fqD = _tet_data(I_, P_, F, d0, d1, d2, d3)
        for j in range(m):
            p = buf[j]
            pi = (I_[p, 0], I_[p, 1], I_[p, 2])
            pf = (P_[p, 0], P_[p, 1], P_[p, 2])
            inside, nz, val = _locate_at(ui_, pi, pf, plA, qfA, fqA, p, a0, a1, a2, a3)
            if not inside:
                inside, nz, val = _locate_at(ui_, pi, pf, plB, qfB, fqB, p, b0, b1, b2, b3)
                if not inside and nnew > 2:
                    inside, nz, val = _locate_at(ui_, pi, pf, plC, qfC, fqC, p, c0, c1, c2, c3)
                    if not inside and nnew > 3:
                        inside, nz, val = _locate_at(ui_, pi, pf, plD, qfD, fqD, p, d0, d1, d2, d3)
            if inside:
                r = F[p] - val
                after += r * r
            if before - after <= thr:
                break
        return before, after
    for k in range(nold):
        t = srt[k]
        before += _crit(crit, S[_TSSE][t], S[_TMAX][t], S[_TCNT][t])
    thr = reltol * before + abstol
    for k in range(nnew):
        q0 = newq[k, 0]
        q1 = newq[k, 1]
        q2 = newq[k, 2]
        q3 = newq[k, 3]
        sse = 0.0
        mx = 0.0
        cnt = 0
        pl, qf, fq = _tet_data(I_, P_, F, q0, q1, q2, q3)
        for j in range(m):
            p = buf[j]
            inside, nz, val = _locate_at(ui_, (I_[p, 0], I_[p, 1], I_[p, 2]), (P_[p, 0], P_[p, 1], P_[p, 2]),
                                         pl, qf, fq, p, q0, q1, q2, q3)
            if inside and (ownvert or (p != q0 and p != q1 and p != q2 and p != q3)):
                r = F[p] - val
                sse += r * r
                if abs(r) > mx:
                    mx = abs(r)
                cnt += 1
        after += _crit(crit, sse, mx, cnt)
        if before - after <= thr:
            break
    return before, after


# ----------------------------------------------------------------------------- insertion

@njit(cache=True)
def insert_point(S, p):
    """Insert original point p (section 4, cases i-iii); returns (case, new tet ids).

    The tets whose closed region contains p are found from p's owner tet by
    crossing faces that contain p: one tet (case i, p interior: 1 -> 4), the one or
    two tets sharing a face (case ii: each -> 3), or all tets around an edge
    (case iii: each -> 2).  Each is replaced by the tets joining p to its faces
    that do not contain p.  Boundary faces and edges are handled alike.
    """
    I_ = S[_IC]
    P_ = S[_P]
    F_ = S[_F]
    ui_ = S[_FOPT][O_USEINT] > 0.0
    tets = S[_TETS]
    nbr = S[_NBR]
    t0 = S[_OWNER][p]
    cav = np.empty(64, np.int64)
    sg = np.empty((64, 4), np.int64)
    ncav = 1
    cav[0] = t0
    ctr = S[_CTR]
    ctr[C_OSTAMP] += 1
    om = S[_OMARK]
    om[t0] = ctr[C_OSTAMP]
    k = 0
    while k < ncav:
        t = cav[k]
        q0 = tets[t, 0]
        q1 = tets[t, 1]
        q2 = tets[t, 2]
        q3 = tets[t, 3]
        sg[k, 0] = _sign(I_, P_, ui_, p, q1, q2, q3)
        sg[k, 1] = _sign(I_, P_, ui_, q0, p, q2, q3)
        sg[k, 2] = _sign(I_, P_, ui_, q0, q1, p, q3)
        sg[k, 3] = _sign(I_, P_, ui_, q0, q1, q2, p)
        for i in range(4):
            if sg[k, i] == 0:
                u = nbr[t, i]
                if u >= 0 and om[u] != ctr[C_OSTAMP]:
                    om[u] = ctr[C_OSTAMP]
                    if ncav == cav.shape[0]:
                        cav = np.concatenate((cav, np.empty(ncav, np.int64)))
                        sg2 = np.empty((2 * ncav, 4), np.int64)
                        _copy2(sg2, sg, ncav)
                        sg = sg2
                    cav[ncav] = u
                    ncav += 1
        k += 1
    nz = 0
    for i in range(4):
        if sg[0, i] == 0:
            nz += 1
    if nz >= 3:
        ctr[C_ERROR] = ERR_DUPLICATE
        return 0, cav[:0]
    newq = np.empty((4 * ncav, 4), np.int64)
    nn = 0
    for k in range(ncav):
        t = cav[k]
        for i in range(4):
            if sg[k, i] > 0:
                for j in range(4):
                    newq[nn, j] = tets[t, j]
                newq[nn, i] = p
                nn += 1
    ids = _replace(S, cav, ncav, newq, nn, True)
    S[_ISVERT][p] = 1
    ctr[C_NVERT] += 1
    ctr[C_CASE1 + nz] += 1
    return nz + 1, ids


@njit(cache=True)
def cone_from_hull(S, p):
    """First insertion (section 3-4): join p to every boundary triangle.

    Replaces the whole current mesh (the triangulation of the fixed points) by the
    cone from p over its hull faces.  Returns the new ids, or an empty array if p
    is not strictly inside the hull (some cone tet would be flat); then nothing
    has changed and the caller inserts p with :func:`insert_point` instead.
    """
    tets = S[_TETS]
    nbr = S[_NBR]
    alive = S[_ALIVE]
    hw = S[_CTR][C_HW]
    old = np.empty(hw, np.int64)
    nold = 0
    nh = 0
    for t in range(hw):
        if alive[t]:
            old[nold] = t
            nold += 1
            for i in range(4):
                if nbr[t, i] < 0:
                    nh += 1
    newq = np.empty((nh, 4), np.int64)
    k = 0
    for n in range(nold):
        t = old[n]
        for i in range(4):
            if nbr[t, i] < 0:
                # outward triangle = inward face with two vertices swapped
                newq[k, 0] = p
                newq[k, 1] = tets[t, FACE_IN[i, 0]]
                newq[k, 2] = tets[t, FACE_IN[i, 2]]
                newq[k, 3] = tets[t, FACE_IN[i, 1]]
                k += 1
    if not _positive(S, newq, nh):
        return old[:0]
    ids = _replace(S, old, nold, newq, nh, False)
    S[_ISVERT][p] = 1
    S[_CTR][C_NVERT] += 1
    S[_CTR][C_CASE1] += 1
    return ids


# ----------------------------------------------------------------------------- configurations

@njit(cache=True)
def config23(S, t, i, old, newq):
    """Configuration 1 seen as two tets (Fig. 2, left): t and its neighbour across face i.

    ::

              d                 d
             /|\\              /|\\
            / | \\            / | \\
          f1--+--f3   2->3  f1--d-e--f3   (edge d-e pierces the face f1 f2 f3)
            \\ | /            \\ | /
             \\|/              \\|/
              e                 e

    Fills old[:2] and newq[:3] with (f1, f2, e, d), (f2, f3, e, d), (f3, f1, e, d);
    returns False when face i is on the hull.
    """
    return _config23_at(S[_TETS], S[_NBR], t, i, old, newq)


@njit(cache=True, _nrt=False)
def _config23_at(tets, nbr, t, i, old, newq):
    """:func:`config23` on the mesh arrays (see :func:`_positive_at`)."""
    u = nbr[t, i]
    if u < 0:
        return False
    d = tets[t, i]
    f1 = tets[t, FACE_IN[i, 0]]
    f2 = tets[t, FACE_IN[i, 1]]
    f3 = tets[t, FACE_IN[i, 2]]
    e = tets[u, _other_index(tets, u, f1, f2, f3)]
    old[0] = t
    old[1] = u
    newq[0, 0], newq[0, 1], newq[0, 2], newq[0, 3] = f1, f2, e, d
    newq[1, 0], newq[1, 1], newq[1, 2], newq[1, 3] = f2, f3, e, d
    newq[2, 0], newq[2, 1], newq[2, 2], newq[2, 3] = f3, f1, e, d
    return True


@njit(cache=True, _nrt=False)
def _edge_opposite(tets, t, a, b):
    """The two vertices (x, y) of tet t other than edge (a, b), with orient3d(a, b, x, y) > 0.

    Every tet of the mesh is positively oriented (:mod:`trivsel.check` tests it), so
    the sign is the parity of the local-index permutation (:data:`EDGE_EVEN`), not a
    predicate: this runs for every edge of every tet of O in every swap round.
    """
    i = -1
    j = -1
    x = -1
    y = -1
    for m in range(4):
        v = tets[t, m]
        if v == a:
            i = m
        elif v == b:
            j = m
        elif x < 0:
            x = v
        else:
            y = v
    if not EDGE_EVEN[i, j]:
        x, y = y, x
    return x, y


@njit(cache=True)
def edge_ring(S, t, a, b, old, ring):
    """Tets around edge (a, b) starting at t, and the ring of opposite vertices.

    Walks face to face around the edge.  Fills old[:k] and ring[:k] ordered so that
    orient3d(a, b, ring[j], ring[j+1]) > 0 and tet old[j] = {a, b, ring[j], ring[j+1]}.
    Returns k for a closed ring (interior edge) of at most old.shape[0] tets, -1
    for an edge on the hull, or -2 for a longer ring.
    """
    return _edge_ring(S[_TETS], S[_NBR], S[_OMARK], -1, t, a, b, old, ring)


@njit(cache=True, _nrt=False)
def _edge_ring(tets, nbr, om, st, t, a, b, old, ring):
    """:func:`edge_ring` on the arrays themselves (taking them out of the state tuple
    per walk was the largest single cost of a greedy run, sampled).

    For :func:`swap`'s scan of O it gives up (returns -3) as soon as the walk meets
    a tet of O (``om[u] == st``) with a smaller id than t, from which the scan
    evaluates this edge instead (every configuration once, from its smallest tet in
    O): about half of the walks stop early.  ``st = -1`` (no stamp) walks the whole
    ring."""
    cap = old.shape[0]
    x, y = _edge_opposite(tets, t, a, b)
    k = 0
    cur = t
    while True:
        if k >= cap:
            return -2
        old[k] = cur
        ring[k] = x
        k += 1
        j = _other_index(tets, cur, a, b, y)  # local index of x in cur
        nxt = nbr[cur, j]
        if nxt < 0:
            return -1
        if nxt == t:
            return k
        if nxt < t and om[nxt] == st:
            return -3
        z = tets[nxt, _other_index(tets, nxt, a, b, y)]
        x = y
        y = z
        cur = nxt


@njit(cache=True)
def edge_ring_open(S, t, a, b, old, ring):
    """Tets around a hull edge (a, b): an open ring from one hull face to the other.

    Fills old[:k] and ring[:k + 1] (tet old[j] = {a, b, ring[j], ring[j+1]}, ordered
    as in :func:`edge_ring`) and returns k, or -1 if the edge is interior or the
    ring is longer than old.shape[0].
    """
    return _edge_ring_open_at(S[_TETS], S[_NBR], t, a, b, old, ring)


@njit(cache=True, _nrt=False)
def _edge_ring_open_at(tets, nbr, t, a, b, old, ring):
    """:func:`edge_ring_open` on the arrays themselves (see :func:`_evaluate_at`)."""
    cap = old.shape[0]
    x, y = _edge_opposite(tets, t, a, b)
    # walk backwards (across the face (a, b, x)) to the first tet of the open ring
    cur = t
    steps = 0
    while True:
        j = _other_index(tets, cur, a, b, x)  # local index of y
        prv = nbr[cur, j]
        if prv < 0:
            break
        if prv == t or steps > 64:
            return -1  # closed ring: an interior edge
        w = tets[prv, _other_index(tets, prv, a, b, x)]
        y = x
        x = w
        cur = prv
        steps += 1
    # walk forwards (across the face (a, b, y)) to the other hull face
    k = 0
    while True:
        if k >= cap:
            return -1
        old[k] = cur
        ring[k] = x
        k += 1
        j = _other_index(tets, cur, a, b, y)
        nxt = nbr[cur, j]
        if nxt < 0:
            ring[k] = y
            return k
        z = tets[nxt, _other_index(tets, nxt, a, b, y)]
        x = y
        y = z
        cur = nxt


@njit(cache=True)
def quads32(a, b, ring, newq):
    """Configuration 1 seen as three tets around edge (a, b) -> two tets (Fig. 2, right to left).

    ::

          a               a
         /|\\             / \\
      c1-+-c3   3->2   c1---c3     the edge a-b is removed; the triangle
         \\|/             \\ /       (c1, c2, c3) becomes the shared face
          b               b
    """
    newq[0, 0], newq[0, 1], newq[0, 2], newq[0, 3] = a, ring[0], ring[1], ring[2]
    newq[1, 0], newq[1, 1], newq[1, 2], newq[1, 3] = ring[0], ring[1], ring[2], b


@njit(cache=True)
def quads44(a, b, ring, alt, newq):
    """Configuration 2 (Fig. 3): four tets around edge (a, b) -> the other diagonal.

    ::

              a                      a
           /  |  \\               /     \\
        c4 ---+--- c2   4->4   c4 ----- c2     edge a-b replaced by c1-c3 (alt 0)
        c1    |    c3          c1 \\   / c3     or by c2-c4 (alt 1)
           \\  |  /               \\ b /
              b

    The ring c1 c2 c3 c4 is ordered as returned by :func:`edge_ring`.
    """
    c1 = ring[alt]
    c2 = ring[(alt + 1) % 4]
    c3 = ring[(alt + 2) % 4]
    c4 = ring[(alt + 3) % 4]
    newq[0, 0], newq[0, 1], newq[0, 2], newq[0, 3] = a, c1, c2, c3
    newq[1, 0], newq[1, 1], newq[1, 2], newq[1, 3] = a, c3, c4, c1
    newq[2, 0], newq[2, 1], newq[2, 2], newq[2, 3] = c1, c2, c3, b
    newq[3, 0], newq[3, 1], newq[3, 2], newq[3, 3] = c3, c4, c1, b


# ----------------------------------------------------------------------------- swapping

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
def _try_flip22(S, srt, hkey, hval, hn, probes, key, t, a, b, old, old2, ring, newq, st, reltol, abstol):
    """(gain, count of the evaluation memory) of the boundary 2-2 flip of hull edge
    (a, b); the gain is 0 if the flip is not admissible or not improving enough.  A
    hull edge between two coplanar hull faces with two tets around it is flipped to
    the other diagonal of the planar quad (a, r0, b, r2).  Fills old[:2] and newq[:2].
    Evaluations go to :func:`swap`'s memory like the others (kind 3).  A function of
    its own, not a branch in :func:`swap`'s loop: written inline, this rare case made
    the whole loop 1.5-1.9x slower."""
    I_ = S[_IC]
    P_ = S[_P]
    ui_ = S[_FOPT][O_USEINT] > 0.0
    om = S[_OMARK]
    k2 = _edge_ring_open_at(S[_TETS], S[_NBR], t, a, b, old2, ring)
    if k2 != 2 or _sign(I_, P_, ui_, a, b, ring[0], ring[2]) != 0:
        return 0.0, hn
    if (old2[0] < t and om[old2[0]] == st) or (old2[1] < t and om[old2[1]] == st):
        return 0.0, hn  # evaluated from its smaller tet
    quads32(a, b, ring, newq)
    if not _positive_at(I_, P_, ui_, newq, 2):
        return 0.0, hn
    old[0] = old2[0]
    old[1] = old2[1]
    _config_key(S[_TVER], 3, -1, -1, old, 2, key)
    slot, found = _cache_slot(hkey, key, probes)
    if found:
        before, after = hval[slot, 0], hval[slot, 1]
        S[_CTR][C_MEMHITS] += 1
    else:
        before, after = _evaluate_at(S, srt, old, 2, newq, 2, reltol, abstol, False)
        S[_CTR][C_EVALS] += 1
        hn = _cache_store(hkey, hval, hn, slot, key, before, after)
    gain = before - after
    if gain > reltol * before + abstol:
        return gain, hn
    return 0.0, hn


# A swap call evaluates the configurations of O round after round (Definition 3), and
# O only grows: without a memory, every round re-evaluates every unchanged
# configuration, which was 76 % (paper) to 90 % (greedy) of all point-in-tet tests.
# A configuration's gain depends only on its old tets and the new diagonal, and a
# tet's points never change while it lives (``_TVER`` counts reuses of an id), so
# the key below identifies it exactly.  Five words, injective for point ids below
# 2^30 (the int32 pool bounds N far lower) and tet ids and versions below 2^31:
#
#   key = (kind << 60 | (d0 + 1) << 30 | (d1 + 1),  ver0 << 32 | (id0 + 1),  ...,  ver3 << 32 | (id3 + 1))
#          kind: 0 = 2-3, 1 = 3-2, 2 = 4-4 with new diagonal d0 < d1, 3 = boundary 2-2 (d = -1);
#          tets sorted by id, 0 padded
#
# The memory lasts one swap call (``memory="call"``: a table that grows, never
# forgets) or the whole run (``memory="run"``, :func:`trivsel.reduce`'s default:
# the fixed table ``S[_MKEY]``, where a key looks at _RUN_PROBES slots and, if
# none is free or its own, overwrites one).  Greedy's insertions are scattered,
# and most configurations around a new point were already evaluated when their
# tets were made: with the run-long memory greedy f4 on 33^3 evaluated 110k
# instead of 201k configurations.  A hit returns the value stored.  Under the
# RMS and max criteria that is what a new evaluation computes, bit for bit;
# under SSE ``before`` sums the residuals stored per point, and a point on a
# face shared with a tet outside the configuration keeps the residual its
# owning tet computed, so a remembered sum may differ from a new one in the
# last bits: decisions differ only between gains equal up to rounding.
_KEYLEN = 5
_CACHE_MAX = 1 << 18  # entries of a call's table; a larger swap (the global pass) evaluates without caching
_RUN_PROBES = 8  # slots a key may occupy in the run-long table (a power of two)


@njit(cache=True, _nrt=False)
def _config_key(tver, kind, d0, d1, old, nold, key):
    """Fill ``key`` with the canonical key of a configuration (see above)."""
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
def swap(S, seed, nseed, with_neighbours):
    """Data-dependent swapping after an insertion (section 4, steps i-iv).

    O = the seed tets (the new ones) and, if ``with_neighbours``, their face
    neighbours (Definition 3).  In each round every configuration 1 (2-3 over each
    interior face, 3-2 around each degree-3 edge) and configuration 2 (4-4 around
    each degree-4 edge, both other diagonals) found in O is evaluated; the admissible
    alternative (all new tets strictly positive) with the largest decrease of the
    criterion sum is applied if that decrease exceeds ``rel_tol * before + abs_tol``
    (gains at rounding level could otherwise cycle).  With the ``first`` option the
    first such improving flip is applied instead.  O is then updated with the new
    tets and their neighbours and the search repeats until nothing improves.
    Evaluations are remembered by configuration (see the comment above
    ``_KEYLEN``), for this call or, with ``memory="run"``, for the whole run.
    Returns the number of flips made.
    """
    tets = S[_TETS]
    nbr = S[_NBR]
    I_ = S[_IC]
    P_ = S[_P]
    alive = S[_ALIVE]
    ctr = S[_CTR]
    fopt = S[_FOPT]
    ui_ = fopt[O_USEINT] > 0.0
    om = S[_OMARK]
    reltol = fopt[O_RELTOL]
    abstol = fopt[O_ABSTOL]
    first = fopt[O_FIRST] > 0.0
    maxrounds = int(fopt[O_MAXROUNDS])
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
    bflip = fopt[O_BFLIP] > 0.0
    tver = S[_TVER]
    tsse = S[_TSSE]
    tmax = S[_TMAX]
    tcnt = S[_TCNT]
    crit = fopt[O_CRIT]
    # evaluated configurations: keys and (before, after) (see _config_key)
    if fopt[O_RUNMEM] > 0.0:
        hkey = S[_MKEY]
        hval = S[_MVAL]
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
    for rnd in range(maxrounds):
        # room for all the configurations this round can store (at most 16 per tet of
        # O), so that the table is never replaced inside the loops below: an array
        # variable reassigned in a loop costs reference counting on every iteration
        # (greedy 65^3: about 10 % of the run)
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
            # configuration 1 as two tets: 2 -> 3 over each interior face
            for i in range(4):
                u = nbr[t, i]
                if u < 0 or (om[u] == st and u < t):
                    continue
                _config23_at(tets, nbr, t, i, old, newq)
                if not _positive_at(I_, P_, ui_, newq, 3):
                    continue
                _config_key(tver, 0, -1, -1, old, 2, key)
                slot, found = _cache_slot(hkey, key, probes)
                if found:
                    before, after = hval[slot, 0], hval[slot, 1]
                    ctr[C_MEMHITS] += 1
                elif _cannot_beat(crit, tsse, tmax, tcnt, old, 2, best_gain):
                    continue  # cannot beat this round's best: left for a later round
                else:
                    before, after = _evaluate_at(S, srt, old, 2, newq, 3, reltol, abstol, False)
                    ctr[C_EVALS] += 1
                    hn = _cache_store(hkey, hval, hn, slot, key, before, after)
                gain = before - after
                if gain > reltol * before + abstol and gain > best_gain:
                    best_gain = gain
                    best_kind = 0
                    best_nold = 2
                    best_nnew = 3
                    _copy1(best_old, old, 2)
                    _copy2(best_new, newq, 3)
                    if first:
                        done = True
                        break
            if done:
                break
            # configurations around edges: 3 -> 2 and 4 -> 4
            for e in range(6):
                a = tets[t, EDGES[e, 0]]
                b = tets[t, EDGES[e, 1]]
                k = _edge_ring(tets, nbr, om, st, t, a, b, old, ring)
                if k == -1 and bflip:
                    g, hn = _try_flip22(S, srt, hkey, hval, hn, probes, key, t, a, b, old, old2, ring, newq, st,
                                        reltol, abstol)
                    if g > best_gain:
                        best_gain = g
                        best_kind = 3
                        best_nold = 2
                        best_nnew = 2
                        _copy1(best_old, old, 2)
                        _copy2(best_new, newq, 2)
                        if first:
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
                nalt = 1 if k == 3 else 2
                gathered = False  # the first diagonal's evaluation left this ring's points in WBUF
                for alt in range(nalt):
                    if k == 3:
                        quads32(a, b, ring, newq)
                        nn = 2
                    else:
                        quads44(a, b, ring, alt, newq)
                        nn = 4
                    if not _positive_at(I_, P_, ui_, newq, nn):
                        continue
                    if k == 3:
                        _config_key(tver, 1, -1, -1, old, 3, key)
                    else:
                        _config_key(tver, 2, ring[alt], ring[(alt + 2) % 4], old, 4, key)
                    slot, found = _cache_slot(hkey, key, probes)
                    if found:
                        before, after = hval[slot, 0], hval[slot, 1]
                        ctr[C_MEMHITS] += 1
                    elif _cannot_beat(crit, tsse, tmax, tcnt, old, k, best_gain):
                        continue  # cannot beat this round's best (see above)
                    else:
                        before, after = _evaluate_at(S, srt, old, k, newq, nn, reltol, abstol, gathered)
                        ctr[C_EVALS] += 1
                        gathered = True
                        hn = _cache_store(hkey, hval, hn, slot, key, before, after)
                    gain = before - after
                    if gain > reltol * before + abstol and gain > best_gain:
                        best_gain = gain
                        best_kind = 1 if k == 3 else 2
                        best_nold = k
                        best_nnew = nn
                        _copy1(best_old, old, k)
                        _copy2(best_new, newq, nn)
                        if first:
                            done = True
                            break
                if done:
                    break
            if done:
                break
        if best_kind < 0:
            break
        ids = _replace(S, best_old, best_nold, best_new, best_nnew, best_kind == 3)
        if ctr[C_ERROR] != 0:
            return nflips
        if best_kind == 3:
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
        if rnd == maxrounds - 1:
            ctr[C_ROUNDCAP] += 1
    return nflips


@njit(cache=True)
def global_pass(S):
    """The optional final swap over all tetrahedra (end of section 4), until nothing
    improves: the cap on flips per insertion (``max_rounds``) does not apply."""
    alive = S[_ALIVE]
    hw = S[_CTR][C_HW]
    seed = np.empty(hw, np.int64)
    n = 0
    for t in range(hw):
        if alive[t]:
            seed[n] = t
            n += 1
    fopt = S[_FOPT]
    cap = fopt[O_MAXROUNDS]
    fopt[O_MAXROUNDS] = UNLIMITED_ROUNDS
    nflips = swap(S, seed, n, False)
    fopt[O_MAXROUNDS] = cap
    return nflips


@njit(cache=True)
def run_insertions(S, order, start, stop, tol_rms, n_total):
    """Insert order[start:stop] one by one, each followed by swapping.

    Stops early once sqrt(sum of squared residuals / n_total) <= tol_rms (if
    tol_rms >= 0) or no residual exceeds the E_inf tolerance held in the options
    (if it is >= 0).  Returns the position reached (exclusive).
    """
    ctr = S[_CTR]
    tolinf = S[_FOPT][O_TOLINF]
    for k in range(start, stop):
        case, ids = insert_point(S, order[k])
        if ctr[C_ERROR] != 0:
            return k
        swap(S, ids, ids.shape[0], True)
        if ctr[C_ERROR] != 0:
            return k + 1
        if tol_rms >= 0.0 and np.sqrt(max(S[_ACC][0], 0.0) / n_total) <= tol_rms:
            return k + 1
        if tolinf >= 0.0 and ctr[C_ABOVE] == 0:
            return k + 1
    return stop


@njit(cache=True)
def fill_buckets(S, ids):
    """Buckets, errors and residuals of a fresh mesh whose tets are ids (all points)."""
    I_ = S[_IC]
    P_ = S[_P]
    F_ = S[_F]
    ui_ = S[_FOPT][O_USEINT] > 0.0
    tets = S[_TETS]
    F = S[_F]
    N = F.shape[0]
    covered = np.zeros(N, np.uint8)
    ownvert = S[_FOPT][O_OWNVERT] > 0.0
    ctr = S[_CTR]
    pool = S[_POOL]
    resid = S[_RESID]
    for k in range(ids.shape[0]):
        t = ids[k]
        q0, q1, q2, q3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        top = ctr[C_POOLTOP]
        S[_BSTART][t] = top
        L = 0
        sse = 0.0
        mx = 0.0
        cnt = 0
        best = -1
        bestr = 0.0
        for p in range(N):
            inside, nz, val = _locate(I_, P_, F_, ui_, q0, q1, q2, q3, p)
            if not inside:
                continue
            if top + L >= pool.shape[0]:
                ctr[C_ERROR] = ERR_POOLCAP
                return
            pool[top + L] = p
            L += 1
            r = F[p] - val
            if S[_CAND][p] and not S[_ISVERT][p] and abs(r) > bestr:
                best = p
                bestr = abs(r)
            if ownvert or (p != q0 and p != q1 and p != q2 and p != q3):
                sse += r * r
                mx = max(mx, abs(r))
                cnt += 1
            if not covered[p]:
                covered[p] = 1
                resid[p] = r
                S[_OWNER][p] = t
        S[_BLEN][t] = L
        ctr[C_POOLTOP] = top + L
        S[_TSSE][t] = sse
        S[_TMAX][t] = mx
        S[_TCNT][t] = cnt
        _set_best(S, t, best, bestr)
    for p in range(N):
        if not covered[p]:
            ctr[C_ERROR] = ERR_UNCOVERED
            return
    acc = S[_ACC]
    acc[0] = 0.0
    tolinf = S[_FOPT][O_TOLINF]
    ctr[C_ABOVE] = 0
    for p in range(N):
        acc[0] += resid[p] * resid[p]
        if tolinf >= 0.0 and abs(resid[p]) > tolinf:
            ctr[C_ABOVE] += 1


@njit(cache=True)
def residuals(S, out):
    """f - L at every original point, from every live tet containing it (eqs. 19-20).

    Returns the largest disagreement between two tets containing the same point
    (zero for a continuous interpolant up to rounding).
    """
    I_ = S[_IC]
    P_ = S[_P]
    F_ = S[_F]
    ui_ = S[_FOPT][O_USEINT] > 0.0
    tets = S[_TETS]
    alive = S[_ALIVE]
    F = S[_F]
    pool = S[_POOL]
    seen = np.zeros(F.shape[0], np.uint8)
    worst = 0.0
    for t in range(S[_CTR][C_HW]):
        if not alive[t]:
            continue
        q0, q1, q2, q3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        s = S[_BSTART][t]
        for j in range(S[_BLEN][t]):
            p = pool[s + j]
            inside, nz, val = _locate(I_, P_, F_, ui_, q0, q1, q2, q3, p)
            r = F[p] - val
            if seen[p]:
                worst = max(worst, abs(r - out[p]))
            else:
                out[p] = r
                seen[p] = 1
    return worst



# ----------------------------------------------------------------------------- greedy selection

@njit(cache=True, _nrt=False)
def _heap_push(S, key, t, ver):
    """Push (key, tet, version) onto the array-backed binary max-heap."""
    hk = S[_HKEY]
    ht = S[_HTET]
    hv = S[_HVER]
    ctr = S[_CTR]
    if ctr[C_HEAPN] >= hk.shape[0]:
        return
    i = ctr[C_HEAPN]
    ctr[C_HEAPN] += 1
    while i > 0:
        parent = (i - 1) >> 1
        if hk[parent] >= key:
            break
        hk[i] = hk[parent]
        ht[i] = ht[parent]
        hv[i] = hv[parent]
        i = parent
    hk[i] = key
    ht[i] = t
    hv[i] = ver


@njit(cache=True)
def _heap_pop(S):
    """Remove and return the top (key, tet, version); tet -1 when empty."""
    hk = S[_HKEY]
    ht = S[_HTET]
    hv = S[_HVER]
    ctr = S[_CTR]
    n = ctr[C_HEAPN]
    if n == 0:
        return 0.0, -1, 0
    key, t, ver = hk[0], ht[0], hv[0]
    n -= 1
    ctr[C_HEAPN] = n
    lk, lt, lv = hk[n], ht[n], hv[n]
    i = 0
    while True:
        c = 2 * i + 1
        if c >= n:
            break
        if c + 1 < n and hk[c + 1] > hk[c]:
            c += 1
        if hk[c] <= lk:
            break
        hk[i] = hk[c]
        ht[i] = ht[c]
        hv[i] = hv[c]
        i = c
    hk[i] = lk
    ht[i] = lt
    hv[i] = lv
    return key, t, ver


@njit(cache=True, _nrt=False)
def _heap_rebuild(S):
    """Drop stale entries: refill the heap from the live tets."""
    S[_CTR][C_HEAPN] = 0
    alive = S[_ALIVE]
    hk = S[_HKEY]
    for t in range(S[_CTR][C_HW]):
        if alive[t] and S[_TBEST][t] >= 0 and S[_CTR][C_HEAPN] < hk.shape[0]:
            _heap_push(S, _greedy_key(S, t), t, S[_TVER][t])


@njit(cache=True, _nrt=False)
def _set_best(S, t, best, bestr):
    S[_TBEST][t] = best
    S[_TBESTR][t] = bestr
    if S[_FOPT][O_GREEDY] > 0.0 and best >= 0:
        if S[_CTR][C_HEAPN] >= S[_HKEY].shape[0]:
            _heap_rebuild(S)  # full of stale entries: refill from the live tets (t included)
        else:
            _heap_push(S, _greedy_key(S, t), t, S[_TVER][t])


@njit(cache=True, _nrt=False)
def _greedy_key(S, t):
    """Heap key of tet t: its worst residual (``greedy_key="max"``) or its squared-error sum ("sse")."""
    if S[_FOPT][O_GKEY] > 0.0:
        return S[_TSSE][t]
    return S[_TBESTR][t]


@njit(cache=True)
def greedy_next(S):
    """The candidate with the largest |f - L| over all tets (Garland & Heckbert 1995, in 3-D).

    Pops stale heap entries (dead or rebuilt tets) until the top is current.
    Returns -1 when no candidate has a nonzero residual.
    """
    alive = S[_ALIVE]
    tver = S[_TVER]
    while True:
        key, t, ver = _heap_pop(S)
        if t < 0:
            return -1
        if alive[t] and tver[t] == ver and S[_TBEST][t] >= 0:
            return S[_TBEST][t]


@njit(cache=True)
def run_greedy(S, stop_nvert, tol_rms, n_total, log):
    """Insert the worst-approximated candidate, swap, repeat, until ``stop_nvert`` vertices.

    Each tet's candidate (its contained non-vertex candidate point with the largest
    residual) sits in the heap; insertion and flips replace tets, and
    :func:`_replace` pushes the new ones, so only touched tets are refreshed.
    Inserted points are appended to ``log``; returns how many were inserted.
    """
    ctr = S[_CTR]
    tolinf = S[_FOPT][O_TOLINF]
    k = 0
    while ctr[C_NVERT] < stop_nvert:
        if tol_rms >= 0.0 and np.sqrt(max(S[_ACC][0], 0.0) / n_total) <= tol_rms:
            break
        if tolinf >= 0.0 and ctr[C_ABOVE] == 0:
            break
        p = greedy_next(S)
        if p < 0:
            break
        case, ids = insert_point(S, p)
        if ctr[C_ERROR] != 0:
            break
        log[k] = p
        k += 1
        swap(S, ids, ids.shape[0], True)
        if ctr[C_ERROR] != 0:
            break
    return k


@njit(cache=True)
def point_weights(S, verts, weights):
    """For every original point: the 4 vertices of a tet containing it and its barycentric weights."""
    I_ = S[_IC]
    P_ = S[_P]
    F_ = S[_F]
    ui_ = S[_FOPT][O_USEINT] > 0.0
    tets = S[_TETS]
    owner = S[_OWNER]
    for p in range(S[_F].shape[0]):
        t = owner[p]
        q0, q1, q2, q3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        verts[p, 0] = q0
        verts[p, 1] = q1
        verts[p, 2] = q2
        verts[p, 3] = q3
        w0 = max(_vol(I_, P_, ui_, p, q1, q2, q3), 0.0)
        w1 = max(_vol(I_, P_, ui_, q0, p, q2, q3), 0.0)
        w2 = max(_vol(I_, P_, ui_, q0, q1, p, q3), 0.0)
        w3 = max(_vol(I_, P_, ui_, q0, q1, q2, p), 0.0)
        tot = w0 + w1 + w2 + w3
        weights[p, 0] = w0 / tot
        weights[p, 1] = w1 / tot
        weights[p, 2] = w2 / tot
        weights[p, 3] = w3 / tot


# ----------------------------------------------------------------------------- Python side

def make_state(points, values, ijk=None, *, criterion="rms", vertices_in_error=True, rel_tol=1e-9,
               abs_tol=None, tol_inf=None, first_improving=False, max_rounds=UNLIMITED_ROUNDS,
               tet_capacity=None, pool_capacity=None, greedy=False, greedy_key="max", candidates=None,
               boundary_flips=False, swap_memory="run", pin=True):
    """Allocate the flat arrays of an empty mesh over the given original points.

    ``memory``: how long :func:`swap` remembers evaluated configurations, ``"call"``
    (one swap) or ``"run"`` (a fixed table of about 2 N entries, 56 bytes each,
    kept for the whole run); default ``"run"`` with ``greedy``, else ``"call"``
    (:func:`trivsel.reduce` passes its ``swap_memory``, ``"run"`` by default).
    See the comment above ``_KEYLEN``.
    ``pin=False`` skips :func:`_pin_signatures` (for :func:`compile_kernels`)."""
    # C-contiguous and writable, so that every state has the same numba type
    P = np.require(points, np.float64, ["C", "W"])
    F = np.require(values, np.float64, ["C", "W"])
    N = F.shape[0]
    IC = np.require(ijk, np.int64, ["C", "W"]) if ijk is not None else np.zeros((N, 3), np.int64)
    cap = int(tet_capacity or (8 * N + 1024))
    pcap = int(pool_capacity or (24 * N + 4096))
    frange = float(F.max() - F.min()) if N else 0.0
    if abs_tol is None:
        abs_tol = 1e-12 * max(frange, 1e-300)
        if criterion == "sse":
            abs_tol = abs_tol**2 * N
    if criterion not in CRITERIA:
        raise ValueError(f"unknown swap criterion {criterion!r}: choose one of {sorted(CRITERIA)}")
    fopt = np.array([1.0 if ijk is not None else 0.0, CRITERIA[criterion], 1.0 if vertices_in_error else 0.0,
                     rel_tol, abs_tol, -1.0 if tol_inf is None else float(tol_inf),
                     1.0 if first_improving else 0.0, float(max_rounds), 1.0 if greedy else 0.0,
                     1.0 if greedy_key == "sse" else 0.0, 1.0 if boundary_flips else 0.0])
    if greedy_key not in ("max", "sse"):
        raise ValueError(f"unknown greedy key {greedy_key!r}: choose 'max' or 'sse'")
    memory = swap_memory
    if memory not in ("call", "run"):
        raise ValueError(f"unknown swap memory {memory!r}: choose 'call' or 'run'")
    fopt = np.append(fopt, 1.0 if memory == "run" else 0.0)  # O_RUNMEM
    mrows = 1 << max(10, int(2 * N - 1).bit_length()) if memory == "run" else 1
    mkey = np.full((mrows, _KEYLEN), -1, np.int64)
    cand = np.ones(N, np.uint8)
    if candidates is not None:
        cand[:] = 0
        cand[np.asarray(candidates, np.int64)] = 1
    # tets, nbr and the greedy candidate of a slot are written when _alloc hands the
    # slot out, so they start uninitialised: np.empty leaves the untouched part of
    # the capacity (8 N tets) unmapped, where np.full wrote it all (3 % of a greedy
    # run on 65^3)
    S = (P, IC, F,
         np.empty((cap, 4), np.int32), np.empty((cap, 4), np.int32), np.zeros(cap, np.uint8),
         np.zeros(cap, np.int32), np.zeros(cap, np.int64), np.zeros(cap, np.int32),
         np.zeros(pcap, np.int32), np.zeros(cap), np.zeros(cap), np.zeros(cap, np.int32),
         np.zeros(N, np.int64), np.zeros(N), np.full(N, -1, np.int32), np.zeros(N, np.uint8),
         np.zeros(N, np.int32), np.zeros(24, np.int64), fopt, np.zeros(4), np.zeros(cap, np.int64),
         np.empty(cap, np.int32), np.zeros(cap), np.zeros(cap, np.int64),
         np.zeros(2 * cap), np.zeros(2 * cap, np.int64), np.zeros(2 * cap, np.int64), cand,
         mkey, np.empty((mrows, 2)))
    if pin:
        _pin_signatures(S)
    return S


_PINNED = set()  # state types the helpers are compiled for


def _helper_signatures(S):
    """The internal helpers and their one signature (int64 indices), callees before
    callers, for the state type of ``S``."""
    from numba import typeof, types as nt

    st = typeof(S)
    i8, b1, f8 = nt.int64, nt.boolean, nt.float64
    v8, m8, m4 = nt.int64[::1], nt.int64[:, ::1], nt.int32[:, ::1]
    f82 = nt.float64[:, ::1]
    return [
        (_sign, (m8, f82, b1, i8, i8, i8, i8)),
        (_vol, (m8, f82, b1, i8, i8, i8, i8)),
        (_crit, (f8, f8, f8, i8)),
        (_other_index, (m4, i8, i8, i8, i8)),
        (_push_unique, (v8, i8, i8, v8, i8)),
        (_with_room, (v8, i8, i8)),
        (_copy1, (v8, v8, i8)),
        (_copy2, (m8, m8, i8)),
        (_sort_into, (v8, i8, v8)),
        (_gather_at, tuple(st.types[k] for k in (_CTR, _MARK, _WBUF, _POOL, _BSTART, _BLEN)) + (v8, i8)),
        (_gather, (st, v8, i8)),
        (_positive_at, (m8, f82, b1, m8, i8)),
        (_positive, (st, m8, i8)),
        (_config23_at, (m4, m4, i8, i8, v8, m8)),
        (_cannot_beat, (f8,) + tuple(st.types[k] for k in (_TSSE, _TMAX, _TCNT)) + (v8, i8, f8)),
        (_evaluate_at, (st, v8, v8, i8, m8, i8, f8, f8, b1)),
        (_evaluate, (st, v8, i8, m8, i8, f8, f8)),
        (_set_best, (st, i8, i8, f8)),
        (_replace, (st, v8, i8, m8, i8, b1)),
        (_config_key, (v8, i8, i8, i8, v8, i8, v8)),
        (_cache_slot, (m8, v8, i8)),
        (_cache_store, (m8, f82, i8, i8, v8, f8, f8)),
        (swap, (st, v8, i8, b1)),  # last: it calls the helpers above
    ]


def _pin(fn, sig):
    """Compile (or load from the cache) ``fn`` for ``sig`` and forbid other variants."""
    fn.disable_compile(False)
    fn.compile(sig)
    fn.disable_compile(True)


def _pin_signatures(S):
    """Compile each internal helper for one argument signature (int64 indices) and
    forbid further variants.

    Without this, numba compiles a helper once per combination of argument types
    it meets while typing its callers: int32 read from ``tets`` against int64
    loop indices, ``Literal[int](2)`` against ``int64``, ``Literal[bool](True)``
    against ``bool``.  That was 7 copies of :func:`_replace`, 12 of :func:`_sign`,
    2 of :func:`swap` and so on: more than half of the one-time compilation.
    With one pinned signature, numba converts the arguments at the call instead.
    Runs in :func:`make_state` (once per state type), so ``import trivsel`` stays
    cheap; each signature comes from the on-disk cache after the first run.
    """
    from numba import typeof

    if not hasattr(swap, "disable_compile"):  # NUMBA_DISABLE_JIT=1: plain Python functions
        return
    st = typeof(S)
    if st in _PINNED:
        return
    for fn, sig in _helper_signatures(S):
        _pin(fn, sig)
    _PINNED.add(st)


#: The pinned helpers of swapping alone (part 0 of :func:`compile_kernels`; ``_evaluate``
#: is its wrapper for :class:`TetMesh`).
_SWAP_ONLY = ("_push_unique", "_with_room", "_config23_at", "_cannot_beat", "_evaluate_at", "_evaluate", "_config_key",
              "_cache_slot", "_cache_store", "swap")


def compile_kernels(method="paper", part=None):
    """Compile the numba kernels of a reduction into numba's on-disk cache.

    A reduction compiles its kernels on first use anyway (about 21 s once per
    machine, then they load from the cache in ``__pycache__``).  This splits the
    work into two halves that share little, so that two processes fill the cache
    in about half the time: the workflow's ``kernels`` rule runs ``trivsel compile
    --part 0`` and ``--part 1`` side by side before the reductions fan out.

    Parameters
    ----------
    method : {"paper", "greedy"}
        Which driver the kernels are for (:func:`run_insertions` or :func:`run_greedy`).
    part : {None, 0, 1}
        ``1``: point insertion (section 4: in a tet, on a face, on an edge), the
        replacement of tets it shares with swapping (compiled first, so that part 0
        finds it in the cache), bucket filling and residuals.  ``0``: swapping
        (section 4: 2-3, 3-2, 4-4 flips) and the configuration evaluation.
        ``None``: both, then the driver: everything a reduction compiles.

    Returns
    -------
    int
        The number of (kernel, signature) pairs compiled or loaded.
    """
    from numba import typeof, types as nt

    if method not in ("paper", "greedy"):
        raise ValueError(f"unknown method {method!r}: choose 'paper' or 'greedy'")
    if part not in (None, 0, 1):
        raise ValueError(f"unknown part {part!r}: choose 0, 1 or None (both)")
    if not hasattr(swap, "disable_compile"):  # NUMBA_DISABLE_JIT=1: nothing to compile
        return 0
    ijk = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.int64)
    S = make_state(ijk.astype(np.float64), np.zeros(4), ijk, pin=False, greedy=method == "greedy")
    st = typeof(S)
    helpers = _helper_signatures(S)
    i8, f8, v8 = nt.int64, nt.float64, nt.int64[::1]
    # cheap leaves first (both halves), then each half's own subtree, callees first
    leaves = [h for h in helpers if h[0] in (_sign, _vol, _crit, _other_index, _copy1, _copy2,
                                             _sort_into, _gather_at, _gather, _positive_at, _positive)]
    replace = [h for h in helpers if h[0] in (_set_best, _replace)]
    swapping = [h for h in helpers if h[0].__name__ in _SWAP_ONLY and h[0] is not swap]
    swapping += replace + [h for h in helpers if h[0] is swap]
    insertion = replace + [(fill_buckets, (st, v8)), (residuals, (st, nt.float64[::1])),
                           (insert_point, (st, i8)), (cone_from_hull, (st, i8))]
    driver = ((run_greedy, (st, i8, f8, f8, v8)) if method == "greedy"
              else (run_insertions, (st, v8, i8, i8, f8, f8)))
    pinned = {fn for fn, _ in helpers}
    plan = leaves + (swapping if part == 0 else insertion if part == 1 else
                     swapping + insertion[len(replace):] + [driver])
    for fn, sig in plan:
        if fn in pinned:
            _pin(fn, sig)
        else:
            fn.compile(sig)
    if part is None:
        _PINNED.add(st)
    return len(plan)


def face_neighbours(tets):
    """Face-neighbour links of a list of tets (numpy; for an initial mesh)."""
    tets = np.asarray(tets, np.int64)
    M = tets.shape[0]
    faces = np.concatenate([np.sort(np.delete(tets, i, axis=1), axis=1) for i in range(4)])
    owner = np.tile(np.arange(M), 4)
    local = np.repeat(np.arange(4), M)
    order = np.lexsort(faces.T[::-1])
    f = faces[order]
    same = np.all(f[1:] == f[:-1], axis=1)
    nbr = np.full((M, 4), -1, np.int64)
    i = np.flatnonzero(same)
    a, b = order[i], order[i + 1]
    nbr[owner[a], local[a]] = owner[b]
    nbr[owner[b], local[b]] = owner[a]
    return nbr


class TetMesh:
    """A mesh over original points, with the named operations of section 4.

    Parameters are those of :func:`make_state`.  ``start(tets)`` installs an
    initial triangulation (e.g. of the fixed points).
    """

    def __init__(self, points, values, ijk=None, **options):
        self.S = make_state(points, values, ijk, **options)
        self.options = options

    # -- state views
    @property
    def counters(self):
        return self.S[_CTR]

    @property
    def resid(self):
        """Residuals f - L of the original points (a view, kept current by every operation)."""
        return self.S[_RESID]

    @property
    def sse_sum(self):
        """The global sum of squared residuals, as the kernel keeps it."""
        return float(self.S[_ACC][0])

    @property
    def round_cap_hits(self):
        """How often swapping stopped at ``max_rounds`` flips."""
        return int(self.S[_CTR][C_ROUNDCAP])

    @property
    def error_code(self):
        return int(self.S[_CTR][C_ERROR])

    def _raise_on_error(self):
        code = self.error_code
        if code:
            names = {ERR_TETCAP: "tet capacity exceeded", ERR_POOLCAP: "point-bucket capacity exceeded",
                     ERR_LINK: "face matching failed", ERR_UNCOVERED: "a point left uncovered",
                     ERR_DUPLICATE: "point coincides with a vertex (duplicate point)"}
            raise MeshError(code, names.get(code, f"error {code}"))

    def live_ids(self):
        hw = self.S[_CTR][C_HW]
        return np.flatnonzero(self.S[_ALIVE][:hw])

    def tetrahedra(self):
        """The live tets as an (M, 4) array of original point indices."""
        return self.S[_TETS][self.live_ids()].astype(np.int64)

    def neighbours(self):
        ids = self.live_ids()
        return ids, self.S[_NBR][ids].astype(np.int64)

    def bucket(self, t):
        s, L = self.S[_BSTART][t], self.S[_BLEN][t]
        return self.S[_POOL][s:s + L].copy()

    def vertices(self):
        return np.flatnonzero(self.S[_ISVERT])

    # -- operations
    def start(self, tets):
        """Install an initial triangulation (positively oriented tets) and fill its buckets."""
        tets = np.asarray(tets, np.int64)
        nbr = face_neighbours(tets)
        ids = np.array([_alloc(self.S) for _ in range(len(tets))], np.int64)
        self._raise_on_error()
        self.S[_TETS][ids] = tets
        self.S[_NBR][ids] = np.where(nbr >= 0, ids[np.maximum(nbr, 0)], -1)
        verts = np.unique(tets)
        self.S[_ISVERT][verts] = 1
        self.S[_CTR][C_NVERT] = len(verts)
        fill_buckets(self.S, ids)
        self._raise_on_error()
        return ids

    def insert(self, p):
        """Insert point p (cases i-iii); returns (case 1/2/3, new tet ids)."""
        case, ids = insert_point(self.S, int(p))
        self._raise_on_error()
        return case, ids

    def cone(self, p):
        ids = cone_from_hull(self.S, int(p))
        self._raise_on_error()
        return ids

    def swap(self, ids, with_neighbours=True):
        ids = np.ascontiguousarray(ids, np.int64)
        n = swap(self.S, ids, len(ids), with_neighbours)
        self._raise_on_error()
        return n

    def global_pass(self):
        n = global_pass(self.S)
        self._raise_on_error()
        return n

    def flip23(self, t, i, force=False):
        """Apply the 2-3 flip of tet t over its face i if admissible (and improving unless force)."""
        old = np.empty(4, np.int64)
        newq = np.empty((4, 4), np.int64)
        if not config23(self.S, int(t), int(i), old, newq) or not _positive(self.S, newq, 3):
            return None
        return self._apply(old, 2, newq, 3, force)

    def flip_edge(self, t, a, b, alt=0, force=False):
        """Apply the 3-2 (degree-3 edge) or 4-4 (degree-4 edge, diagonal alt) flip of edge (a, b)."""
        old = np.empty(4, np.int64)
        ring = np.empty(4, np.int64)
        newq = np.empty((4, 4), np.int64)
        k = edge_ring(self.S, int(t), int(a), int(b), old, ring)
        if k == 3:
            quads32(int(a), int(b), ring, newq)
            nn = 2
        elif k == 4:
            quads44(int(a), int(b), ring, int(alt), newq)
            nn = 4
        else:
            return None
        if not _positive(self.S, newq, nn):
            return None
        return self._apply(old, k, newq, nn, force)

    def flip22(self, t, a, b, force=False):
        """Apply the boundary 2-2 flip of hull edge (a, b) if admissible (and improving unless force)."""
        old = np.empty(2, np.int64)
        ring = np.empty(5, np.int64)
        newq = np.empty((4, 4), np.int64)
        k = edge_ring_open(self.S, int(t), int(a), int(b), old, ring)
        if k != 2 or _orient(self.S, int(a), int(b), int(ring[0]), int(ring[2])) != 0:
            return None
        quads32(int(a), int(b), ring, newq)
        if not _positive(self.S, newq, 2):
            return None
        if not force:
            before, after = _evaluate(self.S, old, 2, newq, 2, 0.0, -np.inf)
            if not after < before:
                return None
        ids = _replace(self.S, old, 2, newq, 2, True)
        self._raise_on_error()
        return ids

    def evaluate(self, old, newq):
        old = np.ascontiguousarray(old, np.int64)
        newq = np.ascontiguousarray(newq, np.int64)
        return _evaluate(self.S, old, len(old), newq, len(newq), 0.0, -np.inf)

    def _apply(self, old, nold, newq, nn, force):
        if not force:
            before, after = _evaluate(self.S, old, nold, newq, nn, 0.0, -np.inf)
            if not after < before:
                return None
        ids = _replace(self.S, old, nold, newq, nn, False)
        self._raise_on_error()
        return ids

    def run(self, order, start, stop, tol_rms=-1.0):
        k = run_insertions(self.S, np.ascontiguousarray(order, np.int64), int(start), int(stop), float(tol_rms),
                           float(self.S[_F].shape[0]))
        self._raise_on_error()
        return int(k)

    def greedy_next(self):
        """The next greedy candidate (largest residual), without inserting it; -1 if none."""
        p = greedy_next(self.S)
        _heap_rebuild(self.S)  # put the popped entry back
        return int(p)

    def run_greedy(self, stop_nvert, tol_rms=-1.0):
        log = np.empty(max(int(stop_nvert) - int(self.S[_CTR][C_NVERT]), 0) + 1, np.int64)
        k = run_greedy(self.S, int(stop_nvert), float(tol_rms), float(self.S[_F].shape[0]), log)
        self._raise_on_error()
        return log[:k].copy()

    def point_weights(self):
        """(N, 4) vertices and barycentric weights of a tet containing each original point."""
        N = self.S[_F].shape[0]
        verts = np.empty((N, 4), np.int64)
        w = np.empty((N, 4))
        point_weights(self.S, verts, w)
        return verts, w

    def residuals(self):
        """Residuals f - L at all original points, and the continuity defect."""
        out = np.zeros(self.S[_F].shape[0])
        worst = residuals(self.S, out)
        return out, worst

    def copy(self):
        other = TetMesh.__new__(TetMesh)
        other.S = tuple(a.copy() for a in self.S)
        other.options = dict(self.options)
        return other

    def criterion_sum(self):
        """The quantity the swaps lower: sum over live tets of their RMS (eq. 14) or max
        (eq. 15) error, or, for the SSE criterion, the squared residuals of all points
        (each counted once)."""
        ids = self.live_ids()
        sse, mx, cnt = self.S[_TSSE][ids], self.S[_TMAX][ids], self.S[_TCNT][ids]
        c = self.S[_FOPT][O_CRIT]
        if c == 0:
            return float(np.sum(np.sqrt(np.divide(sse, cnt, out=np.zeros_like(sse), where=cnt > 0))))
        if c == 1:
            return float(np.sum(mx))
        r = self.S[_RESID]
        return float(np.dot(r, r))

    @property
    def flips(self):
        c = self.S[_CTR]
        out = {"2-3": int(c[C_FLIP23]), "3-2": int(c[C_FLIP32]), "4-4": int(c[C_FLIP44])}
        if self.S[_FOPT][O_BFLIP] > 0.0:
            out["2-2"] = int(c[C_FLIP22])
        return out

    @property
    def evaluations(self):
        """Configurations :func:`swap` evaluated (``made``) and found in its memory
        (``remembered``) so far."""
        c = self.S[_CTR]
        return {"made": int(c[C_EVALS]), "remembered": int(c[C_MEMHITS])}

    @property
    def cases(self):
        c = self.S[_CTR]
        return {"tet": int(c[C_CASE1]), "face": int(c[C_CASE2]), "edge": int(c[C_CASE3])}


class MeshError(RuntimeError):
    """An internal failure of the mesh kernel (capacity or consistency)."""

    def __init__(self, code, message):
        super().__init__(message)
        self.code = code


def check_mesh(mesh, **kwargs):
    """The mesh-validity checker (:func:`trivsel.check.check_mesh`)."""
    from .check import check_mesh as _check

    return _check(mesh, **kwargs)
