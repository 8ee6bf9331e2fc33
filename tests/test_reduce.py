"""The whole method through :func:`trivsel.reduce`: stopping, options, errors, determinism."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import trivsel
import trivsel.methods
from trivsel.mesh import check_mesh
from trivsel.data import grid_from_array, sample_grid, scattered
from trivsel.norms import face_residual_rms
from trivsel.selection import count_for_fraction


def test_fraction_counts_round_half_up_and_include_fixed_points():
    assert count_for_fraction(0.5, 4913) == 2457
    assert count_for_fraction(0.2, 4913) == 983
    assert count_for_fraction(0.1, 4913) == 491
    r = trivsel.reduce(2, n=6, fractions=[0.5, 0.2])
    assert [s.n_selected for s in r.snapshots] == [count_for_fraction(0.2, 343), count_for_fraction(0.5, 343)]
    assert [s.fraction for s in r.snapshots] == [0.2, 0.5]


def test_linear_function_has_zero_error_at_every_snapshot():
    lin = grid_from_array(np.fromfunction(lambda i, j, k: 0.3 * i - 0.2 * j + 0.1 * k + 1.0, (7, 7, 7)))
    r = trivsel.reduce(lin, fractions=[0.1, 0.3, 0.6], check=check_mesh, method="paper")
    for s in r.snapshots:
        assert s.errors["E_inf"] < 1e-12
    assert r.stats["flips"] == {"2-3": 0, "3-2": 0, "4-4": 0}  # nothing to gain, nothing flipped
    d = trivsel.reduce(lin, fractions=[0.1, 0.3, 0.6], check=check_mesh)  # auto: decimate, checked too
    assert d.options["method"] == "decimate" and max(s.errors["E_inf"] for s in d.snapshots) < 1e-12


def test_linear_function_scattered_zero_error():
    rng = np.random.default_rng(0)
    p = rng.random((600, 3))
    d = scattered(p, 2 * p[:, 0] - p[:, 1] + 0.5 * p[:, 2])
    r = trivsel.reduce(d, fractions=[0.2, 0.5], check=check_mesh)
    for s in r.snapshots:
        assert s.errors["E_inf"] < 1e-12


@pytest.mark.parametrize("function", [1, 5])
def test_full_selection_reproduces_the_data(function):
    r = trivsel.reduce(function, n=4, fractions=[1.0], check=check_mesh)
    s = r.snapshots[-1]
    assert s.n_selected == 125
    assert s.errors["E_inf"] < 1e-12


def test_errors_decrease_with_more_points_and_interior_mask_counts():
    r = trivsel.reduce(4, n=8, fractions=[0.1, 0.2, 0.5])
    e = [s.errors["E_rms"] for s in r.snapshots]
    assert e[0] >= e[1] >= e[2] > 0
    d = sample_grid(4, 8)
    assert d.interior_mask().sum() == 7**3
    # the face-residual identity splits E_rms into its boundary and interior parts
    s = r.snapshots[0]
    mask = d.interior_mask()
    face = np.sqrt(np.mean(s.residuals[~mask] ** 2))
    assert face_residual_rms(s.errors["E_rms"], s.errors["E_rms_interior"], 729, 343) == pytest.approx(face)


def test_two_runs_are_identical():
    a = trivsel.reduce(3, n=6, fractions=[0.5, 0.2])
    b = trivsel.reduce(3, n=6, fractions=[0.5, 0.2])
    assert np.array_equal(a.selected, b.selected)
    for sa, sb in zip(a.snapshots, b.snapshots):
        assert np.array_equal(sa.tets, sb.tets)
        assert sa.errors == sb.errors


def test_selected_points_follow_descending_curvature():
    r = trivsel.reduce(1, n=6, fractions=[0.3])
    K = r.curvature[r.order]
    step = 1e-9 * K.max()
    assert np.all(np.diff(np.round(K / step)) <= 0)
    snap = r.snapshots[0]
    assert set(np.unique(snap.tets)) == set(snap.selected.tolist())


def test_interior_candidates_never_select_boundary_points():
    d = sample_grid(5, 6)
    r = trivsel.reduce(d, fractions=[0.3], candidates="interior", check=check_mesh)
    sel = r.snapshots[0].selected[8:]
    assert d.interior_mask()[sel].all()
    # with face points allowed, f5 (curvature peaks on the faces) selects some
    r2 = trivsel.reduce(d, fractions=[0.3], candidates="all")
    assert not d.interior_mask()[r2.snapshots[0].selected[8:]].all()


@pytest.mark.parametrize("opts", [
    {"criterion": "max"}, {"criterion": "sse"}, {"tie_order": "reverse"}, {"tie_order": "random", "seed": 3},
    {"tie_order": "centre"}, {"final_pass": True}, {"first_improving": True}, {"boundary_diagonals": "mirrored"},
    {"vertices_in_error": False}, {"curvature": "local-frame"}, {"ranking": "ascending"}, {"ranking": "random"},
    {"ranking": "analytic"}, {"boundary_flips": True}, {"method": "greedy"}, {"method": "greedy", "greedy_key": "sse"},
])
def test_every_option_gives_a_valid_mesh(opts):
    r = trivsel.reduce(4, n=5, fractions=[0.3, 0.15], check=check_mesh, **opts)
    assert len(r.snapshots) == 2
    for k, v in opts.items():
        assert r.options[k] == v


def test_final_pass_never_worsens_the_criterion_sum():
    from trivsel.mesh import TetMesh
    from trivsel.triangulation import box_tetrahedra

    d = sample_grid(2, 6)
    r = trivsel.reduce(d, fractions=[0.3])
    tm = TetMesh(d.points, d.values, d.ijk)
    tm.start(box_tetrahedra(d.shape, r.options["boundary_diagonals"]))
    order = r.order
    ids = tm.cone(order[0])
    tm.swap(ids)
    tm.run(order, 1, r.snapshots[0].n_selected - 8)
    assert sorted(map(sorted, tm.tetrahedra().tolist())) == sorted(map(sorted, r.snapshots[0].tets.tolist()))
    before = tm.criterion_sum()
    flips = tm.global_pass()
    check_mesh(tm)
    assert tm.criterion_sum() <= before
    assert (flips > 0) == (tm.criterion_sum() < before)
    b = trivsel.reduce(d, fractions=[0.3], final_pass=True)
    assert np.array_equal(r.snapshots[0].selected, b.snapshots[0].selected)
    assert sorted(map(sorted, tm.tetrahedra().tolist())) == sorted(map(sorted, b.snapshots[0].tets.tolist()))


def test_tolerance_stop_rms_and_inf():
    r = trivsel.reduce(4, n=8, tol_rms=0.05)
    s = r.snapshots[-1]
    assert s.errors["E_rms"] <= 0.05
    assert s.n_selected < 729
    r2 = trivsel.reduce(4, n=8, count=s.n_selected - 1)
    assert r2.snapshots[-1].errors["E_rms"] > 0.05  # it stopped at the first count that met the tolerance
    r3 = trivsel.reduce(5, n=6, tol_inf=0.05)
    assert r3.snapshots[-1].errors["E_inf"] <= 0.05


def test_max_flips_caps_the_swap_after_each_insertion_but_not_the_final_pass():
    GREEDY_MAX_FLIPS = trivsel.methods.greedy.DEFAULTS["max_flips"]

    d = sample_grid(5, 10)
    default = trivsel.reduce(d, fractions=[0.1], method="greedy")
    capped = trivsel.reduce(d, fractions=[0.1], method="greedy", max_flips=GREEDY_MAX_FLIPS)
    free = trivsel.reduce(d, fractions=[0.1], method="greedy", max_flips=0)
    assert default.options["max_flips"] == GREEDY_MAX_FLIPS
    np.testing.assert_array_equal(default.selected, capped.selected)
    assert default.stats["round_cap_hits"] > 0 and free.stats["round_cap_hits"] == 0
    one = trivsel.reduce(d, fractions=[0.1], method="greedy", max_flips=1, check=check_mesh)
    assert one.stats["round_cap_hits"] > default.stats["round_cap_hits"]
    assert sum(one.stats["flips"].values()) < sum(free.stats["flips"].values())
    # the paper's method swaps until nothing improves
    assert trivsel.reduce(d, fractions=[0.1]).options["max_flips"] == 0  # paper: until nothing improves
    # the final pass (end of section 4) is not capped: it flips more than once
    fp = trivsel.reduce(d, fractions=[0.1], method="greedy", max_flips=1, final_pass=True)
    assert sum(fp.snapshots[-1].flips.values()) > sum(one.snapshots[-1].flips.values()) + 1


@pytest.mark.parametrize("method, criterion", [("paper", "rms"), ("paper", "max"), ("greedy", "rms")])
def test_run_long_swap_memory_evaluates_less_with_identical_results(method, criterion):
    # under rms and max a remembered gain is the gain a new evaluation computes, bit for bit
    d = sample_grid(4, 12)
    run = trivsel.reduce(d, fractions=[0.2, 0.1], method=method, criterion=criterion, check=check_mesh)
    call = trivsel.reduce(d, fractions=[0.2, 0.1], method=method, criterion=criterion, swap_memory="call")
    assert run.options["swap_memory"] == "run" and call.options["swap_memory"] == "call"
    np.testing.assert_array_equal(run.selected, call.selected)
    for a, b in zip(run.snapshots, call.snapshots):
        np.testing.assert_array_equal(a.tets, b.tets)
        assert a.errors == b.errors
    assert run.stats["flips"] == call.stats["flips"]
    assert run.stats["evaluations"]["made"] < 0.8 * call.stats["evaluations"]["made"]
    assert run.stats["evaluations"]["remembered"] > call.stats["evaluations"]["remembered"]


def test_run_long_swap_memory_under_sse_differs_only_at_rounding_ties():
    # greedy's default criterion: remembered SSE sums may differ from new ones in
    # the last bits, so choices between symmetric configurations can differ
    for f in (1, 4, 5):
        d = sample_grid(f, 12)
        run = trivsel.reduce(d, fractions=[0.1], method="greedy", check=check_mesh)
        call = trivsel.reduce(d, fractions=[0.1], method="greedy", swap_memory="call")
        assert run.stats["evaluations"]["made"] < 0.8 * call.stats["evaluations"]["made"]
        for key in ("E_rms", "E_inf"):
            assert run.snapshots[-1].errors[key] == pytest.approx(call.snapshots[-1].errors[key], rel=0.05)


def test_count_stop():
    r = trivsel.reduce(1, n=6, count=40)
    assert r.snapshots[-1].n_selected == 40
    assert len(r.selected) == 40


@pytest.mark.parametrize("kwargs, message", [
    ({"fractions": [0.0]}, "outside (0, 1]"),
    ({"fractions": [1.2]}, "outside (0, 1]"),
    ({"fractions": [float("nan")]}, "outside (0, 1]"),
    ({"fractions": ["abc"]}, "not a number"),
    ({"fractions": [0.01]}, "fewer than the 8 fixed points"),
    ({"count": 10**6}, "count must be an integer"),
    ({"tol_rms": -1.0}, "tol_rms"),
    ({"fractions": [0.5], "criterion": "l3"}, "unknown criterion"),
    ({"fractions": [0.5], "max_flips": -1}, "max_flips must be >= 0, got -1"),
    ({"fractions": [0.5], "max_flips": 2.5}, "max_flips must be an integer, got 2.5"),
    ({"fractions": [0.5], "max_flips": True}, "max_flips must be an integer, got True"),
    ({"fractions": [0.5], "swap_memory": "forever"}, "unknown swap_memory 'forever': choose one of run, call"),
    ({}, "give fractions"),
])
def test_bad_arguments_raise_input_error(kwargs, message):
    with pytest.raises(trivsel.InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        trivsel.reduce(1, n=4, **kwargs)


@pytest.mark.parametrize("points, values, message", [
    (np.zeros((3, 3)), np.zeros(3), "too few points"),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0.0]]), np.zeros(5), "coplanar"),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1.0], [1, 1, 1]]), np.zeros(6), "duplicate point"),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [np.nan, 0, 1.0]]), np.zeros(5), "non-finite coordinate"),
    (np.eye(5, 3), np.array([0, 1, np.nan, 0, 0]), "non-finite value"),
])
def test_bad_scattered_input(points, values, message):
    with pytest.raises(trivsel.InputError, match=message):
        scattered(points, values)


def test_unknown_function():
    with pytest.raises(trivsel.InputError, match="unknown function 'sombrero'"):
        sample_grid("sombrero", 4)
    assert sample_grid("exponential", 2).name == "4"


def test_jit_and_pure_python_give_identical_results(tmp_path):
    """NUMBA_DISABLE_JIT=1 runs the same kernel as plain Python (for debugging): same result."""
    code = ("import json, trivsel; r = trivsel.reduce(4, n=3, fractions=[0.5, 0.3]);"
            "print(json.dumps({'sel': r.selected.tolist(), 'tets': [sorted(map(sorted, s.tets.tolist())) "
            "for s in r.snapshots], 'err': [s.errors for s in r.snapshots]}))")
    outs = []
    for disable in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=disable)
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
        assert p.returncode == 0, p.stderr
        outs.append(json.loads(p.stdout))
    assert outs[0]["sel"] == outs[1]["sel"]
    assert outs[0]["tets"] == outs[1]["tets"]
    for a, b in zip(outs[0]["err"], outs[1]["err"]):
        for k in a:
            assert a[k] == pytest.approx(b[k], rel=1e-12, abs=1e-15)




def test_compile_kernels_rejects_bad_arguments(capsys):
    from trivsel.cli import main
    from trivsel.mesh import compile_kernels

    with pytest.raises(ValueError, match="unknown part 3"):
        compile_kernels("paper", 3)
    with pytest.raises(ValueError, match="unknown insertion method 'vtk'"):
        compile_kernels("vtk")
    with pytest.raises(SystemExit) as exc:
        main(["compile", "--part", "3"])
    assert exc.value.code == 2
    assert "invalid choice: 3" in capsys.readouterr().err


@pytest.mark.parametrize("method", ["paper", "greedy"])
@pytest.mark.parametrize("stop", [dict(fractions=[0.3, 0.1]), dict(tol_rms=0.01), dict(tol_inf=0.05)])
def test_result_does_not_depend_on_where_the_compiled_loop_is_chunked(monkeypatch, method, stop):
    """The insertion loop returns to Python in chunks (so that Ctrl-C is seen); a chunk
    ending exactly where a tolerance is met must not insert one point more."""
    import trivsel.methods.insertion as R

    def run(step):
        monkeypatch.setattr(R, "CHUNK_STEP", step)
        r = trivsel.reduce(5, n=12, method=method, **stop)
        return [(s.n_selected, s.selected.tobytes(), s.tets.tobytes(), s.residuals.tobytes()) for s in r.snapshots]

    whole = run(10**9)
    assert run(1) == whole
    assert run(7) == whole
    assert run(None) == whole


@pytest.mark.parametrize("method", ["paper", "greedy"])
def test_extreme_magnitudes_are_scaled_exactly(method):
    """Coordinates and values near the float limits (squares overflow or underflow) are
    scaled by a power of two inside: the same selection, and errors scaled back exactly."""
    rng = np.random.default_rng(0)
    p = rng.random((300, 3))
    f = np.sin(4 * p[:, 0]) + p[:, 1] ** 2
    base = trivsel.reduce(scattered(p, f), fractions=[0.3], method=method, values=["data", "fit"])
    b = base.snapshots[-1]
    for e in (-1000, -500, 500, 1000):
        s = trivsel.reduce(scattered(p * 2.0**e, f * 2.0**e), fractions=[0.3], method=method,
                           values=["data", "fit"], check=check_mesh).snapshots[-1]
        assert np.array_equal(s.selected, b.selected) and np.array_equal(s.tets, b.tets)
        assert np.array_equal(s.residuals * 2.0**-e, b.residuals)
        assert {k: v * 2.0**-e for k, v in s.errors.items()} == b.errors
        assert np.array_equal(s.fit["values"] * 2.0**-e, b.fit["values"])
    # a tolerance is in the data's units
    tol = 2 * b.errors["E_rms"]
    n_tol = trivsel.reduce(scattered(p, f), tol_rms=tol, method=method).snapshots[-1].n_selected
    big = trivsel.reduce(scattered(p * 2.0**900, f * 2.0**900), tol_rms=tol * 2.0**900, method=method)
    assert big.snapshots[-1].n_selected == n_tol


@pytest.mark.parametrize("ce, ve", [(1e300, 1e-300), (1e-300, 1e300), (1.0, 1e300), (1.0, 1e-300), (1e300, 1.0)])
def test_coordinates_and_values_at_opposite_float_limits_give_finite_errors(ce, ve):
    rng = np.random.default_rng(1)
    p = rng.random((200, 3))
    f = np.sin(4 * p[:, 0]) + p[:, 1] ** 2
    ref = trivsel.reduce(scattered(p, f), fractions=[0.3]).snapshots[-1].errors["E_rms"]
    for method in ("paper", "greedy"):
        r = trivsel.reduce(scattered(p * ce, f * ve), fractions=[0.3], method=method, check=check_mesh)
        e = r.snapshots[-1].errors["E_rms"] / ve
        assert np.isfinite(e) and 0.2 * ref < e < 5 * ref


def test_scattered_curvature_run_refused_when_delaunay_does_not_fit(monkeypatch):
    import trivsel.resources as res

    rng = np.random.default_rng(0)
    p = rng.random((2000, 3))
    data = scattered(p, p[:, 0])
    monkeypatch.setattr(res, "available_bytes", lambda: 2000 * 1000)  # the mesh fits, the Delaunay does not
    with pytest.raises(trivsel.InputError, match=r"Delaunay tetrahedra of 2000 scattered points needs about"):
        trivsel.reduce(data, fractions=[0.1])
    assert trivsel.reduce(data, fractions=[0.1], method="greedy").snapshots[-1].n_selected == 200
