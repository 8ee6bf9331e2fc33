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
    principal_curvatures,
)
from trivsel.data import FUNCTIONS, sample_grid
from trivsel.triangulation import delaunay_tetrahedra, edge_neighbours, kuhn_tetrahedra


@lru_cache(maxsize=None)
def _grid_graph(n):
    """Edge-neighbour graph of the Kuhn split of the (n+1)^3 grid (cached: building it
    is the slowest part of these tests)."""
    return edge_neighbours(kuhn_tetrahedra((n + 1,) * 3), (n + 1) ** 3)


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
