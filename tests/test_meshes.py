"""`decimate` off the grid: scattered points (their Delaunay tetrahedra) and tetrahedral
meshes read with their cells, whose domain (possibly non-convex) must be kept exactly."""

import json
import subprocess
import sys

import numpy as np
import pytest

import trivsel
from trivsel.data import scattered
from trivsel.decimation import Decimation
from trivsel.decimation.tetmesh import check_mesh_keeps_domain, mesh_volume, start_mesh
from trivsel.exceptions import InputError
from trivsel.triangulation import boundary_triangles, kuhn_tetrahedra


def smooth(p):
    return np.sin(3 * p[:, 0]) + p[:, 1] ** 2 - np.cos(2 * p[:, 2])


def grid_mesh(shape, keep_cell, *, jitter=0.0, origin=0.0, seed=0):
    """The Kuhn split of the unit cells of ``shape`` points for which ``keep_cell(i, j, k)``
    holds, over the points its tetrahedra use, interior points jittered (a float mesh)."""
    pts = np.stack(np.meshgrid(*(np.arange(s, dtype=float) for s in shape), indexing="ij"), -1).reshape(-1, 3)
    tets = kuhn_tetrahedra(shape)
    cell = np.floor(pts[tets].mean(axis=1)).astype(int)
    tets = tets[np.array([keep_cell(*c) for c in cell])]
    used = np.unique(tets)
    remap = np.full(len(pts), -1)
    remap[used] = np.arange(len(used))
    pts, tets = pts[used], remap[tets]
    inner = np.ones(len(pts), bool)
    inner[np.unique(boundary_triangles(tets))] = False
    rng = np.random.default_rng(seed)
    pts[inner] += rng.uniform(-jitter, jitter, (inner.sum(), 3))
    return pts + origin, tets


def l_shape(n=6, **kw):
    """An L-shaped prism: (2n x 2n x n cells) without the quadrant x, y >= n."""
    return grid_mesh((2 * n + 1, 2 * n + 1, n + 1), lambda i, j, k: not (i >= n and j >= n), **kw)


def hollow_cube(n=6, **kw):
    """A cube of (3n)^3 cells with a cubic cavity of n^3 cells in its middle."""
    return grid_mesh((3 * n + 1,) * 3, lambda i, j, k: not all(n <= c < 2 * n for c in (i, j, k)), **kw)


def write_vtu(path, pts, tets, values, **arrays):
    """A .vtu of tetrahedra with the point array ``value`` and ``arrays``: point arrays by name,
    or cell arrays (length ``len(tets)``)."""
    import pyvista as pv

    g = pv.UnstructuredGrid({pv.CellType.TETRA: tets}, pts)
    g.point_data["value"] = values
    for name, a in arrays.items():
        (g.cell_data if len(a) == len(tets) and len(a) != len(pts) else g.point_data)[name] = a
    g.save(path)


def corner_vertices(p, tets):
    """The boundary vertices whose boundary triangles span three or more planes."""
    b = boundary_triangles(tets)
    n = np.cross(p[b[:, 1]] - p[b[:, 0]], p[b[:, 2]] - p[b[:, 0]])
    n = np.round(n / np.linalg.norm(n, axis=1, keepdims=True), 9)
    planes = {}
    for tri, normal in zip(b, map(tuple, n)):
        for v in tri:
            planes.setdefault(int(v), set()).add(normal)
    return np.array(sorted(v for v, s in planes.items() if len(s) >= 3))


def decimated(pts, f, tets=None, count=None):
    d = scattered(pts, f)
    d.tets = tets
    t0, located, _ = start_mesh(d)
    dec = Decimation.on_mesh(pts, t0, f, located=located)
    dec.run(count if count is not None else len(pts) // 10)
    return t0, dec


# ----------------------------------------------------------------------------- validity


def test_scattered_points_keep_their_hull_and_every_point_inside():
    rng = np.random.default_rng(3)
    p = rng.random((3000, 3))
    p[:8] = np.indices((2, 2, 2)).reshape(3, -1).T  # the unit cube is the hull
    t0, dec = decimated(p, smooth(p), count=200)
    assert dec.n_vertices == 200
    check_mesh_keeps_domain(p, t0, dec.tetrahedra())
    assert mesh_volume(p, dec.tetrahedra()) == pytest.approx(1.0, rel=1e-12)
    verts, w = dec.point_weights()
    assert (w >= 0).all() and np.allclose(w.sum(axis=1), 1.0)
    # every residual is that of the interpolant of the tetrahedron holding the point
    L = np.einsum("ij,ij->i", w, smooth(p)[verts])
    assert np.allclose(smooth(p) - L, dec.residuals(), atol=1e-12)


@pytest.mark.parametrize("shape", [l_shape, hollow_cube])
def test_non_convex_meshes_keep_their_domain(shape):
    p, t = shape(4, jitter=0.2, origin=1e6)  # far from the origin: the predicates' exact path decides
    f = smooth(p - 1e6)
    t0, dec = decimated(p, f, t, count=len(p) // 8)
    out = dec.tetrahedra()
    check_mesh_keeps_domain(p, t0, out)
    assert mesh_volume(p, out) == pytest.approx(mesh_volume(p, t0), rel=1e-9)
    # the domain's corners (where three or more boundary planes meet) never move
    assert set(corner_vertices(p, t0).tolist()) <= set(dec.vertices().tolist())


def test_hollow_cube_keeps_its_cavity():
    p, t = hollow_cube(3)
    t0, dec = decimated(p, smooth(p), t, count=60)
    out = dec.tetrahedra()
    check_mesh_keeps_domain(p, t0, out)
    assert mesh_volume(p, out) == pytest.approx(26 * 27, rel=1e-12)
    cavity = boundary_triangles(out)
    inner = np.all((p[cavity] >= 3) & (p[cavity] <= 6), axis=(1, 2))
    assert inner.sum() >= 12  # the cavity's six square faces, two triangles at least each


@pytest.mark.parametrize("kind", ["nearly coplanar", "cospherical", "lattice"])
def test_degenerate_point_sets(kind):
    rng = np.random.default_rng(5)
    if kind == "nearly coplanar":
        p = np.c_[rng.random((400, 2)), 1e-9 * rng.random(400)]
        p[:4, 2] = [0.0, 1.0, 0.5, 0.25]  # a few points off the near-plane
    elif kind == "cospherical":
        u = rng.normal(size=(300, 3))
        p = np.r_[u / np.linalg.norm(u, axis=1, keepdims=True), [[0.0, 0.0, 0.0]]]
    else:
        p = np.indices((7, 7, 7)).reshape(3, -1).T.astype(float)
    t0, dec = decimated(p, smooth(p), count=len(p) // 4)
    check_mesh_keeps_domain(p, t0, dec.tetrahedra())
    verts, w = dec.point_weights()
    assert (w >= 0).all()


def test_lattice_points_keep_the_box():
    p = np.indices((7, 7, 7)).reshape(3, -1).T.astype(float)
    r = trivsel.reduce(scattered(p, smooth(p)), count=40, method="decimate")
    s = r.snapshots[-1]
    assert s.n_selected == 40
    assert mesh_volume(p, s.tets) == pytest.approx(216.0, rel=1e-12)


# ----------------------------------------------------------------------------- quality and API


def test_decimate_beats_greedy_on_scattered_points_with_fitted_values():
    rng = np.random.default_rng(1)
    p = rng.random((4000, 3))
    d = scattered(p, smooth(p) + 0.3 * np.sin(9 * p[:, 1]))
    e = {m: trivsel.reduce(d, fractions=[0.1], method=m, values=("data", "fit")).snapshots[-1].fit["errors"]
         for m in ("greedy", "decimate")}
    assert e["decimate"]["E_rms"] < 0.9 * e["greedy"]["E_rms"]


def test_auto_runs_decimate_on_data_and_the_paper_on_functions():
    rng = np.random.default_rng(2)
    p = rng.random((300, 3))
    assert trivsel.reduce(scattered(p, smooth(p)), fractions=[0.2]).options["method"] == "decimate"
    assert trivsel.reduce(p[:, 0].reshape(-1)[:27].reshape(3, 3, 3), fractions=[0.5]).options["method"] == "decimate"
    assert trivsel.reduce(4, n=4, fractions=[0.5]).options["method"] == "paper"
    assert trivsel.reduce(4, n=4, fractions=[0.5], method="auto").options["method"] == "paper"


def test_mesh_file_through_the_cli(tmp_path):
    import pyvista as pv

    p, t = l_shape(3, jitter=0.15)
    f = smooth(p)
    velocity = np.c_[p[:, 0], -p[:, 1], p[:, 2] ** 2]
    write_vtu(tmp_path / "l.vtu", p, t, f, velocity=velocity, material=np.arange(len(t)) % 3)
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "trivsel", "reduce", str(tmp_path / "l.vtu"), "--array", "value",
                        "--fractions", "0.3",
                        "--values", "data", "fit", "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    result = json.loads((out / "result.json").read_text())
    assert result["options"]["method"] == "decimate" and result["data"]["tetrahedra"] == len(t)
    assert any("cell data (material)" in n for n in result["notes"])
    m = pv.read(out / "mesh_0.3.vtu")
    ids = m.point_data["original_index"]
    assert np.array_equal(m.points, p[ids])  # the file's point ids, the file's coordinates
    assert np.array_equal(m.point_data["velocity"], velocity[ids]) and "material" not in m.cell_data
    tets = ids[m.cells_dict[pv.CellType.TETRA]]
    check_mesh_keeps_domain(p, t, tets)


def test_voxel_cells_are_split_and_said_so(tmp_path):
    """A .vtu of voxel cells (and a boundary triangle) is a mesh: each voxel is Kuhn-split into
    6 tetrahedra whose union is the voxels' union, and result.json says which cells were split
    and which were not used."""
    import pyvista as pv

    from trivsel.io import load

    corners = np.indices((2, 2, 2)).reshape(3, -1).T[:, ::-1]  # corner i + 2 j + 4 k at (i, j, k)
    pts = np.indices((4, 3, 3)).reshape(3, -1).T.astype(float)
    idx = {tuple(q): n for n, q in enumerate(pts.astype(int).tolist())}
    cells = [[idx[tuple(c)] for c in (np.array(c0) + corners).tolist()]
             for c0 in np.ndindex(3, 2, 2) if c0 != (1, 1, 1)]  # 11 voxels around a notch
    g = pv.UnstructuredGrid({pv.CellType.VOXEL: np.array(cells), pv.CellType.TRIANGLE: np.array([[0, 1, 3]])}, pts)
    g.point_data["value"] = smooth(pts)
    g.save(tmp_path / "vox.vtu")
    d = load(tmp_path / "vox.vtu")
    assert len(d.tets) == 6 * len(cells)
    assert np.isclose(mesh_volume(pts, d.tets), len(cells))  # the voxels' union
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "trivsel", "reduce", str(tmp_path / "vox.vtu"), "--fractions", "0.5",
                        "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    notes = json.loads((out / "result.json").read_text())["notes"]
    assert any(f"the input's {len(cells)} voxel cells were each split into 6 tetrahedra" in n for n in notes)
    assert any("the input's 1 cells of lower dimension" in n for n in notes)
    m = pv.read(out / "mesh_0.5.vtu")
    check_mesh_keeps_domain(pts, d.tets, m.point_data["original_index"][m.cells_dict[pv.CellType.TETRA]])


def test_mesh_in_a_notebook_is_a_mesh():
    import pyvista as pv

    p, t = l_shape(3)
    g = pv.UnstructuredGrid({pv.CellType.TETRA: t}, p)
    g.point_data["value"] = smooth(p)
    s = trivsel.reduce(g, fractions=[0.4]).snapshots[-1]
    check_mesh_keeps_domain(p, t, s.tets)


# ----------------------------------------------------------------------------- refusals


def test_bad_meshes_are_refused_with_one_line(tmp_path):
    import pyvista as pv

    p, t = l_shape(2)
    f = smooth(p)
    flat = t.copy()
    flat[0] = [0, 1, 2, 2]
    cases = {"repeats a vertex": flat}
    coplanar = np.flatnonzero(p[:, 2] == 0)[:4]
    cases["is flat"] = np.r_[t, [coplanar]]
    cases["is a face of 3"] = np.r_[t, t[:1]]
    for message, tets in cases.items():
        with pytest.raises(InputError, match=message) as err:
            d = scattered(p, f)
            d.tets = tets
            trivsel.reduce(d, fractions=[0.5])
        assert "\n" not in str(err.value)
    hexa = pv.UnstructuredGrid({pv.CellType.HEXAHEDRON: np.array([[0, 1, 2, 3, 4, 5, 6, 7]])},
                               np.indices((2, 2, 2)).reshape(3, -1).T.astype(float)[[0, 4, 6, 2, 1, 5, 7, 3]])
    hexa.point_data["value"] = np.arange(8.0)
    hexa.save(tmp_path / "hex.vtu")
    with pytest.raises(InputError, match="hexahedron cells"):
        trivsel.reduce(tmp_path / "hex.vtu", fractions=[0.5])
    g = pv.UnstructuredGrid({pv.CellType.TETRA: t}, p)
    g.point_data["value"] = f
    with pytest.raises(InputError, match="would drop the mesh's"):
        trivsel.reduce(g, fractions=[0.5], method="greedy")


def test_duplicate_points_are_refused():
    p = np.random.default_rng(0).random((50, 3))
    p[7] = p[3]
    with pytest.raises(InputError, match="duplicate point"):
        trivsel.reduce(scattered(p, np.zeros(50)), count=10, method="decimate")


def test_a_mesh_on_a_float_lattice_takes_the_exact_integer_path():
    from trivsel.decimation import C_FLOAT, lattice_coordinates

    p, t = hollow_cube(2)
    q = -3.7 + np.round(p).astype(int) * 0.1  # a grid written with spacing 0.1: not exact in binary
    ijk = lattice_coordinates(q)
    assert ijk is not None and np.array_equal(ijk, np.round(p).astype(int))
    assert lattice_coordinates(q + 1e-9 * np.random.default_rng(0).random(q.shape)) is None  # a real shift
    dec = Decimation.on_mesh(q, t, smooth(p))
    assert dec.S.ctr[C_FLOAT] == 0
    dec.run(40)
    check_mesh_keeps_domain(q, t, dec.tetrahedra())


def test_face_multiplicity_counts_each_triangle_by_its_key_and_by_rows():
    """The counts of equal sorted triples, on the int64-key path and on the row path
    (indices too large for one key), against a dictionary count."""
    from collections import Counter

    from trivsel.triangulation import face_multiplicity

    rng = np.random.default_rng(3)
    for hi in (40, 2**22):  # 40^3 fits one int64 key; (2^22)^3 does not
        rows = np.sort(rng.integers(0, hi, (3000, 3)), axis=1)
        rows = np.concatenate([rows, rows[:700], rows[:90]])  # faces seen once, twice and three times
        rng.shuffle(rows)
        seen = Counter(map(tuple, rows.tolist()))
        assert face_multiplicity(rows).tolist() == [seen[tuple(r)] for r in rows.tolist()]


def test_the_face_table_groups_each_triangle_as_a_sort_of_the_face_rows_would():
    """``face_table`` without the (4 M, 3) array of faces: the order of a stable lexicographic
    sort of the sorted face rows, each face's count of its triangle and its winding's parity,
    on the int64-key path and on the column path (ids too large for one key), in chunks of
    any size; ``boundary_triangles`` from it are the faces seen once, in face order."""
    from scipy.spatial import Delaunay

    from trivsel.triangulation import FACES, face_table, tet_faces

    rng = np.random.default_rng(5)
    for n in (5, 60, 400):
        t = Delaunay(rng.random((n, 3))).simplices.astype(np.int64)
        t = np.concatenate([t, t[: len(t) // 3][:, [1, 0, 2, 3]]])  # triangles in three and four tets, folded copies
        faces = np.concatenate([t[:, f] for f in FACES])
        rows = np.sort(faces, axis=1)
        order = np.lexsort(rows.T[::-1])
        odd = np.array([sum(a > b for i, a in enumerate(f) for b in f[i + 1:]) % 2 == 1 for f in faces.tolist()])
        count = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
        count = count[2][count[1].ravel()]
        for shift, chunk in ((0, 1 << 20), (0, 7), (2**40, 5)):  # (2^40)^3 does not fit one key
            ft = face_table(t + shift, chunk=chunk)
            assert np.array_equal(ft["order"], order) and np.array_equal(ft["count"], count)
            assert np.array_equal(ft["odd"], odd)
            sr = rows[order]
            assert np.array_equal(ft["start"], np.flatnonzero(np.r_[True, (sr[1:] != sr[:-1]).any(axis=1)]))
            assert np.array_equal(tet_faces(t + shift, np.arange(len(faces))), faces + shift)
        assert np.array_equal(boundary_triangles(t), faces[count == 1])


def test_a_mesh_files_memory_estimate_counts_its_tetrahedra(monkeypatch):
    """decimate's memory check of a tetrahedral mesh weighs its tetrahedra, not its points
    alone: refused where the points' figure for a grid would have passed."""
    import trivsel.resources as res
    from scipy.spatial import Delaunay

    from trivsel.methods import decimate as dmeth

    rng = np.random.default_rng(0)
    p = rng.random((300, 3))
    t = Delaunay(p).simplices.astype(np.int64)
    data = scattered(p, p[:, 0])
    data.tets = t
    assert dmeth.MESH_BYTES_PER_TET * len(t) > dmeth.BYTES_PER_POINT * len(p)
    monkeypatch.setattr(res, "available_bytes", lambda: dmeth.BYTES_PER_POINT * len(p) + 1)
    with pytest.raises(InputError, match=rf"^decimating a mesh of 300 points and {len(t)} tetrahedra needs about"):
        trivsel.reduce(data, fractions=[0.5], method="decimate")
    monkeypatch.setattr(res, "available_bytes", lambda: dmeth.MESH_BYTES_PER_TET * len(t) + 1)
    assert trivsel.reduce(data, fractions=[0.5], method="decimate").snapshots[-1].n_selected == 150


def test_exact_signs_agree_with_the_robust_predicate_near_flat_tetrahedra():
    """Signs from the fast flat-array volumes with the exact fallback: nearly flat
    tetrahedra (a fourth point a few ulps off the plane of three) and exactly flat ones get
    the sign of the robust predicate, and the volumes equal the reference formula to rounding."""
    from trivsel.predicates import orient3d_float_sign
    from trivsel.triangulation import _exact_signs, _signed_volumes6, orient3d_float

    rng = np.random.default_rng(5)
    a, b, c = rng.uniform(-1, 1, (3, 200, 3))
    s, t = rng.uniform(0.1, 0.4, (2, 200, 1))
    on = a + s * (b - a) + t * (c - a)
    d = on + rng.integers(-3, 4, (200, 3)) * np.spacing(np.abs(on))
    # and 20 exactly flat ones, on integer coordinates
    a[:20], b[:20], c[:20] = rng.integers(-50, 50, (3, 20, 3))
    d[:20] = a[:20] + 2 * (b[:20] - a[:20]) - 3 * (c[:20] - a[:20])
    p = np.concatenate([a, b, c, d])
    tets = np.arange(800).reshape(4, 200).T
    want = [orient3d_float_sign(*p[i], *p[j], *p[k], *p[m]) for i, j, k, m in tets]
    assert 0 in want and 1 in want and -1 in want
    assert _exact_signs(p, tets).tolist() == want
    ref = orient3d_float(p, tets)
    assert np.allclose(_signed_volumes6(p, tets), ref, rtol=0, atol=1e-12)
