"""Reading user data and writing results.

Input formats (:func:`load`):

* ``.vti`` (VTK image data) and legacy ``.vtk`` files holding structured points:
  a regular grid; it takes the exact integer path and keeps its origin and spacing;
* ``.vtu`` and legacy ``.vtk`` unstructured grids with tetrahedra: a tetrahedral mesh, whose
  cells are its domain (possibly non-convex); voxels are split into 6 tetrahedra each and
  cells of lower dimension are not used (both said in the result's notes); other solid cell
  types are refused;
* ``.vtu``, ``.vtp``, ``.vts``, ``.vtr`` and other legacy ``.vtk`` datasets without
  tetrahedra: scattered points with a point-data array;
* ``.npz``: either ``points`` (N x 3) and ``values`` (N), or a 3-D array ``values``
  (indexed [i, j, k] = x, y, z) with optional ``origin`` and ``spacing``; either with an
  optional ``name`` and other value arrays of the shape of ``values`` (``array`` picks one);
  anything else in the archive is refused;
* ``.npy`` (a 3-D array; origin 0, spacing 1) and Zarr stores (``.zarr``, geometry from the
  attributes ``origin`` and ``spacing``): read as ``trivsel blocks`` reads them
  (:func:`trivsel.io.regions.open_volume`), a grid;
* ``.csv``: columns ``x, y, z`` and a value column (``value`` or ``--array NAME``); a column
  name that the header repeats is refused;
* ``.nii`` and ``.nii.gz`` (NIfTI-1/-2, read with nibabel): a grid of the voxel values with
  ``scl_slope``/``scl_inter`` applied (float64), placed by the image's affine (the sform if
  its code is set, else the qform, else the voxel sizes ``pixdim`` with the origin at 0, the
  standard's method 1); coordinates are in the affine's world units (mm), not converted;
* ``.nrrd`` and ``.nhdr`` (a detached header; read with pynrrd): a grid of the samples as
  stored (no value mapping), placed by ``space directions`` and ``space origin``, or else by
  ``spacings`` (1 where unknown) with the origin at 0.

NIfTI and NRRD images keep their exact geometry: an axis that runs backwards (a negative step)
is flipped and a permutation of the axes is undone, so the spacing is positive and every voxel
keeps the world coordinate the file gives it; an oblique (rotated) image is refused.  A 4-D
image (a 4th axis of more than one volume: NIfTI's 4th dimension, NRRD's one non-spatial axis)
needs ``volume=K`` (``--volume K``).  In the output meshes, ``original_index`` of a NIfTI or
NRRD point is its voxel's index into the file's 3-D voxel array in Fortran order (the first
axis fastest, as stored, and as a VTK point id counts), within the chosen volume:
``value == data[..., K].ravel(order="F")[original_index]`` for nibabel's ``get_fdata()`` or
pynrrd's array (with the non-spatial axis last).

In-memory data (numpy arrays, pyvista datasets, nibabel images) take the same code paths
(:func:`from_object`).

Every reader refuses, in one line, integers that float64 cannot hold exactly (beyond 2^53), a
non-finite origin or spacing (also where VTK's readers would read ``nan`` as 0) and coordinates
that overflow, and checks the memory a file needs from its header before reading its data.

Outputs (:func:`write_outputs`) go first to a temporary folder inside the target
and are moved into place only when all of them are complete, so a failure never
leaves partial or corrupt files; a manifest lists what trivsel wrote, so a new run
replaces exactly the files of the previous one and never touches an input or a file
that no trivsel run wrote.
"""

from __future__ import annotations

import contextlib
import inspect
import itertools
import json
import logging
import numbers
import os
import shutil
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..data import PointData, check_float64_exact, grid_from_array, plain_tuple, scattered
from ..exceptions import InputError, one_line, shown
from ..resources import GRID_BYTES_PER_POINT, check_memory

__all__ = ["READERS", "MANIFEST", "TMP_PREFIX", "load", "from_object", "save_npz", "check_output_dir",
           "remove_temporaries", "umask", "write_outputs", "snapshot_to_vtk", "snapshot_to_pyvista", "tetra_grid",
           "write_vtu", "fraction_label"]


def fraction_label(fraction: float) -> str:
    """How a fraction appears in file names: ``f"{fraction:g}"`` (``mesh_0.5.vtu``)."""
    return f"{float(fraction):g}"


def _pick_array(names, array, path, option="--array"):
    """The array to reduce: ``array`` if given (it must be in ``names``), else the only one;
    ``option`` is how the message tells the user to choose (``--array``, ``array=``)."""
    names = list(names)
    if array is not None:
        if array not in names:
            raise InputError(f"array {array!r} not found in {path}; available: {', '.join(names) or 'none'}")
        return array
    if len(names) == 1:
        return names[0]
    if not names:
        raise InputError(f"{path} has no point-data array to reduce")
    raise InputError(f"{path} has several point-data arrays ({', '.join(names)}); choose one with {option}")


def _read_csv(p, array):
    """Scattered points from columns ``x, y, z`` and a value column (``value`` or ``array``)."""
    import pandas as pd

    rows = _count_lines(p)
    check_memory(rows * (5 * 8 + GRID_BYTES_PER_POINT), f"reading {str(p)!r} ({rows} lines)")
    try:
        df = pd.read_csv(p)
    except Exception as exc:  # pandas raises many types
        raise InputError(f"cannot read CSV {str(p)!r}: {one_line(exc)}") from None
    _check_csv_header(p, pd)
    cols = {c: _csv_column(df.columns, c, p) for c in ("x", "y", "z", "value")}
    missing = [c for c in ("x", "y", "z") if cols[c] is None]
    if missing:
        raise InputError(f"CSV {str(p)!r} lacks column(s) {', '.join(missing)}; need x, y, z and a value column")
    others = [c for c in df.columns if c not in (cols["x"], cols["y"], cols["z"])]
    if array is None and cols["value"] is not None:
        array = cols["value"]
    col = _pick_array(others, array, p)
    try:
        # integers as read (scattered() refuses those float64 cannot hold), anything else as float
        pts = np.stack([_number_column(df[cols[c]], p) for c in "xyz"], axis=1)
        vals = _number_column(df[col], p)
    except ValueError as exc:
        raise InputError(f"non-numeric data in {str(p)!r}: {exc}") from None
    return scattered(pts, vals, name=p.stem)


def _check_csv_header(p, pd):
    """Refuse, in one line naming it, a column name that the header of CSV ``p`` repeats: pandas
    would rename the second ``value`` to ``value.1`` and the reader would take the first without
    a word.  The header is read again as a row of text (the same parser, so the same quoting and
    skipped blank lines as the table's) because pandas' column names no longer show the repeat."""
    try:
        header = pd.read_csv(p, header=None, nrows=1, dtype=str, keep_default_na=False).iloc[0].tolist()
    except Exception as exc:  # pandas raises many types
        raise InputError(f"cannot read CSV {str(p)!r}: {one_line(exc)}") from None
    seen = set()
    for name in header:
        if name in seen:
            raise InputError(f"CSV {str(p)!r} has {header.count(name)} columns named {name!r}: rename all but one")
        seen.add(name)


def _csv_column(columns, name, p):
    """The column of a CSV that ``name`` (x, y, z or value) means: the one named so exactly (spaces
    around it aside), else the one named so in other case; None if there is none, and a one-line
    InputError if two could be meant."""
    for match in (lambda c: c.strip() == name, lambda c: c.strip().lower() == name):
        found = [c for c in columns if match(c)]
        if len(found) > 1:
            raise InputError(f"CSV {str(p)!r} has {len(found)} columns that could be {name!r} "
                             f"({', '.join(map(repr, found))}): rename all but one")
        if found:
            return found[0]
    return None


def _number_column(column, p):
    """A CSV column as numbers: integers as pandas read them (checked later), integers beyond
    64 bits (kept as Python ints) refused, true/false refused, anything else converted to float
    (text: ValueError)."""
    a = column.to_numpy()
    if a.dtype.kind == "b" or (a.dtype.kind == "O" and any(isinstance(x, (bool, np.bool_)) for x in a)):
        raise ValueError(f"column {column.name!r} holds true/false, not numbers")
    if a.dtype.kind in "iuf":
        return a
    check_float64_exact(a, lambda at: f"point {at[0]} of {_stem(p)!r}")
    return a.astype(float)


def _count_lines(p) -> int:
    """Lines in a text file, counted in 16 MiB reads (nothing parsed, nothing kept)."""
    n = 0
    with open(p, "rb") as fh:
        while chunk := fh.read(1 << 24):
            n += chunk.count(b"\n")
    return n


def _npz_member_shapes(p):
    """``{name: (shape, dtype)}`` of the arrays in an ``.npz`` from their headers (nothing read).
    A member that is not an ``.npy`` array, one whose header is damaged, or a name the archive
    holds twice (which ``np.load`` would resolve to one of them) is refused with one line."""
    import zipfile

    out = {}
    with zipfile.ZipFile(p) as z:
        for info in z.infolist():
            if not info.filename.endswith(".npy"):
                raise InputError(f"{str(p)!r} holds {info.filename!r}, which is not a NumPy array (.npy): an .npz "
                                 "holds only the arrays of its layout")
            name = info.filename[:-4]
            if name in out:
                raise InputError(f"{str(p)!r} holds two arrays named {name!r}: keep one")
            with z.open(info) as fh:
                try:
                    out[name] = npy_header(fh)
                except Exception as exc:  # numpy raises several types for a damaged header
                    raise InputError(f"cannot read {str(p)!r}: array {name!r}: {one_line(exc)}") from None
    return out


def npy_header(fh):
    """``(shape, dtype)`` from the header of the ``.npy`` data at the file object's position
    (nothing else is read)."""
    version = np.lib.format.read_magic(fh)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, _, dtype = read(fh)
    return tuple(shape), np.dtype(dtype)


#: The members of an ``.npz`` besides its value arrays: what each layout may hold
_NPZ_GRID_KEYS = ("origin", "spacing", "name")
_NPZ_POINTS_KEYS = ("points", "name")


def _read_npz(p, array):
    """The layout :func:`save_npz` writes: a 3-D ``values`` grid (indexed [i, j, k] = x, y, z)
    with optional ``origin`` and ``spacing``, or ``points`` (N x 3) and 1-D ``values``; either
    with an optional ``name`` (a string) and other value arrays of the same shape as
    ``values``, one of which ``array`` picks.  Anything else in the archive is refused
    (:func:`_npz_layout`)."""
    import zipfile

    if not zipfile.is_zipfile(p):
        raise InputError(f"cannot read {str(p)!r}: not a NumPy .npz archive (a zip of .npy arrays)")
    try:
        members = _npz_member_shapes(p)
    except InputError:
        raise
    except Exception as exc:  # a damaged archive
        raise InputError(f"cannot read {str(p)!r}: {one_line(exc)}") from None
    key = array or "values"
    if key in _NPZ_GRID_KEYS + _NPZ_POINTS_KEYS:
        raise InputError(f"--array {key!r} names a member of the layout of {str(p)!r}, not a value array")
    if key not in members:
        raise InputError(f"{str(p)!r} has no array {key!r}; available: {', '.join(members)}")
    shape = _npz_layout(p, members, key)
    # the memory of the arrays and of the grid or points built from them, before reading
    stored = sum(float(np.prod(s)) * dt.itemsize for name, (s, dt) in members.items() if name in (key, "points"))
    check_memory(stored + GRID_BYTES_PER_POINT * float(np.prod(shape)),
                 f"reading {str(p)!r} ({key!r} of shape {shape})")
    try:
        with np.load(p) as z:  # allow_pickle=False: object arrays are refused, never unpickled
            arrays = {k: np.asarray(z[k]) for k in (key, "points", "origin", "spacing", "name") if k in z.files}
    except Exception as exc:  # damaged members, object arrays
        raise InputError(f"cannot read {str(p)!r}: {one_line(exc)}") from None
    v = arrays[key]
    name = _npz_name(p, arrays["name"]) if "name" in arrays else p.stem
    if v.ndim == 3:
        return grid_from_array(v, arrays.get("origin", (0, 0, 0)), arrays.get("spacing", (1, 1, 1)), name=name)
    return scattered(arrays["points"], v, name=name)


def _npz_layout(p, members, key):
    """Check that the members of an ``.npz`` (``{name: (shape, dtype)}``, from the headers) are
    one layout around the value array ``key``: a grid (``key`` 3-D; ``origin``, ``spacing``) or
    scattered points (``key`` 1-D beside ``points``), each with an optional ``name`` and other
    value arrays of ``key``'s shape.  Every other member is refused in one line naming it, so
    that nothing in the file is silently ignored: ``points`` beside a grid (which layout is
    meant?), ``origin`` or ``spacing`` beside points (a grid's geometry, which points do not
    have), and any array neither layout has.

    Returns
    -------
    tuple
        The shape of ``key``.
    """

    def listed(names):
        return ", ".join(f"{n!r} {members[n][0]}" for n in names)

    shape = members[key][0]
    if len(shape) == 3:
        if "points" in members:
            raise InputError(f"{str(p)!r} is ambiguous: it holds a 3-D grid {key!r} {shape} and scattered "
                             f"'points' {members['points'][0]}; keep one layout (a grid: values, origin, spacing; "
                             "scattered: points, values)")
        layout, own, what = "a grid", _NPZ_GRID_KEYS, "origin, spacing, name"
    elif len(shape) == 1:
        if "points" not in members:
            raise InputError(f"{str(p)!r}: a 1-D {key!r} needs a 'points' array (N x 3) beside it")
        geometry = [k for k in ("origin", "spacing") if k in members]
        if geometry:
            raise InputError(f"{str(p)!r} holds scattered 'points' and {listed(geometry)}, which place a grid, not "
                             "points: remove them, or store the grid as a 3-D 'values'")
        layout, own, what = "scattered points", _NPZ_POINTS_KEYS, "points, name"
    else:
        raise InputError(f"{str(p)!r}: {key!r} has shape {shape}: need a 3-D grid, or 1-D values beside a "
                         "'points' array (N x 3)")
    # other value arrays (of key's shape) are alternatives that --array picks
    unused = [n for n, (s, _) in members.items() if n != key and n not in own and s != shape]
    if unused:
        raise InputError(f"{str(p)!r} holds {listed(unused)}, which {layout} does not use: an .npz of {layout} "
                         f"holds {key!r} {shape}, {what} and other value arrays of shape {shape}")
    return shape


def _npz_name(p, a):
    """The data's name from an ``.npz`` member ``name``: one string (as :func:`save_npz` writes it)."""
    if a.ndim != 0 or a.dtype.kind != "U":
        raise InputError(f"{str(p)!r}: 'name' must be one string, got {a.dtype} of shape {a.shape}")
    return str(a)


#: VTK's reader of each VTK suffix: (module of ``vtkmodules``, class)
_VTK_READERS = {".vti": ("vtkIOXML", "vtkXMLImageDataReader"), ".vtu": ("vtkIOXML", "vtkXMLUnstructuredGridReader"),
                ".vtp": ("vtkIOXML", "vtkXMLPolyDataReader"), ".vts": ("vtkIOXML", "vtkXMLStructuredGridReader"),
                ".vtr": ("vtkIOXML", "vtkXMLRectilinearGridReader"), ".vtk": ("vtkIOLegacy", "vtkDataSetReader")}


def _vtk_error(text):
    """The first error of VTK's log ``text`` on one line, without the object's name and
    address (``vtkXMLDataParser (0x55..): Error parsing XML ...`` -> ``Error parsing XML ...``)."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.startswith("ERROR") and i + 1 < len(lines):
            msg = lines[i + 1]
            return " ".join(msg.split("): ", 1)[-1].split())
    return ""


def _read_vtk_dataset(p, what=None):
    """A VTK file read with VTK's own reader for its suffix (pyvista is not needed): the
    dataset and its point-data arrays as ``{name: numpy array}`` (numeric arrays only).

    A file that VTK cannot read raises :class:`~trivsel.exceptions.InputError` with VTK's
    first error on one line (``what`` names the file's role in it, e.g. ``"piece"``); VTK's
    own messages are kept off the terminal meanwhile.
    """
    import importlib

    from vtkmodules.vtkCommonCore import vtkLogger, vtkOutputWindow, vtkStringOutputWindow

    p = Path(p)
    module, cls = _VTK_READERS[_suffix(p)]
    reader = getattr(importlib.import_module(f"vtkmodules.{module}"), cls)()
    reader.SetFileName(str(p))
    previous, log = vtkOutputWindow.GetInstance(), vtkStringOutputWindow()
    verbosity = vtkLogger.GetCurrentVerbosityCutoff()
    vtkOutputWindow.SetInstance(log)
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    try:
        n = _vtk_points_in_header(reader)
        if n:
            check_memory(GRID_BYTES_PER_POINT * n, f"reading {str(p)!r} ({n} points)")
        reader.Update()
        ds = reader.GetOutputDataObject(0)  # asks the pipeline again when the read failed
    finally:
        vtkOutputWindow.SetInstance(previous)
        vtkLogger.SetStderrVerbosity(verbosity)
    error = _vtk_error(log.GetOutput())
    if error or ds is None or ds.GetNumberOfPoints() == 0:
        name = f"{what} {str(p)!r}" if what else f"{str(p)!r} as a VTK file"
        raise InputError(f"cannot read {name}: {error or 'no points in it'}")
    return ds, _vtk_point_arrays(ds)


def _vtk_point_arrays(ds):
    """The numeric, named point-data arrays of a VTK dataset as ``{name: numpy array}`` (copies)."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    pd = ds.GetPointData()
    arrays = {}
    for i in range(pd.GetNumberOfArrays()):
        a = pd.GetArray(i)  # None for string and other non-numeric arrays
        if a is not None and a.GetName():
            arrays[a.GetName()] = np.array(vtk_to_numpy(a))
    return arrays


def _vtk_points_in_header(reader) -> int:
    """The number of points an XML VTK file declares (its image extent, or its pieces'
    ``NumberOfPoints``), read from the header alone; 0 when the reader cannot tell."""
    from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline as sddp

    if not hasattr(reader, "UpdateInformation") or not type(reader).__name__.startswith("vtkXML"):
        return 0
    reader.UpdateInformation()
    info = reader.GetOutputInformation(0)
    if info is not None and info.Has(sddp.WHOLE_EXTENT()):
        e = info.Get(sddp.WHOLE_EXTENT())
        return int(np.prod([max(e[2 * i + 1] - e[2 * i] + 1, 0) for i in range(3)], dtype=np.int64))
    if hasattr(reader, "GetNumberOfPoints"):
        return int(reader.GetNumberOfPoints())
    return 0


def _read_vtk(p, array):
    """VTK files, read with VTK's readers: image data is a grid (exact integer path, origin
    and spacing kept); any other dataset gives scattered points."""
    ds, arrays = _read_vtk_dataset(p)
    if ds.IsA("vtkImageData"):
        _check_vtk_header_geometry(p)
    return _vtk_data(ds, arrays, _pick_array(arrays.keys(), array, p), p, p.stem)


def _vtk_data(ds, arrays, col, p, name) -> PointData:
    """A VTK dataset's point array ``col`` as :class:`PointData`: image data as a grid (its
    origin, spacing and extent kept, a rotated direction refused, ``file_index`` the VTK point
    id), any other dataset as scattered points.  ``p`` names the data in messages."""
    vals = arrays[col]
    if vals.ndim != 1:
        raise InputError(f"array {col!r} in {str(p)!r} has {vals.shape[1]} components; need a scalar array")
    if ds.IsA("vtkImageData"):
        nx, ny, nz = ds.GetDimensions()
        if min(nx, ny, nz) < 2:
            raise InputError(f"image {str(p)!r} has dimensions {(nx, ny, nz)}: need >= 2 points per axis")
        direction = ds.GetDirectionMatrix()
        if any(direction.GetElement(i, j) != (i == j) for i in range(3) for j in range(3)):
            raise InputError(f"image {str(p)!r} has a rotated direction matrix; not supported")
        v3 = vals.reshape((nz, ny, nx)).transpose(2, 1, 0)  # VTK order is x fastest
        spacing = np.asarray(ds.GetSpacing(), float)
        # the first point sits at origin + extent_min * spacing, not at the origin
        origin = np.asarray(ds.GetOrigin(), float) + np.asarray(ds.GetExtent()[0::2], float) * spacing
        data = grid_from_array(v3, origin, spacing, name=name)
        i, j, k = data.ijk.T
        data.file_index = i + nx * (j + ny * k)  # VTK's point id of each grid point
        return data
    data = scattered(np.asarray(_vtk_points(ds), float), vals, name=name)
    data.tets, data.read_notes = _vtk_tetrahedra(ds, p)
    data.point_arrays = {k: v for k, v in arrays.items() if k != col and v.ndim <= 2 and len(v) == data.n_points}
    cd = ds.GetCellData()
    data.cell_arrays = tuple(cd.GetArrayName(i) or f"array {i}" for i in range(cd.GetNumberOfArrays()))
    return data


#: VTK's 3-D cell types other than the tetrahedron and the voxel, by name, which a mesh may not hold
_VTK_SOLID_CELLS = {12: "hexahedron", 13: "wedge", 14: "pyramid", 15: "pentagonal prism",
                    16: "hexagonal prism", 24: "quadratic tetrahedron", 25: "quadratic hexahedron",
                    42: "polyhedron"}


def _vtk_tetrahedra(ds, p):
    """The tetrahedra of an unstructured grid as (M, 4) point ids: its VTK_TETRA cells, and
    its VTK_VOXEL cells (axis-aligned boxes) split by the Kuhn split into 6 tetrahedra each
    (all along the same diagonal, so that neighbouring voxels split their shared faces
    alike); None when it has neither (its points are then scattered data).  Cells of lower
    dimension (boundary triangles, edges, vertices) do not change the domain and are not
    used; another solid cell type is refused with one line.  Returns the tetrahedra and the
    notes saying which cells were split or not used."""
    import warnings

    from vtkmodules.util.numpy_support import vtk_to_numpy

    if not ds.IsA("vtkUnstructuredGrid") or ds.GetNumberOfCells() == 0:
        return None, ()
    with warnings.catch_warnings():  # VTK 9.6 renames it GetCellTypes; older VTK's GetCellTypes differs
        warnings.simplefilter("ignore", DeprecationWarning)
        types = vtk_to_numpy(ds.GetCellTypesArray()).astype(np.int64)
    solid = sorted(set(types.tolist()) & set(_VTK_SOLID_CELLS))
    if solid:
        k = int(np.sum(types == solid[0]))
        raise InputError(f"{str(p)!r} has {k} {_VTK_SOLID_CELLS[solid[0]]} cells (VTK type {solid[0]}): trivsel "
                         "reduces meshes of tetrahedra only; split them into tetrahedra first")
    tet, vox = np.flatnonzero(types == 10), np.flatnonzero(types == 11)
    if len(tet) == 0 and len(vox) == 0:
        return None, ()
    notes = []
    if len(vox):
        notes.append(f"the input's {len(vox)} voxel cells were each split into 6 tetrahedra (the Kuhn split "
                     "along the diagonal from the voxel's first corner to its last) before the reduction")
    if len(types) > len(tet) + len(vox):
        notes.append(f"the input's {len(types) - len(tet) - len(vox)} cells of lower dimension (triangles, "
                     "lines, vertices) do not bound the domain and were not used")
    cells = ds.GetCells()
    offsets = vtk_to_numpy(cells.GetOffsetsArray()).astype(np.int64)
    conn = vtk_to_numpy(cells.GetConnectivityArray()).astype(np.int64)
    # a voxel's corner i + 2 j + 4 k is at (i, j, k): a Kuhn path from corner 0 to corner 7
    # sets one axis bit after another (the orientation is fixed when the mesh is checked)
    paths = [[0, 1 << a, (1 << a) | (1 << b), 7] for a, b, _ in itertools.permutations(range(3))]
    return np.concatenate([conn[offsets[tet][:, None] + np.arange(4)],
                           conn[offsets[vox][:, None] + np.arange(8)][:, paths].reshape(-1, 4)]), tuple(notes)


def _check_vtk_header_geometry(p):
    """Refuse an image whose header gives a non-numeric or non-finite origin or spacing: VTK's
    readers take a ``nan`` there as 0 (XML) or stop parsing, without a word.  Reads the first
    64 KiB, where the XML ``<ImageData>`` tag or the legacy ``ORIGIN``/``SPACING`` lines are."""
    import re

    with open(p, "rb") as fh:
        head = fh.read(1 << 16).decode("latin-1")
    found = {}
    tag = re.search(r"<ImageData\b([^>]*)>", head)
    if tag:
        for key in ("Origin", "Spacing"):
            m = re.search(rf'\b{key}\s*=\s*"([^"]*)"', tag.group(1))
            if m:
                found[key.lower()] = m.group(1).split()
    else:
        for key, name in (("ORIGIN", "origin"), ("SPACING", "spacing"), ("ASPECT_RATIO", "spacing")):
            m = re.search(rf"^{key}[ \t]+([^\n]*)$", head, re.MULTILINE)
            if m:
                found[name] = m.group(1).split()
    for name, words in found.items():
        try:
            ok = len(words) == 3 and all(np.isfinite(float(w)) for w in words)
        except ValueError:
            ok = False
        if not ok:
            raise InputError(f"grid {_stem(p)!r}: the {name} must be 3 finite numbers, got "
                             f"({', '.join(words)}) in {str(p)!r}")


def _vtk_points(ds):
    """The points of a VTK dataset that is not image data, as a numpy array in VTK's point
    order and stored type (a rectilinear grid's from its three coordinate arrays, x fastest)."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    if ds.IsA("vtkRectilinearGrid"):
        x, y, z = (vtk_to_numpy(c) for c in (ds.GetXCoordinates(), ds.GetYCoordinates(), ds.GetZCoordinates()))
        zz, yy, xx = np.meshgrid(z, y, x, indexing="ij")
        return np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=1)
    return vtk_to_numpy(ds.GetPoints().GetData())


def _stem(p) -> str:
    """The file name without its registered suffix (``brain.nii.gz`` -> ``brain``)."""
    suffix = _suffix(p)
    return p.name[: -len(suffix)] if suffix and p.name.lower().endswith(suffix) else p.stem


def _no_array(p, array):
    if array is not None:
        raise InputError(f"--array {array!r} does not apply to {str(p)!r}: the image holds one value per voxel")


def _check_voxel_dtype(p, dtype):
    """Real scalar voxels only (integers or floats): complex, colour and other kinds are refused."""
    dtype = np.dtype(dtype)
    if dtype.kind not in "iuf":
        raise InputError(f"{str(p)!r} holds voxels of type {dtype} (complex, colour or non-numeric); "
                         "need real scalar values")


def _volume_index(p, shape, volume, file_shape=None):
    """The index of the volume to read from an image of ``shape`` (three spatial axes first, then
    one axis of volumes; further axes must have length 1).

    One-line InputError for fewer than 3 dimensions, fewer than 2 voxels on a spatial axis,
    more than one axis of volumes, several volumes and no ``volume``, or ``volume`` out of range;
    they quote ``file_shape`` (the shape in the file's axis order; default ``shape``).
    """
    shape = tuple(int(s) for s in shape)
    told = shape if file_shape is None else tuple(int(s) for s in file_shape)
    if len(shape) < 3:
        raise InputError(f"{str(p)!r} is a {len(told)}-D image of shape {told}: need a 3-D volume")
    if min(shape[:3]) < 2:
        raise InputError(f"{str(p)!r} has shape {told}: need at least 2 voxels along each spatial axis")
    if any(s != 1 for s in shape[4:]):
        raise InputError(f"{str(p)!r} has shape {told}: more than one non-spatial axis is not supported")
    n = shape[3] if len(shape) > 3 else 1
    if volume is None:
        if n > 1:
            raise InputError(f"{str(p)!r} is a 4-D image of {n} volumes (shape {told}): choose one with "
                             f"--volume K, 0 <= K < {n}")
        return 0
    if not 0 <= volume < n:
        raise InputError(f"volume {volume} is out of range: {str(p)!r} holds {n} volume(s), 0 <= K < {n}")
    return int(volume)


#: Largest off-axis entry of a column of an image's index-to-world matrix, relative to the
#: column's step, that still counts as axis-aligned (the rounding of single-precision headers);
#: such entries are dropped, moving a voxel by at most this fraction of a step per voxel.
AXIS_TOLERANCE = 1e-6


def _voxel_grid(p, voxels, matrix, offset, what, name, meta=None) -> PointData:
    """Grid data from a 3-D voxel array placed by ``world = matrix @ (i, j, k) + offset``.

    ``matrix`` must be a permutation times a diagonal (up to :data:`AXIS_TOLERANCE`): the
    voxel axes are permuted into x, y, z order and an axis with a negative step is flipped,
    so that the grid's spacing is positive and each voxel keeps its world coordinate.  The
    grid points' ``file_index`` is their voxel's Fortran-order index in ``voxels``.
    Non-finite values are refused naming the voxel; an oblique or singular matrix is refused.
    """
    m = np.asarray(matrix, float)
    t = np.asarray(offset, float)
    text = np.array2string(m, separator=", ", precision=6).replace("\n", "")
    if m.shape != (3, 3) or t.shape != (3,) or not (np.all(np.isfinite(m)) and np.all(np.isfinite(t))):
        raise InputError(f"{str(p)!r}: the {what} must be a finite 3 x 3 matrix and offset, got {text} "
                         f"and {np.array2string(t, separator=', ')}")
    if np.any(np.abs(m).max(axis=0) == 0):  # before the alignment test, which it would fail confusingly
        raise InputError(f"{str(p)!r} has a zero voxel size (its {what}: {text})")
    axis = np.argmax(np.abs(m), axis=0)  # the world axis each voxel axis runs along
    if sorted(axis.tolist()) != [0, 1, 2]:
        raise InputError(f"{str(p)!r} is not axis-aligned (oblique or singular {what} {text}); "
                         "resample it onto an axis-aligned grid")
    order = np.argsort(axis)  # order[w]: the voxel axis along world axis w
    step = m[np.arange(3), order]  # signed spacing along world axis w
    off = m.copy()
    off[np.arange(3), order] = 0.0
    size = np.abs(m).max(axis=0)  # each voxel axis's step length
    if np.any(np.abs(off).max(axis=0) > AXIS_TOLERANCE * size):
        raise InputError(f"{str(p)!r} is oblique (off-axis terms in its {what} {text}); only axis-aligned "
                         "images (flipped or permuted axes allowed) are supported: resample it first")
    v = np.asarray(voxels)
    if not np.all(np.isfinite(v)):
        bad = np.argwhere(~np.isfinite(v))[0]
        raise InputError(f"non-finite value {v[tuple(bad)]} at voxel {tuple(int(b) for b in bad)} of {str(p)!r}")
    ids = np.arange(v.size, dtype=np.int64).reshape(v.shape, order="F")
    v, ids = v.transpose(order), ids.transpose(order)
    origin = t.copy()
    for w in np.flatnonzero(step < 0):
        v, ids = np.flip(v, w), np.flip(ids, w)
        origin[w] += step[w] * (v.shape[w] - 1)  # the lowest coordinate along w: the last voxel's
    data = grid_from_array(v, origin, np.abs(step), name=name)
    data.file_index = ids.ravel()  # C order over (i, j, k), as grid_from_array numbers the points
    data.meta.update(meta or {})
    return data


@contextlib.contextmanager
def _quiet_nibabel():
    """nibabel's header fixes (a zero ``pixdim`` set to 1) kept off stderr: trivsel checks the
    header as stored and refuses what it cannot use, in one line."""
    from nibabel.imageglobals import logger

    disabled, logger.disabled = logger.disabled, True
    try:
        yield
    finally:
        logger.disabled = disabled


def open_nifti(p, array, volume, *, keep_file_open=False):
    """``(img, shape, dtype, k, affine)`` of a NIfTI image, its header checked: a NIfTI-1/-2
    image of a real voxel type, volume ``k`` of a 4-D one, and its index-to-world affine (the
    sform or qform, or with neither set the standard's method 1: voxel sizes, origin at 0).
    The voxels are not read."""
    import nibabel as nib

    _no_array(p, array)
    from nibabel.openers import ImageOpener

    try:
        with _quiet_nibabel():
            img = nib.load(str(p), keep_file_open=keep_file_open)
            shape, dtype, hdr = img.shape, img.get_data_dtype(), img.header
            with ImageOpener(str(p)) as fh:  # the header as stored, before those fixes
                stored = type(hdr).from_fileobj(fh, check=False)
    except Exception as exc:  # nibabel raises many types for damaged files
        raise InputError(f"cannot read {str(p)!r} as NIfTI: {one_line(exc)}") from None
    return (img, *_nifti_header(p, img, volume, stored))


def _nifti_header(p, img, volume, stored=None):
    """``(shape, dtype, k, affine)`` of a nibabel image, checked as :func:`open_nifti` describes
    (``p`` names it in messages; ``stored``: its header as stored in a file, before nibabel's
    fixes, else the image's own)."""
    import nibabel as nib

    if not isinstance(img, (nib.Nifti1Image, nib.Nifti2Image)):
        raise InputError(f"{str(p)!r} is not a NIfTI image (nibabel reads it as {type(img).__name__})")
    shape, dtype, hdr = img.shape, img.get_data_dtype(), img.header
    _check_voxel_dtype(p, dtype)
    k = _volume_index(p, shape, volume)
    stored = hdr if stored is None else stored
    slope, inter = (float(stored[k]) for k in ("scl_slope", "scl_inter"))
    if np.isinf(slope):
        # the standard scales every voxel by a non-zero slope (a NaN one is read as unset, as
        # nibabel and other readers do); nibabel would read an infinite one as none too
        raise InputError(f"{str(p)!r} has a non-finite scaling (scl_slope = {slope!r}, scl_inter = {inter!r}): "
                         "its values would not be finite numbers")
    pixdim = np.asarray(stored["pixdim"][1:4], float)
    if int(stored["sform_code"]) == 0 and not (np.all(np.isfinite(pixdim)) and np.all(pixdim != 0)):
        # the qform and method 1 scale by pixdim; nibabel would silently take 1 for a 0
        raise InputError(f"{str(p)!r} has a zero or missing voxel size (pixdim[1:4] = {plain_tuple(pixdim)}) and "
                         "no sform to place it otherwise; set the voxel sizes in its header")
    if int(hdr["sform_code"]) == 0 and int(hdr["qform_code"]) == 0:
        # no orientation in the file: the standard's method 1 (voxel sizes, origin at 0), not
        # nibabel's fall-back affine (which flips x and centres the image)
        affine = np.diag([*pixdim, 1.0])
    else:
        affine = np.asarray(img.affine, float)
    return shape, dtype, k, affine


def _read_nifti(p, array, *, volume=None):
    """A NIfTI image through nibabel (see the module docstring): scaled values (float64),
    placement by the affine, flipped and permuted axes undone, oblique images refused."""
    img, shape, _, k, affine = open_nifti(p, array, volume)
    return _nifti_grid(p, img, shape, k, affine, volume, _stem(p))


def _nifti_grid(p, img, shape, k, affine, volume, name) -> PointData:
    """The voxels of volume ``k`` of a checked NIfTI image (:func:`_nifti_header`) as grid data."""
    dtype = img.get_data_dtype()
    n3 = float(np.prod(shape[:3]))
    check_memory(8.0 * float(np.prod(shape)) + (8 + GRID_BYTES_PER_POINT) * n3,
                 f"reading {str(p)!r} (shape {tuple(shape)})")
    try:
        if dtype.kind in "iu" and dtype.itemsize > 4:  # as stored: float64 would round beyond 2^53
            check_float64_exact(img.dataobj.get_unscaled(), lambda at: f"voxel {at} of {str(p)!r}")
        values = np.asarray(img.get_fdata(dtype=np.float64))
    except InputError:
        raise
    except Exception as exc:  # truncated or corrupt data
        raise InputError(f"cannot read the voxels of {str(p)!r}: {one_line(exc)}") from None
    values = values.reshape(tuple(shape[:3]) + (-1,))[..., k]
    return _voxel_grid(p, values, affine[:3, :3], affine[:3, 3], "affine", name,
                       meta={} if volume is None else {"volume": k})


def _nrrd_axes(p, header):
    """The spatial axes of a NRRD image (in file order) and its one non-spatial axis or None.

    Spatial axes are those with a space direction; without ``space directions``, those of kind
    ``domain`` or ``space`` when there are three; otherwise the first three.
    """
    ndim = len(header["sizes"])
    dirs = header.get("space directions")
    kinds = header.get("kinds")
    if dirs is not None:
        spatial = [a for a, d in enumerate(dirs) if d is not None and np.all(np.isfinite(np.asarray(d, float)))]
    elif kinds is not None and sum(str(k).lower() in ("domain", "space") for k in kinds) == 3:
        spatial = [a for a, k in enumerate(kinds) if str(k).lower() in ("domain", "space")]
    else:
        spatial = list(range(min(3, ndim)))
    if len(spatial) != 3 and ndim >= 3:
        raise InputError(f"{str(p)!r} has {len(spatial)} spatial axes (of {ndim}): need 3")
    return spatial, [a for a in range(ndim) if a not in spatial]


def nrrd_placement(p, header, spatial):
    """``(matrix, origin, what)``: a NRRD image's index-to-world placement over its spatial
    axes, from ``space directions`` and ``space origin``; without them, per axis, from
    ``spacings`` and ``axis mins`` (a cell-centred axis's first sample half a spacing past its
    min: ``centerings``, cell where unknown, as the NRRD format's default), a spacing from
    ``axis mins`` and ``axis maxs`` where none is given, else 1 and the origin at 0; ``what``
    names the source for error messages."""
    dirs = header.get("space directions")
    if dirs is not None:
        rows = [np.asarray(dirs[a], float) for a in spatial]
        if any(r.shape != (3,) for r in rows):
            raise InputError(f"{str(p)!r} has a {rows[0].size}-D space: need a 3-D space")
        return (np.stack(rows, axis=1), np.asarray(header.get("space origin", np.zeros(3)), float),
                "space directions (as columns)")
    n_axes = len(header["sizes"])

    def field(name):
        return np.asarray(header.get(name, [np.nan] * n_axes), float)[spatial]

    spacings, mins, maxs = field("spacings"), field("axis mins"), field("axis maxs")
    cell = np.array([str(c).lower() != "node" for c in np.asarray(header.get("centerings", ["???"] * n_axes),
                                                                   object)[spatial]])
    sizes = np.asarray(header["sizes"], float)[spatial]
    span = np.where(cell, sizes, sizes - 1)  # spacings between the axis min and max
    with np.errstate(divide="ignore", invalid="ignore"):
        spacings = np.where(np.isnan(spacings) & (span > 0), (maxs - mins) / span, spacings)
    spacings = np.where(np.isnan(spacings), 1.0, spacings)
    origin = np.where(np.isnan(mins), 0.0, mins + np.where(cell, 0.5 * spacings, 0.0))
    what = "spacings" if np.all(np.isnan(field("axis mins"))) else "spacings and axis mins"
    return np.diag(spacings), origin, what


def _read_nrrd(p, array, *, volume=None):
    """A NRRD image (``.nrrd``, or a ``.nhdr`` header and its data file) through pynrrd: the
    samples as stored, placed by ``space directions`` and ``space origin`` or by ``spacings``;
    flipped and permuted axes undone, oblique images refused."""
    import nrrd

    _no_array(p, array)
    try:
        header = nrrd.read_header(str(p))
        sizes = [int(n) for n in header["sizes"]]
        itemsize = np.dtype(nrrd.reader._determine_datatype(header)).itemsize
    except Exception as exc:  # pynrrd raises many types: a bad header, truncated data, a missing data file
        raise InputError(f"cannot read {str(p)!r} as NRRD: {one_line(exc)}") from None
    count = float(np.prod(sizes))
    n3 = float(np.prod(sorted(sizes, reverse=True)[:3]))  # at most the largest three axes are spatial
    # the samples (twice: a compressed stream is decoded into a buffer first), then the grid of one volume
    check_memory(2.0 * itemsize * count + (8 + GRID_BYTES_PER_POINT) * n3,
                         f"reading {str(p)!r} (sizes {tuple(sizes)})")
    try:
        values, header = nrrd.read(str(p))
    except Exception as exc:  # pynrrd raises many types: a bad header, truncated data, a missing data file
        raise InputError(f"cannot read {str(p)!r} as NRRD: {one_line(exc)}") from None
    values = np.asarray(values)
    _check_voxel_dtype(p, values.dtype)
    spatial, other = _nrrd_axes(p, header)
    file_shape = values.shape
    values = np.moveaxis(values, spatial + other, list(range(values.ndim)))
    k = _volume_index(p, values.shape, volume, file_shape)
    values = values.reshape(values.shape[:3] + (-1,))[..., k]
    matrix, origin, what = nrrd_placement(p, header, spatial)
    return _voxel_grid(p, values, matrix, origin, what, _stem(p), meta={} if volume is None else {"volume": k})


def _read_region_volume(p, array):
    """A ``.npy`` array or a Zarr store, read as ``trivsel blocks`` reads it
    (:func:`trivsel.io.regions.open_volume`): the same geometry (a store's ``origin`` and
    ``spacing`` attributes), the same float64 values (integers beyond 2^53 refused) and, for a
    store that ``trivsel convert`` wrote, the original file's point ids.  The memory is checked
    from the header before the values are read."""
    from .regions import open_volume

    vol = open_volume(p, array=array)
    r = vol.region_data(tuple((0, s) for s in vol.shape))
    ids = r.file_index
    return PointData(points=r.points, values=r.values, ijk=r.ijk, shape=r.shape, origin=r.origin,
                     spacing=r.spacing, name=_stem(p), meta=dict(vol.meta),
                     file_index=None if np.array_equal(ids, np.arange(len(ids))) else ids)


#: File suffix -> reader ``(path, array) -> PointData``; :func:`load` dispatches on it.  A
#: reader of images with several volumes also takes a keyword-only ``volume``.
READERS = {".csv": _read_csv, ".npz": _read_npz, ".npy": _read_region_volume, ".zarr": _read_region_volume,
           ".vti": _read_vtk, ".vtk": _read_vtk, ".vtu": _read_vtk, ".vtp": _read_vtk, ".vts": _read_vtk,
           ".vtr": _read_vtk, ".nii": _read_nifti, ".nii.gz": _read_nifti, ".nrrd": _read_nrrd,
           ".nhdr": _read_nrrd}


def _suffix(p) -> str:
    """The :data:`READERS` key of a path: a registered double suffix (``.nii.gz``) or the last one."""
    double = "".join(p.suffixes[-2:]).lower()
    return double if double in READERS else p.suffix.lower()


def check_not_a_folder(p):
    """One-line InputError when the input ``p``, named as a file of its suffix, is a folder (only a
    Zarr store is one)."""
    if Path(p).is_dir() and _suffix(Path(p)) != ".zarr":
        raise InputError(f"input {str(p)!r} is a folder, not a {_suffix(Path(p))} file")


def load(path, array: str | None = None, *, volume: int | None = None) -> PointData:
    """Read a user file into :class:`~trivsel.data.PointData` by its suffix (:data:`READERS`;
    see the module docstring).

    Parameters
    ----------
    path : str or path-like
        The input file (a Zarr store: its folder).
    array : str, optional
        The point-data array or value column to reduce (files with named arrays), or the
        array of a Zarr group.
    volume : int, optional
        The volume of a 4-D NIfTI or NRRD image, ``0 <= volume < n_volumes`` (required
        when the image has more than one); refused for other formats.

    Raises
    ------
    InputError
        One line naming the file and the problem: a missing or unreadable file, an
        unsupported suffix, or data the reader refuses.
    """
    check_path("the input file", path)
    p = Path(path)
    if not p.exists():
        raise InputError(f"input file {str(p)!r} does not exist")
    logging.getLogger("trivsel").info("reading %s", p)
    reader = READERS.get(_suffix(p))
    if reader is None:
        raise InputError(f"unsupported file type {p.suffix or p.name!r} of {str(p)!r}: "
                         f"read {', '.join(READERS)}")
    check_not_a_folder(p)
    if volume is None:
        return reader(p, array)
    if isinstance(volume, bool) or not isinstance(volume, numbers.Integral):
        raise InputError(f"volume must be an integer, got {shown(volume)}")
    if "volume" not in inspect.signature(reader).parameters:
        raise InputError(f"--volume {volume} applies to 4-D NIfTI and NRRD images, not to {str(p)!r}")
    return reader(p, array, volume=int(volume))


def from_object(obj, *, array: str | None = None, volume: int | None = None) -> PointData:
    """In-memory data as :class:`~trivsel.data.PointData`, by the readers' own code paths.

    * :class:`~trivsel.data.PointData`: itself;
    * a numpy array: a 3-D grid indexed ``[i, j, k]`` = x, y, z with origin 0 and spacing 1
      (:func:`~trivsel.data.grid_from_array` places it otherwise);
    * a VTK or pyvista dataset: image data (``pyvista.ImageData``) as a grid with the origin,
      spacing and extent of a ``.vti`` file; any other dataset (``UnstructuredGrid``,
      ``PolyData``, ...) as scattered points.  The value array is ``array``, or else the
      active scalars, or else the only point-data array;
    * a nibabel NIfTI image (``Nifti1Image``, ``Nifti2Image``): as a ``.nii`` file is read
      (its scaled values, placed by its affine; ``volume`` of a 4-D image);
    * a path (:class:`os.PathLike`): :func:`load`.

    Neither pyvista, VTK nor nibabel is imported here: an object of theirs can only exist
    once its module is.

    Raises
    ------
    InputError
        One line naming the object's type: an unsupported type, or what the reader refuses.
    """
    import sys

    if isinstance(obj, os.PathLike):
        return load(obj, array, volume=volume)
    package = type(obj).__module__.split(".")[0]
    kind = type(obj).__name__ if package == "builtins" else f"{package}.{type(obj).__name__}"
    vtk = sys.modules.get("vtkmodules.vtkCommonDataModel")
    if vtk is not None and isinstance(obj, vtk.vtkDataSet):
        _no_volume(kind, volume)
        return _vtk_object(obj, array, kind)
    nib = sys.modules.get("nibabel")
    if nib is not None and isinstance(obj, nib.spatialimages.SpatialImage):
        _no_array(kind, array)
        if volume is not None and (isinstance(volume, bool) or not isinstance(volume, numbers.Integral)):
            raise InputError(f"volume must be an integer, got {volume!r}")
        shape, _, k, affine = _nifti_header(kind, obj, volume)
        filename = obj.get_filename()
        name = _stem(Path(filename)) if filename else type(obj).__name__
        return _nifti_grid(kind, obj, shape, k, affine, volume, name)
    for option, value in (("array", array), ("volume", volume)):
        if value is not None:
            raise InputError(f"{option}={value!r} applies to files, pyvista datasets and nibabel images, "
                             f"not to a {kind}")
    if isinstance(obj, PointData):
        return obj
    if isinstance(obj, np.ndarray):
        return grid_from_array(obj, name="array")
    raise InputError(f"cannot take a {kind} as data: give a PointData, a 3-D numpy array, a pyvista dataset, "
                     "a nibabel image, a file path or a Table-1 function")


def _no_volume(kind, volume):
    if volume is not None:
        raise InputError(f"volume={volume!r} applies to 4-D NIfTI and NRRD images, not to a {kind}")


def _vtk_object(ds, array, kind) -> PointData:
    """A VTK or pyvista dataset as :class:`PointData` (:func:`_vtk_data`, as for a file)."""
    if ds.GetNumberOfPoints() == 0:
        raise InputError(f"the {kind} has no points")
    arrays = _vtk_point_arrays(ds)
    active = ds.GetPointData().GetScalars()
    if array is None and active is not None and active.GetName() in arrays:
        array = active.GetName()
    return _vtk_data(ds, arrays, _pick_array(arrays, array, kind, option="array="), kind, type(ds).__name__)


def save_npz(data: PointData, path):
    """Write ``data`` in the ``.npz`` layout :func:`load` reads: a grid as a 3-D ``values``
    array with ``origin`` and ``spacing``, scattered data as ``points`` and ``values``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {"name": np.array(str(data.name))}
    if data.is_grid:
        arrays.update(values=np.asarray(data.values).reshape(data.shape), origin=np.asarray(data.origin, float),
                      spacing=np.asarray(data.spacing, float))
    else:
        arrays.update(points=data.points, values=data.values)
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return path


def snapshot_to_vtk(result, snapshot):
    """The snapshot's mesh as a VTK ``vtkUnstructuredGrid`` of tetrahedra over the selected
    points, built with VTK's own modules (no pyvista import: a command-line run writes its
    ``.vtu`` files without it).

    Point data: ``value`` (the selected points' own values), ``original_index``
    (the point's id in the input: its row in a ``.csv`` or ``.npz``, its VTK point id
    in a ``.vti``/``.vtu``, its voxel's Fortran-order index in a NIfTI or NRRD volume;
    for ``--function`` grids the C-order index over (i, j, k)),
    ``curvature`` (K of eq. 10; not for ``method="greedy"``, which does not compute it)
    and, with ``values="fit"``, ``fitted_value``; then the input's other point arrays
    (:attr:`trivsel.data.PointData.point_arrays`) at the selected points, under their own names
    (a name taken above is not repeated).  Field data: ``fraction``.
    """
    sel = np.unique(snapshot.tets)
    remap = np.full(result.data.n_points, -1, np.int64)
    remap[sel] = np.arange(len(sel))
    arrays = {"value": result.data.values[sel]}
    if snapshot.fit is not None:
        fitted = np.empty(len(sel))
        fitted[np.searchsorted(sel, snapshot.fit["vertices"])] = snapshot.fit["values"]
        arrays["fitted_value"] = fitted
    arrays["original_index"] = result.data.file_ids(sel)
    if result.curvature is not None:  # greedy does not compute it
        arrays["curvature"] = result.curvature[sel]
    for name, a in (result.data.point_arrays or {}).items():  # the input's other point arrays
        arrays.setdefault(name, a[sel])
    return tetra_grid(result.data.points[sel], remap[snapshot.tets], arrays,
                      {"fraction": np.array([snapshot.fraction], np.float64)})


def tetra_grid(points, tets, point_data, field_data=None):
    """A VTK ``vtkUnstructuredGrid`` of tetrahedra (VTK_TETRA), built with VTK's own modules.

    ``points`` (M, 3) are stored as float64, ``tets`` (T, 4) index them; ``point_data`` and
    ``field_data`` map names to arrays (copied, in their own types), in order; the point array
    ``value``, if any, is the active scalars (as pyvista makes the first array it is given).
    """
    import_vtk_writer()
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import VTK_TETRA, vtkCellArray, vtkUnstructuredGrid

    def vtk_array(a, name):
        out = numpy_to_vtk(np.ascontiguousarray(a), deep=True)
        out.SetName(name)
        return out

    grid = vtkUnstructuredGrid()
    pts = vtkPoints()
    pts.SetData(vtk_array(np.asarray(points, np.float64), "Points"))
    grid.SetPoints(pts)
    tets = np.asarray(tets, np.int64).reshape(-1, 4)
    cells = vtkCellArray()
    cells.SetData(numpy_to_vtk(np.arange(0, 4 * len(tets) + 1, 4, dtype=np.int64), deep=True),
                  numpy_to_vtk(np.ascontiguousarray(tets.ravel()), deep=True))
    grid.SetCells(VTK_TETRA, cells)
    for name, a in point_data.items():
        grid.GetPointData().AddArray(vtk_array(a, name))
    if "value" in point_data:
        grid.GetPointData().SetActiveScalars("value")
    for name, a in (field_data or {}).items():
        grid.GetFieldData().AddArray(vtk_array(a, name))
    return grid


def snapshot_to_pyvista(result, snapshot):
    """The snapshot's mesh (:func:`snapshot_to_vtk`) as a pyvista ``UnstructuredGrid``."""
    import pyvista as pv

    return pv.wrap(snapshot_to_vtk(result, snapshot))


def write_vtu(grid, path):
    """Write a ``vtkUnstructuredGrid`` as a ``.vtu`` file: binary, zlib-compressed (as
    pyvista's ``save`` writes it).

    VTK builds the file's text in memory (binary data is base64 text in it) and Python writes
    it: VTK's own file output crashes the process when the disk fills up, while Python's
    raises OSError (``ENOSPC``), which a caller can report and clean up after.  Raises OSError
    if VTK's writer fails.
    """
    import_vtk_writer()
    from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridWriter

    writer = vtkXMLUnstructuredGridWriter()
    writer.SetWriteToOutputString(True)
    writer.SetInputData(grid)
    writer.SetDataModeToBinary()
    writer.SetCompressorTypeToZLib()
    if writer.Write() != 1:
        raise OSError(f"VTK could not write {str(path)!r}")
    text = writer.GetOutputString()
    step = 1 << 24
    with open(path, "wb") as fh:
        for i in range(0, len(text), step):  # in slices: one encoded copy of the whole text is not needed
            fh.write(text[i:i + step].encode("ascii"))


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


#: The file in an output folder that lists what trivsel wrote there (and may replace).
MANIFEST = ".trivsel-manifest.json"
#: The name prefix of every temporary file or folder trivsel makes beside its outputs: what a
#: killed run leaves with it is removed by the next run (:func:`remove_temporaries`).
TMP_PREFIX = ".trivsel-tmp-"


def umask() -> int:
    """The process's file mode creation mask (read without changing it where Linux tells)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def umask_mode(mode: int = 0o666) -> int:
    """``mode`` less the umask: the permissions :func:`open` or :func:`os.mkdir` would give.
    Temporary files and folders (:mod:`tempfile`) are made private (0600, 0700); an output
    moved into place from one gets this mode first, so colleagues read it as any other file."""
    return mode & ~umask()


@contextlib.contextmanager
def signals_deferred(*, deliver: bool = True):
    """SIGINT and SIGTERM held back while the block runs and delivered when it ends, so a
    step that must not stop half-way (an import of VTK's extension modules, the moves that
    put a run's outputs in place) completes first.  Only the main thread sets handlers.
    ``deliver=False``: a signal that came is dropped (the step it waited for finished the
    run's work, so the run ends normally a moment later).

    The handlers are replaced by ones that only note the signal (blocking the signal with
    ``pthread_sigmask`` is not enough: numpy's BLAS threads would still take it).
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending = []
    previous = {s: signal.signal(s, lambda signum, frame: pending.append(signum))
                for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)  # None: set outside Python
        if pending and deliver:
            signal.raise_signal(pending[0])  # to the handler the caller had


def import_vtk_writer():
    """Import the VTK modules that build and write the meshes, with signals deferred: an
    interrupt that lands inside the import of an extension module can leave it half set up,
    and the interpreter then crashes.  Cheap once imported."""
    with signals_deferred():
        import vtkmodules.util.numpy_support  # noqa: F401
        import vtkmodules.vtkCommonCore  # noqa: F401
        import vtkmodules.vtkCommonDataModel  # noqa: F401
        import vtkmodules.vtkIOXML  # noqa: F401


def check_path(what, path):
    """One-line InputError unless ``path`` is a ``str`` or an :class:`os.PathLike`."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"{what} must be a path (a str or a pathlib.Path), got {shown(path)}")


def check_output_dir(out_dir, inputs=(), files=()):
    """Check an output folder before any work: it is named, it is not a file, it can be
    created and written, it does not contain an input file (whose name a result could take),
    and none of ``files`` (the names the run will write) is there unless a trivsel run wrote
    it (:data:`MANIFEST`).

    Raises :class:`~trivsel.exceptions.InputError` with one line naming the problem.
    Returns the folder as a resolved :class:`~pathlib.Path`.
    """
    check_path("the output folder", out_dir)
    if not str(out_dir).strip():
        raise InputError(f"--out {str(out_dir)!r} is empty: name the output folder")
    out = Path(out_dir).expanduser()
    check_name(out, f"the output folder {str(out)!r}")
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {str(out)!r} is an existing file, not a folder")
    resolved = out.resolve()
    for inp in inputs:
        ip = Path(inp).expanduser().resolve()
        if ip == resolved or resolved in ip.parents:
            raise InputError(f"input file {str(inp)!r} is inside the output folder {str(out)!r}: "
                             "choose another --out (trivsel never writes over its input)")
        if ip in resolved.parents:  # a folder input, such as a Zarr store
            raise InputError(f"the output folder {str(out)!r} is inside the input {str(inp)!r}: "
                             "choose another --out (trivsel never writes into its input)")
    check_writable(resolved, f"the output folder {str(out)!r}")
    _check_foreign_files(resolved, files)
    return resolved


def check_name(path, what):
    """One-line InputError when the file system cannot even look ``path`` up: a name longer than
    it takes, or a parent folder this process may not search (``Path.exists`` raises then)."""
    try:
        os.stat(path)
    except (FileNotFoundError, NotADirectoryError):  # not there (yet), or under a file: the callers say
        pass
    except OSError as exc:  # the message without the path, which ``what`` names
        raise InputError(f"cannot use {what}: {exc.strerror or one_line(exc)}") from None


def check_writable(path, what):
    """One-line InputError unless ``path`` can be created: its nearest existing ancestor is a
    folder this process can write into, and a folder made there (and removed at once) is
    taken.  Only the attempt tells: as root, ``os.access`` calls ``/proc`` or a read-only
    mount writable, and a run would otherwise find out when it writes, after all its work."""
    import tempfile

    probe = Path(path)
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
        raise InputError(f"cannot write {what}: {str(probe)!r} is not writable")
    try:  # named as a temporary of this host and process (a run killed in this instant leaves it empty)
        os.rmdir(tempfile.mkdtemp(prefix=temporary_prefix("probe"), dir=probe))
    except OSError as exc:
        raise InputError(f"cannot write {what}: {str(probe)!r} takes no new folder: {exc.strerror or one_line(exc)}") from None


def temporary_prefix(name: str) -> str:
    """The prefix of a temporary folder for output ``name``, naming this host and process, so
    that a later run can tell a dead run's leftovers (:func:`remove_dead_temporaries`) from a
    live one's: ``.NAME.trivsel-tmp-HOST-PID-``."""
    import socket

    return f".{name}{TMP_PREFIX}{socket.gethostname().replace('-', '_')}-{os.getpid()}-"


def remove_dead_temporaries(folder) -> None:
    """Remove the temporary folders in ``folder`` (named by :func:`temporary_prefix`) of runs on
    this host whose process has ended: what a killed run could not clean up.  A live run's, or
    another host's on a shared file system, are left alone."""
    import socket

    host = socket.gethostname().replace("-", "_")
    for p in Path(folder).glob(f".*{TMP_PREFIX}*"):
        parts = p.name.split(TMP_PREFIX, 1)[1].rsplit("-", 2)
        if len(parts) != 3 or parts[0] != host or not parts[1].isdigit() or not p.is_dir():
            continue
        try:
            os.kill(int(parts[1]), 0)
            continue  # the run is alive
        except ProcessLookupError:
            pass
        except PermissionError:  # alive, another user's
            continue
        remove_tree(p)


def remove_tree(path) -> None:
    """Remove the folder ``path`` for good, with signals deferred: files that a writer's
    background threads still add while it goes (an interrupted Zarr write) are removed too."""
    import time

    with signals_deferred():
        for _ in range(100):
            shutil.rmtree(path, ignore_errors=True)
            if not os.path.lexists(path):
                return
            time.sleep(0.05)


def rename_no_replace(src, dst) -> None:
    """Rename ``src`` to ``dst``, failing with FileExistsError if ``dst`` exists, even if it
    appeared a moment ago (Linux's ``renameat2`` with ``RENAME_NOREPLACE``; elsewhere, or on a
    file system without it, a check just before :func:`os.rename`)."""
    import ctypes
    import errno

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        renameat2 = None
    if renameat2 is not None:
        at_fdcwd, noreplace = -100, 1
        if renameat2(at_fdcwd, os.fsencode(src), at_fdcwd, os.fsencode(dst), noreplace) == 0:
            return
        err = ctypes.get_errno()
        if err not in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
            raise OSError(err, os.strerror(err), str(dst))
    if os.path.lexists(dst):
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(dst))
    os.rename(src, dst)


def _check_foreign_files(out, files):
    """Refuse when one of ``files`` exists in ``out`` and the folder's manifest does not list
    it: a file a person or another program put there is never replaced."""
    ours = _previous_files(out)
    for name in files:
        f = out / name
        if (f.exists() or f.is_symlink()) and name not in ours:
            raise InputError(f"{str(f)!r} exists and no trivsel run wrote it (it is not in {MANIFEST}): "
                             "move it away or choose another --out")


@contextlib.contextmanager
def _folder_lock(out):
    """An exclusive lock on the folder ``out`` (``flock`` on the folder itself: nothing is
    left behind, and the lock ends with the process).  A second run writing into the same
    folder waits here, so runs never remove each other's temporary folders or mix their files."""
    import fcntl

    fd = os.open(out, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    log = logging.getLogger("trivsel")
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            log.warning("waiting for another trivsel run writing into %s", out)
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError as exc:  # a file system without locks (some network mounts): write unlocked
            log.warning("cannot lock %s (%s); concurrent runs into it are not serialised", out, one_line(exc))
        yield
    finally:
        os.close(fd)  # releases the lock


def remove_temporaries(folder):
    """Remove the temporary files and folders (:data:`TMP_PREFIX`) in ``folder`` that a run
    killed while writing left there."""
    for p in Path(folder).glob(TMP_PREFIX + "*"):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)


def _cell(v, float_format=None):
    """One CSV or table cell: floats by ``float_format`` (default ``repr``, as pandas writes
    them), NaN and None as empty, anything else by ``str``."""
    if v is None:
        return ""
    if isinstance(v, (float, np.floating)):
        if v != v:
            return ""
        return float_format(v) if float_format else repr(float(v))
    return str(v)


def write_csv_rows(rows, path):
    """``rows`` (dicts with the same keys) as a CSV file with a header, the same bytes as
    ``pandas.DataFrame(rows).to_csv(path, index=False)`` for numbers and plain strings, without
    importing pandas (a command-line run saves its import)."""
    import csv

    with open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        if rows:
            w.writerow(list(rows[0]))
            for r in rows:
                w.writerow([_cell(v) for v in r.values()])


def format_rows(rows, float_format=lambda v: f"{v:.6g}"):
    """``rows`` as a text table, columns right-aligned under their names, a numeric column one
    wider than its name (the layout of ``pandas.DataFrame.to_string(index=False)``)."""
    if not rows:
        return ""
    lines = [[] for _ in range(len(rows) + 1)]
    for name in rows[0]:
        vals = [r[name] for r in rows]
        numeric = all(isinstance(v, (numbers.Real, np.number)) and not isinstance(v, (bool, np.bool_))
                      for v in vals)
        cells = [name] + ["NaN" if numeric and v != v else _cell(v, float_format) for v in vals]
        width = max(max(map(len, cells)), len(name) + numeric)
        for line, c in zip(lines, cells):
            line.append(c.rjust(width))
    return "\n".join(" ".join(line) for line in lines)


def write_outputs(result, out_dir, extra: dict | None = None, inputs=()):
    """Write ``errors.csv``, ``mesh_<fraction>.vtu`` and ``result.json`` into ``out_dir``.

    The output contract:

    * ``out_dir`` is checked first (:func:`check_output_dir`): an input file inside
      it is refused, so an input is never overwritten;
    * every file is written into a temporary folder *inside* ``out_dir`` (the same
      file system, so the final moves are atomic renames) and moved into place only
      when all of them are complete;
    * files that an earlier trivsel run wrote there (listed in its manifest,
      :data:`MANIFEST`) and that this run does not produce are removed, so the
      folder never mixes two runs; other files in the folder are left alone;
    * a file in ``out_dir`` that this run would write and that no trivsel run wrote
      (it is not in the manifest) is refused, naming it;
    * runs into one folder are serialised by a lock on the folder while they write;
    * the files get the usual permissions (``0666`` less the umask);
    * the temporary folder is removed on any failure or interruption, and leftovers
      of a killed run are removed by the next one; a failure to write (a full disk)
      raises :class:`~trivsel.exceptions.InputError` with one line, and a folder this
      run created is removed again.
    """
    if not callable(getattr(result, "error_rows", None)) or not hasattr(result, "snapshots"):  # a ReductionResult
        raise InputError(f"write_outputs takes the result of trivsel.reduce, got {shown(result)}")
    if extra is not None and not isinstance(extra, Mapping):
        raise InputError(f"extra must be a mapping of names to JSON values (or None), got {shown(extra)}")
    if extra:
        try:
            json.dumps(dict(extra), allow_nan=True)
        except (TypeError, ValueError) as exc:
            raise InputError(f"extra must hold JSON values only: {one_line(exc)}") from None
    out = check_output_dir(out_dir, inputs)
    import_vtk_writer()
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
        with _folder_lock(out):
            remove_temporaries(out)
            tmp = Path(tempfile.mkdtemp(prefix=TMP_PREFIX, dir=out))
            committed = False
            try:
                _write_into(result, tmp, extra)
                names = json.loads((tmp / MANIFEST).read_text())["files"]
                _check_foreign_files(out, names)
                # the moves complete, or none starts; once they are done the results are complete,
                # and a signal then must not report "the folder is as it was"
                with signals_deferred(deliver=False):
                    _commit(tmp, out, names)
                    committed = True
            finally:
                with signals_deferred(deliver=not committed):
                    shutil.rmtree(tmp, ignore_errors=True)
    except BaseException as exc:
        if created:
            with contextlib.suppress(OSError):
                out.rmdir()  # only if still empty
        if not isinstance(exc, OSError):
            raise
        # a full disk, a folder made read-only meanwhile
        raise InputError(f"cannot write the outputs into {str(out)!r}: {one_line(exc)}; "
                         "the output folder is as it was before this run") from None
    return out


def _write_into(result, tmp, extra):
    """All outputs of ``result`` and their manifest, written into the folder ``tmp``."""
    mode = umask_mode()
    names = ["errors.csv"]
    write_csv_rows(result.error_rows(), tmp / "errors.csv")
    for s in result.snapshots:
        name = f"mesh_{fraction_label(s.fraction)}.vtu"
        write_vtu(snapshot_to_vtk(result, s), tmp / name)
        names.append(name)
    info = {
        "data": {"name": result.data.name, "n_points": result.data.n_points, "grid": result.data.is_grid,
                 "shape": result.data.shape, "origin": result.data.origin, "spacing": result.data.spacing,
                 "tetrahedra": None if result.data.tets is None else int(len(result.data.tets)),
                 **result.data.meta},
        "options": result.options,
        "timings": result.timings,
        "stats": result.stats,
        "notes": result.notes,
        "snapshots": [{"fraction": s.fraction, "n_selected": s.n_selected, "errors": s.errors,
                       "seconds": s.seconds, "n_tets": int(len(s.tets)), "flips": s.flips}
                      for s in result.snapshots],
        "selected": result.selected,
        **(extra or {}),
    }
    with open(tmp / "result.json", "w") as fh:
        json.dump(_jsonable(info), fh, indent=1)
    names.append("result.json")
    with open(tmp / MANIFEST, "w") as fh:
        json.dump({"files": names}, fh)
    for name in names + [MANIFEST]:
        os.chmod(tmp / name, mode)


def _commit(tmp, out, names):
    """Move the complete outputs from ``tmp`` into ``out`` and remove the previous run's other
    files.  The manifest first lists both runs' files, so that even a run killed here (SIGKILL,
    power loss) leaves a folder whose every trivsel file is listed and replaced by the next run."""
    previous = _previous_files(out)
    both = tmp / (MANIFEST + ".both")
    both.write_text(json.dumps({"files": sorted(previous | set(names))}))
    os.chmod(both, umask_mode())
    os.replace(both, out / MANIFEST)
    for name in names:
        os.replace(tmp / name, out / name)
    for name in sorted(previous - set(names)):
        (out / name).unlink(missing_ok=True)
    os.replace(tmp / MANIFEST, out / MANIFEST)


def _previous_files(out):
    """The files an earlier trivsel run listed in the folder's manifest (plain names only)."""
    try:
        files = json.loads((out / MANIFEST).read_text())["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return set()
    return {f for f in files if isinstance(f, str) and f == Path(f).name and not f.startswith(".")}
