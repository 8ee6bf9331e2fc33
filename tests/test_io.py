"""File formats: geometry and values exactly as the file says, and `original_index` in the output
meshes is the input's own point id (values[original_index] == value, coordinates equal)."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
import pyvista as pv

import trivsel
from trivsel.cli import main
from trivsel.io import load, save_npz


def _check_round_trip(out, file_points, file_values):
    m = pv.read(out / "mesh_0.3.vtu")
    ids = m.point_data["original_index"]
    np.testing.assert_array_equal(m.point_data["value"], file_values[ids])
    np.testing.assert_allclose(m.points, file_points[ids], rtol=0, atol=1e-12)


def _image(extent_offset):
    g = pv.ImageData(dimensions=(6, 5, 4), spacing=(0.5, 2.0, 3.0), origin=(10.0, -1.0, 2.0))
    if extent_offset:
        g.extent = (3, 8, 2, 6, 1, 4)  # the first point is at origin + (3, 2, 1) * spacing
    x, y, z = np.asarray(g.points).T
    g.point_data["density"] = np.sin(x) + y * z / 10 + 0.01 * x * x
    return g


@pytest.mark.parametrize("extent_offset", [False, True])
def test_vti_geometry_and_point_ids(tmp_path, extent_offset):
    g = _image(extent_offset)
    g.save(tmp_path / "v.vti")
    data = load(tmp_path / "v.vti")
    assert data.is_grid and data.shape == (6, 5, 4)
    np.testing.assert_allclose(np.asarray(g.points)[data.file_index], data.points, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(g.point_data["density"])[data.file_index], data.values)
    out = tmp_path / "out"
    assert main(["reduce", str(tmp_path / "v.vti"), "--fractions", "0.3", "--out", str(out)]) == 0
    _check_round_trip(out, np.asarray(g.points), np.asarray(g.point_data["density"]))


def test_a_csv_column_named_exactly_is_taken_before_one_in_other_case(tmp_path):
    """``x, y, z, value`` name their columns: an exact name (spaces aside) first, then one in
    other case; two candidates of which none is exact are refused (a hostile case)."""
    rng = np.random.default_rng(1)
    q = rng.random((30, 3))
    path = tmp_path / "c.csv"
    path.write_text("X,x,y, Z ,value,Value\n" + "".join(f"{a + 50},{a},{b},{c},{a},{a + 100}\n" for a, b, c in q))
    d = load(path)
    assert np.array_equal(d.points, q) and np.array_equal(d.values, q[:, 0])
    assert np.array_equal(load(path, array="Value").values, q[:, 0] + 100)


def test_a_nrrd_without_space_directions_is_placed_by_its_axis_mins_and_maxs(tmp_path):
    """Per axis: ``spacings`` and ``axis mins`` (a node-centred axis starts at its min, a
    cell-centred one, the format's default, half a spacing past it), or a spacing from
    ``axis mins`` and ``axis maxs``."""
    import nrrd

    v = np.random.default_rng(0).random((4, 5, 6))
    nrrd.write(str(tmp_path / "a.nrrd"), v, {"spacings": [2.0, 3.0, 4.0], "axis mins": [5.0, 6.0, 7.0],
                                             "centerings": ["node", "cell", "???"]})
    nrrd.write(str(tmp_path / "b.nrrd"), v, {"axis mins": [5.0, 6.0, 7.0], "axis maxs": [11.0, 16.0, 31.0]})
    for name, origin, spacing in (("a", (5.0, 7.5, 9.0), (2.0, 3.0, 4.0)), ("b", (5.75, 7.0, 9.0), (1.5, 2.0, 4.0))):
        d = load(tmp_path / f"{name}.nrrd")
        assert np.allclose(d.origin, origin, rtol=0, atol=1e-12) and np.allclose(d.spacing, spacing, rtol=0, atol=1e-12)
        assert np.array_equal(d.values.reshape(4, 5, 6), v)


def test_vtu_csv_and_npz_point_ids_are_rows(tmp_path):
    rng = np.random.default_rng(3)
    pts = rng.random((120, 3)) * [1, 2, 3] + [5, 0, -1]
    vals = np.cos(pts @ [1.0, 0.5, 0.2])
    pd.DataFrame({"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "value": vals}).to_csv(tmp_path / "p.csv",
                                                                                           index=False)
    np.savez(tmp_path / "p.npz", points=pts, values=vals)
    cloud = pv.PolyData(pts)
    cloud.point_data["value"] = vals
    cloud.save(tmp_path / "p.vtp")
    for name in ("p.csv", "p.npz", "p.vtp"):
        out = tmp_path / f"out-{name}"
        assert main(["reduce", str(tmp_path / name), "--fractions", "0.3", "--out", str(out)]) == 0, name
        _check_round_trip(out, pts, vals)


def test_npz_grid_round_trip_and_function_grid_ids(tmp_path):
    data = trivsel.sample_grid(2, 6)
    save_npz(data, tmp_path / "g.npz")
    back = load(tmp_path / "g.npz")
    assert back.file_index is None and back.shape == data.shape
    out = tmp_path / "out"
    assert main(["reduce", str(tmp_path / "g.npz"), "--fractions", "0.3", "--out", str(out)]) == 0
    _check_round_trip(out, data.points, data.values)


def test_npz_other_value_arrays_are_alternatives_and_other_members_refused(tmp_path):
    """Beside its layout (a grid: values, origin, spacing; points: points, values; either: name)
    an .npz may hold other value arrays of the shape of ``values``, one of which ``array``
    picks; any other member is refused in one line naming it."""
    import zipfile

    p = np.random.default_rng(4).random((30, 3))
    np.savez(tmp_path / "alt.npz", points=p, values=p[:, 0], rho=p[:, 1], name=np.array("cloud"))
    d = load(tmp_path / "alt.npz", array="rho")
    assert np.array_equal(d.values, p[:, 1]) and np.array_equal(d.points, p) and d.name == "cloud"
    grid = np.arange(60.0).reshape(3, 4, 5)
    np.savez(tmp_path / "g.npz", values=grid, rho=-grid, origin=np.ones(3))
    assert np.array_equal(load(tmp_path / "g.npz", array="rho").values, -grid.ravel())
    np.savez(tmp_path / "twice.npz", points=p, values=p[:, 0])
    with zipfile.ZipFile(tmp_path / "twice.npz", "a") as z, pytest.warns(UserWarning, match="Duplicate name"):
        z.writestr("values.npy", _npy_bytes(p[:, 2]))
    with zipfile.ZipFile(tmp_path / "g.npz", "a") as z:
        z.writestr("notes.txt", "a note")
    np.savez(tmp_path / "nm.npz", points=p, values=p[:, 0], name=np.arange(3))
    refused = [("twice.npz", None, "holds two arrays named 'values': keep one"),
               ("g.npz", None, "holds 'notes.txt', which is not a NumPy array (.npy)"),
               ("nm.npz", None, "'name' must be one string, got int64 of shape (3,)"),
               ("alt.npz", "points", "--array 'points' names a member of the layout"),
               ("alt.npz", "name", "--array 'name' names a member of the layout")]
    for name, array, message in refused:
        with pytest.raises(trivsel.InputError, match=re.escape(message)) as info:
            load(tmp_path / name, array=array)
        assert "\n" not in str(info.value)


def _npy_bytes(a):
    import io

    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def test_unsupported_suffix_is_refused(tmp_path, capsys):
    (tmp_path / "brain.mnc").write_bytes(b"\0" * 400)
    assert main(["reduce", str(tmp_path / "brain.mnc"), "--fractions", "0.3", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "unsupported file type '.mnc'" in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_no_interior_point_gives_nan_not_zero():
    from trivsel.norms import error_norms

    e = error_norms(np.array([0.1, -0.2]), np.array([False, False]))
    assert np.isnan(e["E_rms_interior"]) and np.isnan(e["E_inf_interior"]) and e["E_inf"] == 0.2


def test_hull_boundary_mask_is_chunked_and_exact():
    from trivsel.triangulation import hull_boundary_mask

    g = trivsel.sample_grid(1, 5)
    mask = hull_boundary_mask(g.points)
    np.testing.assert_array_equal(mask, ~g.interior_mask())


def test_requests_larger_than_the_memory_are_refused_before_allocating(tmp_path, capsys, monkeypatch):
    assert main(["reduce", "--function", "4", "--n", "2000", "--fractions", "0.1", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "a grid of n = 2000 (2001^3 points) needs about" in err and err.count("\n") == 1
    import trivsel.resources as res

    data = trivsel.sample_grid(1, 16)
    monkeypatch.setattr(res, "available_bytes", lambda: 10**6)
    with pytest.raises(trivsel.InputError, match=r"reducing 4913 points needs about 0.00229 GiB, more than"):
        trivsel.reduce(data, fractions=[0.1])


# NIfTI and NRRD: the grid keeps every voxel where the file puts it; original_index is the voxel's
# Fortran-order index into the file's 3-D voxel array (within the chosen volume).

def _check_voxel_round_trip(path, affine, scaled, tmp_path, volume=None):
    """Every point (loaded, and in the output mesh) sits at ``affine @ [i, j, k, 1]`` of the voxel
    its original_index names and has that voxel's value."""

    def check(ids, points, values):
        ijk = np.stack(np.unravel_index(ids, scaled.shape, order="F"), axis=1)
        world = (np.c_[ijk, np.ones(len(ids))] @ np.asarray(affine, float).T)[:, :3]
        np.testing.assert_allclose(points, world, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(values, scaled.ravel(order="F")[ids])

    data = load(path, volume=volume)
    assert data.is_grid and np.all(data.spacing > 0)
    assert sorted(data.file_index) == list(range(scaled.size))
    check(data.file_index, data.points, data.values)
    out = tmp_path / f"out-{path.name}"
    args = ["reduce", str(path), "--fractions", "0.5", "--out", str(out)]
    assert main(args + ([] if volume is None else ["--volume", str(volume)])) == 0
    m = pv.read(out / "mesh_0.5.vtu")
    check(m.point_data["original_index"], m.points, m.point_data["value"])
    return data


def _save_nifti(path, data, affine, slope_inter=None):
    import nibabel as nib

    img = nib.Nifti1Image(data, affine)
    if slope_inter is not None:
        img.header.set_slope_inter(*slope_inter)
    nib.save(img, path)
    back = nib.load(path)
    return back.affine, back.get_fdata(dtype=np.float64)


def test_nifti_scaling_flipped_axis_and_origin(tmp_path):
    import nibabel as nib

    raw = np.random.default_rng(4).integers(-300, 300, (5, 6, 7)).astype(np.int16)
    affine = np.array([[-1.5, 0, 0, 10.0], [0, 2.0, 0, -4.0], [0, 0, 0.5, 3.0], [0, 0, 0, 1]])
    path = tmp_path / "head.nii.gz"
    back, scaled = _save_nifti(path, raw, affine, (0.5, 10.0))
    assert nib.load(path).get_data_dtype() == np.int16 and np.array_equal(back, affine)
    np.testing.assert_array_equal(scaled, raw * 0.5 + 10.0)  # scl_slope and scl_inter applied
    data = _check_voxel_round_trip(path, affine, scaled, tmp_path)
    assert data.name == "head" and data.shape == (5, 6, 7)
    np.testing.assert_array_equal(data.spacing, [1.5, 2.0, 0.5])
    np.testing.assert_array_equal(data.origin, [10.0 - 1.5 * 4, -4.0, 3.0])  # x runs backwards


def test_nifti_permuted_axes(tmp_path):
    raw = np.random.default_rng(5).random((5, 6, 7)).astype(np.float32)
    # voxel axis 0 runs along y, 1 along z (backwards), 2 along x
    affine = np.array([[0, 0, 0.75, -2.0], [1.5, 0, 0, 1.0], [0, -2.0, 0, 7.0], [0, 0, 0, 1]])
    path = tmp_path / "perm.nii"
    back, scaled = _save_nifti(path, raw, affine)
    data = _check_voxel_round_trip(path, back, scaled, tmp_path)
    assert data.shape == (7, 5, 6)
    np.testing.assert_array_equal(data.spacing, [0.75, 1.5, 2.0])
    np.testing.assert_array_equal(data.origin, [-2.0, 1.0, 7.0 - 2.0 * 5])


def test_nifti_without_orientation_uses_voxel_sizes(tmp_path):
    import nibabel as nib

    img = nib.Nifti1Image(np.random.default_rng(6).random((5, 6, 7)), np.diag([0.5, 1.0, 2.0, 1.0]))
    img.set_sform(None, code=0)
    img.set_qform(None, code=0)
    nib.save(img, tmp_path / "plain.nii")
    scaled = nib.load(tmp_path / "plain.nii").get_fdata()
    data = _check_voxel_round_trip(tmp_path / "plain.nii", np.diag([0.5, 1.0, 2.0, 1.0]), scaled, tmp_path)
    np.testing.assert_array_equal(data.origin, [0, 0, 0])


def test_nifti_4d_needs_a_volume(tmp_path):
    path = tmp_path / "series.nii.gz"
    affine = np.array([[2.0, 0, 0, 1], [0, 2.0, 0, 2], [0, 0, -3.0, 3], [0, 0, 0, 1]])
    back, scaled = _save_nifti(path, np.random.default_rng(7).random((5, 6, 7, 3)), affine)
    with pytest.raises(trivsel.InputError, match=r"4-D image of 3 volumes .*choose one with --volume K"):
        load(path)
    for bad in (3, -1):
        with pytest.raises(trivsel.InputError, match=rf"^volume {bad} is out of range: .* holds 3 volume"):
            load(path, volume=bad)
    data = _check_voxel_round_trip(path, back, scaled[..., 1], tmp_path, volume=1)
    assert data.meta["volume"] == 1
    with pytest.raises(trivsel.InputError, match="--volume 0 applies to 4-D NIfTI and NRRD images"):
        load(tmp_path / "out-series.nii.gz" / "mesh_0.5.vtu", volume=0)


def test_nifti_refusals_are_one_line(tmp_path):
    import nibabel as nib

    rng = np.random.default_rng(8)
    angle = np.deg2rad(30)
    oblique = np.array([[np.cos(angle), -np.sin(angle), 0, 0], [np.sin(angle), np.cos(angle), 0, 0],
                        [0, 0, 1, 0], [0, 0, 0, 1]])
    nib.save(nib.Nifti1Image(rng.random((5, 6, 7)), oblique), tmp_path / "oblique.nii")
    nib.save(nib.Nifti1Image(rng.random((5, 6)), np.eye(4)), tmp_path / "flat.nii")
    nib.save(nib.Nifti1Image(rng.random((5, 6, 7)).astype(np.complex64), np.eye(4)), tmp_path / "complex.nii")
    nan = rng.random((5, 6, 7))
    nan[1, 2, 3] = np.nan
    nib.save(nib.Nifti1Image(nan, np.eye(4)), tmp_path / "nan.nii")
    whole = nib.Nifti1Image(rng.random((5, 6, 7)), np.eye(4)).to_bytes()
    (tmp_path / "truncated.nii").write_bytes(whole[: len(whole) // 2])
    (tmp_path / "junk.nii.gz").write_bytes(b"not a NIfTI file")
    cases = {"oblique.nii": "'.*oblique.nii' is oblique", "flat.nii": r"2-D image of shape \(5, 6\)",
             "complex.nii": "voxels of type complex64", "nan.nii": r"non-finite value nan at voxel \(1, 2, 3\)",
             "truncated.nii": "cannot read the voxels of", "junk.nii.gz": "cannot read .* as NIfTI"}
    for name, message in cases.items():
        with pytest.raises(trivsel.InputError, match=message) as info:
            load(tmp_path / name)
        assert "\n" not in str(info.value) and name in str(info.value)


@pytest.mark.slow
def test_nifti_on_the_command_line(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "vol.nii.gz"
    _save_nifti(path, np.random.default_rng(9).random((5, 6, 7)), np.diag([1.0, 2.0, -1.0, 1.0]))
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "trivsel", "reduce", str(path), "--fractions", "0.5", "--out", str(out)],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert pv.read(out / "mesh_0.5.vtu").n_points == 105
    series = tmp_path / "series.nii"
    _save_nifti(series, np.random.default_rng(9).random((5, 6, 7, 2)), np.eye(4))
    p = subprocess.run([sys.executable, "-m", "trivsel", "reduce", str(series), "--volume", "2", "--fractions", "0.5",
                        "--out", str(tmp_path / "o2")], capture_output=True, text=True)
    assert p.returncode == 2 and p.stderr.count("\n") == 1, p.stderr
    assert p.stderr.startswith("trivsel: error: volume 2 is out of range") and "holds 2 volume(s)" in p.stderr
    assert not (tmp_path / "o2").exists()


def test_nrrd_directions_flips_and_volume(tmp_path):
    import nrrd

    samples = np.random.default_rng(10).integers(0, 1000, (3, 5, 6, 7)).astype(np.uint16)
    # a list axis first (3 volumes), then voxel axes along z (backwards), x and y
    dirs = np.array([[np.nan] * 3, [0, 0, -2.0], [0.5, 0, 0], [0, 1.25, 0]])
    origin = np.array([1.0, 2.0, 3.0])
    path = tmp_path / "d.nrrd"
    nrrd.write(str(path), samples, {"space": "left-posterior-superior", "space directions": dirs,
                                    "space origin": origin, "kinds": ["list", "domain", "domain", "domain"]})
    with pytest.raises(trivsel.InputError, match=r"4-D image of 3 volumes \(shape \(3, 5, 6, 7\)\)"):
        load(path)
    affine = np.eye(4)
    affine[:3, :3], affine[:3, 3] = dirs[1:].T, origin
    data = _check_voxel_round_trip(path, affine, samples[2].astype(float), tmp_path, volume=2)
    np.testing.assert_array_equal(data.spacing, [0.5, 1.25, 2.0])
    np.testing.assert_array_equal(data.origin, [1.0, 2.0, 3.0 - 2.0 * 4])


def test_nrrd_detached_header_and_spacings(tmp_path):
    import nrrd

    samples = np.random.default_rng(11).random((5, 6, 7)).astype(np.float32)
    path = tmp_path / "s.nhdr"
    nrrd.write(str(path), samples, {"spacings": [0.5, 1.0, -2.0]}, detached_header=True)
    data = _check_voxel_round_trip(path, np.diag([0.5, 1.0, -2.0, 1.0]), samples.astype(float), tmp_path)
    assert data.name == "s"
    np.testing.assert_array_equal(data.origin, [0, 0, -12.0])


def test_nrrd_refusals_are_one_line(tmp_path):
    import nrrd

    rng = np.random.default_rng(12)
    nrrd.write(str(tmp_path / "oblique.nrrd"), rng.random((5, 6, 7)),
               {"space": "left-posterior-superior", "space directions": np.array([[1, 0.2, 0], [0, 1, 0], [0, 0, 1.0]])})
    nrrd.write(str(tmp_path / "flat.nrrd"), rng.random((5, 6)))
    nrrd.write(str(tmp_path / "lost.nhdr"), rng.random((5, 6, 7)), detached_header=True)
    (tmp_path / "lost.raw.gz").unlink()
    nrrd.write(str(tmp_path / "whole.nrrd"), rng.random((5, 6, 7)), {"encoding": "raw"})
    whole = (tmp_path / "whole.nrrd").read_bytes()
    (tmp_path / "truncated.nrrd").write_bytes(whole[:-100])
    cases = {"oblique.nrrd": "is oblique", "flat.nrrd": "2-D image of shape", "lost.nhdr": "cannot read .* as NRRD",
             "truncated.nrrd": "cannot read .* as NRRD"}
    for name, message in cases.items():
        with pytest.raises(trivsel.InputError, match=message) as info:
            load(tmp_path / name)
        assert "\n" not in str(info.value) and name in str(info.value)


def _vtk_files(tmp_path):
    """One small file of each VTK format trivsel reads, written by pyvista, with a value
    array ``f`` (and a second array, so that ``--array`` matters)."""
    rng = np.random.default_rng(5)
    img = _image(True)
    img.point_data["f"] = rng.random(img.n_points)
    rect = pv.RectilinearGrid(np.array([0.0, 1.0, 3.0]), np.array([0.0, 2.0, 5.0, 6.0]), np.array([1.0, 2.5]))
    structured = _image(False).cast_to_structured_grid()
    cloud = pv.PolyData(rng.random((40, 3)))
    files = {"v.vti": img, "v.vtk": img, "r.vtr": rect, "s.vts": structured,
             "u.vtu": _image(False).cast_to_unstructured_grid(), "p.vtp": cloud}
    for name, mesh in files.items():
        mesh.point_data["f"] = rng.random(mesh.n_points)
        mesh.point_data["g"] = np.arange(mesh.n_points)
        mesh.save(tmp_path / name)
    return files


def test_every_vtk_format_reads_as_pyvista_reads_it(tmp_path):
    """VTK files are read with VTK's own readers (no pyvista): the points, the values and, for
    image data, the grid's geometry are those pyvista reads from the same file."""
    for name, mesh in _vtk_files(tmp_path).items():
        data = load(tmp_path / name, "f")
        back = pv.read(tmp_path / name)
        if isinstance(back, pv.ImageData):
            assert data.is_grid and data.shape == tuple(back.dimensions), name
            np.testing.assert_array_equal(data.points, np.asarray(back.points)[data.file_index])
            np.testing.assert_array_equal(data.values, np.asarray(back.point_data["f"])[data.file_index])
        else:
            assert not data.is_grid, name
            np.testing.assert_array_equal(data.points, np.asarray(back.points, float))
            np.testing.assert_array_equal(data.values, np.asarray(back.point_data["f"]))


@pytest.mark.parametrize("name, content, message", [
    ("cut.vti", None, "no element found"),
    ("text.vti", b"not xml at all", "syntax error"),
    ("text.vtk", b"hello", "Unrecognized file type"),
    ("half.vtu", b"<VTKFile", "unclosed token"),
])
def test_a_damaged_vtk_file_is_one_line_and_nothing_else(tmp_path, capfd, name, content, message):
    """A VTK file that VTK cannot read: exit 2 and one line naming the file and VTK's first
    error; none of VTK's own log on the terminal; no output folder."""
    if content is None:  # the first half of a good file
        _vtk_files(tmp_path)
        content = (tmp_path / "v.vti").read_bytes()
        content = content[: len(content) // 2]
    (tmp_path / name).write_bytes(content)
    out = tmp_path / "out"
    assert main(["reduce", str(tmp_path / name), "--fractions", "0.5", "--out", str(out)]) == 2
    captured = capfd.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and name in lines[0] and message in lines[0], captured.err
    assert "0x" not in lines[0] and not out.exists()
