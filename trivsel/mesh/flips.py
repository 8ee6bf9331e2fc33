"""The flip configurations of section 4 (Figs. 2-3): which tets a flip replaces, and by which.

Configuration 1 (Fig. 2) is two tets sharing a face or, equivalently, three tets
around an edge: the 2-3 flip (:func:`config23`) and the 3-2 flip
(:func:`quads32`) exchange them.  Configuration 2 (Fig. 3) is four tets around
an edge whose four other vertices are coplanar: the 4-4 flip (:func:`quads44`)
replaces the edge by either diagonal of that quad.  On the hull, two tets
around an edge between coplanar hull faces form the boundary 2-2 flip (the
:func:`quads32` construction on an open ring, :func:`edge_ring_open`).

Each function only fills ``old`` (the tets replaced) and ``newq`` (the new
quadruples); admissibility (positive volumes) and the change itself belong to
:mod:`trivsel.mesh.geometry` and :mod:`trivsel.mesh.storage`.
"""

from __future__ import annotations

from .cache import njit

from .geometry import EDGE_EVEN, FACE_IN, _sign
from .storage import _other_index

# the kinds of flips (also the kinds of swap's memory keys and the order of the flip counters)
FLIP23, FLIP32, FLIP44, FLIP22 = 0, 1, 2, 3


@njit(cache=True)
def config23(S, t, i, old, newq):
    """Configuration 1 seen as two tets (Fig. 2, left): t and its neighbour across face i.

    ::

              d                 d
             /|\\              /|\\
            / | \\            / | \\
          f1--+--f3   2->3  f1--d-e--f3   (edge d-e pierces the face f1 f2 f3)
            \\ | /            \\ | /
             \\|/              \\|/
              e                 e

    Fills old[:2] and newq[:3] with (f1, f2, e, d), (f2, f3, e, d), (f3, f1, e, d);
    returns False when face i is on the hull.
    """
    return _config23_at(S.tets, S.nbr, t, i, old, newq)


@njit(cache=True, _nrt=False)
def _config23_at(tets, nbr, t, i, old, newq):
    """:func:`config23` on the mesh arrays (see :func:`_edge_ring`)."""
    u = nbr[t, i]
    if u < 0:
        return False
    d = tets[t, i]
    f1 = tets[t, FACE_IN[i, 0]]
    f2 = tets[t, FACE_IN[i, 1]]
    f3 = tets[t, FACE_IN[i, 2]]
    e = tets[u, _other_index(tets, u, f1, f2, f3)]
    old[0] = t
    old[1] = u
    newq[0, 0], newq[0, 1], newq[0, 2], newq[0, 3] = f1, f2, e, d
    newq[1, 0], newq[1, 1], newq[1, 2], newq[1, 3] = f2, f3, e, d
    newq[2, 0], newq[2, 1], newq[2, 2], newq[2, 3] = f3, f1, e, d
    return True


@njit(cache=True, _nrt=False)
def _edge_opposite(tets, t, a, b):
    """The two vertices (x, y) of tet t other than edge (a, b), with orient3d(a, b, x, y) > 0.

    Every tet of the mesh is positively oriented (:func:`~trivsel.mesh.validation.check_mesh` tests it), so
    the sign is the parity of the local-index permutation (:data:`EDGE_EVEN`), not a
    predicate: this runs for every edge of every tet of O in every swap round.
    """
    i = -1
    j = -1
    x = -1
    y = -1
    for m in range(4):
        v = tets[t, m]
        if v == a:
            i = m
        elif v == b:
            j = m
        elif x < 0:
            x = v
        else:
            y = v
    if not EDGE_EVEN[i, j]:
        x, y = y, x
    return x, y


@njit(cache=True)
def edge_ring(S, t, a, b, old, ring):
    """Tets around edge (a, b) starting at t, and the ring of opposite vertices.

    Walks face to face around the edge.  Fills old[:k] and ring[:k] ordered so that
    orient3d(a, b, ring[j], ring[j+1]) > 0 and tet old[j] = {a, b, ring[j], ring[j+1]}.
    Returns k for a closed ring (interior edge) of at most old.shape[0] tets, -1
    for an edge on the hull, or -2 for a longer ring.
    """
    return _edge_ring(S.tets, S.nbr, S.omark, -1, t, a, b, old, ring)


@njit(cache=True, _nrt=False)
def _edge_ring(tets, nbr, om, st, t, a, b, old, ring):
    """:func:`edge_ring` on the arrays themselves: taking them out of the state
    would cost reference counting per walk, and swapping walks around every edge
    of every tet of O in every round.

    For the scan of O in :func:`~trivsel.mesh.swap.swap` it gives up (returns -3) as soon as the walk meets
    a tet of O (``om[u] == st``) with a smaller id than t, from which the scan
    evaluates this edge instead (every configuration once, from its smallest tet in
    O): about half of the walks stop early.  ``st = -1`` (no stamp) walks the whole
    ring."""
    cap = old.shape[0]
    x, y = _edge_opposite(tets, t, a, b)
    k = 0
    cur = t
    while True:
        if k >= cap:
            return -2
        old[k] = cur
        ring[k] = x
        k += 1
        j = _other_index(tets, cur, a, b, y)  # local index of x in cur
        nxt = nbr[cur, j]
        if nxt < 0:
            return -1
        if nxt == t:
            return k
        if nxt < t and om[nxt] == st:
            return -3
        z = tets[nxt, _other_index(tets, nxt, a, b, y)]
        x = y
        y = z
        cur = nxt


@njit(cache=True)
def edge_ring_open(S, t, a, b, old, ring):
    """Tets around a hull edge (a, b): an open ring from one hull face to the other.

    Fills old[:k] and ring[:k + 1] (tet old[j] = {a, b, ring[j], ring[j+1]}, ordered
    as in :func:`edge_ring`) and returns k, or -1 if the edge is interior or the
    ring is longer than old.shape[0].
    """
    return _edge_ring_open_at(S.tets, S.nbr, t, a, b, old, ring)


@njit(cache=True, _nrt=False)
def _edge_ring_open_at(tets, nbr, t, a, b, old, ring):
    """:func:`edge_ring_open` on the arrays themselves (see :func:`_edge_ring`)."""
    cap = old.shape[0]
    x, y = _edge_opposite(tets, t, a, b)
    # walk backwards (across the face (a, b, x)) to the first tet of the open ring
    cur = t
    steps = 0
    while True:
        j = _other_index(tets, cur, a, b, x)  # local index of y
        prv = nbr[cur, j]
        if prv < 0:
            break
        if prv == t or steps > 64:
            return -1  # closed ring: an interior edge
        w = tets[prv, _other_index(tets, prv, a, b, x)]
        y = x
        x = w
        cur = prv
        steps += 1
    # walk forwards (across the face (a, b, y)) to the other hull face
    k = 0
    while True:
        if k >= cap:
            return -1
        old[k] = cur
        ring[k] = x
        k += 1
        j = _other_index(tets, cur, a, b, y)
        nxt = nbr[cur, j]
        if nxt < 0:
            ring[k] = y
            return k
        z = tets[nxt, _other_index(tets, nxt, a, b, y)]
        x = y
        y = z
        cur = nxt


@njit(cache=True)
def quads32(a, b, ring, newq):
    """Configuration 1 seen as three tets around edge (a, b) -> two tets (Fig. 2, right to left).

    ::

          a               a
         /|\\             / \\
      c1-+-c3   3->2   c1---c3     the edge a-b is removed; the triangle
         \\|/             \\ /       (c1, c2, c3) becomes the shared face
          b               b
    """
    newq[0, 0], newq[0, 1], newq[0, 2], newq[0, 3] = a, ring[0], ring[1], ring[2]
    newq[1, 0], newq[1, 1], newq[1, 2], newq[1, 3] = ring[0], ring[1], ring[2], b


@njit(cache=True)
def quads44(a, b, ring, alt, newq):
    """Configuration 2 (Fig. 3): four tets around edge (a, b) -> the other diagonal.

    ::

              a                      a
           /  |  \\               /     \\
        c4 ---+--- c2   4->4   c4 ----- c2     edge a-b replaced by c1-c3 (alt 0)
        c1    |    c3          c1 \\   / c3     or by c2-c4 (alt 1)
           \\  |  /               \\ b /
              b

    The ring c1 c2 c3 c4 is ordered as returned by :func:`edge_ring`.
    """
    c1 = ring[alt]
    c2 = ring[(alt + 1) % 4]
    c3 = ring[(alt + 2) % 4]
    c4 = ring[(alt + 3) % 4]
    newq[0, 0], newq[0, 1], newq[0, 2], newq[0, 3] = a, c1, c2, c3
    newq[1, 0], newq[1, 1], newq[1, 2], newq[1, 3] = a, c3, c4, c1
    newq[2, 0], newq[2, 1], newq[2, 2], newq[2, 3] = c1, c2, c3, b
    newq[3, 0], newq[3, 1], newq[3, 2], newq[3, 3] = c3, c4, c1, b


@njit(cache=True, _nrt=False)
def _config22_at(S, om, st, t, a, b, old, old2, ring, newq):
    """The boundary 2-2 flip of hull edge (a, b) of tet t, if it has one.

    ::

        a-------r0              a-------r0
        | \\      |              |      / |
        |   \\    |     2->2     |    /   |     two coplanar hull faces: the planar
        |     \\  |              |  /     |     quad (a, r0, b, r2) takes its other
        r2------b              r2-------b     diagonal r0-r2 (the tets' apex r1 is below)

    Two tets around the edge, whose hull faces (a, b, r0) and (a, b, r2) are
    coplanar: they are replaced by the two tets on the quad's other diagonal, the
    :func:`quads32` construction on the open ring (r0, r1, r2).  Fills old[:2] and
    newq[:2] and returns True, or returns False if the edge has no such
    configuration or it is to be considered from a smaller tet id in O (marked
    ``st`` in ``om``).  ``old2`` is room for the ring walk.
    """
    k2 = _edge_ring_open_at(S.tets, S.nbr, t, a, b, old2, ring)
    if k2 != 2 or _sign(S.ijk, S.points, S.opt.use_int, a, b, ring[0], ring[2]) != 0:
        return False
    if (old2[0] < t and om[old2[0]] == st) or (old2[1] < t and om[old2[1]] == st):
        return False  # considered from its smaller tet
    quads32(a, b, ring, newq)
    old[0] = old2[0]
    old[1] = old2[1]
    return True
