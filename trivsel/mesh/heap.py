"""The greedy method's priority queue: a binary max-heap over tets, keyed by their worst candidate.

Each tet keeps its contained non-vertex candidate point with the largest
residual (``S.tbest``, ``S.tbestr``).  :func:`_set_best` records it whenever a
tet's points are (re)filled and pushes the tet with its slot version
(``S.tver``); entries of dead or refilled tets go stale and are skipped when
popped (:func:`trivsel.mesh.greedy.greedy_next`) or dropped when the heap is
rebuilt.
"""

from __future__ import annotations

from .cache import njit

from .state import C_HEAPN, C_HW


@njit(cache=True, _nrt=False)
def _heap_push(S, key, t, ver):
    """Push (key, tet, version) onto the array-backed binary max-heap."""
    hk = S.hkey
    ht = S.htet
    hv = S.hver
    ctr = S.ctr
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
    hk = S.hkey
    ht = S.htet
    hv = S.hver
    ctr = S.ctr
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
    S.ctr[C_HEAPN] = 0
    alive = S.alive
    hk = S.hkey
    for t in range(S.ctr[C_HW]):
        if alive[t] and S.tbest[t] >= 0 and S.ctr[C_HEAPN] < hk.shape[0]:
            _heap_push(S, _greedy_key(S, t), t, S.tver[t])


@njit(cache=True, _nrt=False)
def _set_best(S, t, best, bestr):
    """Record tet t's worst candidate ``best`` (-1: none) and its |residual| ``bestr``,
    and, for the greedy method, push t with its current version."""
    S.tbest[t] = best
    S.tbestr[t] = bestr
    if S.opt.greedy and best >= 0:
        if S.ctr[C_HEAPN] >= S.hkey.shape[0]:
            _heap_rebuild(S)  # full of stale entries: refill from the live tets (t included)
        else:
            _heap_push(S, _greedy_key(S, t), t, S.tver[t])


@njit(cache=True, _nrt=False)
def _greedy_key(S, t):
    """Heap key of tet t: its worst residual (``greedy_key="max"``) or its squared-error sum ("sse")."""
    if S.opt.greedy_key_sse:
        return S.tsse[t]
    return S.tbestr[t]
