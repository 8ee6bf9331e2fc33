"""The Snakemake workflow: lint, config schema, dry runs of the sweeps and the SLURM
profile, and a real run on a tiny configuration (n = 4, two functions) in a
temporary directory, through a subprocess as a user would run it."""

from __future__ import annotations

import copy
import json
import math
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml
from conftest import SLURM_STATUS_CHECKS, sacct_rows

from trivsel.methods import METHODS
from trivsel.options import Options, config_schema, option_fields, variant_tag
from trivsel.study.report import TABLE1_COLUMNS

REPO = Path(__file__).resolve().parents[1]
SNAKEFILE = REPO / "Snakefile"
PRIMARY = "default"  # the paper's options are the defaults of trivsel.Options


def run_smk(workdir, *args, timeout=300):
    cmd = [sys.executable, "-m", "snakemake", "--snakefile", str(SNAKEFILE), "--directory", str(workdir),
           "--cores", "2", *args]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    r.output = r.stdout + r.stderr  # dry runs log to stdout, real runs to stderr
    return r


def merged(cfg, overrides):
    """cfg with the nested overrides merged in, as Snakemake merges --configfile files."""
    out = copy.deepcopy(cfg)
    for k, v in overrides.items():
        out[k] = merged(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def paper_config():
    return yaml.safe_load((REPO / "config.yaml").read_text())


def write_config(workdir, overrides=None):
    """config.yaml of the repository with the nested overrides, written to workdir."""
    cfg = merged(paper_config(), overrides or {})
    (workdir / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    return cfg


def planned(output, rule):
    """How many jobs of a rule a dry run (-q rules) plans."""
    for line in output.splitlines():
        if line.split()[:1] == [rule] and len(line.split()) == 2 and line.split()[1].isdigit():
            return int(line.split()[1])
    return 0


@pytest.mark.slow
def test_lint_is_clean(tmp_path):
    r = subprocess.run([sys.executable, "-m", "snakemake", "--lint", "--snakefile", str(SNAKEFILE)],
                       capture_output=True, text=True, cwd=REPO, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Congratulations" in r.stdout + r.stderr


@pytest.mark.slow
def test_paper_config_dry_run(tmp_path):
    """The repository's config.yaml: 5 functions at n = 16, one reduce per function, in
    results/runs/n16/default/; the kernels in two halves, then the drivers."""
    write_config(tmp_path)
    r = run_smk(tmp_path, "--dry-run")
    assert r.returncode == 0, r.output
    assert planned(r.output, "reduce") == 5 and planned(r.output, "table1") == 1, r.output
    assert planned(r.output, "kernels") == 2 and planned(r.output, "kernels_driver") == 1, r.output
    assert "results/runs/n16/default/f5/errors.csv" in r.output
    blocks = {b.split("\n")[0].strip(): b for b in r.output.split("rule ")[1:]}
    driver = blocks["kernels_driver:"]
    assert "input: results/kernels/paper_part0.txt, results/kernels/paper_part1.txt" in driver, driver
    assert "output: results/kernels/paper_part2.txt" in driver
    assert "input: results/kernels/paper_part2.txt" in blocks["reduce:"]


SCHEMA = REPO / "workflow" / "schemas" / "config.schema.yaml"


def validate(cfg):
    from snakemake.utils import validate as smk_validate

    smk_validate(cfg, str(SCHEMA))
    return cfg


def list_lengths(cfg):
    return sum(list_lengths(v) if isinstance(v, dict) else len(v) if isinstance(v, list) else 0
               for v in cfg.values())


@pytest.mark.parametrize("sweep", ["resolution.yaml", "criterion.yaml", "candidates.yaml"])
def test_sweep_configs_are_valid(sweep):
    paper = paper_config()
    cfg = merged(paper, yaml.safe_load((REPO / "config" / sweep).read_text()))
    validate(cfg)
    assert list_lengths(cfg) > list_lengths(validate(paper_config()))  # a longer list than the paper's


@pytest.mark.parametrize("stage", ["methods.yaml", "ablation.yaml", "scale.yaml", "realdata.yaml"])
def test_stage_configs_are_valid(stage):
    extra = yaml.safe_load((REPO / "config" / stage).read_text())
    cfg = validate(merged(paper_config(), extra))
    assert cfg[stage.removesuffix(".yaml")]["activate"] is True


@pytest.mark.slow
def test_sweep_dry_run(tmp_path):
    """All three sweep files at once: 3 resolutions x 2 criteria x 2 candidate sets x 5 functions.
    With the paper's fractions they stop when the workflow loads: 50 % of the 9^3 grid is more than
    the 8 corners and 7^3 interior points that `candidates: interior` can select at n = 8."""
    write_config(tmp_path)
    sweeps = [str(REPO / "config" / s) for s in ("resolution.yaml", "criterion.yaml", "candidates.yaml")]
    r = run_smk(tmp_path, "--dry-run", "--quiet", "rules", "--configfile", str(tmp_path / "config.yaml"), *sweeps)
    assert r.returncode != 0 and "Building DAG of jobs" not in r.output, r.output
    assert "config reduce: fractions: 0.5 selects 365 of the 729 points of n = 8, more than the 351" in r.output
    (tmp_path / "fractions.yaml").write_text("reduce: {fractions: [0.45, 0.2, 0.1]}\n")
    r = run_smk(tmp_path, "--dry-run", "--quiet", "rules", "--configfile", str(tmp_path / "config.yaml"), *sweeps,
                str(tmp_path / "fractions.yaml"))
    assert r.returncode == 0, r.output
    assert planned(r.output, "reduce") == 60 and planned(r.output, "table1") == 12, r.output


@pytest.mark.slow
def test_sweep_of_a_non_path_option(tmp_path):
    """Any Options field is a sweep axis: max_flips x swap_memory gives four variant folders
    named by variant_tag, each reduced with the flags of Options.cli_args()."""
    write_config(tmp_path, {"data": {"functions": [1], "n": [4]}, "reduce": {"fractions": [0.5], "options": {
        "max_flips": [0, 3], "swap_memory": ["run", "call"]}}})
    r = run_smk(tmp_path, "--dry-run")
    assert r.returncode == 0, r.output
    # max_flips 0 is the paper method's default, so that combination is the default variant
    combos = {"default": {}, "maxflips~3": {"max_flips": 3}, "mem~call": {"swap_memory": "call"},
              "maxflips~3_mem~call": {"max_flips": 3, "swap_memory": "call"}}
    assert planned(r.output, "reduce") == 4, r.output
    tags = {}
    for tag, combo in combos.items():
        assert variant_tag(Options(**combo)) == tag
        tags[tag] = Options(**combo).cli_args()
        assert f"results/runs/n4/{tag}/f1/errors.csv" in r.output, r.output
    assert tags["maxflips~3_mem~call"] == ["--max-flips", "3", "--swap-memory", "call"]
    # the flags: run the two max_flips variants for real (n = 4, one fraction); the kernel markers
    # are stood in for, the reductions load or compile their kernels themselves
    kernels = tmp_path / "results" / "kernels"
    kernels.mkdir(parents=True)
    for part in (0, 1, 2):
        (kernels / f"paper_part{part}.txt").write_text("stand-in\n")
    targets = [f"results/runs/n4/{tag}/f1/errors.csv" for tag in ("default", "maxflips~3")]
    r = run_smk(tmp_path, *targets)
    assert r.returncode == 0, r.output[-3000:]
    for tag in ("default", "maxflips~3"):
        log = (tmp_path / "results" / "logs" / "reduce" / "n4" / tag / "f1.log").read_text()
        command = log.splitlines()[0]
        assert command.startswith("$ trivsel reduce --function 1 --n 4 --fractions 0.5 "), command
        assert command.endswith(" ".join(["--threads", "1", *tags[tag]])), command
        result = json.loads((tmp_path / "results" / "runs" / "n4" / tag / "f1" / "result.json").read_text())
        assert result["options"]["max_flips"] in ((0, None) if tag == "default" else (3,)), result["options"]


@pytest.mark.slow
def test_a_method_sweep_gives_each_method_only_its_own_options(tmp_path):
    """method x curvature x seed: the paper method runs every combination, greedy (to which
    neither applies) runs once, with no curvature or seed in its folder name or flags."""
    write_config(tmp_path, {"data": {"functions": [1], "n": [4]}, "reduce": {"fractions": [0.5], "options": {
        "method": ["paper", "greedy"], "criterion": [None], "curvature": ["direct", "local-frame"],
        "seed": [0, 1]}}})
    r = run_smk(tmp_path, "--dry-run")
    assert r.returncode == 0, r.output
    assert planned(r.output, "reduce") == 5, r.output
    for tag in ("default", "curv~local-frame", "seed~1", "curv~local-frame_seed~1", "method~greedy"):
        assert f"results/runs/n4/{tag}/f1/errors.csv" in r.output, (tag, r.output)
    assert "method~greedy_curv" not in r.output and "method~greedy_seed" not in r.output


def test_schema_rejects_bad_value_naming_the_key(tmp_path):
    """What a user sees: snakemake stops before running anything and names the key."""
    write_config(tmp_path, {"reduce": {"fractions": [0.5, 1.5]}})
    r = run_smk(tmp_path, "--dry-run")
    assert r.returncode != 0
    assert "1.5 is greater than the maximum of 1" in r.output, r.output
    assert "On instance['reduce']['fractions'][1]" in r.output, r.output


@pytest.mark.parametrize("options,message", [
    ({"methd": ["paper"]}, "Additional properties are not allowed ('methd' was unexpected)"),
    ({"method": ["papr"]}, f"'papr' is not one of {list(METHODS)}"),
])
@pytest.mark.slow
def test_bad_option_fails_at_validation(tmp_path, options, message):
    """A misspelt option key or an unknown method stops the workflow at validation, before
    any job (nothing is planned or run), with the schema's message naming the value."""
    write_config(tmp_path, {"reduce": {"options": options}})
    r = run_smk(tmp_path, "--dry-run")
    assert r.returncode != 0
    assert "Error validating config file." in r.output and message in r.output, r.output
    assert "Building DAG of jobs" not in r.output and not (tmp_path / "results").exists()


@pytest.mark.parametrize("overrides,message", [
    # JSON Schema counts 16.0 as an integer: common.smk checks the ints itself
    ({"data": {"n": [16.0]}}, "config data: n: 16.0 is not an integer (write e.g. 16, not 16.0)"),
    # a value the schema lets through but trivsel.Options does not: its one-line InputError
    ({"reduce": {"options": {"rel_tol": [math.nan]}}}, "config reduce: options: rel_tol must be finite, got nan"),
])
@pytest.mark.slow
def test_bad_value_fails_when_the_workflow_loads(tmp_path, overrides, message):
    write_config(tmp_path, overrides)
    r = run_smk(tmp_path, "--dry-run")
    assert r.returncode != 0
    assert message in r.output, r.output
    assert "Building DAG of jobs" not in r.output


@pytest.mark.parametrize("path,value,message", [
    (("data", "n"), [1], "1 is less than the minimum of 2"),
    (("data", "functions"), [6], "6 is greater than the maximum of 5"),
    (("reduce", "fractions"), [0.0], "0.0 is less than or equal to the minimum of 0"),
    (("reduce", "options", "criterion"), ["rmse"], "'rmse' is not valid under any of the given schemas"),
    (("reduce", "options", "tie_order"), "index", "'index' is not of type 'array'"),
    (("reduce", "options", "max_flips"), [-1], "-1 is not valid under any of the given schemas"),
    (("data", "n"), 16, "16 is not of type 'array'"),
    (("report", "tolerance"), "ten", "'ten' is not of type 'number'"),
    (("reduce", "fraction"), [0.5], "Additional properties are not allowed ('fraction' was unexpected)"),
    (("fractions",), [0.5], "Additional properties are not allowed ('fractions' was unexpected)"),
    (("methods", "vtk_runs"), 0, "0 is less than the minimum of 1"),
    (("scale", "methods"), ["vtkk"], "'vtkk' is not one of ['paper', 'greedy', 'vtk']"),
    (("scale", "fraction"), 1.0, "1.0 is greater than or equal to the maximum of 1"),
    (("golden", "rtol"), -1, "-1 is less than the minimum of 0"),
    (("ablation", "activate"), "yes", "'yes' is not of type 'boolean'"),
])
def test_schema_rejects(path, value, message):
    cfg = paper_config()
    node = cfg
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(Exception) as exc:
        validate(cfg)
    text = str(exc.value) + str(getattr(exc.value, "__cause__", ""))
    assert message in text
    assert path[-1] in text


def test_schema_fills_defaults():
    cfg = validate({"data": {"functions": [1], "n": [4]}})
    assert cfg["reduce"]["fractions"] == [0.5, 0.2, 0.1]
    assert cfg["golden"] == {"table": "", "rtol": 1e-6, "atol": 0.0} and cfg["report"]["figures_3d"] is True
    assert cfg["methods"]["activate"] is False and cfg["scale"]["n"] == [16, 32, 64, 128]
    assert cfg["realdata"]["activate"] is False and cfg["realdata"]["fractions"] == [0.1, 0.05]
    assert cfg["reduce"]["options"] == {}  # omitted options take the defaults of trivsel.Options
    paper = paper_config()
    assert validate(copy.deepcopy(paper)) == paper  # config.yaml spells out every section


def test_every_option_is_in_the_schema():
    """The generated options schema is up to date, has every Options field as a list, and is
    the config schema's reduce: options: (by $ref); the paper's config is the default variant."""
    fields = [f.name for f in option_fields()]
    generated = json.loads((REPO / "workflow" / "schemas" / "options.schema.json").read_text())
    assert generated == config_schema()
    assert list(generated["properties"]) == fields
    assert all(p["type"] == "array" for p in generated["properties"].values())
    schema = yaml.safe_load(SCHEMA.read_text())
    assert schema["properties"]["reduce"]["properties"]["options"]["$ref"] == "options.schema.json"
    options = paper_config()["reduce"]["options"]
    assert set(options) <= set(fields)
    for name in fields:  # each field validates as a one-value sweep of its default
        cfg = paper_config()
        f = next(f for f in option_fields() if f.name == name)
        cfg["reduce"]["options"][name] = [list(f.default) if isinstance(f.default, tuple) else f.default]
        validate(cfg)


@pytest.mark.slow
def test_slurm_profile_dry_run(tmp_path):
    write_config(tmp_path, {"data": {"functions": [1], "n": [32]}})
    r = run_smk(tmp_path, "--dry-run", "--workflow-profile", str(REPO / "workflow" / "profiles" / "slurm"))
    assert r.returncode == 0, r.output
    blocks = {b.split(":")[0].strip(): b for b in r.output.split("rule ")[1:]}
    assert "mem_mb=1218" in blocks["reduce"] and "runtime=7" in blocks["reduce"], blocks["reduce"]  # scaled with n
    assert "mem_mb=4000" in blocks["slice_figure"] and "runtime=15" in blocks["slice_figure"]  # set-resources
    assert "disk_mb=1000" in blocks["sample"]


REALDATA_TARGETS = ["results/report/realdata.md", "results/report/realdata.csv"]


@pytest.mark.slow
def test_realdata_stage_dry_run(tmp_path):
    """config/realdata.yaml adds one run and one figure per volume and the table; without it no
    realdata job is planned."""
    write_config(tmp_path)
    r = run_smk(tmp_path, "--dry-run", "--quiet", "rules")
    assert r.returncode == 0, r.output
    assert planned(r.output, "realdata_run") == 0 and planned(r.output, "realdata_table") == 0, r.output
    r = run_smk(tmp_path, "--dry-run", "--quiet", "rules", "--configfile", str(tmp_path / "config.yaml"),
                str(REPO / "config" / "realdata.yaml"))
    assert r.returncode == 0, r.output
    assert planned(r.output, "realdata_run") == 5 and planned(r.output, "realdata_figure") == 5, r.output
    assert planned(r.output, "realdata_table") == 1, r.output


def test_realdata_schema_rejects_an_unknown_volume():
    cfg = merged(paper_config(), {"realdata": {"activate": True, "volumes": ["chirp", "brain"]}})
    with pytest.raises(Exception, match="'brain' is not one of"):
        validate(cfg)


@pytest.mark.slow
def test_realdata_stage_quick_for_real(tmp_path):
    """The stage on 16^3 crops of the synthetic volumes at one fraction, one VTK run per setting."""
    volumes = ["chirp", "steps"]
    write_config(tmp_path, {"realdata": {"activate": True, "volumes": volumes, "fractions": [0.1],
                                         "curve_fractions": [0.1], "repeats": 1, "quick": True}})
    figures = [f"results/report/figures/realdata_{v}.png" for v in volumes]
    r = run_smk(tmp_path, *REALDATA_TARGETS, *figures)
    assert r.returncode == 0, r.output[-5000:]
    methods = ["decimate", "greedy", "paper"]
    check = pd.read_csv(tmp_path / "results" / "report" / "realdata.csv")
    assert list(check.method) == methods * 2 and list(check.volume) == ["chirp"] * 3 + ["steps"] * 3
    assert set(check["all"]) <= {"pass", "fail"} and set(check.ratio_le_1.fillna("n/a")) <= {"pass", "fail", "n/a"}
    md = (tmp_path / "results" / "report" / "realdata.md").read_text()
    assert "## Targets" in md and "| steps | 10 % |" in md and "![chirp](figures/realdata_chirp.png)" in md
    for v in volumes:
        rows = pd.read_csv(tmp_path / "results" / "realdata" / f"{v}.csv")
        assert len(rows) == 1
        assert rows.loc[0, "shape"] == "16x16x16" and all(f"{m}_fit_E_rms" in rows for m in methods)
        curves = pd.read_csv(tmp_path / "results" / "realdata" / f"{v}_curves.csv")
        assert set(curves.method) == {*methods, "vtk"} and len(curves) == 2 * (len(methods) + 1)
        assert (tmp_path / f"results/report/figures/realdata_{v}.png").stat().st_size > 10_000
        for name in (f"realdata_run/{v}", f"realdata_figure/{v}"):
            assert (tmp_path / "results" / "logs" / f"{name}.log").exists()
            assert (tmp_path / "results" / "benchmarks" / f"{name}.tsv").exists()


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """The whole workflow on n = 4 with two functions, for real."""
    workdir = tmp_path_factory.mktemp("wf")
    write_config(workdir, {"data": {"functions": [2, 4], "n": [4]}})
    r = run_smk(workdir)
    assert r.returncode == 0, r.output[-5000:]
    return workdir


@pytest.mark.slow
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
    assert {p.name for p in (tiny_run / "results" / "kernels").iterdir()} == {
        "paper_part0.txt", "paper_part1.txt", "paper_part2.txt"}
    for rule in ("kernels", "sample", "reduce", "table1", "slice_figure", "slice_figure_3d", "publish"):
        assert (tiny_run / "results" / "logs" / rule).exists() or \
            (tiny_run / "results" / "logs" / f"{rule}.log").exists()
        assert (tiny_run / "results" / "benchmarks" / rule).exists() or \
            (tiny_run / "results" / "benchmarks" / f"{rule}.tsv").exists()


@pytest.mark.slow
def test_tiny_run_is_up_to_date_and_report_builds(tiny_run):
    r = run_smk(tiny_run, "--dry-run")
    assert r.returncode == 0 and "Nothing to be done" in r.output, r.output
    r = run_smk(tiny_run, "--report", "report.html")
    assert r.returncode == 0, r.output
    html = (tiny_run / "report.html").read_text(errors="replace")
    assert "Figures 4-6" in html and "Table 1" in html


@pytest.mark.slow
def test_golden_check_rule(tiny_run, tmp_path):
    """The golden_check rule passes on its own table and fails, naming the cell, on a perturbed one."""
    produced = tiny_run / "results" / "report" / "table1.csv"
    golden = tmp_path / "golden.csv"
    golden.write_bytes(produced.read_bytes())
    target = "results/report/golden_check.txt"
    r = run_smk(tiny_run, target, "--config", f"golden={{table: {golden}}}")
    assert r.returncode == 0, r.output
    assert "OK, all cells within tolerance" in (tiny_run / "results" / "report" / "golden_check.txt").read_text()
    df = pd.read_csv(golden)
    df.loc[(df.function == 4) & (df.fraction == 0.2), "E_rms_interior"] *= 1.01
    df.to_csv(golden, index=False)
    r = run_smk(tiny_run, target, "--forcerun", "golden_check", "--show-failed-logs",
                "--config", f"golden={{table: {golden}}}")
    assert r.returncode != 0
    assert "function=4, fraction=0.2" in r.output and "E_rms_interior" in r.output, r.output


@pytest.mark.slow
def test_readme_rule_rewrites_the_marked_block(tiny_run):
    begin, end = "<!-- BEGIN table1: generated by `snakemake -c all readme` -->", "<!-- END table1 -->"
    (tiny_run / "README.md").write_text(f"# title\n\n{begin}\nstale\n{end}\n\nmore text\n")
    r = run_smk(tiny_run, "readme")
    assert r.returncode == 0, r.output
    text = (tiny_run / "README.md").read_text()
    assert "stale" not in text and text.startswith("# title\n") and text.endswith("\n\nmore text\n")
    assert "| Function | 50 % | 20 % | 10 % |" in text and "2. Quadratic polynomial" in text
    figure, table = tiny_run / "docs" / "fig4_saddle_slices.png", tiny_run / "docs" / "table1.md"
    assert figure.stat().st_size > 10_000
    # docs/ holds only what a rerun reproduces: no run times, and the figure rewritten only when its
    # pixels change (a rerun's report differs in its times, and a PNG encoder may differ in its bytes)
    report = tiny_run / "results" / "report"
    assert "## Run times" in (report / "table1.md").read_text() and "## Run times" not in table.read_text()
    before = {p: p.read_bytes() for p in (figure, table)}
    (report / "table1.md").write_text((report / "table1.md").read_text().replace("| total |", "| total | 99.99 "))
    from PIL import Image

    with Image.open(report / "figures" / "slices_f2.png") as im:
        im.load()
        im.save(report / "figures" / "slices_f2.png", compress_level=9)
    r = run_smk(tiny_run, "readme", "--forcerun", "readme")
    assert r.returncode == 0, r.output
    assert {p: p.read_bytes() for p in (figure, table)} == before


@pytest.mark.parametrize("overrides,messages", [
    # schema (options.schema.json, generated from trivsel.Options): choices and bounds
    ({"reduce": {"options": {"method": ["foo"]}}},
     [f"'foo' is not one of {list(METHODS)}", "On instance['reduce']['options']['method'][0]"]),
    ({"reduce": {"options": {"curvature": ["foo"]}}},
     ["'foo' is not one of ['direct', 'local-frame']", "On instance['reduce']['options']['curvature'][0]"]),
    ({"reduce": {"options": {"seed": [-1]}}},
     ["-1 is less than the minimum of 0", "On instance['reduce']['options']['seed'][0]"]),
    ({"reduce": {"options": {"rel_tol": [-1e-3]}}},
     ["-0.001 is less than the minimum of 0.0", "On instance['reduce']['options']['rel_tol'][0]"]),
    ({"reduce": {"options": {"max_flips": [-2]}}},
     ["-2 is not valid under any of the given schemas", "On instance['reduce']['options']['max_flips'][0]"]),
    # what JSON Schema cannot say, checked when common.smk builds every trivsel.Options
    ({"reduce": {"options": {"rel_tol": [math.inf]}}}, ["config reduce: options: rel_tol must be finite, got inf"]),
    ({"reduce": {"options": {"quantum": [math.nan]}}}, ["config reduce: options: quantum must be finite, got nan"]),
    ({"reduce": {"options": {"seed": [2.0]}}}, ["config reduce: options: seed must be an integer, got 2.0"]),
    ({"data": {"n": [16.0]}}, ["config data: n: 16.0 is not an integer (write e.g. 16, not 16.0)"]),
    # fractions against the grid: at least the 8 fixed corners, at most the selectable points
    ({"reduce": {"fractions": [1e-9]}},
     ["config reduce: fractions: 1e-09 selects 0 of the 4913 points of n = 16, fewer than the 8 fixed corner "
      "points of the box: the smallest fraction for n = 16 is 0.00163 (8 / 4913)"]),
    ({"data": {"n": [16, 4]}, "reduce": {"fractions": [0.5, 0.05]}},
     ["config reduce: fractions: 0.05 selects 6 of the 125 points of n = 4", "smallest fraction for n = 4 is 0.064"]),
    ({"data": {"n": [4]}, "reduce": {"options": {"candidates": ["all", "interior"]}}},
     ["config reduce: fractions: 0.5 selects 63 of the 125 points of n = 4, more than the 35 selectable with "
      "candidates: interior", "the largest fraction for n = 4 is 0.283"]),
    ({"methods": {"activate": True}, "data": {"n": [4]}},
     ["config methods: fractions: 0.05 selects 6 of the 125 points of n = 4"]),
    # an option that applies to none of the swept methods, and a criterion decimate cannot take
    ({"reduce": {"options": {"greedy_key": ["max", "sse"]}}},
     ["config reduce: options: greedy_key: 'sse' applies to greedy only, not to the swept method(s) paper"]),
    ({"reduce": {"options": {"method": ["decimate"], "criterion": [None], "max_flips": [3]}}},
     ["config reduce: options: max_flips: 3 applies to paper and greedy only, not to the swept method(s) "
      "decimate"]),
    ({"reduce": {"options": {"method": ["paper", "decimate"]}}},
     ["config reduce: options: method 'decimate' orders collapses by criterion 'sse' (E_RMS) or 'max' (E_inf), "
      "got 'rms'"]),
])
@pytest.mark.slow
def test_bad_config_fails_before_any_job(tmp_path, overrides, messages):
    """Every bad value stops `snakemake -n` while the workflow loads, before the DAG is built
    (no job, no missing kernel markers), with a message naming the key and the value."""
    write_config(tmp_path, overrides)
    r = run_smk(tmp_path, "--dry-run")
    assert r.returncode != 0
    for message in messages:
        assert message in r.output, r.output
    assert "Building DAG of jobs" not in r.output and "MissingInputException" not in r.output, r.output
    assert not (tmp_path / "results").exists()


@pytest.mark.parametrize("overrides,message", [
    # JSON Schema lets NaN through any bound (every comparison with NaN is false) and inf through
    # a key bounded on one side only: common.smk checks every number finite
    ({"reduce": {"fractions": [0.5, math.nan]}}, "config reduce: fractions: nan must be a finite number in (0, 1]"),
    ({"report": {"tolerance": math.nan}}, "config report: tolerance: nan must be a finite number in (0, 1]"),
    ({"golden": {"rtol": math.inf}}, "config golden: rtol: inf must be a finite number >= 0"),
    ({"golden": {"atol": math.nan}}, "config golden: atol: nan must be a finite number >= 0"),
    # a stage that is off is checked too
    ({"methods": {"fractions": [math.nan]}}, "config methods: fractions: nan must be a finite number in (0, 1]"),
    ({"scale": {"fraction": math.nan}}, "config scale: fraction: nan must be a finite number in (0, 1)"),
    ({"realdata": {"curve_fractions": [0.1, math.nan]}},
     "config realdata: curve_fractions: nan must be a finite number in (0, 1)"),
    # ablation variant names (trivsel.study.ablation.parse_variant), whether the stage is on or not
    ({"ablation": {"activate": True, "variants": ["bogus"]}},
     "config ablation: variants: bad variant part 'bogus' in 'bogus': expected choice=value"),
    ({"ablation": {"activate": True, "variants": ["criterion=bogus"]}},
     "config ablation: variants: unknown value 'bogus' for 'criterion' in 'criterion=bogus'"),
    ({"ablation": {"variants": ["singles", "criterion=bogus"]}},
     "config ablation: variants: unknown value 'bogus' for 'criterion' in 'criterion=bogus'"),
    # the golden table must be an existing file
    ({"golden": {"table": "no/such/golden.csv"}},
     "config golden: table: 'no/such/golden.csv' is not an existing file"),
])
def test_bad_config_value_stops_the_load_in_one_line(tmp_path, overrides, message):
    """A value the schema lets through stops `snakemake -n` while the workflow loads, before
    the DAG is built, with the workflow's one-line message naming the key and the value (a
    WorkflowError, as the other load-time checks), not an exception from the code using it."""
    write_config(tmp_path, overrides)
    r = run_smk(tmp_path, "--dry-run", timeout=120)
    assert r.returncode != 0
    assert "WorkflowError" in r.output and message in r.output, r.output
    assert "ValueError" not in r.output and "Building DAG of jobs" not in r.output, r.output
    assert not (tmp_path / "results").exists()


def test_golden_table_must_be_a_file(tmp_path):
    """A folder as the golden table is refused when the workflow loads; the reproduction's
    relative golden path (.ci/run, --config) plans the golden_check job."""
    write_config(tmp_path, {"data": {"functions": [1], "n": [4]}})
    (tmp_path / "golden").mkdir()
    r = run_smk(tmp_path, "--dry-run", "--config", "golden={table: golden}", timeout=120)
    assert r.returncode != 0
    assert "config golden: table: 'golden' is a folder" in r.output, r.output
    assert "Building DAG of jobs" not in r.output, r.output
    (tmp_path / "tests" / "golden").mkdir(parents=True)
    golden = REPO / "tests" / "golden" / "table1.csv"
    (tmp_path / "tests" / "golden" / "table1.csv").write_bytes(golden.read_bytes())
    r = run_smk(tmp_path, "--dry-run", "--quiet", "rules", "--config", "golden={table: tests/golden/table1.csv}",
                timeout=120)
    assert r.returncode == 0, r.output
    assert planned(r.output, "golden_check") == 1, r.output


@pytest.mark.slow
def test_smallest_fraction_in_the_message_is_accepted(tmp_path):
    """The smallest fraction the message names selects exactly the 8 corners, and the workflow takes it."""
    write_config(tmp_path, {"data": {"functions": [1], "n": [4]}, "reduce": {"fractions": [0.5, 0.064]}})
    r = run_smk(tmp_path, "--dry-run", "--quiet", "rules")
    assert r.returncode == 0, r.output
    assert planned(r.output, "reduce") == 1, r.output


@pytest.mark.slurm
def test_slurm_run_matches_local_run(tmp_path, slurm):
    """Two reductions (n = 4, functions 2 and 4) through `--executor slurm` and the unchanged
    workflow profile: every job goes through sbatch (its SLURM job id in Snakemake's log), sacct
    lists each one as COMPLETED under the run's job name, and the errors.csv files are
    byte-identical to those of a local `-c 2` run of the same configuration."""
    import re

    overrides = {"data": {"functions": [2, 4], "n": [4]}}
    targets = [f"results/runs/n4/{PRIMARY}/f{f}/errors.csv" for f in (2, 4)]
    local, cluster = tmp_path / "local", tmp_path / "slurm"
    for workdir in (local, cluster):
        workdir.mkdir()
        write_config(workdir, overrides)
    profile = REPO / "workflow" / "profiles" / "slurm"
    r = run_smk(cluster, *targets, "--executor", "slurm", "--workflow-profile", str(profile), "--jobs", "4",
                *SLURM_STATUS_CHECKS, timeout=900)
    assert r.returncode == 0, r.output[-5000:]
    submitted = dict(re.findall(r"Job (\d+) has been submitted with SLURM jobid (\d+)", r.output))
    remote_rules = re.findall(r"^rule (\w+):$", r.output, flags=re.M)  # jobs run as cluster jobs
    assert submitted and len(submitted) == len(remote_rules), r.output[-5000:]
    assert {"kernels", "kernels_driver", "reduce"} <= set(remote_rules), remote_rules
    assert "localrule" not in r.output, r.output[-5000:]  # nothing of these targets runs on the host

    ids = sorted(submitted.values(), key=int)
    fields = ["JobID", "JobName", "Comment", "State", "ExitCode", "Partition", "Account", "Elapsed"]
    rows = sacct_rows(ids, fields)
    print("\n".join(["|".join(fields)] + ["|".join(rows[i][f] for f in fields) for i in ids if i in rows]))
    assert set(rows) == set(ids), (ids, rows)
    assert all(row["State"] == "COMPLETED" and row["ExitCode"] == "0:0" for row in rows.values()), rows
    assert len({row["JobName"] for row in rows.values()}) == 1  # the run's UUID, by which the plugin polls sacct
    comments = sorted(row["Comment"].removeprefix("rule_").split("_wildcards")[0] for row in rows.values())
    if any(comments):  # the rule names, when the SLURM stores job comments (the local one does)
        assert comments == sorted(remote_rules), comments

    r = run_smk(local, *targets)
    assert r.returncode == 0, r.output[-5000:]
    for target in targets:
        assert (cluster / target).read_bytes() == (local / target).read_bytes(), target
