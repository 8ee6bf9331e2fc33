"""Fit-aware flips: alternate least-squares vertex values and squared-error flips on a fixed vertex set.

For a greedy selection (``greedy_key="sse"``, fitted values) at 10 % of the points, repeat:
fit the vertex values by least squares on the current mesh, then swap (2-3, 3-2, 4-4 and
boundary 2-2 flips, section 4's operations) until no flip lowers the squared error of the
points under those vertex values.  Each half-step can only lower the fitted E_RMS (the fit is
optimal for the mesh; a flip is taken only if it lowers the error for the values), so this
measures how much a mesh optimised for the fitted values is worth over one optimised for the
data values.

    python benchmarks/bench_fit_flips.py --quick               # 16^3 crops (seconds per volume)
    python benchmarks/bench_fit_flips.py steps chirp --rounds 3

Prints one line per volume: the fitted E_RMS after each round as a ratio to the start.
Volumes as in bench_realdata.py (the real ones need the ``realdata`` extra).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_realdata import VOLUMES, load_volume, missing_packages  # noqa: E402


def fitted(data, tets, vertices):
    """Least-squares vertex values on ``tets`` and the fitted E_RMS over all points."""
    from trivsel.fitting import fit_vertex_values
    from trivsel.mesh import TetMesh

    tm = TetMesh(data.points, data.values, data.ijk, criterion="sse")
    tm.start(tets)
    verts, w = tm.point_weights()
    fv, fr = fit_vertex_values(verts, w, data.values, vertices)
    return fv, float(np.sqrt(np.mean(fr * fr)))


def alternate(data, tets, rounds):
    """``rounds`` of fit then flips; returns the fitted E_RMS before and after each round,
    the flips of each round and the final tetrahedra (checked)."""
    from trivsel.mesh import TetMesh, check_mesh

    vertices = np.unique(tets)
    _, e = fitted(data, tets, vertices)
    history, flips = [e], []
    for _ in range(rounds):
        fv, _ = fitted(data, tets, vertices)
        values = data.values.copy()
        values[vertices] = fv  # the points between the vertices keep their data values
        tm = TetMesh(data.points, values, data.ijk, criterion="sse", boundary_flips=True)
        tm.start(tets)
        flips.append(tm.global_pass())
        check_mesh(tm)
        tets = tm.tetrahedra()
        history.append(fitted(data, tets, vertices)[1])
    return history, flips, tets


def main(argv=None):
    import trivsel
    from trivsel.selection import count_for_fraction

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("volumes", nargs="*", help=f"any of {', '.join(VOLUMES)} (default: all)")
    ap.add_argument("--quick", action="store_true", help="16^3 crops")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--fraction", type=float, default=0.1)
    a = ap.parse_args(argv)
    a.volumes = a.volumes or list(VOLUMES)
    unknown = sorted(set(a.volumes) - set(VOLUMES))
    if unknown:
        ap.error(f"unknown volume {unknown[0]!r}: choose from {', '.join(VOLUMES)}")
    missing = missing_packages(a.volumes)
    if missing:
        sys.exit(f"needs {', '.join(missing)} (pip install -e '.[realdata]')")
    for name in a.volumes:
        data = load_volume(name, quick=a.quick)
        K = count_for_fraction(a.fraction, data.n_points)
        snap = trivsel.reduce(data, count=K, method="greedy", greedy_key="sse").snapshots[-1]
        t0 = time.perf_counter()
        history, flips, _ = alternate(data, snap.tets, a.rounds)
        rounds = "; ".join(f"round {i + 1}: {f} flips, {e / history[0]:.3f}"
                           for i, (f, e) in enumerate(zip(flips, history[1:])))
        print(f"{name} {data.shape}, K = {K}: fitted E_RMS {history[0]:.4g}; {rounds} "
              f"[{time.perf_counter() - t0:.1f} s]", flush=True)


if __name__ == "__main__":
    main()
