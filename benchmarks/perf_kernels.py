"""Where a reduction spends its time inside the compiled kernels, by sampling with Linux perf.

    python benchmarks/perf_kernels.py                             # decimate, aniso to 10 %
    python benchmarks/perf_kernels.py --volume icbm152 --fraction 0.05
    python benchmarks/perf_kernels.py --volume icbm152 --crop 65 --fraction 0.05 --hot 30
    python benchmarks/perf_kernels.py --method greedy --n 64      # f4 on 65^3 to 10 %

The run uses numba's just-in-time kernels (``TRIVSEL_AOT=0``: the same functions and LLVM IR
as the ahead-of-time module a decimation loads by default, see trivsel/aot.py).
numba's cached code has no symbols for perf, so the run compiles its kernels afresh into a
temporary cache, records the address of every function in every compiled library of trivsel
(numba internals: a library's ``_final_module`` and ``_get_compiled_object``, numba 0.68), and
charges each sample to the function it falls in.  Functions that LLVM inlined are charged to
their caller (for `decimate`, ``_cost``, ``_gather``, ``_planes`` and ``_star`` show up as
``_best``).  With ``--hot N`` it also prints the N hottest instruction offsets of the hottest
function and writes its object file (for `objdump -d`).  Needs `perf` (linux-tools); `decimate`
needs the realdata extra.  Not a test: it prints a table.
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
import numba
import trivsel
method, source, fraction, out, crop = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4], int(sys.argv[5])
if method == "decimate":
    from trivsel.study.realdata import REAL, central_crop, load_nifti, load_volume, package_file
    small = load_volume(source, quick=True)
    # the central crop of the whole volume, or the study's volume (a crop already)
    data = central_crop(load_nifti(package_file(*REAL[source][:2]), source), crop) if crop else load_volume(source)
else:
    small, data = trivsel.sample_grid(4, 8), trivsel.sample_grid(4, int(source))
trivsel.reduce(small, fractions=[0.5], method=method)  # compile
with open(out + "/syms.txt", "w") as fh:
    for name, mod in list(sys.modules.items()):
        if not name.startswith("trivsel"):
            continue
        for fn in list(vars(mod).values()):
            if not isinstance(fn, numba.core.dispatcher.Dispatcher):
                continue
            for k, ov in enumerate(fn.overloads.values()):
                lib = ov.library
                try:
                    obj = lib._get_compiled_object()
                except RuntimeError:
                    continue
                label = f"{name}.{fn.__name__}.{k}"
                open(f"{out}/{label}.o", "wb").write(obj)
                for f in lib._final_module.functions:
                    if not f.is_declaration:
                        a = lib.get_pointer_to_function(f.name)
                        if a:
                            fh.write(f"{a:x} {label} {f.name}\n")
t0 = time.perf_counter()
trivsel.reduce(data, fractions=[fraction], method=method)
print(f"{method} on {source} to {fraction:g}: {time.perf_counter() - t0:.2f} s (under perf)", flush=True)
'''


def short(name):
    """``trivsel.decimation.collapse._best`` from numba's mangled name (``_ZN7trivsel10decimation8collapse5_best...``)."""
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
    ap.add_argument("--method", default="decimate", choices=["decimate", "greedy", "paper"])
    ap.add_argument("--volume", default="aniso", help="decimate: a volume of trivsel.study.realdata")
    ap.add_argument("--n", type=int, default=64, help="greedy, paper: f4 on an (n+1)^3 grid")
    ap.add_argument("--crop", type=int, default=0, help="decimate: the central crop^3 of the whole volume (0: the study's volume)")
    ap.add_argument("--fraction", type=float, default=0.1)
    ap.add_argument("--hot", type=int, default=0, help="also print the N hottest offsets of the hottest function")
    a = ap.parse_args(argv)
    source = a.volume if a.method == "decimate" else str(a.n)
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "cache"), TRIVSEL_AOT="0")
        data = Path(tmp) / "perf.data"
        subprocess.run(["perf", "record", "-q", "-o", str(data), sys.executable, "-c", WORKLOAD, a.method, source,
                        str(a.fraction), tmp, str(a.crop)], env=env, check=True)
        ips = subprocess.run(["perf", "script", "-i", str(data), "-F", "ip"], capture_output=True, text=True,
                             check=True).stdout.split()
        rows = sorted((int(x, 16), label, name) for x, label, name in
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
            hot[(name, rows[i][1], ip - starts[i])] += 1
        print(f"{total} samples in the kernels ({len(ips)} in the process)")
        print("| function (callees LLVM inlined included) | share of the kernels' samples |")
        print("|---|---|")
        for name, k in by_fn.most_common(12):
            print(f"| `{name}` | {100 * k / total:.1f} % |")
        if a.hot and by_fn:
            top = by_fn.most_common(1)[0][0]
            offs = [(key, k) for key, k in hot.items() if key[0] == top]
            label = max(offs, key=lambda e: e[1])[0][1]
            obj = Path.cwd() / f"perf_{label}.o"
            obj.write_bytes(Path(tmp, f"{label}.o").read_bytes())
            print(f"\nhottest offsets from the start of {top} (objdump -d {obj.name}; add the function's "
                  "offset from nm):")
            for (name, lab, off), k in sorted(offs, key=lambda e: -e[1])[: a.hot]:
                print(f"  +{off:#x}: {100 * k / total:.1f} %")


if __name__ == "__main__":
    main()
