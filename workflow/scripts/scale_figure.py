"""Rule scale_figure: wall time and peak memory against points, log-log, fitted slopes in the legend."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import pandas as pd  # noqa: E402

from trivsel.study.scaling import scaling_figure  # noqa: E402

sm = snakemake  # noqa: F821
scaling_figure(pd.read_csv(sm.input[0]), sm.output[0])
print(f"wrote {sm.output[0]}")
