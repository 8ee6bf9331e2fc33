"""In-memory data and results: ``trivsel.reduce`` takes numpy arrays, pyvista datasets and nibabel
images as the file readers would read them, a result converts to the pyvista mesh that
``trivsel reduce`` writes, ``.npy`` and Zarr stores load as ``trivsel blocks`` reads them, and
``errors.csv`` says what its data columns are."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
import pyvista as pv

import trivsel
from trivsel.cli import main
from trivsel.io import from_object, load


def _same_data(a, b):
    """Two PointData with the same points, values, grid and input point ids, bit for bit."""
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.values, b.values)
    assert a.is_grid == b.is_grid and a.shape == b.shape
    if a.is_grid:
        np.testing.assert_array_equal(a.ijk, b.ijk)
        np.testing.assert_array_equal(a.origin, b.origin)
        np.testing.assert_array_equal(a.spacing, b.spacing)
    np.testing.assert_array_equal(a.file_ids(np.arange(a.n_points)), b.file_ids(np.arange(b.n_points)))


def _volume(shape=(7, 6, 5), seed=0):
    g = np.indices(shape) / 3.0
    rng = np.random.default_rng(seed)
    return np.sin(g[0]) * np.cos(g[1] - g[2]) + 0.05 * rng.random(shape)


# --- numpy arrays

def test_a_numpy_array_is_a_grid_at_origin_0_spacing_1():
    vol = _volume()
    data = from_object(vol)
    assert data.is_grid and data.shape == vol.shape
    np.testing.assert_array_equal(data.origin, 0.0)
    np.testing.assert_array_equal(data.spacing, 1.0)
    _same_data(data, trivsel.grid_from_array(vol))
    a = trivsel.reduce(vol, fractions=[0.3])
    b = trivsel.reduce(trivsel.grid_from_array(vol, origin=(0, 0, 0), spacing=(1, 1, 1)), fractions=[0.3])
    np.testing.assert_array_equal(a.selected, b.selected)
    assert a.snapshots[0].errors == b.snapshots[0].errors


# --- pyvista datasets

def _image(extent_offset=True):
    g = pv.ImageData(dimensions=(6, 5, 4), spacing=(0.5, 2.0, 3.0), origin=(10.0, -1.0, 2.0))
    if extent_offset:
        g.extent = (3, 8, 2, 6, 1, 4)  # the first point is at origin + (3, 2, 1) * spacing
    x, y, z = np.asarray(g.points).T
    g.point_data["density"] = np.sin(x) + y * z / 10
    g.point_data["label"] = (np.arange(g.n_points) % 3).astype(np.int32)
    g.set_active_scalars("density")
    return g


def test_a_pyvista_image_is_the_grid_its_vti_file_gives(tmp_path):
    g = _image()
    g.save(tmp_path / "v.vti")
    data = from_object(g)
    assert data.is_grid and data.shape == (6, 5, 4)
    _same_data(data, load(tmp_path / "v.vti", "density"))
    np.testing.assert_array_equal(data.origin, [11.5, 3.0, 5.0])
    # array= picks another array; the active scalars are the default
    _same_data(from_object(g, array="label"), load(tmp_path / "v.vti", "label"))
    g.set_active_scalars("label")
    np.testing.assert_array_equal(from_object(g).values, g.point_data["label"][data.file_index])


def test_a_pyvista_image_without_active_scalars_needs_an_array():
    g = _image()
    g.GetPointData().SetActiveScalars(None)
    with pytest.raises(trivsel.InputError, match=r"^pyvista.ImageData has several point-data arrays "
                                                 r"\(density, label\); choose one with array=$"):
        trivsel.reduce(g, fractions=[0.5])
    with pytest.raises(trivsel.InputError, match=r"^array 'nope' not found in pyvista.ImageData; "
                                                 r"available: density, label$"):
        trivsel.reduce(g, fractions=[0.5], array="nope")


def test_a_rotated_pyvista_image_is_refused_naming_its_type():
    g = _image()
    g.direction_matrix = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    with pytest.raises(trivsel.InputError, match=r"^image 'pyvista.ImageData' has a rotated direction matrix"):
        from_object(g)


@pytest.mark.parametrize("kind", ["PolyData", "UnstructuredGrid"])
def test_pyvista_points_are_scattered_data_as_their_file_gives(tmp_path, kind):
    rng = np.random.default_rng(3)
    pts = rng.random((80, 3)) * [1, 2, 3] + [5, 0, -1]
    cloud = pv.PolyData(pts)
    cloud.point_data["value"] = np.cos(pts @ [1.0, 0.5, 0.2])
    ds = cloud if kind == "PolyData" else cloud.cast_to_unstructured_grid()
    path = tmp_path / ("p.vtp" if kind == "PolyData" else "p.vtu")
    ds.save(path)
    data = from_object(ds)
    assert not data.is_grid and data.name == kind
    _same_data(data, load(path))
    r = trivsel.reduce(ds, fractions=[0.5])
    assert r.snapshots[0].n_selected == 40


# --- nibabel images

def test_a_nibabel_image_is_read_as_its_nifti_file(tmp_path):
    import nibabel as nib

    raw = np.random.default_rng(4).integers(-300, 300, (5, 6, 4)).astype(np.int16)
    affine = np.array([[-1.5, 0, 0, 10.0], [0, 2.0, 0, -4.0], [0, 0, 0.5, 3.0], [0, 0, 0, 1]])
    img = nib.Nifti1Image(raw, affine)
    img.header.set_slope_inter(0.5, 10.0)
    path = tmp_path / "head.nii.gz"
    nib.save(img, path)
    loaded = nib.load(path)
    data = from_object(loaded)
    _same_data(data, load(path))
    assert data.name == "head"
    np.testing.assert_array_equal(np.sort(data.values), np.sort(raw.ravel() * 0.5 + 10.0))  # scaled
    np.testing.assert_array_equal(data.spacing, [1.5, 2.0, 0.5])  # x flipped to run forwards
    # an image made in memory: its array, placed by its affine
    mem = from_object(nib.Nifti1Image(raw.astype(np.float64), affine))
    assert mem.name == "Nifti1Image"
    np.testing.assert_array_equal(mem.points, data.points)
    np.testing.assert_array_equal(mem.values, raw.ravel(order="F")[mem.file_index])


def test_a_4d_nibabel_image_takes_a_volume(tmp_path):
    import nibabel as nib

    raw = np.random.default_rng(5).random((4, 5, 3, 2))
    img = nib.Nifti1Image(raw, np.diag([1.0, 2.0, 3.0, 1.0]))
    with pytest.raises(trivsel.InputError, match=r"^'nibabel.Nifti1Image' is a 4-D image of 2 volumes"):
        from_object(img)
    nib.save(img, tmp_path / "t.nii")
    _same_data(from_object(img, volume=1), load(tmp_path / "t.nii", volume=1))
    np.testing.assert_array_equal(from_object(img, volume=1).values, raw[..., 1].ravel())


# --- refusals

@pytest.mark.parametrize("obj, kwargs, message", [
    ([[1.0, 2.0]], {}, r"^cannot take a list as data: give a PointData, a 3-D numpy array, a pyvista dataset"),
    ({"values": 1}, {}, r"^cannot take a dict as data"),
    (pv.MultiBlock(), {}, r"^cannot take a pyvista.MultiBlock as data"),
    (pv.PolyData(), {}, r"^the pyvista.PolyData has no points$"),
    (np.zeros((4, 4)), {}, r"^grid values must be a 3-D array, got shape \(4, 4\)$"),
    (np.zeros((3, 3, 3), bool), {}, r"^values must be real numbers, got an array of dtype bool$"),
    (np.zeros((3, 3, 3)), {"array": "f"}, r"^array='f' applies to files, pyvista datasets and nibabel images, "
                                          r"not to a numpy.ndarray$"),
    (np.zeros((3, 3, 3)), {"volume": 0}, r"^volume=0 applies to files, pyvista datasets and nibabel images"),
    (4, {"array": "f"}, r"^array= applies to input data, not to a Table-1 function$"),
])
def test_bad_objects_are_one_line_naming_the_type(obj, kwargs, message):
    with pytest.raises(trivsel.InputError, match=message) as exc:
        trivsel.reduce(obj, fractions=[0.5], **kwargs)
    assert "\n" not in str(exc.value)


def test_a_non_nifti_nibabel_image_is_refused_naming_its_type():
    import nibabel as nib

    img = nib.MGHImage(np.zeros((3, 3, 3), np.float32), np.eye(4))
    with pytest.raises(trivsel.InputError, match=r"^'nibabel.MGHImage' is not a NIfTI image"):
        trivsel.reduce(img, fractions=[0.5])


def test_taking_a_numpy_array_imports_neither_pyvista_nor_nibabel():
    code = ("import sys, numpy as np, trivsel.io as io; io.from_object(np.zeros((3, 3, 3))); "
            "print([m for m in ('pyvista', 'nibabel', 'vtkmodules') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


# --- results as pyvista meshes

def _same_mesh(a, b):
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.cells, b.cells)
    np.testing.assert_array_equal(a.celltypes, b.celltypes)
    assert list(a.point_data.keys()) == list(b.point_data.keys())
    for name in a.point_data.keys():
        assert a.point_data[name].dtype == b.point_data[name].dtype, name
        np.testing.assert_array_equal(a.point_data[name], b.point_data[name])
    assert list(a.field_data.keys()) == list(b.field_data.keys())
    for name in a.field_data.keys():
        np.testing.assert_array_equal(a.field_data[name], b.field_data[name])
    assert a.active_scalars_name == b.active_scalars_name


@pytest.mark.parametrize("method", ["paper", "greedy"])
def test_to_pyvista_is_the_mesh_file_reduce_writes(tmp_path, method):
    g = _image()
    r = trivsel.reduce(g, fractions=[0.5, 0.3], method=method, values=["data", "fit"])
    trivsel.write_outputs(r, tmp_path / "out")
    for s in r.snapshots:
        mesh = r.to_pyvista(s.fraction)
        assert isinstance(mesh, pv.UnstructuredGrid) and mesh.n_points == s.n_selected
        _same_mesh(mesh, pv.read(tmp_path / "out" / f"mesh_{s.fraction:g}.vtu"))
        assert "fitted_value" in mesh.point_data and ("curvature" in mesh.point_data) == (method == "paper")
        # original_index is the pyvista image's own point id, value its value there
        ids = mesh.point_data["original_index"]
        np.testing.assert_array_equal(mesh.point_data["value"], g.point_data["density"][ids])
        np.testing.assert_allclose(mesh.points, g.points[ids], rtol=0, atol=1e-12)
    assert r.to_pyvista().n_points == r.snapshots[-1].n_selected
    assert "fitted_value" not in trivsel.reduce(g, fractions=[0.5]).to_pyvista(0.5).point_data


# --- .npy and Zarr stores, as trivsel blocks reads them

def test_npy_loads_as_its_array_and_reduces_on_the_command_line(tmp_path):
    vol = _volume()
    np.save(tmp_path / "v.npy", vol)
    data = load(tmp_path / "v.npy")
    _same_data(data, trivsel.grid_from_array(vol))
    assert data.name == "v" and data.file_index is None
    a, b = trivsel.reduce(tmp_path / "v.npy", fractions=[0.3]), trivsel.reduce(vol, fractions=[0.3])
    np.testing.assert_array_equal(a.selected, b.selected)
    assert a.data.name == "v" and a.snapshots[0].errors == b.snapshots[0].errors
    assert main(["reduce", str(tmp_path / "v.npy"), "--fractions", "0.3", "--out", str(tmp_path / "a")]) == 0
    np.savez(tmp_path / "v.npz", values=vol)
    assert main(["reduce", str(tmp_path / "v.npz"), "--fractions", "0.3", "--out", str(tmp_path / "b")]) == 0
    a, b = (pd.read_csv(tmp_path / d / "errors.csv") for d in "ab")
    assert a.equals(b)


def test_npy_integers_are_exact_or_refused(tmp_path):
    vol = (np.arange(60, dtype=np.int64).reshape(3, 4, 5) - 30) * 2**40
    np.save(tmp_path / "i.npy", vol)
    data = load(tmp_path / "i.npy")
    assert np.array_equal(data.values.astype(np.int64), vol.ravel())
    vol[1, 2, 3] = 2**53 + 1
    np.save(tmp_path / "big.npy", vol)
    with pytest.raises(trivsel.InputError, match=r"^value 9007199254740993 at grid index \(1, 2, 3\) of "
                                                 r".*big.npy' is beyond 2\^53"):
        load(tmp_path / "big.npy")
    with pytest.raises(trivsel.InputError, match=r"^--volume 0 applies to 4-D NIfTI and NRRD images"):
        load(tmp_path / "i.npy", volume=0)


def test_zarr_from_convert_loads_as_its_source(tmp_path):
    from trivsel.io.regions import convert

    g = _image()
    g.point_data.remove("label")
    g.save(tmp_path / "v.vti")
    convert(tmp_path / "v.vti", tmp_path / "v.zarr", chunks=3)
    data = load(tmp_path / "v.zarr")
    _same_data(data, load(tmp_path / "v.vti"))  # geometry attributes and the .vti's point ids kept
    assert data.name == "v" and data.file_index is not None
    out = tmp_path / "out"
    assert main(["reduce", str(tmp_path / "v.zarr"), "--fractions", "0.5", "--out", str(out)]) == 0
    m = pv.read(out / "mesh_0.5.vtu")
    ids = m.point_data["original_index"]
    np.testing.assert_array_equal(m.point_data["value"], g.point_data["density"][ids])
    np.testing.assert_allclose(m.points, g.points[ids], rtol=0, atol=1e-12)


def test_an_output_inside_a_zarr_input_is_refused(tmp_path, capsys):
    np.save(tmp_path / "v.npy", _volume())
    from trivsel.io.regions import convert

    convert(tmp_path / "v.npy", tmp_path / "v.zarr")
    before = sorted(p.name for p in (tmp_path / "v.zarr").rglob("*"))
    assert main(["reduce", str(tmp_path / "v.zarr"), "--fractions", "0.5", "--out",
                 str(tmp_path / "v.zarr" / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("trivsel: error: the output folder ") and "is inside the input" in err
    assert err.count("\n") == 1
    assert sorted(p.name for p in (tmp_path / "v.zarr").rglob("*")) == before


def test_a_zarr_store_with_several_arrays_needs_one(tmp_path):
    import zarr

    root = zarr.open_group(str(tmp_path / "g.zarr"), mode="w")
    for name in ("a", "b"):
        arr = root.create_array(name, shape=(3, 4, 5), dtype="float32")
        arr[:] = np.arange(60, dtype=np.float32).reshape(3, 4, 5) * (2 if name == "b" else 1)
        arr.attrs.update({"origin": [1.0, 2.0, 3.0], "spacing": [0.5, 0.5, 2.0]})
    with pytest.raises(trivsel.InputError, match=r"several point-data arrays \(a, b\); choose one with --array"):
        load(tmp_path / "g.zarr")
    data = load(tmp_path / "g.zarr", "b")
    np.testing.assert_array_equal(data.values, np.arange(60.0) * 2)
    np.testing.assert_array_equal(data.origin, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(data.spacing, [0.5, 0.5, 2.0])


def test_npy_memory_is_checked_before_reading(tmp_path, monkeypatch):
    import trivsel.io.regions as regions
    import trivsel.resources as res

    np.save(tmp_path / "v.npy", _volume())
    monkeypatch.setattr(res, "available_bytes", lambda: 1000)

    def never(*args):
        raise AssertionError("the values were read before the memory check")

    monkeypatch.setattr(regions.Volume, "read", never)
    with pytest.raises(trivsel.InputError, match=r"\(7, 6, 5\) points\) needs about .* GiB, more than the"):
        load(tmp_path / "v.npy")


# --- errors.csv columns

def test_errors_columns_say_what_the_data_is(tmp_path):
    f = trivsel.reduce(4, n=4, fractions=[0.5]).error_rows()[0]
    assert (f["function"], f["n"], f["input"], f["n_points"]) == (4, 4, "", 125)
    v = trivsel.reduce(trivsel.grid_from_array(_volume(), name="scan"), fractions=[0.5]).error_rows()[0]
    assert (v["function"], v["n"], v["input"], v["n_points"]) == ("", "", "scan", 210)
    assert list(f) == list(v)


def test_compare_matches_the_rows_of_two_file_runs(tmp_path, capsys):
    """A file's run leaves function and n empty: ``trivsel compare`` matches its rows on
    ``input`` and the empty cells, and still finds a changed value."""
    np.save(tmp_path / "v.npy", _volume())
    for d in ("a", "b"):
        assert main(["reduce", str(tmp_path / "v.npy"), "--fractions", "0.5", "0.3", "--out", str(tmp_path / d)]) == 0
    a, b = (str(tmp_path / d / "errors.csv") for d in "ab")
    assert main(["compare", a, b]) == 0
    table = pd.read_csv(b)
    table.loc[0, "E_rms"] *= 1.01
    table.to_csv(b, index=False)
    capsys.readouterr()
    assert main(["compare", a, b]) == 1
    assert "[input=v, method=decimate, values=data, fraction=0.3] E_rms: new" in capsys.readouterr().out
