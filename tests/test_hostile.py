"""Hostile input, as a new user would try it: every case ends in one line on stderr,
exit status 2 (or 1 for a failed comparison), and no output folder.

``python tests/test_hostile.py`` prints the matrix (case, exit status, message).
"""

from __future__ import annotations

import contextlib
import io
import sys
from pathlib import Path

import numpy as np
import pytest

from trivsel.cli import main

FN = ["--function", "4", "--n", "6"]


def _write(tmp: Path, name: str, make) -> str:
    p = tmp / name
    make(p)
    return str(p)


def _npz(**arrays):
    return lambda p: np.savez(p, **arrays)


def _text(s: str | bytes):
    return lambda p: (p.write_bytes(s) if isinstance(s, bytes) else p.write_text(s))


def _csv(header: str, points, row):
    """A CSV of the line ``header`` and, per point ``(a, b, c)`` of ``points``, the fields ``row(a, b, c)``."""
    return _text(header + "\n" + "".join(",".join(f"{v}" for v in row(*q)) + "\n" for q in points))


def _cloud(n=50, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.random((n, 3))
    return p, np.sin(3 * p[:, 0]) + p[:, 1]


BLOCKS_FN = ["--function", "4", "--n", "8", "--block", "4", "--tol-inf", "0.1"]
BLOCKS_DEC = ["--function", "4", "--n", "8", "--block", "4", "--method", "decimate"]


def _corner_boundary(p):
    """A closed surface over a 5^3 grid that passes the surface checks but cuts the corner
    (0, 0, 0) off the box (the hull of every other grid point), outward."""
    from scipy.spatial import ConvexHull

    from trivsel.data import sample_grid

    d = sample_grid(4, 4)
    keep = np.arange(1, d.n_points)
    pts = d.ijk[keep].astype(float)
    hull = ConvexHull(pts)
    tris = hull.simplices.copy()
    normal = np.cross(pts[tris[:, 1]] - pts[tris[:, 0]], pts[tris[:, 2]] - pts[tris[:, 0]])
    inward = np.einsum("ij,ij->i", normal, hull.equations[:, :3]) < 0
    tris[inward] = tris[inward][:, [0, 2, 1]]
    np.save(p, keep[tris])


def _zarr_store(p):
    from trivsel.io.regions import convert

    np.save(p.with_suffix(".npy"), np.zeros((5, 5, 5)))
    convert(p.with_suffix(".npy"), p)


def GRID_NPY(tmp: Path):
    """A 9^3 grid of smooth values in an ``.npy`` file, as the input of a run."""
    g = np.indices((9, 9, 9)).astype(float)
    return [_write(tmp, "grid9.npy", lambda p: np.save(p, np.sin(g[0] / 3) * g[1] + g[2] ** 2))]


def _cases(tmp: Path):
    """(name, argv, expected exit status, fragments of the message: a distinctive phrase and the bad value)."""
    p, f = _cloud()
    flat = p.copy()
    flat[:, 2] = 0.5
    dup = np.concatenate([p, p[:1]])
    nanv = f.copy()
    nanv[3] = np.nan
    out = str(tmp / "out")
    existing = _write(tmp, "a_file", _text("keep me"))
    cases = [
        ("no input and no --function", ["reduce", "--fractions", "0.5", "--out", out], 2,
         ("give either an input file or --function",)),
        ("input and --function", ["reduce", existing, *FN, "--fractions", "0.5", "--out", out], 2,
         ("give either an input file or --function (not both)",)),
        ("missing input file", ["reduce", str(tmp / "nope.vti"), "--fractions", "0.5", "--out", out], 2,
         ("input file", "nope.vti", "does not exist")),
        ("unsupported suffix", ["reduce", _write(tmp, "x.mnc", _text("x")), "--fractions", "0.5", "--out", out], 2,
         ("unsupported file type '.mnc'", "x.mnc")),
        ("--out is an existing file", ["reduce", *FN, "--fractions", "0.5", "--out", existing], 2,
         ("a_file' is an existing file, not a folder",)),
        ("--out would hold the input", ["reduce", _write(tmp, "in.npz", _npz(points=p, values=f)),
                                        "--fractions", "0.5", "--out", str(tmp)], 2,
         ("in.npz' is inside the output folder", "choose another --out")),
        ("npz without values", ["reduce", _write(tmp, "nov.npz", _npz(points=p)), "--fractions", "0.5",
                                "--out", out], 2, ("nov.npz' has no array 'values'", "available: points")),
        ("npz points not N x 3", ["reduce", _write(tmp, "p2.npz", _npz(points=p[:, :2], values=f)),
                                  "--fractions", "0.5", "--out", out], 2,
         ("points must have shape (N, 3), got (50, 2)",)),
        ("npz values of another length", ["reduce", _write(tmp, "len.npz", _npz(points=p, values=f[:-1])),
                                          "--fractions", "0.5", "--out", out], 2,
         ("values must have shape (50,) to match the points, got (49,)",)),
        ("npz of complex values", ["reduce", _write(tmp, "cx.npz", _npz(points=p, values=f + 1j)),
                                   "--fractions", "0.5", "--out", out], 2,
         ("values must be real numbers", "complex128")),
        ("npz that is not a zip", ["reduce", _write(tmp, "junk.npz", _text(b"\x00\x01junk")), "--fractions", "0.5",
                                   "--out", out], 2, ("cannot read", "junk.npz", "not a NumPy .npz archive")),
        ("npz of object arrays", ["reduce", _write(tmp, "obj.npz", _npz(points=p, values=f.astype(object))),
                                  "--fractions", "0.5", "--out", out], 2,
         ("cannot read", "obj.npz", "Object arrays cannot be loaded")),
        ("npz grid with a bad spacing", ["reduce", _write(tmp, "sp.npz", _npz(values=np.zeros((3, 3, 3)),
                                                                              spacing=np.array([1.0, -1.0, 1.0]))),
                                         "--fractions", "0.5", "--out", out], 2,
         ("grid spacing must be 3 positive finite numbers", "-1.0")),
        ("NaN value", ["reduce", _write(tmp, "nan.npz", _npz(points=p, values=nanv)), "--fractions", "0.5",
                       "--out", out], 2, ("non-finite value nan at point 3",)),
        ("duplicate points", ["reduce", _write(tmp, "dup.npz", _npz(points=dup, values=np.append(f, 0.0))),
                              "--fractions", "0.5", "--out", out], 2, ("duplicate point", "at rows [0, 50]")),
        ("three points", ["reduce", _write(tmp, "three.npz", _npz(points=p[:3], values=f[:3])), "--fractions", "0.5",
                          "--out", out], 2, ("too few points", "got 3")),
        ("coplanar points", ["reduce", _write(tmp, "flat.npz", _npz(points=flat, values=f)), "--fractions", "0.5",
                             "--out", out], 2, ("points are coplanar", "singular values", "0.0]")),
        ("CSV without z", ["reduce", _write(tmp, "noz.csv", _text("x,y,value\n0,0,1\n")), "--fractions", "0.5",
                           "--out", out], 2, ("noz.csv' lacks column(s) z",)),
        ("CSV with text values", ["reduce", _write(tmp, "txt.csv", _text("x,y,z,value\n0,0,0,a\n1,0,0,b\n")),
                                  "--fractions", "0.5", "--out", out], 2, ("non-numeric data in", "txt.csv", "'a'")),
        ("unknown --array", ["reduce", _write(tmp, "arr.npz", _npz(points=p, values=f)), "--array", "rho",
                             "--fractions", "0.5", "--out", out], 2, ("arr.npz' has no array 'rho'",)),
        ("--volume on a CSV", ["reduce", _write(tmp, "v.csv", _text("x,y,z,value\n0,0,0,1\n")), "--volume", "1",
                               "--fractions", "0.5", "--out", out], 2,
         ("--volume 1 applies to 4-D NIfTI and NRRD images", "v.csv")),
        ("fraction 0", ["reduce", *FN, "--fractions", "0", "--out", out], 2, ("fraction 0.0 is outside (0, 1]",)),
        ("fraction 1.5", ["reduce", *FN, "--fractions", "1.5", "--out", out], 2, ("fraction 1.5 is outside (0, 1]",)),
        ("fraction nan", ["reduce", *FN, "--fractions", "nan", "--out", out], 2, ("fraction nan is outside (0, 1]",)),
        ("fraction below the fixed points", ["reduce", *FN, "--fractions", "1e-12", "--out", out], 2,
         ("fewer than the 8 fixed points", "fractions [1e-12]")),
        ("fraction not a number", ["reduce", *FN, "--fractions", "half", "--out", out], 2,
         ("--fractions", "invalid float value: 'half'")),
        ("count 0", ["reduce", *FN, "--count", "0", "--out", out], 2, ("count must be an integer in [1, 343], got 0",)),
        ("count above N", ["reduce", *FN, "--count", "100000", "--out", out], 2,
         ("count must be an integer in [1, 343], got 100000",)),
        ("no stopping rule", ["reduce", *FN, "--out", out], 2, ("give fractions, a count, or an error tolerance",)),
        ("tol_rms inf", ["reduce", *FN, "--tol-rms", "inf", "--out", out], 2,
         ("tol_rms must be a finite number >= 0, got inf",)),
        ("tol_inf negative", ["reduce", *FN, "--tol-inf", "-1", "--out", out], 2,
         ("tol_inf must be a finite number >= 0, got -1",)),
        ("grid n = 1", ["reduce", "--function", "4", "--n", "1", "--fractions", "0.5", "--out", out], 2,
         ("grid resolution n must be an integer >= 2, got 1",)),
        ("grid too large for memory", ["reduce", "--function", "4", "--n", "2000", "--fractions", "0.1",
                                       "--out", out], 2, ("n = 2000", "GiB, more than the")),
        ("unknown function", ["reduce", "--function", "9", "--fractions", "0.5", "--out", out], 2,
         ("unknown function '9'",)),
        ("unknown method", ["reduce", *FN, "--method", "foo", "--fractions", "0.5", "--out", out], 2,
         ("--method: invalid choice: 'foo'",)),
        ("negative seed", ["reduce", *FN, "--seed", "-1", "--fractions", "0.5", "--out", out], 2,
         ("seed must be >= 0, got -1",)),
        ("rel_tol nan", ["reduce", *FN, "--rel-tol", "nan", "--fractions", "0.5", "--out", out], 2,
         ("rel_tol must be finite, got nan",)),
        ("rel_tol inf", ["reduce", *FN, "--rel-tol", "inf", "--fractions", "0.5", "--out", out], 2,
         ("rel_tol must be finite, got inf",)),
        ("quantum nan", ["reduce", *FN, "--quantum", "nan", "--fractions", "0.5", "--out", out], 2,
         ("quantum must be finite, got nan",)),
        ("max_flips negative", ["reduce", *FN, "--max-flips", "-1", "--fractions", "0.5", "--out", out], 2,
         ("max_flips must be >= 0, got -1",)),
        ("threads 0", ["reduce", *FN, "--threads", "0", "--fractions", "0.5", "--out", out], 2,
         ("threads must be an integer >= 1, got 0",)),
        ("--out is empty", ["reduce", *FN, "--fractions", "0.5", "--out", ""], 2, "--out '' is empty"),
        ("npz grid with a NaN origin", ["reduce", _write(tmp, "no.npz", _npz(values=np.zeros((3, 3, 3)),
                                                                             origin=np.array([np.nan, 0.0, 0.0]))),
                                        "--fractions", "0.5", "--out", out], 2, "grid origin must be 3 finite numbers"),
        ("npz grid whose far corner overflows", ["reduce", _write(tmp, "big.npz", _npz(
            values=np.zeros((3, 3, 3)), spacing=np.array([1e308, 1.0, 1.0]))), "--fractions", "0.5", "--out", out],
         2, "cannot place 3 distinct finite points along axis x"),
        ("npz grid spacing too small to move the origin", ["reduce", _write(tmp, "tiny.npz", _npz(
            values=np.zeros((3, 3, 3)), origin=np.array([1.0, 0.0, 0.0]), spacing=np.array([1e-20, 1.0, 1.0]))),
            "--fractions", "0.5", "--out", out], 2, "cannot place 3 distinct finite points along axis x"),
        ("boundary cutting a corner off the box", ["reduce", "--function", "4", "--n", "4", "--tol-inf", "0.05",
                                                   "--method", "greedy", "--boundary",
                                                   _write(tmp, "corner.npy", _corner_boundary), "--out", out], 2,
         "does not lie in one face of the box"),
        ("blocks: --out is empty", ["blocks", *BLOCKS_FN, "--out", ""], 2, "--out '' is empty"),
        ("blocks: --out is an existing file", ["blocks", *BLOCKS_FN, "--out", existing], 2,
         "is an existing file, not a folder"),
        ("blocks: --out would hold the input", ["blocks", _write(tmp, "in.npy", lambda p: np.save(p, np.zeros((5,) * 3))),
                                                "--block", "2", "--tol-inf", "0.1", "--out", str(tmp)], 2,
         "is inside the output folder"),
        ("blocks: --out inside the input store", ["blocks", _write(tmp, "in.zarr", _zarr_store), "--block", "2",
                                                  "--tol-inf", "0.1", "--out", str(tmp / "in.zarr" / "out")], 2,
         "is inside the input"),
        ("blocks: -c 0", ["blocks", *BLOCKS_FN, "-c", "0", "--out", out], 2,
         "cores (-c) must be 'all' or an integer >= 1, got '0'"),
        ("blocks: -c -1", ["blocks", *BLOCKS_FN, "-c", "-1", "--out", out], 2, "cores (-c) must be 'all'"),
        ("blocks: --out cannot be created", ["blocks", *BLOCKS_DEC, "--fraction", "0.3", "--out",
                                             "/proc/trivsel-no-such-folder/out"], 2,
         ("cannot write the output folder '/proc/trivsel-no-such-folder/out': '/proc' takes no new folder",)),
        ("--out cannot be created", ["reduce", *FN, "--fractions", "0.5", "--out", "/proc/trivsel-no-such-folder/out"],
         2, ("cannot write the output folder '/proc/trivsel-no-such-folder/out': '/proc' takes no new folder",)),
        ("blocks: --values fit with a method that writes data values",
         ["blocks", *BLOCKS_FN, "--values", "fit", "--out", out], 2,
         ("method 'greedy' writes the data values in blocks, not ['fit']", "--values applies to --method decimate")),
        ("blocks: --n with an input volume", ["blocks", *GRID_NPY(tmp), "--n", "5", "--block", "4", "--tol-inf",
                                              "0.1", "--out", out], 2,
         ("--n applies to --function, not to an input volume (got n 5",)),
        ("--n with an input file", ["reduce", *GRID_NPY(tmp), "--n", "5", "--fractions", "0.5", "--out", out], 2,
         ("--n applies to --function, not to input files (got --n 5",)),
        ("blocks: a billion blocks", ["blocks", "--function", "4", "--n", "2000", "--block", "2", "--tol-inf", "0.1",
                                      "--out", out], 2, "into 1,000,000,000 blocks (1,000,003,008 jobs), more than "
                                                        "the 20,000 a run plans: use --block 75 or more"),
        ("blocks: a billion blocks, dry run", ["blocks", "--function", "4", "--n", "2000", "--block", "2",
                                               "--tol-inf", "0.1", "-n", "--out", out], 2, "use --block"),
        ("blocks: a grid of 10^27 points, dry run", ["blocks", "--function", "4", "--n", "1000000000", "--block",
                                                     "64", "--tol-inf", "0.1", "-n", "--out", out], 2,
         "more than the 20,000 a run plans: use --block 37037037 or more"),
        ("blocks: a block larger than the memory", ["blocks", "--function", "4", "--n", "3000", "--block", "3000",
                                                    "--tol-inf", "0.1", "--out", out], 2,
         "GiB of memory available: use a smaller --block"),
        ("blocks: block size 0", ["blocks", "--function", "4", "--n", "8", "--block", "0", "--tol-inf", "0.1",
                                  "--out", out], 2, "block must be an integer from 2 to 2147483647 (grid intervals per "
                                                    "block), got 0"),
        ("blocks: tol_inf nan", ["blocks", "--function", "4", "--n", "8", "--block", "4", "--tol-inf", "nan",
                                 "--out", out], 2, "tol_inf must be a finite number >= 0, got nan"),
        ("blocks: grid with a NaN origin", ["blocks", _write(tmp, "bo.npz", _npz(values=np.zeros((5, 5, 5)),
                                                                                 origin=np.array([0.0, np.inf, 0.0]))),
                                            "--block", "2", "--tol-inf", "0.1", "--out", out], 2,
         "grid origin must be 3 finite numbers, got (0.0, inf, 0.0)"),
        ("blocks: integers beyond 2^53", ["blocks", _write(tmp, "i64.npy", lambda p: np.save(
            p, np.full((5, 5, 5), 2**53 + 1, np.int64))), "--block", "2", "--tol-inf", "0.1", "--out", out], 2,
         "float64 cannot hold it exactly"),
        ("blocks: --volume with --function", ["blocks", *BLOCKS_FN, "--volume", "1", "--out", out], 2,
         "--volume applies to input files"),
        ("blocks: merged 'no' in --config", ["blocks", *BLOCKS_FN, "--config",
                                             _write(tmp, "m.yaml", _text("merged: 'no'\n")), "--out", out], 2,
         "merged must be true or false, got 'no'"),
        ("blocks: greedy with a count", ["blocks", *BLOCKS_FN, "--count", "50", "--out", out], 2,
         "method 'greedy' stops in blocks at tol_inf only, not at count: use --tol-inf (or --method decimate)"),
        ("blocks: decimate without a stop", ["blocks", *BLOCKS_DEC, "--out", out], 2,
         "give a stop: --count, --fraction, --tol-rms or --tol-inf"),
        ("blocks: greedy with tol_rms", ["blocks", *BLOCKS_FN, "--tol-rms", "0.01", "--out", out], 2,
         "method 'greedy' stops in blocks at tol_inf only, not at tol_rms: use --tol-inf (or --method decimate)"),
        ("blocks: decimate, tol_rms -0.5", ["blocks", *BLOCKS_DEC, "--tol-rms", "-0.5", "--out", out], 2,
         "tol_rms must be a finite number >= 0, got -0.5"),
        ("blocks: decimate, tol_rms nan", ["blocks", *BLOCKS_DEC, "--tol-rms", "nan", "--out", out], 2,
         "tol_rms must be a finite number >= 0, got nan"),
        ("blocks: decimate, tol_rms 'small' in --config", ["blocks", *BLOCKS_DEC, "--config",
                                                            _write(tmp, "r.yaml", _text("tol_rms: small\n")),
                                                            "--out", out], 2,
         "tol_rms must be a finite number >= 0, got 'small'"),
        ("blocks: decimate, count and fraction", ["blocks", *BLOCKS_DEC, "--count", "50", "--fraction", "0.1",
                                                  "--out", out], 2, "give one of count and fraction, not both"),
        ("blocks: decimate, count 3", ["blocks", *BLOCKS_DEC, "--count", "3", "--out", out], 2,
         "count must be a whole number from 8 (the box's corners) to the 729 points; got 3"),
        ("blocks: decimate, count above the points", ["blocks", *BLOCKS_DEC, "--count", "730", "--out", out], 2,
         "to the 729 points; got 730"),
        ("blocks: decimate, fraction 1.5", ["blocks", *BLOCKS_DEC, "--fraction", "1.5", "--out", out], 2,
         "fraction must be a number in (0, 1]; got 1.5"),
        ("blocks: decimate, fraction nan", ["blocks", *BLOCKS_DEC, "--fraction", "nan", "--out", out], 2,
         "fraction must be a number in (0, 1]; got nan"),
        ("blocks: decimate, values 'fitted' in --config", ["blocks", *BLOCKS_DEC, "--count", "50", "--config",
                                                            _write(tmp, "v.yaml", _text("values: [data, fitted]\n")),
                                                            "--out", out], 2,
         "values must be a list of data and fit (each once); got ['data', 'fitted']"),
        ("blocks: decimate, count 'many' in --config", ["blocks", *BLOCKS_DEC, "--config",
                                                         _write(tmp, "c.yaml", _text("count: many\n")), "--out", out],
         2, "count must be a whole number from 8 (the box's corners) to the 729 points; got 'many'"),
        ("blocks: decimate, tol_inf -1", ["blocks", *BLOCKS_DEC, "--tol-inf", "-1", "--out", out], 2,
         "tol_inf must be a finite number >= 0, got -1"),
        ("blocks: decimate, block 1", ["blocks", "--function", "4", "--n", "8", "--block", "1", "--method", "decimate",
                                       "--count", "50", "--out", out], 2, "block must be an integer from 2 to 2147483647 "
                                                                          "(grid intervals per block), got 1"),
        ("blocks: decimate of a grid larger than the memory", ["blocks", "--function", "4", "--n", "3000", "--block",
                                                               "64", "--method", "decimate", "--fraction", "0.05",
                                                               "--out", out], 2,
         "needs about"),
        ("blocks: Snakemake's --touch after --", ["blocks", *BLOCKS_FN, "--out", out, "--", "--touch"], 2,
         "Snakemake's --touch cannot be passed after '--'"),
        ("blocks: Snakemake's --directory after --", ["blocks", *BLOCKS_FN, "--out", out, "--", "--directory",
                                                      str(tmp)], 2, "Snakemake's --directory cannot be passed"),
        ("blocks: Snakemake's --cores after --", ["blocks", *BLOCKS_FN, "--out", out, "--", "--cores=0"], 2,
         "use -c before '--'"),
        ("decimate --block with two fractions", ["reduce", *GRID_NPY(tmp), "--block", "4", "--fractions", "0.1", "0.2",
                                                 "--out", out], 2, ("option block takes one count or fraction",)),
        ("decimate --block, criterion max", ["reduce", *GRID_NPY(tmp), "--block", "4", "--criterion", "max",
                                             "--count", "50", "--out", out], 2, ("not criterion 'max'",)),
        ("decimate --block, candidates interior", ["reduce", *GRID_NPY(tmp), "--block", "4", "--candidates",
                                                   "interior", "--count", "50", "--out", out], 2,
         ("not candidates 'interior'",)),
        ("decimate --block on scattered points", ["reduce", _write(tmp, "bl.npz", _npz(points=p, values=f)), "--block",
                                                  "4", "--count", "20", "--out", out], 2,
         ("option block applies to grids",)),
        ("decimate --block -3", ["reduce", *GRID_NPY(tmp), "--block", "-3", "--count", "50", "--out", out], 2,
         ("block must be", "-3")),
        ("greedy --block", ["reduce", *GRID_NPY(tmp), "--method", "greedy", "--block", "4", "--count", "50", "--out",
                            out], 2, ("option block (--block) applies to method decimate only, not to greedy",)),
        ("compare: missing table", ["compare", str(tmp / "no.csv"), existing], 2, ("table", "no.csv' does not exist")),
        ("compare: a folder", ["compare", str(tmp), existing], 2, (f"table '{tmp}' is not a file",)),
        ("compare: empty table", ["compare", _write(tmp, "e.csv", _text("")), existing], 2,
         ("cannot read table", "e.csv' as CSV")),
        ("compare: binary junk", ["compare", _write(tmp, "j.csv", _text(b"\xc1\xff\x00junk")), existing], 2,
         ("cannot read table", "j.csv' as CSV")),
        ("compare: no numeric column", ["compare", *[_write(tmp, "w.csv", _text("name,kind\na,b\n"))] * 2], 2,
         ("w.csv' has no numeric column to compare",)),
        ("compare: rtol nan", ["compare", existing, existing, "--rtol", "nan"], 2,
         ("--rtol must be a finite number >= 0, got nan",)),
        ("compare: tables differ", ["compare", _write(tmp, "n.csv", _text("a,b\n1,2\n")),
                                    _write(tmp, "g.csv", _text("a,b\n1,3\n"))], 1,
         ("1 offending cell(s)", "b: new 2 != golden 3")),
    ]
    return cases + _output_cases(tmp) + _input_cases(tmp) + _compare_cases(tmp)


#: An errors.csv of a file's run with data and fit values: its rows differ only in the key column ``values``.
GOLD_ROWS = ["function,n,input,method,values,fraction,n_selected,E_rms,seconds",
             ",,g9,decimate,data,0.5,10,0.1,1.5", ",,g9,decimate,fit,0.5,10,0.09,1.2"]


def _table(tmp: Path, name: str, rows=GOLD_ROWS, drop=(), rename=None, add=None) -> str:
    """GOLD_ROWS (or ``rows``) as ``name``, without the columns ``drop``, with the columns renamed
    by ``rename`` and an extra column ``add`` = (name, value) at the end."""
    table = [r.split(",") for r in rows]
    keep = [i for i, c in enumerate(table[0]) if c not in drop]
    table = [[r[i] for i in keep] for r in table]
    table[0] = [(rename or {}).get(c, c) for c in table[0]]
    if add:
        table = [r + [add[0] if i == 0 else add[1]] for i, r in enumerate(table)]
    return _write(tmp, name, _text("\n".join(",".join(r) for r in table) + "\n"))


def _vtu(p):
    import pyvista as pv

    pv.ImageData(dimensions=(3, 3, 3)).cast_to_unstructured_grid().save(p)


def _compare_cases(tmp: Path):
    """``trivsel compare`` on tables it cannot compare (exit 2) and on column changes (exit 1)."""
    gold = _table(tmp, "gold.csv")
    ragged = "\n".join(GOLD_ROWS[:2] + [GOLD_ROWS[2] + ",9"]) + "\n"
    twice = "\n".join([GOLD_ROWS[0].replace("E_rms", "E_rms,E_rms")] + [r + ",0.1" for r in GOLD_ROWS[1:]]) + "\n"
    return [
        ("compare: key column missing from the new table", ["compare", _table(tmp, "nm.csv", drop=["method"]), gold],
         2, ("key column 'method' of the golden table", "gold.csv' is missing from the new table", "nm.csv'")),
        ("compare: key column renamed in the new table", ["compare", _table(tmp, "Nm.csv", rename={"method": "Method"}),
                                                          gold], 2, ("key column 'method'", "(it has 'Method')")),
        ("compare: key column values missing (data and fit rows)",
         ["compare", _table(tmp, "nv.csv", drop=["values"], rows=GOLD_ROWS[:2]), gold], 2,
         ("key column 'values' of the golden table", "is missing from the new table")),
        ("compare: key column missing from the golden table", ["compare", gold, _table(tmp, "gnv.csv", drop=["values"])],
         2, ("key column 'values' of the new table", "is missing from the golden table", "gnv.csv'")),
        ("compare: ragged row", ["compare", _write(tmp, "rag.csv", _text(ragged)), gold], 2,
         ("cannot read table", "rag.csv' as CSV: line 3 has 10 fields, the header 9")),
        ("compare: duplicate column name", ["compare", _write(tmp, "two.csv", _text(twice)), gold], 2,
         ("two.csv' as CSV: the header names column 'E_rms' twice (columns 8 and 9)",)),
        ("compare: a mesh file as the new table", ["compare", _write(tmp, "m.vtu", _vtu), gold], 2,
         ("m.vtu' as CSV: it is XML, not comma-separated values",)),
        ("compare: a table of no rows", ["compare", _table(tmp, "h.csv", rows=GOLD_ROWS[:1]), gold], 2,
         ("h.csv' has no rows, only the header",)),
        ("compare: a key twice in the new table", ["compare", _table(tmp, "dk.csv", rows=GOLD_ROWS[:2] + GOLD_ROWS[1:2]), gold], 2,
         ("new table", "dk.csv' has two rows with the key input=g9, method=decimate, values=data, fraction=0.5 "
          "(data rows 1 and 2)")),
        ("compare: a key twice in the golden table", ["compare", gold, _table(tmp, "gdk.csv", rows=GOLD_ROWS + GOLD_ROWS[2:])],
         2, ("golden table", "gdk.csv' has two rows with the key", "values=fit", "(data rows 2 and 3)")),
        ("compare: no column in common", ["compare", _write(tmp, "ab.csv", _text("a,b\n1,2\n")), gold], 2,
         ("ab.csv' has none of the columns of the golden table",)),
        ("compare: a compared column missing", ["compare", _table(tmp, "ne.csv", drop=["E_rms"]), gold], 1,
         ("1 offending cell(s)", "E_rms: missing column")),
        ("compare: an extra column", ["compare", _table(tmp, "ex.csv", add=("E_max", "0.3")), gold], 1,
         ("1 offending cell(s)", "E_max: extra column")),
        ("compare: a wall-clock column missing", ["compare", _table(tmp, "ns.csv", drop=["seconds"]), gold], 0,
         ("ns.csv matches",)),
    ]


BIG = 2**53 + 1  # the first integer float64 cannot hold
BEYOND = "is beyond 2^53: float64 cannot hold it exactly"
NOT_OURS = "exists and no trivsel run wrote it"


def _nearly_a_line(n=40, seed=2):
    """Scattered points all but four of them on a line: their hull's tetrahedra are flat in float64."""
    rng = np.random.default_rng(seed)
    q = rng.random((n, 3))
    q[:, 1], q[:, 2] = 2 * q[:, 0], 3 * q[:, 0]
    q[:4] += rng.random((4, 3))
    return q


def _folded_mesh(p):
    """Two tetrahedra that share a triangle and lie on the same side of it."""
    import pyvista as pv

    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.2, 0.2, 0.3]], float)
    g = pv.UnstructuredGrid(np.array([4, 0, 1, 2, 3, 4, 0, 1, 2, 4]), np.full(2, 10, np.uint8), pts)
    g.point_data["value"] = np.arange(5.0)
    g.save(p)


def _infinite_slope(p):
    """An int16 NIfTI whose header's scl_slope is infinite (a NIfTI-1 header keeps it at byte 112)."""
    import struct

    _nifti(np.arange(64, dtype=np.int16).reshape(4, 4, 4), np.eye(4))(p)
    b = bytearray(p.read_bytes())
    b[112:116] = struct.pack("<f", np.inf)
    p.write_bytes(bytes(b))


def _truncated(make, cut):
    """A file as ``make`` writes it, less its last ``cut`` bytes."""
    def write(p):
        make(p)
        p.write_bytes(p.read_bytes()[:-cut])
    return write


def _long_double(p):
    """A long-double grid one of whose values float64 would round (where long double is wider)."""
    v = np.ones((3, 3, 3), np.longdouble)
    v[0, 0, 1] += np.longdouble(2) ** -60
    np.save(p, v)


def _big_grid(dtype=np.int64):
    v = np.arange(27, dtype=dtype).reshape(3, 3, 3)
    v[1, 2, 0] = BIG
    return v


def _nifti(data, affine=None, *, pixdim=None, sform=None, qform=None):
    def make(p):
        import nibabel as nib

        img = nib.Nifti1Image(data, affine, dtype=data.dtype)  # no affine: the header's pixdim is kept
        if pixdim is not None:
            img.header["pixdim"][1:4] = pixdim
        if sform is not None:
            img.header["sform_code"] = sform
        if qform is not None:
            img.header["qform_code"] = qform
        nib.save(img, p)
    return make


def _nrrd(data, header, **kwargs):
    def make(p):
        import nrrd

        nrrd.write(str(p), data, header, **kwargs)
    return make


def _vti(values, origin=(0.0, 0.0, 0.0)):
    def make(p):
        import pyvista as pv

        g = pv.ImageData(dimensions=values.shape, origin=origin)
        g.point_data["v"] = values.ravel(order="F")
        g.save(p)
    return make


def _zarr(values, attributes):
    def make(p):
        import zarr

        if int(zarr.__version__.split(".")[0]) >= 3:
            zarr.create_array(store=str(p), data=values, attributes=attributes, zarr_format=3)
        else:
            a = zarr.open_array(str(p), mode="w", shape=values.shape, dtype=values.dtype)
            a[...] = values
            a.attrs.update(attributes)
    return make


def _npy(values):
    return lambda p: np.save(p, values)


def _huge_npz(p):
    """An .npz whose header declares a 4000^3 float64 grid (477 GiB) over a few bytes of data."""
    import zipfile

    buf = io.BytesIO()
    np.lib.format.write_array_header_2_0(buf, {"descr": "<f8", "fortran_order": False, "shape": (4000,) * 3})
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("values.npy", buf.getvalue() + b"\0" * 64)


def _huge_npy(p):
    """A .npy whose header declares 2e11 x 3 int64 (4.4 TiB) over a few bytes of data."""
    with open(p, "wb") as fh:
        np.lib.format.write_array_header_2_0(fh, {"descr": "<i8", "fortran_order": False, "shape": (2 * 10**11, 3)})
        fh.write(b"\0" * 64)


def _huge_nhdr(p):
    """A raw NRRD header declaring 4000^3 float64 samples over a data file of 64 bytes."""
    (p.parent / "huge.raw").write_bytes(b"\0" * 64)
    p.write_text("NRRD0004\ntype: double\ndimension: 3\nsizes: 4000 4000 4000\nendian: little\n"
                 "encoding: raw\ndata file: huge.raw\n\n")


def _huge_nifti(p):
    """A NIfTI header declaring 4000^3 float32 voxels, with 64 bytes of data after it."""
    import nibabel as nib

    hdr = nib.Nifti1Header()
    hdr.set_data_shape((4000,) * 3)
    hdr.set_data_dtype(np.float32)
    with open(p, "wb") as fh:
        hdr.write_to(fh)
        fh.write(b"\0" * (352 - fh.tell() + 64))


def _huge_vti(p):
    """An image declaring 4000^3 points, with one tiny inline array."""
    p.write_text('<?xml version="1.0"?>\n<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian">\n'
                 '<ImageData WholeExtent="0 3999 0 3999 0 3999" Origin="0 0 0" Spacing="1 1 1">\n'
                 '<Piece Extent="0 3999 0 3999 0 3999"><PointData Scalars="v">\n'
                 '<DataArray type="Float64" Name="v" format="ascii">0 1 2</DataArray>\n'
                 '</PointData></Piece></ImageData></VTKFile>\n')


def _output_cases(tmp: Path):
    """Output folders and files that are not trivsel's to write."""
    theirs = tmp / "theirs"
    theirs.mkdir(exist_ok=True)
    (theirs / "errors.csv").write_text("their table")
    mine = tmp / "mine"
    mine.mkdir(exist_ok=True)
    (mine / "mesh_0.5.vtu").write_text("their mesh")
    store = _write(tmp, "store.zarr", _zarr(np.zeros((3, 3, 3)), {}))
    arr = _write(tmp, "arr.npy", _npy(np.zeros((3, 3, 3))))
    (tmp / "empty.zarr").mkdir(exist_ok=True)
    return [
        ("--out empty", ["reduce", *FN, "--fractions", "0.5", "--out", ""], 2, "--out '' is empty"),
        ("--out holds a foreign errors.csv", ["reduce", *FN, "--fractions", "0.5", "--out", str(theirs)], 2,
         f"errors.csv' {NOT_OURS}"),
        ("--out holds a foreign mesh", ["reduce", *FN, "--fractions", "0.5", "--out", str(mine)], 2,
         f"mesh_0.5.vtu' {NOT_OURS}"),
        ("convert: output empty", ["convert", arr, ""], 2, "the output '' is empty"),
        ("convert: output inside the input", ["convert", store, f"{store}/inner.zarr"], 2,
         "is inside the input"),
        ("convert: output an existing empty folder", ["convert", arr, str(tmp / "empty.zarr")], 2,
         "exists: trivsel convert never overwrites"),
        ("convert: output under a file", ["convert", arr, str(tmp / "a_file" / "x.zarr")], 2, "is not writable"),
        ("convert: output where no folder can be made", ["convert", arr, "/proc/x.zarr"], 2,
         "cannot write '/proc/x.zarr': '/proc' takes no new folder"),
        # a name longer than the file system takes (255 bytes): Path.exists raises, not False
        ("--out name too long", ["reduce", *FN, "--fractions", "0.5", "--out", str(tmp / ("n" * 300))], 2,
         ("cannot use the output folder", "nnnnnnnnnn", "File name too long")),
        ("blocks: --out name too long", ["blocks", *BLOCKS_FN, "--out", str(tmp / ("n" * 300))], 2,
         ("cannot use the output folder", "nnnnnnnnnn", "File name too long")),
        ("convert: output name too long", ["convert", arr, str(tmp / ("n" * 300 + ".zarr"))], 2,
         ("cannot use the output", "nnnnnnnnnn.zarr", "File name too long")),
        ("blocks: --out under a file", ["blocks", *BLOCKS_FN, "--out", str(tmp / "a_file" / "run")], 2,
         "a_file' is not writable"),
    ]


def _input_cases(tmp: Path):
    """Inputs whose values or geometry would be silently changed, or that would fill the memory."""
    out = str(tmp / "out")
    red = ["--fractions", "0.5", "--out", out]
    p, f = _cloud()
    big_ints = np.arange(50, dtype=np.int64)
    big_ints[7] = -BIG
    csv = "x,y,z,value\n" + "".join(f"{a},{b},{c},{v}\n" for (a, b, c), v in zip(p, big_ints))
    nan3 = np.array([np.nan, 0.0, 0.0])
    nan_affine = np.eye(4)
    nan_affine[0, 3] = np.nan
    grid = np.random.default_rng(3).random((3, 4, 5))
    return [
        ("npz grid of integers beyond 2^53", ["reduce", _write(tmp, "bigg.npz", _npz(values=_big_grid())), *red],
         2, f"value {BIG} at grid index (1, 2, 0) of 'bigg' {BEYOND}"),
        ("npz points of integers beyond 2^53", ["reduce", _write(tmp, "bigs.npz", _npz(points=p, values=big_ints)),
                                                *red], 2, f"value {-BIG} at point 7 of 'bigs' {BEYOND}"),
        ("CSV of integers beyond 2^53", ["reduce", _write(tmp, "big.csv", _text(csv)), *red], 2,
         f"value {-BIG} at point 7 of 'big' {BEYOND}"),
        ("CSV of integers beyond 64 bits", ["reduce", _write(tmp, "huge.csv", _text(csv.replace(
            f",{-BIG}\n", f",{2**64 + 5}\n"))), *red], 2, f"value {2**64 + 5} at point 7 of 'huge' {BEYOND}"),
        ("vti of integers beyond 2^53", ["reduce", _write(tmp, "big.vti", _vti(_big_grid())), *red], 2,
         f"value {BIG} at grid index (1, 2, 0) of 'big' {BEYOND}"),
        ("NRRD of uint64 beyond 2^53", ["reduce", _write(tmp, "big.nrrd", _nrrd(_big_grid(np.uint64), {})), *red],
         2, f"value {BIG} at grid index (1, 2, 0) of 'big' {BEYOND}"),
        ("NIfTI of int64 beyond 2^53", ["reduce", _write(tmp, "big.nii", _nifti(_big_grid(), np.eye(4))), *red], 2,
         f"value {BIG} at voxel (1, 2, 0) of"),
        ("convert: npy beyond 2^53",
         ["convert", _write(tmp, "big.npy", _npy(_big_grid())), str(tmp / "out" / "b.zarr")], 2,
         f"value {BIG} at grid index (1, 2, 0) of"),
        ("NIfTI zero voxel size, no orientation", ["reduce", _write(tmp, "z.nii", _nifti(grid, pixdim=[0, 1, 1],
                                                                                      sform=0, qform=0)), *red],
         2, "has a zero or missing voxel size (pixdim[1:4] = (0.0, 1.0, 1.0))"),
        ("NIfTI NaN voxel size, qform only", ["reduce", _write(tmp, "q.nii", _nifti(grid, pixdim=[1, np.nan, 1],
                                                                                  sform=0, qform=1)), *red],
         2, "has a zero or missing voxel size (pixdim[1:4] = (1.0, nan, 1.0))"),
        ("convert: NIfTI zero voxel size", ["convert", str(tmp / "z.nii"), str(tmp / "out" / "z.zarr")], 2,
         "has a zero or missing voxel size"),
        ("npz grid origin NaN", ["reduce", _write(tmp, "on.npz", _npz(values=grid, origin=nan3)), *red], 2,
         "grid origin must be 3 finite numbers, got (nan, 0.0, 0.0)"),
        ("npz grid origin of 2 numbers", ["reduce", _write(tmp, "o2.npz", _npz(values=grid, origin=np.zeros(2))),
                                          *red], 2, "grid origin must be 3 finite numbers, got (0.0, 0.0)"),
        ("npz grid spacing of 4 numbers", ["reduce", _write(tmp, "s4.npz", _npz(values=grid, spacing=np.ones(4))),
                                           *red], 2,
         "grid spacing must be 3 positive finite numbers, got (1.0, 1.0, 1.0, 1.0)"),
        ("NRRD zero spacing", ["reduce", _write(tmp, "zs.nrrd", _nrrd(grid, {"spacings": [1.0, 0.0, 1.0]})), *red],
         2, "has a zero voxel size (its spacings"),
        ("npz grid coordinates overflow", ["reduce", _write(tmp, "of.npz", _npz(values=grid, origin=np.full(3, 1e308),
                                                                                spacing=np.full(3, 1e308))), *red],
         2, "cannot place 3 distinct finite points along axis x in float64"),
        ("vti origin NaN", ["reduce", _write(tmp, "on.vti", _vti(grid, origin=(0.0, np.nan, 0.0))), *red], 2,
         "grid 'on': the origin must be 3 finite numbers, got (0, nan, 0)"),
        ("legacy vtk origin inf", ["reduce", _write(tmp, "oi.vtk", _text(
            "# vtk DataFile Version 3.0\nx\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 2 2 2\nORIGIN 0 0 inf\n"
            "SPACING 1 1 1\nPOINT_DATA 8\nSCALARS v double 1\nLOOKUP_TABLE default\n0 1 2 3 4 5 6 7\n")), *red],
         2, "grid 'oi': the origin must be 3 finite numbers, got (0, 0, inf)"),
        ("NIfTI origin NaN", ["reduce", _write(tmp, "on.nii", _nifti(grid, nan_affine)), *red], 2,
         "must be a finite 3 x 3 matrix and offset"),
        ("NRRD origin NaN", ["reduce", _write(tmp, "on.nrrd", _nrrd(grid, {"space": "left-posterior-superior",
                                                                          "space directions": np.eye(3),
                                                                          "space origin": nan3})), *red],
         2, "must be a finite 3 x 3 matrix and offset"),
        ("convert: zarr origin NaN", ["convert", _write(tmp, "on.zarr", _zarr(grid, {"origin": [0, 0, float("nan")]})),
                                      str(tmp / "out" / "o.zarr")], 2, "attribute 'origin' must be 3 finite numbers"),
        ("convert: zarr coordinates overflow",
         ["convert", _write(tmp, "of.zarr", _zarr(grid, {"origin": [1e308] * 3, "spacing": [1e308] * 3})),
          str(tmp / "out" / "o.zarr")], 2, "cannot place 3 distinct finite points along axis x in float64"),
        ("boundary header beyond memory", ["reduce", *FN, "--boundary", _write(tmp, "huge_b.npy", _huge_npy),
                                           *red], 2, "huge_b.npy' (shape (200000000000, 3)) needs about"),
        ("npz header beyond memory", ["reduce", _write(tmp, "huge.npz", _huge_npz), *red], 2,
         "('values' of shape (4000, 4000, 4000)) needs about"),
        ("raw NRRD header beyond memory", ["reduce", _write(tmp, "huge.nhdr", _huge_nhdr), *red], 2,
         "(sizes (4000, 4000, 4000)) needs about"),
        ("NIfTI header beyond memory", ["reduce", _write(tmp, "huge.nii", _huge_nifti), *red], 2,
         "(shape (4000, 4000, 4000)) needs about"),
        ("vti header beyond memory", ["reduce", _write(tmp, "huge.vti", _huge_vti), *red], 2,
         "(64000000000 points) needs about"),
        ("max_flips beyond an int64", ["reduce", *FN, "--max-flips", "99999999999999999999", *red], 2,
         "max_flips must be <= 9223372036854775807, got 99999999999999999999"),
        ("block beyond what a run takes", ["reduce", *FN, "--method", "decimate", "--block", str(2**63 - 1), *red],
         2, f"block must be <= 2147483647, got {2**63 - 1}"),
        ("quantum 0", ["reduce", *FN, "--quantum", "0", *red], 2, "quantum must be >= 1e-15, got 0.0"),
        ("quantum below float64's rounding", ["reduce", *FN, "--quantum", "1e-300", *red], 2,
         "quantum must be >= 1e-15, got 1e-300"),
        ("a folder named as a CSV", ["reduce", _write(tmp, "d.csv", lambda q: q.mkdir()), *red], 2,
         "d.csv' is a folder, not a .csv file"),
        ("blocks on a folder named as a NIfTI", ["blocks", _write(tmp, "d.nii", lambda q: q.mkdir()), "--block",
                                                 "2", "--tol-inf", "0", "--out", out, "-c", "1"], 2,
         "d.nii' is a folder, not a .nii file"),
        ("points too near a line for greedy", ["reduce", _write(tmp, "line.npz", _npz(points=_nearly_a_line(),
                                                                                  values=f[:40])),
                                               "--method", "greedy", *red], 2,
         ("the points are too near a plane or a line for 'greedy'", "--method decimate takes them")),
        ("CSV with two columns that could be the values", ["reduce", _write(tmp, "vv.csv", _csv(
            "x,y,z,Value,VALUE", p, lambda a, b, c: (a, b, c, a, a + 100))), *red], 2,
         "has 2 columns that could be 'value' ('Value', 'VALUE'): rename all but one"),
        ("CSV of true/false values", ["reduce", _write(tmp, "tf.csv", _csv(
            "x,y,z,value", p, lambda a, b, c: (a, b, c, a > 0.5))), *red], 2,
         "column 'value' holds true/false, not numbers"),
        ("CSV row with a field too many", ["reduce", _write(tmp, "row.csv", _text("x,y,z,value\n1,2,3,4\n1,2,3,4,5\n")),
                                           *red], 2, "Expected 4 fields in line 3, saw 5"),
        ("npz grid of a complex origin", ["reduce", _write(tmp, "cxo.npz", _npz(values=np.zeros((3, 4, 5)),
                                                                                origin=np.array([7j, 0, 0]))), *red],
         2, "grid origin must be real numbers, got complex128 values [7j, 0j, 0j]"),
        ("npz grid of a true/false spacing", ["reduce", _write(tmp, "bsp.npz", _npz(values=np.zeros((3, 4, 5)),
                                                                                    spacing=np.ones(3, bool))), *red],
         2, "grid spacing must be real numbers, got bool values"),
        ("long double values that float64 would round", ["reduce", _write(tmp, "ld.npy", _long_double), *red], 2,
         "has more precision than float64 holds: it would be rounded"),
        ("convert of long double values that float64 would round",
         ["convert", _write(tmp, "ld2.npy", _long_double), str(tmp / "out" / "ld.zarr")], 2,
         ("at grid index (0, 0, 1) of", "ld2.npy' has more precision than float64 holds")),
        ("blocks on a truncated int16 NIfTI", ["blocks", _write(tmp, "tr.nii", _truncated(_nifti(
            np.arange(729, dtype=np.int16).reshape(9, 9, 9), np.eye(4)), 600)), "--block", "4", "--tol-inf", "0.5",
            "--out", out, "-c", "1"], 2, ("tr.nii'", "could the file be damaged?")),
        ("NIfTI of an infinite scl_slope", ["reduce", _write(tmp, "slope.nii", _infinite_slope), *red], 2,
         "has a non-finite scaling (scl_slope = inf, scl_inter = 0.0)"),
        ("npz of 4-D values", ["reduce", _write(tmp, "v4.npz", _npz(values=np.zeros((2, 2, 2, 2)))), *red], 2,
         "'values' has shape (2, 2, 2, 2): need a 3-D grid, or 1-D values beside a 'points' array"),
        ("npz points with a NaN coordinate", ["reduce", _write(tmp, "pn.npz", _npz(points=np.where(
            np.arange(150).reshape(50, 3) == 10, np.nan, p), values=f)), *red], 2,
         ("non-finite coordinate in point 3: (0.9350724237877682, nan, ",)),
        ("npz grid of a 3 x 1 spacing", ["reduce", _write(tmp, "s31.npz", _npz(values=np.zeros((3, 3, 3)),
                                                                               spacing=np.ones((3, 1)))), *red], 2,
         "grid spacing must be 3 positive finite numbers, got [[1.0], [1.0], [1.0]]"),
        ("npz of scattered points beside a 3-D values grid", ["reduce", _write(tmp, "pg.npz", _npz(
            points=p[:10], values=grid)), *red], 2,
         "pg.npz' is ambiguous: it holds a 3-D grid 'values' (3, 4, 5) and scattered 'points' (10, 3)"),
        ("npz of scattered points with a grid's origin and spacing", ["reduce", _write(tmp, "po.npz", _npz(
            points=p, values=f, origin=np.ones(3), spacing=np.full(3, 2.0))), *red], 2,
         "po.npz' holds scattered 'points' and 'origin' (3,), 'spacing' (3,), which place a grid, not points"),
        ("npz grid with an array it does not use", ["reduce", _write(tmp, "gm.npz", _npz(
            values=grid, mask=np.ones(5, bool))), *red], 2, "gm.npz' holds 'mask' (5,), which a grid does not use"),
        ("CSV with two columns named value", ["reduce", _write(tmp, "vv2.csv", _csv(
            "x,y,z,value,value", p, lambda a, b, c: (a, b, c, -a, a))), *red], 2,
         "vv2.csv' has 2 columns named 'value': rename all but one"),
        ("CSV with two columns named x", ["reduce", _write(tmp, "xx.csv", _csv(
            "x,y,z,x,value", p, lambda a, b, c: (7 * a, b, c, a, a))), *red], 2,
         "xx.csv' has 2 columns named 'x': rename all but one"),
        ("zarr file_index of a negative base", ["reduce", _write(tmp, "fb.zarr", _zarr(grid, {"file_index": {
            "base": -5, "strides": [20, 5, 1]}})), *red], 2,
         ("attribute 'file_index' {'base': -5, 'strides': [20, 5, 1]}",
          "gives grid points negative indices (down to -5) for the shape (3, 4, 5)")),
        ("zarr file_index of zero strides", ["reduce", _write(tmp, "fz.zarr", _zarr(grid, {"file_index": {
            "base": 0, "strides": [0, 0, 0]}})), *red], 2,
         "'file_index' {'base': 0, 'strides': [0, 0, 0]} has a zero stride along axis x"),
        ("zarr file_index whose strides give two points one index", ["reduce", _write(tmp, "fc.zarr", _zarr(
            grid, {"file_index": {"base": 0, "strides": [1, 3, 5]}})), *red], 2,
         "{'base': 0, 'strides': [1, 3, 5]} gives grid points (0, 2, 0) and (1, 0, 1) the same index 6"),
        ("zarr file_index beyond an int64", ["reduce", _write(tmp, "fo.zarr", _zarr(grid, {"file_index": {
            "base": 0, "strides": [2**62, 5, 1]}})), *red], 2,
         f"gives grid points indices beyond an int64 (up to {2**63 + 19}) for the shape (3, 4, 5)"),
        ("convert to a store named only .zarr", ["convert", _write(tmp, "g.npy", lambda q: np.save(q, np.zeros(
            (3, 3, 3)))), str(tmp / "out" / ".zarr")], 2, "must be named *.zarr (a name before .zarr)"),
        ("a folded tetrahedral mesh", ["reduce", _write(tmp, "fold.vtu", _folded_mesh), "--method", "decimate", *red],
         2, "is folded: tetrahedra 0 and 1 share triangle [0, 1, 2] and lie on the same side of it"),
        ("blocks config whose input is a number", ["blocks", "--config", _write(tmp, "in5.yaml", _text(
            "block: 4\ntol_inf: 0.1\ninput: 5\n")), "--out", out, "-c", "1"], 2,
         "input must be a path (a non-empty string), got 5"),
        ("blocks config whose block is a list", ["blocks", "--config", _write(tmp, "bl.yaml", _text(
            "block: [4, 4, 8]\nmethod: decimate\nfraction: 0.3\nfunction: 4\nn: 8\n")), "--out", out, "-c", "1"], 2,
         "block must be an integer from 2 to 2147483647 (grid intervals per block), got [4, 4, 8]"),
    ]


def _run(argv):
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code
    return code, err.getvalue(), out.getvalue()


#: Notices a first run on a machine prints before its work (the one-time compile of a method's
#: kernels, or the wait for another process compiling them): not part of a refusal
NOTICES = ("trivsel: compiling the ", "trivsel: waiting for another process that is compiling ")


def _lines(text):
    """The non-empty lines of ``text`` but the one-time compile's notices."""
    return [x for x in text.strip().splitlines() if x and not x.startswith(NOTICES)]


def _names():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        return [c[0] for c in _cases(Path(d))]


@pytest.mark.parametrize("name", _names())
def test_hostile_case_gives_one_line_and_no_output(tmp_path, name):
    _check_case(tmp_path, {c[0]: c for c in _cases(tmp_path)}[name])


def _blocks_refusals():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        return [c[0] for c in _cases(Path(d)) if c[1][0] == "blocks" and c[2] == 2]


@pytest.mark.parametrize("name", _blocks_refusals())
def test_blocks_dry_run_refuses_what_the_run_refuses(tmp_path, name):
    """`trivsel blocks -n` refuses every input the run refuses before it starts work (an output
    folder that cannot be created among them), with the same line, and makes nothing."""
    _, argv, expected, fragments = {c[0]: c for c in _cases(tmp_path)}[name]
    at = argv.index("--") if "--" in argv else len(argv)  # -n is trivsel's, before Snakemake's arguments
    _check_case(tmp_path, (name, [*argv[:at], "-n", *argv[at:]], expected, fragments))


def _check_case(tmp_path, case):
    _, argv, expected, fragments = case
    fragments = (fragments,) if isinstance(fragments, str) else fragments
    assert max(map(len, fragments)) >= 10, fragments  # a phrase of the message, not a character
    code, err, out = _run(argv)
    assert code == expected, (code, err)
    text = err if expected == 2 else out
    lines = _lines(text)
    if expected == 2:
        assert len(lines) == 1 and lines[0].startswith("trivsel"), err
        assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in text, (fragment, text)
    assert not (tmp_path / "out").exists()
    assert (tmp_path / "a_file").read_text() == "keep me"


# ----------------------------------------------------------------------------- blocks: folders with a history

def _one_line(err, fragment):
    lines = _lines(err)
    assert len(lines) == 1 and lines[0].startswith("trivsel: error: ") and "Traceback" not in err, err
    assert fragment in lines[0], err


def _snapshot(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("name, content, fragment", [
    ("summary.json", "my notes", "summary.json' was not written by trivsel blocks"),
    ("mesh.vtu", "my mesh", "mesh.vtu' was not written by trivsel blocks"),
    ("pieces", None, "pieces' was not written by trivsel blocks"),
    ("blocks.json", "{}", "blocks.json' is not the configuration of a trivsel blocks run"),
])
def test_blocks_never_overwrites_what_no_blocked_run_wrote(tmp_path, name, content, fragment):
    out = tmp_path / "theirs"
    out.mkdir()
    if content is None:
        (out / name).mkdir()
        (out / name / "x.vtu").write_text("theirs")
    else:
        (out / name).write_text(content)
    before = _snapshot(out)
    for extra in ([], ["-n"]):  # a dry run predicts the refusal
        code, err, _ = _run(["blocks", *BLOCKS_FN, *extra, "--out", str(out)])
        assert code == 2
        _one_line(err, fragment)
        assert _snapshot(out) == before and sorted(p.name for p in out.iterdir()) == [name]


def test_blocks_rerun_with_another_setting_or_a_changed_input_is_refused(tmp_path):
    """An earlier run's folder (its blocks.json): other settings, or an input changed since,
    are refused naming the difference; the folder stays as it was."""
    import os

    from trivsel.blocks import write_config

    src = tmp_path / "v.npy"
    np.save(src, np.arange(125.0).reshape(5, 5, 5))
    out = tmp_path / "run"
    write_config(out, {"input": str(src), "block": 2, "tol_inf": 0.1})
    before = _snapshot(out)
    code, err, _ = _run(["blocks", str(src), "--block", "2", "--tol-inf", "0.2", "--out", str(out)])
    assert code == 2
    _one_line(err, "holds a blocked run with another configuration (tol_inf: 0.1 there, 0.2 now)")
    np.save(src, np.arange(125.0).reshape(5, 5, 5) + 1)  # the same size: the time tells
    st = os.stat(src)
    os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    code, err, _ = _run(["blocks", str(src), "--block", "2", "--tol-inf", "0.1", "--out", str(out)])
    assert code == 2
    _one_line(err, f"the input {str(src.resolve())!r} changed since the blocked run in")
    assert _snapshot(out) == before


def test_blocks_bad_file_read_whole_is_one_line_in_a_process(tmp_path):
    """The warning that a file is read whole comes only after its checks: a bad one is one line
    (in-process runs above do not see log records, which pytest captures)."""
    import subprocess

    np.savez(tmp_path / "bo.npz", values=np.zeros((5, 5, 5)), origin=np.array([0.0, np.inf, 0.0]))
    r = subprocess.run([sys.executable, "-m", "trivsel", "blocks", str(tmp_path / "bo.npz"), "--block", "2",
                        "--tol-inf", "0.1", "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    _one_line(r.stderr, "grid origin must be 3 finite numbers, got (0.0, inf, 0.0)")
    assert not (tmp_path / "o").exists()


def test_blocks_refuses_a_folder_another_run_holds(tmp_path):
    from trivsel.blocks import _lock_folder

    out = tmp_path / "busy"
    out.mkdir()
    lock = _lock_folder(out)
    try:
        for extra in ([], ["-n"]):  # a dry run predicts the refusal
            code, err, _ = _run(["blocks", *BLOCKS_FN, *extra, "--out", str(out)])
            assert code == 2
            _one_line(err, "another trivsel blocks run is working in")
    finally:
        import os

        os.close(lock)
    assert list(out.iterdir()) == []


def test_blocks_that_snakemake_stops_before_any_job_leaves_nothing(tmp_path, capfd):
    """An argument Snakemake refuses (after ``--``) ends the run before any job: the folders and
    the configuration that run made are taken back; a folder of the user's keeps only its files."""
    for out in (tmp_path / "new" / "run", tmp_path / "mine"):
        if out.name == "mine":
            out.mkdir()
            (out / "notes.txt").write_text("keep me")
        code, err, _ = _run(["blocks", *FN, "--block", "4", "--tol-inf", "0.1", "--out", str(out), "-c", "1", "--",
                             "--no-such-snakemake-flag"])
        err += capfd.readouterr().err
        assert code == 1 and "unrecognized arguments: --no-such-snakemake-flag" in err, err
    assert not (tmp_path / "new").exists()
    assert [q.name for q in (tmp_path / "mine").iterdir()] == ["notes.txt"]


def test_blocks_dry_run_creates_nothing(tmp_path, capfd):
    import tempfile

    plans = set(Path(tempfile.gettempdir()).glob("trivsel-blocks-plan-*"))
    out = tmp_path / "new" / "planned"  # the dry run tries to make it, as the run would, and removes it
    assert main(["blocks", *BLOCKS_FN, "-n", "--out", str(out)]) == 0
    text = "".join(capfd.readouterr())
    assert "This was a dry-run" in text and "block" in text
    assert list(tmp_path.iterdir()) == []
    assert set(Path(tempfile.gettempdir()).glob("trivsel-blocks-plan-*")) == plans


def test_boundary_tolerance_that_cannot_be_met_warns(tmp_path):
    """--tol-inf that a prescribed boundary cannot meet: exit 0 with the best mesh, one warning
    line naming the errors, and tolerance_met: false in result.json (true when it is met)."""
    import json

    from trivsel.data import sample_grid

    d = sample_grid(4, 4)
    n = d.shape[0]
    corner = {c: (c[0] * (n - 1) * n + c[1] * (n - 1)) * n + c[2] * (n - 1)
              for c in np.ndindex(2, 2, 2)}
    quads = [[(0, 0, 0), (0, 1, 0), (0, 1, 1), (0, 0, 1)], [(1, 0, 0), (1, 0, 1), (1, 1, 1), (1, 1, 0)],
             [(0, 0, 0), (0, 0, 1), (1, 0, 1), (1, 0, 0)], [(0, 1, 0), (1, 1, 0), (1, 1, 1), (0, 1, 1)],
             [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 0, 1), (0, 1, 1), (1, 1, 1), (1, 0, 1)]]
    tris = [[corner[q[0]], corner[q[i]], corner[q[i + 1]]] for q in quads for i in (1, 2)]
    np.save(tmp_path / "coarse.npy", np.array(tris))
    code, err, _ = _run(["reduce", "--function", "4", "--n", "4", "--tol-inf", "0.001", "--method", "greedy",
                         "--boundary", str(tmp_path / "coarse.npy"), "--out", str(tmp_path / "o")])
    assert code == 0, err
    warnings = [x for x in err.splitlines() if x.startswith("trivsel: warning:")]
    assert len(warnings) == 1 and "the tolerance was not met: E_inf" in warnings[0] and "> --tol-inf 0.001" in \
        warnings[0], err
    assert json.loads((tmp_path / "o" / "result.json").read_text())["tolerance_met"] is False
    code, err, _ = _run(["reduce", "--function", "4", "--n", "4", "--tol-inf", "0.1", "--method", "greedy",
                         "--out", str(tmp_path / "met")])
    assert code == 0 and "warning" not in err
    assert json.loads((tmp_path / "met" / "result.json").read_text())["tolerance_met"] is True


# ----------------------------------------------------------------------------- blocks: real runs

def _blocks(out, *args, source=("--function", "4", "--n", "8")):
    import subprocess

    return subprocess.run([sys.executable, "-m", "trivsel", "blocks", *source, "--block", "4", "--tol-inf", "0.05",
                           "--out", str(out), "-c", "2", *args], capture_output=True, text=True, timeout=900,
                          preexec_fn=lambda: __import__("os").umask(0o022))


def _processes_in(folder):
    """Processes whose working folder is ``folder`` (Snakemake's jobs run there)."""
    import os

    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            if os.readlink(f"/proc/{pid}/cwd") == str(folder):
                found.append(int(pid))
        except OSError:
            pass
    return found


@pytest.mark.slow
def test_blocks_success_rerun_and_a_limited_run(tmp_path):
    """A run leaves no lock and no temporary file, its files readable as the umask says; a rerun
    is 'nothing to run'; a deleted mesh is made again; a run that Snakemake's own arguments
    stop before the merge is an error, not a success."""
    from trivsel.io import TMP_PREFIX

    out = tmp_path / "ok"
    r = _blocks(out)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("trivsel blocks: ran "), r.stderr
    names = [p.name for p in out.rglob("*")]
    assert not [n for n in names if n.startswith(TMP_PREFIX) or n.endswith(".lock")], names
    for f in ["mesh.vtu", "mesh.pvtu", "summary.json", "blocks.json", "pieces/0_0_0.vtu", "pieces/0_0_0.npz"]:
        assert (out / f).stat().st_mode & 0o777 == 0o644, f
    r = _blocks(out)
    assert r.returncode == 0 and "nothing to run" in r.stderr, r.stderr
    mesh = (out / "mesh.vtu").read_bytes()
    (out / "mesh.vtu").unlink()
    r = _blocks(out)
    assert r.returncode == 0 and (out / "mesh.vtu").read_bytes() == mesh, r.stderr
    r = _blocks(tmp_path / "limited", "--", "--until", "lines")
    assert r.returncode == 1
    _one_line(r.stderr, "Snakemake ended without writing summary.json, mesh.pvtu, mesh.vtu")

    # SIGTERM while the merge runs again: the previous results stay as they were
    import signal
    import subprocess
    import time

    results = {n: (out / n).read_bytes() for n in ("summary.json", "mesh.pvtu", "mesh.vtu")}
    (out / "merged" / "mesh.vtu").unlink()
    p = subprocess.Popen([sys.executable, "-m", "trivsel", "blocks", "--function", "4", "--n", "8", "--block", "4",
                          "--tol-inf", "0.05", "--out", str(out), "-c", "2"], stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    while time.time() < deadline and not any(b"merge" in Path(f"/proc/{pid}/cmdline").read_bytes()
                                             for pid in _processes_in(out)):
        time.sleep(0.02)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert {n: (out / n).read_bytes() for n in results} == results
    assert not list(out.rglob(TMP_PREFIX + "*")) and _processes_in(out) == []


def test_blocks_nan_anywhere_is_refused_before_any_job(tmp_path):
    """A non-finite value is found by reading the input through before the first run, not by
    the job that reads it after others have run: one line, exit 2, no folder."""
    v = np.fromfunction(lambda i, j, k: np.sin(i) + j * k / 10.0, (9, 9, 9)).astype(np.float32)
    v[6, 6, 6] = np.inf  # inside block 1_1_1 only: no line or plane reads it
    np.save(tmp_path / "inf.npy", v)
    for extra in ([], ["-n"]):
        code, err, _ = _run(["blocks", str(tmp_path / "inf.npy"), "--block", "4", "--tol-inf", "0.05", *extra,
                             "--out", str(tmp_path / "o")])
        assert code == 2
        _one_line(err, f"non-finite value inf at grid index (6, 6, 6) of {str(tmp_path / 'inf.npy')!r}")
        assert not (tmp_path / "o").exists()


def test_blocks_stamp_sees_a_detached_nrrd_data_file_change(tmp_path):
    """A .nhdr's samples are in its data file: changing them (the header untouched) is a
    changed input, refused on a rerun in the same folder."""
    import os

    from trivsel.blocks import input_stamp, write_config

    v = np.arange(125.0).reshape(5, 5, 5)
    (tmp_path / "v.raw").write_bytes(v.astype("<f8").tobytes(order="F"))
    (tmp_path / "v.nhdr").write_text("NRRD0004\ntype: double\ndimension: 3\nsizes: 5 5 5\nendian: little\n"
                                     "encoding: raw\ndata file: v.raw\n\n")
    out = tmp_path / "run"
    write_config(out, {"input": str(tmp_path / "v.nhdr"), "block": 2, "tol_inf": 0.1})
    before = _snapshot(out)
    stamp = input_stamp(tmp_path / "v.nhdr")
    (tmp_path / "v.raw").write_bytes((v + 1).astype("<f8").tobytes(order="F"))
    st = os.stat(tmp_path / "v.raw")
    os.utime(tmp_path / "v.raw", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert input_stamp(tmp_path / "v.nhdr")[:2] == stamp[:2] and input_stamp(tmp_path / "v.nhdr") != stamp
    code, err, _ = _run(["blocks", str(tmp_path / "v.nhdr"), "--block", "2", "--tol-inf", "0.1", "--out", str(out)])
    assert code == 2
    _one_line(err, f"the input {str((tmp_path / 'v.nhdr').resolve())!r} changed since the blocked run in")
    assert _snapshot(out) == before


@pytest.mark.slow
def test_blocks_failing_job_gives_its_own_message(tmp_path):
    """A job that fails shows its own one-line reason.  The input's values were read through
    when the folder's run was first set up; here they are changed afterwards in place (same
    size and time, so the stamp cannot tell), and the one job that reads the bad value fails."""
    import os

    from trivsel.blocks import write_config

    v = np.fromfunction(lambda i, j, k: np.sin(i) + j * k / 10.0, (9, 9, 9))
    src = tmp_path / "nan.npy"
    np.save(src, v)
    write_config(tmp_path / "o", {"input": str(src), "block": 4, "tol_inf": 0.05})
    st = os.stat(src)
    v[6, 6, 6] = np.nan  # inside block 1_1_1 only: no line or plane reads it
    np.save(src, v)
    os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns))
    r = _blocks(tmp_path / "o", source=(str(src),))
    assert r.returncode == 2
    _one_line(r.stderr, "job block 1_1_1 failed: non-finite value nan at grid index (6, 6, 6)")
    assert "logs/block/1_1_1.log" in r.stderr


@pytest.mark.slow
@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_blocks_signal_stops_every_job(tmp_path, sig):
    """SIGTERM or SIGINT to `trivsel blocks` alone (not its process group): one line, exit
    130, no process left working in the folder, no temporary file; a rerun completes."""
    import os
    import signal
    import subprocess
    import time

    from trivsel.io import TMP_PREFIX

    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "trivsel", "blocks", "--function", "4", "--n", "24", "--block", "8", "--tol-inf",
           "0.01", "--out", str(out), "-c", "2"]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 600
    while time.time() < deadline and not list(out.glob("planes/*.npz")):
        time.sleep(0.1)
    assert _processes_in(out), "no job was running"
    p.send_signal(getattr(signal, sig))
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert err.strip().splitlines() == [
        "trivsel: interrupted; jobs that had started were stopped and finished ones are kept: run it again to "
        "resume"]
    assert _processes_in(out) == []
    assert not list(out.rglob(TMP_PREFIX + "*"))
    assert not (out / "summary.json").exists()
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0 and (out / "mesh.vtu").exists(), r.stderr[-3000:]
    assert os.listdir(out)


if __name__ == "__main__":  # the matrix for notes: case | exit | message
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        print("| case | exit | message |\n|---|---|---|")
        for name, argv, _, _ in _cases(Path(d)):
            code, err, out = _run(argv)
            msg = (err.strip() or out.strip()).splitlines()
            print(f"| {name} | {code} | {msg[0] if msg else ''} |")
    sys.exit(0)


@pytest.mark.parametrize("argv", [["reduce", "--function", "4", "--n", "6", "--fractions", "0.5", "0.2"],
                                  ["compare", "GOLDEN", "GOLDEN"]])
def test_a_closed_stdout_ends_the_command_quietly_and_keeps_its_files(tmp_path, argv):
    """`trivsel ... | head`: the reader goes before the command prints.  No traceback; status 141
    (128 + SIGPIPE, as a Unix tool); the files the command wrote are complete."""
    import os
    import subprocess

    golden = tmp_path / "golden.csv"
    golden.write_text("a,b\n1,2\n")
    argv = [str(golden) if x == "GOLDEN" else x for x in argv]
    if argv[0] == "reduce":
        argv += ["--out", str(tmp_path / "out")]
    r, w = os.pipe()
    os.close(r)  # nobody will read what the command prints
    try:
        p = subprocess.run([sys.executable, "-m", "trivsel", *argv], stdout=w, stderr=subprocess.PIPE, text=True,
                           timeout=300)
    finally:
        os.close(w)
    assert p.returncode == 141 and "Traceback" not in p.stderr and "BrokenPipe" not in p.stderr, p.stderr
    if argv[0] == "reduce":
        assert {x.name for x in (tmp_path / "out").iterdir()} >= {"errors.csv", "mesh_0.2.vtu", "mesh_0.5.vtu",
                                                                   "result.json"}
        assert "0.2" in (tmp_path / "out" / "errors.csv").read_text()


# ----------------------------------------------------------------------------- the Python API

def _api_cases():
    """(name, call on a 6^3 grid ``v``, scattered points ``p``/``f`` and a result ``r``, the
    exception and a phrase of its one-line message)."""
    import numpy.ma as ma

    import trivsel

    red = trivsel.reduce
    return [
        ("count NaN", lambda v, p, f, r, d: red(v, count=float("nan")), "count must be an integer in [1, 216], got nan"),
        ("count inf", lambda v, p, f, r, d: red(v, count=float("inf")), "count must be an integer in [1, 216], got inf"),
        ("count a list", lambda v, p, f, r, d: red(v, count=[30]), "count must be an integer in [1, 216], got [30]"),
        ("count complex", lambda v, p, f, r, d: red(v, count=30 + 0j), "count must be an integer in [1, 216]"),
        ("tol_rms a string", lambda v, p, f, r, d: red(v, tol_rms="0.1"), "tol_rms must be a finite number >= 0, got '0.1'"),
        ("tol_inf an array", lambda v, p, f, r, d: red(v, tol_inf=np.array([0.1, 0.2])),
         "tol_inf must be a finite number >= 0, got [0.1, 0.2]"),
        ("tol_rms a bool", lambda v, p, f, r, d: red(v, tol_rms=True), "tol_rms must be a finite number >= 0, got True"),
        ("fractions a bool", lambda v, p, f, r, d: red(v, fractions=True), "fraction True is not a number"),
        ("fractions a dict", lambda v, p, f, r, d: red(v, fractions={0.5: "x"}),
         "fractions must be a number or a sequence of numbers, got {0.5: 'x'}"),
        ("fractions a string", lambda v, p, f, r, d: red(v, fractions="0.5"),
         "fractions must be a number or a sequence of numbers, got '0.5'"),
        ("an unknown keyword", lambda v, p, f, r, d: red(v, count=30, frobnicate=1),
         "reduce() got an unexpected keyword argument 'frobnicate'"),
        ("progress not callable", lambda v, p, f, r, d: red(v, count=30, progress="x"),
         "progress must be a function (or None), got 'x'"),
        ("check not callable", lambda v, p, f, r, d: red(v, count=30, check=3), "check must be a function (or None), got 3"),
        ("n with an array", lambda v, p, f, r, d: red(v, count=30, n=8),
         "n= applies to a Table-1 function, not to input data (got n=8)"),
        ("a masked grid", lambda v, p, f, r, d: red(ma.masked_array(v, mask=v > 0.9), count=30), "masked value(s)"),
        ("masked scattered values", lambda v, p, f, r, d: trivsel.scattered(p, ma.masked_array(f, mask=f > 0.5)),
         "masked value(s)"),
        ("load of a number", lambda v, p, f, r, d: trivsel.load(123),
         "the input file must be a path (a str or a pathlib.Path), got 123"),
        ("snapshot of a string", lambda v, p, f, r, d: r.snapshot("abc"), "fraction must be a number, got 'abc'"),
        ("write_outputs into None", lambda v, p, f, r, d: trivsel.write_outputs(r, None),
         "the output folder must be a path (a str or a pathlib.Path), got None"),
        ("write_outputs of no result", lambda v, p, f, r, d: trivsel.write_outputs("x", d),
         "write_outputs takes the result of trivsel.reduce, got 'x'"),
        ("write_outputs with extra not JSON", lambda v, p, f, r, d: trivsel.write_outputs(r, d, extra={"a": object()}),
         "extra must hold JSON values only"),
    ]


@pytest.mark.parametrize("name", [c[0] for c in _api_cases()])
def test_the_python_api_refuses_bad_arguments_in_one_line(tmp_path, name):
    """A notebook's wrong argument: one line naming it and its value, before any work; nothing
    written, and the caller's arrays as they were."""
    import trivsel

    _, call, fragment = {c[0]: c for c in _api_cases()}[name]
    v = np.random.default_rng(0).random((6, 6, 6))
    p, f = _cloud(20)
    r = trivsel.reduce(np.random.default_rng(1).random((4, 4, 4)), count=20, method="greedy")
    v0, p0, f0 = v.copy(), p.copy(), f.copy()
    with pytest.raises((trivsel.InputError, TypeError)) as info:
        call(v, p, f, r, tmp_path / "out")
    message = str(info.value)
    assert "\n" not in message and fragment in message, message
    assert not (tmp_path / "out").exists()
    assert np.array_equal(v, v0) and np.array_equal(p, p0) and np.array_equal(f, f0)


def test_numpy_bools_and_numbers_are_taken_as_python_ones():
    """A NumPy bool is a bool (it was refused as 'got True'), NumPy numbers are numbers."""
    import trivsel

    v = np.random.default_rng(0).random((6, 6, 6))
    r = trivsel.reduce(v, count=np.int64(30), method="paper", final_pass=np.bool_(True))
    assert r.options["final_pass"] is True and r.snapshots[-1].n_selected == 30
    r = trivsel.reduce(v, fractions=np.array([0.5, 0.2]), method="greedy", tol_inf=np.float32(0.0))
    assert [s.n_selected for s in r.snapshots] == [43, 108]


def test_a_blocks_config_that_names_a_setting_twice_is_refused(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("block: 8\ntol_inf: 0.1\nblock: 4\n")
    code, err, _ = _run(["blocks", "--function", "4", "--n", "8", "--config", str(cfg), "--out", str(tmp_path / "out")])
    assert code == 2 and _lines(err) == [f"trivsel: error: cannot read config {cfg}: the setting 'block' is given "
                                         "twice (line 3)"], err
    assert not (tmp_path / "out").exists()
