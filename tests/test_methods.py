"""Greedy selection, fitted values, the matched-count harness of every method
(trivsel.study.comparison) and its tables, plot and workflow stage."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

import trivsel
from trivsel.mesh import check_mesh
from trivsel.data import sample_grid, scattered
from trivsel.mesh import TetMesh
from trivsel.study.comparison import COLUMNS, METHODS, compare_methods, methods_figure, methods_markdown, methods_table, \
    target_check
from trivsel.selection import count_for_fraction
from trivsel.triangulation import box_tetrahedra, cube_corners, delaunay_tetrahedra, hull_triangles

REPO = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- greedy


def _kinked_grid(n=8):
    """f = |x| + 0.5 y on the (n+1)^3 grid over [-1, 1]^3: exactly piecewise linear on two tets' worth
    of boxes (x <= 0 and x >= 0)."""
    x = np.linspace(-1.0, 1.0, n + 1)
    X, Y, _ = np.meshgrid(x, x, x, indexing="ij")
    return trivsel.grid_from_array(np.abs(X) + 0.5 * Y, origin=(-1, -1, -1), spacing=(2 / n,) * 3)


@pytest.mark.parametrize("key", ["max", "sse"])
def test_greedy_reaches_zero_error_with_few_points(key):
    data = _kinked_grid(8)
    r = trivsel.reduce(data, method="greedy", greedy_key=key, tol_inf=1e-12, values=["data", "fit"],
                       check=check_mesh)
    s = r.snapshots[-1]
    assert s.errors["E_inf"] < 1e-12 and s.fit["errors"]["E_inf"] < 1e-9
    # 8 corners plus the kink x = 0 (its 4 cube-edge points, perhaps a few on it); of 729 points
    assert 12 <= s.n_selected <= 30, s.n_selected
    assert np.unique(s.tets).size == s.n_selected


@pytest.mark.parametrize("function", [1, 2, 3, 4, 5])
def test_fit_never_worse_than_data_on_the_same_mesh(function):
    data = sample_grid(function, 6)
    for method in ("paper", "greedy"):
        r = trivsel.reduce(data, method=method, fractions=[0.5, 0.2, 0.1], values=["data", "fit"])
        for s in r.snapshots:
            assert s.fit["errors"]["E_rms"] <= s.errors["E_rms"] * (1 + 1e-12) + 1e-15, (method, s.fraction)
            # the fit lives on the same mesh: its vertices are the selected points
            assert np.array_equal(np.sort(s.fit["vertices"]), np.sort(np.unique(s.tets)))


def _random_case(seed, n_inner=40):
    rng = np.random.default_rng(seed)
    corners = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
    pts = np.vstack([corners, rng.uniform(-0.95, 0.95, (n_inner, 3))])
    vals = np.sin(2 * pts[:, 0]) + pts[:, 1] * pts[:, 2] + 0.3 * pts[:, 2] ** 2
    return scattered(pts, vals)


def _greedy_mesh(data):
    """A greedy TetMesh set up as reduce() does: fixed points triangulated, the rest candidates."""
    if data.is_grid:
        fixed = cube_corners(data.shape)
        start = box_tetrahedra(data.shape, "kuhn")
    else:
        _, fixed = hull_triangles(data.points)
        start = fixed[delaunay_tetrahedra(data.points[fixed])]
    cand = np.setdiff1d(np.arange(data.n_points), fixed)
    tm = TetMesh(data.points, data.values, data.ijk, criterion="sse", greedy=True, greedy_key="max",
                 candidates=cand)
    tm.start(start)
    return tm, cand


@pytest.mark.parametrize("case", ["random-0", "random-1", "grid"])
def test_each_greedy_insertion_takes_the_largest_residual(case):
    """Step by step: the greedy choice has the largest |f - L| among the candidates not yet
    selected; the mesh is valid after every insertion and every swap.  E_inf is not asserted to
    fall (pinning one point can worsen a neighbour)."""
    if case == "grid":
        data = sample_grid(3, 4)
    else:
        data = _random_case(int(case[-1]))
    tm, cand = _greedy_mesh(data)
    check_mesh(tm)
    steps = 0
    for _ in range(25):
        r, _ = tm.residuals()
        free = np.setdiff1d(cand, tm.vertices())  # candidates not yet selected
        p = tm.greedy_next()
        if p < 0:
            assert np.abs(r[free]).max(initial=0.0) == 0.0
            break
        assert p in free, f"greedy chose {p}, not a free candidate"
        worst = np.abs(r[free]).max()
        assert abs(r[p]) >= worst * (1 - 1e-12), (abs(r[p]), worst)
        _, ids = tm.insert(p)
        check_mesh(tm)
        tm.swap(ids)
        check_mesh(tm)
        assert p in tm.vertices()
        steps += 1
    assert steps >= 10


# --------------------------------------------------------------------------- the harness


@pytest.fixture(scope="module")
def small_comparison():
    return compare_methods(sample_grid(4, 6), fractions=[0.5, 0.2, 0.1], vtk_runs=5, random_seeds=3)


def test_harness_has_every_method_and_value_mode(small_comparison):
    df = small_comparison
    assert list(df.columns[:len(COLUMNS)]) == COLUMNS
    pairs = set(zip(df["method"], df["values"]))
    for m in ("paper", "greedy", "greedy-sse", "decimate"):
        assert {(m, "data"), (m, "fit")} <= pairs
    assert {("vtk", "free"), ("random-delaunay", "data"), ("curvature-delaunay", "data")} <= pairs
    assert len(df) == 3 * (8 + 3)
    assert (df[df["method"] == "vtk"]["runs"] == 5).all()
    assert (df[df["method"] == "random-delaunay"]["runs"] == 3).all()


def test_harness_really_matches_counts(small_comparison):
    df = small_comparison
    N = 7**3
    for f, g in df.groupby("fraction"):
        target = count_for_fraction(f, N)
        assert (g["n_target"] == target).all()
        exact = g[g["method"] != "vtk"]
        assert (exact["n_selected"] == target).all(), exact[["method", "n_selected"]]
        assert (exact["n_selected_min"] == target).all() and (exact["n_selected_max"] == target).all()
        v = g[g["method"] == "vtk"].iloc[0]
        assert target - 3 <= v["n_selected_min"] <= v["n_selected"] <= v["n_selected_max"] <= target


def test_harness_spreads_and_outside_counts(small_comparison):
    df = small_comparison
    for k in ("E_rms", "E_inf"):
        assert (df[f"{k}_min"] <= df[k] * (1 + 1e-12)).all() and (df[k] <= df[f"{k}_max"] * (1 + 1e-12)).all()
    single = df[df["runs"] == 1]
    assert (single["E_rms_min"] == single["E_rms"]).all()
    assert (df[df["method"] != "vtk"]["n_outside"] == 0).all()
    assert (df["n_outside"] >= 0).all() and (df["seconds"] > 0).all()
    # greedy beats the random subset everywhere on this smooth function
    for f, g in df.groupby("fraction"):
        e = g.set_index(["method", "values"])["E_inf"]
        assert e[("greedy", "data")] < e[("random-delaunay", "data")]


def test_harness_curvature_delaunay_uses_the_paper_points():
    data = sample_grid(2, 5)
    df = compare_methods(data, fractions=[0.3], methods=["paper", "curvature-delaunay"])
    assert set(df["method"]) == {"paper", "curvature-delaunay"}
    df2 = compare_methods(data, fractions=[0.3], methods=["curvature-delaunay"])
    assert set(df2["method"]) == {"curvature-delaunay"}
    a = df[df["method"] == "curvature-delaunay"].iloc[0]
    b = df2.iloc[0]
    assert a["E_rms"] == b["E_rms"] and a["n_selected"] == b["n_selected"]
    with pytest.raises(ValueError, match="unknown methods"):
        compare_methods(data, fractions=[0.3], methods=["bogus"])


# --------------------------------------------------------------------------- tables


def _fabricated_rows():
    """Two functions x two fractions; VTK wins function 2's E_RMS at 10 % and is above the count
    (too many vertices) in function 1 at 50 %."""
    rows = []
    for fn in (1, 2):
        for f, target in ((0.5, 100), (0.1, 20)):
            base = dict(function=fn, n=4, fraction=f, n_target=target, runs=1, n_outside=0.0,
                        max_outside_distance=0.0, seconds=1.0)

            def add(method, values, e_rms, e_inf, n_sel=target, **kw):
                r = dict(base, method=method, values=values, n_selected=n_sel, E_rms=e_rms,
                         E_rms_interior=e_rms, E_inf=e_inf, E_inf_interior=e_inf, n_selected_min=n_sel,
                         n_selected_max=n_sel, E_rms_min=e_rms, E_rms_max=e_rms, E_inf_min=e_inf, E_inf_max=e_inf)
                r.update(kw)
                rows.append(r)

            add("curvature-delaunay", "data", 0.5, 0.9)
            add("greedy", "fit", 0.010, 0.05)
            add("greedy", "data", 0.012, 0.04)
            vtk_rms = 0.008 if (fn == 2 and f == 0.1) else 0.02
            over = target + 1 if (fn == 1 and f == 0.5) else target
            add("vtk", "free", vtk_rms, 0.06, n_sel=target - 1, runs=5, n_selected_min=target - 2,
                n_selected_max=over, E_rms_min=vtk_rms / 2, E_rms_max=vtk_rms * 2, n_outside=7.0, seconds=0.1)
            add("paper", "data", 0.3, 0.6)
    return rows


def test_methods_table_orders_rows_and_fills_columns():
    rows = _fabricated_rows()
    for r in rows:
        r.pop("max_outside_distance")
    df = methods_table(rows[::-1])
    assert list(df.columns) == COLUMNS
    assert df["max_outside_distance"].isna().all()
    first = df[(df["function"] == 1) & (df["fraction"] == 0.5)]
    assert list(first["method"]) == ["greedy", "greedy", "paper", "vtk", "curvature-delaunay"]
    assert list(first["values"][:2]) == ["data", "fit"]
    assert list(df["fraction"][:5]) == [0.5] * 5 and list(df["function"][:10]) == [1] * 10
    assert methods_table([]).columns.tolist() == COLUMNS
    assert [m for m in METHODS if m in set(df["method"])] == ["greedy", "paper", "vtk", "curvature-delaunay"]


def test_target_check_on_fabricated_rows():
    chk = target_check(_fabricated_rows())
    assert len(chk) == 4
    c = chk.set_index(["function", "fraction"])
    assert c.loc[(1, 0.1), "holds_inf"] and c.loc[(1, 0.1), "holds_rms"]
    assert not c.loc[(1, 0.5), "count_ok"]  # a VTK run above the count: not a fair cell
    assert not c.loc[(1, 0.5), "holds_inf"] and not c.loc[(1, 0.5), "holds_rms"]
    assert c.loc[(2, 0.1), "holds_inf"] and not c.loc[(2, 0.1), "holds_rms"]
    assert c.loc[(2, 0.1), "greedy_fit_E_rms"] == 0.010 and c.loc[(2, 0.1), "vtk_E_rms"] == 0.008
    assert list(chk["fraction"]) == [0.5, 0.1, 0.5, 0.1]
    assert len(target_check(_fabricated_rows(), fractions=[0.1])) == 2


def test_methods_markdown_on_fabricated_rows():
    md = methods_markdown(_fabricated_rows(), figures={(4, 1): "figures/methods_f1_n4.png"})
    head, rest = md.split("\n## ", 1)
    assert head.startswith("# How good is it")
    assert "**E_inf: greedy lower in 3 of 4 cells; E_RMS: greedy lower in 2 of 4 cells.**" in head
    # the failing cell, split into interior and boundary-face RMS (equal here by construction)
    assert "2. saddle at 10 % (0.0100 vs 0.00800, +25 %; interior 0.0100 vs 0.00800, faces 0.010 vs 0.0080)" in head
    assert "| 1. quadratic | 50 % | 100 / 98-101 |" in head
    assert "![E_RMS and E_inf against the vertex count, function 1](figures/methods_f1_n4.png)" in rest
    assert "| 10 % | vtk | free | 18-20 |" in rest and "| 7 | 0.10 |" in rest


def test_methods_figure_writes_png(tmp_path):
    out = tmp_path / "m.png"
    methods_figure(_fabricated_rows(), out, function=2, n=4)
    assert out.stat().st_size > 10_000
    with pytest.raises(ValueError, match="no rows"):
        methods_figure(_fabricated_rows(), tmp_path / "x.png", function=3)


# --------------------------------------------------------------------------- workflow


@pytest.mark.slow
def test_methods_sweep_config_dry_run(tmp_path):
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    assert cfg["methods"]["activate"] is False  # the paper's reproduction stays fast
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    r = subprocess.run([sys.executable, "-m", "snakemake", "--snakefile", str(REPO / "Snakefile"), "--directory",
                        str(tmp_path), "--cores", "2", "--dry-run", "--quiet", "rules", "--configfile",
                        str(tmp_path / "config.yaml"), str(REPO / "config" / "methods.yaml")],
                       capture_output=True, text=True, timeout=120)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out
    lines = [line.split() for line in out.splitlines()]
    assert ["methods_run", "5"] in lines and ["methods_figure", "5"] in lines and ["methods_table", "1"] in lines


@pytest.mark.slow
def test_methods_stage_and_readme_block_for_real(tmp_path):
    """The methods stage on n = 4 for one function, then `readme` rewrites the Table-1 block of the
    README and the methods block of docs/methods.md."""
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    cfg["data"].update(functions=[2], n=[4])
    cfg["report"]["figures_3d"] = False
    cfg["methods"].update(activate=True, fractions=[0.5, 0.3], vtk_runs=5, random_seeds=3)
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    t1 = ("<!-- BEGIN table1: generated by `snakemake -c all readme` -->", "<!-- END table1 -->")
    m = ("<!-- BEGIN methods: generated by `snakemake -c all readme --configfile config/methods.yaml` -->",
         "<!-- END methods -->")
    (tmp_path / "README.md").write_text(f"# t\n\n{t1[0]}\nold table\n{t1[1]}\n\nend\n")
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "methods.md").write_text(f"# How good is it\n\n{m[0]}\nold methods\n{m[1]}\n\nend\n")
    r = subprocess.run([sys.executable, "-m", "snakemake", "--snakefile", str(REPO / "Snakefile"), "--directory",
                        str(tmp_path), "--cores", "2", "all", "readme"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (r.stdout + r.stderr)[-5000:]
    rep = tmp_path / "results" / "report"
    df = pd.read_csv(rep / "methods.csv")
    assert list(df.columns[:len(COLUMNS)]) == COLUMNS
    assert sorted(df["fraction"].unique()) == [0.1, 0.2, 0.3, 0.5]  # Table-1 fractions + the sweep
    assert set(df["method"]) == set(METHODS)
    assert (rep / "figures" / "methods_f2_n4.png").stat().st_size > 10_000
    md = (rep / "methods.md").read_text()
    assert "of 3 cells" in md and "### Function 2. saddle, n = 4" in md
    text = (tmp_path / "README.md").read_text()
    assert "old table" not in text and text.endswith("\n\nend\n")
    text = (tmp_path / "docs" / "methods.md").read_text()
    assert "old methods" not in text and text.endswith("\n\nend\n")
    block = text.split(m[0], 1)[1].split(m[1], 1)[0]
    assert "| 2. saddle | 50 % |" in block and "## Every method" not in block and "# How good" not in block
