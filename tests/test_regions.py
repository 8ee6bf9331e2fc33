"""Volumes read by region (trivsel.io.regions), `trivsel convert` to Zarr, and partitioned output
(trivsel.io.pieces): a region holds exactly the whole volume's points there, bit for bit."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest
import pyvista as pv

import trivsel
from trivsel.cli import main
from trivsel.data import PointData, grid_from_array
from trivsel.io import load
from trivsel.io.regions import RegionData, check_region, convert, open_volume

REGIONS = [((0, 5), (0, 6), (0, 7)), ((1, 4), (2, 6), (3, 7)), ((4, 5), (0, 6), (6, 7)), ((0, 2), (5, 6), (0, 1))]


def _same(a, b):
    """Equal bit for bit (not just ==: -0.0 and 0.0 differ)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _c_index(ijk, shape):
    return (ijk[:, 0] * shape[1] + ijk[:, 1]) * shape[2] + ijk[:, 2]


def _check_regions(vol, whole: PointData, regions):
    """Every region's values, points, ijk and input point ids are the whole volume's there."""
    assert vol.shape == whole.shape
    assert _same(vol.origin, np.asarray(whole.origin, float)) and _same(vol.spacing, np.asarray(whole.spacing, float))
    full = whole.values.reshape(whole.shape)
    for r in regions:
        sl = tuple(slice(a, b) for a, b in r)
        assert _same(vol.read(r), full[sl]), r
        points, ijk = vol.points(r)
        sel = _c_index(ijk, whole.shape)
        assert _same(points, whole.points[sel]) and _same(ijk, whole.ijk[sel]), r
        assert np.array_equal(vol.file_ids(ijk), whole.file_ids(sel)), r
        if min(b - a for a, b in r) >= 2:
            d = vol.region_data(r)
            assert isinstance(d, RegionData) and d.shape == tuple(b - a for a, b in r)
            assert _same(d.values, whole.values[sel]) and _same(d.points, whole.points[sel])
            assert _same(d.ijk, whole.ijk[sel]) and np.array_equal(d.file_ids(np.arange(d.n_points)),
                                                                   whole.file_ids(sel))


def _regions_of(shape):
    """Regions of a grid of ``shape``: whole, inner, one-point-thick, single points."""
    n = np.asarray(shape)
    return [tuple((0, int(s)) for s in n), tuple((1, int(s) - 1) for s in n),
            ((int(n[0]) - 1, int(n[0])), (0, int(n[1])), (1, 3)), ((0, 2), (int(n[1]) - 1, int(n[1])), (0, 1))]


# --- sources

@pytest.mark.parametrize("function", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("slab_points", [1 << 18, 1, 300])  # a region whole, a plane, two planes at a time
def test_function_regions_are_sample_grid_bit_for_bit(function, slab_points, monkeypatch):
    """A function grid's regions, evaluated an x-slab at a time, are those of the whole grid."""
    import trivsel.io.regions as regions

    monkeypatch.setattr(regions, "FUNCTION_POINTS", slab_points)
    whole = trivsel.sample_grid(function, 10)
    vol = open_volume(function=function, n=10)
    assert vol.name == str(function) and vol.meta == {"function": function, "n": 10}
    _check_regions(vol, whole, _regions_of(whole.shape) + [((3, 9), (0, 4), (5, 11))])


def test_npy_is_memory_mapped_and_read_by_region(tmp_path):
    rng = np.random.default_rng(1)
    for name, arr in {"c.npy": rng.integers(-999, 999, (5, 6, 7)).astype(np.int16),
                      "f.npy": np.asfortranarray(rng.random((5, 6, 7)).astype(np.float32))}.items():
        np.save(tmp_path / name, arr)
        vol = open_volume(tmp_path / name)
        assert vol.by_region and vol.dtype == arr.dtype and vol.name == name[0]
        assert isinstance(vol._block((slice(0, 1),) * 3).base, np.memmap)
        _check_regions(vol, grid_from_array(arr), REGIONS)


def _zarr_array(path, values, zarr_format, attributes=None, name=None):
    import zarr

    if name is None:
        arr = zarr.create_array(store=str(path), shape=values.shape, chunks=(2, 3, 4), dtype=values.dtype,
                                zarr_format=zarr_format, attributes=attributes or {})
    else:
        group = zarr.open_group(str(path), mode="a", zarr_format=zarr_format)
        arr = group.create_array(name, shape=values.shape, chunks=(2, 3, 4), dtype=values.dtype,
                                 attributes=attributes or {})
    arr[...] = values
    return arr


@pytest.mark.parametrize("zarr_format", [3, 2])
def test_zarr_region_reads_touch_only_their_chunks(tmp_path, zarr_format):
    values = np.random.default_rng(2).random((5, 6, 7))
    geometry = {"origin": [1.5, -2.0, 0.25], "spacing": [0.5, 2.0, 0.1]}
    _zarr_array(tmp_path / "v.zarr", values, zarr_format, geometry)
    vol = open_volume(tmp_path / "v.zarr")
    assert vol.by_region and vol.name == "v"
    _check_regions(vol, grid_from_array(values, geometry["origin"], geometry["spacing"], name="v"), REGIONS)
    # a region read loads only its chunks: a damaged chunk elsewhere goes unnoticed
    chunk = tmp_path / "v.zarr" / ("c/2/1/1" if zarr_format == 3 else "2.1.1")  # points [4:5, 3:6, 4:7]
    chunk.write_bytes(b"damaged")
    assert vol.read(((0, 4), (0, 6), (0, 7))).shape == (4, 6, 7)
    with pytest.raises(trivsel.InputError, match=r"^cannot read region \(\(0, 5\), \(0, 6\), \(0, 7\)\) of"):
        vol.read(((0, 5), (0, 6), (0, 7)))


@pytest.mark.parametrize("shape, base, strides", [((3, 4, 5), 0, [20, 5, 1]), ((4, 4, 5), 3, [-1, 4, 16]),
                                                  ((2, 2, 2), 0, [3, 4, 5])])
def test_zarr_file_index_that_numbers_each_point_once_is_kept(tmp_path, shape, base, strides):
    """A ``file_index`` that gives every grid point its own non-negative index is read as
    written: C order, a flipped axis (a negative stride, as convert writes for a flipped NIfTI
    axis) and strides that do not nest but still never collide on the grid."""
    values = np.arange(float(np.prod(shape))).reshape(shape)
    _zarr_array(tmp_path / "s.zarr", values, 3, {"file_index": {"base": base, "strides": strides}})
    d = load(tmp_path / "s.zarr")
    expected = base + d.ijk @ np.asarray(strides)
    assert expected.min() >= 0 and len(set(expected.tolist())) == d.n_points
    assert np.array_equal(d.file_ids(np.arange(d.n_points)), expected)


def test_zarr_groups_need_the_array_name(tmp_path):
    rng = np.random.default_rng(3)
    _zarr_array(tmp_path / "g.zarr", rng.random((4, 4, 4)), 3, name="density")
    assert open_volume(tmp_path / "g.zarr").shape == (4, 4, 4)  # the only array
    _zarr_array(tmp_path / "g.zarr", rng.integers(0, 9, (3, 4, 5)).astype(np.uint8), 3, name="labels")
    with pytest.raises(trivsel.InputError, match="several point-data arrays .*density, labels.*--array"):
        open_volume(tmp_path / "g.zarr")
    assert open_volume(tmp_path / "g.zarr", array="labels").shape == (3, 4, 5)
    with pytest.raises(trivsel.InputError, match=r"^array 'missing' not found in .*available: density, labels"):
        open_volume(tmp_path / "g.zarr", array="missing")
    _zarr_array(tmp_path / "one.zarr", rng.random((4, 4, 4)), 3, {"spacing": [1, 0, 1]})
    with pytest.raises(trivsel.InputError, match="attribute 'spacing' must be 3 positive finite numbers"):
        open_volume(tmp_path / "one.zarr")
    with pytest.raises(trivsel.InputError, match="array 'x' not found .*one array, not a group"):
        open_volume(tmp_path / "one.zarr", array="x")


def _save_nifti(path, data, affine, slope_inter=None):
    import nibabel as nib

    img = nib.Nifti1Image(data, affine)
    if slope_inter is not None:
        img.header.set_slope_inter(*slope_inter)
    nib.save(img, path)


# voxel axis 0 runs along y (backwards), 1 along z, 2 along x (backwards)
PERMUTED = np.array([[0, 0, -0.75, 4.0], [-1.5, 0, 0, 1.0], [0, 2.0, 0, 7.0], [0, 0, 0, 1]])


@pytest.mark.parametrize("name", ["head.nii", "head.nii.gz"])
def test_nifti_regions_with_scaling_flips_and_permutation(tmp_path, name):
    raw = np.random.default_rng(4).integers(-300, 300, (6, 7, 5)).astype(np.int16)
    _save_nifti(tmp_path / name, raw, PERMUTED, (0.1, 10.3))  # a slope float32 cannot hold exactly
    whole = load(tmp_path / name)
    vol = open_volume(tmp_path / name)
    assert vol.by_region and vol.dtype == np.int16 and vol.shape == whole.shape == (5, 6, 7)
    _check_regions(vol, whole, _regions_of(vol.shape) + REGIONS)


def test_nifti_4d_volume(tmp_path):
    data = np.random.default_rng(5).random((5, 6, 7, 3)).astype(np.float32)
    _save_nifti(tmp_path / "series.nii", data, np.diag([2.0, -1.0, 3.0, 1.0]))
    with pytest.raises(trivsel.InputError, match=r"4-D image of 3 volumes .*--volume K"):
        open_volume(tmp_path / "series.nii")
    vol = open_volume(tmp_path / "series.nii", volume=2)
    assert vol.meta == {"volume": 2}
    _check_regions(vol, load(tmp_path / "series.nii", volume=2), REGIONS)


def _nrrd_directions(samples, encoding, **options):
    import nrrd

    # a list axis first (volumes), then voxel axes along z (backwards), x and y
    dirs = np.array([[np.nan] * 3, [0, 0, -2.0], [0.5, 0, 0], [0, 1.25, 0]])
    header = {"space": "left-posterior-superior", "space directions": dirs, "space origin": [1.0, 2.0, 3.0],
              "kinds": ["list", "domain", "domain", "domain"], "encoding": encoding}
    return lambda path: nrrd.write(str(path), samples, {**header, **options.pop("header", {})}, **options)


@pytest.mark.parametrize("name, kwargs", [("d.nrrd", {}), ("big.nrrd", {"header": {"endian": "big"}}),
                                          ("s.nhdr", {"detached_header": True})])
def test_raw_nrrd_is_memory_mapped(tmp_path, name, kwargs):
    samples = np.random.default_rng(6).integers(0, 60000, (3, 7, 5, 6)).astype(np.uint16)
    _nrrd_directions(samples, "raw", **kwargs)(tmp_path / name)
    vol = open_volume(tmp_path / name, volume=1)
    assert vol.by_region and vol.dtype == np.uint16 and vol.shape == (5, 6, 7)
    _check_regions(vol, load(tmp_path / name, volume=1), _regions_of(vol.shape) + REGIONS)


def test_nrrd_line_and_byte_skips(tmp_path):
    import nrrd

    samples = np.random.default_rng(7).random((5, 6, 7))
    nrrd.write(str(tmp_path / "a.nhdr"), samples, {"encoding": "raw", "spacings": [0.5, -1.0, 2.0]},
               detached_header=True)
    data = (tmp_path / "a.raw").read_bytes()
    (tmp_path / "a.raw").write_bytes(b"skip me\nand me\n" + b"\0" * 5 + data)
    text = (tmp_path / "a.nhdr").read_text().replace("data file:", "line skip: 2\nbyte skip: 5\ndata file:")
    (tmp_path / "a.nhdr").write_text(text)
    _check_regions(open_volume(tmp_path / "a.nhdr"), load(tmp_path / "a.nhdr"), REGIONS)
    (tmp_path / "a.nhdr").write_text(text.replace("byte skip: 5", "byte skip: -1"))
    _check_regions(open_volume(tmp_path / "a.nhdr"), load(tmp_path / "a.nhdr"), REGIONS)
    (tmp_path / "a.raw").write_bytes(data[:-8])
    with pytest.raises(trivsel.InputError, match=r"holds 1672 bytes of data, the header's sizes \(5, 6, 7\)"):
        open_volume(tmp_path / "a.nhdr")


def test_whole_file_sources_are_loaded_once_with_a_warning(tmp_path, caplog):
    samples = np.random.default_rng(8).integers(0, 900, (3, 7, 5, 6)).astype(np.int16)
    _nrrd_directions(samples, "gzip")(tmp_path / "z.nrrd")
    g = pv.ImageData(dimensions=(6, 5, 4), spacing=(0.5, 2.0, 3.0), origin=(10.0, -1.0, 2.0))
    g.point_data["density"] = np.arange(g.n_points, dtype=np.int32) * 3 - 50
    g.save(tmp_path / "v.vti")
    with caplog.at_level(logging.WARNING, logger="trivsel"):
        for name, volume in (("z.nrrd", 2), ("v.vti", None)):
            vol = open_volume(tmp_path / name, volume=volume)
            assert not vol.by_region and name in caplog.text and "trivsel convert" in caplog.text
            _check_regions(vol, load(tmp_path / name, volume=volume), _regions_of(vol.shape))
    assert open_volume(tmp_path / "v.vti").dtype == np.int32
    np.savetxt(tmp_path / "p.csv", np.random.default_rng(9).random((10, 4)), delimiter=",", header="x,y,z,value",
               comments="")
    with pytest.raises(trivsel.InputError, match="holds scattered points, not a grid"):
        open_volume(tmp_path / "p.csv")


def test_refusals_are_one_line(tmp_path):
    vol = open_volume(function=1, n=4)
    bad = {((0, 5), (0, 5), (0, 6)): r"out of bounds along axis z: need 0 <= start < stop <= 5",
           ((2, 2), (0, 5), (0, 5)): "is empty along axis x", ((-1, 2), (0, 5), (0, 5)): "out of bounds along axis x",
           ((0, 5), (0, 5)): "three .start, stop. pairs of integers", ((0, 2.5), (0, 5), (0, 5)): "pairs of integers",
           ((0, True), (0, 5), (0, 5)): "pairs of integers", 5: "pairs of integers"}
    for region, message in bad.items():
        for call in (vol.read, vol.points, vol.region_data):
            with pytest.raises(trivsel.InputError, match=message) as info:
                call(region)
            assert "\n" not in str(info.value)
    with pytest.raises(trivsel.InputError, match=r"has shape \(1, 5, 5\): a grid needs at least 2 points per axis"):
        vol.region_data(((0, 1), (0, 5), (0, 5)))
    np.save(tmp_path / "flat.npy", np.zeros((4, 4)))
    np.save(tmp_path / "complex.npy", np.zeros((3, 3, 3), complex))
    nan = np.zeros((3, 3, 3))
    nan[1, 2, 0] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    np.save(tmp_path / "huge.npy", np.full((3, 3, 3), 2**53 + 1, np.int64))
    (tmp_path / "other.mnc").write_bytes(b"\0" * 10)
    cases = {"flat.npy": r"shape \(4, 4\): need a 3-D grid", "complex.npy": "voxels of type complex128",
             "missing.npy": "does not exist", "other.mnc": "unsupported file type '.mnc'"}
    for name, message in cases.items():
        with pytest.raises(trivsel.InputError, match=message):
            open_volume(tmp_path / name)
    with pytest.raises(trivsel.InputError, match=r"non-finite value nan at grid index \(1, 2, 0\)"):
        open_volume(tmp_path / "nan.npy").read(((1, 3), (1, 3), (0, 2)))
    with pytest.raises(trivsel.InputError, match="beyond 2\\^53"):
        open_volume(tmp_path / "huge.npy").read(((0, 1), (0, 1), (0, 1)))
    for kwargs, message in (({}, "either an input file or a function"),
                            ({"path": "a.npy", "function": 1}, "not both"),
                            ({"function": 1, "array": "a"}, "--array applies to input files"),
                            ({"function": 1, "n": 1}, "n must be an integer >= 2"),
                            ({"path": tmp_path / "flat.npy", "volume": 0}, "--volume 0 applies to 4-D")):
        with pytest.raises(trivsel.InputError, match=message):
            open_volume(**kwargs)
    assert check_region([[0, 1], (0, 2), (np.int64(1), 3)], (2, 2, 3)) == ((0, 1), (0, 2), (1, 3))


@pytest.mark.parametrize("method", ["paper", "decimate"])
def test_region_data_reduces_as_its_own_grid(method):
    """Global ijk change nothing in a reduction: the region reduces as the same grid numbered from 0."""
    vol = open_volume(function=4, n=12)
    r = ((3, 10), (2, 8), (5, 13))
    region = vol.region_data(r)
    local = PointData(points=region.points, values=region.values, ijk=region.ijk - region.offset,
                      shape=region.shape, origin=region.origin + np.asarray(region.offset) * region.spacing,
                      spacing=region.spacing, name=region.name)
    assert np.array_equal(region.interior_mask(), local.interior_mask()) and local.interior_mask().sum() == 5 * 4 * 6
    a, b = (trivsel.reduce(d, fractions=[0.3], method=method) for d in (region, local))
    assert np.array_equal(a.snapshots[0].tets, b.snapshots[0].tets)
    errors = [c for c in a.errors_frame().columns if c.startswith("E_")]
    assert len(errors) == 4 and a.errors_frame()[errors].equals(b.errors_frame()[errors])
    assert isinstance(replace(region, values=region.values * 2), RegionData)  # as reduce's rescaling makes it


# --- convert

def _check_converted(store, whole: PointData, dtype):
    import zarr

    arr = zarr.open_array(str(store), mode="r")
    assert arr.metadata.zarr_format == 3 and arr.dtype == dtype
    vol = open_volume(store)
    assert vol.by_region and vol.name == whole.name
    _check_regions(vol, whole, _regions_of(whole.shape) + [tuple((0, s) for s in whole.shape)])


def test_convert_stores_long_double_values_as_float64_where_they_fit_it(tmp_path):
    """Zarr has no float wider than 64 bits: a long-double volume whose values float64 holds
    exactly is stored as float64, the same values (one that float64 would round is refused: a
    hostile case)."""
    v = np.linspace(-3, 5, 60).astype(np.longdouble).reshape(3, 4, 5)
    np.save(tmp_path / "ld.npy", v)
    store = convert(tmp_path / "ld.npy", tmp_path / "ld.zarr")
    vol = open_volume(store)
    assert vol.dtype == np.float64
    assert np.array_equal(vol.read(((0, 3), (0, 4), (0, 5))), v.astype(np.float64))


def test_convert_round_trips_exactly(tmp_path):
    """NIfTI (flips, permutation, scaling), NRRD, .vti and .npy: every point's coordinates,
    value and original id in the Zarr store are io.load's of the original."""
    import nrrd

    rng = np.random.default_rng(10)
    raw = rng.integers(-300, 300, (6, 7, 5)).astype(np.int16)
    _save_nifti(tmp_path / "scaled.nii.gz", raw, PERMUTED, (0.5, 10.25))
    _save_nifti(tmp_path / "plain.nii.gz", raw, PERMUTED)
    _save_nifti(tmp_path / "doubled.nii", raw, np.diag([-1.0, 2.0, 0.5, 1.0]), (2.0, 0.0))  # integers again
    samples = rng.integers(0, 60000, (3, 7, 5, 6)).astype(np.uint16)
    _nrrd_directions(samples, "raw")(tmp_path / "d.nrrd")
    nrrd.write(str(tmp_path / "s.nhdr"), rng.random((5, 6, 7)).astype(np.float32), {"spacings": [0.5, 1.0, -2.0]},
               detached_header=True)
    g = pv.ImageData(dimensions=(6, 5, 4), spacing=(0.5, 2.0, 3.0), origin=(10.0, -1.0, 2.0))
    g.point_data["density"] = rng.random(g.n_points)
    g.save(tmp_path / "v.vti")
    np.save(tmp_path / "a.npy", raw)
    cases = [("scaled.nii.gz", None, np.float64), ("plain.nii.gz", None, np.int16), ("doubled.nii", None, np.int16),
             ("d.nrrd", 1, np.uint16), ("s.nhdr", None, np.float32), ("v.vti", None, np.float64),
             ("a.npy", None, np.int16)]
    for name, volume, dtype in cases:
        out = tmp_path / "zarr" / f"{name}.zarr"
        args = ["convert", str(tmp_path / name), str(out), "--chunks", "3"] + (["--volume", "1"] if volume else [])
        assert main(args) == 0, name
        whole = grid_from_array(raw, name="a") if name == "a.npy" else load(tmp_path / name, volume=volume)
        _check_converted(out, whole, dtype)
    assert [p.name for p in (tmp_path / "zarr").iterdir() if p.name.startswith(".")] == []


def test_convert_function_grid_and_chunks(tmp_path):
    import zarr

    out = convert(open_volume(function=3, n=8), tmp_path / "f3.zarr", chunks=(4, 9, 2))
    assert zarr.open_array(str(out), mode="r").chunks == (4, 9, 2)
    _check_converted(out, trivsel.sample_grid(3, 8), np.float64)
    assert open_volume(out).meta == {"function": 3, "n": 8}


def test_convert_refuses_existing_output_and_leaves_nothing_on_failure(tmp_path, capsys, monkeypatch):
    np.save(tmp_path / "a.npy", np.random.default_rng(11).random((5, 6, 7)))
    (tmp_path / "out.zarr").mkdir()
    (tmp_path / "out.zarr" / "keep").write_text("mine")
    for out, message in (("out.zarr", "exists: trivsel convert never overwrites"), ("out.npy", "must be named *.zarr")):
        assert main(["convert", str(tmp_path / "a.npy"), str(tmp_path / out)]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1 and err.startswith("trivsel: error: ")
    assert (tmp_path / "out.zarr" / "keep").read_text() == "mine"
    assert main(["convert", str(tmp_path / "a.npy"), str(tmp_path / "c.zarr"), "--chunks", "0"]) == 2
    assert "chunks must be an integer >= 1" in capsys.readouterr().err

    from trivsel.io import regions

    reads = []

    def failing(self, region):  # the third slab fails, after two were written
        reads.append(region)
        if len(reads) == 3:
            raise KeyboardInterrupt
        return original(self, region)

    original = regions.Volume.read
    monkeypatch.setattr(regions.Volume, "read", failing)
    assert main(["convert", str(tmp_path / "a.npy"), str(tmp_path / "new.zarr"), "--chunks", "2"]) == 130
    assert len(reads) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npy", "out.zarr"]  # no new.zarr, no temporary


# --- partitioned output

def _two_pieces(tmp_path):
    """Two blocks of a 5^3 grid that share the plane i = 2, Kuhn-split, as pieces."""
    from trivsel.io.pieces import write_piece
    from trivsel.triangulation import kuhn_tetrahedra

    vol = open_volume(function=2, n=4)
    paths, n_tets = [], 0
    for name, r in (("a", ((0, 3), (0, 5), (0, 5))), ("b", ((2, 5), (0, 5), (0, 5)))):
        d = vol.region_data(r)
        tets = kuhn_tetrahedra(d.shape)
        n_tets += len(tets)
        paths.append(write_piece(tmp_path / "pieces" / f"{name}.vtu", d.points, tets, d.values,
                                 d.file_ids(np.arange(d.n_points))))
    return vol, paths, n_tets


def test_pvtu_and_vtm_open_as_all_pieces(tmp_path):
    from trivsel.io.pieces import write_pvtu, write_vtm

    vol, paths, n_tets = _two_pieces(tmp_path)
    piece = pv.read(paths[0])
    assert set(piece.point_data.keys()) == {"value", "original_index"}
    assert piece.point_data["original_index"].dtype == np.int64 and np.all(piece.celltypes == pv.CellType.TETRA)
    pvtu = write_pvtu(tmp_path / "mesh.pvtu", paths)
    assert 'Source="pieces/a.vtu"' in pvtu.read_text()
    mesh = pv.read(pvtu)
    assert mesh.n_cells == n_tets and mesh.n_points == 2 * 3 * 5 * 5
    assert mesh.point_data["original_index"].dtype == np.int64
    vtm = pv.read(write_vtm(tmp_path / "mesh.vtm", paths))
    assert vtm.n_blocks == 2 and sum(b.n_cells for b in vtm) == n_tets
    with pytest.raises(trivsel.InputError, match="mesh.pvtu' exists; pass overwrite=True"):
        write_pvtu(tmp_path / "mesh.pvtu", paths)
    write_pvtu(tmp_path / "mesh.pvtu", paths[:1], overwrite=True)
    assert pv.read(tmp_path / "mesh.pvtu").n_cells == n_tets // 2
    with pytest.raises(trivsel.InputError, match="piece .*missing.vtu' does not exist"):
        write_vtm(tmp_path / "other.vtm", [tmp_path / "missing.vtu"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesh.pvtu", "mesh.vtm", "pieces"]  # no temporaries


def test_a_damaged_or_foreign_piece_is_one_line(tmp_path):
    """merge_pieces and write_pvtu name the piece VTK cannot read (and VTK's first error), a
    piece without ``value`` or ``original_index``, and a piece with cells other than tetrahedra."""
    from trivsel.io.pieces import merge_pieces, write_pvtu

    vol, paths, n_tets = _two_pieces(tmp_path)
    cut = tmp_path / "cut.vtu"
    cut.write_bytes(paths[0].read_bytes()[:200])
    for call in (lambda: merge_pieces([paths[0], cut], tmp_path / "m.vtu"),
                 lambda: write_pvtu(tmp_path / "m.pvtu", [cut])):
        with pytest.raises(trivsel.InputError, match=r"cannot read piece .*cut.vtu': .*XML") as info:
            call()
        assert "\n" not in str(info.value) and "0x" not in str(info.value)
    grid = pv.read(paths[0])
    grid.point_data.pop("original_index")
    grid.save(tmp_path / "no_ids.vtu")
    with pytest.raises(trivsel.InputError, match="no_ids.vtu' has no point array 'original_index'"):
        merge_pieces([tmp_path / "no_ids.vtu"], tmp_path / "m.vtu")
    hexes = pv.ImageData(dimensions=(3, 3, 3)).cast_to_unstructured_grid()
    hexes.point_data["value"] = np.zeros(27)
    hexes.point_data["original_index"] = np.arange(27)
    hexes.save(tmp_path / "hexes.vtu")
    with pytest.raises(trivsel.InputError, match="hexes.vtu' has cells other than tetrahedra"):
        merge_pieces([tmp_path / "hexes.vtu"], tmp_path / "m.vtu")
    assert not (tmp_path / "m.vtu").exists() and not (tmp_path / "m.pvtu").exists()


def test_merge_dedups_shared_points_and_keeps_every_tet(tmp_path):
    from trivsel.io.pieces import merge_pieces, write_piece

    vol, paths, n_tets = _two_pieces(tmp_path)
    merged = pv.read(merge_pieces(paths, tmp_path / "merged.vtu"))
    whole = vol.region_data(((0, 5), (0, 5), (0, 5)))
    ids = merged.point_data["original_index"]
    assert merged.n_cells == n_tets and merged.n_points == 5 * 5 * 5  # the shared plane once
    assert np.array_equal(ids, np.arange(125))  # sorted by original_index
    assert _same(np.asarray(merged.points), whole.points) and _same(merged.point_data["value"], whole.values)
    tets = np.asarray(merged.cells).reshape(-1, 5)[:, 1:]
    pieces = [pv.read(p) for p in paths]
    original = np.concatenate([p.point_data["original_index"][np.asarray(p.cells).reshape(-1, 5)[:, 1:]]
                               for p in pieces])
    assert np.array_equal(ids[tets], original)  # every tet, over the same points
    with pytest.raises(trivsel.InputError, match="merged.vtu' exists"):
        merge_pieces(paths, tmp_path / "merged.vtu")
    p = pieces[1]
    write_piece(tmp_path / "moved.vtu", np.asarray(p.points) + 1e-9, np.asarray(p.cells).reshape(-1, 5)[:, 1:],
                p.point_data["value"], p.point_data["original_index"])
    with pytest.raises(trivsel.InputError, match="original_index 50 has different coordinates or values"):
        merge_pieces([paths[0], tmp_path / "moved.vtu"], tmp_path / "bad.vtu")
    assert not (tmp_path / "bad.vtu").exists()
    for args, message in (((np.zeros((2, 2)), np.zeros((0, 4), int), np.zeros(2), np.arange(2)), r"\(M, 3\)"),
                          ((np.zeros((4, 3)), [[0, 1, 2, 4]], np.zeros(4), np.arange(4)), "refer to point 4"),
                          ((np.zeros((4, 3)), [[0, 1, 2, 3]], np.zeros(3), np.arange(4)), "values must be 4"),
                          ((np.zeros((4, 3)), [[0, 1, 2, 3]], np.zeros(4), np.zeros(4)), "original_index must be")):
        with pytest.raises(trivsel.InputError, match=message):
            write_piece(tmp_path / "x.vtu", *args)
