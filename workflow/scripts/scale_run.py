"""Rule scale_run: one measurement (trivsel.study.scaling.measure) of one method at one n, in a fresh process."""

import json
import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

from trivsel.study.scaling import measure  # noqa: E402

sm = snakemake  # noqa: F821
method, n = sm.wildcards.scale_method, int(sm.wildcards.n)
print(f"{method}, n = {n} ({(n + 1) ** 3} points), function {sm.params.function} to {sm.params.fraction:g}; "
      f"fresh process, warm-up on the 5^3 grid first")
res = measure(method, n, function=int(sm.params.function), fraction=float(sm.params.fraction),
              threads=int(sm.threads), log=print)
with open(sm.output[0], "w") as fh:
    json.dump(res, fh, indent=1)
print(json.dumps(res, indent=1))
