"""Compilation of the numba kernels: one pinned signature per helper, and :func:`compile_kernels`.

Numba increments and decrements the reference count of every array an ordinary
compiled function receives (each array of the state) and of every array variable
reassigned in a loop.  So the helpers of the swap loop (the ``*_at`` variants)
allocate nothing and are compiled with ``_nrt=False``: no reference counting at
all, whether they receive arrays or the whole state; and nothing in
:func:`~trivsel.mesh.swap.swap`'s inner loops rebinds an array.

Without pinning, numba compiles a helper once per combination of argument types
it meets while typing its callers: int32 read from ``tets`` against int64 loop
indices, ``Literal[int](2)`` against ``int64``, ``Literal[bool](True)`` against
``bool``, each a full copy of the helper and of everything it calls.  With one
pinned signature (int64 indices, :func:`pin_signatures`), numba converts the
arguments at the call instead.  Pinning runs in
:func:`~trivsel.mesh.state.make_state` (once per state type), so ``import
trivsel`` stays cheap; each signature comes from the on-disk cache after the
first run.  The kernel modules (and numba) are imported by the functions that
need them, so :func:`compile_kernels` finds a built extension module without them.
"""

from __future__ import annotations

_PINNED = set()  # state types the helpers are compiled for
_FROM_CACHE = set()  # (state type, method kernel) whose entry kernels were all in the cache


def helper_signatures(S):
    """The internal helpers and their one signature (int64 indices), callees before
    callers, for the state type of ``S``."""
    from numba import typeof, types as nt

    from . import criteria, flips, geometry, heap, storage, swap

    st = typeof(S)
    i8, b1, f8 = nt.int64, nt.boolean, nt.float64
    v8, m8, m4 = nt.int64[::1], nt.int64[:, ::1], nt.int32[:, ::1]
    f82 = nt.float64[:, ::1]
    return [
        (geometry._sign, (m8, f82, b1, i8, i8, i8, i8)),
        (geometry._vol, (m8, f82, b1, i8, i8, i8, i8)),
        (criteria._crit, (i8, f8, f8, i8)),
        (storage._other_index, (m4, i8, i8, i8, i8)),
        (swap._push_unique, (v8, i8, i8, v8, i8)),
        (swap._with_room, (v8, i8, i8)),
        (storage._copy1, (v8, v8, i8)),
        (storage._copy2, (m8, m8, i8)),
        (storage._sort_into, (v8, i8, v8)),
        (storage._gather_at, tuple(typeof(a) for a in (S.ctr, S.mark, S.wbuf, S.pool, S.bstart, S.blen))
         + (v8, i8)),
        (storage._gather, (st, v8, i8)),
        (geometry._positive_at, (m8, f82, b1, m8, i8)),
        (geometry._positive, (st, m8, i8)),
        (flips._edge_opposite, (m4, i8, i8, i8)),
        (flips.quads32, (i8, i8, v8, m8)),
        (flips.quads44, (i8, i8, v8, i8, m8)),
        (flips._config23_at, (m4, m4, i8, i8, v8, m8)),
        (flips._config22_at, (st, v8, i8, i8, i8, i8, v8, v8, v8, m8)),
        (criteria._cannot_beat, (i8,) + tuple(typeof(a) for a in (S.tsse, S.tmax, S.tcnt)) + (v8, i8, f8)),
        (criteria._evaluate_at, (st, v8, v8, i8, m8, i8, f8, f8, b1)),
        (criteria._evaluate, (st, v8, i8, m8, i8, f8, f8)),
        (heap._set_best, (st, i8, i8, f8)),
        (storage._replace, (st, v8, i8, m8, i8, b1)),
        (swap._config_key, (v8, i8, i8, i8, v8, i8, v8)),
        (swap._cache_slot, (m8, v8, i8)),
        (swap._cache_store, (m8, f82, i8, i8, v8, f8, f8)),
        (swap.swap, (st, v8, i8, b1, i8)),  # last: it calls the helpers above
    ]


def _pin(fn, sig):
    """Compile (or load from the cache) ``fn`` for ``sig`` and forbid other variants."""
    fn.disable_compile(False)
    fn.compile(sig)
    fn.disable_compile(True)


def entry_signatures(S, kernel):
    """The kernels a reduction calls from Python, and the signatures it calls them with.

    ``kernel`` is a method's ``KERNEL`` (``"paper"`` or ``"greedy"``): which driver
    (:func:`~trivsel.mesh.drivers.run_insertions` or :func:`~trivsel.mesh.greedy.run_greedy`).
    Everything else a reduction runs is compiled into these kernels' machine code.
    ``S`` is a state or its numba type.
    """
    from numba import typeof, types as nt

    from . import drivers, greedy, insertion, storage, swap

    st = S if isinstance(S, nt.Type) else typeof(S)
    i8, f8, b1 = nt.int64, nt.float64, nt.boolean
    v8, m8, f82 = nt.int64[::1], nt.int64[:, ::1], nt.float64[:, ::1]
    driver = ((greedy.run_greedy, (st, i8, f8, f8, v8)) if kernel == "greedy"
              else (drivers.run_insertions, (st, v8, i8, i8, f8, f8)))
    return [(storage._alloc, (st,)), (storage.fill_buckets, (st, v8)), (drivers.residuals, (st, nt.float64[::1])),
            (insertion.insert_point, (st, i8)), (insertion.cone_from_hull, (st, i8)), (swap.swap, (st, v8, i8, b1, i8)),
            driver, (drivers.global_pass, (st,)), (drivers.point_weights, (st, m8, f82))]


def _cached(fn, sig):
    """Whether numba's on-disk cache holds ``fn`` compiled for ``sig`` on this machine
    (:func:`trivsel.aot.in_cache`; ``False`` if it cannot tell: pin, as without a cache)."""
    from ..aot import in_cache

    return in_cache(fn, sig)


def pin_signatures(S):
    """Compile each internal helper for its one argument signature (see the module
    notes) and forbid further variants; once per state type.

    When the cache already holds every kernel a reduction of this state calls
    from Python (:func:`entry_signatures`), nothing will be compiled, so nothing
    needs pinning: loading the 27 helpers from the cache would cost about a
    second per process for machine code the entry kernels already contain.
    """
    from numba import typeof

    from . import swap

    if not hasattr(swap.swap, "disable_compile"):  # NUMBA_DISABLE_JIT=1: plain Python functions
        return
    st = typeof(S)
    if st in _PINNED:
        return
    kernel = "greedy" if S.opt.greedy else "paper"
    if (st, kernel) in _FROM_CACHE:
        return
    if all(_cached(fn, sig) for fn, sig in entry_signatures(S, kernel)):
        _FROM_CACHE.add((st, kernel))
        return
    for fn, sig in helper_signatures(S):
        _pin(fn, sig)
    _PINNED.add(st)


def _plan(S, method, part, helpers):
    """What ``part`` of :func:`compile_kernels` compiles, in order: (kernel, signature), from the
    pinned ``helpers`` (:func:`helper_signatures`) and the entry kernels."""
    from . import criteria, drivers, flips, geometry, heap, insertion, storage, swap

    # the pinned helpers that only swapping uses (part 0; _evaluate is its wrapper for TetMesh)
    swap_only = (swap._push_unique, swap._with_room, flips._edge_opposite, flips.quads32, flips.quads44,
                 flips._config23_at, flips._config22_at, criteria._cannot_beat, criteria._evaluate_at,
                 criteria._evaluate, swap._config_key, swap._cache_slot, swap._cache_store)
    cheap = (geometry._sign, geometry._vol, criteria._crit, storage._other_index, storage._copy1, storage._copy2,
             storage._sort_into, storage._gather_at, storage._gather, geometry._positive_at, geometry._positive)
    # the entry kernels of insertion (part 1); the others are part 2's
    inserting = (storage._alloc, storage.fill_buckets, drivers.residuals, insertion.insert_point,
                 insertion.cone_from_hull)
    # cheap leaves first (every part), then each part's own subtree, callees first
    leaves = [h for h in helpers if h[0] in cheap]
    replace = [h for h in helpers if h[0] in (heap._set_best, storage._replace)]
    swapping = [h for h in helpers if h[0] in swap_only] + replace + [h for h in helpers if h[0] is swap.swap]
    called = [h for h in entry_signatures(S, method) if h[0] is not swap.swap]
    insertion_ = [h for h in called if h[0] in inserting]
    driving = [h for h in called if h[0] not in inserting]  # the driver, the global pass, the point weights
    if part == 0:
        return leaves + swapping
    if part == 1:
        return leaves + replace + insertion_
    return leaves + swapping + insertion_ + driving


PARTS = (0, 1, 2)


def compile_kernels(method="paper", part=None):
    """Compile the numba kernels of a reduction into numba's on-disk cache.

    A reduction compiles its kernels on first use anyway (once per machine; they
    load from the cache in ``__pycache__`` afterwards).  This splits the work into
    parts that share little, so that two processes fill the cache side by side:
    ``trivsel compile --part 0`` and ``--part 1`` at once, then ``--part 2``,
    which finds everything but the drivers in the cache.  With kernels ahead of time
    (:mod:`trivsel.mesh.entries`, the default), part 2 builds the extension module
    that reductions load instead of numba's cache, from the kernels of parts 0 and 1
    and the drivers' sources; once it is built, every part returns at once.

    Parameters
    ----------
    method : {"paper", "greedy"}
        The insertion method the kernels are for.  Both run the same kernels up
        to the driver, and parts 2 and None compile the method's own driver (the
        other one compiles on its first run).  Every method's ``compile_kernels``
        (:mod:`trivsel.methods`) is what ``trivsel compile`` calls.
    part : {None, 0, 1, 2}
        ``0``: swapping (section 4: 2-3, 3-2, 4-4 and 2-2 flips) and the
        evaluation of configurations, with the replacement of tets
        (:func:`~trivsel.mesh.storage._replace`) that it shares with insertion.
        ``1``: point insertion (section 4: in a tet, on a face, on an edge),
        the replacement of tets, bucket filling and residuals.
        ``2``: the method's driver (:func:`~trivsel.mesh.drivers.run_insertions`
        or :func:`~trivsel.mesh.greedy.run_greedy`), the global pass and the point
        weights; run after 0 and 1 it only loads their kernels from the cache.
        With kernels ahead of time: the extension module of all of them.
        ``None``: everything, in one process.

    Returns
    -------
    int
        The number of (kernel, signature) pairs compiled or loaded (the extension
        module's exports when it was built; 0 when it was there already).
    """
    if method not in ("paper", "greedy"):
        raise ValueError(f"unknown insertion method {method!r}: choose 'paper' or 'greedy'")
    if part not in (None,) + PARTS:
        raise ValueError(f"unknown part {part!r}: choose 0, 1, 2 or None (all)")
    from .. import aot
    from . import entries

    S = entries.probe_state(method)
    if aot.enabled() and entries.built(S):  # what a reduction loads is there, found without numba
        return 0
    from numba import typeof

    from . import swap

    if not hasattr(swap.swap, "disable_compile"):  # NUMBA_DISABLE_JIT=1: nothing to compile
        return 0
    if aot.enabled() and part in (None, 2):  # the extension module, from what parts 0 and 1 left in the cache
        if not aot.is_jit(entries.kernels(S, rebuild=True)):
            return len(entry_signatures(S, method))
        # the build failed (logged): numba's own driver, as without ahead-of-time kernels
    st = typeof(S)
    helpers = helper_signatures(S)
    plan = _plan(S, method, part, helpers)
    if not all(_cached(fn, sig) for fn, sig in plan):
        aot.compile_notice(method if part is None else f"{method} (part {part})")
    pinned = {fn for fn, _ in helpers}
    for fn, sig in plan:
        if fn in pinned:
            _pin(fn, sig)
        else:
            fn.compile(sig)
    if part in (None, 2):
        _PINNED.add(st)
    return len(plan)
