"""Rule publish: copy the primary run's Table 1 and figures to results/report/."""

import shutil
import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

sm = snakemake  # noqa: F821
pairs = [(sm.input.table_csv, sm.output.table_csv), (sm.input.table_md, sm.output.table_md)]
pairs += list(zip(sm.input.figures, sm.output.figures))
for src, dst in pairs:
    shutil.copyfile(src, dst)
    print(f"{src} -> {dst}")
