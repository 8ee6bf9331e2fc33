"""Rule realdata_figure: one volume's E_RMS (fitted values) against the vertex count, log-log."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import pandas as pd  # noqa: E402

from trivsel.study.realdata import curves_figure  # noqa: E402

sm = snakemake  # noqa: F821
curves_figure(pd.read_csv(sm.input[0]), sm.output[0], volume=sm.wildcards.volume)
print(f"wrote {sm.output[0]}")
