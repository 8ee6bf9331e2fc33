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
from scipy.spatial import ConvexHull, Delaunay

__all__ = [
    "orient3d_float",
    "kuhn_tetrahedra",
    "box_tetrahedra",
    "delaunay_tetrahedra",
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


def orient3d_float(p, tets):
    """Signed volume times 6 of each tetrahedron (float; for checks, not predicates)."""
    a, b, c, d = (p[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)


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
    """Delaunay tetrahedra of scattered points, positively oriented, degenerate ones dropped."""
    tri = Delaunay(np.asarray(points, float))
    tets = tri.simplices.astype(np.int64)
    vol = orient3d_float(np.asarray(points, float), tets)
    neg = vol < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    return tets[np.abs(vol) > 0]


def boundary_triangles(tets) -> np.ndarray:
    """Faces belonging to exactly one tetrahedron (Definition 1), oriented outward.

    The returned triangles ``(a, b, c)`` have the tetrahedron's fourth vertex on
    their negative side, i.e. ``orient3d(a, b, c, inside) < 0``.
    """
    tets = np.asarray(tets, np.int64)
    # the face opposite local vertex i, ordered so that the tet's vertex i lies on its negative side
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    once = counts[inv.ravel()] == 1
    return faces[once]


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
