"""Point-selection methods: a registry of modules with one protocol.

:func:`trivsel.reduce` and the block stages (:mod:`trivsel.blocks`) call every method
through the same few names.  A method is a module that defines

``NAME``
    its name (the ``method`` option);
``DEFAULTS``
    its values for the options whose default depends on the method (the
    :class:`~trivsel.options.Options` fields that default to ``None``);
``PRESCRIBED_BOUNDARY``
    whether it can start from prescribed boundary triangles (``reduce(boundary=...)``,
    which the 3-D stage of ``trivsel blocks`` uses);
``check(data, options)``
    a one-line :class:`~trivsel.exceptions.InputError` for option combinations it
    cannot run on ``data``;
``check_options(options)``, optional
    a one-line InputError for option values the method cannot take whatever the data
    (:class:`~trivsel.options.Options` calls it);
``memory(data, options) -> [(bytes, what), ...]``
    its peak memory, checked against what is available before any work;
``run(problem) -> MethodRun``
    the whole run on a checked :class:`~trivsel.methods.protocol.Problem`, returning
    a :class:`~trivsel.methods.protocol.MethodRun` (snapshots, selection, counters);
``compile_kernels(part=None) -> int``
    compile (or load) its kernels once per machine (``trivsel compile``).

The insertion methods (``paper``, ``greedy``; ``INSERTS = True``: the insertion and swap
options of :class:`~trivsel.options.Options` apply to them) share the top-down run of
:mod:`trivsel.methods.insertion` and the kernels of :mod:`trivsel.mesh`, and define
for it ``GREEDY_QUEUE`` (whether the mesh keeps the per-tetrahedron candidate queue of
error-driven insertion), ``KERNEL`` (the driver compiled into
:mod:`trivsel.mesh.entries`), ``needs_curvature``, ``rank``, ``start`` and ``advance``.
``decimate`` removes points from the full mesh (a grid's Kuhn split, the Delaunay
tetrahedra of scattered points, or a mesh's own tetrahedra) with the kernels of
:mod:`trivsel.decimation`.

``method="auto"`` is not a module: :func:`trivsel.options.choose_method` resolves it
before the options are checked.

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
