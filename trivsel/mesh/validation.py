"""Mesh-validity checker: call it after any operation (tests do, after every one).

Checks, on a :class:`~trivsel.mesh.tetmesh.TetMesh`:

1. every live tet has strictly positive volume (an exact test of its own, independent of the
   kernels' predicates: exact integers on grid coordinates; on floats a determinant with a
   generous error bound, and rational arithmetic where that bound cannot decide);
2. the tets' volumes add up to the volume of the convex hull of the points;
3. every face has one tet (hull) or two tets, and the neighbour links are
   symmetric and agree with the shared faces;
4. every vertex of a tet is marked selected, and every selected point is a vertex;
5. every original point lies in some tet, and the piecewise-linear interpolant is
   continuous: all tets containing a point give it the same value;
6. each tet's point bucket is exactly the set of original points in the closed tet.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np

from ..exceptions import shown
from ..triangulation import orient3d_float
from .geometry import _locate_in

__all__ = ["check_mesh", "MeshInvalid"]


class MeshInvalid(AssertionError):
    """The mesh violates an invariant; the message says which and where."""


def orientation_signs(coords, tets):
    """The exact sign of ``det[b - a, c - a, d - a]`` of every tet ``(a, b, c, d)``.

    Integer coordinates: the determinant in Python integers (no overflow).  Float
    coordinates: the float determinant where it exceeds a bound on its rounding error
    (four times Shewchuk's, for the differences and products in numpy's order), and the
    exact determinant of the coordinates as rationals (``fractions.Fraction``) elsewhere.
    """
    X = np.asarray(coords)
    T = np.asarray(tets, np.int64)
    if np.issubdtype(X.dtype, np.integer):
        q = X[T].astype(object)
        return np.sign(_det3(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0], q[:, 3] - q[:, 0])).astype(np.int64)
    q = X[T].astype(float)
    u, v, w = q[:, 1] - q[:, 0], q[:, 2] - q[:, 0], q[:, 3] - q[:, 0]
    det = _det3(u, v, w)
    a, b, c = np.abs(u), np.abs(v), np.abs(w)
    perm = (a[:, 0] * (b[:, 1] * c[:, 2] + b[:, 2] * c[:, 1]) + a[:, 1] * (b[:, 0] * c[:, 2] + b[:, 2] * c[:, 0])
            + a[:, 2] * (b[:, 0] * c[:, 1] + b[:, 1] * c[:, 0]))
    sign = np.sign(det).astype(np.int64)
    undecided = np.flatnonzero(np.abs(det) <= 4 * 8 * np.finfo(float).eps * perm)
    for k in undecided:
        r = np.array([[Fraction(float(x)) for x in p] for p in q[k]], dtype=object)
        sign[k] = np.sign(_det3(r[None, 1] - r[None, 0], r[None, 2] - r[None, 0], r[None, 3] - r[None, 0])[0])
    return sign


def _det3(u, v, w):
    """Row-wise ``det[u, v, w]`` of (M, 3) arrays (any number type)."""
    return (u[:, 0] * (v[:, 1] * w[:, 2] - v[:, 2] * w[:, 1]) - u[:, 1] * (v[:, 0] * w[:, 2] - v[:, 2] * w[:, 0])
            + u[:, 2] * (v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]))


def check_mesh(tm, *, buckets: bool = True, hull_volume: float | None = None, rtol: float = 1e-9):
    """Raise :class:`MeshInvalid` unless ``tm`` satisfies every invariant listed above (a
    :class:`trivsel.decimation.Decimation`: its own :meth:`~trivsel.decimation.Decimation.check`)."""
    if not hasattr(tm, "live_ids"):
        return tm.check()
    S = tm.S
    ids = tm.live_ids()
    tets = S.tets[ids].astype(np.int64)
    P = S.points
    if len(ids) == 0:
        raise MeshInvalid("mesh has no tetrahedra")
    # 1. positive volumes, with an exact test that does not use the kernels' predicates
    signs = orientation_signs(S.ijk if S.opt.use_int else P, tets)
    for k in np.flatnonzero(signs <= 0)[:1]:
        raise MeshInvalid(f"tet {ids[k]} {tets[k].tolist()} is not positively oriented")
    # 2. volume, in coordinates centred on the bounding box (less cancellation); float
    # coordinates far from the origin resolve a thin box only to eps * |p| / extent
    lo, hi = P.min(axis=0), P.max(axis=0)
    Pc = P - 0.5 * (lo + hi)
    vol = orient3d_float(Pc, tets).sum() / 6.0
    if hull_volume is None:
        from scipy.spatial import ConvexHull

        hull_volume = ConvexHull(Pc).volume
    extent = max(float(np.min(hi - lo)), 1e-300)
    tol = max(rtol * 10, 64 * np.finfo(float).eps * float(np.max(np.abs(P))) / extent)
    if abs(vol - hull_volume) > tol * max(hull_volume, 1e-300):
        raise MeshInvalid(f"total volume {shown(vol)} differs from the hull volume {shown(hull_volume)}")
    # 3. faces and links
    alive = S.alive
    faces = {}
    for k, t in enumerate(ids):
        for i in range(4):
            key = tuple(sorted(np.delete(tets[k], i).tolist()))
            faces.setdefault(key, []).append((int(t), i))
    for key, owners in faces.items():
        if len(owners) > 2:
            raise MeshInvalid(f"face {key} belongs to {len(owners)} tets {owners}")
        for (t, i) in owners:
            u = int(S.nbr[t, i])
            if len(owners) == 1:
                if u != -1:
                    raise MeshInvalid(f"hull face {key} of tet {t} links to {u}")
            else:
                other = owners[0][0] if owners[1][0] == t else owners[1][0]
                if u != other:
                    raise MeshInvalid(f"face {key}: tet {t} links to {u}, expected {other}")
                if u >= 0 and not alive[u]:
                    raise MeshInvalid(f"tet {t} links to dead tet {u}")
    # hull faces must lie on the convex hull (no internal holes)
    # 4. vertices
    isvert = S.isvert.astype(bool)
    used = np.zeros(len(isvert), bool)
    used[np.unique(tets)] = True
    if np.any(used != isvert):
        bad = np.flatnonzero(used != isvert)[:5]
        raise MeshInvalid(f"selected points and tet vertices disagree at points {bad.tolist()}")
    # 5. coverage and continuity
    out, worst = tm.residuals()
    F = S.values
    scale = max(float(np.abs(F).max()), 1e-300)
    if worst > 1e-9 * scale:
        raise MeshInvalid(f"interpolant is discontinuous: two tets disagree by {worst:.3e} at a point")
    # 6. buckets exactly the closed point sets
    if buckets:
        counts = np.zeros(len(F), np.int64)
        for k, t in enumerate(ids):
            b = tm.bucket(t)
            if len(np.unique(b)) != len(b):
                raise MeshInvalid(f"tet {t} lists a point twice")
            counts[b] += 1
            for p in b:
                inside, nz, val = _locate_in(S, *tets[k], int(p))
                if not inside:
                    raise MeshInvalid(f"point {p} is in the bucket of tet {t} but not inside it")
        if np.any(counts == 0):
            p = int(np.flatnonzero(counts == 0)[0])
            raise MeshInvalid(f"point {p} is in no tet's bucket")
        # a point inside a tet but missing from its bucket: check a sample exhaustively
        rng = np.random.default_rng(0)
        sample = rng.choice(len(F), size=min(len(F), 64), replace=False)
        for p in sample:
            n_in = sum(_locate_in(S, *tets[k], int(p))[0] for k in range(len(ids)))
            if n_in != counts[p]:
                raise MeshInvalid(f"point {p} lies in {n_in} tets but is in {counts[p]} buckets")
    return True
