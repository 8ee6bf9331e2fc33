r"""The blocks' cost threshold (:func:`trivsel.decimation.blocked.threshold`) without their
recorded sequences in memory at once.

The cut of ``decimate`` in blocks compares counts and squared errors of every block's recorded
sequence (running maxima of collapse costs, non-decreasing, and the running squared error
beside them) at candidate thresholds.  Held whole, the sequences take 16 bytes a recorded
collapse, about every point of the grid.  Here they are read one block at a time, again for
each *stream*, and only a bounded sample of them is kept:

    window   (a, b]: the costs between the last candidate known to fail and the first known
             to hold (at first every cost); a block's costs in it are a slice of its sequence
    runs     a block's equal costs in a row count as one (ties: flat data); a run is its
             cost, its block, the count up to its end and the squared error there
    sample   every m-th run of each block's slice, m doubled (and the sample thinned)
             whenever it grows past ``RUNS``: at most 2 RUNS runs are held
    queries  up to ``QUERIES`` costs of the sample, evenly spaced; the next stream counts
             every block's sequence at each of them exactly, which narrows the window to
             the two queries around the answer
    exact    once a stream keeps every run of the window (m = 1), the answer is found
             among them by bisection, each step counting exactly

Each predicate (the count left at a threshold falls to the aim; the projected squared error
passes the budget's share) is monotone in the threshold, so the smallest cost where it holds
is what :func:`~trivsel.decimation.blocked.threshold`'s bisection over every distinct cost
finds, and the sums are taken in block order as there, so the results are the same, bit for
bit.  A window holds at most ``RUNS * (1 / QUERIES + blocks / RUNS)`` of the last one's runs, so
a few streams suffice even at 10^9 recorded collapses.

The quota passes' cut across their regions (:func:`streamed_cut_quota`,
:func:`streamed_kth_cost`) is found the same way: the k-th cheapest cost is the smallest where
at least k are at or below it; the counts take every collapse below one cost and share the
ties at it out region by region; and with a budget, the longest run of the cut's order whose
squared error (each region's at its count, summed in region order) fits in it is found by the
same search, then among the ties at the cost where it first does not fit.
"""

from __future__ import annotations

import bisect

import numpy as np

INF = np.inf
#: The runs of the window a stream keeps at most (twice this, before it thins them)
RUNS = 1 << 17
#: The costs of the sample whose counts the next stream finds exactly
QUERIES = 256

__all__ = ["streamed_threshold", "streamed_cut_counts", "streamed_kth_cost", "streamed_cut_quota", "RUNS", "QUERIES"]


def _sums(counts, sse_terms):
    """The collapses and the squared error (summed in block order, as
    :func:`~trivsel.decimation.blocked.sse_at` sums them) of the blocks' sequences cut at
    ``counts`` (``sse_terms``: each block's running squared error there, 0 where none)."""
    total_sse = np.cumsum(np.asarray(sse_terms, np.float64))  # sequential, as sum() over the blocks
    return int(np.sum(counts, dtype=np.int64)), (float(total_sse[-1]) if len(total_sse) else 0.0)


class _Window:
    """One predicate's search: the smallest cost where it holds lies in ``(lo, hi]``."""

    def __init__(self, holds):
        self.holds = holds  # holds(n_collapses, sse) -> bool, monotone (false, then true)
        self.lo, self.hi = -INF, INF
        self.answer = None  # (cost, found); found False: it holds nowhere
        self.queries = None
        self.whole = False  # keep every run of the window (a round that did not narrow it)


def _stream_sample(read, windows, runs):
    """One stream: each open window's runs, every m-th of each block's slice (m doubled as
    needed).  Returns, per window, the runs kept (cost, block, count, squared error), the
    counts and errors at its lower end per block, and m; and the largest recorded cost."""
    state, largest = [], None
    for w in windows:
        state.append({"cost": [], "block": [], "count": [], "sse": [], "index": [], "m": 1, "kept": 0,
                      "base_c": [], "base_s": []})
    for i, (r, s) in enumerate(read()):
        if len(r):
            largest = float(r[-1]) if largest is None else max(largest, float(r[-1]))
        for w, st in zip(windows, state):
            a = int(np.searchsorted(r, w.lo, side="right")) if w.lo > -INF else 0
            b = int(np.searchsorted(r, w.hi, side="right")) if w.hi < INF else len(r)
            st["base_c"].append(a)
            st["base_s"].append(float(s[a - 1]) if a > 0 else 0.0)
            if b <= a:
                continue
            piece = r[a:b]
            ends = np.flatnonzero(np.r_[piece[1:] != piece[:-1], True])  # the last of each run of equal costs
            index = np.arange(len(ends), dtype=np.int64)
            keep = (index + 1) % st["m"] == 0
            ends, index = ends[keep], index[keep]
            st["cost"].append(piece[ends])
            st["block"].append(np.full(len(ends), i, np.int64))
            st["count"].append(a + ends + 1)
            st["sse"].append(np.asarray(s[a + ends], np.float64))
            st["index"].append(index)
            st["kept"] += len(ends)
            while st["kept"] > 2 * runs and not w.whole:  # twice the step, every other run of the sample
                st["m"] *= 2
                for name in ("cost", "block", "count", "sse", "index"):
                    st[name] = [np.concatenate(st[name])]
                keep = (st["index"][0] + 1) % st["m"] == 0
                for name in ("cost", "block", "count", "sse", "index"):
                    st[name] = [st[name][0][keep]]
                st["kept"] = int(keep.sum())
    out = []
    for st in state:
        cat = {k: (np.concatenate(st[k]) if st[k] else np.zeros(0, np.float64 if k in ("cost", "sse") else np.int64))
               for k in ("cost", "block", "count", "sse")}
        out.append((cat, np.asarray(st["base_c"], np.int64), np.asarray(st["base_s"], np.float64), st["m"]))
    return out, largest


def _exact_smallest(w, cat, base_c, base_s):
    """The smallest cost of a window's every run (``cat``) where ``w`` holds, by bisection."""
    order = np.lexsort((cat["block"], cat["cost"]))  # by cost, then block: each block's runs stay in order
    cost, block = cat["cost"][order], cat["block"][order]
    count, sse = cat["count"][order], cat["sse"][order]
    distinct = np.unique(cost)

    def holds(t):
        upto = np.searchsorted(cost, t, side="right")  # the runs at or below t, a prefix of the order
        c, s = base_c.copy(), base_s.copy()
        # each block's last run at or below t (a block's runs come in order of cost)
        blocks, from_end = np.unique(block[:upto][::-1], return_index=True)
        last = upto - 1 - from_end
        c[blocks], s[blocks] = count[last], sse[last]
        return w.holds(*_sums(c, s))

    return distinct, bisect.bisect_left(range(len(distinct)), True, key=lambda k: holds(distinct[k]))


def _query_stream(read, windows):
    """One stream: the collapses and squared error of every block at each window's queries."""
    acc = [(np.zeros(len(w.queries), np.int64), np.zeros(len(w.queries), np.float64)) for w in windows]
    for r, s in read():
        for w, (n, e) in zip(windows, acc):
            c = np.searchsorted(r, w.queries, side="right")
            n += c
            e += np.where(c > 0, np.asarray(s, np.float64)[np.maximum(c - 1, 0)] if len(s) else 0.0, 0.0)
    return acc


def _smallest_costs(read, predicates, runs, queries):
    """For each monotone predicate ``holds(n_collapses, sse)`` of the blocks' sequences cut at a
    threshold, the smallest recorded cost where it holds: ``(cost, below, found)`` with ``below`` the largest recorded cost under it (None if none)
    and ``found`` False where it holds at no recorded cost (``cost`` is then the largest)."""
    windows = [_Window(p) for p in predicates]
    while any(w.answer is None for w in windows):
        open_ = [w for w in windows if w.answer is None]
        sampled, largest = _stream_sample(read, open_, runs)
        asking = []
        for w, (cat, base_c, base_s, m) in zip(open_, sampled):
            if m == 1:  # every run of the window: the answer among them
                distinct, k = _exact_smallest(w, cat, base_c, base_s)
                if k < len(distinct):
                    below = float(distinct[k - 1]) if k > 0 else (None if w.lo == -INF else float(w.lo))
                    w.answer = (float(distinct[k]), below, True)
                elif w.hi < INF:  # the upper end is a cost where it holds (a query)
                    below = float(distinct[-1]) if len(distinct) else (None if w.lo == -INF else float(w.lo))
                    w.answer = (float(w.hi), below, True)
                else:
                    w.answer = (largest, None, False)
                continue
            d = np.unique(cat["cost"])
            pick = np.unique(np.linspace(0, len(d) - 1, min(queries, len(d))).round().astype(np.int64))
            w.queries = d[pick]
            asking.append(w)
        if asking:
            for w, (n, e) in zip(asking, _query_stream(read, asking)):
                ok = np.array([w.holds(int(a), float(b)) for a, b in zip(n, e)], bool)
                first = int(np.argmax(ok)) if ok.any() else len(ok)
                was = (w.lo, w.hi)
                if first < len(ok):
                    w.hi = float(w.queries[first])
                if first > 0:
                    w.lo = float(w.queries[first - 1])
                w.whole = (w.lo, w.hi) == was
    return [w.answer for w in windows]


def streamed_threshold(read, inner, seam_points, target, budget=INF, *, share, runs=None, queries=None):
    """:func:`trivsel.decimation.blocked.threshold` of the sequences ``read()`` yields, one
    ``(runmax, sse)`` per block in block order, each time it is called (``sse``: the running
    squared error, zeros where none was recorded; ``share``: ``SSE_SHARE``).  Returns
    ``(tau, decided)``, the same values, holding a bounded sample (``runs``, ``queries``: the
    module's ``RUNS`` and ``QUERIES`` by default)."""
    # at least 4 runs a block: a sample then has 2 distinct costs or more, and each window is smaller
    runs = max(RUNS if runs is None else int(runs), 4 * len(inner))
    queries = QUERIES if queries is None else int(queries)
    if target is None and budget == INF:
        return INF, INF
    total = int(sum(inner))
    preds, names = [], []
    if target is not None:
        def by_count(n, _):  # threshold()'s left(t) <= target
            kept = total - n
            return kept + seam_points * kept / max(total, 1) <= target

        preds.append(by_count)
        names.append("count")
    if budget < INF:
        scale = (total + seam_points) / max(total, 1)

        def by_budget(_, e):  # threshold()'s projected error past the budget's share
            return e * scale > share * budget

        preds.append(by_budget)
        names.append("budget")
    answers = dict(zip(names, _smallest_costs(read, preds, runs, queries)))
    some = next(iter(answers.values()))
    if some[0] is None:  # no recorded collapse at all
        return INF, INF
    tau = decided = INF
    if "count" in answers:
        cost, _, found = answers["count"]
        tau, decided = cost, (cost if found else INF)
    if "budget" in answers:
        cost, below, found = answers["budget"]
        if found:
            t = below if below is not None else float(np.nextafter(cost, -INF))
            at = cost
        else:
            t, at = cost, INF
        if t < tau:
            tau, decided = t, at
    return tau, decided


def streamed_cut_counts(read, tau, inner, seam_points, target, cut_counts_of):
    """:func:`trivsel.decimation.blocked.cut_counts` at ``tau`` and the squared error the blocks
    add (:func:`~trivsel.decimation.blocked.sse_at`), in two streams of ``read()``:
    ``cut_counts_of(hi, lo, inner, seam_points, target)`` shares out the ties."""
    hi, lo = [], []
    for r, _ in read():
        hi.append(int(np.searchsorted(r, tau, side="right")))
        lo.append(int(np.searchsorted(r, tau, side="left")))
    counts = cut_counts_of(hi, lo, inner, seam_points, target)
    total = 0
    for (_, s), c in zip(read(), counts):
        if c > 0:
            total += s[c - 1]
    return counts, float(total)


# --- the quota passes' cut across their regions (trivsel.decimation.blocked.cut_quota)


def _least_runs(runs, regions):
    """``RUNS`` (or ``runs``), and at least 4 runs a region, as :func:`streamed_threshold` keeps
    at least 4 a block."""
    return max(RUNS if runs is None else int(runs), 4 * regions)


def _kth(read, k, lengths, runs, queries):
    """:func:`streamed_kth_cost` of records of ``lengths``, ``runs`` resolved."""
    if not 0 < k <= sum(lengths):
        return INF
    (cost, _, _), = _smallest_costs(read, [lambda n, _: n >= k], runs, queries)
    return cost


def streamed_kth_cost(read, k, *, runs=None, queries=None):
    """The ``k``-th smallest recorded cost (1-based) of the sequences ``read()`` yields, one
    ``(runmax, sse)`` per region (``sse`` is not used), or inf where fewer than ``k`` (or
    ``k`` < 1) were recorded: the smallest cost at or below which ``k`` are, the value that
    sorting them all would put at ``k - 1``, from a bounded sample."""
    lengths = [len(r) for r, _ in read()]
    return _kth(read, int(k), lengths, _least_runs(runs, len(lengths)), QUERIES if queries is None else int(queries))


def _terms_at(read, counts):
    """Each region's running squared error at its count (0.0 at none)."""
    return np.array([float(s[c - 1]) if c > 0 else 0.0 for (_, s), c in zip(read(), counts)], np.float64)


def _ties_taken(read, cost, wanted):
    """Each region's count when ``wanted`` of the sequences' collapses are taken, cheapest first
    and ties at ``cost`` (the cost of the last one taken) by region: every one below it, then
    the ties region by region."""
    lo, hi = [], []
    for r, _ in read():
        lo.append(int(np.searchsorted(r, cost, side="left")))
        hi.append(int(np.searchsorted(r, cost, side="right")))
    need, counts = int(wanted) - sum(lo), []
    for a, b in zip(lo, hi):
        t = min(b - a, need)
        counts.append(a + t)
        need -= t
    return counts


def _within_budget(read, budget, runs, queries):
    """The longest run of the sequences' collapses in the cut's order (cost, then region, then
    place in the region), whose squared error (each region's running one at its count, summed
    in region order) is at most ``budget``, and the error: ``(counts, sse)``.  The error only
    grows along that order (running maxima), so it is the longest whose every prefix fits."""
    counts = [len(r) for r, _ in read()]
    if budget < 0:  # not even none fits
        return [0] * len(counts), 0.0
    whole = _sums(counts, _terms_at(read, counts))[1]
    if whole <= budget:
        return counts, whole
    (cost, _, _), = _smallest_costs(read, [lambda _, e: e > budget], runs, queries)
    # every collapse below ``cost`` fits; of the ties at it, regions in order, the first that do
    lo, hi, at_lo, at_hi = [], [], [], []
    for r, s in read():  # each region's count and running squared error below the cost and at it
        lo.append(int(np.searchsorted(r, cost, side="left")))
        hi.append(int(np.searchsorted(r, cost, side="right")))
        at_lo.append(float(s[lo[-1] - 1]) if lo[-1] > 0 else 0.0)
        at_hi.append(float(s[hi[-1] - 1]) if hi[-1] > 0 else 0.0)
    at_lo, at_hi = np.array(at_lo, np.float64), np.array(at_hi, np.float64)

    def error(j, sse_j):  # regions before j with every tie, j at sse_j, the ones after it with none
        terms = np.concatenate([at_hi[:j], [sse_j], at_lo[j + 1:]])
        return float(np.cumsum(terms)[-1])

    j = bisect.bisect_left(range(len(lo)), True, key=lambda j: error(j, at_hi[j]) > budget)
    s_j = None
    for k, (_, s) in enumerate(read()):  # region j's running squared error
        if k == j:
            s_j = np.asarray(s, np.float64)

    def with_ties(q):  # region j's running squared error with q of its ties
        return float(s_j[lo[j] + q - 1]) if lo[j] + q > 0 else 0.0

    q = bisect.bisect_left(range(hi[j] - lo[j] + 1), True, key=lambda q: error(j, with_ties(q)) > budget) - 1
    return hi[:j] + [lo[j] + q] + lo[j + 1:], error(j, with_ties(q))


def streamed_cut_quota(read, surplus, budget=INF, limit=INF, *, runs=None, queries=None):
    """:func:`trivsel.decimation.blocked.cut_quota` of the sequences ``read()`` yields, one
    ``(runmax, sse)`` per region in region order each time it is called: how many collapses each
    region makes, and the squared error they add.

    The cut's order is by cost, then region, then place in the region; it takes none above
    ``limit``, the first ``surplus`` (None: every one) and, with a ``budget``, the longest
    prefix of those whose squared error fits in it.  That error is each region's running
    squared error at its count, summed in region order (as the blocks' is,
    :func:`~trivsel.decimation.blocked.sse_at`), so that a bounded sample of the sequences
    finds it: each count is the prefix of its region's sequence below a cost, and the ties at
    that cost are shared out region by region."""
    queries = QUERIES if queries is None else int(queries)

    def below_limit():  # each region's prefix at or below the limit
        for r, s in read():
            c = int(np.searchsorted(r, limit, side="right")) if limit < INF else len(r)
            yield r[:c], s[:c]

    counts = [len(r) for r, _ in below_limit()]
    runs = _least_runs(runs, len(counts))
    if surplus is not None and int(surplus) < sum(counts):
        n = max(int(surplus), 0)
        cost = _kth(below_limit, n, counts, runs, queries) if n else -INF
        counts = _ties_taken(below_limit, cost, n)

    def taken():
        for (r, s), c in zip(below_limit(), counts):
            yield r[:c], s[:c]

    if budget < INF:
        return _within_budget(taken, budget, runs, queries)
    return counts, _sums(counts, _terms_at(taken, counts))[1]
