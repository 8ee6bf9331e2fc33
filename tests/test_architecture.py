"""The package's architecture: every method behind one protocol, no import cycle between
the package's parts, and the block stages open to any method that takes a prescribed
boundary."""

import ast
import types
from pathlib import Path

import numpy as np
import pytest

import trivsel
from trivsel.methods import METHODS

PACKAGE = Path(trivsel.__file__).parent


def _modules():
    """``{dotted name: path}`` of every module of the library (the studies excluded)."""
    out = {}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        if parts[:2] != ("trivsel", "study"):
            out[".".join(parts)] = path
    return out


def _imports(name, path, modules):
    """The library modules that ``name`` imports anywhere in its source (inside functions too)."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package
            for _ in range(node.level - 1):
                base = base.rsplit(".", 1)[0]
            module = (f"{base}.{node.module}" if node.module else base) if node.level else node.module
            targets = [f"{module}.{a.name}" for a in node.names] + [module]
        for t in targets:
            while t not in modules and "." in t:
                t = t.rsplit(".", 1)[0]
            if t in modules and t != name:
                found.add(t)
    return found


def _unit(name):
    """The part of the package a module belongs to: ``trivsel.X`` (a module or a subpackage)."""
    return ".".join(name.split(".")[:2])


def _cycle(graph):
    """One cycle of ``graph`` ({node: set of nodes}) as a list, or None."""
    state = {}

    def visit(v, path):
        state[v] = 1
        for w in sorted(graph.get(v, ())):
            if state.get(w) == 1:
                return path[path.index(w):] + [w]
            if w not in state:
                found = visit(w, path + [w])
                if found:
                    return found
        state[v] = 2
        return None

    for v in sorted(graph):
        if v not in state:
            found = visit(v, [v])
            if found:
                return found
    return None


def _unit_graph():
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        for t in _imports(name, path, modules):
            if _unit(t) != _unit(name):
                graph.setdefault(_unit(name), set()).add(_unit(t))
    return graph


def test_the_parts_of_the_package_import_each_other_without_a_cycle():
    graph = _unit_graph()
    assert graph["trivsel.reduction"] >= {"trivsel.methods", "trivsel.result"}
    assert "trivsel.decimation" in graph["trivsel.methods"] and "trivsel.mesh" in graph["trivsel.methods"]
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))


def test_the_cycle_check_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}}) is None


def test_reduce_and_the_block_stages_name_no_method():
    """The front end and the block stages reach every method through the registry only (and
    the protocol's types)."""
    modules = _modules()
    stages = [name for name in modules if name == "trivsel.reduction" or _unit(name) == "trivsel.blocks"]
    assert len(stages) >= 3
    for name in stages:
        graph = _imports(name, modules[name], modules)
        named = {m for m in graph if m.startswith(("trivsel.methods.", "trivsel.decimation", "trivsel.mesh"))}
        assert named <= {"trivsel.methods.protocol"}, (name, named)


@pytest.mark.parametrize("name", list(METHODS))
def test_every_method_runs_through_the_protocol(name):
    module = METHODS[name]
    data = trivsel.sample_grid(4, 6)
    opts = trivsel.Options(method=name).resolve()
    need = module.memory(data, opts)
    assert need and all(b > 0 and isinstance(what, str) for b, what in need)
    from trivsel.methods.protocol import Problem

    out = module.run(Problem(data=data, options=opts, stop=dict(fractions=[0.2], count=None, tol_rms=None,
                                                                tol_inf=None)))
    assert [s.n_selected for s in out.snapshots] == [69]
    assert len(out.selected) == 69 and len(np.unique(out.selected)) == 69
    r = trivsel.reduce(data, fractions=[0.2], method=name)
    np.testing.assert_array_equal(r.snapshots[-1].tets, out.snapshots[-1].tets)


def test_a_new_method_runs_in_reduce_and_in_blocks_through_the_registry(monkeypatch):
    """A method registered under a new name (here greedy's run, renamed) is usable by
    ``reduce`` and by the block stages without any change to them."""
    from trivsel import blocks
    from trivsel.exceptions import InputError

    greedy = METHODS["greedy"]
    calls = []

    def run(problem):
        calls.append(problem.boundary is not None)
        return greedy.run(problem)

    toy = types.SimpleNamespace(NAME="toy", DEFAULTS=greedy.DEFAULTS, PRESCRIBED_BOUNDARY=True, INSERTS=True,
                                check=greedy.check,
                                memory=greedy.memory, run=run, compile_kernels=greedy.compile_kernels)
    monkeypatch.setitem(METHODS, "toy", toy)
    assert trivsel.reduce(4, n=6, fractions=[0.2], method="toy").snapshots[-1].n_selected == 69
    x = np.linspace(-1, 1, 9)
    f = np.exp(-(x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2))

    class Volume:
        shape, origin, spacing = f.shape, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)

        def read(self, region):
            return f[tuple(slice(*r) for r in region)]

    tets, _ = blocks.reduce_in_blocks(Volume(), blocks.plan_blocks(f.shape, 4), tol_inf=0.05, method="toy")
    assert calls == [False] + [True] * 8 and len(tets)
    blocks.check_tetrahedra(f.shape, tets)
    monkeypatch.setitem(METHODS, "toy", types.SimpleNamespace(**{**vars(toy), "PRESCRIBED_BOUNDARY": False}))
    with pytest.raises(InputError, match="method 'toy' cannot take the blocks' prescribed faces: choose paper or greedy or decimate"):
        blocks.make_config({"function": 4, "n": 8, "block": 4, "tol_inf": 0.1, "method": "toy"})
