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
* :mod:`~trivsel.mesh.tetmesh` - :class:`TetMesh`, the Python face of it all;
* :mod:`~trivsel.mesh.validation` - :func:`check_mesh`, the mesh-validity checker;
* :mod:`~trivsel.mesh.cache` - numba's on-disk cache, stamped with all the package's sources.
"""

from .cache import install as _install_cache

_install_cache()  # before any kernel is defined

from .compile import compile_kernels  # noqa: E402
from .criteria import CRITERIA  # noqa: E402
from .state import (ERR_DUPLICATE, ERR_LINK, ERR_POOLCAP, ERR_TETCAP, ERR_UNCOVERED,  # noqa: E402
                    UNLIMITED_ROUNDS, make_state)
from .tetmesh import MeshError, TetMesh, face_neighbours  # noqa: E402
from .validation import MeshInvalid, check_mesh  # noqa: E402

__all__ = ["TetMesh", "MeshError", "ERR_TETCAP", "ERR_POOLCAP", "ERR_LINK", "ERR_UNCOVERED", "ERR_DUPLICATE",
           "CRITERIA", "UNLIMITED_ROUNDS", "compile_kernels", "check_mesh", "MeshInvalid", "make_state",
           "face_neighbours"]
