"""Rule table1: our errors beside the published Table 1 (csv + Markdown)."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

from trivsel.study.report import write_table1  # noqa: E402

sm = snakemake  # noqa: F821
ablation = getattr(sm.input, "ablation", None) or []  # results/report/ablation.csv with `ablation: true`
ablation = [ablation] if isinstance(ablation, str) else list(ablation)
table = write_table1(
    list(sm.input.errors),
    sm.output.csv,
    sm.output.md,
    result_jsons=list(sm.input.results),
    tol=float(sm.params.tolerance),
    options=dict(sm.params.options),
    ablation_csv=ablation[0] if ablation else None,
)
print(table.to_string())
