"""trivsel: data point selection for piecewise trilinear approximation.

A reproduction and extension of Hamann & Chen (1994), *Data point selection for
piecewise trilinear approximation*.  Modules follow the paper:

* :mod:`trivsel.functions` - the five test functions of Table 1 (section 5);
* :mod:`trivsel.data` - point data, the grid of eq. (18), scattered input;
* :mod:`trivsel.triangulation` - initial triangulation and boundary (sections 1, 3);
* :mod:`trivsel.curvature` - absolute curvature (section 2, eqs. 4-10);
* :mod:`trivsel.selection` - ranking and stopping (section 3);
* :mod:`trivsel.methods` - the point-selection methods (``paper``, ``greedy``, ``decimate``), one
  protocol that :func:`reduce` and the block stages call;
* :mod:`trivsel.mesh` - the insertion methods' kernels: the data-dependent tetrahedral mesh (section 4);
* :mod:`trivsel.decimation` - ``decimate``'s kernels: half-edge collapses from the full grid;
* :mod:`trivsel.norms` - E_RMS and E_inf (section 5, eqs. 19-20);
* :mod:`trivsel.fitting` - least-squares vertex values on a mesh;
* :mod:`trivsel.options` - every option, defined once (:class:`Options`);
* :mod:`trivsel.reduction` - :func:`reduce`, the whole method; :mod:`trivsel.result` what it returns;
* :mod:`trivsel.io` - reading user files and objects, writing results; :mod:`trivsel.io.regions` volumes
  read by region (Zarr, ``.npy``, raw NRRD, NIfTI, functions), :mod:`trivsel.io.pieces` partitioned output
  (``.vtu`` pieces, ``.pvtu``, ``.vtm``, merging);
* :mod:`trivsel.blocks` - large grids in blocks with conforming seams (``trivsel blocks``), and
  :mod:`trivsel.blocks.faces`, the 1-D and 2-D reductions of a block's lines and faces;
* :mod:`trivsel.regression` - comparing error tables against golden ones.

``import trivsel`` is cheap: :func:`reduce` and :func:`load` import the compiled
kernel and the file readers on first use.  The studies that reproduce and measure
the paper (Table 1, figures, comparisons with VTK) live in :mod:`trivsel.study`,
which the library never imports.
"""

from .exceptions import InputError

__version__ = "0.1.0"

# Everything else on first use (PEP 562): ``import trivsel`` loads no numpy, so the
# command line handles Ctrl-C from its first moments.
_LAZY = {"Options": ("options", "Options"), "reduce": ("reduction", "reduce"),
         "ReductionResult": ("result", "ReductionResult"), "load": ("io", "load"),
         "write_outputs": ("io", "write_outputs"), "PointData": ("data", "PointData"),
         "grid_from_array": ("data", "grid_from_array"), "sample_grid": ("data", "sample_grid"),
         "scattered": ("data", "scattered"), "FUNCTIONS": ("functions", "FUNCTIONS")}
_SUBMODULES = {"aot", "blocks", "cli", "curvature", "data", "decimation", "exceptions", "fitting", "functions", "io",
               "mesh", "methods", "norms", "options", "predicates", "reduction", "regression", "resources", "result",
               "selection", "study", "triangulation"}


def __getattr__(name):
    import importlib

    if name in _LAZY:
        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(f".{module}", __name__), attr)
        globals()[name] = value
        return value
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    """The loaded names and the lazy ones (:data:`_LAZY`, the submodules), so that ``dir(trivsel)``
    and completion show ``reduce``, ``load``, ``Options`` before their first use."""
    return sorted(set(globals()) | set(_LAZY) | _SUBMODULES)


__all__ = ["InputError", "Options", "PointData", "FUNCTIONS", "sample_grid", "scattered", "grid_from_array",
           "reduce", "ReductionResult", "load", "write_outputs"]
