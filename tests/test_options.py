"""The Options registry, the method registry and the library/study split: one definition of
every option feeds the API, the CLI, the workflow's schema and the docs."""

from __future__ import annotations

import ast
import inspect
import json
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import examples

import trivsel
from trivsel.cli import build_parser
from trivsel.methods import METHODS, get_method
from trivsel.options import (Options, applies, config_schema, option_fields, option_groups, options_markdown,
                             variant_tag)

REPO = Path(__file__).resolve().parents[1]
LIBRARY = REPO / "trivsel"


def _value_strategy(f):
    meta = f.metadata
    if meta["kind"] == "choice":
        choices = list(METHODS) if f.name == "method" else list(meta["choices"])
        base = st.sampled_from(choices)
        if meta["sequence"]:
            return st.lists(base, min_size=1, max_size=len(choices), unique=True).map(tuple)
        return base
    if meta["kind"] == "bool":
        return st.booleans()
    if meta["kind"] == "int":
        return st.integers(min_value=int(meta["minimum"]), max_value=10**6)
    return st.floats(min_value=meta["minimum"], max_value=1e3, allow_nan=False, allow_infinity=False)


def _options_of(method):
    """Keyword dicts of :class:`Options` for ``method``: any values of the options that apply to it
    (``method`` itself left out, for the default method, as often as not)."""
    fields_ = [f for f in option_fields() if f.name != "method" and applies(f.name, method)]
    required = {"method": st.just(method)} if method != "paper" else {}
    optional = {f.name: _value_strategy(f) for f in fields_}
    if method == "decimate":  # its collapses are ordered by 'sse' or 'max' (methods.decimate.check_options)
        optional["criterion"] = st.sampled_from(["sse", "max"])
    if method == "paper":
        optional["method"] = st.just(method)
    return st.fixed_dictionaries(required, optional=optional)


_OPTIONS = st.sampled_from(list(METHODS)).flatmap(_options_of)


@settings(max_examples=examples(4 / 3), deadline=None)
@given(_OPTIONS)
def test_cli_args_parse_back_to_the_same_options(kw):
    opts = Options(**kw)
    ns = build_parser().parse_args(["reduce", "--function", "1", "--out", "x", *opts.cli_args()])
    from trivsel.options import from_namespace

    assert from_namespace(ns) == opts


@settings(max_examples=examples(2 / 3), deadline=None)
@given(_OPTIONS, _OPTIONS)
def test_variant_tags_are_unique_per_option_set(a, b):
    oa, ob = Options(**a), Options(**b)
    assert (variant_tag(oa) == variant_tag(ob)) == (oa == ob)


def test_every_field_is_a_cli_flag_a_reduce_keyword_a_schema_entry_and_documented():
    params = inspect.signature(trivsel.reduce).parameters
    flags = {a.dest for a in build_parser()._subparsers._group_actions[0].choices["reduce"]._actions}
    schema = config_schema()["properties"]
    doc = options_markdown()
    for f in option_fields():
        assert f.name in params and params[f.name].kind is inspect.Parameter.KEYWORD_ONLY
        assert params[f.name].default == ("auto" if f.name == "method" else f.default)
        assert f.name in flags
        assert f.name in schema
        assert f"| `{f.name}` |" in doc
        assert f"    {f.name} : " in trivsel.reduce.__doc__
    assert {f.name for f in fields(Options)} == set(schema)


def test_generated_files_are_up_to_date():
    r = subprocess.run([sys.executable, "-m", "trivsel.options", "--root", str(REPO), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    assert json.loads((REPO / "workflow/schemas/options.schema.json").read_text()) == config_schema()


@pytest.mark.parametrize("kw, message", [
    ({"method": "bottom-up"}, "unknown method 'bottom-up': choose one of paper, greedy"),
    ({"criterion": "l3"}, "unknown criterion 'l3'"),
    ({"final_pass": "yes"}, "final_pass must be true or false, got 'yes'"),
    ({"seed": -1}, "seed must be >= 0, got -1"),
    ({"rel_tol": float("inf")}, "rel_tol must be finite, got inf"),
    ({"rel_tol": float("nan")}, "rel_tol must be finite"),
    ({"max_flips": 1.5}, "max_flips must be an integer, got 1.5"),
    ({"values": []}, "values must name at least one of data, fit"),
    ({"values": ["data", "best"]}, "unknown values 'best'"),
])
def test_bad_options_are_one_line_input_errors(kw, message):
    with pytest.raises(trivsel.InputError, match=message.replace("(", r"\(").replace(")", r"\)")) as e:
        Options(**kw)
    assert "\n" not in str(e.value)


def test_method_defaults_live_in_the_method_module_and_resolve():
    for name, module in METHODS.items():
        resolved = Options(method=name).resolve()
        for key, value in module.DEFAULTS.items():
            assert getattr(Options(), key) is None, "a method default overrides only fields defaulting to None"
            assert getattr(resolved, key) == value
        assert Options(method=name, criterion="max").resolve().criterion == "max"
    assert all(getattr(Options().resolve(), f.name) is not None for f in option_fields())


def test_every_method_module_has_the_protocol():
    for name, module in METHODS.items():
        assert get_method(name) is module and module.NAME == name
        for attr in ("DEFAULTS", "PRESCRIBED_BOUNDARY", "check", "memory", "run", "compile_kernels"):
            assert hasattr(module, attr), f"method {name} lacks {attr}"
        assert callable(module.run) and callable(module.memory) and callable(module.compile_kernels)


def test_reduce_takes_an_options_object_and_keyword_overrides():
    base = trivsel.reduce(4, n=6, fractions=[0.3], method="greedy", greedy_key="sse")
    via = trivsel.reduce(4, n=6, fractions=[0.3], options=trivsel.Options(method="greedy", greedy_key="sse"))
    over = trivsel.reduce(4, n=6, fractions=[0.3], options=trivsel.Options(method="greedy"), greedy_key="sse")
    for r in (via, over):
        assert (r.selected == base.selected).all() and r.options == base.options
    with pytest.raises(TypeError, match="unexpected keyword argument 'own_vertices'"):
        trivsel.reduce(4, n=6, fractions=[0.3], own_vertices=False)


def _imports(path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            yield ("." * node.level) + (node.module or "")
        elif isinstance(node, ast.Import):
            yield from (a.name for a in node.names)


def test_the_library_never_imports_the_study():
    for path in LIBRARY.rglob("*.py"):
        if "study" in path.relative_to(LIBRARY).parts:
            continue
        for name in _imports(path):
            assert "study" not in name, f"{path.relative_to(REPO)} imports {name}"


def test_import_trivsel_is_light():
    # not even numpy: the command line's Ctrl-C handling starts before the first heavy import
    code = ("import sys, trivsel, trivsel.cli; heavy = [m for m in ('numpy', 'matplotlib', 'vtk', 'vtkmodules', "
            "'pyvista', 'snakemake', 'numba', 'pandas', 'trivsel.study') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    code = ("import sys, trivsel; trivsel.reduce(4, n=4, fractions=[0.5]); "
            "print([m for m in ('matplotlib', 'vtk', 'vtkmodules', 'snakemake', 'trivsel.study') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


@pytest.mark.parametrize("source", ["function", "vti"])
def test_a_command_line_reduction_does_not_import_pandas_or_pyvista(tmp_path, source):
    """``trivsel reduce`` writes errors.csv and prints its table without pandas, and reads and
    writes VTK files with VTK's own modules, without pyvista (together about 0.7 s of every
    command-line run)."""
    args = ["--function", "4", "--n", "4"]
    if source == "vti":
        pv = pytest.importorskip("pyvista")
        img = pv.ImageData(dimensions=(5, 5, 5))
        img.point_data["f"] = np.arange(125.0) % 7
        img.save(tmp_path / "in.vti")
        args = [str(tmp_path / "in.vti")]
    code = (f"import sys; from trivsel.cli import main; main(['reduce', *{args!r}, "
            f"'--fractions', '0.5', '--out', {str(tmp_path / 'out')!r}]); "
            "print([m for m in ('pandas', 'pyvista', 'matplotlib', 'trivsel.study') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"
    assert (tmp_path / "out" / "errors.csv").read_text().startswith(
        "function,n,input,n_points,method,values,fraction,")


def test_no_import_cycles_in_the_library():
    """Module-level imports between trivsel modules form no cycle."""
    graph = {}
    for path in LIBRARY.rglob("*.py"):
        mod = ".".join(path.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__")
        pkg = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        deps = set()
        for node in ast.parse(path.read_text()).body:  # module level only: lazy imports may close loops
            if isinstance(node, ast.ImportFrom) and node.level:
                base = pkg
                for _ in range(node.level - 1):
                    base = base.rpartition(".")[0]
                if node.module:
                    target = f"{base}.{node.module}"
                    deps.add(target)
                    deps.update(f"{target}.{a.name}" for a in node.names)
                else:  # `from . import x, y`: the sibling modules x and y
                    deps.update(f"{base}.{a.name}" for a in node.names)
        graph[mod] = deps
    graph = {m: {d for d in deps if d in graph and d != m} for m, deps in graph.items()}

    def visit(m, stack):
        if m in stack:
            raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(m):] + [m]))
        for d in graph[m]:
            visit(d, stack + [m])

    for m in graph:
        visit(m, [])


# -- options that do not apply to the method

#: (method, option, a value other than the default, the methods the option applies to)
_INAPPLICABLE = [
    ("decimate", "greedy_key", "sse", "greedy"),
    ("paper", "greedy_key", "sse", "greedy"),
    ("greedy", "curvature", "local-frame", "paper"),
    ("greedy", "ranking", "random", "paper"),
    ("greedy", "tie_order", "random", "paper"),
    ("decimate", "seed", 3, "paper"),
    ("decimate", "max_flips", 3, "paper and greedy"),
    ("decimate", "boundary_flips", False, "paper and greedy"),
    ("decimate", "swap_memory", "call", "paper and greedy"),
    ("decimate", "final_pass", True, "paper and greedy"),
    ("paper", "lazy_queue", False, "decimate"),
]


def _flag_args(name, value):
    flag = "--" + name.replace("_", "-")
    if isinstance(value, bool):
        return [flag if value else "--no-" + flag[2:]]
    return [flag, str(value)]


@pytest.mark.parametrize("method, name, value, only", _INAPPLICABLE)
def test_an_option_of_another_method_is_refused_naming_its_methods(method, name, value, only):
    message = f"option {name} (--{name.replace('_', '-')}) applies to method"
    tail = f" {only} only, not to {method}"
    with pytest.raises(trivsel.InputError) as e:
        Options(method=method, **{name: value})
    assert message in str(e.value) and str(e.value).endswith(tail) and "\n" not in str(e.value)
    with pytest.raises(trivsel.InputError, match=f"{name}.*{tail}"):
        trivsel.reduce(4, n=4, fractions=[0.5], method=method, **{name: value})
    with pytest.raises(trivsel.InputError, match=f"{name}.*{tail}"):  # an Options object and a keyword
        trivsel.reduce(4, n=4, fractions=[0.5], options=Options(method=method), **{name: value})


@pytest.mark.parametrize("method, name, value, only", _INAPPLICABLE)
def test_the_command_line_refuses_an_option_of_another_method(tmp_path, method, name, value, only):
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "trivsel", "reduce", "--function", "4", "--n", "4", "--fractions",
                        "0.5", "--method", method, *_flag_args(name, value), "--out", str(out)],
                       capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip() == (f"trivsel: error: option {name} (--{name.replace('_', '-')}) applies to "
                                f"method{'s' if ' and ' in only else ''} {only} only, not to {method}")
    assert not out.exists()


def test_a_flag_given_at_its_default_value_is_still_refused_for_another_method(tmp_path):
    """On the command line and as a keyword of reduce, what the user gives is a setting,
    even when it equals the default; an Options object cannot tell, and accepts it."""
    from trivsel.cli import main

    assert main(["reduce", "--function", "4", "--n", "4", "--fractions", "0.5", "--method", "decimate",
                 "--greedy-key", "max", "--out", str(tmp_path / "o")]) == 2
    with pytest.raises(trivsel.InputError, match="greedy_key .* applies to method greedy only, not to decimate"):
        trivsel.reduce(4, n=4, fractions=[0.5], method="decimate", greedy_key="max")
    assert Options(method="decimate", greedy_key="max") == Options(method="decimate")


def test_defaults_of_options_that_do_not_apply_are_fine_and_resolve_to_nothing_for_decimate():
    for name in METHODS:
        Options(method=name)  # every default, whatever applies
    resolved = Options(method="decimate").resolve()
    assert resolved.criterion == "sse" and resolved.max_flips is None and resolved.boundary_flips is None
    r = trivsel.reduce(4, n=4, fractions=[0.5], method="decimate")
    assert r.options["method"] == "decimate" and r.options["max_flips"] is None


def test_help_and_docstring_group_the_options_by_method():
    reduce_parser = build_parser()._subparsers._group_actions[0].choices["reduce"]
    titles = {a.dest: g.title for g in reduce_parser._action_groups for a in g._group_actions}
    assert titles["method"].startswith("options of every method")
    assert titles["greedy_key"] == "options of method greedy only"
    assert titles["lazy_queue"] == "options of method decimate only"
    assert titles["curvature"] == titles["seed"] == "options of method paper only"
    assert titles["max_flips"] == titles["final_pass"] == "options of methods paper and greedy only"
    helptext = reduce_parser.format_help()
    assert helptext.index("options of method paper only") < helptext.index("\n  --curvature") \
        < helptext.index("options of method greedy only") < helptext.index("\n  --greedy-key")
    doc = trivsel.reduce.__doc__
    assert "greedy_key : {'max', 'sse'}, default max; method greedy only" in doc
    assert "lazy_queue : bool, default true; method decimate only" in doc
    assert "max_flips : int, default method's default; methods paper and greedy only" in doc
    # grouped: every method's options first, then by method
    order = [f.name for _, group in option_groups() for f in group]
    positions = [doc.index(f"    {name} : ") for name in order]
    assert positions == sorted(positions)
    md = options_markdown()
    assert md.index("## Method paper only") < md.index("| `curvature` |") < md.index("## Method greedy only")


def test_every_option_applies_to_a_known_method():
    from trivsel.options import method_group

    for f in option_fields():
        assert method_group(f.name) and set(method_group(f.name)) <= set(METHODS), f.name
    assert method_group("max_flips") == ("paper", "greedy")
    assert [f.name for f in option_fields() if not applies(f.name, "decimate")] == [
        "tie_order", "boundary_diagonals", "vertices_in_error", "final_pass", "first_improving", "curvature",
        "neighbourhood", "ranking", "rel_tol", "quantum", "seed", "greedy_key", "boundary_flips", "max_flips",
        "swap_memory"]


@pytest.mark.parametrize("kw, message", [
    ({"seed": np.float64(2.0)}, "seed must be an integer, got 2.0"),
    ({"max_flips": np.float32(1.5)}, "max_flips must be an integer, got 1.5"),
    ({"final_pass": np.float64(0.5)}, "final_pass must be true or false, got 0.5"),
    ({"values": np.array(["data", "best"])}, "unknown values 'best'"),
    ({"criterion": np.str_("l3")}, "unknown criterion 'l3'"),
])
def test_a_numpy_scalar_in_a_bad_option_prints_as_a_plain_number(kw, message):
    with pytest.raises(trivsel.InputError) as e:
        Options(**kw)
    assert message in str(e.value) and "np." not in str(e.value) and "array(" not in str(e.value)


@pytest.mark.parametrize("kw, message", [
    ({"fractions": [np.float64(1.5)]}, "fraction 1.5 is outside (0, 1]"),
    ({"fractions": [0.5], "tol_rms": np.float64(-0.5)}, "tol_rms must be a finite number >= 0, got -0.5"),
    ({"count": np.int64(10**9)}, "got 1000000000"),
    ({"fractions": [0.5], "threads": np.int64(0)}, "threads must be an integer >= 1, got 0"),
])
def test_a_numpy_scalar_in_a_bad_argument_prints_as_a_plain_number(kw, message):
    with pytest.raises(trivsel.InputError) as e:
        trivsel.reduce(4, n=4, **kw)
    assert message in str(e.value) and "np." not in str(e.value)


def test_a_numpy_value_in_a_bad_choice_or_block_size_prints_as_plain_text():
    from trivsel.selection import candidate_points, rank_candidates

    with pytest.raises(trivsel.InputError) as e:
        rank_candidates(np.zeros(3), np.arange(3), tie_order=np.str_("sideways"))
    assert "unknown tie order 'sideways'" in str(e.value) and "np." not in str(e.value)
    with pytest.raises(trivsel.InputError) as e:
        candidate_points(8, np.arange(8), np.zeros(8, bool), np.str_("edges"))
    assert "unknown candidate set 'edges'" in str(e.value) and "np." not in str(e.value)
    from trivsel.blocks import plan_blocks

    with pytest.raises(trivsel.InputError) as e:
        plan_blocks((9, 9, 9), np.float64(2.5))
    assert str(e.value).endswith("got 2.5") and "np." not in str(e.value)


def test_dir_shows_the_lazy_names():
    names = dir(trivsel)
    assert {"reduce", "load", "Options", "ReductionResult", "sample_grid", "mesh", "cli"} <= set(names)
    assert set(trivsel.__all__) <= set(names)
