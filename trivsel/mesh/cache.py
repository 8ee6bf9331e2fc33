"""Numba's on-disk cache for the kernels of this package, invalidated by a change in any of its modules.

Numba checks a cached kernel against its own source file only.  A kernel here
calls kernels and reads constants of other modules (the counter indices of
:mod:`~trivsel.mesh.state`, the predicates of :mod:`trivsel.predicates`), and its
cached machine code contains them: after a change in one module, the kernels
of the others would load from the cache with the old callees and constants.
So every kernel of the package is stamped with one hash of all the package's
sources (and of :mod:`trivsel.predicates`): any change recompiles them all, as
for a single module.  :func:`install` puts the locators below ahead of numba's
own.  The kernel modules take numba's ``njit`` from here, so the locators are in
place before any kernel is defined; importing this module alone (for
:func:`package_stamp` and the list of sources) does not import numba.
"""

from __future__ import annotations

import glob
import hashlib
import os

_PKG_DIR = os.path.dirname(os.path.abspath(__file__))
_SOURCES = sorted(glob.glob(os.path.join(_PKG_DIR, "*.py"))) + [
    os.path.join(os.path.dirname(_PKG_DIR), "predicates.py")]
_stamp = []


def package_stamp():
    """The hash of the sources of every module whose kernels or constants the package's kernels use."""
    if not _stamp:
        h = hashlib.sha256()
        for path in _SOURCES:
            with open(path, "rb") as f:
                h.update(f.read())
        _stamp.append(h.hexdigest())
    return _stamp[0]


class _PackageStamp:
    """Mixin: for the kernels of this package, the source stamp is :func:`package_stamp`."""

    def get_source_stamp(self):
        return package_stamp()

    @classmethod
    def from_function(cls, py_func, py_file):
        if os.path.dirname(os.path.abspath(py_file)) != _PKG_DIR:
            return None
        return super().from_function(py_func, py_file)


def _locator(caching, name, legacy):
    base = getattr(caching, name, None) or getattr(caching, legacy)
    return type("Package" + name, (_PackageStamp, base), {})


LOCATORS = []  # made by install(), once


def install():
    """Put the package's locators ahead of numba's own (once)."""
    from numba.core import caching

    if not LOCATORS:
        # numba's order: a user-provided cache directory, then __pycache__, then the user-wide one
        LOCATORS.extend([_locator(caching, "UserProvidedCacheLocator", "_UserProvidedCacheLocator"),
                         _locator(caching, "InTreeCacheLocator", "_InTreeCacheLocator"),
                         _locator(caching, "UserWideCacheLocator", "_UserWideCacheLocator")])
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl")
    classes = impl._locator_classes
    if classes[:len(LOCATORS)] != LOCATORS:
        classes[:0] = LOCATORS


def njit(*args, **kwargs):
    """numba's ``njit``, after :func:`install`: every kernel of the package is defined through it."""
    install()
    from numba import njit as _njit

    return _njit(*args, **kwargs)
