"""The swap criteria and the evaluation of a configuration (section 4, eqs. 14-15).

One place for every criterion a flip is judged by.  A flip replaces the old
tets of a configuration by new ones over the same points; it is judged by the
change of

* ``CRIT_RMS``: the sum over the tets of their RMS error (eq. 14),
  ``sqrt(sum r^2 / n)`` over the n points in the closed tet;
* ``CRIT_MAX``: the sum over the tets of their max error (eq. 15), ``max |r|``;
* ``CRIT_SSE``: the sum of squared residuals over the configuration's points,
  each counted once: the exact change of the global L2 error (eq. 19).

Residuals are ``r = f - L`` with L the linear interpolant of the tet (eq. 16).
Under RMS and max, a tet's own four vertices (residual 0) count in n only with
``vertices_in_error`` (Definition 2).  :data:`CRITERIA` maps the option names to
the codes.
"""

from __future__ import annotations

import numpy as np
from .cache import njit

from .geometry import _locate_at, _tet_data
from .state import A_BEFORE, C_LASTM, CRIT_MAX, CRIT_RMS, CRIT_SSE, CRITERIA  # noqa: F401 (CRITERIA: the API)
from .storage import _gather_at, _sort_into

#: Margin of :func:`_cannot_beat` against the rounding of the evaluated sums (a sum of m
#: non-negative terms is exact to m * 2^-53 relative; m < 10^6 points per configuration)
_BOUND_MARGIN = 1.0 + 1e-9


@njit(cache=True)
def _crit(c, sse, mx, cnt):
    """The error of one tet under swap criterion ``c``.

    Parameters
    ----------
    c : int
        ``CRIT_RMS``, ``CRIT_MAX`` or ``CRIT_SSE``.
    sse, mx : float
        Sum of the squared residuals and max |residual| of the tet's points.
    cnt : int
        Number of those points.

    Returns
    -------
    float
        ``sqrt(sse / cnt)`` (eq. 14; 0 without points), ``mx`` (eq. 15) or ``sse``.
    """
    if c == CRIT_RMS:
        return np.sqrt(sse / cnt) if cnt > 0 else 0.0
    if c == CRIT_MAX:
        return mx
    return sse


@njit(cache=True, _nrt=False)
def _cannot_beat(crit, tsse, tmax, tcnt, old, nold, best_gain):
    """Whether a flip of the old tets surely cannot beat the round's ``best_gain``,
    from an upper bound of its gain that costs no point test: ``before`` itself
    (``after`` >= 0), the sum of the old tets' stored errors (criteria RMS and max,
    eqs. 14-15; :func:`_evaluate` sums the same terms in another order, hence
    :data:`_BOUND_MARGIN`).  Never for SSE, whose ``before`` sums the stored global
    residuals instead: equal in exact arithmetic, but not within a relative
    rounding margin where residuals are much smaller than the values."""
    if crit == CRIT_SSE or best_gain <= 0.0:
        return False
    ub = 0.0
    for k in range(nold):
        t = old[k]
        ub += _crit(crit, tsse[t], tmax[t], tcnt[t])
    return ub * _BOUND_MARGIN <= best_gain


@njit(cache=True)
def _evaluate(S, old, nold, newq, nnew, reltol, abstol):
    """Criterion sums (before, after) of replacing old by newq, without changing the mesh.

    For RMS/max criteria these are sums of per-tet errors (eqs. 14-15) as in step
    (iii) of section 4; for SSE the sum of squared residuals over the points of the
    configuration, each counted once (the exact change of the global L2 error).

    ``after`` is a sum of non-negative terms, so its partial sums only grow: as
    soon as ``before - partial <= reltol * before + abstol`` the flip cannot pass
    swapping's test for an improvement and the evaluation stops, returning
    the partial sum (a lower bound of ``after`` that decides the same).
    ``abstol = -inf`` evaluates in full.  It does not also stop when the flip
    cannot beat the best one found so far in the round: such a configuration
    would have to be evaluated again in a later round.
    """
    return _evaluate_at(S, np.empty(4, np.int64), old, nold, newq, nnew, reltol, abstol, False)


@njit(cache=True, _nrt=False)
def _evaluate_at(S, srt, old, nold, newq, nnew, reltol, abstol, reuse):
    """:func:`_evaluate` with room ``srt`` for the sorted ids, allocating nothing, and
    compiled without reference counting: swapping calls it for every configuration
    it evaluates, where the arrays of the state would otherwise be counted in and
    out per call.

    ``reuse``: the previous call evaluated the same old tets (the other diagonal of a
    4-4 configuration), so their points are still in ``S.wbuf`` and, for SSE,
    their ``before`` in ``S.acc[A_BEFORE]``: no second gather.
    """
    I_ = S.ijk
    P_ = S.points
    F = S.values
    opt = S.opt
    ui_ = opt.use_int
    crit = opt.criterion
    ownvert = opt.vertices_in_error
    # the old tets in ascending id order: the sums then do not depend on the tet the
    # configuration was found from, to the last bit (equal gains stay equal)
    _sort_into(old, nold, srt)
    ctr = S.ctr
    if reuse:
        m = ctr[C_LASTM]
    else:
        m = _gather_at(ctr, S.mark, S.wbuf, S.pool, S.bstart, S.blen, srt, nold)
        ctr[C_LASTM] = m
    buf = S.wbuf
    before = 0.0
    after = 0.0
    if crit == CRIT_SSE:
        if reuse:
            before = S.acc[A_BEFORE]
        else:
            resid = S.resid
            for j in range(m):
                p = buf[j]
                before += resid[p] * resid[p]
            S.acc[A_BEFORE] = before
        thr = reltol * before + abstol
        # each point in the first new tet that contains it (2 to 4 tets; their data once)
        a0, a1, a2, a3 = newq[0, 0], newq[0, 1], newq[0, 2], newq[0, 3]
        b0, b1, b2, b3 = newq[1, 0], newq[1, 1], newq[1, 2], newq[1, 3]
        kc = min(2, nnew - 1)
        kd = min(3, nnew - 1)
        c0, c1, c2, c3 = newq[kc, 0], newq[kc, 1], newq[kc, 2], newq[kc, 3]
        d0, d1, d2, d3 = newq[kd, 0], newq[kd, 1], newq[kd, 2], newq[kd, 3]
        plA, qfA, fqA = _tet_data(I_, P_, F, a0, a1, a2, a3)
        plB, qfB, fqB = _tet_data(I_, P_, F, b0, b1, b2, b3)
        plC, qfC, fqC = _tet_data(I_, P_, F, c0, c1, c2, c3)
        plD, qfD, fqD = _tet_data(I_, P_, F, d0, d1, d2, d3)
        for j in range(m):
            p = buf[j]
            pi = (I_[p, 0], I_[p, 1], I_[p, 2])
            pf = (P_[p, 0], P_[p, 1], P_[p, 2])
            inside, nz, val = _locate_at(ui_, pi, pf, plA, qfA, fqA, p, a0, a1, a2, a3)
            if not inside:
                inside, nz, val = _locate_at(ui_, pi, pf, plB, qfB, fqB, p, b0, b1, b2, b3)
                if not inside and nnew > 2:
                    inside, nz, val = _locate_at(ui_, pi, pf, plC, qfC, fqC, p, c0, c1, c2, c3)
                    if not inside and nnew > 3:
                        inside, nz, val = _locate_at(ui_, pi, pf, plD, qfD, fqD, p, d0, d1, d2, d3)
            if inside:
                r = F[p] - val
                after += r * r
            if before - after <= thr:
                break
        return before, after
    for k in range(nold):
        t = srt[k]
        before += _crit(crit, S.tsse[t], S.tmax[t], S.tcnt[t])
    thr = reltol * before + abstol
    for k in range(nnew):
        q0 = newq[k, 0]
        q1 = newq[k, 1]
        q2 = newq[k, 2]
        q3 = newq[k, 3]
        sse = 0.0
        mx = 0.0
        cnt = 0
        pl, qf, fq = _tet_data(I_, P_, F, q0, q1, q2, q3)
        for j in range(m):
            p = buf[j]
            inside, nz, val = _locate_at(ui_, (I_[p, 0], I_[p, 1], I_[p, 2]), (P_[p, 0], P_[p, 1], P_[p, 2]),
                                         pl, qf, fq, p, q0, q1, q2, q3)
            if inside and (ownvert or (p != q0 and p != q1 and p != q2 and p != q3)):
                r = F[p] - val
                sse += r * r
                if abs(r) > mx:
                    mx = abs(r)
                cnt += 1
        after += _crit(crit, sse, mx, cnt)
        if before - after <= thr:
            break
    return before, after


def criterion_sum(criterion, tsse, tmax, tcnt, resid):
    """The quantity the swaps lower, in numpy (for tests and read-outs).

    Under ``CRIT_RMS`` and ``CRIT_MAX`` the sum over the given tets (their stored
    ``tsse``, ``tmax``, ``tcnt``) of their RMS (eq. 14) or max (eq. 15) error;
    under ``CRIT_SSE`` the squared residuals ``resid`` of all points, each
    counted once.
    """
    if criterion == CRIT_RMS:
        return float(np.sum(np.sqrt(np.divide(tsse, tcnt, out=np.zeros_like(tsse), where=tcnt > 0))))
    if criterion == CRIT_MAX:
        return float(np.sum(tmax))
    return float(np.dot(resid, resid))
