"""Reading user data and writing results.

Input formats (:func:`load`):

* ``.vti`` (VTK image data) and legacy ``.vtk`` files holding structured points:
  a regular grid; it takes the exact integer path and keeps its origin and spacing;
* ``.vtu``, ``.vtp``, ``.vts``, ``.vtr`` and other legacy ``.vtk`` datasets:
  scattered points with a point-data array;
* ``.npz``: either ``points`` (N x 3) and ``values`` (N), or a 3-D array ``values``
  (indexed [i, j, k] = x, y, z) with optional ``origin`` and ``spacing``;
* ``.csv``: columns ``x, y, z`` and a value column (``value`` or ``--array NAME``).

Outputs (:func:`write_outputs`) go first to a temporary folder inside the target
and are moved into place only when all of them are complete, so a failure never
leaves partial or corrupt files; a manifest lists what trivsel wrote, so a new run
replaces exactly the files of the previous one and never touches an input.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .data import PointData, grid_from_array, scattered
from .exceptions import InputError

__all__ = ["READERS", "MANIFEST", "load", "save_npz", "check_output_dir", "write_outputs", "snapshot_to_pyvista",
           "fraction_label"]


def fraction_label(fraction: float) -> str:
    """How a fraction appears in file names: ``f"{fraction:g}"`` (``mesh_0.5.vtu``)."""
    return f"{float(fraction):g}"


def _pick_array(names, array, path):
    names = list(names)
    if array is not None:
        if array not in names:
            raise InputError(f"array {array!r} not found in {path}; available: {', '.join(names) or 'none'}")
        return array
    if len(names) == 1:
        return names[0]
    if not names:
        raise InputError(f"{path} has no point-data array to reduce")
    raise InputError(f"{path} has several point-data arrays ({', '.join(names)}); choose one with --array")


def _read_csv(p, array):
    """Scattered points from columns ``x, y, z`` and a value column (``value`` or ``array``)."""
    import pandas as pd

    try:
        df = pd.read_csv(p)
    except Exception as exc:  # pandas raises many types
        raise InputError(f"cannot read CSV {str(p)!r}: {exc}") from None
    cols = {c.strip().lower(): c for c in df.columns}
    missing = [c for c in ("x", "y", "z") if c not in cols]
    if missing:
        raise InputError(f"CSV {str(p)!r} lacks column(s) {', '.join(missing)}; need x, y, z and a value column")
    others = [c for c in df.columns if c.strip().lower() not in ("x", "y", "z")]
    if array is None and "value" in cols:
        array = cols["value"]
    col = _pick_array(others, array, p)
    try:
        pts = df[[cols["x"], cols["y"], cols["z"]]].to_numpy(float)
        vals = df[col].to_numpy(float)
    except ValueError as exc:
        raise InputError(f"non-numeric data in {str(p)!r}: {exc}") from None
    return scattered(pts, vals, name=p.stem)


def _read_npz(p, array):
    """The layout :func:`save_npz` writes: a 3-D ``values`` grid (indexed [i, j, k] = x, y, z)
    with optional ``origin`` and ``spacing``, or ``points`` (N x 3) and 1-D ``values``."""
    try:
        z = np.load(p)
    except Exception as exc:
        raise InputError(f"cannot read {str(p)!r}: {exc}") from None
    key = array or "values"
    if key not in z:
        raise InputError(f"{str(p)!r} has no array {key!r}; available: {', '.join(z.files)}")
    v = np.asarray(z[key])
    name = str(z["name"]) if "name" in z else p.stem
    if v.ndim == 3:
        return grid_from_array(v, z["origin"] if "origin" in z else (0, 0, 0),
                               z["spacing"] if "spacing" in z else (1, 1, 1), name=name)
    if "points" not in z:
        raise InputError(f"{str(p)!r}: a 1-D {key!r} needs a 'points' array (N x 3) beside it")
    return scattered(z["points"], v, name=name)


def _read_vtk(p, array):
    """VTK files through pyvista: image data is a grid (exact integer path, origin and
    spacing kept); any other dataset gives scattered points."""
    import pyvista as pv

    try:
        mesh = pv.read(str(p))
    except Exception as exc:
        raise InputError(f"cannot read {str(p)!r} with pyvista: {exc}") from None
    col = _pick_array(mesh.point_data.keys(), array, p)
    vals = np.asarray(mesh.point_data[col])
    if vals.ndim != 1:
        raise InputError(f"array {col!r} in {str(p)!r} has {vals.shape[1]} components; need a scalar array")
    if isinstance(mesh, pv.ImageData):
        nx, ny, nz = mesh.dimensions
        if min(nx, ny, nz) < 2:
            raise InputError(f"image {str(p)!r} has dimensions {mesh.dimensions}: need >= 2 points per axis")
        if np.any(np.asarray(mesh.direction_matrix) != np.eye(3)):
            raise InputError(f"image {str(p)!r} has a rotated direction matrix; not supported")
        v3 = vals.reshape((nz, ny, nx)).transpose(2, 1, 0)  # VTK order is x fastest
        spacing = np.asarray(mesh.spacing, float)
        # the first point sits at origin + extent_min * spacing, not at the origin
        origin = np.asarray(mesh.origin, float) + np.asarray(mesh.extent[0::2], float) * spacing
        data = grid_from_array(v3, origin, spacing, name=p.stem)
        i, j, k = data.ijk.T
        data.file_index = i + nx * (j + ny * k)  # VTK's point id of each grid point
        return data
    return scattered(np.asarray(mesh.points, float), vals, name=p.stem)


#: File suffix -> reader ``(path, array) -> PointData``; :func:`load` dispatches on it.
READERS = {".csv": _read_csv, ".npz": _read_npz, ".vti": _read_vtk, ".vtk": _read_vtk, ".vtu": _read_vtk,
           ".vtp": _read_vtk, ".vts": _read_vtk, ".vtr": _read_vtk}


def load(path, array: str | None = None) -> PointData:
    """Read a user file into :class:`~trivsel.data.PointData` by its suffix (:data:`READERS`;
    see the module docstring)."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"input file {str(p)!r} does not exist")
    reader = READERS.get(p.suffix.lower())
    if reader is None:
        raise InputError(f"unsupported file type {p.suffix or p.name!r} of {str(p)!r}: "
                         f"read {', '.join(READERS)}")
    return reader(p, array)


def save_npz(data: PointData, path):
    """Write ``data`` in the ``.npz`` layout :func:`load` reads: a grid as a 3-D ``values``
    array with ``origin`` and ``spacing``, scattered data as ``points`` and ``values``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {"name": np.array(str(data.name))}
    if data.is_grid:
        arrays.update(values=np.asarray(data.values).reshape(data.shape), origin=np.asarray(data.origin, float),
                      spacing=np.asarray(data.spacing, float))
    else:
        arrays.update(points=data.points, values=data.values)
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return path


def snapshot_to_pyvista(result, snapshot):
    """The snapshot's mesh as a pyvista UnstructuredGrid over the selected points.

    Point data: ``value`` (the selected points' own values), ``original_index``
    (the point's id in the input: its row in a ``.csv`` or ``.npz``, its VTK point id
    in a ``.vti``/``.vtu``; for ``--function`` grids the C-order index over (i, j, k)),
    ``curvature`` (K of eq. 10; not for ``method="greedy"``, which does not compute it)
    and, with ``values="fit"``, ``fitted_value``.
    """
    import pyvista as pv

    sel = np.unique(snapshot.tets)
    remap = np.full(result.data.n_points, -1, np.int64)
    remap[sel] = np.arange(len(sel))
    cells = np.hstack([np.full((len(snapshot.tets), 1), 4), remap[snapshot.tets]]).ravel()
    types = np.full(len(snapshot.tets), pv.CellType.TETRA, np.uint8)
    grid = pv.UnstructuredGrid(cells, types, result.data.points[sel])
    grid.point_data["value"] = result.data.values[sel]
    if snapshot.fit is not None:
        fitted = np.empty(len(sel))
        fitted[np.searchsorted(sel, snapshot.fit["vertices"])] = snapshot.fit["values"]
        grid.point_data["fitted_value"] = fitted
    grid.point_data["original_index"] = result.data.file_ids(sel)
    if result.curvature is not None:  # greedy does not compute it
        grid.point_data["curvature"] = result.curvature[sel]
    grid.field_data["fraction"] = np.array([snapshot.fraction])
    return grid


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


#: The file in an output folder that lists what trivsel wrote there (and may replace).
MANIFEST = ".trivsel-manifest.json"
_TMP_PREFIX = ".trivsel-tmp-"


def check_output_dir(out_dir, inputs=()):
    """Check an output folder before any work: it is not a file, it can be created and
    written, and it does not contain an input file (whose name a result could take).

    Raises :class:`~trivsel.exceptions.InputError` with one line naming the problem.
    Returns the folder as a resolved :class:`~pathlib.Path`.
    """
    out = Path(out_dir).expanduser()
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {str(out)!r} is an existing file, not a folder")
    resolved = out.resolve()
    for inp in inputs:
        ip = Path(inp).expanduser().resolve()
        if ip == resolved or resolved in ip.parents:
            raise InputError(f"input file {str(inp)!r} is inside the output folder {str(out)!r}: "
                             "choose another --out (trivsel never writes over its input)")
    probe = resolved
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
        raise InputError(f"cannot write the output folder {str(out)!r}: {str(probe)!r} is not writable")
    return resolved


def _remove_stale_temporaries(out):
    """Temporary folders of an earlier run that was killed while writing."""
    for p in out.glob(_TMP_PREFIX + "*"):
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)


def write_outputs(result, out_dir, extra: dict | None = None, inputs=()):
    """Write ``errors.csv``, ``mesh_<fraction>.vtu`` and ``result.json`` into ``out_dir``.

    The output contract:

    * ``out_dir`` is checked first (:func:`check_output_dir`): an input file inside
      it is refused, so an input is never overwritten;
    * every file is written into a temporary folder *inside* ``out_dir`` (the same
      file system, so the final moves are atomic renames) and moved into place only
      when all of them are complete;
    * files that an earlier trivsel run wrote there (listed in its manifest,
      :data:`MANIFEST`) and that this run does not produce are removed, so the
      folder never mixes two runs; other files in the folder are left alone;
    * the temporary folder is removed on any failure or interruption, and leftovers
      of a killed run are removed by the next one.
    """
    out = check_output_dir(out_dir, inputs)
    out.mkdir(parents=True, exist_ok=True)
    _remove_stale_temporaries(out)
    tmp = Path(tempfile.mkdtemp(prefix=_TMP_PREFIX, dir=out))
    try:
        names = ["errors.csv"]
        result.errors_frame().to_csv(tmp / "errors.csv", index=False)
        for s in result.snapshots:
            name = f"mesh_{fraction_label(s.fraction)}.vtu"
            snapshot_to_pyvista(result, s).save(str(tmp / name))
            names.append(name)
        info = {
            "data": {"name": result.data.name, "n_points": result.data.n_points, "grid": result.data.is_grid,
                     "shape": result.data.shape, "origin": result.data.origin, "spacing": result.data.spacing,
                     **result.data.meta},
            "options": result.options,
            "timings": result.timings,
            "stats": result.stats,
            "snapshots": [{"fraction": s.fraction, "n_selected": s.n_selected, "errors": s.errors,
                           "seconds": s.seconds, "n_tets": int(len(s.tets)), "flips": s.flips}
                          for s in result.snapshots],
            "selected": result.selected,
            **(extra or {}),
        }
        with open(tmp / "result.json", "w") as fh:
            json.dump(_jsonable(info), fh, indent=1)
        names.append("result.json")
        with open(tmp / MANIFEST, "w") as fh:
            json.dump({"files": names}, fh)
        previous = _previous_files(out)
        for name in names:
            os.replace(tmp / name, out / name)
        for name in sorted(previous - set(names)):
            (out / name).unlink(missing_ok=True)
        os.replace(tmp / MANIFEST, out / MANIFEST)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def _previous_files(out):
    """The files an earlier trivsel run listed in the folder's manifest (plain names only)."""
    try:
        files = json.loads((out / MANIFEST).read_text())["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return set()
    return {f for f in files if isinstance(f, str) and f == Path(f).name and not f.startswith(".")}
