"""trivsel: data point selection for piecewise trilinear approximation.

A reproduction and extension of Hamann & Chen (1994), *Data point selection for
piecewise trilinear approximation*.  Modules follow the paper:

* :mod:`trivsel.data` - the test functions and the grid of section 5 (eq. 18);
* :mod:`trivsel.triangulation` - initial triangulation and boundary (sections 1, 3);
* :mod:`trivsel.curvature` - absolute curvature (section 2, eqs. 4-10);
* :mod:`trivsel.selection` - ranking and stopping (section 3);
* :mod:`trivsel.mesh` - the data-dependent tetrahedral mesh (section 4);
* :mod:`trivsel.errors` - E_RMS and E_inf (section 5, eqs. 19-20).
"""

from .errors_input import InputError
from .data import sample_grid, scattered, grid_from_array, PointData, FUNCTIONS

__version__ = "0.1.0"


def reduce(*args, **kwargs):
    """Select points and build the data-dependent mesh; see :func:`trivsel.reduction.reduce`."""
    from .reduction import reduce as _reduce

    return _reduce(*args, **kwargs)


__all__ = ["InputError", "sample_grid", "scattered", "grid_from_array", "PointData", "FUNCTIONS", "reduce"]
