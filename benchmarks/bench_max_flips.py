#!/usr/bin/env python
"""Greedy's cap on flips after each insertion (``max_flips``): time against errors.

For each cap: the time of greedy on the 65^3 grid, function 4 to 10 % (best of
``--repeats`` runs in this process, after an untimed warm-up), and E_RMS and E_inf
on the 33^3 grid for functions 1-5 at 10 % and 5 %, as ratios to the uncapped run
(``max_flips`` = ``trivsel.mesh.UNLIMITED_ROUNDS``) measured in the same invocation.

Usage::

    python benchmarks/bench_max_flips.py                   # caps 3 4 6 8 and unlimited
    python benchmarks/bench_max_flips.py --caps 6 --repeats 3
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from trivsel import reduce
from trivsel.data import sample_grid
from trivsel.mesh import UNLIMITED_ROUNDS as UNLIMITED


def run(cap, n_time, repeats):
    times = []
    d = sample_grid(4, n_time)
    for _ in range(repeats):
        t0 = time.perf_counter()
        reduce(d, fractions=[0.1], method="greedy", max_flips=cap)
        times.append(time.perf_counter() - t0)
    errs = []
    for f in range(1, 6):
        res = reduce(sample_grid(f, 32), fractions=[0.1, 0.05], method="greedy", max_flips=cap)
        errs += [(s.errors["E_rms"], s.errors["E_inf"]) for s in res.snapshots]
    return min(times), np.array(errs)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--caps", type=int, nargs="+", default=[3, 4, 6, 8])
    ap.add_argument("--repeats", type=int, default=2, help="timed runs per cap on 65^3 (best is shown)")
    ap.add_argument("--n", type=int, default=64, help="grid intervals of the timed runs (default 64)")
    args = ap.parse_args(argv)
    reduce(sample_grid(4, 4), fractions=[0.1], method="greedy")  # warm-up: load the compiled kernels
    t_ref, e_ref = run(UNLIMITED, args.n, args.repeats)
    print(f"greedy, f4 {args.n + 1}^3 to 10 % (best of {args.repeats}); errors f1-f5 on 33^3 at 10 % and 5 %, "
          f"ratio to the unlimited run\n")
    print(f"{'max_flips':>10} {'seconds':>8} {'time ratio':>10} {'E_RMS mean':>10} {'worst':>6} "
          f"{'E_inf mean':>10} {'worst':>6}")
    print(f"{'unlimited':>10} {t_ref:8.2f} {1.0:10.2f} {1.0:10.3f} {1.0:6.3f} {1.0:10.3f} {1.0:6.3f}")
    for cap in args.caps:
        t, e = run(cap, args.n, args.repeats)
        r = e / e_ref
        print(f"{cap:>10} {t:8.2f} {t / t_ref:10.2f} {r[:, 0].mean():10.3f} {r[:, 0].max():6.3f} "
              f"{r[:, 1].mean():10.3f} {r[:, 1].max():6.3f}")


if __name__ == "__main__":
    main()
