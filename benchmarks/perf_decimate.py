"""Where a `decimate` run spends its time inside the compiled kernels, by sampling with Linux perf.

    python benchmarks/perf_decimate.py                    # aniso to 10 %
    python benchmarks/perf_decimate.py --volume icbm152 --fraction 0.05

numba's cached code carries no symbols for perf, so the run compiles its kernels afresh into a
temporary cache, records the address of every function in the compiled libraries, and charges
each sample to the function it falls in.  Functions that LLVM inlined are charged to their caller
(``_cost``, ``_gather``, ``_planes`` and ``_star`` show up as ``_best``).  With ``--hot N`` it also
prints the N hottest instruction offsets of ``_best`` (for `objdump -d` of the object written
beside them).  Needs `perf` (linux-tools) and the realdata extra.  Not a test: it prints a table.
"""

import argparse
import bisect
import collections
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

WORKLOAD = r'''
import sys, time
from trivsel.study.realdata import load_volume
from trivsel import decimation as D
vol, fraction, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
D.reduce_by_collapse(load_volume(vol, quick=True), [100])  # compile
with open(out + "/syms.txt", "w") as fh:
    for fn in (D._run, D._init, D._flush):
        for ov in fn.overloads.values():
            lib = ov.library
            for f in lib._final_module.functions:
                if not f.is_declaration:
                    a = lib.get_pointer_to_function(f.name)
                    if a:
                        fh.write(f"{a:x} {fn.__name__} {f.name}\n")
            if fn is D._run:
                open(out + "/run.o", "wb").write(lib._get_compiled_object())
data = load_volume(vol)
t0 = time.perf_counter()
D.reduce_by_collapse(data, [round(fraction * data.n_points)])
print(f"{vol} to {fraction:g}: {time.perf_counter() - t0:.2f} s (under perf)", flush=True)
'''


def short(name):
    """``trivsel.decimation._best`` from numba's mangled name (``_ZN7trivsel10decimation5_bestB2v4...``)."""
    parts, i = [], 3 if name.startswith("_ZN") else 0
    while i < len(name) and name[i].isdigit():
        j = i
        while name[j].isdigit():
            j += 1
        k = int(name[i:j])
        parts.append(name[j:j + k])
        i = j + k
    return ".".join(parts) or name[:40]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--volume", default="aniso")
    ap.add_argument("--fraction", type=float, default=0.1)
    ap.add_argument("--hot", type=int, default=0, help="also print the N hottest offsets in _best")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "cache"))
        data = Path(tmp) / "perf.data"
        subprocess.run(["perf", "record", "-q", "-o", str(data), sys.executable, "-c", WORKLOAD, a.volume,
                        str(a.fraction), tmp], env=env, check=True)
        ips = subprocess.run(["perf", "script", "-i", str(data), "-F", "ip"], capture_output=True, text=True,
                             check=True).stdout.split()
        rows = sorted((int(x, 16), entry, name) for x, entry, name in
                      (line.split(" ", 2) for line in Path(tmp, "syms.txt").read_text().splitlines()))
        starts = [r[0] for r in rows]
        by_fn, hot, total = collections.Counter(), collections.Counter(), 0
        for x in ips:
            ip = int(x, 16)
            i = bisect.bisect_right(starts, ip) - 1
            if i < 0 or ip - starts[i] > 0x10000:
                continue
            total += 1
            name = short(rows[i][2].strip())
            by_fn[name] += 1
            if name.endswith("._best"):
                hot[ip - starts[i]] += 1
        print(f"{total} samples in the kernels ({len(ips)} in the process)")
        print("| function (callees LLVM inlined included) | share of the kernels' samples |")
        print("|---|---|")
        for name, k in by_fn.most_common(12):
            print(f"| `{name}` | {100 * k / total:.1f} % |")
        if a.hot:
            obj = Path.cwd() / "perf_decimate_run.o"
            obj.write_bytes(Path(tmp, "run.o").read_bytes())
            print(f"\nhottest offsets from _best's start (objdump -d {obj.name}; add _best's offset from nm):")
            for off, k in hot.most_common(a.hot):
                print(f"  +{off:#x}: {100 * k / total:.1f} %")


if __name__ == "__main__":
    main()
