#!/usr/bin/env python
r"""``decimate`` in blocks against ``decimate`` unblocked, at the same vertex count.

    python benchmarks/bench_blocked_decimate.py --volumes t1 f4 --size 129 --block 32 --fractions 0.05 0.1

For each volume and fraction: the blocked run (:func:`trivsel.decimation.blocked.decimate_in_blocks`,
in this process) to the fraction, its merged mesh checked as a conforming tetrahedralisation of
the box (:func:`trivsel.blocks.check_tetrahedra`) with every point inside its tetrahedron
(barycentric weights from integer determinants, all >= 0); then the unblocked run
(:func:`trivsel.decimation.reduce_by_collapse`) at the blocked run's vertex count.  Prints the
ratios blocked / unblocked of E_RMS with data values, E_RMS with fitted values (least squares
on each mesh: the blocked one tile by tile, :func:`trivsel.decimation.blocked.tile_fit`, as the
blocked paths fit it) and E_inf with data values, and the
seconds of both.  ``t1`` is the central crop of the ICBM152 2009a T1 (nilearn's wheel: the
``realdata`` extra), ``gm`` the same crop of the template's grey-matter probability map (a
signal of another kind: smooth, with bands of steep change), ``f4`` the paper's function 4
sampled on the same number of points.
``--tol-rms`` compares at one tolerance instead: the unblocked run to each fraction, its E_RMS
(data values) the tolerance of the blocked run (``tol_rms``: a squared-error budget its stages
share).  Prints the blocked run's count against the unblocked one's, its E_RMS against the
tolerance (at most 1 by construction) and the seconds of both::

    python benchmarks/bench_blocked_decimate.py --tol-rms --volumes t1 f4 --size 129 --block 32

``--whole-t1`` runs the blocked decimation alone on the whole 1 mm template (8.7 M points) and
prints its time, its count and its process's peak memory.

``--jobs`` runs ``trivsel blocks --method decimate --values data fit -c 2`` as a user does, a
whole process timed by ``/usr/bin/time`` after ``trivsel compile --method decimate`` (as a run
after the first on a machine finds the kernels): on the whole T1 (``--jobs t1``, converted to Zarr
first) or on function 4 (``--jobs f4 --size 257``), to each ``--fractions`` (or ``--count``).
Prints the wall time, the largest process's peak memory (every job is a process of its own),
the largest job by Snakemake's benchmark files, the count and the errors, then the job seconds by rule::

    python benchmarks/bench_blocked_decimate.py --jobs t1 --block 48 --fractions 0.05
    python benchmarks/bench_blocked_decimate.py --jobs t1 --block 48 --count 362160
    python benchmarks/bench_blocked_decimate.py --jobs f4 --size 257 --block 64 --fractions 0.05
    python benchmarks/bench_blocked_decimate.py --jobs t1 --block 48 --rms 1.16

``--job-peaks`` runs ``trivsel blocks --method decimate`` on function 4 (``--size``, ``--block``,
the first of ``--fractions``, ``--values data fit``) keeping every job's files, then runs again,
on a copy of the folder, the item of each kind of job that Snakemake's benchmark files show as the
largest, as a process of its own under ``/usr/bin/time``: its peak memory (with the code that
``PYTHONPATH`` names, so two versions compare)::

    python benchmarks/bench_blocked_decimate.py --job-peaks --size 129 --block 32 --fractions 0.05

``--requests FOLDER...`` reads finished runs (kept with ``--notemp``, or with ``--jobs ... --keep``)
and prints, for each kind of job, the largest peak memory Snakemake's benchmark files recorded
(``max_rss``, sampled: it can read low, short jobs always; a ``finish`` of 4.3 GB by ``/usr/bin/time``
read 1.9 GB) beside the memory that kind of job requests, and the longest wall time beside its
runtime request (:func:`trivsel.blocks.decimate.job_resources`, with the code that ``PYTHONPATH``
names; on SLURM a job ends at its request)::

    python benchmarks/bench_blocked_decimate.py --requests RUN1 RUN2

``--phases f4 --block 64`` times pass 1 on one interior block by its phases (lazy queue, then the
exact queue down to its share of the count, and below it the exact queue or the lazy one).

``--record-exact`` runs the blocked decimation (``--threads`` processes) with every block's record
exact to its end and as by default (exact to its share of the count, lazy below it:
``RECORD_EXACT_TO``): the errors and seconds of both and their ratios::

    python benchmarks/bench_blocked_decimate.py --record-exact --volumes f4 t1 --size 129 --block 32 --threads 2

``--record-floor`` times pass 1 on every block of each volume, each block recorded to its end and
to ``RECORD_FLOOR`` of its share of the count, the two alternating: the seconds of both and their
ratio, the blocks whose record stopped short, those the cut records again
(:func:`trivsel.decimation.blocked.short_blocks`), and whether the threshold is that of whole
records; also where each block stands at the threshold (its vertices left over its share)::

    python benchmarks/bench_blocked_decimate.py --record-floor --volumes f4 t1 --size 129 --block 32 --fractions 0.05 0.1
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def volume(name, size):
    if name in ("t1", "gm"):
        from bench_cli import t1_crop

        d = t1_crop(size, "icbm152" if name == "t1" else "gm")
    else:
        from trivsel.data import sample_grid

        d = sample_grid(int(name[1:]), size - 1)
    return d.values.reshape(d.shape)


def blocked(vol, block, **stop):
    """The blocked run to ``stop``, its mesh checked (a conforming tetrahedralisation of the box,
    every point inside its tetrahedron): the run, its seconds, each point's vertices and weights
    and its residuals with data values."""
    from trivsel.blocks import check_tetrahedra
    from trivsel.decimation.blocked import decimate_in_blocks, point_weights

    f = vol.reshape(-1).astype(float)
    t = time.perf_counter()
    out = decimate_in_blocks(vol, block, **stop)
    tb = time.perf_counter() - t
    check_tetrahedra(vol.shape, out["tets"])
    verts, w = point_weights(vol.shape, out["tets"], out["ptet"])
    if w.min() < 0:
        raise SystemExit("a point lies outside the tetrahedron that holds it")
    return out, tb, verts, w, f - np.einsum("ij,ij->i", w, f[verts])


def compare(name, vol, block, fraction):
    from trivsel.data import grid_from_array
    from trivsel.decimation import reduce_by_collapse
    from trivsel.decimation.blocked import block_list, tile_fit
    from trivsel.norms import error_norms

    data = grid_from_array(vol)
    interior = data.interior_mask()
    f = vol.reshape(-1).astype(float)
    out, tb, verts, w, r = blocked(vol, block, fraction=fraction)
    # fitted as the blocked paths fit: tile by tile
    col = np.full(len(f), -1)
    col[out["vertices"]] = np.arange(len(out["vertices"]))
    fitted = tile_fit(vol.shape, block_list(vol.shape, block)[0], out["tets"], out["ptet"], out["vertices"], f)
    rf = f - np.einsum("ij,ij->i", w, fitted[col[verts]])
    C = len(out["vertices"])
    t = time.perf_counter()
    shots, *_ = reduce_by_collapse(data, [C], values=("data", "fit"))
    tu = time.perf_counter() - t
    s = shots[-1]
    eb, ebf, eu, euf = error_norms(r, interior), error_norms(rf, interior), s.errors, s.fit["errors"]
    return (f"| {name} | {block} | {fraction:g} | {round(fraction * vol.size)} | {C} | "
            f"{eb['E_rms'] / eu['E_rms']:.3f} | {ebf['E_rms'] / euf['E_rms']:.3f} | {eb['E_inf'] / eu['E_inf']:.3f} | "
            f"{eu['E_rms']:.4g}, {euf['E_rms']:.4g}, {eu['E_inf']:.4g} | {tb:.0f}, {tu:.0f} |")


def compare_tol(name, vol, block, fraction):
    """One row of ``--tol-rms``: unblocked to ``fraction``, then blocked to its E_RMS."""
    from trivsel.data import grid_from_array
    from trivsel.decimation import reduce_by_collapse
    from trivsel.selection import count_for_fraction

    m = count_for_fraction(fraction, vol.size)
    t = time.perf_counter()
    shots, *_ = reduce_by_collapse(grid_from_array(vol), [m])
    tu = time.perf_counter() - t
    tol = float(np.sqrt(np.mean(shots[-1].residuals ** 2)))
    out, tb, _, _, r = blocked(vol, block, tol_rms=tol)
    e = float(np.sqrt(np.mean(r ** 2)))
    C = len(out["vertices"])
    return f"| {name} | {block} | {fraction:g} | {tol:.4g} | {m} | {C} | {C / m:.4f} | {e / tol:.6f} | {tb:.0f}, {tu:.0f} |"


def whole_t1(block, fraction):
    from trivsel.decimation.blocked import decimate_in_blocks
    from trivsel.study.realdata import REAL, load_nifti, package_file

    package, rel, _ = REAL["icbm152"]
    d = load_nifti(package_file(package, rel), "icbm152")
    vol = d.values.reshape(d.shape)
    t = time.perf_counter()
    out = decimate_in_blocks(vol, block, fraction=fraction)
    took = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    print(f"whole T1 {vol.shape} ({vol.size} points), blocks of {block}, {fraction:g}: {len(out['vertices'])} vertices "
          f"in {took:.0f} s, peak {peak:.2f} GB (one process); {out['stats']}")


def jobs(source, size, block, fraction=None, count=None, keep=None, rms=None):
    """One ``trivsel blocks --method decimate`` run as a whole process (see the module docstring)."""
    import json
    import re
    import subprocess
    import tempfile

    folder = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="bench-blocks-"))
    if source == "t1":
        from trivsel.study.realdata import REAL, package_file

        package, rel, _ = REAL["icbm152"]
        store = folder / "t1.zarr"
        if not store.exists():
            subprocess.run([sys.executable, "-m", "trivsel", "convert", str(package_file(package, rel)), str(store)],
                           check=True)
        src = [str(store)]
    else:
        src = ["--function", source[1:], "--n", str(size - 1)]
    stop, name = ((["--count", str(count)], count) if count is not None else (["--tol-rms", str(rms)], f"rms{rms}")
                  if rms is not None else (["--fraction", str(fraction)], fraction))
    out = folder / f"run-{source}-{block}-{name}"
    # the kernels as a user's runs after the first on a machine find them (compiled once, then loaded)
    subprocess.run([sys.executable, "-m", "trivsel", "compile", "--method", "decimate"], check=True,
                   capture_output=True)
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "trivsel", "blocks", *src, "--block", str(block), "--method",
           "decimate", *stop, "--values", "data", "fit", "--out", str(out), "-c", "2"]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(p.stderr[-2000:])
    wall = p.stderr.split("Elapsed (wall clock) time (h:mm:ss or m:ss): ")[1].split()[0]
    peak = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr).group(1)) / 2**20
    rows, by_rule = [], {}
    for tsv in (out / "benchmarks").rglob("*.tsv"):
        vals = tsv.read_text().splitlines()[1].split("\t")
        name = str(tsv.relative_to(out / "benchmarks").with_suffix(""))
        rows.append((float(vals[2]), name))
        rule = by_rule.setdefault(name.split("/")[0], [0, 0.0])
        rule[0] += 1
        rule[1] += float(vals[0])
    job_mb, job = max(rows)
    s = json.loads((out / "summary.json").read_text())
    target = f"{s['target']:,}" if s["target"] is not None else f"tol_rms {s['tol_rms']:g}"
    print(f"| {source} {s['points']:,} points | {block} | {target} | {s['vertices']:,} | {wall} | {peak:.2f} | "
          f"{job} {job_mb / 1024:.2f} | {s['E_rms']:.4g} | {s['fit']['E_rms']:.4g} | {s['E_inf']:.4g} |", flush=True)
    print("  job seconds by rule (jobs): " + ", ".join(f"{rule} {sec:.1f} ({n})" for rule, (n, sec) in
                                                      sorted(by_rule.items(), key=lambda kv: -kv[1][1])), flush=True)


def job_peaks(size, block, fraction):
    """``--job-peaks`` (see the module docstring)."""
    import re
    import shutil
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory(prefix="bench-job-peaks-") as tmp:
        out = Path(tmp) / "run"
        subprocess.run([sys.executable, "-m", "trivsel", "blocks", "--function", "4", "--n", str(size - 1), "--block",
                        str(block), "--method", "decimate", "--fraction", str(fraction), "--values", "data", "fit",
                        "--out", str(out), "-c", "2", "--", "--notemp"], check=True, capture_output=True)
        largest = {}  # kind -> (Snakemake's max_rss in MB, item)
        for tsv in (out / "benchmarks").rglob("*.tsv"):
            name = tsv.relative_to(out / "benchmarks").with_suffix("")
            kind, item = name.parts[0], (name.parts[1] if len(name.parts) > 1 else "")
            mb = float(tsv.read_text().splitlines()[1].split("\t")[2])
            if kind != "kernels" and mb >= largest.get(kind, (-1.0, ""))[0]:
                largest[kind] = (mb, item)
        print(f"| f4 {size}^3, blocks of {block}, {fraction:g} | kind | item | peak MB (/usr/bin/time) | seconds |")
        print("|---|---|---|---|---|")
        for kind in ("costs", "cut", "mesh", "step", "rcosts", "quota", "apply", "tiles", "fit", "pieces", "finish"):
            if kind not in largest:
                continue
            item = largest[kind][1]
            copy = Path(tmp) / "copy"
            shutil.copytree(out, copy)
            p = subprocess.run(["/usr/bin/time", "-f", "%M %e", sys.executable, "-m", "trivsel.blocks.decimate", kind,
                                str(copy), *([item] if item else [])], capture_output=True, text=True)
            if p.returncode != 0:
                raise SystemExit(p.stderr[-2000:])
            kb, secs = re.findall(r"^(\d+) ([\d.]+)$", p.stderr, flags=re.M)[-1]
            print(f"| | {kind} | {item or '-'} | {int(kb) / 1024:.0f} | {float(secs):.2f} |", flush=True)
            shutil.rmtree(copy)


def requests(folders):
    """``--requests`` (see the module docstring)."""
    import json

    from trivsel.blocks import read_config
    from trivsel.blocks.decimate import job_resources

    print("| run | points | tetrahedra after the blocks | kind | largest max_rss MB (item) | request MB | "
          "request / peak | longest s (item) | runtime request s | request / longest |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for folder in map(Path, folders):
        cfg, plan = read_config(folder)
        largest, longest = {}, {}
        for tsv in (folder / "benchmarks").rglob("*.tsv"):
            name = tsv.relative_to(folder / "benchmarks").with_suffix("")
            kind = name.parts[0].split("_")[0]
            row = tsv.read_text().splitlines()[1].split("\t")
            secs, mb, item = float(row[0]), float(row[2]), "/".join(name.parts[1:]) or "-"
            if mb >= largest.get(kind, (-1.0, ""))[0]:
                largest[kind] = (mb, item)
            if secs >= longest.get(kind, (-1.0, ""))[0]:
                longest[kind] = (secs, item)
        state = folder / "passes" / "0" / "state.npz"
        tets = len(np.load(state)["T"]) if state.exists() else None
        points = json.loads((folder / "summary.json").read_text())["points"]
        for kind in ("costs", "cut", "mesh", "step", "rcosts", "quota", "apply", "tiles", "fit", "pieces", "finish"):
            if kind in largest:
                mb, item = largest[kind]
                secs, slow = longest[kind]
                req, minutes = job_resources(cfg, plan, kind)
                print(f"| {folder.name} | {points:,} | {tets if tets is None else f'{tets:,}'} | {kind} | "
                      f"{mb:.0f} ({item}) | {req} | {req / max(mb, 1.0):.1f} | {secs:.1f} ({slow}) | {60 * minutes} | "
                      f"{60 * minutes / max(secs, 1.0):.1f} |", flush=True)


def phases(source, block, fraction):
    """Pass 1 on one interior block, its phases timed: the lazy queue to twice its share of the
    count, then the exact queue to its share, half, a quarter, and to the end; and again with
    the lazy queue below its share (what pass 1 does: ``RECORD_EXACT_TO``).  Each row gives the
    block's squared error at its end."""
    from trivsel.decimation import EXACT_WITHIN, Decimation
    from trivsel.decimation.blocked import _block_state, block_cuts

    if source == "t1":
        from trivsel.study.realdata import REAL, load_nifti, package_file

        package, rel, _ = REAL["icbm152"]
        d = load_nifti(package_file(package, rel), "icbm152")
    else:
        from trivsel.data import sample_grid

        d = sample_grid(int(source[1:]), 4 * block)
    full = d.values.reshape(d.shape)
    cuts = [block_cuts(n, block) for n in full.shape]
    lo = [int(c[len(c) // 2 - 1]) for c in cuts]  # a block away from the box
    vol = full[lo[0]:lo[0] + block + 1, lo[1]:lo[1] + block + 1, lo[2]:lo[2] + block + 1]
    print(f"{source}: the block at {lo} of {block} intervals ({vol.size} points), fraction {fraction:g}")
    for below in ("exact", "lazy"):
        S, _, seam = _block_state(vol, lo, full.shape, [c[1:-1] for c in cuts])
        t = time.perf_counter()
        dec = Decimation(None, None, None, state=S)
        share = (~seam).sum() * fraction
        rows = [("start", time.perf_counter() - t, dec.n_vertices, dec.sse)]
        t = time.perf_counter()
        dec.run(int(seam.sum() + EXACT_WITHIN * share))
        rows.append(("lazy to twice its share", time.perf_counter() - t, dec.n_vertices, dec.sse))
        dec.lazy = False
        for f in (1.0, 0.5, 0.25, 0.0):
            t = time.perf_counter()
            dec.run(int(seam.sum() + f * share))
            rows.append((f"{'exact' if f == 1.0 else below} to {f:g} of its share", time.perf_counter() - t,
                         dec.n_vertices, dec.sse))
            dec.lazy = below == "lazy"
        print(f"  below its share {below} ({int(seam.sum())} points on seams):")
        for what, secs, nv, sse in rows:
            print(f"    {what}: {secs:.2f} s, {nv} vertices, squared error {sse:.6g}")


def record_floor(name, size, block, fraction):
    """Pass 1 with and without the record floor on every block of ``name`` (module docstring)."""
    from trivsel.decimation import blocked as B
    from trivsel.selection import count_for_fraction

    vol = volume(name, size)
    N = vol.size
    cuts, bounds = B.block_list(vol.shape, block)
    seams = [c[1:-1] for c in cuts]
    target = count_for_fraction(fraction, N)
    secs = {0.0: 0.0, B.RECORD_FLOOR: 0.0}
    rec = {0.0: [], B.RECORD_FLOOR: []}
    for i, (lo, hi) in enumerate(bounds):
        values = vol[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1]
        for floor in (list(secs) if i % 2 else list(secs)[::-1]):
            t = time.perf_counter()
            rec[floor].append(B.block_costs(values, lo, vol.shape, seams, fraction=target / N, floor=floor))
            secs[floor] += time.perf_counter() - t
    inner = [r[1] for r in rec[0.0]]
    cut = {f: B.threshold([r[0] for r in rs], inner, N - sum(inner), B.aim(target, N, N - sum(inner)))
           for f, rs in rec.items()}
    floored = rec[B.RECORD_FLOOR]
    short = [r[4] for r in floored]
    again = B.short_blocks([r[0] for r in floored], short, cut[B.RECORD_FLOOR][1])
    tau = cut[0.0][0]
    left = np.array([(n - np.searchsorted(r[0], tau, side="right")) / (n * target / N) for r, n in zip(rec[0.0], inner)])
    print(f"| {name} {size}^3 | {block} | {fraction:g} | {secs[0.0]:.1f} | {secs[B.RECORD_FLOOR]:.1f} | "
          f"{secs[B.RECORD_FLOOR] / secs[0.0]:.2f} | {sum(short)} of {len(bounds)} | {len(again)} | "
          f"{'yes' if cut[B.RECORD_FLOOR][0] == tau else 'once recorded again' if again else 'NO'} | {left.min():.2f}, {np.median(left):.2f} |",
          flush=True)


def record_exact(name, vol, block, fraction, threads):
    """The blocked run (:func:`blocked`: its mesh checked) with each block's record exact to its
    end (``RECORD_EXACT_TO`` 0), then as by default (one run of each): the errors of both (data
    values, fitted values, E_inf), the seconds, and the ratios default / exact."""
    from trivsel.decimation import blocked as B
    from trivsel.fitting import fit_vertex_values

    f = vol.reshape(-1).astype(float)
    default = B.RECORD_EXACT_TO
    res = {}
    for v in (0.0, default):
        B.RECORD_EXACT_TO = v
        try:
            out, secs, verts, w, r = blocked(vol, block, fraction=fraction, threads=threads)
        finally:
            B.RECORD_EXACT_TO = default
        _, rf = fit_vertex_values(verts, w, f, out["vertices"])
        res[v] = (float(np.sqrt(np.mean(r ** 2))), float(np.sqrt(np.mean(rf ** 2))), float(np.abs(r).max()), secs)
    e, d = res[0.0], res[default]
    print(f"| {name} | {block} | {fraction:g} | {len(out['vertices'])} | {e[0]:.6g}, {e[1]:.6g}, {e[2]:.4g} | "
          f"{d[0]:.6g}, {d[1]:.6g}, {d[2]:.4g} | {d[0] / e[0]:.4f} | {d[1] / e[1]:.4f} | {d[2] / e[2]:.3f} | "
          f"{e[3]:.0f}, {d[3]:.0f} | {d[3] / e[3]:.2f} |", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--volumes", nargs="+", default=["t1", "f4"], help="t1 (the T1 crop), gm (the same crop of the "
                    "template's grey-matter probability map) or fN (function N)")
    ap.add_argument("--size", type=int, default=65, help="points per axis")
    ap.add_argument("--block", type=int, default=32, help="grid intervals per block")
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.05, 0.1])
    ap.add_argument("--whole-t1", action="store_true", help="the blocked run alone on the whole T1 template")
    ap.add_argument("--jobs", choices=["t1", "f4"], help="trivsel blocks --method decimate as a whole process")
    ap.add_argument("--count", type=int, help="with --jobs: stop at this count instead of the fractions")
    ap.add_argument("--rms", type=float, help="with --jobs: stop at this E_RMS tolerance instead of the fractions")
    ap.add_argument("--keep", help="with --jobs: the folder for the runs (default: a new temporary one)")
    ap.add_argument("--phases", choices=["t1", "f4"], help="pass 1 on one block, its phases timed")
    ap.add_argument("--record-floor", action="store_true",
                    help="pass 1 on every block, recorded to its end and to RECORD_FLOOR of its share, timed")
    ap.add_argument("--record-exact", action="store_true",
                    help="the blocked run with records exact to their end against the default (RECORD_EXACT_TO)")
    ap.add_argument("--threads", type=int, default=1, help="processes of the blocked runs in this process")
    ap.add_argument("--tol-rms", action="store_true",
                    help="blocked to the unblocked run's E_RMS at each fraction, not to its count")
    ap.add_argument("--job-peaks", action="store_true", help="each kind of job's peak memory, as a process of its own")
    ap.add_argument("--requests", nargs="+", metavar="FOLDER",
                    help="finished runs: each kind of job's largest recorded peak against its memory request")
    a = ap.parse_args(argv)
    if a.requests:
        requests(a.requests)
        return
    if a.job_peaks:
        job_peaks(a.size, a.block, a.fractions[0])
        return
    if a.phases:
        phases(a.phases, a.block, a.fractions[0])
        return
    if a.record_floor:
        print("| volume | block | fraction | pass 1 s, whole records | to the floor | ratio | short | recorded again "
              "| same threshold | left at it / share: min, median |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for name in a.volumes:
            for fraction in a.fractions:
                record_floor(name, a.size, a.block, fraction)
        return
    if a.record_exact:
        print("| volume | block | fraction | vertices | exact records: E_RMS, fit, E_inf | default | E_RMS ratio | "
              "fit ratio | E_inf ratio | seconds exact, default | ratio |")
        print("|---" * 11 + "|")
        for name in a.volumes:
            vol = volume(name, a.size)
            for fr in a.fractions:
                record_exact(f"{name} {a.size}^3", vol, a.block, fr, a.threads)
        return
    if a.jobs:
        print("| input | block | target | vertices | wall | largest process GB | largest job GB | E_RMS data | "
              "E_RMS fit | E_inf |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for fr in [None] if a.count is not None or a.rms is not None else a.fractions:
            jobs(a.jobs, a.size, a.block, fraction=fr, count=a.count, keep=a.keep, rms=a.rms)
        return
    if a.whole_t1:
        for fr in a.fractions:
            whole_t1(a.block, fr)
        return
    if a.tol_rms:
        head, row = ("| volume | block | fraction | tol_rms (unblocked E_RMS) | unblocked vertices | blocked vertices | "
                     "ratio | blocked E_RMS / tol_rms | seconds blocked, unblocked |"), compare_tol
    else:
        head, row = ("| volume | block | fraction | target | vertices | E_RMS data | E_RMS fit | E_inf data | "
                     "unblocked E_RMS, fit, E_inf | seconds blocked, unblocked |"), compare
    print(head)
    print("|---" * (head.count("|") - 1) + "|")
    for name in a.volumes:
        vol = volume(name, a.size)
        for fr in a.fractions:
            print(row(f"{name} {a.size}^3", vol, a.block, fr), flush=True)


if __name__ == "__main__":
    main()
