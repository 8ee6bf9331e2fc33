"""Rule realdata_table: every volume's rows as the ratio table with the targets checked
(realdata.md) and the check as numbers (realdata.csv)."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import pandas as pd  # noqa: E402

from trivsel.study.realdata import realdata_markdown, target_check  # noqa: E402

sm = snakemake  # noqa: F821
rows = pd.concat([pd.read_csv(p) for p in sm.input], ignore_index=True)
methods = list(sm.params.methods)
check = target_check(rows, methods)
check.to_csv(sm.output.csv, index=False, float_format="%.10g")
with open(sm.output.md, "w") as fh:
    fh.write(realdata_markdown(rows, methods, figures=dict(sm.params.figures)))
print(check.to_string())
print(f"{len(rows)} rows from {len(sm.input)} volumes")
