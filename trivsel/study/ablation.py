"""Ablation of the paper's open choices against Table 1 (section 5).

A *variant* is a set of choices that differ from the defaults
(:class:`trivsel.Options`), named ``choice=value`` joined by ``+`` in a
fixed order, e.g. ``boundary_diagonals=mirrored+first_improving=yes``; ``default``
changes nothing.  Every variant is run on the Table-1 functions at the paper's
resolution and its 30 numbers (E_RMS with and without boundary, 3 fractions,
5 functions) are compared with the default run and with the published values.

Choices (:data:`CHOICES`; the first value is the default):

* options of :func:`trivsel.reduce`: ``criterion``, ``candidates``, ``tie_order``,
  ``vertices_in_error``, ``final_pass``, ``first_improving``, ``boundary_diagonals``,
  ``curvature``;
* ``rounding`` of the point counts: ``half-up`` (the package: 50 % of 4913 is
  2457), ``floor`` (2456, 982, 491) or ``half-even`` (2456, 983, 491); emulated by
  asking :func:`trivsel.reduce` for the exact counts;
* ``neighbourhood`` of the curvature fit: ``kuhn`` (edge neighbours in the Kuhn
  split, the package), ``box`` (the 26 grid neighbours, the 3 x 3 x 3 block) or
  ``two-ring`` (neighbours of neighbours in the Kuhn split): the ``neighbourhood``
  option of :func:`trivsel.reduce`.

Diagnostic orders (not the paper's; :data:`DIAGNOSTICS`): ``ranking=analytic``
(exact curvature of the function), ``random`` and ``ascending``.  They bracket
what insertion order each published number implies: a cell that only an
uninformative order reproduces says something about the paper's run.

Groups of variants (:func:`variant_names`): ``singles`` (one choice changed),
``diagnostics``, ``mirrored`` (mirrored diagonals with each other single change),
``search`` (criterion x first_improving x curvature x boundary_diagonals) and
``all``.  The best consistent set (:func:`best_consistent`) is the non-diagnostic
variant with the most cells within 10 %, then within 5 %, then the smallest
median |deviation|.

    python -m trivsel.study.ablation --out results/ablation --groups all --jobs 2
    snakemake -c all --configfile config/ablation.yaml        # the workflow's stage
"""

from __future__ import annotations

import argparse
import itertools
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd

from .published import load_published

__all__ = [
    "CHOICES", "DIAGNOSTICS", "GROUPS", "VARIANTS", "parse_variant", "variant_name", "variant_names",
    "is_diagnostic", "run_variant", "run_ablation", "summarise", "choice_effects", "closest_variants",
    "best_consistent", "bracket_orders", "ablation_markdown", "write_ablation_report",
]

#: The paper's open choices that the ablation varies (fields of :class:`trivsel.Options`), in name order.
ABLATED = ("boundary_diagonals", "criterion", "first_improving", "curvature", "neighbourhood", "tie_order",
           "candidates", "vertices_in_error", "final_pass")


def _option_values(name):
    """The values of an option, the paper method's default first."""
    from ..methods import paper
    from ..options import option_fields

    f = {f.name: f for f in option_fields()}[name]
    default = paper.DEFAULTS[name] if f.default is None else f.default
    values = (False, True) if f.metadata["kind"] == "bool" else f.metadata["choices"]
    return [default] + [v for v in values if v != default]


def _option_doc(name):
    from ..options import option_fields

    f = {f.name: f for f in option_fields()}[name]
    return f.metadata["doc"] + (f" ({f.metadata['paper']})" if f.metadata["paper"] else "")


#: Every open choice and its values; the first value is the default.
CHOICES = {**{k: _option_values(k) for k in ABLATED}, "rounding": ["half-up", "floor", "half-even"]}
#: Diagnostic insertion orders (not the paper's); default "curvature".
DIAGNOSTICS = {"ranking": _option_values("ranking")}
#: Name order of the keys in a variant name.
KEY_ORDER = list(CHOICES) + list(DIAGNOSTICS)
#: Choices the ablation emulates around :func:`trivsel.reduce` (not reduce options).
EMULATED = ("rounding",)
#: What each choice means (the Markdown summary lists these).
CHOICE_DOCS = {**{k: _option_doc(k) for k in ABLATED},
               "rounding": "rounding of the point counts (50 % of 4913 = 2456.5)",
               "ranking": "diagnostic insertion order (not the paper's)"}
CELLS = ("E_rms", "E_rms_interior")
CELL_LABEL = {"E_rms": "E_RMS", "E_rms_interior": "E_RMS*"}
SEARCH_KEYS = ("criterion", "first_improving", "curvature", "boundary_diagonals")


# --------------------------------------------------------------------------- names
def _fmt(v) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    return str(v)


def _default(key):
    return (CHOICES.get(key) or DIAGNOSTICS[key])[0]


def variant_name(choices: dict) -> str:
    """Canonical name: the non-default choices as ``key=value`` joined by ``+``."""
    unknown = set(choices) - set(KEY_ORDER)
    if unknown:
        raise ValueError(f"unknown choice(s) {sorted(unknown)}; known: {KEY_ORDER}")
    parts = [f"{k}={_fmt(choices[k])}" for k in KEY_ORDER if k in choices and choices[k] != _default(k)]
    return "+".join(parts) or "default"


def parse_variant(name: str) -> dict:
    """``'boundary_diagonals=mirrored+first_improving=yes'`` -> the choices dict (validated)."""
    if name == "default":
        return {}
    out = {}
    for part in name.split("+"):
        key, sep, val = part.partition("=")
        values = CHOICES.get(key) or DIAGNOSTICS.get(key)
        if not sep or values is None:
            raise ValueError(f"bad variant part {part!r} in {name!r}: expected choice=value, "
                             f"choices {KEY_ORDER}")
        match = [v for v in values if _fmt(v) == val]
        if not match:
            raise ValueError(f"unknown value {val!r} for {key!r} in {name!r}: one of {[_fmt(v) for v in values]}")
        out[key] = match[0]
    if variant_name(out) != name:
        raise ValueError(f"variant {name!r} is not in canonical form: {variant_name(out)!r}")
    return out


def is_diagnostic(name: str) -> bool:
    return any(k in DIAGNOSTICS for k in parse_variant(name))


def _singles():
    return ["default"] + [variant_name({k: v}) for k, vals in CHOICES.items() for v in vals[1:]]


def _diagnostics():
    return [variant_name({k: v}) for k, vals in DIAGNOSTICS.items() for v in vals[1:]]


def _mirrored():
    """The other boundary diagonals combined with each other single change (the
    group that chose the default: it was measured with ``kuhn`` as the default)."""
    other = CHOICES["boundary_diagonals"][1]
    out = [variant_name({"boundary_diagonals": other})]
    for k, vals in CHOICES.items():
        if k != "boundary_diagonals":
            out += [variant_name({"boundary_diagonals": other, k: v}) for v in vals[1:]]
    return out


def _search():
    return [variant_name(dict(zip(SEARCH_KEYS, combo)))
            for combo in itertools.product(*(CHOICES[k] for k in SEARCH_KEYS))]


GROUPS = {"singles": _singles, "diagnostics": _diagnostics, "mirrored": _mirrored, "search": _search}


def variant_names(spec=("all",)) -> list:
    """Group names (``singles``, ``diagnostics``, ``mirrored``, ``search``, ``all``) and/or
    variant names -> ordered unique variant names, ``default`` first."""
    if isinstance(spec, str):
        spec = [spec]
    names = ["default"]
    for item in spec:
        if item == "all":
            for g in GROUPS.values():
                names += g()
        elif item in GROUPS:
            names += GROUPS[item]()
        else:
            parse_variant(item)
            names.append(item)
    return list(dict.fromkeys(names))


#: The variants of the full ablation (``all``): name -> choices.
VARIANTS = {name: parse_variant(name) for name in variant_names("all")}


# --------------------------------------------------------------------------- running
def _rounded_count(fraction: float, n_points: int, rounding: str) -> int:
    from decimal import ROUND_FLOOR, ROUND_HALF_EVEN, ROUND_HALF_UP, Decimal

    mode = {"half-up": ROUND_HALF_UP, "floor": ROUND_FLOOR, "half-even": ROUND_HALF_EVEN}[rounding]
    return int((Decimal(repr(float(fraction))) * Decimal(int(n_points))).quantize(Decimal(1), rounding=mode))


def run_variant(name: str, function: int, n: int = 16, fractions=(0.5, 0.2, 0.1)) -> list:
    """One variant on one Table-1 function: a row per fraction (nominal fraction kept)."""
    from ..data import sample_grid
    from ..reduction import reduce

    choices = parse_variant(name)
    data = sample_grid(function, n)
    N = data.n_points
    opts = {k: v for k, v in choices.items() if k not in EMULATED}
    rounding = choices.get("rounding", "half-up")
    counts = {_rounded_count(f, N, rounding): float(f) for f in fractions}
    # exact counts: c / N is rounded half up back to c by trivsel.selection.count_for_fraction
    req = [c / N for c in counts]
    t0 = time.perf_counter()
    r = reduce(data, fractions=req, **opts)
    rows = []
    for s in r.snapshots:
        rows.append({"variant": name, "n": n, "function": int(function), "fraction": counts[s.n_selected],
                     "n_selected": s.n_selected, **{k: float(v) for k, v in s.errors.items()},
                     "seconds": round(time.perf_counter() - t0, 3)})
    return rows


def _run_task(task):
    return run_variant(*task)


def run_ablation(variants=None, functions=(1, 2, 3, 4, 5), n=16, fractions=(0.5, 0.2, 0.1), jobs=1,
                 progress=print) -> pd.DataFrame:
    """Run every variant on every function; one row per (variant, function, fraction).

    ``variants``: names (or a dict name -> anything, for compatibility); ``None`` = all.
    ``jobs`` > 1 runs the reductions in that many processes.
    """
    names = variant_names("all") if variants is None else list(variants)
    tasks = [(v, int(f), int(n), tuple(fractions)) for v in names for f in functions]
    rows = []
    t0 = time.perf_counter()
    if jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=jobs) as ex:
            for task, res in zip(tasks, ex.map(_run_task, tasks)):
                rows += res
                if progress:
                    progress(f"{task[0]} f{task[1]}: {res[0]['seconds']:.1f} s ({time.perf_counter() - t0:.0f} s)")
    else:
        for task in tasks:
            res = _run_task(task)
            rows += res
            if progress:
                progress(f"{task[0]} f{task[1]}: {res[0]['seconds']:.1f} s ({time.perf_counter() - t0:.0f} s)")
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------- analysis
def _with_published(table: pd.DataFrame, published: pd.DataFrame | None) -> pd.DataFrame:
    pub = load_published() if published is None else published
    pub = pub[["function", "fraction", "E_rms", "E_rms_interior"]].rename(
        columns={"E_rms": "published_E_rms", "E_rms_interior": "published_E_rms_interior"})
    t = table.drop(columns=[c for c in table.columns if c.startswith("published_")], errors="ignore")
    t = t.assign(_k=t["fraction"].astype(float).round(9))
    t = t.merge(pub.assign(_k=pub["fraction"].astype(float).round(9)).drop(columns="fraction"),
                on=["function", "_k"], how="left").drop(columns="_k")
    return t


def ablation_table(table: pd.DataFrame, published: pd.DataFrame | None = None) -> pd.DataFrame:
    """The long table with published values, deviations from them and changes against
    the default variant (per cent), and whether the variant is a diagnostic order."""
    t = _with_published(table, published)
    key = ["function", "fraction"]
    base = t[t.variant == "default"].set_index(key)
    for c in CELLS:
        t[f"dev_{c}_pct"] = 100 * (t[c] / t[f"published_{c}"] - 1)
        if len(base):
            ref = base[c].reindex(pd.MultiIndex.from_frame(t[key])).to_numpy()
            t[f"change_{c}_pct"] = 100 * (t[c] / ref - 1)
    t["diagnostic"] = [is_diagnostic(v) for v in t["variant"]]
    return t


def _cells(g: pd.DataFrame, prefix: str = "") -> np.ndarray:
    g = g.sort_values(["function", "fraction"], ascending=[True, False])
    return np.concatenate([g[prefix + c].to_numpy(float) for c in CELLS])


def summarise(table: pd.DataFrame, published: pd.DataFrame | None = None, tol=0.10) -> pd.DataFrame:
    """Per variant: change against the default run and closeness to the paper.

    Columns: ``median_change`` and ``max_change`` (relative change of the numbers
    against the default variant, in per cent, signed median and the change of
    largest magnitude), ``within_5``/``within_10`` (how many lie within 5 % / 10 % of
    the published value), ``cells`` (how many have a published value),
    ``median_abs_dev`` (median |ours/published - 1|, per cent), ``diagnostic`` and
    ``changed`` (number of choices changed).  Rows in the order of the table.
    """
    t = _with_published(table, published)
    key = ["function", "fraction"]
    base = t[t.variant == "default"].set_index(key)
    out = []
    for name, g in t.groupby("variant", sort=False):
        g = g.sort_values(key, ascending=[True, False])
        ours = _cells(g)
        pubv = _cells(g, "published_")
        if len(base):
            ref = np.concatenate([base[c].reindex(pd.MultiIndex.from_frame(g[key])).to_numpy(float) for c in CELLS])
            change = 100 * (ours / ref - 1)
        else:
            change = np.full_like(ours, np.nan)
        ok = np.isfinite(pubv)
        dev = np.abs(ours[ok] / pubv[ok] - 1)
        fin = change[np.isfinite(change)]
        out.append({"variant": name, "diagnostic": is_diagnostic(name), "changed": len(parse_variant(name)),
                    "median_change": float(np.median(fin)) if len(fin) else float("nan"),
                    "max_change": float(fin[np.argmax(np.abs(fin))]) if len(fin) else float("nan"),
                    "within_5": int(np.sum(dev <= 0.05 + 1e-12)), "within_10": int(np.sum(dev <= tol + 1e-12)),
                    "cells": int(ok.sum()),
                    "median_abs_dev": float(100 * np.median(dev)) if len(dev) else float("nan")})
    return pd.DataFrame(out)


def _rank_key(summary: pd.DataFrame):
    """Best first: most cells within 10 %, then within 5 %, then the smallest median
    |deviation| (to 0.01 percentage points, so rounding noise is a tie), then fewest
    changed choices, then table order."""
    s = summary.assign(_dev=summary["median_abs_dev"].round(2), _order=np.arange(len(summary)))
    s = s.sort_values(["within_10", "within_5", "_dev", "changed", "_order"],
                      ascending=[False, False, True, True, True], kind="stable")
    return s.drop(columns=["_dev", "_order"])


def best_consistent(summary: pd.DataFrame) -> pd.Series:
    """The non-diagnostic variant matching the paper best (the order of :func:`_rank_key`:
    most cells within 10 %, then within 5 %, then the smallest median |deviation|, then
    the fewest changed choices)."""
    return _rank_key(summary[~summary["diagnostic"]]).iloc[0]


def choice_effects(summary: pd.DataFrame) -> pd.DataFrame:
    """The single-change variants (and diagnostics) with the choice they change."""
    rows = []
    for r in summary.itertuples(index=False):
        ch = parse_variant(r.variant)
        if len(ch) != 1:
            continue
        (k, v), = ch.items()
        rows.append({"choice": k, "value": _fmt(v), **r._asdict()})
    return pd.DataFrame(rows)


def closest_variants(table: pd.DataFrame, published: pd.DataFrame | None = None, best: str | None = None,
                     tol: float = 0.10) -> pd.DataFrame:
    """For each published cell, the variant closest to the paper: over all variants and
    over the consistent (non-diagnostic) ones, with the default's and ``best``'s values.

    ``reachable``: ``default`` (the default is within ``tol``), ``consistent`` (some
    non-diagnostic variant is), ``diagnostic only`` (only a diagnostic order is) or
    ``no``.
    """
    t = _with_published(table, published)
    t = t[t["published_E_rms"].notna()]
    rows = []
    for (f, frac), g in t.groupby(["function", "fraction"], sort=True):
        diag = np.array([is_diagnostic(v) for v in g["variant"]])
        for c in CELLS:
            p = float(g[f"published_{c}"].iloc[0])
            dev = (g[c] / p - 1).abs().to_numpy()
            i = int(np.argmin(dev))
            row = {"function": int(f), "fraction": float(frac), "column": c, "published": p}
            d = g[g.variant == "default"]
            row["default"] = float(d[c].iloc[0]) if len(d) else float("nan")
            row["default_dev_pct"] = 100 * (row["default"] / p - 1)
            row.update({"closest_variant": g["variant"].iloc[i], "closest_value": float(g[c].iloc[i]),
                        "closest_dev_pct": 100 * float(g[c].iloc[i] / p - 1)})
            if (~diag).any():
                j = np.flatnonzero(~diag)[int(np.argmin(dev[~diag]))]
                row.update({"consistent_variant": g["variant"].iloc[j], "consistent_value": float(g[c].iloc[j]),
                            "consistent_dev_pct": 100 * float(g[c].iloc[j] / p - 1)})
            else:
                row.update({"consistent_variant": "", "consistent_value": float("nan"),
                            "consistent_dev_pct": float("nan")})
            if best is not None:
                b = g[g.variant == best]
                row["best_value"] = float(b[c].iloc[0]) if len(b) else float("nan")
                row["best_dev_pct"] = 100 * (row["best_value"] / p - 1)
            tolp = 100 * tol + 1e-9
            if abs(row["default_dev_pct"]) <= tolp:
                row["reachable"] = "default"
            elif abs(row["consistent_dev_pct"]) <= tolp:
                row["reachable"] = "consistent"
            elif abs(row["closest_dev_pct"]) <= tolp:
                row["reachable"] = "diagnostic only"
            else:
                row["reachable"] = "no"
            rows.append(row)
    out = pd.DataFrame(rows)
    order = {c: i for i, c in enumerate(CELLS)}
    return out.sort_values(["function", "fraction", "column"], ascending=[True, False, True],
                           key=lambda s: s.map(order) if s.name == "column" else s).reset_index(drop=True)


def bracket_orders(table: pd.DataFrame, published: pd.DataFrame | None = None) -> pd.DataFrame:
    """Where each published number lies between the curvature order (default) and the
    diagnostic orders: ``position`` = (published - default) / (order - default), so 0 is
    the curvature order, 1 that order (random: an uninformative order)."""
    t = _with_published(table, published)
    t = t[t["published_E_rms"].notna()]
    rows = []
    for (f, frac), g in t.groupby(["function", "fraction"], sort=True):
        d = g[g.variant == "default"]
        if not len(d):
            continue
        for c in CELLS:
            p = float(g[f"published_{c}"].iloc[0])
            row = {"function": int(f), "fraction": float(frac), "column": c, "published": p,
                   "curvature": float(d[c].iloc[0])}
            for v in DIAGNOSTICS["ranking"][1:]:
                x = g[g.variant == variant_name({"ranking": v})]
                val = float(x[c].iloc[0]) if len(x) else float("nan")
                row[v] = val
                den = val - row["curvature"]
                row[f"position_{v}"] = (p - row["curvature"]) / den if den and math.isfinite(den) else float("nan")
            rows.append(row)
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------- report
def _pc(v, signed=True):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    v = round(float(v), 1) + 0.0  # no negative zero
    return f"{v:+.1f} %" if signed else f"{v:.1f} %"


def _md_table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(x) for x in r) + " |" for r in rows]
    return lines


def _frac(f):
    return f"{100 * float(f):g} %"


def ablation_markdown(table: pd.DataFrame, published: pd.DataFrame | None = None, tol: float = 0.10,
                      top: int = 15) -> str:
    """The Markdown summary of an ablation (the workflow's ``results/report/ablation.md``)."""
    summ = summarise(table, published, tol)
    best = best_consistent(summ)
    closest = closest_variants(table, published, best=best["variant"], tol=tol)
    default = summ[summ.variant == "default"]
    d = default.iloc[0] if len(default) else None
    ns = sorted(set(int(x) for x in table["n"])) if "n" in table.columns else []
    funcs = sorted(set(int(x) for x in table["function"]))
    nvar = table["variant"].nunique()
    L = ["# Ablation of the paper's open choices against Table 1", ""]
    L.append(f"{nvar} variants x functions {', '.join(map(str, funcs))}"
             + (f" at n = {', '.join(map(str, ns))}" if ns else "")
             + f"; {int(summ['cells'].max())} published numbers per variant (E_RMS and E_RMS* without "
             f"boundary). A variant is the set of choices changed from the defaults, `choice=value` joined "
             f"by `+`. Deviations are ours / published - 1; \"change\" is against the default variant.")
    if ns and ns != [16]:
        L += ["", f"Note: the published values are for n = 16; this ablation uses n = {ns[0]}, so the "
                  "deviations are not like-for-like."]
    L += ["", "## Best consistent set of choices", ""]
    L.append("Among the variants that keep the paper's curvature order (no diagnostic order), ranked by "
             f"cells within ±{100 * tol:g} %, then within ±5 %, then the median |deviation|:")
    L.append("")
    rank = _rank_key(summ[~summ["diagnostic"]]).head(top)
    L += _md_table(["variant", f"within ±{100 * tol:g} %", "within ±5 %", "median abs dev", "median change",
                    "largest change"],
                   [[f"`{r.variant}`", f"{r.within_10} / {r.cells}", f"{r.within_5} / {r.cells}",
                     _pc(r.median_abs_dev, False), _pc(r.median_change), _pc(r.max_change)]
                    for r in rank.itertuples(index=False)])
    L.append("")
    if d is not None:
        L.append(f"**Best: `{best['variant']}`**: {best['within_10']} of {best['cells']} cells within "
                 f"±{100 * tol:g} % and {best['within_5']} within ±5 % (median |dev| "
                 f"{best['median_abs_dev']:.1f} %), against {d['within_10']} and {d['within_5']} "
                 f"(median |dev| {d['median_abs_dev']:.1f} %) with the defaults.")
        L.append("")

    L += ["## Effect of each choice", ""]
    L.append("One choice changed from the defaults; change of the numbers against the default run (median "
             "and largest), and closeness to the paper.")
    L.append("")
    eff = choice_effects(summ)
    if len(eff):
        L += _md_table(["choice", "value", "median change", "largest change", f"within ±{100 * tol:g} %",
                        "within ±5 %", "median abs dev", "what"],
                       [[f"`{r.choice}`", f"`{r.value}`" + (" (diagnostic)" if r.diagnostic else ""),
                         _pc(r.median_change), _pc(r.max_change), r.within_10, r.within_5,
                         _pc(r.median_abs_dev, False), CHOICE_DOCS.get(r.choice, "")]
                        for r in eff.itertuples(index=False)])
        L.append("")

    L += ["## Each cell: the variant closest to the paper", ""]
    L.append("`closest` over all variants (diagnostic orders included), `consistent` over the variants "
             "that keep the curvature order; \"reachable\": whether the default, some consistent variant, "
             f"only a diagnostic order, or nothing comes within ±{100 * tol:g} %.")
    L.append("")
    L += _md_table(["function", "fraction", "cell", "published", "default", "best set", "closest variant",
                    "consistent variant", "reachable"],
                   [[r.function, _frac(r.fraction), CELL_LABEL[r.column], f"{r.published:.3f}",
                     f"{r.default:.3f} ({_pc(r.default_dev_pct)})",
                     f"{r.best_value:.3f} ({_pc(r.best_dev_pct)})",
                     f"`{r.closest_variant}` {r.closest_value:.3f} ({_pc(r.closest_dev_pct)})",
                     f"`{r.consistent_variant}` {r.consistent_value:.3f} ({_pc(r.consistent_dev_pct)})",
                     r.reachable]
                    for r in closest.itertuples(index=False)])
    L.append("")

    br = bracket_orders(table, published)
    L += ["## What the diagnostic orders imply", ""]
    if len(br) and br[[f"position_{v}" for v in DIAGNOSTICS["ranking"][1:]]].notna().any().any():
        L.append("Each published number placed between our curvature order (position 0) and a diagnostic "
                 "order (position 1): `random` is an uninformative order, `ascending` the reverse of the "
                 "paper's, `analytic` the exact curvature of the function. A position near 0 means the "
                 "published run ordered the points like our curvature estimate; near 1 for `random`, that "
                 "it did no better than an uninformative order.")
        L.append("")
        L += _md_table(["function", "fraction", "cell", "published", "curvature", "analytic", "random",
                        "ascending", "position random", "position ascending"],
                       [[r.function, _frac(r.fraction), CELL_LABEL[r.column], f"{r.published:.3f}",
                         f"{r.curvature:.3f}", f"{r.analytic:.3f}", f"{r.random:.3f}", f"{r.ascending:.3f}",
                         f"{r.position_random:.2f}", f"{r.position_ascending:.2f}"]
                        for r in br.itertuples(index=False)])
        L.append("")
    notes = []
    for f, g in closest.groupby("function", sort=True):
        only = g[g.reachable == "diagnostic only"]
        no = g[g.reachable == "no"]
        if len(only):
            vs = sorted(set(only.closest_variant))
            notes.append(f"- Function {f}: {len(only)} cell(s) come within ±{100 * tol:g} % only under "
                         f"{', '.join(f'`{v}`' for v in vs)}, never under the curvature order: the published "
                         "run cannot have inserted the points of this function in the order of its curvature "
                         "as printed.")
        if len(no):
            worst = no.iloc[int(np.argmax(no.consistent_dev_pct.abs().to_numpy()))]
            notes.append(f"- Function {f}: {len(no)} cell(s) no variant brings within ±{100 * tol:g} %; "
                         f"the nearest consistent variant still deviates by up to "
                         f"{_pc(worst.consistent_dev_pct)} ({_frac(worst.fraction)}, "
                         f"{CELL_LABEL[worst.column]}).")
        low = g[(g.reachable.isin(["no", "diagnostic only"])) & (g.consistent_dev_pct < 0)]
        if len(low) == len(g) and len(g):
            ratio = float(np.median(g.published / g.consistent_value))
            notes.append(f"- Function {f}: every consistent variant is *below* the published numbers (the "
                         f"paper's errors are about {ratio:.1f} x the closest consistent ones).")
    L += notes or ["- Every cell is within reach of a consistent variant."]
    L.append("")
    L += ["## Reproduce", "",
          "`python -m trivsel.study.ablation --out DIR --groups all --jobs 2`, or in the workflow "
          "`snakemake -c all --configfile config/ablation.yaml`. Rounding is emulated by asking "
          "`trivsel.reduce` for exact counts; the neighbourhood is its `neighbourhood` option.", ""]
    return "\n".join(L)


def write_ablation_report(csvs, out_csv, out_md, published_csv=None, tol: float = 0.10,
                          out_summary=None, out_closest=None) -> pd.DataFrame:
    """Stack per-variant CSVs (from :func:`run_ablation`) into ``out_csv`` (one row per
    variant, function and fraction, with published values and deviations) and write the
    Markdown summary ``out_md``; optionally the per-variant summary and the per-cell
    closest table.  Returns the long table."""
    if isinstance(csvs, (str, Path)):
        csvs = [csvs]
    table = pd.concat([pd.read_csv(p) for p in csvs], ignore_index=True)
    pub = load_published(published_csv)
    long = ablation_table(table, pub)
    for p in (out_csv, out_md, out_summary, out_closest):
        if p:
            Path(p).parent.mkdir(parents=True, exist_ok=True)
    long.to_csv(out_csv, index=False, float_format="%.10g")
    Path(out_md).write_text(ablation_markdown(table, pub, tol))
    if out_summary:
        summarise(table, pub, tol).to_csv(out_summary, index=False, float_format="%.6g")
    if out_closest:
        best = best_consistent(summarise(table, pub, tol))["variant"]
        closest_variants(table, pub, best=best, tol=tol).to_csv(out_closest, index=False, float_format="%.10g")
    return long


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="folder for ablation.csv, ablation.md, ablation_summary.csv, "
                                                 "closest.csv")
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--functions", type=int, nargs="*", default=[1, 2, 3, 4, 5])
    ap.add_argument("--groups", nargs="*", default=["singles", "diagnostics"],
                    help=f"groups ({', '.join(GROUPS)}, all) and/or variant names")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--list", action="store_true", help="print the variant names and exit")
    a = ap.parse_args(argv)
    names = variant_names(a.groups)
    if a.list:
        print("\n".join(names))
        return
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    raw = out / "ablation_runs.csv"
    table = run_ablation(names, functions=a.functions, n=a.n, jobs=a.jobs)
    table.to_csv(raw, index=False)
    write_ablation_report([raw], out / "ablation.csv", out / "ablation.md", out_summary=out / "ablation_summary.csv",
                          out_closest=out / "closest.csv")
    summ = summarise(table)
    print(_rank_key(summ).to_string(index=False, float_format=lambda v: f"{v:.2f}"))


if __name__ == "__main__":  # pragma: no cover
    main()
