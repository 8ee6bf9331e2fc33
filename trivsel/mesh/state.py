"""The mesh state: named flat arrays, the options, the counters and :func:`make_state`.

A mesh is a :class:`MeshState`, a named tuple of numpy arrays plus the
:class:`Options` (a named tuple of scalars).  Numba compiles a field access such
as ``S.tets`` to a static item access, and a named tuple of arrays can be
cached on disk with the functions that take it.  There is no object per element:
every array is preallocated to a capacity and tet slots are recycled through a
free list (:mod:`trivsel.mesh.storage`)::

    tets[t]   = (v0, v1, v2, v3)     original point indices, orient3d > 0
    nbr[t, i] = tet across the face opposite v_i, or -1 on the hull
    pool[bstart[t] : bstart[t] + blen[t]]
              = the original points in the *closed* tet t (vertices and points on
                faces and edges included: a point on a shared face is in both tets)
    tsse, tmax, tcnt = squared-residual sum, max |residual| and point count of t
                       (the terms of eqs. 14-15)

The counters are one int64 array ``S.ctr`` indexed by the ``C_*`` constants
below, and the two running float sums one array ``S.acc`` indexed by ``A_*``:
kernels update them in place.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Swap rounds (flips) per call that mean "until nothing improves" (``max_rounds``'s default)
UNLIMITED_ROUNDS = 100000

# ----------------------------------------------------------------------------- swap criteria (S.opt.criterion)
CRIT_RMS, CRIT_MAX, CRIT_SSE = 0, 1, 2  # see trivsel.mesh.criteria
CRITERIA = {"rms": CRIT_RMS, "max": CRIT_MAX, "sse": CRIT_SSE}
#: Words of a configuration's key in swap's memory (trivsel.mesh.swap)
KEYLEN = 5

# ----------------------------------------------------------------------------- counters (S.ctr)
C_HW = 0  # high-water mark of tet slots handed out
C_NFREE = 1  # tet slots on the free list
C_POOLTOP = 2  # first unused entry of the point pool
C_STAMP = 3  # stamp of the point marks (S.mark) of the last gather
C_ERROR = 4  # error code (ERR_*) of the first failure, 0 if none
C_FLIP23 = 5  # flips made, by configuration (C_FLIP23 + kind for kinds 0-2)
C_FLIP32 = 6
C_FLIP44 = 7
C_NVERT = 8  # vertices (selected points)
C_ABOVE = 9  # points whose |residual| exceeds the E_inf tolerance
C_OSTAMP = 10  # stamp of the tet marks (S.omark)
C_CASE1 = 11  # insertions by case of section 4 (C_CASE1 + p's zero signs): in a tet,
C_CASE2 = 12  # on a face,
C_CASE3 = 13  # on an edge
C_ROUNDCAP = 14  # swap calls stopped by max_rounds rather than by no improvement
C_HEAPN = 15  # entries of the greedy heap
C_FLIP22 = 16  # boundary 2-2 flips
C_LASTM = 17  # points gathered by the last evaluation (see _evaluate_at's ``reuse``)
C_EVALS = 18  # configurations swap evaluated
C_MEMHITS = 19  # configurations swap found in its memory
N_COUNTERS = 20

# ----------------------------------------------------------------------------- running sums (S.acc)
A_SSE = 0  # the global sum of squared residuals (the numerator of E_RMS, eq. 19)
A_BEFORE = 1  # SSE criterion: the last evaluated configuration's ``before``
N_SUMS = 2

# ----------------------------------------------------------------------------- error codes (S.ctr[C_ERROR])
ERR_TETCAP, ERR_POOLCAP, ERR_LINK, ERR_UNCOVERED, ERR_DUPLICATE = 1, 2, 3, 4, 5
ERROR_MESSAGES = {ERR_TETCAP: "tet capacity exceeded", ERR_POOLCAP: "point-bucket capacity exceeded",
                  ERR_LINK: "face matching failed", ERR_UNCOVERED: "a point left uncovered",
                  ERR_DUPLICATE: "point coincides with a vertex (duplicate point)"}

#: How long :func:`~trivsel.mesh.swap.swap` remembers evaluated configurations
SWAP_MEMORIES = ("run", "call")
#: What orders the greedy heap: a tet's worst candidate residual or its squared-error sum
GREEDY_KEYS = ("max", "sse")


class Options(NamedTuple):
    """The options of a mesh, fixed for its life (scalars, so that every state has one numba type)."""

    use_int: bool  # grid points: exact integer predicates on ``ijk``, else robust float ones on ``points``
    criterion: int  # swap criterion, a ``CRIT_*`` code of :mod:`trivsel.mesh.criteria`
    vertices_in_error: bool  # a tet's own four vertices count in its error (Definition 2, eqs. 14-15)
    rel_tol: float  # a flip must lower the criterion sum by more than rel_tol * before + abs_tol
    abs_tol: float
    tol_inf: float  # E_inf tolerance of the run (counts C_ABOVE), or -1.0 for none
    first_improving: bool  # apply the first improving flip found, not the best of the round
    max_rounds: int  # flips per swap call after an insertion (the global pass is unlimited)
    greedy: bool  # keep the greedy heap of the tets' worst candidates
    greedy_key_sse: bool  # the heap key is the tet's squared-error sum, not its worst residual
    boundary_flips: bool  # also the boundary 2-2 flip of coplanar hull faces
    run_memory: bool  # swap's memory lasts the whole run (``S.mkey``), not one call


class MeshState(NamedTuple):
    """The arrays of a mesh (see the module notes).  ``cap`` = tet capacity, N = original points."""

    points: np.ndarray  # (N, 3) float coordinates
    ijk: np.ndarray  # (N, 3) int64 grid coordinates (zeros off grids)
    values: np.ndarray  # (N,) the data values f
    tets: np.ndarray  # (cap, 4) int32 vertices, positively oriented
    nbr: np.ndarray  # (cap, 4) int32 tet across the face opposite each vertex, -1 on the hull
    alive: np.ndarray  # (cap,) uint8
    free: np.ndarray  # (cap,) int32 free list of dead slots
    bstart: np.ndarray  # (cap,) int64 bucket start in the pool
    blen: np.ndarray  # (cap,) int32 bucket length
    pool: np.ndarray  # (pool capacity,) int32 point buckets
    tsse: np.ndarray  # (cap,) squared-residual sum of a tet's points
    tmax: np.ndarray  # (cap,) max |residual|
    tcnt: np.ndarray  # (cap,) int32 point count
    mark: np.ndarray  # (N,) int64 point marks (gathering each point once)
    resid: np.ndarray  # (N,) residual f - L of each point, from its owner tet
    owner: np.ndarray  # (N,) int32 the tet a point's residual comes from
    isvert: np.ndarray  # (N,) uint8 selected points
    wbuf: np.ndarray  # (N,) int32 work buffer: the points of a cavity or configuration
    ctr: np.ndarray  # (N_COUNTERS,) int64 counters, indexed by C_*
    opt: Options
    acc: np.ndarray  # (N_SUMS,) running float sums, indexed by A_*
    omark: np.ndarray  # (cap,) int64 tet marks (the set O of swapping, the cavity of an insertion)
    tbest: np.ndarray  # (cap,) int32 a tet's worst candidate point (greedy), -1 if none
    tbestr: np.ndarray  # (cap,) its |residual|
    tver: np.ndarray  # (cap,) int64 how often a slot was handed out (versions for the heap and swap's memory)
    hkey: np.ndarray  # (2 cap,) greedy heap: keys,
    htet: np.ndarray  # (2 cap,) int64 tets
    hver: np.ndarray  # (2 cap,) int64 and the tets' versions when pushed
    cand: np.ndarray  # (N,) uint8 candidate points (may be selected)
    mkey: np.ndarray  # (rows, key length) int64 swap's run-long memory: keys, -1 = empty,
    mval: np.ndarray  # (rows, 2) and the (before, after) evaluated


def make_state(points, values, ijk=None, *, criterion="rms", vertices_in_error=True, rel_tol=1e-9,
               abs_tol=None, tol_inf=None, first_improving=False, max_rounds=UNLIMITED_ROUNDS,
               tet_capacity=None, pool_capacity=None, greedy=False, greedy_key="max", candidates=None,
               boundary_flips=False, swap_memory="run", pin=True):
    """Allocate the arrays of an empty mesh over the given original points.

    Parameters
    ----------
    points, values : array_like
        (N, 3) coordinates and (N,) data values of the original points.
    ijk : array_like, optional
        (N, 3) integer grid coordinates: predicates and the weights of eq. 13 are
        then exact integers.
    criterion : {"rms", "max", "sse"}
        Swap criterion: sum of the tets' RMS errors (eq. 14), of their max errors
        (eq. 15), or the global squared residual.
    vertices_in_error : bool
        A tet's error includes its own four vertices (Definition 2).
    rel_tol, abs_tol : float
        A flip must lower the criterion sum by more than ``rel_tol * before +
        abs_tol`` (default ``abs_tol``: 1e-12 of the value range, squared and times
        N under SSE).
    tol_inf : float, optional
        E_inf tolerance: the drivers stop when no residual exceeds it.
    first_improving : bool
        Apply the first improving flip found instead of the best of the round.
    max_rounds : int
        Flips per swap call after an insertion.
    tet_capacity, pool_capacity : int, optional
        Tet slots (default 8 N + 1024) and point-bucket entries (24 N + 4096).
    greedy : bool
        Keep the heap of :mod:`trivsel.mesh.greedy`; ``greedy_key`` ("max" or "sse") orders it.
    candidates : array_like, optional
        The points that may be selected (default all).
    boundary_flips : bool
        Also try the boundary 2-2 flip.
    swap_memory : {"run", "call"}
        How long swapping remembers evaluated configurations: the whole run (a
        fixed table of about 2 N entries, 56 bytes each) or one swap call (see
        :mod:`trivsel.mesh.swap`).
    pin : bool
        Compile the helpers for their one signature (:func:`trivsel.mesh.compile.pin_signatures`);
        ``False`` for :func:`~trivsel.mesh.compile.compile_kernels`.

    Returns
    -------
    MeshState
    """
    # C-contiguous and writable, so that every state has the same numba type
    P = np.require(points, np.float64, ["C", "W"])
    F = np.require(values, np.float64, ["C", "W"])
    N = F.shape[0]
    IC = np.require(ijk, np.int64, ["C", "W"]) if ijk is not None else np.zeros((N, 3), np.int64)
    cap = int(tet_capacity or (8 * N + 1024))
    pcap = int(pool_capacity or (24 * N + 4096))
    if criterion not in CRITERIA:
        raise ValueError(f"unknown swap criterion {criterion!r}: choose one of {sorted(CRITERIA)}")
    if greedy_key not in GREEDY_KEYS:
        raise ValueError(f"unknown greedy key {greedy_key!r}: choose 'max' or 'sse'")
    if swap_memory not in SWAP_MEMORIES:
        raise ValueError(f"unknown swap memory {swap_memory!r}: choose 'call' or 'run'")
    frange = float(F.max() - F.min()) if N else 0.0
    if abs_tol is None:
        abs_tol = 1e-12 * max(frange, 1e-300)
        if CRITERIA[criterion] == CRIT_SSE:
            abs_tol = abs_tol**2 * N
    opt = Options(use_int=ijk is not None, criterion=int(CRITERIA[criterion]),
                  vertices_in_error=bool(vertices_in_error), rel_tol=float(rel_tol), abs_tol=float(abs_tol),
                  tol_inf=-1.0 if tol_inf is None else float(tol_inf), first_improving=bool(first_improving),
                  max_rounds=int(max_rounds), greedy=bool(greedy), greedy_key_sse=greedy_key == "sse",
                  boundary_flips=bool(boundary_flips), run_memory=swap_memory == "run")
    mrows = 1 << max(10, int(2 * N - 1).bit_length()) if opt.run_memory else 1
    cand = np.ones(N, np.uint8)
    if candidates is not None:
        cand[:] = 0
        cand[np.asarray(candidates, np.int64)] = 1
    # tets, nbr, the greedy candidate of a slot and the memory's values are written
    # before they are read (tets, nbr and tbest when _alloc hands the slot out), so
    # they start uninitialised: np.empty leaves the unused part of the capacity
    # unmapped, where np.full would write it all
    S = MeshState(
        points=P, ijk=IC, values=F,
        tets=np.empty((cap, 4), np.int32), nbr=np.empty((cap, 4), np.int32), alive=np.zeros(cap, np.uint8),
        free=np.zeros(cap, np.int32), bstart=np.zeros(cap, np.int64), blen=np.zeros(cap, np.int32),
        pool=np.zeros(pcap, np.int32), tsse=np.zeros(cap), tmax=np.zeros(cap), tcnt=np.zeros(cap, np.int32),
        mark=np.zeros(N, np.int64), resid=np.zeros(N), owner=np.full(N, -1, np.int32),
        isvert=np.zeros(N, np.uint8), wbuf=np.zeros(N, np.int32), ctr=np.zeros(N_COUNTERS, np.int64),
        opt=opt, acc=np.zeros(N_SUMS), omark=np.zeros(cap, np.int64),
        tbest=np.empty(cap, np.int32), tbestr=np.zeros(cap), tver=np.zeros(cap, np.int64),
        hkey=np.zeros(2 * cap), htet=np.zeros(2 * cap, np.int64), hver=np.zeros(2 * cap, np.int64), cand=cand,
        mkey=np.full((mrows, KEYLEN), -1, np.int64), mval=np.empty((mrows, 2)))
    if pin:
        from .compile import pin_signatures

        pin_signatures(S)
    return S


def copy_state(S):
    """A deep copy of a state (the options are immutable and shared)."""
    return MeshState(*(a if isinstance(a, Options) else a.copy() for a in S))
