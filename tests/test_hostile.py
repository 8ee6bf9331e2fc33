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
         ("grid spacing must be positive and finite", "-1.0")),
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


if __name__ == "__main__":  # the matrix for notes: case | exit | message
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        print("| case | exit | message |\n|---|---|---|")
        for name, argv, _, _ in _cases(Path(d)):
            code, err, out = _run(argv)
            msg = (err.strip() or out.strip()).splitlines()
            print(f"| {name} | {code} | {msg[0] if msg else ''} |")
    sys.exit(0)
