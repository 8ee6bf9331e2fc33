"""Rule scale_table: the measurements stacked (scaling.csv) and the summary with fitted slopes,
ratios trivsel/VTK and the targets (scaling.md)."""

import json
import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

from trivsel.study.scaling import fit_slopes, scaling_markdown, scaling_table  # noqa: E402

sm = snakemake  # noqa: F821
rows = []
for path in sm.input:
    with open(path) as fh:
        rows.append(json.load(fh))
table = scaling_table(rows)
table.to_csv(sm.output.csv, index=False, float_format="%.6g")
with open(sm.output.md, "w") as fh:
    fh.write(scaling_markdown(table, function=int(sm.params.function), fraction=float(sm.params.fraction),
                              figure=sm.params.figure))
print(table.to_string(index=False))
print(fit_slopes(table, ("seconds", "peak_mb", "extra_mb")).to_string(index=False))
