"""Approximation errors (section 5, eqs. 19-20).

``E_RMS = sqrt(sum d^2 / N)`` and ``E_inf = max |d|`` over all original points,
``d = f - L`` with ``L`` the linear interpolant of the tetrahedron containing the
point.  The "without boundary" values (the starred column of Table 1) use only the
points off the domain boundary, normalised by their own count ((n - 1)^3 on an
(n + 1)^3 grid).
"""

from __future__ import annotations

import numpy as np

__all__ = ["total_rms_error", "total_max_error", "error_norms", "face_residual_rms"]


def total_rms_error(residuals, mask=None) -> float:
    """E_RMS of eq. (19) over all points, or over ``mask`` normalised by its own count
    (NaN when there is no point to measure, e.g. no interior point)."""
    r = np.asarray(residuals, float)
    if mask is not None:
        r = r[np.asarray(mask, bool)]
    return float(np.sqrt(np.mean(r * r))) if r.size else float("nan")


def total_max_error(residuals, mask=None) -> float:
    """E_inf of eq. (20) over all points, or over ``mask`` (NaN when it selects no point)."""
    r = np.asarray(residuals, float)
    if mask is not None:
        r = r[np.asarray(mask, bool)]
    return float(np.max(np.abs(r))) if r.size else float("nan")


def error_norms(residuals, interior_mask) -> dict:
    """The four numbers of a Table-1 row: E_rms, E_rms_interior, E_inf, E_inf_interior."""
    return {
        "E_rms": total_rms_error(residuals),
        "E_rms_interior": total_rms_error(residuals, interior_mask),
        "E_inf": total_max_error(residuals),
        "E_inf_interior": total_max_error(residuals, interior_mask),
    }


def face_residual_rms(e_rms, e_rms_interior, n_all, n_interior) -> float:
    """RMS residual on the boundary points implied by a pair (E_rms, E_rms*).

    From ``E_rms^2 n_all = E_rms*^2 n_interior + e_face^2 (n_all - n_interior)``
    (e.g. 4913 = 3375 + 1538 on the 17^3 grid).  Returns NaN when the pair is
    inconsistent (negative implied sum).
    """
    s = e_rms**2 * n_all - e_rms_interior**2 * n_interior
    nb = n_all - n_interior
    return float(np.sqrt(s / nb)) if s >= 0 and nb > 0 else float("nan")


class ErrorSums:
    """The four numbers of :func:`error_norms`, accumulated over chunks of residuals (``add``),
    so that the residuals of every point need not be in memory at once."""

    def __init__(self):
        self.sse = self.sse_in = 0.0
        self.n = self.n_in = 0
        self.max = self.max_in = float("-inf")

    def add(self, residuals, interior_mask):
        r = np.abs(np.asarray(residuals, float))
        m = np.asarray(interior_mask, bool)
        self.sse += float(np.sum(r * r))
        self.n += r.size
        ri = r[m]
        self.sse_in += float(np.sum(ri * ri))
        self.n_in += ri.size
        if r.size:
            self.max = max(self.max, float(r.max()))
        if ri.size:
            self.max_in = max(self.max_in, float(ri.max()))

    def to_array(self):
        """The sums as six numbers (``add_sums`` adds them to another's)."""
        return np.array([self.sse, self.n, self.sse_in, self.n_in, self.max, self.max_in], np.float64)

    def add_sums(self, sums):
        """Add the sums of another chunk of residuals (an array of :meth:`to_array`)."""
        sse, n, sse_in, n_in, mx, mx_in = (float(x) for x in sums)
        self.sse += sse
        self.n += int(n)
        self.sse_in += sse_in
        self.n_in += int(n_in)
        self.max, self.max_in = max(self.max, mx), max(self.max_in, mx_in)

    def norms(self) -> dict:
        nan = float("nan")
        return {"E_rms": float(np.sqrt(self.sse / self.n)) if self.n else nan,
                "E_rms_interior": float(np.sqrt(self.sse_in / self.n_in)) if self.n_in else nan,
                "E_inf": self.max if self.n else nan, "E_inf_interior": self.max_in if self.n_in else nan}
