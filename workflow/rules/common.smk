# Helpers shared by the rules: the sweep (variants), target lists, resources.
# No rules here (snakemake --lint: do not mix functions and rules in one file).

import hashlib
import importlib.util
import itertools
import re
from pathlib import Path

#: Reduction options in path order; each config key is a list (a sweep axis).
OPTION_KEYS = [
    "method",
    "criterion",
    "candidates",
    "tie_order",
    "boundary_diagonals",
    "vertices_in_error",
    "final_pass",
    "curvature",
    "seed",
]
#: Short names used in the variant directory name.
OPTION_SHORT = {
    "method": "method",
    "criterion": "crit",
    "candidates": "cand",
    "tie_order": "tie",
    "boundary_diagonals": "diag",
    "vertices_in_error": "verr",
    "final_pass": "final",
    "curvature": "curv",
    "seed": "seed",
}


def _tag_value(v):
    if isinstance(v, bool):
        return "yes" if v else "no"
    return str(v).replace("_", "-")


def variant_tag(options):
    """Directory name of one option combination, e.g. method~paper_crit~rms_..."""
    return "_".join(f"{OPTION_SHORT[k]}~{_tag_value(options[k])}" for k in OPTION_KEYS)


#: tag -> options dict, for every combination of the option lists (config order).
VARIANTS = {}
for _combo in itertools.product(*(config[k] for k in OPTION_KEYS)):
    _opts = dict(zip(OPTION_KEYS, _combo))
    VARIANTS[variant_tag(_opts)] = _opts

#: The primary run (first value of every list), shown in results/report/.
PRIMARY_VARIANT = variant_tag({k: config[k][0] for k in OPTION_KEYS})
PRIMARY_N = config["n"][0]
FUNCTIONS = list(config["functions"])
NS = list(config["n"])
FRACTIONS = sorted(set(float(f) for f in config["fractions"]), reverse=True)
FRACTION_LABELS = [f"{f:g}" for f in FRACTIONS]


wildcard_constraints:
    function="[1-5]",
    n="[0-9]+",
    variant="|".join(re.escape(t) for t in VARIANTS),
    fraction="[0-9.e-]+",


# --- code versions: Snakemake reruns a job when its params change, so each rule gets
# a hash of the trivsel modules it runs.  Editing the package then reruns exactly
# the affected jobs (the package is not a script, so Snakemake would not see it).
_PKG_DIR = Path(importlib.util.find_spec("trivsel").origin).parent
_NOT_CORE = {"figures.py", "report.py", "compare.py", "methods.py", "ablation.py"}


def source_hash(*names):
    """Short hash of the named trivsel modules; no names: the core (all but figures/report/compare)."""
    if names:
        files = [_PKG_DIR / name for name in names]
    else:
        files = sorted(p for p in _PKG_DIR.glob("*.py") if p.name not in _NOT_CORE)
    h = hashlib.sha256()
    for p in files:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


CODE_CORE = source_hash()
CODE_DATA = source_hash("data.py")
CODE_REPORT = source_hash("report.py", "data.py")
CODE_FIGURES = source_hash("figures.py", "report.py", "data.py", "triangulation.py")
CODE_METHODS = CODE_CORE + source_hash("methods.py")
CODE_METHODS_REPORT = source_hash("methods.py", "figures.py", "data.py")


def reduce_cli_args(options):
    """The trivsel reduce flags of one option combination."""
    args = [
        "--method", str(options["method"]),
        "--criterion", str(options["criterion"]),
        "--candidates", str(options["candidates"]),
        "--tie-order", str(options["tie_order"]),
        "--boundary-diagonals", str(options["boundary_diagonals"]),
        "--curvature", str(options["curvature"]),
        "--seed", str(options["seed"]),
    ]
    if not options["vertices_in_error"]:
        args.append("--no-vertices-in-error")
    if options["final_pass"]:
        args.append("--final-pass")
    return args


def kernel_markers(wildcards):
    """The two halves of `trivsel compile` for the method of the run's variant."""
    method = VARIANTS[wildcards.variant]["method"]
    return [f"results/kernels/{method}_part{part}.txt" for part in (0, 1)]


def run_dir(n, variant, function):
    return f"results/runs/n{n}/{variant}/f{function}"


def errors_csvs(wildcards):
    return [f"{run_dir(wildcards.n, wildcards.variant, f)}/errors.csv" for f in FUNCTIONS]


def result_jsons(wildcards):
    return [f"{run_dir(wildcards.n, wildcards.variant, f)}/result.json" for f in FUNCTIONS]


def all_runs():
    """(n, variant, function) of every reduction in the sweep."""
    return [(n, v, f) for n in NS for v in VARIANTS for f in FUNCTIONS]


def figure_names():
    names = ["slices"] + (["slices3d"] if config["figures_3d"] else [])
    return [f"{name}_f{f}.png" for name in names for f in FUNCTIONS]


def all_targets():
    targets = [
        "results/report/table1.csv",
        "results/report/table1.md",
        "results/report/errors_all.csv",
        "results/report/erms_vs_fraction.png",
    ]
    targets += [f"results/report/figures/{name}" for name in figure_names()]
    for n in NS:
        for v in VARIANTS:
            targets.append(f"results/runs/n{n}/{v}/table1.csv")
            targets += [f"results/runs/n{n}/{v}/figures/{name}" for name in figure_names()]
    if config["golden_table"]:
        targets.append("results/report/golden_check.txt")
    if config["methods"]:
        targets += methods_targets()
    return targets


# --- resources: grow with the number of grid points (n+1)^3.  Measured for one
# reduction on this project's machine: n = 16 (4913 points) 3 s and 0.2 GB,
# n = 32 (35937 points) 33 s and 0.38 GB; time grows about as points^1.2.
def _points(wildcards):
    return (int(wildcards.n) + 1) ** 3


def reduce_mem_mb(wildcards, attempt):
    return int(500 + 0.02 * _points(wildcards)) * attempt


def reduce_runtime(wildcards, attempt):
    """Minutes, with a wide margin: 5 for n <= 32, about 50 for n = 64."""
    return int(5 + 2 * (_points(wildcards) / 35937) ** 1.5) * attempt


def figure_mem_mb(wildcards, attempt):
    return int(1500 + 0.02 * _points(wildcards)) * attempt


# --- stage "methods" (workflow/rules/methods.smk; on with `methods: true`): every method at
# matched counts, at the Table-1 fractions and the sweep methods_fractions.
METHODS_FRACTIONS = sorted(set(FRACTIONS) | set(float(f) for f in config["methods_fractions"]), reverse=True)


def methods_targets():
    targets = ["results/report/methods.csv", "results/report/methods.md"]
    targets += [f"results/report/figures/methods_f{f}_n{n}.png" for n in NS for f in FUNCTIONS]
    return targets


# Measured on this project's machine for n = 16 (4913 points), every method at 6 counts:
# 10-16 s and 0.30-0.35 GB (max RSS) per job.
def methods_mem_mb(wildcards, attempt):
    return int(1000 + 0.05 * _points(wildcards)) * attempt


def methods_runtime(wildcards, attempt):
    """Minutes: about ten reductions' worth (three trivsel runs, 5 VTK runs per count)."""
    return int(10 + 10 * (_points(wildcards) / 35937) ** 1.5) * attempt
