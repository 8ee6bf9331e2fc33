#!/usr/bin/env python
"""The least-squares fit of a mesh made in blocks, solved tile by tile, against the fit of the
whole mesh.

For a central crop of the ICBM152 2009a T1 (or f4 with ``--f4``), decimated in blocks to a
fraction (:func:`trivsel.decimation.blocked.decimate_in_blocks`), the vertex values are fitted
twice on the same mesh: over the whole mesh at once (:func:`trivsel.fitting.fit_vertex_values`)
and tile by tile (:func:`trivsel.decimation.blocked.tile_fit`, the blocks as tiles), with each
number of rings asked for.  Printed per row: E_RMS of each (eq. 19, over every grid point),
their ratio, the largest difference of a vertex value, and the CPU seconds of each fit.

    python benchmarks/bench_tile_fit.py                          # T1 65^3 in blocks of 16, 5 %
    python benchmarks/bench_tile_fit.py --size 129 --block 32 --rings 0 1 2 3
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=65, help="crop (grid points per axis; default 65)")
    ap.add_argument("--block", type=int, default=16, help="block size in grid intervals (default 16)")
    ap.add_argument("--fraction", type=float, default=0.05)
    ap.add_argument("--rings", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--f4", action="store_true", help="f4 (Table 1) on the grid, not the T1 crop")
    a = ap.parse_args(argv)

    from bench_cli import t1_crop
    from trivsel.data import sample_grid
    from trivsel.decimation.blocked import block_list, decimate_in_blocks, point_weights, tile_fit
    from trivsel.fitting import fit_vertex_values

    d = sample_grid(4, a.size - 1) if a.f4 else t1_crop(a.size)
    vol = np.asarray(d.values, float).reshape(d.shape)
    f = vol.reshape(-1)
    out = decimate_in_blocks(vol, a.block, fraction=a.fraction)
    verts, w = point_weights(d.shape, out["tets"], out["ptet"])
    t = time.process_time()
    whole, res = fit_vertex_values(verts, w, f, out["vertices"])
    t_whole = time.process_time() - t
    e_whole = float(np.sqrt(np.mean(res ** 2)))
    col = np.full(len(f), -1)
    col[out["vertices"]] = np.arange(len(out["vertices"]))
    cuts, blocks = block_list(d.shape, a.block)
    name = "f4" if a.f4 else "T1"
    print(f"{name} {a.size}^3 in {len(blocks)} blocks of {a.block} to {a.fraction:g}: {len(out['vertices'])} vertices, "
          f"{len(out['tets'])} tetrahedra")
    print("| rings | E_RMS whole mesh | E_RMS tiles | ratio | largest |value difference| | CPU s whole | CPU s tiles |")
    print("|---|---|---|---|---|---|---|")
    for r in a.rings:
        t = time.process_time()
        tiled = tile_fit(d.shape, cuts, out["tets"], out["ptet"], out["vertices"], f, rings=r)
        t_tiles = time.process_time() - t
        e = float(np.sqrt(np.mean((f - np.einsum("ij,ij->i", w, tiled[col[verts]])) ** 2)))
        print(f"| {r} | {e_whole:.6g} | {e:.6g} | {e / e_whole:.8f} | {np.max(np.abs(tiled - whole)):.3g} | "
              f"{t_whole:.2f} | {t_tiles:.2f} |")


if __name__ == "__main__":
    main()
