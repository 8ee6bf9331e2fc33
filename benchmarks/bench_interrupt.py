"""How fast `trivsel reduce` stops on Ctrl-C, at every stage of a large run.

Starts whole `trivsel reduce` processes, sends SIGINT after each of the given delays,
and prints the stage the run was in (from its stage messages), the time from the
signal to the process's exit, its exit status and its last stderr line.

    python benchmarks/bench_interrupt.py                       # grid 129^3 and 1e6 scattered points
    python benchmarks/bench_interrupt.py --delays 2 5 --grid 64 --scattered 200000
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _stage(stderr: str) -> str:
    stages = [x.split("] ", 1)[1] for x in stderr.replace("\r", "\n").splitlines() if x.startswith("trivsel [")]
    return stages[-1].split(" (")[0] if stages else "start-up (imports, reading)"


def interrupt_once(args, delay, workdir):
    out = Path(workdir) / f"out-{time.monotonic_ns()}"
    cmd = [sys.executable, "-m", "trivsel", "reduce", *args, "--progress", "always", "--out", str(out)]
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    if p.poll() is not None:
        return {"delay": delay, "stage": "finished before the signal", "latency": float("nan"),
                "exit": p.returncode, "last line": ""}
    t0 = time.perf_counter()
    p.send_signal(signal.SIGINT)
    _, err = p.communicate()
    latency = time.perf_counter() - t0
    last = [x for x in err.replace("\r", "\n").splitlines() if x.strip()]
    return {"delay": delay, "stage": _stage(err), "latency": latency, "exit": p.returncode,
            "last line": last[-1] if last else "", "output left": out.exists()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--delays", type=float, nargs="+", default=[1, 3, 6, 12, 25, 50])
    ap.add_argument("--grid", type=int, default=128, help="grid intervals n of the f4 run (0: skip)")
    ap.add_argument("--scattered", type=int, default=1_000_000, help="scattered points of the paper run (0: skip)")
    a = ap.parse_args(argv)
    # a shell starts background jobs with SIGINT ignored, and children inherit that:
    # restore the default so that the runs measured here see the signal
    signal.signal(signal.SIGINT, signal.default_int_handler)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        runs = []
        if a.grid:
            runs.append((f"f4 grid {a.grid + 1}^3, paper, 10 %",
                         ["--function", "4", "--n", str(a.grid), "--fractions", "0.1"]))
        if a.scattered:
            rng = np.random.default_rng(0)
            pts = rng.random((a.scattered, 3))
            np.savez(Path(d) / "cloud.npz", points=pts, values=np.sin(4 * pts[:, 0]) + pts[:, 1] ** 2)
            runs.append((f"{a.scattered} scattered points, paper, 1 %",
                         [str(Path(d) / "cloud.npz"), "--fractions", "0.01"]))
        for name, args in runs:
            for delay in a.delays:
                r = interrupt_once(args, delay, d)
                rows.append({"run": name, **r})
                print(f"{name:40s} signal at {delay:5.1f} s  {r['stage']:45s} exit {r['exit']}  "
                      f"stopped {r['latency']:.2f} s after the signal", flush=True)
    print("\n| run | signal at (s) | stage | stopped after (s) | exit | output left |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['run']} | {r['delay']:g} | {r['stage']} | {r['latency']:.2f} | {r['exit']} | "
              f"{r.get('output left', '')} |")
    print(f"\nmedian {np.nanmedian([r['latency'] for r in rows]):.2f} s, "
          f"max {np.nanmax([r['latency'] for r in rows]):.2f} s")


if __name__ == "__main__":
    main()
