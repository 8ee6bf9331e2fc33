"""Rules kernels and kernels_driver: one part of `trivsel compile` (numba's on-disk cache, then the
extension module of trivsel.aot), then a marker."""

import sys
from pathlib import Path

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

from trivsel.cli import main  # noqa: E402

sm = snakemake  # noqa: F821
argv = ["compile", "--method", sm.wildcards.method, "--part", str(sm.params.part)]
print("$ trivsel " + " ".join(argv), flush=True)
try:
    rc = main(argv)
except SystemExit as exc:  # argparse errors and explicit exits
    rc = exc.code
if rc not in (None, 0):
    raise SystemExit(f"trivsel compile failed with exit status {rc}")
Path(sm.output[0]).write_text(f"trivsel {' '.join(argv)}: done (see {sm.log[0]})\n")
