"""Rule erms_figure: E_RMS against the selected fraction, published values as markers."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import pandas as pd  # noqa: E402

from trivsel.study.figures import erms_figure  # noqa: E402

sm = snakemake  # noqa: F821
erms_figure(pd.read_csv(sm.input[0]), sm.output[0])
print(f"wrote {sm.output[0]}")
