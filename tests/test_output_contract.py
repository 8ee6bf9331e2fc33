"""The output contract of `trivsel reduce --out`: an input is never overwritten, a folder never
mixes two runs, a failure or an interruption leaves the previous outputs intact and no litter."""

from __future__ import annotations

import json
import os
import re
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


# --- files that are not trivsel's, faults while writing, permissions, concurrent runs, convert

ONE_LINE_INTERRUPT = "trivsel: interrupted; the output folder is as it was before this run"


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def test_a_file_no_trivsel_run_wrote_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    out = tmp_path / "d"
    out.mkdir()
    (out / "result.json").write_text("their notes")
    import trivsel.reduction as reduction

    monkeypatch.setattr(reduction, "reduce", lambda *a, **k: pytest.fail("the reduction ran"))
    assert _run("--fractions", "0.5", "--out", str(out)) == 2
    err = capsys.readouterr().err
    assert err == (f"trivsel: error: {str(out / 'result.json')!r} exists and no trivsel run wrote it (it is not in "
                   f"{tio.MANIFEST}): move it away or choose another --out\n")
    assert _listing(out) == ["result.json"] and (out / "result.json").read_text() == "their notes"


def test_a_foreign_mesh_named_only_after_the_run_is_refused_at_write_time(tmp_path):
    """A tolerance decides the fraction, so the mesh's name is known only at the end: the
    check is made again, under the folder's lock, before anything is moved."""
    result = trivsel.reduce(4, n=4, tol_rms=0.05)
    out = tmp_path / "d"
    out.mkdir()
    name = f"mesh_{tio.fraction_label(result.snapshots[0].fraction)}.vtu"
    (out / name).write_text("their mesh")
    with pytest.raises(trivsel.InputError, match=f"{name}' exists and no trivsel run wrote it"):
        tio.write_outputs(result, out)
    assert _listing(out) == [name] and (out / name).read_text() == "their mesh"


def test_files_of_an_earlier_run_are_replaced_and_keep_the_umask_mode(tmp_path):
    out = tmp_path / "d"
    old = os.umask(0o027)
    try:
        assert _run("--fractions", "0.5", "--out", str(out)) == 0
        assert _run("--fractions", "0.5", "--out", str(out)) == 0  # its own files: replaced, no refusal
    finally:
        os.umask(old)
    modes = {p.name: p.stat().st_mode & 0o777 for p in out.iterdir()}
    assert modes == {n: 0o640 for n in (tio.MANIFEST, "errors.csv", "mesh_0.5.vtu", "result.json")}


def test_pieces_get_the_umask_mode_not_mkstemps_0600(tmp_path):
    from trivsel.io.pieces import write_piece, write_pvtu

    old = os.umask(0o022)
    try:
        pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
        piece = write_piece(tmp_path / "p0.vtu", pts, np.array([[0, 1, 2, 3]]), np.zeros(4), np.arange(4))
        pvtu = write_pvtu(tmp_path / "mesh.pvtu", [piece])
    finally:
        os.umask(old)
    assert piece.stat().st_mode & 0o777 == 0o644 and pvtu.stat().st_mode & 0o777 == 0o644


def _full_disk(*args, **kwargs):
    import errno

    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_full_disk_gives_one_line_and_keeps_the_previous_results(tmp_path, capsys, monkeypatch):
    out = tmp_path / "d"
    assert _run("--fractions", "0.5", "0.2", "--out", str(out)) == 0
    before = _snapshot(out)
    capsys.readouterr()
    monkeypatch.setattr(tio, "write_vtu", _full_disk)
    assert _run("--fractions", "0.4", "--out", str(out)) == 2
    err = capsys.readouterr().err
    assert err == (f"trivsel: error: cannot write the outputs into {str(out)!r}: [Errno 28] No space left on device; "
                   "the output folder is as it was before this run\n")
    assert _snapshot(out) == before
    assert _run("--fractions", "0.4", "--out", str(tmp_path / "new" / "d")) == 2
    assert not (tmp_path / "new" / "d").exists()  # the folder this run made is gone again


def _tiny_tmpfs_script(tmp_path, script):
    """Run ``script`` (sh) in a private mount namespace with a 64 KiB tmpfs at $T; None when
    this machine cannot (not root, no unshare)."""
    import shutil

    if os.geteuid() != 0 or shutil.which("unshare") is None:
        return None
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    full = f"mount -t tmpfs -o size=64k tmpfs {mnt} || exit 99\nT={mnt}\n{script}"
    p = subprocess.run(["unshare", "-m", "sh", "-c", full], capture_output=True, text=True, timeout=600,
                       env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    return None if p.returncode == 99 else p


def test_a_real_full_disk_gives_one_line_not_a_crash(tmp_path):
    """On a real 64 KiB tmpfs: the first run fits, the second (a 17^3 grid's meshes) does not.
    VTK's own file writer crashed the process here (SIGSEGV); now one line, exit 2, and the
    first run's files as they were."""
    py = f"{sys.executable} -m trivsel reduce --function 4 --progress never"
    p = _tiny_tmpfs_script(tmp_path, f"""
{py} --n 4 --fractions 0.5 --out $T/o >/dev/null 2>&1 || exit 98
cd $T/o && md5sum * .trivsel-manifest.json > $T/../before.txt
{py} --n 16 --fractions 0.5 0.3 --out $T/o 2>$T/../err.txt >/dev/null
echo "rc=$?"
cd $T/o && md5sum * .trivsel-manifest.json > $T/../after.txt
ls -a $T/o
""")
    if p is None:
        pytest.skip("needs root and unshare to mount a tmpfs")
    assert "rc=2" in p.stdout, (p.stdout, p.stderr)
    err = (tmp_path / "err.txt").read_text()
    assert err.endswith("No space left on device; the output folder is as it was before this run\n")
    assert err.count("\n") == 1 and err.startswith("trivsel: error: cannot write the outputs into ")
    assert (tmp_path / "before.txt").read_text() == (tmp_path / "after.txt").read_text()
    assert ".trivsel-tmp-" not in p.stdout


def test_signals_are_deferred_while_vtk_is_imported_and_outputs_are_moved():
    """A SIGTERM inside :func:`trivsel.io.signals_deferred` is handled when the block ends,
    not in it; ``trivsel reduce`` has VTK's writer imported before the selection starts."""
    code = ("import os, signal, sys\n"
            "from trivsel.io import signals_deferred\n"
            "signal.signal(signal.SIGTERM, lambda *a: print('handled', flush=True))\n"
            "with signals_deferred():\n"
            "    os.kill(os.getpid(), signal.SIGTERM)\n"
            "    print('inside', flush=True)\n"
            "print('after', flush=True)\n"
            "import trivsel.reduction as r\n"
            "real = r.reduce\n"
            "def check(*a, **k):\n"
            "    print('vtk imported' if 'vtkmodules.vtkIOXML' in sys.modules else 'vtk not imported')\n"
            "    return real(*a, **k)\n"
            "r.reduce = check\n"
            "from trivsel.cli import main\n"
            "main(['reduce', '--function', '4', '--n', '4', '--fractions', '0.5', '--out', sys.argv[1]])\n")
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        p = subprocess.run([sys.executable, "-c", code, os.path.join(d, "o")], capture_output=True, text=True,
                           timeout=300)
    assert p.stdout.split("\n")[:4] == ["inside", "handled", "after", "vtk imported"], p.stderr


def test_a_second_run_waits_for_the_folder_lock_and_keeps_the_others_temporary(tmp_path):
    """While one run holds the folder (writing its outputs), a second run into the same folder
    waits; it does not remove the first run's temporary folder meanwhile."""
    import threading

    out = tmp_path / "d"
    assert _run("--fractions", "0.5", "--out", str(out)) == 0
    result = trivsel.reduce(4, n=4, fractions=[0.3])
    done = []
    with tio._folder_lock(out):
        live = out / ".trivsel-tmp-live"
        live.mkdir()  # the other run's files, half written
        worker = threading.Thread(target=lambda: done.append(tio.write_outputs(result, out)))
        worker.start()
        worker.join(1.0)
        assert worker.is_alive() and not done and live.is_dir()
        live.rmdir()
    worker.join(60)
    assert done and _listing(out) == [tio.MANIFEST, "errors.csv", "mesh_0.3.vtu", "result.json"]


def test_two_runs_into_one_folder_both_succeed(tmp_path):
    out = tmp_path / "d"
    args = ["reduce", "--function", "4", "--n", "10", "--progress", "never", "--out", str(out), "--fractions"]
    runs = [subprocess.Popen([sys.executable, "-m", "trivsel", *args, f], stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True) for f in ("0.5", "0.3")]
    errs = [r.communicate(timeout=300)[1] for r in runs]
    assert [r.returncode for r in runs] == [0, 0], errs
    files = json.loads((out / tio.MANIFEST).read_text())["files"]
    assert _listing(out) == sorted([tio.MANIFEST, *files])  # one run's files, nothing mixed, no temporaries
    assert len([f for f in files if f.startswith("mesh_")]) == 1


def test_convert_interrupted_leaves_no_temporary_and_the_next_run_removes_dead_ones(tmp_path):
    np.save(tmp_path / "a.npy", np.random.default_rng(0).random((120, 60, 60)))
    code = ("import sys, trivsel.io.regions as r\n"
            "real = r.Volume.read\n"
            "def read(self, region):\n"
            "    print('slab', flush=True); return real(self, region)\n"
            "r.Volume.read = read\n"
            "from trivsel.cli import main\n"
            "sys.exit(main(['convert', sys.argv[1], sys.argv[2], '--chunks', '2']))\n")
    for sig in (signal.SIGINT, signal.SIGTERM):
        p = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "a.npy"), str(tmp_path / "o" / "b.zarr")],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_sigint_default)
        for _ in range(5):  # a few slabs are written: zarr's writer threads are busy
            assert p.stdout.readline().strip() == "slab"
        p.send_signal(sig)
        _, err = p.communicate(timeout=120)
        assert p.returncode == 130 and err == ONE_LINE_INTERRUPT + "\n", err
        assert not (tmp_path / "o").exists()  # no store, no temporary, not even the folder it made
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (tmp_path / "o").mkdir()
    stale = tmp_path / "o" / f"{tio.temporary_prefix('x.zarr').rsplit('-', 2)[0]}-{dead.pid}-abcdefgh"
    (stale / "c").mkdir(parents=True)
    alive = tmp_path / "o" / f"{tio.temporary_prefix('y.zarr')}abcdefgh"  # this process's: alive
    alive.mkdir()
    assert main(["convert", str(tmp_path / "a.npy"), str(tmp_path / "o" / "b.zarr")]) == 0
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == [alive.name, "b.zarr"]


def test_convert_store_gets_the_umask_mode(tmp_path):
    np.save(tmp_path / "a.npy", np.zeros((3, 3, 3)))
    old = os.umask(0o022)
    try:
        assert main(["convert", str(tmp_path / "a.npy"), str(tmp_path / "b.zarr")]) == 0
    finally:
        os.umask(old)
    assert (tmp_path / "b.zarr").stat().st_mode & 0o777 == 0o755  # not mkdtemp's 0700


def test_convert_never_replaces_an_output_that_appears_meanwhile(tmp_path, capsys, monkeypatch):
    from trivsel.io import regions

    np.save(tmp_path / "a.npy", np.zeros((3, 3, 3)))
    out = tmp_path / "b.zarr"
    real = regions._write_zarr

    def racing(vol, path, chunks, dtype):
        out.mkdir()  # someone else's empty folder: a plain rename would replace it
        return real(vol, path, chunks, dtype)

    monkeypatch.setattr(regions, "_write_zarr", racing)
    assert main(["convert", str(tmp_path / "a.npy"), str(out)]) == 2
    assert capsys.readouterr().err == (f"trivsel: error: the output {str(out)!r} appeared while converting: "
                                       "trivsel convert never overwrites; the copy is discarded\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npy", "b.zarr"] and not any(out.iterdir())


def test_convert_on_a_full_disk_gives_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    from trivsel.io import regions

    np.save(tmp_path / "a.npy", np.zeros((3, 3, 3)))
    monkeypatch.setattr(regions, "_write_zarr", _full_disk)
    out = tmp_path / "new" / "b.zarr"
    assert main(["convert", str(tmp_path / "a.npy"), str(out)]) == 2
    assert capsys.readouterr().err == f"trivsel: error: cannot write {str(out)!r}: [Errno 28] No space left on device\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npy"]


def test_a_signal_while_the_outputs_are_moved_lets_the_moves_finish(tmp_path, monkeypatch):
    """SIGTERM during the moves into place: they complete, and the run ends normally with the
    new results (not "interrupted; the folder is as it was", which would be false then)."""
    out = tmp_path / "d"
    assert _run("--fractions", "0.5", "--out", str(out)) == 0
    real = tio._commit

    def signalled(tmp, folder, names):
        os.kill(os.getpid(), signal.SIGTERM)
        return real(tmp, folder, names)

    monkeypatch.setattr(tio, "_commit", signalled)
    assert _run("--fractions", "0.3", "--out", str(out)) == 0
    assert _listing(out) == [tio.MANIFEST, "errors.csv", "mesh_0.3.vtu", "result.json"]


@pytest.mark.slow
def test_blocks_on_a_full_disk_give_one_line_and_resume_once_there_is_room(tmp_path):
    """On a real 1.5 MB tmpfs: a first blocked run fits; a second, larger one fills the disk in a
    job (whose log then stays empty): one line that says so, exit 1, no temporary file, the first
    run's files as they were; with room again (the tmpfs grown), the same command completes."""
    py = f"{sys.executable} -m trivsel blocks --function 4 --tol-inf 0.01 -c 2"
    p = _tiny_tmpfs_script(tmp_path, f"""
mount -o remount,size=1500k $T || exit 99
{py} --n 8 --block 4 --out $T/a >/dev/null 2>&1 || exit 98
cd $T/a && find . -type f -not -path './.snakemake/*' | sort | xargs md5sum > $T/../before.txt
{py} --n 32 --block 8 --out $T/b 2>$T/../err.txt >/dev/null
echo "rc=$?"
find $T -name '.trivsel-tmp-*'
cd $T/a && find . -type f -not -path './.snakemake/*' | sort | xargs md5sum > $T/../after.txt
mount -o remount,size=64m $T
{py} --n 32 --block 8 --out $T/b 2>$T/../err2.txt >/dev/null
echo "rerun rc=$?"
""")
    if p is None:
        pytest.skip("needs root and unshare to mount a tmpfs")
    assert "rc=1" in p.stdout, (p.stdout, p.stderr)
    err = (tmp_path / "err.txt").read_text()
    assert re.fullmatch(r"trivsel: error: (job \w+ [\d_]+|Snakemake) failed: no space left on the device of "
                        + re.escape(repr(str(tmp_path / "mnt" / "b")))
                        + r"; free some and run the same command again to resume\n", err), err
    assert ".trivsel-tmp-" not in p.stdout
    assert (tmp_path / "before.txt").read_text() == (tmp_path / "after.txt").read_text()
    assert "rerun rc=0" in p.stdout, (p.stdout, (tmp_path / "err2.txt").read_text())
