"""Rule methods_table: all methods' rows stacked (methods.csv) and the Markdown summary
with the target check (methods.md)."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import pandas as pd  # noqa: E402

from trivsel.study.comparison import methods_markdown, methods_table, target_check  # noqa: E402

sm = snakemake  # noqa: F821
table = methods_table(pd.concat([pd.read_csv(p) for p in sm.input], ignore_index=True))
table.to_csv(sm.output.csv, index=False, float_format="%.10g")
figures = {(int(n), int(f)): path for (n, f), path in dict(sm.params.figures).items()}
with open(sm.output.md, "w") as fh:
    fh.write(methods_markdown(table, list(sm.params.fractions), figures=figures))
print(target_check(table, list(sm.params.fractions)).to_string())
print(f"{len(table)} rows from {len(sm.input)} runs")
