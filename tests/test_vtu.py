"""The ``.vtu`` writer that streams its cells (trivsel.io.vtu): what VTK reads back, what the
format says byte by byte, and the merged mesh written in chunks."""

from __future__ import annotations

import re
import struct
import zlib

import numpy as np
import pytest
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader

import trivsel
from trivsel.io import tetra_grid, write_vtu
from trivsel.io.pieces import write_piece, write_piece_in_chunks
from trivsel.io.vtu import BLOCK, write_tetra_vtu


def _read(path):
    """Everything VTK reads from a .vtu: points, connectivity, offsets, cell types, the point
    arrays (name, type, values) in order, and the active scalars' name."""
    r = vtkXMLUnstructuredGridReader()
    r.SetFileName(str(path))
    r.Update()
    g = r.GetOutput()
    cells = g.GetCells()
    pd = g.GetPointData()
    arrays = [(pd.GetArrayName(k), vtk_to_numpy(pd.GetArray(k))) for k in range(pd.GetNumberOfArrays())]
    active = pd.GetScalars().GetName() if pd.GetScalars() is not None else None
    points = vtk_to_numpy(g.GetPoints().GetData()) if g.GetPoints() is not None else np.zeros((0, 3))
    types = vtk_to_numpy(g.GetCellTypes()) if g.GetNumberOfCells() else np.zeros(0, np.uint8)
    return (points, vtk_to_numpy(cells.GetConnectivityArray()), vtk_to_numpy(cells.GetOffsetsArray()), types,
            arrays, active)


def _decode(path):
    """The file decoded by the format alone (no VTK): each DataArray's attributes and its
    bytes, from its offset in the appended data, its UInt64 header and its zlib blocks."""
    raw = open(path, "rb").read()
    start = raw.index(b"<AppendedData")
    head = raw[:start].decode("ascii")
    data = raw.index(b"_", start) + 1
    assert 'header_type="UInt64"' in head and 'compressor="vtkZLibDataCompressor"' in head
    out = {}
    for tag in re.findall(r"<DataArray [^>]*/>", head):
        attrs = dict(re.findall(r'(\w+)="([^"]*)"', tag))
        at = data + int(attrs["offset"])
        n, block, last = struct.unpack("<3Q", raw[at:at + 24])
        sizes = struct.unpack(f"<{n}Q", raw[at + 24:at + 24 + 8 * n])
        at += 24 + 8 * n
        parts = []
        for k, s in enumerate(sizes):
            part = zlib.decompress(raw[at:at + s])
            assert len(part) == (last if k == n - 1 and last else block)
            parts.append(part)
            at += s
        dtype = {"Float64": "<f8", "Int64": "<i8", "UInt8": "<u1"}[attrs["type"]]
        out[attrs["Name"]] = (attrs, np.frombuffer(b"".join(parts), dtype))
    return head, out


def _mesh(rng, m, t):
    return (rng.random((m, 3)), rng.integers(0, m, (t, 4)) if m else np.zeros((t, 4), int), rng.random(m),
            rng.integers(0, 2**40, m))


# 0 cells; 1; a connectivity of exactly one block (BLOCK // 32 rows) and of one byte more; several blocks
@pytest.mark.parametrize("m, t, chunk", [(0, 0, 5), (4, 0, 5), (4, 1, 5), (50, BLOCK // 32, 100),
                                         (50, BLOCK // 32 + 1, 7), (300, 5000, 1), (300, 5000, 999)])
def test_vtk_reads_the_streamed_file_as_it_reads_its_own_writers(tmp_path, m, t, chunk):
    """The same points, cells, types, point arrays (names, types, values, order) and active
    scalars as the same grid written by VTK's own writer, whatever the chunks of rows."""
    rng = np.random.default_rng(m + t)
    points, tets, values, ids = _mesh(rng, m, t)
    fitted = rng.random(m)
    data = {"value": values, "fitted_value": fitted, "original_index": ids}
    rows = [tets[s:s + chunk] for s in range(0, t, chunk)]
    write_tetra_vtu(tmp_path / "s.vtu", points, rows, t, data, chunk=chunk)
    write_vtu(tetra_grid(points, tets, data), tmp_path / "v.vtu")
    mine, theirs = _read(tmp_path / "s.vtu"), _read(tmp_path / "v.vtu")
    for a, b in zip(mine[:4], theirs[:4]):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert [(n, a.dtype) for n, a in mine[4]] == [(n, a.dtype) for n, a in theirs[4]]
    assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(mine[4], theirs[4]))
    assert mine[5] == theirs[5] == "value"


def test_the_file_is_what_the_format_says(tmp_path):
    """Decoded without VTK: every array at its offset, its header's block count, block size and
    last block, each block's compressed size, and the values written."""
    rng = np.random.default_rng(3)
    points, tets, values, ids = _mesh(rng, 700, 3001)
    write_tetra_vtu(tmp_path / "s.vtu", points, [tets[:1000], tets[1000:]], len(tets),
                    {"value": values, "original_index": ids}, chunk=512)
    head, arrays = _decode(tmp_path / "s.vtu")
    assert 'NumberOfPoints="700" NumberOfCells="3001"' in head and '<PointData Scalars="value">' in head
    assert list(arrays) == ["value", "original_index", "Points", "connectivity", "offsets", "types"]
    assert np.array_equal(arrays["value"][1], values) and np.array_equal(arrays["original_index"][1], ids)
    assert arrays["Points"][0]["NumberOfComponents"] == "3"
    assert np.array_equal(arrays["Points"][1].reshape(-1, 3), points)
    assert np.array_equal(arrays["connectivity"][1].reshape(-1, 4), tets)
    assert np.array_equal(arrays["offsets"][1], 4 * np.arange(1, 3002))
    assert np.all(arrays["types"][1] == 10)


def test_chunks_that_do_not_match_what_was_announced_leave_no_file(tmp_path):
    """Too few or too many rows, rows of another shape, a corner outside the points: a
    ValueError naming it, and neither the file nor a temporary beside it."""
    rng = np.random.default_rng(4)
    points, tets, values, ids = _mesh(rng, 20, 10)
    bad = tets.copy()
    bad[7, 2] = 20
    for chunks, n, message in (([tets], 11, "10 cells given, 11 announced"),
                               ([tets, tets], 10, "more than the 10 cells announced"),
                               ([tets[:, :3]], 10, r"\(k, 4\) integer chunks"),
                               ([tets.astype(float)], 10, r"\(k, 4\) integer chunks"),
                               ([bad], 10, "refers to point 20")):
        with pytest.raises(ValueError, match=message):
            write_piece_in_chunks(tmp_path / "x.vtu", points, lambda c=chunks: iter(c), n, values, ids)
        assert list(tmp_path.iterdir()) == []
    with pytest.raises(trivsel.InputError, match="original_index 18446744073709551615 does not fit"):
        write_piece(tmp_path / "x.vtu", points, tets, values, np.full(20, 2**64 - 1, np.uint64))
    assert list(tmp_path.iterdir()) == []


def test_the_merged_mesh_is_the_same_file_in_chunks_or_whole(tmp_path):
    """``_write_mesh`` renumbers a large mesh a chunk of rows at a time against its sorted
    vertices, and a small one with ``np.unique``: the same file, byte for byte, with the
    vertices sorted by the input's point id and every cell over the same grid points."""
    from trivsel.blocks.decimate import _write_mesh
    from trivsel.io.regions import open_volume
    from trivsel.triangulation import kuhn_tetrahedra

    vol = open_volume(function=4, n=8)
    shape = vol.shape
    d = vol.region_data(tuple((0, n) for n in shape))
    tets = kuhn_tetrahedra(shape)
    tets = tets[np.random.default_rng(5).permutation(len(tets))[:len(tets) // 3]]  # not every point a corner
    f = d.values
    vertices = np.unique(tets)
    fit_at = (vertices, np.linspace(-1, 1, len(vertices)))
    every = (np.arange(len(f)), f)  # values at more points than the corners: each takes its own
    _write_mesh(tmp_path / "whole.vtu", vol, shape, tets, every, fit_at, chunk=len(tets))
    _write_mesh(tmp_path / "chunks.vtu", vol, shape, tets, (vertices, f[vertices]), fit_at, chunk=97)
    assert (tmp_path / "whole.vtu").read_bytes() == (tmp_path / "chunks.vtu").read_bytes()
    points, conn, _, _, arrays, _ = _read(tmp_path / "chunks.vtu")
    named = dict(arrays)
    assert np.all(np.diff(named["original_index"]) > 0)
    at = np.argsort(d.file_ids(vertices))
    assert np.array_equal(named["original_index"], d.file_ids(vertices)[at])
    assert np.array_equal(points, d.points[vertices[at]])
    assert np.array_equal(named["fitted_value"], fit_at[1][at])
    assert np.array_equal(named["value"], f[vertices[at]])
    assert np.array_equal(vertices[at][conn.reshape(-1, 4)], tets)
