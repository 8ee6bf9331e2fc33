"""How many points the insertion methods visit, by the size of the call, and how large the tets stay.

    python benchmarks/point_work.py                              # paper, f4 on 65^3, to 2 % and 10 %
    python benchmarks/point_work.py --method greedy
    python benchmarks/point_work.py --n 32 --fractions 0.05 0.1

The kernel has no such counters (they would cost every reduction), so the script copies the
package into a temporary directory and adds two counts to that copy only:

* every call of ``_fill_tets`` (the cavity of an insertion or a flip) adds its points;
* every evaluation in ``_evaluate_at`` adds the points it gathered.

Each count goes to one of three classes by the call's point count: at most 64, 65-1000, or more
than 1000. The copy runs with numba's own kernels (``TRIVSEL_AOT=0``) in a temporary numba
cache, so it compiles once (about a minute) and leaves the package's caches alone. For each
fraction the script runs a reduction from scratch and prints the cumulative counts. It also
prints the sizes of the live tets' point buckets (``S.blen``) at the end. Not a test: it prints
a table.
"""

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# (file, the exact text, the text with the counters); the counters are S.ctr[N .. N + 11],
# N the kernel's own counter count
PATCHES = [
    ("trivsel/mesh/state.py", "N_COUNTERS = {n}", "N_COUNTERS = {n} + 12"),
    ("trivsel/mesh/storage.py",
     "    npairs = 0\n    for j in range(m):\n",
     "    npairs = 0\n    _cls = 0 if m <= 64 else (1 if m <= 1000 else 2)\n"
     "    ctr[{n} + _cls] += m\n    ctr[{n} + 3 + _cls] += 1\n    for j in range(m):\n"),
    ("trivsel/mesh/criteria.py",
     "        ctr[C_LASTM] = m\n    buf = S.wbuf\n",
     "        ctr[C_LASTM] = m\n    _cls = 0 if m <= 64 else (1 if m <= 1000 else 2)\n"
     "    ctr[{n} + 6 + _cls] += m\n    ctr[{n} + 9 + _cls] += 1\n    buf = S.wbuf\n"),
]

WORKLOAD = r'''
import sys
import numpy as np
import trivsel
from trivsel.mesh.state import N_COUNTERS
from trivsel.methods import get_method

print(f"(the counting copy: {trivsel.__file__})")

method, function, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
fractions = [float(f) for f in sys.argv[4:]]
meshes = []
m = get_method(method)
advance = m.advance


def recording_advance(mesh, *args, **kwargs):
    meshes.append(mesh)
    return advance(mesh, *args, **kwargs)


m.advance = recording_advance
data = trivsel.sample_grid(function, n)
c0 = N_COUNTERS - 12
print(f"{method}, f{function} on {n + 1}^3: points visited (calls), by the call's point count")
print("| to | fills <= 64 | fills 65-1000 | fills > 1000 | evaluations <= 64 | evaluations 65-1000 "
      "| evaluations > 1000 |")
print("|---|---|---|---|---|---|---|")
stats = []
for f in fractions:
    meshes.clear()
    trivsel.reduce(data, fractions=[f], method=method)
    S = meshes[-1].S
    c = S.ctr[c0:c0 + 12]
    cells = [f"{c[k]:,} ({c[k + 3]:,})" for k in (0, 1, 2)] + [f"{c[k]:,} ({c[k + 3]:,})" for k in (6, 7, 8)]
    print(f"| {f:g} | " + " | ".join(cells) + " |")
    hw = S.ctr[0]
    blen = S.blen[:hw][S.alive[:hw].astype(bool)]
    stats.append((f, blen))
print("\n| to | live tets | median bucket | 90th percentile | largest |")
print("|---|---|---|---|---|")
for f, blen in stats:
    print(f"| {f:g} | {blen.size:,} | {np.median(blen):g} | {np.percentile(blen, 90):g} | {blen.max():,} |")
'''


def patched_copy(dest):
    """A copy of the package with the counters added; fails if the kernel's text has moved."""
    shutil.copytree(ROOT / "trivsel", dest / "trivsel", ignore=shutil.ignore_patterns("__pycache__"))
    state = (dest / "trivsel/mesh/state.py").read_text()
    n = int(state.split("N_COUNTERS = ", 1)[1].split()[0])
    for rel, old, new in PATCHES:
        path = dest / rel
        text = path.read_text()
        old, new = old.format(n=n), new.format(n=n)
        if text.count(old) != 1:
            raise SystemExit(f"point_work.py: the text to patch was not found once in {rel}; update PATCHES")
        path.write_text(text.replace(old, new))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", choices=["paper", "greedy"], default="paper")
    ap.add_argument("--function", type=int, default=4)
    ap.add_argument("--n", type=int, default=64, help="grid intervals per axis (65^3 points for 64)")
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.02, 0.1])
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        patched_copy(tmp)
        env = dict(os.environ, PYTHONPATH=str(tmp), TRIVSEL_AOT="0", NUMBA_CACHE_DIR=str(tmp / "cache"))
        cmd = [sys.executable, "-c", WORKLOAD, a.method, str(a.function), str(a.n), *map(str, a.fractions)]
        # run from the copy: `python -c` puts the working directory first on sys.path
        return subprocess.run(cmd, env=env, cwd=tmp).returncode


if __name__ == "__main__":
    sys.exit(main())
