"""Decimation by half-edge collapses (``method="decimate"``, :mod:`trivsel.decimation`).

Every mesh is checked by the independent checker (positive volumes on integer
coordinates, every face in two tets or on the box, the box's volume filled), and the
residuals are checked against a brute-force evaluation of the interpolant that does
not use the kernel's buckets.
"""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from conftest import examples

import trivsel
from trivsel.blocks import check_tetrahedra
from trivsel.cli import main
from trivsel.data import grid_from_array
from trivsel.decimation import INF, Decimation, grid_tetrahedra, reduce_by_collapse
from trivsel.decimation.collapse import _best, _gather, _gather_points, _locate_star, _planes, _star, _value_moved


def _value_in(P, f, q0, q1, q2, q3, p):
    """``(inside, L)`` of p in the closed tet (q0, q1, q2, q3) by its four orientations with p
    in each slot (exact integers) and the linear interpolant of eq. 13 there."""
    x = [P[q0], P[q1], P[q2], P[q3]]
    lam = [int(_det(*(P[p] if s == r else x[r] for r in range(4)))) for s in range(4)]
    if min(lam) < 0:
        return False, 0.0
    l0, l1, l2, l3 = (float(v) for v in lam)
    return True, (l0 * f[q0] + l1 * f[q1] + l2 * f[q2] + l3 * f[q3]) / (l0 + l1 + l2 + l3)


def _det(a, b, c, d):
    """``det[b - a, c - a, d - a]`` of broadcast integer coordinate arrays (..., 3): exact."""
    u, v, w = b - a, c - a, d - a
    return (u[..., 0] * (v[..., 1] * w[..., 2] - v[..., 2] * w[..., 1])
            - u[..., 1] * (v[..., 0] * w[..., 2] - v[..., 2] * w[..., 0])
            + u[..., 2] * (v[..., 0] * w[..., 1] - v[..., 1] * w[..., 0]))


def brute_force_residuals(ijk, values, tets):
    """f - L at every point, L found by testing every tet (exact integer barycentrics, eq. 13)."""
    P = np.asarray(ijk, np.int64)
    T = np.asarray(tets, np.int64)
    q = P[T][None]  # (1, M, 4, 3)
    x = P[:, None]  # (N, 1, 3)
    lam = np.stack([_det(*(x if s == r else q[:, :, r] for r in range(4))) for s in range(4)], axis=-1)
    inside = np.all(lam >= 0, axis=2)
    assert inside.any(axis=1).all(), f"points {np.flatnonzero(~inside.any(axis=1))} are in no tetrahedron"
    t = np.argmax(inside, axis=1)
    lt = lam[np.arange(len(P)), t]
    return values - (lt * values[T[t]]).sum(1) / lt.sum(1)


# a constant slab over a ramp, a step and noise: zero-cost collapses, ties and real costs
def slab_volume(shape=(6, 7, 5)):
    i, j, k = np.meshgrid(*(np.arange(n) for n in shape), indexing="ij")
    rng = np.random.default_rng(3)
    return np.where(i < 3, 0.0, 0.5 * j + (k > 2) + 0.1 * rng.normal(size=shape))


@pytest.mark.parametrize("shape", [(2, 2, 2), (3, 2, 5), (4, 4, 4)])
def test_the_kuhn_split_fills_the_grid(shape):
    T = grid_tetrahedra(shape)
    assert T.shape == (6 * int(np.prod(np.asarray(shape) - 1)), 4)
    check_tetrahedra(shape, T)


@pytest.mark.parametrize("shape", [(2, 2, 2), (3, 2, 5), (4, 5, 3)])
def test_the_kuhn_split_lists_each_cells_six_paths_in_order(shape):
    """Row 6 c + q is the monotone path of permutation q through cell c (cells in C order),
    its first two corners swapped for an odd permutation; int32 written into ``out`` alike."""
    from itertools import permutations

    nx, ny, nz = shape
    index = lambda i, j, k: (i * ny + j) * nz + k  # noqa: E731
    rows = []
    for i in range(nx - 1):
        for j in range(ny - 1):
            for k in range(nz - 1):
                for perm in permutations(range(3)):
                    path, at = [index(i, j, k)], [i, j, k]
                    for axis in perm:
                        at[axis] += 1
                        path.append(index(*at))
                    odd = sum(perm[x] > perm[y] for x in range(3) for y in range(x + 1, 3)) % 2
                    rows.append([path[1], path[0], path[2], path[3]] if odd else path)
    T = grid_tetrahedra(shape)
    assert T.dtype == np.int64 and np.array_equal(T, rows)
    out = np.full((len(rows), 4), -1, np.int32)
    assert grid_tetrahedra(shape, out=out) is out and np.array_equal(out, rows)
    with pytest.raises(ValueError, match=r"C-contiguous \(%d, 4\)" % len(rows)):
        grid_tetrahedra(shape, out=np.zeros((len(rows) + 1, 4), np.int32))
    with pytest.raises(ValueError, match="at least 2 points per axis"):
        grid_tetrahedra((1, 4, 4))
    with pytest.raises(ValueError, match="int8 cannot index the 216 points"):
        grid_tetrahedra((6, 6, 6), dtype=np.int8)


def test_every_stage_of_a_run_is_a_valid_mesh_with_exact_residuals():
    data = grid_from_array(slab_volume())
    dec = Decimation(data.ijk, data.shape, data.values)
    N = data.n_points
    for count in (150, 60, 25, 9):
        assert dec.run(count) == 0 and dec.n_vertices == count
        T = dec.tetrahedra()
        check_tetrahedra(data.shape, T)
        assert np.array_equal(np.unique(T), dec.vertices())
        r = dec.residuals()
        assert np.allclose(r, brute_force_residuals(data.ijk, data.values, T), atol=1e-12)
        assert np.isclose(dec.sse, np.sum(r * r), rtol=1e-9, atol=1e-12)
        verts, w = dec.point_weights()
        assert np.allclose(data.values - (w * data.values[verts]).sum(1), r, atol=1e-12)
    assert len(dec.removed()) == N - 9


def assert_queue_exact(dec):
    """Every vertex is queued with the cost of the collapse a fresh evaluation finds, or not
    queued if it has none: the queue holds exact costs.  (Targets and their tet counts, the tie
    breakers, may be older: a target's tets change without its source's.)"""
    S = dec.S
    for v in range(S.P.shape[0]):
        if not S.isv[v]:
            assert S.hpos[v] < 0
            continue
        key, w, d, delta = _best(S, v, S.sc, S.G, S.mark, dec.tol_inf)
        assert not S.dirty[v]
        if key == INF:
            assert S.hpos[v] < 0, v
        else:
            assert S.hpos[v] >= 0 and S.hkey[v] == key, v


def brute_force_collapse(ijk, shape, tets, v, w):
    """The tets after moving vertex v onto w (those of edge vw dropped), or None if the move
    breaks the box constraint (w must be on every box face that v is on; corners stay) or
    leaves a tet without positive volume."""
    P = np.asarray(ijk, np.int64)
    on = (P[v] == 0) | (P[v] == np.asarray(shape) - 1)
    if on.all() or np.any(on & (P[w] != P[v])):
        return None
    T = tets[~((tets == v).any(1) & (tets == w).any(1))].copy()
    T[T == v] = w
    q = P[T]
    if np.any(_det(q[:, 0], q[:, 1], q[:, 2], q[:, 3]) <= 0):
        return None
    return T


@pytest.mark.parametrize("key", ["sse", "max"])
def test_queued_costs_are_those_of_a_brute_force_collapse(key):
    """For each queued vertex v, collapse v onto its queued target w in a copy of the tets, and
    evaluate the residuals of every point from scratch in the new mesh: the change of their
    squared sum is the queued change (and the key, for 'sse'); for 'max' the key is the largest
    |residual| of v and its buckets' points.  No other valid collapse of v is cheaper."""
    i, j, k = np.meshgrid(*(np.arange(n) for n in (4, 5, 4)), indexing="ij")
    values = np.where(i < 2, 0.0, 0.5 * j + (k > 1)) + 0.1 * np.random.default_rng(5).normal(size=i.shape)
    data = grid_from_array(values)
    dec = Decimation(data.ijk, data.shape, data.values, key=key)
    dec.run(45)
    S = dec.S
    T = dec.tetrahedra()
    before = brute_force_residuals(data.ijk, data.values, T)
    assert np.isclose(np.sum(before**2), dec.sse)
    checked = 0
    for v in np.flatnonzero(S.hpos >= 0):
        star = np.flatnonzero((S.T == v).any(1) & S.alive)
        moving = np.concatenate([[v], np.flatnonzero(~S.isv & np.isin(S.ptet, star))])

        def cost(w):
            after = brute_force_residuals(data.ijk, data.values, brute_force_collapse(data.ijk, data.shape, T, v, w))
            delta = np.sum(after**2) - np.sum(before**2)
            return (delta if key == "sse" else np.max(np.abs(after[moving]))), delta

        w = S.htgt[v]
        assert brute_force_collapse(data.ijk, data.shape, T, v, w) is not None, (v, w)
        k, delta = cost(w)
        assert np.isclose(S.hkey[v], k, rtol=1e-9, atol=1e-12), (v, w, S.hkey[v], k)
        assert np.isclose(S.hsse[v], delta, rtol=1e-9, atol=1e-12), (v, w, S.hsse[v], delta)
        for u in np.setdiff1d(T[(T == v).any(1)], [v, w]):
            if brute_force_collapse(data.ijk, data.shape, T, v, u) is not None:
                assert cost(u)[0] >= S.hkey[v] - 1e-12, (v, u)
        checked += np.sum(before[moving] ** 2) > 1e-4  # the collapse replaces real residuals
    assert checked >= 20
    assert np.ptp(S.hkey[S.hpos >= 0]) > 0.1  # real costs, not only zero ones


@settings(deadline=None, max_examples=examples(1))
@given(st.integers(0, 2**31), st.integers(0, 3), st.integers(1, 40))
def test_a_point_in_a_moved_tetrahedron_is_weighed_as_by_four_orientations(seed, slot, span):
    """On grid coordinates ``_value_moved`` finds p's weights from the far face's plane and two
    orientations (the last by difference): the same answer, bit for bit, as the four
    orientations of ``_value_in``, inside, outside and on the faces, for any target w."""
    rng = np.random.default_rng(seed)
    P = rng.integers(-span, span + 1, size=(40, 3)).astype(np.int64)
    P[5:] = P[rng.integers(0, 5, size=35)] * rng.integers(0, 2, size=(35, 1)) + rng.integers(-2, 3, size=(35, 3))
    f = rng.normal(size=len(P))
    q = rng.choice(5, size=4, replace=False)  # a tet, vertex v in ``slot``, w a sixth point
    v, w = q[slot], [x for x in range(5) if x not in q][0]
    if _det(*(P[x] for x in q)) < 0:
        q[[0, 1]] = q[[1, 0]]
        slot = {0: 1, 1: 0}.get(slot, slot)
    Q = q[None].astype(np.int64)
    sc = np.array([slot], np.int64)
    moved = [w if s == slot else q[s] for s in range(4)]
    assume(_det(*(P[x] for x in q)) > 0 and _det(*(P[x] for x in moved)) > 0)  # as a valid collapse has them
    assert Q[0, slot] == v
    # on the moved tet, by construction: its centroid, the midpoints of its edges, the centroids of its faces
    P *= 12
    M = P[moved]
    on = [M.sum(0) // 4] + [(M[a] + M[b]) // 2 for a in range(4) for b in range(a + 1, 4)]
    on += [(M.sum(0) - M[a]) // 3 for a in range(4)]
    P = np.concatenate([P, np.array(on)])
    f = np.concatenate([f, rng.normal(size=len(on))])
    G = np.zeros((1, 4), np.int64)
    _planes(P, Q, sc, 1, G)
    seen = 0
    for p in range(len(P)):
        got = _value_moved(P, False, f, Q, G, sc, 0, w, p)
        want = _value_in(P, f, *moved, p)
        assert (got[0] < 0) == want[0] and (not want[0] or got[1] == want[1]), (p, got, want)
        seen += want[0]
    assert seen >= len(on) + 4  # those, and the moved tet's corners
    # another target
    u = next((x for x in range(len(P))
              if x not in q and x != w and _det(*(P[y] if y != v else P[x] for y in q)) > 0), None)
    assume(u is not None)
    at_u = [u if s == slot else q[s] for s in range(4)]
    for p in range(len(P)):
        got, want = _value_moved(P, False, f, Q, G, sc, 0, u, p), _value_in(P, f, *at_u, p)
        assert (got[0] < 0) == want[0] and (not want[0] or got[1] == want[1]), (u, p)


@pytest.mark.parametrize("fraction", [0.5, 0.15])
def test_the_walk_finds_the_tet_a_scan_finds_first(fraction):
    """``_locate_star`` walks from a point's hint across the faces that separate it: for every
    queued vertex v of a half-decimated grid, every valid target w and v and every point of
    its buckets, it returns the star tet that a scan (the hint, then the others in order)
    finds first, and the same value, bit for bit.  Many of these points lie on faces and
    edges of the moved tets, where more than one tet holds them."""
    i, j, k = np.meshgrid(*(np.arange(n) for n in (9, 8, 7)), indexing="ij")
    values = np.sin(0.7 * i) * np.cos(0.5 * j) + 0.2 * k + 0.05 * np.random.default_rng(3).normal(size=i.shape)
    data = grid_from_array(values)
    dec = Decimation(data.ijk, data.shape, data.values)
    dec.run(int(fraction * data.values.size))
    S = dec.S
    sc = np.zeros(256, np.int64)
    Q, G, kw, X = S.Q, S.G, S.kw, S.X
    located = on_boundary = 0
    for v in np.flatnonzero(S.hpos >= 0):
        n = _star(S, v, sc)
        _gather(S, sc, n, Q)
        m, _ = _gather_points(S, sc, n)
        _planes(S.P, Q, sc, n, G)
        for w in np.unique(Q[:n]):
            if w == v or not S.isv[w] or any(S.lock[v] >> a & 1 and S.P[w, a] != S.P[v, a] for a in range(3)):
                continue  # not a vertex, or off a box face that v is on
            kw[:n] = (Q[:n] == w).any(1)
            moved = [[w if Q[t, s] == v else Q[t, s] for s in range(4)] for t in range(n)]
            if any(not kw[t] and _det(*(S.P[x] for x in moved[t])) <= 0 for t in range(n)):
                continue  # not a valid collapse
            X[:n] = -2
            for q in range(-1, m):
                p = v if q < 0 else S.pbuf[q]
                hint = -1 if q < 0 else S.phome[q]
                order = ([hint] if hint >= 0 and not kw[hint] else []) + [t for t in range(n) if t != hint and not kw[t]]
                holds = [t for t in order if _value_moved(S.P, False, S.f, Q, G, sc, t, w, p)[0] < 0]
                got = _locate_star(S.P, False, S.f, Q, G, sc, kw, X, n, w, p, hint)
                assert holds and got[0] == holds[0], (v, w, p, got, holds)
                assert got[1] == _value_moved(S.P, False, S.f, Q, G, sc, holds[0], w, p)[1]
                located += 1
                on_boundary += len(holds) > 1
    assert located > 1000 and on_boundary > 100, (located, on_boundary)


@settings(deadline=None, max_examples=examples(1 / 6))
@given(st.tuples(st.integers(2, 5), st.integers(2, 5), st.integers(2, 5)), st.integers(0, 2**31),
       st.sampled_from(["normal", "integers", "flat"]), st.floats(0.0, 0.9), st.sampled_from(["sse", "max"]),
       st.booleans())
def test_any_grid_and_values_give_a_valid_mesh(shape, seed, kind, keep, key, lazy):
    rng = np.random.default_rng(seed)
    if kind == "normal":
        a = rng.normal(size=shape)
    elif kind == "integers":
        a = rng.integers(0, 3, size=shape).astype(float)
    else:
        a = np.zeros(shape)
    data = grid_from_array(a)
    dec = Decimation(data.ijk, data.shape, data.values, key=key, lazy=lazy)
    dec.run(max(8, int(keep * data.n_points)))
    if lazy:
        dec.lazy = False
        assert_queue_exact(dec)
    T = dec.tetrahedra()
    check_tetrahedra(data.shape, T)
    # the 8 corners never move
    corners = [np.ravel_multi_index(c, shape) for c in np.ndindex(2, 2, 2)
               for c in [tuple(ci * (n - 1) for ci, n in zip(c, shape))]]
    assert set(corners) <= set(dec.vertices().tolist())
    assert np.allclose(dec.residuals(), brute_force_residuals(data.ijk, data.values, T), atol=1e-9)


@pytest.mark.parametrize("shape, lock, key, tol_inf, levels", [
    ((7, 6, 5), "box", "sse", None, 0), ((7, 6, 5), "box", "sse", None, 3), ((6, 6, 6), "all", "max", None, 2),
    ((5, 4, 6), "box", "sse", 0.6, 3), ((3, 3, 3), "box", "max", None, 0), ((2, 5, 4), "box", "sse", None, 2)])
def test_a_fresh_grid_is_queued_from_its_template_as_by_every_vertex_evaluated(shape, lock, key, tol_inf, levels):
    """``init_grid`` (an interior vertex's first evaluation from one template) queues every
    vertex as ``init`` (``_best`` of each) does, bit for bit: keys, changes of the sum,
    targets and the tie rule's degrees.  Values with few levels make many keys tie."""
    from trivsel.decimation import kernels, new_state

    rng = np.random.default_rng(sum(shape) + levels)
    n = int(np.prod(shape))
    values = rng.integers(0, levels, n).astype(float) if levels else rng.normal(size=n)
    ijk = np.indices(shape).reshape(3, -1).T
    tol = -1.0 if tol_inf is None else tol_inf
    a, b = (new_state(ijk, shape, values, lock=lock, key=key) for _ in range(2))
    kernels(a).init(a, tol)
    kernels(b).init_grid(b, tol, *shape)
    for name in ("hkey", "hsse", "htgt", "qkey", "qdeg", "hpos", "hv"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.ctr[2] == b.ctr[2] and a.ctr[2] > 0  # the same number queued, some
    if min(shape) >= 3:  # interior vertices with a valid collapse exist, and the template found them
        interior = np.all((ijk > 0) & (ijk < np.array(shape) - 1), axis=1)
        assert np.isfinite(a.hkey[interior]).any()


@pytest.mark.parametrize("mesh, key, lazy, tol_inf", [
    ("grid", "sse", True, None), ("grid", "sse", False, None), ("grid", "max", True, None),
    ("grid", "sse", True, 0.8), ("scattered", "sse", True, None), ("scattered", "max", False, None)])
def test_a_collapse_from_the_places_its_evaluation_kept_is_the_collapse_located_again(mesh, key, lazy, tol_inf):
    """``_collapse`` takes the tets and residuals that the evaluation just before it kept
    (``State.LT``, ``LR``) instead of locating v and its star's points again: the run is the
    same to the bit as one whose evaluations keep nothing (zero-width ``LT``, ``LR``), and
    many collapses (most, with lazy updates) did follow their own evaluation."""
    from trivsel.decimation import C_KEPT, C_LAST, new_mesh_state, new_state
    from trivsel.decimation.tetmesh import start_mesh

    rng = np.random.default_rng(7)
    if mesh == "grid":
        shape = (11, 10, 9)
        values = (np.sin(np.indices(shape).sum(axis=0) / 3.0) + rng.normal(0, 0.3, shape)).ravel()
        ijk = np.indices(shape).reshape(3, -1).T
        states = [new_state(ijk, shape, values, key=key, lazy=lazy) for _ in range(2)]
    else:
        pts = rng.random((600, 3))
        values = np.sin(4 * pts[:, 0]) * np.cos(3 * pts[:, 1]) + pts[:, 2] ** 2
        t0, located, _ = start_mesh(trivsel.scattered(pts, values))
        states = [new_mesh_state(pts, t0, values, located=located, key=key, lazy=lazy) for _ in range(2)]
    kept, plain = states
    plain = plain._replace(LT=plain.LT[:, :0], LR=plain.LR[:, :0])
    runs = []
    for S in (kept, plain):
        dec = Decimation(None, None, None, tol_inf=tol_inf, key=key, state=S)
        dec.run(len(values) // 8)
        runs.append(dec)
    a, b = runs
    assert len(a.removed()) > len(values) // 2
    assert np.array_equal(a.removed(), b.removed()) and np.array_equal(a.into(), b.into())
    assert np.array_equal(a.tetrahedra(), b.tetrahedra())
    assert np.array_equal(a.residuals(), b.residuals()) and a.sse == b.sse
    assert np.array_equal(a.S.ptet, b.S.ptet)
    assert b.S.ctr[C_LAST] == -1 and b.S.ctr[C_KEPT] == 0  # nothing kept without room
    assert a.S.ctr[C_KEPT] > (0.5 if lazy else 0.02) * len(a.removed())


def assert_heap(S):
    """The queue's slots hold a heap of ``QUEUE_ARITY`` children a slot under the order
    (key, degree, vertex): every entry comes after its parent's, each slot's key and degree
    are its vertex's, and ``hpos`` is the inverse of ``hv``."""
    from trivsel.decimation import C_HN, QUEUE_ARITY

    nh = int(S.ctr[C_HN])
    hv = S.hv[:nh].astype(np.int64)
    assert np.array_equal(S.hpos[hv], np.arange(nh))
    assert (S.hpos >= 0).sum() == nh
    assert np.array_equal(S.qkey[:nh], S.hkey[hv])
    entries = list(zip(S.qkey[:nh].tolist(), S.qdeg[:nh].tolist(), hv.tolist()))
    for i in range(1, nh):
        assert entries[(i - 1) // QUEUE_ARITY] < entries[i], i
    if nh:
        assert entries[0] == min(entries)


@pytest.mark.parametrize("levels, key, lazy", [(0, "sse", False), (2, "sse", True), (3, "max", False), (2, "max", True)])
def test_the_queue_is_a_heap_whose_head_is_the_least_entry(levels, key, lazy):
    """After every run of collapses, lazy or exact, the queue is a heap: the collapse made next
    is the least (key, degree, vertex), whatever the heap's shape.  Values with few levels make
    keys tie, so that the degree and the vertex decide."""
    rng = np.random.default_rng(levels + 11 * lazy)
    shape = (7, 6, 5)
    n = int(np.prod(shape))
    values = rng.integers(0, levels, n).astype(float) if levels else rng.normal(size=n)
    dec = Decimation(np.indices(shape).reshape(3, -1).T, shape, values, key=key, lazy=lazy)
    assert_heap(dec.S)
    for count in range(n - 7, 30, -7):
        dec.run(count)
        assert_heap(dec.S)


def test_lazy_updates_leave_a_valid_mesh_and_an_exact_queue_when_switched_off():
    """With lazy updates a changed vertex keeps its stale cost (marked) until it reaches the head
    of the queue; switching them off re-evaluates every marked vertex, after which the queue is
    the one exact updates would hold for this mesh."""
    data = grid_from_array(slab_volume())
    dec = Decimation(data.ijk, data.shape, data.values, lazy=True)
    assert dec.lazy
    dec.run(120)
    assert dec.S.dirty.any()  # stale costs: lazy updates did skip evaluations
    T = dec.tetrahedra()
    check_tetrahedra(data.shape, T)
    assert np.allclose(dec.residuals(), brute_force_residuals(data.ijk, data.values, T), atol=1e-12)
    dec.lazy = False
    assert not dec.lazy
    assert_queue_exact(dec)
    dec.run(30)
    assert_queue_exact(dec)
    check_tetrahedra(data.shape, dec.tetrahedra())


@pytest.mark.slow
def test_int64_indices_give_the_same_run(monkeypatch):
    """A mesh too large for int32 corner indices runs on int64 ones (a second compilation of
    the kernels): forced here on a small grid, the run is the same to the bit."""
    import trivsel.decimation as dm

    data = grid_from_array(slab_volume())
    runs = []
    for limit in (dm.INT32_CORNERS, 0):
        monkeypatch.setattr(dm, "INT32_CORNERS", limit)
        dec = Decimation(data.ijk, data.shape, data.values, lazy=True)
        assert dec.S.T.dtype == (np.int32 if limit else np.int64)
        dec.run(60)
        dec.lazy = False
        dec.run(12)
        runs.append((dec.removed(), dec.residuals(), dec.tetrahedra(), *dec.point_weights()))
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


def test_a_full_corner_pool_is_compacted_and_the_run_is_the_same(monkeypatch):
    """With no room in the corner pool, the first segment that must grow makes the run compact
    the pool; the run is the same to the bit as with room."""
    import trivsel.decimation as dm

    data = grid_from_array(slab_volume())
    runs = []
    for room in (dm.POOL_ROOM, 1.0):
        monkeypatch.setattr(dm, "POOL_ROOM", room)
        dec = Decimation(data.ijk, data.shape, data.values, lazy=True)
        dec.run(60)
        dec.lazy = False
        dec.run(9)
        check_tetrahedra(data.shape, dec.tetrahedra())
        runs.append((dec.compactions, dec.removed(), dec.residuals(), dec.tetrahedra()))
    assert runs[0][0] == 0 and runs[1][0] >= 1
    for a, b in zip(runs[0][1:], runs[1][1:]):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("room", [None, 1.0])
def test_no_corner_pool_entry_is_read_before_it_is_written(monkeypatch, room):
    """The pool is left as the allocator gives it (zeros, mapped only when used): a pool whose
    every entry holds a corner that is there (tet 0's) before the kernels write it, with room
    and with compactions, gives the run to the bit."""
    import trivsel.decimation as dm

    if room is not None:
        monkeypatch.setattr(dm, "POOL_ROOM", room)
    data = grid_from_array(slab_volume())
    runs = []
    for pool in (dm._pool, lambda size, dtype: np.full(size, 1, dtype)):
        monkeypatch.setattr(dm, "_pool", pool)
        dec = Decimation(data.ijk, data.shape, data.values, lazy=True)
        dec.run(60)
        dec.lazy = False
        dec.run(9)
        runs.append((dec.compactions, dec.removed(), dec.into(), dec.residuals(), dec.tetrahedra()))
    assert (runs[0][0] >= 1) == (room is not None) and runs[0][0] == runs[1][0]
    for a, b in zip(runs[0][1:], runs[1][1:]):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("shape", [(3, 3, 3), (4, 3, 2), (5, 5, 5)])
def test_a_tiny_mesh_with_no_pool_room_runs_to_its_end(monkeypatch, shape):
    """Near the end of a small grid a star is most of the mesh, so a collapse asks for more room
    than the corners take: a compaction gives it, and the run ends as with room."""
    import trivsel.decimation as dm

    values = np.random.default_rng(1).normal(size=shape)
    data = grid_from_array(values)
    ends = []
    for room in (dm.POOL_ROOM, 1.0):
        monkeypatch.setattr(dm, "POOL_ROOM", room)
        dec = Decimation(data.ijk, data.shape, data.values)
        dec.run(8)
        check_tetrahedra(data.shape, dec.tetrahedra())
        ends.append((dec.removed(), dec.tetrahedra(), dec.compactions))
    assert np.array_equal(ends[0][0], ends[1][0]) and np.array_equal(ends[0][1], ends[1][1])
    assert ends[1][2] <= 3


def test_the_strict_queue_is_the_plain_greedy_path():
    """``lazy_queue=False`` collapses in the strict greedy order whatever the stop: the same path
    as exact updates all along, and every snapshot of one run lies on it."""
    data = grid_from_array(slab_volume())
    one = trivsel.reduce(data, count=12, method="decimate", lazy_queue=False)
    r = trivsel.reduce(data, fractions=[0.1, 0.3], count=12, method="decimate", lazy_queue=False)
    assert np.array_equal(r.order, one.order) and r.options["lazy_queue"] is False
    dec = Decimation(data.ijk, data.shape, data.values)
    dec.run(12)
    # the order lists the points kept at 12 (corners excepted) first, then the removed ones
    assert np.array_equal(r.order[-len(dec.removed()):], dec.removed()[::-1])


def test_lazy_updates_stay_exact_near_each_stop():
    """The default schedule: lazy while more than twice the target count of vertices remain,
    exact below.  On a volume with real costs it ends within a few percent of the strict order's
    errors, and a snapshot is as close as a run to that count alone."""
    from trivsel.study.realdata import synthetic

    data = synthetic("chirp", n=20)
    N = data.n_points
    lazy = trivsel.reduce(data, fractions=[0.05, 0.3], method="decimate", values=["data", "fit"])
    strict = trivsel.reduce(data, fractions=[0.05, 0.3], method="decimate", values=["data", "fit"],
                            lazy_queue=False)
    for a, b in zip(lazy.snapshots, strict.snapshots):
        assert a.n_selected == b.n_selected
        check_tetrahedra(data.shape, a.tets)
        assert a.errors["E_rms"] <= 1.05 * b.errors["E_rms"]
        assert a.fit["errors"]["E_rms"] <= 1.05 * b.fit["errors"]["E_rms"]
    # a run lazy all the way to the target (exact_within=1) is worse: the schedule matters
    all_lazy = reduce_by_collapse(data, [round(0.05 * N)], exact_within=1.0)[0][-1]
    assert all_lazy.errors["E_rms"] > 1.05 * strict.snapshots[0].errors["E_rms"]


def test_a_linear_volume_decimates_to_its_corners_with_no_error():
    i, j, k = np.meshgrid(np.arange(6), np.arange(5), np.arange(4), indexing="ij")
    data = grid_from_array(1.5 * i - 2.0 * j + 0.25 * k + 3.0)
    for lazy in (False, True):
        s = trivsel.reduce(data, count=8, method="decimate", lazy_queue=lazy).snapshots[-1]
        assert s.errors["E_inf"] < 1e-12
        check_tetrahedra(data.shape, s.tets)
        # a half-edge collapse cannot remove an interior vertex whose star is the whole box (its
        # target's box faces would flatten tets), so reaching the 8 corners depends on the path;
        # the strict order gets there; the lazy one may stop one interior vertex short (it does here)
        assert s.n_selected <= 9 if lazy else s.n_selected == 8


def test_reduce_snapshots_prefix_and_fit():
    data = grid_from_array(slab_volume())
    N = data.n_points
    r = trivsel.reduce(data, fractions=[0.1, 0.3], count=40, method="decimate", values=["data", "fit"])
    counts = [s.n_selected for s in r.snapshots]
    assert counts == sorted(counts) and counts[0] == round(0.1 * N)
    for s in r.snapshots:
        check_tetrahedra(data.shape, s.tets)
        assert set(s.selected.tolist()) == set(np.unique(s.tets).tolist())
        assert np.array_equal(s.selected, r.selected[: s.n_selected])
        assert s.fit["errors"]["E_rms"] <= s.errors["E_rms"] * (1 + 1e-12)
    assert r.curvature is None and len(r.order) == N - 8
    # the same run again: identical
    r2 = trivsel.reduce(data, fractions=[0.1, 0.3], count=40, method="decimate")
    for a, b in zip(r.snapshots, r2.snapshots):
        assert np.array_equal(a.tets, b.tets) and np.array_equal(a.residuals, b.residuals)


def test_a_spacing_changes_nothing_but_the_coordinates():
    a = slab_volume()
    r1 = trivsel.reduce(grid_from_array(a), fractions=[0.2], method="decimate")
    r2 = trivsel.reduce(grid_from_array(a, origin=(5.0, -1.0, 2.0), spacing=(4.0, 4.0, 5.0)), fractions=[0.2],
                        method="decimate")
    s1, s2 = r1.snapshots[-1], r2.snapshots[-1]
    assert np.array_equal(s1.tets, s2.tets) and np.allclose(s1.residuals, s2.residuals)


@pytest.mark.parametrize("exact_within", [np.inf, 1.0])
def test_tolerances_stop_at_the_last_collapse_within_them(exact_within):
    """Stops are decided on exact costs: a run with lazy updates up to the tolerance
    (``exact_within=1``) switches to exact updates when it would stop, and goes on if it can."""
    data = grid_from_array(slab_volume())
    N, tol, seen = data.n_points, 0.05, []
    s = reduce_by_collapse(data, [8], tol_rms=tol, exact_within=exact_within, check=seen.append)[0][-1]
    assert s.errors["E_rms"] <= tol
    dec = seen[-1]
    assert not dec.lazy
    assert_queue_exact(dec)
    # the next collapse in the exact order would go above the tolerance
    assert dec.sse + dec.S.hsse[dec.S.hv[0]] > tol**2 * N
    if exact_within == np.inf:
        # the strict path does not depend on the stop: one more collapse goes above
        assert trivsel.reduce(data, tol_rms=tol, method="decimate", lazy_queue=False).snapshots[-1].n_selected \
            == s.n_selected
        nxt = trivsel.reduce(data, count=s.n_selected - 1, method="decimate", lazy_queue=False).snapshots[-1]
        assert nxt.errors["E_rms"] > tol
    r = trivsel.reduce(data, tol_inf=0.2, method="decimate")
    s = r.snapshots[-1]
    assert np.abs(s.residuals).max() <= 0.2 and s.n_selected < data.n_points // 2
    check_tetrahedra(data.shape, s.tets)


@pytest.mark.parametrize("stop", [{"tol_inf": 0.05}, {"tol_rms": 0.01}, {"count": 100}])
def test_identical_runs_decide_alike_however_the_chunks_are_timed(monkeypatch, stop):
    """A run is cut into timed calls of the compiled loop (Ctrl-C stays prompt).  Whether to
    update the queue lazily is decided at fixed counts, not where a call ended: calls of the
    smallest and of growing lengths give the same mesh (f5 to E_inf 0.05 kept 68 or 63 points
    when the decision followed the calls)."""
    import trivsel.decimation as dm

    data = trivsel.sample_grid(5, 16)
    runs = []
    for seconds in (1e-12, 1e12):
        monkeypatch.setattr(dm, "CHUNK_SECONDS", seconds)
        monkeypatch.setattr(dm, "DECIDE_EVERY", 64)
        runs.append(trivsel.reduce(data, method="decimate", **stop).snapshots[-1])
    assert runs[0].n_selected == runs[1].n_selected
    assert np.array_equal(runs[0].tets, runs[1].tets)


def test_the_queue_is_released_before_the_last_fit():
    """After the last snapshot the queue, corner pool and scratch arrays are freed before the
    fit (their memory does not add to the fit's), and the results are those of a run that keeps
    them (a check callback keeps them)."""
    import trivsel.decimation as dm

    data = trivsel.sample_grid(4, 12)
    kept = []
    snaps = dm.reduce_by_collapse(data, [400, 100], values=("data", "fit"))[0]
    same = dm.reduce_by_collapse(data, [400, 100], values=("data", "fit"), check=kept.append)[0]
    for a, b in zip(snaps, same):
        assert np.array_equal(a.tets, b.tets) and np.array_equal(a.fit["values"], b.fit["values"])
    assert all(len(getattr(kept[-1].S, k)) > 0 for k in dm.Decimation.QUEUE_FIELDS)
    dec = dm.Decimation(data.ijk, data.shape, data.values)
    dec.run(100)
    dec.release_queue()
    assert all(len(getattr(dec.S, k)) == 0 for k in dm.Decimation.QUEUE_FIELDS)
    assert dec.tetrahedra().shape[0] > 0 and len(dec.vertices()) == 100
    dec.point_weights()
    with pytest.raises(RuntimeError, match="released"):
        dec.run(50)


def test_a_run_of_many_short_calls_ends(monkeypatch):
    """Calls cut short at every decision count (here every vertex) keep their length bounded:
    a million-point run made about a thousand of them, and the length, grown 4-fold each
    time, overflowed a float."""
    import trivsel.decimation as dm

    monkeypatch.setattr(dm, "DECIDE_EVERY", 1)
    monkeypatch.setattr(dm, "CHUNK_SECONDS", 1e12)
    s = trivsel.reduce(trivsel.sample_grid(4, 10), method="decimate", tol_inf=0.05).snapshots[-1]
    assert np.abs(s.residuals).max() <= 0.05


def test_the_max_criterion_aims_at_e_inf():
    """criterion="max" takes the collapse that leaves the smallest largest residual first: on a
    noisy volume its E_inf is lower than the squared-error order's, its E_RMS higher."""
    rng = np.random.default_rng(5)
    i, j, k = np.meshgrid(*(np.arange(n) for n in (12, 11, 10)), indexing="ij")
    data = grid_from_array(np.sin(i / 3.0) * np.cos(j / 4.0) + 0.2 * k + rng.normal(0, 0.05, i.shape))
    s_sse = trivsel.reduce(data, fractions=[0.1], method="decimate").snapshots[-1]
    s_max = trivsel.reduce(data, fractions=[0.1], method="decimate", criterion="max").snapshots[-1]
    check_tetrahedra(data.shape, s_max.tets)
    assert s_max.errors["E_inf"] < s_sse.errors["E_inf"] and s_max.errors["E_rms"] > s_sse.errors["E_rms"]
    with pytest.raises(trivsel.InputError, match="'rms'"):
        trivsel.reduce(data, fractions=[0.1], method="decimate", criterion="rms")


def test_interior_candidates_keep_every_box_point():
    data = grid_from_array(slab_volume())
    r = trivsel.reduce(data, count=170, method="decimate", candidates="interior")
    s = r.snapshots[-1]
    boundary = np.flatnonzero(~data.interior_mask())
    assert set(boundary.tolist()) <= set(s.selected.tolist())
    check_tetrahedra(data.shape, s.tets)


@pytest.mark.parametrize("call, message", [
    (lambda: trivsel.reduce(trivsel.scattered(np.random.default_rng(1).random((50, 3)), np.zeros(50)), count=3,
                            method="decimate"), "fewer than the 4 points"),
    (lambda: trivsel.reduce(4, n=4, count=7, method="decimate"), "fewer than the 8 points"),
    (lambda: trivsel.reduce(4, n=4, count=20, method="decimate",
                            boundary=np.array([[0, 1, 2]])), "prescribed boundary"),
])
def test_bad_requests_give_one_line(call, message):
    with pytest.raises(trivsel.InputError, match=message) as exc:
        call()
    assert "\n" not in str(exc.value)


def test_command_line(tmp_path):
    out = tmp_path / "out"
    assert main(["reduce", "--function", "4", "--n", "6", "--method", "decimate", "--fractions", "0.2",
                 "--values", "data", "fit", "--out", str(out)]) == 0
    text = (out / "errors.csv").read_text()
    assert "decimate" in text and "fit" in text


def test_a_replay_of_the_recorded_collapses_gives_the_same_mesh():
    """``Decimation.replay`` makes the collapses a run recorded (``removed``, ``into``) with no
    cost or queue: the same tetrahedra, buckets and residuals, also across corner-pool compactions."""
    from trivsel.data import sample_grid
    from trivsel.decimation import Decimation, new_state

    d = sample_grid(4, 20)
    a = Decimation(d.ijk, d.shape, d.values, lazy=True)
    a.run(600)
    S = new_state(d.ijk, d.shape, d.values, lazy=True)
    S = S._replace(cpool=S.cpool[:int(S.vcap.sum())])  # no room above the segments: the replay compacts
    b = Decimation(None, None, None, state=S, queue=False)
    b.replay(a.removed(), a.into())
    assert np.array_equal(a.tetrahedra(), b.tetrahedra()) and np.array_equal(a.S.ptet, b.S.ptet)
    assert np.array_equal(a.residuals(), b.residuals()) and b.n_vertices == 600
    assert np.array_equal(b.removed(), a.removed()) and np.array_equal(b.into(), a.into())
    assert b.compactions > 0


def test_blocks_hold_their_indices_in_int32_with_the_meshes_of_int64(monkeypatch):
    """The passes' whole-grid arrays (tetrahedra, each point's tetrahedron, region ids) are int32
    while the indices fit (``index_type``) and give the meshes that int64 gives."""
    from trivsel.data import sample_grid
    from trivsel.decimation import blocked

    assert blocked.index_type(2**31 - 1) is np.int32 and blocked.index_type(2**31) is np.int64
    d = sample_grid(4, 32)
    vol = d.values.reshape(d.shape)
    small = blocked.decimate_in_blocks(vol, 12, fraction=0.05)
    assert small["tets"].dtype == np.int32 and small["ptet"].dtype == np.int32
    monkeypatch.setattr(blocked, "index_type", lambda n: np.int64)
    wide = blocked.decimate_in_blocks(vol, 12, fraction=0.05)
    assert wide["tets"].dtype == np.int64 and wide["ptet"].dtype == np.int64
    assert np.array_equal(small["tets"], wide["tets"]) and np.array_equal(small["ptet"], wide["ptet"])
    assert np.array_equal(small["vertices"], wide["vertices"])
