"""The Snakemake workflow: lint, config schema, dry runs of the sweeps and the SLURM
profile, and a real run on a tiny configuration (n = 4, two functions) in a
temporary directory, through a subprocess as a user would run it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from trivsel.study.report import TABLE1_COLUMNS

REPO = Path(__file__).resolve().parents[1]
SNAKEFILE = REPO / "Snakefile"
PRIMARY = "method~paper_crit~rms_cand~all_tie~index_diag~mirrored_verr~yes_final~no_curv~direct_seed~0"


def run_smk(workdir, *args, timeout=300):
    cmd = [sys.executable, "-m", "snakemake", "--snakefile", str(SNAKEFILE), "--directory", str(workdir),
           "--cores", "2", *args]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    r.output = r.stdout + r.stderr  # dry runs log to stdout, real runs to stderr
    return r


def write_config(workdir, **overrides):
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    cfg.update(overrides)
    (workdir / "config.yaml").write_text(yaml.safe_dump(cfg))
    return cfg


def test_lint_is_clean(tmp_path):
    r = subprocess.run([sys.executable, "-m", "snakemake", "--lint", "--snakefile", str(SNAKEFILE)],
                       capture_output=True, text=True, cwd=REPO, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Congratulations" in r.stdout + r.stderr


def test_paper_config_dry_run():
    """The repository's config.yaml: 5 functions at n = 16, one reduce per function."""
    r = run_smk(REPO, "--dry-run", "--quiet", "rules")
    assert r.returncode == 0, r.output
    counts = dict(line.split()[:2] for line in r.output.splitlines()
                  if len(line.split()) == 2 and line.split()[1].isdigit())
    # jobs may be fewer if results/ is partly built; the plan never has more than one reduce per function
    assert int(counts.get("reduce", 0)) <= 5


SCHEMA = REPO / "workflow" / "schemas" / "config.schema.yaml"


def validate(cfg):
    from snakemake.utils import validate as smk_validate

    smk_validate(cfg, str(SCHEMA))
    return cfg


@pytest.mark.parametrize("sweep", ["resolution.yaml", "criterion.yaml", "candidates.yaml"])
def test_sweep_configs_are_valid(sweep):
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    cfg.update(yaml.safe_load((REPO / "config" / sweep).read_text()))
    validate(cfg)
    assert sum(len(v) for v in cfg.values() if isinstance(v, list)) > 14  # a longer list than the paper's


def test_sweep_dry_run(tmp_path):
    """All three sweep files at once: 3 resolutions x 2 criteria x 2 candidate sets x 5 functions."""
    write_config(tmp_path)
    sweeps = [str(REPO / "config" / s) for s in ("resolution.yaml", "criterion.yaml", "candidates.yaml")]
    r = run_smk(tmp_path, "--dry-run", "--quiet", "rules", "--configfile", str(tmp_path / "config.yaml"), *sweeps)
    assert r.returncode == 0, r.output
    assert any(line.split() == ["reduce", "60"] for line in r.output.splitlines()), r.output
    assert any(line.split() == ["table1", "12"] for line in r.output.splitlines()), r.output


def test_schema_rejects_bad_value_naming_the_key(tmp_path):
    """What a user sees: snakemake stops before running anything and names the key."""
    write_config(tmp_path, fractions=[0.5, 1.5])
    r = run_smk(tmp_path, "--dry-run")
    assert r.returncode != 0
    assert "1.5 is greater than the maximum of 1" in r.output, r.output
    assert "On instance['fractions'][1]" in r.output, r.output


@pytest.mark.parametrize("key,value,message", [
    ("n", [1], "1 is less than the minimum of 2"),
    ("functions", [6], "6 is greater than the maximum of 5"),
    ("fractions", [0.0], "0.0 is less than or equal to the minimum of 0"),
    ("criterion", ["rmse"], "'rmse' is not one of ['rms', 'max', 'sse']"),
    ("n", 16, "16 is not of type 'array'"),
    ("tolerance", "ten", "'ten' is not of type 'number'"),
    ("fraction", [0.5], "Additional properties are not allowed ('fraction' was unexpected)"),
])
def test_schema_rejects(key, value, message):
    cfg = yaml.safe_load((REPO / "config.yaml").read_text())
    cfg[key] = value
    with pytest.raises(Exception) as exc:
        validate(cfg)
    text = str(exc.value) + str(getattr(exc.value, "__cause__", ""))
    assert message in text
    assert key in text


def test_schema_fills_defaults():
    cfg = validate({"functions": [1], "n": [4]})
    assert cfg["fractions"] == [0.5, 0.2, 0.1]
    assert cfg["criterion"] == ["rms"] and cfg["curvature"] == ["direct"]
    assert cfg["golden_table"] == "" and cfg["figures_3d"] is True
    paper = yaml.safe_load((REPO / "config.yaml").read_text())
    assert validate(dict(paper)) == paper  # config.yaml spells out every key


def test_slurm_profile_dry_run(tmp_path):
    write_config(tmp_path, functions=[1], n=[32])
    r = run_smk(tmp_path, "--dry-run", "--workflow-profile", str(REPO / "workflow" / "profiles" / "slurm"))
    assert r.returncode == 0, r.output
    blocks = {b.split(":")[0].strip(): b for b in r.output.split("rule ")[1:]}
    assert "mem_mb=1218" in blocks["reduce"] and "runtime=7" in blocks["reduce"], blocks["reduce"]  # scaled with n
    assert "mem_mb=4000" in blocks["slice_figure"] and "runtime=15" in blocks["slice_figure"]  # set-resources
    assert "disk_mb=1000" in blocks["sample"]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """The whole workflow on n = 4 with two functions, for real."""
    workdir = tmp_path_factory.mktemp("wf")
    write_config(workdir, functions=[2, 4], n=[4])
    r = run_smk(workdir)
    assert r.returncode == 0, r.output[-5000:]
    return workdir


def test_tiny_run_outputs(tiny_run):
    rep = tiny_run / "results" / "report"
    table = pd.read_csv(rep / "table1.csv")
    assert list(table.columns) == TABLE1_COLUMNS
    assert len(table) == 6 and set(table.function) == {2, 4}
    assert list(table.fraction[:3]) == [0.5, 0.2, 0.1]
    counts = table.n_selected.values[:3]
    assert (abs(counts - table.fraction.values[:3] * 125) <= 1).all() and counts[0] > counts[1] > counts[2]
    assert (table.published_E_rms > 0).all()
    md = (rep / "table1.md").read_text()
    assert "n = 4" in md and "| 50 % | 20 % | 10 % |" in md and "## Options used" in md
    for name in ("slices_f2.png", "slices_f4.png", "slices3d_f2.png", "slices3d_f4.png"):
        assert (rep / "figures" / name).stat().st_size > 10_000
    assert (rep / "erms_vs_fraction.png").stat().st_size > 10_000
    run = tiny_run / "results" / "runs" / "n4" / PRIMARY / "f4"
    assert {p.name for p in run.iterdir()} >= {"errors.csv", "result.json", "mesh_0.5.vtu", "mesh_0.2.vtu",
                                              "mesh_0.1.vtu"}
    for rule in ("sample", "reduce", "table1", "slice_figure", "slice_figure_3d", "publish"):
        assert (tiny_run / "results" / "logs" / rule).exists() or \
            (tiny_run / "results" / "logs" / f"{rule}.log").exists()
        assert (tiny_run / "results" / "benchmarks" / rule).exists() or \
            (tiny_run / "results" / "benchmarks" / f"{rule}.tsv").exists()


def test_tiny_run_is_up_to_date_and_report_builds(tiny_run):
    r = run_smk(tiny_run, "--dry-run")
    assert r.returncode == 0 and "Nothing to be done" in r.output, r.output
    r = run_smk(tiny_run, "--report", "report.html")
    assert r.returncode == 0, r.output
    html = (tiny_run / "report.html").read_text(errors="replace")
    assert "Figures 4-6" in html and "Table 1" in html


def test_golden_check_rule(tiny_run, tmp_path):
    """The golden_check rule passes on its own table and fails, naming the cell, on a perturbed one."""
    produced = tiny_run / "results" / "report" / "table1.csv"
    golden = tmp_path / "golden.csv"
    golden.write_bytes(produced.read_bytes())
    target = "results/report/golden_check.txt"
    r = run_smk(tiny_run, target, "--config", f"golden_table={golden}")
    assert r.returncode == 0, r.output
    assert "OK, all cells within tolerance" in (tiny_run / "results" / "report" / "golden_check.txt").read_text()
    df = pd.read_csv(golden)
    df.loc[(df.function == 4) & (df.fraction == 0.2), "E_rms_interior"] *= 1.01
    df.to_csv(golden, index=False)
    r = run_smk(tiny_run, target, "--forcerun", "golden_check", "--show-failed-logs",
                "--config", f"golden_table={golden}")
    assert r.returncode != 0
    assert "function=4, fraction=0.2" in r.output and "E_rms_interior" in r.output, r.output


def test_readme_rule_rewrites_the_marked_block(tiny_run):
    begin, end = "<!-- BEGIN table1: generated by `snakemake -c all readme` -->", "<!-- END table1 -->"
    (tiny_run / "README.md").write_text(f"# title\n\n{begin}\nstale\n{end}\n\nmore text\n")
    r = run_smk(tiny_run, "readme")
    assert r.returncode == 0, r.output
    text = (tiny_run / "README.md").read_text()
    assert "stale" not in text and text.startswith("# title\n") and text.endswith("\n\nmore text\n")
    assert "| Function | 50 % | 20 % | 10 % |" in text and "2. Quadratic polynomial" in text
    assert (tiny_run / "docs" / "fig4_saddle_slices.png").stat().st_size > 10_000
