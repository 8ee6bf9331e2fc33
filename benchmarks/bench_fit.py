#!/usr/bin/env python
"""The least-squares fit (``values="fit"``) before and after: seconds, peak memory, same values.

For the central 65^3 and 129^3 crops of the ICBM152 2009a T1 (nilearn, loaded as
``benchmarks/bench_realdata.py`` does), decimated to 5 % (``method="decimate"``), the mesh's
point weights are saved once; then each fit runs in a fresh process:

* ``old``: the former path, kept here for comparison only: the N x m sparse matrix A, ``A^T A``
  and SuperLU (``scipy.sparse.linalg.spsolve``);
* ``new``: :func:`trivsel.fitting.fit_vertex_values` (normal equations assembled from the
  points' weights, Jacobi-preconditioned conjugate gradients).

Printed per crop and path: the fit's seconds, the process's peak resident memory and the part of
it above the loaded inputs (``VmHWM`` after loading and after the fit), and,
for ``new`` against ``old``, the largest difference of the fitted values relative to their
largest magnitude and the relative differences of E_RMS and E_inf (eqs. 19-20).  With ``--cli``
also the whole process ``trivsel reduce crop.vti --method decimate --fractions 0.05 --values data
fit`` with each fit (the old one patched in), its wall seconds and peak memory (``VmHWM``).

    python benchmarks/bench_fit.py                 # 65^3 and 129^3 (a few minutes: two decimations)
    python benchmarks/bench_fit.py --sizes 65 --cli
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cli import t1_crop as crop, write_vti  # noqa: E402


def old_fit(verts, weights, values, vertices):
    """The former fit: the N x m CSR matrix A, ``A^T A`` and a sparse direct solve."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    verts = np.asarray(verts, np.int64)
    w = np.asarray(weights, float)
    f = np.asarray(values, float)
    vertices = np.asarray(vertices, np.int64)
    col = np.full(f.shape[0], -1, np.int64)
    col[vertices] = np.arange(len(vertices))
    cols = col[verts]
    N = f.shape[0]
    rows = np.repeat(np.arange(N), 4)
    keep = w.ravel() > 0
    A = sp.csr_matrix((w.ravel()[keep], (rows[keep], cols.ravel()[keep])), shape=(N, len(vertices)))
    fitted = spsolve((A.T @ A).tocsc(), A.T @ f)
    return fitted, f - A @ fitted


def _peak_mb():
    """This process's peak resident memory (``VmHWM``), in MB.  Not ``getrusage``'s
    ``ru_maxrss``: a child started by ``fork`` and ``exec`` inherits its parent's peak there."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def prepare(size, out):
    """Decimate the crop to 5 % and save its point weights, values, vertices and interior mask."""
    from trivsel.decimation import reduce_by_collapse

    data = crop(size)
    got = {}

    def keep(dec):
        got["verts"], got["weights"] = dec.point_weights()
        got["vertices"] = dec.vertices()

    reduce_by_collapse(data, [round(0.05 * data.n_points)], values=("data",), check=keep)
    np.savez(out, values=data.values, interior=data.interior_mask(), **got)


def fit(which, inputs, out):
    """One fit in this process; prints its seconds and memory as JSON."""
    import scipy.sparse.linalg  # noqa: F401  (imported by the old module on import: not timed)

    from trivsel.fitting import fit_vertex_values

    z = np.load(inputs)
    verts, weights, values, vertices = z["verts"], z["weights"], z["values"], z["vertices"]
    peak_inputs = _peak_mb()
    t0 = time.perf_counter()
    fitted, residuals = (old_fit if which == "old" else fit_vertex_values)(verts, weights, values, vertices)
    seconds = time.perf_counter() - t0
    np.savez(out, fitted=fitted, residuals=residuals)
    print(json.dumps({"seconds": seconds, "peak_mb": _peak_mb(), "inputs_mb": peak_inputs,
                      "N": int(values.shape[0]), "m": int(len(vertices))}))


def cli(which, vti, out):
    """``trivsel reduce`` in this process, with the old fit patched in for ``old``."""
    import trivsel.fitting
    from trivsel.cli import main

    if which == "old":
        trivsel.fitting.fit_vertex_values = old_fit
    code = main(["reduce", vti, "--method", "decimate", "--fractions", "0.05", "--values", "data", "fit",
                 "--out", out])
    print(json.dumps({"peak_mb": _peak_mb()}))
    sys.exit(code)


def child(*args):
    """Run this script with ``args`` in a fresh process; its stdout and wall seconds."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, __file__, *map(str, args)], capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t0
    if r.returncode:
        raise SystemExit(f"bench_fit: {' '.join(map(str, args))} failed:\n{r.stderr[-2000:]}")
    return r.stdout, seconds


def errors(path, interior):
    from trivsel.norms import error_norms

    r = np.load(path)
    return r["fitted"], error_norms(r["residuals"], interior)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[65, 129], help="crop edges (default 65 129)")
    ap.add_argument("--cli", action="store_true", help="also time the whole `trivsel reduce` process")
    ap.add_argument("--worker", nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        kind, *rest = a.worker
        return {"prepare": lambda: prepare(int(rest[0]), rest[1]), "fit": lambda: fit(*rest),
                "cli": lambda: cli(*rest)}[kind]()
    print(f"# bench_fit {time.strftime('%Y-%m-%d %H:%M')}: ICBM152 T1 central crops, decimate to 5 %")
    print("| crop | N | m | fit | seconds | peak MB | above inputs MB | max rel diff values | rel diff E_RMS | rel diff E_inf |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cli_rows = []
        for size in a.sizes:
            inputs = tmp / f"mesh{size}.npz"
            child("--worker", "prepare", size, inputs)
            interior = np.load(inputs)["interior"]
            res = {}
            for which in ("old", "new"):
                out, _ = child("--worker", "fit", which, inputs, tmp / f"{which}{size}.npz")
                res[which] = json.loads(out.strip().splitlines()[-1])
                res[which]["fitted"], res[which]["errors"] = errors(tmp / f"{which}{size}.npz", interior)
            o, n = res["old"], res["new"]
            for which, r in res.items():
                if which == "old":
                    diffs = "", "", ""
                else:
                    diffs = (f"{np.abs(n['fitted'] - o['fitted']).max() / np.abs(o['fitted']).max():.1e}",
                             *(f"{abs(n['errors'][k] - o['errors'][k]) / o['errors'][k]:.1e}" for k in ("E_rms", "E_inf")))
                print(f"| {size}^3 | {r['N']} | {r['m']} | {which} | {r['seconds']:.2f} | {r['peak_mb']:.0f} | "
                      f"{r['peak_mb'] - r['inputs_mb']:.0f} | " + " | ".join(diffs) + " |", flush=True)
            print(f"|  |  |  | E_RMS old {o['errors']['E_rms']:.9g}, new {n['errors']['E_rms']:.9g}; "
                  f"E_inf old {o['errors']['E_inf']:.9g}, new {n['errors']['E_inf']:.9g} | | | | | | |", flush=True)
            if a.cli:
                vti = tmp / f"crop{size}.vti"
                write_vti(crop(size), vti)
                for which in ("old", "new"):
                    out, seconds = child("--worker", "cli", which, vti, tmp / f"out_{which}{size}")
                    peak = json.loads(out.strip().splitlines()[-1])["peak_mb"]
                    cli_rows.append(f"| {size}^3 | {which} fit | {seconds:.1f} | {peak:.0f} |")
        if a.cli:
            print()
            print("| crop | `trivsel reduce ... --values data fit` with | wall s | peak MB |")
            print("|---|---|---|---|")
            for row in cli_rows:
                print(row)


if __name__ == "__main__":
    main()
