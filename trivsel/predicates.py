"""Geometric predicates: the sign of ``orient3d(a, b, c, d) = det[b - a, c - a, d - a]``.

Two small pure functions, compiled with numba:

* :func:`orient3d_int` - exact, on integer grid coordinates (int64; products of three
  coordinate differences stay far below 2^63 for any grid that fits in memory);
* :func:`orient3d_float_sign` (and :func:`orient3d_robust`, a determinant with that
  sign) - robust, on float coordinates: a float determinant
  with Shewchuk's static error bound decides when it can; otherwise the sign is
  computed exactly by expansion arithmetic (:func:`orient3d_exact_sign`), which
  represents every coordinate difference and triple product as an unevaluated sum
  of doubles, so the result is exact for any finite double input.

Everything also runs as plain Python with ``NUMBA_DISABLE_JIT=1``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_EPS = 2.0**-53
_SPLITTER = 134217729.0  # 2^27 + 1
# Shewchuk's orient3d error bound A: (7 + 56 eps) eps
_O3D_ERRBOUND = (7.0 + 56.0 * _EPS) * _EPS


@njit(cache=True)
def orient3d_value(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz):
    """``det[b - a, c - a, d - a]``: exact on int64 coordinates (numba compiles an int64
    version), the plain float determinant on doubles (approximate; for weights)."""
    ux = bx - ax
    uy = by - ay
    uz = bz - az
    vx = cx - ax
    vy = cy - ay
    vz = cz - az
    wx = dx - ax
    wy = dy - ay
    wz = dz - az
    return ux * (vy * wz - vz * wy) - uy * (vx * wz - vz * wx) + uz * (vx * wy - vy * wx)


#: exact integer orientation (int64 coordinates) and float determinant (doubles):
#: one generic function, specialised by numba for each argument type
orient3d_int = orient3d_value
orient3d_float = orient3d_value


# --- expansion arithmetic (Shewchuk 1997), used only when the filter fails -------

@njit(cache=True)
def _two_sum(a, b):
    x = a + b
    bv = x - a
    av = x - bv
    return x, (a - av) + (b - bv)


@njit(cache=True)
def _split(a):
    c = _SPLITTER * a
    hi = c - (c - a)
    return hi, a - hi


@njit(cache=True)
def _two_product(a, b):
    x = a * b
    ahi, alo = _split(a)
    bhi, blo = _split(b)
    err = x - ahi * bhi - alo * bhi - ahi * blo
    return x, alo * blo - err


@njit(cache=True)
def _grow(e, n, b):
    """Add double ``b`` to the nonoverlapping expansion ``e[:n]`` (increasing magnitude)."""
    q = b
    m = 0
    for i in range(n):
        q, h = _two_sum(q, e[i])
        if h != 0.0:
            e[m] = h
            m += 1
    if q != 0.0:
        e[m] = q
        m += 1
    return m


@njit(cache=True, _nrt=True)  # it allocates: explicit, so callers compiled without NRT may call it
def orient3d_exact_sign(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz):
    """Exact sign of ``det[b - a, c - a, d - a]`` for double inputs (expansion arithmetic).

    Each difference is an exact two-term expansion; the determinant is the sum of
    6 x 8 triple products, each an exact four-term expansion; the sum is grown
    into one nonoverlapping expansion whose largest component carries the sign.
    """
    # rows u = b - a, v = c - a, w = d - a as (hi, lo) pairs
    u = np.empty((3, 2))
    v = np.empty((3, 2))
    w = np.empty((3, 2))
    u[0, 0], u[0, 1] = _two_sum(bx, -ax)
    u[1, 0], u[1, 1] = _two_sum(by, -ay)
    u[2, 0], u[2, 1] = _two_sum(bz, -az)
    v[0, 0], v[0, 1] = _two_sum(cx, -ax)
    v[1, 0], v[1, 1] = _two_sum(cy, -ay)
    v[2, 0], v[2, 1] = _two_sum(cz, -az)
    w[0, 0], w[0, 1] = _two_sum(dx, -ax)
    w[1, 0], w[1, 1] = _two_sum(dy, -ay)
    w[2, 0], w[2, 1] = _two_sum(dz, -az)
    e = np.zeros(6 * 8 * 4 + 1)
    n = np.int64(0)  # not Literal[int](0): one compiled _grow
    # det = sum over permutations (i, j, k) of sign * u_i v_j w_k
    perms = ((0, 1, 2, 1.0), (1, 2, 0, 1.0), (2, 0, 1, 1.0),
             (0, 2, 1, -1.0), (2, 1, 0, -1.0), (1, 0, 2, -1.0))
    for pi in range(6):
        i, j, k, s = perms[pi]
        for p in range(2):
            for q in range(2):
                p1, p0 = _two_product(u[i, p], v[j, q])
                for r in range(2):
                    z = s * w[k, r]
                    h1, h0 = _two_product(p1, z)
                    g1, g0 = _two_product(p0, z)
                    n = _grow(e, n, h1)
                    n = _grow(e, n, h0)
                    n = _grow(e, n, g1)
                    n = _grow(e, n, g0)
    if n == 0:
        return 0
    return 1 if e[n - 1] > 0.0 else -1


@njit(cache=True)
def orient3d_robust(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz):
    """``det[b - a, c - a, d - a]`` on doubles, with the exact sign: the float determinant
    when Shewchuk's static error bound shows its sign is right, else 0.0 or the exact sign
    (expansion arithmetic) times the bound.  For weights whose signs decide."""
    adx = ax - dx
    bdx = bx - dx
    cdx = cx - dx
    ady = ay - dy
    bdy = by - dy
    cdy = cy - dy
    adz = az - dz
    bdz = bz - dz
    cdz = cz - dz
    bdxcdy = bdx * cdy
    cdxbdy = cdx * bdy
    cdxady = cdx * ady
    adxcdy = adx * cdy
    adxbdy = adx * bdy
    bdxady = bdx * ady
    # det[a-d, b-d, c-d] = -det[b-a, c-a, d-a]
    det = adz * (bdxcdy - cdxbdy) + bdz * (cdxady - adxcdy) + cdz * (adxbdy - bdxady)
    perm = ((abs(bdxcdy) + abs(cdxbdy)) * abs(adz) + (abs(cdxady) + abs(adxcdy)) * abs(bdz)
            + (abs(adxbdy) + abs(bdxady)) * abs(cdz))
    bound = _O3D_ERRBOUND * perm
    if det > bound or -det > bound:
        return -det
    return orient3d_exact_sign(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz) * (bound if bound > 0.0 else 1e-300)


@njit(cache=True)
def orient3d_float_sign(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz):
    """Robust sign of ``orient3d`` on doubles: filtered float, exact fallback."""
    v = orient3d_robust(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz)
    return 1 if v > 0 else (-1 if v < 0 else 0)
