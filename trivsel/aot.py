"""Kernels compiled ahead of time, so that a process runs them without importing numba.

A process that calls numba's kernels pays before the first call, even when the machine
code comes from numba's on-disk cache: numba's import, and the initialisation of its
compiler's target (which imports scipy.linalg, among others), about half a second on the
2-core machine the benchmarks run on.  A decimation of a real scan takes two to three
seconds in all, so that is a fifth of it.  numba's ``pycc`` compiles the same Python
functions, with the same numba and LLVM, into an ordinary Python extension module that
needs neither numba nor its compiler to load.

:func:`kernels` returns the kernels of a library for a state of a given array layout.  A
library is a module of numba kernels with ``aot_exports(state_type[, variant])``: the names
Python calls them by, each with its kernel, its signature and, optionally, the Python
function to compile in its place (say, a one-line call of the kernel, so that the build
links numba's cached machine code); ``aot_prepare(state)``, when there is one, runs before
a build.  Used by ``decimate`` (:mod:`trivsel.decimation`) and by the insertion methods
(:mod:`trivsel.mesh.entries`, one module per method's driver).  :func:`kernels` gives:

1. the extension module built before for this layout, these sources, this Python, numba
   and numpy, and this machine's architecture;
2. else it builds that module (numba's ``pycc`` and a C compiler: about as long as numba's
   own first compile, once per machine) and loads it; processes that need it at the same
   time build it once (the others wait for it, :func:`_one_builder`);
3. else numba's just-in-time kernels themselves: when ``TRIVSEL_AOT=0`` or
   ``NUMBA_DISABLE_JIT=1`` is set, or the build failed (no C compiler, say; the failure
   is logged once and remembered, and ``trivsel compile`` tries again).

Both give the same results to the bit: the same functions compiled by the same numba to
the same LLVM IR, without fast-math.  The module is compiled for the architecture's
generic CPU, so it also runs where one cache directory serves machines of different CPU
models.  The extension module does not check the types of its arguments as numba's
dispatcher does, so its file name carries the exact layout of the state it was built for
(dtype, dimensions, contiguity and alignment of every array, the type of every scalar): a
state of another layout finds no module and gets its own.

Modules live in ``$NUMBA_CACHE_DIR/trivsel-aot`` when that is set, else in the package's
``__pycache__/aot`` (where numba keeps its cache), else in ``~/.cache/trivsel/aot``.  Each
change of the sources or versions builds a new module (about 1 MB), so a build keeps the
:data:`KEEP` newest modules of its library and variant and deletes the older ones (a state
layout or a Python still in use rebuilds its own if it was among them).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib
import importlib.util
import logging
import os
import platform
import shutil
import sys
import sysconfig
import tempfile
import types
from pathlib import Path

__all__ = ["kernels", "cache_dir", "layout", "is_jit"]

log = logging.getLogger("trivsel")

_PKG_DIR = Path(__file__).resolve().parent
_loaded: dict = {}
#: Modules of one library and variant kept in the cache directory (the newest; see the notes)
KEEP = 4


def enabled() -> bool:
    """Whether ahead-of-time kernels are used (``TRIVSEL_AOT=0`` or ``NUMBA_DISABLE_JIT=1``: not)."""
    if os.environ.get("TRIVSEL_AOT", "1").strip() in ("0", "false", "no", "off"):
        return False
    return os.environ.get("NUMBA_DISABLE_JIT", "0").strip() in ("", "0")


def cache_dir() -> Path:
    """Where the extension modules are kept (see the module's notes)."""
    env = os.environ.get("NUMBA_CACHE_DIR")
    if env:
        return Path(env) / "trivsel-aot"
    here = _PKG_DIR / "__pycache__"
    if os.access(here if here.is_dir() else _PKG_DIR, os.W_OK):
        return here / "aot"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "trivsel" / "aot"


def layout(state) -> str:
    """The exact layout of a state (a named tuple of arrays, and of named tuples of scalars) as
    numba types it: each array's name, dtype, dimensions, contiguity, alignment and
    writability; each scalar's name and type."""
    return ";".join(f"{name}:{_field_layout(a)}" for name, a in zip(state._fields, state))


def _field_layout(a) -> str:
    import numpy as np

    if isinstance(a, np.ndarray):
        fl = a.flags
        return f"{a.dtype.str}:{a.ndim}:{'C' if fl.c_contiguous else 'A'}:{int(fl.aligned)}:{int(fl.writeable)}"
    if isinstance(a, tuple):
        return "(" + ",".join(f"{n}:{_field_layout(x)}" for n, x in zip(getattr(a, "_fields", range(len(a))), a)) + ")"
    dtype = getattr(a, "dtype", None)  # a numpy scalar: its dtype, else the Python type
    return dtype.str if dtype is not None else type(a).__name__


def _package_version(name):
    """The bytes that identify an installed package's version, read without importing it."""
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        return b""
    root = Path(spec.origin).parent
    for candidate in ("_version.py", "version.py", "__init__.py"):
        p = root / candidate
        if p.is_file():
            return p.read_bytes()
    return b""


@functools.lru_cache(maxsize=None)
def _build_hash(module, sources) -> bytes:
    """What a build depends on besides the state's layout (read once per process)."""
    import numpy as np

    h = hashlib.sha256()
    for part in (module, sys.version, platform.machine(), np.__version__):
        h.update(part.encode() + b"\0")
    for name in ("numba", "llvmlite"):
        h.update(_package_version(name) + b"\0")
    for path in sources:
        h.update(Path(path).read_bytes() + b"\0")
    return h.digest()


def _key(module, sources, state, variant) -> str:
    h = hashlib.sha256(_build_hash(module, tuple(sources)))
    h.update(layout(state).encode() + b"\0" + str(variant).encode())
    return h.hexdigest()[:20]


def _paths(module, sources, state, variant=None):
    """The extension module's name, its file and the file that records a failed build."""
    from importlib.machinery import EXTENSION_SUFFIXES

    stem = module.rsplit(".", 1)[-1] + (f"_{variant}" if variant else "")
    name = "_aot_" + stem + "_" + _key(module, sources, state, variant)
    d = cache_dir()
    return name, d / (name + EXTENSION_SUFFIXES[0]), d / (name + ".failed")


def _prune(path, keep=None):
    """Delete all but the ``keep`` (default :data:`KEEP`) newest modules of ``path``'s library and
    variant: the files named as ``path`` but for the hash."""
    import re

    keep = KEEP if keep is None else keep
    name, suffix = path.name.split(".", 1)
    pattern = re.compile(re.escape(name.rsplit("_", 1)[0]) + r"_[0-9a-f]{20}\." + re.escape(suffix) + "$")
    found = []
    for p in path.parent.iterdir():
        if pattern.match(p.name):
            try:
                found.append((p.stat().st_mtime, p))
            except OSError:
                pass
    found.sort(reverse=True)
    for _, p in found[keep:]:
        if p != path:
            try:
                p.unlink()  # a process that has it loaded keeps its mapping
            except OSError:
                pass


def _import(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _exports(module, state, variant):
    """``module``'s exports for ``state``: name -> (numba kernel, signature[, body to compile
    ahead of time in its place, when that is not the kernel's own Python function])."""
    mod = importlib.import_module(module)
    st = _numba_type(state)
    return mod.aot_exports(st) if variant is None else mod.aot_exports(st, variant)


#: How long the notice before the one-time compile of a method's kernels says it takes, by what
#: the notice calls them (the others: ``COMPILE_TIME``); measured in docs/notes
COMPILE_TIMES = {"decimation": "1-2 min"}
COMPILE_TIME = "30-60 s"


def compile_notice(what):
    """Say on the ``trivsel`` logger, at WARNING so that it shows without any logging set
    up (and in the command line whether stderr is a terminal or not), that the kernels of
    ``what`` are being compiled, and for about how long."""
    compiled.append(what)
    log.warning("compiling the %s kernels once for this machine (about %s; later runs load them)", what,
                COMPILE_TIMES.get(what, COMPILE_TIME))


#: What :func:`compile_notice` announced in this process, in order.
compiled: list = []
#: The kernels this process waited for while another process compiled them (:func:`_one_builder`).
waited: list = []


def _label(module, variant):
    """What the notice calls the kernels of ``module``: the variant (``paper``), else the
    package they belong to (``trivsel.decimation.collapse``: ``decimation``)."""
    return variant or module.split(".")[1]


def in_cache(fn, sig) -> bool:
    """Whether numba's on-disk cache holds ``fn`` compiled for ``sig`` (a numba signature or a
    tuple of argument types) on this machine; reads the cache's index only, ``False`` if it
    cannot tell."""
    try:
        cache = fn._cache
        return cache._index_key(tuple(getattr(sig, "args", sig)), fn.targetctx.codegen()) in \
            cache._cache_file._load_index()
    except Exception:  # noqa: BLE001 - another numba's internals
        return False


def _jit(module, state, variant=None):
    exports = _exports(module, state, variant)
    ns = types.SimpleNamespace(**{k: e[0] for k, e in exports.items()})
    if hasattr(next(iter(exports.values()))[0], "py_func"):
        # numba compiles a kernel on its first call, and a run calls only some of them: the
        # notice comes with the first call of one that numba's cache does not hold
        what = _label(module, variant)
        for name, e in exports.items():
            if not in_cache(e[0], e[1]):
                setattr(ns, name, _announced(e[0], what))
    ns.JIT = True  # numba's own kernels, not an extension module
    return ns


def _announced(kernel, what):
    """``kernel`` (numba's, not in its cache yet), which says that the kernels of ``what`` are
    being compiled (:func:`compile_notice`, once a process) when it is first called."""
    def call(*args):
        if what not in compiled:
            compile_notice(what)
        return kernel(*args)

    return call


def is_jit(kernels_) -> bool:
    """Whether :func:`kernels` returned numba's just-in-time kernels (not an extension module)."""
    return bool(getattr(kernels_, "JIT", False))


def _numba_type(state):
    from numba import typeof

    return typeof(state)


def build(module, state, path, variant=None):
    """Compile ``module``'s :func:`aot_exports` for the layout of ``state`` into the extension
    module ``path`` (written whole or not at all).  ``module.aot_prepare(state)``, when the
    module has it, runs first (say, to fix the signatures of the kernels the exports call)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba.pycc's pending deprecation
        from numba.pycc import CC

    if os.name == "posix":  # before minutes of LLVM work that a missing compiler would waste
        compiler = (os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc").split()[0]
        if shutil.which(compiler) is None:
            raise OSError(f"no C compiler: {compiler!r} not found")
    prepare = getattr(importlib.import_module(module), "aot_prepare", None)
    if prepare is not None:
        prepare(state)
    exports = _exports(module, state, variant)
    path.parent.mkdir(parents=True, exist_ok=True)
    name = path.name.split(".")[0]
    with tempfile.TemporaryDirectory(prefix=name + "-", dir=path.parent) as tmp:
        cc = CC(name)
        cc.output_dir = tmp
        cc.verbose = False
        for export, entry in exports.items():
            body = entry[2] if len(entry) > 2 else entry[0].py_func
            cc.export(export, entry[1])(body)
        cc.compile()
        os.replace(os.path.join(tmp, path.name), path)


def _build_or_remember(module, state, path, failed, variant):
    """Build the module (after the compile notice); on failure, log it once and record it in
    ``failed``, so that later processes go to numba's kernels without trying again."""
    compile_notice(_label(module, variant))
    try:
        build(module, state, path, variant)
        _prune(path)
    except Exception as exc:  # noqa: BLE001 - any failure falls back to numba's JIT
        text = " ".join(str(exc).split())[:500] or type(exc).__name__
        log.warning("could not compile %s ahead of time (%s): using numba's just-in-time kernels", module, text)
        try:
            failed.parent.mkdir(parents=True, exist_ok=True)
            failed.write_text(text + "\n")
        except OSError:
            pass


@contextlib.contextmanager
def _one_builder(path, what):
    """Hold an exclusive lock on ``path``'s lock file while this process builds it, so that
    processes that start together (a workflow's jobs, a shell loop over files) build a module
    once: the others say so, wait, and load it.  ``flock`` is released when the process ends,
    however it ends.  The lock file is deleted once the module is built (a process that comes
    later finds the module and takes no lock); where there is no ``fcntl`` or the cache
    directory cannot be written, nothing is locked."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        yield
        return
    lock = path.with_name(path.name.split(".", 1)[0] + ".lock")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            waited.append(what)
            log.warning("waiting for another process that is compiling the %s kernels", what)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
        if path.exists():
            try:
                lock.unlink()
            except OSError:
                pass
    finally:
        os.close(fd)


def kernels(module, sources, state, *, variant=None, rebuild=False):
    """The kernels of ``module`` (its :func:`aot_exports`) for states of the layout of ``state``,
    as attributes: from the extension module built ahead of time, built now if need be, or
    numba's own (see the module's notes).

    Parameters
    ----------
    module : str
        The module that defines the numba kernels and ``aot_exports(state_type)``.
    sources : sequence of path
        The source files whose change must rebuild the module (the kernels' own, and every
        module whose kernels or constants they use).
    state : NamedTuple of numpy arrays
        A state of the layout the kernels will be called with.
    variant : str, optional
        Passed on as ``aot_exports(state_type, variant)``, for a module whose exports
        differ by variant (a method's driver, say); part of the extension module's name.
    rebuild : bool
        Build even if an earlier build failed (``trivsel compile``).
    """
    if not enabled():
        return _jit(module, state, variant)
    name, path, failed = _paths(module, sources, state, variant)
    if path in _loaded:
        return _loaded[path]
    if rebuild and failed.exists():
        failed.unlink()
    if not path.exists() and not failed.exists():
        with _one_builder(path, _label(module, variant)):
            if not path.exists() and not failed.exists():  # else another process built it while this one waited
                _build_or_remember(module, state, path, failed, variant)
    if path.exists():
        try:
            _loaded[path] = _import(name, path)
            return _loaded[path]
        except ImportError as exc:
            log.warning("could not load %s (%s): using numba's just-in-time kernels", path, exc)
    return _jit(module, state, variant)
