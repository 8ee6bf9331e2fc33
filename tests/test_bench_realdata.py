"""Smoke tests of the real-data benchmark (trivsel.study.realdata and its command line
benchmarks/bench_realdata.py): its core function on tiny volumes, and the evaluation-as-a-matrix
that both its scores and its least-squares refits rest on."""

import importlib.util
import math

import numpy as np
import pytest

import trivsel
from conftest import IN_CI, load_benchmark_script
from trivsel.study import realdata as rd
from trivsel.study.baselines import evaluate_mesh_at_points, vtk_quadric_decimation


bench = load_benchmark_script("bench_realdata")

HAVE_REAL = importlib.util.find_spec("nilearn") is not None and importlib.util.find_spec("dipy") is not None


def _quiet(_msg):
    pass


def test_measure_on_a_tiny_synthetic_volume():
    data = rd.synthetic("chirp", 10)
    row = rd.measure(data, 0.1, repeats=1, scales=("raw", 0.3), say=_quiet)
    K = trivsel.selection.count_for_fraction(0.1, data.n_points)
    assert 9 <= row["n_vertices"] <= K
    assert row["vtk_split"] in rd.SPLITS and row["vtk_scale"] in ("raw", 0.3)
    # the refit can only lower E_RMS: VTK's own values are one feasible choice
    assert row["vtk_refit_E_rms"] <= row["vtk_E_rms"] * (1 + 1e-9)
    for m in rd.METHODS:
        for k in ("fit_over_vtk", "fit_over_refit", "inf_over_vtk", "time_over_vtk", "fit_over_delaunay_fit"):
            assert math.isfinite(row[f"{m}_{k}"]) and row[f"{m}_{k}"] >= 0, (m, k)
        assert row[f"{m}_fit_E_rms"] <= row[f"{m}_E_rms"] * (1 + 1e-9)
    assert row["greedy_vertex_ratio"] >= 0 and row["decimate_vertex_ratio"] >= 0
    ratios, details = rd.tables([row], list(rd.METHODS))
    assert ratios.count("\n") == 2 and "| chirp | 10 % |" in ratios and "| chirp |" in details
    # the workflow's report of the same row: one check per method, pass/fail as the ratios say
    check = rd.target_check([row])
    assert list(check.method) == list(rd.METHODS)
    for _, c in check.iterrows():
        assert c["fit_le_vtk"] == ("pass" if row[f"{c['method']}_fit_over_vtk"] <= 1 else "fail")
        assert c["time_le_2vtk"] == ("pass" if row[f"{c['method']}_time_over_vtk"] <= 2 else "fail")
        assert (c["ratio_le_1"] == "n/a") == (c["method"] not in rd.RATIO_METHODS)
        assert c["all"] == ("pass" if all(c[k] != "fail" for k in rd.TARGETS) else "fail")
    md = rd.realdata_markdown([row], figures={"chirp": "figures/realdata_chirp.png"})
    assert "## Targets" in md and ratios in md and "![chirp](figures/realdata_chirp.png)" in md


def test_curves_one_reduction_per_method(monkeypatch, tmp_path):
    data = rd.synthetic("steps", 10)
    calls = []
    real_reduce = trivsel.reduce

    def counting_reduce(*args, **kwargs):
        calls.append(kwargs.get("method"))
        return real_reduce(*args, **kwargs)

    monkeypatch.setattr(trivsel, "reduce", counting_reduce)
    df = rd.curves(data, [0.1, 0.05], methods=("decimate", "greedy"), repeats=1, scales=("raw",), say=_quiet)
    assert calls == ["decimate", "greedy"]  # every fraction a snapshot of one run
    assert list(df.columns) == rd.CURVE_COLUMNS and len(df) == 3 * 2 * 2
    assert set(zip(df.method, df["values"])) == {("decimate", "data"), ("decimate", "fit"), ("greedy", "data"),
                                                 ("greedy", "fit"), ("vtk", "free"), ("vtk", "fit")}
    ours = df[df.method != "vtk"]
    assert (ours.n_vertices == ours.n_target).all() and set(ours.fraction) == {0.05, 0.1}
    assert (df[df.method == "vtk"].n_vertices <= df[df.method == "vtk"].n_target).all()
    wide = df.pivot_table(index=["method", "fraction"], columns="values", values="E_rms")
    assert (wide["fit"].dropna() <= wide[["data", "free"]].max(axis=1).dropna() * (1 + 1e-9)).all()
    out = rd.curves_figure(df, tmp_path / "steps.png")
    assert out.stat().st_size > 10_000


def test_operator_scores_as_baselines_and_refits_as_trivsel():
    data = rd.synthetic("steps", 9)
    # VTK's decimated mesh: the operator evaluates like evaluate_mesh_at_points, outside points included
    dm = vtk_quadric_decimation(data, n_edges=data.n_points - 80, grid=rd.vtk_input(data, "kuhn6", 1.0), seed=0)
    A, out, _ = rd.mesh_operator(dm.points, dm.tets, data.points)
    ref, ref_out = evaluate_mesh_at_points(dm.points, dm.tets, dm.values, data.points)
    assert out.any() and np.array_equal(out, ref_out)
    np.testing.assert_allclose(A @ dm.values, ref, rtol=0, atol=1e-9)
    # on trivsel's own mesh the least-squares solve gives trivsel's fitted E_RMS
    r = trivsel.reduce(data, count=60, method="greedy", values=["data", "fit"])
    s = r.snapshots[-1]
    A, out, _ = rd.mesh_operator(data.points, s.tets, data.points)
    assert not out.any()
    e = rd.score(A, data.values, rd.least_squares_values(A, data.values, data.values))
    assert e["E_rms"] == pytest.approx(s.fit["errors"]["E_rms"], rel=1e-6, abs=1e-12)


def test_missing_packages_give_one_line(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "dipy" else real(name, *a))
    with pytest.raises(SystemExit) as exc:
        bench.main(["--volumes", "aniso", "chirp"])
    msg = str(exc.value)
    assert "dipy" in msg and "realdata" in msg and "\n" not in msg
    # the library's line, as the workflow's run job prints it
    one = rd.missing_message(["aniso"], "leave it out")
    assert one.startswith("the real volume aniso needs dipy") and "pip install -e '.[realdata]'" in one
    assert rd.missing_message(["chirp", "steps"]) is None
    with pytest.raises(rd.MissingExtra, match="realdata"):
        rd.load_volume("aniso")


@pytest.mark.skipif(not HAVE_REAL, reason="nilearn and dipy not installed (pip install -e '.[realdata]')")
def test_real_volumes_load_and_measure():
    shapes = {}
    for name in rd.REAL:
        d = rd.load_volume(name, quick=True)
        assert np.all(np.isfinite(d.values)) and np.ptp(d.values) > 0
        shapes[name] = (d.shape, tuple(d.spacing))
    assert shapes["icbm152"] == ((16, 16, 16), (1.0, 1.0, 1.0))
    assert shapes["statmap"] == ((16, 16, 16), (3.0, 3.0, 3.0))
    assert shapes["aniso"][0] == (16, 16, 16) and np.allclose(shapes["aniso"][1], (4, 4, 5))
    full = rd.load_volume("aniso")
    assert full.shape == (58, 58, 24) and full.meta["frame"].startswith("voxel axes")
    row = rd.measure(rd.central_crop(full, 9), 0.1, repeats=1,
                        scales=("raw",), methods=("greedy",), say=_quiet)
    assert row["vtk_refit_E_rms"] <= row["vtk_E_rms"] * (1 + 1e-9) and row["greedy_fit_over_refit"] > 0


def test_decimate_hashes_tell_identical_runs_from_different_ones(tmp_path, monkeypatch, capsys):
    hashes = load_benchmark_script("decimate_hashes")
    one = hashes.run_hash("chirp", True, "sse", "box", None)
    assert hashes.run_hash("chirp", True, "sse", "box", None) == one
    assert hashes.run_hash("chirp", True, "max", "box", None) != one
    assert hashes.run_hash("chirp", True, "sse", "all", None) != one
    monkeypatch.setattr(hashes, "CASES", [("chirp", True, "sse", "box", None), ("steps", True, "max", "box", None)])
    path = tmp_path / "h.json"
    assert hashes.main(["save", str(path)]) == 0
    assert hashes.main(["check", str(path)]) == 0
    assert "2 of 2 runs identical" in capsys.readouterr().out
    saved = path.read_text().replace(one, "0" * len(one))
    path.write_text(saved)
    assert hashes.main(["check", str(path)]) == 1
    assert "differ: chirp-True-sse-box-None" in capsys.readouterr().out


@pytest.mark.skipif(not HAVE_REAL and not IN_CI, reason="nilearn and dipy not installed (pip install -e '.[test]')")
def test_a_real_volume_from_a_wheel_decimates_better_than_greedy(tmp_path):
    """A crop of the MNI T1 template inside nilearn's wheel, saved as a NIfTI file and read back
    as a user's file is: decimate reaches a lower E_RMS than greedy at the same point count,
    both meshes fill the box, and every selected point keeps its value and its voxel index
    into the file (``original_index``, Fortran order)."""
    import nibabel as nib

    from trivsel.blocks import check_tetrahedra

    package, rel, _ = rd.REAL["icbm152"]
    img = nib.load(rd.package_file(package, rel))  # CI installs the test extra: a missing file fails
    start = np.array([90, 110, 80])
    block = np.asarray(img.dataobj[tuple(slice(b, b + n) for b, n in zip(start, (14, 12, 10)))], np.float64)
    assert np.ptp(block) > 0
    affine = img.affine.copy()
    affine[:3, 3] = img.affine[:3, :3] @ start + img.affine[:3, 3]
    path = tmp_path / "crop.nii.gz"
    nib.save(nib.Nifti1Image(block, affine), path)
    data = trivsel.load(path)
    assert data.shape == (14, 12, 10) and data.n_points == block.size
    count = 170
    runs = {m: trivsel.reduce(data, method=m, count=count).snapshots[-1] for m in ("decimate", "greedy")}
    for m, s in runs.items():
        assert s.n_selected == count, m
        check_tetrahedra(data.shape, s.tets)
        assert np.array_equal(np.unique(s.tets), np.sort(s.selected)), m
        ids = data.file_ids(s.selected)
        assert np.array_equal(block.ravel(order="F")[ids], data.values[s.selected]), m
        assert np.allclose(nib.affines.apply_affine(affine, np.column_stack(np.unravel_index(ids, block.shape, "F"))),
                           data.points[s.selected]), m
    assert runs["decimate"].errors["E_rms"] < runs["greedy"].errors["E_rms"]
