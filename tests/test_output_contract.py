"""The output contract of `trivsel reduce --out`: an input is never overwritten, a folder never
mixes two runs, a failure or an interruption leaves the previous outputs intact and no litter."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import trivsel
import trivsel.io as tio
from trivsel.cli import main


def _run(*args):
    return main(["reduce", "--function", "4", "--n", "4", *args])


def _listing(folder):
    return sorted(p.name for p in folder.iterdir())


def test_an_input_inside_the_output_folder_is_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "out"
    assert _run("--fractions", "0.5", "--out", str(out)) == 0
    mesh = out / "mesh_0.5.vtu"
    before = mesh.read_bytes()
    capsys.readouterr()
    rc = main(["reduce", str(mesh), "--array", "value", "--fractions", "0.5", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "is inside the output folder" in err and err.count("\n") == 1
    assert mesh.read_bytes() == before


def test_an_existing_file_as_output_folder_is_refused(tmp_path, capsys):
    f = tmp_path / "taken"
    f.write_text("user data")
    assert _run("--fractions", "0.5", "--out", str(f)) == 2
    assert "is an existing file" in capsys.readouterr().err
    assert f.read_text() == "user data"


def test_a_new_run_replaces_exactly_the_previous_runs_files(tmp_path):
    out = tmp_path / "d"
    assert _run("--fractions", "0.5", "0.2", "--out", str(out)) == 0
    (out / "notes.txt").write_text("mine")
    assert _run("--fractions", "0.3", "--out", str(out)) == 0
    assert _listing(out) == [tio.MANIFEST, "errors.csv", "mesh_0.3.vtu", "notes.txt", "result.json"]
    assert json.loads((out / tio.MANIFEST).read_text())["files"] == ["errors.csv", "mesh_0.3.vtu", "result.json"]


def test_a_failure_while_writing_keeps_the_previous_outputs_and_leaves_no_litter(tmp_path, monkeypatch):
    out = tmp_path / "d"
    assert _run("--fractions", "0.5", "0.2", "--out", str(out)) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    calls = []
    real = tio.snapshot_to_vtk

    def failing(result, snapshot):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt  # as Ctrl-C or SIGTERM would, half-way through the meshes
        return real(result, snapshot)

    monkeypatch.setattr(tio, "snapshot_to_vtk", failing)
    assert _run("--fractions", "0.4", "0.1", "--out", str(out)) == 130
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_leftovers_of_a_killed_run_are_removed_by_the_next(tmp_path):
    out = tmp_path / "d"
    (out / ".trivsel-tmp-killed").mkdir(parents=True)
    (out / ".trivsel-tmp-killed" / "mesh_0.5.vtu").write_text("half")
    assert _run("--fractions", "0.5", "--out", str(out)) == 0
    assert not [p for p in out.iterdir() if p.name.startswith(".trivsel-tmp-")]


def test_sigterm_exits_130_with_one_line(tmp_path):
    code = ("import sys, time, trivsel.reduction as r\n"
            "real = r.reduce\n"
            "def slow(*a, **k):\n"
            "    print('started', flush=True); time.sleep(30); return real(*a, **k)\n"
            "r.reduce = slow\n"
            "from trivsel.cli import main\n"
            f"sys.exit(main(['reduce', '--function', '4', '--n', '4', '--fractions', '0.5', '--out', r'{tmp_path}/o']))\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "started"
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    assert err.strip().splitlines() == ["trivsel: interrupted; the output folder is as it was before this run"]
    assert not (tmp_path / "o").exists()


def _sigint_default():
    """In the child: SIGINT as at an interactive terminal.  A test run started in the
    background by a shell ignores SIGINT, and its children would inherit that."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow
def test_ctrl_c_inside_the_compiled_loop_stops_the_run_there(tmp_path):
    """The insertion loop returns to Python in short chunks, so SIGINT ends the run
    mid-way (not after the whole loop) with one line and exit 130."""
    code = ("import sys, trivsel.methods.paper as m\n"
            "real = m.advance\n"
            "def traced(mesh, order, done, stop, *a):\n"
            "    print(done, flush=True); return real(mesh, order, done, stop, *a)\n"
            "m.advance = traced\n"
            "from trivsel.cli import main\n"
            f"sys.exit(main(['reduce', '--function', '4', '--n', '40', '--fractions', '0.5', "
            f"'--out', r'{tmp_path}/o']))\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=_sigint_default)
    assert p.stdout.readline().strip().isdigit()  # inside the insertion loop
    assert p.stdout.readline().strip().isdigit()  # and a chunk later
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert err.strip().splitlines() == ["trivsel: interrupted; the output folder is as it was before this run"]
    reached = int(out.split()[-1]) if out.split() else 0
    assert reached < 0.5 * 41**3 - 8  # it stopped inside the loop, far from the target
    assert not (tmp_path / "o").exists()


def test_python_dash_m_ends_with_130_on_ctrl_c(tmp_path):
    """``python -m trivsel``: SIGINT during a long stage gives the one line and status 130
    (not an interpreter that ends itself by the signal)."""
    p = subprocess.Popen([sys.executable, "-m", "trivsel", "reduce", "--function", "4", "--n", "48",
                          "--fractions", "0.5", "--progress", "always", "--out", str(tmp_path / "o")],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, preexec_fn=_sigint_default)
    for line in p.stderr:  # wait for the first stage message
        if line.startswith("trivsel ["):
            break
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert err.replace("\r", "\n").strip().splitlines()[-1] == (
        "trivsel: interrupted; the output folder is as it was before this run")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("make", [
    lambda: trivsel.reduce(4, n=6, fractions=[0.5, 0.1], values=["data", "fit"]),
    lambda: trivsel.reduce(2, n=6, fractions=[0.2], method="decimate"),
    lambda: trivsel.reduce(trivsel.scattered(np.random.default_rng(1).random((200, 3)),
                                             np.random.default_rng(2).random(200)), count=120, method="greedy"),
])
def test_mesh_files_are_what_pyvista_writes(tmp_path, make):
    """The ``.vtu`` files are written with VTK's modules alone, byte for byte as pyvista's
    ``save`` writes the same mesh (points, tetrahedra, the point and field arrays, the active
    scalars); and they read back to the snapshot's vertices and tetrahedra."""
    pv = pytest.importorskip("pyvista")
    result = make()
    for k, s in enumerate(result.snapshots):
        tio.write_vtu(tio.snapshot_to_vtk(result, s), tmp_path / f"a{k}.vtu")
        sel = np.unique(s.tets)
        grid = pv.UnstructuredGrid(np.hstack([np.full((len(s.tets), 1), 4), np.searchsorted(sel, s.tets)]).ravel(),
                                   np.full(len(s.tets), pv.CellType.TETRA, np.uint8), result.data.points[sel])
        grid.point_data["value"] = result.data.values[sel]
        if s.fit is not None:
            fitted = np.empty(len(sel))
            fitted[np.searchsorted(sel, s.fit["vertices"])] = s.fit["values"]
            grid.point_data["fitted_value"] = fitted
        grid.point_data["original_index"] = result.data.file_ids(sel)
        if result.curvature is not None:
            grid.point_data["curvature"] = result.curvature[sel]
        grid.field_data["fraction"] = np.array([s.fraction])
        grid.save(tmp_path / f"b{k}.vtu")
        assert (tmp_path / f"a{k}.vtu").read_bytes() == (tmp_path / f"b{k}.vtu").read_bytes()
        back = pv.read(tmp_path / f"a{k}.vtu")
        assert np.array_equal(back.points, result.data.points[sel])
        assert np.array_equal(sel[back.cells_dict[pv.CellType.TETRA]], s.tets)
        assert back.point_data.active_scalars_name == "value"


def test_a_mesh_file_that_cannot_be_written_is_an_error(tmp_path):
    result = trivsel.reduce(4, n=4, fractions=[0.5])
    with pytest.raises(OSError, match="No such file"):
        tio.write_vtu(tio.snapshot_to_vtk(result, result.snapshots[0]), tmp_path / "missing" / "m.vtu")


@pytest.mark.parametrize("make", [
    lambda: trivsel.reduce(4, n=6, fractions=[0.5, 0.1]),
    lambda: trivsel.reduce(2, n=6, fractions=[0.2], method="decimate", values=["data", "fit"]),
    lambda: trivsel.reduce(trivsel.scattered(np.random.default_rng(1).random((200, 3)),
                                             np.random.default_rng(2).random(200)), count=120, method="greedy"),
    lambda: trivsel.reduce(4, n=6, tol_rms=0.01, method="decimate"),
])
def test_errors_csv_and_the_printed_table_are_what_pandas_writes(tmp_path, make):
    """errors.csv and the table ``trivsel reduce`` prints are written without pandas, byte for
    byte as ``DataFrame.to_csv`` and ``to_string`` would (grid and scattered inputs, fitted
    values, a fraction from a tolerance); a NaN is an empty CSV cell and ``NaN`` in the table."""
    pd = pytest.importorskip("pandas")
    rows = make().error_rows()
    rows[-1]["E_rms_interior"] = float("nan")  # as for a region with no points
    tio.write_csv_rows(rows, tmp_path / "a.csv")
    pd.DataFrame(rows).to_csv(tmp_path / "b.csv", index=False)
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    fmt = lambda v: f"{v:.6g}"  # noqa: E731
    assert tio.format_rows(rows, fmt) == pd.DataFrame(rows).to_string(index=False, float_format=fmt)
