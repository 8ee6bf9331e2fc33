"""The CLI: outputs, user file formats, and one-line errors with no output for bad input."""

import json
import os
import re
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
import pyvista as pv

from trivsel.cli import main
from trivsel.data import sample_grid

ERRORS_COLUMNS = ["function", "n", "input", "n_points", "method", "values", "fraction", "n_selected", "E_rms",
                  "E_rms_interior", "E_inf", "E_inf_interior"]  # no wall times: they are in result.json


def test_reduce_function_writes_errors_meshes_and_json(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["reduce", "--function", "4", "--n", "6", "--fractions", "0.5", "0.2", "0.1", "--out", str(out)]) == 0
    df = pd.read_csv(out / "errors.csv")
    assert list(df.columns) == ERRORS_COLUMNS
    assert sorted(df.fraction) == [0.1, 0.2, 0.5]
    assert set(df.method) == {"paper"} and set(df["values"]) == {"data"}
    for f in ("0.5", "0.2", "0.1"):
        m = pv.read(out / f"mesh_{f}.vtu")
        row = df[df.fraction == float(f)].iloc[0]
        assert m.n_points == row.n_selected
        assert set(m.point_data.keys()) >= {"value", "original_index", "curvature"}
        d = sample_grid(4, 6)
        assert np.allclose(m.points, d.points[m.point_data["original_index"]])
        assert np.allclose(m.point_data["value"], d.values[m.point_data["original_index"]])
        assert m.volume == pytest.approx(8.0)
    info = json.loads((out / "result.json").read_text())
    assert info["options"]["criterion"] == "rms" and len(info["selected"]) == df.n_selected.max()
    # the wall times: per snapshot (time from the start to that count) and per stage
    snaps = info["snapshots"]
    assert [s["n_selected"] for s in snaps] == sorted(df.n_selected) and all(s["seconds"] > 0 for s in snaps)
    assert info["timings"]["total"] >= max(s["seconds"] for s in snaps)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".trivsel-")]


def test_vti_grid_takes_the_exact_path_and_keeps_spacing(tmp_path):
    d = sample_grid(4, 6)
    img = pv.ImageData(dimensions=(7, 7, 7), spacing=(2 / 6,) * 3, origin=(-1, -1, -1))
    # VTK order is x fastest; our values are C order over (i, j, k)
    img.point_data["f"] = d.values.reshape(7, 7, 7).transpose(2, 1, 0).ravel()
    path = tmp_path / "blob.vti"
    img.save(path)
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["reduce", str(path), "--method", "paper", "--fractions", "0.3", "--out", str(a)]) == 0
    assert main(["reduce", "--function", "4", "--n", "6", "--fractions", "0.3", "--out", str(b)]) == 0
    ea, eb = pd.read_csv(a / "errors.csv"), pd.read_csv(b / "errors.csv")
    # a file's run names its input; function and n are those of Table-1 runs only
    assert ea.input[0] == "blob" and ea.function.isna().all() and ea.n.isna().all()
    assert (ea.n_points == 343).all() and (eb.function == 4).all() and (eb.n == 6).all() and eb.input.isna().all()
    assert np.allclose(ea[["E_rms", "E_inf", "E_rms_interior"]], eb[["E_rms", "E_inf", "E_rms_interior"]])
    info = json.loads((a / "result.json").read_text())
    assert info["data"]["grid"] and np.allclose(info["data"]["spacing"], 2 / 6)
    # physical placement kept: shift the origin and the mesh moves with it
    img.origin = (10, 0, 0)
    img.save(path)
    c = tmp_path / "c"
    assert main(["reduce", str(path), "--fractions", "0.3", "--out", str(c)]) == 0
    assert pv.read(c / "mesh_0.3.vtu").bounds[0] == pytest.approx(10.0)


def test_csv_and_npz_scattered_input(tmp_path):
    rng = np.random.default_rng(1)
    p = rng.random((300, 3))
    v = np.exp(-((p - 0.5) ** 2).sum(1) * 4)
    pd.DataFrame({"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "value": v}).to_csv(tmp_path / "pts.csv", index=False)
    np.savez(tmp_path / "pts.npz", points=p, values=v)
    for name in ("pts.csv", "pts.npz"):
        out = tmp_path / name.replace(".", "_")
        assert main(["reduce", str(tmp_path / name), "--fractions", "0.5", "--out", str(out)]) == 0
        assert pd.read_csv(out / "errors.csv").n_selected[0] == 150
    a = pd.read_csv(tmp_path / "pts_csv" / "errors.csv")
    b = pd.read_csv(tmp_path / "pts_npz" / "errors.csv")
    assert np.allclose(a.E_rms, b.E_rms)


def _bad_files(tmp):
    rng = np.random.default_rng(2)
    p = rng.random((40, 3))
    v = p[:, 0]
    cases = {}
    df = pd.DataFrame({"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "value": v})
    nan = df.copy()
    nan.loc[5, "value"] = np.nan
    nan.to_csv(tmp / "nan.csv", index=False)
    cases["nan.csv"] = "non-finite value nan at point 5"
    dup = pd.concat([df, df.iloc[[3]]])
    dup.to_csv(tmp / "dup.csv", index=False)
    cases["dup.csv"] = "duplicate point"
    df.iloc[:3].to_csv(tmp / "few.csv", index=False)
    cases["few.csv"] = "too few points"
    flat = df.copy()
    flat["z"] = 0.0
    flat.to_csv(tmp / "flat.csv", index=False)
    cases["flat.csv"] = "coplanar"
    df.drop(columns="z").to_csv(tmp / "noz.csv", index=False)
    cases["noz.csv"] = "lacks column(s) z"
    return cases


def _run_cli(*args):
    return subprocess.run([sys.executable, "-m", "trivsel", *args], capture_output=True, text=True)


@pytest.mark.parametrize("args, message", [
    (["--function", "7"], "unknown function '7'"),
    (["--function", "1", "--fractions", "0"], "fraction 0.0 is outside (0, 1]"),
    (["--function", "1", "--fractions", "1.5"], "fraction 1.5 is outside (0, 1]"),
    (["--function", "1", "--n", "1"], "n must be an integer >= 2, got 1"),
    (["missing.vti"], "does not exist"),
    (["--function", "1", "--threads", "0"], "threads must be an integer >= 1, got 0"),
    (["--function", "1", "--method", "greedy", "--max-flips", "-2"], "max_flips must be >= 0, got -2"),
    (["--function", "1", "--swap-memory", "forever"], "argument --swap-memory: invalid choice: 'forever'"),
    (["--function", "1", "--method", "simplex"], "argument --method: invalid choice: 'simplex'"),
    (["--function", "1", "--max-flips", "two"], "argument --max-flips: invalid int value: 'two'"),
])
def test_bad_cli_arguments_one_line_error_no_output(tmp_path, args, message):
    out = tmp_path / "out"
    extra = [] if "--fractions" in args else ["--fractions", "0.5"]
    p = _run_cli("reduce", *args, *extra, "--out", str(out))
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("trivsel: error: ") and message in lines[0], p.stderr
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_bad_input_files_one_line_error_no_output(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    for name, message in _bad_files(data).items():
        out = tmp_path / ("out_" + name)
        p = _run_cli("reduce", str(data / name), "--fractions", "0.5", "--out", str(out))
        assert p.returncode == 2, (name, p.stderr)
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], (name, p.stderr)
        assert not out.exists()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["data"]


@pytest.mark.slow
def test_array_choice_required_when_ambiguous(tmp_path):
    img = pv.ImageData(dimensions=(4, 4, 4))
    img.point_data["a"] = np.arange(64.0)
    img.point_data["b"] = np.arange(64.0) ** 2
    img.save(tmp_path / "two.vti")
    p = _run_cli("reduce", str(tmp_path / "two.vti"), "--fractions", "0.5", "--out", str(tmp_path / "o"))
    assert p.returncode == 2 and "choose one with --array" in p.stderr
    p = _run_cli("reduce", str(tmp_path / "two.vti"), "--array", "c", "--fractions", "0.5", "--out", str(tmp_path / "o"))
    assert p.returncode == 2 and "array 'c' not found" in p.stderr
    assert main(["reduce", str(tmp_path / "two.vti"), "--array", "b", "--fractions", "0.5",
                 "--out", str(tmp_path / "o")]) == 0


def test_compare_command(tmp_path):
    out = tmp_path / "o"
    assert main(["reduce", "--function", "2", "--n", "4", "--fractions", "0.5", "--out", str(out)]) == 0
    golden = out / "errors.csv"
    assert main(["compare", str(golden), str(golden)]) == 0
    df = pd.read_csv(golden)
    df.loc[0, "E_rms"] *= 1.01
    df.to_csv(tmp_path / "moved.csv", index=False)
    p = _run_cli("compare", str(tmp_path / "moved.csv"), str(golden), "--rtol", "1e-3")
    assert p.returncode == 1 and "E_rms" in p.stdout


@pytest.mark.slow
def test_progress_line_on_request_and_quiet_in_logs(tmp_path):
    args = ["reduce", "--function", "4", "--n", "8", "--fractions", "0.3", "0.1"]
    p = _run_cli(*args, "--out", str(tmp_path / "a"), "--progress", "always")
    lines = [x for x in p.stderr.replace("\r", "\n").splitlines() if "points/s" in x]
    done = [int(x.split("]")[1].split("/")[0]) for x in lines]
    assert len(lines) > 10 and done == sorted(done) and done[-1] == 219  # 30 % of 729, rounded half up
    stages = [x for x in p.stderr.replace("\r", "\n").splitlines() if x.startswith("trivsel [")]
    assert [s.split("] ")[1].split(" ")[0] for s in stages] == ["curvature", "inserting"]
    quiet = _run_cli(*args, "--out", str(tmp_path / "b"))  # stderr is a pipe here, as in workflow logs
    assert "points/s" not in quiet.stderr and "trivsel [" not in quiet.stderr and quiet.returncode == 0


def test_long_stages_are_announced_for_scattered_files(tmp_path):
    rng = np.random.default_rng(0)
    p = rng.random((300, 3))
    np.savez(tmp_path / "pts.npz", points=p, values=p[:, 0] ** 2)
    for method, expected in (("paper", ["reading", "convex", "Delaunay", "curvature", "inserting"]),
                             ("auto", ["reading", "Delaunay", "decimating"])):
        r = _run_cli("reduce", str(tmp_path / "pts.npz"), "--fractions", "0.3", "--out", str(tmp_path / method),
                     "--progress", "always", "--method", method)
        stages = [x.split("] ")[1] for x in r.stderr.replace("\r", "\n").splitlines() if x.startswith("trivsel [")]
        assert [s.split(" ")[0] for s in stages] == expected, stages


def test_reduce_progress_callback_reports_current_errors():
    import trivsel

    seen = []
    r = trivsel.reduce(2, n=6, fractions=[0.4], progress=lambda *a: seen.append(a))
    assert seen[-1][0] == seen[-1][1] == r.snapshots[-1].n_selected
    assert seen[-1][2] == pytest.approx(r.snapshots[-1].errors["E_rms"], rel=1e-9)
    assert seen[-1][3] == pytest.approx(r.snapshots[-1].errors["E_inf"], rel=1e-12)


def test_errors_csv_is_identical_across_runs(tmp_path):
    """errors.csv holds no wall times, so two runs of the same reduction give the same bytes."""
    args = ["reduce", "--function", "1", "--n", "4", "--fractions", "0.5"]
    a, b = tmp_path / "a", tmp_path / "b"
    assert main([*args, "--out", str(a)]) == 0
    assert main([*args, "--out", str(b)]) == 0
    assert (a / "errors.csv").read_bytes() == (b / "errors.csv").read_bytes()
    assert "seconds" not in (a / "errors.csv").read_text().splitlines()[0]


def _run_cli_raw(*args):
    """:func:`_run_cli` with stderr as written (text mode would turn each \\r into a new line)."""
    p = subprocess.run([sys.executable, "-m", "trivsel", *args], capture_output=True)
    p.stdout, p.stderr = p.stdout.decode(), p.stderr.decode()
    return p


def _progress_lines(stderr):
    """The progress updates of a --progress always run: every piece between \\r and \\n with 'points/s'."""
    return [x for x in stderr.replace("\r", "\n").splitlines() if "points/s" in x]


def _bars(lines):
    return [x.split("]")[0].lstrip("[") for x in lines]


def test_decimate_progress_counts_down_on_one_line_and_ends_it(tmp_path):
    """decimate goes down from the full grid: 'N points, down to T', the count falling, the bar
    filling to its width and never beyond, all on one line that ends before the next output."""
    p = _run_cli_raw("reduce", "--function", "4", "--n", "8", "--method", "decimate", "--fractions", "0.3",
                     "0.1", "--out", str(tmp_path / "o"), "--progress", "always")
    assert p.returncode == 0, p.stderr
    lines = _progress_lines(p.stderr)
    counts = [int(x.split("] ")[1].split(" points")[0]) for x in lines]
    assert all(", down to 73" in x for x in lines), lines  # 10 % of 729, rounded half up
    assert counts[0] == 729 and counts[-1] == 73 and counts == sorted(counts, reverse=True), counts
    bars = _bars(lines)
    assert all(len(b) == 24 for b in bars) and bars[0].strip() == "" and bars[-1] == "#" * 24
    assert not [x for x in lines if "/73 points" in x]
    progress = p.stderr[p.stderr.index("\r["):]
    line, _, after = progress.partition("\n")  # the whole progress line, then the next output
    assert line.count("\r") == len(lines) and "points/s" not in after
    assert after.startswith("wrote "), after


def test_a_run_stopped_by_a_tolerance_ends_its_line_and_names_the_fraction_it_missed(tmp_path):
    out = tmp_path / "o"
    p = _run_cli_raw("reduce", "--function", "4", "--n", "8", "--fractions", "0.5", "0.1", "--tol-rms", "0.06",
                     "--out", str(out), "--progress", "always")
    assert p.returncode == 0, p.stderr
    lines = _progress_lines(p.stderr)
    stopped = int(lines[-1].split("] ")[1].split("/")[0])
    assert stopped < 365 and lines[-1].split("] ")[1].startswith(f"{stopped}/365 points")
    note = (f"fraction 0.5 (365 points) not reached: the run stopped at {stopped} points "
            "(E_RMS <= tol_rms was met)")
    after = p.stderr.split(lines[-1], 1)[1]
    assert after.lstrip(" ").startswith(f"\ntrivsel: warning: {note}\n"), after  # the progress line ended first
    assert json.loads((out / "result.json").read_text())["notes"] == [note]
    quiet = _run_cli("reduce", "--function", "4", "--n", "8", "--fractions", "0.5", "0.1", "--tol-rms", "0.06",
                     "--out", str(tmp_path / "q"))  # no progress: the warning still shows
    assert f"trivsel: warning: {note}\n" in quiet.stderr and "points/s" not in quiet.stderr


def test_decimate_stopped_by_a_tolerance_says_which_fraction_it_did_not_reach(tmp_path, caplog):
    import trivsel

    out = tmp_path / "o"
    p = _run_cli("reduce", "--function", "4", "--n", "8", "--method", "decimate", "--fractions", "0.5", "0.1",
                 "--tol-inf", "0.05", "--out", str(out))
    assert p.returncode == 0, p.stderr
    info = json.loads((out / "result.json").read_text())
    stopped = min(s["n_selected"] for s in info["snapshots"])
    assert stopped > 73
    note = (f"fraction 0.1 (73 points) not reached: the run stopped at {stopped} points (no collapse was left "
            "that keeps every residual within tol_inf)")
    # the first line, after the one-time compile's notice on a machine that has not compiled yet
    lines = [x for x in p.stderr.splitlines() if not x.startswith("trivsel: compiling")]
    assert info["notes"] == [note] and lines[0] == f"trivsel: warning: {note}", p.stderr
    with caplog.at_level("WARNING", logger="trivsel"):
        r = trivsel.reduce(4, n=8, method="decimate", fractions=[0.5, 0.1], tol_inf=0.05)
    said = [rec.getMessage() for rec in caplog.records if not rec.getMessage().startswith("compiling")]
    assert r.notes == [note] and said == [f"warning: {note}"]
    assert trivsel.reduce(4, n=8, method="decimate", fractions=[0.5, 0.1]).notes == []


def test_tolerance_help_is_right_for_both_directions():
    from trivsel.cli import build_parser

    reduce_parser = build_parser()._subparsers._group_actions[0].choices["reduce"]
    helps = {a.dest: a.help for a in reduce_parser._actions}
    for name, err in (("tol_rms", "E_RMS"), ("tol_inf", "E_inf")):
        assert f"paper and greedy stop inserting once {err} <= this" in helps[name]
        assert f"decimate stops removing before {err} would exceed it" in helps[name]


def test_compile_says_what_it_did(capsys):
    """The first call builds the kernels or loads them (another test, in this process or
    another worker, may have built them first); the second loads them and says so."""
    assert main(["compile", "--method", "decimate"]) == 0
    out = capsys.readouterr().out
    assert re.match(r"(compiled the decimate kernels in|the decimate kernels were compiled already: loaded in|"
                    r"the decimate kernels were compiled by another process: waited for them and loaded them in) "
                    r"[\d.]+ s\n$", out), out
    assert main(["compile", "--method", "decimate"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("the decimate kernels were compiled already: loaded in "), out
    assert "0 kernel" not in out


@pytest.mark.skipif(os.name != "posix", reason="the build lock is flock(2)")
def test_compile_waits_for_another_process_that_compiles_the_same_kernels(tmp_path, monkeypatch, capsys):
    """`trivsel compile` started while another process builds the same module (its lock held)
    says that it waits, then loads that process's module and says so, with no compile of its own."""
    import fcntl
    import shutil
    import threading
    import time

    from trivsel import aot
    from trivsel import decimation as dm

    assert main(["compile", "--method", "decimate"]) == 0  # a built module, to stand for the other's
    capsys.readouterr()
    g = np.indices((3, 3, 3)).reshape(3, -1).T
    S = dm.new_state(g, (3, 3, 3), np.arange(27.0) % 5, lazy=True)  # compile_kernels's layout
    name, built, _ = aot._paths(dm.KERNELS, dm.KERNEL_SOURCES, S)
    monkeypatch.setattr(aot, "cache_dir", lambda: tmp_path / "aot")
    monkeypatch.setattr(aot, "_loaded", {})
    _, path, _ = aot._paths(dm.KERNELS, dm.KERNEL_SOURCES, S)
    path.parent.mkdir()
    fd = os.open(path.with_name(name + ".lock"), os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)  # the other process, building
    code = []
    waiter = threading.Thread(target=lambda: code.append(main(["compile", "--method", "decimate"])))
    waiter.start()
    err = ""
    for _ in range(1000):
        err += capsys.readouterr().err
        if "waiting" in err:
            break
        time.sleep(0.01)
    assert err == "trivsel: waiting for another process that is compiling the decimation kernels\n", err
    shutil.copyfile(built, path)  # its module, then its lock released
    os.close(fd)
    waiter.join(60)
    out = capsys.readouterr()
    assert code == [0] and out.out.startswith("the decimate kernels were compiled by another process: waited "
                                              "for them and loaded them in "), out
    assert "compiling" not in out.err
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]


def test_the_one_time_compile_is_announced_when_stderr_is_not_a_terminal(tmp_path, monkeypatch, capsys):
    """A reduction that has to build its kernels says so first, on stderr, with the time it takes; one
    that finds them built says nothing.  (The build itself is replaced by a quick failure here, which
    falls back to numba's kernels.)"""
    from trivsel import aot

    args = ["reduce", "--function", "4", "--n", "4", "--method", "decimate", "--fractions", "0.5"]
    assert main(["compile", "--method", "decimate"]) == 0  # built here, unless another test built them
    capsys.readouterr()
    assert main([*args, "--out", str(tmp_path / "warm")]) == 0
    assert "compiling" not in capsys.readouterr().err  # built: nothing to announce

    def no_build(module, state, path, variant=None):
        raise OSError("no C compiler here")

    monkeypatch.setattr(aot, "cache_dir", lambda: tmp_path / "aot")
    monkeypatch.setattr(aot, "build", no_build)
    assert main([*args, "--out", str(tmp_path / "cold")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "trivsel: compiling the decimation kernels once for this machine (about 1-2 min; later runs " \
                     "load them)", err
    assert err[1].startswith("trivsel: could not compile trivsel.decimation.collapse ahead of time"), err
