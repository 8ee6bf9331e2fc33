#!/usr/bin/env python
"""E_inf of ``decimate`` with ``criterion="max"`` at VTK's vertex counts, against the VTK runs of
a ``bench_realdata.py`` CSV (VTK's runs are seeded, so they are not repeated here).

    python benchmarks/bench_decimate_max.py benchmarks/results/bench_realdata_<stamp>.csv

Prints, per row of the CSV: VTK's E_inf (median of its runs), E_inf of ``greedy`` (from the CSV),
of ``decimate`` with the default ``sse`` order (from the CSV) and with ``criterion="max"`` (run
here, data values), and the last over VTK's; and E_RMS of both ``decimate`` orders with fitted
values.
"""

from __future__ import annotations

import argparse
import csv
import time

import trivsel
from trivsel.study.realdata import load_volume, warm_up


def _cell(row, key):
    """A CSV value to 4 significant digits, or "-" if the run had no such column (a CSV of
    ``bench_realdata.py --methods decimate`` has no greedy columns)."""
    return f"{float(row[key]):.4g}" if row.get(key) not in (None, "") else "-"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("csv", help="a bench_realdata.py CSV (with decimate columns; greedy's are optional)")
    a = ap.parse_args(argv)
    with open(a.csv, newline="") as fh:
        rows = list(csv.DictReader(fh))
    warm_up(["decimate"])
    print("| volume | kept | n_vertices | VTK E_inf | greedy E_inf | decimate E_inf | decimate max E_inf | "
          "max / VTK | decimate fit E_RMS | decimate max fit E_RMS | decimate max s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    cache = {}
    for r in rows:
        name = r["volume"]
        data = cache.setdefault(name, load_volume(name))
        t0 = time.perf_counter()
        res = trivsel.reduce(data, count=int(r["n_vertices"]), method="decimate", criterion="max",
                             values=["data", "fit"])
        s = res.snapshots[-1]
        took = time.perf_counter() - t0
        vtk = float(r["vtk_E_inf"])
        print(f"| {name} | {100 * float(r['fraction']):g} % | {r['n_vertices']} | {vtk:.4g} | "
              f"{_cell(r, 'greedy_E_inf')} | {float(r['decimate_E_inf']):.4g} | {s.errors['E_inf']:.4g} | "
              f"{s.errors['E_inf'] / vtk:.2f} | {float(r['decimate_fit_E_rms']):.4g} | "
              f"{s.fit['errors']['E_rms']:.4g} | {took:.1f} |", flush=True)


if __name__ == "__main__":
    main()
