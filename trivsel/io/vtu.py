"""A ``.vtu`` of tetrahedra written a chunk at a time, in VTK's XML format, without a VTK
grid or the file's text in memory.

:func:`write_tetra_vtu` writes what VTK's ``vtkXMLUnstructuredGridWriter`` writes with
appended raw data and zlib compression (``SetDataModeToAppended()``,
``EncodeAppendedDataOff()``, ``SetCompressorTypeToZLib()``), with 64-bit headers: the XML
first, then each array's bytes, compressed in blocks::

    <VTKFile type="UnstructuredGrid" version="1.0" header_type="UInt64" compressor=...>
      ... <DataArray type="Float64" Name="value" format="appended" offset="0"   />
      ... <DataArray type="Int64" Name="connectivity" format="appended" offset="812" />
      <AppendedData encoding="raw">
       _[header][block][block]...[header][block]...       offsets count from after "_"
      </AppendedData>

    header: UInt64 [number of blocks, block size, bytes in the last block (0: a full
            block), the compressed size of each block]

An array's header comes before its blocks, but the compressed sizes are known only once the
blocks are written; so a header of the same length is written first and filled in after the
array's last block, and the XML's offsets, fields of a fixed width, are filled in at the end.
The cells' connectivity comes as chunks of rows, so that a caller never holds it whole
(a merged mesh of tens of millions of tetrahedra); VTK's writer holds its own copies of every
array and, in memory, the compressed file.
"""

from __future__ import annotations

import zlib
from xml.sax.saxutils import quoteattr

import numpy as np

__all__ = ["write_tetra_vtu"]

#: Uncompressed bytes per compressed block (VTK's default).
BLOCK = 32768
#: zlib's level (VTK's ``vtkZLibDataCompressor`` default).
LEVEL = 5
#: Room for an offset in the XML: any 64-bit byte count fits.
_OFFSET_WIDTH = 20
#: VTK's cell type of a tetrahedron.
VTK_TETRA = 10
#: (numpy kind, bytes) -> VTK XML type name.
VTK_TYPES = {("i", 1): "Int8", ("u", 1): "UInt8", ("i", 2): "Int16", ("u", 2): "UInt16", ("i", 4): "Int32",
             ("u", 4): "UInt32", ("i", 8): "Int64", ("u", 8): "UInt64", ("f", 4): "Float32", ("f", 8): "Float64"}


class _Blocks:
    """One array's compressed blocks, written as its bytes arrive (``add``), with its header
    filled in by ``close``."""

    def __init__(self, fh, nbytes):
        self.fh, self.nbytes = fh, nbytes
        self.nblocks = -(-nbytes // BLOCK)
        self.at = fh.tell()
        fh.write(bytes(8 * (3 + self.nblocks)))  # the header, filled in by close
        self.sizes, self.pending, self.seen = [], bytearray(), 0

    def _emit(self, data):
        out = zlib.compress(data, LEVEL)
        self.fh.write(out)
        self.sizes.append(len(out))

    def add(self, a):
        view = memoryview(np.ascontiguousarray(a).reshape(-1).view(np.uint8))
        self.seen += len(view)
        if self.seen > self.nbytes:
            raise ValueError(f"more than the {self.nbytes} bytes announced")
        if self.pending:
            need = BLOCK - len(self.pending)
            self.pending += view[:need]
            view = view[need:]
            if len(self.pending) < BLOCK:
                return
            self._emit(bytes(self.pending))
            self.pending = bytearray()
        full = len(view) - len(view) % BLOCK
        for s in range(0, full, BLOCK):
            self._emit(view[s:s + BLOCK])
        self.pending = bytearray(view[full:])

    def close(self):
        if self.pending:
            self._emit(bytes(self.pending))
        if self.seen != self.nbytes or len(self.sizes) != self.nblocks:
            raise ValueError(f"{self.seen} bytes written, {self.nbytes} announced")
        end = self.fh.tell()
        self.fh.seek(self.at)
        self.fh.write(np.array([self.nblocks, BLOCK, self.nbytes % BLOCK, *self.sizes], "<u8").tobytes())
        self.fh.seek(end)


def _xml(n_points, n_cells, arrays, offsets):
    """The file's XML up to the appended data's "_", the offsets as fixed-width fields."""

    def array(name, dtype, components, offset):
        o = f'offset="{offset}"'
        comp = f' NumberOfComponents="{components}"' if components != 1 else ""
        return (f'<DataArray type="{VTK_TYPES[dtype.kind, dtype.itemsize]}" Name={quoteattr(name)}{comp} '
                f'format="appended" {o}{" " * (_OFFSET_WIDTH + 9 - len(o))}/>')

    def tags(kind):
        return [array(name, dt, c, o) for (name, dt, c, k, _), o in zip(arrays, offsets) if k == kind]

    point, coords, cells = tags("point"), tags("points"), tags("cells")
    scalars = ' Scalars="value"' if any(name == "value" and k == "point" for name, _, _, k, _ in arrays) else ""
    ind = "\n" + " " * 8
    return ('<?xml version="1.0"?>\n'
            '<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64" '
            'compressor="vtkZLibDataCompressor">\n'
            '  <UnstructuredGrid>\n'
            f'    <Piece NumberOfPoints="{n_points}" NumberOfCells="{n_cells}">\n'
            f'      <PointData{scalars}>{ind}{ind.join(point)}\n      </PointData>\n'
            '      <CellData>\n      </CellData>\n'
            f'      <Points>{ind}{ind.join(coords)}\n      </Points>\n'
            f'      <Cells>{ind}{ind.join(cells)}\n      </Cells>\n'
            '    </Piece>\n'
            '  </UnstructuredGrid>\n'
            '  <AppendedData encoding="raw">\n   _').encode("ascii")


def write_tetra_vtu(path, points, cells, n_cells, point_data, *, chunk=1 << 20):
    """Write tetrahedra as a ``.vtu`` file (VTK_TETRA cells; appended raw data, zlib).

    Parameters
    ----------
    path : str or path-like
        The file, written in place (a caller that wants it atomic writes a temporary file).
    points : (M, 3) float
        The points, stored as Float64.
    cells : iterable of (k, 4) int arrays
        The tetrahedra, as indices into ``points``, in chunks of rows; read once.
    n_cells : int
        The number of rows the chunks hold together.
    point_data : dict of str to (M,) array
        Point arrays, in order: floats are stored as Float64, integers as Int64; one named
        ``value`` is the active scalars.
    chunk : int
        Rows of the cells' offsets and types made at a time.

    Raises
    ------
    ValueError
        Chunks that are not (k, 4) integers, that index outside ``points`` or that do not
        add up to ``n_cells`` rows; a point array of another length.  The file is then
        incomplete: the caller removes it.
    """
    points = np.asarray(points, "<f8")
    m = len(points)
    if points.shape != (m, 3):
        raise ValueError(f"points must be (M, 3), got {points.shape}")
    n_cells = int(n_cells)
    arrays, data = [], []
    for name, a in point_data.items():
        a = np.asarray(a)
        if a.shape != (m,) or a.dtype.kind not in "iuf":
            raise ValueError(f"point array {name!r} must be {m} numbers, got {a.dtype} of shape {a.shape}")
        dt = np.dtype("<f8") if a.dtype.kind == "f" else np.dtype("<i8")
        arrays.append((name, dt, 1, "point", m))
        data.append(a)
    # (name, type, components, where it goes, tuples)
    arrays += [("Points", np.dtype("<f8"), 3, "points", m), ("connectivity", np.dtype("<i8"), 1, "cells", 4 * n_cells),
               ("offsets", np.dtype("<i8"), 1, "cells", n_cells), ("types", np.dtype("<u1"), 1, "cells", n_cells)]
    offsets = [0] * len(arrays)
    with open(path, "wb") as fh:
        head = _xml(m, n_cells, arrays, offsets)
        fh.write(head)
        start = fh.tell()

        def one(k, parts):
            _, dt, components, _, tuples = arrays[k]
            offsets[k] = fh.tell() - start
            out = _Blocks(fh, tuples * components * dt.itemsize)
            for part in parts:
                out.add(part)
            out.close()

        for k, (a, (_, dt, _, _, _)) in enumerate(zip(data, arrays)):
            one(k, [a.astype(dt, copy=False)])
        one(len(data), [points])

        def connectivity():
            rows = 0
            for c in cells:
                c = np.asarray(c)
                if c.ndim != 2 or c.shape[1] != 4 or (c.size and c.dtype.kind not in "iu"):
                    raise ValueError(f"cells must come as (k, 4) integer chunks, got {c.dtype} of shape {c.shape}")
                if c.size and (c.min() < 0 or c.max() >= m):
                    raise ValueError(f"a cell refers to point {int(c.min() if c.min() < 0 else c.max())}: "
                                     f"need 0 <= index < {m}")
                rows += len(c)
                if rows > n_cells:
                    raise ValueError(f"more than the {n_cells} cells announced")
                yield c.astype("<i8", copy=False)
            if rows != n_cells:
                raise ValueError(f"{rows} cells given, {n_cells} announced")

        one(len(data) + 1, connectivity())
        one(len(data) + 2, (np.arange(s + 1, min(s + chunk, n_cells) + 1, dtype="<i8") * 4
                            for s in range(0, n_cells, chunk)))
        one(len(data) + 3, (np.full(min(chunk, n_cells - s), VTK_TETRA, "<u1") for s in range(0, n_cells, chunk)))
        fh.write(b"\n  </AppendedData>\n</VTKFile>\n")
        fh.seek(0)
        final = _xml(m, n_cells, arrays, offsets)
        if len(final) != len(head):  # the fields are wide enough for any offset
            raise ValueError("the XML's length changed")
        fh.write(final)
