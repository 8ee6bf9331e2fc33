"""Rule methods_figure: E_RMS and E_inf against the vertex count, every method, log-log."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import pandas as pd  # noqa: E402

from trivsel.study.comparison import methods_figure  # noqa: E402

sm = snakemake  # noqa: F821
methods_figure(pd.read_csv(sm.input[0]), sm.output[0], function=sm.wildcards.function, n=sm.wildcards.n)
print(f"wrote {sm.output[0]}")
