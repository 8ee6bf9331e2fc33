"""Rule reduce: run `trivsel reduce` once, to the largest fraction, with snapshots.

Calls the package's command-line entry point in-process, so the rule does not
depend on `trivsel` being on PATH; the log starts with the equivalent command.
"""

import shlex
import sys
from pathlib import Path

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

from trivsel.cli import main  # noqa: E402

sm = snakemake  # noqa: F821
outdir = str(Path(sm.output.errors).parent)
argv = [
    "reduce",
    "--function", str(sm.wildcards.function),
    "--n", str(sm.wildcards.n),
    "--fractions", *[f"{f:g}" for f in sm.params.fractions],
    "--out", outdir,
    "--threads", str(sm.threads),
    *sm.params.args,
]
print("$ trivsel " + shlex.join(argv), flush=True)
try:
    rc = main(argv)
except SystemExit as exc:  # argparse errors and explicit exits
    rc = exc.code
if rc not in (None, 0):
    raise SystemExit(f"trivsel reduce failed with exit status {rc}")
missing = [p for p in [sm.output.errors, sm.output.result, *sm.output.meshes] if not Path(p).is_file()]
if missing:
    raise SystemExit(f"trivsel reduce did not write {missing}")
