"""Data: trivariate point data (x, y, z, f) of eq. (1) and the grid of section 5 (eq. 18).

:func:`sample_grid` evaluates a Table-1 function (:mod:`trivsel.functions`) on the
``(n + 1)^3`` grid over ``[-1, 1]^3``

.. math::  x_{i,j,k} = ((2i - n)/n, (2j - n)/n, (2k - n)/n), \\quad i, j, k = 0..n

and keeps the integer coordinates ``(i, j, k)`` beside the float ones, so that
every geometric predicate on grid data can run in exact integer arithmetic.

Point numbering is C order over ``(i, j, k)``: ``index = (i (n+1) + j) (n+1) + k``
(``i`` is x and varies slowest).  This is the "index" tie order of the ranking.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np

from .exceptions import InputError, shown
from .functions import FUNCTIONS, resolve_function

__all__ = ["PointData", "sample_grid", "grid_from_array", "check_grid_geometry", "scattered", "points_values",
           "check_float64_exact", "plain_tuple", "EXACT_INTEGER"]


@dataclass
class PointData:
    """Trivariate data (x, y, z, f) of eq. (1).

    Attributes
    ----------
    points : (N, 3) float64
        Coordinates ``x_i``.
    values : (N,) float64
        Function values ``f_i``.
    ijk : (N, 3) int64 or None
        Integer grid coordinates when the data lie on a regular grid; then all
        predicates are exact integer arithmetic and ``points = origin + ijk * spacing``.
    shape : tuple of 3 ints or None
        Grid dimensions (number of points per axis) for grid data.
    origin, spacing : (3,) float64 or None
        Physical placement of a grid.
    name : str
        A label used in output tables (function number or file stem).
    file_index : (N,) int64 or None
        The point id of each point in the file it was read from, when that order
        differs from trivsel's (a VTK image numbers its points x fastest, trivsel's
        grids x slowest); ``None``: the point's own index.  Written to the output
        meshes as ``original_index``.
    tets : (M, 4) int64 or None
        The tetrahedra of a mesh read with its cells (a ``.vtu`` or ``.vtk``); its domain,
        possibly non-convex, is their union.  ``None``: the domain of scattered points is
        their convex hull.
    point_arrays : dict or None
        The input file's other point arrays (``{name: (N, ...) array}``), written for the
        selected points beside ``value`` in the output meshes.
    cell_arrays : tuple of str
        The names of the input's cell arrays: the reduced mesh's cells are new, so they are
        not carried (noted in the result).
    read_notes : tuple of str
        What the reader did that is not one-to-one with the file (cells split into
        tetrahedra, cells not used), repeated in the result's notes.
    """

    points: np.ndarray
    values: np.ndarray
    ijk: np.ndarray | None = None
    shape: tuple | None = None
    origin: np.ndarray | None = None
    spacing: np.ndarray | None = None
    name: str = "data"
    meta: dict = field(default_factory=dict)
    file_index: np.ndarray | None = None
    tets: np.ndarray | None = None
    point_arrays: dict | None = None
    cell_arrays: tuple = ()
    read_notes: tuple = ()

    def file_ids(self, indices):
        """The input file's point ids of the given (trivsel) point indices."""
        indices = np.asarray(indices, np.int64)
        return indices if self.file_index is None else self.file_index[indices]

    @property
    def is_grid(self) -> bool:
        return self.ijk is not None

    @property
    def n_points(self) -> int:
        return int(self.values.shape[0])

    def interior_mask(self) -> np.ndarray:
        """Points not on the domain boundary (the starred column of Table 1).

        For a grid these are the points with every integer coordinate strictly
        between 0 and the last index: ``(n - 1)^3`` of them on an ``(n + 1)^3`` grid.
        For scattered data it is computed from the convex hull (see
        :func:`trivsel.triangulation.hull_boundary_mask`), for a mesh from the boundary
        triangles of its tetrahedra.
        """
        if self.is_grid:
            hi = np.asarray(self.shape) - 1
            return np.all((self.ijk > 0) & (self.ijk < hi), axis=1)
        if self.tets is not None:
            from .triangulation import boundary_triangles

            inner = np.ones(self.n_points, bool)
            inner[np.unique(boundary_triangles(self.tets))] = False
            return inner
        from .triangulation import hull_boundary_mask

        return ~hull_boundary_mask(self.points)


def sample_grid(function, n: int = 16) -> PointData:
    """Sample Table-1 function ``function`` on the ``(n+1)^3`` grid of eq. (18).

    Parameters
    ----------
    function : int or str
        1-5 or one of ``quadratic, saddle, cubic, exponential, trigonometric``.
    n : int
        Number of grid intervals per axis (``n >= 2``); the paper uses ``n = 16``.
    """
    num = resolve_function(function)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise InputError(f"grid resolution n must be an integer >= 2, got {shown(n)}")
    n = int(n)
    from .resources import GRID_BYTES_PER_POINT, check_memory

    check_memory(GRID_BYTES_PER_POINT * float(n + 1) ** 3, f"a grid of n = {n} ({n + 1}^3 points)")
    idx = np.arange(n + 1)
    ii, jj, kk = np.meshgrid(idx, idx, idx, indexing="ij")
    ijk = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1).astype(np.int64)
    spacing = np.full(3, 2.0 / n)
    origin = np.full(3, -1.0)
    points = (2.0 * ijk - n) / n
    values = FUNCTIONS[num][2](points[:, 0], points[:, 1], points[:, 2]).astype(float)
    return PointData(points=points, values=values, ijk=ijk, shape=(n + 1,) * 3,
                     origin=origin, spacing=spacing, name=str(num),
                     meta={"function": num, "n": n})


#: Largest integer magnitude every float64 holds exactly; larger integer samples are refused.
EXACT_INTEGER = 2**53


def check_float64_exact(a, place) -> None:
    """One-line InputError when the array ``a`` holds a value that float64 cannot hold exactly,
    instead of rounding it: an integer beyond 2^53 in magnitude, or a float wider than 64 bits
    (long double) that float64 would round; ``place(index)`` names where the first such value is
    (``"grid index (1, 2, 3) of 'x.npy'"``).  Other arrays pass."""
    a = np.asarray(a)
    if a.dtype.kind == "f" and a.dtype.itemsize > 8:
        with np.errstate(over="ignore", invalid="ignore"):
            rounded = a.astype(np.float64).astype(a.dtype) != a
        rounded &= ~np.isnan(a)
        if rounded.any():
            at = tuple(int(i) for i in np.argwhere(rounded)[0])
            raise InputError(f"value {np.format_float_positional(a[at])} at {place(at)} has more precision than "
                             "float64 holds: it would be rounded")
        return
    if a.dtype.kind == "O":  # Python integers beyond 64 bits (a CSV column of them)
        big = np.array([isinstance(x, numbers.Integral) and abs(int(x)) > EXACT_INTEGER for x in a.ravel()],
                       bool).reshape(a.shape)
    elif a.dtype.kind not in "iu" or a.dtype.itemsize <= 4 or not a.size:  # 32-bit integers always fit
        return
    else:
        big = a > EXACT_INTEGER
        if a.dtype.kind == "i":
            big |= a < -EXACT_INTEGER
    if big.any():
        at = tuple(int(i) for i in np.argwhere(big)[0])
        raise InputError(f"value {int(a[at])} at {place(at)} is beyond 2^53: float64 cannot hold it exactly")


def _real_array(a, name, place=None):
    """``a`` as float64; complex, boolean, text or object data are refused instead of
    being cast (a cast would drop imaginary parts or reinterpret the data), and so are
    integers that float64 cannot hold exactly (:func:`check_float64_exact`)."""
    if isinstance(a, np.ma.MaskedArray) and np.ma.count_masked(a):  # asarray would take the masked values
        raise InputError(f"{name} has {np.ma.count_masked(a)} masked value(s): fill them (or drop those points) "
                         "first, since every value is data to trivsel")
    arr = np.asarray(a)
    if arr.dtype.kind not in "iuf":
        raise InputError(f"{name} must be real numbers, got an array of dtype {arr.dtype}")
    check_float64_exact(arr, place or (lambda at: f"index {at} of the {name}"))
    return arr.astype(float, copy=False)


def check_grid_geometry(shape, origin, spacing):
    """A grid's ``origin`` and ``spacing`` as float64 arrays, checked against its ``shape``:
    three finite numbers each, the spacing positive, and every grid line's coordinate
    finite and distinct from its neighbour's (a spacing too small to move the origin, or
    a far corner beyond float64's range, would place two points at one coordinate).

    Raises :class:`~trivsel.exceptions.InputError` naming the bad value.
    """
    def text(v):  # a vector as a tuple; any other shape as it is
        return "(" + ", ".join(repr(float(x)) for x in v) + ")" if np.ndim(v) == 1 else shown(np.asarray(v))

    for what, v in (("origin", origin), ("spacing", spacing)):  # real numbers: not complex, not true/false
        a = np.asarray(v)
        if a.dtype.kind not in "iuf" and not (a.dtype.kind == "O" and all(
                isinstance(x, numbers.Real) and not isinstance(x, (bool, np.bool_)) for x in a.ravel())):
            raise InputError(f"grid {what} must be real numbers, got {a.dtype} values {shown(a)}")
    try:
        o = np.asarray(origin, float)
        sp = np.asarray(spacing, float)
    except (TypeError, ValueError):
        raise InputError(f"grid origin and spacing must be 3 numbers each, got {origin!r} and {spacing!r}") from None
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise InputError(f"grid origin must be 3 finite numbers, got {text(o)}")
    if sp.shape != (3,) or not np.all(np.isfinite(sp)) or np.any(sp <= 0):
        raise InputError(f"grid spacing must be 3 positive finite numbers, got {text(sp)}")
    with np.errstate(over="ignore"):
        for a, n in enumerate(shape):
            n = int(n)
            if n <= 2**20:  # every coordinate of the axis
                line = o[a] + np.arange(n, dtype=float) * sp[a]
                ok = np.all(np.isfinite(line)) and np.all(np.diff(line) > 0)
            else:  # both ends, and a spacing of more than two float steps at the largest coordinate
                i = np.r_[np.arange(64), np.arange(n - 64, n)].astype(float)
                line = o[a] + i * sp[a]
                top = np.max(np.abs(line)) if np.all(np.isfinite(line)) else np.inf
                ok = np.isfinite(top) and np.all(np.diff(line[:64]) > 0) and np.all(np.diff(line[64:]) > 0) \
                    and sp[a] > 2 * np.spacing(top)
            if not ok:
                raise InputError(f"grid origin {text(o)} and spacing {text(sp)} cannot place {int(n)} distinct "
                                 f"finite points along axis {'xyz'[a]} in float64")
    return o, sp


def plain_tuple(v):
    """Numbers as a plain tuple for a message (``(nan, 0.0, 1.0)``, not numpy reprs)."""
    try:
        return tuple(float(x) for x in np.asarray(v, float).ravel())
    except (TypeError, ValueError):
        return v


def grid_from_array(values3d, origin=(0.0, 0.0, 0.0), spacing=(1.0, 1.0, 1.0), name="data"):
    """Wrap a 3-D array of samples (indexed ``[i, j, k]`` = x, y, z) as grid data."""
    v = _real_array(values3d, "values", lambda at: f"grid index {at} of {name!r}")
    if v.ndim != 3:
        raise InputError(f"grid values must be a 3-D array, got shape {v.shape}")
    if min(v.shape) < 2:
        raise InputError(f"grid needs at least 2 points per axis, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        bad = np.argwhere(~np.isfinite(v))[0]
        raise InputError(f"non-finite value {v[tuple(bad)]} at grid index {tuple(int(b) for b in bad)}")
    origin, spacing = check_grid_geometry(v.shape, origin, spacing)
    from .resources import GRID_BYTES_PER_POINT, check_memory

    check_memory(GRID_BYTES_PER_POINT * float(v.size), f"a grid of {v.shape} points")
    idx = [np.arange(s) for s in v.shape]
    ii, jj, kk = np.meshgrid(*idx, indexing="ij")
    ijk = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1).astype(np.int64)
    points = origin + ijk * spacing
    return PointData(points=points, values=v.ravel().copy(), ijk=ijk, shape=tuple(v.shape),
                     origin=origin, spacing=spacing, name=name)


def points_values(points, values, name="data"):
    """Points (N, 3) and values (N,) as float arrays; one-line InputError on bad shapes."""
    p = _real_array(points, "points", lambda at: f"point {at[0]} (coordinate {at[-1]}) of {name!r}")
    f = _real_array(values, "values", lambda at: f"point {at[0]} of {name!r}")
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"points must have shape (N, 3), got {p.shape}")
    if f.shape != (p.shape[0],):
        raise InputError(f"values must have shape ({p.shape[0]},) to match the points, got {f.shape}")
    return p, f


def scattered(points, values, name="data") -> PointData:
    """Validate scattered input (points ``N x 3`` and ``N`` values).

    Rejects NaN/inf, wrong shapes, duplicate points, fewer than 5 points and
    point sets that do not span 3-D space (all coplanar), each with a one-line
    :class:`~trivsel.exceptions.InputError` naming the bad value.
    """
    p, f = points_values(points, values, name)
    if p.shape[0] < 5:
        raise InputError(f"too few points: need at least 5 for a 3-D triangulation, got {p.shape[0]}")
    if not np.all(np.isfinite(p)):
        row = int(np.argwhere(~np.isfinite(p))[0, 0])
        raise InputError(f"non-finite coordinate in point {row}: {tuple(p[row].tolist())}")
    if not np.all(np.isfinite(f)):
        row = int(np.argwhere(~np.isfinite(f))[0, 0])
        raise InputError(f"non-finite value {f[row]} at point {row}")
    # rows sorted lexicographically (twice as fast as np.unique(axis=0)); equal neighbours are duplicates
    s = p[np.lexsort((p[:, 2], p[:, 1], p[:, 0]))]
    same = np.all(s[1:] == s[:-1], axis=1)
    if same.any():
        dup = s[int(np.argmax(same))]
        rows = np.flatnonzero(np.all(p == dup, axis=1))
        raise InputError(f"duplicate point ({', '.join(f'{float(c):.17g}' for c in dup)}) at rows {rows.tolist()}")
    centred = p - p.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[-1] <= 1e-12 * max(sv[0], 1e-300):
        raise InputError(f"points are coplanar (or collinear): singular values {np.round(sv, 12).tolist()}; "
                         "a tetrahedral mesh needs points spanning 3-D space")
    return PointData(points=p, values=f, name=name)
