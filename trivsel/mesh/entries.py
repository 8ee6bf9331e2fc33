"""The kernels a reduction calls from Python, compiled ahead of time (:mod:`trivsel.aot`).

A reduction by insertion (the paper's method or greedy) calls a few kernels from Python
(:func:`entry_signatures`: the insertion cases, swapping, a method's driver, the read-outs);
everything else is compiled into their machine code.  Loading them from numba's on-disk
cache costs every process about half a second before its first insertion: numba's
compiler target is set up and each kernel's cache entry is read.  :func:`kernels` gives the
same functions from an extension module that :mod:`trivsel.aot` builds once per machine
and state layout, and that loads in milliseconds; or numba's own kernels, pinned
(:func:`~trivsel.mesh.compile.pin_signatures`), where that is switched off or fails.

The module is built from two kinds of export bodies:

* the kernels that ``trivsel compile --part 0`` and ``--part 1`` compile with numba anyway
  (swapping and the insertion cases, which the drivers call) are exported through a
  one-line Python function calling the numba kernel, so the build links numba's cached
  machine code instead of typing them again (and ``swap``, typed as an export of its own,
  fails on its ``kind`` variable, assigned constants of different values);
* the drivers, the global pass and the point weights, which only Python calls, are
  exported from their own Python functions, so no process has to compile them with numba
  first.

Both are the same functions as numba's kernels, compiled by the same numba: the results
are identical to the bit (``tests/test_aot.py``).
"""

from __future__ import annotations

import os

from .cache import _PKG_DIR, _SOURCES

#: The module of the numba kernels and their export bodies
KERNELS = "trivsel.mesh.entry_kernels"
#: The sources whose change must rebuild the extension module (every module the kernels use)
SOURCES = tuple(_SOURCES) + (os.path.join(os.path.dirname(_PKG_DIR), "aot.py"),)


def _variant(S):
    return "greedy" if S.opt.greedy else "paper"


def kernels(S, *, rebuild=False):
    """The entry kernels for states of the layout and method of ``S``, as attributes named as
    in :func:`~trivsel.mesh.entry_kernels.aot_exports`: from the extension module (built now
    if need be), or numba's own, pinned (:func:`trivsel.aot.kernels`; the same results)."""
    from .. import aot

    k = aot.kernels(KERNELS, SOURCES, S, variant=_variant(S), rebuild=rebuild)
    if aot.is_jit(k):
        from .compile import pin_signatures

        pin_signatures(S)
    return k


def probe_state(method):
    """The smallest state of a method (a tetrahedron's four corners on a grid): the layout
    every grid or scattered reduction's state has, for compiling and building."""
    import numpy as np

    from .state import make_state

    ijk = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.int64)
    return make_state(ijk.astype(np.float64), np.zeros(4), ijk, pin=False, greedy=method == "greedy")


def built(S) -> bool:
    """Whether the extension module for the layout and method of ``S`` is there (and may be
    loaded without building anything)."""
    from .. import aot

    return aot._paths(KERNELS, SOURCES, S, _variant(S))[1].exists()
