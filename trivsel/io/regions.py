"""Volumes read by region: a block of a large grid without loading the whole grid.

:func:`open_volume` opens a regular grid of values (a file, or a Table-1 function) and
returns a :class:`Volume`, which knows the grid's shape, origin and spacing from the
header alone and reads any box of points (a *region*) on demand.  A block job reads its
region and never the whole volume.

A region is three ``(start, stop)`` pairs of grid indices, one per axis (x, y, z), with
``stop`` exclusive, as in ``values[start:stop]``: ``((0, 64), (64, 128), (0, 1))``.

Sources and how they are read:

* a Zarr store (``*.zarr``, a directory; format v3 as :func:`convert` writes it, or v2):
  the array named by ``array`` or the store's only array, indexed ``[i, j, k]`` = x, y, z;
  geometry from its attributes ``origin`` and ``spacing`` (default 0 and 1), the input's point
  ids from ``file_index`` (as :func:`convert` writes it; one that does not give each point its
  own non-negative index is refused).  By region:
  a read loads only the chunks it touches;
* ``.npy``: a 3-D array indexed ``[i, j, k]``, memory-mapped; origin 0, spacing 1.  By region;
* NRRD with raw encoding (``.nrrd`` with the data after the header, or a ``.nhdr`` header and
  its raw data file), any type and endianness pynrrd reads: the data are memory-mapped at the
  header's offset (``line skip``, ``byte skip`` included).  By region;
* NIfTI (``.nii``, ``.nii.gz``) through nibabel's array proxy: a read fetches only the bytes
  of the region (``.nii``) or decompresses the stream up to the region's end (``.nii.gz``;
  memory stays that of the region, the time grows with the region's depth in the file);
* a Table-1 function (``function``, ``n``): evaluated at the region's points only, an x-slab
  at a time;
* everything else :func:`trivsel.io.load` reads as a grid (``.vti``, legacy ``.vtk``, ``.npz``)
  and NRRD with compressed or text encoding: **loaded whole** once, when the volume is opened
  (a warning says so); ``trivsel convert`` (:func:`convert`) copies any source into a Zarr
  store that block jobs read by region.  Scattered points (``.csv``, ``.vtu``) are refused.

Values and geometry are exactly those :func:`trivsel.io.load` (and
:func:`trivsel.data.sample_grid`) give for the whole volume: NIfTI scaling applied in
float64, samples converted to float64 (integers beyond 2^53, which float64 cannot hold
exactly, are refused), flipped and permuted NIfTI/NRRD axes undone, oblique images refused,
a 4-D image's volume chosen with ``volume``.  A region's :class:`RegionData` equals the
corresponding points of the whole volume's :class:`~trivsel.data.PointData` bit for bit:
the same coordinates, values, integer coordinates and input point ids.

Point order: C order over ``(i, j, k)`` (``i`` slowest), as
:func:`~trivsel.data.grid_from_array` numbers a grid.
"""

from __future__ import annotations

import contextlib
import logging
import numbers
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data import PointData, check_float64_exact, check_grid_geometry
from ..exceptions import InputError, one_line, shown

__all__ = ["Volume", "RegionData", "open_volume", "check_region", "convert"]

log = logging.getLogger("trivsel")


def check_region(region, shape) -> tuple:
    """``region`` as a tuple of three ``(start, stop)`` int pairs inside a grid of ``shape``.

    Raises
    ------
    InputError
        One line naming the region and the grid's shape: not three pairs of integers,
        an empty range (``stop <= start``) or one outside ``0 .. shape``.
    """
    try:
        pairs = [tuple(r) for r in region]
    except TypeError:
        pairs = []
    if len(pairs) != 3 or any(len(r) != 2 or not all(isinstance(v, numbers.Integral) and not isinstance(v, bool)
                                                    for v in r) for r in pairs):
        raise InputError(f"a region must be three (start, stop) pairs of integers, got {shown(region)}")
    out = tuple((int(a), int(b)) for a, b in pairs)
    for axis, ((a, b), n) in enumerate(zip(out, shape)):
        if not 0 <= a < b <= n:
            raise InputError(f"region {out} is {'empty' if b <= a else 'out of bounds'} along axis {'xyz'[axis]}: "
                             f"need 0 <= start < stop <= {n} (the grid has shape {tuple(shape)})")
    return out


@dataclass
class RegionData(PointData):
    """The :class:`~trivsel.data.PointData` of one region of a :class:`Volume`.

    ``points``, ``values``, ``ijk`` (global grid coordinates: the whole volume's), ``origin``,
    ``spacing`` and the input point ids (``file_index``) are those of the whole volume's
    points; ``shape`` is the region's, and the points are numbered in C order within it, so
    :func:`trivsel.reduce` treats the region as a grid of its own.

    Attributes
    ----------
    offset : tuple of 3 int
        The region's first grid index (``ijk`` of its point 0).
    volume_shape : tuple of 3 int
        The whole volume's shape.
    """

    offset: tuple = (0, 0, 0)
    volume_shape: tuple | None = None

    def interior_mask(self) -> np.ndarray:
        """Points not on the region's boundary (the boundary of the grid that a reduction
        of this region sees), from the global ``ijk`` less the region's offset."""
        lo = np.asarray(self.offset, np.int64)
        hi = lo + np.asarray(self.shape, np.int64) - 1
        return np.all((self.ijk > lo) & (self.ijk < hi), axis=1)


class Volume:
    """A regular grid of values that is read by region (see the module docstring).

    Made by :func:`open_volume`; not constructed directly.

    Attributes
    ----------
    shape : tuple of 3 int
        Points per axis (x, y, z).
    origin, spacing : (3,) float64
        The first point's coordinates and the step per axis (positive).
    name : str
        The file stem or the function's number.
    dtype : numpy.dtype
        The type of the values as the source stores them (before any NIfTI scaling):
        what :func:`convert` keeps when the values are exactly representable in it.
    by_region : bool
        False for a source that was loaded whole when it was opened.
    meta : dict
        ``volume`` (a 4-D image's chosen volume), ``function`` and ``n`` (function grids).
    source : str
        The path, or ``function N`` for a function grid.
    file_base, file_strides : int and tuple of 3 int
        The input's point id of grid point ``ijk`` is ``file_base + ijk @ file_strides``
        (:meth:`file_ids`).
    """

    def __init__(self, *, shape, origin, spacing, name, block, dtype, source, by_region=True, coords=None,
                 file_ids=None, slab_axis=0, meta=None):
        self.shape = tuple(int(s) for s in shape)
        self.origin, self.spacing = check_grid_geometry(self.shape, origin, spacing)
        self.name = str(name)
        self.source = str(source)
        self.by_region = bool(by_region)
        self.meta = dict(meta or {})
        self._block = block  # tuple of 3 slices -> the region's samples, [i, j, k], as stored
        self._dtype = dtype  # a dtype, or a callable giving it (a second look at a file loaded whole)
        self._coords = coords  # ijk (M, 3) -> points; None: origin + ijk * spacing
        # the input's point id of grid point ijk is base + ijk @ strides (C order over the grid by default)
        c_order = (self.shape[1] * self.shape[2], self.shape[2], 1)
        base, strides = file_ids if file_ids is not None else (0, c_order)
        self.file_base, self.file_strides = int(base), tuple(int(s) for s in strides)
        self.slab_axis = int(slab_axis)  # the grid axis along which the source stores contiguous slabs

    def __repr__(self):
        return (f"Volume({self.source!r}, shape={self.shape}, origin={tuple(self.origin.tolist())}, "
                f"spacing={tuple(self.spacing.tolist())}{'' if self.by_region else ', loaded whole'})")

    @property
    def dtype(self) -> np.dtype:
        if callable(self._dtype):
            self._dtype = np.dtype(self._dtype())
        return np.dtype(self._dtype)

    def read(self, region) -> np.ndarray:
        """The values of ``region`` as a float64 array of the region's shape, indexed
        ``[i, j, k]`` relative to the region's first point.  Reads only that region.

        Raises
        ------
        InputError
            A bad region (:func:`check_region`), unreadable data, or a non-finite value
            (naming its grid index).
        """
        r = check_region(region, self.shape)
        try:
            block = np.asarray(self._block(tuple(slice(a, b) for a, b in r)))
        except (InputError, MemoryError):
            raise
        except Exception as exc:  # truncated files, damaged chunks, I/O errors
            # a damaged Zarr chunk leaves the read's other tasks in zarr's event loop: let them end,
            # or asyncio reports each on stderr when the process exits
            _settle_zarr()
            raise InputError(f"cannot read region {r} of {self.source!r}: {one_line(exc)}") from None
        return _exact_float(block, r, self.source)

    def points(self, region):
        """The coordinates ``(M, 3)`` and global integer coordinates ``ijk`` ``(M, 3)`` of the
        region's points, in C order over ``(i, j, k)``; bit for bit those of the whole grid."""
        r = check_region(region, self.shape)
        ii, jj, kk = np.meshgrid(*(np.arange(a, b, dtype=np.int64) for a, b in r), indexing="ij")
        ijk = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1)
        return self.coordinates(ijk), ijk

    def coordinates(self, ijk):
        """The coordinates ``(M, 3)`` of grid points ``ijk`` ``(M, 3)``, bit for bit those of the
        whole grid."""
        # the same expression as grid_from_array's (or sample_grid's), so the same rounding
        return self.origin + ijk * self.spacing if self._coords is None else self._coords(ijk)

    def file_ids(self, ijk) -> np.ndarray:
        """The input's point id of each grid point ``ijk`` (global): its voxel's Fortran-order
        index in a NIfTI or NRRD volume, its VTK point id in a ``.vti``, else the C-order
        index over the grid (as for :func:`~trivsel.data.sample_grid`)."""
        return self.file_base + np.asarray(ijk, np.int64) @ np.asarray(self.file_strides, np.int64)

    def region_data(self, region) -> RegionData:
        """The region as :class:`RegionData`: the whole volume's points there, with global
        ``ijk`` and ``file_index``; at least 2 points per axis (a grid to reduce)."""
        r = check_region(region, self.shape)
        shape = tuple(b - a for a, b in r)
        if min(shape) < 2:
            raise InputError(f"region {r} has shape {shape}: a grid needs at least 2 points per axis")
        from ..resources import GRID_BYTES_PER_POINT, check_memory

        check_memory(GRID_BYTES_PER_POINT * float(np.prod(shape)), f"region {r} ({shape} points)")
        values = self.read(r)
        points, ijk = self.points(r)
        return RegionData(points=points, values=values.ravel(), ijk=ijk, shape=shape, origin=self.origin.copy(),
                          spacing=self.spacing.copy(), name=self.name, meta={**self.meta, "region": r},
                          file_index=self.file_ids(ijk), offset=tuple(a for a, _ in r), volume_shape=self.shape)


def _exact_float(block, region, source):
    """Samples as float64 exactly: real numbers only, integers within 2^53, all finite."""
    if block.dtype.kind not in "iuf":
        raise InputError(f"{source!r} holds values of type {block.dtype}: need real numbers")
    start = np.array([a for a, _ in region])
    check_float64_exact(block, lambda at: f"grid index {tuple((np.array(at) + start).tolist())} of {source!r}")
    values = block.astype(np.float64)  # a copy: never a view of a memory map
    if not np.all(np.isfinite(values)):
        at = np.argwhere(~np.isfinite(values))[0]
        raise InputError(f"non-finite value {values[tuple(at)]} at grid index {tuple((at + start).tolist())} "
                         f"of {source!r}")
    return values


def open_volume(path=None, *, function=None, n=None, array: str | None = None, volume: int | None = None) -> Volume:
    """Open a volume for reading by region (see the module docstring for the sources).

    Opening reads the header only (except for the sources that are loaded whole).

    Parameters
    ----------
    path : str or path-like, optional
        A Zarr store, ``.npy``, NRRD, NIfTI or any grid file :func:`trivsel.io.load` reads.
    function : int or str, optional
        A Table-1 function instead of a file (1-5 or its name).
    n : int, optional
        Grid intervals per axis of ``function`` (default 16, as :func:`~trivsel.data.sample_grid`);
        refused with a ``path`` (as ``trivsel reduce`` refuses ``--n`` with an input file).
    array : str, optional
        The array of a Zarr group, or the point-data array of a VTK or ``.npz`` file.
    volume : int, optional
        The volume of a 4-D NIfTI or NRRD image (required when it has several).

    Raises
    ------
    InputError
        One line: both or neither of ``path`` and ``function``, ``n`` with a ``path``, a missing file, an
        unsupported or scattered source, or anything :func:`trivsel.io.load` refuses.
    """
    if (path is None) == (function is None):
        raise InputError("give either an input file or a function (not both)")
    if volume is not None and (isinstance(volume, bool) or not isinstance(volume, numbers.Integral)):
        raise InputError(f"volume must be an integer, got {shown(volume)}")
    if function is not None:
        if array is not None or volume is not None:
            raise InputError(f"--{'array' if array is not None else 'volume'} applies to input files, "
                             "not to --function")
        return _function_volume(function, 16 if n is None else n)
    if n is not None:
        raise InputError(f"--n applies to --function, not to input files (got n {shown(n)} with {str(path)!r})")
    p = Path(path)
    if not p.exists():
        raise InputError(f"input file {str(p)!r} does not exist")
    from . import READERS, _suffix, check_not_a_folder

    suffix = _suffix(p)
    if suffix == ".zarr" or (p.is_dir() and any((p / f).exists() for f in ("zarr.json", ".zarray", ".zgroup"))):
        opener = _zarr_volume
    elif suffix == ".npy":
        opener = _npy_volume
    elif suffix in (".nii", ".nii.gz"):
        opener = _nifti_volume
    elif suffix in (".nrrd", ".nhdr"):
        opener = _nrrd_volume
    elif suffix in READERS:
        return _whole_volume(p, array, volume)
    else:
        raise InputError(f"unsupported file type {p.suffix or p.name!r} of {str(p)!r}: read "
                         f"{', '.join(dict.fromkeys(['.zarr', '.npy', *READERS]))}")
    if opener is not _zarr_volume:
        check_not_a_folder(p)
    if opener in (_zarr_volume, _npy_volume) and volume is not None:
        raise InputError(f"--volume {volume} applies to 4-D NIfTI and NRRD images, not to {str(p)!r}")
    return opener(p, array, volume)


#: Points of a function grid evaluated at a time (:func:`open_volume` with ``function``)
FUNCTION_POINTS = 1 << 18


def _function_volume(function, n):
    """A Table-1 function on the grid of :func:`~trivsel.data.sample_grid`, evaluated per region."""
    from ..functions import FUNCTIONS, resolve_function

    num = resolve_function(function)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise InputError(f"grid resolution n must be an integer >= 2, got {shown(n)}")
    n = int(n)

    def coords(ijk):
        return (2.0 * ijk - n) / n  # sample_grid's expression

    def block(slices):
        out = np.empty(tuple(s.stop - s.start for s in slices))
        # an x-slab of at most FUNCTION_POINTS points at a time: its temporaries (the indices, the
        # coordinates, the function's own) for a slab, not for the whole region
        step = max(1, FUNCTION_POINTS // max(1, out.shape[1] * out.shape[2]))
        for a in range(0, out.shape[0], step):
            lo = slices[0].start + a
            ii, jj, kk = np.meshgrid(np.arange(lo, min(lo + step, slices[0].stop), dtype=np.int64),
                                     *(np.arange(s.start, s.stop, dtype=np.int64) for s in slices[1:]), indexing="ij")
            p = coords(np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1))
            # called on the columns of an (M, 3) array as sample_grid does: the same loops, the same bits
            out[a:a + step] = FUNCTIONS[num][2](p[:, 0], p[:, 1], p[:, 2]).astype(float).reshape(ii.shape)
        return out

    return Volume(shape=(n + 1,) * 3, origin=np.full(3, -1.0), spacing=np.full(3, 2.0 / n), name=str(num),
                  block=block, dtype=np.float64, source=f"function {num}", coords=coords,
                  meta={"function": num, "n": n})


def _check_grid_shape(p, shape):
    shape = tuple(int(s) for s in shape)
    if len(shape) != 3 or min(shape) < 2:
        raise InputError(f"{str(p)!r} holds an array of shape {shape}: need a 3-D grid with at least 2 points "
                         "per axis")
    return shape


def _attribute_vector(p, attrs, key, default):
    value = attrs.get(key, default)
    try:
        v = np.asarray(value, float)
    except (TypeError, ValueError):
        v = np.zeros(0)
    ok = v.shape == (3,) and np.all(np.isfinite(v)) and (key != "spacing" or np.all(v > 0))
    if not ok:
        need = "3 positive finite numbers" if key == "spacing" else "3 finite numbers"
        raise InputError(f"{str(p)!r}: attribute {key!r} must be {need}, got {shown(value)}")
    return v


def _zarr_volume(p, array, volume):
    """A Zarr array (v3 or v2): the store's root array, or the group's array named ``array``
    (or its only one); geometry from the attributes ``origin`` and ``spacing``."""
    import zarr

    from . import _check_voxel_dtype, _pick_array

    try:
        node = zarr.open(store=str(p), mode="r")
    except Exception as exc:  # not a store, a format this zarr cannot read
        raise InputError(f"cannot open {str(p)!r} as a Zarr store (zarr {zarr.__version__}): {one_line(exc)}") from None
    if isinstance(node, zarr.Array):
        if array is not None:
            raise InputError(f"array {array!r} not found in {str(p)!r}: the store is one array, not a group")
        arr = node
    else:
        members = dict(node.arrays())
        arr = members[_pick_array(sorted(members), array, p)]
    shape = _check_grid_shape(p, arr.shape)
    _check_voxel_dtype(p, arr.dtype)
    attrs = dict(arr.attrs)
    ids = attrs.get("file_index")
    file_ids = None if ids is None else _file_index(p, ids, shape)
    meta = attrs.get("meta") if isinstance(attrs.get("meta"), dict) else {}
    return Volume(shape=shape, origin=_attribute_vector(p, attrs, "origin", [0.0] * 3),
                  spacing=_attribute_vector(p, attrs, "spacing", [1.0] * 3), name=attrs.get("name", p.stem),
                  block=lambda s: arr[s], dtype=arr.dtype, source=str(p), file_ids=file_ids, meta=meta)


def _file_index(p, ids, shape):
    """A store's ``file_index`` attribute as ``(base, strides)``: grid point ``ijk`` was point
    ``base + ijk @ strides`` of the original file.  What :func:`convert` writes (a C- or
    Fortran-order numbering of the grid, with flipped axes as negative strides) passes; refused
    in one line naming the value: anything but an integer ``base`` and 3 integer ``strides``, and
    a numbering that does not give each grid point its own non-negative int64 index (a negative
    index, a zero stride, two points on one index, an index beyond an int64).

    Parameters
    ----------
    p : pathlib.Path
        The store (for the messages).
    ids : object
        The attribute's value.
    shape : tuple of 3 ints
        The store's grid shape.

    Returns
    -------
    tuple
        ``(base, strides)``: an int and a list of 3 ints.
    """

    def integer(v):
        return isinstance(v, numbers.Integral) and not isinstance(v, bool)

    def refuse(why):
        return InputError(f"{str(p)!r}: attribute 'file_index' {shown(ids)} {why}")

    try:
        base, strides = ids["base"], list(ids["strides"])
    except (KeyError, TypeError, IndexError):
        base, strides = None, []
    if not integer(base) or len(strides) != 3 or not all(map(integer, strides)):
        raise refuse("must be {'base': int, 'strides': [3 ints]}")
    base, strides = int(base), [int(s) for s in strides]
    if 0 in strides:
        axis = "xyz"[strides.index(0)]
        raise refuse(f"has a zero stride along axis {axis}: the points along it would share one index")
    # Python integers: the extreme indices exactly, however large base and strides are
    low = base + sum(s * (n - 1) for s, n in zip(strides, shape) if s < 0)
    high = base + sum(s * (n - 1) for s, n in zip(strides, shape) if s > 0)
    if low < 0:
        raise refuse(f"gives grid points negative indices (down to {low}) for the shape {tuple(shape)}")
    if high > np.iinfo(np.int64).max:
        raise refuse(f"gives grid points indices beyond an int64 (up to {high}) for the shape {tuple(shape)}")
    clash = _index_collision(strides, shape)
    if clash is not None:
        a, b = clash
        raise refuse(f"gives grid points {a} and {b} the same index {base + sum(i * s for i, s in zip(a, strides))}"
                     f" for the shape {tuple(shape)}")
    return base, strides


def _index_collision(strides, shape):
    """Two grid points of ``shape`` that ``ijk @ strides`` (non-zero integer strides whose
    indices :func:`_file_index` found within an int64) maps onto the same index, or None if the
    map is one-to-one.

    A C- or Fortran-order numbering, up to flips and a permutation of the axes, nests its axes
    (each stride's magnitude exceeds the span of the smaller ones) and is one-to-one at once.
    Otherwise two points collide where a difference ``d`` (``|d[x]| < shape[x]``, not all 0) has
    ``d @ strides == 0``: ``d`` is searched over the two shortest axes, the third solved for."""
    span = 0
    for x in sorted(range(3), key=lambda ax: abs(strides[ax])):
        if abs(strides[x]) <= span:
            break
        span += abs(strides[x]) * (shape[x] - 1)
    else:
        return None
    a, b, c = sorted(range(3), key=lambda ax: shape[ax])
    # |d @ strides| is at most the indices' range, which fits an int64
    db = np.arange(-(shape[b] - 1), shape[b], dtype=np.int64)
    for da in range(shape[a]):  # d and -d give the same pair: d[a] >= 0, and d[b] > 0 where d[a] == 0
        rest = da * np.int64(strides[a]) + db * np.int64(strides[b])
        hit = (rest % strides[c] == 0) & (np.abs(rest // strides[c]) < shape[c]) & ((da > 0) | (db > 0))
        if hit.any():
            i = int(np.flatnonzero(hit)[0])
            d = [0, 0, 0]
            d[a], d[b], d[c] = da, int(db[i]), -int(rest[i] // strides[c])
            first = tuple(max(0, -v) for v in d)
            return first, tuple(f + v for f, v in zip(first, d))
    return None


def _npy_volume(p, array, volume):
    """A 3-D ``.npy`` array, memory-mapped; origin 0, spacing 1."""
    from . import _check_voxel_dtype, _no_array

    _no_array(p, array)
    try:
        arr = np.load(p, mmap_mode="r")  # allow_pickle=False: object arrays are refused
    except Exception as exc:
        raise InputError(f"cannot read {str(p)!r} as a NumPy .npy array: {one_line(exc)}") from None
    shape = _check_grid_shape(p, arr.shape)
    _check_voxel_dtype(p, arr.dtype)
    return Volume(shape=shape, origin=np.zeros(3), spacing=np.ones(3), name=p.stem, block=lambda s: arr[s],
                  dtype=arr.dtype, source=str(p), slab_axis=0 if arr.flags.c_contiguous else 2)


class _VoxelAxes:
    """How a voxel array placed by ``world = matrix @ (i, j, k) + offset`` becomes trivsel's
    grid: the permutation and flips of :func:`trivsel.io._voxel_grid`, applied to regions.

    ``voxel_shape``: the 3 spatial sizes in the file's axis order.
    """

    def __init__(self, p, matrix, offset, what, name, voxel_shape):
        from . import _voxel_grid

        m, t = np.asarray(matrix, float), np.asarray(offset, float)
        # io's checks and refusals (oblique, singular, non-finite placement) on a 2^3 stand-in
        _voxel_grid(p, np.zeros((2, 2, 2)), m, t, what, name)
        self.order = np.argsort(np.argmax(np.abs(m), axis=0))  # order[w]: the voxel axis along world axis w
        step = m[np.arange(3), self.order]
        self.flip = step < 0
        self.shape = tuple(int(voxel_shape[a]) for a in self.order)
        self.spacing = np.abs(step)
        self.origin = t.copy()
        for w in np.flatnonzero(self.flip):
            self.origin[w] += step[w] * (self.shape[w] - 1)  # io's expression: the last voxel's coordinate
        fortran = np.cumprod([1, *voxel_shape[:2]])  # each voxel axis's step in the Fortran-order index
        sign = np.where(self.flip, -1, 1)
        self.strides = sign * fortran[self.order]
        self.base = int(sum((self.shape[w] - 1) * fortran[self.order[w]] for w in np.flatnonzero(self.flip)))
        self.slab_axis = int(np.flatnonzero(self.order == 2)[0])  # the slowest axis in the file

    def voxel_slices(self, slices):
        """The voxel-array slices (file axis order) holding the grid region ``slices``."""
        out = [None] * 3
        for w, s in enumerate(slices):
            n = self.shape[w]
            out[self.order[w]] = slice(n - s.stop, n - s.start) if self.flip[w] else s
        return out

    def to_grid(self, voxels):
        """A voxel block (file axis order) as a grid block ``[i, j, k]``."""
        v = np.asarray(voxels).transpose(self.order)
        return np.flip(v, tuple(np.flatnonzero(self.flip))) if self.flip.any() else v

    def volume(self, p, read, dtype, name, meta, by_region=True):
        """A :class:`Volume` reading the voxel array through ``read(voxel_slices)``."""
        return Volume(shape=self.shape, origin=self.origin, spacing=self.spacing, name=name,
                      block=lambda s: self.to_grid(read(self.voxel_slices(s))), dtype=dtype, source=str(p),
                      by_region=by_region, file_ids=(self.base, self.strides), slab_axis=self.slab_axis, meta=meta)


def _nifti_volume(p, array, volume):
    """A NIfTI image through nibabel's array proxy: each read fetches the region's voxels
    and applies ``scl_slope``/``scl_inter`` in float64, as ``get_fdata()`` does."""
    from . import _stem, open_nifti

    # one open stream: a .nii.gz is not re-opened per read
    img, shape, dtype, k, affine = open_nifti(p, array, volume, keep_file_open=True)
    axes = _VoxelAxes(p, affine[:3, :3], affine[:3, 3], "affine", _stem(p), shape[:3])
    rest = (k,) + (0,) * (len(shape) - 4) if len(shape) > 3 else ()
    proxy = img.dataobj
    # the proxy applies the scaling in the slope's type, a Python float (float64): get_fdata()'s values
    return axes.volume(p, lambda s: proxy[tuple(s) + rest], dtype, _stem(p), {} if volume is None else {"volume": k})


def _nrrd_volume(p, array, volume):
    """A NRRD image: raw encoding memory-mapped (by region); any other encoding loaded whole."""
    import nrrd

    from . import _check_voxel_dtype, _no_array, _nrrd_axes, _stem, _volume_index, nrrd_placement

    _no_array(p, array)
    try:
        with open(p, "rb") as fh:
            header = nrrd.read_header(fh)
            data_start = fh.tell()  # read_header leaves the file just after the header
    except Exception as exc:  # pynrrd raises many types for a bad header
        raise InputError(f"cannot read {str(p)!r} as NRRD: {one_line(exc)}") from None
    if str(header.get("encoding", "")).lower() != "raw":
        return _whole_volume(p, array, volume, why=f"its NRRD encoding is {header.get('encoding')!r}, not raw")
    try:
        # pynrrd's own mapping of the header's type and endian field to a numpy type
        dtype = np.dtype(nrrd.reader._determine_datatype(header))
        sizes = tuple(int(s) for s in header["sizes"])
    except Exception as exc:
        raise InputError(f"cannot read {str(p)!r} as NRRD: {one_line(exc)}") from None
    _check_voxel_dtype(p, dtype)
    data, offset = _nrrd_data_offset(p, header, data_start)
    count = int(np.prod(sizes))
    size = os.path.getsize(data)
    stored = size - offset if offset >= 0 else size  # offset < 0: byte skip -1 and a file shorter than the data
    if offset < 0 or stored // dtype.itemsize != count:  # pynrrd's own check of the data's length
        raise InputError(f"cannot read {str(p)!r} as NRRD: {str(data)!r} holds {stored} bytes of data, "
                         f"the header's sizes {sizes} of {dtype} need {count * dtype.itemsize}")
    spatial, other = _nrrd_axes(p, header)
    k = _volume_index(p, [sizes[a] for a in spatial + other], volume, sizes)
    axes = _VoxelAxes(p, *nrrd_placement(p, header, spatial), _stem(p), [sizes[a] for a in spatial])
    mm = np.memmap(data, dtype=dtype, mode="r", offset=offset, shape=sizes, order="F")
    pick = {a: (k if i == 0 else 0) for i, a in enumerate(other)}  # io: the first non-spatial axis holds volumes

    def read(voxel_slices):
        index = [pick.get(a) for a in range(len(sizes))]
        for c, a in enumerate(spatial):
            index[a] = voxel_slices[c]
        return mm[tuple(index)]

    return axes.volume(p, read, dtype, _stem(p), {} if volume is None else {"volume": k})


def _nrrd_data_offset(p, header, data_start):
    """The raw data's file and byte offset: the header's ``data file`` (relative to the
    header's folder) or the header's own file after it, then ``line skip`` lines and
    ``byte skip`` bytes (-1: the data end the file), as pynrrd reads them."""
    name = header.get("data file", header.get("datafile"))
    data = p if name is None else p.parent / name
    start = data_start if name is None else 0
    line_skip = int(header.get("line skip", header.get("lineskip", 0)))
    byte_skip = int(header.get("byte skip", header.get("byteskip", 0)))
    if line_skip < 0 or byte_skip < -1:
        raise InputError(f"cannot read {str(p)!r} as NRRD: line skip {line_skip} or byte skip {byte_skip} "
                         "is out of range")
    try:
        with open(data, "rb") as fh:
            fh.seek(start)
            for _ in range(line_skip):
                fh.readline()
            pos = fh.tell()
    except OSError as exc:
        raise InputError(f"cannot read {str(p)!r} as NRRD: its data file {str(data)!r}: {one_line(exc)}") from None
    if byte_skip == -1:
        size = int(np.prod(header["sizes"])) * np.dtype(_nrrd_type(header)).itemsize
        return data, os.path.getsize(data) - size
    return data, pos + byte_skip


def _nrrd_type(header):
    import nrrd

    return nrrd.reader._determine_datatype(header)


def _whole_volume(p, array, volume, why=None):
    """Any grid :func:`trivsel.io.load` reads, loaded whole now (a warning says so)."""
    from . import _suffix, load

    data = load(p, array, volume=volume)
    if not data.is_grid:
        raise InputError(f"{str(p)!r} holds scattered points, not a grid: region reads need a regular grid")
    # after the reader's checks, so that bad input stays one line
    log.warning("%s is loaded whole (%s); 'trivsel convert' makes a Zarr store that block jobs read by region",
                p, why or f"{_suffix(p)} files cannot be read by region")
    values = data.values.reshape(data.shape)
    n = data.shape
    c_index = [n[1] * n[2], n[2], 1]  # the C-order index of the unit steps (1,0,0), (0,1,0), (0,0,1)
    ids = data.file_ids(np.arange(data.n_points))
    base, strides = int(ids[0]), [int(ids[c] - ids[0]) for c in c_index]
    if not np.array_equal(ids, base + data.ijk @ np.asarray(strides, np.int64)):
        raise RuntimeError(f"the point ids of {p} are not a permutation and flip of the grid's")  # io never does that
    return Volume(shape=n, origin=data.origin, spacing=data.spacing, name=data.name, block=lambda s: values[s],
                  dtype=lambda: _stored_dtype(p, array), source=str(p), by_region=False, file_ids=(base, strides),
                  meta=data.meta)


def _stored_dtype(p, array):
    """The type of a file's samples as stored (the values io.load gives are float64), for
    :func:`convert`; float64 where a format does not say."""
    from . import _pick_array, _suffix

    suffix = _suffix(p)
    if suffix in (".nrrd", ".nhdr"):
        import nrrd

        return _nrrd_type(nrrd.read_header(str(p)))
    if suffix in (".vti", ".vtk"):
        from . import _read_vtk_dataset

        _, arrays = _read_vtk_dataset(p)  # a second read: VTK files are the small ones
        return arrays[_pick_array(arrays.keys(), array, p)].dtype
    if suffix == ".npz":
        with np.load(p) as z:
            return z[array or "values"].dtype
    return np.float64


def _check_chunks(chunks):
    c = (chunks,) * 3 if isinstance(chunks, numbers.Integral) else tuple(chunks)
    if len(c) != 3 or not all(isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= 1 for v in c):
        raise InputError(f"chunks must be an integer >= 1 or three of them, got {shown(chunks)}")
    return tuple(int(v) for v in c)


def convert(source, out, *, chunks=64, array: str | None = None, volume: int | None = None) -> Path:
    """Copy a volume into a Zarr store that :func:`open_volume` reads by region.

    The store (format v3; v2 with zarr 2, which cannot write v3) is one array indexed
    ``[i, j, k]`` = x, y, z in trivsel's grid order (a NIfTI or NRRD image's flipped and
    permuted axes already undone), chunked ``chunks`` points per axis, with the attributes
    ``origin``, ``spacing`` and ``name`` (the exact geometry), ``file_index`` (the input's
    point id of grid point ``ijk`` is ``base + ijk @ strides``: the voxel's Fortran-order
    index in the original NIfTI or NRRD file, so ``original_index`` is unchanged by the
    conversion) and ``meta``.

    Value type: the source's stored type (:attr:`Volume.dtype`, e.g. int16 for most MRI)
    when every value, as read (scaling applied), is exactly representable in it; float64
    otherwise (a NIfTI scaling that gives non-integers, or integers out of the type's range).
    The copy is written once in the stored type and, at the first value that does not fit,
    restarted in float64.

    The source is read in slabs of ``chunks`` along the axis it stores slowest (memory: a
    slab), except for the formats that :func:`open_volume` loads whole.

    Parameters
    ----------
    source : str, path-like or Volume
        Any input of :func:`open_volume`, or an open :class:`Volume` (a function grid).
    out : str or path-like
        The new store, named ``*.zarr``; it must not exist.
    chunks : int or 3 ints
        Chunk size in points per axis (at most the grid's).
    array, volume
        As for :func:`open_volume`.

    Returns
    -------
    pathlib.Path
        ``out``.

    Raises
    ------
    InputError
        One line: an existing or empty ``out``, one inside the input, a name without ``.zarr``,
        bad ``chunks``, a failure to write (a full disk), or what :func:`open_volume` refuses.
        Nothing is left behind on any failure or interruption: the store is written into a
        temporary sibling folder (named by host and process, so that the next run removes
        what a killed one left) and renamed at the end, never over an ``out`` that appeared
        meanwhile; it gets the usual permissions (0777 less the umask).
    """
    from . import check_writable, remove_dead_temporaries, remove_tree, rename_no_replace, signals_deferred
    from . import check_name, temporary_prefix, umask_mode

    if not str(out).strip():
        raise InputError(f"the output {str(out)!r} is empty: name a new *.zarr store")
    out = Path(out).expanduser()
    if out.suffix.lower() != ".zarr":
        raise InputError(f"the output {str(out)!r} must be named *.zarr" + (
            " (a name before .zarr)" if out.name.lower() == ".zarr" else ""))
    check_name(out, f"the output {str(out)!r}")
    if out.exists() or out.is_symlink():
        raise InputError(f"the output {str(out)!r} exists: trivsel convert never overwrites; remove it or choose "
                         "another name")
    if not isinstance(source, Volume):
        src = Path(source).expanduser().resolve()
        if src == out.resolve() or src in out.resolve().parents:
            raise InputError(f"the output {str(out)!r} is inside the input {str(source)!r}: trivsel never writes "
                             "into its input; choose another place")
    check_writable(out.parent, f"{str(out)!r}")
    chunk = _check_chunks(chunks)
    vol = source if isinstance(source, Volume) else open_volume(source, array=array, volume=volume)
    chunk = tuple(min(c, n) for c, n in zip(chunk, vol.shape))
    from ..resources import check_memory

    axis = vol.slab_axis
    slab = list(vol.shape)
    slab[axis] = chunk[axis]
    check_memory(24.0 * float(np.prod(slab)), f"converting {vol.source!r} in slabs of {tuple(slab)} points")
    created = [d for d in (out.parent, *out.parent.parents) if not d.exists()]
    tmp = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        remove_dead_temporaries(out.parent)
        tmp = Path(tempfile.mkdtemp(prefix=temporary_prefix(out.name), dir=out.parent))
        t0 = time.perf_counter()
        # a long double is stored as float64 (Zarr has no wider float), where every value fits it exactly
        wide = vol.dtype.kind == "f" and vol.dtype.itemsize > 8
        candidates = ([] if wide else [vol.dtype]) + ([np.dtype(np.float64)] if vol.dtype != np.float64 else [])
        for dtype in candidates:
            if _write_zarr(vol, tmp, chunk, dtype):
                break
            log.info("%s: values not exactly representable as %s; writing float64", vol.source, dtype)
            shutil.rmtree(tmp)
            tmp.mkdir()
        os.chmod(tmp, umask_mode(0o777))  # mkdtemp's folder is private (0700): the usual permissions
        rename_no_replace(tmp, out)  # never replaces an out that appeared meanwhile (even an empty folder)
    except BaseException as exc:
        if isinstance(exc, KeyboardInterrupt):
            with signals_deferred():
                _settle_zarr()
        if tmp is not None:
            remove_tree(tmp)
        for d in created:  # the parent folders this run made, if still empty
            with contextlib.suppress(OSError):
                d.rmdir()
        if isinstance(exc, FileExistsError):
            raise InputError(f"the output {str(out)!r} appeared while converting: trivsel convert never "
                             "overwrites; the copy is discarded") from None
        if isinstance(exc, OSError):
            raise InputError(f"cannot write {str(out)!r}: {one_line(exc)}") from None
        raise
    log.info("wrote %s (%s, %s) in %.1f s", out, vol.shape, dtype, time.perf_counter() - t0)
    return out


def _settle_zarr(timeout=10.0):
    """Let the write tasks that an interrupt abandoned in zarr's event loop (a thread of its own)
    finish, so that no chunk is written after the store is removed, and no task is destroyed
    pending when the process ends (asyncio would report each on stderr)."""
    import asyncio

    try:
        from zarr.core.sync import loop  # zarr 3: [the loop] once one was started
    except ImportError:  # zarr 2 writes synchronously
        return
    if loop[0] is None or not loop[0].is_running():
        return

    async def others():
        tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        if tasks:
            await asyncio.wait(tasks, timeout=timeout)

    with contextlib.suppress(Exception):
        asyncio.run_coroutine_threadsafe(others(), loop[0]).result(timeout + 1)


def _write_zarr(vol, path, chunks, dtype):
    """Write ``vol`` as a Zarr array in ``dtype`` at ``path``; False at the first slab whose
    values ``dtype`` does not hold exactly (the store is then incomplete)."""
    import zarr

    attrs = {"origin": vol.origin.tolist(), "spacing": vol.spacing.tolist(), "name": vol.name,
             "file_index": {"base": vol.file_base, "strides": list(vol.file_strides)},
             "meta": {k: v for k, v in vol.meta.items() if isinstance(v, (int, float, str))}}
    if int(zarr.__version__.split(".")[0]) >= 3:
        arr = zarr.create_array(store=str(path), shape=vol.shape, chunks=chunks, dtype=dtype, attributes=attrs,
                                zarr_format=3)
    else:  # zarr 2 (the last release for Python 3.10) writes the v2 format, which open_volume reads too
        arr = zarr.open_array(str(path), mode="w", shape=vol.shape, chunks=chunks, dtype=dtype)
        arr.attrs.update(attrs)
    axis = vol.slab_axis
    step = chunks[axis]
    for start in range(0, vol.shape[axis], step):
        region = [(0, n) for n in vol.shape]
        region[axis] = (start, min(start + step, vol.shape[axis]))
        values = vol.read(region)
        with np.errstate(invalid="ignore", over="ignore"):
            stored = values.astype(dtype)
        if not np.array_equal(stored.astype(np.float64), values):
            return False
        arr[tuple(slice(a, b) for a, b in region)] = stored
    return True
