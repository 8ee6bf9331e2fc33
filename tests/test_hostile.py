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


def _cloud(n=50, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.random((n, 3))
    return p, np.sin(3 * p[:, 0]) + p[:, 1]


BLOCKS_FN = ["--function", "4", "--n", "8", "--block", "4", "--tol-inf", "0.1"]


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
                                  "--out", out], 2, "block size must be an integer >= 2"),
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
        ("blocks: method decimate in --config", ["blocks", *BLOCKS_FN, "--config",
                                                 _write(tmp, "d.yaml", _text("method: decimate\n")), "--out", out], 2,
         "method 'decimate' cannot take the blocks' prescribed faces: choose paper or greedy"),
        ("blocks: Snakemake's --touch after --", ["blocks", *BLOCKS_FN, "--out", out, "--", "--touch"], 2,
         "Snakemake's --touch cannot be passed after '--'"),
        ("blocks: Snakemake's --directory after --", ["blocks", *BLOCKS_FN, "--out", out, "--", "--directory",
                                                      str(tmp)], 2, "Snakemake's --directory cannot be passed"),
        ("blocks: Snakemake's --cores after --", ["blocks", *BLOCKS_FN, "--out", out, "--", "--cores=0"], 2,
         "use -c before '--'"),
        ("compare: missing table", ["compare", str(tmp / "no.csv"), existing], 2, ("table", "no.csv' does not exist")),
        ("compare: a folder", ["compare", str(tmp), existing], 2, (f"table '{tmp}' is not a file",)),
        ("compare: empty table", ["compare", _write(tmp, "e.csv", _text("")), existing], 2,
         ("cannot read table", "e.csv' as CSV")),
        ("compare: binary junk", ["compare", _write(tmp, "j.csv", _text(b"\xc1\xff\x00junk")), existing], 2,
         ("cannot read table", "j.csv' as CSV")),
        ("compare: no numeric column", ["compare", existing, existing], 2,
         ("a_file' has no numeric column to compare",)),
        ("compare: rtol nan", ["compare", existing, existing, "--rtol", "nan"], 2,
         ("--rtol must be a finite number >= 0, got nan",)),
        ("compare: tables differ", ["compare", _write(tmp, "n.csv", _text("a,b\n1,2\n")),
                                    _write(tmp, "g.csv", _text("a,b\n1,3\n"))], 1,
         ("1 offending cell(s)", "b: new 2 != golden 3")),
    ]
    return cases


def _run(argv):
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code
    return code, err.getvalue(), out.getvalue()


def _names():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        return [c[0] for c in _cases(Path(d))]


@pytest.mark.parametrize("name", _names())
def test_hostile_case_gives_one_line_and_no_output(tmp_path, name):
    case = {c[0]: c for c in _cases(tmp_path)}[name]
    _, argv, expected, fragments = case
    fragments = (fragments,) if isinstance(fragments, str) else fragments
    assert max(map(len, fragments)) >= 10, fragments  # a phrase of the message, not a character
    code, err, out = _run(argv)
    assert code == expected, (code, err)
    text = err if expected == 2 else out
    lines = [x for x in text.strip().splitlines() if x]
    if expected == 2:
        assert len(lines) == 1 and lines[0].startswith("trivsel"), err
        assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in text, (fragment, text)
    assert not (tmp_path / "out").exists()
    assert (tmp_path / "a_file").read_text() == "keep me"


# ----------------------------------------------------------------------------- blocks: folders with a history

def _one_line(err, fragment):
    lines = [x for x in err.strip().splitlines() if x]
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
        code, err, _ = _run(["blocks", *BLOCKS_FN, "--out", str(out)])
    finally:
        import os

        os.close(lock)
    assert code == 2
    _one_line(err, "another trivsel blocks run is working in")
    assert list(out.iterdir()) == []


def test_blocks_dry_run_creates_nothing(tmp_path, capfd):
    import tempfile

    plans = set(Path(tempfile.gettempdir()).glob("trivsel-blocks-plan-*"))
    out = tmp_path / "planned"
    assert main(["blocks", *BLOCKS_FN, "-n", "--out", str(out)]) == 0
    text = "".join(capfd.readouterr())
    assert "This was a dry-run" in text and "block" in text
    assert not out.exists()
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


@pytest.mark.slow
def test_blocks_failing_job_gives_its_own_message(tmp_path):
    v = np.fromfunction(lambda i, j, k: np.sin(i) + j * k / 10.0, (9, 9, 9))
    v[6, 6, 6] = np.nan  # inside block 1_1_1 only: no line or plane reads it
    np.save(tmp_path / "nan.npy", v)
    r = _blocks(tmp_path / "o", source=(str(tmp_path / "nan.npy"),))
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
