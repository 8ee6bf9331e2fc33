"""Scaling study: power-law fits, the table/figure/summary assembly on fabricated
measurements, one real measurement in a child process, and the workflow's scale stage on a
tiny configuration (n = 4, 6; paper, greedy, vtk) through a subprocess."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from trivsel.study.scaling import (SCALE_COLUMNS, fit_power_law, fit_slopes, measure, ratios, scaling_figure,
                             scaling_markdown, scaling_table)

REPO = Path(__file__).resolve().parents[1]


def test_exact_power_law_gives_the_exponent():
    x = np.array([4913.0, 35937.0, 274625.0, 2146689.0])
    b, c, r2 = fit_power_law(x, 3e-5 * x**1.27)
    assert b == pytest.approx(1.27, abs=1e-12) and c == pytest.approx(3e-5, rel=1e-9) and r2 == pytest.approx(1.0)
    b, c, r2 = fit_power_law(x, np.full(4, 7.0))  # constant: slope 0
    assert b == pytest.approx(0.0, abs=1e-12) and c == pytest.approx(7.0)
    # non-positive values are dropped; fewer than two sizes give NaN
    b, _, _ = fit_power_law([10, 100, 1000], [0.0, 2.0, 20.0])
    assert b == pytest.approx(1.0)
    assert np.isnan(fit_power_law([10, 10], [1, 2])[0])


def fabricated_rows():
    rows = []
    for n in (16, 32, 64):
        N = (n + 1) ** 3
        sel = int(round(0.1 * N))
        for method, a, b, mem in (("vtk", 1e-5, 1.0, 0.001), ("paper", 2e-6, 1.2, 0.002),
                                  ("greedy", 1e-6, 1.3, 0.004)):
            rows.append(dict(method=method, n=n, n_points=N, n_selected=sel - (method == "vtk"),
                             seconds=a * N**b, peak_mb=200.0 + mem * N, base_mb=200.0, warmup_seconds=0.5,
                             run_peak_mb=200.0 + mem * N, process_peak_mb=210.0 + mem * N))
    # a repeated measurement: the table keeps the median
    rows.append(dict(rows[-1], seconds=rows[-1]["seconds"] * 3))
    rows.append(dict(rows[-2], seconds=rows[-2]["seconds"] * 5))
    return rows


def test_table_slopes_ratios_markdown_and_figure(tmp_path):
    table = scaling_table(fabricated_rows())
    assert list(table.columns) == SCALE_COLUMNS + ["base_mb", "warmup_seconds"]
    assert list(table.method.unique()) == ["paper", "greedy", "vtk"] and len(table) == 9
    g64 = table[(table.method == "greedy") & (table.n == 64)].iloc[0]
    assert g64.seconds == pytest.approx(3 * 1e-6 * (65**3) ** 1.3)  # median of s, 3 s, 5 s

    slopes = fit_slopes(table, ("seconds", "peak_mb", "extra_mb")).set_index(["method", "quantity"])
    assert slopes.loc[("vtk", "seconds"), "slope"] == pytest.approx(1.0)
    assert slopes.loc[("paper", "seconds"), "slope"] == pytest.approx(1.2)
    assert slopes.loc[("paper", "extra_mb"), "slope"] == pytest.approx(1.0)  # memory above the baseline
    assert slopes.loc[("paper", "peak_mb"), "slope"] < 1.0  # the baseline flattens the total
    assert slopes.loc[("paper", "seconds"), "slope_last"] == pytest.approx(1.2)
    assert slopes.loc[("paper", "seconds"), "n_fit"] == 3

    rat = ratios(table)
    assert len(rat) == 6 and set(rat.method) == {"paper", "greedy"}
    r = rat[(rat.method == "paper") & (rat.n == 16)].iloc[0]
    N = 17**3
    assert r.ratio_seconds == pytest.approx(2e-6 * N**1.2 / (1e-5 * N))

    md = scaling_markdown(table, figure="figures/scaling.png")
    assert "![time and memory against points](figures/scaling.png)" in md
    assert "## Fitted slopes" in md and "## Ratios trivsel / VTK per n" in md
    ratio64 = 2e-6 * (65**3) ** 1.2 / (1e-5 * 65**3)  # about 2.4: over the target
    assert f"65^3 to 10 %, paper no slower than VTK (ratio <= 1): ratio {ratio64:.2f}" in md
    assert "**NOT MET**" in md
    assert "129^3 to 10 % with greedy under 10 minutes and 8 GiB: not measured" in md
    assert "time slope of paper no worse than VTK's: 1.20 vs 1.00: **NOT MET**" in md

    # a row at n = 128 that meets the target, and a fast paper run at 65^3
    big = dict(method="greedy", n=128, n_points=129**3, n_selected=214669, seconds=300.0, peak_mb=3000.0)
    rows = fabricated_rows() + [big]
    rows = [dict(r, seconds=1.0) if r["method"] == "paper" and r["n"] == 64 else r for r in rows]
    md = scaling_markdown(scaling_table(rows))
    assert "129^3 to 10 % with greedy under 10 minutes and 8 GiB: 300 s, 2.93 GiB: **MET**" in md
    assert "paper no slower than VTK (ratio <= 1): ratio " in md and "): **MET**" in md

    out = scaling_figure(table, tmp_path / "scaling.png")
    assert Path(out).stat().st_size > 10_000
    with pytest.raises(ValueError, match="lack the columns"):
        scaling_table([dict(method="paper", n=4)])


@pytest.mark.slow
def test_measure_in_a_fresh_process():
    """One real measurement: a child process, warm-up first, memory of that child only."""
    r = measure("greedy", 6, warmup_n=4, timeout=120)
    assert r["method"] == "greedy" and r["n_points"] == 343 and r["n_selected"] == 34  # 34.3 rounds to 34
    assert 0 < r["seconds"] < 30 and r["warmup_seconds"] > 0
    assert r["peak_mb"] >= r["base_mb"] > 50
    assert r["process_peak_mb"] >= r["base_mb"]
    with pytest.raises(RuntimeError, match="invalid choice"):
        measure("nonsense", 6)


def run_smk(workdir, *args, timeout=300):
    cmd = [sys.executable, "-m", "snakemake", "--snakefile", str(REPO / "Snakefile"), "--directory", str(workdir),
           "--cores", "2", *args]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    r.output = r.stdout + r.stderr
    return r


TARGETS = ["results/report/scaling.csv", "results/report/scaling.md", "results/report/figures/scaling.png"]


@pytest.mark.slow
def test_scale_stage_tiny(tmp_path):
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    cfg["data"].update(functions=[4], n=[4])
    cfg["scale"].update(activate=True, n=[4, 6], methods=["paper", "greedy", "vtk"])
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    r = run_smk(tmp_path, "--dry-run", "--quiet", "rules")  # `all` includes the scale targets
    assert r.returncode == 0, r.output
    assert any(line.split() == ["scale_run", "6"] for line in r.output.splitlines()), r.output
    r = run_smk(tmp_path, *TARGETS)
    assert r.returncode == 0, r.output[-5000:]
    rep = tmp_path / "results" / "report"
    table = pd.read_csv(rep / "scaling.csv")
    assert list(table.columns[:6]) == SCALE_COLUMNS
    assert len(table) == 6 and list(table.method.unique()) == ["paper", "greedy", "vtk"]
    assert set(table.n) == {4, 6} and set(table.n_points) == {125, 343}
    trivsel_rows = table[table.method != "vtk"]
    assert set(zip(trivsel_rows.n, trivsel_rows.n_selected)) == {(4, 13), (6, 34)}  # 12.5 rounds up
    assert (table.seconds > 0).all() and (table.peak_mb >= table.base_mb).all()
    md = (rep / "scaling.md").read_text()
    assert "## Fitted slopes" in md and "| paper | 6 | 343 |" in md and "## Targets" in md
    assert (rep / "figures" / "scaling.png").stat().st_size > 10_000
    one = json.loads((tmp_path / "results" / "scale" / "vtk" / "n6.json").read_text())
    assert one["method"] == "vtk" and one["warmup_seconds"] > 0
    for name in ("scale_run/paper/n4", "scale_table", "scale_figure"):
        assert (tmp_path / "results" / "logs" / f"{name}.log").exists()
        assert (tmp_path / "results" / "benchmarks" / f"{name}.tsv").exists()


def test_scale_config_is_valid_and_off_by_default():
    from snakemake.utils import validate

    schema = str(REPO / "workflow" / "schemas" / "config.schema.yaml")
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    assert cfg["scale"]["activate"] is False
    for key, section in yaml.safe_load((REPO / "config" / "scale.yaml").read_text()).items():
        cfg[key] = {**cfg.get(key, {}), **section} if isinstance(section, dict) else section
    validate(cfg, schema)
    assert cfg["scale"]["activate"] is True and cfg["scale"]["n"] == [16, 32, 64, 128]
    bad = dict(cfg, scale=dict(cfg["scale"], methods=["paper", "meshlab"]))
    with pytest.raises(Exception, match="meshlab"):
        validate(bad, schema)
