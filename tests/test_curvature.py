"""Tests for trivsel.curvature: local quadratic fits and absolute curvature (eqs. 4-10)."""

from functools import lru_cache
from itertools import permutations

import numpy as np
import pytest

from trivsel.curvature import (
    absolute_curvature,
    analytic_absolute_curvature,
    analytic_derivatives,
    fit_quadratic,
    local_frame_curvature,
    principal_curvatures,
    tet_normals,
    vertex_normals,
)
from trivsel.data import sample_grid
from trivsel.functions import FUNCTIONS
from trivsel.exceptions import InputError
from trivsel.triangulation import (
    delaunay_tetrahedra,
    edge_neighbours,
    hull_boundary_mask,
    kuhn_tetrahedra,
)


@lru_cache(maxsize=None)
def _grid_tets(n):
    """Kuhn split of the (n+1)^3 grid (cached)."""
    return kuhn_tetrahedra((n + 1,) * 3)


@lru_cache(maxsize=None)
def _grid_graph(n):
    """Edge-neighbour graph of the Kuhn split of the (n+1)^3 grid (cached: building it
    is the slowest part of these tests)."""
    return edge_neighbours(_grid_tets(n), (n + 1) ** 3)


def _grid_fit(function, n):
    data = sample_grid(function, n)
    ip, ix = _grid_graph(n)
    grad, hess, used, info = fit_quadratic(data.points, data.values, ip, ix, return_info=True)
    return data, grad, hess, used, info


def _grid_K(function, n):
    data = sample_grid(function, n)
    return data, absolute_curvature(data.points, data.values, neighbours=_grid_graph(n))


# ---------------------------------------------------------------------------
# principal_curvatures (eq. 8)
# ---------------------------------------------------------------------------

def test_zero_gradient_gives_hessian_eigenvalues():
    rng = np.random.default_rng(1)
    a = rng.standard_normal((50, 3, 3))
    hess = a + np.swapaxes(a, 1, 2)
    kappa = principal_curvatures(np.zeros((50, 3)), hess)
    np.testing.assert_allclose(kappa, np.linalg.eigvalsh(hess), atol=1e-13)


def test_matches_nonsymmetric_weingarten_matrix():
    """Symmetric form (1/l) S H S has the eigenvalues of (1/l) H (I + g g^T)^-1 (eq. 8)."""
    rng = np.random.default_rng(2)
    g = rng.standard_normal((200, 3)) * rng.choice([1e-9, 0.1, 1.0, 10.0], size=(200, 1))
    a = rng.standard_normal((200, 3, 3))
    hess = a + np.swapaxes(a, 1, 2)
    ell = np.sqrt(1 + np.sum(g * g, axis=1))
    gram = np.eye(3) + g[:, :, None] * g[:, None, :]
    w = hess @ np.linalg.inv(gram) / ell[:, None, None]
    ref = np.sort(np.linalg.eigvals(w).real, axis=1)
    np.testing.assert_allclose(principal_curvatures(g, hess), ref, atol=1e-10)


@pytest.mark.parametrize("radius", [0.5, 2.0, 7.0])
def test_hypersphere_graph_has_curvatures_one_over_R(radius):
    """Graph of f = sqrt(R^2 - |x|^2) is part of the 3-sphere of radius R in R^4:
    all principal curvatures are -1/R (upward normal = inward), everywhere."""
    rng = np.random.default_rng(3)
    x = rng.uniform(-1, 1, size=(100, 3))
    x *= (0.9 * radius * rng.random((100, 1))) / np.linalg.norm(x, axis=1, keepdims=True)
    x[0] = 0.0  # the origin, where g = 0 and H = -I/R
    f = np.sqrt(radius**2 - np.sum(x * x, axis=1))
    grad = -x / f[:, None]
    hess = -(np.eye(3) / f[:, None, None] + x[:, :, None] * x[:, None, :] / (f**3)[:, None, None])
    kappa = principal_curvatures(grad, hess)
    np.testing.assert_allclose(kappa, -1.0 / radius, rtol=1e-10)
    np.testing.assert_allclose(np.abs(kappa).sum(axis=1), 3.0 / radius, rtol=1e-10)


def test_principal_curvatures_broadcasts_single_point():
    kappa = principal_curvatures(np.zeros(3), np.diag([3.0, 1.0, 2.0]))
    assert kappa.shape == (3,)
    np.testing.assert_allclose(kappa, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError):
        principal_curvatures(np.zeros((4, 3)), np.zeros((5, 3, 3)))


# ---------------------------------------------------------------------------
# analytic derivatives of the Table-1 functions
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("function", sorted(FUNCTIONS))
def test_analytic_derivatives_match_finite_differences(function):
    f = FUNCTIONS[function][2]
    rng = np.random.default_rng(4)
    p = rng.uniform(-1, 1, size=(40, 3))
    grad, hess = analytic_derivatives(function, p)
    e = 1e-4
    eye = np.eye(3)
    fd_grad = np.stack([(f(*(p + e * eye[i]).T) - f(*(p - e * eye[i]).T)) / (2 * e) for i in range(3)], 1)
    np.testing.assert_allclose(grad, fd_grad, atol=1e-7)
    fd_hess = np.empty_like(hess)
    for i in range(3):
        for j in range(3):
            pp, pm, mp, mm = (f(*(p + s * e * eye[i] + t * e * eye[j]).T)
                              for s, t in ((1, 1), (1, -1), (-1, 1), (-1, -1)))
            fd_hess[:, i, j] = (pp - pm - mp + mm) / (4 * e * e)
    np.testing.assert_allclose(hess, fd_hess, atol=1e-5)
    assert np.allclose(hess, np.swapaxes(hess, 1, 2))


def test_analytic_curvature_f1_at_origin():
    # g = 0, H = 0.8 I  ->  kappa = 0.8 three times, K = 2.4
    np.testing.assert_allclose(analytic_absolute_curvature("quadratic", np.zeros((1, 3))), [2.4])


# ---------------------------------------------------------------------------
# fit_quadratic / absolute_curvature on grids
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("function", [1, 2])
@pytest.mark.parametrize("n", [4, 8, 16])
def test_quadratics_are_fitted_exactly_everywhere(function, n):
    data, K = _grid_K(function, n)
    np.testing.assert_allclose(K, analytic_absolute_curvature(function, data.points), rtol=0, atol=1e-10)
    _, grad, hess, _, _ = _grid_fit(function, n)
    ga, ha = analytic_derivatives(function, data.points)
    np.testing.assert_allclose(grad, ga, atol=1e-10)
    np.testing.assert_allclose(hess, ha, atol=1e-10)


@pytest.mark.parametrize("n", [4, 8, 16])
def test_grid_boundary_points_and_only_they_use_the_two_ring(n):
    """On cube faces/edges/corners the 1-ring has two distinct values of the normal
    coordinate (u and u^2 inseparable): those points, and no others, widen to the
    2-ring; no point needs the 3-ring or the minimum-norm fallback."""
    data, _, _, used, info = _grid_fit(1, n)
    np.testing.assert_array_equal(used, ~data.interior_mask())
    assert set(np.unique(info["ring"])) == {1, 2}
    assert not info["min_norm"].any()


def test_cubic_hessian_exact_inside_gradient_error_shrinks():
    """f3 is cubic, not in the quadratic space.  At interior grid points the Kuhn
    1-ring is point-symmetric (offsets come in pairs +-d), which decouples the
    odd and even monomials: the cubic terms alias only into the linear ones, so
    the Hessian is exact and the gradient error is O(h^2).
    Observed max interior gradient error: n=4 5.2e-2, 8 1.3e-2, 16 3.2e-3 (ratio 4)."""
    errs = []
    for n in (4, 8, 16):
        data, grad, hess, _, _ = _grid_fit(3, n)
        ga, ha = analytic_derivatives(3, data.points)
        inner = data.interior_mask()
        np.testing.assert_allclose(hess[inner], ha[inner], atol=1e-10)
        errs.append(np.abs(grad - ga)[inner].max())
    assert errs[0] > 1e-3  # genuinely not exact
    assert errs[0] / errs[1] > 3.5 and errs[1] / errs[2] > 3.5, errs


@pytest.mark.parametrize("function", [4, 5])
def test_curvature_error_decreases_under_refinement(function):
    """Max |K - K_exact| over points with all coordinates in [-0.5, 0.5] (all interior):
    f4: n=8 4.7e-2, 16 1.2e-2, 32 2.9e-3 (ratios 4.0, 4.0);
    f5: n=8 1.5e-1, 16 3.8e-2, 32 9.5e-3 (ratios 3.9, 4.0) -- second order."""
    errs = []
    for n in (8, 16, 32):
        data, K = _grid_K(function, n)
        core = np.all(np.abs(data.points) <= 0.5 + 1e-12, axis=1)
        errs.append(np.abs(K - analytic_absolute_curvature(function, data.points))[core].max())
    assert errs[0] / errs[1] > 1.5 and errs[1] / errs[2] > 1.5, errs
    assert errs[-1] < 0.02, errs


def test_ties_at_symmetric_grid_points():
    """f1 and the Kuhn split are invariant under permutations of the axes, and f1 is
    fitted exactly, so K agrees at all points related by permutations and
    reflections (i -> n - i) up to rounding."""
    n = 8
    data, K = _grid_K(1, n)
    index = {tuple(t): i for i, t in enumerate(data.ijk.tolist())}
    worst = 0.0
    for ijk in [(1, 2, 3), (0, 1, 5), (0, 0, 3), (2, 2, 7), (4, 4, 4), (0, 0, 0)]:
        group = set()
        for perm in permutations(ijk):
            for mask in range(8):
                group.add(tuple(n - c if mask >> a & 1 else c for a, c in enumerate(perm)))
        vals = K[[index[t] for t in group]]
        worst = max(worst, (vals.max() - vals.min()) / vals.max())
    assert worst <= 1e-12


# ---------------------------------------------------------------------------
# scattered points (Delaunay initial triangulation)
# ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def scattered_cloud():
    rng = np.random.default_rng(12345)
    p = rng.random((400, 3))
    tets = delaunay_tetrahedra(p)
    return p, tets, edge_neighbours(tets, len(p))


def test_scattered_linear_has_zero_curvature(scattered_cloud):
    p, tets, _ = scattered_cloud
    f = 0.3 + 1.2 * p[:, 0] - 0.7 * p[:, 1] + 2.0 * p[:, 2]
    K = absolute_curvature(p, f, tets=tets)
    assert np.abs(K).max() <= 1e-9


def test_scattered_quadratic_exact(scattered_cloud):
    p, _, (ip, ix) = scattered_cloud
    x, y, z = p.T
    f = 0.4 * (x * x - y * y - z * z) + 0.3 * x * y + 0.5 * y * z - 0.1 * z
    grad = np.stack([0.8 * x + 0.3 * y, -0.8 * y + 0.3 * x + 0.5 * z, -0.8 * z + 0.5 * y - 0.1], axis=1)
    hess = np.broadcast_to(np.array([[0.8, 0.3, 0.0], [0.3, -0.8, 0.5], [0.0, 0.5, -0.8]]), (len(p), 3, 3))
    K_exact = np.abs(principal_curvatures(grad, hess)).sum(axis=1)
    K = absolute_curvature(p, f, neighbours=(ip, ix))
    # every point has >= 10 points in reach (1- or 2-ring), so the fit is exact everywhere
    np.testing.assert_allclose(K, K_exact, rtol=0, atol=1e-8)
    # default: Delaunay built internally
    np.testing.assert_allclose(absolute_curvature(p, f), K_exact, rtol=0, atol=1e-8)


def test_scattered_widening_only_for_small_neighbourhoods(scattered_cloud):
    """With random points, a 1-ring fit is deficient only if it has fewer than the 10
    points a quadratic needs (fewer than 9 neighbours)."""
    p, _, (ip, ix) = scattered_cloud
    _, _, used, info = fit_quadratic(p, p[:, 0], ip, ix, return_info=True)
    np.testing.assert_array_equal(used, np.diff(ip) < 9)
    assert not info["min_norm"].any()


def test_fit_matches_per_point_lstsq(scattered_cloud):
    """The batched QR solve equals numpy's lstsq per point (unscaled coordinates)."""
    p, _, (ip, ix) = scattered_cloud
    f = np.exp(-0.5 * np.sum((p - 0.4) ** 2, axis=1)) + np.sin(3 * p[:, 0])
    grad, hess, used = fit_quadratic(p, f, ip, ix)
    for i in np.flatnonzero(~used)[:60]:
        nb = np.r_[i, ix[ip[i]:ip[i + 1]]]
        x, y, z = (p[nb] - p[i]).T
        a = np.stack([np.ones_like(x), x, y, z, x * x, y * y, z * z, x * y, x * z, y * z], axis=1)
        c = np.linalg.lstsq(a, f[nb], rcond=None)[0]
        h = np.array([[2 * c[4], c[7], c[8]], [c[7], 2 * c[5], c[9]], [c[8], c[9], 2 * c[6]]])
        np.testing.assert_allclose(grad[i], c[1:4], rtol=1e-7, atol=1e-8)
        np.testing.assert_allclose(hess[i], h, rtol=1e-7, atol=1e-6)


def test_min_norm_fallback_for_tiny_data():
    """Five points: even the 3-ring has < 10 points; the minimum-norm solution is used,
    flagged, and finite."""
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1.0]])
    ip, ix = edge_neighbours(delaunay_tetrahedra(p), 5)
    grad, hess, used, info = fit_quadratic(p, p[:, 0] + p[:, 1] ** 2, ip, ix, return_info=True)
    assert used.all() and info["min_norm"].all() and (info["ring"] == 3).all()
    assert np.isfinite(grad).all() and np.isfinite(hess).all()


def test_chunking_does_not_change_results():
    data = sample_grid(5, 8)
    ip, ix = _grid_graph(8)
    ref = fit_quadratic(data.points, data.values, ip, ix)
    small = fit_quadratic(data.points, data.values, ip, ix, chunk_points=37, chunk_rows=500)
    for a, b in zip(ref, small):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("estimator", ["direct", "local-frame"])
def test_threads_give_identical_results(estimator):
    data = sample_grid(3, 10)
    kw = dict(tets=_grid_tets(10), neighbours=_grid_graph(10), estimator=estimator, chunk_points=50)
    one = absolute_curvature(data.points, data.values, threads=1, **kw)
    two = absolute_curvature(data.points, data.values, threads=3, **kw)
    np.testing.assert_array_equal(one, two)


@pytest.mark.parametrize("threads", [0, -1, 1.5, True])
def test_bad_threads_rejected(threads):
    data = sample_grid(1, 4)
    with pytest.raises(InputError, match=f"threads must be an integer >= 1, got {threads!r}"):
        absolute_curvature(data.points, data.values, neighbours=_grid_graph(4), threads=threads)


# ---------------------------------------------------------------------------
# local-frame estimator (Hamann 1994b)
# ---------------------------------------------------------------------------

def _grid_K_local(function, n, **options):
    data = sample_grid(function, n)
    return data, local_frame_curvature(data.points, data.values, tets=_grid_tets(n),
                                       neighbours=_grid_graph(n), **options)


def _ball_grid(n, half, radius):
    """(n+1)^3 grid on [-half, half]^3 with the hypersphere-graph values, interior mask."""
    i = np.arange(n + 1)
    ijk = np.stack(np.meshgrid(i, i, i, indexing="ij"), axis=-1).reshape(-1, 3)
    p = (2.0 * ijk - n) / n * half
    f = np.sqrt(radius**2 - np.sum(p * p, axis=1))
    return p, f, np.all((ijk > 0) & (ijk < n), axis=1)


def test_tet_normals_are_orthogonal_and_scaled_by_lifted_volume():
    rng = np.random.default_rng(21)
    p = rng.random((60, 3))
    tets = delaunay_tetrahedra(p)
    f = np.sin(3 * p[:, 0]) + p[:, 1] * p[:, 2]
    nt = tet_normals(p, f, tets)
    lifted = np.c_[p, f]
    edges = lifted[tets[:, 1:]] - lifted[tets[:, :1]]
    np.testing.assert_allclose(np.einsum("mij,mj->mi", edges, nt), 0, atol=1e-12)
    assert (nt[:, 3] > 0).all()
    # n_T = 6 V (-grad L, 1): last component is 6 V, the rest -6 V grad L
    six_v = np.abs(np.linalg.det(p[tets[:, 1:]] - p[tets[:, :1]]))
    np.testing.assert_allclose(nt[:, 3], six_v, rtol=1e-12)
    df = (f[tets[:, 1:]] - f[tets[:, :1]])[..., None]
    grad = np.linalg.solve(p[tets[:, 1:]] - p[tets[:, :1]], df)[..., 0]
    np.testing.assert_allclose(nt[:, :3], -six_v[:, None] * grad, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("function", [1, 2])
def test_volume_weighted_normal_exact_for_quadratics_inside_grid(function):
    """Point-symmetric Kuhn stars: the quadratic parts of opposite tets cancel in the
    volume-weighted mean, so the normal is exact (uniform weighting: 3.0e-3 off, n=8)."""
    data = sample_grid(function, 8)
    g, _ = analytic_derivatives(function, data.points)
    exact = np.c_[-g, np.ones(len(g))]
    exact /= np.linalg.norm(exact, axis=1, keepdims=True)
    inner = data.interior_mask()
    vol = vertex_normals(data.points, data.values, _grid_tets(8))
    uni = vertex_normals(data.points, data.values, _grid_tets(8), weighting="uniform")
    np.testing.assert_allclose(np.linalg.norm(vol, axis=1), 1, rtol=1e-14)
    np.testing.assert_allclose(vol[inner], exact[inner], atol=1e-13)
    assert np.abs(uni - exact)[inner].max() > 1e-3
    assert (vol[:, 3] > 0).all() and (uni[:, 3] > 0).all()


@pytest.mark.parametrize("radius", [1.0, 2.0])
def test_local_frame_hypersphere_grid(radius):
    """Graph of sqrt(R^2 - |x|^2) on the grid over [-0.4, 0.4]^3: kappa_i = -1/R, K = 3/R.
    Observed max relative error of K (local frame / direct):
    R=1 (slopes up to 0.96): interior n=8 3.3e-3 / 1.7e-2, n=16 9.3e-4 / 8.6e-3;
                             all points n=8 1.6e-2 / 1.9e-1, n=16 4.4e-3 / 1.3e-1;
    R=2 (slopes up to 0.37): interior n=8 6.7e-4 / 6.2e-4, n=16 1.7e-4 / 1.6e-4;
                             all points n=8 3.7e-3 / 4.3e-2, n=16 9.3e-4 / 2.5e-2.
    Not exact (the height function of a sphere has a quartic term), but second
    order everywhere, and far better than the direct fit on the boundary and
    where the graph is steep (in the flat interior the two are on a par)."""
    errs = []
    for n in (8, 16):
        p, f, inner = _ball_grid(n, 0.4, radius)
        tets = _grid_tets(n)
        nb = _grid_graph(n)
        K, info = local_frame_curvature(p, f, tets=tets, neighbours=nb, return_info=True)
        Kd = absolute_curvature(p, f, neighbours=nb)
        el = np.abs(K - 3 / radius) * radius / 3
        ed = np.abs(Kd - 3 / radius) * radius / 3
        assert (info["kappa"][inner] < 0).all()       # upward normal points inward
        assert el.max() < 0.25 * ed.max()             # all points, boundary included
        if radius == 1.0:
            assert el[inner].max() < 0.25 * ed[inner].max()
        errs.append((el[inner].max(), el.max()))
    assert errs[1][0] < (5e-3 if radius == 1.0 else 1e-3) / 4, errs
    assert errs[0][0] / errs[1][0] > 3 and errs[0][1] / errs[1][1] > 3, errs


def test_local_frame_hypersphere_scattered():
    """748 random points in the ball of radius 0.7 R (R = 1), Delaunay triangulation.
    Observed relative error of K, local frame vs direct: median over the 629 non-hull
    points 8.3e-3 vs 1.5e-2 (max 9.1e-2 vs 1.3e-1); max over the 276 points with
    |x| < 0.5: 1.7e-2 vs 8.9e-2."""
    rng = np.random.default_rng(7)
    x = rng.uniform(-0.7, 0.7, (1400, 3))
    x = x[np.linalg.norm(x, axis=1) <= 0.7]
    f = np.sqrt(1 - np.sum(x * x, axis=1))
    tets = delaunay_tetrahedra(x)
    K = absolute_curvature(x, f, tets=tets, estimator="local-frame")
    Kd = absolute_curvature(x, f, tets=tets)
    el, ed = np.abs(K - 3) / 3, np.abs(Kd - 3) / 3
    inner = ~hull_boundary_mask(x)
    deep = np.linalg.norm(x, axis=1) < 0.5
    assert np.median(el[inner]) < 0.012 and np.median(el[inner]) < 0.7 * np.median(ed[inner])
    assert el[deep].max() < 0.03 and el[deep].max() < 0.3 * ed[deep].max()


@pytest.mark.slow
@pytest.mark.parametrize("function", [1, 2, 4, 5])
def test_estimators_agree_under_refinement(function):
    """Max |K_local - K_direct| over interior points (f1, f2; the direct fit is exact
    there) or points in [-0.5, 0.5]^3 (f4, f5), observed for n = 8, 16, 32:
    f1 5.7e-3, 1.4e-3, 3.5e-4 (ratios 4.1, 4.0);  f2 1.1e-2, 3.2e-3, 8.4e-4 (3.4, 3.8);
    f4 3.3e-2, 9.3e-3, 2.4e-3 (3.5, 3.8);         f5 4.1e-3, 1.4e-3, 3.8e-4 (2.9, 3.7).
    (On the grid boundary the local frame is only first order: f1 0.27, 0.13, 0.06.)"""
    diffs = []
    for n in (8, 16, 32):
        data, Kd = _grid_K(function, n)
        _, Kl = _grid_K_local(function, n)
        if function in (1, 2):
            region = data.interior_mask()
        else:
            region = np.all(np.abs(data.points) <= 0.5 + 1e-12, axis=1)
        diffs.append(np.abs(Kl - Kd)[region].max())
    assert diffs[0] / diffs[1] > 2.5 and diffs[1] / diffs[2] > 3.2, diffs
    assert diffs[2] < {1: 5e-4, 2: 1.2e-3, 4: 3.5e-3, 5: 6e-4}[function], diffs


def test_local_frame_linear_is_flat(scattered_cloud):
    p, tets, nb = scattered_cloud
    f = 0.3 + 1.2 * p[:, 0] - 0.7 * p[:, 1] + 2.0 * p[:, 2]
    K = local_frame_curvature(p, f, tets=tets, neighbours=nb)
    assert np.abs(K).max() <= 1e-9
    data = sample_grid(1, 8)
    g = data.points @ np.array([0.5, -2.0, 1.0]) - 3.0
    for weighting in ("volume", "uniform"):
        K = local_frame_curvature(data.points, g, tets=_grid_tets(8), weighting=weighting)
        assert np.abs(K).max() <= 1e-9


def test_local_frame_api(scattered_cloud):
    p, tets, nb = scattered_cloud
    x, y, z = p.T
    f = np.exp(-((x - 0.5) ** 2 + y * y)) + 0.3 * z * z
    K, info = local_frame_curvature(p, f, tets=tets, neighbours=nb, return_info=True)
    np.testing.assert_array_equal(absolute_curvature(p, f, tets=tets, estimator="local-frame"), K)
    # default: Delaunay built internally (the same triangulation here)
    np.testing.assert_allclose(local_frame_curvature(p, f), K, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(K, np.abs(info["kappa"]).sum(axis=1), rtol=1e-14)
    assert info["normal"].shape == (len(p), 4) and not info["min_norm"].any()
    # same neighbourhoods as the direct fit
    _, _, _, dinfo = fit_quadratic(p, f, *nb, return_info=True)
    np.testing.assert_array_equal(info["ring"], dinfo["ring"])
    # chunking does not change results
    small = local_frame_curvature(p, f, tets=tets, neighbours=nb, chunk_points=23, chunk_rows=400)
    np.testing.assert_allclose(small, K, rtol=1e-12, atol=1e-13)
    with pytest.raises(InputError):
        local_frame_curvature(p, f, neighbours=nb)          # normals need the tets
    with pytest.raises(ValueError):
        absolute_curvature(p, f, tets=tets, estimator="paper")
    with pytest.raises(ValueError):
        local_frame_curvature(p, f, tets=tets, weighting="area")


def test_local_frame_grid_rings_and_kuhn_symmetry():
    """Grid: boundary points widen to the 2-ring exactly as in the direct fit.  K is
    invariant under the symmetries of f1 that the Kuhn split shares (axis
    permutations and the central reflection i -> n - i of all axes at once)."""
    n = 8
    data = sample_grid(1, n)
    K, info = local_frame_curvature(data.points, data.values, tets=_grid_tets(n),
                                    neighbours=_grid_graph(n), return_info=True)
    np.testing.assert_array_equal(info["ring"] > 1, ~data.interior_mask())
    index = {tuple(t): i for i, t in enumerate(data.ijk.tolist())}
    for ijk in [(1, 2, 3), (0, 1, 5), (0, 0, 3), (2, 2, 7), (0, 0, 0)]:
        group = {tuple(perm) for perm in permutations(ijk)}
        group |= {tuple(n - c for c in t) for t in group}
        vals = K[[index[t] for t in group]]
        assert (vals.max() - vals.min()) <= 1e-12 * vals.max()


@pytest.mark.parametrize("n", [3, 10, 16])
@pytest.mark.parametrize("function", [1, 3, 5])
def test_grid_shared_stencil_fit_matches_per_point_fits(function, n):
    # the interior points share one design matrix (one SVD instead of a QR each);
    # the result equals the per-point fits up to rounding, including grids whose
    # coordinates are not exact binary fractions (n = 10) and the widened rings
    data = sample_grid(function, n)
    ip, ix = _grid_graph(n)
    g0, h0, u0, i0 = fit_quadratic(data.points, data.values, ip, ix, return_info=True)
    g1, h1, u1, i1 = fit_quadratic(data.points, data.values, ip, ix, grid=True, chunk_points=97,
                                   return_info=True)
    scale = max(1.0, np.abs(h0).max())
    np.testing.assert_allclose(g1, g0, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(h1, h0, rtol=0, atol=1e-11 * scale)
    np.testing.assert_array_equal(u1, u0)
    np.testing.assert_array_equal(i1["ring"], i0["ring"])
    np.testing.assert_array_equal(i1["min_norm"], i0["min_norm"])


def test_grid_shared_stencil_fit_flags_underdetermined_rings_on_long_edges():
    # regression (129^3): the 127 points of each box edge share one 1-ring of 6
    # neighbours, enough rows for the shared SVD (64), which returned 6 singular
    # values of a 6 x 10 design and passed it as full rank: K = 44 on the edges
    # instead of about 1, and the paper method inserted 762 edge points first
    from trivsel.triangulation import kuhn_edge_neighbours, neighbour_graph

    shape = (4, 4, 131)
    axes = [np.linspace(-1, 1, s) for s in shape]
    p = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    f = 0.5 * p[:, 0] ** 2 - p[:, 1] * p[:, 2] + 2 * p[:, 2] ** 2 + p[:, 0]
    ip, ix = neighbour_graph(*kuhn_edge_neighbours(shape), shape=shape, kind="kuhn")
    g0, h0, u0, i0 = fit_quadratic(p, f, ip, ix, return_info=True)
    g1, h1, u1, i1 = fit_quadratic(p, f, ip, ix, grid=True, return_info=True)
    np.testing.assert_array_equal(i1["ring"], i0["ring"])
    np.testing.assert_allclose(h1, h0, rtol=0, atol=1e-8)
    exact = np.array([[1.0, 0, 0], [0, 0, -1], [0, -1, 4]])
    np.testing.assert_allclose(h1, np.broadcast_to(exact, h1.shape), rtol=0, atol=1e-6)


def test_grid_hint_on_scattered_points_changes_nothing(scattered_cloud):
    # rows only share a factorisation where their coordinate offsets agree
    p, _, (ip, ix) = scattered_cloud
    f = p[:, 0] ** 2 - p[:, 1] * p[:, 2] + np.sin(3 * p[:, 0])
    g0, h0, _ = fit_quadratic(p, f, ip, ix)
    g1, h1, _ = fit_quadratic(p, f, ip, ix, grid=True)
    np.testing.assert_allclose(g1, g0, rtol=0, atol=1e-10)
    np.testing.assert_allclose(h1, h0, rtol=0, atol=1e-9)


@pytest.mark.parametrize("shape", [(2, 2, 2), (2, 3, 5), (5, 4, 3), (7, 7, 7)])
def test_kuhn_stencil_graph_equals_the_graph_of_the_kuhn_tets(shape):
    from trivsel.triangulation import kuhn_edge_neighbours

    ip, ix = kuhn_edge_neighbours(shape)
    jp, jx = edge_neighbours(kuhn_tetrahedra(shape), int(np.prod(shape)))
    np.testing.assert_array_equal(ip, jp)
    np.testing.assert_array_equal(ix, jx)
