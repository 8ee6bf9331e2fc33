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
  in the exact greedy order near it.  A collapse right after its vertex's evaluation
  takes the tetrahedra and residuals that the evaluation found for the moved points
  (``State.LT``, ``LR``) instead of locating them again.
* **Stop**: at a vertex count, before the collapse that would take E_RMS above a
  tolerance, or when no collapse keeps every residual within an E_inf tolerance.

Geometry is on integer grid coordinates: barycentric weights are unchanged by the
grid's spacing and origin (an affine map), so the interpolant, the residuals and
the validity are those of the grid in world coordinates.
"""

from __future__ import annotations

from itertools import permutations
from typing import NamedTuple

import os

import numpy as np

__all__ = ["grid_tetrahedra", "Decimation"]

INF = np.inf

# lock bits of a point: bit a (a = 0, 1, 2) set when the point is on the box's low or high
# face normal to axis a; LOCK_ALL when it may not move at all; LOCK_MESH when it is on the
# boundary of a mesh's domain (it moves only within its flat patch or along its crease)
LOCK_ALL = 8
LOCK_MESH = 16
#: Corners (4 per tet) below which the mesh's indices are int32 (above, int64; the same results)
INT32_CORNERS = 2**31
#: Room in the corner pool, over the corners' segments (``_segments``);
#: when a segment must move and the pool is full, it is compacted (``Decimation._compact``)
POOL_ROOM = 1.5
#: Children of a slot of the collapse queue's heap (``_sift_down`` in :mod:`.collapse`)
QUEUE_ARITY = 4
#: The most tetrahedra around one vertex that a collapse considers (a vertex with more stays)
STAR_CAPACITY = 1 << 16
#: The most points of a star whose places an evaluation keeps for the collapse that may follow it
#: (``State.LT``, ``State.LR``); a star with more has them located again by the collapse
KEEP_POINTS = 1 << 12


def _split_size(shape):
    """The number of tetrahedra of the Kuhn split of the grid ``shape``: 6 a cell."""
    return 6 * int(np.prod(np.asarray(shape, np.int64) - 1))


def grid_tetrahedra(shape, *, dtype=np.int64, out=None):
    """The Kuhn split of the grid ``shape``: 6 positively oriented tetrahedra per cell,
    each a monotone path from the cell's low corner to its high corner, so that
    neighbouring cells split their shared faces alike.

    Parameters
    ----------
    shape : tuple of 3 ints
        Points per axis, at least 2 each; points are numbered in C order.
    dtype : integer dtype, optional
        The indices' type, when ``out`` is not given.
    out : (M, 4) integer array, optional
        Filled in place (C-contiguous, ``M = 6 * prod(shape - 1)``): the split written
        straight into the array that keeps it, with no temporary of its size.

    Returns
    -------
    (M, 4) array
        Row ``6 c + q`` is tetrahedron q of cell c (cells in C order of their low corner):
        a cell's 6 tets side by side, so a vertex's tets lie close together in memory::

            a -> b -> c -> d       one step along each axis, in the order of permutation q
            (a, b, c, d), or (b, a, c, d) for an odd permutation: positive orientation
    """
    n = np.asarray(shape, np.int64)
    if n.shape != (3,) or np.any(n < 2):
        raise ValueError(f"a grid needs at least 2 points per axis, got {tuple(shape)}")
    M = _split_size(n)
    if out is None:
        out = np.empty((M, 4), dtype)
    elif out.shape != (M, 4) or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous ({M}, 4) array, got {out.shape}")
    if int(np.prod(n)) - 1 > np.iinfo(out.dtype).max:
        raise ValueError(f"{out.dtype} cannot index the {int(np.prod(n))} points of the grid {tuple(shape)}")
    step = np.array([n[1] * n[2], n[2], 1], np.int64)
    # each cell's low corner, by broadcasting the axes' offsets (no meshgrid of the grid's size)
    base = (np.arange(n[0] - 1)[:, None, None] * step[0] + np.arange(n[1] - 1)[None, :, None] * step[1]
            + np.arange(n[2] - 1)[None, None, :]).astype(out.dtype)
    cells = out.reshape(n[0] - 1, n[1] - 1, n[2] - 1, 6, 4)
    for q, perm in enumerate(permutations(range(3))):
        corner = [0, step[perm[0]], step[perm[0]] + step[perm[1]], step.sum()]
        # the path's orientation is the sign of the permutation
        if sum(perm[x] > perm[y] for x in range(3) for y in range(x + 1, 3)) % 2:
            corner[0], corner[1] = corner[1], corner[0]
        for s in range(4):
            np.add(base, corner[s], out=cells[:, :, :, q, s], casting="unsafe")
    return out


class State(NamedTuple):
    """The flat arrays of a decimation (numba compiles field access statically)::

        P[p]          integer grid coordinates of point p
        f[p]          its value
        T[t]          the 4 vertices of tet t (orient3d > 0) while alive[t]
        corner c = 4 t + s is slot s of tet t; the corners of vertex v are the segment
        cpool[vstart[v]:vstart[v] + deg[v]] (capacity vcap[v]), newest last: reading a
        star is one contiguous read, not a chain of cache misses (see ``_link`` in
        :mod:`trivsel.decimation.collapse`)
        phead[t]      first point in the bucket of tet t; pnext[p] the next; ptet[p] the tet
        (indices into the mesh are int32 while the corners fit, see ``INT32_CORNERS``)
        res[p]        f - L at p (0 at vertices); isv[p] whether p is a vertex
        dirty[v]      v is queued with a cost from before its tets last changed (lazy)
        lock[p]       the box constraint (bits above)
        heap          hv[0:hn] vertices by (key, degree, vertex), QUEUE_ARITY children a
                      slot; qkey, qdeg the key and degree of each slot's entry; hpos[v]
                      v's slot (-1: not queued); hkey[v], hsse[v], htgt[v] the key, the
                      change of the squared-residual sum and the target of v's cheapest
                      collapse (kept once v is removed)
        removed[k]    the k-th vertex removed, into[k] the vertex it moved onto
        acc[0]        the sum of squared residuals; ctr: [n_vertices, n_removed, heap size,
                      the max criterion, lazy updates, the corner pool's top, float
                      coordinates, the vertex whose best collapse LT/LR hold (-1: none),
                      their row, its star's point count, the collapses made from them]
        LT, LR        for the last evaluated vertex v and its cheapest collapse: the tet
                      and the residual of v (column 0) and of each point of its star's
                      buckets, in ``pbuf`` order, as the collapse will place them (two rows:
                      the best candidate's and the one being costed)
        scratch       sc a star's corners, Q their tets' vertices, G their far faces'
                      planes, kw whether each holds the target being tried, X[i, j]
                      the star tet across tet i's face opposite its slot j, B the
                      boundary triangles around a mesh's boundary vertex; pbuf
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
    qkey: np.ndarray
    qdeg: np.ndarray
    removed: np.ndarray
    into: np.ndarray
    dirty: np.ndarray
    sc: np.ndarray
    Q: np.ndarray
    G: np.ndarray
    kw: np.ndarray
    X: np.ndarray
    B: np.ndarray
    stamp: np.ndarray
    pbuf: np.ndarray
    phome: np.ndarray
    aff: np.ndarray
    acc: np.ndarray
    ctr: np.ndarray
    LT: np.ndarray
    LR: np.ndarray


C_NV, C_NREM, C_HN, C_MAXKEY, C_LAZY, C_PTOP, C_FLOAT, C_LAST, C_LROW, C_LM, C_KEPT = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10


def _kept_places():
    """Empty ``State.LT`` and ``State.LR``, as keyword arguments of :class:`State`."""
    return {"LT": np.zeros((2, KEEP_POINTS), np.int64), "LR": np.zeros((2, KEEP_POINTS))}

#: The module of the compiled kernels, and the sources their machine code depends on
KERNELS = "trivsel.decimation.collapse"
_HERE = os.path.dirname(os.path.abspath(__file__))
_PARENT = os.path.dirname(_HERE)
KERNEL_SOURCES = (os.path.join(_HERE, "collapse.py"), os.path.join(_HERE, "__init__.py"),
                  *(os.path.join(_PARENT, f) for f in ("predicates.py", "aot.py")))


def kernels(S, *, rebuild=False):
    """The kernels ``init``, ``link``, ``run``, ``replay``, ``flush`` and ``weights`` for states of the layout of
    ``S``: compiled ahead of time and loaded without numba, or numba's own
    (:func:`trivsel.aot.kernels`; the same results)."""
    from ..aot import kernels as _kernels

    return _kernels(KERNELS, KERNEL_SOURCES, S, rebuild=rebuild)


def _segments(deg):
    """Capacities and starts of consecutive corner segments for vertices of degrees ``deg``:
    each with half its count again as room, plus 4."""
    cap = deg + deg // 2 + 4
    return cap, np.cumsum(cap) - cap


def _pool(size, dtype):
    """A corner pool of ``size`` entries.  Zeros from the allocator, not a fill: the operating
    system maps a page of it only when a segment is written there, so the room above the
    segments, which a run fills slowly and rarely all of, takes no memory until it is used.
    Nothing reads a pool entry that was not written (a segment is read up to its count), so
    what the room holds does not matter."""
    return np.zeros(size, dtype)


def _aligned_empty(shape, dtype, line=64):
    """An empty C-order array whose data starts on a cache-line boundary, so that rows of a
    size that divides ``line`` never straddle two lines."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape)) * dtype.itemsize
    buf = np.empty(nbytes + line, np.uint8)
    off = -buf.ctypes.data % line
    return buf[off:off + nbytes].view(dtype).reshape(shape)


def _plain(a, dtype):
    """``a`` as a C-contiguous, writeable base array of ``dtype``: the caller's own array when it
    is one, else a copy (a memmap or another subclass is taken as its base array).  Every state
    of a layout then has one numba type, and so one compiled module: a read-only array (values
    read from a CSV file, say) is a numba type of its own, which would need a compile of its own.
    The kernels never write coordinates or values."""
    return np.require(a, dtype, ["C", "W", "E"])


def new_state(ijk, shape, values, *, lock="box", key="sse", lazy=False):
    """The :class:`State` of a decimation of grid data before its first collapse (the corner
    segments sized, nothing linked or queued yet: the kernels' ``init`` does that)."""
    # int32 coordinates: half the memory a star's points take; the kernels' arithmetic on
    # them is int64 (numba widens smaller integers), exact as before
    P = _plain(ijk, np.int32)
    N = P.shape[0]
    M = _split_size(shape)
    # indices as int32 while they fit (and counts and lock bits smaller still): the queue
    # visits the volume in cost order, so a collapse reads these arrays at random, and
    # the smaller they are the more of them stays in cache
    ix = np.int32 if 4 * M < INT32_CORNERS else np.int64
    T = grid_tetrahedra(shape, out=_aligned_empty((M, 4), ix))
    deg = np.bincount(T.ravel(), minlength=N)
    cap, vstart = _segments(deg)
    hi = np.asarray(shape, np.int64) - 1
    on = (P == 0) | (P == hi)
    lk = (on[:, 0] * 1 + on[:, 1] * 2 + on[:, 2] * 4).astype(np.int64)
    lk[on.all(axis=1)] |= LOCK_ALL
    if lock == "all":
        lk[on.any(axis=1)] |= LOCK_ALL
    return State(P=P, f=_plain(values, np.float64), T=T, alive=np.ones(M, np.bool_),
                 cpool=_pool(int(cap.sum() * POOL_ROOM), ix), vstart=vstart, vcap=cap.astype(np.int32),
                 phead=np.full(M, -1, ix),
                 pnext=np.full(N, -1, ix), ptet=np.full(N, -1, ix), res=np.zeros(N),
                 isv=np.ones(N, np.bool_), lock=lk.astype(np.int8), hv=np.zeros(N, ix), hpos=np.full(N, -1, ix),
                 hkey=np.full(N, INF), hsse=np.full(N, INF), htgt=np.full(N, -1, ix), qkey=np.full(N, INF), qdeg=np.zeros(N, np.int32),
                 deg=np.zeros(N, np.int32), mark=np.zeros(N, np.int64),
                 removed=np.zeros(N, np.int64), into=np.zeros(N, np.int64), dirty=np.zeros(N, np.bool_), sc=np.zeros(STAR_CAPACITY, np.int64),
                 Q=np.zeros((STAR_CAPACITY, 4), np.int64), G=np.zeros((STAR_CAPACITY, 4), np.int64),
                 kw=np.zeros(STAR_CAPACITY, np.bool_), X=np.full((STAR_CAPACITY, 4), -2, np.int64), B=np.zeros((2 * STAR_CAPACITY, 2), np.int64),
                 stamp=np.zeros(1, np.int64),
                 pbuf=np.zeros(N, np.int64), phome=np.zeros(N, np.int64), aff=np.zeros(N, np.int64), acc=np.zeros(1),
                 ctr=np.array([N, 0, 0, key == "max", bool(lazy), cap.sum(), 0, -1, 0, 0, 0], np.int64),
                 **_kept_places())


def _det3(u, v, w):
    """Row-wise ``det[u, v, w]`` of (k, 3) arrays."""
    return np.einsum("ij,ij->i", np.cross(u, v), w)


def _cross(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def lattice_weights(x, q):
    """The integer barycentric weights of points in their tetrahedra on a lattice, as the
    collapse kernel computes them: ``x`` the points' coordinates and ``q`` their tetrahedra's
    corners' (three int64 arrays each, one per axis, of shapes (k,) and (k, 4)).  With ``d_j
    = q_j - x`` (corner j less the point), the signed volumes with x in each slot in turn are
    exact integers from two cross products::

        l0 = d1 . (d2 x d3)     l1 = -d0 . (d2 x d3)
        l2 = d3 . (d0 x d1)     l3 = -d2 . (d0 x d1)

    Returns the (k, 4) int64 array of ``l``."""
    d = [[q[a][:, j] - x[a] for a in range(3)] for j in range(4)]
    c23, c01 = _cross(d[2], d[3]), _cross(d[0], d[1])
    return np.stack([_dot(d[1], c23), -_dot(d[0], c23), _dot(d[3], c01), -_dot(d[2], c01)], axis=1)


def lattice_interpolant(lam, fc):
    """The linear interpolant (eq. 13) at points of weights ``lam`` (:func:`lattice_weights`)
    in tetrahedra of corner values ``fc`` (k, 4), as the collapse kernel computes it: ``(l0 f0
    + l1 f1 + l2 f2 + l3 f3) / (l0 + l1 + l2 + l3)`` in that order, not from rounded weights.
    A residual the kernel kept within a tolerance is then the same number here, to the bit."""
    lf, fc = lam.astype(np.float64), np.asarray(fc, np.float64)
    return (lf[:, 0] * fc[:, 0] + lf[:, 1] * fc[:, 1] + lf[:, 2] * fc[:, 2] + lf[:, 3] * fc[:, 3]) \
        / (lf[:, 0] + lf[:, 1] + lf[:, 2] + lf[:, 3])


#: How far (in units of the float spacing of the largest coordinate) a point may be from
#: its lattice position and still count as on the lattice: the rounding of ``origin + i *
#: spacing`` in whatever order a writer computed it, nothing a user would mean as a shift.
LATTICE_ULPS = 64


def lattice_coordinates(points):
    """Integer coordinates ``ijk`` with ``points = origin + ijk * spacing`` per axis, up to the
    rounding of that formula in float (:data:`LATTICE_ULPS`), or None when the points are not
    on such a lattice (or it has more than 2^20 steps per axis).  A mesh made from a grid,
    written with a float spacing such as 0.1, is on a lattice."""
    p = np.asarray(points, np.float64)
    ijk = np.empty(p.shape, np.int64)
    for a in range(3):
        u = np.unique(p[:, a])
        if len(u) < 2:
            return None
        span = float(u[-1] - u[0])
        steps = round(span / float(np.min(np.diff(u))))
        if not 1 <= steps < 2**20:
            return None
        step = span / steps
        k = np.round((p[:, a] - u[0]) / step)
        tol = LATTICE_ULPS * np.spacing(max(abs(float(u[0])), abs(float(u[-1])), span))
        if np.max(np.abs(u[0] + k * step - p[:, a])) > tol:
            return None
        ijk[:, a] = k.astype(np.int64)
    return ijk


def new_mesh_state(points, tets, values, *, located=None, key="sse", lazy=False, boundary=None):
    """The :class:`State` of a decimation of a tetrahedral mesh: coordinates ``points``,
    positively oriented ``tets`` (every tet of nonzero volume, conforming), point values;
    ``located`` the tet holding each point that is no tet's vertex (-1 for the vertices).
    The mesh's boundary vertices get ``LOCK_MESH``.  Points on a lattice (a mesh made
    from a grid, say) take the exact integer predicates of grids on their lattice
    coordinates (an affine image: the same signs and barycentric weights); other points
    the robust predicates on their float coordinates (``ctr[C_FLOAT]``).  ``boundary``: the
    mesh's boundary triangles, when the caller has them."""
    from ..triangulation import boundary_triangles

    ijk = lattice_coordinates(points)
    P = _plain(points, np.float64) if ijk is None else ijk.astype(np.int32)
    f = _plain(values, np.float64)
    Tm = np.asarray(tets, np.int64)
    N, M = P.shape[0], Tm.shape[0]
    ix = np.int32 if 4 * M < INT32_CORNERS and N < INT32_CORNERS else np.int64
    T = _aligned_empty((M, 4), ix)
    T[...] = Tm
    deg = np.bincount(Tm.ravel(), minlength=N)
    cap, vstart = _segments(deg)
    lk = np.zeros(N, np.int8)
    lk[np.unique(boundary_triangles(Tm) if boundary is None else boundary)] = LOCK_MESH
    isv = deg > 0
    phead = np.full(M, -1, ix)
    pnext = np.full(N, -1, ix)
    ptet = np.full(N, -1, ix)
    res = np.zeros(N)
    if located is not None:  # points that are no tet's vertex: in the tet that holds them
        inside = np.flatnonzero(~isv)
        for p in inside:
            t = int(located[p])
            ptet[p] = t
            pnext[p] = phead[t]
            phead[t] = p
        if len(inside) and ijk is not None:  # the kernel's own interpolant: its sums of squared residuals start right
            corners = Tm[ptet[inside]]
            lam = lattice_weights(tuple(ijk[inside, a] for a in range(3)), tuple(ijk[corners, a] for a in range(3)))
            res[inside] = f[inside] - lattice_interpolant(lam, f[corners])
        elif len(inside):
            pf = np.asarray(points, np.float64)
            q = pf[Tm[ptet[inside]]]  # (k, 4, 3)
            x = pf[inside]
            lam = np.stack([_det3(q[:, 1] - x, q[:, 2] - x, q[:, 3] - x), _det3(x - q[:, 0], q[:, 2] - q[:, 0],
                            q[:, 3] - q[:, 0]), _det3(q[:, 1] - q[:, 0], x - q[:, 0], q[:, 3] - q[:, 0]),
                            _det3(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0], x - q[:, 0])], axis=1)
            lam = np.maximum(lam, 0.0)
            lam /= lam.sum(axis=1, keepdims=True)
            res[inside] = f[inside] - np.einsum("ij,ij->i", lam, f[Tm[ptet[inside]]])
    return State(P=P, f=f, T=T, alive=np.ones(M, np.bool_),
                 cpool=_pool(int(cap.sum() * POOL_ROOM), ix), vstart=vstart, vcap=cap.astype(np.int32),
                 phead=phead, pnext=pnext, ptet=ptet, res=res, isv=isv.copy(), lock=lk, hv=np.zeros(N, ix),
                 hpos=np.full(N, -1, ix), hkey=np.full(N, INF), hsse=np.full(N, INF), htgt=np.full(N, -1, ix),
                 qkey=np.full(N, INF), qdeg=np.zeros(N, np.int32), deg=np.zeros(N, np.int32), mark=np.zeros(N, np.int64),
                 removed=np.zeros(N, np.int64), into=np.zeros(N, np.int64), dirty=np.zeros(N, np.bool_), sc=np.zeros(STAR_CAPACITY, np.int64),
                 Q=np.zeros((STAR_CAPACITY, 4), np.int64), G=np.zeros((STAR_CAPACITY, 4), np.int64),
                 kw=np.zeros(STAR_CAPACITY, np.bool_), X=np.full((STAR_CAPACITY, 4), -2, np.int64), B=np.zeros((2 * STAR_CAPACITY, 2), np.int64),
                 stamp=np.zeros(1, np.int64),
                 pbuf=np.zeros(N, np.int64), phome=np.zeros(N, np.int64), aff=np.zeros(N, np.int64), acc=np.zeros(1),
                 ctr=np.array([int(isv.sum()), 0, 0, key == "max", bool(lazy), cap.sum(), ijk is None, -1, 0, 0, 0],
                              np.int64),
                 **_kept_places())


class Decimation:
    """A decimation in progress on grid data (integer coordinates ``ijk``, C-order points).

    ``run(count, sse_max)`` collapses down to ``count`` vertices (or to the tolerance);
    between calls the state is kept, so one run passes several counts.  ``lock`` is
    ``"box"`` (corners fixed; edge and face points move along their edge or face) or
    ``"all"`` (every box point fixed: only interior points are removed).  ``key`` orders
    the collapses: ``"sse"`` by the change of the squared-residual sum (aims at E_RMS),
    ``"max"`` by the largest |residual| of the points that move (aims at E_inf).  ``lazy``
    starts with lazy updates of the queue (the module's docstring); :attr:`lazy` switches.
    ``state``: a state made elsewhere (:func:`new_state` or :func:`new_mesh_state`); ``grid``:
    that state's grid shape when it is :func:`new_state`'s fresh Kuhn split (lock bits may
    differ), whose interior vertices are then first evaluated from one template.
    """

    def __init__(self, ijk, shape, values, *, tol_inf=None, lock="box", key="sse", lazy=False, state=None,
                 queue=True, grid=None):
        self.tol_inf = -1.0 if tol_inf is None else float(tol_inf)
        self.S = new_state(ijk, shape, values, lock=lock, key=key, lazy=lazy) if state is None else state
        self.S.acc[0] = float(np.sum(self.S.res ** 2))
        self.compactions = 0
        self._k = kernels(self.S)
        grid = shape if state is None else grid  # a fresh Kuhn split: interior vertices from one template
        if queue and grid is not None:
            self._k.init_grid(self.S, self.tol_inf, *(int(n) for n in grid))
        elif queue:
            self._k.init(self.S, self.tol_inf)
        else:  # for replay only: no collapse is costed
            self._k.link(self.S)

    @classmethod
    def on_mesh(cls, points, tets, values, *, located=None, tol_inf=None, key="sse", lazy=False, boundary=None):
        """A decimation of a tetrahedral mesh (:func:`new_mesh_state`): its boundary is kept
        exactly, its vertices removed by the same collapses as on a grid."""
        return cls(None, None, None, tol_inf=tol_inf, key=key, lazy=lazy,
                   state=new_mesh_state(points, tets, values, located=located, key=key, lazy=lazy,
                                        boundary=boundary))

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
            self._k.flush(self.S, self.tol_inf)
        self.S.ctr[C_LAZY] = bool(on)

    @property
    def sse(self):
        return float(self.S.acc[0])

    def run(self, count, sse_max=INF, key_max=INF):
        """Collapse to ``count`` vertices; returns 0 (reached), 1 (no valid collapse left)
        or 2 (the next collapse would take the squared-residual sum above ``sse_max``, or
        has a key, its cost, above ``key_max``)."""
        if self.released:
            raise RuntimeError("this decimation's queue was released: no collapse can follow")
        while True:
            code = int(self._k.run(self.S, int(count), float(sse_max), float(key_max), self.tol_inf))
            if code != 3:
                return code
            self._compact()

    def replay(self, removed, into):
        """Make the collapses ``removed[k] -> into[k]`` in order, as an earlier run from the same
        start made them (:meth:`removed`, :meth:`into`): the same mesh, residuals and buckets,
        with no cost computed.  Made with ``queue=False``: no :meth:`run` may follow."""
        vs, ws = np.ascontiguousarray(removed, np.int64), np.ascontiguousarray(into, np.int64)
        done = 0
        while done < len(vs):
            done = int(self._k.replay(self.S, vs, ws, done))
            if done < len(vs):
                self._compact()

    def _compact(self):
        """Copy every vertex's corners, in order, into a new pool, each segment with half its
        count again as room, and above the segments as much room as they take, and at least
        what the kernels' ``_run`` asks for any collapse (so that it never asks twice in a row)."""
        S = self.S
        v = np.flatnonzero(S.deg > 0)
        d = S.deg[v].astype(np.int64)
        cap, start = _segments(d)
        room = max(int(cap.sum() * (max(POOL_ROOM, 2.0) - 1.0)), 8 * int(d.max()) + 16)
        pool = _pool(int(cap.sum()) + room, S.cpool.dtype)
        k = np.arange(d.sum()) - np.repeat(np.cumsum(d) - d, d)
        pool[np.repeat(start, d) + k] = S.cpool[np.repeat(S.vstart[v], d) + k]
        S.vstart[v] = start
        S.vcap[:] = 0
        S.vcap[v] = cap
        S.ctr[C_PTOP] = cap.sum()
        self.S = S._replace(cpool=pool)
        self.compactions += 1

    #: The fields only collapses use: the queue, the corner pool and the scratch arrays.
    QUEUE_FIELDS = ("cpool", "vstart", "vcap", "deg", "hv", "hpos", "hkey", "hsse", "htgt", "qkey", "qdeg", "mark", "dirty",
                    "pbuf", "phome", "aff", "LT", "LR")

    def release_queue(self):
        """Free what only further collapses would use (:attr:`QUEUE_FIELDS`, about half the
        state) once none will follow, so that what comes after (the fit) does not add its
        memory to theirs.  The mesh, the buckets and the residuals stay: tetrahedra, vertices,
        residuals and point weights are read as before; :meth:`run` is refused."""
        self.S = self.S._replace(**{k: np.empty((0,) + getattr(self.S, k).shape[1:], getattr(self.S, k).dtype)
                                    for k in self.QUEUE_FIELDS})

    @property
    def released(self):
        """Whether :meth:`release_queue` has run (the corner pool is never empty before)."""
        return self.S.cpool.size == 0

    def removed(self):
        """The removed points, in order of removal."""
        return self.S.removed[: self.S.ctr[C_NREM]].copy()

    def into(self):
        """The vertex each removed point moved onto, in order of removal."""
        return self.S.into[: self.S.ctr[C_NREM]].copy()

    def vertices(self):
        return np.flatnonzero(self.S.isv)

    def tetrahedra(self):
        return self.S.T[self.S.alive].astype(np.int64)

    def residuals(self):
        return self.S.res.copy()

    def point_weights(self):
        return self._k.weights(self.S)

    def check(self):
        """Raise :class:`trivsel.mesh.validation.MeshInvalid` unless every live tetrahedron is
        positively oriented (exact), no face is in more than two, and every point that is no
        vertex lies in the tetrahedron of its bucket (weights >= 0 summing to 1)."""
        from ..mesh.validation import MeshInvalid
        from ..triangulation import _exact_signs, face_multiplicity

        S, tets = self.S, self.tetrahedra()
        if S.ctr[C_FLOAT]:
            sign = _exact_signs(S.P, tets)
        else:
            d = (S.P[tets[:, 1:]] - S.P[tets[:, :1]]).astype(np.int64)
            sign = np.sign(np.einsum("ij,ij->i", np.cross(d[:, 0], d[:, 1]), d[:, 2]))
        if (sign <= 0).any():
            k = int(np.argmax(sign <= 0))
            raise MeshInvalid(f"tet {tets[k].tolist()} is not positively oriented")
        faces = np.sort(np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 2, 3]], tets[:, [0, 1, 3]],
                                        tets[:, [0, 1, 2]]]), axis=1)
        if face_multiplicity(faces).max() > 2:
            raise MeshInvalid("a face is in more than two tetrahedra")
        _, w = self.point_weights()
        if (w < 0).any() or not np.allclose(w.sum(axis=1), 1.0):
            raise MeshInvalid("a point lies outside the tetrahedron of its bucket")


#: Target wall time of one call into the compiled loop, so that Ctrl-C stops a run promptly.
CHUNK_SECONDS = 0.25
#: While lazy updates may be chosen, whether the run is far from its stop (:func:`_far`) is
#: decided when the vertex count is a multiple of this, so that identical runs decide alike
#: however long their timed chunks are.
DECIDE_EVERY = 1024
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
                       t_start=None, start=None):
    """The whole run of ``method="decimate"`` for :func:`trivsel.reduce`.

    Collapses from the full grid down through ``targets`` (counts, visited in
    descending order), or until E_RMS would exceed ``tol_rms`` or no collapse keeps
    every residual within ``tol_inf``.  The queue is updated lazily while more than
    ``exact_within`` times the target count of vertices remain and E_RMS and E_inf are
    below ``tol_rms`` and ``tol_inf`` over ``exact_within``; nearer the stop, and for
    every stopping decision, it holds exact costs (``inf``: exact throughout).  Returns ``(snapshots, selected, stats,
    seconds)``: the snapshots ascending by count (:class:`trivsel.result.Snapshot`),
    the points in the order in which a selection grows (the final vertices in index
    order, then the removed points from last to first: ``selected[:k]`` is the
    selection of a snapshot with ``k`` points), the counters, and the seconds spent on
    the snapshots' errors and fits.  ``start``: the start mesh of non-grid data, as
    :func:`trivsel.decimation.tetmesh.start_mesh` gives it, when the caller has it.
    """
    import math
    import time

    from ..norms import error_norms
    from ..result import Snapshot

    t_start = time.perf_counter() if t_start is None else t_start
    N = data.n_points
    interior = data.interior_mask() if interior is None else interior
    if data.is_grid:  # on the grid's own lattice coordinates (a region's start at 0)
        dec = Decimation(data.ijk - data.ijk.min(axis=0), data.shape, data.values, tol_inf=tol_inf,
                         lock="all" if candidates == "interior" else "box", key=key)
    else:
        from .tetmesh import start_mesh

        tets, located, boundary = start_mesh(data) if start is None else start
        dec = Decimation.on_mesh(data.points, tets, data.values, located=located, tol_inf=tol_inf, key=key,
                                 boundary=boundary)
        if candidates == "interior":
            dec.S.lock[~interior] |= LOCK_ALL
    sse_max = INF if tol_rms is None else float(tol_rms) ** 2 * N * (1.0 + 1e-12)
    shots, t_errors, step, stopped, near, code = [], 0.0, 4096, False, False, 0
    last = min(int(t) for t in targets)  # progress counts down from the full grid to the last target

    def report():
        if progress is not None:
            progress(dec.n_vertices, last, float(np.sqrt(max(dec.sse, 0.0) / N)), float(np.max(np.abs(dec.S.res))),
                     time.perf_counter() - t_start)

    report()
    for target in sorted(set(int(t) for t in targets), reverse=True):
        while not stopped and dec.n_vertices > target:
            stop_at = max(target, dec.n_vertices - step)
            dec.lazy = not near and _far(dec, target, exact_within, tol_rms, tol_inf, N)
            if dec.lazy:
                stop_at = max(stop_at, math.floor(exact_within * target))
            if not near:  # decide lazy or exact at fixed counts only, not where a timed chunk ends
                stop_at = max(stop_at, (dec.n_vertices - 1) // DECIDE_EVERY * DECIDE_EVERY)
            t0, n0 = time.perf_counter(), dec.n_vertices
            code = dec.run(stop_at, sse_max)
            took = time.perf_counter() - t0
            # the next call's length from this one's rate, growing at most 4-fold, never past N
            step = int(min(max((n0 - dec.n_vertices) * CHUNK_SECONDS / max(took, 1e-6), 256), 4 * step, N))
            if code != 0 and dec.lazy:
                near = True  # a stop is decided with exact costs only
                continue
            stopped = code != 0
            report()
        te = time.perf_counter()
        if check is not None:
            check(dec)
        r = dec.residuals()
        fit = None
        if check is None and (stopped or target == last):
            # the last snapshot: the fit's memory does not come on top of the queue's (a check
            # callback may keep the decimation to inspect its queue: then it stays)
            dec.release_queue()
        if "fit" in values:
            from ..fitting import fit_on_mesh

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
    # why the run ended: the smallest target reached, or why no further collapse was made
    why = {0: "every target was reached",
           1: "no collapse was left" + (" that keeps every residual within tol_inf" if tol_inf is not None else ""),
           2: "the next collapse would raise E_RMS above tol_rms"}[code]
    stats = {"collapses": int(len(removed)), "tets": int(dec.S.alive.sum()), "stopped": why}
    return snaps, selected, stats, t_errors


def compile_kernels():
    """Build (or load) the kernels of a decimation for the layout every grid of fewer than
    ``INT32_CORNERS / 24`` points has, ahead of time unless that is off or cannot be done
    (:func:`trivsel.aot.kernels`; an earlier failure is tried again), and run them on a
    3 x 3 x 3 grid: lazy updates, then exact ones, then the point weights.  Returns the
    number of entry kernels that ran (the others are compiled into them)."""
    g = np.indices((3, 3, 3)).reshape(3, -1).T
    values = np.arange(27.0) % 5
    k = kernels(new_state(g, (3, 3, 3), values, lazy=True), rebuild=True)
    dec = Decimation(g, (3, 3, 3), values, lazy=True)
    dec.run(16)
    dec.lazy = False
    dec.run(8)
    dec.point_weights()
    return sum(1 for name in ("init", "run", "flush", "weights") if callable(getattr(k, name, None)))
