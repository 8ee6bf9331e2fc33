"""Point insertion: the three cases of section 4 and the first cone from the hull (section 3).

A selected point p splits the tets whose closed region contains it; each such tet
is replaced by the tets joining p to its faces that do not contain p::

    case (i)   p inside a tet     1 tet  -> 4 tets    p joined to the 4 faces
    case (ii)  p inside a face    2 tets -> 6 tets    each joined to its 3 faces off p
                                  (1 -> 3 on the hull)
    case (iii) p inside an edge   k tets -> 2k tets   each joined to its 2 faces off the
                                                      edge (k tets around it)

All three go through :func:`~trivsel.mesh.storage._replace`; hull faces and
edges are handled alike (``new_hull``: the split hull faces stay hull faces).
"""

from __future__ import annotations

import numpy as np
from .cache import njit

from .geometry import FACE_IN, _positive, _sign
from .state import C_CASE1, C_ERROR, C_HW, C_NVERT, C_OSTAMP, ERR_DUPLICATE
from .storage import _copy2, _replace


@njit(cache=True)
def insert_point(S, p):
    """Insert original point p (section 4, cases i-iii).

    The tets whose closed region contains p are found from p's owner tet by
    crossing faces that contain p: one tet (case i, p interior: 1 -> 4), the one or
    two tets sharing a face (case ii: each -> 3), or all tets around an edge
    (case iii: each -> 2).  Each is replaced by the tets joining p to its faces
    that do not contain p.  Boundary faces and edges are handled alike.

    Parameters
    ----------
    S : MeshState
    p : int
        An original point that is not a vertex yet.

    Returns
    -------
    (int, int64 array)
        The case (1, 2 or 3) and the new tet ids; (0, empty) with
        ``S.ctr[C_ERROR]`` set if p coincides with a vertex (``ERR_DUPLICATE``)
        or the change failed.
    """
    I_ = S.ijk
    P_ = S.points
    ui_ = S.opt.use_int
    tets = S.tets
    nbr = S.nbr
    t0 = S.owner[p]
    cav = np.empty(64, np.int64)
    sg = np.empty((64, 4), np.int64)
    ncav = 1
    cav[0] = t0
    ctr = S.ctr
    ctr[C_OSTAMP] += 1
    om = S.omark
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
    S.isvert[p] = 1
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
    tets = S.tets
    nbr = S.nbr
    alive = S.alive
    hw = S.ctr[C_HW]
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
    S.isvert[p] = 1
    S.ctr[C_NVERT] += 1
    S.ctr[C_CASE1] += 1
    return ids
