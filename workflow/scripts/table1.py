"""Rule table1: our errors beside the published Table 1 (csv + Markdown)."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

from trivsel.report import write_table1  # noqa: E402

sm = snakemake  # noqa: F821
table = write_table1(
    list(sm.input.errors),
    sm.output.csv,
    sm.output.md,
    result_jsons=list(sm.input.results),
    tol=float(sm.params.tolerance),
    options=dict(sm.params.options),
)
print(table.to_string())
