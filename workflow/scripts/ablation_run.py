"""Rule ablation_run: one ablation variant on every configured function (trivsel.study.ablation)."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import pandas as pd  # noqa: E402

from trivsel.study.ablation import run_variant  # noqa: E402

sm = snakemake  # noqa: F821
name, n = sm.wildcards.ablation_variant, int(sm.wildcards.n)
rows = []
for f in sm.params.functions:
    res = run_variant(name, int(f), n=n, fractions=list(sm.params.fractions))
    print(f"{name} f{f} n={n}: {res[0]['seconds']:.1f} s, "
          + ", ".join(f"{r['fraction']:g}: E_rms {r['E_rms']:.4f} / {r['E_rms_interior']:.4f}*" for r in res))
    rows += res
pd.DataFrame(rows).to_csv(sm.output[0], index=False, float_format="%.12g")
