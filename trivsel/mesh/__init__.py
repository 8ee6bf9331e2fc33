"""The data-dependent tetrahedral mesh of section 4, as flat arrays and small named operations.

Modules, in the order of their dependencies:

* :mod:`~trivsel.mesh.state` - the state (named arrays, options, counters) and :func:`make_state`;
* :mod:`~trivsel.mesh.geometry` - predicates and point location (eqs. 13, 16);
* :mod:`~trivsel.mesh.heap` - the greedy method's priority queue over tets;
* :mod:`~trivsel.mesh.storage` - tet slots, point buckets, links and the one primitive ``_replace``;
* :mod:`~trivsel.mesh.criteria` - the swap criteria (eqs. 14-15, SSE) and the evaluation of a flip;
* :mod:`~trivsel.mesh.insertion` - the insertion cases (i)-(iii) of section 4 and the first cone;
* :mod:`~trivsel.mesh.flips` - the flip configurations (Figs. 2-3);
* :mod:`~trivsel.mesh.swap` - data-dependent swapping and its memory;
* :mod:`~trivsel.mesh.greedy`, :mod:`~trivsel.mesh.drivers` - the loops of the two methods;
* :mod:`~trivsel.mesh.compile` - signature pinning and :func:`compile_kernels`;
* :mod:`~trivsel.mesh.entries`, :mod:`~trivsel.mesh.entry_kernels` - the kernels a reduction
  calls, compiled ahead of time (:mod:`trivsel.aot`);
* :mod:`~trivsel.mesh.tetmesh` - :class:`TetMesh`, the Python face of it all;
* :mod:`~trivsel.mesh.validation` - :func:`check_mesh`, the mesh-validity checker;
* :mod:`~trivsel.mesh.cache` - numba's on-disk cache, stamped with all the package's sources.

Importing the package, building a :class:`TetMesh` and running its reduction kernels from
the extension module import no numba; the kernel modules (and :func:`compile_kernels`,
:func:`check_mesh`) load it when first used.
"""

from .state import (CRITERIA, ERR_DUPLICATE, ERR_LINK, ERR_POOLCAP, ERR_TETCAP, ERR_UNCOVERED,  # noqa: F401
                    UNLIMITED_ROUNDS, make_state)
from .tetmesh import MeshError, TetMesh, face_neighbours  # noqa: F401

__all__ = ["TetMesh", "MeshError", "ERR_TETCAP", "ERR_POOLCAP", "ERR_LINK", "ERR_UNCOVERED", "ERR_DUPLICATE",
           "CRITERIA", "UNLIMITED_ROUNDS", "compile_kernels", "check_mesh", "MeshInvalid", "make_state",
           "face_neighbours"]

_LAZY = {"compile_kernels": "compile", "check_mesh": "validation", "MeshInvalid": "validation"}


def __getattr__(name):
    """The names whose modules import numba, loaded on first use."""
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
