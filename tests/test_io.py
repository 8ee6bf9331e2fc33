"""File formats: geometry and values exactly as the file says, and `original_index` in the output
meshes is the input's own point id (values[original_index] == value, coordinates equal)."""

from __future__ import annotations

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


def test_unsupported_suffix_is_refused(tmp_path, capsys):
    (tmp_path / "brain.nii").write_bytes(b"\0" * 400)
    assert main(["reduce", str(tmp_path / "brain.nii"), "--fractions", "0.3", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "unsupported file type '.nii'" in err and err.count("\n") == 1
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
