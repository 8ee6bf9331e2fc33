"""Partitioned output: the meshes of separately reduced blocks as pieces of one dataset.

* :func:`write_piece`: one block's tetrahedra as a ``.vtu`` file with the point arrays
  ``value`` and ``original_index`` (int64, the point's id in the whole input);
  :func:`write_piece_in_chunks` the same from chunks of tetrahedra, never held whole
  (:mod:`trivsel.io.vtu` writes both);
* :func:`write_pvtu`: a ``.pvtu`` file (VTK's parallel unstructured grid) over the pieces,
  which ParaView and pyvista open as one mesh;
* :func:`write_vtm`: a ``.vtm`` file (VTK's multiblock dataset), each piece one block;
* :func:`merge_pieces`: one ``.vtu`` over the global point numbering (a point that several
  pieces share, the same ``original_index``, appears once).

Every file is written to a temporary file beside it and moved into place with
:func:`os.replace`, so a reader never sees a partial file; an existing file is replaced
only when the caller passes ``overwrite=True``.
"""

from __future__ import annotations

import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..exceptions import InputError
from . import TMP_PREFIX, _read_vtk_dataset, _vtk_points, umask_mode
from .vtu import VTK_TYPES, write_tetra_vtu

__all__ = ["write_piece", "write_piece_in_chunks", "write_pvtu", "write_vtm", "merge_pieces"]

def _atomic_write(path, write, overwrite):
    """``write(tmp)`` into a temporary file beside ``path`` (same suffix: VTK picks its
    writer by it), then :func:`os.replace` it onto ``path`` with the usual permissions (0666
    less the umask).  Refuses an existing ``path`` unless ``overwrite``; removes the
    temporary file on any failure."""
    path = Path(path)
    if not overwrite and (path.exists() or path.is_symlink()):
        raise InputError(f"{str(path)!r} exists; pass overwrite=True to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    # the temporary prefix marks it as trivsel's, so that the leftovers of a killed run are removed
    fd, tmp = tempfile.mkstemp(prefix=f"{TMP_PREFIX}{path.stem}-", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, umask_mode())  # mkstemp's file is private (0600): the usual permissions instead
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def _piece_arrays(points, values, original_index, arrays=None):
    """The points and the point arrays of a piece, checked: ``(points, {name: array})``."""
    p = np.asarray(points, float)
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise InputError(f"points must be a finite (M, 3) array, got shape {p.shape}")
    m = p.shape[0]
    v = np.asarray(values)
    ids = np.asarray(original_index)
    if v.shape != (m,) or v.dtype.kind not in "iuf":
        raise InputError(f"values must be {m} real numbers (one per point), got {v.dtype} of shape {v.shape}")
    if ids.shape != (m,) or ids.dtype.kind not in "iu":
        raise InputError(f"original_index must be {m} integers (one per point), got {ids.dtype} of shape {ids.shape}")
    if ids.size and ids.dtype.kind == "u" and ids.max() > np.iinfo(np.int64).max:
        raise InputError(f"original_index {int(ids.max())} does not fit in int64")
    extra = {}
    for name, a in (arrays or {}).items():
        a = np.asarray(a)
        if a.shape != (m,) or a.dtype.kind not in "iuf":
            raise InputError(f"point array {name!r} must be {m} real numbers, got {a.dtype} of shape {a.shape}")
        extra[name] = a.astype(float, copy=False)
    return p, {"value": v.astype(float, copy=False), **extra, "original_index": ids.astype(np.int64, copy=False)}


def write_piece(path, points, tets, values, original_index, *, overwrite: bool = False, arrays=None) -> Path:
    """Write one piece: a ``.vtu`` of VTK_TETRA cells (:func:`trivsel.io.vtu.write_tetra_vtu`).

    Parameters
    ----------
    path : str or path-like
        The ``.vtu`` file.
    points : (M, 3) float
        The piece's points.
    tets : (T, 4) int
        Tetrahedra as indices into ``points``.
    values : (M,) float
        Point array ``value``.
    original_index : (M,) int
        Point array ``original_index`` (int64): each point's id in the whole input.
    overwrite : bool
        Replace an existing file (refused otherwise).
    arrays : dict of str to (M,) float, optional
        More point arrays (``fit``, say).
    """
    t = np.asarray(tets)
    if t.dtype.kind not in "iu" or t.ndim != 2 or t.shape[1] != 4:
        raise InputError(f"tets must be an integer (T, 4) array, got {t.dtype} of shape {t.shape}")
    m = len(np.asarray(points))
    if t.size and (t.min() < 0 or t.max() >= m):
        raise InputError(f"tets refer to point {int(t.min() if t.min() < 0 else t.max())}: need 0 <= index < {m}")
    return write_piece_in_chunks(path, points, lambda: [t], len(t), values, original_index, overwrite=overwrite,
                                 arrays=arrays)


def write_piece_in_chunks(path, points, tet_chunks, n_tets, values, original_index, *, overwrite: bool = False,
                          arrays=None) -> Path:
    """:func:`write_piece` with the tetrahedra made a chunk of rows at a time, never whole:
    ``tet_chunks()`` yields ``(k, 4)`` integer arrays, ``n_tets`` rows in all.  The file is
    written from the chunks as they come (:func:`trivsel.io.vtu.write_tetra_vtu`), so a
    merged mesh of tens of millions of tetrahedra takes no more memory than its points and a
    chunk."""
    p, data = _piece_arrays(points, values, original_index, arrays)
    return _atomic_write(path, lambda tmp: write_tetra_vtu(tmp, p, tet_chunks(), n_tets, data), overwrite)


def _relative(piece, folder):
    return Path(os.path.relpath(Path(piece).resolve(), Path(folder).resolve())).as_posix()


def _existing(piece_paths):
    paths = [Path(p) for p in piece_paths]
    if not paths:
        raise InputError("no pieces given")
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise InputError(f"piece {missing[0]!r} does not exist ({len(missing)} of {len(paths)} missing)")
    return paths


def _xml_text(root):
    ET.indent(root, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _vtk_file(kind):
    return ET.Element("VTKFile", type=kind, version="1.0", byte_order="LittleEndian", header_type="UInt64")


def _write_text(path, text, overwrite):
    def write(tmp):
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)

    return _atomic_write(path, write, overwrite)


def write_pvtu(path, piece_paths, *, overwrite: bool = False, relative_to=None) -> Path:
    """Write a ``.pvtu`` over ``piece_paths`` (``.vtu`` files, referenced by their paths
    relative to the ``.pvtu``'s folder, or to ``relative_to``, the folder it will be moved
    to): ``pv.read(path)`` gives all pieces' cells as one unstructured grid.

    The point arrays and the points' type are declared from the first piece; every piece
    must have the same (as :func:`write_piece` writes them).
    """
    paths = _existing(piece_paths)
    first, arrays = _read_vtk_dataset(paths[0], "piece")
    root = _vtk_file("PUnstructuredGrid")
    grid = ET.SubElement(root, "PUnstructuredGrid", GhostLevel="0")
    point_data = ET.SubElement(grid, "PPointData", **({"Scalars": "value"} if "value" in arrays else {}))
    for name, a in arrays.items():
        ET.SubElement(point_data, "PDataArray", type=_vtk_type(a.dtype, name), Name=name,
                      NumberOfComponents=str(1 if a.ndim == 1 else a.shape[1]))
    pts = ET.SubElement(grid, "PPoints")
    ET.SubElement(pts, "PDataArray", type=_vtk_type(_vtk_points(first).dtype, "Points"),
                  NumberOfComponents="3")
    folder = Path(path).parent if relative_to is None else Path(relative_to)
    for p in paths:
        ET.SubElement(grid, "Piece", Source=_relative(p, folder))
    return _write_text(path, _xml_text(root), overwrite)


def _vtk_type(dtype, name):
    try:
        return VTK_TYPES[np.dtype(dtype).kind, np.dtype(dtype).itemsize]
    except KeyError:
        raise InputError(f"array {name!r} has type {dtype}, which a .pvtu cannot declare") from None


def write_vtm(path, piece_paths, *, overwrite: bool = False) -> Path:
    """Write a ``.vtm`` (vtkMultiBlockDataSet) with one block per piece, named by the
    piece's file stem and referenced by its path relative to the ``.vtm``'s folder."""
    paths = _existing(piece_paths)
    root = _vtk_file("vtkMultiBlockDataSet")
    blocks = ET.SubElement(root, "vtkMultiBlockDataSet")
    folder = Path(path).parent
    for i, p in enumerate(paths):
        ET.SubElement(blocks, "DataSet", index=str(i), name=p.stem, file=_relative(p, folder))
    return _write_text(path, _xml_text(root), overwrite)


def merge_pieces(piece_paths, out_vtu, *, overwrite: bool = False) -> Path:
    """Merge pieces into one ``.vtu`` over the global point numbering.

    A point that several pieces share (the same ``original_index``) appears once; the points
    are sorted by ``original_index``; every tetrahedron of every piece is kept (remapped to
    the merged points).  The merged file has the point arrays ``value`` and
    ``original_index`` (other point arrays are dropped).

    Raises
    ------
    InputError
        A missing or unreadable piece, a piece without ``value`` or ``original_index`` or
        with cells other than tetrahedra, or a point that two pieces give different
        coordinates or values.
    """
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonDataModel import VTK_TETRA

    paths = _existing(piece_paths)
    points, values, ids, tets = [], [], [], []
    offset = 0
    for p in paths:
        g, arrays = _read_vtk_dataset(p, "piece")
        for name in ("value", "original_index"):
            if name not in arrays:
                raise InputError(f"piece {str(p)!r} has no point array {name!r}")
        if g.GetNumberOfCells() and not (g.IsHomogeneous() and g.GetCellType(0) == VTK_TETRA):
            raise InputError(f"piece {str(p)!r} has cells other than tetrahedra")
        points.append(np.asarray(_vtk_points(g), float))
        values.append(arrays["value"].astype(float))
        ids.append(arrays["original_index"].astype(np.int64))
        tets.append(np.asarray(vtk_to_numpy(g.GetCells().GetConnectivityArray()), np.int64).reshape(-1, 4) + offset)
        offset += g.GetNumberOfPoints()
    points, values, ids = np.concatenate(points), np.concatenate(values), np.concatenate(ids)
    unique, first, inverse = np.unique(ids, return_index=True, return_inverse=True)
    # a shared point must be the same point in every piece
    differ = np.any(points != points[first][inverse], axis=1) | (values != values[first][inverse])
    if differ.any():
        bad = int(ids[np.argmax(differ)])
        raise InputError(f"original_index {bad} has different coordinates or values in two pieces")
    return write_piece(out_vtu, points[first], inverse.ravel()[np.concatenate(tets)], values[first], unique,
                       overwrite=overwrite)
