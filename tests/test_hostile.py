"""Hostile input, as a new user would try it: every case ends in one line on stderr,
exit status 2 (or 1 for a failed comparison), and no output folder.

``python tests/test_hostile.py`` prints the matrix (case, exit status, message).
"""

from __future__ import annotations

import contextlib
import io
import sys
from pathlib import Path

import numpy as np
import pytest

from trivsel.cli import main

FN = ["--function", "4", "--n", "6"]


def _write(tmp: Path, name: str, make) -> str:
    p = tmp / name
    make(p)
    return str(p)


def _npz(**arrays):
    return lambda p: np.savez(p, **arrays)


def _text(s: str | bytes):
    return lambda p: (p.write_bytes(s) if isinstance(s, bytes) else p.write_text(s))


def _cloud(n=50, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.random((n, 3))
    return p, np.sin(3 * p[:, 0]) + p[:, 1]


def _cases(tmp: Path):
    """(name, argv, expected exit status, a fragment of the one-line message)."""
    p, f = _cloud()
    flat = p.copy()
    flat[:, 2] = 0.5
    dup = np.concatenate([p, p[:1]])
    nanv = f.copy()
    nanv[3] = np.nan
    out = str(tmp / "out")
    existing = _write(tmp, "a_file", _text("keep me"))
    cases = [
        ("no input and no --function", ["reduce", "--fractions", "0.5", "--out", out], 2, "give either"),
        ("input and --function", ["reduce", existing, *FN, "--fractions", "0.5", "--out", out], 2, "not both"),
        ("missing input file", ["reduce", str(tmp / "nope.vti"), "--fractions", "0.5", "--out", out], 2,
         "does not exist"),
        ("unsupported suffix", ["reduce", _write(tmp, "x.mnc", _text("x")), "--fractions", "0.5", "--out", out], 2,
         "unsupported file type"),
        ("--out is an existing file", ["reduce", *FN, "--fractions", "0.5", "--out", existing], 2, "existing file"),
        ("--out would hold the input", ["reduce", _write(tmp, "in.npz", _npz(points=p, values=f)),
                                        "--fractions", "0.5", "--out", str(tmp)], 2, "input"),
        ("npz without values", ["reduce", _write(tmp, "nov.npz", _npz(points=p)), "--fractions", "0.5",
                                "--out", out], 2, "values"),
        ("npz points not N x 3", ["reduce", _write(tmp, "p2.npz", _npz(points=p[:, :2], values=f)),
                                  "--fractions", "0.5", "--out", out], 2, "points"),
        ("npz values of another length", ["reduce", _write(tmp, "len.npz", _npz(points=p, values=f[:-1])),
                                          "--fractions", "0.5", "--out", out], 2, "values"),
        ("npz of complex values", ["reduce", _write(tmp, "cx.npz", _npz(points=p, values=f + 1j)),
                                   "--fractions", "0.5", "--out", out], 2, "values"),
        ("npz that is not a zip", ["reduce", _write(tmp, "junk.npz", _text(b"\x00\x01junk")), "--fractions", "0.5",
                                   "--out", out], 2, "junk.npz"),
        ("npz of object arrays", ["reduce", _write(tmp, "obj.npz", _npz(points=p, values=f.astype(object))),
                                  "--fractions", "0.5", "--out", out], 2, "obj.npz"),
        ("npz grid with a bad spacing", ["reduce", _write(tmp, "sp.npz", _npz(values=np.zeros((3, 3, 3)),
                                                                              spacing=np.array([1.0, -1.0, 1.0]))),
                                         "--fractions", "0.5", "--out", out], 2, "spacing"),
        ("NaN value", ["reduce", _write(tmp, "nan.npz", _npz(points=p, values=nanv)), "--fractions", "0.5",
                       "--out", out], 2, "nan"),
        ("duplicate points", ["reduce", _write(tmp, "dup.npz", _npz(points=dup, values=np.append(f, 0.0))),
                              "--fractions", "0.5", "--out", out], 2, "duplicate"),
        ("three points", ["reduce", _write(tmp, "three.npz", _npz(points=p[:3], values=f[:3])), "--fractions", "0.5",
                          "--out", out], 2, "points"),
        ("coplanar points", ["reduce", _write(tmp, "flat.npz", _npz(points=flat, values=f)), "--fractions", "0.5",
                             "--out", out], 2, "coplanar"),
        ("CSV without z", ["reduce", _write(tmp, "noz.csv", _text("x,y,value\n0,0,1\n")), "--fractions", "0.5",
                           "--out", out], 2, "z"),
        ("CSV with text values", ["reduce", _write(tmp, "txt.csv", _text("x,y,z,value\n0,0,0,a\n1,0,0,b\n")),
                                  "--fractions", "0.5", "--out", out], 2, "txt.csv"),
        ("unknown --array", ["reduce", _write(tmp, "arr.npz", _npz(points=p, values=f)), "--array", "rho",
                             "--fractions", "0.5", "--out", out], 2, "rho"),
        ("--volume on a CSV", ["reduce", _write(tmp, "v.csv", _text("x,y,z,value\n0,0,0,1\n")), "--volume", "1",
                               "--fractions", "0.5", "--out", out], 2, "volume"),
        ("fraction 0", ["reduce", *FN, "--fractions", "0", "--out", out], 2, "0"),
        ("fraction 1.5", ["reduce", *FN, "--fractions", "1.5", "--out", out], 2, "1.5"),
        ("fraction nan", ["reduce", *FN, "--fractions", "nan", "--out", out], 2, "nan"),
        ("fraction below the fixed points", ["reduce", *FN, "--fractions", "1e-12", "--out", out], 2, "fixed"),
        ("fraction not a number", ["reduce", *FN, "--fractions", "half", "--out", out], 2, "half"),
        ("count 0", ["reduce", *FN, "--count", "0", "--out", out], 2, "count"),
        ("count above N", ["reduce", *FN, "--count", "100000", "--out", out], 2, "count"),
        ("no stopping rule", ["reduce", *FN, "--out", out], 2, "fractions"),
        ("tol_rms inf", ["reduce", *FN, "--tol-rms", "inf", "--out", out], 2, "tol_rms"),
        ("tol_inf negative", ["reduce", *FN, "--tol-inf", "-1", "--out", out], 2, "tol_inf"),
        ("grid n = 1", ["reduce", "--function", "4", "--n", "1", "--fractions", "0.5", "--out", out], 2, "n"),
        ("grid too large for memory", ["reduce", "--function", "4", "--n", "2000", "--fractions", "0.1",
                                       "--out", out], 2, "GiB"),
        ("unknown function", ["reduce", "--function", "9", "--fractions", "0.5", "--out", out], 2, "9"),
        ("unknown method", ["reduce", *FN, "--method", "foo", "--fractions", "0.5", "--out", out], 2, "foo"),
        ("negative seed", ["reduce", *FN, "--seed", "-1", "--fractions", "0.5", "--out", out], 2, "seed"),
        ("rel_tol nan", ["reduce", *FN, "--rel-tol", "nan", "--fractions", "0.5", "--out", out], 2, "rel_tol"),
        ("rel_tol inf", ["reduce", *FN, "--rel-tol", "inf", "--fractions", "0.5", "--out", out], 2, "rel_tol"),
        ("quantum nan", ["reduce", *FN, "--quantum", "nan", "--fractions", "0.5", "--out", out], 2, "quantum"),
        ("max_flips negative", ["reduce", *FN, "--max-flips", "-1", "--fractions", "0.5", "--out", out], 2,
         "max_flips"),
        ("threads 0", ["reduce", *FN, "--threads", "0", "--fractions", "0.5", "--out", out], 2, "threads"),
        ("compare: missing table", ["compare", str(tmp / "no.csv"), existing], 2, "does not exist"),
        ("compare: a folder", ["compare", str(tmp), existing], 2, "not a file"),
        ("compare: empty table", ["compare", _write(tmp, "e.csv", _text("")), existing], 2, "cannot read"),
        ("compare: binary junk", ["compare", _write(tmp, "j.csv", _text(b"\xc1\xff\x00junk")), existing], 2,
         "cannot read"),
        ("compare: no numeric column", ["compare", existing, existing], 2, "no numeric column"),
        ("compare: rtol nan", ["compare", existing, existing, "--rtol", "nan"], 2, "--rtol"),
        ("compare: tables differ", ["compare", _write(tmp, "n.csv", _text("a,b\n1,2\n")),
                                    _write(tmp, "g.csv", _text("a,b\n1,3\n"))], 1, "b"),
    ]
    return cases + _output_cases(tmp) + _input_cases(tmp)


BIG = 2**53 + 1  # the first integer float64 cannot hold
BEYOND = "is beyond 2^53: float64 cannot hold it exactly"
NOT_OURS = "exists and no trivsel run wrote it"


def _big_grid(dtype=np.int64):
    v = np.arange(27, dtype=dtype).reshape(3, 3, 3)
    v[1, 2, 0] = BIG
    return v


def _nifti(data, affine=None, *, pixdim=None, sform=None, qform=None):
    def make(p):
        import nibabel as nib

        img = nib.Nifti1Image(data, affine, dtype=data.dtype)  # no affine: the header's pixdim is kept
        if pixdim is not None:
            img.header["pixdim"][1:4] = pixdim
        if sform is not None:
            img.header["sform_code"] = sform
        if qform is not None:
            img.header["qform_code"] = qform
        nib.save(img, p)
    return make


def _nrrd(data, header, **kwargs):
    def make(p):
        import nrrd

        nrrd.write(str(p), data, header, **kwargs)
    return make


def _vti(values, origin=(0.0, 0.0, 0.0)):
    def make(p):
        import pyvista as pv

        g = pv.ImageData(dimensions=values.shape, origin=origin)
        g.point_data["v"] = values.ravel(order="F")
        g.save(p)
    return make


def _zarr(values, attributes):
    def make(p):
        import zarr

        if int(zarr.__version__.split(".")[0]) >= 3:
            zarr.create_array(store=str(p), data=values, attributes=attributes, zarr_format=3)
        else:
            a = zarr.open_array(str(p), mode="w", shape=values.shape, dtype=values.dtype)
            a[...] = values
            a.attrs.update(attributes)
    return make


def _npy(values):
    return lambda p: np.save(p, values)


def _huge_npz(p):
    """An .npz whose header declares a 4000^3 float64 grid (477 GiB) over a few bytes of data."""
    import zipfile

    buf = io.BytesIO()
    np.lib.format.write_array_header_2_0(buf, {"descr": "<f8", "fortran_order": False, "shape": (4000,) * 3})
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("values.npy", buf.getvalue() + b"\0" * 64)


def _huge_npy(p):
    """A .npy whose header declares 2e11 x 3 int64 (4.4 TiB) over a few bytes of data."""
    with open(p, "wb") as fh:
        np.lib.format.write_array_header_2_0(fh, {"descr": "<i8", "fortran_order": False, "shape": (2 * 10**11, 3)})
        fh.write(b"\0" * 64)


def _huge_nhdr(p):
    """A raw NRRD header declaring 4000^3 float64 samples over a data file of 64 bytes."""
    (p.parent / "huge.raw").write_bytes(b"\0" * 64)
    p.write_text("NRRD0004\ntype: double\ndimension: 3\nsizes: 4000 4000 4000\nendian: little\n"
                 "encoding: raw\ndata file: huge.raw\n\n")


def _huge_nifti(p):
    """A NIfTI header declaring 4000^3 float32 voxels, with 64 bytes of data after it."""
    import nibabel as nib

    hdr = nib.Nifti1Header()
    hdr.set_data_shape((4000,) * 3)
    hdr.set_data_dtype(np.float32)
    with open(p, "wb") as fh:
        hdr.write_to(fh)
        fh.write(b"\0" * (352 - fh.tell() + 64))


def _huge_vti(p):
    """An image declaring 4000^3 points, with one tiny inline array."""
    p.write_text('<?xml version="1.0"?>\n<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian">\n'
                 '<ImageData WholeExtent="0 3999 0 3999 0 3999" Origin="0 0 0" Spacing="1 1 1">\n'
                 '<Piece Extent="0 3999 0 3999 0 3999"><PointData Scalars="v">\n'
                 '<DataArray type="Float64" Name="v" format="ascii">0 1 2</DataArray>\n'
                 '</PointData></Piece></ImageData></VTKFile>\n')


def _output_cases(tmp: Path):
    """Output folders and files that are not trivsel's to write."""
    theirs = tmp / "theirs"
    theirs.mkdir(exist_ok=True)
    (theirs / "errors.csv").write_text("their table")
    mine = tmp / "mine"
    mine.mkdir(exist_ok=True)
    (mine / "mesh_0.5.vtu").write_text("their mesh")
    store = _write(tmp, "store.zarr", _zarr(np.zeros((3, 3, 3)), {}))
    arr = _write(tmp, "arr.npy", _npy(np.zeros((3, 3, 3))))
    (tmp / "empty.zarr").mkdir(exist_ok=True)
    return [
        ("--out empty", ["reduce", *FN, "--fractions", "0.5", "--out", ""], 2, "--out '' is empty"),
        ("--out holds a foreign errors.csv", ["reduce", *FN, "--fractions", "0.5", "--out", str(theirs)], 2,
         f"errors.csv' {NOT_OURS}"),
        ("--out holds a foreign mesh", ["reduce", *FN, "--fractions", "0.5", "--out", str(mine)], 2,
         f"mesh_0.5.vtu' {NOT_OURS}"),
        ("convert: output empty", ["convert", arr, ""], 2, "the output '' is empty"),
        ("convert: output inside the input", ["convert", store, f"{store}/inner.zarr"], 2,
         "is inside the input"),
        ("convert: output an existing empty folder", ["convert", arr, str(tmp / "empty.zarr")], 2,
         "exists: trivsel convert never overwrites"),
        ("convert: output under a file", ["convert", arr, str(tmp / "a_file" / "x.zarr")], 2, "is not writable"),
    ]


def _input_cases(tmp: Path):
    """Inputs whose values or geometry would be silently changed, or that would fill the memory."""
    out = str(tmp / "out")
    red = ["--fractions", "0.5", "--out", out]
    p, f = _cloud()
    big_ints = np.arange(50, dtype=np.int64)
    big_ints[7] = -BIG
    csv = "x,y,z,value\n" + "".join(f"{a},{b},{c},{v}\n" for (a, b, c), v in zip(p, big_ints))
    nan3 = np.array([np.nan, 0.0, 0.0])
    nan_affine = np.eye(4)
    nan_affine[0, 3] = np.nan
    grid = np.random.default_rng(3).random((3, 4, 5))
    return [
        ("npz grid of integers beyond 2^53", ["reduce", _write(tmp, "bigg.npz", _npz(values=_big_grid())), *red],
         2, f"value {BIG} at grid index (1, 2, 0) of 'bigg' {BEYOND}"),
        ("npz points of integers beyond 2^53", ["reduce", _write(tmp, "bigs.npz", _npz(points=p, values=big_ints)),
                                                *red], 2, f"value {-BIG} at point 7 of 'bigs' {BEYOND}"),
        ("CSV of integers beyond 2^53", ["reduce", _write(tmp, "big.csv", _text(csv)), *red], 2,
         f"value {-BIG} at point 7 of 'big' {BEYOND}"),
        ("CSV of integers beyond 64 bits", ["reduce", _write(tmp, "huge.csv", _text(csv.replace(
            f",{-BIG}\n", f",{2**64 + 5}\n"))), *red], 2, f"value {2**64 + 5} at point 7 of 'huge' {BEYOND}"),
        ("vti of integers beyond 2^53", ["reduce", _write(tmp, "big.vti", _vti(_big_grid())), *red], 2,
         f"value {BIG} at grid index (1, 2, 0) of 'big' {BEYOND}"),
        ("NRRD of uint64 beyond 2^53", ["reduce", _write(tmp, "big.nrrd", _nrrd(_big_grid(np.uint64), {})), *red],
         2, f"value {BIG} at grid index (1, 2, 0) of 'big' {BEYOND}"),
        ("NIfTI of int64 beyond 2^53", ["reduce", _write(tmp, "big.nii", _nifti(_big_grid(), np.eye(4))), *red], 2,
         f"value {BIG} at voxel (1, 2, 0) of"),
        ("convert: npy beyond 2^53",
         ["convert", _write(tmp, "big.npy", _npy(_big_grid())), str(tmp / "out" / "b.zarr")], 2,
         f"value {BIG} at grid index (1, 2, 0) of"),
        ("NIfTI zero voxel size, no orientation", ["reduce", _write(tmp, "z.nii", _nifti(grid, pixdim=[0, 1, 1],
                                                                                      sform=0, qform=0)), *red],
         2, "has a zero or missing voxel size (pixdim[1:4] = (0.0, 1.0, 1.0))"),
        ("NIfTI NaN voxel size, qform only", ["reduce", _write(tmp, "q.nii", _nifti(grid, pixdim=[1, np.nan, 1],
                                                                                  sform=0, qform=1)), *red],
         2, "has a zero or missing voxel size (pixdim[1:4] = (1.0, nan, 1.0))"),
        ("convert: NIfTI zero voxel size", ["convert", str(tmp / "z.nii"), str(tmp / "out" / "z.zarr")], 2,
         "has a zero or missing voxel size"),
        ("npz grid origin NaN", ["reduce", _write(tmp, "on.npz", _npz(values=grid, origin=nan3)), *red], 2,
         "grid 'on': the origin must be 3 finite numbers, got (nan, 0.0, 0.0)"),
        ("npz grid origin of 2 numbers", ["reduce", _write(tmp, "o2.npz", _npz(values=grid, origin=np.zeros(2))),
                                          *red], 2, "grid 'o2': the origin must be 3 finite numbers, got (0.0, 0.0)"),
        ("npz grid spacing of 4 numbers", ["reduce", _write(tmp, "s4.npz", _npz(values=grid, spacing=np.ones(4))),
                                           *red], 2,
         "grid spacing must be positive and finite, got (1.0, 1.0, 1.0, 1.0)"),
        ("NRRD zero spacing", ["reduce", _write(tmp, "zs.nrrd", _nrrd(grid, {"spacings": [1.0, 0.0, 1.0]})), *red],
         2, "has a zero voxel size (its spacings"),
        ("npz grid coordinates overflow", ["reduce", _write(tmp, "of.npz", _npz(values=grid, origin=np.full(3, 1e308),
                                                                                spacing=np.full(3, 1e308))), *red],
         2, "grid 'of': the coordinates overflow"),
        ("vti origin NaN", ["reduce", _write(tmp, "on.vti", _vti(grid, origin=(0.0, np.nan, 0.0))), *red], 2,
         "grid 'on': the origin must be 3 finite numbers, got (0, nan, 0)"),
        ("legacy vtk origin inf", ["reduce", _write(tmp, "oi.vtk", _text(
            "# vtk DataFile Version 3.0\nx\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 2 2 2\nORIGIN 0 0 inf\n"
            "SPACING 1 1 1\nPOINT_DATA 8\nSCALARS v double 1\nLOOKUP_TABLE default\n0 1 2 3 4 5 6 7\n")), *red],
         2, "grid 'oi': the origin must be 3 finite numbers, got (0, 0, inf)"),
        ("NIfTI origin NaN", ["reduce", _write(tmp, "on.nii", _nifti(grid, nan_affine)), *red], 2,
         "must be a finite 3 x 3 matrix and offset"),
        ("NRRD origin NaN", ["reduce", _write(tmp, "on.nrrd", _nrrd(grid, {"space": "left-posterior-superior",
                                                                          "space directions": np.eye(3),
                                                                          "space origin": nan3})), *red],
         2, "must be a finite 3 x 3 matrix and offset"),
        ("convert: zarr origin NaN", ["convert", _write(tmp, "on.zarr", _zarr(grid, {"origin": [0, 0, float("nan")]})),
                                      str(tmp / "out" / "o.zarr")], 2, "attribute 'origin' must be 3 finite numbers"),
        ("convert: zarr coordinates overflow",
         ["convert", _write(tmp, "of.zarr", _zarr(grid, {"origin": [1e308] * 3, "spacing": [1e308] * 3})),
          str(tmp / "out" / "o.zarr")], 2, "the coordinates overflow"),
        ("boundary header beyond memory", ["reduce", *FN, "--boundary", _write(tmp, "huge_b.npy", _huge_npy),
                                           *red], 2, "huge_b.npy' (shape (200000000000, 3)) needs about"),
        ("npz header beyond memory", ["reduce", _write(tmp, "huge.npz", _huge_npz), *red], 2,
         "('values' of shape (4000, 4000, 4000)) needs about"),
        ("raw NRRD header beyond memory", ["reduce", _write(tmp, "huge.nhdr", _huge_nhdr), *red], 2,
         "(sizes (4000, 4000, 4000)) needs about"),
        ("NIfTI header beyond memory", ["reduce", _write(tmp, "huge.nii", _huge_nifti), *red], 2,
         "(shape (4000, 4000, 4000)) needs about"),
        ("vti header beyond memory", ["reduce", _write(tmp, "huge.vti", _huge_vti), *red], 2,
         "(64000000000 points) needs about"),
    ]


def _run(argv):
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code
    return code, err.getvalue(), out.getvalue()


def _names():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        return [c[0] for c in _cases(Path(d))]


@pytest.mark.parametrize("name", _names())
def test_hostile_case_gives_one_line_and_no_output(tmp_path, name):
    case = {c[0]: c for c in _cases(tmp_path)}[name]
    _, argv, expected, fragment = case
    code, err, out = _run(argv)
    assert code == expected, (code, err)
    text = err if expected == 2 else out
    lines = [x for x in text.strip().splitlines() if x]
    if expected == 2:
        assert len(lines) == 1 and lines[0].startswith("trivsel"), err
        assert "Traceback" not in err
    assert fragment.lower() in text.lower(), text
    assert not (tmp_path / "out").exists()
    assert (tmp_path / "a_file").read_text() == "keep me"


if __name__ == "__main__":  # the matrix for notes: case | exit | message
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        print("| case | exit | message |\n|---|---|---|")
        for name, argv, _, _ in _cases(Path(d)):
            code, err, out = _run(argv)
            msg = (err.strip() or out.strip()).splitlines()
            print(f"| {name} | {code} | {msg[0] if msg else ''} |")
    sys.exit(0)
