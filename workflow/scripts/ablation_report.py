"""Rule ablation_report: stack the variants into ablation.csv and write ablation.md."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

from trivsel.study.ablation import best_consistent, summarise, write_ablation_report  # noqa: E402

sm = snakemake  # noqa: F821
long = write_ablation_report(list(sm.input), sm.output.csv, sm.output.md, tol=float(sm.params.tolerance),
                             out_summary=sm.output.summary, out_closest=sm.output.closest)
summ = summarise(long[["variant", "n", "function", "fraction", "n_selected", "E_rms", "E_rms_interior"]],
                 tol=float(sm.params.tolerance))
print(summ.to_string(index=False))
print("best consistent set:", best_consistent(summ)["variant"])
