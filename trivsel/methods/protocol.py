"""What :func:`trivsel.reduce` hands a method, and what the method gives back.

:func:`trivsel.reduce` checks the data, the options and the stopping rule once, for
every method, scales extreme data into the safe range, and calls the method's
``run`` with a :class:`Problem`.  The method answers with a :class:`MethodRun`;
``reduce`` scales it back and returns a :class:`~trivsel.result.ReductionResult`.
The block stages (:mod:`trivsel.blocks`) go through the same call.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..selection import count_for_fraction

__all__ = ["Problem", "MethodRun", "target_counts", "requested_fractions", "unreached"]


@dataclass
class Problem:
    """One reduction, checked.

    Attributes
    ----------
    data : PointData
        The points and values (scaled into the safe range, see :func:`trivsel.reduce`).
    options : Options
        Every option, the method's defaults resolved.
    stop : dict
        ``fractions`` (list of float), ``count`` (int or None), ``tol_rms`` and
        ``tol_inf`` (float or None, in the units of ``data``).
    boundary : (m, 3) int array or None
        Prescribed boundary triangles (grid data), as :func:`trivsel.reduce` takes them.
    threads : int
        Threads for the stages that run in parallel.
    check : callable or None
        ``check(mesh)`` at the first step and at every snapshot.
    progress : callable or None
        ``progress(n_selected, n_target, e_rms, e_inf, seconds)``.
    t_start : float
        ``time.perf_counter()`` at the start of the run.
    """

    data: object
    options: object
    stop: dict
    boundary: np.ndarray | None = None
    threads: int = 1
    check: Callable | None = None
    progress: Callable | None = None
    t_start: float = 0.0

    def targets(self):
        """The point counts to stop at, ascending: each fraction's and ``count``."""
        return target_counts(self.stop["fractions"], self.stop["count"], self.data.n_points)


@dataclass
class MethodRun:
    """What a method's ``run`` returns (in the units of :attr:`Problem.data`).

    Attributes
    ----------
    snapshots : list of Snapshot
        Ascending by point count.
    selected : (m,) int
        The points of the largest snapshot, in the order a selection grows:
        ``selected[:k]`` is the selection of a snapshot with ``k`` points.
    curvature : (N,) float or None
        Absolute curvature of every point, for a method that ranks by it.
    order : (M,) int
        The candidates in ranked or inserted order (the removed points, last removed
        first, for a method that removes points).
    timings : dict
        Seconds for ``curvature``, ``selection``, ``errors`` and ``total``.
    stats : dict
        The method's counters (flips, collapses, tetrahedra).
    notes : list of str
        The requested counts the run did not reach, and why (:func:`unreached`).
    """

    snapshots: list
    selected: np.ndarray
    curvature: np.ndarray | None
    order: np.ndarray
    timings: dict
    stats: dict
    notes: list = field(default_factory=list)


def target_counts(fractions, count, n_points):
    """The point counts to stop at, ascending: each fraction's (rounded half up) and ``count``."""
    counts = {count_for_fraction(f, n_points) for f in fractions}
    if count is not None:
        counts.add(int(count))
    return sorted(counts)


def requested_fractions(snapshots, fractions, n_points):
    """Label the snapshots that hit a requested fraction's count with that fraction as
    requested (not ``m / N``)."""
    req = {count_for_fraction(f, n_points): f for f in fractions}
    for s in snapshots:
        if s.n_selected in req:
            s.fraction = req[s.n_selected]



def unreached(stop, n_points, stopped_at, reason, *, up):
    """One note, logged as a warning, per fraction or count of ``stop`` that a run stopping at
    ``stopped_at`` points did not reach (counting ``up`` by insertion, else down)."""
    asked = [(f"fraction {f:g} ({count_for_fraction(f, n_points)} points)", count_for_fraction(f, n_points))
             for f in stop["fractions"]]
    if stop["count"] is not None:
        asked.append((f"count {int(stop['count'])}", int(stop["count"])))
    notes = []
    for what, m in asked:
        if (m > stopped_at) if up else (m < stopped_at):
            notes.append(f"{what} not reached: the run stopped at {stopped_at} points ({reason})")
            logging.getLogger("trivsel").warning("warning: %s", notes[-1])
    return notes
