"""Kernels compiled ahead of time (:mod:`trivsel.aot`): the same results as numba's, loaded
without numba, and a fallback to numba's kernels whenever they cannot be built or loaded."""

import json
import logging
import os
import subprocess
import sys
from importlib.machinery import EXTENSION_SUFFIXES

import numpy as np
import pytest

import trivsel
from trivsel import aot
from trivsel import decimation as dm
from trivsel.data import sample_grid, scattered
from trivsel.triangulation import start_tetrahedra


def _run(data, key, lock, tol_inf=None):
    """Everything a decimation's kernels produce, lazily then exactly, at three counts."""
    dec = dm.Decimation(data.ijk, data.shape, data.values, key=key, lock=lock, tol_inf=tol_inf, lazy=True)
    N = data.n_points
    out = []
    for count in (N // 2, N // 5, N // 10):
        if count < N // 4:
            dec.lazy = False
        code = dec.run(count)
        verts, w = dec.point_weights()
        out.append((code, dec.removed(), dec.residuals(), dec.tetrahedra(), dec.sse, verts, w))
    return dec, out


def _same(a, b):
    for x, y in zip(a, b):
        for u, v in zip(x, y):
            assert np.array_equal(u, v)


@pytest.mark.parametrize("fn, n, key, lock, tol_inf", [(4, 12, "sse", "box", None), (5, 11, "max", "box", None),
                                                       (1, 10, "sse", "all", None), (4, 12, "sse", "box", 0.02)])
def test_ahead_of_time_kernels_give_numbas_results_to_the_bit(monkeypatch, fn, n, key, lock, tol_inf):
    data = sample_grid(fn, n)
    dec, ours = _run(data, key, lock, tol_inf)
    assert isinstance(dec._k, type(aot)), "the kernels were not compiled ahead of time"
    assert dec._k.__file__.startswith(str(aot.cache_dir()))
    monkeypatch.setenv("TRIVSEL_AOT", "0")
    dec, numbas = _run(data, key, lock, tol_inf)
    assert not isinstance(dec._k, type(aot))
    assert aot.is_jit(dec._k)  # numba's own kernels
    _same(ours, numbas)


def test_a_state_of_another_layout_gets_its_own_module(monkeypatch):
    """The extension module does not check argument types, so the layout is in its name."""
    data = sample_grid(4, 4)
    s32 = dm.new_state(data.ijk, data.shape, data.values)
    monkeypatch.setattr(dm, "INT32_CORNERS", 0)
    s64 = dm.new_state(data.ijk, data.shape, data.values)
    assert s32.T.dtype == np.int32 and s64.T.dtype == np.int64
    assert aot.layout(s32) != aot.layout(s64)
    p32 = aot._paths(dm.KERNELS, dm.KERNEL_SOURCES, s32)[1]
    p64 = aot._paths(dm.KERNELS, dm.KERNEL_SOURCES, s64)[1]
    assert p32 != p64
    odd = s32._replace(cpool=s32.cpool[::2])  # not contiguous: another type for numba
    assert aot.layout(odd) != aot.layout(s32)


def _read_only(a):
    a = np.array(a)
    a.flags.writeable = False
    return a


def test_read_only_or_strided_inputs_give_the_layout_of_writeable_ones(tmp_path):
    """Values read from a CSV file come as a read-only view, and numba types a read-only
    array apart: a state made from them would need a compile of its own.  Grid and mesh
    states take such inputs (and strided or other-typed ones) as a copy of the one layout,
    and leave the caller's arrays as they were."""
    data = sample_grid(4, 5)
    base = dm.new_state(data.ijk, data.shape, data.values)
    values = _read_only(data.values)
    mapped = np.memmap(tmp_path / "values.f8", np.float64, "w+", shape=data.values.shape)
    mapped[:] = data.values
    strided = np.stack([data.values, data.values], axis=1)[:, 0]
    for ijk, vals in [(_read_only(data.ijk), values), (np.asfortranarray(data.ijk), strided),
                      (data.ijk.astype(np.int16), data.values.astype(np.float32)), (data.ijk, mapped)]:
        s = dm.new_state(ijk, data.shape, vals)
        assert aot.layout(s) == aot.layout(base)
        assert type(s.f) is np.ndarray and type(s.P) is np.ndarray
        assert s.f.flags.writeable and s.P.flags.writeable
        assert np.array_equal(s.f, np.asarray(vals, np.float64)) and np.array_equal(s.P, base.P)
    assert not values.flags.writeable and np.array_equal(values, data.values)

    sc = _scattered_data()
    tets = start_tetrahedra(sc.points)
    mesh = dm.new_mesh_state(sc.points, tets, sc.values)
    ro = dm.new_mesh_state(_read_only(sc.points), tets, _read_only(sc.values))
    assert aot.layout(ro) == aot.layout(mesh)
    assert np.array_equal(ro.P, mesh.P) and np.array_equal(ro.f, mesh.f)


def test_a_failed_build_falls_back_to_numba_once_and_is_tried_again_by_compile(monkeypatch, tmp_path, caplog):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    calls = []

    def no_compiler(module, state, path, variant=None):
        calls.append(path)
        raise OSError("command 'gcc' failed: No such file or directory")

    monkeypatch.setattr(aot, "build", no_compiler)
    data = sample_grid(4, 6)
    with caplog.at_level(logging.INFO, logger="trivsel"):
        dec = dm.Decimation(data.ijk, data.shape, data.values)
    assert len(calls) == 1
    assert aot.is_jit(dec._k)  # numba's own kernels
    assert "could not compile trivsel.decimation.collapse ahead of time (command 'gcc' failed" in caplog.text
    failed = list(tmp_path.glob("trivsel-aot/*.failed"))
    assert len(failed) == 1 and "gcc" in failed[0].read_text()
    caplog.clear()
    dec2 = dm.Decimation(data.ijk, data.shape, data.values)  # remembered: no second try, no second warning
    assert len(calls) == 1 and "could not" not in caplog.text
    assert dec2.run(20) == 0 and dec.run(20) == 0
    assert np.array_equal(dec.removed(), dec2.removed())
    dm.compile_kernels()  # tries again
    assert len(calls) == 2


def test_no_c_compiler_is_found_before_any_compiling(monkeypatch, tmp_path, caplog):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CC", "no-such-compiler-for-trivsel")
    data = sample_grid(4, 6)
    with caplog.at_level(logging.WARNING, logger="trivsel"):
        dec = dm.Decimation(data.ijk, data.shape, data.values)
    assert aot.is_jit(dec._k)
    assert "no C compiler: 'no-such-compiler-for-trivsel' not found" in caplog.text
    assert dec.run(20) == 0


def test_a_damaged_module_is_not_loaded(monkeypatch, tmp_path, caplog):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    data = sample_grid(4, 6)
    S = dm.new_state(data.ijk, data.shape, data.values)
    name, path, _ = aot._paths(dm.KERNELS, dm.KERNEL_SOURCES, S)
    path.parent.mkdir(parents=True)
    path.write_bytes(b"\x7fELF not really")
    with caplog.at_level(logging.WARNING, logger="trivsel"):
        dec = dm.Decimation(data.ijk, data.shape, data.values)
    assert aot.is_jit(dec._k)
    assert f"could not load {path}" in caplog.text
    assert dec.run(20) == 0


def test_a_build_keeps_only_the_newest_modules_of_its_library(monkeypatch, tmp_path):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    data = sample_grid(4, 6)
    S = dm.new_state(data.ijk, data.shape, data.values)
    name, path, _ = aot._paths(dm.KERNELS, dm.KERNEL_SOURCES, S)
    d = path.parent
    d.mkdir(parents=True)
    stem, suffix = name.rsplit("_", 1)[0], path.name.split(".", 1)[1]
    old = [d / f"{stem}_{i:020x}.{suffix}" for i in range(6)]  # earlier sources, oldest first
    for i, p in enumerate(old):
        p.write_bytes(b"old")
        os.utime(p, (1000 + i, 1000 + i))
    others = [d / f"_aot_other_kernels_{0:020x}.{suffix}",  # another library
              d / f"{stem}_paper_{0:020x}.{suffix}",  # another variant
              d / f"{stem}_{1:020x}.failed"]
    for p in others:
        p.write_bytes(b"x")
    monkeypatch.setattr(aot, "build", lambda module, state, p, variant=None: p.write_bytes(b"new"))
    monkeypatch.setattr(aot, "_import", lambda name, p: "the new module")
    assert aot.kernels(dm.KERNELS, dm.KERNEL_SOURCES, S) == "the new module"
    left = {p.name for p in d.iterdir()}
    assert left == {path.name} | {p.name for p in old[-(aot.KEEP - 1):]} | {p.name for p in others}


@pytest.mark.skipif(os.name != "posix", reason="the build lock is flock(2)")
def test_a_module_another_process_is_building_is_waited_for_not_built_again(monkeypatch, tmp_path, caplog):
    """While another process holds the module's build lock (a workflow's jobs that start
    together), a process says that it waits, builds nothing, and loads that process's module."""
    import fcntl
    import threading
    import time

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    data = sample_grid(4, 6)
    S = dm.new_state(data.ijk, data.shape, data.values)
    name, path, _ = aot._paths(dm.KERNELS, dm.KERNEL_SOURCES, S)
    builds = []
    monkeypatch.setattr(aot, "build", lambda module, state, p, variant=None: builds.append(p))
    monkeypatch.setattr(aot, "_import", lambda name, p: p.read_bytes())
    path.parent.mkdir(parents=True)
    lock = path.with_name(name + ".lock")
    fd = os.open(lock, os.O_RDWR | os.O_CREAT)  # its own open file: flock(2) sets it against the thread's
    fcntl.flock(fd, fcntl.LOCK_EX)  # the other process, building
    got = []
    waiter = threading.Thread(target=lambda: got.append(aot.kernels(dm.KERNELS, dm.KERNEL_SOURCES, S)))
    with caplog.at_level(logging.WARNING, logger="trivsel"):
        waiter.start()
        for _ in range(500):
            if "waiting" in caplog.text:
                break
            time.sleep(0.01)
        assert "waiting for another process that is compiling the decimation kernels" in caplog.text
        assert waiter.is_alive() and not got
        path.write_bytes(b"the other process's module")
        os.close(fd)  # its build is over
        waiter.join(30)
    assert got == [b"the other process's module"] and builds == [] and aot.waited[-1] == "decimation"
    assert "compiling the decimation kernels once" not in caplog.text
    assert not lock.exists()  # a module built leaves no lock behind


def test_a_build_takes_the_lock_and_leaves_no_lock_file(monkeypatch, tmp_path):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    data = sample_grid(4, 6)
    S = dm.new_state(data.ijk, data.shape, data.values)
    name, path, _ = aot._paths(dm.KERNELS, dm.KERNEL_SOURCES, S)
    held = []

    def build(module, state, p, variant=None):  # the lock is held while it builds
        if os.name == "posix":
            import fcntl

            fd = os.open(p.with_name(name + ".lock"), os.O_RDWR)
            try:
                with pytest.raises(BlockingIOError):
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                held.append(True)
            finally:
                os.close(fd)
        p.write_bytes(b"built")

    monkeypatch.setattr(aot, "build", build)
    monkeypatch.setattr(aot, "_import", lambda name, p: p.read_bytes())
    assert aot.kernels(dm.KERNELS, dm.KERNEL_SOURCES, S) == b"built"
    assert held == ([True] if os.name == "posix" else [])
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]


@pytest.mark.parametrize("env", [{"TRIVSEL_AOT": "0"}, {"NUMBA_DISABLE_JIT": "1"}, {"TRIVSEL_AOT": "off"}])
def test_switched_off(monkeypatch, env):
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    assert not aot.enabled()
    monkeypatch.delenv("TRIVSEL_AOT", raising=False)
    monkeypatch.delenv("NUMBA_DISABLE_JIT", raising=False)
    assert aot.enabled()


def test_numbas_kernels_announce_a_compile_when_one_not_in_its_cache_is_called(monkeypatch, caplog):
    """With numba's own kernels, the compile notice comes with the first call of a kernel that
    numba's cache does not hold, once a process: a run that calls only cached kernels says
    nothing, although others of the library (that it never calls) are not in the cache."""
    calls = []

    def kernel(name):
        def fn(*args):
            calls.append(name)
            return len(args)
        fn.py_func = fn  # as a numba dispatcher has
        return fn

    exports = {name: (kernel(name), (name,)) for name in ("init", "run", "weights", "replay")}
    monkeypatch.setattr(aot, "_exports", lambda module, state, variant: exports)
    monkeypatch.setattr(aot, "in_cache", lambda fn, sig: sig[0] in ("init", "run"))
    monkeypatch.setattr(aot, "compiled", [])
    k = aot._jit("trivsel.decimation.collapse", None)
    with caplog.at_level(logging.WARNING, logger="trivsel"):
        assert k.init(1, 2) == 2 and k.run() == 0
        assert aot.compiled == [] and not caplog.records
        assert k.weights(1) == 1 and k.replay(1) == 1 and k.weights(2) == 1
    assert aot.compiled == ["decimation"] and len(caplog.records) == 1
    assert "compiling the decimation kernels once" in caplog.records[0].getMessage()
    assert calls == ["init", "run", "weights", "replay", "weights"] and aot.is_jit(k)


def test_the_cache_directory_follows_numbas(monkeypatch, tmp_path):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert aot.cache_dir() == tmp_path / "trivsel-aot"
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    assert aot.cache_dir().parent.name in ("__pycache__", "trivsel")


_DECIMATE_WITHOUT_NUMBA = """
import json, sys
import trivsel
out = []
for lazy in (True, False):
    for criterion in ("sse", "max"):
        r = trivsel.reduce(4, n=8, fractions=[0.05, 0.3], method="decimate", lazy_queue=lazy, criterion=criterion,
                           values=["data", "fit"])
        out.append([[s.n_selected, s.errors, s.fit["errors"], s.selected.tolist()] for s in r.snapshots])
print(json.dumps({"numba": "numba" in sys.modules, "results": out}))
"""


def _python(args, env):
    """The standard output of ``python *args`` in a new process (which must succeed)."""
    p = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=900, env=env)
    assert p.returncode == 0, p.stderr
    return p.stdout


def _same_without_numba(code, env, built_dir, built):
    """``code`` run with the extension modules (never importing numba, building nothing) and
    with numba's own kernels: the same results."""
    ours = json.loads(_python(["-c", code], env))
    assert ours["numba"] is False
    assert sorted(built_dir.iterdir()) == built
    numbas = json.loads(_python(["-c", code], dict(env, TRIVSEL_AOT="0")))
    assert numbas["numba"] is True
    assert numbas["results"] == ours["results"]


@pytest.mark.slow
def test_compile_builds_what_a_decimation_runs_and_a_run_needs_no_numba(tmp_path):
    """After `trivsel compile --method decimate` in an empty cache, decimations with lazy and
    exact updates, both criteria and fitted values run in a process that never imports numba,
    build nothing more, and give the results of numba's own kernels (a cold compile)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("TRIVSEL_AOT", None)
    _python(["-m", "trivsel", "compile", "--method", "decimate"], env)
    built = sorted((tmp_path / "cache" / "trivsel-aot").iterdir())
    assert len(built) == 1 and built[0].name.endswith(tuple(EXTENSION_SUFFIXES))
    _same_without_numba(_DECIMATE_WITHOUT_NUMBA, env, tmp_path / "cache" / "trivsel-aot", built)


# --- the insertion methods' kernels (trivsel.mesh.entries)

def _scattered_data():
    rng = np.random.default_rng(3)
    p = rng.uniform(-1, 1, (400, 3))
    return scattered(p, np.sin(3 * p[:, 0]) * p[:, 1] + p[:, 2] ** 2)


# every kernel a reduction calls from Python: both drivers, the first cone and swap, the
# three stopping rules, both swap criteria, the final global pass, the point weights of
# fitted values, grids (exact integer predicates) and scattered points (float ones)
_MESH_RUNS = [("paper", 4, 10, dict(fractions=[0.5, 0.2, 0.1], values=["data", "fit"])),
              ("paper", 5, 9, dict(fractions=[0.3, 0.1], criterion="max", final_pass=True)),
              ("paper", 2, 8, dict(tol_rms=0.01)),
              ("paper", "scattered", None, dict(fractions=[0.3])),
              ("greedy", 1, 9, dict(fractions=[0.3, 0.1], values=["data", "fit"])),
              ("greedy", 4, 9, dict(tol_inf=0.05)),
              ("greedy", "scattered", None, dict(fractions=[0.2]))]


def _mesh_run(method, fn, n, kw):
    data = _scattered_data() if fn == "scattered" else sample_grid(fn, n)
    r = trivsel.reduce(data, method=method, **kw)
    out = [r.selected, r.order]
    for s in r.snapshots:
        out += [s.selected, s.tets, s.residuals, np.array(list(s.errors.values())), np.array(list(s.flips.values()))]
        if s.fit is not None:
            out += [s.fit["values"]]
    return out


@pytest.mark.parametrize("method, fn, n, kw", _MESH_RUNS)
def test_insertion_kernels_ahead_of_time_give_numbas_results_to_the_bit(monkeypatch, method, fn, n, kw):
    from trivsel.mesh import entries

    loaded = []
    real = entries.kernels

    def spy(S, **kwargs):
        loaded.append(real(S, **kwargs))
        return loaded[-1]

    monkeypatch.setattr("trivsel.mesh.tetmesh.kernels", spy)
    ours = _mesh_run(method, fn, n, kw)
    assert loaded and all(isinstance(k, type(aot)) for k in loaded), "not the extension module"
    assert loaded[0].__file__.startswith(str(aot.cache_dir()))
    monkeypatch.setenv("TRIVSEL_AOT", "0")
    loaded.clear()
    numbas = _mesh_run(method, fn, n, kw)
    assert loaded and all(aot.is_jit(k) for k in loaded)
    assert len(ours) == len(numbas)
    for a, b in zip(ours, numbas):
        assert np.array_equal(a, b)


def test_insertion_kernels_fall_back_to_numbas_when_no_module_can_be_built(monkeypatch, tmp_path, caplog):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))  # no module there (numba's own cache is unchanged)

    def no_compiler(module, state, path, variant=None):
        raise OSError("no C compiler: 'cc' not found")

    monkeypatch.setattr(aot, "build", no_compiler)
    with caplog.at_level(logging.WARNING, logger="trivsel"):
        ours = _mesh_run("paper", 4, 6, dict(fractions=[0.3, 0.1]))
    assert "could not compile trivsel.mesh.entry_kernels ahead of time (no C compiler" in caplog.text
    assert len(list(tmp_path.glob("trivsel-aot/*.failed"))) == 1
    monkeypatch.setenv("TRIVSEL_AOT", "0")
    for a, b in zip(ours, _mesh_run("paper", 4, 6, dict(fractions=[0.3, 0.1]))):
        assert np.array_equal(a, b)


def test_the_mesh_state_layout_names_its_options_types():
    """The options are scalars in the state: their types are part of the layout (numba types
    a Python bool, int and float differently), and so of the module's name."""
    from trivsel.mesh import make_state

    ijk = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.int64)
    S = make_state(ijk.astype(float), np.zeros(4), ijk, pin=False)
    text = aot.layout(S)
    assert "opt:(use_int:bool,criterion:int," in text and "rel_tol:float" in text
    odd = S._replace(opt=S.opt._replace(max_rounds=np.int32(5)))
    assert aot.layout(odd) != text
    assert "max_rounds:<i4" in aot.layout(odd)


_MESH_WITHOUT_NUMBA = """
import json, sys
import numpy as np
import trivsel
from trivsel.data import sample_grid
out = []
for method in ("paper", "greedy"):
    for kw in (dict(fractions=[0.5, 0.1], values=["data", "fit"]), dict(tol_rms=0.02), dict(fractions=[0.2], final_pass=True)):
        r = trivsel.reduce(sample_grid(4, 8), method=method, **kw)
        out.append([[s.n_selected, s.errors, s.selected.tolist(), s.tets.tolist(), s.flips,
                     None if s.fit is None else s.fit["errors"]] for s in r.snapshots])
print(json.dumps({"numba": "numba" in sys.modules, "results": out}))
"""


_KERNELS = """
import importlib, json, pkgutil, numba, trivsel
from trivsel import mesh, predicates
modules = [predicates] + [importlib.import_module("trivsel.mesh." + m.name) for m in pkgutil.iter_modules(mesh.__path__)]
kernels = list({id(f): f for m in modules for f in vars(m).values()
                if isinstance(f, numba.core.registry.CPUDispatcher)}.values())
def misses():
    return {f.__name__: sum(f.stats.cache_misses.values()) for f in kernels}
def hits():
    return sum(sum(f.stats.cache_hits.values()) for f in kernels)
def run():
    out = {}
    for method in ("paper", "greedy"):
        s = trivsel.reduce(4, n=3, fractions=[0.5], method=method).snapshots[-1]
        out[method] = [s.selected.tolist(), s.tets.tolist(), s.residuals.tolist()]
    return out
"""

_DRIVERS_THEN_REDUCE = _KERNELS + """
for method in ("paper", "greedy"):
    mesh.compile_kernels(method, 2)
before = misses()
loaded = hits()
results = run()
after = misses()
print(json.dumps({"compiled": {k: v for k, v in before.items() if v}, "loaded": loaded, "results": results,
                  "then": {k: after[k] - before[k] for k in after if after[k] != before[k]},
                  "multi": [f.__name__ for f in kernels if len(f.signatures) > 1 and "orient3d" not in f.__name__]}))
"""

_REDUCE_FROM_CACHE = _KERNELS + """
results = run()
print(json.dumps({"results": results, "compiled": {k: v for k, v in misses().items() if v},
                  "loaded": sorted(f.__name__ for f in kernels if f.signatures)}))
"""


def _compile_side_by_side(part_args, env):
    """``trivsel compile`` with each of ``part_args`` in processes running at once (which must succeed)."""
    procs = [subprocess.Popen([sys.executable, "-m", "trivsel", "compile", *args], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=env) for args in part_args]
    for proc in procs:
        _, err = proc.communicate(timeout=900)
        assert proc.returncode == 0, err


@pytest.mark.slow
def test_the_workflows_compile_jobs_cover_every_reduction_with_and_without_numba(tmp_path):
    """The workflow's sequence in an empty cache: `trivsel compile --part 0` and `--part 1`
    side by side, then `--part 2` for each method.

    * It builds one extension module per method, after which `trivsel compile` returns at
      once without importing numba, and paper and greedy reductions (fitted values, a
      tolerance, the final pass) run in a process that never imports numba and builds
      nothing, with the results of numba's own kernels.
    * With numba's own kernels (``TRIVSEL_AOT=0``), part 2 compiles each method's driver
      from the kernels parts 0 and 1 left in the cache, and then a paper and a greedy
      reduction compile nothing more (numba's cache-miss counters): the parts compile the
      very signatures a reduction needs, and no kernel has a second variant (the
      predicates have an int and a float one).  A new process then loads only the
      kernels a reduction calls from Python (the helpers are inside their machine code,
      so they are not pinned one by one) and gets the same results.

    About 60 s: a cold compile, two builds and numba's drivers."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("TRIVSEL_AOT", None)
    _compile_side_by_side([["--part", "0"], ["--part", "1"]], env)
    for args in (["--part", "2"], ["--method", "greedy", "--part", "2"]):
        _python(["-m", "trivsel", "compile", *args], env)
    built = sorted((tmp_path / "cache" / "trivsel-aot").iterdir())
    # _aot_entry_kernels_{variant}_{hash}.so: one per method
    assert sorted(b.name.split(".")[0].split("_")[-2] for b in built) == ["greedy", "paper"]
    assert all(b.name.endswith(tuple(EXTENSION_SUFFIXES)) for b in built)
    # built: nothing to do, found without importing numba (the workflow's kernels jobs in a warm run)
    code = "import sys\nfrom trivsel.cli import main\nmain(['compile', '--part', '0'])\nprint('numba' in sys.modules)"
    out = _python(["-c", code], env)
    assert out.startswith("the paper kernels (part 0) were compiled already: loaded in ") and out.split()[-1] == "False"

    jit = dict(env, TRIVSEL_AOT="0")
    out = json.loads(_python(["-c", _DRIVERS_THEN_REDUCE], jit))
    # the drivers were compiled, so the cache is the test's own; the rest came from parts 0 and 1
    assert {"run_insertions", "run_greedy"} <= set(out["compiled"])
    assert out["loaded"] > 20
    assert out["then"] == {}
    assert out["multi"] == []
    warm = json.loads(_python(["-c", _REDUCE_FROM_CACHE], jit))
    assert warm["compiled"] == {}
    assert warm["results"] == out["results"]
    entries = {"_alloc", "fill_buckets", "cone_from_hull", "insert_point", "swap", "run_insertions", "run_greedy",
               "residuals", "global_pass", "point_weights"}
    assert {"swap", "run_insertions", "run_greedy"} <= set(warm["loaded"]) <= entries

    _same_without_numba(_MESH_WITHOUT_NUMBA, env, tmp_path / "cache" / "trivsel-aot", built)
