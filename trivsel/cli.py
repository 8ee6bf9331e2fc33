"""Command-line interface: ``trivsel reduce``, ``trivsel compare`` and ``trivsel compile``.

The workflow, the benchmarks and CI depend on these names::

    trivsel reduce --function 4 --n 16 --fractions 0.5 0.2 0.1 --out DIR
    trivsel reduce INPUT [--array NAME] [--volume K] --fractions 0.5 0.2 0.1 --out DIR
    trivsel compare NEW.csv GOLDEN.csv --rtol 1e-6
    trivsel compile [--method paper] [--part 0|1|2]
    trivsel convert INPUT OUT.zarr [--chunks 64] [--array NAME] [--volume K]
    trivsel blocks INPUT --block 64 --tol-inf 0.01 --out DIR [-c N] [-n] [--verbose] [-- SNAKEMAKE ARGS]

Bad input gives one line ``trivsel: error: ...`` on stderr, exit status 2 and no
output files.
"""

from __future__ import annotations

import argparse
import sys

from .exceptions import InputError, MemoryShortage, check_tolerance, one_line, shown

__all__ = ["main", "build_parser"]


class _Parser(argparse.ArgumentParser):
    """argparse with the one-line error of every other bad input (no usage block);
    the sub-command parsers inherit it."""

    def error(self, message):
        self.exit(2, f"trivsel: error: {message}\n")


def build_parser():
    parser = _Parser(prog="trivsel", description="Data point selection for piecewise trilinear "
                                     "approximation (Hamann & Chen 1994).",
                     epilog="exit status: 0 done; 1 a comparison found changes (compare) or a job failed "
                            "(blocks); 2 bad input, one line on stderr, nothing written; 130 interrupted (Ctrl-C, "
                            "SIGTERM), the output folder as it was; 141 stdout closed before the command printed "
                            "(`| head`), what it wrote is kept")
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", required=True)

    r = sub.add_parser("reduce", help="select points and write the reduced meshes and their errors",
                       description="Reduce a Table-1 function sampled on a grid (--function, --n) or a user "
                                   "file (.vti/.vtk/.vtu/.vtp/.vts/.vtr via VTK, .npz, .npy, .zarr, .csv with "
                                   "x,y,z,value, .nii/.nii.gz NIfTI, .nrrd/.nhdr NRRD).")
    r.add_argument("input", nargs="?", help="data file (omit with --function)")
    r.add_argument("--function", help="Table-1 function: 1-5 or quadratic, saddle, cubic, exponential, "
                                      "trigonometric")
    r.add_argument("--n", type=int, help="grid intervals per axis for --function (default 16)")
    r.add_argument("--array", help="point-data array / value column of the input file")
    r.add_argument("--volume", type=int, metavar="K",
                   help="volume K (0-based) of a 4-D NIfTI or NRRD image (required when it has several)")
    stop = r.add_argument_group("stopping (section 3)", "A fraction or count that the run does not reach (a "
                                                         "tolerance stops it first) is a warning on stderr and a "
                                                         "note in result.json.")
    stop.add_argument("--fractions", type=float, nargs="+", help="fractions of all points, e.g. 0.5 0.2 0.1")
    stop.add_argument("--count", type=int, help="number of points to select")
    stop.add_argument("--tol-rms", type=float, help="E_RMS tolerance: paper and greedy stop inserting once "
                                                    "E_RMS <= this; decimate stops removing before E_RMS would "
                                                    "exceed it")
    stop.add_argument("--tol-inf", type=float, help="E_inf tolerance: paper and greedy stop inserting once "
                                                    "E_inf <= this; decimate stops removing before E_inf would "
                                                    "exceed it")
    r.add_argument("--boundary", metavar="TRIANGLES.npy",
                   help="prescribed boundary of grid data: an (m, 3) integer array of point indices (C order "
                        "over i, j, k) forming a closed triangulation of the box's surface, each triangle in "
                        "one face; its vertices are kept, only interior points are inserted and no flip "
                        "changes it.  The boundary's other points keep their errors: a --tol-inf or "
                        "--tol-rms they prevent gives a warning and tolerance_met: false in result.json "
                        "(exit status 0, the best mesh written)")
    r.add_argument("--out", required=True, help="output folder (errors.csv, mesh_<fraction>.vtu, result.json)")
    r.add_argument("--check", action="store_true", help="run the mesh-validity checker at every snapshot (slow)")
    r.add_argument("--progress", choices=["auto", "always", "never"], default="auto",
                   help="progress line on stderr: 'auto' shows it only on a terminal (quiet in workflow logs)")
    r.add_argument("--threads", type=int, default=1,
                   help="threads for the curvature fits, and processes for the blocks and regions of "
                        "decimate --block (default 1; the result does not depend on it)")
    from .options import add_arguments

    add_arguments(r)  # one group per set of methods the options apply to

    k = sub.add_parser("compile", help="compile the numba kernels into the on-disk cache (once per machine)",
                       description="A reduction compiles its kernels on first use (once; they load "
                                   "from the cache afterwards).  --part 0 and --part 1 compile the two halves "
                                   "(swapping; insertion) in two processes side by side, as the workflow's "
                                   "kernels rule does, then --part 2 the extension module that "
                                   "reductions load without numba (the method's driver and all it "
                                   "calls; numba's own driver without a C compiler or with "
                                   "TRIVSEL_AOT=0); without --part, everything the method needs.")
    from .methods import METHODS

    k.add_argument("--method", default="paper", choices=list(METHODS))
    k.add_argument("--part", type=int, choices=[0, 1, 2],
                   help="one part only: 0 swapping, 1 insertion, 2 the extension module with the "
                        "method's driver (default: all)")

    c = sub.add_parser("compare", help="compare an error table with a golden one; exit 1 on any change",
                       description="Rows are matched on their key columns (function, n, input, method, "
                                   "values, fraction, ...) and cells compared with |new - golden| <= atol + rtol * "
                                   "|golden|.  Exit 1 on a changed cell, a missing or extra row, or a column that "
                                   "one table has and the other lacks; exit 2 on a table that is not a CSV table, "
                                   "a key column that one table lacks, or a key that two rows share.")
    c.add_argument("new")
    c.add_argument("golden")
    c.add_argument("--rtol", type=float, default=1e-6)
    c.add_argument("--atol", type=float, default=0.0)

    v = sub.add_parser("convert", help="copy a volume into a chunked Zarr store that block jobs read by region",
                       description="Write INPUT (.nii/.nii.gz, .nrrd/.nhdr, .vti, .npy, .zarr or any grid trivsel "
                                   "reads) as a Zarr array in trivsel's grid order with its exact geometry "
                                   "(attributes origin, spacing, name); the values keep the file's type when "
                                   "they are exactly representable in it, else float64.  An existing OUT.zarr "
                                   "is refused; an interrupted run leaves none.")
    v.add_argument("input", help="the volume to convert")
    v.add_argument("output", help="the new Zarr store (*.zarr; must not exist)")
    v.add_argument("--chunks", type=int, default=64, help="chunk size in points per axis (default 64)")
    v.add_argument("--array", help="point-data array of a .vti / array of a Zarr group")
    v.add_argument("--volume", type=int, metavar="K", help="volume K (0-based) of a 4-D NIfTI or NRRD image")

    b = sub.add_parser("blocks", help="reduce a large grid in blocks with conforming seams (a Snakemake workflow)",
                       description="Cut the grid into blocks that share faces, reduce every cut line (1-D), "
                                   "every face (2-D) and every block (3-D, its faces prescribed) to the E_inf "
                                   "tolerance, and merge: OUT/mesh.pvtu (one piece per block), OUT/mesh.vtu "
                                   "(merged) and OUT/summary.json.  With --method decimate: bottom-up decimation "
                                   "in blocks (recorded collapse costs, one threshold, regions across the seams) "
                                   "to --count, --fraction, --tol-rms or --tol-inf, the same mesh as trivsel reduce "
                                   "--block.  "
                                   "The jobs run through Snakemake: locally "
                                   "on -c cores, or on a cluster with Snakemake's arguments after '--', e.g. "
                                   "-- --executor slurm --workflow-profile workflow/profiles/slurm.  Run again "
                                   "to resume a killed run.")
    b.add_argument("input", nargs="?", help="the volume (.zarr, .npy, raw .nrrd/.nhdr, .nii/.nii.gz; others are "
                                            "read whole: trivsel convert them first); omit with --function")
    b.add_argument("--function", help="Table-1 function, evaluated block by block (needs no file)")
    b.add_argument("--n", type=int, help="grid intervals per axis for --function")
    b.add_argument("--array", help="point-data array / Zarr array of the input")
    b.add_argument("--volume", type=int, metavar="K", help="volume K (0-based) of a 4-D image")
    b.add_argument("--config", metavar="FILE.yaml",
                   help="the settings as YAML keys (input, function, n, array, volume, block, tol_inf, method, "
                        "merged, count, fraction, tol_rms, values; see config/blocks.yaml); options given here "
                        "override them")
    b.add_argument("--block", type=int, help="grid intervals per block along each axis (e.g. 64)")
    b.add_argument("--tol-inf", type=float, help="E_inf tolerance every stage meets (so the merged mesh does)")
    b.add_argument("--method", choices=[n for n, m in METHODS.items()
                                        if m.PRESCRIBED_BOUNDARY or getattr(m, "BLOCK_STAGES", None)],
                   help="the 3-D stage's method (default greedy), or decimate: bottom-up decimation in blocks, "
                        "which also stops at --count, --fraction or --tol-rms")
    b.add_argument("--count", type=int, help="decimate: stop at this many vertices in all")
    b.add_argument("--fraction", type=float, help="decimate: stop at this fraction of the points")
    b.add_argument("--tol-rms", type=float, help="decimate: E_RMS tolerance (data values) the merged mesh meets: "
                                                 "the stages share its squared-error budget")
    b.add_argument("--values", nargs="+", choices=["data", "fit"],
                   help="decimate: the vertex values written (data, and/or fit: least-squares values; "
                        "default data)")
    b.add_argument("--no-merged", action="store_true", help="write the pieces and mesh.pvtu, not mesh.vtu")
    b.add_argument("--out", required=True, help="the run's folder (created; run again to resume)")
    b.add_argument("-c", "--cores", default="all", help="cores for local jobs (default all)")
    b.add_argument("--job-points", type=int, metavar="N",
                   help="planes and blocks smaller than N grid points are reduced several to a job, one after "
                        "the other in one process (default: 2000000 on a cluster, where each job costs seconds of "
                        "scheduling; 0, one job per plane and block, on a local run); the results are the same "
                        "(decimate's jobs are x-slabs of blocks and regions already)")
    b.add_argument("-n", "--dry-run", action="store_true",
                   help="show the jobs and their resources; run nothing and create nothing (what the run "
                        "would refuse before any job is refused the same way)")
    b.add_argument("-v", "--verbose", action="store_true",
                   help="show Snakemake's own log (default: one progress line over the jobs, and a failing "
                        "job's own message)")
    return parser


def _version():
    from . import __version__

    return f"trivsel {__version__}"


class _Progress:
    """One self-overwriting status line on stderr: bar, points, current errors, rate.

    Works both ways: a run that inserts counts up to its target, a decimation counts
    down to it (the first call gives the count it starts from).  :meth:`close` ends the
    line, however the run ended (a tolerance or an interruption stops it short of the
    target), and log lines end it before they are written."""

    width = 24

    def __init__(self, stream=None):
        self.stream = stream or sys.stderr
        self.start = None
        self.open = False
        self.length = 0

    def __call__(self, done, total, e_rms, e_inf, seconds):
        if self.start is None:
            self.start = done
        if total >= self.start:  # inserting: up to the target
            frac = done / total if total else 1.0
            counts = f"{done}/{total} points"
        else:  # decimating: from the first count down to the target
            frac = (self.start - done) / (self.start - total)
            counts = f"{done} points, down to {total}"
        frac = min(max(frac, 0.0), 1.0)
        moved = done if total >= self.start else self.start - done  # points inserted, or removed
        rate = moved / seconds if seconds > 0 else 0.0
        bar = "#" * int(round(self.width * frac))
        errors = f"  E_rms {e_rms:.4g}  E_inf {e_inf:.4g}" if e_rms == e_rms else ""  # NaN: not known yet
        text = f"[{bar:<{self.width}}] {counts}{errors}  {rate:.0f} points/s"
        self.stream.write("\r" + text + " " * max(self.length - len(text), 0))
        self.stream.flush()
        self.open, self.length = True, len(text)

    def close(self):
        """End the line (once)."""
        if self.open:
            self.stream.write("\n")
            self.stream.flush()
            self.open = False


def _show_messages(stages, progress=None):
    """Print the reduction's messages on stderr: always its warnings and the one-time
    compile notice (``trivsel: ...``), and with ``stages`` its stage messages (hull,
    Delaunay, curvature, insertion) with the time since start, so that long stages are
    visibly under way.  A progress line that is open is ended first."""
    import logging

    class Lines(logging.Handler):
        _trivsel_cli = True

        def emit(self, record):
            if progress is not None:
                progress.close()
            if record.levelno >= logging.WARNING:
                text = f"trivsel: {record.getMessage()}"
            else:
                text = f"trivsel [{record.relativeCreated:7.0f} ms] {record.getMessage()}"
            sys.stderr.write(text + "\n")
            sys.stderr.flush()

    logger = logging.getLogger("trivsel")
    for h in [h for h in logger.handlers if getattr(h, "_trivsel_cli", False)]:
        logger.removeHandler(h)
    logger.addHandler(Lines())
    logger.setLevel(logging.INFO if stages else logging.WARNING)


def _cmd_reduce(a):
    from .data import sample_grid
    from .functions import resolve_function
    from .io import check_output_dir, format_rows, fraction_label, import_vtk_writer, load, write_outputs
    from .options import AUTO, choose_method, from_namespace, option_fields
    from .reduction import reduce

    if (a.input is None) == (a.function is None):
        raise InputError("give either an input file or --function (not both)")
    if a.function is None and a.n is not None:
        raise InputError(f"--n applies to --function, not to input files (got --n {a.n} with {a.input!r})")
    if a.function is not None and a.n is None:
        a.n = 16
    chosen = a.method in (None, AUTO)
    if chosen:
        a.method = choose_method(a.function is not None,
                                 [f.name for f in option_fields() if getattr(a, f.name, None) is not None],
                                 prescribed_boundary=a.boundary is not None)
    try:
        options = from_namespace(a)
    except InputError as exc:
        if not chosen:
            raise
        raise InputError(f"{exc} (method auto runs {a.method} on "
                         f"{'a Table-1 function' if a.function is not None else 'an input file'}: "
                         "give --method to choose another)") from None
    files = ["errors.csv", "result.json"] + [f"mesh_{fraction_label(f)}.vtu" for f in a.fractions or ()]
    check_output_dir(a.out, [p for p in (a.input, a.boundary) if p is not None], files)  # before any work
    show = a.progress == "always" or (a.progress == "auto" and sys.stderr.isatty())
    progress = _Progress() if show else None
    _show_messages(show, progress)
    if a.function is not None:
        if a.array is not None:
            raise InputError("--array applies to input files, not to --function")
        if a.volume is not None:
            raise InputError("--volume applies to input files, not to --function")
    check = None
    if a.check:
        from .mesh import check_mesh

        check = check_mesh
    boundary = None if a.boundary is None else _read_triangles(a.boundary)
    inputs = [p for p in (a.input, a.boundary) if p is not None]
    import_vtk_writer()  # now, not when the selection is done: see import_vtk_writer
    try:
        if a.function is not None:
            data = sample_grid(resolve_function(a.function), a.n)
        else:
            from .resources import interruptible

            data = interruptible(load, a.input, a.array, volume=a.volume)  # large files: Ctrl-C stays prompt
        result = reduce(data, fractions=a.fractions, count=a.count, tol_rms=a.tol_rms, tol_inf=a.tol_inf,
                        boundary=boundary, options=options, threads=a.threads, check=check, progress=progress)
    except MemoryShortage as exc:
        hint = _blocks_hint(a, options.method, exc.available)
        raise InputError(f"{exc}; {hint}" if hint else str(exc)) from None
    finally:
        if progress is not None:
            progress.close()
    unmet = _unmet_tolerance(result.snapshots[-1].errors, tol_rms=a.tol_rms, tol_inf=a.tol_inf)
    extra = {"command": sys.argv}
    if a.tol_rms is not None or a.tol_inf is not None:
        extra["tolerance_met"] = unmet is None
    out = write_outputs(result, a.out, extra=extra, inputs=inputs)
    print(format_rows(result.error_rows()))
    if unmet is not None:
        why = " (a prescribed boundary keeps its points' errors)" if boundary is not None else ""
        print(f"trivsel: warning: the tolerance was not met: {unmet}{why}; "
              "result.json says tolerance_met: false", file=sys.stderr)
    print(f"wrote {out}/errors.csv, {len(result.snapshots)} mesh file(s) and result.json "
          f"in {result.timings['total']:.2f} s", file=sys.stderr)
    return 0


def _blocks_hint(a, chosen, available):
    """The ``trivsel blocks`` command line that does the job of the reduce command ``a`` in
    bounded memory, as a phrase for a memory refusal, or None (scattered input, or a
    prescribed boundary: blocks cut grids into boxes of their own)."""
    import shlex

    from .blocks import SUGGESTED_BLOCKS
    from .io.regions import open_volume

    if a.boundary is not None:
        return None
    if a.input is not None:
        try:
            shape = open_volume(a.input, array=a.array, volume=a.volume).shape  # its header: is it a grid?
        except InputError:
            return None
        source = [a.input] + (["--array", a.array] if a.array else []) + (
            ["--volume", str(a.volume)] if a.volume is not None else [])
    else:
        shape = open_volume(function=a.function, n=a.n).shape
        source = ["--function", str(a.function), "--n", str(a.n)]
    if chosen == "decimate" and (a.count is not None) + len(a.fractions or ()) <= 1:
        # decimate's own stages in blocks: as jobs, or in this process where they fit
        from .blocks.decimate import block_for_memory as jobs_block

        stop = (["--count", str(a.count)] if a.count is not None
                else ["--fraction", f"{float(a.fractions[0]):g}"] if a.fractions else [])
        stop += ["--tol-rms", f"{float(a.tol_rms):g}"] if a.tol_rms is not None else []
        stop += ["--tol-inf", f"{float(a.tol_inf):g}"] if a.tol_inf is not None else []
        # the largest block whose region jobs fit a core's share, and every other job here too
        # (the step and tiles jobs hold arrays over the whole grid)
        sizes = [b for b in SUGGESTED_BLOCKS if b <= jobs_block(available)]
        needs = [_decimate_jobs_memory(a, shape, b) for b in sizes]
        fit = [b for b, need in zip(sizes, needs) if max(need.values()) <= available]
        least = min(range(len(sizes)), key=lambda i: max(needs[i].values()))  # when none fits: the least
        cmd = ["trivsel", "blocks", *source, "--method", "decimate", "--block", str(fit[0] if fit else sizes[least]),
               *stop, *(["--values", *a.values] if a.values else []), "--out", a.out, "-c", "2"]
        block = _decimate_block_for_memory(a, shape, available)
        one = ""
        if block is not None:
            argv = [x for i, x in enumerate(a.argv)  # the same command, its --block replaced
                    if x != "--block" and not x.startswith("--block=") and (i == 0 or a.argv[i - 1] != "--block")]
            one = f" (or in one process: {shlex.join(['trivsel', *argv, '--block', str(block)])})"
        if not fit and needs[least]["kernels"] <= available:  # a job fits here, not the whole grid's arrays
            kind = max(needs[least], key=needs[least].get)
            need = needs[least][kind]
            return (f"decimate in blocks ({shlex.join(cmd)}) needs about {need / 2**30:.3g} GiB for its {kind} job, "
                    f"so run it where a job may have that much{one}; here, in bounded memory: "
                    + _greedy_blocks_hint(a, chosen, available, source, shape))
        return "in blocks of bounded memory: " + shlex.join(cmd) + one
    return "in blocks of bounded memory: " + _greedy_blocks_hint(a, chosen, available, source, shape)


def _decimate_jobs_memory(a, shape, block):
    """The memory of each kind of job of ``trivsel blocks --method decimate`` for the reduce
    command ``a`` on a grid of ``shape`` in blocks of ``block`` (bytes by kind)."""
    from .blocks.decimate import jobs_memory

    cfg = {"count": a.count, "fraction": float(a.fractions[0]) if a.fractions else None, "tol_rms": a.tol_rms,
           "tol_inf": a.tol_inf, "values": list(a.values or ["data"])}
    return jobs_memory(shape, cfg, block)


def _greedy_blocks_hint(a, chosen, available, source, shape):
    """The phrase of :func:`_blocks_hint` for the methods that take the blocks' faces (their
    jobs are bounded by the block at any grid size), on a grid of ``shape``."""
    import shlex

    from .blocks import block_for_memory, job_resources, plan_blocks
    from .methods import METHODS, get_method

    able = [name for name, m in METHODS.items() if m.PRESCRIBED_BOUNDARY]
    method = chosen if get_method(chosen).PRESCRIBED_BOUNDARY else "greedy"
    tol = "TOL" if a.tol_inf is None else f"{float(a.tol_inf):g}"
    block = block_for_memory(available)
    plan = plan_blocks(shape, block)
    # the merged mesh's job grows with the grid: without it where it does not fit and a job does
    merge, job = (job_resources(plan, kind)[0] * 2**20 for kind in ("merge", "kernels"))
    cmd = ["trivsel", "blocks", *source, "--block", str(block), "--tol-inf", tol, "--method", method,
           *(["--no-merged"] if merge > available >= job else []), "--out", a.out, "-c", "2"]
    notes = []
    if a.tol_inf is None:
        notes.append("blocks stop at an E_inf tolerance TOL")
    if method != chosen:
        notes.append(f"they run {' or '.join(able)}")
    return shlex.join(cmd) + (f" ({'; '.join(notes)})" if notes else "")


def _decimate_block_for_memory(a, shape, available):
    """The largest ``--block`` (128 down to 16) with which ``decimate`` fits in ``available``
    bytes on a grid of ``shape``, or None (a stop that blocks do not take, or too large even in
    blocks)."""
    import math
    from types import SimpleNamespace

    from .methods.decimate import memory
    from .options import Options

    if (a.count is not None) + len(a.fractions or ()) > 1:
        return None
    grid = SimpleNamespace(n_points=math.prod(shape), is_grid=True, tets=None)
    for block in (128, 96, 64, 48, 32, 16):
        opts = Options(method="decimate", block=block, values=tuple(a.values or ("data",)))
        if sum(b for b, _ in memory(grid, opts)) <= available:
            return block
    return None


def _unmet_tolerance(errors, *, tol_rms=None, tol_inf=None):
    """``None`` when no tolerance was given or the errors meet one of them (the stopping
    rule stops at the first met); else the errors against the tolerances, as text."""
    given = [(name, key, tol) for name, key, tol in (("--tol-rms", "E_rms", tol_rms), ("--tol-inf", "E_inf", tol_inf))
             if tol is not None]
    if not given or any(errors[key] <= tol for _, key, tol in given):
        return None
    return ", ".join(f"{key} {float(errors[key]):.6g} > {name} {float(tol):g}" for name, key, tol in given)


def _read_triangles(path):
    """An (m, 3) integer array from a ``.npy`` file (never unpickled)."""
    import numpy as np

    from .io import npy_header
    from .resources import check_memory

    try:
        with open(path, "rb") as fh:
            shape, dtype = npy_header(fh)
    except (OSError, ValueError):
        pass  # np.load says what is wrong
    else:
        check_memory(float(np.prod(shape)) * dtype.itemsize, f"reading boundary {path!r} (shape {shape})")
    try:
        tris = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read boundary {path!r} as a .npy array: {one_line(exc, first=True)}") from None
    return tris


def _cmd_compile(a):
    import os
    import time

    from . import aot
    from .methods import get_method

    _show_messages(False)  # the compile notice and the build's warnings as ``trivsel: ...``
    t0 = time.perf_counter()
    before, waits = len(aot.compiled), len(aot.waited)
    get_method(a.method).compile_kernels(a.part)
    what = f"the {a.method} kernels" + ("" if a.part is None else f" (part {a.part})")
    took = time.perf_counter() - t0
    if os.environ.get("NUMBA_DISABLE_JIT", "0").strip() not in ("", "0"):
        print(f"nothing to compile: NUMBA_DISABLE_JIT is set, so {what} run as Python")
    elif len(aot.compiled) > before:
        print(f"compiled {what} in {took:.1f} s")
    elif len(aot.waited) > waits:
        print(f"{what} were compiled by another process: waited for them and loaded them in {took:.1f} s")
    else:
        print(f"{what} were compiled already: loaded in {took:.1f} s")
    return 0


def _cmd_compare(a):
    import os

    from .regression import compare_frames, format_mismatches, read_table

    for name, tol in (("--rtol", a.rtol), ("--atol", a.atol)):
        check_tolerance(name, tol)
    for path in (a.new, a.golden):
        if not os.path.isfile(path):
            raise InputError(f"table {path!r} " + ("is not a file" if os.path.exists(path) else "does not exist"))
    new, golden = read_table(a.new), read_table(a.golden)
    mism = compare_frames(new, golden, rtol=a.rtol, atol=a.atol, names=(a.new, a.golden))
    if mism:
        print(format_mismatches(mism, a.new, a.golden, a.rtol, a.atol))
        return 1
    print(f"{a.new} matches {a.golden} (rtol {a.rtol:g}, atol {a.atol:g})")
    return 0


def _cmd_convert(a):
    import time

    from .io.regions import convert

    t0 = time.perf_counter()
    out = convert(a.input, a.output, chunks=a.chunks, array=a.array, volume=a.volume)
    print(f"wrote {out} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


#: The settings of ``trivsel blocks`` that options and ``--config`` keys share (``merged`` is ``--no-merged``)
BLOCKS_KEYS = ("input", "function", "n", "array", "volume", "block", "tol_inf", "method", "count", "fraction",
               "tol_rms", "values")


def _cmd_blocks(a, snakemake_args):
    from .blocks import check_types, run_workflow

    config = {}
    if a.config:
        config = _read_yaml(a.config)
    for key in BLOCKS_KEYS:
        if getattr(a, key) is not None:
            config[key] = getattr(a, key)
    if a.no_merged:
        config["merged"] = False
    check_types(config)
    if (config.get("input") is None) == (config.get("function") is None):
        raise InputError("give either an input volume or --function (and --n), not both")
    if config.get("function") is not None and config.get("n") is None:
        raise InputError("give --n (grid intervals per axis) with --function")
    if config.get("function") is None and config.get("n") is not None:
        raise InputError(f"--n applies to --function, not to an input volume (got n {shown(config['n'])} with "
                         f"{str(config.get('input'))!r})")
    needed = ("block",) if config.get("method") == "decimate" else ("block", "tol_inf")
    for key in needed:
        if config.get(key) is None:
            raise InputError(f"give --{key.replace('_', '-')} (or `{key}:` in --config)")
    from .blocks import JobFailed

    try:
        done = run_workflow(a.out, config, cores=a.cores, snakemake_args=snakemake_args, dry_run=a.dry_run,
                            verbose=a.verbose, show=sys.stderr.isatty(), job_points=a.job_points)
    except JobFailed as exc:
        print(f"trivsel: error: {exc}", file=sys.stderr)
        return exc.status
    if a.dry_run:
        return done
    import json
    from pathlib import Path

    s = json.loads((Path(a.out).expanduser() / "summary.json").read_text())
    if done is None:  # --verbose: Snakemake's log tells what ran
        what = "done"
    elif done:  # Snakemake counts the target rule `all` among its steps
        what = f"ran {done - 1} job(s)"
    else:
        what = "nothing to run: the results are up to date with the input and settings"
    print(f"trivsel blocks: {what}; {a.out}: {s['vertices']} of {s['points']} points, {s['tetrahedra']} "
          f"tetrahedra, E_rms {s['E_rms']:.4g}, E_inf {s['E_inf']:.4g}"
          + (f"; fitted values: E_rms {s['fit']['E_rms']:.4g}, E_inf {s['fit']['E_inf']:.4g}" if "fit" in s else ""),
          file=sys.stderr)
    if s.get("target") is not None and s["vertices"] > s["target"]:  # as reduce warns
        print(f"trivsel blocks: warning: count {s['target']} not reached: the run stopped at {s['vertices']} points "
              f"({s.get('stopped') or 'no reason recorded'})", file=sys.stderr)
    for note in s.get("notes", []):
        print(f"trivsel blocks: note: {note}", file=sys.stderr)
    return 0


def _read_yaml(path):
    import yaml

    class UniqueKeys(yaml.SafeLoader):
        """YAML that names a setting twice is refused: a loader would keep the last silently."""

        def construct_mapping(self, node, deep=False):
            seen = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=deep)
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"the setting {key!r} is given twice (line {key_node.start_mark.line + 1})",
                        key_node.start_mark)
                seen.add(key)
            return super().construct_mapping(node, deep=deep)

    try:
        with open(path) as fh:
            d = yaml.load(fh, Loader=UniqueKeys)  # noqa: S506 - a SafeLoader
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(f"cannot read config {path}: {one_line(exc, first=True)}") from None
    if not isinstance(d, dict):
        raise InputError(f"config {path} must be a mapping of settings, got {type(d).__name__}")
    known = {*BLOCKS_KEYS, "merged"}
    unknown = sorted(set(d) - known)
    if unknown:
        raise InputError(f"config {path}: unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})")
    return d


def _terminate(signum, frame):
    raise KeyboardInterrupt


#: The exit status when stdout is closed before the command has printed (128 + SIGPIPE, as a
#: Unix tool that the signal ends)
SIGPIPE_STATUS = 141


def _stdout_to_devnull():
    """Point stdout's file descriptor at the null device, so that the interpreter's last flush
    of a closed pipe does not print a traceback."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # no file descriptor (stdout replaced in a test, say)
        pass


def main(argv=None):
    """Run the command line; returns the exit status (2: bad input, 130: interrupted, 141: stdout
    closed before the command had printed)."""
    import signal
    import threading

    main_thread = threading.current_thread() is threading.main_thread()
    if main_thread:  # SIGTERM like Ctrl-C: the outputs stay as they were, the temporaries go
        previous = signal.signal(signal.SIGTERM, _terminate)
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        passed = []  # `trivsel blocks ... -- ARGS`: ARGS go to Snakemake as they are
        if argv[:1] == ["blocks"] and "--" in argv:
            passed = argv[argv.index("--") + 1:]
            argv = argv[:argv.index("--")]
        a = build_parser().parse_args(argv)  # inside: building the parser imports numpy
        a.argv = argv
        if a.command == "reduce":
            return _cmd_reduce(a)
        if a.command == "compile":
            return _cmd_compile(a)
        if a.command == "compare":
            return _cmd_compare(a)
        if a.command == "convert":
            return _cmd_convert(a)
        if a.command == "blocks":
            return _cmd_blocks(a, passed)
    except InputError as exc:
        print(f"trivsel: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # stdout closed early (`... | head`): the files written stay, as a Unix tool's would
        _stdout_to_devnull()
        return SIGPIPE_STATUS
    except KeyboardInterrupt:
        if argv[:1] == ["blocks"]:
            print("trivsel: interrupted; jobs that had started were stopped and finished ones are kept: run it "
                  "again to resume", file=sys.stderr)
        else:
            print("trivsel: interrupted; the output folder is as it was before this run", file=sys.stderr)
        return 130
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)
    return 2  # pragma: no cover


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
