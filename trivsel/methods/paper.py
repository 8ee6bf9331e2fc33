"""The paper's method (Hamann & Chen 1994, sections 2-4).

Rank the candidates by descending absolute curvature ``K = |k1| + |k2| + |k3|`` of a
local least-squares quadratic (section 2, eqs. 4-10), with ties in a documented
order (section 3); join the first candidate to every boundary triangle (section 3)
and insert the others in that order, each followed by data-dependent swapping
(2-3, 3-2 and 4-4 flips) that lowers the sum of the tetrahedral errors (section 4,
eqs. 14-15).
"""

from __future__ import annotations

import numpy as np

from ..exceptions import InputError
from .insertion import check_domain, insertion_protocol

NAME = "paper"
#: Section 4's criterion (eq. 14), swapping until nothing improves, interior flips only.
DEFAULTS = {"criterion": "rms", "boundary_flips": False, "max_flips": 0}
GREEDY_QUEUE = False
KERNEL = "paper"
#: A prescribed boundary (section 3's start from given triangles) is supported.
PRESCRIBED_BOUNDARY = True
#: It inserts points and swaps (the insertion and swap options apply).
INSERTS = True

#: ``run``, ``memory`` and ``compile_kernels``: the top-down run of :mod:`trivsel.methods.insertion`.
run, memory, compile_kernels = insertion_protocol(__name__)


def needs_curvature(options):
    return True


def check(data, options):
    """Reject option combinations this method cannot run on ``data``."""
    check_domain(NAME, data)
    if options.neighbourhood == "box" and not data.is_grid:
        raise InputError("neighbourhood 'box' needs grid data")
    if options.ranking == "analytic" and "function" not in data.meta:
        raise InputError("ranking 'analytic' needs a Table-1 function (--function), not a data file")


def rank(data, candidates, options, *, tets=None, threads=1):
    """Absolute curvature of every point (section 2) and the candidates in insertion order (section 3).

    ``tets`` is a triangulation of all points (scattered data: its edges are the
    fit's neighbours); grids use the edges of the Kuhn split without building it.
    """
    from ..curvature import absolute_curvature, analytic_absolute_curvature
    from ..selection import rank_candidates
    from ..triangulation import edge_neighbours, kuhn_edge_neighbours, kuhn_tetrahedra, neighbour_graph

    N = data.n_points
    if data.is_grid:
        graph = kuhn_edge_neighbours(data.shape)
        if options.curvature == "local-frame":  # its normals need the tets
            tets = kuhn_tetrahedra(data.shape)
    else:
        graph = edge_neighbours(tets, N)
    graph = neighbour_graph(*graph, shape=data.shape, kind=options.neighbourhood)
    fast = {"grid": True} if data.is_grid and options.curvature == "direct" else {}  # one SVD for the interior
    K = absolute_curvature(data.points, data.values, tets=tets, neighbours=graph, estimator=options.curvature,
                           threads=threads, **fast)
    key = K
    if options.ranking == "ascending":
        key = -K
    elif options.ranking == "random":
        key = np.random.default_rng(options.seed).random(N)
    elif options.ranking == "analytic":
        key = analytic_absolute_curvature(data.meta["function"], data.points)
    order = rank_candidates(key, candidates, tie_order=options.tie_order, points=data.points, seed=options.seed,
                            quantum=options.quantum)
    return K, order


def start(mesh, order):
    """Join the first candidate to every boundary triangle (section 3) and swap.

    A first candidate that is not strictly inside (on a face or edge of the box) is
    inserted into the triangulation of the fixed points instead.  Returns the
    number of candidates inserted (1)."""
    p = order[0]
    ids = mesh.cone(p)
    if len(ids) == 0:
        _, ids = mesh.insert(p)
    mesh.swap(ids)
    return 1


def advance(mesh, order, done, stop, tol_rms, n_fixed):
    """Insert ``order[done:stop]`` with swapping after each (section 4); stops early
    once E_RMS <= ``tol_rms`` (negative: never).  Returns ``(done, inserted)``."""
    new = mesh.run(order, done, stop, tol_rms)
    return new, order[done:new]
