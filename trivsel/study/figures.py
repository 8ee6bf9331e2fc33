"""Figures 4-6 of the paper and an E_RMS-versus-fraction plot.

* :func:`slice_figure` - matplotlib, a 2 x 2 panel per function (original data
  upper left, then the reduced data sets, e.g. 50 % upper right, 20 % lower left,
  10 % lower right).  Each panel shows the piecewise-linear approximation on the
  three orthogonal mid-planes x = 0, y = 0, z = 0, all panels with one colour
  map and one range, titled with the fraction, the point count and E_RMS; the
  selected points lying on each plane are marked.
* :func:`slice_figure_3d` - the same panel layout rendered off-screen with
  pyvista: the three slice planes through the volume plus the reduced mesh's
  vertices, composed into one image with a shared colour bar.
* :func:`erms_figure` - E_RMS and E_RMS* against the selected fraction, one
  subplot per function, the published Table 1 values as open markers.

Meshes are the ``mesh_<fraction>.vtu`` files written by ``trivsel reduce``:
tetrahedra on the selected points with point data ``value``.  The approximation
on a plane is the exact cut of the tetrahedral mesh (:func:`plane_cut`), drawn
with linear (Gouraud) shading on each cut triangle, i.e. exactly the paper's
piecewise linear L restricted to the plane.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

__all__ = [
    "original_mesh",
    "load_mesh",
    "plane_cut",
    "plane_values",
    "slice_figure",
    "slice_figure_3d",
    "erms_figure",
    "percent_label",
]

AXES = "xyz"
CMAP = "viridis"
#: zlib level of the PNG files: 3 writes them in about half the time of PIL's default 6, for
#: files about 15 % larger
PNG = {"compress_level": 3}


def _pyvista():
    """Import pyvista for off-screen use (EGL on headless Linux)."""
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    pv.OFF_SCREEN = True
    return pv


def _pyplot():
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "cairo"):
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save_png(fig, out_png, dpi):
    """Write ``fig`` to ``out_png`` at :data:`PNG`'s compression, close it, return ``out_png``:
    every figure of the study is written here."""
    fig.savefig(out_png, dpi=dpi, pil_kwargs=PNG)
    _pyplot().close(fig)
    return out_png


def percent_label(fraction: float) -> str:
    """'50 %' for 0.5."""
    return f"{100 * float(fraction):g} %"


def original_mesh(data):
    """All original grid points as a tetrahedral mesh (the Kuhn split of section 5)."""
    pv = _pyvista()
    from ..triangulation import kuhn_tetrahedra

    tets = kuhn_tetrahedra(data.shape)
    cells = np.hstack([np.full((len(tets), 1), 4, dtype=np.int64), tets]).ravel()
    celltypes = np.full(len(tets), pv.CellType.TETRA, dtype=np.uint8)
    grid = pv.UnstructuredGrid(cells, celltypes, np.asarray(data.points, float))
    grid.point_data["value"] = np.asarray(data.values, float)
    grid.point_data["original_index"] = np.arange(len(data.values), dtype=np.int64)
    return grid


def load_mesh(path):
    """Read a ``mesh_<fraction>.vtu`` written by ``trivsel reduce``."""
    pv = _pyvista()
    mesh = pv.read(str(path))
    if "value" not in mesh.point_data:
        raise ValueError(f"{path}: mesh has no point data 'value' (has {list(mesh.point_data)})")
    return mesh


def _plane_coordinate(data, axis: int) -> float:
    """Coordinate of the grid layer nearest the domain's mid-plane along ``axis``."""
    if data.is_grid:
        layer = (data.shape[axis] - 1) // 2
        return float(data.origin[axis] + layer * data.spacing[axis])
    lo, hi = data.points[:, axis].min(), data.points[:, axis].max()
    return 0.5 * (lo + hi)


def _bounds(data):
    return data.points.min(axis=0), data.points.max(axis=0)


def plane_cut(mesh, axis: int, coord: float):
    """Exact restriction of the mesh's piecewise-linear interpolant to the plane ``x_axis = coord``.

    The tetrahedral mesh is cut by the plane (``vtkCutter``: values are
    interpolated linearly along the cut tetrahedron edges, so they are exact) and
    the cut polygons are split into triangles; on each triangle the interpolant
    is linear.  The plane is moved by 1e-9 of the domain size towards the domain
    centre so that it never contains tetrahedron faces (which would give
    duplicated or degenerate polygons); the value change is of that order.

    Returns ``(uv, triangles, values, (u_axis, v_axis))`` with ``uv`` the
    in-plane coordinates of the cut vertices.

    (A point probe, ``vtkProbeFilter``, is not used: with the long, skinny
    tetrahedra of a data-dependent mesh its tolerant cell search returned a
    wrong tetrahedron for about a quarter of the points of a plane.)
    """
    pv = _pyvista()
    b = np.asarray(mesh.bounds, float).reshape(3, 2)
    extent = float(np.max(b[:, 1] - b[:, 0]))
    centre = float(b[axis].mean())
    shift = 1e-9 * extent * (1.0 if coord <= centre else -1.0)
    origin = b.mean(axis=1)
    origin[axis] = coord + shift
    normal = np.zeros(3)
    normal[axis] = 1.0
    cut = mesh.slice(normal=normal, origin=origin).triangulate()
    u_ax, v_ax = [a for a in range(3) if a != axis]
    if cut.n_cells == 0:
        return np.zeros((0, 2)), np.zeros((0, 3), np.int64), np.zeros(0), (u_ax, v_ax)
    faces = np.asarray(cut.faces).reshape(-1, 4)
    tris = faces[:, 1:].astype(np.int64)
    pts = np.asarray(cut.points, float)
    vals = np.asarray(cut.point_data["value"], float)
    return pts[:, [u_ax, v_ax]], tris, vals, (u_ax, v_ax)


def _rasterize(uv, tris, vals, u, v):
    """Sample a piecewise-linear function on triangles at the grid ``u x v`` (exact, NaN outside)."""
    out = np.full((len(v), len(u)), np.nan)
    if len(tris) == 0:
        return out
    a, b, c = uv[tris[:, 0]], uv[tris[:, 1]], uv[tris[:, 2]]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    scale = max(float(np.ptp(u)) * float(np.ptp(v)), 1e-300)
    tol = 1e-9
    for t in np.flatnonzero(np.abs(det) > 1e-14 * scale):
        tri_uv = uv[tris[t]]
        lo, hi = tri_uv.min(axis=0), tri_uv.max(axis=0)
        iu = np.flatnonzero((u >= lo[0] - 1e-12) & (u <= hi[0] + 1e-12))
        iv = np.flatnonzero((v >= lo[1] - 1e-12) & (v <= hi[1] + 1e-12))
        if not len(iu) or not len(iv):
            continue
        uu, vv = np.meshgrid(u[iu], v[iv], indexing="xy")
        du, dv = uu - a[t, 0], vv - a[t, 1]
        l1 = (du * (c[t, 1] - a[t, 1]) - dv * (c[t, 0] - a[t, 0])) / det[t]
        l2 = ((b[t, 0] - a[t, 0]) * dv - (b[t, 1] - a[t, 1]) * du) / det[t]
        l0 = 1.0 - l1 - l2
        inside = (l0 >= -tol) & (l1 >= -tol) & (l2 >= -tol)
        if not inside.any():
            continue
        f = vals[tris[t]]
        block = out[np.ix_(iv, iu)]
        block[inside] = (l0 * f[0] + l1 * f[1] + l2 * f[2])[inside]
        out[np.ix_(iv, iu)] = block
    return out


def plane_values(mesh, axis: int, coord: float, lo, hi, res: int = 161):
    """The mesh's piecewise-linear interpolant sampled on a ``res x res`` grid of a plane.

    Exact (see :func:`plane_cut`).  Returns ``(values, (u_axis, v_axis))``
    with ``values[v, u]`` (ready for ``imshow(origin='lower')``), NaN outside the mesh.
    """
    uv, tris, vals, (u_ax, v_ax) = plane_cut(mesh, axis, coord)
    u = np.linspace(lo[u_ax], hi[u_ax], res)
    v = np.linspace(lo[v_ax], hi[v_ax], res)
    return _rasterize(uv, tris, vals, u, v), (u_ax, v_ax)


def _panel_title(fraction, n_points, erms, erms_int):
    if fraction is None:
        head = "original data"
    else:
        head = f"{percent_label(fraction)} selected"
    s = f"{head}: {n_points} points"
    if erms is not None and np.isfinite(erms):
        s += f", E$_{{RMS}}$ = {erms:.3f}"
        if erms_int is not None and np.isfinite(erms_int):
            s += f" ({erms_int:.3f}*)"
    return s


def _panels(data, meshes, errors):
    """[(fraction or None, mesh, n_points, E_rms, E_rms_interior)] in paper order."""
    out = [(None, original_mesh(data), data.n_points, None, None)]
    for fraction in sorted(meshes, reverse=True):
        mesh = meshes[fraction]
        mesh = load_mesh(mesh) if isinstance(mesh, (str, Path)) else mesh
        erms = erms_int = None
        n_sel = mesh.n_points
        if errors is not None:
            row = errors[np.isclose(errors["fraction"].astype(float), float(fraction))]
            if len(row):
                erms = float(row["E_rms"].iloc[0])
                erms_int = float(row["E_rms_interior"].iloc[0])
                n_sel = int(row["n_selected"].iloc[0])
        out.append((fraction, mesh, n_sel, erms, erms_int))
    return out


def _function_title(function, n):
    if function is None:
        return ""
    from ..functions import FUNCTIONS

    short, expr, _ = FUNCTIONS[int(function)]
    s = f"Function {int(function)} ({short}): f(x, y, z) = {expr}"
    if n is not None:
        s += f", n = {n}"
    return s


def slice_figure(data, meshes: dict, out_png, errors=None, function=None, dpi: int = 110,
                 cmap: str = CMAP):
    """Matplotlib 2 x 2 panel of mid-plane slices (Figs. 4-6 of the paper).

    Parameters
    ----------
    data : :class:`trivsel.data.PointData` on a grid (the original data).
    meshes : {fraction: path to mesh_<fraction>.vtu or pyvista mesh}; up to three,
        shown in decreasing fraction after the original.
    errors : DataFrame with fraction, n_selected, E_rms, E_rms_interior (errors.csv).
    function : Table-1 number for the title.
    """
    plt = _pyplot()
    from matplotlib import colors as mcolors

    panels = _panels(data, meshes, errors)
    lo, hi = _bounds(data)
    vmin, vmax = float(np.min(data.values)), float(np.max(data.values))
    if vmax - vmin < 1e-12:
        vmin, vmax = vmin - 0.5, vmax + 0.5
    norm = mcolors.Normalize(vmin=vmin, vmax=vmax)
    spacing = (np.asarray(hi) - np.asarray(lo)) / np.maximum(np.asarray(data.shape) - 1, 1) \
        if data.is_grid else np.full(3, 1e-6)

    nrow = 2 if len(panels) > 2 else 1
    ncol = 2 if len(panels) > 1 else 1
    fig = plt.figure(figsize=(7.2 * ncol + 1.2, 2.6 * nrow + 1.1), dpi=dpi)
    outer = fig.add_gridspec(nrow, ncol, left=0.04, right=0.90, top=0.80 if nrow == 2 else 0.70,
                             bottom=0.07, hspace=0.55, wspace=0.12)
    for p, (fraction, mesh, n_pts, erms, erms_int) in enumerate(panels):
        r, c = divmod(p, ncol)
        inner = outer[r, c].subgridspec(1, 3, wspace=0.32)
        pts = np.asarray(mesh.points)
        for axis in range(3):
            ax = fig.add_subplot(inner[0, axis])
            coord = _plane_coordinate(data, axis)
            uv, tris, vals, (u_ax, v_ax) = plane_cut(mesh, axis, coord)
            if len(tris):
                # Gouraud shading interpolates linearly on each triangle: exactly the
                # piecewise-linear approximation on the plane, at any resolution.
                ax.tripcolor(uv[:, 0], uv[:, 1], tris, vals, shading="gouraud", cmap=cmap, norm=norm,
                             rasterized=True)
            ax.set_aspect("equal")
            if fraction is not None:
                near = np.abs(pts[:, axis] - coord) <= 0.5 * spacing[axis]
                ax.plot(pts[near, u_ax], pts[near, v_ax], "o", ms=2.6, mfc="white", mec="black",
                        mew=0.5, linestyle="none")
            ax.set_xlim(lo[u_ax], hi[u_ax])
            ax.set_ylim(lo[v_ax], hi[v_ax])
            ax.set_title(f"{AXES[axis]} = {coord:g}", fontsize=9, pad=3)
            ax.set_xlabel(AXES[u_ax], fontsize=8, labelpad=1)
            ax.set_ylabel(AXES[v_ax], fontsize=8, labelpad=1)
            ax.tick_params(labelsize=7, length=2, pad=1)
            ax.set_xticks([lo[u_ax], 0.5 * (lo[u_ax] + hi[u_ax]), hi[u_ax]])
            ax.set_yticks([lo[v_ax], 0.5 * (lo[v_ax] + hi[v_ax]), hi[v_ax]])
            if axis == 1:
                ax.text(0.5, 1.22, _panel_title(fraction, n_pts, erms, erms_int), transform=ax.transAxes,
                        ha="center", va="bottom", fontsize=10.5, fontweight="bold")
    cax = fig.add_axes([0.925, 0.12, 0.018, 0.68])
    cb = fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), cax=cax)
    cb.set_label("f (piecewise-linear approximation)", fontsize=9)
    cb.ax.tick_params(labelsize=8)
    title = _function_title(function, (data.shape[0] - 1) if data.is_grid else None)
    fig.suptitle(title + "\nmid-plane slices; dots: selected points on the plane; * = without boundary",
                 fontsize=11.5, y=0.985)
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    return _save_png(fig, out_png, dpi)


def _render_panel_3d(pv, mesh, clim, cmap, show_points, window, coords=(0.0, 0.0, 0.0)):
    plotter = pv.Plotter(off_screen=True, window_size=list(window))
    plotter.set_background("white")
    slices = mesh.slice_orthogonal(x=coords[0], y=coords[1], z=coords[2])
    plotter.add_mesh(slices, scalars="value", cmap=cmap, clim=clim, show_scalar_bar=False,
                     lighting=False)
    plotter.add_mesh(mesh.outline(), color="black", line_width=1.5)
    if show_points:
        cloud = pv.PolyData(np.asarray(mesh.points))
        plotter.add_mesh(cloud, color="black", point_size=4.0, render_points_as_spheres=True)
    plotter.camera_position = "iso"
    plotter.camera.azimuth = 15
    plotter.reset_camera()
    plotter.camera.zoom(1.0)
    plotter.add_axes(color="black", line_width=2, labels_off=False)
    img = plotter.screenshot(return_img=True)
    plotter.close()
    return img


def slice_figure_3d(data, meshes: dict, out_png, errors=None, function=None, dpi: int = 110,
                    cmap: str = CMAP):
    """pyvista off-screen version: slice planes through the volume plus the mesh vertices.

    Each panel is rendered separately, at the pixel size of its cell of the 2 x 2
    layout, and the four images are placed pixel for pixel in a matplotlib figure,
    which adds the titles and one shared colour bar.
    """
    pv = _pyvista()
    plt = _pyplot()
    from matplotlib import colors as mcolors

    panels = _panels(data, meshes, errors)
    vmin, vmax = float(np.min(data.values)), float(np.max(data.values))
    if vmax - vmin < 1e-12:
        vmin, vmax = vmin - 0.5, vmax + 0.5
    coords = tuple(_plane_coordinate(data, a) for a in range(3))
    nrow = 2 if len(panels) > 2 else 1
    ncol = 2 if len(panels) > 1 else 1
    fig = plt.figure(figsize=(6.2 * ncol + 1.0, 5.2 * nrow + 0.8), dpi=dpi)
    gs = fig.add_gridspec(nrow, ncol, left=0.01, right=0.89, top=0.90 if nrow == 2 else 0.84,
                          bottom=0.02, hspace=0.12, wspace=0.02)
    # each panel is rendered at the pixel size of its cell and placed pixel for pixel
    # (figimage): no resampling of the renderings when the figure is saved
    width, height = fig.canvas.get_width_height()
    for p, (fraction, mesh, n_pts, erms, erms_int) in enumerate(panels):
        r, c = divmod(p, ncol)
        box = gs[r, c].get_position(fig)
        x0, y0 = int(round(box.x0 * width)), int(round(box.y0 * height))
        w, h = int(round(box.x1 * width)) - x0, int(round(box.y1 * height)) - y0
        img = _render_panel_3d(pv, mesh, (vmin, vmax), cmap, show_points=fraction is not None, window=(w, h),
                               coords=coords)
        fig.figimage(img, xo=x0, yo=y0, origin="upper")
        fig.text(0.5 * (box.x0 + box.x1), box.y1 + 0.004, _panel_title(fraction, n_pts, erms, erms_int),
                 ha="center", va="bottom", fontsize=11, fontweight="bold")
    norm = mcolors.Normalize(vmin=vmin, vmax=vmax)
    cax = fig.add_axes([0.91, 0.15, 0.02, 0.62])
    cb = fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), cax=cax)
    cb.set_label("f (piecewise-linear approximation)", fontsize=10)
    cb.ax.tick_params(labelsize=9)
    title = _function_title(function, (data.shape[0] - 1) if data.is_grid else None)
    fig.suptitle(title + "\nslices x = 0, y = 0, z = 0 through the tetrahedral mesh; black: mesh vertices",
                 fontsize=12, y=0.985)
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    return _save_png(fig, out_png, dpi)


def _variant_cols():
    from ..options import option_fields

    return ["n"] + [f.name for f in option_fields()]


def _series_labels(df):
    """Label each run by the option columns that vary across the table."""
    cols = [c for c in _variant_cols() if c in df.columns and df[c].astype(str).nunique() > 1]
    if "variant" in df.columns and not cols and df["variant"].nunique() > 1:
        cols = ["variant"]
    if not cols:
        return cols, {(): "ours"}
    labels = {}
    for key, _ in df.groupby(cols, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        labels[key] = ", ".join(f"{c}={v}" for c, v in zip(cols, key))
    return cols, labels


def erms_figure(errors, out_png, published=None, functions=None, dpi: int = 110):
    """E_RMS (solid) and E_RMS* without boundary (dashed) against the selected fraction.

    ``errors`` is a DataFrame with function, fraction, E_rms, E_rms_interior and
    optionally option columns (a sweep: one line per combination).  Published
    Table-1 values are drawn as large open markers.
    """
    plt = _pyplot()
    import pandas as pd

    from .published import load_published

    df = errors.copy()
    if published is None:
        published = load_published()
    if functions is None:
        functions = sorted(int(f) for f in df["function"].unique())
    cols, labels = _series_labels(df)
    nplot = len(functions) + 1
    ncol = min(3, nplot)
    nrow = int(np.ceil(nplot / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.7 * nrow), dpi=dpi, squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    handles = {}
    for k, fn in enumerate(functions):
        ax = axes.flat[k]
        sub = df[df["function"] == fn]
        groups = sub.groupby(cols, sort=True) if cols else [((), sub)]
        for s, (key, grp) in enumerate(groups):
            key = key if isinstance(key, tuple) else (key,)
            colour = colours[s % len(colours)]
            grp = grp.sort_values("fraction")
            x = 100 * grp["fraction"].astype(float)
            h1, = ax.plot(x, grp["E_rms"], "-o", color=colour, ms=5, lw=1.6)
            h2, = ax.plot(x, grp["E_rms_interior"], "--s", color=colour, ms=4.5, lw=1.4)
            handles.setdefault(f"{labels.get(key, key)}: E_RMS", h1)
            handles.setdefault(f"{labels.get(key, key)}: E_RMS* (no boundary)", h2)
        pub = published[published["function"] == fn].sort_values("fraction")
        if len(pub):
            x = 100 * pub["fraction"].astype(float)
            h3, = ax.plot(x, pub["E_rms"], "o", ms=11, mfc="none", mec="black", mew=1.6, linestyle="none")
            h4, = ax.plot(x, pub["E_rms_interior"], "s", ms=10, mfc="none", mec="0.45", mew=1.6,
                          linestyle="none")
            handles.setdefault("published E_RMS (Table 1)", h3)
            handles.setdefault("published E_RMS* (Table 1)", h4)
        from .published import function_label

        ax.set_title(function_label(fn), fontsize=9.5)
        ax.set_xlabel("selected points (% of all)", fontsize=9)
        ax.set_ylabel("RMS error", fontsize=9)
        ax.set_xlim(0, max(55, float(100 * df["fraction"].max()) + 5))
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    for ax in list(axes.flat)[len(functions):]:
        ax.set_axis_off()
    legend_ax = axes.flat[len(functions)]
    legend_ax.legend(list(handles.values()), list(handles.keys()), loc="center", fontsize=8.5, frameon=False)
    fig.suptitle("Total RMS error against the fraction of selected points (ours: lines; published: open markers)",
                 fontsize=11.5)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    _ = pd  # imported for callers passing DataFrames
    return _save_png(fig, out_png, dpi)
