"""Least-squares vertex values (``values="fit"``, :mod:`trivsel.fitting`) against a dense solve.

The reference is :func:`numpy.linalg.lstsq` on the dense N x m matrix of the
weights, built here row by row from ``verts`` and ``weights`` without the module's
assembly.
"""

import numpy as np
import pytest

from trivsel import fitting
from trivsel.data import grid_from_array
from trivsel.decimation import Decimation
from trivsel.fitting import fit_vertex_values, normal_equations, solve_normal_equations


def dense_matrix(verts, weights, n_vertices, vertices):
    """The dense N x m matrix A of the fit: A[p, j] = weight of point p on vertex j."""
    col = {int(v): j for j, v in enumerate(vertices)}
    A = np.zeros((len(verts), n_vertices))
    for p, (vs, ws) in enumerate(zip(verts, weights)):
        for v, w in zip(vs, ws):
            if w > 0:
                A[p, col[int(v)]] += w
    return A


def dense_fit(verts, weights, values, vertices):
    A = dense_matrix(verts, weights, len(vertices), vertices)
    x = np.linalg.lstsq(A, values, rcond=None)[0]
    return A, x


def random_mesh(rng, N=300, m=40, n_lonely=5):
    """Weights of N points on m of them: each vertex has weight 1 on itself; of the
    other points, most have 4 random positive weights, some lie on a face, an edge or
    a vertex (weights exactly 0 and 1, the zero ones on points that are not vertices);
    ``n_lonely`` vertices carry no weight but their own point's."""
    vertices = np.sort(rng.choice(N, m, replace=False))
    others = np.setdiff1d(np.arange(N), vertices)
    social = vertices[n_lonely:]
    verts = np.repeat(np.arange(N)[:, None], 4, axis=1)
    w = np.zeros((N, 4))
    w[vertices, 0] = 1.0
    for p in others:
        k = rng.choice([1, 2, 3, 4], p=[0.05, 0.1, 0.15, 0.7])
        verts[p, :k] = rng.choice(social, k, replace=False)
        verts[p, k:] = rng.choice(others, 4 - k)  # zero weights on non-vertices
        w[p, :k] = rng.dirichlet(np.ones(k))
    f = rng.normal(size=N) * 10 + np.arange(N) * 0.1
    return verts, w, f, vertices


@pytest.mark.parametrize("seed", range(4))
def test_fit_equals_the_dense_least_squares_solution(seed):
    rng = np.random.default_rng(seed)
    verts, w, f, vertices = random_mesh(rng)
    A, x = dense_fit(verts, w, f, vertices)
    fitted, residuals = fit_vertex_values(verts, w, f, vertices)
    scale = np.abs(x).max()
    assert np.abs(fitted - x).max() <= 1e-10 * scale
    assert np.abs(residuals - (f - A @ fitted)).max() <= 1e-12 * np.abs(f).max()
    # the lonely vertices take their own data value exactly (their row of A is e_j alone)
    lonely = np.flatnonzero(np.abs(A).sum(axis=0) == 1.0)
    assert lonely.size >= 5
    assert np.abs(fitted[lonely] - f[vertices[lonely]]).max() <= 1e-10 * scale


def test_normal_equations_are_those_of_the_dense_matrix():
    rng = np.random.default_rng(7)
    verts, w, f, vertices = random_mesh(rng, N=120, m=20)
    A = dense_matrix(verts, w, len(vertices), vertices)
    K, b = normal_equations(verts, w, f, vertices)
    assert np.abs(K.toarray() - A.T @ A).max() <= 1e-13 * np.abs(A.T @ A).max()
    assert np.abs(b - A.T @ f).max() <= 1e-13 * np.abs(A.T @ f).max()
    assert np.array_equal(K.toarray(), K.toarray().T)


def test_the_fit_on_a_decimation_is_the_dense_least_squares_fit():
    i, j, k = np.meshgrid(*(np.arange(7),) * 3, indexing="ij")
    rng = np.random.default_rng(1)
    data = grid_from_array(np.sin(i * 0.9) * j + (k > 3) * 2.0 + 0.05 * rng.normal(size=i.shape))
    dec = Decimation(data.ijk, data.shape, data.values)
    dec.run(30)
    verts, w = dec.point_weights()
    vertices = dec.vertices()
    A, x = dense_fit(verts, w, data.values, vertices)
    fitted, residuals = fit_vertex_values(verts, w, data.values, vertices)
    assert np.abs(fitted - x).max() <= 1e-10 * np.abs(x).max()
    e_dense = np.sqrt(np.mean((data.values - A @ x) ** 2))
    assert abs(np.sqrt(np.mean(residuals**2)) - e_dense) <= 1e-10 * e_dense
    # and never worse than the data values on the same mesh
    assert np.sqrt(np.mean(residuals**2)) <= np.sqrt(np.mean(dec.residuals() ** 2))


def test_a_loose_tolerance_is_caught_and_the_default_one_is_tight():
    rng = np.random.default_rng(11)
    verts, w, f, vertices = random_mesh(rng, N=400, m=60, n_lonely=0)
    A, x = dense_fit(verts, w, f, vertices)
    K, b = normal_equations(verts, w, f, vertices)

    def normal_residual(v):  # relative residual of the normal equations, by the dense matrix
        return np.linalg.norm(A.T @ (f - A @ v)) / np.linalg.norm(A.T @ f)

    loose, its_loose = solve_normal_equations(K, b, f[vertices], rtol=1e-3)
    tight, its_tight = solve_normal_equations(K, b, f[vertices])
    assert normal_residual(loose) > 1e-10 and np.abs(loose - x).max() > 1e-9 * np.abs(x).max()
    assert normal_residual(tight) <= 10 * fitting.RTOL <= 1e-10
    assert np.abs(tight - x).max() <= 1e-10 * np.abs(x).max()
    assert its_tight > its_loose
    fitted, _ = fit_vertex_values(verts, w, f, vertices)
    assert normal_residual(fitted) <= 10 * fitting.RTOL


def test_the_direct_fallback_and_a_column_without_weight():
    rng = np.random.default_rng(5)
    verts, w, f, vertices = random_mesh(rng, N=200, m=30)
    A, x = dense_fit(verts, w, f, vertices)
    K, b = normal_equations(verts, w, f, vertices)
    direct, its = solve_normal_equations(K, b, np.zeros(len(b)), maxiter=1)
    assert its == 1 and np.abs(direct - x).max() <= 1e-10 * np.abs(x).max()
    # a vertex that no weight refers to (not even its own point's) keeps its start value
    w2 = w.copy()
    j = 3
    w2[vertices[j]] = 0.0
    fitted, _ = fit_vertex_values(verts, w2, f, vertices)
    assert fitted[j] == f[vertices[j]]
    keep = np.arange(len(vertices)) != j
    _, x2 = dense_fit(verts, w2, f, vertices)
    assert np.abs(fitted[keep] - x2[keep]).max() <= 1e-10 * np.abs(x2).max()


def test_a_positive_weight_on_a_point_that_is_not_a_vertex_is_refused():
    rng = np.random.default_rng(2)
    verts, w, f, vertices = random_mesh(rng, N=50, m=10)
    p = np.setdiff1d(np.arange(50), vertices)[0]
    verts[p, 3], w[p, 3] = p, 0.25
    with pytest.raises(ValueError, match="not a mesh vertex"):
        fit_vertex_values(verts, w, f, vertices)


def test_the_benchmarks_former_fit_is_the_same_least_squares_solution():
    from conftest import load_benchmark_script

    old_fit = load_benchmark_script("bench_fit").old_fit
    rng = np.random.default_rng(4)
    verts, w, f, vertices = random_mesh(rng, N=250, m=35)
    _, x = dense_fit(verts, w, f, vertices)
    old, old_res = old_fit(verts, w, f, vertices)
    new, new_res = fit_vertex_values(verts, w, f, vertices)
    assert np.abs(old - x).max() <= 1e-10 * np.abs(x).max()
    assert np.abs(new - old).max() <= 1e-10 * np.abs(old).max()
    assert np.abs(new_res - old_res).max() <= 1e-10 * np.abs(f).max()


def test_a_zero_right_hand_side_gives_zero_at_once():
    rng = np.random.default_rng(6)
    verts, w, f, vertices = random_mesh(rng, N=60, m=12)
    K, _ = normal_equations(verts, w, f, vertices)
    x, its = solve_normal_equations(K, np.zeros(len(vertices)), f[vertices])
    assert its == 0 and not x.any()


def test_the_chunks_off_diagonal_sums_add_up_as_one_sparse_sum_at_a_time():
    """``_sum_in_order`` gives the entries of ``((A + B) + C) + ...`` bit for bit: each entry
    summed in the matrices' order, on values where another order rounds differently, with
    sums that cancel to no entry."""
    import functools
    import operator

    import scipy.sparse as sp

    rng = np.random.default_rng(3)
    m = 30
    mats = []
    for _ in range(9):
        a = sp.random(m, m, density=0.3, random_state=rng, format="csr")
        a.data = rng.normal(size=a.nnz) * 10.0 ** rng.integers(-8, 8, a.nnz)
        mats.append(a)
    mats.append(-mats[0])  # cancels some entries exactly, where nothing else touched them
    ref = functools.reduce(operator.add, mats)
    got = fitting._sum_in_order(mats)
    ref.sort_indices()
    assert np.array_equal(got.indptr, ref.indptr) and np.array_equal(got.indices, ref.indices)
    assert np.array_equal(got.data, ref.data)
    # the order matters: summed in reverse, some entries round differently
    rev = fitting._sum_in_order(mats[::-1])
    assert not np.array_equal(rev.toarray(), ref.toarray())


def test_the_normal_equations_over_many_chunks_are_those_of_one_sparse_sum_at_a_time(monkeypatch):
    """Chunks folded into the running sum a few at a time give the same ``K`` and ``b``, bit for
    bit, as adding each chunk's sparse matrix to it in turn."""
    import scipy.sparse as sp

    rng = np.random.default_rng(11)
    verts, w, f, vertices = random_mesh(rng, N=400, m=50)
    monkeypatch.setattr(fitting, "CHUNK", 16)
    monkeypatch.setattr(fitting, "_FOLD", 3)
    K, b = normal_equations(verts, w, f, vertices)
    col = fitting.column_map(len(f), vertices)
    m = len(vertices)
    diag, b_ref, off = np.zeros(m), np.zeros(m), sp.csr_matrix((m, m))
    for s in range(0, len(f), 16):
        c, ws = fitting._chunk(verts, w, col, s, s + 16)
        diag += np.bincount(c.ravel(), (ws * ws).ravel(), minlength=m)
        b_ref += np.bincount(c.ravel(), (ws * f[s:s + 16, None]).ravel(), minlength=m)
        rows, cols, data = [], [], []
        for i, j in fitting._PAIRS:
            p = ws[:, i] * ws[:, j]
            rows.append(c[p > 0, i])
            cols.append(c[p > 0, j])
            data.append(p[p > 0])
        off = off + sp.csr_matrix((np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))), shape=(m, m))
    K_ref = (off + off.T + sp.diags(diag)).tocsr()
    assert np.array_equal(b, b_ref)
    assert np.array_equal(K.toarray(), K_ref.toarray())
