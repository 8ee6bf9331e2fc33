"""The Python face of the mesh kernel: :class:`TetMesh` and :class:`MeshError`."""

from __future__ import annotations

import functools
import types

import numpy as np

from .entries import kernels
from .state import (A_SSE, C_ABOVE, C_CASE1, C_CASE2, C_CASE3, C_ERROR, C_EVALS, C_FLIP22, C_FLIP23, C_FLIP32, C_FLIP44,
                    C_HW, C_MEMHITS, C_NVERT, C_ROUNDCAP, ERROR_MESSAGES, copy_state, make_state)


@functools.lru_cache(maxsize=None)
def _nb():
    """The numba kernels of the step-by-step operations (flips, evaluations, the greedy
    queue), which a reduction does not call: imported, with numba, on first use."""
    from .compile import pin_signatures
    from .criteria import _evaluate, criterion_sum
    from .drivers import run_insertions
    from .flips import config23, edge_ring, edge_ring_open, quads32, quads44
    from .geometry import _orient, _positive
    from .greedy import greedy_next, run_greedy
    from .heap import _heap_rebuild
    from .storage import _replace

    return types.SimpleNamespace(**locals())


class MeshError(RuntimeError):
    """An internal failure of the mesh kernel (capacity or consistency); ``code`` is an ``ERR_*`` code."""

    def __init__(self, code, message):
        super().__init__(message)
        self.code = code


def face_neighbours(tets):
    """Face-neighbour links of a list of tets (numpy; for an initial mesh)."""
    tets = np.asarray(tets, np.int64)
    M = tets.shape[0]
    faces = np.concatenate([np.sort(np.delete(tets, i, axis=1), axis=1) for i in range(4)])
    owner = np.tile(np.arange(M), 4)
    local = np.repeat(np.arange(4), M)
    order = np.lexsort(faces.T[::-1])
    f = faces[order]
    same = np.all(f[1:] == f[:-1], axis=1)
    nbr = np.full((M, 4), -1, np.int64)
    i = np.flatnonzero(same)
    a, b = order[i], order[i + 1]
    nbr[owner[a], local[a]] = owner[b]
    nbr[owner[b], local[b]] = owner[a]
    return nbr


class TetMesh:
    """A mesh over original points, with the named operations of section 4.

    Parameters are those of :func:`~trivsel.mesh.state.make_state` (``criterion``,
    ``vertices_in_error``, ``rel_tol``, ``abs_tol``, ``tol_inf``, ``first_improving``,
    ``max_rounds``, ``tet_capacity``, ``pool_capacity``, ``greedy``, ``greedy_key``,
    ``candidates``, ``boundary_flips``, ``swap_memory``).  ``start(tets)`` installs an
    initial triangulation (e.g. of the fixed points).  The state ``S`` is a
    :class:`~trivsel.mesh.state.MeshState`.
    """

    def __init__(self, points, values, ijk=None, **options):
        self.S = make_state(points, values, ijk, pin=False, **options)
        self.options = options
        # the kernels a reduction calls: ahead of time or numba's own (trivsel.mesh.entries)
        self._k = kernels(self.S)

    def _jit(self):
        """The state, after pinning the helpers that the other (numba) kernels call."""
        _nb().pin_signatures(self.S)
        return self.S

    # -- state views
    @property
    def counters(self):
        """The int64 counters (indexed by the ``C_*`` constants of :mod:`trivsel.mesh.state`)."""
        return self.S.ctr

    @property
    def resid(self):
        """The residual f - L of every original point (a view, updated as the mesh changes)."""
        return self.S.resid

    @property
    def n_above_tol_inf(self):
        """How many points have a residual above the option ``tol_inf`` (when it is set)."""
        return int(self.S.ctr[C_ABOVE])

    @property
    def sse_sum(self):
        """The global sum of squared residuals, kept up to date by every change."""
        return float(self.S.acc[A_SSE])

    @property
    def round_cap_hits(self):
        """Swap calls stopped by ``max_rounds`` rather than because nothing improved."""
        return int(self.S.ctr[C_ROUNDCAP])

    @property
    def error_code(self):
        """The kernel's error code (an ``ERR_*`` constant), 0 if none."""
        return int(self.S.ctr[C_ERROR])

    def _raise_on_error(self):
        code = self.error_code
        if code:
            raise MeshError(code, ERROR_MESSAGES.get(code, f"error {code}"))

    def live_ids(self):
        """The ids of the live tets, ascending."""
        hw = self.S.ctr[C_HW]
        return np.flatnonzero(self.S.alive[:hw])

    def tetrahedra(self):
        """The live tets as an (M, 4) array of original point indices."""
        return self.S.tets[self.live_ids()].astype(np.int64)

    def bucket(self, t):
        """The original points in the closed tet t (a copy of its bucket)."""
        s, L = self.S.bstart[t], self.S.blen[t]
        return self.S.pool[s:s + L].copy()

    def vertices(self):
        """The selected points (the vertices of the mesh), ascending."""
        return np.flatnonzero(self.S.isvert)

    # -- operations
    def start(self, tets):
        """Install an initial triangulation (positively oriented tets) and fill its buckets."""
        tets = np.asarray(tets, np.int64)
        nbr = face_neighbours(tets)
        ids = np.array([self._k._alloc(self.S) for _ in range(len(tets))], np.int64)
        self._raise_on_error()
        self.S.tets[ids] = tets
        self.S.nbr[ids] = np.where(nbr >= 0, ids[np.maximum(nbr, 0)], -1)
        verts = np.unique(tets)
        self.S.isvert[verts] = 1
        self.S.ctr[C_NVERT] = len(verts)
        self._k.fill_buckets(self.S, ids)
        self._raise_on_error()
        return ids

    def insert(self, p):
        """Insert point p (cases i-iii); returns (case 1/2/3, new tet ids)."""
        case, ids = self._k.insert_point(self.S, int(p))
        self._raise_on_error()
        return case, ids

    def cone(self, p):
        """Join p to every hull face (the first insertion); empty if p is not strictly inside."""
        ids = self._k.cone_from_hull(self.S, int(p))
        self._raise_on_error()
        return ids

    def swap(self, ids, with_neighbours=True):
        """Data-dependent swapping from the tets ``ids`` (and their neighbours); returns the flips made."""
        ids = np.ascontiguousarray(ids, np.int64)
        n = self._k.swap(self.S, ids, len(ids), bool(with_neighbours), self.S.opt.max_rounds)
        self._raise_on_error()
        return n

    def global_pass(self):
        """The final swap over all tets, until nothing improves; returns the flips made."""
        n = self._k.global_pass(self.S)
        self._raise_on_error()
        return n

    def flip23(self, t, i, force=False):
        """Apply the 2-3 flip of tet t over its face i if admissible (and improving unless force)."""
        old = np.empty(4, np.int64)
        newq = np.empty((4, 4), np.int64)
        if not _nb().config23(self._jit(), int(t), int(i), old, newq) or not _nb()._positive(self.S, newq, 3):
            return None
        return self._apply(old, 2, newq, 3, force)

    def flip_edge(self, t, a, b, alt=0, force=False):
        """Apply the 3-2 (degree-3 edge) or 4-4 (degree-4 edge, diagonal alt) flip of edge (a, b)."""
        old = np.empty(4, np.int64)
        ring = np.empty(4, np.int64)
        newq = np.empty((4, 4), np.int64)
        k = _nb().edge_ring(self._jit(), int(t), int(a), int(b), old, ring)
        if k == 3:
            _nb().quads32(int(a), int(b), ring, newq)
            nn = 2
        elif k == 4:
            _nb().quads44(int(a), int(b), ring, int(alt), newq)
            nn = 4
        else:
            return None
        if not _nb()._positive(self.S, newq, nn):
            return None
        return self._apply(old, k, newq, nn, force)

    def flip22(self, t, a, b, force=False):
        """Apply the boundary 2-2 flip of hull edge (a, b) if admissible (and improving unless force)."""
        old = np.empty(2, np.int64)
        ring = np.empty(5, np.int64)
        newq = np.empty((4, 4), np.int64)
        k = _nb().edge_ring_open(self._jit(), int(t), int(a), int(b), old, ring)
        if k != 2 or _nb()._orient(self.S, int(a), int(b), int(ring[0]), int(ring[2])) != 0:
            return None
        _nb().quads32(int(a), int(b), ring, newq)
        if not _nb()._positive(self.S, newq, 2):
            return None
        return self._apply(old, 2, newq, 2, force, new_hull=True)

    def evaluate(self, old, newq):
        """The criterion sums (before, after) of replacing the tets ``old`` by the quadruples ``newq``."""
        old = np.ascontiguousarray(old, np.int64)
        newq = np.ascontiguousarray(newq, np.int64)
        return _nb()._evaluate(self._jit(), old, len(old), newq, len(newq), 0.0, -np.inf)

    def _apply(self, old, nold, newq, nn, force, new_hull=False):
        """Replace old by newq if the criterion sum decreases (or if ``force``); the new ids or None."""
        if not force:
            before, after = _nb()._evaluate(self._jit(), old, nold, newq, nn, 0.0, -np.inf)
            if not after < before:
                return None
        ids = _nb()._replace(self._jit(), old, nold, newq, nn, new_hull)
        self._raise_on_error()
        return ids

    def run(self, order, start, stop, tol_rms=-1.0):
        """Insert ``order[start:stop]``, each followed by swapping; returns the position reached."""
        k = self._driver("run_insertions")(self.S, np.ascontiguousarray(order, np.int64), int(start), int(stop),
                                           float(tol_rms), float(self.S.values.shape[0]))
        self._raise_on_error()
        return int(k)

    def _driver(self, name):
        """A method's driver: the other method's is not in this mesh's extension module."""
        fn = getattr(self._k, name, None)
        if fn is None:
            self._jit()
            fn = getattr(_nb(), name)
        return fn

    def greedy_next(self):
        """The next greedy candidate (largest residual), without inserting it; -1 if none."""
        p = _nb().greedy_next(self._jit())
        _nb()._heap_rebuild(self.S)  # put the popped entry back
        return int(p)

    def run_greedy(self, stop_nvert, tol_rms=-1.0):
        log = np.empty(max(int(stop_nvert) - int(self.S.ctr[C_NVERT]), 0) + 1, np.int64)
        k = self._driver("run_greedy")(self.S, int(stop_nvert), float(tol_rms), float(self.S.values.shape[0]), log)
        self._raise_on_error()
        return log[:k].copy()

    def point_weights(self):
        """(N, 4) vertices and barycentric weights of a tet containing each original point."""
        N = self.S.values.shape[0]
        verts = np.empty((N, 4), np.int64)
        w = np.empty((N, 4))
        self._k.point_weights(self.S, verts, w)
        return verts, w

    def residuals(self):
        """Residuals f - L at all original points, and the continuity defect."""
        out = np.zeros(self.S.values.shape[0])
        worst = self._k.residuals(self.S, out)
        return out, worst

    def copy(self):
        """An independent copy of the mesh."""
        other = TetMesh.__new__(TetMesh)
        other.S = copy_state(self.S)
        other.options = dict(self.options)
        other._k = self._k
        return other

    def criterion_sum(self):
        """The quantity the swaps lower (see :func:`trivsel.mesh.criteria.criterion_sum`)."""
        ids = self.live_ids()
        return _nb().criterion_sum(self.S.opt.criterion, self.S.tsse[ids], self.S.tmax[ids], self.S.tcnt[ids],
                             self.S.resid)

    @property
    def flips(self):
        """Flips made so far, by configuration ("2-2" only with ``boundary_flips``)."""
        c = self.S.ctr
        out = {"2-3": int(c[C_FLIP23]), "3-2": int(c[C_FLIP32]), "4-4": int(c[C_FLIP44])}
        if self.S.opt.boundary_flips:
            out["2-2"] = int(c[C_FLIP22])
        return out

    @property
    def evaluations(self):
        """Configurations :func:`~trivsel.mesh.swap.swap` evaluated (``made``) and found in its memory
        (``remembered``) so far."""
        c = self.S.ctr
        return {"made": int(c[C_EVALS]), "remembered": int(c[C_MEMHITS])}

    @property
    def cases(self):
        """Insertions so far, by case of section 4: in a tet, on a face, on an edge."""
        c = self.S.ctr
        return {"tet": int(c[C_CASE1]), "face": int(c[C_CASE2]), "edge": int(c[C_CASE3])}
