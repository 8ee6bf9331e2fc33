"""Blocked reduction (``trivsel blocks``): the price of the seams, large grids in bounded
memory, a real volume, and the plan of a 1025^3 run.

    python benchmarks/bench_blocks.py seams [--n 128] [--block 32] [--tol 0.002] [--input VOL]
        E_RMS of the blocked result against the unblocked greedy run at the same vertex
        count (each stage in this process; the target: within 10 %), on function 4 or the
        central (n+1)^3 crop of a volume (e.g. the ``icbm`` run's Zarr store).
    python benchmarks/bench_blocks.py big [--n 256] [--block 64] [--tol 0.002] [--cores 2]
        ``trivsel blocks --function 4`` as a whole process: wall time, the largest peak
        memory of any job (Snakemake's benchmark files), and the merged mesh checked.
    python benchmarks/bench_blocks.py icbm [--block 64] [--tol 8]
        The nilearn ICBM152 2009a T1 at 1 mm (197 x 233 x 189), converted to Zarr and
        reduced in blocks; the merged mesh checked (needs the ``realdata`` extra).
    python benchmarks/bench_blocks.py local --input VOL.zarr [--n 47] [--blocks 8 12 47] [--tols 8 10]
        Block size as a regulariser: the stages on a crop for several block sizes and
        tolerances, against greedy over the whole crop at the same vertex count.
    python benchmarks/bench_blocks.py slurm [--n 256] [--block 64] [--tol 0.002] [--cores 2] [--ungrouped]
        The same ``trivsel blocks`` run locally (``-c cores``) and through the SLURM profile
        (the loopback SLURM of scripts/slurm-local.sh, which must be running): wall times, cluster
        jobs submitted, and the two results compared.  ``--ungrouped`` adds a SLURM run with one
        cluster job per plane and per block (``--job-points 0``).
    python benchmarks/bench_blocks.py plan [--n 1024] [--block 128] [--measured FOLDER]
        The jobs and resources of a 1025^3 run (``-n``; the .pvtu output, no merged .vtu,
        which would need tens of GB in one job at this size), and its core-hours estimated from
        the block jobs' seconds per point of a finished run (FOLDER, e.g. the ``big`` run's).
    python benchmarks/bench_blocks.py plan --method decimate [--n 1024] [--block 64] [--fraction 0.05]
            [--measured FOLDER]
        The same for ``--method decimate`` (as the SLURM executor would submit it), its
        core-hours from every job of a finished decimate run (e.g. the folder
        ``bench_blocked_decimate.py --jobs f4 --size 257 --keep DIR`` leaves).

Outputs go under benchmarks/results/blocks/ (not in git).  The figures of a run on this
machine are in benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "blocks"


def _stage_all(vol, plan, tol, method="greedy"):
    """The blocked tetrahedra, E_RMS over all points (every stage's squared residuals) and E_inf."""
    from trivsel.blocks import reduce_in_blocks

    tets, st = reduce_in_blocks(vol, plan, tol_inf=tol, method=method)
    owned = list(st["lines"].values()) + list(st["planes"].values()) + st["blocks"]
    sse = sum(r["sse"] for r in owned)
    return tets, float(np.sqrt(sse / plan.n_points())), max(s["max"] for s in st["blocks"])


class _Crop:
    """The central ``size``^3 region of a volume, read by region like the volume itself."""

    def __init__(self, vol, size):
        self.vol = vol
        self.lo = [max((s - size) // 2, 0) for s in vol.shape]
        self.shape = tuple(min(size, s) for s in vol.shape)

    def read(self, region):
        return self.vol.read(tuple((lo + a, lo + b) for lo, (a, b) in zip(self.lo, region)))


def seams(a):
    from trivsel import reduce
    from trivsel.blocks import check_tetrahedra, plan_blocks
    from trivsel.data import sample_grid
    from trivsel.io.regions import open_volume

    from trivsel.data import grid_from_array

    if a.input:  # the central (n+1)^3 crop of a volume
        vol = _Crop(open_volume(a.input), a.n + 1)
        whole = grid_from_array(vol.read(tuple((0, s) for s in vol.shape)))
        name = f"{Path(a.input).name}, central crop"
    else:
        vol = open_volume(function=a.function, n=a.n)
        whole = sample_grid(a.function, a.n)
        name = f"f{a.function}"
    plan = plan_blocks(vol.shape, a.block)
    t0 = time.perf_counter()
    tets, e_rms_b, e_inf_b = _stage_all(vol, plan, a.tol)
    t_blocked = time.perf_counter() - t0
    check_tetrahedra(vol.shape, tets)
    V = len(np.unique(tets))
    t0 = time.perf_counter()
    snap = reduce(whole, count=V, method="greedy").snapshots[-1]
    t_unblocked = time.perf_counter() - t0
    e = snap.errors
    print(f"{name} on {vol.shape}, blocks of {a.block} intervals ({len(plan.blocks())} blocks), "
          f"tol_inf {a.tol:g}")
    print("| run | vertices | E_RMS | E_inf | seconds |\n|---|---|---|---|---|")
    print(f"| blocked (tolerance) | {V} | {e_rms_b:.4g} | {e_inf_b:.4g} | {t_blocked:.1f} |")
    print(f"| unblocked greedy (same count) | {snap.n_selected} | {e['E_rms']:.4g} | {e['E_inf']:.4g} | "
          f"{t_unblocked:.1f} |")
    print(f"E_RMS blocked / unblocked = {e_rms_b / e['E_rms']:.3f} (target <= 1.10)")


def local(a):
    """Block size as a tool for quality: the stages in one process on a crop, for several block
    sizes and tolerances, against greedy over the whole crop at the same vertex count."""
    from trivsel import reduce
    from trivsel.blocks import check_tetrahedra, plan_blocks
    from trivsel.data import grid_from_array
    from trivsel.io.regions import open_volume

    vol = _Crop(open_volume(a.input), a.n + 1)
    whole = grid_from_array(vol.read(tuple((0, s) for s in vol.shape)))
    print(f"{Path(a.input).name}, central crop {vol.shape}")
    print("| block | tol_inf | vertices | E_RMS | E_inf | greedy E_RMS at that count | greedy E_inf | ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for block in a.blocks:
        for tol in a.tols:
            tets, e_rms, e_inf = _stage_all(vol, plan_blocks(vol.shape, block), tol)
            check_tetrahedra(vol.shape, tets)
            V = len(np.unique(tets))
            g = reduce(whole, count=V, method="greedy").snapshots[-1].errors
            print(f"| {block} | {tol:g} | {V} | {e_rms:.4g} | {e_inf:.4g} | {g['E_rms']:.4g} | {g['E_inf']:.4g} | "
                  f"{e_rms / g['E_rms']:.3f} |", flush=True)


def _run_blocks(args, out, cores):
    cmd = [sys.executable, "-m", "trivsel", "blocks", *args, "--out", str(out), "-c", str(cores)]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        sys.exit(f"trivsel blocks failed ({r.returncode}):\n{r.stderr[-4000:]}")
    return wall


def job_table(out):
    """Per job: rule, item, seconds and peak resident MB from Snakemake's benchmark files."""
    rows = []
    for tsv in sorted((Path(out) / "benchmarks").rglob("*.tsv")):
        with open(tsv) as fh:
            rec = next(csv.DictReader(fh, delimiter="\t"))
        rule = tsv.parent.name if tsv.parent.name != "benchmarks" else tsv.stem
        rss = rec.get("max_rss", "NA")
        rows.append({"rule": rule, "item": tsv.stem, "s": float(rec["s"]),
                     "max_rss_mb": float(rss) if rss not in ("NA", "-") else float("nan")})
    return rows


def _report_run(out, wall, shape):
    from trivsel.blocks import check_tetrahedra, item_name, read_config

    summary = json.loads((Path(out) / "summary.json").read_text())
    rows = job_table(out)
    peak = max(rows, key=lambda r: np.nan_to_num(r["max_rss_mb"]))
    _, plan = read_config(out)
    t0 = time.perf_counter()
    tets = np.concatenate([np.load(Path(out) / "pieces" / f"{item_name(b)}.npz")["tets"] for b in plan.blocks()])
    check_tetrahedra(shape, tets)
    t_check = time.perf_counter() - t0
    by_rule = {}
    for r in rows:
        d = by_rule.setdefault(r["rule"], [0, 0.0, 0.0])
        d[0] += 1
        d[1] += r["s"]
        d[2] = max(d[2], np.nan_to_num(r["max_rss_mb"]))
    print(f"points {summary['points']}, vertices {summary['vertices']} ({100 * summary['fraction']:.2f} %), "
          f"tetrahedra {summary['tetrahedra']}, E_RMS {summary['E_rms']:.4g}, E_inf {summary['E_inf']:.4g} "
          f"(tolerance {summary['tol_inf']:g})")
    print(f"wall time {wall:.0f} s; merged mesh valid (checked in {t_check:.0f} s)")
    print("| rule | jobs | job seconds (sum) | largest peak RSS (MB) |\n|---|---|---|---|")
    for rule, (n, s, m) in by_rule.items():
        print(f"| {rule} | {n} | {s:.0f} | {m:.0f} |")
    print(f"largest job: {peak['rule']} {peak['item']} at {peak['max_rss_mb']:.0f} MB (target < 1536 MB)")


def big(a):
    out = RESULTS / f"f{a.function}_n{a.n}_b{a.block}"
    shutil.rmtree(out, ignore_errors=True)
    wall = _run_blocks(["--function", str(a.function), "--n", str(a.n), "--block", str(a.block),
                        "--tol-inf", str(a.tol), "--no-merged"], out, a.cores)
    _report_run(out, wall, (a.n + 1,) * 3)


def icbm(a):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_realdata import REAL, package_file

    src = package_file(REAL["icbm152"][0], REAL["icbm152"][1])
    if src is None:
        sys.exit("needs nilearn (pip install -e '.[realdata]')")
    RESULTS.mkdir(parents=True, exist_ok=True)
    store = RESULTS / "icbm152.zarr"
    if not store.exists():
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "trivsel", "convert", str(src), str(store)], check=True)
        print(f"converted in {time.perf_counter() - t0:.1f} s")
    from trivsel.io.regions import open_volume

    shape = open_volume(store).shape
    out = RESULTS / f"icbm152_b{a.block}"
    shutil.rmtree(out, ignore_errors=True)
    wall = _run_blocks([str(store), "--block", str(a.block), "--tol-inf", str(a.tol)], out, a.cores)
    print(f"ICBM152 T1 {shape}")
    _report_run(out, wall, shape)


def slurm(a):
    import os

    from trivsel.blocks import group_components, plan_blocks

    profile = Path(__file__).resolve().parents[1] / "workflow" / "profiles" / "slurm"
    args = ["--function", str(a.function), "--n", str(a.n), "--block", str(a.block), "--tol-inf", str(a.tol),
            "--no-merged"]
    on_slurm = ["--", "--executor", "slurm", "--workflow-profile", str(profile), "--jobs", "100",
                "--slurm-init-seconds-before-status-checks", "5"]
    plan_ = plan_blocks((a.n + 1,) * 3, a.block)
    print(f"f{a.function}, n {a.n}, blocks of {a.block}: {len(plan_.blocks())} blocks, {len(plan_.planes())} planes; "
          f"group_components {group_components(plan_)}; -c {a.cores}; load average before "
          f"{os.getloadavg()[0]:.1f}")
    runs = [("local", []), ("slurm, batched", on_slurm)]
    if a.ungrouped:
        runs.append(("slurm, one job per plane and block", ["--job-points", "0"] + on_slurm))
    results = {}
    for name, extra in runs:
        out = RESULTS / f"slurm_f{a.function}_n{a.n}_b{a.block}_{name.split(',')[0]}{len(results)}"
        shutil.rmtree(out, ignore_errors=True)
        # --verbose: Snakemake's own log, which names the SLURM jobs it submits
        cmd = [sys.executable, "-m", "trivsel", "blocks", *args, "--out", str(out), "-c", str(a.cores), "--verbose",
               *extra]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if r.returncode != 0:
            sys.exit(f"{name}: trivsel blocks failed ({r.returncode}):\n{r.stderr[-4000:]}")
        jobs = len(set(re.findall(r"submitted with SLURM jobid (\d+)", r.stdout + r.stderr)))
        block_s = sum(row["s"] for row in job_table(out) if row["rule"] == "block")
        results[name] = {"summary": (out / "summary.json").read_text(), "tets": [
            np.load(p)["tets"].tobytes() for p in sorted((out / "pieces").glob("*.npz"))]}
        print(f"{name}: {wall:.0f} s wall, {jobs} SLURM jobs, block jobs' own seconds {block_s:.0f}, "
              f"load average {os.getloadavg()[0]:.1f}", flush=True)
    first = next(iter(results.values()))
    print("results identical:", all(r == first for r in results.values()))


def print_requests(text):
    """The largest memory and runtime requests of a Snakemake dry run's jobs."""
    mem = [int(m) for m in re.findall(r"mem_mb=(\d+)", text)]
    runtime = [int(m) for m in re.findall(r"runtime=(\d+)", text)]
    print(f"requests: mem_mb up to {max(mem)}, runtime up to {max(runtime)} min")


def plan(a):
    if a.method == "decimate":
        return plan_decimate(a)
    from trivsel.blocks import item_name, plan_blocks, read_config

    out = RESULTS / f"plan_n{a.n}_b{a.block}"
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "trivsel", "blocks", "--function", str(a.function), "--n", str(a.n), "--block",
           str(a.block), "--tol-inf", str(a.tol), "--no-merged", "--out", str(out), "-n"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(r.stderr[-4000:])
    text = r.stdout + r.stderr
    table = [ln for ln in text.splitlines() if ln.split()[:1] and ln.split()[0] in
             ("job", "kernels", "lines", "plane", "block", "merge", "all", "total")]
    print("\n".join(table[:table.index(next(ln for ln in table if ln.startswith("total"))) + 1]))
    print_requests(text)
    p = plan_blocks((a.n + 1,) * 3, a.block)
    pts = sum(int(np.prod([hi - lo for lo, hi in p.block_region(b)])) for b in p.blocks())
    print(f"{len(p.blocks())} blocks, {len(p.planes())} planes, {len(p.lines())} lines; "
          f"{pts / 1e9:.2f} G block points")
    if a.measured:
        _, mplan = read_config(a.measured)
        rows = {r["item"]: r for r in job_table(a.measured) if r["rule"] == "block"}
        secs = sum(rows[item_name(b)]["s"] for b in mplan.blocks())
        mpts = sum(int(np.prod([hi - lo for lo, hi in mplan.block_region(b)])) for b in mplan.blocks())
        other = sum(r["s"] for r in job_table(a.measured) if r["rule"] in ("lines", "plane", "merge"))
        rate = secs / mpts
        scale = p.n_points() / mplan.n_points()
        est = (rate * pts + other * scale) / 3600
        print(f"measured {rate * 1e6:.2f} s per million block points ({a.measured}); estimate "
              f"{est:.1f} core-hours for the blocks, lines, planes and merge of {a.n + 1}^3 "
              f"(lines, planes and merge scaled by the points)")


def plan_decimate(a):
    """The jobs and requests of ``trivsel blocks --method decimate`` on an (n+1)^3 grid, as a
    cluster runs them (Snakemake's dry run with the SLURM executor: a local run of this size is
    refused for memory), and, from a finished run (``--measured``), its core-hours: every job's
    seconds but the kernels' scaled by the points (each stage's work is per point)."""
    from trivsel.blocks import read_config

    out = RESULTS / f"plan_decimate_n{a.n}_b{a.block}"
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "trivsel", "blocks", "--function", str(a.function), "--n", str(a.n), "--block",
           str(a.block), "--method", "decimate", "--fraction", str(a.fraction), "--no-merged", "--out", str(out),
           "-n", "--", "--executor", "slurm", "--jobs", "100"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(r.stderr[-4000:])
    text = r.stdout + r.stderr
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.split()[:2] == ["job", "count"])
    end = next(i for i in range(start, len(lines)) if lines[i].startswith("total"))
    print("\n".join(lines[start:end + 1]))
    print_requests(text)
    if a.measured:
        _, mplan = read_config(a.measured)
        rows = [row for row in job_table(a.measured) if row["rule"] != "kernels"]
        secs = sum(row["s"] for row in rows)
        N = (a.n + 1) ** 3
        est = secs * N / mplan.n_points() / 3600
        print(f"measured {secs:.0f} job seconds for {mplan.n_points():,} points ({a.measured}); estimate "
              f"{est:.1f} core-hours for {a.n + 1}^3 ({N:,} points, scaled by the points)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=["seams", "big", "icbm", "plan", "local", "slurm"])
    ap.add_argument("--function", type=int, default=4)
    ap.add_argument("--n", type=int)
    ap.add_argument("--block", type=int)
    ap.add_argument("--tol", type=float)
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--measured", help="plan: a finished run's folder for the seconds per point")
    ap.add_argument("--method", choices=["greedy", "decimate"], default="greedy",
                    help="plan: the method (decimate: the jobs of --method decimate, stopped by --fraction)")
    ap.add_argument("--fraction", type=float, default=0.05, help="plan --method decimate: the kept fraction")
    ap.add_argument("--input", help="seams, local: a volume (e.g. a .zarr) whose central (n+1)^3 crop is reduced")
    ap.add_argument("--blocks", type=int, nargs="+", default=[8, 12, 47], help="local: block sizes")
    ap.add_argument("--tols", type=float, nargs="+", default=[8.0, 10.0], help="local: E_inf tolerances")
    ap.add_argument("--ungrouped", action="store_true", help="slurm: also one cluster job per plane and block")
    a = ap.parse_args()
    defaults = {"seams": (128, 32, 0.002), "big": (256, 64, 0.002), "icbm": (None, 64, 8.0),
                "plan": (1024, 128, 0.002), "local": (47, None, None), "slurm": (256, 64, 0.002)}[a.what]
    a.n = a.n if a.n is not None else defaults[0]
    a.block = a.block if a.block is not None else defaults[1]
    a.tol = a.tol if a.tol is not None else defaults[2]
    {"seams": seams, "big": big, "icbm": icbm, "plan": plan, "local": local, "slurm": slurm}[a.what](a)


if __name__ == "__main__":
    main()
