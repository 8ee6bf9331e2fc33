"""Error-driven selection (beyond the paper): Garland & Heckbert (1995) lifted to 3-D.

Every tetrahedron keeps its worst-approximated candidate (largest |f - L|, or with
``greedy_key="sse"`` the worst point of the tetrahedron with the largest sum of
squared residuals) in a priority queue; the method inserts the worst, swaps as the
paper does (section 4), and refreshes only the tetrahedra that changed.  No
curvature is computed: the candidates are chosen as the run goes.
"""

from __future__ import annotations

import numpy as np

from .insertion import check_domain, insertion_protocol

NAME = "greedy"
#: Squared residuals as the swap criterion, boundary 2-2 flips, at most 6 flips per
#: insertion (the trade-off of time against error is in docs/methods.md).
DEFAULTS = {"criterion": "sse", "boundary_flips": True, "max_flips": 6}
GREEDY_QUEUE = True
KERNEL = "greedy"
#: A prescribed boundary (section 3's start from given triangles) is supported.
PRESCRIBED_BOUNDARY = True
#: It inserts points and swaps (the insertion and swap options apply).
INSERTS = True

#: ``run``, ``memory`` and ``compile_kernels``: the top-down run of :mod:`trivsel.methods.insertion`.
run, memory, compile_kernels = insertion_protocol(__name__)


def needs_curvature(options):
    return False


def check(data, options):
    """Every option combination runs (the curvature and ranking options do not apply)."""
    check_domain(NAME, data)


def rank(data, candidates, options, *, tets=None, threads=1):
    """No ranking: the candidates, unordered, and no curvature."""
    return None, candidates


def start(mesh, order):
    """Nothing to do before the first insertion: the queue starts from the fixed points' mesh."""
    return 0


def advance(mesh, order, done, stop, tol_rms, n_fixed):
    """Insert the worst-approximated candidate, swap, repeat, until ``stop`` candidates are
    in, E_RMS <= ``tol_rms`` (negative: never) or no candidate is left.
    Returns ``(done, inserted)``."""
    log = mesh.run_greedy(n_fixed + stop, tol_rms)
    return done + len(log), np.asarray(log, np.int64)
