"""Rule golden_check: compare results/report/table1.csv with the golden table.

Fails (and prints the offending cells to the log) when a number moved beyond
the tolerance; on success writes the comparison summary.
"""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

from trivsel.regression import compare_tables, format_mismatches  # noqa: E402

sm = snakemake  # noqa: F821
rtol, atol = float(sm.params.rtol), float(sm.params.atol)
bad = compare_tables(sm.input.new, sm.input.golden, rtol=rtol, atol=atol)
text = format_mismatches(bad, sm.input.new, sm.input.golden, rtol, atol)
print(text)
if bad:
    raise SystemExit(1)
with open(sm.output[0], "w") as fh:
    fh.write(text + "\n")
