"""What each option of the ranking and of the swaps does, not only that it is accepted:
every test here fails if its option were ignored (``docs/options.md`` says what each does)."""

import numpy as np
import pytest

import trivsel
from trivsel.data import sample_grid
from trivsel.mesh import TetMesh, check_mesh


def quantised(K, order, quantum):
    """The sort key of the ranking: K rounded to multiples of ``quantum * max K``."""
    return np.round(K[order] / (quantum * np.abs(K[order]).max())).astype(np.int64)


@pytest.fixture(scope="module")
def tied():
    """A quadratic (function 1): its curvature is the same at every interior point, up to
    rounding, so the candidates come in large groups of ties."""
    d = sample_grid(1, 6)
    return d, {t: trivsel.reduce(d, count=40, tie_order=t, seed=3) for t in ("index", "reverse", "centre", "random")}


def _tie_groups(r):
    order = r.order
    key = quantised(r.curvature, order, r.options["quantum"])
    assert np.all(np.diff(key) <= 0)  # descending curvature first
    groups = [order[key == k] for k in np.unique(key)]
    assert max(len(g) for g in groups) >= 20, [len(g) for g in groups]  # the function does have ties
    return groups


def test_tie_order_orders_each_group_of_equal_curvature(tied):
    d, runs = tied
    for g in _tie_groups(runs["index"]):
        assert np.all(np.diff(g) > 0)
    for g in _tie_groups(runs["reverse"]):
        assert np.all(np.diff(g) < 0)
    centre = d.points.mean(axis=0)
    for g in _tie_groups(runs["centre"]):
        assert np.all(np.diff(np.linalg.norm(d.points[g] - centre, axis=1)) >= -1e-9)
    big = max(_tie_groups(runs["random"]), key=len)
    assert not np.all(np.diff(big) > 0) and not np.all(np.diff(big) < 0)
    # the same groups in each case: only the order within them changes
    for t in ("reverse", "centre", "random"):
        assert [sorted(g) for g in _tie_groups(runs[t])] == [sorted(g) for g in _tie_groups(runs["index"])]


def test_random_tie_order_follows_the_seed():
    d = sample_grid(1, 6)
    a, b, c = (trivsel.reduce(d, count=40, tie_order="random", seed=s).order for s in (1, 1, 2))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_ranking_ascending_reverses_the_curvature_order():
    d = sample_grid(4, 6)
    desc = trivsel.reduce(d, count=40)
    asc = trivsel.reduce(d, count=40, ranking="ascending")
    q = desc.options["quantum"]
    assert np.all(np.diff(quantised(desc.curvature, desc.order, q)) <= 0)
    assert np.all(np.diff(quantised(asc.curvature, asc.order, q)) >= 0)
    assert sorted(asc.order) == sorted(desc.order)
    assert asc.curvature[asc.order[0]] < asc.curvature[asc.order[-1]]


def test_ranking_random_is_no_curvature_order():
    d = sample_grid(4, 6)
    r = trivsel.reduce(d, count=40, ranking="random", seed=4)
    key = quantised(r.curvature, r.order, r.options["quantum"])
    assert np.any(np.diff(key) > 0) and np.any(np.diff(key) < 0)


def test_quantum_merges_near_equal_curvatures_into_index_ordered_ties():
    """A coarse quantum makes curvatures within 10 % of the largest one tie; ties then go in
    index order, so the ranking differs from the fine one."""
    d = sample_grid(4, 6)
    fine = trivsel.reduce(d, count=40)
    coarse = trivsel.reduce(d, count=40, quantum=0.1)
    key = quantised(coarse.curvature, coarse.order, 0.1)
    assert len(np.unique(key)) <= 11
    assert np.all(np.diff(key) <= 0)
    for k in np.unique(key):
        assert np.all(np.diff(coarse.order[key == k]) > 0)
    assert not np.array_equal(fine.order, coarse.order)


def test_rel_tol_is_the_least_relative_gain_of_a_flip():
    """A flip must lower the criterion sum by more than rel_tol times it: rel_tol = 1 asks for
    a negative sum, so nothing flips; the default flips."""
    d = sample_grid(4, 6)
    default = trivsel.reduce(d, fractions=[0.3], check=check_mesh)
    never = trivsel.reduce(d, fractions=[0.3], rel_tol=1.0, check=check_mesh)
    assert sum(default.stats["flips"].values()) > 20
    assert sum(never.stats["flips"].values()) == 0
    some = trivsel.reduce(d, fractions=[0.3], rel_tol=0.5, check=check_mesh)
    assert 0 < sum(some.stats["flips"].values()) < sum(default.stats["flips"].values())


def _one_flip_gains(first_improving, steps=60):
    """For each of the next ``steps`` points of a run: from the same mesh, insert it and make
    one flip (best or first improving); the criterion sum's decrease by that flip."""
    d = sample_grid(5, 6)
    r = trivsel.reduce(d, fractions=[0.2])
    snap = r.snapshots[0]
    rest = [p for p in r.order if p not in set(snap.selected.tolist())]
    gains = []
    for p in rest[:steps]:
        tm = TetMesh(d.points, d.values, d.ijk, first_improving=first_improving, max_rounds=1)
        tm.start(snap.tets)
        _, ids = tm.insert(p)
        before = tm.criterion_sum()
        n = tm.swap(ids)
        gains.append(before - tm.criterion_sum() if n else 0.0)
    return np.array(gains)


def test_first_improving_applies_a_flip_no_better_than_the_best():
    best, first = _one_flip_gains(False), _one_flip_gains(True)
    assert np.all((best > 0) == (first > 0))  # an improving flip exists for both or neither
    assert np.all(best >= first - 1e-12)
    assert np.sum(best > first + 1e-12) >= 3  # and the first one found is often not the best


def test_first_improving_changes_the_run_and_keeps_a_valid_mesh():
    d = sample_grid(4, 6)
    a = trivsel.reduce(d, fractions=[0.3, 0.15], check=check_mesh)
    b = trivsel.reduce(d, fractions=[0.3, 0.15], first_improving=True, check=check_mesh)
    assert a.stats["flips"] != b.stats["flips"]
    assert not np.array_equal(a.snapshots[-1].tets, b.snapshots[-1].tets)


@pytest.mark.parametrize("criterion", ["rms", "max"])
def test_vertices_in_error_counts_a_tets_own_vertices(criterion):
    """The criterion sum (eqs. 14-15) recomputed from the buckets and the residuals: under
    RMS a tet's own four vertices add 4 to its point count only with vertices_in_error; the
    max error is the same either way (their residual is 0)."""
    d = sample_grid(4, 6)
    r = trivsel.reduce(d, fractions=[0.2])
    tets = r.snapshots[0].tets
    sums = {}
    for own in (True, False):
        tm = TetMesh(d.points, d.values, d.ijk, criterion=criterion, vertices_in_error=own)
        tm.start(tets)
        res, _ = tm.residuals()
        want = 0.0
        for t, q in zip(tm.live_ids(), tm.tetrahedra()):
            b = np.setdiff1d(tm.bucket(t), q)
            rr = res[b]
            n = len(b) + (4 if own else 0)
            want += (np.sqrt(np.sum(rr**2) / n) if n else 0.0) if criterion == "rms" else np.max(np.abs(rr),
                                                                                                  initial=0.0)
        assert np.isclose(tm.criterion_sum(), want, rtol=1e-12), own
        sums[own] = want
    if criterion == "rms":
        assert sums[True] < sums[False] * 0.99
    else:
        assert sums[True] == sums[False]
