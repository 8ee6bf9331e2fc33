"""The start mesh of a decimation off the grid: a tetrahedral mesh checked and oriented.

* Scattered points: their Delaunay tetrahedralisation, made free of flat tetrahedra
  (:func:`trivsel.triangulation.start_tetrahedra`); its domain is their convex hull.
* A mesh read from a file: its own tetrahedra, whose domain may be non-convex.  Each is
  oriented positively by the exact predicate; a flat one, one with a repeated or unknown
  vertex, a face shared by more than two tetrahedra, or two tetrahedra on the same side of
  their shared face (folded) is refused with one line.

Points that are no tetrahedron's vertex (Qhull leaves out points it deems coplanar with a
facet; a file may list points its cells do not use) are located in the tetrahedron that
holds them, and start as residuals there; one outside every tetrahedron is refused.
"""

from __future__ import annotations

import numpy as np

from ..exceptions import InputError

__all__ = ["start_mesh", "check_tetrahedra_of_file", "locate_points", "mesh_volume", "check_mesh_keeps_domain"]


def mesh_volume(points, tets):
    """The volume of a tetrahedral mesh (sum of its tetrahedra's, in float)."""
    from ..triangulation import _signed_volumes6

    return float(np.sum(np.abs(_signed_volumes6(np.asarray(points, float), tets)))) / 6.0


def check_tetrahedra_of_file(points, tets, place="the mesh"):
    """``(tets, boundary)``: ``tets`` (M, 4) of ``points`` positively oriented, after one-line
    checks (indices in range, four distinct vertices, no zero volume (exact), no face in more
    than two, none folded: :func:`_check_unfolded`), and their boundary triangles, oriented outward as
    :func:`trivsel.triangulation.boundary_triangles` gives them, from the same face count."""
    from ..triangulation import _exact_signs, face_table, tet_faces

    p = np.asarray(points, float)
    t = np.array(tets, dtype=np.int64, copy=True)
    if t.ndim != 2 or t.shape[1] != 4 or len(t) == 0:
        raise InputError(f"{place} has no tetrahedra (cells of shape {t.shape})")
    bad = np.flatnonzero((t < 0).any(axis=1) | (t >= len(p)).any(axis=1))
    if len(bad):
        raise InputError(f"tetrahedron {int(bad[0])} of {place} has vertex ids {t[bad[0]].tolist()} outside "
                         f"0..{len(p) - 1}")
    s = np.sort(t, axis=1)
    bad = np.flatnonzero((s[:, 1:] == s[:, :-1]).any(axis=1))
    del s
    if len(bad):
        raise InputError(f"tetrahedron {int(bad[0])} of {place} repeats a vertex: {t[bad[0]].tolist()}")
    sign = _exact_signs(p, t)
    if (sign == 0).any():
        k = int(np.argmax(sign == 0))
        raise InputError(f"tetrahedron {k} of {place} is flat (zero volume): vertices {t[k].tolist()}")
    t[sign < 0] = t[sign < 0][:, [0, 2, 1, 3]]
    del sign
    faces = face_table(t)  # face f: the one opposite local vertex f // M of tetrahedron f % M
    if faces["count"].max() > 2:
        k = int(np.argmax(faces["count"] > 2))
        raise InputError(f"{place} is not a manifold tetrahedral mesh: triangle "
                         f"{sorted(tet_faces(t, [k])[0].tolist())} is a face of {int(faces['count'][k])} tetrahedra")
    _check_unfolded(t, faces, place)
    return t, tet_faces(t, np.flatnonzero(faces["count"] == 1))


def _check_unfolded(t, faces, place):
    """One-line InputError when two of the positively oriented tetrahedra ``t`` fold over their
    shared face: they lie on the same side of it (its two copies in :func:`face_table`
    ``faces``, each wound with its tetrahedron's opposite vertex on its negative side, wind the
    same way; exact).  Tetrahedra that overlap without sharing a face are not looked for."""
    from ..triangulation import tet_faces

    order, start, count, odd = faces["order"], faces["start"], faces["count"], faces["odd"]
    first = order[start]  # a triangle's first copy, and its second where it has one
    two = count[first] == 2
    a, b = first[two], order[start[two] + 1]
    same = np.flatnonzero(odd[a] == odd[b])
    if len(same):
        a, b = int(a[same[0]]), int(b[same[0]])
        raise InputError(f"{place} is folded: tetrahedra {a % len(t)} and {b % len(t)} share triangle "
                         f"{sorted(tet_faces(t, [a])[0].tolist())} and lie on the same side of it")


def locate_points(points, tets, which, place="the mesh"):
    """For each point index in ``which``, the tetrahedron of ``tets`` (positively oriented)
    whose closed volume holds it (exact signs), searched among the tetrahedra with the
    nearest centroids first.  A point in none is refused with one line."""
    p = np.asarray(points, float)
    out = np.full(len(which), -1, np.int64)
    if len(which) == 0:  # the usual case: scipy's import is not paid for nothing
        return out
    from scipy.spatial import cKDTree

    from ..triangulation import _exact_signs

    tree = cKDTree(p[tets].mean(axis=1))
    for i, q in enumerate(which):
        for k in (min(32, len(tets)), len(tets)):
            _, near = tree.query(p[q], k=k)
            near = np.atleast_1d(near)
            for t in near:
                a, b, c, d = tets[t]
                faces = np.array([[q, b, c, d], [a, q, c, d], [a, b, q, d], [a, b, c, q]])
                if (_exact_signs(p, faces) >= 0).all():
                    out[i] = t
                    break
            if out[i] >= 0:
                break
        if out[i] < 0:
            raise InputError(f"point {int(q)} {tuple(float(x) for x in p[q])} of {place} is in no tetrahedron "
                             "and lies outside the mesh")
    return out


def start_mesh(data):
    """``(tets, located, boundary)`` to start a decimation of non-grid ``data``: the file's own
    tetrahedra (``data.tets``) or the Delaunay tetrahedra of the points; ``located`` the
    tetrahedron of each point that is no vertex (-1 for the vertices); the mesh's boundary
    triangles (outward)."""
    import logging

    from ..triangulation import boundary_triangles, start_tetrahedra

    log = logging.getLogger("trivsel")
    if data.tets is not None:
        log.info("checking the %d tetrahedra of the mesh", len(data.tets))
        tets, boundary = check_tetrahedra_of_file(data.points, data.tets, repr(data.name))
    else:
        log.info("Delaunay tetrahedra of %d scattered points", data.n_points)
        tets = start_tetrahedra(data.points)
        boundary = boundary_triangles(tets)
    located = np.full(data.n_points, -1, np.int64)
    used = np.zeros(data.n_points, bool)
    used[tets.ravel()] = True
    loose = np.flatnonzero(~used)
    located[loose] = locate_points(data.points, tets, loose, repr(data.name))
    return tets, located, boundary


def start_interior_mask(points, tets, located, boundary):
    """Points not on the boundary of the start mesh ``tets`` (:func:`start_mesh`): the mesh's
    vertices on none of its boundary triangles, and the points no tetrahedron uses
    (``located[i] >= 0``) that lie on no boundary face of their tetrahedron (exact signs).
    For scattered points this is the convex hull's surface without computing the hull again.
    ``boundary``: the boundary triangles of ``tets`` (:func:`start_mesh` gives them)."""
    p = np.asarray(points, float)
    bnd = boundary
    inner = np.ones(len(p), bool)
    inner[np.unique(bnd)] = False
    loose = np.flatnonzero(located >= 0)
    if len(loose):
        from ..predicates import orient3d_float_sign

        faces = {tuple(sorted(f)): f for f in bnd.tolist()}
        for q in loose:
            t = tets[located[q]]
            for i in range(4):
                f = faces.get(tuple(sorted(int(t[j]) for j in range(4) if j != i)))
                if f is not None and orient3d_float_sign(*p[f[0]], *p[f[1]], *p[f[2]], *p[q]) == 0:
                    inner[q] = False
                    break
    return inner


def check_mesh_keeps_domain(points, before, after):
    """Check that ``after`` is a valid tetrahedral mesh of the domain of ``before`` (both over
    ``points``): every tetrahedron positively oriented (exact), no face in more than two,
    the same volume and boundary area (to 1e-9 relative), and every boundary vertex of
    ``after`` a boundary vertex of ``before``.  Raises AssertionError naming the first
    failure."""
    from ..triangulation import _exact_signs, boundary_triangles, face_multiplicity

    p = np.asarray(points, float)
    after = np.asarray(after, np.int64)
    sign = _exact_signs(p, after)
    if (sign <= 0).any():
        t = int(np.argmax(sign <= 0))
        raise AssertionError(f"tetrahedron {t} {after[t].tolist()} is not positively oriented")
    faces = np.sort(np.concatenate([after[:, [1, 2, 3]], after[:, [0, 2, 3]], after[:, [0, 1, 3]],
                                    after[:, [0, 1, 2]]]), axis=1)
    cnt = face_multiplicity(faces)
    if cnt.max() > 2:
        raise AssertionError(f"face {faces[int(np.argmax(cnt))].tolist()} is in {cnt.max()} tetrahedra")
    v0, v1 = mesh_volume(p, before), mesh_volume(p, after)
    if abs(v1 - v0) > 1e-9 * v0:
        raise AssertionError(f"the mesh's volume changed from {v0!r} to {v1!r}")

    def area(tris):
        q = p[tris]
        return float(np.sum(np.linalg.norm(np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]), axis=1))) / 2.0

    b0, b1 = boundary_triangles(before), boundary_triangles(after)
    a0, a1 = area(b0), area(b1)
    if abs(a1 - a0) > 1e-9 * a0:
        raise AssertionError(f"the boundary's area changed from {a0!r} to {a1!r}")
    off = np.setdiff1d(np.unique(b1), np.unique(b0))
    if len(off):
        raise AssertionError(f"vertex {int(off[0])} is on the new boundary but inside the old domain")
