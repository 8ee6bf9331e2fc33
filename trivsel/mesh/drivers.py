"""The drivers of the paper's method and the read-outs of a finished mesh.

:func:`run_insertions` inserts points in a given order (section 3's ranking),
each followed by swapping; :func:`global_pass` is the optional final swap over
the whole mesh; :func:`residuals` and :func:`point_weights` read the
piecewise-linear interpolant back (eqs. 13, 16, 19-20).
"""

from __future__ import annotations

import numpy as np
from .cache import njit

from .geometry import _locate, _vol
from .insertion import insert_point
from .state import A_SSE, C_ABOVE, C_ERROR, C_HW, UNLIMITED_ROUNDS
from .swap import swap


@njit(cache=True)
def run_insertions(S, order, start, stop, tol_rms, n_total):
    """The paper's method: insert ``order[start:stop]`` one by one (section 3's
    ranking), each followed by swapping (section 4).

    Parameters
    ----------
    S : MeshState
    order : int64 array
        Candidate points, best first.
    start, stop : int
        The part of ``order`` to insert.
    tol_rms : float
        Stop once E_RMS = sqrt(sum of squared residuals / n_total) <= tol_rms
        (eq. 19); negative for no tolerance.  The E_inf tolerance is the option
        ``tol_inf``: stop once no residual exceeds it.
    n_total : float
        N, the number of original points.

    Returns
    -------
    int
        The position in ``order`` reached (exclusive); less than ``stop`` after
        a tolerance is met or on an error (``S.ctr[C_ERROR]``).
    """
    ctr = S.ctr
    tolinf = S.opt.tol_inf
    for k in range(start, stop):
        case, ids = insert_point(S, order[k])
        if ctr[C_ERROR] != 0:
            return k
        swap(S, ids, ids.shape[0], True, S.opt.max_rounds)
        if ctr[C_ERROR] != 0:
            return k + 1
        if tol_rms >= 0.0 and np.sqrt(max(S.acc[A_SSE], 0.0) / n_total) <= tol_rms:
            return k + 1
        if tolinf >= 0.0 and ctr[C_ABOVE] == 0:
            return k + 1
    return stop


@njit(cache=True)
def global_pass(S):
    """The optional final swap over all tetrahedra (end of section 4), until nothing
    improves: the cap on flips per insertion (``max_rounds``) does not apply."""
    alive = S.alive
    hw = S.ctr[C_HW]
    seed = np.empty(hw, np.int64)
    n = 0
    for t in range(hw):
        if alive[t]:
            seed[n] = t
            n += 1
    return swap(S, seed, n, False, UNLIMITED_ROUNDS)


@njit(cache=True)
def residuals(S, out):
    """The residuals f - L at every original point, from every live tet containing it
    (the terms of eqs. 19-20), into ``out``.

    Returns
    -------
    float
        The largest disagreement between two tets containing the same point (zero
        for a continuous interpolant, up to rounding).
    """
    I_ = S.ijk
    P_ = S.points
    F_ = S.values
    ui_ = S.opt.use_int
    tets = S.tets
    alive = S.alive
    F = F_
    pool = S.pool
    seen = np.zeros(F.shape[0], np.uint8)
    worst = 0.0
    for t in range(S.ctr[C_HW]):
        if not alive[t]:
            continue
        q0, q1, q2, q3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        s = S.bstart[t]
        for j in range(S.blen[t]):
            p = pool[s + j]
            inside, nz, val = _locate(I_, P_, F_, ui_, q0, q1, q2, q3, p)
            r = F[p] - val
            if seen[p]:
                worst = max(worst, abs(r - out[p]))
            else:
                out[p] = r
                seen[p] = 1
    return worst


@njit(cache=True)
def point_weights(S, verts, weights):
    """For every original point p, the vertices of its owner tet into ``verts[p]`` and
    p's barycentric weights in it (eq. 13, the sub-volumes over the volume) into
    ``weights[p]``: L(p) = sum of weights times the vertex values (eq. 16)."""
    I_ = S.ijk
    P_ = S.points
    ui_ = S.opt.use_int
    tets = S.tets
    owner = S.owner
    for p in range(S.values.shape[0]):
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
