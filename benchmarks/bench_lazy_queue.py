#!/usr/bin/env python
"""`decimate`'s lazy queue updates against the strict greedy order, per switch factor.

    python benchmarks/bench_lazy_queue.py                                   # five volumes, f = 3, 2, 1.5
    python benchmarks/bench_lazy_queue.py --volumes aniso --factors 2 --key max

For each volume of trivsel.study.realdata (the real ones need the realdata extra) and kept fraction,
runs ``reduce_by_collapse(data, [K], exact_within=f)`` (lazy while more than f K vertices remain,
exact below; f = inf is the strict order) and prints, for each f, the CPU time and E_RMS (data
values), E_inf and E_RMS with fitted values as ratios to the strict run in the same process.
Times exclude the fits.
"""

import argparse
import sys
import time

import numpy as np

from trivsel.decimation import reduce_by_collapse
from trivsel.study.realdata import load_volume


def run(data, K, f, key):
    t0 = time.process_time()
    snaps, _, _, t_fits = reduce_by_collapse(data, [K], exact_within=f, key=key, values=("data", "fit"))
    s = snaps[-1]
    return time.process_time() - t0 - t_fits, s.errors["E_rms"], s.errors["E_inf"], s.fit["errors"]["E_rms"]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--volumes", nargs="+", default=["icbm152", "statmap", "aniso", "chirp", "steps"])
    ap.add_argument("--fractions", nargs="+", type=float, default=[0.1, 0.05])
    ap.add_argument("--factors", nargs="+", type=float, default=[3.0, 2.0, 1.5])
    ap.add_argument("--key", choices=["sse", "max"], default="sse")
    a = ap.parse_args(argv)
    warm = load_volume("chirp", quick=True)
    for f in (np.inf, 2.0):
        reduce_by_collapse(warm, [100], exact_within=f, values=("data", "fit"))
    head = " | ".join(f"f={f:g}: time | E_RMS | E_inf | fit E_RMS" for f in a.factors)
    print(f"| volume | kept | K | strict s | {head} |")
    print("|---" * (4 + 4 * len(a.factors)) + "|")
    for name in a.volumes:
        data = load_volume(name)
        for fraction in a.fractions:
            K = int(fraction * data.n_points)
            base = run(data, K, np.inf, a.key)
            cells = []
            for f in a.factors:
                r = run(data, K, f, a.key)
                cells += [f"{x / b:.3f}" for x, b in zip(r, base)]
            print(f"| {name} | {fraction:.0%} | {K} | {base[0]:.2f} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
