"""Whole processes against whole processes: `trivsel reduce FILE.vti` against a VTK script.

Both sides start a fresh Python process, import what they need, read the same ``.vti``
(Table-1 function 4 on an (n+1)^3 grid, or a volume of trivsel.study.realdata), reduce it
to a fraction of its points (10 %) and write a ``.vtu``.  VTK's side is what a VTK user
would run, at its fastest: every combination of the two tetrahedral splits a user reaches
for (pyvista's ``triangulate()``, 5 tets per cell; the Kuhn split, 6) and the two ways to
stop ``vtkUnstructuredGridQuadricDecimation`` (``SetTargetReduction(1 - fraction)``, or
``SetNumberOfEdgesToDecimate`` to the same vertex count as trivsel) is timed, and the
fastest variant's median counts.  Runs alternate between the programs so that a
change in the machine's load hits both.  trivsel's kernels are compiled once before the
timing (a first-use cost, measured by ``trivsel compile``: the extension modules of
trivsel/aot.py, and numba's cache for ``--numba-too``).

    python benchmarks/bench_cli.py                      # n = 32, 64; 3 runs each
    python benchmarks/bench_cli.py --n 32 64 128 --repeats 3
    python benchmarks/bench_cli.py --volumes icbm152 statmap aniso --fractions 0.1 0.05 --methods decimate
    python benchmarks/bench_cli.py --numba-too           # also each method with TRIVSEL_AOT=0
    python benchmarks/bench_cli.py --crops 65 129 --fractions 0.05 --methods decimate --values data fit

Prints one table: median seconds per program and the ratio trivsel / VTK's fastest, and each
program's peak resident memory (its largest run) against VTK's least.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

VTK_SCRIPT = r'''
import sys
import numpy as np
import pyvista as pv
from vtkmodules.vtkFiltersCore import vtkUnstructuredGridQuadricDecimation

src, dst, split, stop, n_keep, fraction = sys.argv[1:5] + [int(sys.argv[5]), float(sys.argv[6])]
image = pv.read(src)
if split == "pv5":
    grid = image.triangulate()
else:  # the Kuhn split: six tets around each cube's main diagonal
    nx, ny, nz = image.dimensions
    i, j, k = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), np.arange(nz - 1), indexing="ij")
    base = (i + nx * (j + ny * k)).ravel()
    e = np.array([1, nx, nx * ny])
    tets = []
    for a, b in ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)):
        c = 3 - a - b
        tets.append(np.stack([base, base + e[a], base + e[a] + e[b], base + e[a] + e[b] + e[c]], axis=1))
    tets = np.concatenate(tets)
    P = np.asarray(image.points)
    a_, b_, c_, d_ = (P[tets[:, q]] for q in range(4))
    neg = np.einsum("ij,ij->i", np.cross(b_ - a_, c_ - a_), d_ - a_) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]  # positively oriented, as VTK's own split
    cells = np.hstack([np.full((len(tets), 1), 4), tets]).ravel()
    grid = pv.UnstructuredGrid(cells, np.full(len(tets), pv.CellType.TETRA, np.uint8), image.points)
    grid.point_data["f"] = image.point_data["f"]
'''

#: The filter as a VTK user runs it, after ``grid`` (scalars ``f``), ``stop``, ``n_keep``,
#: ``fraction`` and ``dst`` are set; it writes the result and prints its vertex count.
VTK_FILTER = r'''
grid.point_data.active_scalars_name = "f"
flt = vtkUnstructuredGridQuadricDecimation()
flt.SetInputData(grid)
flt.SetScalarsName("f")
if stop == "target":
    flt.SetTargetReduction(1.0 - fraction)
else:
    flt.SetTargetReduction(0.0)
    flt.SetNumberOfEdgesToDecimate(grid.n_points - n_keep)
flt.Update()
out = pv.wrap(flt.GetOutput())
out.save(dst)
print(out.n_points)
'''
VTK_SCRIPT += VTK_FILTER


def write_vti(d, path):
    """Grid data ``d`` (:class:`trivsel.PointData`) as a ``.vti`` with the point array ``f``."""
    import pyvista as pv

    img = pv.ImageData(dimensions=d.shape, spacing=tuple(d.spacing), origin=tuple(d.origin))
    img.point_data["f"] = d.values.reshape(d.shape).ravel(order="F")  # VTK order: x fastest
    img.save(path)
    return d.n_points


#: Runs a command in a forked grandchild and writes its peak resident memory (kB) to a file.
#: ``ru_maxrss`` of a direct child would start at the benchmark's own size: a process keeps
#: the high-water mark of the memory it was forked with across ``exec``.
PEAK_LAUNCHER = """import os, sys
pid = os.fork()
if pid == 0:
    os.execvp(sys.argv[2], sys.argv[2:])
_, status, usage = os.wait4(pid, 0)
open(sys.argv[1], "w").write(str(usage.ru_maxrss))
sys.exit(os.waitstatus_to_exitcode(status))
"""


def run(cmd, env=None):
    """Seconds, stdout and peak resident memory (GB) of one whole process."""
    with tempfile.TemporaryDirectory() as tmp:
        peak = Path(tmp) / "peak"
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-c", PEAK_LAUNCHER, str(peak), *map(str, cmd)], capture_output=True,
                           text=True, env=env)
        seconds = time.perf_counter() - t0
        if r.returncode:
            raise SystemExit(f"failed: {' '.join(map(str, cmd))}\n{r.stderr[-2000:]}")
        return seconds, r.stdout, int(peak.read_text()) / 2**20


def t1_crop(size, name="icbm152"):
    """The central ``size``^3 crop of the ICBM152 2009a T1 template (1 mm, nilearn's wheel), or
    of another real volume of trivsel.study.realdata (``name``; "gm", its grey-matter map)."""
    from trivsel.study.realdata import REAL, central_crop, load_nifti, package_file

    package, rel, _ = REAL[name]
    path = package_file(package, rel)
    if path is None:
        raise SystemExit(f"the volume {name} needs {package}: pip install -e '.[realdata]'")
    return central_crop(load_nifti(path, name), size)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, nargs="+", help="grid intervals per axis of function 4 (default: 32 64, "
                    "unless --volumes)")
    ap.add_argument("--volumes", nargs="+", default=[], help="volumes of trivsel.study.realdata")
    ap.add_argument("--crops", type=int, nargs="+", default=[],
                    help="edges of central crops of the ICBM152 T1 (e.g. 65 129)")
    ap.add_argument("--values", nargs="+", default=["data"], help="trivsel's --values (e.g. data fit)")
    ap.add_argument("--vtk-stops", nargs="+", default=["target", "edges"], choices=["target", "edges"],
                    help="VTK's ways to stop that are timed (both splits each)")
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.1])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--methods", nargs="+", default=["paper", "greedy"])
    ap.add_argument("--numba-too", action="store_true",
                    help="also time each method with numba's own kernels (TRIVSEL_AOT=0), in the same alternation")
    a = ap.parse_args(argv)
    import trivsel
    from trivsel.selection import count_for_fraction

    cases = [(f"f4 {n + 1}^3", lambda n=n: trivsel.sample_grid(4, n))
             for n in (a.n or ([] if a.volumes or a.crops else [32, 64]))]
    cases += [(f"T1 {c}^3", lambda c=c: t1_crop(c)) for c in a.crops]
    if a.volumes:
        from trivsel.study.realdata import load_volume

        cases += [(v, lambda v=v: load_volume(v)) for v in a.volumes]

    py = sys.executable
    jit_env = dict(os.environ, TRIVSEL_AOT="0")
    for m in a.methods:  # every kernel a timed run loads, so that no timed run compiles
        subprocess.run([py, "-m", "trivsel", "compile", "--method", m], check=True, capture_output=True)
        if a.numba_too:
            subprocess.run([py, "-m", "trivsel", "compile", "--method", m], check=True, capture_output=True,
                           env=jit_env)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        script = tmp / "vtk_decimate.py"
        script.write_text(VTK_SCRIPT)
        for label, make in cases:
            d = make()
            vti = tmp / "input.vti"
            write_vti(d, vti)
            N = d.n_points
            for fraction in a.fractions:
                keep = count_for_fraction(fraction, N)
                progs = {m: [py, "-m", "trivsel", "reduce", str(vti), "--array", "f", "--fractions", str(fraction),
                             "--method", m, "--values", *a.values, "--progress", "never", "--out", str(tmp / f"out_{m}")]
                         for m in a.methods}
                if a.numba_too:
                    progs.update({f"{m} (numba)": progs[m] for m in a.methods})
                for split in ("pv5", "kuhn6"):
                    for stop in a.vtk_stops:
                        progs[f"vtk-{split}-{stop}"] = [py, str(script), str(vti), str(tmp / "vtk.vtu"), split, stop,
                                                        str(keep), str(fraction)]
                times = {k: [] for k in progs}
                peaks = {k: [] for k in progs}
                for _ in range(a.repeats):
                    for name, cmd in progs.items():
                        seconds, _, gb = run(cmd, jit_env if name.endswith("(numba)") else None)
                        times[name].append(seconds)
                        peaks[name].append(gb)
                med = {k: statistics.median(v) for k, v in times.items()}
                peak = {k: max(v) for k, v in peaks.items()}
                vtk_best = min((k for k in med if k.startswith("vtk-")), key=med.get)
                vtk_least = min(peak[k] for k in peak if k.startswith("vtk-"))
                for m in [k for k in progs if not k.startswith("vtk-")]:
                    rows.append((label, N, fraction, m, med[m], vtk_best, med[vtk_best], med[m] / med[vtk_best],
                                 peak[m], vtk_least))
                print(f"{label} to {fraction:g}: " + ", ".join(f"{k} {v:.2f} s {peak[k]:.2f} GB" for k, v in med.items()),
                      flush=True)
    print(f"\nwhole processes, medians of {a.repeats} alternating runs; peak memory: the largest of a "
          "program's runs, VTK's the least of its variants")
    print("| input | points | kept | method | trivsel s | VTK's fastest | VTK s | ratio | trivsel GB | VTK GB "
          "| memory ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for label, N, fraction, m, t, best, tv, ratio, gb, vgb in rows:
        print(f"| {label} | {N} | {fraction:.0%} | {m} | {t:.2f} | {best} | {tv:.2f} | **{ratio:.2f}** | {gb:.2f} "
              f"| {vgb:.2f} | **{gb / vgb:.2f}** |")


if __name__ == "__main__":
    main()
