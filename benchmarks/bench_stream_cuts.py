#!/usr/bin/env python
r"""The quota job's cut, streamed, against the same cut of every record held at once.

    python benchmarks/bench_stream_cuts.py --regions 1000 --per 20000 60000

A quota pass of ``decimate`` in blocks cuts across its regions' records: each region's running
maxima of collapse costs and its running squared error, 16 bytes a recorded collapse, in one
costs file per x-slab of regions.  The seams pass records about every seam point, about 6 % of
the grid's points on f4 at 129^3 in blocks of 32 (121,728 of 2.1 M), so some 60 M at 1025^3.

This writes such records (``--regions`` regions of ``--per`` collapses each, random costs with
ties, ten slab files), then runs the cut as a process of its own under ``/usr/bin/time``, twice:

* ``held``: every record read into memory, concatenated and sorted by (cost, region), the first
  ``surplus`` taken (what the quota job did before it read the records in streams);
* ``streamed``: :func:`trivsel.decimation.streamcut.streamed_cut_quota` over the files, one
  region's arrays at a time (what the quota job does).

Prints, for each size, both processes' wall time and peak memory, and whether their counts are
the same (they must be: the same cut).  With ``--budget`` the cut is also held to a squared-error
budget (half the records' total); the held cut's error is then summed in the cut's order, the
streamed one's region by region, so only the counts are compared.
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

SLABS = 10


def write_records(folder, regions, per, seed=0):
    """``regions`` records of ``per`` collapses, in ``SLABS`` files ``costs/S.npz`` (members
    ``runmax_R`` and ``sse_R``, as the rcosts jobs write them).  Returns the sum of the last
    running squared errors."""
    rng = np.random.default_rng(seed)
    (folder / "costs").mkdir(parents=True)
    total = 0.0
    for s in range(SLABS):
        with zipfile.ZipFile(folder / "costs" / f"{s}.npz", "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            for r in range(s * regions // SLABS, (s + 1) * regions // SLABS):
                costs = np.maximum.accumulate(np.round(rng.exponential(1.0, per), 2))  # ties
                sse = np.cumsum(rng.exponential(1e-3, per))
                total += float(sse[-1])
                for name, a in ((f"runmax_{r}", costs), (f"sse_{r}", sse)):
                    with zf.open(name + ".npy", "w", force_zip64=True) as fh:
                        np.lib.format.write_array(fh, a)
    return total


def read_regions(folder, regions):
    """Every region's (runmax, sse) in order, one region at a time, as the quota job reads them."""
    for s in range(SLABS):
        with np.load(folder / "costs" / f"{s}.npz") as z:
            for r in range(s * regions // SLABS, (s + 1) * regions // SLABS):
                yield z[f"runmax_{r}"], z[f"sse_{r}"]


def held_cut(folder, regions, surplus, budget):
    """The cut of every record held at once: by (cost, region), the first ``surplus``, then the
    prefix whose squared error (summed in that order) fits in ``budget``."""
    runmax, sse = zip(*read_regions(folder, regions))
    value = np.concatenate(runmax)
    region = np.repeat(np.arange(len(runmax)), [len(r) for r in runmax])
    take = np.lexsort((region, value))[:surplus]
    if budget < np.inf:
        add = np.concatenate([np.diff(s, prepend=0.0) for s in sse])[take]
        take = take[:int(np.searchsorted(np.cumsum(add) > budget, True))]
    return np.bincount(region[take], minlength=len(runmax))


def child(mode, folder, regions, surplus, budget):
    folder = Path(folder)
    if mode == "held":
        counts = held_cut(folder, regions, surplus, budget)
    else:
        from trivsel.decimation.streamcut import streamed_cut_quota

        counts, _ = streamed_cut_quota(lambda: read_regions(folder, regions), surplus, budget)
    print(hashlib.sha256(np.asarray(counts, np.int64).tobytes()).hexdigest()[:16], int(np.sum(counts)))


def timed(mode, folder, regions, surplus, budget):
    """``(wall s, peak MB, counts' hash)`` of the cut as a process of its own."""
    cmd = ["/usr/bin/time", "-f", "%e %M", sys.executable, __file__, "--child", mode, str(folder), str(regions),
           str(surplus), repr(budget)]
    p = subprocess.run(cmd, capture_output=True, text=True, check=True)
    wall, kb = p.stderr.strip().splitlines()[-1].split()
    return float(wall), int(kb) / 1024, p.stdout.split()[0]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--regions", type=int, default=1000)
    ap.add_argument("--per", type=int, nargs="+", default=[20000, 60000], help="recorded collapses per region")
    ap.add_argument("--surplus", type=float, default=0.3, help="the surplus, as a part of the records")
    ap.add_argument("--budget", action="store_true", help="also a squared-error budget: half the records' total")
    ap.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        mode, folder, regions, surplus, budget = a.child
        return child(mode, folder, int(regions), int(surplus), float(budget))
    print("| recorded collapses | held: wall s | held: peak MB | streamed: wall s | streamed: peak MB | same counts |")
    print("|---|---|---|---|---|---|")
    for per in a.per:
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            total = write_records(folder, a.regions, per)
            surplus = int(a.surplus * a.regions * per)
            budget = 0.5 * total if a.budget else np.inf
            h = timed("held", folder, a.regions, surplus, budget)
            s = timed("streamed", folder, a.regions, surplus, budget)
            print(f"| {a.regions * per:,} | {h[0]:.1f} | {h[1]:.0f} | {s[0]:.1f} | {s[1]:.0f} | {h[2] == s[2]} |",
                  flush=True)


if __name__ == "__main__":
    sys.exit(main())
