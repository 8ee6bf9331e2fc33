"""Hashes of `method="decimate"` runs, to check that a kernel change leaves the results identical.

    python benchmarks/decimate_hashes.py save  HASHES.json   # before the change
    python benchmarks/decimate_hashes.py check HASHES.json   # after: exit 1 if any run differs

19 runs: the volumes of trivsel.study.realdata (needs the realdata extra) at full size and as 16^3
crops, both collapse orders, every box point locked, and E_inf tolerances.  Each run is hashed over
the removed points in order, the residuals, the tetrahedra and the squared-error sum at 30 %, 10 %
and 5 % of the points.  About a minute on 2 cores.
"""

import argparse
import hashlib
import json
import sys

import numpy as np

from trivsel.decimation import Decimation
from trivsel.study.realdata import load_volume

CASES = ([(name, True, key, "box", None)
          for name in ("icbm152", "statmap", "aniso", "chirp", "steps", "gm", "piesno") for key in ("sse", "max")]
         + [("icbm152", False, "sse", "box", None), ("chirp", False, "sse", "box", None),
            ("aniso", True, "sse", "all", None), ("statmap", True, "sse", "box", 0.5),
            ("chirp", True, "max", "box", 0.3)])


def run_hash(name, quick, key, lock, tol_inf):
    data = load_volume(name, quick=quick)
    dec = Decimation(data.ijk, data.shape, data.values, key=key, lock=lock, tol_inf=tol_inf)
    h = hashlib.sha1()
    for fraction in (0.3, 0.1, 0.05):
        dec.run(int(fraction * data.n_points))
        for a in (dec.removed(), dec.residuals(), dec.tetrahedra(), np.float64(dec.sse)):
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mode", choices=["save", "check"])
    ap.add_argument("path")
    a = ap.parse_args(argv)
    hashes = {"-".join(map(str, c)): run_hash(*c) for c in CASES}
    if a.mode == "save":
        with open(a.path, "w") as fh:
            json.dump(hashes, fh, indent=1)
        print(f"{len(hashes)} runs hashed into {a.path}")
        return 0
    with open(a.path) as fh:
        ref = json.load(fh)
    differ = [k for k in ref if ref[k] != hashes.get(k)]
    print(f"{len(ref) - len(differ)} of {len(ref)} runs identical" + (f"; differ: {', '.join(differ)}" if differ else ""))
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
