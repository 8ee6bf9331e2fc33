"""Smoke tests of benchmarks/bench_realdata.py: its core function on tiny volumes, and the
evaluation-as-a-matrix that both its scores and its least-squares refits rest on."""

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

import trivsel
from trivsel.study.baselines import evaluate_mesh_at_points, vtk_quadric_decimation

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_realdata.py"
_spec = importlib.util.spec_from_file_location("bench_realdata", _PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)

HAVE_REAL = importlib.util.find_spec("nilearn") is not None and importlib.util.find_spec("dipy") is not None


def _quiet(_msg):
    pass


def test_measure_on_a_tiny_synthetic_volume():
    data = bench.synthetic("chirp", 10)
    row = bench.measure(data, 0.1, repeats=1, scales=("raw", 0.3), say=_quiet)
    K = trivsel.selection.count_for_fraction(0.1, data.n_points)
    assert 9 <= row["n_vertices"] <= K
    assert row["vtk_split"] in bench.SPLITS and row["vtk_scale"] in ("raw", 0.3)
    # the refit can only lower E_RMS: VTK's own values are one feasible choice
    assert row["vtk_refit_E_rms"] <= row["vtk_E_rms"] * (1 + 1e-9)
    for m in bench.METHODS:
        for k in ("fit_over_vtk", "fit_over_refit", "inf_over_vtk", "time_over_vtk", "fit_over_delaunay_fit"):
            assert math.isfinite(row[f"{m}_{k}"]) and row[f"{m}_{k}"] >= 0, (m, k)
        assert row[f"{m}_fit_E_rms"] <= row[f"{m}_E_rms"] * (1 + 1e-9)
    assert row["greedy_vertex_ratio"] >= 0 and row["decimate_vertex_ratio"] >= 0
    ratios, details = bench.tables([row], list(bench.METHODS))
    assert ratios.count("\n") == 2 and "| chirp | 10 % |" in ratios and "| chirp |" in details


def test_operator_scores_as_baselines_and_refits_as_trivsel():
    data = bench.synthetic("steps", 9)
    # VTK's decimated mesh: the operator evaluates like evaluate_mesh_at_points, outside points included
    dm = vtk_quadric_decimation(data, n_edges=data.n_points - 80, grid=bench.vtk_input(data, "kuhn6", 1.0), seed=0)
    A, out, _ = bench.mesh_operator(dm.points, dm.tets, data.points)
    ref, ref_out = evaluate_mesh_at_points(dm.points, dm.tets, dm.values, data.points)
    assert out.any() and np.array_equal(out, ref_out)
    np.testing.assert_allclose(A @ dm.values, ref, rtol=0, atol=1e-9)
    # on trivsel's own mesh the least-squares solve gives trivsel's fitted E_RMS
    r = trivsel.reduce(data, count=60, method="greedy", values=["data", "fit"])
    s = r.snapshots[-1]
    A, out, _ = bench.mesh_operator(data.points, s.tets, data.points)
    assert not out.any()
    e = bench.score(A, data.values, bench.least_squares_values(A, data.values, data.values))
    assert e["E_rms"] == pytest.approx(s.fit["errors"]["E_rms"], rel=1e-6, abs=1e-12)


def test_missing_packages_give_one_line(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(bench.importlib.util, "find_spec", lambda name, *a: None if name == "dipy" else real(name, *a))
    with pytest.raises(SystemExit) as exc:
        bench.main(["--volumes", "aniso", "chirp"])
    msg = str(exc.value)
    assert "dipy" in msg and "realdata" in msg and "\n" not in msg


@pytest.mark.skipif(not HAVE_REAL, reason="nilearn and dipy not installed (pip install -e '.[realdata]')")
def test_real_volumes_load_and_measure():
    shapes = {}
    for name in bench.REAL:
        d = bench.load_volume(name, quick=True)
        assert np.all(np.isfinite(d.values)) and np.ptp(d.values) > 0
        shapes[name] = (d.shape, tuple(d.spacing))
    assert shapes["icbm152"] == ((16, 16, 16), (1.0, 1.0, 1.0))
    assert shapes["statmap"] == ((16, 16, 16), (3.0, 3.0, 3.0))
    assert shapes["aniso"][0] == (16, 16, 16) and np.allclose(shapes["aniso"][1], (4, 4, 5))
    full = bench.load_volume("aniso")
    assert full.shape == (58, 58, 24) and full.meta["frame"].startswith("voxel axes")
    row = bench.measure(bench.central_crop(full, 9), 0.1, repeats=1,
                        scales=("raw",), methods=("greedy",), say=_quiet)
    assert row["vtk_refit_E_rms"] <= row["vtk_E_rms"] * (1 + 1e-9) and row["greedy_fit_over_refit"] > 0
