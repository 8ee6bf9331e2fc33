"""Rule collect_errors: every run's errors.csv stacked, with n and the options as columns."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

from trivsel.study.report import collect_runs  # noqa: E402

sm = snakemake  # noqa: F821
table = collect_runs(zip(list(sm.input), list(sm.params.runs)))
table.to_csv(sm.output[0], index=False, float_format="%.10g")
print(f"{len(table)} rows from {len(sm.input)} runs")
