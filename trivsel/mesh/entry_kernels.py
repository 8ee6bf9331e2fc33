"""The export bodies of :mod:`trivsel.mesh.entries`'s extension module, and what its build calls
(:func:`aot_exports`, :func:`aot_prepare`; see :mod:`trivsel.aot`)."""

from __future__ import annotations

from .compile import _pin, entry_signatures, helper_signatures
from .drivers import residuals
from .insertion import cone_from_hull, insert_point
from .storage import _alloc, fill_buckets
from .swap import swap

VARIANTS = ("paper", "greedy")


# One-line export bodies: each calls numba's kernel, whose machine code the build links in
def _swap_export(S, seed, nseed, with_neighbours, max_rounds):
    return swap(S, seed, nseed, with_neighbours, max_rounds)


def _insert_point_export(S, p):
    return insert_point(S, p)


def _cone_from_hull_export(S, p):
    return cone_from_hull(S, p)


def _alloc_export(S):
    return _alloc(S)


def _fill_buckets_export(S, ids):
    return fill_buckets(S, ids)


def _residuals_export(S, out):
    return residuals(S, out)


_BODIES = {swap: _swap_export, insert_point: _insert_point_export, cone_from_hull: _cone_from_hull_export,
           _alloc: _alloc_export, fill_buckets: _fill_buckets_export, residuals: _residuals_export}


def aot_exports(state_type, variant):
    """The entry kernels (:func:`~trivsel.mesh.compile.entry_signatures`) of the method kernel
    ``variant`` for states of numba type ``state_type``, by name: (kernel, signature) or
    (kernel, signature, export body)."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown mesh kernel {variant!r}: choose 'paper' or 'greedy'")
    out = {}
    for fn, sig in entry_signatures(state_type, variant):
        body = _BODIES.get(fn)
        out[fn.__name__] = (fn, sig) if body is None else (fn, sig, body)
    return out


def aot_prepare(S):
    """Before a build: compile (or load) every helper for its one signature, so that the
    kernels the exports call are the ones numba's cache holds (:mod:`trivsel.mesh.compile`)."""
    for fn, sig in helper_signatures(S):
        _pin(fn, sig)
