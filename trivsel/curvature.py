"""Absolute curvature of the graph of trivariate data (section 2, eqs. 4-10).

The graph of ``f(x, y, z)`` is the hypersurface ``s(x) = (x, y, z, f(x, y, z))`` of
R^4 (eq. 4).  With gradient ``g = (f_x, f_y, f_z)`` and Hessian ``H`` its upward
unit normal is ``n = (-g, 1) / l`` with ``l = sqrt(1 + |g|^2)`` (eq. 7), and the
Gauss-Weingarten map is (eq. 8)

.. math::  W = -A = \\frac{1}{l} H (I + g g^T)^{-1}.

The eigenvalues ``kappa_1, kappa_2, kappa_3`` of ``W`` are the principal
curvatures (eq. 9) and the weight of a data point is the absolute curvature
(eq. 10)

.. math::  K = |\\kappa_1| + |\\kappa_2| + |\\kappa_3|.

For data, ``g`` and ``H`` come from a local least-squares trivariate quadratic
fitted around each point over its edge neighbours in the initial triangulation
(:func:`fit_quadratic`), as summarised at the end of section 2 (the details are
in Hamann 1994b, which we do not have; the choices made here are documented in
:func:`fit_quadratic`).  This is the ``"direct"`` estimator.

The ``"local-frame"`` estimator (:func:`local_frame_curvature`) follows the
method of Hamann 1994b ("Curvature approximation of 3D manifolds in 4D space",
CAGD 11(6)): a normal in R^4 averaged from the lifted tetrahedra around the
point, a local orthonormal frame on it, a quadratic height function fitted in
that frame over the same neighbourhood, and eq. (8) in the frame.
:func:`absolute_curvature` selects between them (``estimator=``).

:func:`analytic_absolute_curvature` evaluates ``K`` from
the exact derivatives of the five Table-1 functions, for tests and diagnostics.

Everything is vectorised over points: the least-squares problems are solved as
stacked (batched) LAPACK calls on chunks of points grouped by neighbourhood size.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .data import points_values
from .functions import resolve_function
from .exceptions import InputError, check_threads

__all__ = [
    "fit_quadratic",
    "principal_curvatures",
    "absolute_curvature",
    "local_frame_curvature",
    "vertex_normals",
    "tet_normals",
    "analytic_derivatives",
    "analytic_absolute_curvature",
]

#: Coefficients of the local quadratic: 1, x, y, z, x^2, y^2, z^2, xy, xz, yz.
_N_COEF = 10


# ---------------------------------------------------------------------------
# principal curvatures (eqs. 8-10)
# ---------------------------------------------------------------------------

def principal_curvatures(grad, hess):
    """Principal curvatures of the graph of ``f`` from its gradient and Hessian (eqs. 7-9).

    Returns the eigenvalues of the Gauss-Weingarten matrix of eq. (8),

    .. math::  W = \\frac{1}{l} H (I + g g^T)^{-1}, \\qquad l = \\sqrt{1 + |g|^2},

    which the paper writes as ``-A``.  ``W`` is not symmetric, but it is similar to
    the symmetric matrix ``(1/l) S H S`` with ``S = (I + g g^T)^{-1/2}``
    (``W = S^{-1} [(1/l) S H S] S``), and

    .. math::  S = I + c\\, g g^T, \\qquad c = -\\frac{1}{l (1 + l)}
               \\;\\Big(= \\frac{1/l - 1}{|g|^2}\\Big),

    which is smooth at ``g = 0`` (no division by ``|g|``).  The eigenvalues are
    therefore computed with :func:`numpy.linalg.eigvalsh` of the symmetric form:
    always real, accurate, vectorised.

    Sign convention: the curvatures are those of eq. (8) as printed, i.e. with
    respect to the upward normal ``(-g, 1)/l`` of eq. (7): a convex ``f`` (such as
    Table-1 function 1) has positive curvatures, and at a critical point
    (``g = 0``) they are the eigenvalues of ``H``.  The opposite convention (the
    eigenvalues of ``A``) only flips all signs; the absolute curvature ``K`` of
    eq. (10) does not depend on it.

    Parameters
    ----------
    grad : (..., 3) array_like
        Gradients ``(f_x, f_y, f_z)``.
    hess : (..., 3, 3) array_like
        Hessians (symmetric; only the symmetric part is used).

    Returns
    -------
    (..., 3) float64
        ``kappa_1 <= kappa_2 <= kappa_3`` for every point.
    """
    g = np.asarray(grad, dtype=float)
    h = np.asarray(hess, dtype=float)
    if g.shape[-1:] != (3,) or h.shape[-2:] != (3, 3) or g.shape[:-1] != h.shape[:-2]:
        raise ValueError(f"grad must be (..., 3) and hess (..., 3, 3) with matching leading "
                         f"dimensions, got {g.shape} and {h.shape}")
    g2 = np.einsum("...i,...i->...", g, g)
    ell = np.sqrt(1.0 + g2)
    c = -1.0 / (ell * (1.0 + ell))
    s = np.eye(3) + c[..., None, None] * g[..., :, None] * g[..., None, :]
    w = (s @ h @ s) / ell[..., None, None]
    w = 0.5 * (w + np.swapaxes(w, -1, -2))
    return np.linalg.eigvalsh(w)


def _abs_sum(kappa):
    """Eq. (10): ``K = |k1| + |k2| + |k3|``."""
    return np.abs(kappa).sum(axis=-1)


# ---------------------------------------------------------------------------
# local least-squares quadratic
# ---------------------------------------------------------------------------

def _upper_triangular_inverse(r):
    """Inverse of a stack of upper-triangular matrices by back substitution.

    Singular (zero-diagonal) matrices give ``inf``/``nan`` entries instead of an
    exception, which the caller treats as rank deficiency.
    """
    n, k, _ = r.shape
    x = np.zeros_like(r)
    eye = np.eye(k)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for i in range(k - 1, -1, -1):
            rhs = eye[i] - np.einsum("nk,nkj->nj", r[:, i, i + 1:], x[:, i + 1:, :])
            x[:, i, :] = rhs / r[:, i, i][:, None]
    return x


def _design(u):
    """Quadratic design matrix (..., 10) from scaled local coordinates u (..., 3)."""
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    return np.stack([np.ones_like(x), x, y, z, x * x, y * y, z * z, x * y, x * z, y * z], axis=-1)


def _scaled_offsets(d, mask):
    """Zero the padding rows of offsets ``d`` (n, m, k) and scale each row set to ``max |d| = 1``.

    Returns the scaled offsets and the per-point length scale ``h`` (1 for an
    isolated point, whose offsets are all zero).
    """
    d = d * mask[..., None]
    scale = np.max(np.abs(d), axis=(1, 2))
    scale[scale == 0] = 1.0                                            # isolated point
    return d / scale[:, None, None], scale


def _solve_scaled(u, b, mask, rtol):
    """Batched least-squares quadratic ``q(u) ~ b`` in scaled coordinates, with a rank test.

    Parameters
    ----------
    u : (n, m, 3)
        Scaled local coordinates (padding rows are zeroed through ``mask``).
    b : (n, m)
        Right-hand sides.
    mask : (n, m) bool
        False for padding rows (they become zero rows: weight 0).

    Returns
    -------
    coef : (n, 10)
        Coefficients (min-norm where deficient).
    deficient : (n,) bool
        ``sigma_min <= rtol * sigma_max`` for the design matrix.
    """
    n, m, _ = u.shape
    rows = max(m, _N_COEF + 1)
    aug = np.zeros((n, rows, _N_COEF + 1))
    aug[:, :m, :_N_COEF] = _design(u) * mask[..., None]
    aug[:, :m, _N_COEF] = b * mask
    # QR of [A | b]: R_aug = [[R, Q^T b], [0, rho]]; LS solution is R^-1 (Q^T b).
    r_aug = np.linalg.qr(aug, mode="r")
    r = np.ascontiguousarray(r_aug[:, :_N_COEF, :_N_COEF])
    qtb = r_aug[:, :_N_COEF, _N_COEF]
    rinv = _upper_triangular_inverse(r)
    with np.errstate(invalid="ignore", over="ignore"):
        cond_f = np.linalg.norm(r, axis=(1, 2)) * np.linalg.norm(rinv, axis=(1, 2))
        coef = np.einsum("nij,nj->ni", rinv, qtb)
    # cond_2 <= cond_F (Frobenius), so cond_F < 1/rtol certifies full rank without an SVD.
    sure = np.isfinite(cond_f) & (cond_f < 1.0 / rtol) & np.all(np.isfinite(coef), axis=1)
    deficient = np.zeros(n, dtype=bool)
    check = np.flatnonzero(~sure)
    if check.size:
        uu, sv, vt = np.linalg.svd(r[check])
        bad = sv[:, -1] <= rtol * sv[:, 0]
        deficient[check] = bad
        # SVD solution: exact for the borderline full-rank ones, min-norm (singular
        # values below rtol * sigma_max dropped) for the deficient ones.
        keep = sv > rtol * sv[:, :1]
        inv_s = np.where(keep, 1.0 / np.where(keep, sv, 1.0), 0.0)
        y = np.einsum("nji,nj->ni", uu, qtb[check]) * inv_s
        coef[check] = np.einsum("nji,nj->ni", vt, y)
    return coef, deficient


def _fit_block(points, values, centres, nbr, mask, rtol):
    """Direct fit of one block of equally padded neighbourhoods.

    Parameters
    ----------
    centres : (n,) int
        Point the quadratic is centred at.
    nbr : (n, m) int
        Neighbourhood point indices (the centre included), padded.
    mask : (n, m) bool
        False for padding rows.

    Returns
    -------
    coef : (n, 10)
        Coefficients in scaled coordinates (min-norm where deficient).
    scale : (n,)
        The local length scale ``h``.
    deficient : (n,) bool
        ``sigma_min <= rtol * sigma_max`` for the design matrix.
    """
    u, scale = _scaled_offsets(points[nbr] - points[centres][:, None, :], mask)
    coef, deficient = _solve_scaled(u, values[nbr] - values[centres][:, None], mask, rtol)
    return coef, scale, deficient


#: Output layout of the block fits: (trailing shape, dtype) per returned array.
_DIRECT_OUT = (((_N_COEF,), float), ((), float), ((), bool))
_FRAME_OUT = (((_N_COEF,), float), ((), float), ((), bool), ((), bool))


def _fit_rows(block, centres, ptr, idx, chunk_rows, chunk_points, out=_DIRECT_OUT, threads=1):
    """Run ``block(centres, nbr, mask)`` over neighbourhoods given as CSR rows ``(ptr, idx)``.

    Neighbourhoods are sorted by size and processed in chunks padded to the
    chunk's largest size, so padding is small and memory is bounded by about
    ``chunk_rows * 11 * 8`` bytes per array and thread.  ``out`` gives the
    trailing shape and dtype of each array ``block`` returns.  With ``threads``
    > 1 the chunks run on a thread pool (numpy's batched LAPACK and most array
    operations release the GIL); every chunk writes its own rows, so the result
    does not depend on ``threads``.
    """
    sizes = np.diff(ptr)
    order = np.argsort(sizes, kind="stable")
    n = centres.size
    results = [np.empty((n,) + shape, dtype=dtype) for shape, dtype in out]
    chunks = []
    start = 0
    while start < n:
        m = max(int(sizes[order[min(start + chunk_points, n) - 1]]), 1)
        stop = min(start + chunk_points, start + max(chunk_rows // m, 1), n)
        m = max(int(sizes[order[stop - 1]]), 1)  # sizes sorted: last is the largest
        chunks.append((start, stop, m))
        start = stop

    def run(chunk):
        start, stop, m = chunk
        sel = order[start:stop]
        lo, ln = ptr[sel], sizes[sel]
        col = np.arange(m)
        mask = col[None, :] < ln[:, None]
        pos = np.where(mask, lo[:, None] + col[None, :], 0)
        nbr = np.where(mask, idx[pos] if idx.size else 0, centres[sel][:, None])
        for res, part in zip(results, block(centres[sel], nbr, mask)):
            res[sel] = part

    if threads > 1 and len(chunks) > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(min(threads, len(chunks))) as pool:
            list(pool.map(run, chunks))
    else:
        for chunk in chunks:
            run(chunk)
    return results


def _widening_fits(npts, indptr, indices, max_ring, fit):
    """Fit over closed k-rings, widening (k = 1, 2, ..., ``max_ring``) where deficient.

    ``fit(todo, ptr, idx, last)`` fits the points ``todo`` over the CSR rows
    ``(ptr, idx)`` (row i: the neighbourhood of ``todo[i]``) and returns
    ``(arrays, deficient)``; ``arrays`` are stored per point, the ``deficient``
    points are refitted over the next ring (``last``: there is none, so deficient
    fits must be usable, i.e. minimum-norm).

    Returns
    -------
    arrays : list of (npts, ...) arrays
    ring : (npts,) int8
        The ring finally used.
    still_deficient : (npts,) bool
        Deficient even over ``max_ring``.
    """
    # closed 1-ring (point itself + edge neighbours) as a sparse pattern
    adj = sp.csr_matrix((np.ones(indices.size, dtype=np.int32), indices, indptr), shape=(npts, npts))
    closed = (adj + sp.identity(npts, dtype=np.int32, format="csr")).tocsr()
    del adj  # as large as the graph: not kept through the fits
    closed.sum_duplicates()
    closed.sort_indices()
    # int64 indices once, in place of the int32 ones (the fits index with them)
    closed.indptr, closed.indices = closed.indptr.astype(np.int64), closed.indices.astype(np.int64)

    results = None
    ring = np.ones(npts, dtype=np.int8)
    todo = np.arange(npts)
    rows = closed
    for k in range(1, max_ring + 1):
        arrays, deficient = fit(todo, rows.indptr.astype(np.int64, copy=False),
                                rows.indices.astype(np.int64, copy=False), k == max_ring)
        if results is None:
            results = list(arrays)  # the first ring fits every point, in order: kept, not copied
        else:
            for res, a in zip(results, arrays):
                res[todo] = a
        del arrays
        ring[todo] = k
        if not deficient.any() or k == max_ring:
            break
        # widen: (k+1)-ring of the deficient points = their k-ring rows times the closed 1-ring
        rows = rows[np.flatnonzero(deficient)] @ closed
        rows.sort_indices()
        todo = todo[deficient]
    still = np.zeros(npts, dtype=bool)
    still[todo[deficient]] = True
    return results, ring, still


def _coef_to_derivatives(coef, scale):
    """Gradient and Hessian at the centre from scaled-coordinate coefficients."""
    h1 = scale[:, None]
    h2 = (scale * scale)[:, None]
    grad = coef[:, 1:4] / h1
    hess = np.empty((coef.shape[0], 3, 3))
    diag = 2.0 * coef[:, 4:7] / h2
    xy, xz, yz = (coef[:, 7:10] / h2).T
    hess[:, 0, 0], hess[:, 1, 1], hess[:, 2, 2] = diag.T
    hess[:, 0, 1] = hess[:, 1, 0] = xy
    hess[:, 0, 2] = hess[:, 2, 0] = xz
    hess[:, 1, 2] = hess[:, 2, 1] = yz
    return grad, hess


def _csr_rows(ptr, idx, rows):
    """The CSR sub-matrix of the given rows."""
    lo, ln = ptr[rows], np.diff(ptr)[rows]
    sub_ptr = np.zeros(rows.size + 1, dtype=np.int64)
    np.cumsum(ln, out=sub_ptr[1:])
    take = np.repeat(lo - sub_ptr[:-1], ln) + np.arange(sub_ptr[-1])
    return sub_ptr, idx[take]


def _shared_stencils(points, todo, ptr, idx, min_rows=64):
    """Groups of rows with one common neighbourhood geometry.

    On a grid with C-ordered point indices, all interior points list the same
    index offsets, and so do the points of each face, edge and corner class.
    Rows are grouped by their index offsets (a hash, then checked exactly); a
    group is kept if it has at least ``min_rows`` rows, and within it only the
    rows whose coordinate offsets agree with its first row's (to 1e-9 of their
    size, so rounding of the grid coordinates does not matter).  Everything goes
    a column (one offset, one axis) at a time: rows x offsets temporaries of a
    2-million-point grid would be hundreds of MB each.

    Returns a list of ``(rows, index offsets)``.
    """
    ln = np.diff(ptr)
    if ln.size == 0:
        return []
    L = int(ln.max())
    starts = ptr[:-1]
    mult = np.random.default_rng(0).integers(1, 2**62, size=L) | 1
    h = ln * 1000003
    last = idx.size - 1
    with np.errstate(over="ignore"):
        for k in range(L):
            off_k = np.where(k < ln, idx[np.minimum(starts + k, last)] - todo, 0)
            h = h + off_k * mult[k]
    uniq, inv, counts = np.unique(h, return_inverse=True, return_counts=True)
    by_group = np.argsort(inv.ravel(), kind="stable")  # each group's rows, ascending
    ends = np.cumsum(counts)
    groups = []
    cols = [np.ascontiguousarray(points[:, a]) for a in range(3)]
    for g in np.flatnonzero(counts >= min_rows):
        rows = by_group[ends[g] - counts[g]:ends[g]]
        r0 = rows[0]
        m = int(ln[r0])
        pattern = idx[starts[r0]:starts[r0] + m] - todo[r0]
        rows = rows[ln[rows] == m]
        sr, c = starts[rows], todo[rows]
        ok = np.ones(rows.size, bool)
        for k in range(m):
            ok &= idx[sr + k] == c + pattern[k]
        rows, c = rows[ok], c[ok]
        d0 = points[todo[r0] + pattern] - points[todo[r0]]
        tol = 1e-9 * max(float(np.abs(d0).max()), np.finfo(float).tiny)
        ok = np.ones(rows.size, bool)
        for a in range(3):
            x = cols[a]
            xc = x[c]
            for k in range(m):
                ok &= np.abs(x[c + pattern[k]] - xc - d0[k, a]) <= tol
        rows = rows[ok]
        if rows.size >= min_rows:
            groups.append((rows, pattern))
    return groups


def _fit_shared(points, values, centres, pattern, rtol, chunk_points, need_min_norm):
    """Least-squares quadratics of points that share one neighbourhood geometry.

    One SVD of the common design matrix replaces a QR per point: the
    coefficients are ``pinv(A) b`` for every right-hand side ``b``.  Returns
    ``(coef, scale, deficient)``; a rank-deficient design gives the minimum-norm
    coefficients if ``need_min_norm`` (the widest ring) and None otherwise (the
    points are refitted over a wider ring anyway).
    """
    c0 = centres[0]
    u, scale = _scaled_offsets((points[c0 + pattern] - points[c0])[None], np.ones((1, pattern.size), bool))
    a = _design(u[0])
    uu, sv, vt = np.linalg.svd(a, full_matrices=False)
    # fewer neighbours than coefficients (a 1-ring on a box edge has 6) is deficient
    # whatever the min(m, 10) singular values say: the per-point fits pad to 10 rows
    deficient = bool(pattern.size < _N_COEF or sv[-1] <= rtol * sv[0])
    coef = None
    if not deficient or need_min_norm:
        keep = sv > rtol * sv[0]
        inv_s = np.where(keep, 1.0 / np.where(keep, sv, 1.0), 0.0)
        pinv_t = (uu * inv_s) @ vt  # (m, 10): b @ pinv_t = pinv(A) b
        coef = np.empty((centres.size, _N_COEF))
        for start in range(0, centres.size, chunk_points):
            c = centres[start:start + chunk_points]
            coef[start:start + c.size] = (values[c[:, None] + pattern] - values[c][:, None]) @ pinv_t
    return coef, np.full(centres.size, scale[0]), np.full(centres.size, deficient)


def fit_quadratic(points, values, indptr, indices, *, rtol=1e-8, max_ring=3,
                  chunk_rows=300_000, chunk_points=20_000, threads=1, grid=False, return_info=False):
    """Local least-squares quadratics: gradient and Hessian at every data point.

    For each point ``x_0`` the trivariate quadratic

    .. math::  q(u) = c_0 + c_1 u + c_2 v + c_3 w + c_4 u^2 + c_5 v^2 + c_6 w^2
               + c_7 uv + c_8 uw + c_9 vw,
               \\qquad (u, v, w) = (\\mathbf{x} - \\mathbf{x}_0) / h,

    is fitted by (unweighted) least squares to the data at ``x_0`` itself and its
    edge neighbours in the initial triangulation (the "local least square
    polynomial approximation" of sections 1-2).  The coordinates are centred at
    ``x_0`` and scaled by ``h``, the largest coordinate offset in the
    neighbourhood, so that ``|u|, |v|, |w| <= 1`` and the design matrix is well
    conditioned; the values are centred at ``f(x_0)`` (this only shifts ``c_0``).
    The derivatives at ``x_0`` are then ``f_x = c_1 / h``, ``f_xx = 2 c_4 / h^2``,
    ``f_xy = c_7 / h^2`` etc., the input of eq. (8).  A quadratic ``f`` is
    reproduced exactly wherever the fit has full rank.

    Rank deficiency and widening: the fit is rank deficient if the design matrix
    has ``sigma_min <= rtol * sigma_max``.  This happens e.g. on the faces, edges
    and corners of a grid, where the 1-ring has only two distinct values of the
    normal coordinate, so ``u`` and ``u^2`` cannot be separated.  Such points are
    refitted over the 2-ring (neighbours of neighbours), and if still deficient
    over the 3-ring (``max_ring``).  Points still deficient over the widest ring
    get the minimum-norm least-squares solution in the scaled coefficients
    (singular values ``<= rtol * sigma_max`` dropped); their derivatives are then
    only one choice among many equally good fits, and ``info['min_norm']`` flags
    them.  This needs fewer than 10 points in reach (tiny data sets) or
    degenerate point configurations.

    Algorithm: per chunk, the augmented matrix ``[A | b]`` is QR-factorised
    (batched LAPACK), giving ``R`` and ``Q^T b``.  ``R`` is inverted by batched
    back substitution; ``cond_F(R) = ||R||_F ||R^-1||_F >= cond_2(A)``, so
    ``cond_F < 1/rtol`` certifies full rank without an SVD.  Only the remaining
    (deficient or borderline) fits take an SVD of the 10 x 10 ``R``.

    Parameters
    ----------
    points : (N, 3) array_like
    values : (N,) array_like
    indptr, indices : CSR arrays
        Edge-neighbour graph of the initial triangulation, e.g. from
        :func:`trivsel.triangulation.edge_neighbours` (the point itself need not,
        but may, be listed).
    rtol : float
        Relative singular-value threshold for rank deficiency.
    max_ring : int
        Widest ring tried before falling back to the minimum-norm solution.
    chunk_rows, chunk_points : int
        Memory bounds: at most ``chunk_points`` points and ``chunk_rows`` padded
        design rows per batched solve.
    threads : int
        Chunks solved in parallel (the result is the same for any value).
    grid : bool
        The points are a regular grid in C order (``trivsel.sample_grid``,
        ``grid_from_array``): the points whose neighbourhood is the full stencil
        and the points of each boundary class share one design matrix per
        class, so one SVD solves each class (``pinv(A) b``; equal to the
        per-point QR up to rounding, and much faster); the rest take the general
        path.  Only a hint: rows share a solve only where their coordinate
        offsets are checked to agree.
    return_info : bool
        Also return a dict with ``ring`` ((N,) int8, the ring finally used) and
        ``min_norm`` ((N,) bool).

    Returns
    -------
    grad : (N, 3) float64
    hess : (N, 3, 3) float64
    used_two_ring : (N,) bool
        True where the 1-ring fit was rank deficient and a wider ring was used.
    info : dict, only if ``return_info``
    """
    p, f = points_values(points, values)
    npts = p.shape[0]
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    if indptr.shape != (npts + 1,):
        raise InputError(f"indptr must have length N + 1 = {npts + 1}, got {indptr.shape}")
    if max_ring < 1:
        raise ValueError(f"max_ring must be >= 1, got {max_ring}")
    threads = check_threads(threads)

    def block(centres, nbr, mask):
        return _fit_block(p, f, centres, nbr, mask, rtol)

    def fit(todo, ptr, idx, last):
        coef = np.zeros((todo.size, _N_COEF))
        scale = np.ones(todo.size)
        deficient = np.zeros(todo.size, dtype=bool)
        done = np.zeros(todo.size, dtype=bool)
        for rows, pattern in (_shared_stencils(p, todo, ptr, idx) if grid else []):
            c, h, dfc = _fit_shared(p, f, todo[rows], pattern, rtol, chunk_points, last)
            if c is not None:
                coef[rows] = c
            scale[rows], deficient[rows], done[rows] = h, dfc, True
        rest = np.flatnonzero(~done)
        if rest.size == todo.size:
            coef, scale, deficient = _fit_rows(block, todo, ptr, idx, chunk_rows, chunk_points, threads=threads)
        elif rest.size:
            sub_ptr, sub_idx = _csr_rows(ptr, idx, rest)
            coef[rest], scale[rest], deficient[rest] = _fit_rows(block, todo[rest], sub_ptr, sub_idx,
                                                                 chunk_rows, chunk_points, threads=threads)
        return _coef_to_derivatives(coef, scale), deficient

    (grad, hess), ring, min_norm = _widening_fits(npts, indptr, indices, max_ring, fit)
    used = ring > 1
    if return_info:
        return grad, hess, used, {"ring": ring, "min_norm": min_norm}
    return grad, hess, used


# ---------------------------------------------------------------------------
# the paper's estimator: local frame in R^4 (Hamann 1994b)
# ---------------------------------------------------------------------------

#: Normal weightings accepted by :func:`vertex_normals`.
NORMAL_WEIGHTINGS = ("volume", "uniform")


def _det3(a, b, c):
    """Determinant of the 3 x 3 matrices with rows ``a, b, c`` (..., 3)."""
    return np.einsum("...i,...i->...", a, np.cross(b, c))


def tet_normals(points, values, tets):
    """Upward normals in R^4 of the lifted tetrahedra ``(x, y, z, f)``, unnormalised.

    For a tetrahedron with lifted vertices ``P_0, ..., P_3`` the hyperplane they
    span has the normal given by the generalised cross product of the edge
    vectors ``e_i = P_i - P_0``: ``n_k = (-1)^k det(E without column k)``, the
    cofactors of a 4 x 4 determinant whose other three rows are the ``e_i``
    (orthogonal to every ``e_i`` by construction).  Oriented so that the last
    component is positive, it is

    .. math::  n_T = 6 V_T (-\\nabla L_T, 1), \\qquad |n_T| = 6\\,\\mathrm{vol}_3(T^*),

    where ``V_T`` is the tetrahedron's volume in R^3, ``L_T`` the linear
    interpolant of the data on it, and ``vol_3(T*) = V_T sqrt(1 + |grad L_T|^2)``
    the 3-volume of the lifted tetrahedron in R^4.  The same hyperplane (and
    normal) is obtained from whichever vertex the edges are taken.  Degenerate
    tetrahedra (``V_T = 0``, vertical or no hyperplane) give the zero vector.

    Returns
    -------
    (M, 4) float64
    """
    p = np.asarray(points, dtype=float)
    f = np.asarray(values, dtype=float)
    t = np.asarray(tets, dtype=np.int64)
    lifted = np.concatenate([p, f[:, None]], axis=1)
    e = lifted[t[:, 1:]] - lifted[t[:, :1]]                             # (M, 3, 4)
    cols = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))
    raw = np.stack([(-1.0) ** k * _det3(*(e[:, i, list(c)] for i in range(3)))
                    for k, c in enumerate(cols)], axis=1)
    return raw * np.sign(raw[:, 3:4])


def vertex_normals(points, values, tets, weighting="volume", chunk=500_000):
    """Approximate unit normals in R^4 of the graph at the vertices (Hamann 1994b, step 1).

    The normals of the lifted tetrahedra incident to a vertex (:func:`tet_normals`,
    all oriented with positive last component) are averaged and normalised.

    ``weighting="volume"`` (default) weights each unit normal by the 3-volume of
    the lifted tetrahedron in R^4, i.e. it sums the raw generalised cross
    products.  Since ``n_T = 6 V_T (-grad L_T, 1)``, the result is the upward
    normal ``(-g, 1) / sqrt(1 + |g|^2)`` of the *volume-weighted mean gradient*
    ``g`` of the piecewise-linear interpolant over the vertex star.  Why this
    one: (i) for a quadratic ``f`` and a point-symmetric star (every interior
    point of a Kuhn-split grid) the quadratic parts of opposite tetrahedra cancel
    and ``g`` is the exact gradient, so the normal is exact; (ii) thin or sliver
    tetrahedra, whose interpolant gradient is unreliable, get a small weight;
    (iii) it needs no normalisation per tetrahedron.
    ``weighting="uniform"`` is the unweighted mean of the unit normals
    ``(-grad L_T, 1) / sqrt(1 + |grad L_T|^2)`` (degenerate tetrahedra skipped);
    it is not exact for quadratics on symmetric stars (the unit normals of
    opposite tetrahedra do not average to a multiple of the true one) and is kept
    for the ablation.

    Vertices in no non-degenerate tetrahedron get ``(0, 0, 0, 1)`` (the frame of
    the direct fit).

    Parameters
    ----------
    points : (N, 3) array_like
    values : (N,) array_like
    tets : (M, 4) int array_like
    weighting : {"volume", "uniform"}
    chunk : int
        Tetrahedra processed at a time (memory bound).

    Returns
    -------
    (N, 4) float64
        Unit normals, last component positive.
    """
    if weighting not in NORMAL_WEIGHTINGS:
        raise ValueError(f"weighting must be one of {NORMAL_WEIGHTINGS}, got {weighting!r}")
    p = np.asarray(points, dtype=float)
    f = np.asarray(values, dtype=float)
    t = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    npts = p.shape[0]
    acc = np.zeros((npts, 4))
    for start in range(0, t.shape[0], chunk):
        tt = t[start:start + chunk]
        nt = tet_normals(p, f, tt)
        if weighting == "uniform":
            norm = np.linalg.norm(nt, axis=1, keepdims=True)
            nt = np.divide(nt, norm, out=np.zeros_like(nt), where=norm > 0)
        flat = tt.ravel()
        for k in range(4):
            acc[:, k] += np.bincount(flat, weights=np.repeat(nt[:, k], 4), minlength=npts)
    ok = acc[:, 3] > 0
    acc[~ok] = (0.0, 0.0, 0.0, 1.0)
    return acc / np.linalg.norm(acc, axis=1, keepdims=True)


def _frame_block(points, lifted, normals, centres, nbr, mask, rtol):
    """Local-frame fit of one block of equally padded neighbourhoods.

    The neighbourhood decision (``deficient``) uses the same (x, y, z) design as
    the direct fit, so both estimators use the same rings.  The fit itself is the
    quadratic height ``h(u, v, w)`` over the tangent coordinates in the frame of
    :func:`local_frame_curvature`; ``frame_deficient`` is its own rank test.

    Returns
    -------
    coef : (n, 10), scale : (n,), deficient : (n,) bool, frame_deficient : (n,) bool
    """
    ux, _ = _scaled_offsets(points[nbr] - points[centres][:, None, :], mask)
    _, deficient = _solve_scaled(ux, np.zeros(mask.shape), mask, rtol)
    d = lifted[nbr] - lifted[centres][:, None, :]                      # (n, m, 4)
    nrm = normals[centres]
    a, b = nrm[:, :3], nrm[:, 3]
    dx, df = d[..., :3], d[..., 3]
    ad = np.einsum("nmi,ni->nm", dx, a)
    height = ad + b[:, None] * df                                       # n . d
    # tangent coordinates t_i . d with t_i = (e_i - a_i a / (1 + b), -a_i)
    tang = dx - a[:, None, :] * (ad / (1.0 + b)[:, None] + df)[..., None]
    u, scale = _scaled_offsets(tang, mask)
    coef, frame_deficient = _solve_scaled(u, height, mask, rtol)
    return coef, scale, deficient, frame_deficient


def local_frame_curvature(points, values, tets=None, neighbours=None, *, weighting="volume",
                          rtol=1e-8, max_ring=3, chunk_rows=300_000, chunk_points=20_000,
                          threads=1, return_info=False):
    """Absolute curvature (eq. 10) by the local-frame method of Hamann (1994b).

    Section 2 of Hamann & Chen (1994), "Data point selection for piecewise
    trilinear approximation", defers the curvature estimate to
    B. Hamann, "Curvature approximation of 3D manifolds in 4D space", Computer
    Aided Geometric Design 11(6), 1994 ("Hamann 1994b"): the graph of ``f`` is a
    3-manifold in R^4, and at every data point ``s_0 = (x_0, f_0)``

    1. an approximate unit normal ``n`` is estimated from the normals of the
       lifted tetrahedra ``(x, y, z, f)`` incident to the vertex in the initial
       triangulation (:func:`vertex_normals`; by default each weighted by its
       3-volume in R^4, see there for why);
    2. a local orthonormal frame ``(t_1, t_2, t_3, n)`` is set up.  With
       ``n = (a, b)``, ``a in R^3``, ``b > 0``, we take the minimal rotation of
       the coordinate frame that carries ``e_4`` to ``n``:
       ``t_i = (e_i - a_i a / (1 + b), -a_i)``.  (Any orthonormal tangent basis,
       e.g. Gram-Schmidt of the coordinate axes against ``n``, gives the same
       curvatures: the full quadratic space and eq. 8 are invariant under
       rotations of ``(u, v, w)``; this one is closed-form and smooth);
    3. the neighbours ``s_j`` (the point itself and its edge neighbours in the
       initial triangulation, widened to the 2-ring (3-ring) exactly where the
       direct fit :func:`fit_quadratic` widens, i.e. where the (x, y, z) design is
       rank deficient) are expressed in that frame: tangential coordinates
       ``u_j = t_i . (s_j - s_0)`` and height ``h_j = n . (s_j - s_0)``;
    4. a trivariate quadratic height function ``h(u, v, w)``, constant and
       first-order terms included (the estimated normal is not exact), is fitted
       by least squares (the same scaled, batched QR solver as the direct fit);
       its gradient ``g`` and Hessian ``H`` at the origin give the principal
       curvatures through eq. 8 in the local frame
       (:func:`principal_curvatures`), and ``K = |k1| + |k2| + |k3|``.

    If ``n`` were the exact normal, ``g`` would vanish and ``H`` would be the
    second fundamental form; fitting ``g`` too makes the estimate insensitive to
    the normal's error to first order.  The curvature signs refer to the upward
    normal, as for the direct fit (``n`` has positive last component).

    Rank deficiency of the fit in the local frame (``sigma_min <= rtol *
    sigma_max``) falls back to the minimum-norm solution; points still
    deficient over ``max_ring`` in the (x, y, z) design or deficient in the frame
    are flagged in ``info['min_norm']``.

    Parameters
    ----------
    points : (N, 3) array_like
    values : (N,) array_like
    tets : (M, 4) int array_like, optional
        The initial triangulation (Kuhn split for grids, Delaunay for scattered
        points); needed for the normals.  If both ``tets`` and ``neighbours`` are
        omitted, the Delaunay triangulation of ``points`` is built.
    neighbours : (indptr, indices), optional
        Edge-neighbour graph (CSR) of ``tets``; built from ``tets`` if omitted.
    weighting : {"volume", "uniform"}
        Averaging of the tetrahedron normals (:func:`vertex_normals`).
    rtol, max_ring, chunk_rows, chunk_points, threads
        As for :func:`fit_quadratic`.
    return_info : bool
        Also return a dict with ``normal`` ((N, 4)), ``grad`` ((N, 3)) and
        ``hess`` ((N, 3, 3)) of the height function in the local frame,
        ``kappa`` ((N, 3), principal curvatures), ``ring`` and ``min_norm``.

    Returns
    -------
    K : (N,) float64
    info : dict, only if ``return_info``

    Notes
    -----
    Unlike the direct fit, this estimate is not exact for quadratic ``f``: the
    graph of a quadratic is not a quadratic height function over a tilted frame.
    On Kuhn-split grids it agrees with the (there exact) direct fit to
    ``O(h^2)`` at interior points (f1: max difference 5.7e-3, 1.4e-3, 3.5e-4 for
    ``n = 8, 16, 32``) but only to ``O(h)`` on the grid boundary, where the star
    and the 2-ring are one-sided (f1: 0.27, 0.13, 0.06).  It is better than the
    direct fit where the graph is steep, e.g. near the rim of a hypersphere
    graph.  Boundary points are kept by the selection anyway (section 3).

    See Also
    --------
    absolute_curvature : ``estimator="local-frame"`` calls this function.
    fit_quadratic : the direct estimator (quadratic in x, y, z).
    """
    from .triangulation import delaunay_tetrahedra, edge_neighbours

    p, f = points_values(points, values)
    npts = p.shape[0]
    if max_ring < 1:
        raise ValueError(f"max_ring must be >= 1, got {max_ring}")
    if tets is None:
        if neighbours is not None:
            raise InputError("the local-frame curvature estimator needs the tetrahedra of the "
                             "initial triangulation (tets) for the normals; got only neighbours")
        tets = delaunay_tetrahedra(p)
    tets = np.asarray(tets, dtype=np.int64)
    if neighbours is None:
        neighbours = edge_neighbours(tets, npts)
    indptr, indices = (np.asarray(a, dtype=np.int64) for a in neighbours)
    if indptr.shape != (npts + 1,):
        raise InputError(f"indptr must have length N + 1 = {npts + 1}, got {indptr.shape}")

    threads = check_threads(threads)
    normals = vertex_normals(p, f, tets, weighting=weighting)
    lifted = np.concatenate([p, f[:, None]], axis=1)

    def block(centres, nbr, mask):
        return _frame_block(p, lifted, normals, centres, nbr, mask, rtol)

    def fit(todo, ptr, idx, last):
        coef, scale, deficient, frame_def = _fit_rows(block, todo, ptr, idx, chunk_rows,
                                                      chunk_points, out=_FRAME_OUT, threads=threads)
        grad, hess = _coef_to_derivatives(coef, scale)
        return (grad, hess, frame_def), deficient

    (grad, hess, frame_def), ring, still = _widening_fits(npts, indptr, indices, max_ring, fit)
    kappa = principal_curvatures(grad, hess)
    K = _abs_sum(kappa)
    if return_info:
        return K, {"normal": normals, "grad": grad, "hess": hess, "kappa": kappa,
                   "ring": ring, "min_norm": still | frame_def}
    return K


# ---------------------------------------------------------------------------
# absolute curvature of data (eq. 10)
# ---------------------------------------------------------------------------

#: Curvature estimators accepted by :func:`absolute_curvature`.
ESTIMATORS = ("direct", "local-frame")


def absolute_curvature(points, values, tets=None, neighbours=None, *, estimator="direct",
                       **fit_options):
    """Absolute curvature ``K = |k1| + |k2| + |k3|`` (eq. 10) at every data point.

    ``estimator="direct"`` (default): derivatives of ``f`` come from
    :func:`fit_quadratic` (a quadratic in x, y, z) over the edge neighbours in the
    initial triangulation, the principal curvatures from
    :func:`principal_curvatures` (eq. 8).

    ``estimator="local-frame"``: the method of Hamann (1994b) that section 2
    defers to, :func:`local_frame_curvature`: a quadratic height function fitted
    in a local orthonormal frame of R^4 built on a normal averaged from the
    lifted tetrahedra, over the same neighbourhoods.  Needs ``tets``.

    Parameters
    ----------
    points : (N, 3) array_like
    values : (N,) array_like
    tets : (M, 4) int array, optional
        The initial triangulation (eq. 3): the Kuhn split
        (:func:`trivsel.triangulation.kuhn_tetrahedra`) for grids, the Delaunay
        triangulation for scattered points.  If both ``tets`` and ``neighbours``
        are omitted, the Delaunay triangulation of ``points`` is built.
    neighbours : (indptr, indices), optional
        A ready edge-neighbour graph (CSR); takes precedence over ``tets`` for
        the neighbourhoods.  The local-frame estimator still needs ``tets``.
    estimator : {"direct", "local-frame"}
    **fit_options
        Passed on to :func:`fit_quadratic` (``rtol``, ``max_ring``, chunk sizes,
        ``threads``) or :func:`local_frame_curvature` (the same, plus ``weighting``).

    Returns
    -------
    (N,) float64
    """
    from .triangulation import delaunay_tetrahedra, edge_neighbours

    if estimator not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")
    p = np.asarray(points, dtype=float)
    if estimator == "local-frame":
        return local_frame_curvature(p, values, tets=tets, neighbours=neighbours, **fit_options)
    if neighbours is None:
        if tets is None:
            tets = delaunay_tetrahedra(p)
        neighbours = edge_neighbours(tets, p.shape[0])
    indptr, indices = neighbours
    grad, hess, _ = fit_quadratic(p, values, indptr, indices, **fit_options)
    return _abs_sum(principal_curvatures(grad, hess))


# ---------------------------------------------------------------------------
# exact derivatives of the Table-1 functions
# ---------------------------------------------------------------------------

def analytic_derivatives(function, points):
    """Exact gradient and Hessian of Table-1 function ``function`` at ``points``.

    Written out by hand:

    1. ``0.4 (x^2 + y^2 + z^2)``: ``g = 0.8 (x, y, z)``, ``H = 0.8 I``.
    2. ``0.4 (x^2 - y^2 - z^2)``: ``g = 0.8 (x, -y, -z)``, ``H = diag(0.8, -0.8, -0.8)``.
    3. ``0.15 (x^3 + 2 x^2 y - x z^2 + 2 y^2)``:
       ``g = 0.15 (3x^2 + 4xy - z^2, 2x^2 + 4y, -2xz)``,
       ``H = 0.15 [[6x + 4y, 4x, -2z], [4x, 4, 0], [-2z, 0, -2x]]``.
    4. ``exp(-(x^2 + y^2 + z^2)/2)``: ``g = -f x``, ``H = f (x x^T - I)``.
    5. ``0.1 (cos(pi x) + cos(pi y) + cos(pi z))``: ``g_i = -0.1 pi sin(pi x_i)``,
       ``H = diag(-0.1 pi^2 cos(pi x_i))``.

    Parameters
    ----------
    function : int or str
        Table-1 number 1-5 or short name.
    points : (N, 3) array_like

    Returns
    -------
    grad : (N, 3), hess : (N, 3, 3)
    """
    num = resolve_function(function)
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"points must have shape (N, 3), got {p.shape}")
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    n = p.shape[0]
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    if num == 1:
        grad = 0.8 * p
        hess = 0.8 * eye.copy()
    elif num == 2:
        sgn = np.array([1.0, -1.0, -1.0])
        grad = 0.8 * p * sgn
        hess = 0.8 * np.broadcast_to(np.diag(sgn), (n, 3, 3)).copy()
    elif num == 3:
        grad = 0.15 * np.stack([3 * x * x + 4 * x * y - z * z, 2 * x * x + 4 * y, -2 * x * z], axis=1)
        zero = np.zeros_like(x)
        hess = 0.15 * np.stack([np.stack([6 * x + 4 * y, 4 * x, -2 * z], axis=-1),
                                np.stack([4 * x, 4 + zero, zero], axis=-1),
                                np.stack([-2 * z, zero, -2 * x], axis=-1)], axis=1)
    elif num == 4:
        f = np.exp(-0.5 * (x * x + y * y + z * z))
        grad = -f[:, None] * p
        hess = f[:, None, None] * (p[:, :, None] * p[:, None, :] - eye)
    else:  # 5
        grad = -0.1 * np.pi * np.sin(np.pi * p)
        hess = np.zeros((n, 3, 3))
        idx = np.arange(3)
        hess[:, idx, idx] = -0.1 * np.pi**2 * np.cos(np.pi * p)
    return grad, hess


def analytic_absolute_curvature(function, points):
    """Exact absolute curvature (eq. 10) of Table-1 function ``function`` at ``points``.

    Uses :func:`analytic_derivatives` and the same :func:`principal_curvatures`
    as the data-based :func:`absolute_curvature`, so the two differ only by the
    least-squares derivative error.

    Returns
    -------
    (N,) float64
    """
    grad, hess = analytic_derivatives(function, points)
    return _abs_sum(principal_curvatures(grad, hess))
