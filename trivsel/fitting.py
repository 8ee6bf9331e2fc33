"""Vertex values fitted by least squares (``values="fit"``), beyond the paper.

The paper's approximation interpolates the selected points' own values
(``values="data"``): the result is a true selection.  With ``values="fit"`` the
mesh is kept and its vertex values ``v`` are chosen to minimise the squared error
over *all* original points, ``sum_p (f_p - sum_j w_pj v_j)^2`` (the numerator of
eq. 19's E_RMS), where ``w_pj`` are the barycentric weights (eq. 13) of point p in
a tet containing it.  This is the like-for-like comparison with decimation methods
that place vertex values freely (VTK's quadric decimation), on E_RMS; it never has
a larger E_RMS than ``data`` on the same mesh, since the data values are one
feasible choice.

The normal equations ``K v = b`` with ``K = A^T A`` and ``b = A^T f`` (``A`` the
N x m matrix of the weights) are assembled directly from each point's 4 x 4 outer
product of its weights, in chunks of points, so ``A`` is never formed: ``K`` holds
one entry per pair of vertices that share a tet.  ``K`` is symmetric positive
definite (each vertex is an original point with weight 1 on itself, so
``K >= I``) and is solved by conjugate gradients with a diagonal (Jacobi)
preconditioner, started from the data values at the vertices, until the relative
residual ``|b - K v| / |b|`` is at most :data:`RTOL` (checked on the true
residual, not the recursive one).  A sparse direct factorisation fills in badly
on 3-D meshes.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["fit_vertex_values", "fit_on_mesh", "normal_equations", "solve_normal_equations", "RTOL"]

#: Relative residual of the normal equations, ``|b - K v| / |b|``, at which the fit stops.
RTOL = 1e-12
#: Points per chunk when assembling the normal equations and the residuals.
CHUNK = 1 << 16
#: The pairs (a, b), a < b, of a point's 4 weights: the off-diagonal entries of its outer product.
_PAIRS = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
#: Chunks whose off-diagonal sums are added to the running sum at once (:func:`_sum_in_order`).
_FOLD = 32


def column_map(n_points, vertices):
    """Column of every original point in the fit (its index among ``vertices``), -1 for the
    others: int32 while the vertices' count allows, so a grid-sized map takes 4 bytes a point."""
    dtype = np.int32 if len(vertices) < 2**31 else np.int64
    col = np.full(n_points, -1, dtype)
    col[vertices] = np.arange(len(vertices), dtype=dtype)
    return col


def _chunk(verts, weights, col, s, e):
    """The columns and weights of the points ``s:e``; weights that are not positive
    become 0 on column 0 (they do not enter the fit)."""
    w = np.asarray(weights[s:e], float)
    c = col[np.asarray(verts[s:e], np.int64)]
    pos = w > 0
    if np.any(c[pos] < 0):
        raise ValueError("a weight refers to a point that is not a mesh vertex")
    return np.where(pos, c, 0), np.where(pos, w, 0.0)


def _dot(x, y):
    """``x . y`` without BLAS: a threaded BLAS dot on vectors of this size costs
    far more than the product itself when the cores are busy."""
    return float(np.einsum("i,i->", x, y))


def _norm(x):
    """The 2-norm of ``x`` (:func:`_dot`)."""
    return _dot(x, x) ** 0.5


def normal_equations(verts, weights, values, vertices):
    """The normal equations ``K v = b`` of the least-squares fit, ``K = A^T A``, ``b = A^T f``.

    ``A`` (N x m, row p holding point p's barycentric weights of eq. 13 in the
    columns of its tet's vertices) is not formed: ``K`` is the sum over the points
    of the 4 x 4 outer products of their weights, and ``b`` the sum of the weights
    times the values, accumulated over chunks of :data:`CHUNK` points.

    Parameters
    ----------
    verts, weights : (N, 4)
        For each original point, the vertices of a tet containing it and the
        barycentric weights.  Weights that are not positive are ignored.
    values : (N,)
        The original values f.
    vertices : (m,) int
        The mesh vertices: column j of ``A`` is point ``vertices[j]``.

    Returns
    -------
    K : scipy.sparse.csr_matrix (m, m)
        Symmetric positive semi-definite (definite when every vertex carries a
        positive weight).
    b : (m,) float

    Raises
    ------
    ValueError
        When a positive weight refers to a point that is not among ``vertices``.
    """
    f = np.asarray(values, float)
    vertices = np.asarray(vertices, np.int64)
    N, m = f.shape[0], len(vertices)
    col = column_map(N, vertices)
    return _normal_equations(((*_chunk(verts, weights, col, s, min(s + CHUNK, N)), f[s:s + CHUNK])
                              for s in range(0, N, CHUNK)), m)


def _normal_equations(chunks, m):
    """``K`` and ``b`` of :func:`normal_equations` from chunks of points ``(c, w, f)``: their
    columns and weights (as :func:`_chunk` gives them) and values."""
    diag, b = np.zeros(m), np.zeros(m)
    off = sp.csr_matrix((m, m))
    batch = []
    for c, w, fv in chunks:
        diag += np.bincount(c.ravel(), (w * w).ravel(), minlength=m)
        b += np.bincount(c.ravel(), (w * fv[:, None]).ravel(), minlength=m)
        prod = [w[:, i] * w[:, j] for i, j in _PAIRS]
        keep = [p > 0 for p in prod]
        rows = np.concatenate([c[k, i] for (i, _), k in zip(_PAIRS, keep)])
        cols = np.concatenate([c[k, j] for (_, j), k in zip(_PAIRS, keep)])
        data = np.concatenate([p[k] for p, k in zip(prod, keep)])
        # each unordered pair once (in either orientation); K adds the transpose
        batch.append(sp.csr_matrix((data, (rows, cols)), shape=(m, m)))
        if len(batch) == _FOLD:
            off, batch = _sum_in_order([off] + batch), []
    off = _sum_in_order([off] + batch)
    K = (off + off.T + sp.diags(diag)).tocsr()
    return K, b


def _sum_in_order(mats):
    """``((mats[0] + mats[1]) + mats[2]) + ...`` (canonical CSR matrices of one shape), entry by
    entry in that order, as the sparse sum one at a time gives it bit for bit, in time linear
    in the entries: each sum of two takes time in the entries of both, and the running sum
    grows with every chunk."""
    if len(mats) == 1:
        return mats[0]
    m, n = mats[0].shape
    key = np.concatenate([np.repeat(np.arange(m, dtype=np.int64), np.diff(a.indptr)) * n + a.indices for a in mats])
    val = np.concatenate([a.data for a in mats])
    order = np.argsort(key, kind="stable")  # by entry, each entry's terms in the matrices' order
    key, val = key[order], val[order]
    del order
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, np.int64)
    size = np.diff(np.r_[start, len(key)])
    total = val[start]
    for t in range(1, int(size.max()) if len(size) else 0):  # the t-th term of every entry that has one
        more = np.flatnonzero(size > t)
        total[more] += val[start[more] + t]
    key = key[start]
    nonzero = total != 0  # a sum of 0 is no entry, as in the sparse sum
    key, total = key[nonzero], total[nonzero]
    indptr = np.searchsorted(key, np.arange(m + 1, dtype=np.int64) * n)
    return sp.csr_matrix((total, (key % n).astype(mats[0].indices.dtype), indptr), shape=(m, n))


def solve_normal_equations(K, b, x0, *, rtol=RTOL, maxiter=None):
    """Solve ``K x = b`` (symmetric positive definite) by Jacobi-preconditioned
    conjugate gradients from ``x0``, to ``|b - K x| <= rtol |b|``.

    The stop is decided on the true residual ``b - K x``: when the recursive
    residual says converged but the true one does not, the iteration restarts from
    the current ``x``.  An unknown with a zero diagonal (no weight on it) keeps its
    value in ``x0``.  If the iteration has not converged after ``maxiter``
    iterations, the system is solved by a sparse direct factorisation instead.

    Parameters
    ----------
    K : sparse (m, m)
    b, x0 : (m,) float
    rtol : float
        Relative residual to reach.
    maxiter : int, optional
        Iterations before the direct fallback; default ``max(1000, 10 sqrt(m))``.

    Returns
    -------
    x : (m,) float
    iterations : int
        Conjugate-gradient iterations done (0 when ``x0`` already satisfies the tolerance).
    """
    K = sp.csr_matrix(K)
    b = np.asarray(b, float)
    x = np.array(x0, float)
    m = b.shape[0]
    d = K.diagonal()
    free = d > 0
    if not np.all(free):
        # a column without weight: its row and column of K are zero; solve for the others
        K = K[free][:, free]
        b = b[free]
        x_free, its = solve_normal_equations(K, b, x[free], rtol=rtol, maxiter=maxiter)
        x[free] = x_free
        return x, its
    maxiter = max(1000, int(10 * np.sqrt(m))) if maxiter is None else int(maxiter)
    stop = rtol * _norm(b)
    if stop == 0.0:
        return np.zeros(m), 0  # b = 0: the solution of K x = 0
    dinv = 1.0 / d
    its = 0
    r = b - K @ x
    while _norm(r) > stop:
        if its >= maxiter:
            from scipy.sparse.linalg import spsolve

            return spsolve(K.tocsc(), b), its
        z = dinv * r
        p = z.copy()
        rz = _dot(r, z)
        while its < maxiter:
            q = K @ p
            alpha = rz / _dot(p, q)
            x += alpha * p
            r -= alpha * q
            its += 1
            if _norm(r) <= stop:
                break
            z = dinv * r
            rz, rz_old = _dot(r, z), rz
            p *= rz / rz_old
            p += z
        r = b - K @ x
    return x, its


def fit_vertex_values(verts, weights, values, vertices):
    """Least-squares vertex values on a fixed mesh.

    Minimises ``sum_p (f_p - L(p))^2`` over all original points p, with ``L(p)``
    the linear interpolant of the vertex values in p's tet (eq. 13), i.e. the
    squared residuals whose mean is eq. 19's E_RMS squared.  The normal equations
    (:func:`normal_equations`) are solved to a relative residual of :data:`RTOL`
    (:func:`solve_normal_equations`), starting from the data values at the
    vertices.

    Parameters
    ----------
    verts, weights : (N, 4)
        For each original point, the vertices of a tet containing it and the
        barycentric weights (from :meth:`trivsel.mesh.TetMesh.point_weights`).
    values : (N,)
        The original values f.
    vertices : (m,) int
        The mesh vertices (selected points).

    Returns
    -------
    fitted : (m,) float
        Values at ``vertices``.
    residuals : (N,) float
        ``f - L_fit`` at every original point.
    """
    f = np.asarray(values, float)
    vertices = np.asarray(vertices, np.int64)
    K, b = normal_equations(verts, weights, f, vertices)
    fitted, _ = solve_normal_equations(K, b, f[vertices])
    del K
    col = column_map(f.shape[0], vertices)
    residuals = np.empty_like(f)
    for s in range(0, f.shape[0], CHUNK):
        e = min(s + CHUNK, f.shape[0])
        c, w = _chunk(verts, weights, col, s, e)
        residuals[s:e] = f[s:e] - np.einsum("ij,ij->i", w, fitted[c])
    return fitted, residuals


def fit_on_mesh(mesh, values, interior):
    """A snapshot's ``fit``: least-squares values on ``mesh`` (anything with
    ``point_weights()`` and ``vertices()``: :class:`trivsel.mesh.TetMesh`,
    :class:`trivsel.decimation.Decimation`), as the dict :class:`trivsel.result.Snapshot`
    holds: ``vertices``, ``values``, ``residuals`` and their ``errors`` (eqs. 19-20)."""
    from .norms import error_norms

    verts, w = mesh.point_weights()
    vtx = mesh.vertices()
    fv, fr = fit_vertex_values(verts, w, values, vtx)
    return {"vertices": vtx, "values": fv, "residuals": fr, "errors": error_norms(fr, interior)}
