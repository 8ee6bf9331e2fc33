"""Geometric predicates and point location in a tet (eqs. 13 and 16), on grids or scattered points.

On grids a point-in-tet test is four dot products with the tet's integer face
planes (:func:`_tet_data`), the exact sub-volumes of eq. (13), computed once per
tet and loop rather than once per point.  Off grids the signs are robust
(:func:`~trivsel.predicates.orient3d_float_sign`).

The hot predicates take the coordinate arrays themselves, not the state: pulling
an array out of the state costs a reference-count update per call.
"""

from __future__ import annotations

import numpy as np
from .cache import njit

from ..predicates import orient3d_float, orient3d_float_sign, orient3d_int

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


@njit(cache=True, _nrt=False)
def _sign(I, P, ui, a, b, c, d):
    """Sign of orient3d of original points a, b, c, d: exact on the integer grid
    coordinates ``I`` when ``ui``, robust on the float coordinates ``P`` otherwise.

    It takes the coordinate arrays themselves, not the state: pulling an array out
    of the state costs a reference-count update per call, far more than the
    predicate itself."""
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
    as weights; on floats the signs are robust (:func:`orient3d_float_sign`).  Scalars and tuples only: it is
    inlined into the point loops, where every array argument of an inlined
    function would cost a reference-count update per point.
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
    """:func:`_sign` on the state (for checks and tests; not for inner loops)."""
    return _sign(S.ijk, S.points, S.opt.use_int, a, b, c, d)


@njit(cache=True)
def _locate_in(S, q0, q1, q2, q3, p):
    """:func:`_locate` on the state (for checks and tests; not for inner loops)."""
    return _locate(S.ijk, S.points, S.values, S.opt.use_int, q0, q1, q2, q3, p)


@njit(cache=True)
def _positive(S, newq, nnew):
    """Admissibility: every new tet has strictly positive volume."""
    return _positive_at(S.ijk, S.points, S.opt.use_int, newq, nnew)


@njit(cache=True, _nrt=False)
def _positive_at(I_, P_, ui_, newq, nnew):
    """:func:`_positive` on the coordinate arrays (for swapping's loop: every array
    taken out of the state costs a reference-count update per call)."""
    for k in range(nnew):
        if _sign(I_, P_, ui_, newq[k, 0], newq[k, 1], newq[k, 2], newq[k, 3]) <= 0:
            return False
    return True
