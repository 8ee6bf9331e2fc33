"""Report assembly, golden-table comparison and figures on fabricated small results."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import trivsel
from trivsel import regression as compare
from trivsel.exceptions import InputError
from trivsel.study import report
from trivsel.triangulation import kuhn_tetrahedra

REPO = Path(__file__).resolve().parents[1]
GOLDEN = REPO / "tests" / "golden" / "table1.csv"


# --------------------------------------------------------------------------- fabrication
def fabricated_errors(function, factor=1.05, n=16, fractions=(0.5, 0.2, 0.1)):
    """errors.csv rows as `trivsel reduce` writes them, E_RMS = factor * published."""
    pub = report.load_published()
    rows = []
    npts = (n + 1) ** 3
    for fr in fractions:
        p = pub[(pub.function == function) & np.isclose(pub.fraction, fr)]
        e, ei = (float(p.E_rms.iloc[0]), float(p.E_rms_interior.iloc[0])) if len(p) else (0.1, 0.05)
        rows.append(dict(function=function, n=n, method="paper", values="data", fraction=fr,
                         n_selected=int(round(fr * npts)), E_rms=factor * e, E_rms_interior=factor * ei,
                         E_inf=3 * e, E_inf_interior=2 * ei))
    return pd.DataFrame(rows)


def fabricated_run(tmp_path, function, n=4, fractions=(0.5, 0.2, 0.1), factor=1.05):
    """A run directory like `trivsel reduce --out`: errors.csv, result.json, mesh_<f>.vtu.

    The "reduced" meshes are Kuhn triangulations of coarse sub-grids (every
    2nd grid line), so they are valid tetrahedral meshes of the cube.
    """
    pv = pytest.importorskip("pyvista")
    out = tmp_path / f"f{function}"
    out.mkdir(parents=True, exist_ok=True)
    data = trivsel.sample_grid(function, n)
    fabricated_errors(function, factor=factor, n=n, fractions=fractions).to_csv(out / "errors.csv", index=False)
    step = 2
    idx = np.arange(0, n + 1, step)
    sub = np.array([(i * (n + 1) + j) * (n + 1) + k for i in idx for j in idx for k in idx])
    m = len(idx)
    tets = kuhn_tetrahedra((m, m, m))
    for fr in fractions:
        cells = np.hstack([np.full((len(tets), 1), 4), tets]).ravel()
        grid = pv.UnstructuredGrid(cells, np.full(len(tets), pv.CellType.TETRA, np.uint8), data.points[sub])
        grid.point_data["value"] = data.values[sub]
        grid.point_data["original_index"] = sub
        grid.point_data["curvature"] = np.zeros(len(sub))
        grid.save(out / f"mesh_{fr:g}.vtu")
    (out / "result.json").write_text(json.dumps({
        "function": function, "options": {"criterion": "rms", "candidates": "all"},
        "timings": {"curvature": 0.01, "selection": 0.02}}))
    return out, data


# --------------------------------------------------------------------------- Table 1
def test_published_table_is_table1():
    pub = report.load_published()
    assert len(pub) == 15
    assert set(pub.function) == {1, 2, 3, 4, 5}
    row = pub[(pub.function == 4) & np.isclose(pub.fraction, 0.1)].iloc[0]
    assert (row.E_rms, row.E_rms_interior) == (0.165, 0.117)


def test_assemble_table1_columns_rows_and_ratios():
    errors = pd.concat([fabricated_errors(f) for f in (1, 2, 3, 4, 5)], ignore_index=True)
    errors = errors.sample(frac=1.0, random_state=1)  # order must not matter
    table = report.assemble_table1(errors)
    assert list(table.columns) == report.TABLE1_COLUMNS
    assert len(table) == 15
    assert list(table.function) == [1, 1, 1, 2, 2, 2, 3, 3, 3, 4, 4, 4, 5, 5, 5]
    assert list(table.fraction[:3]) == [0.5, 0.2, 0.1]
    np.testing.assert_allclose(table.ratio_E_rms, 1.05)
    np.testing.assert_allclose(table.ratio_E_rms_interior, 1.05)
    r = table[(table.function == 2) & (table.fraction == 0.2)].iloc[0]
    assert r.published_E_rms == 0.220 and r.published_E_rms_interior == 0.120


def test_assemble_table1_rejects_two_runs_of_one_function():
    errors = pd.concat([fabricated_errors(1), fabricated_errors(1)], ignore_index=True)
    with pytest.raises(ValueError, match="more than one error row"):
        report.assemble_table1(errors)


def test_markdown_flags_cells_outside_tolerance():
    errors = pd.concat([fabricated_errors(f) for f in (1, 2, 3, 4, 5)], ignore_index=True)
    bad = (errors.function == 5) & (errors.fraction == 0.1)
    errors.loc[bad, "E_rms"] *= 2.0  # +110 %: flagged; everything else +5 %
    table = report.assemble_table1(errors)
    md = report.table1_markdown(table, tol=0.10, n=16, options={"criterion": "rms"})
    assert md.count(" ⚠**") == 1
    assert "**0.149 / 0.071 (+110.0 %) ⚠**" in md
    assert "0.148 / 0.141 (+5.0 %)" in md and "0.080\\* / 0.076\\* (+5.0 %)" in md
    assert "**29 of 30**" in md
    assert "| 50 % | 20 % | 10 % |" in md
    assert "- `criterion`: rms" in md
    assert "Note: the published values are for n = 16" not in md
    assert "n = 8, so the deviations" in report.table1_markdown(table, n=8)


def test_write_table1_from_fabricated_run_directories(tmp_path):
    csvs, jsons = [], []
    for f in (1, 4):
        out = tmp_path / f"f{f}"
        out.mkdir()
        fabricated_errors(f, factor=0.95).to_csv(out / "errors.csv", index=False)
        (out / "result.json").write_text(json.dumps({"function": f, "options": {"criterion": "rms"},
                                                     "timings": {"curvature": 0.5},
                                                     "snapshots": [{"seconds": 0.25}, {"seconds": 1.5}]}))
        csvs.append(out / "errors.csv")
        jsons.append(out / "result.json")
    table = report.write_table1(csvs, tmp_path / "t.csv", tmp_path / "t.md", result_jsons=jsons)
    assert len(table) == 6
    back = pd.read_csv(tmp_path / "t.csv")
    assert list(back.columns) == report.TABLE1_COLUMNS
    np.testing.assert_allclose(back.ratio_E_rms, 0.95)
    md = (tmp_path / "t.md").read_text()
    assert "## Run times" in md and "curvature (s)" in md and "reduce seconds" in md
    # the reduce time is the last snapshot's time in result.json (errors.csv has no times)
    assert "| Function | reduce seconds | curvature (s) |" in md and "| 1 | 1.50 | 0.50 |" in md
    assert "## Options used" in md and "`criterion`: rms" in md
    assert "table1_published.csv" in md


def test_collect_runs_adds_options_and_published():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        runs = []
        for crit in ("rms", "max"):
            p = Path(d) / f"{crit}.csv"
            fabricated_errors(3).to_csv(p, index=False)
            runs.append((p, {"n": 16, "variant": f"crit~{crit}", "criterion": crit}))
        allruns = report.collect_runs(runs)
    assert len(allruns) == 6
    assert set(allruns.criterion) == {"rms", "max"}
    np.testing.assert_allclose(allruns.ratio_E_rms, 1.05)


# --------------------------------------------------------------------------- golden comparison
@pytest.fixture
def table_csv(tmp_path):
    errors = pd.concat([fabricated_errors(f) for f in (1, 2, 3, 4, 5)], ignore_index=True)
    p = tmp_path / "table1.csv"
    report.assemble_table1(errors).to_csv(p, index=False)
    return p


def test_compare_passes_on_identical_and_reordered_tables(table_csv, tmp_path):
    assert compare.compare_tables(table_csv, table_csv) == []
    shuffled = pd.read_csv(table_csv).sample(frac=1.0, random_state=3)
    p = tmp_path / "shuffled.csv"
    shuffled.to_csv(p, index=False)
    assert compare.compare_tables(p, table_csv, rtol=0) == []


def test_compare_reports_the_offending_cells(table_csv, tmp_path):
    df = pd.read_csv(table_csv)
    df.loc[(df.function == 4) & (df.fraction == 0.1), "E_rms_interior"] *= 1 + 1e-4
    df.loc[(df.function == 2) & (df.fraction == 0.5), "n_selected"] += 1
    p = tmp_path / "perturbed.csv"
    df.to_csv(p, index=False)
    bad = compare.compare_tables(p, table_csv, rtol=1e-6)
    assert {(m.row, m.column) for m in bad} == {("function=4, fraction=0.1", "E_rms_interior"),
                                                ("function=2, fraction=0.5", "n_selected")}
    text = compare.format_mismatches(bad, p, table_csv, 1e-6, 0)
    assert "2 offending cell(s)" in text and "E_rms_interior" in text and "rel. change +0.01 %" in text
    # within a looser tolerance the value change passes, the count change does not
    assert [m.column for m in compare.compare_tables(p, table_csv, rtol=1e-3)] == ["n_selected"]
    assert [m.column for m in compare.compare_tables(p, table_csv, rtol=0, atol=2)] == ["n_selected"]


def test_compare_missing_rows_and_columns(table_csv, tmp_path):
    df = pd.read_csv(table_csv)
    p = tmp_path / "short.csv"
    df[df.function != 5].drop(columns=["E_inf"]).to_csv(p, index=False)
    bad = compare.compare_tables(p, table_csv)
    reasons = {m.reason for m in bad}
    assert reasons == {"missing row", "missing column"}
    assert sum(m.reason == "missing row" for m in bad) == 3
    with pytest.raises(FileNotFoundError):
        compare.compare_tables(tmp_path / "nope.csv", table_csv)


def test_compare_refuses_a_key_column_that_one_table_lacks(table_csv, tmp_path):
    """A key column (here ``function``) missing or renamed in either table is an InputError
    naming the column and both tables, not rows matched on the keys left."""
    df = pd.read_csv(table_csv)
    renamed = tmp_path / "renamed.csv"
    df.rename(columns={"function": "Function"}).to_csv(renamed, index=False)
    with pytest.raises(InputError, match=r"key column 'function' of the golden table '.*table1.csv' is missing "
                                         r"from the new table '.*renamed.csv' \(it has 'Function'\)"):
        compare.compare_tables(renamed, table_csv)
    with pytest.raises(InputError, match="key column 'function' of the new table .* is missing from the golden"):
        compare.compare_tables(table_csv, renamed)
    with pytest.raises(InputError, match="key column 'fraction' of the golden table is missing from the new table"):
        compare.compare_frames(df.drop(columns=["fraction"]), df)


def test_compare_reports_columns_that_one_table_lacks(table_csv, tmp_path):
    """A compared column the new table lacks and a column only the new table has are offending
    cells (exit status 1 in the CLI); a wall-clock column is neither."""
    df = pd.read_csv(table_csv)
    bad = compare.compare_frames(df.drop(columns=["E_inf"]).assign(E_max=1.0, note="x", seconds=2.0), df)
    assert [(m.column, m.reason) for m in bad] == [("E_inf", "missing column"), ("E_max", "extra column"),
                                                   ("note", "extra column")]
    assert "E_max: extra column" in compare.format_mismatches(bad)
    assert compare.compare_frames(df, df.assign(seconds=2.0)) == []


def test_compare_refuses_a_key_that_two_rows_share(table_csv):
    df = pd.read_csv(table_csv)
    twice = pd.concat([df, df.iloc[[4]]], ignore_index=True)
    with pytest.raises(InputError, match=r"the new table has two rows with the key function=2, fraction=0.2 "
                                         r"\(data rows 5 and 16\)"):
        compare.compare_frames(twice, df)
    with pytest.raises(InputError, match="the golden table 'g.csv' has two rows with the key function=2"):
        compare.compare_frames(df, twice, names=("n.csv", "g.csv"))


@pytest.mark.parametrize("text, message", [
    ("function,fraction,E_rms\n1,0.5,0.1,7\n2,0.5,0.2\n", "line 2 has 4 fields, the header 3"),
    ("function,fraction,E_rms\n1,0.5\n", "line 2 has 2 fields, the header 3"),
    ("function,E_rms,E_rms\n1,0.1,0.2\n", "the header names column 'E_rms' twice (columns 2 and 3)"),
    (",function,E_rms\n0,1,0.1\n", "column 1 of the header has no name"),
    ('<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid">\n', "it is XML, not comma-separated values"),
    ("", "the file is empty"),
])
def test_read_table_refuses_what_pandas_would_misread(tmp_path, text, message):
    p = tmp_path / "t.csv"
    p.write_text(text)
    with pytest.raises(InputError) as info:
        compare.read_table(p)
    assert str(info.value).startswith(f"cannot read table {str(p)!r} as CSV: {message}")


def test_the_report_table_has_the_golden_columns():
    """The CI regression compares results/report/table1.csv with the golden table: they must
    have the same columns, or every run would report missing or extra columns."""
    assert list(pd.read_csv(GOLDEN).columns) == report.TABLE1_COLUMNS


def _trivsel_cli():
    exe = Path(sys.executable).parent / "trivsel"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "trivsel.cli"]


def test_compare_command_on_golden_table(tmp_path):
    """`trivsel compare` passes on the golden table and fails, naming the cell, on a perturbed copy."""
    if not GOLDEN.is_file():
        pytest.fail(f"golden table missing: {GOLDEN} (produce it with the paper workflow, see workflow/README-section.md)")
    ok = subprocess.run(_trivsel_cli() + ["compare", str(GOLDEN), str(GOLDEN), "--rtol", "1e-6"],
                        capture_output=True, text=True)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    df = pd.read_csv(GOLDEN)
    df.loc[(df.function == 3) & (df.fraction == 0.2), "E_rms"] *= 1.001
    p = tmp_path / "perturbed.csv"
    df.to_csv(p, index=False)
    bad = subprocess.run(_trivsel_cli() + ["compare", str(p), str(GOLDEN), "--rtol", "1e-6"],
                         capture_output=True, text=True)
    assert bad.returncode == 1
    assert "function=3, fraction=0.2" in bad.stdout + bad.stderr
    assert "E_rms" in bad.stdout + bad.stderr


# --------------------------------------------------------------------------- figures
def test_figures_from_fabricated_meshes(tmp_path):
    from trivsel.study import figures

    out, data = fabricated_run(tmp_path, 2)
    errors = pd.read_csv(out / "errors.csv")
    meshes = {fr: out / f"mesh_{fr:g}.vtu" for fr in (0.5, 0.2, 0.1)}
    png = figures.slice_figure(data, meshes, tmp_path / "slices.png", errors=errors, function=2)
    png3 = figures.slice_figure_3d(data, meshes, tmp_path / "slices3d.png", errors=errors, function=2)
    allruns = report.collect_runs([(out / "errors.csv", {"n": 4, "variant": "v"})])
    pngE = figures.erms_figure(allruns, tmp_path / "erms.png")
    import matplotlib.image as mpimg

    for p in (png, png3, pngE):
        img = mpimg.imread(p)
        assert img.shape[0] > 300 and img.shape[1] > 500
        assert img[..., :3].std() > 0.05  # not blank
    # the 3-D panels are placed pixel for pixel in the four cells of the 2 x 2 layout
    img = mpimg.imread(png3)[..., :3]
    assert img.shape[:2] == (1232, 1474)  # (5.2 * 2 + 0.8) x (6.2 * 2 + 1.0) inches at 110 dpi
    for rows in (slice(140, 600), slice(660, 1200)):
        for cols in (slice(20, 640), slice(660, 1280)):
            cell = img[rows, cols]
            assert (cell.min(axis=-1) < 0.5).mean() > 0.05  # a rendering, not the white background


def test_plane_values_reproduce_linear_data(tmp_path):
    """On a mesh the probe returns the piecewise-linear interpolant: exact for linear f."""
    from trivsel.study import figures

    data = trivsel.sample_grid(1, 4)
    data.values = 0.3 * data.points[:, 0] - 0.2 * data.points[:, 1] + 0.1 * data.points[:, 2] + 1
    mesh = figures.original_mesh(data)
    vals, (u, v) = figures.plane_values(mesh, 2, 0.25, data.points.min(0), data.points.max(0), res=9)
    assert (u, v) == (0, 1)
    g = np.linspace(-1, 1, 9)
    xx, yy = np.meshgrid(g, g, indexing="xy")
    np.testing.assert_allclose(vals, 0.3 * xx - 0.2 * yy + 0.1 * 0.25 + 1, atol=1e-7)


def test_plane_values_exact_on_skinny_mesh():
    """Slices through an irregular mesh match a brute-force barycentric evaluation."""
    pv = pytest.importorskip("pyvista")
    from scipy.spatial import Delaunay

    from trivsel.study import figures

    rng = np.random.default_rng(7)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    pts = np.vstack([corners, rng.uniform(-1, 1, (60, 3)) * [1, 0.2, 1]])  # flattened cloud: skinny tets
    vals = np.sin(2 * pts[:, 0]) + pts[:, 1] * pts[:, 2]
    tets = Delaunay(pts).simplices
    cells = np.hstack([np.full((len(tets), 1), 4), tets]).ravel()
    mesh = pv.UnstructuredGrid(cells, np.full(len(tets), pv.CellType.TETRA, np.uint8), pts)
    mesh.point_data["value"] = vals
    got, (u, v) = figures.plane_values(mesh, 0, 0.1, [-1, -1, -1], [1, 1, 1], res=25)
    g = np.linspace(-1, 1, 25)
    A = pts[tets[:, 1:]] - pts[tets[:, :1]]
    Ainv = np.linalg.inv(np.transpose(A, (0, 2, 1)))
    for iv in range(0, 25, 3):
        for iu in range(0, 25, 3):
            p = np.array([0.1, g[iu], g[iv]])
            lam = np.einsum("tij,tj->ti", Ainv, p - pts[tets[:, 0]])
            b = np.concatenate([1 - lam.sum(1, keepdims=True), lam], 1)
            t = np.flatnonzero(b.min(1) >= -1e-9)[0]
            assert abs(got[iv, iu] - b[t] @ vals[tets[t]]) < 1e-6


def test_save_load_data_roundtrip(tmp_path):
    from trivsel.io import load, save_npz

    data = trivsel.sample_grid(3, 4)
    back = load(save_npz(data, tmp_path / "d.npz"))
    np.testing.assert_array_equal(back.values, data.values)
    np.testing.assert_array_equal(back.ijk, data.ijk)
    np.testing.assert_allclose(back.points, data.points, atol=1e-15)
    assert back.shape == data.shape and back.interior_mask().sum() == 27
    rng = np.random.default_rng(0)
    pts = trivsel.scattered(rng.random((20, 3)), rng.random(20))
    back = load(save_npz(pts, tmp_path / "p.npz"))
    np.testing.assert_array_equal(back.points, pts.points)
    np.testing.assert_array_equal(back.values, pts.values)
    assert not back.is_grid


def test_golden_table_has_the_table1_layout():
    if not GOLDEN.is_file():
        pytest.fail(f"golden table missing: {GOLDEN}")
    g = pd.read_csv(GOLDEN)
    assert list(g.columns) == report.TABLE1_COLUMNS and len(g) == 15
