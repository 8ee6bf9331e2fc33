"""Bottom-up selection (beyond the paper): half-edge collapses from the full grid.

Start from every grid point and remove, one at a time, the vertex whose removal by a
half-edge collapse onto a neighbouring point raises the sum of squared residuals
(the numerator of E_RMS, eq. 19) least, until the count, fraction or tolerance is
reached (:mod:`trivsel.decimation`).  The vertices stay data points: the result is a
true selection, with the data values at its vertices (or fitted ones with
``values="fit"``).  Aims at E_RMS, or with ``criterion="max"`` at E_inf (the
collapse that leaves the smallest largest residual first); grid data only.  The
options of curvature, ranking and swapping do not apply.
"""

from __future__ import annotations

from ..exceptions import InputError

NAME = "decimate"
#: No insertion and no swapping: the swap options do not apply (they stay None).
DEFAULTS = {"criterion": "sse"}
GREEDY_QUEUE = False
KERNEL = "decimate"
#: reduce() hands the whole run to :func:`trivsel.decimation.reduce_by_collapse`.
DECIMATES = True


def needs_curvature(options):
    return False


def check_options(options):
    """The criterion orders the collapses: ``sse`` (the default) by the change of the squared
    error, ``max`` by the largest residual of the points that move; not ``rms``."""
    if options.criterion == "rms":
        raise InputError("method 'decimate' orders collapses by criterion 'sse' (E_RMS) or 'max' (E_inf), "
                         "got 'rms'")


def check(data, options):
    """Grid data only (the collapses are tested on integer grid coordinates)."""
    if not data.is_grid:
        raise InputError("method 'decimate' needs grid data (a .vti, NIfTI, NRRD or array volume); "
                         "scattered points: use 'greedy' or 'paper'")
