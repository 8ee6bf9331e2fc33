"""Initial triangulation and boundary (sections 1 and 3, Definition 1).

* Grids: every cube ``{x_{i+I, j+J, k+K} | I, J, K in {0, 1}}`` is split into six
  tetrahedra around its main diagonal (the Kuhn/Freudenthal split), which is a
  Delaunay triangulation of the grid points (section 5).
* Scattered points: :class:`scipy.spatial.Delaunay`.

Tetrahedra are index quadruples (eq. 3), always stored positively oriented:
``orient3d(a, b, c, d) = det[b - a, c - a, d - a] > 0``.

Definition 1: a face belonging to exactly one tetrahedron is a *boundary
triangle*; its vertices are *boundary vertices*.  For a box-shaped grid the
redundant boundary points are dropped and only the 8 corners are kept (the
boundary polyhedron is 12 triangles, section 5); :func:`box_tetrahedra` gives
the six tetrahedra on the corners whose boundary they are.
"""

from __future__ import annotations

import itertools

import numpy as np
# scipy.spatial (Qhull) is imported where it is used: grids never need it, and it is a
# large share of a short run's start-up.
from .exceptions import InputError

__all__ = [
    "orient3d_float",
    "kuhn_tetrahedra",
    "box_tetrahedra",
    "delaunay_tetrahedra",
    "start_tetrahedra",
    "exact_hull_tetrahedra",
    "scattered_start",
    "boundary_triangles",
    "edge_neighbours",
    "kuhn_edge_neighbours",
    "neighbour_graph",
    "cube_corners",
    "hull_triangles",
    "hull_boundary_mask",
]

# The six Kuhn tetrahedra of the unit cube, as paths 000 -> 111 along the axes in
# every order (p0, p1, p2): (v000, v000 + e_p0, v000 + e_p0 + e_p1, v111).
_KUHN_OFFSETS = []
for _perm in itertools.permutations(range(3)):
    _v = np.zeros(3, dtype=np.int64)
    _path = [_v.copy()]
    for _ax in _perm:
        _v[_ax] += 1
        _path.append(_v.copy())
    _t = np.array(_path)
    # orient positively: det[b-a, c-a, d-a] > 0
    if np.linalg.det((_t[1:] - _t[0]).astype(float)) < 0:
        _t = _t[[0, 2, 1, 3]]
    _KUHN_OFFSETS.append(_t)
_KUHN_OFFSETS = np.array(_KUHN_OFFSETS)  # (6, 4, 3)


def orient3d_float(p, tets, chunk: int = 1 << 20):
    """Signed volume times 6 of each tetrahedron (float; for checks, not predicates).

    In chunks of ``chunk`` tetrahedra: the temporaries of all at once would take
    about 200 bytes per tetrahedron."""
    tets = np.asarray(tets)
    out = np.empty(len(tets))
    for s in range(0, len(tets), chunk):
        a, b, c, d = (p[tets[s:s + chunk, i]] for i in range(4))
        out[s:s + chunk] = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)
    return out


def kuhn_tetrahedra(shape, mirror_x: bool = False) -> np.ndarray:
    """Kuhn/Freudenthal split of a grid of ``shape`` points into ``6 prod(shape - 1)`` tets.

    Parameters
    ----------
    shape : 3 ints
        Points per axis; point ``(i, j, k)`` has index ``(i * shape[1] + j) * shape[2] + k``.
    mirror_x : bool
        Split every cube along the diagonal ``(1,0,0)-(0,1,1)`` instead of
        ``(0,0,0)-(1,1,1)`` (the mirror image; also Delaunay).

    Returns
    -------
    (M, 4) int64, positively oriented.
    """
    sx, sy, sz = (int(s) for s in shape)
    ii, jj, kk = np.meshgrid(np.arange(sx - 1), np.arange(sy - 1), np.arange(sz - 1), indexing="ij")
    base = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1)  # (C, 3)
    off = _KUHN_OFFSETS.copy()
    if mirror_x:
        off[:, :, 0] = 1 - off[:, :, 0]
        off = off[:, [0, 2, 1, 3]]  # mirroring flips orientation
    v = base[:, None, None, :] + off[None, :, :, :]  # (C, 6, 4, 3)
    idx = (v[..., 0] * sy + v[..., 1]) * sz + v[..., 2]
    return idx.reshape(-1, 4).astype(np.int64)


def delaunay_tetrahedra(points) -> np.ndarray:
    """Delaunay tetrahedra of scattered points, positively oriented, degenerate ones dropped.

    For neighbour graphs only: dropping a flat tetrahedron may leave the
    triangulation non-conforming.  :func:`start_tetrahedra` gives a conforming one.
    """
    from scipy.spatial import Delaunay

    tri = Delaunay(np.asarray(points, float))
    tets = tri.simplices.astype(np.int64)
    del tri  # Qhull's output (neighbours, facet equations) is as large again
    vol = orient3d_float(np.asarray(points, float), tets)
    neg = vol < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    return tets[np.abs(vol) > 0]


def _signed_volumes6(p, tets, chunk: int = 1 << 18):
    """Signed volume times 6 of each tetrahedron, as :func:`orient3d_float` but from the
    coordinates as three flat arrays: about five times faster, equal to it up to rounding
    (not bit for bit), so for signs outside the float filter and for checks only."""
    tets = np.asarray(tets)
    out = np.empty(len(tets))
    x, y, z = (np.ascontiguousarray(p[:, i]) for i in range(3))
    for s in range(0, len(tets), chunk):
        i0, i1, i2, i3 = (np.ascontiguousarray(tets[s:s + chunk, k]) for k in range(4))
        ax, ay, az = x[i0], y[i0], z[i0]
        bx, by, bz = x[i1] - ax, y[i1] - ay, z[i1] - az
        cx, cy, cz = x[i2] - ax, y[i2] - ay, z[i2] - az
        dx, dy, dz = x[i3] - ax, y[i3] - ay, z[i3] - az
        out[s:s + chunk] = (by * cz - bz * cy) * dx + (bz * cx - bx * cz) * dy + (bx * cy - by * cx) * dz
    return out


def _exact_signs(p, tets):
    """Exact orientation sign of each tetrahedron (filtered float, exact fallback)."""
    vol = _signed_volumes6(p, tets)
    sign = np.sign(vol).astype(np.int64)
    # only near-zero volumes need the exact test: |error| of the float determinant
    # is far below 1e-10 of the product of the edge lengths
    ext = np.ptp(p, axis=0).max() if len(p) else 1.0
    near = np.flatnonzero(np.abs(vol) <= 1e-10 * ext ** 3)
    if len(near):  # numba's import and dispatch only when a sign needs them
        from .predicates import orient3d_float_sign
    for t in near:
        a, b, c, d = (p[i] for i in tets[t])
        sign[t] = orient3d_float_sign(*a, *b, *c, *d)
    return sign


def _quad_diagonals(p, tet):
    r"""The two diagonals ``((a, c), (b, d))`` of a flat tetrahedron's four coplanar
    vertices in convex position, or None when they are not (one vertex inside the
    triangle of the others, or three collinear).

    ::

        d ------- c      faces with diagonal ac: abc, acd (one side of the plane)
        |  \   /  |      faces with diagonal bd: abd, bcd (the other side)
        |    X    |
        |  /   \  |
        a ------- b
    """
    q = p[list(tet)]
    normal = np.cross(q[1] - q[0], q[2] - q[0]) + np.cross(q[2] - q[0], q[3] - q[0]) \
        + np.cross(q[3] - q[0], q[1] - q[0])
    drop = int(np.argmax(np.abs(normal)))
    uv = np.delete(q, drop, axis=1)

    def side(i, j, k):
        (x0, y0), (x1, y1), (x2, y2) = uv[i], uv[j], uv[k]
        return np.sign((x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0))

    for (i, k), (j, m) in (((0, 1), (2, 3)), ((0, 2), (1, 3)), ((0, 3), (1, 2))):
        if side(i, k, j) * side(i, k, m) < 0 and side(j, m, i) * side(j, m, k) < 0:
            return (tet[i], tet[k]), (tet[j], tet[m])
    return None


def _face_map(tets):
    faces = {}
    for t, tet in enumerate(tets):
        for i in range(4):
            faces.setdefault(tuple(sorted(tet[j] for j in range(4) if j != i)), []).append(t)
    return faces


def start_tetrahedra(points) -> np.ndarray:
    r"""A conforming tetrahedralization of the convex hull of ``points`` with no flat
    tetrahedra: the start mesh for scattered data (section 3).

    Delaunay tetrahedra of (nearly) cospherical points can include flat ones: four
    coplanar vertices in convex position whose two sides are triangulated with
    different diagonals.  Dropping such a tetrahedron leaves two faces unmatched, so
    each flat one is removed by a local flip instead (exact orientation signs):

    * its faces on one side lie on the hull: the flat tetrahedron is dropped, and
      its other two faces become hull faces;
    * the two neighbours on one side share their apex ``p``: the pyramid ``p`` over
      the quad, split along one diagonal, is re-split along the other, which
      matches the faces on the far side (three tetrahedra become two)::

                p                         p
              / | \                     / | \
            a - + - c     ->          a - + - c      diagonal ac  ->  bd
              \ | /                     \ | /
            (b, d flat)               (b, d below)
    """
    from scipy.spatial import Delaunay

    p = np.asarray(points, float)
    tets = Delaunay(p).simplices.astype(np.int64)
    sign = _exact_signs(p, tets)
    tets[sign < 0] = tets[sign < 0][:, [0, 2, 1, 3]]
    flat = sign == 0
    if not flat.any():
        return tets
    good = [tuple(t) for t in tets[~flat]]
    pending = [tuple(t) for t in tets[flat]]
    for _ in range(4 * len(pending) + 4):
        if not pending:
            break
        f = pending.pop(0)
        diag = _quad_diagonals(p, f)
        if diag is None:
            raise InputError(f"the convex hull is too degenerate to tetrahedralize: hull vertices {f} are coplanar "
                             "and not in convex position")
        faces = _face_map(good)
        done = False
        for (a, c), (b, d) in (diag, diag[::-1]):
            # the two faces of f that contain the diagonal ac, and their neighbours
            nb = [faces.get(tuple(sorted(face)), []) for face in ((a, b, c), (a, c, d))]
            if not nb[0] and not nb[1]:
                done = True  # hull side: drop f
                break
            if len(nb[0]) == 1 and len(nb[1]) == 1:
                t1, t2 = good[nb[0][0]], good[nb[1][0]]
                apex1 = set(t1) - {a, b, c}
                apex2 = set(t2) - {a, c, d}
                if apex1 == apex2:
                    (apex,) = apex1
                    for k in sorted((nb[0][0], nb[1][0]), reverse=True):
                        good.pop(k)
                    for new in ((apex, a, b, d), (apex, b, c, d)):
                        s = _exact_signs(p, np.array([new]))[0]
                        good.append(new if s > 0 else (new[0], new[2], new[1], new[3]))
                    done = True
                    break
        if not done:
            pending.append(f)  # another flip may make its neighbours share an apex
    if pending:
        raise InputError(f"the convex hull is too degenerate to tetrahedralize: {len(pending)} flat Delaunay "
                         "tetrahedra of its vertices could not be flipped away")
    return np.array(good, dtype=np.int64)


def _signs_against(p, tris, q):
    """Exact sign of ``orient3d(a, b, c, x)`` for every triangle row and point ``x`` of
    ``q`` (float filter, exact fallback); shape (len(q), len(tris))."""
    from .predicates import orient3d_float_sign

    a, b, c = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    n = np.cross(b - a, c - a)
    ext = max(float(np.ptp(np.concatenate([p, q]), axis=0).max()), 1e-300)
    out = np.empty((len(q), len(tris)), np.int64)
    step = max(1, (1 << 20) // max(len(tris), 1))
    for s in range(0, len(q), step):
        x = q[s:s + step]
        d = np.einsum("fk,pfk->pf", n, x[:, None, :] - a[None, :, :])
        sign = np.sign(d).astype(np.int64)
        for i, f in zip(*np.nonzero(np.abs(d) <= 1e-10 * ext ** 3)):
            sign[i, f] = orient3d_float_sign(*a[f], *b[f], *c[f], *x[i])
        out[s:s + step] = sign
    return out


def exact_hull_tetrahedra(points, order):
    r"""A tetrahedralization of the convex hull of ``points[order]`` built with exact
    orientation tests (beneath-beyond): start from a tetrahedron of four points, then
    join each point that lies strictly beyond the current hull to every hull face it
    sees.  Every tetrahedron has an exactly positive volume, the result conforms,
    and a point on or inside the hull is never a vertex.

    ::

              p   (beyond the faces it sees)
             /|\
            / | \      horizon edges: the edges of the seen faces that only one of
        ---a--+--b---  them has; the new hull faces are (edge, p)

    Returns the tetrahedra (global point ids).  Used when Qhull's triangulation of
    nearly degenerate input cannot be verified exactly.
    """
    p = np.asarray(points, float)
    order = np.asarray(order, np.int64)
    q = p[order]
    # a non-degenerate first tetrahedron: extreme in x, farthest from it, from that line, from that plane
    i0 = int(np.argmin(q[:, 0]))
    i1 = int(np.argmax(np.linalg.norm(q - q[i0], axis=1)))
    u = q[i1] - q[i0]
    i2 = int(np.argmax(np.linalg.norm(np.cross(q - q[i0], u), axis=1)))
    nrm = np.cross(u, q[i2] - q[i0])
    d = (q - q[i0]) @ nrm
    i3 = int(np.argmax(np.abs(d)))
    first = np.array([order[i0], order[i1], order[i2], order[i3]])
    s = _exact_signs(p, first[None])[0]
    if s == 0:
        raise InputError("the points are coplanar: their convex hull has no volume")
    if s < 0:
        first = first[[0, 2, 1, 3]]
    tets = [tuple(first)]
    a, b, c, dd = first
    # outward hull faces: the tet's fourth vertex on their negative side
    faces = np.array([(b, c, dd), (a, dd, c), (a, b, dd), (a, c, b)], np.int64)
    placed = set(first.tolist())
    for g in order:
        if g in placed:
            continue
        seen = _signs_against(p, faces, p[[g]])[0] > 0
        if not seen.any():
            continue
        vis = faces[seen]
        tets.extend((int(f[0]), int(f[1]), int(f[2]), int(g)) for f in vis)
        edges = {}
        for f in vis:
            for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
                key = (min(e), max(e))
                edges[key] = None if key in edges else e
        horizon = [e for e in edges.values() if e is not None]
        faces = np.concatenate([faces[~seen], np.array([(e[0], e[1], g) for e in horizon], np.int64)])
        placed.add(int(g))
    return np.array(tets, dtype=np.int64)


def _is_valid_start(p, tets, near):
    """Exact check of a start mesh: positive volumes, every face in one or two
    tetrahedra, and no point of ``near`` strictly outside a boundary face."""
    if (_exact_signs(p, tets) <= 0).any():
        return False
    faces = np.sort(np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 2, 3]], tets[:, [0, 1, 3]],
                                    tets[:, [0, 1, 2]]]), axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    if counts.max() > 2:
        return False
    bnd = boundary_triangles(tets)
    return not (_signs_against(p, bnd, p[near]) > 0).any()


def scattered_start(points, hull_vertices):
    """The start mesh of scattered data (section 3) and its vertices.

    Qhull's Delaunay tetrahedra of the hull vertices, made free of flat ones by
    :func:`start_tetrahedra`, when an exact check confirms them; otherwise (nearly
    degenerate input, where Qhull's tolerances misplace the hull) the exact
    construction :func:`exact_hull_tetrahedra` over the hull vertices and the
    points near the hull.

    Returns
    -------
    tets : (M, 4) int64, global point ids, positively oriented
    vertices : (V,) int64, the sorted vertex ids (the fixed points)
    """
    from scipy.spatial import QhullError

    p = np.asarray(points, float)
    hull_vertices = np.asarray(hull_vertices, np.int64)
    near = np.union1d(np.flatnonzero(hull_boundary_mask(p, rtol=1e-9)), hull_vertices)
    try:
        tets = hull_vertices[start_tetrahedra(p[hull_vertices])]
        if _is_valid_start(p, tets, near):
            return tets, np.unique(tets)
    except (QhullError, InputError):  # Qhull's failure on degenerate input: the exact construction handles it
        pass
    rest = np.setdiff1d(near, hull_vertices)
    tets = exact_hull_tetrahedra(p, np.concatenate([hull_vertices, rest]))
    return tets, np.unique(tets)


#: The face opposite local vertex i of a tetrahedron, wound so that vertex i lies on its
#: negative side (outward for a positively oriented tetrahedron)::
#:
#:            3
#:           /|\        face 0: 1 2 3    face 2: 0 1 3
#:          / | \       face 1: 0 3 2    face 3: 0 2 1
#:         /  2  \
#:        / /   \ \
#:       0 ------- 1
FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
#: Tetrahedra whose faces :func:`face_table` takes at a time
FACE_CHUNK = 1 << 20


def face_table(tets, *, chunk=FACE_CHUNK):
    """The faces of ``tets`` (M, 4) grouped by triangle, without an (4 M, 3) array of them:
    face ``f = i M + k`` is face ``i`` of tetrahedron ``k`` (:data:`FACES`).  Returns a dict:

    * ``order``: the faces sorted by their sorted vertex triples, ties in face order (as a
      stable lexicographic sort of the rows);
    * ``start``: where each run of equal triangles begins in ``order``;
    * ``count``: for each face, how many faces are its triangle (int32);
    * ``odd``: for each face, whether its winding is an odd permutation of its sorted
      vertices (two copies of a triangle wound alike have equal ``odd``).

    One int64 key per face while the vertex ids allow (``n^3 < 2^63``), else the three
    sorted columns, sorted together.  About 30 bytes a face."""
    t = np.asarray(tets)
    M = len(t)
    F = 4 * M
    n = int(t.max()) + 1 if t.size else 1
    keyed = n ** 3 < 2 ** 63
    cols = np.empty((1 if keyed else 3, F), np.int64)
    odd = np.empty(F, bool)
    for i, (a, b, c) in enumerate(FACES):
        for s in range(0, M, chunk):
            x, y, z = (t[s:s + chunk, j].astype(np.int64) for j in (a, b, c))
            lo, hi = np.minimum(np.minimum(x, y), z), np.maximum(np.maximum(x, y), z)
            mid = x + y + z - lo - hi
            at = slice(i * M + s, i * M + s + len(x))
            odd[at] = (x > y) ^ (x > z) ^ (y > z)  # the parity of the inversions
            if keyed:
                cols[0, at] = (lo * n + mid) * n + hi
            else:
                cols[0, at], cols[1, at], cols[2, at] = lo, mid, hi
    order, start, count = _runs(cols)
    return {"order": order, "start": start, "count": count, "odd": odd}


def _runs(cols):
    """``(order, start, count)`` of rows given as key columns (one int64 key a row, or the
    row's columns): a stable lexicographic sort, where each run of equal rows begins in it,
    and each row's count of its equals (int32)."""
    F = cols.shape[1]
    order = np.argsort(cols[0], kind="stable") if len(cols) == 1 else np.lexsort(cols[::-1])
    same = np.ones(max(F - 1, 0), bool)  # a row equal to the one before it in ``order``
    for col in cols:
        c = col[order]
        same &= c[1:] == c[:-1]
        del c
    start = np.flatnonzero(np.r_[True, ~same]) if F else np.zeros(0, np.int64)
    runs = np.diff(np.append(start, F)).astype(np.int32)
    count = np.empty(F, np.int32)
    count[order] = np.repeat(runs, runs)
    return order, start, count


def tet_faces(tets, f):
    """Faces ``f`` of :func:`face_table`'s numbering as vertex triples, wound as :data:`FACES`."""
    t = np.asarray(tets)
    f = np.asarray(f, np.int64)
    if len(f) == 0:
        return np.zeros((0, 3), t.dtype)
    return t[(f % len(t))[:, None], FACES[f // len(t)]]


def boundary_triangles(tets) -> np.ndarray:
    """Faces belonging to exactly one tetrahedron (Definition 1), oriented outward.

    The returned triangles ``(a, b, c)`` have the tetrahedron's fourth vertex on
    their negative side, i.e. ``orient3d(a, b, c, inside) < 0``.
    """
    tets = np.asarray(tets, np.int64)
    return tet_faces(tets, np.flatnonzero(face_table(tets)["count"] == 1))


def face_multiplicity(rows):
    """For each row of sorted vertex triples ``rows`` (F, 3), how many rows equal it: one
    integer key per row while they fit in int64 (one 1-D argsort, then the length of each
    run of equal keys), else rows compared."""
    rows = np.asarray(rows, np.int64).reshape(-1, 3)
    n = int(rows.max()) + 1 if rows.size else 1
    cols = ((rows[:, 0] * n + rows[:, 1]) * n + rows[:, 2])[None] if n ** 3 < 2 ** 63 else rows.T
    return _runs(cols)[2]


def edge_neighbours(tets, n_points: int):
    """Edge-neighbour graph of a triangulation as CSR arrays ``(indptr, indices)``."""
    tets = np.asarray(tets, np.int64)
    a = np.concatenate([tets[:, i] for i, j in itertools.combinations(range(4), 2)])
    b = np.concatenate([tets[:, j] for i, j in itertools.combinations(range(4), 2)])
    n = np.int64(n_points)
    # each undirected edge as one integer key, both directions, deduplicated
    key = np.unique(np.concatenate([a * n + b, b * n + a]))
    src, dst = np.divmod(key, n)
    indptr = np.zeros(n_points + 1, dtype=np.int64)
    indptr[1:] = np.cumsum(np.bincount(src, minlength=n_points))
    return indptr, dst


def kuhn_edge_neighbours(shape):
    """Edge-neighbour graph of :func:`kuhn_tetrahedra` built directly from its stencil.

    Every edge of the Kuhn split joins grid points whose index offsets are a
    nonzero vector with components in {0, 1} or in {0, -1} (the edges of the
    cube paths from 000 to 111), so an interior point has 14 neighbours.  Same CSR
    arrays as :func:`edge_neighbours` on the tets, without sorting 7 N pairs.
    """
    sx, sy, sz = (int(s) for s in shape)
    offs = np.array([o for o in itertools.product((0, 1), repeat=3) if any(o)], dtype=np.int64)
    offs = np.concatenate([-offs, offs])  # 14 offsets
    offs = offs[np.lexsort((offs[:, 2], offs[:, 1], offs[:, 0]))]  # ascending linear offset
    n = sx * sy * sz
    # per offset: which points have that neighbour (a box of the grid), one column each
    ok = np.zeros((n, len(offs)), dtype=bool)
    okv = ok.reshape(sx, sy, sz, len(offs))
    for c, (di, dj, dk) in enumerate(offs):
        okv[max(0, -di):sx - max(0, di), max(0, -dj):sy - max(0, dj), max(0, -dk):sz - max(0, dk), c] = True
    step = (offs[:, 0] * sy + offs[:, 1]) * sz + offs[:, 2]  # linear index offsets, ascending
    rows, cols = np.nonzero(ok)  # row-major: by point, then by ascending offset
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(ok.sum(axis=1), out=indptr[1:])
    return indptr, rows + step[cols]


def neighbour_graph(indptr, indices, shape=None, kind: str = "kuhn"):
    """Neighbourhood of each point for the curvature fit, as CSR ``(indptr, indices)``.

    ``kind``: ``"kuhn"`` returns the given edge graph (of the initial triangulation);
    ``"two-ring"`` adds the neighbours' neighbours; ``"box"`` (grids only, needs
    ``shape``) is the 26 surrounding grid points.
    """
    import scipy.sparse as sp

    n = len(indptr) - 1
    if kind == "kuhn":
        return indptr, indices
    if kind == "two-ring":
        a = sp.csr_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n)) + sp.identity(n, format="csr")
        a = (a @ a).tocsr()
    elif kind == "box":
        if shape is None:
            raise ValueError("the 'box' neighbourhood needs grid data")
        sx, sy, sz = (int(s) for s in shape)
        ii, jj, kk = np.meshgrid(np.arange(sx), np.arange(sy), np.arange(sz), indexing="ij")
        ijk = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1)
        rows, cols = [], []
        for d in itertools.product((-1, 0, 1), repeat=3):
            if d == (0, 0, 0):
                continue
            q = ijk + np.asarray(d)
            ok = np.all((q >= 0) & (q < np.array([sx, sy, sz])), axis=1)
            rows.append(np.flatnonzero(ok))
            cols.append((q[ok, 0] * sy + q[ok, 1]) * sz + q[ok, 2])
        r, c = np.concatenate(rows), np.concatenate(cols)
        a = sp.csr_matrix((np.ones(len(r)), (r, c)), shape=(n, n))
    else:
        raise ValueError(f"unknown neighbourhood {kind!r}: choose 'kuhn', 'two-ring' or 'box'")
    a.setdiag(0)
    a.eliminate_zeros()
    a.sort_indices()
    return a.indptr.astype(np.int64), a.indices.astype(np.int64)


def cube_corners(shape) -> np.ndarray:
    """Indices of the 8 corner points of a grid of ``shape`` points."""
    sx, sy, sz = (int(s) for s in shape)
    c = [(i, j, k) for i in (0, sx - 1) for j in (0, sy - 1) for k in (0, sz - 1)]
    return np.array([(i * sy + j) * sz + k for i, j, k in c], dtype=np.int64)


def box_tetrahedra(shape, diagonals: str) -> np.ndarray:
    """Six tetrahedra on the 8 corners of a grid box (its coarsest triangulation).

    Their boundary is the 12 initial boundary triangles of section 3.  The paper
    does not fix the face diagonals: ``diagonals='kuhn'`` takes those of the Kuhn
    split of the whole box (all through the main diagonal's end points),
    ``'mirrored'`` those of the split mirrored in x (the ``boundary_diagonals``
    option of :class:`trivsel.Options`).
    """
    if diagonals not in ("kuhn", "mirrored"):
        raise ValueError(f"unknown boundary diagonals {diagonals!r}: choose 'kuhn' or 'mirrored'")
    corners = cube_corners(shape).reshape(2, 2, 2)
    unit = kuhn_tetrahedra((2, 2, 2), mirror_x=(diagonals == "mirrored"))
    # unit-cube index (i*2+j)*2+k -> corner point index
    return corners.ravel()[unit]


def hull_triangles(points):
    """Convex-hull triangles (outward) and hull vertices of scattered points.

    Only the extreme points (vertices of the hull polytope, as Qhull reports them)
    are returned as vertices; points lying in the interior of hull faces or edges
    are not, so they stay candidates for selection like the face points of a grid.
    """
    from scipy.spatial import ConvexHull

    p = np.asarray(points, float)
    hull = ConvexHull(p)
    tris = hull.simplices.astype(np.int64).copy()
    centroid = p[hull.vertices].mean(axis=0)
    a, b, c = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    s = np.einsum("ij,ij->i", np.cross(b - a, c - a), centroid - a)
    flip = s > 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    return tris, np.unique(tris)


def hull_boundary_mask(points, rtol: float = 1e-12) -> np.ndarray:
    """True for points on the convex hull's surface (on a hull facet's plane)."""
    from scipy.spatial import ConvexHull

    p = np.asarray(points, float)
    hull = ConvexHull(p)
    scale = np.max(np.abs(p)) if p.size else 1.0
    tol = rtol * max(scale, 1e-300)
    eq = hull.equations
    out = np.zeros(len(p), bool)
    # in chunks: a points x facets distance matrix would need gigabytes for large clouds
    step = max(1, (1 << 22) // max(len(eq), 1))
    for s in range(0, len(p), step):
        dist = p[s:s + step] @ eq[:, :3].T + eq[:, 3]
        out[s:s + step] = np.any(np.abs(dist) <= tol, axis=1)
    return out


def boundary_cone(coords, triangles, apex) -> np.ndarray:
    """The first triangulation from a prescribed boundary (section 3): ``apex`` joined
    to every boundary triangle.

    Parameters
    ----------
    coords : (N, 3) array
        Point coordinates: the integer grid coordinates of a grid (the signs are then
        exact), or float coordinates.
    triangles : (m, 3) int array
        A closed, consistently oriented surface around ``apex`` (outward or inward;
        see :func:`check_closed_surface`).
    apex : int
        A point strictly inside the surface, from which every triangle is visible.

    Returns
    -------
    (m, 4) int64
        Positively oriented tetrahedra ``(apex, a, b, c)``, in one order for the
        surface however its triangles were listed or oriented.

    Raises
    ------
    InputError
        If a triangle is flat or the apex lies in a triangle's plane (the cone would
        have a flat tetrahedron), or if the cone does not fill the surface's inside
        once (the triangles do not enclose the apex as a star-shaped surface).
    """
    tris = np.asarray(triangles, np.int64)
    tets = np.empty((len(tris), 4), np.int64)
    tets[:, 0] = int(apex)
    tets[:, 1:] = tris
    c = np.asarray(coords, float)
    vol = orient3d_float(c, tets)
    if np.any(vol == 0):
        bad = tris[np.flatnonzero(vol == 0)[0]]
        raise InputError(f"boundary triangle {tuple(int(v) for v in bad)} is flat or in the plane of the "
                         f"first interior point {int(apex)}")
    # a consistently oriented surface faces the apex one way throughout (either, as
    # the caller's orientation is not prescribed), unless it is not star-shaped from it
    neg = vol < 0
    if neg.any() and not neg.all():
        bad = tris[np.flatnonzero(neg != (np.count_nonzero(neg) * 2 > len(neg)))[0]]
        raise InputError(f"boundary triangle {tuple(int(v) for v in bad)} faces the first interior point "
                         f"{int(apex)} the other way: the surface is not star-shaped from it")
    if neg.all():
        tets[:, 2], tets[:, 3] = tris[:, 2], tris[:, 1]
    # a closed surface around the apex covers every direction once: the solid angles
    # of its triangles sum to 4 pi exactly when it winds around the apex once
    total = float(np.sum(_solid_angles(c, tets)))
    if not np.isclose(total, 4.0 * np.pi, rtol=1e-9):
        raise InputError(f"the boundary triangles do not enclose the first interior point {int(apex)} once "
                         f"(solid angle {total / np.pi:.6g} pi, not 4 pi)")
    # one order whatever the caller's: each triangle rotated to start at its smallest
    # index (keeping its orientation), the rows sorted, so that the run does not depend
    # on how the same surface was listed
    tri = tets[:, 1:]
    r = np.argmin(tri, axis=1)
    tri = tri[np.arange(len(tri))[:, None], (r[:, None] + np.arange(3)) % 3]
    tets[:, 1:] = tri[np.lexsort(tri.T[::-1])]
    return tets


def _solid_angles(c, tets):
    """Solid angle at vertex 0 of each positively oriented tetrahedron (Van Oosterom & Strackee)."""
    a, b, d = (c[tets[:, i]] - c[tets[:, 0]] for i in (1, 2, 3))
    la, lb, ld = (np.linalg.norm(v, axis=1) for v in (a, b, d))
    num = np.abs(np.einsum("ij,ij->i", a, np.cross(b, d)))
    den = (la * lb * ld + np.einsum("ij,ij->i", a, b) * ld + np.einsum("ij,ij->i", a, d) * lb
           + np.einsum("ij,ij->i", b, d) * la)
    return 2.0 * np.arctan2(num, den)


def check_closed_surface(triangles, n_points=None) -> np.ndarray:
    """``triangles`` as an (m, 3) int64 array after checking that they form a closed,
    consistently oriented surface: indices in range, no repeated vertex in a
    triangle, no triangle twice, every edge in exactly two triangles that run along
    it in opposite directions.

    Raises
    ------
    InputError
        Naming the first bad triangle or edge.
    """
    tris = np.asarray(triangles)
    if tris.ndim != 2 or tris.shape[1] != 3 or len(tris) < 4 or tris.dtype.kind not in "iu":
        raise InputError(f"boundary must be an (m, 3) integer array of m >= 4 triangles, got "
                         f"{tris.dtype} array of shape {tris.shape}")
    tris = tris.astype(np.int64)
    if n_points is not None and (tris.min() < 0 or tris.max() >= n_points):
        bad = tris[np.flatnonzero(np.any((tris < 0) | (tris >= n_points), axis=1))[0]]
        raise InputError(f"boundary triangle {tuple(int(v) for v in bad)} indexes a point outside "
                         f"0..{n_points - 1}")
    s = np.sort(tris, axis=1)
    rep = (s[:, 0] == s[:, 1]) | (s[:, 1] == s[:, 2])
    if rep.any():
        raise InputError(f"boundary triangle {tuple(int(v) for v in tris[np.flatnonzero(rep)[0]])} "
                         f"repeats a vertex")
    u, cnt = np.unique(s, axis=0, return_counts=True)
    if np.any(cnt > 1):
        raise InputError(f"boundary triangle {tuple(int(v) for v in u[np.flatnonzero(cnt > 1)[0]])} "
                         f"is given twice")
    # closed and consistently oriented: each directed edge once, and its reverse once
    directed = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    ud, dcnt = np.unique(directed, axis=0, return_counts=True)
    if np.any(dcnt > 1):
        e = ud[np.flatnonzero(dcnt > 1)[0]]
        raise InputError(f"boundary edge {tuple(int(v) for v in e)} is in more than two triangles, or two "
                         f"triangles around it are oriented alike")
    key = ud[:, 0] * (int(ud.max()) + 1) + ud[:, 1]
    rev = ud[:, 1] * (int(ud.max()) + 1) + ud[:, 0]
    missing = ~np.isin(rev, key)
    if missing.any():
        e = ud[np.flatnonzero(missing)[0]]
        raise InputError(f"boundary edge {tuple(int(v) for v in e)} has one triangle, not two: the surface "
                         f"is not closed")
    return tris
