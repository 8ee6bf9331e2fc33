"""Property-based tests: `reduce` on generated point sets (random, clustered, nearly degenerate,
anisotropic, tiny and huge scales) either gives a valid mesh, checked after every snapshot by the
mesh-validity checker, or refuses the input with a one-line InputError.

The number of cases comes from the hypothesis profile in conftest.py (1000 in CI)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, note
from hypothesis import strategies as st

import trivsel
from trivsel.mesh import check_mesh

KINDS = ("uniform", "clustered", "slab", "anisotropic", "grid-jitter")


@st.composite
def point_sets(draw):
    kind = draw(st.sampled_from(KINDS))
    n = draw(st.integers(5, 48))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        p = rng.random((n, 3))
    elif kind == "clustered":
        centres = rng.random((draw(st.integers(1, 3)), 3))
        p = centres[rng.integers(0, len(centres), n)] + 0.02 * rng.standard_normal((n, 3))
    elif kind == "slab":  # nearly coplanar: a thin slab
        p = rng.random((n, 3)) * [1.0, 1.0, draw(st.sampled_from([1e-2, 1e-4, 1e-7]))]
    elif kind == "anisotropic":
        p = rng.random((n, 3)) * 10.0 ** rng.uniform(-3, 3, 3)
    else:  # a grid with a little jitter: many near-coplanar and near-cospherical quadruples
        m = int(np.ceil(n ** (1 / 3))) + 1
        g = np.stack(np.meshgrid(*[np.arange(m)] * 3, indexing="ij"), -1).reshape(-1, 3).astype(float)
        # jitter 0 is exactly cospherical and coplanar (flat Delaunay tetrahedra: see FIXTURES)
        jitter = draw(st.sampled_from([0.0, 1e-12, 1e-9, 1e-3, 1e-2]))
        p = g[rng.permutation(len(g))[:n]] + jitter * rng.random((n, 3))
    scale = 10.0 ** draw(st.integers(-6, 6))
    offset = draw(st.sampled_from([0.0, 1.0, 1e3]))
    p = p * scale + offset * scale
    f = np.sin(3 * p[:, 0] / scale) + (p[:, 1] / scale) ** 2 - p[:, 2] / scale
    f = f * 10.0 ** draw(st.integers(-6, 6)) + 0.01 * rng.standard_normal(n) * draw(st.sampled_from([0, 1]))
    note(f"kind={kind} n={n} seed={seed} scale={scale:g} offset={offset:g}")
    return p, f


@given(point_sets(), st.sampled_from(["paper", "greedy"]), st.floats(0.05, 1.0), st.booleans())
def test_reduce_gives_a_valid_mesh_or_a_clean_refusal(pf, method, fraction, final_pass):
    points, values = pf
    try:
        data = trivsel.scattered(points, values)
    except trivsel.InputError as exc:  # duplicates, coplanar points, too few points
        assert "\n" not in str(exc)
        return
    fractions = [fraction, 1.0]
    try:
        r = trivsel.reduce(data, fractions=fractions, method=method, final_pass=final_pass, check=check_mesh)
    except trivsel.InputError as exc:
        assert "\n" not in str(exc)
        assert "fewer than the" in str(exc), str(exc)  # the fraction is below the hull's vertices
        r = trivsel.reduce(data, fractions=[1.0], method=method, final_pass=final_pass, check=check_mesh)
    full = r.snapshots[-1]
    frange = float(np.ptp(values)) or 1.0
    assert full.errors["E_inf"] <= 1e-9 * frange  # every point a vertex, or (greedy) nothing left to fix
    assert full.n_selected == data.n_points or method == "greedy"
    for s in r.snapshots:
        assert np.isfinite(s.errors["E_rms"]) and np.isfinite(s.errors["E_inf"])
        assert len(np.unique(s.selected)) == s.n_selected


#: Point sets that once broke the geometry, each named for what makes it hard.
FIXTURES = {
    # exactly on an integer grid: cospherical and coplanar hull points, so Qhull's Delaunay
    # triangulation of the hull vertices contains a flat tetrahedron
    "grid-subset-flat-delaunay": np.array(
        [[1, 0, 0], [2, 1, 0], [1, 2, 3], [0, 2, 0], [2, 3, 0], [1, 1, 3], [3, 1, 1], [0, 1, 0], [3, 2, 2],
         [3, 0, 2], [0, 2, 2], [0, 0, 2], [2, 2, 2], [2, 0, 2], [1, 0, 3], [2, 3, 3], [0, 2, 3], [3, 2, 1],
         [2, 1, 1]], float),
}


def _grid_subset(n, seed, jitter, offset):
    """The first n points of a shuffled 5^3 (or smaller) integer grid, jittered and shifted."""
    rng = np.random.default_rng(seed)
    m = int(np.ceil(n ** (1 / 3))) + 1
    g = np.stack(np.meshgrid(*[np.arange(m)] * 3, indexing="ij"), -1).reshape(-1, 3).astype(float)
    return g[rng.permutation(len(g))[:n]] + jitter * rng.random((n, 3)) + offset


FIXTURES["grid-subset-nearly-cospherical-far-from-origin"] = _grid_subset(28, 153945, 1e-9, 1000.0)


@pytest.mark.parametrize("name, method, n, scale", [
    ("grid-subset-flat-delaunay", "paper", 18, 0.1),
    ("grid-subset-flat-delaunay", "greedy", 19, 1.0),
    ("grid-subset-nearly-cospherical-far-from-origin", "paper", 28, 1.0),
])
def test_named_fixtures_that_broke_the_start_mesh(name, method, n, scale):
    """Qhull's Delaunay tetrahedra of these hull vertices include a flat one (exact grid)
    or misplace the hull (nearly cospherical, far from the origin)."""
    p = FIXTURES[name][:n] * scale
    f = np.sin(3 * p[:, 0] / scale) + (p[:, 1] / scale) ** 2 - p[:, 2] / scale
    trivsel.reduce(trivsel.scattered(p, f), fractions=[1.0], method=method, check=check_mesh)


def _hypothesis_examples(ci):
    """``{test: max_examples}`` of every hypothesis test, as collected under CI=true or not."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    here = Path(__file__).parent
    code = ("import importlib, json, sys; sys.path.insert(0, sys.argv[1]); import conftest\n"
            "out = {}\n"
            "for name in sys.argv[2:]:\n"
            "    m = importlib.import_module(name)\n"
            "    for k, f in vars(m).items():\n"
            "        s = getattr(f, '_hypothesis_internal_use_settings', None)\n"
            "        if s is not None and hasattr(f, 'hypothesis'):\n"
            "            out[name + '.' + k] = s.max_examples\n"
            "print(json.dumps(out))\n")
    modules = sorted(p.stem for p in here.glob("test_*.py") if "@given" in p.read_text())
    env = {**os.environ, "CI": "true" if ci else "false"}
    r = subprocess.run([sys.executable, "-c", code, str(here), *modules], capture_output=True, text=True, env=env,
                       check=True)
    return json.loads(r.stdout)


def test_every_hypothesis_test_runs_more_examples_in_ci():
    """No @given test fixes its own count: each follows the profile (CI=true: 1000 examples
    where a plain run has 150), scaled for tests whose cases cost more or less."""
    dev, ci = _hypothesis_examples(False), _hypothesis_examples(True)
    assert set(dev) == set(ci) and len(dev) >= 7, sorted(dev)
    for name in dev:
        assert ci[name] >= 6 * dev[name], (name, dev[name], ci[name])
