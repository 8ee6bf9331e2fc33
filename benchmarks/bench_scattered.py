#!/usr/bin/env python
"""``decimate`` against VTK's tetrahedral decimation off the grid: scattered points and meshes.

Inputs, from real volumes that ship in the nilearn and dipy wheels (loaded as
``benchmarks/bench_realdata.py`` loads them, :func:`trivsel.study.realdata.load_volume`):

* ``<volume>/scattered``: ``--points`` points at uniform random positions (seed 0) in the
  volume's box, with the volume's values trilinearly interpolated there; trivsel and VTK
  both start from their Delaunay tetrahedra;
* ``<volume>/vtu``: the same points and their Delaunay tetrahedra written to a ``.vtu`` and
  read back with ``trivsel.load`` (a tetrahedral mesh: its cells are its domain);
* ``icbm152/mask``: a non-convex mesh, the Kuhn split of the cells of the ICBM152 crop whose
  eight voxels are all above 30 % of its maximum (the brain's tissue), with the voxel values;
* ``<volume>/shell`` (``--shell``): a non-convex mesh whose boundary is curved and rough, as an
  FEM mesh of a curved part has (:func:`shell_mesh`).

For each input and kept fraction, VTK (``vtkUnstructuredGridQuadricDecimation`` on the same
tetrahedra) runs as in ``bench_realdata.py``: every weight of the value in its quadric is
screened with seed 0, the best is run again with ``--repeats - 1`` more seeds, and the medians
are kept.  Points outside VTK's mesh (its boundary moves) are scored at the nearest point of
its boundary, not dropped.  trivsel ``decimate`` then runs at VTK's median vertex count, with
data values and with fitted values.

Printed: trivsel's E_RMS (fitted values) over VTK's and over VTK's with refitted values; E_inf
(data values) over VTK's; whole processes against whole processes (``process_s_over_vtk``): the
input written to a file (``.npz`` of points and values, or the ``.vtu``), then ``trivsel reduce
FILE --count K --method decimate --values data fit`` against a VTK script that reads the same
file, builds the Delaunay tetrahedra of scattered points (``pv.PolyData(P).delaunay_3d()``), runs
the filter with the weight screened above (C ``rand()`` unseeded, as a user runs it), stopped at
the same count, and writes a ``.vtu`` (medians of ``--repeats`` alternating runs; both peak memories in GB); trivsel's
in-process ``reduce`` over VTK's in-process Delaunay and ``Update()`` (``inproc_s_over_vtk``); and
whether trivsel kept the domain: its mesh's volume against the input mesh's (relative
difference) and its validity (:func:`trivsel.decimation.tetmesh.check_mesh_keeps_domain`).

``--trivsel-only`` skips VTK and times one ``trivsel reduce --fractions F`` process per input
(seconds and peak memory), for sizes where VTK's screening would take hours.

    python benchmarks/bench_scattered.py                          # 20k points, 3 volumes (about 20 min)
    python benchmarks/bench_scattered.py --points 100000 --fractions 0.05 --no-mask
    python benchmarks/bench_scattered.py --points 1000000 --fractions 0.05 --trivsel-only --no-vtu --no-mask
    python benchmarks/bench_scattered.py --points --no-mask --shell --volumes statmap icbm152
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_cli import VTK_FILTER, run  # noqa: E402  (as bench_cli.py runs them)


def trilinear(grid, points):
    """The grid data's trilinear interpolant at ``points``."""
    from scipy.interpolate import RegularGridInterpolator

    axes = [grid.origin[a] + grid.spacing[a] * np.arange(grid.shape[a]) for a in range(3)]
    return RegularGridInterpolator(axes, grid.values.reshape(grid.shape))(points)


def scattered_sample(grid, n, seed=0):
    from trivsel.data import scattered

    lo = np.asarray(grid.origin, float)
    hi = lo + np.asarray(grid.spacing) * (np.asarray(grid.shape) - 1)
    p = np.random.default_rng(seed).uniform(lo, hi, (n, 3))
    return scattered(p, trilinear(grid, p), name="scattered")


def as_vtu(data, folder):
    """The points and their Delaunay tetrahedra written to a .vtu and read back as a mesh."""
    import pyvista as pv

    import trivsel
    from trivsel.triangulation import start_tetrahedra

    tets = start_tetrahedra(data.points)
    g = pv.UnstructuredGrid({pv.CellType.TETRA: tets}, data.points)
    g.point_data["value"] = data.values
    path = Path(folder) / "delaunay.vtu"
    g.save(path)
    return trivsel.load(path)


def brain_mask_mesh(grid, level=0.3):
    """The Kuhn split of the cells whose 8 voxels are all above ``level`` times the maximum."""
    from trivsel.data import scattered
    from trivsel.triangulation import kuhn_tetrahedra

    tets = kuhn_tetrahedra(grid.shape)
    inside = grid.values > level * grid.values.max()
    cells = tets.reshape(-1, 6, 4)
    corner = np.stack([grid.ijk[cells[:, 0, 0]] + np.array(o) for o in np.ndindex(2, 2, 2)], 1)
    keep = inside[np.ravel_multi_index(corner.reshape(-1, 3).T, grid.shape)].reshape(-1, 8).all(axis=1)
    tets = cells[keep].reshape(-1, 4)
    used = np.unique(tets)
    remap = np.full(grid.n_points, -1)
    remap[used] = np.arange(len(used))
    d = scattered(grid.points[used], grid.values[used], name="mask")
    d.tets = remap[tets]
    return d


def shell_mesh(grid, n=25000, alpha=6.0, seed=7):
    """A non-convex mesh with a curved, rough boundary (as an FEM mesh of a curved part has): VTK's
    alpha-shape Delaunay tetrahedra (``delaunay_3d(alpha=...)``) of ``n`` random points in a thick
    spherical shell of the volume's box (radii 0.45-0.95 of the half-box), with the volume's
    values trilinearly interpolated; the points no tetrahedron uses are left out."""
    import pyvista as pv

    from trivsel.data import scattered

    lo = np.asarray(grid.origin, float)
    hi = lo + np.asarray(grid.spacing) * (np.asarray(grid.shape) - 1)
    p = np.random.default_rng(seed).uniform(lo, hi, (3 * n, 3))
    r = np.linalg.norm((p - (lo + hi) / 2) / (hi - lo) * 2, axis=1)
    p = p[(r > 0.45) & (r < 0.95)][:n]
    tets = pv.PolyData(p).delaunay_3d(alpha=alpha).cells_dict[pv.CellType.TETRA]
    used = np.unique(tets)
    remap = np.full(len(p), -1)
    remap[used] = np.arange(len(used))
    d = scattered(p[used], trilinear(grid, p[used]), name="shell")
    d.tets = remap[tets]
    return d


VTK_SCRIPT = r'''
import sys
import numpy as np
import pyvista as pv
from vtkmodules.vtkFiltersCore import vtkUnstructuredGridQuadricDecimation

src, dst, n_keep, scale = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
stop, fraction = "edges", None
if src.endswith(".npz"):  # scattered points: VTK's own Delaunay tetrahedra first
    z = np.load(src)
    grid = pv.PolyData(z["points"]).delaunay_3d()
    grid.point_data["f"] = z["values"] * scale
else:
    grid = pv.read(src)
    grid.point_data["f"] = grid.point_data["value"] * scale
''' + VTK_FILTER


def write_input(data, path):
    """The input as a user has it: scattered points as an .npz, a mesh as a .vtu of its tetrahedra."""
    if data.tets is None:
        np.savez(path.with_suffix(".npz"), points=data.points, values=data.values)
        return path.with_suffix(".npz")
    import pyvista as pv

    g = pv.UnstructuredGrid({pv.CellType.TETRA: data.tets}, data.points)
    g.point_data["value"] = data.values
    g.save(path.with_suffix(".vtu"))
    return path.with_suffix(".vtu")


def trivsel_command(src, out, stop):
    return [sys.executable, "-m", "trivsel", "reduce", str(src), *(["--array", "value"] if src.suffix == ".vtu" else []),
            *stop, "--method", "decimate", "--values", "data", "fit", "--progress", "never", "--out", str(out)]


def processes(data, K, vtk, repeats, folder):
    """Whole trivsel and VTK processes on the same file, alternating: median seconds, peak GB."""
    folder = Path(folder)
    src = write_input(data, folder / "input")
    script = folder / "vtk_decimate.py"
    script.write_text(VTK_SCRIPT)
    progs = {"trivsel": trivsel_command(src, folder / "out", ["--count", str(K)]),
             "vtk": [sys.executable, str(script), str(src), str(folder / "vtk.vtu"), str(K), repr(vtk["abs_scale"])]}
    runs = {k: [] for k in progs}
    for _ in range(repeats):
        for name, cmd in progs.items():
            runs[name].append(run(cmd))  # seconds, stdout, peak GB
    return {k: (statistics.median(r[0] for r in v), max(r[2] for r in v)) for k, v in runs.items()}


def vtk_delaunay_seconds(points, repeats):
    import pyvista as pv

    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        pv.PolyData(points).delaunay_3d()
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def measure(label, data, fraction, repeats, say, folder):
    import trivsel
    from trivsel.decimation.tetmesh import check_mesh_keeps_domain, mesh_volume, start_mesh
    from trivsel.study.realdata import run_vtk

    vtk = run_vtk(data, fraction, repeats=repeats, splits=("cells",), say=say)
    K = int(round(vtk["n_vertices"]))
    vtk_seconds = vtk["seconds"] + (vtk_delaunay_seconds(data.points, repeats) if data.tets is None else 0.0)
    runs = []
    for k in range(repeats):
        t0 = time.perf_counter()
        r = trivsel.reduce(data, count=K, method="decimate", values=["data", "fit"])
        runs.append(time.perf_counter() - t0)
    s = r.snapshots[-1]
    before, _, boundary = start_mesh(data)
    check_mesh_keeps_domain(data.points, before, s.tets)
    v0 = mesh_volume(data.points, before)
    proc = processes(data, K, vtk, repeats, folder)
    return {"input": label, "fraction": fraction, "N": data.n_points, "K": K, "trivsel_K": s.n_selected,
            "boundary_vertices": int(len(np.unique(boundary))),
            "process_s_over_vtk": proc["trivsel"][0] / proc["vtk"][0],
            "trivsel_process_s": proc["trivsel"][0], "vtk_process_s": proc["vtk"][0],
            "trivsel_GB": proc["trivsel"][1], "vtk_GB": proc["vtk"][1],
            "fit_rms_over_vtk": s.fit["errors"]["E_rms"] / vtk["E_rms"],
            "fit_rms_over_vtk_refit": s.fit["errors"]["E_rms"] / vtk["refit_E_rms"],
            "inf_over_vtk": s.errors["E_inf"] / vtk["E_inf"],
            "inproc_s_over_vtk": statistics.median(runs) / vtk_seconds,
            "volume_change": abs(mesh_volume(data.points, s.tets) - v0) / v0,
            "vtk_outside": int(vtk["n_outside"]),
            "trivsel_seconds": statistics.median(runs), "vtk_seconds": vtk_seconds,
            "fit_E_rms": s.fit["errors"]["E_rms"], "vtk_E_rms": vtk["E_rms"], "vtk_refit_E_rms": vtk["refit_E_rms"],
            "E_inf": s.errors["E_inf"], "vtk_E_inf": vtk["E_inf"]}


def main(argv=None):
    from trivsel.study.realdata import load_volume

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--volumes", nargs="+", default=["icbm152", "statmap", "aniso"])
    ap.add_argument("--points", nargs="*", type=int, default=[20000], help="scattered samples of each volume "
                    "(none: --points with no value)")
    ap.add_argument("--fractions", nargs="+", type=float, default=[0.1, 0.05])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-mask", action="store_true", help="skip the non-convex brain-mask mesh")
    ap.add_argument("--no-vtu", action="store_true", help="skip the .vtu meshes")
    ap.add_argument("--shell", action="store_true",
                    help="also a mesh with a curved, rough boundary per volume (shell_mesh)")
    ap.add_argument("--trivsel-only", action="store_true",
                    help="time one trivsel process per input and fraction (seconds, peak GB), no VTK")
    a = ap.parse_args(argv)

    def say(msg):
        print(msg, file=sys.stderr, flush=True)

    # every kernel a timed run loads, so that no timed run compiles
    subprocess.run([sys.executable, "-m", "trivsel", "compile", "--method", "decimate"], check=True,
                   capture_output=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.volumes:
            grid = load_volume(name)
            inputs = []
            for n in a.points:
                d = scattered_sample(grid, n)
                inputs.append((f"{name}/scattered {n}", d))
                if not a.no_vtu:
                    inputs.append((f"{name}/vtu {n}", as_vtu(d, tmp)))
            if name == "icbm152" and not a.no_mask:
                inputs.append((f"{name}/mask", brain_mask_mesh(grid)))
            if a.shell:
                inputs.append((f"{name}/shell", shell_mesh(grid)))
            for label, d in inputs:
                for fr in a.fractions:
                    say(f"{label}, {fr:g} ...")
                    if a.trivsel_only:
                        src = write_input(d, Path(tmp) / "input")
                        sec, _, gb = run(trivsel_command(src, Path(tmp) / "out", ["--fractions", str(fr)]))
                        rows.append({"input": label, "fraction": fr, "N": d.n_points, "trivsel_process_s": sec,
                                     "trivsel_GB": gb})
                    else:
                        rows.append(measure(label, d, fr, a.repeats, say, tmp))
    cols = (["input", "fraction", "N", "trivsel_process_s", "trivsel_GB"] if a.trivsel_only else
            ["input", "fraction", "N", "K", "trivsel_K", "boundary_vertices", "fit_rms_over_vtk", "fit_rms_over_vtk_refit", "inf_over_vtk",
             "process_s_over_vtk", "trivsel_GB", "vtk_GB", "inproc_s_over_vtk", "volume_change", "vtk_outside"])
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.3g}" if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
