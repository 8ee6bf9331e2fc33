"""Greedy selection: insert the worst-approximated candidate, swap, repeat.

The 3-D analogue of Garland & Heckbert's (1995) greedy insertion, an alternative
to the paper's curvature order; the priority queue is :mod:`trivsel.mesh.heap`.
"""

from __future__ import annotations

import numpy as np
from .cache import njit

from .heap import _heap_pop
from .insertion import insert_point
from .state import A_SSE, C_ABOVE, C_ERROR, C_NVERT
from .swap import swap


@njit(cache=True)
def greedy_next(S):
    """The candidate with the largest |f - L| over all tets (Garland & Heckbert 1995, in 3-D).

    Pops stale heap entries (dead or rebuilt tets) until the top is current.
    Returns -1 when no candidate has a nonzero residual.
    """
    alive = S.alive
    tver = S.tver
    while True:
        key, t, ver = _heap_pop(S)
        if t < 0:
            return -1
        if alive[t] and tver[t] == ver and S.tbest[t] >= 0:
            return S.tbest[t]


@njit(cache=True)
def run_greedy(S, stop_nvert, tol_rms, n_total, log):
    """Insert the worst-approximated candidate, swap, repeat, until ``stop_nvert`` vertices.

    Each tet's candidate (its contained non-vertex candidate point with the largest
    residual) sits in the heap; insertion and flips replace tets, and
    :func:`~trivsel.mesh.storage._replace` pushes the new ones, so only touched
    tets are refreshed.

    Parameters
    ----------
    S : MeshState
    stop_nvert : int
        Stop at this many vertices.
    tol_rms : float
        Stop once E_RMS <= tol_rms (eq. 19; negative: no tolerance); also once no
        residual exceeds the option ``tol_inf``, if set.
    n_total : float
        N, the number of original points.
    log : int64 array
        Receives the inserted points in order.

    Returns
    -------
    int
        How many points were inserted.
    """
    ctr = S.ctr
    tolinf = S.opt.tol_inf
    k = 0
    while ctr[C_NVERT] < stop_nvert:
        if tol_rms >= 0.0 and np.sqrt(max(S.acc[A_SSE], 0.0) / n_total) <= tol_rms:
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
        swap(S, ids, ids.shape[0], True, S.opt.max_rounds)
        if ctr[C_ERROR] != 0:
            break
    return k
