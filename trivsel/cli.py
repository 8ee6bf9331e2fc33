"""Command-line interface: ``trivsel reduce``, ``trivsel compare`` and ``trivsel compile``.

The workflow, the benchmarks and CI depend on these names::

    trivsel reduce --function 4 --n 16 --fractions 0.5 0.2 0.1 --out DIR
    trivsel reduce INPUT [--array NAME] --fractions 0.5 0.2 0.1 --out DIR
    trivsel compare NEW.csv GOLDEN.csv --rtol 1e-6
    trivsel compile [--method paper] [--part 0|1]

Bad input gives one line ``trivsel: error: ...`` on stderr, exit status 2 and no
output files.
"""

from __future__ import annotations

import argparse
import sys

from .errors_input import InputError

__all__ = ["main", "build_parser"]


def _add_option_args(p):
    from .reduction import DEFAULTS, OPTION_DOCS

    g = p.add_argument_group("method options (the paper's open choices; defaults reproduce Table 1)")
    g.add_argument("--method", default=DEFAULTS["method"], choices=["paper", "greedy"],
                   help="'paper': curvature ranking (sections 2-4); 'greedy': insert the worst-approximated "
                        "point next (error-driven, beyond the paper)")
    g.add_argument("--greedy-key", default="max", choices=["max", "sse"],
                   help="greedy: next point = largest residual ('max', aims at E_inf) or worst point of the tet "
                        "with the largest squared-error sum ('sse', aims at E_RMS)")
    g.add_argument("--values", nargs="+", default=["data"], choices=["data", "fit"],
                   help="vertex values: the selected points' own ('data', the paper) and/or least-squares "
                        "values over all points ('fit'); one errors.csv row per snapshot and mode")
    g.add_argument("--criterion", default=None, choices=["rms", "max", "sse"],
                   help=OPTION_DOCS["criterion"] + " (default: rms for paper, sse for greedy)")
    g.add_argument("--candidates", default=DEFAULTS["candidates"], choices=["all", "interior"],
                   help=OPTION_DOCS["candidates"])
    g.add_argument("--tie-order", default=DEFAULTS["tie_order"], choices=["index", "reverse", "random", "centre"],
                   help=OPTION_DOCS["tie_order"])
    g.add_argument("--boundary-diagonals", default=DEFAULTS["boundary_diagonals"], choices=["kuhn", "mirrored"],
                   help=OPTION_DOCS["boundary_diagonals"])
    g.add_argument("--no-vertices-in-error", dest="own_vertices", action="store_false",
                   help="exclude a tet's own vertices from its error (eqs. 14-15)")
    g.add_argument("--final-pass", action="store_true", help=OPTION_DOCS["final_pass"])
    g.add_argument("--first-improving", action="store_true", help=OPTION_DOCS["first_improving"])
    g.add_argument("--curvature", default=DEFAULTS["curvature"], choices=["direct", "local-frame"],
                   help=OPTION_DOCS["curvature"])
    g.add_argument("--boundary-flips", dest="boundary_flips", action="store_true", default=None,
                   help="also 2-2 flip edges between coplanar hull faces (default: on for greedy, off for paper)")
    g.add_argument("--no-boundary-flips", dest="boundary_flips", action="store_false")
    g.add_argument("--neighbourhood", default=DEFAULTS["neighbourhood"], choices=["kuhn", "two-ring", "box"],
                   help=OPTION_DOCS["neighbourhood"])
    g.add_argument("--ranking", default=DEFAULTS["ranking"], choices=["curvature", "ascending", "random", "analytic"],
                   help=OPTION_DOCS["ranking"])
    g.add_argument("--rel-tol", type=float, default=DEFAULTS["rel_tol"], help=OPTION_DOCS["rel_tol"])
    g.add_argument("--max-flips", type=int, default=None, help=OPTION_DOCS["max_flips"])
    g.add_argument("--swap-memory", default=DEFAULTS["swap_memory"], choices=["run", "call"],
                   help=OPTION_DOCS["swap_memory"])
    g.add_argument("--seed", type=int, default=DEFAULTS["seed"], help="seed for the random tie order")


class _Parser(argparse.ArgumentParser):
    """argparse with the one-line error of every other bad input (no usage block);
    the sub-command parsers inherit it."""

    def error(self, message):
        self.exit(2, f"trivsel: error: {message}\n")


def build_parser():
    parser = _Parser(prog="trivsel", description="Data point selection for piecewise trilinear "
                                     "approximation (Hamann & Chen 1994).")
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", required=True)

    r = sub.add_parser("reduce", help="select points and write the reduced meshes and their errors",
                       description="Reduce a Table-1 function sampled on a grid (--function, --n) or a user "
                                   "file (.vti/.vtk/.vtu via pyvista, .npz, .csv with x,y,z,value).")
    r.add_argument("input", nargs="?", help="data file (omit with --function)")
    r.add_argument("--function", help="Table-1 function: 1-5 or quadratic, saddle, cubic, exponential, "
                                      "trigonometric")
    r.add_argument("--n", type=int, default=16, help="grid intervals per axis for --function (default 16)")
    r.add_argument("--array", help="point-data array / value column of the input file")
    stop = r.add_argument_group("stopping (section 3)")
    stop.add_argument("--fractions", type=float, nargs="+", help="fractions of all points, e.g. 0.5 0.2 0.1")
    stop.add_argument("--count", type=int, help="number of points to select")
    stop.add_argument("--tol-rms", type=float, help="stop when E_RMS <= this")
    stop.add_argument("--tol-inf", type=float, help="stop when E_inf <= this")
    r.add_argument("--out", required=True, help="output folder (errors.csv, mesh_<fraction>.vtu, result.json)")
    r.add_argument("--check", action="store_true", help="run the mesh-validity checker at every snapshot (slow)")
    r.add_argument("--progress", choices=["auto", "always", "never"], default="auto",
                   help="progress line on stderr: 'auto' shows it only on a terminal (quiet in workflow logs)")
    r.add_argument("--threads", type=int, default=1,
                   help="threads for the curvature fits, the stage that parallelises (default 1; the result "
                        "does not depend on it)")
    _add_option_args(r)

    k = sub.add_parser("compile", help="compile the numba kernels into the on-disk cache (once per machine)",
                       description="A reduction compiles its kernels on first use (once; they load "
                                   "from the cache afterwards).  --part 0 and --part 1 compile the two halves "
                                   "(swapping; insertion) in two processes side by side, as the workflow's "
                                   "kernels rule does, then --part 2 the drivers of both methods; without "
                                   "--part, everything.")
    k.add_argument("--method", default="paper", choices=["paper", "greedy"])
    k.add_argument("--part", type=int, choices=[0, 1, 2],
                   help="one part only: 0 swapping, 1 insertion, 2 the drivers (default: all)")

    c = sub.add_parser("compare", help="compare an error table with a golden one; exit 1 on any change",
                       description="Cells are matched on their key columns and compared with "
                                   "|new - golden| <= atol + rtol * |golden|.")
    c.add_argument("new")
    c.add_argument("golden")
    c.add_argument("--rtol", type=float, default=1e-6)
    c.add_argument("--atol", type=float, default=0.0)
    return parser


def _version():
    from . import __version__

    return f"trivsel {__version__}"


def _progress_line(done, total, e_rms, e_inf, seconds):
    """One self-overwriting status line: bar, points, current errors, rate."""
    width = 24
    frac = done / total if total else 1.0
    bar = "#" * int(round(width * frac))
    rate = done / seconds if seconds > 0 else 0.0
    end = "\n" if done >= total else ""
    sys.stderr.write(f"\r[{bar:<{width}}] {done}/{total} points  E_rms {e_rms:.4g}  E_inf {e_inf:.4g}  "
                     f"{rate:.0f} points/s{end}")
    sys.stderr.flush()


def _cmd_reduce(a):
    from .data import resolve_function, sample_grid
    from .io import load, write_outputs
    from .reduction import reduce

    if (a.input is None) == (a.function is None):
        raise InputError("give either an input file or --function (not both)")
    if a.function is not None:
        if a.array is not None:
            raise InputError("--array applies to input files, not to --function")
        data = sample_grid(resolve_function(a.function), a.n)
    else:
        data = load(a.input, a.array)
    check = None
    if a.check:
        from .mesh import check_mesh

        check = check_mesh
    criterion = a.criterion or ("sse" if a.method == "greedy" else "rms")
    show = a.progress == "always" or (a.progress == "auto" and sys.stderr.isatty())
    result = reduce(data, progress=_progress_line if show else None, fractions=a.fractions, count=a.count, tol_rms=a.tol_rms, tol_inf=a.tol_inf,
                    method=a.method, criterion=criterion, candidates=a.candidates, tie_order=a.tie_order,
                    own_vertices=a.own_vertices, final_pass=a.final_pass, first_improving=a.first_improving,
                    boundary_diagonals=a.boundary_diagonals, curvature=a.curvature, ranking=a.ranking,
                    rel_tol=a.rel_tol, values=a.values, greedy_key=a.greedy_key,
                    neighbourhood=a.neighbourhood, boundary_flips=a.boundary_flips, max_flips=a.max_flips,
                    swap_memory=a.swap_memory,
                    seed=a.seed, threads=a.threads, check=check)
    out = write_outputs(result, a.out, extra={"command": sys.argv})
    df = result.errors_frame()
    print(df.to_string(index=False, float_format=lambda v: f"{v:.6g}"))
    print(f"wrote {out}/errors.csv, {len(result.snapshots)} mesh file(s) and result.json "
          f"in {result.timings['total']:.2f} s", file=sys.stderr)
    return 0


def _cmd_compile(a):
    import time

    from .mesh import compile_kernels

    t0 = time.perf_counter()
    n = compile_kernels(a.method, a.part)
    part = "all parts" if a.part is None else f"part {a.part}"
    print(f"compiled or loaded {n} kernel signatures ({a.method}, {part}) in {time.perf_counter() - t0:.1f} s")
    return 0


def _cmd_compare(a):
    from .compare import compare_tables, format_mismatches

    for path in (a.new, a.golden):
        import os

        if not os.path.exists(path):
            raise InputError(f"table {path!r} does not exist")
    mism = compare_tables(a.new, a.golden, rtol=a.rtol, atol=a.atol)
    if mism:
        print(format_mismatches(mism, a.new, a.golden, a.rtol, a.atol))
        return 1
    print(f"{a.new} matches {a.golden} (rtol {a.rtol:g}, atol {a.atol:g})")
    return 0


def main(argv=None):
    parser = build_parser()
    a = parser.parse_args(argv)
    try:
        if a.command == "reduce":
            return _cmd_reduce(a)
        if a.command == "compile":
            return _cmd_compile(a)
        if a.command == "compare":
            return _cmd_compare(a)
    except InputError as exc:
        print(f"trivsel: error: {exc}", file=sys.stderr)
        return 2
    return 2  # pragma: no cover


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
