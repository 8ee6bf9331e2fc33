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

from trivsel import aot
from trivsel import decimation as dm
from trivsel.data import sample_grid


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
    assert hasattr(dec._k.run, "signatures")  # numba's dispatcher
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


def test_a_failed_build_falls_back_to_numba_once_and_is_tried_again_by_compile(monkeypatch, tmp_path, caplog):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    calls = []

    def no_compiler(module, state, path):
        calls.append(path)
        raise OSError("command 'gcc' failed: No such file or directory")

    monkeypatch.setattr(aot, "build", no_compiler)
    data = sample_grid(4, 6)
    with caplog.at_level(logging.INFO, logger="trivsel"):
        dec = dm.Decimation(data.ijk, data.shape, data.values)
    assert len(calls) == 1
    assert hasattr(dec._k.run, "signatures")  # numba's kernels
    assert "could not compile trivsel.decimation_kernels ahead of time (command 'gcc' failed" in caplog.text
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
    assert hasattr(dec._k.run, "signatures")
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
    assert hasattr(dec._k.run, "signatures")
    assert f"could not load {path}" in caplog.text
    assert dec.run(20) == 0


@pytest.mark.parametrize("env", [{"TRIVSEL_AOT": "0"}, {"NUMBA_DISABLE_JIT": "1"}, {"TRIVSEL_AOT": "off"}])
def test_switched_off(monkeypatch, env):
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    assert not aot.enabled()
    monkeypatch.delenv("TRIVSEL_AOT", raising=False)
    monkeypatch.delenv("NUMBA_DISABLE_JIT", raising=False)
    assert aot.enabled()


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


@pytest.mark.slow
def test_compile_builds_what_a_decimation_runs_and_a_run_needs_no_numba(tmp_path):
    """After `trivsel compile --method decimate` in an empty cache, decimations with lazy and
    exact updates, both criteria and fitted values run in a process that never imports numba,
    build nothing more, and give the results of numba's own kernels.  About 40 s: a cold
    compile."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("TRIVSEL_AOT", None)
    p = subprocess.run([sys.executable, "-m", "trivsel", "compile", "--method", "decimate"], capture_output=True,
                       text=True, timeout=900, env=env)
    assert p.returncode == 0, p.stderr
    built = sorted((tmp_path / "cache" / "trivsel-aot").iterdir())
    assert len(built) == 1 and built[0].name.endswith(tuple(EXTENSION_SUFFIXES))
    p = subprocess.run([sys.executable, "-c", _DECIMATE_WITHOUT_NUMBA], capture_output=True, text=True,
                       timeout=900, env=env)
    assert p.returncode == 0, p.stderr
    ours = json.loads(p.stdout)
    assert ours["numba"] is False
    assert sorted((tmp_path / "cache" / "trivsel-aot").iterdir()) == built
    p = subprocess.run([sys.executable, "-c", _DECIMATE_WITHOUT_NUMBA], capture_output=True, text=True,
                       timeout=900, env=dict(env, TRIVSEL_AOT="0"))
    assert p.returncode == 0, p.stderr
    numbas = json.loads(p.stdout)
    assert numbas["numba"] is True
    assert numbas["results"] == ours["results"]
