"""The mesh kernel (section 4): insertion cases i-iii, flips, swapping, validity after every operation."""

import json
from pathlib import Path

import numpy as np
import pytest

from trivsel.mesh import MeshInvalid, TetMesh, check_mesh
from trivsel.mesh.geometry import _orient
from trivsel.triangulation import box_tetrahedra, delaunay_tetrahedra, hull_triangles, orient3d_float

FIXTURES = Path(__file__).parent / "fixtures"


def _mesh(points, tets, values=None, exact=True, hull_volume=None, **opt):
    points = np.asarray(points, float)
    if values is None:
        values = points[:, 0] ** 2 + 0.5 * points[:, 1] * points[:, 2]
    ijk = np.asarray(points, np.int64) if exact else None
    tm = TetMesh(points, values, ijk, **opt)
    tm.start(np.asarray(tets))
    check_mesh(tm, hull_volume=hull_volume)
    return tm


def _volume(tm):
    return orient3d_float(tm.S.points, tm.tetrahedra()).sum() / 6


# A positively oriented tet and points placed in its interior, on a face, on an edge.
TET = [[0, 0, 0], [6, 0, 0], [0, 6, 0], [0, 0, 6]]


@pytest.mark.parametrize("exact", [True, False])
def test_case_i_interior_point_splits_one_into_four(exact):
    tm = _mesh(TET + [[1, 1, 1]], [[0, 1, 2, 3]], exact=exact)
    case, ids = tm.insert(4)
    assert case == 1 and len(ids) == 4
    check_mesh(tm)
    assert _volume(tm) == pytest.approx(36.0)


@pytest.mark.parametrize("exact", [True, False])
def test_case_ii_point_on_hull_face_splits_into_three(exact):
    tm = _mesh(TET + [[2, 2, 0]], [[0, 1, 2, 3]], exact=exact)  # on face z = 0
    case, ids = tm.insert(4)
    assert case == 2 and len(ids) == 3
    check_mesh(tm)


@pytest.mark.parametrize("exact", [True, False])
def test_case_ii_point_on_shared_face_splits_both_tets(exact):
    # two tets sharing face (1, 2, 3); the point lies inside that face
    pts = TET + [[6, 6, 6], [2, 2, 2]]
    tets = [[0, 1, 2, 3], [4, 1, 3, 2]]
    tm = _mesh(pts, tets, exact=exact)
    case, ids = tm.insert(5)
    assert case == 2 and len(ids) == 6
    check_mesh(tm)
    assert _volume(tm) == pytest.approx(36.0 + 36.0 * 2)


@pytest.mark.parametrize("exact", [True, False])
def test_case_iii_point_on_hull_edge_splits_into_two(exact):
    tm = _mesh(TET + [[3, 0, 0]], [[0, 1, 2, 3]], exact=exact)
    case, ids = tm.insert(4)
    assert case == 3 and len(ids) == 2
    check_mesh(tm)


def _octahedron():
    # poles a = 0 (top), b = 1 (bottom); equator 2..5; four tets around the axis a-b
    pts = [[0, 0, 2], [0, 0, -2], [2, 0, 0], [0, 2, 0], [-2, 0, 0], [0, -2, 0]]
    tets = []
    for k in range(4):
        c, d = 2 + k, 2 + (k + 1) % 4
        t = [0, 1, c, d]
        if orient3d_float(np.array(pts, float), np.array([t]))[0] < 0:
            t = [0, 1, d, c]
        tets.append(t)
    return pts, tets


@pytest.mark.parametrize("exact", [True, False])
def test_case_iii_point_on_interior_edge_splits_the_whole_ring(exact):
    pts, tets = _octahedron()
    tm = _mesh(pts + [[0, 0, 1]], tets, exact=exact)
    case, ids = tm.insert(6)
    assert case == 3 and len(ids) == 8
    check_mesh(tm)


@pytest.mark.parametrize("exact", [True, False])
def test_flip44_to_either_diagonal_and_back(exact):
    pts, tets = _octahedron()
    tm = _mesh(pts, tets, exact=exact)
    vol = _volume(tm)
    t = tm.live_ids()[0]
    for alt, diag in ((0, None), (1, None)):
        tm2 = tm.copy()
        ids = tm2.flip_edge(t, 0, 1, alt=alt, force=True)
        assert ids is not None and len(ids) == 4
        check_mesh(tm2)
        assert _volume(tm2) == pytest.approx(vol)
        edges = {tuple(sorted((a, b))) for tet in tm2.tetrahedra() for a in tet for b in tet if a != b}
        assert (0, 1) not in edges
        # and back: the new diagonal has degree 4 again
        new_diag = [e for e in [(2, 4), (3, 5)] if e in edges]
        assert len(new_diag) == 1
        a, b = new_diag[0]
        t2 = next(x for x in tm2.live_ids() if a in tm2.S.tets[x] and b in tm2.S.tets[x])
        assert tm2.flip_edge(t2, a, b, alt=0, force=True) is not None
        check_mesh(tm2)


@pytest.mark.parametrize("exact", [True, False])
def test_flip23_then_flip32_restores_the_pair(exact):
    # d above and e below a triangle; segment d-e pierces it: 2-3 admissible
    pts = [[0, 0, 0], [6, 0, 0], [0, 6, 0], [1, 1, 4], [2, 2, -4]]
    tets = [[0, 1, 2, 3], [0, 2, 1, 4]]
    tm = _mesh(pts, tets, exact=exact)
    vol = _volume(tm)
    t = tm.live_ids()[0]
    i = int(np.flatnonzero(tm.S.tets[t] == 3)[0])  # face opposite d
    ids = tm.flip23(t, i, force=True)
    assert ids is not None and len(ids) == 3
    check_mesh(tm)
    assert _volume(tm) == pytest.approx(vol)
    t3 = ids[0]
    ids2 = tm.flip_edge(t3, 3, 4, force=True)  # edge d-e has degree 3
    assert ids2 is not None and len(ids2) == 2
    check_mesh(tm)
    assert sorted(map(sorted, tm.tetrahedra().tolist())) == sorted(map(sorted, tets))


@pytest.mark.parametrize("exact", [True, False])
def test_flip23_not_admissible_when_segment_misses_the_face(exact):
    pts = [[0, 0, 0], [6, 0, 0], [0, 6, 0], [1, 1, 4], [9, 9, -4]]
    tets = [[0, 1, 2, 3], [0, 2, 1, 4]]
    tm = _mesh(pts, tets, exact=exact, hull_volume=48.0)  # the pair's union is not convex
    t = tm.live_ids()[0]
    i = int(np.flatnonzero(tm.S.tets[t] == 3)[0])
    assert tm.flip23(t, i, force=True) is None
    check_mesh(tm, hull_volume=48.0)


@pytest.mark.parametrize("exact", [True, False])
def test_boundary_flip22_between_coplanar_hull_faces(exact):
    # square base in z = 0 split along p0-p2, apex above: the hull edge p0-p2 has two
    # coplanar hull faces and two tets around it; the 2-2 flip moves it to p1-p3
    pts = [[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0], [1, 1, 4]]
    tets = [[0, 1, 2, 4], [0, 2, 3, 4]]
    tm = _mesh(pts, tets, exact=exact)
    t = tm.live_ids()[0]
    assert tm.flip22(t, 1, 4, force=True) is None  # not a coplanar pair: (1, 4) is a hull edge of one tet
    ids = tm.flip22(t, 0, 2, force=True)
    assert ids is not None and len(ids) == 2
    check_mesh(tm)
    edges = {tuple(sorted((a, b))) for tet in tm.tetrahedra() for a in tet for b in tet if a != b}
    assert (1, 3) in edges and (0, 2) not in edges
    t2 = tm.live_ids()[0]
    assert tm.flip22(t2, 1, 3, force=True) is not None  # and back
    check_mesh(tm)
    assert sorted(map(sorted, tm.tetrahedra().tolist())) == sorted(map(sorted, tets))


def test_flip_is_applied_only_when_it_lowers_the_evaluated_sum():
    pts = [[0, 0, 0], [6, 0, 0], [0, 6, 0], [1, 1, 4], [2, 2, -4], [1, 1, 0], [2, 1, 1]]
    vals = np.array([0, 0, 0, 0, 0, 1.0, 0.3])
    tets = delaunay_tetrahedra(np.array(pts, float))
    tm = _mesh(pts, tets, values=vals)
    for t in tm.live_ids():
        for i in range(4):
            tm2 = tm.copy()
            before = tm2.criterion_sum()
            ids = tm2.flip23(t, i)
            if ids is not None:
                check_mesh(tm2)
                assert tm2.criterion_sum() < before


def test_checker_detects_a_broken_link():
    pts, tets = _octahedron()
    tm = _mesh(pts, tets)
    t = tm.live_ids()[0]
    tm.S.nbr[t, 2] = -1  # break a neighbour link
    with pytest.raises(MeshInvalid):
        check_mesh(tm)


@pytest.mark.parametrize("exact", [True, False])
def test_checker_detects_an_inverted_tet(exact):
    pts, tets = _octahedron()
    tm = _mesh(pts, tets, exact=exact)
    t = tm.live_ids()[1]
    tm.S.tets[t, [0, 1]] = tm.S.tets[t, [1, 0]]
    with pytest.raises(MeshInvalid, match=rf"tet {t} \[.*\] is not positively oriented"):
        check_mesh(tm)


@pytest.mark.parametrize("exact", [True, False])
def test_checker_detects_an_overlapping_tet(exact):
    """One tet's vertex replaced by another point so that the tet stays positively oriented
    but covers part of its neighbours: the mesh no longer tiles the hull."""
    from itertools import product

    from trivsel.decimation import grid_tetrahedra
    from trivsel.mesh.validation import orientation_signs

    pts = np.array(list(np.ndindex(3, 3, 3)), float)
    tm = _mesh(pts, grid_tetrahedra((3, 3, 3)), exact=exact)
    T = tm.S.tets
    ids = tm.live_ids()
    faces = {frozenset(T[t].tolist()) for t in ids}
    for t, s, p in product(ids, range(4), range(len(pts))):
        q = T[t].copy()
        q[s] = p
        if p not in T[t] and frozenset(q.tolist()) not in faces and orientation_signs(pts, q[None])[0] > 0:
            break
    T[t] = q
    with pytest.raises(MeshInvalid) as info:
        check_mesh(tm)
    assert "not positively oriented" not in str(info.value)


# ---------------------------------------------------------------- random sequences, checked after every step

def _run_checked(points, values, exact, order, fixed_tets, criterion="rms", swap=True, boundary_flips=False):
    ijk = np.asarray(points, np.int64) if exact else None
    tm = TetMesh(np.asarray(points, float), values, ijk, criterion=criterion, boundary_flips=boundary_flips)
    tm.start(fixed_tets)
    hull_vol = None
    check_mesh(tm, hull_volume=hull_vol)
    for p in order:
        case, ids = tm.insert(p)
        check_mesh(tm)
        if swap:
            before = tm.criterion_sum()
            tm.swap(ids)
            check_mesh(tm)
            # the swap only applies flips that lower the sum it evaluates
            assert tm.criterion_sum() <= before * (1 + 1e-12) + 1e-15
    r, worst = tm.residuals()
    return tm, r


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("criterion", ["rms", "max", "sse", "sse+2-2"])
def test_random_order_on_a_grid_checked_after_every_operation(seed, criterion):
    bflips = criterion.endswith("+2-2")
    criterion = criterion.replace("+2-2", "")
    rng = np.random.default_rng(seed)
    n = 3
    idx = np.arange(n + 1)
    ijk = np.stack(np.meshgrid(idx, idx, idx, indexing="ij"), -1).reshape(-1, 3)
    vals = rng.normal(size=len(ijk))
    fixed = box_tetrahedra((n + 1,) * 3, "kuhn")
    corners = np.unique(fixed)
    order = rng.permutation(np.setdiff1d(np.arange(len(ijk)), corners))
    tm, r = _run_checked(ijk, vals, True, order, fixed, criterion, boundary_flips=bflips)
    # every point selected: the interpolant reproduces the data
    assert np.max(np.abs(r)) < 1e-12
    assert sum(tm.cases.values()) == len(order)


def _scattered_case(kind, seed):
    rng = np.random.default_rng(seed)
    if kind == "random":
        pts = rng.random((30, 3))
    elif kind == "cospherical":
        v = rng.normal(size=(24, 3))
        pts = v / np.linalg.norm(v, axis=1)[:, None]
        pts = np.vstack([pts, 0.3 * rng.random((6, 3))])
    elif kind == "coplanar":
        # points on three parallel planes, many on hull faces and shared planes
        xy = rng.random((10, 2))
        pts = np.vstack([np.column_stack([xy, np.full(10, z)]) for z in (0.0, 0.5, 1.0)])
    else:  # integer lattice subset: many degenerate (coplanar, collinear) configurations, float path
        pts = rng.choice(np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3),
                         size=35, replace=False).astype(float)
    return pts


@pytest.mark.parametrize("kind", ["random", "cospherical", "coplanar", "lattice"])
@pytest.mark.parametrize("seed", range(2))
def test_random_order_on_scattered_points_checked_after_every_operation(kind, seed):
    pts = _scattered_case(kind, seed)
    vals = np.sin(3 * pts[:, 0]) + pts[:, 1] * pts[:, 2]
    _, hv = hull_triangles(pts)
    fixed_tets = hv[delaunay_tetrahedra(pts[hv])]
    order = np.random.default_rng(seed + 10).permutation(np.setdiff1d(np.arange(len(pts)), hv))
    tm, r = _run_checked(pts, vals, False, order, fixed_tets)
    assert np.max(np.abs(r)) < 1e-9


def test_fixture_robustness_lattice_insertions():
    """Named fixture: an insertion order on a lattice subset that once needed new hull faces."""
    fx = json.loads((FIXTURES / "hull_face_insertion.json").read_text())
    pts = np.array(fx["points"], float)
    vals = np.array(fx["values"], float)
    tm, r = _run_checked(pts, vals, fx["exact"], fx["order"], np.array(fx["start_tets"]))
    assert np.max(np.abs(r)) < 1e-12


def test_orientation_predicate_int_and_float_agree_on_grid_points():
    rng = np.random.default_rng(3)
    pts = rng.integers(0, 5, size=(40, 3))
    tmi = TetMesh(pts.astype(float), np.zeros(40), pts)
    tmf = TetMesh(pts.astype(float), np.zeros(40), None)
    for _ in range(500):
        a, b, c, d = rng.integers(0, 40, 4)
        exact = int(np.sign(round(np.linalg.det((pts[[b, c, d]] - pts[a]).astype(float)))))
        assert _orient(tmi.S, a, b, c, d) == exact
        assert _orient(tmf.S, a, b, c, d) == exact


def test_face_planes_give_the_exact_sub_volumes_of_eq_13():
    """The integer face planes of _tet_data evaluate to orient3d with p in place of
    each vertex, exactly (they are the weights of eq. 13 on grids)."""
    from trivsel.mesh.geometry import _tet_data
    from trivsel.predicates import orient3d_int

    rng = np.random.default_rng(11)
    coords = rng.integers(-300, 300, size=(60, 3)).astype(np.int64)
    P = coords.astype(float)
    F = rng.random(60)
    for _ in range(300):
        q = [int(v) for v in rng.choice(60, 4, replace=False)]
        pl, _, _ = _tet_data(coords, P, F, *q)
        p = coords[int(rng.integers(60))]
        for i in range(4):
            args = [coords[v] for v in q]
            args[i] = p
            expect = orient3d_int(*[int(c) for v in args for c in v])
            got = pl[4 * i] * p[0] + pl[4 * i + 1] * p[1] + pl[4 * i + 2] * p[2] + pl[4 * i + 3]
            assert got == expect


def _random_mesh_configs(criterion, seed=3):
    """A Delaunay mesh over random points with random values, and its 2-3 configurations."""
    from trivsel.mesh.flips import config23

    rng = np.random.default_rng(seed)
    pts = rng.random((40, 3))
    tm = TetMesh(pts, rng.random(40), criterion=criterion)
    tm.start(delaunay_tetrahedra(pts))
    configs = []
    for t in tm.live_ids():
        for i in range(4):
            old = np.empty(4, np.int64)
            newq = np.empty((4, 4), np.int64)
            if config23(tm.S, int(t), i, old, newq):
                configs.append((old[:2].copy(), newq[:3].copy()))
    return tm, configs


@pytest.mark.parametrize("criterion", ["rms", "max", "sse"])
def test_evaluation_does_not_depend_on_the_order_of_the_old_tets(criterion):
    # swap remembers evaluations by configuration, whichever tet it was found from:
    # the sums must be the same to the last bit (equal gains must stay equal)
    tm, configs = _random_mesh_configs(criterion)
    assert len(configs) > 20
    for old, newq in configs:
        assert tm.evaluate(old, newq) == tm.evaluate(old[::-1], newq)


@pytest.mark.parametrize("criterion", ["rms", "max", "sse"])
def test_early_stopped_evaluation_decides_like_the_full_one(criterion):
    from trivsel.mesh.criteria import _evaluate

    tm, configs = _random_mesh_configs(criterion)
    stopped = 0
    for old, newq in configs:
        full_b, full_a = _evaluate(tm.S, old, 2, newq, 3, 0.0, -np.inf)
        for reltol, abstol in [(1e-9, 0.0), (0.0, 1e-3), (0.3, 0.0)]:
            b, a = _evaluate(tm.S, old, 2, newq, 3, reltol, abstol)
            thr = reltol * full_b + abstol
            assert b == full_b
            assert (b - a > thr) == (full_b - full_a > thr)
            if b - a > thr:
                assert a == full_a  # an improving flip is always evaluated in full
            else:
                assert a <= full_a
                stopped += a < full_a
    assert stopped > 0  # the early stop did happen


def test_config_keys_are_distinct_and_do_not_depend_on_the_order_of_the_tets():
    from trivsel.mesh.swap import _KEYLEN, _config_key

    tver = np.array([0, 3, 1, 2**31 - 1, 7, 0, 0, 5], np.int64)
    keys = set()
    for kind, d, olds in [(0, (-1, -1), [(1, 2), (2, 3), (0, 1), (6, 7)]),
                          (1, (-1, -1), [(1, 2, 3), (0, 1, 2), (5, 6, 7)]),
                          (2, (4, 9), [(0, 1, 2, 3), (1, 2, 3, 4)]), (2, (9, 5), [(0, 1, 2, 3)]),
                          (2, (2**30 - 2, 0), [(0, 1, 2, 3)]), (3, (-1, -1), [(1, 2), (0, 7)])]:
        for old in olds:
            key = np.empty(_KEYLEN, np.int64)
            _config_key(tver, kind, d[0], d[1], np.array(old, np.int64), len(old), key)
            rev = np.empty(_KEYLEN, np.int64)
            _config_key(tver, kind, d[1], d[0], np.array(old[::-1], np.int64), len(old), rev)
            np.testing.assert_array_equal(key, rev)
            assert key[0] != -1  # -1 marks an empty slot
            keys.add(tuple(key))
    assert len(keys) == 13
    # a tet id reused (its version counts up) is another key
    key = np.empty(_KEYLEN, np.int64)
    _config_key(tver, 0, -1, -1, np.array([1, 2], np.int64), 2, key)
    tver[2] += 1
    key2 = np.empty(_KEYLEN, np.int64)
    _config_key(tver, 0, -1, -1, np.array([1, 2], np.int64), 2, key2)
    assert tuple(key) != tuple(key2)


def test_bounded_memory_table_forgets_but_never_returns_a_wrong_value():
    # the run-long memory (swap_memory="run") is a fixed table: a key looks at a few
    # slots and may overwrite one; a lookup finds a key only with its own value
    from trivsel.mesh.swap import _KEYLEN, _cache_slot, _cache_store

    rng = np.random.default_rng(5)
    hkey = np.full((64, _KEYLEN), -1, np.int64)
    hval = np.empty((64, 2))
    truth = {}
    found_any = lost_any = False
    for it in range(2000):
        key = np.zeros(_KEYLEN, np.int64)
        key[0] = int(rng.integers(0, 300))
        key[1] = int(rng.integers(0, 3))
        slot, found = _cache_slot(hkey, key, 4)
        k = tuple(key)
        if found:
            found_any = True
            assert tuple(hval[slot]) == truth[k]
        else:
            lost_any |= k in truth
            truth[k] = (float(it), -float(it))
            _cache_store(hkey, hval, 0, slot, key, float(it), -float(it))
    assert found_any and lost_any
