"""The orientation predicates against exact rational arithmetic, on inputs where a float
determinant cannot decide the sign: points on a plane perturbed by one ulp, and small
configurations far from the origin.  Every double is a rational number, so
``fractions.Fraction`` gives the true sign of the determinant."""

from fractions import Fraction

import numpy as np
import pytest

from trivsel.decimation.collapse import _orient
from trivsel.mesh.validation import orientation_signs
from trivsel.predicates import orient3d_exact_sign, orient3d_float_sign


def exact_orient(a, b, c, d):
    """``det[b - a, c - a, d - a]`` of the exact rational values of the coordinates."""
    a, b, c, d = ([Fraction(x) if isinstance(x, float) else Fraction(int(x)) for x in p] for p in (a, b, c, d))
    u = [b[i] - a[i] for i in range(3)]
    v = [c[i] - a[i] for i in range(3)]
    w = [d[i] - a[i] for i in range(3)]
    return (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
            + u[2] * (v[0] * w[1] - v[1] * w[0]))


def sign(x):
    return (x > 0) - (x < 0)


def float_det(a, b, c, d):
    """The plain float determinant, as a filter without an error bound would take it."""
    return float(np.linalg.det(np.array([np.subtract(b, a), np.subtract(c, a), np.subtract(d, a)])))


def near_degenerate(seed, n):
    """``n`` quadruples (a, b, c, d) with d on the plane of a, b, c up to rounding and then
    moved by a few ulps, at scales from 1e-3 to 1e15 (so that the determinant is at the
    rounding level of its terms, where a float filter cannot decide), and a few exactly
    flat ones far from the origin; their true signs are positive, negative and zero."""
    rng = np.random.default_rng(seed)
    cases = []
    for k in range(n):
        scale = 10.0 ** rng.integers(-3, 16)
        a, b, c = (scale * rng.uniform(-1, 1, 3) for _ in range(3))
        s, t = rng.random(2)
        d = a + s * (b - a) + t * (c - a)
        # 1 ulp up or down in one coordinate, or a few; or left as rounded
        axis = rng.integers(0, 3)
        for _ in range(rng.integers(0, 4)):
            d[axis] = np.nextafter(d[axis], np.inf if k % 2 else -np.inf)
        cases.append(tuple(tuple(float(x) for x in p) for p in (a, b, c, d)))
    # exactly coplanar (the sign is 0): d = b + c - a on integers near 1e15, exact in doubles
    for k in range(40):
        a, b, c = (1e15 + rng.integers(-50, 50, 3).astype(float) for _ in range(3))
        cases.append(tuple(tuple(float(x) for x in p) for p in (a, b, c, b + c - a)))
    # and a tiny step on a huge coordinate, flat and not
    big = 2.0**52
    cases.append(((big, 0.0, 0.0), (big + 1, 0.0, 0.0), (big, 1.0, 0.0), (big + 3, 5.0, 0.0)))
    cases.append(((1e15, 1e15, 1e15), (1e15 + 0.125, 1e15, 1e15), (1e15, 1e15 + 0.125, 1e15),
                  (1e15, 1e15, 1e15 + 0.125)))
    cases.append(((1e15, 1e15, 1e15), (1e15 + 0.125, 1e15, 1e15), (1e15, 1e15 + 0.125, 1e15),
                  (1e15 + 0.125, 1e15 + 0.125, 1e15)))
    return cases


CASES = near_degenerate(seed=7, n=400)


def test_the_cases_are_ones_a_float_determinant_gets_wrong():
    """Otherwise the test below would not exercise the exact fallback."""
    truth = [sign(exact_orient(*q)) for q in CASES]
    naive = [sign(float_det(*q)) for q in CASES]
    wrong = sum(t != s for t, s in zip(truth, naive))
    assert wrong >= len(CASES) // 5, wrong
    assert all(truth.count(s) >= 20 for s in (-1, 0, 1)), [truth.count(s) for s in (-1, 0, 1)]


def _flat(q):
    return [x for p in q for x in p]


def test_orient3d_float_sign_is_exact_where_the_filter_cannot_decide():
    for q in CASES:
        want = sign(exact_orient(*q))
        assert orient3d_float_sign(*_flat(q)) == want, q
        assert orient3d_exact_sign(*_flat(q)) == want, q
        # an odd permutation flips the sign, an even one keeps it
        a, b, c, d = q
        assert orient3d_float_sign(*_flat((b, a, c, d))) == -want, q
        assert orient3d_float_sign(*_flat((b, c, a, d))) == want, q


def test_orient3d_float_sign_on_clear_cases():
    rng = np.random.default_rng(1)
    for _ in range(200):
        q = [tuple(float(x) for x in rng.normal(size=3)) for _ in range(4)]
        assert orient3d_float_sign(*_flat(q)) == sign(exact_orient(*q))


@pytest.mark.parametrize("extent", [3, 1000, 2**20])
def test_decimation_integer_orientation_is_the_exact_determinant(extent):
    """``_orient`` of the decimation kernels, on int64 grid coordinates: the exact sign, and
    the exact value as a double (exact below 2^53), including flat and nearly flat tets."""
    rng = np.random.default_rng(extent)
    P = rng.integers(0, extent, size=(64, 3)).astype(np.int64)
    # exactly coplanar quadruples: points of the plane z = x + 2 y (mod nothing: kept small)
    flat = rng.integers(0, max(2, extent // 4), size=(16, 2))
    P[:16] = np.column_stack([flat[:, 0], flat[:, 1], flat[:, 0] + 2 * flat[:, 1]])
    quads = [tuple(rng.choice(64, 4, replace=False)) for _ in range(300)]
    quads += [tuple(rng.choice(16, 4, replace=False)) for _ in range(50)]
    zero = 0
    for a, b, c, d in quads:
        want = exact_orient(P[a], P[b], P[c], P[d])
        assert _orient(P, False, a, b, c, d) == float(want), (a, b, c, d)
        zero += want == 0
    assert zero >= 50


def test_the_mesh_checkers_own_orientation_is_exact():
    """``check_mesh`` tests orientation without the kernels' predicates: its own test must be
    exact too, on the same near-flat float inputs and on integers."""
    pts = np.array([p for q in CASES for p in q])
    tets = np.arange(len(pts)).reshape(-1, 4)
    want = [sign(exact_orient(*q)) for q in CASES]
    assert orientation_signs(pts, tets).tolist() == want
    rng = np.random.default_rng(5)
    ijk = rng.integers(-2**40, 2**40, size=(100, 4, 3))  # products beyond int64 and float precision
    ijk[50:, 3] = ijk[50:, 1] + ijk[50:, 2] - ijk[50:, 0]  # flat
    ijk[75:, 3, 0] += 1  # flat but for one unit
    ijk = ijk.reshape(-1, 3)
    tets = np.arange(400).reshape(-1, 4)
    assert orientation_signs(ijk, tets).tolist() == [sign(exact_orient(*ijk[t])) for t in tets]
