"""Ablation of the paper's open choices against Table 1 (section 5).

Every variant changes one option of :data:`trivsel.reduction.DEFAULTS` and is run
on the five functions at the paper's resolution; the 30 numbers of Table 1
(E_RMS with and without boundary, 3 fractions, 5 functions) are compared with
the default run and with the published values.

    python -m trivsel.ablation --out results/ablation      # or the workflow's ablation config
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd

from .report import load_published

__all__ = ["VARIANTS", "run_ablation", "summarise"]

#: name -> options that differ from the defaults.  Diagnostic orders (not the
#: paper's) bracket what ordering each published number implies.
VARIANTS = {
    "default": {},
    "criterion=max": {"criterion": "max"},
    "criterion=sse": {"criterion": "sse"},
    "candidates=interior": {"candidates": "interior"},
    "tie_order=reverse": {"tie_order": "reverse"},
    "tie_order=random": {"tie_order": "random", "seed": 1},
    "tie_order=centre": {"tie_order": "centre"},
    "own_vertices=no": {"own_vertices": False},
    "final_pass=yes": {"final_pass": True},
    "first_improving=yes": {"first_improving": True},
    "boundary_diagonals=mirrored": {"boundary_diagonals": "mirrored"},
    "curvature=local-frame": {"curvature": "local-frame"},
    "ranking=analytic (diagnostic)": {"ranking": "analytic"},
    "ranking=random (diagnostic)": {"ranking": "random", "seed": 1},
    "ranking=ascending (diagnostic)": {"ranking": "ascending"},
}

CELLS = ("E_rms", "E_rms_interior")


def run_ablation(variants=None, functions=(1, 2, 3, 4, 5), n=16, fractions=(0.5, 0.2, 0.1), progress=print):
    """Run every variant on every function; one row per (variant, function, fraction)."""
    from .reduction import reduce

    variants = VARIANTS if variants is None else variants
    rows = []
    for name, opts in variants.items():
        for f in functions:
            t0 = time.perf_counter()
            r = reduce(f, n=n, fractions=list(fractions), **opts)
            for s in r.snapshots:
                rows.append({"variant": name, "function": f, "fraction": s.fraction, "n_selected": s.n_selected,
                             **s.errors, "seconds": time.perf_counter() - t0})
            if progress:
                progress(f"{name} f{f}: {time.perf_counter() - t0:.1f} s")
    return pd.DataFrame(rows)


def summarise(table: pd.DataFrame, published: pd.DataFrame | None = None, tol=0.10) -> pd.DataFrame:
    """Per variant: change against the default run and closeness to the paper over the 30 numbers.

    Columns: ``median_change`` and ``max_change`` (relative change of the 30 numbers
    against the default variant, in per cent, signed median and largest magnitude),
    ``within_5``/``within_10`` (how many of the 30 lie within 5 % / 10 % of the
    published value) and ``median_abs_dev`` (median |ours/published - 1|, per cent).
    """
    pub = load_published() if published is None else published
    key = ["function", "fraction"]
    pub = pub.rename(columns={"E_rms": "pub_E_rms", "E_rms_interior": "pub_E_rms_interior"})
    t = table.merge(pub[key + ["pub_E_rms", "pub_E_rms_interior"]], on=key, how="left")
    base = t[t.variant == "default"].set_index(key)
    out = []
    for name, g in t.groupby("variant", sort=False):
        g = g.set_index(key)
        ours = np.concatenate([g[c].to_numpy() for c in CELLS])
        ref = np.concatenate([base.loc[g.index, c].to_numpy() for c in CELLS])
        pubv = np.concatenate([g["pub_" + c].to_numpy() for c in CELLS])
        change = 100 * (ours / ref - 1)
        dev = np.abs(ours / pubv - 1)
        out.append({"variant": name, "median_change": float(np.median(change)),
                    "max_change": float(change[np.argmax(np.abs(change))]),
                    "within_5": int(np.sum(dev <= 0.05)), "within_10": int(np.sum(dev <= tol)),
                    "median_abs_dev": float(100 * np.median(dev))})
    return pd.DataFrame(out)


def closest_variants(table: pd.DataFrame, published: pd.DataFrame | None = None) -> pd.DataFrame:
    """For each of the 30 cells, the variant whose number is closest to the published one."""
    pub = load_published() if published is None else published
    rows = []
    for (f, frac), g in table.groupby(["function", "fraction"]):
        p = pub[(pub.function == f) & np.isclose(pub.fraction, frac)].iloc[0]
        for c in CELLS:
            dev = (g[c] / p[c] - 1).abs()
            i = dev.idxmin()
            rows.append({"function": f, "fraction": frac, "column": c, "published": p[c],
                         "default": float(g[g.variant == "default"][c].iloc[0]),
                         "closest_variant": g.loc[i, "variant"], "closest_value": g.loc[i, c],
                         "closest_dev_pct": 100 * float(g.loc[i, c] / p[c] - 1)})
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="folder for ablation.csv, ablation_summary.csv, closest.csv")
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--variants", nargs="*", help="subset of variant names")
    a = ap.parse_args(argv)
    from pathlib import Path

    variants = VARIANTS if not a.variants else {k: VARIANTS[k] for k in a.variants}
    table = run_ablation(variants, n=a.n)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "ablation.csv", index=False)
    summ = summarise(table)
    summ.to_csv(out / "ablation_summary.csv", index=False)
    closest_variants(table).to_csv(out / "closest.csv", index=False)
    print(summ.to_string(index=False, float_format=lambda v: f"{v:.2f}"))


if __name__ == "__main__":  # pragma: no cover
    main()
