# Helpers shared by the rules: the checked configuration, the sweep (variants), target
# lists, code hashes, resources.
# No rules here (snakemake --lint: do not mix functions and rules in one file).

import dataclasses
import hashlib
import importlib.util
import itertools
import math
import numbers
import re
from pathlib import Path

import yaml
from snakemake.exceptions import WorkflowError

from trivsel.exceptions import InputError
from trivsel.methods import get_method
from trivsel.options import Options, applies, config_schema, method_group, option_fields, variant_tag
from trivsel.selection import count_for_fraction


# --- checks the schema cannot make.  JSON Schema compares a number with its bounds, and every
# comparison with NaN is false, so `.nan` passes any minimum and maximum, and `.inf` passes a key
# bounded on one side only (golden: rtol, atol).  So every number of the config is checked
# finite here, before any code below uses it, and the message gives the key's range from the
# schema.  `reduce: options:` is left to trivsel.Options (build_variants), which refuses a
# non-finite option with its own one-line message.
_CONFIG_SCHEMA = yaml.safe_load(Path(workflow.basedir, "workflow", "schemas", "config.schema.yaml").read_text())


def _range_text(schema):
    """The schema's bounds of a number as text: " in (0, 1]", " >= 0", or "" (no bounds)."""
    lo = ("(", ">", schema.get("exclusiveMinimum")) if "exclusiveMinimum" in schema else \
        ("[", ">=", schema.get("minimum"))
    hi = (")", "<", schema.get("exclusiveMaximum")) if "exclusiveMaximum" in schema else \
        ("]", "<=", schema.get("maximum"))
    if lo[2] is not None and hi[2] is not None:
        return f" in {lo[0]}{lo[2]:g}, {hi[2]:g}{hi[0]}"
    for _, op, bound in (lo, hi):
        if bound is not None:
            return f" {op} {bound:g}"
    return ""


def _require_finite(path, value, schema):
    if isinstance(value, dict):
        for k, v in value.items():
            if path == ("reduce",) and k == "options":
                continue
            _require_finite(path + (k,), v, schema.get("properties", {}).get(k, {}))
    elif isinstance(value, list):
        for v in value:
            _require_finite(path, v, schema.get("items", {}))
    elif isinstance(value, numbers.Real) and not isinstance(value, bool) and not math.isfinite(value):
        raise WorkflowError(f"config {': '.join(path)}: {value!r} must be a finite number{_range_text(schema)}")


_require_finite((), config, _CONFIG_SCHEMA)


# JSON Schema also counts 16.0 as an integer, so the integer keys are checked here for
# Python ints (a YAML "16.0" is a float and would become a folder n16.0).
def _require_ints(key, values):
    values = values if isinstance(values, list) else [values]
    for v in values:
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise WorkflowError(f"config {key}: {v!r} is not an integer (write e.g. 16, not 16.0)")


for _key, _values in [
    ("data: functions", config["data"]["functions"]),
    ("data: n", config["data"]["n"]),
    ("methods: vtk_runs", config["methods"]["vtk_runs"]),
    ("methods: random_seeds", config["methods"]["random_seeds"]),
    ("scale: n", config["scale"]["n"]),
    ("scale: function", config["scale"]["function"]),
    ("realdata: repeats", config["realdata"]["repeats"]),
]:
    _require_ints(_key, _values)


# --- the reduction options: `reduce: options:` is validated by the Snakefile against the
# generated workflow/schemas/options.schema.json (a $ref of config.schema.yaml).  The schema's
# defaults are not applied through that $ref (the referenced file declares its own $schema,
# so jsonschema validates it with a plain validator), so the omitted keys are filled in here
# from trivsel.options.config_schema() (every key then shows in the report's captions).
_OPTION_DEFAULTS = {name: prop["default"] for name, prop in config_schema()["properties"].items()}
config["reduce"]["options"] = {
    name: list(config["reduce"]["options"].get(name, default)) for name, default in _OPTION_DEFAULTS.items()
}
_FIELD_DEFAULTS = {f.name: f.default for f in option_fields()}


def canonical_options(options):
    """The same options with a value that equals the method's default written as the
    default (None), so that e.g. `criterion: [rms]` under the paper method is the
    `default` variant and not a second folder with the same reduction."""
    method_defaults = get_method(options.method).DEFAULTS
    same = {
        k: None
        for k, v in method_defaults.items()
        if _FIELD_DEFAULTS[k] is None and getattr(options, k) == v
    }
    return dataclasses.replace(options, **same)


def build_variants(option_lists):
    """tag -> trivsel.Options for every combination of the option lists (config order).

    An option that does not apply to a combination's method (trivsel.options.applies)
    takes its default in that combination, so that e.g. `method: [paper, greedy]` with
    `curvature: [direct, local-frame]` runs greedy once; a value that applies to none of
    the swept methods is refused.  Built when the workflow loads, so a bad value stops it
    before any job runs with the one-line message of trivsel.InputError."""
    names = list(option_lists)
    variants, used = {}, set()
    for combo in itertools.product(*(option_lists[k] for k in names)):
        chosen = dict(zip(names, combo))
        method = chosen.get("method", _FIELD_DEFAULTS["method"])
        kept = {k: v for k, v in chosen.items() if k == "method" or applies(k, method)}
        used.update((k, repr(v)) for k, v in kept.items())
        try:
            options = canonical_options(Options(**kept))
        except InputError as exc:
            raise WorkflowError(f"config reduce: options: {exc}") from None
        variants.setdefault(variant_tag(options), options)
    for k in names:
        for v in option_lists[k]:
            if v != _FIELD_DEFAULTS[k] and v is not None and (k, repr(v)) not in used:
                methods = sorted({str(m) for m in option_lists.get("method", [_FIELD_DEFAULTS["method"]])})
                raise WorkflowError(f"config reduce: options: {k}: {v!r} applies to "
                                    f"{' and '.join(method_group(k))} only, not to the swept method(s) "
                                    f"{', '.join(methods)}")
    return variants


# --- the golden table: golden_check reads it as a file, and a folder would pass the dry run
# and fail only in the job (a missing file only when the DAG is built).  A relative path is
# relative to the working directory, as the rule's input is.
_GOLDEN = config["golden"]["table"]
if _GOLDEN and not Path(_GOLDEN).is_file():
    raise WorkflowError(
        f"config golden: table: {_GOLDEN!r} is "
        f"{'a folder' if Path(_GOLDEN).is_dir() else 'not an existing file'}"
        + ("" if Path(_GOLDEN).is_absolute() else f" (relative to the working directory {str(Path.cwd())!r})")
    )


#: tag -> trivsel.Options of every variant of the sweep.
VARIANTS = build_variants(config["reduce"]["options"])
#: The primary run (first value of every list), shown in results/report/.
PRIMARY_VARIANT = next(iter(VARIANTS))
PRIMARY_N = config["data"]["n"][0]
FUNCTIONS = list(config["data"]["functions"])
NS = list(config["data"]["n"])
FRACTIONS = sorted(set(float(f) for f in config["reduce"]["fractions"]), reverse=True)
FRACTION_LABELS = [f"{f:g}" for f in FRACTIONS]
#: Methods of the variants: each gets its kernels compiled once.
KERNEL_METHODS = sorted({o.method for o in VARIANTS.values()})


# --- fractions against the grids (the schema only knows (0, 1]): a fraction counts
# round(f * (n+1)^3) points, rounded half up (trivsel.selection.count_for_fraction), and a
# reduction needs at least the 8 fixed corner points of the box and at most the fixed points
# plus the selectable ones (with `candidates: interior`, the (n-1)^3 interior points), so a
# fraction outside that range would only fail in its reduce job.
def check_fractions(key, fractions, ns, candidate_sets=("all",)):
    for n in ns:
        N = (n + 1) ** 3
        for cand in candidate_sets:
            n_max = N if cand == "all" else 8 + (n - 1) ** 3
            for f in fractions:
                m = count_for_fraction(f, N)
                if m < 8:
                    raise WorkflowError(
                        f"config {key}: {f!r} selects {m} of the {N} points of n = {n}, fewer than "
                        f"the 8 fixed corner points of the box: the smallest fraction for n = {n} "
                        f"is {8 / N:.3g} (8 / {N})"
                    )
                if m > n_max:
                    raise WorkflowError(
                        f"config {key}: {f!r} selects {m} of the {N} points of n = {n}, more than "
                        f"the {n_max} selectable with candidates: {cand} (the 8 corners and "
                        f"{n_max - 8} candidates): the largest fraction for n = {n} is "
                        f"{math.floor(1000 * (n_max + 0.499) / N) / 1000:g}"
                    )


check_fractions("reduce: fractions", FRACTIONS, NS, sorted({o.candidates for o in VARIANTS.values()}))


wildcard_constraints:
    function="[1-5]",
    n="[0-9]+",
    variant="|".join(re.escape(t) for t in VARIANTS),
    fraction="[0-9.e-]+",


def variant_options(variant):
    """The options of a variant with every method default filled in (for the tables)."""
    return VARIANTS[variant].resolve().to_dict()


def variant_columns(n, variant):
    """The columns errors_all.csv gets for one run: n, the variant and its options, except
    `values`, which errors.csv has already (one row per fraction and kind of values)."""
    options = {k: v for k, v in variant_options(variant).items() if k != "values"}
    return {"n": n, "variant": variant, **options}


def variant_cli_args(wildcards):
    """The `trivsel reduce` flags of the run's variant."""
    return VARIANTS[wildcards.variant].cli_args()


# --- code versions: Snakemake reruns a job when its params change, so each rule gets
# a hash of the trivsel code it runs.  Editing the package then reruns exactly the
# affected jobs (the package is not a script, so Snakemake would not see it).
# CODE_CORE covers the library (trivsel/**/*.py, subpackages such as trivsel/mesh/
# included) but not the studies (trivsel/study/), which the report, figure, methods,
# ablation, scale and realdata rules hash by module.
_PKG_DIR = Path(importlib.util.find_spec("trivsel").origin).parent


def source_hash(*names):
    """Short hash of the named files under trivsel/ (e.g. "study/report.py"); no names:
    the library, every trivsel/**/*.py outside trivsel/study/."""
    if names:
        files = [_PKG_DIR / name for name in names]
    else:
        files = sorted(
            p for p in _PKG_DIR.rglob("*.py") if "study" not in p.relative_to(_PKG_DIR).parts[:-1]
        )
    h = hashlib.sha256()
    for p in files:
        h.update(p.relative_to(_PKG_DIR).as_posix().encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


CODE_CORE = source_hash()
CODE_DATA = source_hash("data.py", "functions.py", "io/__init__.py")
_PUBLISHED = ("study/published.py", "study/table1_published.csv")
CODE_REPORT = source_hash("study/report.py", "study/ablation.py", *_PUBLISHED)
CODE_FIGURES = source_hash("study/figures.py", "io/__init__.py", *_PUBLISHED)
CODE_METHODS = CODE_CORE + source_hash("study/comparison.py", "study/baselines.py")
CODE_METHODS_REPORT = source_hash("study/comparison.py", "study/figures.py")
CODE_ABLATION = CODE_CORE + source_hash("study/ablation.py", *_PUBLISHED)
CODE_ABLATION_REPORT = source_hash("study/ablation.py", "study/report.py", *_PUBLISHED)
CODE_SCALE = CODE_CORE + source_hash("study/scaling.py", "study/baselines.py")
CODE_SCALE_REPORT = source_hash("study/scaling.py", "study/figures.py")
CODE_REALDATA = CODE_CORE + source_hash("study/realdata.py", "study/baselines.py")
CODE_REALDATA_REPORT = source_hash("study/realdata.py", "study/figures.py")
CODE_GOLDEN = source_hash("regression.py")


def kernel_driver_marker(wildcards):
    """`trivsel compile --part 2` (the extension module) of the method of the run's variant."""
    return f"results/kernels/{VARIANTS[wildcards.variant].method}_part2.txt"


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
    names = ["slices"] + (["slices3d"] if config["report"]["figures_3d"] else [])
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
    if config["golden"]["table"]:
        targets.append("results/report/golden_check.txt")
    if config["methods"]["activate"]:
        targets += methods_targets()
    return targets


# --- resources: a fixed part (interpreter, libraries) plus a cost per grid point (n+1)^3,
# with a wide margin; the time grows a little faster than the number of points.  The
# measurements behind the constants are in benchmarks/README.md.
def _points(wildcards):
    return (int(wildcards.n) + 1) ** 3


def reduce_mem_mb(wildcards, attempt):
    return int(500 + 0.02 * _points(wildcards)) * attempt


def reduce_runtime(wildcards, attempt):
    """Minutes, with a wide margin: 5 for n <= 32, about 50 for n = 64."""
    return int(5 + 2 * (_points(wildcards) / 35937) ** 1.5) * attempt


def figure_mem_mb(wildcards, attempt):
    return int(1500 + 0.02 * _points(wildcards)) * attempt


# --- stage "methods" (workflow/rules/methods.smk; on with `methods: activate: true`): every
# method at matched counts, at the Table-1 fractions and the sweep `methods: fractions`.
METHODS_FRACTIONS = sorted(
    set(FRACTIONS) | set(float(f) for f in config["methods"]["fractions"]), reverse=True
)
if config["methods"]["activate"]:
    check_fractions("methods: fractions", METHODS_FRACTIONS, NS)
if config["scale"]["activate"]:
    check_fractions("scale: fraction", [config["scale"]["fraction"]], config["scale"]["n"])


def methods_targets():
    targets = ["results/report/methods.csv", "results/report/methods.md"]
    targets += [f"results/report/figures/methods_f{f}_n{n}.png" for n in NS for f in FUNCTIONS]
    return targets


# A methods job runs every method at every count: about ten reductions' worth.
def methods_mem_mb(wildcards, attempt):
    return int(1000 + 0.05 * _points(wildcards)) * attempt


def methods_runtime(wildcards, attempt):
    """Minutes: about ten reductions' worth (three trivsel runs, 5 VTK runs per count)."""
    return int(10 + 10 * (_points(wildcards) / 35937) ** 1.5) * attempt
