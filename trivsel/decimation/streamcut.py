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
"""

from __future__ import annotations

import bisect

import numpy as np

INF = np.inf
#: The runs of the window a stream keeps at most (twice this, before it thins them)
RUNS = 1 << 17
#: The costs of the sample whose counts the next stream finds exactly
QUERIES = 256

__all__ = ["streamed_threshold", "streamed_cut_counts", "RUNS", "QUERIES"]


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
