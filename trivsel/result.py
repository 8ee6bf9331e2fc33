"""What a reduction returns: :class:`ReductionResult` and its :class:`Snapshot` s.

Every method (:mod:`trivsel.methods`) produces the same result: the snapshots at the
requested counts, each with its mesh over the original point indices, the residuals
and E_RMS / E_inf with and without the boundary points (section 5, eqs. 19-20).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .exceptions import InputError, is_real, shown

__all__ = ["Snapshot", "ReductionResult"]


@dataclass
class Snapshot:
    """The mesh when ``n_selected`` points are selected.

    ``tets`` index the original points; ``errors`` holds E_rms, E_rms_interior,
    E_inf, E_inf_interior; ``seconds`` is the wall time from the start of the run
    until this snapshot (curvature included).
    """

    fraction: float
    n_selected: int
    selected: np.ndarray
    tets: np.ndarray
    residuals: np.ndarray
    errors: dict
    seconds: float
    flips: dict = field(default_factory=dict)
    fit: dict | None = None  # values="fit": {"values": (m,) at sorted vertices, "residuals", "errors"}


@dataclass
class ReductionResult:
    """What :func:`reduce` returns.

    Attributes
    ----------
    data : PointData
    selected : (m,) int
        Selected point indices in insertion order: fixed points first, then the
        candidates as inserted (``selected[:k]`` is the selection of size k).
    curvature : (N,) float or None
        Absolute curvature K of every point (eq. 10); None for a method that does
        not rank by curvature (``greedy`` chooses points by their error).
    order : (M,) int
        The candidates in ranked order (``greedy``: the points as inserted).
    snapshots : list of Snapshot
        One per requested fraction/count, ascending by count.
    options : dict
        Every option used (:class:`~trivsel.options.Options`, method defaults
        resolved) and the stopping rule (``fractions``, ``count``, ``tol_rms``,
        ``tol_inf``).
    timings : dict
        Seconds for ``curvature``, ``selection`` (insertion and swapping),
        ``errors``, and ``total``.
    stats : dict
        Insertion cases and flip counts at the end of the run.
    notes : list of str
        What the run could not do as asked: each requested fraction or count that it
        did not reach (a tolerance stopped it first, or no point was left to insert or
        remove), with the count it stopped at.  Also logged as warnings.
    """

    data: PointData
    selected: np.ndarray
    curvature: np.ndarray | None
    order: np.ndarray
    snapshots: list
    options: dict
    timings: dict
    stats: dict
    notes: list = field(default_factory=list)

    def snapshot(self, fraction):
        """The snapshot for ``fraction`` (nearest match)."""
        if not is_real(fraction) or fraction != fraction:
            raise InputError(f"fraction must be a number, got {shown(fraction)}")
        return min(self.snapshots, key=lambda s: abs(s.fraction - float(fraction)))

    def to_pyvista(self, fraction=None):
        """The mesh of the snapshot for ``fraction`` (nearest match; default the last, largest)
        as a ``pyvista.UnstructuredGrid`` of tetrahedra: the same points, cells, point arrays
        (``value``, ``original_index``, ``curvature``, ``fitted_value`` with
        ``values=["data", "fit"]``) and field data as ``mesh_<fraction>.vtu`` of
        ``trivsel reduce`` (:func:`trivsel.io.snapshot_to_vtk` builds both)."""
        from .io import snapshot_to_pyvista

        return snapshot_to_pyvista(self, self.snapshots[-1] if fraction is None else self.snapshot(fraction))

    def errors_frame(self):
        """One row per snapshot with the columns of ``errors.csv``, as a pandas DataFrame.

        No wall times: two runs with the same input and options give the same table
        (the times are in ``result.json``: ``snapshots[*].seconds`` and ``timings``)."""
        import pandas as pd

        return pd.DataFrame(self.error_rows())

    def error_rows(self):
        """The rows of :meth:`errors_frame` as a list of dicts (column order kept).

        The data's columns: ``function`` and ``n`` (the Table-1 function and its grid
        intervals per axis) for a function grid, empty otherwise; ``input`` (the data's
        name: a file's name without its suffix, or the name given to
        :func:`~trivsel.data.grid_from_array`), empty for a function grid; ``n_points``,
        the number of points of the data."""
        meta = self.data.meta
        function = "function" in meta
        rows = []
        for mode in self.options.get("values", ["data"]):
            for s in self.snapshots:
                err = s.errors if mode == "data" else s.fit["errors"]
                rows.append({
                    "function": meta["function"] if function else "",
                    "n": meta["n"] if function else "",
                    "input": "" if function else self.data.name,
                    "n_points": self.data.n_points,
                    "method": self.options["method"],
                    "values": mode,
                    "fraction": s.fraction,
                    "n_selected": s.n_selected,
                    **{k: err[k] for k in ("E_rms", "E_rms_interior", "E_inf", "E_inf_interior")},
                })
        return rows
