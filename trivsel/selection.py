"""Data point selection (section 3): fixed points, candidates, ranking and stopping counts.

* Fixed points ``B*`` (eq. 11): for a box-shaped grid only its 8 corners (the
  redundant boundary points are removed, section 5); for scattered data the
  vertices of the convex hull.
* Candidates ``I* = X* \\ B*`` (eq. 12): by default **all** other points, the
  non-corner points on the box's faces and edges included.  Table 1 requires this:
  with corners only, the faces' interpolant never changes and E_RMS could not fall
  below about 0.31/0.20/0.14/0.13/0.13 for f1-f5 (see
  ``shared/paper/what-table1-implies.md``).  ``candidates="interior"`` ranks only the
  points off the domain boundary, as the text of section 3 reads.
* Ranking: descending absolute curvature K (eq. 10).  K is quantised first
  (relative step ``quantum``) so that values equal up to rounding noise stay ties;
  ties are broken by a documented stable order (``tie_order``).
* Counts: a fraction of *all* points, fixed points included, rounded half up
  (50 % of 4913 is 2457).
"""

from __future__ import annotations

from collections.abc import Mapping
from decimal import ROUND_HALF_UP, Decimal

import numpy as np

from .exceptions import InputError, is_real, shown

__all__ = ["count_for_fraction", "validate_fractions", "candidate_points", "rank_candidates", "TIE_ORDERS"]

TIE_ORDERS = ("index", "reverse", "random", "centre")


def validate_fractions(fractions):
    """Check every fraction is a number in (0, 1]; return them as floats."""
    if fractions is None:
        return []
    if isinstance(fractions, (str, bytes, Mapping)):  # a string's characters or a dict's keys are no fractions
        raise InputError(f"fractions must be a number or a sequence of numbers, got {shown(fractions)}")
    try:
        seq = list(fractions)
    except TypeError:
        seq = [fractions]
    out = []
    for f in seq:
        if not is_real(f):
            raise InputError(f"fraction {shown(f)} is not a number")
        v = float(f)
        if not (0.0 < v <= 1.0) or v != v:
            raise InputError(f"fraction {shown(f)} is outside (0, 1]")
        out.append(v)
    return out


def count_for_fraction(fraction: float, n_points: int) -> int:
    """Number of points for a fraction of all points, rounded half up (2457 for 0.5 * 4913)."""
    q = (Decimal(repr(float(fraction))) * Decimal(int(n_points))).quantize(Decimal(1), rounding=ROUND_HALF_UP)
    return int(q)


def candidate_points(n_points: int, fixed, interior_mask=None, mode: str = "all") -> np.ndarray:
    """Indices of the points that may be selected (eq. 12), ascending.

    ``mode="all"``: every point except the fixed ones.  ``mode="interior"``: only
    points not on the domain boundary (needs ``interior_mask``).
    """
    keep = np.ones(n_points, bool)
    keep[np.asarray(fixed, np.int64)] = False
    if mode == "interior":
        keep &= np.asarray(interior_mask, bool)
    elif mode != "all":
        raise InputError(f"unknown candidate set {shown(mode)}: choose 'all' or 'interior'")
    return np.flatnonzero(keep)


def rank_candidates(curvature, candidates, *, tie_order: str = "index", points=None, seed: int = 0,
                    quantum: float = 1e-9) -> np.ndarray:
    """Candidates in insertion order: descending quantised curvature, then ``tie_order``.

    Parameters
    ----------
    curvature : (N,) float
        Absolute curvature K of every point (eq. 10).
    candidates : (M,) int
        Indices allowed for selection.
    tie_order : {"index", "reverse", "random", "centre"}
        How points of equal (quantised) curvature are ordered: ascending point
        index (C order over (i, j, k), the default), descending index, a seeded
        random permutation, or ascending distance to the centroid of ``points``
        (then index).
    quantum : float
        Relative quantisation step: ``K`` is rounded to multiples of
        ``quantum * max(K)`` before sorting.
    """
    K = np.asarray(curvature, float)
    c = np.asarray(candidates, np.int64)
    kmax = float(np.max(np.abs(K[c]))) if len(c) else 0.0
    step = quantum * kmax if kmax > 0 else 1.0
    key = np.round(K[c] / step).astype(np.int64)
    if tie_order == "index":
        tie = c
    elif tie_order == "reverse":
        tie = -c
    elif tie_order == "random":
        tie = np.random.default_rng(seed).permutation(len(c))
    elif tie_order == "centre":
        p = np.asarray(points, float)
        d = np.linalg.norm(p[c] - p.mean(axis=0), axis=1)
        tie = np.round(d / (1e-9 * max(d.max(), 1e-300))).astype(np.int64) * (len(c) + 1) + np.arange(len(c))
    else:
        raise InputError(f"unknown tie order {shown(tie_order)}: choose one of {', '.join(TIE_ORDERS)}")
    order = np.lexsort((tie, -key))
    return c[order]
