"""Block edges and faces (trivsel.blocks.faces): 1-D and 2-D greedy selection and the face mesh contract."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from conftest import examples

from trivsel.blocks.faces import check_face_mesh, face_residuals, reduce_face, reduce_polyline

# Residuals are recomputed here by other formulas than the kernel's: rounding may differ.
SLACK = 1e-12


def polyline_residuals(values, kept):
    values = np.asarray(values, float)
    return np.abs(values - np.interp(np.arange(values.size), kept, values[kept]))


def edges_border(values, tol):
    """The border mask a block reduction hands a face: its four edges reduced in 1-D."""
    border = np.zeros(values.shape, bool)
    border[reduce_polyline(values[:, 0], tol_inf=tol), 0] = True
    border[reduce_polyline(values[:, -1], tol_inf=tol), -1] = True
    border[0, reduce_polyline(values[0], tol_inf=tol)] = True
    border[-1, reduce_polyline(values[-1], tol_inf=tol)] = True
    return border


def corners_only(shape):
    border = np.zeros(shape, bool)
    border[[0, 0, -1, -1], [0, -1, 0, -1]] = True
    return border


def face_values(name, nu, nv, seed=0):
    u, v = np.mgrid[0:nu, 0:nv] / np.array([nu - 1, nv - 1])[:, None, None]
    if name == "smooth":
        return np.sin(3 * u) * np.cos(4 * v) + 0.5 * u * v
    if name == "sharp":                      # a step edge across the face, off the grid lines
        return (u + 0.4 * v > 0.7).astype(float)
    if name == "noise":
        return np.random.default_rng(seed).random((nu, nv))
    return np.full((nu, nv), 2.5)            # constant


def consecutive_border_segments(border):
    """The border points counter-clockwise in (u, v) from (0, 0), as consecutive pairs."""
    nu, nv = border.shape
    ring = ([(u, 0) for u in range(nu - 1)] + [(nu - 1, v) for v in range(nv - 1)]
            + [(u, nv - 1) for u in range(nu - 1, 0, -1)] + [(0, v) for v in range(nv - 1, 0, -1)])
    kept = [u * nv + v for u, v in ring if border[u, v]]
    return sorted(zip(kept, kept[1:] + kept[:1]))


def boundary_edges(triangles):
    """Directed edges of the triangles without an opposite twin."""
    edges = {(int(a), int(b)) for t in triangles for a, b in zip(t, np.roll(t, -1))}
    return sorted(e for e in edges if e[::-1] not in edges)


def barycentric_fit(values, tri, u, v):
    """The linear interpolant of triangle ``tri`` (flat indices) at grid point (u, v), by
    float barycentric coordinates (not the kernel's formulas); None outside the closed triangle."""
    (au, bu, cu), (av, bv, cv) = np.divmod(np.asarray(tri), values.shape[1])
    lam = np.linalg.solve([[bu - au, cu - au], [bv - av, cv - av]], [u - au, v - av])
    if lam.min() < -1e-12 or lam.sum() > 1 + 1e-12:
        return None
    fa, fb, fc = values.ravel()[list(tri)]
    return fa + lam[0] * (fb - fa) + lam[1] * (fc - fa)


def brute_residuals(values, triangles, rows=None, cols=None):
    """|f - interpolant| point by point (the first triangle containing the point); NaN
    where no triangle does."""
    out = np.full(values.shape, np.nan)
    for u in range(values.shape[0]) if rows is None else rows:
        for v in range(values.shape[1]) if cols is None else cols:
            for tri in triangles:
                fit = barycentric_fit(values, tri, u, v)
                if fit is not None:
                    out[u, v] = abs(values[u, v] - fit)
                    break
    return out


def quad_sse(values, pair):
    """Squared error of the closed union of two triangles, each grid point once."""
    pu, pv = np.divmod(np.array(pair).ravel(), values.shape[1])
    r = brute_residuals(values, pair, range(pu.min(), pu.max() + 1), range(pv.min(), pv.max() + 1))
    return float(np.nansum(r * r))


def orient(nv, a, b, c):
    (au, av), (bu, bv), (cu, cv) = divmod(a, nv), divmod(b, nv), divmod(c, nv)
    return (bu - au) * (cv - av) - (bv - av) * (cu - au)


# --- block edges (1-D) ---------------------------------------------------------------------

@settings(max_examples=examples(4 / 15))
@given(st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=300), st.floats(0, 50))
def test_polyline_meets_tolerance_on_random_signals(values, tol):
    kept = reduce_polyline(values, tol_inf=tol)
    assert kept[0] == 0 and kept[-1] == len(values) - 1 and np.all(np.diff(kept) > 0)
    assert polyline_residuals(values, kept).max() <= tol + SLACK * 1e3


@settings(max_examples=examples(1 / 15))
@given(st.integers(2, 3000), st.floats(1e-4, 0.5))
def test_polyline_meets_tolerance_on_smooth_signals(n, tol):
    x = np.linspace(0, 6, n)
    values = np.sin(x) + 0.3 * np.cos(7 * x)
    kept = reduce_polyline(values, tol_inf=tol)
    assert kept[0] == 0 and kept[-1] == n - 1
    assert polyline_residuals(values, kept).max() <= tol + SLACK


def test_polyline_step_keeps_both_sides_of_the_jump():
    values = np.r_[np.zeros(50), np.ones(50)]
    assert reduce_polyline(values, tol_inf=0.01).tolist() == [0, 49, 50, 99]


def test_polyline_constant_keeps_only_the_ends():
    assert reduce_polyline(np.full(1000, -3.0), tol_inf=0.0).tolist() == [0, 999]
    assert reduce_polyline([1.0, 5.0], tol_inf=0.0).tolist() == [0, 1]


def test_polyline_ties_go_to_the_smallest_index():
    # 1 and 2 are equally bad from (0, 3); with 1 kept, 2 is within 0.5 of the segment 1-3
    assert reduce_polyline([0.0, 1.0, 1.0, 0.0], tol_inf=0.5).tolist() == [0, 1, 3]


def test_polyline_is_deterministic_and_fast_enough_for_long_edges():
    values = np.random.default_rng(3).normal(size=10_000).cumsum()
    first = reduce_polyline(values, tol_inf=0.5)
    assert np.array_equal(first, reduce_polyline(values.copy(), tol_inf=0.5))
    assert first.dtype == np.int64 and polyline_residuals(values, first).max() <= 0.5 + SLACK


@pytest.mark.parametrize("values, tol, words", [
    ([0.0, np.nan, 1.0], 0.1, "nan at index 1"),
    ([0.0, np.inf], 0.1, "inf at index 1"),
    ([1.0], 0.1, "shape (1,)"),
    ([[0.0, 1.0]], 0.1, "shape (1, 2)"),
    ([0.0, 1.0], -1.0, "-1.0"),
    ([0.0, 1.0], float("nan"), "nan"),
    ([0.0, 1.0], True, "True"),
])
def test_polyline_bad_input_is_one_line_naming_the_value(values, tol, words):
    with pytest.raises(ValueError) as info:
        reduce_polyline(values, tol_inf=tol)
    assert words in str(info.value) and "\n" not in str(info.value)


# --- block faces (2-D) ---------------------------------------------------------------------

@pytest.mark.parametrize("name", ["smooth", "sharp", "noise", "constant"])
@pytest.mark.parametrize("shape", [(33, 33), (17, 40)])
def test_face_meets_tolerance_with_edge_borders(name, shape):
    values = face_values(name, *shape)
    tol = 0.02 * max(np.ptp(values), 1.0)
    border = edges_border(values, tol)
    vertices, triangles = reduce_face(values, border, tol_inf=tol)
    check_face_mesh(shape, vertices, triangles, border)
    assert face_residuals(values, vertices, triangles).max() <= tol + SLACK
    assert vertices.dtype == np.int64 and triangles.dtype == np.int64 and triangles.shape[1] == 3
    assert boundary_edges(triangles) == consecutive_border_segments(border)
    if name == "noise":
        assert vertices.size > 0.5 * values.size
    elif name == "smooth":
        assert vertices.size < 0.1 * values.size


def test_constant_face_inserts_only_the_start_point():
    # the border meets the tolerance on its own; with interior points the start point
    # (nearest the centre, ties: smallest flat index) is inserted all the same
    values = face_values("constant", 8, 9)
    border = edges_border(values, 0.0)
    vertices, _ = reduce_face(values, border, tol_inf=0.0)
    start = 3 * 9 + 4                      # centre (3.5, 4): (3, 4) and (4, 4) tie
    assert vertices.tolist() == sorted(np.flatnonzero(border).tolist() + [start])


@settings(max_examples=examples(0.1))
@given(st.integers(2, 12), st.integers(2, 12), st.integers(0, 2**16), st.sampled_from([0.0, 0.05, 0.3]),
       st.booleans())
def test_face_contract_on_random_faces(nu, nv, seed, tol, from_edges):
    rng = np.random.default_rng(seed)
    values = np.round(rng.normal(size=(nu, nv)), 1)          # rounding: many ties
    if from_edges:
        border = edges_border(values, tol)
    else:
        border = corners_only((nu, nv))
        border[[0, -1], :] |= rng.random((2, nv)) < 0.4
        border[:, [0, -1]] |= rng.random((nu, 2)) < 0.4
    vertices, triangles = reduce_face(values, border, tol_inf=tol)
    check_face_mesh((nu, nv), vertices, triangles, border)
    residuals = face_residuals(values, vertices, triangles)
    assert residuals[1:-1, 1:-1].max(initial=0.0) <= tol + SLACK
    if from_edges:
        assert residuals.max() <= tol + SLACK
    again = reduce_face(values.copy(), border.copy(), tol_inf=tol)
    assert np.array_equal(vertices, again[0]) and np.array_equal(triangles, again[1])


@pytest.mark.parametrize("shape", [(2, 2), (2, 9), (9, 2), (2, 30)])
def test_strip_faces_have_no_candidates(shape):
    values = face_values("noise", *shape)
    border = edges_border(values, 0.1)
    vertices, triangles = reduce_face(values, border, tol_inf=0.1)
    check_face_mesh(shape, vertices, triangles, border)
    assert vertices.tolist() == np.flatnonzero(border).tolist()
    assert len(triangles) == vertices.size - 2
    assert face_residuals(values, vertices, triangles).max() <= 0.1 + SLACK


def test_face_is_deterministic():
    values = face_values("noise", 25, 31, seed=7)
    border = edges_border(values, 0.2)
    first = reduce_face(values, border, tol_inf=0.2)
    for _ in range(2):
        again = reduce_face(values.copy(), border.copy(), tol_inf=0.2)
        assert np.array_equal(first[0], again[0]) and np.array_equal(first[1], again[1])


def test_max_vertices_stops_early_with_a_valid_mesh():
    values = face_values("smooth", 40, 40)
    border = corners_only(values.shape)
    full, _ = reduce_face(values, border, tol_inf=1e-4)
    vertices, triangles = reduce_face(values, border, tol_inf=1e-4, max_vertices=30)
    assert full.size > 30 and vertices.size == 30
    check_face_mesh(values.shape, vertices, triangles, border)
    least, _ = reduce_face(values, border, tol_inf=1e-4, max_vertices=5)
    assert least.size == 5                 # the corners and the start point
    with pytest.raises(ValueError, match="max_vertices must be an integer >= 5"):
        reduce_face(values, border, tol_inf=1e-4, max_vertices=4)


@pytest.mark.parametrize("name", ["smooth", "noise"])
def test_no_single_swap_lowers_the_squared_error(name):
    # every edge whose triangles changed is tested after the change, so the final mesh
    # is locally optimal for data-dependent swapping (section 4); checked independently
    values = face_values(name, 12, 14, seed=5)
    border = corners_only(values.shape)
    _, triangles = reduce_face(values, border, tol_inf=0.1 * np.ptp(values))
    nv = values.shape[1]
    by_edge = {(int(t[i]), int(t[(i + 1) % 3])): int(t[(i + 2) % 3]) for t in triangles for i in range(3)}
    tested = 0
    for (a, b), c in by_edge.items():
        d = by_edge.get((b, a))
        if d is None or a > b or orient(nv, a, d, c) <= 0 or orient(nv, d, b, c) <= 0:
            continue
        before = quad_sse(values, [(a, b, c), (b, a, d)])
        after = quad_sse(values, [(a, d, c), (d, b, c)])
        assert after >= before * (1 - 1e-9) - 1e-12, (a, b, c, d, before, after)
        tested += 1
    assert tested > 10


# A 3x4 face, flat indices (u down, v across), corners only as border, zero but for
# f = 1 at (1, 2):
#
#     0 . 1 . 2 . 3
#     4 . 5 . 6 . 7
#     8 . 9 .10 .11
#
# The start point is 5: (1, 1) and (1, 2) are equally near the centre (1, 1.5), 5 is
# the smaller index.  Its cone has the triangles 0-8-5, 8-11-5, 11-3-5, 3-0-5.  Point 6
# (residual 1 > 0.5) lies inside 11-3-5, which splits into 11-3-6, 3-5-6, 5-11-6.  No swap
# changes any residual (the only non-vertex points lie on the border), so none is made.
@pytest.fixture
def bump_3x4():
    values = np.zeros((3, 4))
    values[1, 2] = 1.0
    expected = [[0, 5, 3], [0, 8, 5], [3, 5, 6], [3, 6, 11], [5, 8, 11], [5, 11, 6]]
    return values, corners_only((3, 4)), [0, 3, 5, 6, 8, 11], expected


def test_known_configuration_3x4(bump_3x4):
    values, border, vertices, triangles = bump_3x4
    got_v, got_t = reduce_face(values, border, tol_inf=0.5)
    assert got_v.tolist() == vertices and got_t.tolist() == triangles
    # with the tolerance at the bump's height (within: <=) only the start point goes in: the cone
    got_v, got_t = reduce_face(values, border, tol_inf=1.0)
    assert got_v.tolist() == [0, 3, 5, 8, 11]
    assert got_t.tolist() == [[0, 5, 3], [0, 8, 5], [3, 5, 11], [5, 8, 11]]


@pytest.mark.parametrize("name", ["smooth", "noise"])
def test_face_residuals_match_brute_force(name):
    values = face_values(name, 7, 9, seed=2)
    vertices, triangles = reduce_face(values, corners_only(values.shape), tol_inf=0.05)
    assert np.allclose(face_residuals(values, vertices, triangles), brute_residuals(values, triangles),
                       rtol=0, atol=1e-12)


def test_large_smooth_face():
    values = face_values("smooth", 129, 129)
    tol = 0.01 * np.ptp(values)
    border = edges_border(values, tol)
    vertices, triangles = reduce_face(values, border, tol_inf=tol)
    check_face_mesh(values.shape, vertices, triangles, border)
    assert face_residuals(values, vertices, triangles).max() <= tol + SLACK
    assert 40 < vertices.size < 400


@pytest.mark.parametrize("change, words", [
    (lambda t: t[1:], "cover area"),
    (lambda t: np.r_[t[:1, ::-1], t[1:]], "has area"),
    (lambda t: np.r_[t, t[:1]], "cover area 7.5, the rectangle 6"),
])
def test_check_face_mesh_rejects_broken_meshes(bump_3x4, change, words):
    values, border, vertices, triangles = bump_3x4
    broken = change(np.array(triangles))
    with pytest.raises(AssertionError, match=words):
        check_face_mesh(values.shape, np.unique(broken), broken, border)


def test_check_face_mesh_rejects_overlaps_of_the_right_total_area():
    # on the 2x2 face (0, 2, 3) and (0, 2, 1) each have area 1/2 but overlap along 0 -> 2
    with pytest.raises(AssertionError, match="edge \\(0, 0\\) -> \\(1, 0\\) is in 2 triangles the same way"):
        check_face_mesh((2, 2), [0, 1, 2, 3], [[0, 2, 3], [0, 2, 1]], corners_only((2, 2)))


def test_check_face_mesh_rejects_a_border_another_block_would_not_see(bump_3x4):
    values, border, vertices, triangles = bump_3x4
    other = border.copy()
    other[0, 2] = True                     # a neighbour keeps (0, 2): the edge 0-3 must be split there
    with pytest.raises(AssertionError, match="boundary vertices differ from border at \\(0, 2\\)$"):
        check_face_mesh(values.shape, vertices, triangles, other)


@pytest.mark.parametrize("values, border, tol, words", [
    (np.zeros((4, 4)), np.eye(4, dtype=bool)[::-1] | np.eye(4, dtype=bool), 0.1, "at (1, 1)"),
    (np.zeros((4, 4)), np.ones((4, 4), bool) & ~np.eye(4, dtype=bool), 0.1, "False at (0, 0)"),
    (np.where(np.eye(4) > 0, np.nan, 0.0), corners_only((4, 4)), 0.1, "nan at index (0, 0)"),
    (np.zeros((4, 4)), corners_only((4, 4)), -0.5, "got -0.5"),
    (np.zeros((4, 4)), corners_only((4, 4)).astype(int), 0.1, "boolean array"),
    (np.zeros((4, 4)), corners_only((4, 5)), 0.1, "shape (4, 4)"),
    (np.zeros((1, 4)), corners_only((1, 4)), 0.1, "shape (1, 4)"),
])
def test_face_bad_input_is_one_line_naming_the_value(values, border, tol, words):
    with pytest.raises(ValueError) as info:
        reduce_face(values, border, tol_inf=tol)
    assert words in str(info.value) and "\n" not in str(info.value)
