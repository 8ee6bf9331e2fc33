"""``trivsel blocks --method decimate``: the stages of ``trivsel reduce --block`` as Snakemake
jobs (:mod:`trivsel.blocks.decimate`) give the same mesh as one process, with the count, the
errors and the fitted values of that mesh, as a conforming tetrahedralisation in pieces."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from conftest import made_once
from trivsel.blocks import check_tetrahedra
from trivsel.cli import main
from trivsel.data import sample_grid
from trivsel.decimation.blocked import decimate_in_blocks, point_weights, quality_note

pytest.importorskip("snakemake")


def _read(path):
    import pyvista as pv

    m = pv.read(path)
    ids = np.asarray(m.point_data["original_index"])
    return m, ids, ids[np.asarray(m.cells).reshape(-1, 5)[:, 1:]]


def _same_tets(a, b):
    return np.array_equal(np.unique(np.sort(a, axis=1), axis=0), np.unique(np.sort(b, axis=1), axis=0))


# The run of the tests that rerun some of its jobs in process: f4, n 40, blocks of 16, to a count
# of 3000 with fitted values, its temporary files kept.  It is made once for the whole test run (whichever worker
# asks first; conftest.made_once); each test gets a copy of its folder (the jobs name their
# files relative to it), so that a job one test reruns or a file it changes reaches no other test.
_COUNTED_RUN = ["blocks", "--function", "4", "--n", "40", "--block", "16", "--method", "decimate", "--count", "3000",
                "--values", "data", "fit"]


@pytest.fixture(scope="module")
def _counted_run(tmp_path_factory):
    def make(folder):
        assert main(_COUNTED_RUN + ["--out", str(folder / "run"), "-c", "2", "--", "--notemp"]) == 0

    return made_once(tmp_path_factory, "counted", make) / "run"


@pytest.fixture
def counted_run(_counted_run, tmp_path):
    """A copy of the module's counted run, in ``tmp_path / "run"``."""
    return Path(shutil.copytree(_counted_run, tmp_path / "run", symlinks=True))


def test_the_jobs_give_the_mesh_of_one_process_with_its_errors(tmp_path, capsys):
    import pyvista as pv

    n, block, count = 40, 16, 3000
    vol = sample_grid(4, n).values.reshape((n + 1,) * 3)
    out = tmp_path / "run"
    argv = ["blocks", "--function", "4", "--n", str(n), "--block", str(block), "--method", "decimate", "--count",
            str(count), "--out", str(out), "-c", "2"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "3000 of 68921 points" in err
    note = quality_note(68921, count, block)  # blocks of 16, 4.35 % of the points
    assert f"trivsel blocks: note: {note}\n" in err
    ref = decimate_in_blocks(vol, block, count=count)
    m, ids, tets = _read(out / "mesh.vtu")
    assert np.array_equal(np.sort(ids), ref["vertices"]) and _same_tets(tets, ref["tets"])
    check_tetrahedra(vol.shape, tets)
    assert np.allclose(m.point_data["value"], vol.reshape(-1)[ids])
    # the pieces hold every tetrahedron once
    whole = pv.read(out / "mesh.pvtu")
    assert whole.n_cells == len(tets) and len(list((out / "pieces").glob("*.vtu"))) == 27
    verts, w = point_weights(vol.shape, ref["tets"], ref["ptet"])
    f = vol.reshape(-1)
    r = f - np.einsum("ij,ij->i", w, f[verts])
    s = json.loads((out / "summary.json").read_text())
    assert s["vertices"] == count and s["tetrahedra"] == len(tets) and s["stopped"] == "the count was reached"
    assert s["notes"] == [note]
    assert s["E_rms"] == pytest.approx(np.sqrt(np.mean(r**2)), rel=1e-12)
    assert s["E_inf"] == pytest.approx(np.abs(r).max(), rel=1e-12)
    # a rerun has nothing to do; another count in the same folder is refused
    assert main(argv) == 0
    assert "nothing to run" in capsys.readouterr().err
    assert main(argv[:-5] + ["2000", "--out", str(out), "-c", "2"]) == 2
    assert "another configuration (count" in capsys.readouterr().err


def test_a_nifti_file_fraction_and_fitted_values_match_reduce_with_block(tmp_path, capsys):
    """A real-looking input (an anisotropic NIfTI volume, read by region): the blocks' mesh is
    ``trivsel reduce FILE --block B``'s, with the same points, values and fitted values."""
    import nibabel as nib

    rng = np.random.default_rng(5)
    g = np.stack(np.indices((29, 26, 23)), axis=-1) / 20.0
    vol = np.sin(3 * g[..., 0]) * np.cos(2 * g[..., 1]) + (g[..., 2] > 0.6) + 0.05 * rng.standard_normal(g.shape[:3])
    path = tmp_path / "scan.nii.gz"
    nib.save(nib.Nifti1Image(vol.astype(np.float32), np.diag([0.9, 1.1, 2.5, 1.0])), path)
    assert main(["reduce", str(path), "--method", "decimate", "--block", "8", "--fractions", "0.05", "--values",
                 "data", "fit", "--out", str(tmp_path / "one")]) == 0
    out = tmp_path / "run"
    assert main(["blocks", str(path), "--block", "8", "--method", "decimate", "--fraction", "0.05", "--values", "data",
                 "fit", "--out", str(out), "-c", "2"]) == 0
    err = capsys.readouterr().err
    (one,) = (tmp_path / "one").glob("mesh_*.vtu")
    m1, ids1, tets1 = _read(one)
    m2, ids2, tets2 = _read(out / "mesh.vtu")
    assert np.array_equal(np.sort(ids1), ids2) and _same_tets(tets1, tets2)
    at = np.argsort(ids1)
    assert np.array_equal(np.asarray(m1.points)[at], np.asarray(m2.points))
    assert np.array_equal(np.asarray(m1.point_data["value"])[at], np.asarray(m2.point_data["value"]))
    assert np.allclose(np.asarray(m1.point_data["fitted_value"])[at], m2.point_data["fitted_value"], atol=1e-9)
    s = json.loads((out / "summary.json").read_text())
    errors = {row.split(",")[5]: row.split(",") for row in (tmp_path / "one" / "errors.csv").read_text().split()[1:]}
    assert s["E_rms"] == pytest.approx(float(errors["data"][8]), rel=1e-9)
    assert s["fit"]["E_rms"] == pytest.approx(float(errors["fit"][8]), rel=1e-6)
    assert s["fit"]["E_rms"] < s["E_rms"]
    assert f"fitted values: E_rms {s['fit']['E_rms']:.4g}" in err


@pytest.mark.parametrize("stop, tol, error, why", [
    ("tol_inf", 0.02, "E_inf", "no collapse was left that keeps every residual within tol_inf"),
    ("tol_rms", 0.004, "E_rms", "the next collapses would raise E_RMS above tol_rms"),
])
def test_a_tolerance_stop_holds_across_the_seams(tmp_path, stop, tol, error, why):
    n, block = 24, 8
    vol = sample_grid(4, n).values.reshape((n + 1,) * 3)
    out = tmp_path / "run"
    assert main(["blocks", "--function", "4", "--n", str(n), "--block", str(block), "--method", "decimate",
                 f"--{stop.replace('_', '-')}", str(tol), "--no-merged", "--out", str(out), "-c", "2"]) == 0
    ref = decimate_in_blocks(vol, block, **{stop: tol})
    import pyvista as pv

    whole = pv.read(out / "mesh.pvtu")
    ids = np.asarray(whole.point_data["original_index"])
    tets = ids[np.asarray(whole.cells).reshape(-1, 5)[:, 1:]]
    assert _same_tets(tets, ref["tets"]) and not (out / "mesh.vtu").exists()
    s = json.loads((out / "summary.json").read_text())
    assert s["vertices"] == len(ref["vertices"]) and s[error] <= tol and s[stop] == tol
    assert s["stopped"] == why


def test_an_e_inf_tolerance_holds_to_the_bit_and_a_count_it_stops_short_of_is_said(tmp_path, capsys):
    """Values in steps of the tolerance, so that the kernels keep residuals at the tolerance
    itself: the final errors are computed as the kernels computed those residuals, so E_inf
    is at most tol_inf to the bit, in one process (``reduce --block``) and as jobs; and the
    jobs say that the count was not reached, and why, as ``reduce`` does."""
    g = np.indices((9, 9, 9)).astype(float)
    npy = tmp_path / "g9.npy"
    np.save(npy, np.sin(g[0] / 3) + g[1] * g[2] / 20)
    assert main(["reduce", str(npy), "--method", "decimate", "--block", "4", "--tol-inf", "0.05", "--out",
                 str(tmp_path / "one")]) == 0
    assert "tolerance was not met" not in capsys.readouterr().err
    import pandas as pd

    one = pd.read_csv(tmp_path / "one" / "errors.csv")
    assert one["E_inf"].max() <= 0.05
    assert main(["blocks", str(npy), "--method", "decimate", "--block", "4", "--count", "100", "--tol-inf", "0.05",
                 "--out", str(tmp_path / "jobs"), "-c", "2"]) == 0
    s = json.loads((tmp_path / "jobs" / "summary.json").read_text())
    assert s["E_inf"] <= 0.05 and s["vertices"] > 100
    assert f"trivsel blocks: warning: count 100 not reached: the run stopped at {s['vertices']} points (no collapse " \
           "was left that keeps every residual within tol_inf)" in capsys.readouterr().err.splitlines()


def test_a_run_stopped_half_way_resumes_to_the_same_mesh(tmp_path, capsys):
    """A run that Snakemake stops after the third pass's step (its temporary files half used)
    ends without results; the same command again completes it, to the mesh of one process."""
    n, block, count = 24, 8, 900
    vol = sample_grid(4, n).values.reshape((n + 1,) * 3)
    out = tmp_path / "run"
    argv = ["blocks", "--function", "4", "--n", str(n), "--block", str(block), "--method", "decimate", "--count",
            str(count), "--out", str(out), "-c", "2"]
    assert main(argv + ["--", "--until", "step_3"]) == 1
    assert "ended without writing summary.json" in capsys.readouterr().err
    assert (out / "passes" / "3" / "state.npz").exists() and not (out / "summary.json").exists()
    assert main(argv) == 0
    _, ids, tets = _read(out / "mesh.vtu")
    ref = decimate_in_blocks(vol, block, count=count)
    assert np.array_equal(np.sort(ids), ref["vertices"]) and _same_tets(tets, ref["tets"])
    assert not list((out / "passes").rglob("*.npz"))  # the temporary files are gone once read


def test_the_plan_and_the_job_memory_come_from_the_configuration(tmp_path, capfd):
    from trivsel.blocks import decimate as D

    full = {"block": 64, "values": ["data", "fit"], "plan": {"shape": [197, 233, 189]}}
    plan = D.plan_decimation((197, 233, 189), 64)
    assert plan.counts == (3, 4, 3)
    st = D.Stages({"block": 64, "fraction": 0.05, "plan": plan.to_dict()}, plan)
    assert [k for k, _ in st.passes] == ["seams"] * 3 + ["quota"] * 4 + ["rest"] * 4 and st.target() == 433764
    assert D.Stages({"block": 64, "tol_inf": 1.0, "plan": plan.to_dict()}, plan).passes == st.passes[:3]
    assert D.Stages({"block": 64, "tol_rms": 1.0, "plan": plan.to_dict()}, plan).passes == st.passes  # a budget
    # a block job holds one block's decimation; a region job one region's (2 x 2 x 2 blocks), as dense
    # as the mesh after the blocks allows (every point a vertex without a count)
    five = {**full, "fraction": 0.05}
    mb = {k: D.job_resources(five, plan, k)[0] for k in ("costs", "rcosts")}
    assert mb["costs"] < mb["rcosts"] < 2600 and mb["rcosts"] > 2000
    assert D.job_resources(full, plan, "rcosts")[0] > 2 * mb["rcosts"]
    assert D.job_resources({**five, "block": 32}, D.plan_decimation(plan.shape, 32), "rcosts")[0] < 800
    # f4 at 129^3 in blocks of 32: the largest rcosts jobs peaked at 148 MB (5 %) and 734 MB (50 %, its
    # region all vertices: 261,766 points, 1,499,160 tetrahedra; docs/notes)
    p129 = D.plan_decimation((129,) * 3, 32)
    region = {f: D.job_resources({**full, "block": 32, "fraction": f, "plan": p129.to_dict()}, p129, "rcosts")[0]
              for f in (0.05, 0.5)}
    assert 148 < region[0.05] < region[0.5] and 1.3 * 734 < region[0.5] < 2 * 734
    # the whole-grid jobs ask for the mesh the stop allows: f4 at 129^3 in blocks of 32 with fitted values
    # peaked at 175 and 551 MB (step) at 5 % and 50 % (docs/notes)
    ask = {f: {k: D.job_resources({**full, "fraction": f, "plan": p129.to_dict()}, p129, k)[0]
               for k in ("step", "tiles", "fit", "pieces", "finish")} for f in (0.05, 0.5)}
    assert 175 < ask[0.05]["step"] < ask[0.5]["step"] and 551 < ask[0.5]["step"] < 2 * 551 + 400
    assert all(ask[0.05][k] < ask[0.5][k] for k in ask[0.05])
    # the last jobs, f4 in blocks of 32 with fitted values, each run alone under /usr/bin/time, peaked at
    # 212 (tiles), 126 (fit), 60 (pieces) and 191 MB (finish) at 129^3 to 5 %, and at 503, 339, 99 and
    # 284 MB at 97^3 to 50 % (docs/notes)
    for (n, f), peak in {(128, 0.05): {"tiles": 212, "fit": 126, "pieces": 60, "finish": 191},
                         (96, 0.5): {"tiles": 503, "fit": 339, "pieces": 99, "finish": 284}}.items():
        pn = D.plan_decimation((n + 1,) * 3, 32)
        got = {k: D.job_resources({**full, "block": 32, "fraction": f, "plan": pn.to_dict()}, pn, k)[0] for k in peak}
        assert all(peak[k] < got[k] < 3 * peak[k] + 400 for k in peak), (n, got)
    alone = {k: D.job_resources({**full, "tol_rms": 1.0, "plan": p129.to_dict()}, p129, k)[0] for k in ask[0.5]}
    assert all(alone[k] >= ask[0.5][k] for k in alone)  # a tolerance alone: the whole grid's mesh
    # a dry run lists the jobs and writes nothing
    assert main(["blocks", "--function", "4", "--n", "16", "--block", "8", "--method", "decimate", "--count", "100",
                 "-n", "--out", str(tmp_path / "dry")]) == 0
    assert "step_6" in capfd.readouterr().out and not (tmp_path / "dry").exists()


def test_a_slab_job_asks_for_three_times_the_longest_it_took():
    """On SLURM a job ends at its runtime request.  Pass 1 on a slab of f4 at 257^3 in blocks of
    64 (4.2 M points) took up to 249 s on a loaded machine and about 140 s on a quiet one; a
    slab of regions of f4 at 129^3 in blocks of 32 to 50 % up to 41 s (docs/notes).  Their
    requests (and the mesh and apply jobs' after them) are at least three times that, and grow
    with the slab, not the grid."""
    from trivsel.blocks import decimate as D

    def minutes(n, block, kind, fraction=0.05):
        plan = D.plan_decimation((n,) * 3, block)
        return D.job_resources({"block": block, "fraction": fraction, "plan": plan.to_dict()}, plan, kind)[1]

    assert minutes(257, 64, "costs") * 60 >= 3 * 249 and minutes(257, 64, "mesh") == minutes(257, 64, "costs")
    assert minutes(129, 32, "rcosts", 0.5) * 60 >= 3 * 41 and minutes(129, 32, "apply") == minutes(129, 32, "rcosts")
    for kind in ("costs", "rcosts"):  # 64x the points, 16x a slab's
        assert minutes(1025, 64, kind) < 20 * minutes(257, 64, kind)


def test_the_memory_check_weighs_every_kind_of_job_of_the_run(tmp_path, capsys, monkeypatch):
    """A local run is refused when any of its jobs needs more than is available, ``quota`` (a
    region's decimation and a sample of the regions' costs) and ``cut`` as well as the others; the block
    size it names runs every job within what is available."""
    import trivsel.resources as res
    from trivsel.blocks import decimate as D
    from trivsel.exceptions import InputError

    shape = (197, 233, 189)
    full = {"block": 64, "fraction": 0.05, "values": ["data", "fit"], "plan": D.plan_decimation(shape, 64).to_dict()}
    st = D.Stages(full, D.plan_decimation(shape, 64))
    assert sorted(st.job_kinds()) == sorted(["kernels", "costs", "cut", "mesh", "step", "rcosts", "quota", "apply",
                                             "tiles", "fit", "pieces", "finish"])
    mb = {k: D.job_resources(full, st.plan, k)[0] for k in st.job_kinds()}
    assert max(mb, key=mb.get) == "quota"
    avail = (max(v for k, v in mb.items() if k != "quota") + mb["quota"]) // 2 * 2**20  # all but quota fit
    monkeypatch.setattr(res, "available_bytes", lambda: avail)
    with pytest.raises(InputError, match=r"^a quota job of decimate in blocks of 64 needs about 2.4\d* GiB, more than "
                                         r"the 2.4\d* GiB available: use --block 48$"):
        D.check_job_memory(full)
    p48 = D.plan_decimation(shape, 48)
    cfg48 = {**full, "block": 48, "plan": p48.to_dict()}
    assert all(D.job_resources(cfg48, p48, k)[0] * 2**20 <= avail for k in D.Stages(cfg48, p48).job_kinds())
    D.check_job_memory(cfg48)
    # a tolerance alone has no cut or quota: its largest job keeps the whole grid's mesh by tile, which no
    # block size helps
    tol = {**full, "fraction": None, "tol_inf": 1.0}
    assert "quota" not in D.Stages(tol, st.plan).job_kinds()
    monkeypatch.setattr(res, "available_bytes", lambda: 4 * 2**30)
    with pytest.raises(InputError, match=r"^a tiles job .* run it on a larger machine or a cluster$"):
        D.check_job_memory(tol)  # the region jobs are larger here, but smaller blocks bring them down
    monkeypatch.setattr(res, "available_bytes", lambda: 6.5 * 2**30)
    with pytest.raises(InputError, match=r"^an apply job of decimate in blocks of 64 needs about 6.\d+ GiB, more than "
                                         r"the 6.5 GiB available: use --block 48$"):
        D.check_job_memory(tol)
    # from the command line: one line, exit 2, no run folder
    monkeypatch.setattr(res, "available_bytes", lambda: 64 * 2**20)
    out = tmp_path / "run"
    assert main(["blocks", "--function", "4", "--n", "40", "--block", "16", "--method", "decimate", "--count", "3000",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "job of decimate in blocks of 16 needs about" in err and not out.exists(), err


def test_files_of_a_run_begun_before_errors_were_recorded_read_as_no_error_spent(tmp_path):
    """A counted run begun by a version that recorded no squared errors, resumed by this one:
    its costs, ``tau.json`` and ``quota.npz`` have no errors, and read as none spent (that run
    had no budget), so the cut and the steps go on."""
    from trivsel.blocks import decimate as D

    plan = D.plan_decimation((17, 17, 17), 8)
    st = D.Stages({"block": 8, "count": 100, "plan": plan.to_dict()}, plan)
    (tmp_path / "costs").mkdir()
    for slab in st.slabs:
        np.savez(tmp_path / "costs" / f"{slab}.npz",
                 **{k: v for i, _, _ in st.blocks_of(slab)
                    for k, v in ((f"runmax_{i}", np.arange(5.0)), (f"inner_{i}", np.int64(200)))})
    D._cut(tmp_path, st)
    tau = json.loads((tmp_path / "tau.json").read_text())
    assert tau["sse"] == 0.0 and D._spent(tmp_path, st, 0) == 0.0
    (tmp_path / "tau.json").write_text(json.dumps({k: v for k, v in tau.items() if k != "sse"}))
    (tmp_path / "passes" / "0").mkdir(parents=True)
    np.savez(tmp_path / "passes" / "0" / "quota.npz", region=np.zeros(0, np.int64), quota=np.zeros(0, np.int64))
    assert D._spent(tmp_path, st, 0) == 0.0 and D._spent(tmp_path, st, 1) == 0.0


def test_blocks_recorded_short_of_the_cut_are_recorded_again_by_the_cut_job(counted_run, monkeypatch):
    """The costs jobs record each block down to a floor under its share of the count; where the
    cut compares a cost past a record's end, the cut job records that block again to its end
    (``costs/whole.npz``) and the mesh jobs replay it: the threshold and the blocks' meshes of
    whole records.  Here the floor is raised to the whole share, so that blocks are recorded
    again, and the stages run in this process."""
    from trivsel.blocks import decimate as D

    out = counted_run
    tau = json.loads((out / "tau.json").read_text())
    meshes = {p.name: D._load(p) for p in (out / "meshes").glob("*.npz")}
    (out / "tau.json").unlink()
    monkeypatch.setattr(D.B, "RECORD_FLOOR", 1.0)
    monkeypatch.setattr(D.B, "RECORD_TAIL", 0.0)
    for kind in ("costs", "cut", "mesh"):
        for item in ([str(s) for s in range(3)] if kind != "cut" else [""]):
            D.run_job(out, kind, item)
    again = json.loads((out / "tau.json").read_text())
    assert again.pop("recorded_again") > 0 and len(D._load(out / "costs" / "whole.npz")) > 0
    tau.pop("recorded_again")
    assert again == tau
    for name, z in meshes.items():
        again = D._load(out / "meshes" / name)
        assert z.keys() == again.keys() and all(np.array_equal(z[k], again[k]) for k in z)


def test_the_cut_job_reads_the_blocks_records_one_at_a_time(counted_run, tmp_path, capsys, monkeypatch):
    """The cut job holds a sample of the blocks' recorded costs, not every record: with the
    sample cut to a few runs a block it reads the costs files in several streams, one block's
    arrays at a time, and writes the same ``tau.json``, byte for byte (a count and a budget)."""
    from trivsel.blocks import decimate as D

    for stop in (["--count", "3000"], ["--tol-rms", "0.002"]):
        out = counted_run if stop[0] == "--count" else tmp_path / stop[0][2:]
        if stop[0] != "--count":
            assert main(["blocks", "--function", "4", "--n", "40", "--block", "16", "--method", "decimate", *stop,
                         "--out", str(out), "-c", "2", "--", "--notemp"]) == 0
            capsys.readouterr()
        before = (out / "tau.json").read_bytes()
        reads, samples = _with_small_samples(monkeypatch, out, "cut")
        assert (out / "tau.json").read_bytes() == before
        streams = reads.count("0.npz")
        assert streams > 4 and all(reads.count(f"{s}.npz") == streams for s in range(3))
        blocks = len(D.Stages(*D.read_config(out)).plan.blocks())
        assert all(n <= 2 * 4 * blocks for n in samples)


def _with_small_samples(monkeypatch, out, kind, item=""):
    """Job ``kind`` (``item``) of run ``out`` run with the streamed cuts' sample cut to one run
    (so at least 4 a block or region) and 2 queries a stream: the names of the costs files it
    opened (an entry an opening) and the size of each sample its streams kept."""
    from trivsel.blocks import decimate as D
    from trivsel.decimation import streamcut

    reads, held = [], []
    load, sample = np.load, streamcut._stream_sample

    def spy(path, *a, **k):  # every costs file opened
        z = load(path, *a, **k)
        if Path(path).parent.name == "costs":
            reads.append(Path(path).name)
        return z

    with monkeypatch.context() as m:
        m.setattr(D.np, "load", spy)
        m.setattr(streamcut, "RUNS", 1)
        m.setattr(streamcut, "QUERIES", 2)
        m.setattr(streamcut, "_stream_sample", lambda *a: held.append(out_ := sample(*a)) or out_)
        D.run_job(out, kind, item)
    return reads, [len(cat["cost"]) for h, _ in held for cat, *_ in h]


def test_a_killed_cut_or_quota_jobs_leftovers_do_not_stop_it_again(counted_run):
    """The cut and quota jobs record blocks and regions again each into a file of its own, in a
    folder of their own that they remove at the end.  A job killed while writing one leaves its
    temporary file there; run again, the job ends as it would have, and leaves no such folder."""
    from trivsel.blocks import decimate as D

    out = counted_run
    st = D.Stages(*D.read_config(out))
    p = [kind for kind, _ in st.passes].index("quota")
    folders = {"cut": out / "costs" / "again", "quota": out / "passes" / str(p) / "again"}
    outputs = {"cut": out / "tau.json", "quota": out / "passes" / str(p) / "quota.npz"}
    for kind, folder in folders.items():
        before = D._load(outputs[kind]) if kind == "quota" else outputs[kind].read_bytes()
        folder.mkdir()
        (folder / ".trivsel-tmp-3-x1y2.npz").write_bytes(b"PK")  # half written
        (folder / "3.npz").write_bytes(b"")  # written by the killed job, never read by this one
        D.run_job(out, kind, "" if kind == "cut" else str(p))
        assert not folder.exists()
        if kind == "quota":
            now = D._load(outputs[kind])
            assert all(np.array_equal(before[k], now[k], equal_nan=True) for k in before)
        else:
            assert outputs[kind].read_bytes() == before


def _quota_pass_run(out):
    """The counted run ``out`` (kept with its files): the jobs' module, the run's folder, its
    stages, the first quota pass and that pass's folder."""
    from trivsel.blocks import decimate as D
    from trivsel.blocks import read_config

    st = D.Stages(*read_config(out))
    p = [kind for kind, _ in st.passes].index("quota")
    return D, out, st, p, out / "passes" / str(p)


def test_regions_recorded_short_of_the_quota_limit_are_recorded_again_by_the_quota_job(counted_run, monkeypatch):
    """The first quota pass records each region to its share of the surplus and derives the cost
    limit from that; where the limit lies at or past a record's end, the quota job records that
    region again to twice its share (``again.npz``) and the apply jobs use it: the limit, the
    quotas and the meshes of whole records.  Here the first records stop at 16 collapses, so that
    regions are recorded again, and the pass's jobs run again in this process."""
    D, out, st, p, folder = _quota_pass_run(counted_run)
    assert D._load(folder / "plan.npz")["ran"]
    names = ["quota.npz"] + [f"out/{s}.npz" for s in st.region_slabs(p)]
    before = {name: D._load(folder / name) for name in names}
    monkeypatch.setattr(D.B, "FIRST_QUOTA_RECORD", 0)
    D.run_job(out, "step", str(p))
    for kind in ("rcosts", "quota", "apply"):
        for item in ([f"{p}_{s}" for s in st.region_slabs(p)] if kind != "quota" else [str(p)]):
            D.run_job(out, kind, item)
    plan = D._load(folder / "plan.npz")
    assert (plan["caps"] < plan["whole_caps"]).any()
    again = D._load(folder / "again.npz")
    assert any(k.startswith("runmax_") for k in again)
    for name, z in before.items():
        now = D._load(folder / name)
        assert z.keys() == now.keys() and all(np.array_equal(z[k], now[k], equal_nan=True) for k in z), name


def test_region_and_quota_jobs_read_only_their_part_of_the_pass(counted_run, monkeypatch):
    """A region job's memory is its regions': of the pass's plan it reads the regions and the
    pass's figures, not the whole mesh's layout (``order``: every tetrahedron of the pass's
    regions; ``left``: a flag per point), and the quota job reads the regions' costs, not their
    meshes.  Run again while every .npz member read is recorded, the jobs write the same files."""
    D, out, st, p, folder = _quota_pass_run(counted_run)
    assert {"order", "left"} <= set(D._load(folder / "plan.npz"))
    names = ["quota.npz", "again.npz"] + [f"{d}/{s}.npz" for d in ("costs", "out") for s in st.region_slabs(p)]
    before = {name: D._load(folder / name) for name in names}
    read, job = [], [None]
    getitem = np.lib.npyio.NpzFile.__getitem__

    def recorded(self, key):
        read.append((job[0], os.path.relpath(self.fid.name, folder), key))
        return getitem(self, key)

    monkeypatch.setattr(np.lib.npyio.NpzFile, "__getitem__", recorded)
    for kind in ("rcosts", "quota", "apply"):
        job[0] = kind
        for item in ([f"{p}_{s}" for s in st.region_slabs(p)] if kind != "quota" else [str(p)]):
            D.run_job(out, kind, item)
    monkeypatch.undo()
    plan = {(kind, key) for kind, f, key in read if f == "plan.npz"}
    assert {key for _, key in plan} <= set(D.PLAN_OF_REGIONS) and ("rcosts", "caps") in plan
    quota = [key for kind, f, key in read if kind == "quota" and f.startswith("costs")]
    assert {key.split("_")[0] for key in quota} == {"runmax", "sse"}
    for name, z in before.items():
        now = D._load(folder / name)
        assert z.keys() == now.keys() and all(np.array_equal(z[k], now[k], equal_nan=True) for k in z), name


def test_the_quota_job_reads_the_regions_records_one_at_a_time(counted_run, monkeypatch):
    """The quota job holds a sample of the regions' recorded costs, not every record: with the
    sample cut to a few runs a region, every quota job of the counted run (the first derives
    the quota passes' limit, the others cut at it) reads its pass's costs files in several
    streams, one region's arrays at a time, and writes the same quotas, squared error and limit,
    also where it records regions again (``again.npz``, the first records cut to 16 collapses)."""
    D, out, st, first, _ = _quota_pass_run(counted_run)
    passes = [p for p, (kind, _) in enumerate(st.passes)
              if kind == "quota" and D._load(out / "passes" / str(p) / "plan.npz")["ran"]]
    assert first in passes and len(passes) > 1
    monkeypatch.setattr(D.B, "FIRST_QUOTA_RECORD", 0)
    for p in range(first, len(st.passes)):  # the first quota pass's regions recorded to 16 collapses
        for kind in ("step", "rcosts", "quota", "apply"):
            for item in [f"{p}_{s}" for s in st.region_slabs(p)] if kind in ("rcosts", "apply") else [str(p)]:
                D.run_job(out, kind, item)
    assert any(k.startswith("runmax_") for k in D._load(out / "passes" / str(first) / "again.npz"))
    streams, samples = [], []
    for p in passes:
        folder = out / "passes" / str(p)
        before = {name: D._load(folder / name) for name in ("quota.npz", "again.npz")}
        reads, sizes = _with_small_samples(monkeypatch, out, "quota", str(p))
        for name, z in before.items():
            now = D._load(folder / name)
            assert z.keys() == now.keys() and all(np.array_equal(z[k], now[k], equal_nan=True) for k in z), name
        slabs = st.region_slabs(p)
        streams.append(reads.count(f"{slabs[0]}.npz"))
        assert all(reads.count(f"{s}.npz") == streams[-1] for s in slabs)
        regions = len(D._load(folder / "plan.npz")["region"])
        assert all(n <= 2 * 4 * regions for n in sizes)
        samples.append(len(sizes))
        assert not (folder / "again").exists()
    # the first derives the limit from a sample; a later one cuts its surplus below the limit from one
    assert streams[0] > 4 and samples[0] > 0 and any(n > 4 and k > 0 for n, k in zip(streams[1:], samples[1:]))


def test_the_last_jobs_read_only_the_tiles_around_their_own(counted_run, monkeypatch):
    """After the last pass the mesh is kept by tile.  For each of its tiles, a ``fit`` job reads
    the samples of the box the tile's solve may reach, a ``pieces`` job those of the tile, and
    each reads the mesh of only the tiles that meet that box (and the values of the vertices
    of the tetrahedra it holds).  Run again while every read is recorded, they write the same
    files, byte for byte, and so they do from tiles written without their tetrahedra's boxes
    (a run begun before the tiles kept them)."""
    from trivsel.blocks import _atomic_savez_each, read_config
    from trivsel.blocks import decimate as D

    out = counted_run
    st = D.Stages(*read_config(out))
    plan = st.plan
    files = [f"{d}/{s}.npz" for d in ("fit", "sums") for s in st.slabs] + \
        [f"pieces/{p.name}" for p in (out / "pieces").glob("*.vtu")]
    before = {name: (out / name).read_bytes() for name in files}
    boxes, read, job = [], [], [None]
    read_box, getitem = D._read_box, np.lib.npyio.NpzFile.__getitem__
    monkeypatch.setattr(D, "_read_box", lambda vol, lo, hi: boxes.append((job[0], lo, hi)) or read_box(vol, lo, hi))

    def recorded(self, key):
        read.append((job[0], Path(self.fid.name).parent.name, key))
        return getitem(self, key)

    monkeypatch.setattr(np.lib.npyio.NpzFile, "__getitem__", recorded)
    for kind in ("fit", "pieces"):
        for s in st.slabs:
            job[0] = (kind, s)
            D.run_job(out, kind, str(s))
    monkeypatch.undo()
    assert {name: (out / name).read_bytes() for name in files} == before
    per = plan.counts[1] * plan.counts[2]
    for kind in ("fit", "pieces"):
        for s in st.slabs:
            mine = [(lo, hi) for j, lo, hi in boxes if j == (kind, s)]
            assert len(mine) == per  # one box a tile
            for t, (lo, hi) in zip(range(s * per, (s + 1) * per), mine):
                want = D.B.fit_reach(plan.shape, plan.cuts, t) if kind == "fit" else D.B.tile_box(plan.shape,
                                                                                                  plan.cuts, t)
                assert np.array_equal(lo, want[0]) and np.array_equal(hi, want[1])
            meets = {u for lo, hi in mine for u in D.B.tiles_meeting(plan.cuts, lo, hi)}
            mesh = {int(key.split("_")[1]) for j, d, key in read if j == (kind, s) and d == "tiles"
                    and key.split("_")[0] in ("tets", "rows", "owner", "bmin", "bmax")}
            assert mesh and mesh <= meets
    assert len(meets) < len(plan.blocks())  # the last pieces job: a slab's tiles, not the whole mesh
    for s in st.slabs:  # the tiles without the boxes: each job finds them from the tetrahedra
        path = out / "tiles" / f"{s}.npz"
        with np.load(path) as z:
            kept = {k: z[k] for k in z.files if not k.startswith(("bmin_", "bmax_"))}
            assert len(kept) < len(z.files)
        _atomic_savez_each(path, [kept])
    for name in files:
        (out / name).unlink()
    for kind in ("fit", "pieces"):
        for s in st.slabs:
            D.run_job(out, kind, str(s))
    assert {name: (out / name).read_bytes() for name in files} == before


@pytest.mark.slurm
def test_on_slurm_the_jobs_give_the_mesh_of_one_process(tmp_path, slurm):
    """Every job through sbatch with the unchanged workflow profile, each COMPLETED in sacct, and
    the mesh of one process (a tolerance stop: three passes, no quota jobs)."""
    import re
    import subprocess
    import sys
    from pathlib import Path

    from conftest import SLURM_STATUS_CHECKS, sacct_rows

    n, block, tol = 24, 8, 0.02
    profile = Path(__file__).resolve().parents[1] / "workflow" / "profiles" / "slurm"
    out = tmp_path / "slurm"
    r = subprocess.run([sys.executable, "-m", "trivsel", "blocks", "--function", "4", "--n", str(n), "--block",
                        str(block), "--method", "decimate", "--tol-inf", str(tol), "--out", str(out), "--verbose", "--",
                        "--executor", "slurm", "--workflow-profile", str(profile),
                        *SLURM_STATUS_CHECKS], capture_output=True, text=True, timeout=1200)
    output = r.stdout + r.stderr
    assert r.returncode == 0, output[-5000:]
    ids = sorted(set(re.findall(r"has been submitted with SLURM jobid (\d+)", output)), key=int)
    rows = sacct_rows(ids, ["JobID", "State", "ExitCode"])
    assert len(ids) >= 10 and set(rows) == set(ids), (ids, rows)
    assert all(row["State"] == "COMPLETED" and row["ExitCode"] == "0:0" for row in rows.values()), rows
    _, _, tets = _read(out / "mesh.vtu")
    vol = sample_grid(4, n).values.reshape((n + 1,) * 3)
    assert _same_tets(tets, decimate_in_blocks(vol, block, tol_inf=tol)["tets"])
