"""The whole method: :func:`reduce` (sections 2-5 put together).

:func:`reduce` checks the data, the options and the stopping rule once for every
method, then hands the run to the method (:mod:`trivsel.methods`): the paper's
(sections 2-4: curvature ranking, insertion, data-dependent swapping), ``greedy``
or ``decimate``.  Every method returns snapshots at the requested counts with E_RMS
and E_inf, with and without the boundary points (section 5, eqs. 19-20), and
optionally least-squares vertex values on the same mesh.
"""

from __future__ import annotations

import inspect
import numbers
import time
from dataclasses import replace

import numpy as np

from .data import PointData, sample_grid
from .exceptions import InputError, check_callable, check_count, check_threads, check_tolerance, shown
from .functions import resolve_function
from .methods import get_method
from .methods.protocol import Problem
from .options import AUTO, Options, check_applicable, choose_method, option_fields
from .result import ReductionResult, Snapshot
from .selection import validate_fractions

__all__ = ["reduce", "ReductionResult", "Snapshot"]

_STOP_PARAMS = """    data : PointData, numpy array, pyvista dataset, nibabel image, path, int or str
        The data: :class:`~trivsel.data.PointData`; a 3-D numpy array (a grid indexed
        ``[i, j, k]`` = x, y, z with origin 0 and spacing 1; place it with
        :func:`~trivsel.data.grid_from_array`); a pyvista (or VTK) dataset, image data
        as a grid with its origin and spacing, others as scattered points; a nibabel
        NIfTI image, as a ``.nii`` file is read; a :class:`pathlib.Path` to a file
        (:func:`~trivsel.io.load`); or a Table-1 function number or name (a ``str``),
        sampled on the ``(n+1)^3`` grid of eq. (18).  A pyvista dataset or file with
        tetrahedra is a mesh: ``decimate`` keeps its domain (possibly non-convex).
    fractions : sequence of float in (0, 1], optional
        Stop at these fractions of all points (fixed points included, rounded half
        up: 50 % of 4913 is 2457).  One run goes to the largest; the others are
        snapshots on the way.
    count : int, optional
        Stop at this number of points instead (also a snapshot).
    tol_rms, tol_inf : float, optional
        Error tolerances of E_RMS (eq. 19) and E_inf (eq. 20) over all points.  The
        inserting methods (``paper``, ``greedy``) stop as soon as the error is at or
        below the tolerance (or when every candidate is inserted); ``decimate`` stops
        before a removal would raise the error above it (or when no removal is
        left).  A fraction or count that the run does not reach first is noted in
        :attr:`ReductionResult.notes` and logged as a warning.
    n : int, optional
        Grid intervals per axis when ``data`` is a Table-1 function (default 16, the
        paper's); refused with other data.
    array : str, optional
        The point-data array of a pyvista dataset or file (default: a dataset's
        active scalars, or the only array).
    volume : int, optional
        The volume of a 4-D NIfTI image or file.
    boundary : (m, 3) int array, optional
        Prescribed boundary triangles of grid data (indices of its points): a closed,
        consistently oriented triangulation of the box's surface.  Section 3's start
        with these triangles instead of the 12 of the box: their vertices are fixed,
        the first interior point (the paper: the largest curvature; greedy: the one
        nearest the centre) is joined to every triangle, only interior points are
        inserted and no flip changes the boundary.  A neighbouring box given the same
        triangles on a shared face meets this mesh conformingly
        (:mod:`trivsel.blocks`).
    options : Options, optional
        Every choice of the method at once; the keyword options below override its
        fields.
    threads : int
        Threads for the curvature fits (section 2), the only stage that runs in
        parallel; the result does not depend on it.
    check : callable, optional
        Called as ``check(mesh)`` after the first insertion and at every snapshot
        (tests pass :func:`trivsel.mesh.check_mesh`).
    progress : callable, optional
        Called about 200 times as ``progress(n_selected, n_target, e_rms, e_inf,
        seconds)`` with the current E_RMS and E_inf over all points; ``n_target`` is
        the count the run goes to (up by insertion; ``decimate`` counts down to it
        from the full grid, and calls first with the full grid's count)."""


def reduce(data, *, fractions=None, count=None, tol_rms=None, tol_inf=None, n=None, array=None, volume=None,
           boundary=None, options=None, threads=1, check=None, progress=None, **option_overrides):
    t_start = time.perf_counter()
    is_function = isinstance(data, (str, numbers.Integral)) and not isinstance(data, bool)
    known = {f.name for f in option_fields()}
    for name in option_overrides:
        if name not in known:
            raise TypeError(f"reduce() got an unexpected keyword argument {name!r}")
    if option_overrides.get("method", AUTO if options is None else None) == AUTO:
        # a Table-1 function, by number or name or sampled (sample_grid), is the paper's data
        sampled = isinstance(data, PointData) and "function" in data.meta
        option_overrides["method"] = choose_method(is_function or sampled,
                                                   [k for k, v in option_overrides.items() if v is not None],
                                                   prescribed_boundary=boundary is not None)
    opts = _options(options, option_overrides)
    method = get_method(opts.method)
    if is_function:
        if array is not None or volume is not None:
            raise InputError(f"{'array' if array is not None else 'volume'}= applies to input data, "
                             "not to a Table-1 function")
        data = sample_grid(resolve_function(data), 16 if n is None else n)
    else:
        if n is not None:
            raise InputError(f"n= applies to a Table-1 function, not to input data (got n={shown(n)})")
        from .io import from_object

        data = from_object(data, array=array, volume=volume)
    method.check(data, opts)
    threads = check_threads(threads)
    fractions = validate_fractions(fractions)
    N = data.n_points
    tol_rms, tol_inf = check_tolerance("tol_rms", tol_rms), check_tolerance("tol_inf", tol_inf)
    count = check_count(count, N)
    check_callable("check", check)
    check_callable("progress", progress)
    if not fractions and count is None and tol_rms is None and tol_inf is None:
        raise InputError("give fractions, a count, or an error tolerance (tol_rms / tol_inf) to stop at")
    stop = dict(fractions=fractions, count=count, tol_rms=tol_rms, tol_inf=tol_inf)
    from .resources import check_memory

    for nbytes, what in method.memory(data, opts):
        check_memory(nbytes, what)
    data_in, stop_in = data, stop
    data, scaling = _safe_scale(data)
    problem = Problem(data=data, options=opts, stop=scaling.stop_in(stop), boundary=boundary, threads=threads,
                      check=check, progress=scaling.progress_out(progress), t_start=t_start)
    out = method.run(problem)
    out.notes[:0] = data_in.read_notes
    if data_in.cell_arrays:
        out.notes.append(f"the input's cell data ({', '.join(data_in.cell_arrays)}) is not in the output: the "
                         "reduced mesh has other cells")
    return ReductionResult(data=data_in, selected=out.selected, curvature=scaling.curvature_out(out.curvature),
                           order=out.order, snapshots=[scaling.snapshot_out(s) for s in out.snapshots],
                           options={**opts.to_dict(), **stop_in}, timings=out.timings, stats=out.stats,
                           notes=out.notes)




#: Coordinate extents within 2**+-SAFE_COORD_EXPONENT (orientation determinants are
#: cubic in them) and value magnitudes within 2**+-SAFE_VALUE_EXPONENT (sums of squared
#: residuals) are used as given; others are scaled by a power of two first.
SAFE_COORD_EXPONENT = 100
SAFE_VALUE_EXPONENT = 400


class _Scaling:
    """Exact power-of-two scale factors for coordinates (``c``) and values (``v``).

    Squares and products of values near the float limits overflow or underflow (E_RMS
    becomes inf or 0, every curvature 0, no flip changes an error), and so do the
    orientation determinants of extreme coordinates.  Multiplying by a power of two
    is exact, and the method is invariant under it: the curvature ranking (eq. 10
    scales by ``v / c**2``), the flips (section 4: sums of squared residuals scale by
    ``v**2``) and the selection are those of the unscaled data, and the errors and
    fitted values are scaled back exactly.
    """

    def __init__(self, c=1.0, v=1.0):
        self.c, self.v = float(c), float(v)

    def stop_in(self, stop):
        tol = {k: (None if stop[k] is None else stop[k] * self.v) for k in ("tol_rms", "tol_inf")}
        return {**stop, **tol}

    def progress_out(self, progress):
        if progress is None or self.v == 1.0:
            return progress
        return lambda m, target, e_rms, e_inf, seconds: progress(m, target, e_rms / self.v, e_inf / self.v, seconds)

    def curvature_out(self, K):
        return K if K is None or (self.c == 1.0 and self.v == 1.0) else K * (self.c * self.c / self.v)

    def snapshot_out(self, s):
        if self.v == 1.0:
            return s
        s.residuals = s.residuals / self.v
        s.errors = {k: e / self.v for k, e in s.errors.items()}
        if s.fit is not None:
            s.fit = {**s.fit, "values": s.fit["values"] / self.v, "residuals": s.fit["residuals"] / self.v,
                     "errors": {k: e / self.v for k, e in s.fit["errors"].items()}}
        return s


def _exponent(size):
    """``round(log2(size))``, or None for 0 (and non-finite) sizes."""
    return int(np.round(np.log2(size))) if np.isfinite(size) and size > 0.0 else None


def _safe_scale(data):
    """``data`` with coordinates and values scaled into the safe range (a copy, when
    needed), and the :class:`_Scaling` that maps the results back.

    One common factor when it brings both the coordinate extent and the values into
    the safe range: the graph of ``f`` then only changes in size, so every curvature
    of section 2 scales alike and the ranking is that of the unscaled data.  Otherwise
    (say coordinates near 1e300 and values near 1e-300) each gets its own factor.
    """
    extent = float(np.max(np.ptp(data.points, axis=0))) if data.n_points else 0.0
    ec = _exponent(extent)
    ev = _exponent(float(np.max(np.abs(data.values))) if data.n_points else 0.0)

    def safe(shift=0):
        return ((ec is None or abs(ec - shift) <= SAFE_COORD_EXPONENT)
                and (ev is None or abs(ev - shift) <= SAFE_VALUE_EXPONENT))

    if safe():
        return data, _Scaling()
    shift = ec if ec is not None and abs(ec) > SAFE_COORD_EXPONENT else ev
    if safe(shift):
        c = v = float(np.ldexp(1.0, -shift))
    else:
        c = float(np.ldexp(1.0, -ec)) if ec is not None and abs(ec) > SAFE_COORD_EXPONENT else 1.0
        v = float(np.ldexp(1.0, -ev)) if ev is not None and abs(ev) > SAFE_VALUE_EXPONENT else 1.0
    changes = {}
    if c != 1.0:
        changes["points"] = data.points * c
        if data.is_grid:
            changes["origin"] = np.asarray(data.origin, float) * c
            changes["spacing"] = np.asarray(data.spacing, float) * c
    if v != 1.0:
        changes["values"] = data.values * v
    return replace(data, **changes), _Scaling(c, v)


def _options(options, overrides):
    """One validated, method-resolved :class:`Options` from ``options`` and keyword overrides."""
    if options is None:
        options = Options()
    elif not isinstance(options, Options):
        raise InputError(f"options must be a trivsel.Options, got {type(options).__name__}")
    unknown = sorted(set(overrides) - {f.name for f in option_fields()})
    if unknown:
        raise TypeError(f"reduce() got an unexpected keyword argument {unknown[0]!r}")
    merged = replace(options, **overrides) if overrides else options
    # a keyword given is a setting, even at its default value
    check_applicable([k for k, v in overrides.items() if v is not None], merged.method)
    return merged.resolve()


def _option_docs():
    """The numpydoc entries of the option keywords, generated from :class:`Options` and
    grouped by the methods they apply to (:func:`~trivsel.options.option_groups`)."""
    from .options import _choices, _default_text, group_title, option_groups

    out = []
    for methods, group in option_groups():
        for f in group:
            meta = f.metadata
            kind = ("{" + ", ".join(repr(c) for c in _choices(f)) + "}" if meta["kind"] == "choice"
                    else meta["kind"])
            if meta["sequence"]:
                kind = f"list of {kind}"
            ref = f" ({meta['paper']})" if meta["paper"] else ""
            out.append(f"    {f.name} : {kind}, default {_default_text(f)}; {group_title(methods)}\n"
                       f"        {meta['doc']}{ref}.")
    return "\n".join(out)


reduce.__doc__ = f"""Select points and build the data-dependent tetrahedral mesh (Hamann & Chen 1994).

    Parameters
    ----------
{_STOP_PARAMS}

    Other Parameters
    ----------------
{_option_docs()}

    Returns
    -------
    ReductionResult

    Raises
    ------
    InputError
        For bad data, fractions, counts, tolerances or options, with a one-line
        message naming the value.

    Notes
    -----
    Each option applies to the methods named after its default ("every method",
    "method paper only", ...); giving it for another method raises InputError.
    """


def _signature():
    params = [p for p in inspect.signature(reduce).parameters.values() if p.kind != p.VAR_KEYWORD]
    # method="auto": the method of the data (``choose_method``), the paper's for a Table-1 function
    params += [inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY,
                                 default=AUTO if f.name == "method" else f.default)
               for f in option_fields()]
    return inspect.Signature(params)


reduce.__signature__ = _signature()
