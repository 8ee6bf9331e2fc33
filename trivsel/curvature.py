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
:func:`fit_quadratic`).  :func:`analytic_absolute_curvature` evaluates ``K`` from
the exact derivatives of the five Table-1 functions, for tests and diagnostics.

Everything is vectorised over points: the least-squares problems are solved as
stacked (batched) LAPACK calls on chunks of points grouped by neighbourhood size.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .data import resolve_function
from .errors_input import InputError

__all__ = [
    "fit_quadratic",
    "principal_curvatures",
    "absolute_curvature",
    "analytic_derivatives",
    "analytic_absolute_curvature",
]

#: Monomials of the local quadratic, in coefficient order.
MONOMIALS = ("1", "x", "y", "z", "x^2", "y^2", "z^2", "xy", "xz", "yz")
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


def _fit_block(points, values, centres, nbr, mask, rtol):
    """Fit one block of equally padded neighbourhoods.

    Parameters
    ----------
    centres : (n,) int
        Point the quadratic is centred at.
    nbr : (n, m) int
        Neighbourhood point indices (the centre included), padded.
    mask : (n, m) bool
        False for padding rows (they become zero rows: weight 0).

    Returns
    -------
    coef : (n, 10)
        Coefficients in scaled coordinates (min-norm where deficient).
    scale : (n,)
        The local length scale ``h``.
    deficient : (n,) bool
        ``sigma_min <= rtol * sigma_max`` for the design matrix.
    """
    n, m = nbr.shape
    d = points[nbr] - points[centres][:, None, :]                     # (n, m, 3)
    d *= mask[..., None]
    scale = np.max(np.abs(d), axis=(1, 2))
    scale[scale == 0] = 1.0                                            # isolated point
    u = d / scale[:, None, None]
    rows = max(m, _N_COEF + 1)
    aug = np.zeros((n, rows, _N_COEF + 1))
    aug[:, :m, :_N_COEF] = _design(u) * mask[..., None]
    aug[:, :m, _N_COEF] = (values[nbr] - values[centres][:, None]) * mask
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
    return coef, scale, deficient


def _fit_rows(points, values, centres, ptr, idx, rtol, chunk_rows, chunk_points):
    """Fit quadratics for ``centres`` whose neighbourhoods are CSR rows ``(ptr, idx)``.

    Neighbourhoods are sorted by size and processed in chunks padded to the
    chunk's largest size, so padding is small and memory is bounded by about
    ``chunk_rows * 11 * 8`` bytes per array.
    """
    sizes = np.diff(ptr)
    order = np.argsort(sizes, kind="stable")
    n = centres.size
    coef = np.empty((n, _N_COEF))
    scale = np.empty(n)
    deficient = np.empty(n, dtype=bool)
    start = 0
    while start < n:
        m = max(int(sizes[order[min(start + chunk_points, n) - 1]]), 1)
        stop = min(start + chunk_points, start + max(chunk_rows // m, 1), n)
        m = max(int(sizes[order[stop - 1]]), 1)  # sizes sorted: last is the largest
        sel = order[start:stop]
        lo, ln = ptr[sel], sizes[sel]
        col = np.arange(m)
        mask = col[None, :] < ln[:, None]
        pos = np.where(mask, lo[:, None] + col[None, :], 0)
        nbr = np.where(mask, idx[pos] if idx.size else 0, centres[sel][:, None])
        c, s, dfc = _fit_block(points, values, centres[sel], nbr, mask, rtol)
        coef[sel], scale[sel], deficient[sel] = c, s, dfc
        start = stop
    return coef, scale, deficient


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


def fit_quadratic(points, values, indptr, indices, *, rtol=1e-8, max_ring=3,
                  chunk_rows=300_000, chunk_points=20_000, return_info=False):
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
    p = np.asarray(points, dtype=float)
    f = np.asarray(values, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"points must have shape (N, 3), got {p.shape}")
    npts = p.shape[0]
    if f.shape != (npts,):
        raise InputError(f"values must have shape ({npts},), got {f.shape}")
    indptr = np.asarray(indptr, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    if indptr.shape != (npts + 1,):
        raise InputError(f"indptr must have length N + 1 = {npts + 1}, got {indptr.shape}")
    if max_ring < 1:
        raise ValueError(f"max_ring must be >= 1, got {max_ring}")

    # closed 1-ring (point itself + edge neighbours) as a sparse pattern
    adj = sp.csr_matrix((np.ones(indices.size, dtype=np.int32), indices, indptr), shape=(npts, npts))
    closed = (adj + sp.identity(npts, dtype=np.int32, format="csr")).tocsr()
    closed.sum_duplicates()
    closed.sort_indices()

    grad = np.empty((npts, 3))
    hess = np.empty((npts, 3, 3))
    ring = np.ones(npts, dtype=np.int8)
    todo = np.arange(npts)
    rows = closed
    for k in range(1, max_ring + 1):
        coef, scale, deficient = _fit_rows(p, f, todo, rows.indptr.astype(np.int64),
                                           rows.indices.astype(np.int64), rtol,
                                           chunk_rows, chunk_points)
        g, h = _coef_to_derivatives(coef, scale)
        grad[todo], hess[todo] = g, h
        ring[todo] = k
        if not deficient.any() or k == max_ring:
            break
        # widen: (k+1)-ring of the deficient points = their k-ring rows times the closed 1-ring
        rows = rows[np.flatnonzero(deficient)] @ closed
        rows.sort_indices()
        todo = todo[deficient]
    min_norm = np.zeros(npts, dtype=bool)
    min_norm[todo[deficient]] = True
    used = ring > 1
    if return_info:
        return grad, hess, used, {"ring": ring, "min_norm": min_norm}
    return grad, hess, used


# ---------------------------------------------------------------------------
# absolute curvature of data (eq. 10)
# ---------------------------------------------------------------------------

def absolute_curvature(points, values, tets=None, neighbours=None, **fit_options):
    """Absolute curvature ``K = |k1| + |k2| + |k3|`` (eq. 10) at every data point.

    Derivatives come from :func:`fit_quadratic` over the edge neighbours in the
    initial triangulation, the principal curvatures from
    :func:`principal_curvatures` (eq. 8).

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
        A ready edge-neighbour graph (CSR); takes precedence over ``tets``.
    **fit_options
        Passed on to :func:`fit_quadratic` (``rtol``, ``max_ring``, chunk sizes).

    Returns
    -------
    (N,) float64
    """
    from .triangulation import delaunay_tetrahedra, edge_neighbours

    p = np.asarray(points, dtype=float)
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
