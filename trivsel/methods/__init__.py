"""Point-selection methods: a registry of modules with one small protocol.

A method is a module that defines

``NAME``
    its name (the ``method`` option);
``DEFAULTS``
    its values for the options whose default depends on the method (the
    :class:`~trivsel.options.Options` fields that default to ``None``);
``GREEDY_QUEUE``
    whether the mesh keeps the per-tetrahedron candidate queue of error-driven
    insertion (:class:`~trivsel.mesh.TetMesh`'s ``greedy``);
``KERNEL``
    which driver :func:`trivsel.mesh.compile_kernels` compiles (into the extension module of
    :mod:`trivsel.mesh.entries`) for it;
``check_options(options)``, optional
    raises :class:`~trivsel.exceptions.InputError` for option values the method cannot
    take whatever the data (:class:`~trivsel.options.Options` calls it);
``needs_curvature(options) -> bool``
    whether :func:`rank` needs the curvature graph of all points (on scattered data
    that is a Delaunay triangulation of every point);
``rank(data, candidates, options, *, tets, threads) -> (K, order)``
    the absolute curvature of every point (or ``None``) and the candidates in
    insertion order (a method that chooses as it goes returns them unordered);
``advance(mesh, order, done, stop, tol_rms) -> (done, inserted)``
    insert candidates into the mesh, with swapping, until ``stop`` of them are in
    (or the RMS tolerance is met, or nothing is left to improve), and return the
    new count and the points inserted, in order.

A method that defines ``DECIMATES = True`` (``decimate``) removes points from the full
grid instead of inserting them; :func:`trivsel.reduce` hands it the whole run.

Adding a method is one module here and one line in :data:`METHODS`.
"""

from __future__ import annotations

from ..exceptions import InputError, shown
from . import decimate, greedy, paper

__all__ = ["METHODS", "get_method"]

#: name -> method module, in the order the docs list them (the first is the default).
METHODS = {paper.NAME: paper, greedy.NAME: greedy, decimate.NAME: decimate}


def get_method(name):
    """The method module called ``name``; one-line InputError for an unknown name."""
    try:
        return METHODS[name]
    except (KeyError, TypeError):
        raise InputError(f"unknown method {shown(name)}: choose one of {', '.join(METHODS)}") from None
