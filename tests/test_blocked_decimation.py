"""``decimate`` in blocks (:mod:`trivsel.decimation.blocked`): the merged mesh is a conforming
tetrahedralisation of the box whose vertices are data points, every other point lies in the
tetrahedron that holds it, the count asked for is met, and the errors stay near those of the
unblocked run at the same count."""

import re
import shlex

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import trivsel
from trivsel.blocks import check_tetrahedra
from trivsel.data import grid_from_array, sample_grid
from trivsel.decimation import reduce_by_collapse
from trivsel.decimation.blocked import (SSE_SHARE, block_cuts, cut_counts, cut_quota, decimate_in_blocks, quality_note,
                                        quota_limit, running_sse, short_blocks, sse_at, streamed_cut_counts,
                                        streamed_cut_quota, streamed_kth_cost, streamed_threshold, threshold,
                                        tied_counts, tile_fit, tile_of)
from trivsel.selection import count_for_fraction

from conftest import examples


def smooth_volume(shape, seed=3):
    """A smooth random volume with a sharp ridge: sums of Gaussians and one step."""
    rng = np.random.default_rng(seed)
    g = np.stack(np.indices(shape), axis=-1).astype(float) / (np.asarray(shape) - 1)
    v = np.zeros(shape)
    for _ in range(6):
        c, s = rng.random(3), 0.1 + 0.2 * rng.random()
        v += rng.normal() * np.exp(-np.sum((g - c) ** 2, axis=-1) / (2 * s * s))
    return v + 0.5 * (g[..., 0] + 0.3 * g[..., 1] > 0.6)


def f4(n):
    d = sample_grid(4, n)
    return d.values.reshape(d.shape)


def residuals(vol, out):
    """Residuals at every point, each point located in its tetrahedron by exact integer
    barycentric coordinates (all >= 0: asserted)."""
    shape, f = vol.shape, vol.reshape(-1).astype(float)
    N = f.size
    ijk = np.stack(np.unravel_index(np.arange(N), shape), axis=1)
    r = np.zeros(N)
    p = np.flatnonzero(out["ptet"] >= 0)
    assert np.array_equal(np.sort(np.r_[p, out["vertices"]]), np.arange(N)), "a point is neither vertex nor inside"
    q = ijk[out["tets"][out["ptet"][p]]]  # (k, 4, 3) integers
    x = ijk[p]

    def det(a, b, c):
        return np.einsum("ij,ij->i", np.cross(a, b), c)

    lam = np.stack([det(q[:, 1] - x, q[:, 2] - x, q[:, 3] - x), det(x - q[:, 0], q[:, 2] - q[:, 0], q[:, 3] - q[:, 0]),
                    det(q[:, 1] - q[:, 0], x - q[:, 0], q[:, 3] - q[:, 0]),
                    det(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0], x - q[:, 0])], axis=1)
    assert lam.min() >= 0, "a point lies outside the tetrahedron that holds it"
    w = lam / lam.sum(axis=1, keepdims=True)
    r[p] = f[p] - np.einsum("ij,ij->i", w, f[out["tets"][out["ptet"][p]]])
    return r


def test_blocks_meet_on_shared_faces_and_a_short_last_block_joins_the_one_before():
    assert block_cuts(33, 16).tolist() == [0, 16, 32]
    assert block_cuts(40, 16).tolist() == [0, 16, 39]  # 39 - 32 = 7 < 8: no block of 7
    assert block_cuts(45, 16).tolist() == [0, 16, 32, 44]
    assert block_cuts(10, 16).tolist() == [0, 9]


@pytest.mark.parametrize("name, vol, block, fraction", [
    ("f4", f4(40), 12, 0.05),
    ("smooth, not a cube", smooth_volume((37, 29, 21)), 10, 0.1),
])
def test_the_merged_mesh_is_a_conforming_tetrahedralisation_of_data_points_at_the_count(name, vol, block, fraction):
    out = decimate_in_blocks(vol, block, fraction=fraction)
    check_tetrahedra(vol.shape, out["tets"])  # positive volumes, conforming faces, the box filled
    assert np.array_equal(np.unique(out["tets"]), out["vertices"])
    assert len(out["vertices"]) == count_for_fraction(fraction, vol.size)
    corners = [np.ravel_multi_index(c, vol.shape) for c in np.ndindex(2, 2, 2)
               for c in [tuple(np.asarray(c) * (np.asarray(vol.shape) - 1))]]
    assert set(corners) <= set(out["vertices"].tolist())
    r = residuals(vol, out)
    assert np.all(r[out["vertices"]] == 0)
    assert out["stats"]["blocks"] > 8


@pytest.mark.parametrize("vol, block, count", [
    (sample_grid(4, 8).values.reshape(9, 9, 9), 4, 729),  # every point: nothing to remove
    (sample_grid(4, 8).values.reshape(9, 9, 9), 4, 700),  # symmetric data: blocks tie at the threshold
    (np.arange(125.0).reshape(5, 5, 5), 2, 125),  # linear data: every collapse costs 0
    (np.fromfunction(lambda i, j, k: np.sin(i / 2) * j + k ** 2, (4, 5, 6)), 4, 100),
])
def test_collapses_of_equal_cost_at_the_threshold_do_not_take_the_count_below_the_target(vol, block, count):
    """The blocks' cut takes, of the collapses whose cost ties at its threshold, only as many as
    keep the projected count at the target (:func:`cut_counts`): taking them all took these runs
    to 723, 665, 69 and 66."""
    out = decimate_in_blocks(vol, block, count=count)
    assert len(out["vertices"]) == count
    runmax = [np.array([0.0, 1.0, 1.0, 1.0, 2.0]), np.array([1.0, 1.0, 3.0])]
    assert cut_counts(runmax, 1.0) == [4, 2]  # without a target: every collapse at tau
    assert cut_counts(runmax, 1.0, [10, 10], 0, 20 - 3) == [3, 0]  # three removals: below tau, then in block order
    assert cut_counts(runmax, 1.0, [10, 10], 0, 20 - 5) == [4, 1]
    assert cut_counts(runmax, 1.0, [10, 10], 0, 20 - 9) == [4, 2]  # room for every tie: all of them
    assert cut_counts(runmax, 1.0, [10, 10], 10, 20 - 3) == [4, 2]  # the seams at the blocks' density: 30 * 14 / 20


def test_errors_stay_near_the_unblocked_run_at_the_same_count():
    """Measured on f4 at 49^3 in blocks of 16 to 5 %: E_RMS 1.02x, E_inf 0.96x the unblocked
    run's.  A cut that ignores the seams (or a lazy queue to the end) costs 10-20 % here."""
    vol = f4(48)
    out = decimate_in_blocks(vol, 16, fraction=0.05)
    r = residuals(vol, out)
    shots, *_ = reduce_by_collapse(grid_from_array(vol), [len(out["vertices"])])
    ru = shots[-1].residuals
    assert np.sqrt(np.mean(r ** 2)) <= 1.05 * np.sqrt(np.mean(ru ** 2))
    assert np.abs(r).max() <= 1.10 * np.abs(ru).max()


def test_an_e_inf_tolerance_holds_for_every_point_across_the_seams():
    vol = smooth_volume((30, 30, 30), seed=5)
    tol = 0.02
    out = decimate_in_blocks(vol, 10, tol_inf=tol)
    check_tetrahedra(vol.shape, out["tets"])
    r = residuals(vol, out)
    assert np.abs(r).max() <= tol
    assert len(out["vertices"]) < 0.5 * vol.size  # the seams were freed, not kept


def rms(r):
    return float(np.sqrt(np.mean(r ** 2)))


def test_an_e_rms_tolerance_holds_across_the_seams_with_about_the_count_of_one_piece():
    """With ``tol_rms`` the stages share the budget ``tol_rms^2 N``: the merged mesh's E_RMS is
    within the tolerance, its squared error within the bound the run reports, and it keeps about
    as many vertices as one piece at that tolerance (measured on f4 at 49^3 in blocks of 16, at
    one piece's E_RMS at 5 %: 1.008x its count; at 10 %: 1.003x)."""
    vol = f4(48)
    m = count_for_fraction(0.05, vol.size)
    shots, *_ = reduce_by_collapse(grid_from_array(vol), [m])
    tol = rms(shots[-1].residuals)
    out = decimate_in_blocks(vol, 16, tol_rms=tol)
    check_tetrahedra(vol.shape, out["tets"])
    r = residuals(vol, out)
    assert rms(r) <= tol
    assert np.sum(r ** 2) <= out["stats"]["sse_bound"] * (1 + 1e-9) <= tol ** 2 * vol.size
    assert len(out["vertices"]) <= 1.03 * m


def ramps(shape):
    """``sin(i / 3) j + k^2``: linear along j and quadratic along k, so that many collapses cost
    nothing but the rounding of their interpolants (a residual of 1e-15 where the exact one is 0)."""
    i, j, k = np.indices(shape).astype(float)
    return np.sin(i / 3) * j + k ** 2


@pytest.mark.parametrize("shape, block, tol", [
    ((7, 17, 12), 12, 0.0),
    ((11, 11, 13), 7, 0.0),
    ((11, 13, 12), 7, 5.830679117429392e-16),  # the E_RMS of a run to 30 % in one piece
])
def test_an_e_rms_tolerance_on_the_scale_of_rounding_holds_in_blocks(shape, block, tol):
    """Found by fuzzing ``reduce(..., block=...)``: at ``tol_rms`` 0 these runs reported E_RMS
    of 3e-15 (one piece: 0).  The regions' decimations started from their points' residuals in
    the rounded weights, while the collapses and the final errors take the kernel's interpolant,
    so a collapse could trade one rounding for another inside the budget."""
    d = grid_from_array(ramps(shape))
    for block_ in (block, None):
        shot = trivsel.reduce(d, method="decimate", tol_rms=tol, **({"block": block_} if block_ else {})).snapshots[-1]
        assert shot.errors["E_rms"] <= tol, block_


@settings(max_examples=examples(0.02), deadline=None)
@given(st.tuples(*[st.integers(4, 11)] * 3), st.integers(3, 7), st.sampled_from([0.0, 1e-16, 1e-15, 1e-14]),
       st.sampled_from(["ramps", "levels"]), st.integers(0, 2**32 - 1))
def test_an_e_rms_tolerance_holds_in_blocks_down_to_zero(shape, block, tol, kind, seed):
    """The E_RMS that ``reduce(..., block=...)`` reports is within ``tol_rms``, tolerances of 0
    and on the scale of rounding included, on data where many collapses cost exactly or nearly
    nothing (ramps; a few integer levels)."""
    vol = ramps(shape) if kind == "ramps" else np.random.default_rng(seed).integers(0, 3, shape).astype(float)
    shot = trivsel.reduce(grid_from_array(vol), method="decimate", tol_rms=tol, block=block).snapshots[-1]
    assert shot.errors["E_rms"] <= tol


def test_a_regions_points_start_with_the_residuals_of_the_kernels_interpolant():
    """A mesh on a lattice with points inside its tetrahedra (a region of a pass) starts with
    each point's residual from the kernel's interpolant, the number its collapses and the
    final errors take (:func:`point_weights_of`), bit for bit."""
    from trivsel.decimation import new_mesh_state
    from trivsel.decimation.blocked import point_weights

    vol = ramps((9, 10, 11)) * 1.1
    out = decimate_in_blocks(vol, 4, fraction=0.2)
    f = vol.reshape(-1)
    _, _, value = point_weights(vol.shape, out["tets"], out["ptet"], f)
    ijk = np.stack(np.unravel_index(np.arange(vol.size), vol.shape), axis=1)
    S = new_mesh_state(ijk * 0.5 + 3.0, out["tets"], f, located=out["ptet"])  # a lattice of another spacing
    inside = out["ptet"] >= 0
    assert inside.sum() > 100
    assert np.array_equal(S.res[inside], (f - value)[inside])


@pytest.mark.parametrize("first", ["count", "tol_rms"])
def test_a_count_and_an_e_rms_tolerance_stop_at_whichever_comes_first(first):
    vol = smooth_volume((30, 30, 30), seed=5)
    if first == "count":  # 1.2 times the E_RMS of the run to the count alone: the budget then holds the count
        tol = 1.2 * rms(residuals(vol, decimate_in_blocks(vol, 10, count=900)))
    else:  # half one piece's E_RMS at the count: out of reach at that count
        tol = rms(reduce_by_collapse(grid_from_array(vol), [900])[0][-1].residuals) / 2
    out = decimate_in_blocks(vol, 10, count=900, tol_rms=tol)
    check_tetrahedra(vol.shape, out["tets"])
    assert rms(residuals(vol, out)) <= tol
    assert (len(out["vertices"]) == 900) == (first == "count")


def test_identical_runs_give_identical_meshes_in_one_process_or_two():
    vol = smooth_volume((25, 25, 25), seed=7)
    a, b, c = (decimate_in_blocks(vol, 8, count=900, threads=t) for t in (1, 1, 2))
    assert all(np.array_equal(a[k], b[k]) and np.array_equal(a[k], c[k]) for k in ("vertices", "tets", "ptet"))


def held(runmax):
    """Records held in memory, read as the quota job reads its files: one ``(runmax, sse)`` a
    region, in order, each time it is called (no errors)."""
    return lambda: ((r, np.zeros(len(r))) for r in runmax)


def test_the_quota_passes_share_a_count_by_one_cost():
    """quota_limit: the ceil(share * surplus)-th cheapest of the first quota pass's recorded costs
    (inf when it recorded fewer); cut_quota takes nothing above it, a prefix of each region."""
    runmax = [np.array([1.0, 2.0, 5.0, 9.0]), np.array([0.5, 3.0, 3.0]), np.zeros(0)]
    read = held(runmax)
    assert quota_limit(read, 10, 0.25) == 2.0  # the 3rd cheapest of 0.5, 1, 2, 3, 3, 5, 9
    assert quota_limit(read, 10, 0.625) == 9.0 and quota_limit(read, 10, 0.75) == np.inf
    counts, _ = cut_quota(runmax, 10, limit=3.0)
    assert counts.tolist() == [2, 3, 0]
    assert cut_quota(runmax, 4, limit=3.0)[0].tolist() == [2, 2, 0]  # the surplus first, ties by region
    assert cut_quota(runmax, 10)[0].tolist() == [4, 3, 0]


def test_a_quota_cut_below_its_limit_counts_the_squared_error_of_what_it_takes():
    """With a cost limit the regions' sequences are cut to their prefixes at it: the squared error
    counted is that of the collapses taken, region by region, whatever the sequences beyond the limit
    hold, and the budget stops the cut on it."""
    runmax = [np.array([1.0, 2.0, 5.0, 9.0]), np.array([0.5, 3.0, 3.0, 4.0])]
    sse = [np.array([1.0, 3.0, 100.0, 1000.0]), np.array([0.5, 2.0, 4.0, 10.0])]
    counts, spent = cut_quota(runmax, 10, sse, limit=3.0)
    assert counts.tolist() == [2, 3] and spent == 3.0 + 4.0
    counts, spent = cut_quota(runmax, 10, sse, budget=4.9, limit=3.0)  # 0.5, 1, 2 fit (3.5); 3 (1.5 more) does not
    assert counts.tolist() == [2, 1] and spent == 3.0 + 0.5


def test_records_cut_at_a_floor_give_the_threshold_of_whole_records():
    """threshold's ``decided``: the largest cost it compared (inf where it needed every collapse);
    short_blocks: the records that stop at their floor at or below it, to record again."""
    runmax = [np.array([1.0, 2.0, 3.0]), np.array([1.5, 4.0])]
    inner = [10, 10]
    assert threshold(runmax, inner, 0, 17) == (2.0, 2.0)  # 1, 1.5, 2 removed: 17 left
    assert threshold(runmax, inner, 0, 14) == (4.0, np.inf)  # out of reach: every collapse
    assert short_blocks(runmax, [True, True], 2.0) == []
    assert short_blocks(runmax, [True, False], 3.0) == [0] and short_blocks(runmax, [False, True], 4.0) == [1]
    sse = [np.array([1.0, 2.0, 9.0]), np.array([0.5, 8.0])]  # the budget binds first: decided by 3.0
    assert threshold(runmax, inner, 0, 15, sse, budget=4.0 / SSE_SHARE) == (2.0, 3.0)


@pytest.mark.parametrize("floor", [0.0, 1.0])
def test_blocks_recorded_to_a_floor_give_the_mesh_of_whole_records(floor, monkeypatch):
    """Pass 1 records each block to RECORD_FLOOR times its share of the count; the blocks whose
    record ends below a cost the cut compared are recorded again to their end.  At the floor of
    the whole share (blocks recorded again) and at none, the mesh of the default floor."""
    from trivsel.decimation import blocked

    vol = smooth_volume((30, 30, 30), seed=5)
    ref = decimate_in_blocks(vol, 10, count=900)
    again = []
    short = blocked.short_blocks
    monkeypatch.setattr(blocked, "short_blocks", lambda *a: again.append(short(*a)) or again[-1])
    monkeypatch.setattr(blocked, "RECORD_FLOOR", floor)
    monkeypatch.setattr(blocked, "RECORD_TAIL", 0.0)  # no record goes on past its floor
    out = decimate_in_blocks(vol, 10, count=900)
    assert all(np.array_equal(ref[k], out[k]) for k in ("vertices", "tets", "ptet"))
    assert (len(again[0]) > 0) == (floor > 0) == (out["stats"]["recorded_again"] > 0) and again[-1] == []


def count_recorded(monkeypatch):
    """A list that gets the length of every region's record (``region_decimate`` with ``costs``)."""
    from trivsel.decimation import blocked

    recorded = []
    region = blocked.region_decimate

    def spy(*a, costs=False, **k):
        out = region(*a, costs=costs, **k)
        if costs:
            recorded.append(len(out[0]))
        return out

    monkeypatch.setattr(blocked, "region_decimate", spy)
    return recorded


def test_quota_passes_record_only_up_to_their_limit_and_make_the_collapses_of_whole_records(monkeypatch):
    """Once the first quota pass has derived the quota passes' cost limit, the later ones stop
    recording at it (the cut takes nothing above it): the mesh of records that go on past it,
    with fewer collapses recorded.  A limit below the derived one would change the mesh."""
    from trivsel.decimation import blocked

    assert blocked.record_limit("seams", 2.0, 1.0) == 2.0
    assert blocked.record_limit("quota", 2.0, 1.0) == 1.0
    assert blocked.record_limit("quota", 2.0, None) == np.inf
    assert blocked.record_limit("rest", 2.0, 1.0) == np.inf
    vol = smooth_volume((30, 30, 30), seed=5)
    recorded = count_recorded(monkeypatch)
    ref = decimate_in_blocks(vol, 10, count=900)
    limited = sum(recorded)
    assert any(p["limit"] < np.inf for p in ref["stats"]["seam_passes"][1:])
    recorded.clear()
    monkeypatch.setattr(blocked, "record_limit", lambda kind, tau, limit: tau if kind == "seams" else np.inf)
    out = decimate_in_blocks(vol, 10, count=900)
    assert all(np.array_equal(ref[k], out[k]) for k in ("vertices", "tets", "ptet"))
    assert limited < sum(recorded)


@pytest.mark.parametrize("tail", [0.0, 10.0])
def test_a_block_recorded_to_any_floor_is_a_prefix_of_its_whole_record(tail, monkeypatch):
    """Pass 1's record of a block is the same sequence whatever its floor and tail: exact costs
    from twice its share down to RECORD_EXACT_TO of it, lazy after, wherever the record stops on
    the way, so the cut and pass 2 see prefixes of one sequence (a block with a flat part, whose
    collapses of cost 0 go on past the floor)."""
    from trivsel.decimation import blocked

    vol = smooth_volume((21, 21, 21), seed=7)
    vol[:, :9] = 0.0
    cuts, bounds = blocked.block_list(vol.shape, 10)
    seam_axes = [c[1:-1] for c in cuts]
    monkeypatch.setattr(blocked, "RECORD_TAIL", tail)
    lo, hi = bounds[0]
    values = vol[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1]
    whole = blocked.block_costs(values, lo, vol.shape, seam_axes, fraction=0.1, floor=0.0)[2]
    for floor in (0.25, 0.5, 1.0, 1.5):
        part = blocked.block_costs(values, lo, vol.shape, seam_axes, fraction=0.1, floor=floor)[2]
        assert 0 < len(part[0]) <= len(whole[0])
        assert all(np.array_equal(p, w[:len(p)]) for p, w in zip(part, whole)), floor


def test_a_region_replays_its_recorded_collapses_up_to_its_quota_to_the_mesh_of_its_run(monkeypatch):
    """Where a pass's cut takes only the first of a region's recorded collapses, they are replayed
    (no cost computed again): the mesh of the region run again to its quota."""
    from trivsel.decimation import blocked

    vol = smooth_volume((30, 30, 30), seed=5)
    calls = []
    region = blocked.region_decimate

    def spy(*a, recorded=None, **k):
        calls.append(recorded is not None)
        return region(*a, recorded=recorded, **k)

    monkeypatch.setattr(blocked, "region_decimate", spy)
    out = decimate_in_blocks(vol, 10, count=900)
    assert any(calls)  # some regions replayed
    monkeypatch.setattr(blocked, "region_decimate", lambda *a, recorded=None, **k: region(*a, **k))
    ran = decimate_in_blocks(vol, 10, count=900)
    assert all(np.array_equal(out[k], ran[k]) for k in ("vertices", "tets", "ptet"))


def test_a_small_count_in_small_blocks_stays_near_one_piece():
    """Blocks small against the tetrahedra near the stop: 900 of 27,000 points in blocks of 10.  The
    blocks' cut aims at twice the count, so the seam passes end above it, and the quota passes share
    the rest by one cost across their grids; taken from one grid's free vertices, as it once was,
    E_RMS was 7x one piece's."""
    from trivsel.decimation import reduce_by_collapse

    vol = smooth_volume((30, 30, 30), seed=5)
    out = decimate_in_blocks(vol, 10, count=900)
    check_tetrahedra(vol.shape, out["tets"])
    one = reduce_by_collapse(grid_from_array(vol), [900])[0][-1]
    assert len(out["vertices"]) == 900
    assert rms(residuals(vol, out)) <= 1.3 * rms(one.residuals)
    limits = [p["limit"] for p in out["stats"]["seam_passes"] if p["limit"] < np.inf]
    assert limits and len(set(limits)) == 1  # one cost for the quota passes


@pytest.mark.parametrize("n, target, block, noted", [
    (1000, 50, 32, False), (1000, 500, 64, False), (1000, 49, 32, True), (1000, 50, 16, True),
    (1000, 900, 31, True), (1000, None, 16, False)])
def test_a_count_in_blocks_is_noted_where_it_was_measured_to_lose(n, target, block, noted):
    """Blocks under FAITHFUL_BLOCK, or a count under FAITHFUL_FRACTION of the points, get one line that
    names the block, the share of the points and what to do; a tolerance alone (no count) gets none."""
    note = quality_note(n, target, block)
    assert (note is not None) == noted
    if noted:
        assert "\n" not in note and f"blocks of {block} to {100 * target / n:.3g} %" in note
        assert "use larger blocks" in note


def test_reduce_with_block_gives_the_count_and_errors_of_its_mesh():
    """``trivsel.reduce(..., block=B)``: one snapshot at the count, its errors those of its own
    tetrahedra (recomputed here), fitted values at least as good as the data values."""
    import trivsel

    vol = smooth_volume((33, 30, 27), seed=11)
    r = trivsel.reduce(vol, fractions=[0.05], method="decimate", block=10, values=("data", "fit"))
    (s,) = r.snapshots
    assert s.n_selected == count_for_fraction(0.05, vol.size) == 1337 and r.stats["blocks"] == 27
    check_tetrahedra(vol.shape, s.tets)
    out = decimate_in_blocks(vol, 10, fraction=0.05)
    assert np.array_equal(out["tets"], s.tets)
    assert np.allclose(residuals(vol, out), s.residuals, atol=1e-12)
    assert s.fit["errors"]["E_rms"] <= s.errors["E_rms"]
    assert r.options["block"] == 10
    assert r.notes == [quality_note(vol.size, 1337, 10)]  # blocks under 32: the run says what it may cost
    # to an E_RMS tolerance: the mesh of decimate_in_blocks, within it
    tol = 0.9 * s.errors["E_rms"]
    (t,) = trivsel.reduce(vol, tol_rms=tol, method="decimate", block=10).snapshots
    assert np.array_equal(t.tets, decimate_in_blocks(vol, 10, tol_rms=tol)["tets"])
    assert t.errors["E_rms"] <= tol


def test_the_cli_writes_the_blocked_mesh_and_suggests_block_when_memory_is_short(tmp_path, monkeypatch, capsys):
    import pyvista as pv

    from trivsel import resources
    from trivsel.cli import main

    vol = smooth_volume((21, 21, 21), seed=2)
    np.save(tmp_path / "v.npy", vol)
    assert main(["reduce", str(tmp_path / "v.npy"), "--block", "10", "--count", "600", "--values", "data", "fit",
                 "--out", str(tmp_path / "o")]) == 0
    assert "warning" not in capsys.readouterr().err
    (path,) = (tmp_path / "o").glob("mesh_*.vtu")
    m = pv.read(path)
    assert m.n_points == 600 and abs(m.volume - 20 ** 3) < 1e-6
    assert np.allclose(m.point_data["value"], vol.reshape(-1)[m.point_data["original_index"]])
    # blocks of 8 with tetrahedra as large: the regions free too few vertices, and the run says so
    assert main(["reduce", str(tmp_path / "v.npy"), "--block", "8", "--count", "300", "--out",
                 str(tmp_path / "o8")]) == 0
    err = capsys.readouterr().err
    stopped = re.search(r"count 300 not reached: the run stopped at (\d+) points \(no more vertices were free in "
                        r"the regions of blocks of 8: a larger block \(or one piece\) reaches the count\)", err)
    assert stopped and int(stopped.group(1)) > 300, err
    assert f"{int(stopped.group(1))}" in (tmp_path / "o8" / "errors.csv").read_text()

    # 8.1 M points need 3.8 GiB in one piece; with 2 GiB available, blocks of 48 fit, and every job
    # of decimate's in blocks of 32 (the step and last jobs hold the whole grid's arrays).  The grid
    # is sampled before the reduction weighs its memory, so it is kept this small: the refusal
    # and the command it names work alike for any grid too large for the memory.
    monkeypatch.setattr(resources, "available_bytes", lambda: 2 * 2**30)
    argv = ["reduce", "--function", "4", "--n", "200", "--method", "decimate", "--fractions", "0.05", "--out",
            str(tmp_path / "big")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # the refusal names decimate's jobs in blocks (regions of at most 1.5 GiB), and the one-process --block
    jobs = (f"trivsel blocks --function 4 --n 200 --method decimate --block 32 --fraction 0.05 --out "
            f"{tmp_path / 'big'} -c 2")
    assert len(err) == 1 and err[0].endswith(f"in blocks of bounded memory: {jobs} (or in one process: trivsel "
                                             + " ".join(argv) + " --block 48)"), err
    assert not (tmp_path / "big").exists()
    assert main(shlex.split(jobs)[1:] + ["-n"]) == 0  # the command named passes its own memory check
    capsys.readouterr()
    assert not (tmp_path / "big").exists()

    # 1025^3 points: decimate's step and tiles jobs hold the whole grid's arrays, more than any block
    # size leaves here; the refusal says what they need and names the bounded command that fits
    monkeypatch.setattr(resources, "available_bytes", lambda: 21 * 2**30)
    argv[4] = "1024"
    assert main(argv) == 2
    (err,) = capsys.readouterr().err.strip().splitlines()
    named = re.fullmatch(r".*; decimate in blocks \((trivsel blocks .*)\) needs about (\d+) GiB for its tiles job, "
                         r"so run it where a job may have that much; here, in bounded memory: (trivsel blocks .*) "
                         r"\(blocks stop at an E_inf tolerance TOL; they run paper or greedy\)", err)
    assert named and int(named.group(2)) > 21, err
    assert main(shlex.split(named.group(1))[1:] + ["-n"]) == 2
    assert "needs about" in capsys.readouterr().err
    assert main(shlex.split(named.group(3).replace("TOL", "0.01"))[1:] + ["-n"]) == 0
    capsys.readouterr()
    assert not (tmp_path / "big").exists()


def test_the_grid_weights_of_a_mesh_are_the_decimations_own_bit_for_bit():
    """:func:`point_weights` (integer signed volumes, in chunks of points) gives each point the
    vertices and weights that the decimation's kernel gives it."""
    from trivsel.decimation import Decimation
    from trivsel.decimation.blocked import point_weights, point_weights_of

    vol = smooth_volume((11, 9, 13), seed=2)
    data = grid_from_array(vol)
    dec = Decimation(data.ijk, data.shape, data.values)
    dec.run(90)
    verts, w = dec.point_weights()
    S = dec.S
    ptet = np.where(S.isv, -1, S.ptet)
    got_v, got_w = point_weights(vol.shape, np.asarray(S.T), ptet)
    assert np.array_equal(got_v, verts) and np.array_equal(got_w, w)
    assert (w > 0).any(axis=1).all() and ((w > 0) & (w < 1)).any()
    some = np.arange(5, vol.size, 7)
    part_v, part_w = point_weights_of(vol.shape, np.asarray(S.T), ptet, some)
    assert np.array_equal(part_v, verts[some]) and np.array_equal(part_w, w[some])


def test_the_quota_limit_of_records_to_the_share_is_that_of_whole_records():
    """Records cut at a cap give the limit of records to the whole cap once the regions whose
    record ends at or below the limit are recorded again; without that, the limit differs."""
    from trivsel.decimation.blocked import limit_of_whole_records, quota_limit, record_ends, short_regions

    rng = np.random.default_rng(4)
    whole = [np.sort(rng.exponential(s, 60)) for s in (1.0, 0.2, 3.0, 0.5)]
    caps, whole_caps = [20, 20, 20, 60], [60, 60, 60, 60]
    share, surplus = 0.5, 90
    cut = [w[:c] for w, c in zip(whole, caps)]
    assert quota_limit(held(cut), surplus, share) != quota_limit(held(whole), surplus, share)
    asked = []

    runmax = list(cut)

    def again(ks):
        asked.append(list(ks))
        for k in ks:
            runmax[k] = whole[k]

    limit, recorded = limit_of_whole_records(held(runmax), surplus, share, caps, whole_caps, again)
    assert limit == quota_limit(held(whole), surplus, share)
    assert recorded == [k for k in range(4)
                        if caps[k] < 60 and cut[k][-1] <= quota_limit(held(cut), surplus, share)]
    assert 0 < len(recorded) < 3 and len(asked) == 1  # the one whose record ends past the limit is not
    assert short_regions(record_ends(held(runmax)), [60] * 4, whole_caps, limit) == []


def test_the_first_quota_pass_recorded_to_the_share_gives_the_mesh_of_records_to_twice_it(monkeypatch):
    """The first quota pass records each region to its share of the surplus (and none again
    here); recorded to twice it, or to 16 collapses (regions recorded again), the meshes are
    the same, with a count, and with a count and a tolerance."""
    from trivsel.decimation import blocked

    vol = smooth_volume((40, 40, 40), seed=5)
    recorded = count_recorded(monkeypatch)
    for stop in (dict(count=3000), dict(count=3000, tol_rms=0.004)):
        runs = {}
        for times in (1, 2, 0):
            monkeypatch.setattr(blocked, "FIRST_QUOTA_RECORD", times)
            recorded.clear()
            out = decimate_in_blocks(vol, 10, **stop)
            runs[times] = out, sum(recorded), sum(p["recorded_again"] for p in out["stats"]["seam_passes"])
        ref = runs[1][0]
        for times in (2, 0):
            assert all(np.array_equal(ref[k], runs[times][0][k]) for k in ("vertices", "tets", "ptet"))
        assert runs[1][1] < runs[2][1] and runs[1][2] == 0 and runs[0][2] > 0


@st.composite
def recorded_blocks(draw):
    """Blocks' records as the cut reads them: running maxima of costs (ties and empty records
    among them), running squared errors, points off the seams, seam points, a target, a budget."""
    k = draw(st.integers(1, 6))
    levels = draw(st.integers(1, 40))
    scale = draw(st.sampled_from([1.0, 0.37, 1e-3]))
    runmax, sse, inner = [], [], []
    for _ in range(k):
        n = draw(st.integers(0, 150))
        costs = draw(st.lists(st.integers(0, levels), min_size=n, max_size=n))
        deltas = draw(st.lists(st.floats(-0.5, 2.0), min_size=n, max_size=n))
        runmax.append(np.maximum.accumulate(np.sort(np.asarray(costs, float) * scale)) if n else np.zeros(0))
        sse.append(running_sse(deltas))
        inner.append(n + draw(st.integers(0, 30)))
    seam = draw(st.integers(0, 200))
    target = draw(st.none() | st.integers(0, sum(inner) + seam + 5))
    most = sum(float(s[-1]) for s in sse if len(s))
    budget = draw(st.just(np.inf) | st.floats(0.0, 1.5).map(lambda f: f * (most + 1e-9) / SSE_SHARE))
    return runmax, sse, inner, seam, target, budget


@settings(max_examples=examples(2.0), deadline=None)
@given(recorded_blocks(), st.integers(1, 12), st.integers(1, 6))
def test_the_streamed_cut_is_the_cut_of_records_held_whole(blocks, runs, queries):
    """The cut job reads the blocks' records one at a time, keeping a sample of at most about
    ``runs`` of them and counting ``queries`` costs a stream: the same threshold, the same
    ``decided``, the same counts and squared error as of every record held at once, whatever
    the ties, empty records and budget."""
    runmax, sse, inner, seam, target, budget = blocks
    streams = []

    def read():
        streams.append(1)
        return zip(runmax, sse)

    tau, decided = threshold(runmax, inner, seam, target, sse, budget)
    assert streamed_threshold(read, inner, seam, target, budget, share=SSE_SHARE, runs=runs,
                              queries=queries) == (tau, decided)
    if np.isfinite(tau):
        counts = cut_counts(runmax, tau, inner, seam, target)
        assert streamed_cut_counts(read, tau, inner, seam, target, tied_counts) == (counts, sse_at(sse, counts))


def quota_cut_held_whole(runmax, sse, surplus, budget, limit):
    """The quota cut of every region's record held at once: its collapses by cost, then region,
    then place (a stable sort), none above ``limit``, the first ``surplus`` of them, and of those
    the longest prefix whose squared error (each region's at its count, summed in region order:
    :func:`sse_at`) fits in ``budget``."""
    rm = [r[:np.searchsorted(r, limit, side="right")] for r in runmax]
    value = np.concatenate(rm + [np.zeros(0)])
    region = np.repeat(np.arange(len(rm)), [len(r) for r in rm])
    order = np.lexsort((region, value))[:surplus]

    def counts(n):
        return np.bincount(region[order[:n]], minlength=len(rm)).tolist()

    n = len(order)
    if budget < np.inf:
        n = next((k - 1 for k in range(len(order) + 1) if sse_at(sse, counts(k)) > budget), n)
    return counts(n), sse_at(sse, counts(n))


@settings(max_examples=examples(2.0), deadline=None)
@given(recorded_blocks(), st.integers(1, 12), st.integers(1, 6), st.data())
def test_the_streamed_quota_cut_is_the_cut_of_records_held_whole(regions, runs, queries, data):
    """The quota job reads the regions' records one at a time, keeping a sample of at most about
    ``runs`` of them and counting ``queries`` costs a stream: the k-th cheapest cost (the quota
    limit) and the quota cut (the counts and the squared error they add, with and without a
    surplus, a limit and a budget) are those of every record held at once, whatever the ties and
    empty records; so is ``cut_quota``, which the passes in one process call."""
    runmax, sse, *_ = regions
    total = sum(len(r) for r in runmax)
    surplus = data.draw(st.none() | st.integers(1, total + 5))
    costs = sorted({float(c) for r in runmax for c in r})
    limit = data.draw(st.just(np.inf) | (st.sampled_from(costs) if costs else st.just(np.inf)))
    most = sum(float(s[-1]) for s in sse if len(s))
    budget = data.draw(st.just(np.inf) | st.floats(0.0, 1.2).map(lambda f: f * most))

    def read():
        return zip(runmax, sse)

    counts, spent = quota_cut_held_whole(runmax, sse, surplus, budget, limit)
    got = streamed_cut_quota(read, surplus, budget, limit, runs=runs, queries=queries)
    assert (list(got[0]), got[1]) == (counts, spent)
    held = cut_quota(runmax, surplus, sse, budget, limit)
    assert held[0].tolist() == counts and held[1] == spent
    every = np.sort(np.concatenate(runmax + [np.zeros(0)]))
    for k in (0, 1, 2, total // 2, total, total + 1):
        want = float(every[k - 1]) if 0 < k <= total else np.inf
        assert streamed_kth_cost(read, k, runs=runs, queries=queries) == want


def test_a_stream_keeps_a_bounded_sample_of_the_records():
    """Each stream of the cut keeps at most twice its runs (every m-th run of a block, m doubled
    as the sample grows), and a few streams narrow a million recorded costs to the answer."""
    from trivsel.decimation import streamcut

    rng = np.random.default_rng(1)
    runmax = [np.sort(rng.random(250_000)) for _ in range(4)]
    sse = [running_sse(rng.random(len(r))) for r in runmax]
    kept, streams = [], []
    sample = streamcut._stream_sample

    def spy(read, windows, runs):
        out, largest = sample(read, windows, runs)
        kept.extend(len(cat["cost"]) for cat, *_ in out)
        return out, largest

    def read():
        streams.append(1)
        return zip(runmax, sse)

    inner = [len(r) + 10 for r in runmax]
    want = threshold(runmax, inner, 5000, 300_000)
    import unittest.mock as mock

    with mock.patch.object(streamcut, "_stream_sample", spy):
        assert streamed_threshold(read, inner, 5000, 300_000, share=SSE_SHARE, runs=1000) == want
    assert max(kept) <= 2000 and 2 < len(streams) <= 12


@settings(max_examples=examples(0.5), deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.integers(0, 5), st.booleans(), st.integers(1, 7))
def test_a_pass_merged_in_place_is_the_pass_merged_into_new_arrays(seed, n_tets, regions, grow, chunk_log):
    """``merge_pass(in_place=True)`` (the step and last jobs: the kept rows moved up within
    ``T`` a chunk at a time) gives the same tetrahedra, owners, vertex flags and count as the
    merge into new arrays, with regions that give back fewer tetrahedra than they take, none,
    or more (then ``T`` has no room and new arrays are made)."""
    import trivsel.decimation.blocked as blocked

    rng = np.random.default_rng(seed)
    N = 60
    T = rng.integers(0, N, (n_tets, 4)).astype(np.int32)
    isv = rng.random(N) < 0.5
    owner = np.where(isv, -1, rng.integers(0, n_tets, N)).astype(np.int32)
    taken = rng.permutation(n_tets)[:rng.integers(0, n_tets + 1)]
    cuts = np.sort(rng.integers(0, len(taken) + 1, regions))
    starts, ends = np.r_[0, cuts], np.r_[cuts, len(taken)]
    plan = {"order": taken, "starts": starts, "ends": ends}
    vertices, points = rng.permutation(np.flatnonzero(isv)), rng.permutation(np.flatnonzero(~isv))
    results = []
    for k in range(len(starts)):
        size = ends[k] - starts[k]
        nt = rng.integers(0, N, (size + rng.integers(1, 4) if grow else rng.integers(0, size + 1), 4))
        rem, vertices = vertices[:rng.integers(0, 3)], vertices[2:]
        nonv, points = points[:rng.integers(0, 4)], points[3:]
        rows = rng.integers(0, max(len(nt), 1), len(nonv)) if len(nt) else np.zeros(0, np.int64)
        results.append((rem, nt.astype(np.int32), nonv if len(nt) else nonv[:0], rows))
    monkey = blocked.PLAN_CHUNK
    blocked.PLAN_CHUNK = 2 ** chunk_log
    try:
        want = blocked.merge_pass(T.copy(), owner.copy(), isv, plan, lambda: iter(results))
        got = blocked.merge_pass(T.copy(), owner.copy(), isv, plan, lambda: iter(results), in_place=True)
    finally:
        blocked.PLAN_CHUNK = monkey
    for a, b in zip(want, got):
        assert np.array_equal(a, b) and np.asarray(a).dtype == np.asarray(b).dtype


def _fit_rms(vol, out, fitted):
    """E_RMS over every grid point of ``out``'s mesh with vertex values ``fitted``."""
    from trivsel.decimation.blocked import point_weights

    verts, w = point_weights(vol.shape, out["tets"], out["ptet"])
    col = np.full(vol.size, -1)
    col[out["vertices"]] = np.arange(len(out["vertices"]))
    return float(np.sqrt(np.mean((vol.reshape(-1) - np.einsum("ij,ij->i", w, fitted[col[verts]])) ** 2)))


@pytest.fixture(scope="module")
def ridge_in_blocks():
    """A volume with a ridge, decimated in blocks of 8 to 8 %, and its whole mesh's least-squares fit."""
    from trivsel.decimation.blocked import point_weights
    from trivsel.fitting import fit_vertex_values

    vol = smooth_volume((29, 26, 25), seed=5)
    out = decimate_in_blocks(vol, 8, fraction=0.08)
    verts, w = point_weights(vol.shape, out["tets"], out["ptet"])
    whole, _ = fit_vertex_values(verts, w, vol.reshape(-1), out["vertices"])
    return vol, out, whole


def test_every_grid_point_has_one_tile():
    """A point on a cut belongs to the block above it, the last cut to the last block."""
    cuts = (np.array([0, 4, 9]), np.array([0, 3]), np.array([0, 5, 10, 12]))
    i = np.array([0, 3, 4, 8, 9, 9])
    j = np.array([0, 3, 1, 2, 0, 3])
    k = np.array([0, 4, 5, 10, 12, 11])
    assert tile_of((i, j, k), cuts).tolist() == [0, 0, 4, 5, 5, 5]


def test_the_tile_fit_is_the_whole_mesh_fit_to_its_rings(ridge_in_blocks):
    """Solved tile by tile, with three rings of tetrahedra around each tile, the fit's E_RMS is
    the whole mesh's least-squares fit's within a part in a million (never below it: that one
    is the least); without rings, the tiles' seams cost a part in a hundred."""
    vol, out, whole = ridge_in_blocks
    cuts = [block_cuts(n, 8) for n in vol.shape]
    best = _fit_rms(vol, out, whole)
    tiled = tile_fit(vol.shape, cuts, out["tets"], out["ptet"], out["vertices"], vol.reshape(-1))
    bare = tile_fit(vol.shape, cuts, out["tets"], out["ptet"], out["vertices"], vol.reshape(-1), rings=0)
    assert best * (1 - 1e-9) <= _fit_rms(vol, out, tiled) <= best * (1 + 1e-6)
    assert _fit_rms(vol, out, bare) > best * (1 + 1e-3)


def test_a_tile_fit_of_one_tile_is_the_whole_mesh_fit(ridge_in_blocks):
    """With one tile (every vertex an unknown of one solve) the values are the whole mesh's fit,
    to the solver's tolerance."""
    vol, out, whole = ridge_in_blocks
    cuts = [np.array([0, n - 1]) for n in vol.shape]
    one = tile_fit(vol.shape, cuts, out["tets"], out["ptet"], out["vertices"], vol.reshape(-1))
    assert np.allclose(one, whole, rtol=0, atol=1e-8 * np.abs(whole).max())


def test_a_tile_solved_from_its_surroundings_alone_is_the_whole_tile_fit(ridge_in_blocks):
    """The mesh kept by tile (``mesh_tiles``): each point in one tile, each tetrahedron in every
    tile its corners' box meets.  Read from the tiles that meet the box a tile's solve may
    reach (``mesh_meeting``), the tetrahedra are exactly those that meet the box, with each
    point's tetrahedron; the tile's fit from them alone (``fit_tile``) is ``tile_fit``'s over
    the whole mesh, to the bit."""
    from trivsel.decimation.blocked import (fit_reach, fit_tile, mesh_meeting, mesh_tiles, tet_boxes, tet_extent,
                                            tile_box, tiles_meeting)

    vol, out, _ = ridge_in_blocks
    shape, T, ptet, f = vol.shape, out["tets"], out["ptet"], vol.reshape(-1)
    cuts = [block_cuts(n, 8) for n in shape]
    whole = tile_fit(shape, cuts, T, ptet, out["vertices"], f)
    tiles = list(mesh_tiles(shape, cuts, T, ptet, chunk=1000))
    corners = np.stack(np.unravel_index(T, shape), axis=-1)
    tmin, tmax = corners.min(axis=1), corners.max(axis=1)

    def meeting(lo, hi):
        return np.flatnonzero(np.all((tmin <= hi) & (tmax >= lo), axis=1))

    assert sum(len(o) for _, _, o in tiles) == vol.size and len(tiles) == np.prod([len(c) - 1 for c in cuts])
    for t, (tets, rows, _) in enumerate(tiles):
        assert np.array_equal(rows, meeting(*tile_box(shape, cuts, t))) and np.array_equal(tets, T[rows])
    assert sum(len(r) for _, r, _ in tiles) > len(T)  # tetrahedra across the seams are kept twice or more
    col = np.full(vol.size, -1)
    col[out["vertices"]] = np.arange(len(out["vertices"]))
    vtile = tile_of(np.unravel_index(out["vertices"], shape), cuts)
    for t in range(len(tiles)):
        lo, hi = fit_reach(shape, cuts, t)
        tets, rows, lptet, ext = mesh_meeting(shape, lo, hi, [(*tiles[u], *tile_box(shape, cuts, u),
                                                                tet_boxes(shape, tiles[u][0]))
                                                               for u in tiles_meeting(cuts, lo, hi)])
        assert np.array_equal(rows, meeting(lo, hi)) and np.array_equal(tets, T[rows])
        assert ext == tet_extent(shape, tets)
        ids = np.ravel_multi_index(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij"),
                                   shape).ravel()
        g = ptet[ids]
        assert np.array_equal(lptet == -1, g < 0) and np.array_equal(rows[lptet[g >= 0]], g[g >= 0])
        verts, columns = np.unique(tets, return_inverse=True)
        own, got = fit_tile(shape, cuts, t, tets, lptet, lo, hi, f[ids], verts, f[verts], extent=ext)
        assert np.array_equal(own, out["vertices"][vtile == t]) and len(own)
        assert np.array_equal(got, whole[col[own]])
        # with the corners' places among the vertices given, as the fit jobs give them
        own2, got2 = fit_tile(shape, cuts, t, tets, lptet, lo, hi, f[ids], verts, f[verts], extent=ext,
                              columns=columns.reshape(tets.shape))
        assert np.array_equal(own2, own) and np.array_equal(got2, got)


def test_grid_coordinates_are_kept_in_the_least_type_that_holds_them():
    """The tiles keep their tetrahedra's boxes as grid coordinates: int16 up to an edge of 32768
    points (coordinates to 32767), int32 beyond, so no coordinate wraps."""
    from trivsel.decimation.blocked import coordinate_type

    assert coordinate_type((32768, 5, 5)) is np.int16 and coordinate_type((5, 32768, 5)) is np.int16
    assert coordinate_type((5, 5, 32769)) is np.int32 and coordinate_type((40000, 40000, 2)) is np.int32
    for n in (32768, 32769):
        t = coordinate_type((n, 2, 2))
        assert int(np.array(n - 1).astype(t)) == n - 1
