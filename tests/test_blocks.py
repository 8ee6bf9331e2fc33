"""Blocked reduction (trivsel.blocks) and the prescribed boundary it rests on
(``reduce(boundary=...)``): conforming seams, the global E_inf tolerance, and the same
result from any split of the work."""

import contextlib
import json
import re
import subprocess
import sys

import numpy as np
import pytest

from conftest import made_once
from trivsel import reduce
from trivsel.blocks import (Plan, check_tetrahedra, item_name, merge_blocks, plan_blocks, read_config,
                            reduce_in_blocks, run_job, write_config)
from trivsel.data import sample_grid
from trivsel.exceptions import InputError
from trivsel.mesh import TetMesh, check_mesh
from trivsel.triangulation import kuhn_tetrahedra


def hull_faces(tets):
    """The faces of a tetrahedral mesh that are in one tetrahedron, outward."""
    f = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    _, inv, cnt = np.unique(np.sort(f, axis=1), axis=0, return_inverse=True, return_counts=True)
    return f[cnt[inv.ravel()] == 1]


def as_set(tris):
    return set(map(tuple, np.sort(np.asarray(tris), axis=1).tolist()))


class ArrayVolume:
    """An in-memory volume with the region reader's interface."""

    def __init__(self, values):
        self.values = values
        self.shape, self.origin, self.spacing = values.shape, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
        self.reads = []

    def read(self, region):
        self.reads.append(region)
        return self.values[tuple(slice(*r) for r in region)]


def grid_values(function, n):
    d = sample_grid(function, n)
    return d, d.values.reshape(d.shape)


def evaluate(d, tets):
    """E_RMS and E_inf of a mesh over every grid point, independently of how it was made:
    a fresh mesh state started from the tetrahedra locates every point again."""
    tm = TetMesh(d.points, d.values, d.ijk)
    tm.start(tets)
    check_mesh(tm)
    r = tm.residuals()[0]
    return float(np.sqrt(np.mean(r * r))), float(np.max(np.abs(r)))


def blocked(vol, plan, tol, method="greedy"):
    """Every stage in process; returns (tets, (lines, planes, block stats))."""
    tets, st = reduce_in_blocks(vol, plan, tol_inf=tol, method=method)
    return tets, (st["lines"], st["planes"], st["blocks"])


# ----------------------------------------------------------------------------- prescribed boundary

@pytest.mark.parametrize("method", ["paper", "greedy"])
def test_prescribed_boundary_is_kept(method):
    d = sample_grid(4, 8)
    boundary = hull_faces(kuhn_tetrahedra(d.shape))
    r = reduce(d, tol_inf=0.05, boundary=boundary, method=method, check=check_mesh)
    s = r.snapshots[-1]
    assert as_set(hull_faces(s.tets)) == as_set(boundary)  # no boundary flip, no boundary insertion
    assert s.errors["E_inf"] <= 0.05
    inserted = r.selected[len(np.unique(boundary)) + 1:]
    assert d.interior_mask()[inserted].all()  # only interior points are inserted
    assert evaluate(d, s.tets)[1] == pytest.approx(s.errors["E_inf"])


def test_prescribed_boundary_orientation_either_way():
    d = sample_grid(2, 6)
    b = hull_faces(kuhn_tetrahedra(d.shape))
    t1 = reduce(d, count=240, boundary=b).snapshots[-1].tets
    t2 = reduce(d, count=240, boundary=b[:, [0, 2, 1]]).snapshots[-1].tets
    assert np.array_equal(t1, t2)


@pytest.mark.parametrize("change, message", [
    (lambda b: b[1:], "is not closed"),
    (lambda b: np.vstack([b, b[:1]]), "given twice"),
    (lambda b: np.where(b == b[0, 0], 10**6, b), "outside"),
    (lambda b: np.vstack([b[:1, [0, 2, 1]], b[1:]]), "oriented alike"),
    (lambda b: b.astype(float), "integer array"),
])
def test_bad_boundary_is_refused(change, message):
    d = sample_grid(2, 6)
    b = hull_faces(kuhn_tetrahedra(d.shape))
    with pytest.raises(InputError, match=message) as e:
        reduce(d, count=240, boundary=change(b))
    assert "\n" not in str(e.value)


def test_boundary_inside_the_box_is_refused():
    d = sample_grid(2, 6)
    inner = sample_grid(2, 4)  # the hull of a smaller box, renumbered into the 7^3 grid
    b = hull_faces(kuhn_tetrahedra(inner.shape))
    ijk = np.stack(np.unravel_index(b, inner.shape), axis=-1) + 1
    b7 = (ijk[..., 0] * 7 + ijk[..., 1]) * 7 + ijk[..., 2]
    with pytest.raises(InputError, match="inside the box"):
        reduce(d, count=240, boundary=b7)


def test_boundary_needs_a_grid():
    from trivsel.data import scattered

    rng = np.random.default_rng(0)
    p = rng.random((50, 3))
    with pytest.raises(InputError, match="needs grid data"):
        reduce(scattered(p, p[:, 0]), count=20, boundary=np.array([[0, 1, 2]] * 4))
    with pytest.raises(InputError, match="cannot take a prescribed boundary"):
        reduce(scattered(p, p[:, 0]), count=20, boundary=np.array([[0, 1, 2]] * 4), method="decimate")


# ----------------------------------------------------------------------------- plan

def test_plan_cuts():
    plan = plan_blocks((33, 17, 10), 8)
    assert plan.cuts == ((0, 8, 16, 24, 32), (0, 8, 16), (0, 9))  # 9 - 8 = 1 interval joins the block before
    assert plan.counts == (4, 2, 1)
    assert len(plan.blocks()) == 8
    assert len(plan.planes()) == 5 + 3 + 2
    assert len(plan.lines()) == 3 * 2 + 5 * 2 + 5 * 3
    assert plan.block_region((3, 1, 0)) == ((24, 33), (8, 17), (0, 10))
    assert Plan.from_dict(json.loads(json.dumps(plan.to_dict()))) == plan


@pytest.mark.parametrize("shape, block, message", [((2, 9, 9), 4, "at least 3"), ((9, 9, 9), 1, ">= 2"),
                                                   ((9, 9, 9), 2.5, ">= 2")])
def test_plan_refuses(shape, block, message):
    with pytest.raises(InputError, match=message):
        plan_blocks(shape, block)


# ----------------------------------------------------------------------------- blocked reduction

@pytest.mark.parametrize("function, tol", [(4, 0.02), (2, 0.05)])
def test_blocked_mesh_is_conforming_and_within_tolerance(function, tol):
    d, f = grid_values(function, 20)
    vol = ArrayVolume(f)
    plan = plan_blocks(f.shape, 7)
    assert plan.counts == (3, 3, 3)
    tets, (lines, planes, blocks) = blocked(vol, plan, tol)
    check_tetrahedra(f.shape, tets)  # positive, conforming across seams, fills the box
    e_rms, e_inf = evaluate(d, tets)
    assert e_inf <= tol
    # every point is owned by one stage (the cut points, kept, by none): the stages'
    # squared residuals add up to the whole mesh's
    nodes = np.prod([len(c) for c in plan.cuts])
    own = sum(r["count"] for r in lines.values()) + sum(r["count"] for r in planes.values()) + \
        sum(s["count"] for s in blocks)
    assert own + nodes == d.n_points
    sse = sum(r["sse"] for r in lines.values()) + sum(r["sse"] for r in planes.values()) + \
        sum(s["sse"] for s in blocks)
    assert np.sqrt(sse / d.n_points) == pytest.approx(e_rms, rel=1e-9)
    assert max(s["max"] for s in blocks) == pytest.approx(e_inf, rel=1e-12)
    # no job read the whole volume
    assert all(np.prod([b - a for a, b in r]) < f.size for r in vol.reads)


def test_one_block_equals_the_unblocked_run_with_the_same_boundary():
    d, f = grid_values(4, 12)
    vol = ArrayVolume(f)
    plan = plan_blocks(f.shape, 64)
    assert plan.counts == (1, 1, 1)
    tets, (_, planes, _) = blocked(vol, plan, 0.02)
    faces = np.concatenate([planes[p]["triangles"] for p in plan.planes()])
    hull = hull_faces(tets)
    assert as_set(hull) == as_set(faces)
    direct = reduce(d, tol_inf=0.02, boundary=hull, method="greedy").snapshots[-1].tets
    assert np.array_equal(np.sort(np.sort(direct, axis=1), axis=0), np.sort(np.sort(tets, axis=1), axis=0))


@pytest.mark.parametrize("method", ["paper", "greedy"])
def test_blocked_paper_and_greedy(method):
    d, f = grid_values(2, 12)
    tets, _ = blocked(ArrayVolume(f), plan_blocks(f.shape, 6), 0.05, method=method)
    check_tetrahedra(f.shape, tets)
    assert evaluate(d, tets)[1] <= 0.05


def test_check_tetrahedra_finds_a_gap():
    shape = (4, 4, 4)
    tets = kuhn_tetrahedra(shape)
    check_tetrahedra(shape, tets)
    with pytest.raises(AssertionError, match="fill"):
        check_tetrahedra(shape, tets[1:])
    with pytest.raises(AssertionError, match="volume"):
        check_tetrahedra(shape, np.vstack([tets[:1, [0, 2, 1, 3]], tets[1:]]))


# ----------------------------------------------------------------------------- the workflow (trivsel blocks)

def run_blocks(out, *args, timeout=900):
    """`trivsel blocks` with Snakemake's own log (--verbose), which the tests read."""
    cmd = [sys.executable, "-m", "trivsel", "blocks", "--function", "4", "--n", "16", "--block", "8",
           "--tol-inf", "0.01", "--out", str(out), "--verbose", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def result_files(out):
    """What a blocked run wrote, by relative path: the arrays of its .npz files (wall
    times left out) and the bytes of the others (logs and Snakemake's records left out)."""
    files = {}
    for sub in ("lines", "planes", "pieces"):
        for p in sorted((out / sub).iterdir()):
            if p.suffix == ".npz":
                with np.load(p) as z:
                    files[f"{sub}/{p.name}"] = {k: z[k].tobytes() for k in z.files if k != "seconds"}
            else:
                files[f"{sub}/{p.name}"] = p.read_bytes()
    for name in ("summary.json", "mesh.pvtu", "mesh.vtu"):
        files[name] = (out / name).read_bytes()
    return files


@pytest.fixture
def run_on_two_cores(tmp_path_factory):
    """The folder of ``run_blocks(out, "-c", "2")``, which two tests compare with runs of their
    own: made once for the whole test run (conftest.made_once), read only."""
    def make(folder):
        r = run_blocks(folder / "out", "-c", "2")
        assert r.returncode == 0, r.stderr[-3000:]

    return made_once(tmp_path_factory, "blocks-c2", make) / "out"


@pytest.mark.slow
def test_workflow_same_result_for_any_number_of_jobs_and_after_a_kill(tmp_path, run_on_two_cores):
    import os
    import signal
    import time

    import pyvista as pv

    r1 = run_blocks(tmp_path / "c1", "-c", "1")
    assert r1.returncode == 0, r1.stderr[-3000:]
    one = result_files(tmp_path / "c1")
    assert one == result_files(run_on_two_cores)

    summary = json.loads(one["summary.json"])
    assert summary["E_inf"] <= 0.01 and summary["blocks"] == 8
    d = sample_grid(4, 16)
    merged = pv.read(tmp_path / "c1" / "mesh.vtu")
    tets = merged.point_data["original_index"][merged.cells_dict[pv.CellType.TETRA]]
    check_tetrahedra(d.shape, tets)
    assert np.array_equal(merged.points, d.points[merged.point_data["original_index"]])
    assert evaluate(d, tets) == pytest.approx((summary["E_rms"], summary["E_inf"]), rel=1e-9)
    assert pv.read(tmp_path / "c1" / "mesh.pvtu").n_cells == summary["tetrahedra"] == len(tets)

    # killed (SIGKILL, the lock left behind) once some blocks are done, then run again
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "trivsel", "blocks", "--function", "4", "--n", "16", "--block", "8",
           "--tol-inf", "0.01", "--out", str(out), "-c", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 600
    while time.time() < deadline and len(list((out / "pieces").glob("*.npz")) if (out / "pieces").exists() else []) < 2:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out / "summary.json").exists()
    finished = len(list((out / "pieces").glob("*.npz")))
    # its Snakemake gets SIGTERM, stops its jobs and ends; meanwhile it holds the folder
    while True:
        r3 = run_blocks(out, "-c", "2")
        if "another trivsel blocks run is working" not in r3.stderr or time.time() > deadline:
            break
        time.sleep(1)
    assert not list(out.rglob(".trivsel-tmp-*"))
    assert r3.returncode == 0, r3.stderr[-3000:]
    assert result_files(out) == one
    # it resumed: the blocks finished before the kill did not run again
    # (Snakemake writes "localrule block:" for a job it runs on this machine)
    reran = len(re.findall(r"^(?:local)?rule block:", r3.stderr, flags=re.M))
    assert 1 <= reran <= 8 - finished + 1, r3.stderr[-3000:]


@pytest.mark.slow
def test_workflow_dry_run_plans_resources(tmp_path):
    r = run_blocks(tmp_path / "plan", "-n")
    assert r.returncode == 0, r.stderr[-3000:]
    text = r.stdout + r.stderr
    for rule in ("kernels", "lines", "plane", "block", "merge"):
        assert re.search(rf"^{rule}\s+\d+", text, flags=re.M), text[-3000:]
    assert "mem_mb=" in text and "runtime=" in text
    assert not (tmp_path / "plan").exists()  # a dry run creates nothing


@pytest.mark.parametrize("args, message", [
    ([], "give either an input volume or --function"),
    (["x.zarr", "--function", "4", "--n", "8", "--block", "4", "--tol-inf", "0.1"], "not both"),
    (["--function", "4", "--block", "4", "--tol-inf", "0.1"], "give --n"),
    (["--function", "4", "--n", "16", "--tol-inf", "0.1"], "give --block"),
    (["--function", "4", "--n", "16", "--block", "4"], "give --tol-inf"),
    (["--function", "4", "--n", "16", "--block", "1", "--tol-inf", "0.1"], "block must be an integer from 2 to"),
    (["--function", "4", "--n", "16", "--block", "4", "--tol-inf", "-1"], "tol_inf"),
    (["--function", "9", "--n", "16", "--block", "4", "--tol-inf", "0.1"], "function"),
    (["missing.zarr", "--block", "4", "--tol-inf", "0.1"], "missing.zarr"),
    (["--function", "4", "--n", "16", "--block", "4", "--tol-inf", "0.1", "--job-points", "-1"],
     "--job-points must be a whole number of grid points, 0 or more; got -1"),
])
def test_blocks_bad_input(tmp_path, args, message):
    r = subprocess.run([sys.executable, "-m", "trivsel", "blocks", *args, "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "o" / "summary.json").exists()


def test_blocks_refuses_a_folder_with_another_configuration(tmp_path):
    write_config(tmp_path, {"function": 4, "n": 8, "block": 4, "tol_inf": 0.1})
    write_config(tmp_path, {"function": 4, "n": 8, "block": 4, "tol_inf": 0.1})  # the same: resumes
    with pytest.raises(InputError, match="another configuration"):
        write_config(tmp_path, {"function": 4, "n": 8, "block": 4, "tol_inf": 0.2})


@pytest.mark.parametrize("n, block, planes, blocks", [
    (16, 8, 9, 8),        # small: every plane in one cluster job, every block in one
    (256, 64, 15, 8),     # 64 blocks of 65^3 points: 8 to a cluster job
    (128, 32, 15, 32),    # 33^3 points a block: 2 M points reached at 56, evened out to 2 x 32
    (1024, 128, 2, 1),    # a block of 129^3 points is a cluster job of its own
])
def test_group_components_batch_small_jobs(n, block, planes, blocks):
    from trivsel.blocks import MIN_CLUSTER_JOB_POINTS, group_components

    plan = plan_blocks((n + 1,) * 3, block)
    assert group_components(plan) == {"planes": planes, "blocks": blocks}
    # a smaller minimum makes smaller cluster jobs; one point a job, one job each
    assert group_components(plan, min_points=1) == {"planes": 1, "blocks": 1}
    assert group_components(plan, min_points=MIN_CLUSTER_JOB_POINTS // 4)["blocks"] <= blocks


@pytest.mark.slow
def test_batched_jobs_give_the_result_of_one_job_per_plane_and_block(tmp_path, run_on_two_cores):
    """Planes and blocks reduced several to a job, one after the other in one process (the
    rules a cluster run gets, here asked for on a local run), write what one job per plane
    and per block writes; batches of consecutive items, the last one shorter."""
    from trivsel.blocks import job_batches

    assert job_batches(range(7), 3) == [[0, 1, 2], [3, 4, 5], [6]]
    assert job_batches(range(2), 0) == [[0], [1]]
    # 9 planes of 17^2 points, 8 blocks of 9^3 points: 3 planes and 2 blocks a job, evened out
    batched = run_blocks(tmp_path / "batched", "-c", "2", "--job-points", str(4 * 17 * 17 - 1))
    assert batched.returncode == 0, batched.stderr[-3000:]
    rules = set(re.findall(r"^(?:local)?rule (\w+):$", batched.stdout + batched.stderr, flags=re.M))
    assert {"planes_0", "planes_1", "planes_2", "blocks_0", "blocks_1", "blocks_2"} <= rules, rules
    assert not rules & {"plane", "block"}, rules
    assert result_files(tmp_path / "batched") == result_files(run_on_two_cores)


def test_a_batch_names_the_item_that_failed(tmp_path, monkeypatch, capsys):
    """A job of several blocks stops at the first that fails, and its one line names it."""
    import trivsel.blocks as blocks

    done = []

    def job(out, kind, name):
        if name == "0_1_0":
            raise InputError("the region cannot be read")
        done.append(name)

    monkeypatch.setattr(blocks, "run_job", job)
    assert blocks.main(["block", str(tmp_path), "0_0_0", "0_1_0", "1_0_0"]) == 2
    assert done == ["0_0_0"]
    assert capsys.readouterr().err == "trivsel: error: block 0_1_0: the region cannot be read\n"
    assert blocks.main(["block", str(tmp_path), "0_1_0"]) == 2
    assert capsys.readouterr().err == "trivsel: error: the region cannot be read\n"
    assert blocks.main(["lines", str(tmp_path), "0", "1"]) == 2  # only planes and blocks come in batches
    assert "usage" in capsys.readouterr().err


def test_a_job_file_is_written_group_by_group_and_only_whole(tmp_path):
    """A job's .npz is written one block's (or region's) arrays at a time, as they are made: the
    file reads as :func:`numpy.savez` would have written it, each group is written before the
    next is asked for, and a job that fails half-way leaves neither the file nor a part of it."""
    from trivsel.blocks import _atomic_savez_each

    rng = np.random.default_rng(0)
    groups = [{f"tets_{i}": rng.integers(0, 9, (i + 2, 4)), f"removed_{i}": np.int64(i), f"runmax_{i}": rng.random(i)}
              for i in range(4)]
    path = tmp_path / "slab.npz"
    asked = []

    def made(fail_at=None):
        for i, g in enumerate(groups):
            if i == fail_at:
                raise RuntimeError("a block failed")
            if asked:  # the group before is in the file already
                tmp = [q for q in tmp_path.iterdir() if q != path]
                assert len(tmp) == 1 and tmp[0].stat().st_size > sum(a.nbytes for a in groups[i - 1].values())
            asked.append(i)
            yield g

    _atomic_savez_each(path, made())
    assert asked == [0, 1, 2, 3]
    np.savez(tmp_path / "ref.npz", **{k: v for g in groups for k, v in g.items()})
    with np.load(path) as z, np.load(tmp_path / "ref.npz") as ref:
        assert z.files == ref.files and all(np.array_equal(z[k], ref[k]) and z[k].dtype == ref[k].dtype for k in z.files)
    (tmp_path / "ref.npz").unlink()
    before = path.read_bytes()
    asked.clear()
    with pytest.raises(RuntimeError, match="a block failed"):
        _atomic_savez_each(path, made(fail_at=2))
    assert sorted(tmp_path.iterdir()) == [path] and path.read_bytes() == before


def test_a_job_run_by_hand_names_what_is_wrong_in_one_line(tmp_path, capsys):
    """The job entry points (``python -m trivsel.blocks`` and ``trivsel.blocks.decimate``, what
    a workflow rule runs, and what a user reruns by hand) keep the commands' contract: a folder
    that is not a run, an item that names none of the run's jobs, or a job whose inputs were not
    written yet is one line and exit 2, and nothing is written."""
    import trivsel.blocks as blocks
    from trivsel.blocks import decimate as D
    from trivsel.blocks import write_config

    greedy, dec = tmp_path / "greedy", tmp_path / "decimate"
    write_config(greedy, {"function": 4, "n": 16, "block": 8, "tol_inf": 0.01})
    write_config(dec, {"function": 4, "n": 16, "block": 8, "method": "decimate", "fraction": 0.1})
    before = sorted(tmp_path.rglob("*"))
    cases = [
        (blocks.main, ["block", str(tmp_path / "none"), "0_0_0"], "not the folder of a blocked run (no blocks.json)"),
        (blocks.main, ["block", str(greedy), "x"], "no block job 'x' in this run: its block jobs are 0_0_0,"),
        (blocks.main, ["block", str(greedy), "2_0_0"], "no block job '2_0_0'"),
        (blocks.main, ["plane", str(greedy), "3_0"], "no plane job '3_0'"),
        (blocks.main, ["lines", str(greedy), "-1"], "no lines job '-1' in this run: its lines jobs are 0, 1, 2"),
        (blocks.main, ["plane", str(greedy), "0_0"], "job plane 0_0: a file it reads is missing"),
        (D.main, ["costs", str(tmp_path / "none"), "0"], "not the folder of a blocked run"),
        (D.main, ["costs", str(dec), "01"], "no costs job '01' in this run: its costs jobs are 0, 1"),
        (D.main, ["quota", str(dec), "x"], "no quota job 'x'"),
        (D.main, ["rcosts", str(dec), "0"], "no rcosts job '0' in this run: its rcosts jobs are 0_0,"),
        (D.main, ["apply", str(dec), "0_9"], "no apply job '0_9'"),
        (D.main, ["mesh", str(dec), "0"], "job mesh 0: a file it reads is missing"),
    ]
    for main_, argv, message in cases:
        assert main_(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("trivsel: error: ") and message in err and err.count("\n") == 1, (argv, err)
    assert sorted(tmp_path.rglob("*")) == before


@pytest.mark.slurm
def test_slurm_blocked_run_matches_local_run(tmp_path, slurm):
    """A blocked run through `--executor slurm` and the unchanged workflow profile: every
    job (kernels, lines, planes, blocks, merge) goes through sbatch, batched into as many
    cluster jobs as `group_components` says (kernels and lines one, the planes and the blocks
    of this small grid one each, each batch one process: rules planes_0 and blocks_0, the merge
    one), sacct lists each one COMPLETED, and every result equals a local run's."""
    import math
    from pathlib import Path

    from conftest import SLURM_STATUS_CHECKS, sacct_rows

    from trivsel.blocks import group_components

    profile = Path(__file__).resolve().parents[1] / "workflow" / "profiles" / "slurm"
    r = run_blocks(tmp_path / "slurm", "--", "--executor", "slurm", "--workflow-profile", str(profile), "--jobs", "4",
                   *SLURM_STATUS_CHECKS)
    output = r.stdout + r.stderr
    assert r.returncode == 0, output[-5000:]
    ids = sorted(set(re.findall(r"has been submitted with SLURM jobid (\d+)", output)), key=int)
    _, plan = read_config(tmp_path / "slurm")
    groups = group_components(plan)
    n_jobs = 1 + math.ceil(len(plan.planes()) / groups["planes"]) + math.ceil(len(plan.blocks()) / groups["blocks"]) + 1
    assert len(ids) == n_jobs == 4, output[-5000:]
    remote_rules = re.findall(r"^\s*rule (\w+):$", output, flags=re.M)  # grouped jobs are indented
    assert sorted(set(remote_rules)) == ["blocks_0", "kernels", "lines", "merge", "planes_0"], remote_rules
    fields = ["JobID", "JobName", "State", "ExitCode"]
    rows = sacct_rows(ids, fields)
    assert set(rows) == set(ids), (ids, rows)
    assert all(row["State"] == "COMPLETED" and row["ExitCode"] == "0:0" for row in rows.values()), rows

    local = run_blocks(tmp_path / "local", "-c", "2")
    assert local.returncode == 0, local.stderr[-3000:]
    assert result_files(tmp_path / "slurm") == result_files(tmp_path / "local")


def slurm_blocks_command(out):
    """The `trivsel blocks` command of the SLURM fault tests: f4, n 16, blocks of 8, in ``out``,
    through the workflow profile."""
    from pathlib import Path

    from conftest import SLURM_STATUS_CHECKS

    profile = Path(__file__).resolve().parents[1] / "workflow" / "profiles" / "slurm"
    return [sys.executable, "-m", "trivsel", "blocks", "--function", "4", "--n", "16", "--block", "8",
            "--tol-inf", "0.01", "--out", str(out), "--", "--executor", "slurm", "--workflow-profile", str(profile),
            "--jobs", "4", *SLURM_STATUS_CHECKS]


@contextlib.contextmanager
def background_run(cmd, log, env=None):
    """`trivsel blocks` ``cmd`` started in a session of its own (environment ``env``, default this
    one's), its output in ``log``; if it still runs on the way out (a check failed), it is killed and
    the SLURM jobs of its folder cancelled."""
    import os
    import signal

    from trivsel.blocks.slurm import active_jobs, job_prefix

    with open(log, "w") as fh:
        proc = subprocess.Popen(cmd, stdout=fh, stderr=fh, start_new_session=True, env=env)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            prefix = job_prefix(cmd[cmd.index("--out") + 1])
            subprocess.run(["scancel", *[i for i, _ in active_jobs(prefix)]], check=False)
            proc.wait()


@pytest.mark.slurm
def test_slurm_cancelled_job_ends_the_run_and_a_rerun_completes(tmp_path, slurm):
    """A block job cancelled with scancel while it runs: the run ends within a bounded time (not
    the wait for ever of a state polled from sacct), its last line names the job and CANCELLED,
    no job of the folder is left in the queue, and the same command run again completes, with
    every job it submitted COMPLETED and the result of a local run."""
    import time

    from conftest import sacct_rows

    from trivsel.blocks.slurm import active_jobs, job_prefix

    out = tmp_path / "slurm"
    cmd = slurm_blocks_command(out)
    prefix = job_prefix(out)
    log = tmp_path / "first.log"
    with background_run(cmd + ["--retries", "0"], log) as proc:  # no retry, so that the cancelled job ends the run
        cancelled, deadline = None, time.time() + 600
        while cancelled is None and time.time() < deadline and proc.poll() is None:
            # the block jobs run once every plane is done: then the one running job is theirs
            running = [i for i, state in active_jobs(prefix) if state == "RUNNING"]
            if running and (out / "logs" / "block").is_dir() and any((out / "logs" / "block").iterdir()):
                cancelled = running[0]
                subprocess.run(["scancel", cancelled], check=True, timeout=60)
            time.sleep(0.5)
        assert cancelled, log.read_text()[-5000:]
        proc.wait(timeout=240)
    lines = log.read_text().splitlines()
    assert proc.returncode not in (0, None), lines[-40:]
    assert re.match(rf"trivsel: error: SLURM job {cancelled} .*ended CANCELLED.*run the same command again",
                    lines[-1]), lines[-40:]
    assert not active_jobs(prefix)
    assert not (out / "summary.json").exists()

    # the rerun with Snakemake's own log (--verbose), which names the jobs it submits
    rerun = cmd[:cmd.index("--")] + ["--verbose"] + cmd[cmd.index("--"):]
    r = subprocess.run(rerun, capture_output=True, text=True, timeout=900)
    output = r.stdout + r.stderr
    assert r.returncode == 0, output[-5000:]
    ids = re.findall(r"has been submitted with SLURM jobid (\d+)", output)
    assert ids and not re.search(r"^\s*rule (kernels|lines|planes?(_\d+)?):$", output, flags=re.M), output[-5000:]
    rows = sacct_rows(ids, ["JobID", "JobName", "State"])
    assert all(row["State"] == "COMPLETED" and row["JobName"].startswith(prefix + "_") for row in rows.values()), rows
    local = run_blocks(tmp_path / "local", "-c", "2")
    assert local.returncode == 0, local.stderr[-3000:]
    assert result_files(out) == result_files(tmp_path / "local")


def processes_in(folder):
    """``{pid: command line}`` of the live processes working in ``folder`` (their current folder:
    Snakemake's and the jobs' in a run's folder)."""
    import os
    from pathlib import Path

    found = {}
    for p in Path("/proc").iterdir():
        try:
            if p.name.isdigit() and os.readlink(p / "cwd") == str(folder) and (p / "stat").read_text().rsplit(
                    ")", 1)[1].split()[0] != "Z":
                found[int(p.name)] = (p / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # ended meanwhile, or not ours to read
            pass
    return found


#: Put on the jobs' PYTHONPATH: the kernels job of a run holds SIGTERM for a minute before it
#: starts, as a job inside a long compiled kernel does (Python acts on a signal only between
#: bytecodes), after writing ``held`` in its folder.
HOLD_SIGTERM = """
import os, signal, sys, time
if sys.orig_argv[1:4] in (["-m", "trivsel.blocks", "kernels"], ["-m", "trivsel.blocks.decimate", "kernels"]):
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
    open("held", "w").close()
    time.sleep(60)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM})
"""


@pytest.mark.slurm
def test_slurm_cancelled_job_leaves_no_process(tmp_path, slurm):
    """A job cancelled while its process cannot take SIGTERM (held for a minute, as in a long
    compiled kernel): SLURM kills it KillWait seconds later, and the Snakemake of the job's batch
    script ends with the script, so when the run has ended, no process of the run is left.  (Under
    proctrack/linuxproc, SLURM sends SIGKILL only to the processes descended from the job's
    slurmstepd: a process whose parent shell died of the SIGTERM would be left.)"""
    import os
    import signal
    import time

    from trivsel.blocks.slurm import active_jobs, job_prefix

    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(HOLD_SIGTERM)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(hook), *filter(None, [os.environ.get("PYTHONPATH")])]))
    out = tmp_path / "slurm"
    cmd = slurm_blocks_command(out)
    prefix = job_prefix(out)
    log = tmp_path / "run.log"
    left = {}
    try:
        with background_run(cmd + ["--retries", "0"], log, env=env) as proc:
            deadline = time.time() + 300
            while not (out / "held").exists() and time.time() < deadline and proc.poll() is None:
                time.sleep(0.2)
            running = [i for i, state in active_jobs(prefix) if state == "RUNNING"]
            assert (out / "held").exists() and running, log.read_text()[-5000:]
            subprocess.run(["scancel", *running], check=True, timeout=60)
            proc.wait(timeout=240)
        lines = log.read_text().splitlines()
        assert proc.returncode not in (0, None) and "ended CANCELLED" in lines[-1], lines[-40:]
        assert not active_jobs(prefix)
        end = time.time() + 5  # the last job processes exit as Snakemake does
        while (left := processes_in(out)) and time.time() < end:
            time.sleep(0.2)
        assert not left, left
    finally:
        for pid in processes_in(out):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


@pytest.mark.slurm
def test_slurm_timed_out_job_ends_the_run_and_a_rerun_completes(tmp_path, slurm):
    """A block job that runs past its time limit (1 minute, SLURM's least, given with Snakemake's
    `--set-resources`; its commands stopped with SIGSTOP, as a job stuck on a slow file system
    would be) is ended TIMEOUT by SLURM: the run ends within a bounded time, its last line names
    the job, TIMEOUT and how to give the job more time, no job of the folder is left in the
    queue, and the same command without the short limit completes with the result of a local run."""
    import os
    import signal
    import time
    from pathlib import Path

    from trivsel.blocks.slurm import active_jobs, job_prefix

    out = tmp_path / "slurm"
    cmd = slurm_blocks_command(out)
    prefix = job_prefix(out)
    log = tmp_path / "first.log"
    # no retry, so that the timed-out job ends the run
    with background_run(cmd + ["--retries", "0", "--set-resources", "blocks_0:runtime=1"], log) as proc:
        stopped, deadline = None, time.time() + 600
        while stopped is None and time.time() < deadline and proc.poll() is None:
            # the blocks' job (its comment names its rule), stopped as soon as it runs: its batch
            # script and the commands in it, not srun, which talks to slurmctld (once, with srun
            # stopped too, SLURM did not end the job at its limit)
            rows = [r.split("|") for r in subprocess.run(["squeue", "--me", "-h", "-o", "%i|%j|%k|%T"],
                                                         capture_output=True, text=True, timeout=60).stdout.split()]
            job = next((r[0] for r in rows if r[1].startswith(prefix + "_") and r[2:] == ["rule_blocks_0", "RUNNING"]),
                       None)
            pids = [x.split()[0] for x in subprocess.run(["scontrol", "listpids", job], capture_output=True,
                                                         text=True, timeout=60).stdout.splitlines()[1:]] if job else []
            for pid in pids:
                try:
                    if Path(f"/proc/{pid}/comm").read_text().strip() not in ("srun", "slurmstepd"):
                        os.kill(int(pid), signal.SIGSTOP)
                        stopped = job
                except OSError:  # ended meanwhile
                    pass
            time.sleep(0.5)
        assert stopped, log.read_text()[-5000:]
        # SLURM ends it 1 to 1.5 minutes after it started (it checks the limits every 30 s), and
        # Snakemake's status checks, 10 s further apart each time, see it up to 1 minute later and
        # sleep once more before Snakemake exits; meanwhile the local run to compare with
        local = run_blocks(tmp_path / "local", "-c", "2")
        assert local.returncode == 0, local.stderr[-3000:]
        proc.wait(timeout=360)
    lines = log.read_text().splitlines()
    assert proc.returncode not in (0, None), lines[-40:]
    assert re.match(rf"trivsel: error: SLURM job {stopped} .*ended TIMEOUT.*--set-resources blocks_0:runtime=MINUTES"
                    r".* run the same command again", lines[-1]), lines[-40:]
    assert not active_jobs(prefix)
    assert not (out / "summary.json").exists()

    r = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, (r.stdout + r.stderr)[-5000:]
    assert result_files(out) == result_files(tmp_path / "local")


def test_cli_reduce_with_a_boundary(tmp_path):
    """`trivsel reduce --boundary TRIANGLES.npy`: the mesh keeps the given surface; a bad file
    is one line and exit 2."""
    import pyvista as pv

    from trivsel.cli import main

    d = sample_grid(4, 6)
    b = hull_faces(kuhn_tetrahedra(d.shape))
    np.save(tmp_path / "b.npy", b)
    assert main(["reduce", "--function", "4", "--n", "6", "--tol-inf", "0.05", "--method", "greedy",
                 "--boundary", str(tmp_path / "b.npy"), "--out", str(tmp_path / "o")]) == 0
    mesh = pv.read(next((tmp_path / "o").glob("mesh_*.vtu")))
    tets = mesh.point_data["original_index"][mesh.cells_dict[pv.CellType.TETRA]]
    assert as_set(hull_faces(tets)) == as_set(b)
    (tmp_path / "bad.npy").write_text("not an array")
    r = subprocess.run([sys.executable, "-m", "trivsel", "reduce", "--function", "4", "--n", "6", "--count", "200",
                        "--boundary", str(tmp_path / "bad.npy"), "--out", str(tmp_path / "o2")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "cannot read boundary" in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "o2").exists()


def test_blocked_nifti_keeps_its_geometry(tmp_path):
    """A blocked run of a NIfTI with scaling, flipped and permuted axes, job by job from the
    files (as the workflow runs them): the merged mesh's points are the file's voxels at
    their world coordinates with their values (original_index: the voxel's Fortran-order
    index), the mesh is valid and within the tolerance."""
    import nibabel as nib
    import pyvista as pv

    from trivsel.io import load

    x, y, z = np.meshgrid(*(np.linspace(-1, 1, s) for s in (9, 11, 10)), indexing="ij")
    raw = np.round(1000 * np.exp(-(x**2 + 2 * y**2 + z**2))).astype(np.int16)
    affine = np.array([[0, 0, -0.75, 4.0], [-1.5, 0, 0, 1.0], [0, 2.0, 0, 7.0], [0, 0, 0, 1]])
    img = nib.Nifti1Image(raw, affine)
    img.header.set_slope_inter(0.5, 3.0)
    nib.save(img, tmp_path / "head.nii.gz")
    whole = load(tmp_path / "head.nii.gz")

    out = tmp_path / "run"
    cfg = write_config(out, {"input": str(tmp_path / "head.nii.gz"), "block": 4, "tol_inf": 20.0})
    _, plan = read_config(out)
    assert plan.shape == whole.shape and cfg["spacing"] == list(whole.spacing)
    run_job(out, "lines", "0"), run_job(out, "lines", "1"), run_job(out, "lines", "2")
    for p in plan.planes():
        run_job(out, "plane", item_name(p))
    for b in plan.blocks():
        run_job(out, "block", item_name(b))
    summary = merge_blocks(out)
    merged = pv.read(out / "mesh.vtu")
    ids = merged.point_data["original_index"]
    at = np.searchsorted(whole.file_ids(np.arange(whole.n_points)), ids, sorter=np.argsort(
        whole.file_ids(np.arange(whole.n_points))))
    order = np.argsort(whole.file_ids(np.arange(whole.n_points)))[at]
    assert np.array_equal(merged.points, whole.points[order])
    assert np.array_equal(merged.point_data["value"], whole.values[order])
    tets = order[merged.cells_dict[pv.CellType.TETRA]]
    check_tetrahedra(whole.shape, tets)
    e_rms, e_inf = evaluate(whole, tets)
    assert e_inf <= 20.0 and e_inf == pytest.approx(summary["E_inf"])
    assert e_rms == pytest.approx(summary["E_rms"], rel=1e-9)


def _memory_refusal(tmp_path, capsys, monkeypatch, *args):
    """``trivsel reduce ARGS`` with 1 MB of memory available: its one-line refusal."""
    import trivsel.resources as res
    from trivsel.cli import main

    monkeypatch.setattr(res, "available_bytes", lambda: 1_000_000)
    assert main(["reduce", *args, "--out", str(tmp_path / "o")]) == 2
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and not (tmp_path / "o").exists(), err
    return err


@pytest.mark.parametrize("args, expect", [
    (["--method", "decimate", "--tol-inf", "0.05"], "--method decimate --block 16 --tol-inf 0.05 --out {out} -c 2"),
    (["--method", "decimate", "--tol-rms", "0.05"], "--method decimate --block 16 --tol-rms 0.05 --out {out} -c 2"),
    (["--method", "greedy", "--tol-rms", "0.05"],
     "--block 16 --tol-inf TOL --method greedy --out {out} -c 2 (blocks stop at an E_inf tolerance TOL)"),
    (["--method", "paper", "--fractions", "0.1"],
     "--block 16 --tol-inf TOL --method paper --out {out} -c 2 (blocks stop at an E_inf tolerance TOL)"),
])
def test_memory_refusal_names_the_blocks_command_line(tmp_path, capsys, monkeypatch, args, expect):
    err = _memory_refusal(tmp_path, capsys, monkeypatch, "--function", "4", "--n", "12", *args)
    assert "reducing 2197 points needs about" in err or "decimating 2197 points needs about" in err, err
    assert ("in blocks of bounded memory: trivsel blocks --function 4 --n 12 "
            + expect.format(out=tmp_path / "o")) in err, err


def test_memory_refusal_of_scattered_points_names_no_blocks_command(tmp_path, capsys, monkeypatch):
    rng = np.random.default_rng(0)
    p = rng.random((3000, 3))
    np.savez(tmp_path / "pts.npz", points=p, values=p[:, 0])
    err = _memory_refusal(tmp_path, capsys, monkeypatch, str(tmp_path / "pts.npz"), "--fractions", "0.1")
    assert "needs about" in err and "trivsel blocks" not in err, err


@pytest.mark.slow
def test_the_blocks_command_of_a_memory_refusal_does_the_job(tmp_path, capsys, monkeypatch):
    """The command line that a refusal names runs as it stands and meets the tolerance."""
    import shlex

    import nibabel as nib

    from trivsel.cli import main

    v = sample_grid(4, 12).values.reshape(13, 13, 13)
    nib.save(nib.Nifti1Image(v.astype(np.float32), np.eye(4)), tmp_path / "scan.nii.gz")
    err = _memory_refusal(tmp_path, capsys, monkeypatch, str(tmp_path / "scan.nii.gz"), "--method", "decimate",
                          "--tol-inf", "0.02")
    cmd = shlex.split(err.split("in blocks of bounded memory: ", 1)[1].split(" (", 1)[0])
    assert cmd[:3] == ["trivsel", "blocks", str(tmp_path / "scan.nii.gz")], cmd
    assert main(cmd[1:]) == 0
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["E_inf"] <= 0.02 + 1e-12, summary


@pytest.mark.slurm
def test_slurm_failing_job_gives_its_own_message(tmp_path, slurm):
    """On SLURM, a block job that refuses its input (a value changed in place after the run's
    set-up, as in the hostile test of a local run) ends the run with that job's own line and
    exit status 2, not only the job's SLURM state: a rerun would not mend it."""
    import os
    from pathlib import Path

    from conftest import SLURM_STATUS_CHECKS

    from trivsel.blocks import write_config

    v = np.fromfunction(lambda i, j, k: np.sin(i) + j * k / 10.0, (9, 9, 9))
    src = tmp_path / "nan.npy"
    np.save(src, v)
    write_config(tmp_path / "o", {"input": str(src), "block": 4, "tol_inf": 0.05})
    st = os.stat(src)
    v[6, 6, 6] = np.nan  # inside block 1_1_1 only
    np.save(src, v)
    os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns))
    profile = Path(__file__).resolve().parents[1] / "workflow" / "profiles" / "slurm"
    r = subprocess.run([sys.executable, "-m", "trivsel", "blocks", str(src), "--block", "4", "--tol-inf", "0.05",
                        "--out", str(tmp_path / "o"), "--", "--executor", "slurm", "--workflow-profile", str(profile),
                        *SLURM_STATUS_CHECKS, "--retries", "0"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(
        "trivsel: error: job blocks_0 failed: block 1_1_1: non-finite value nan at grid index (6, 6, 6)"), r.stderr
