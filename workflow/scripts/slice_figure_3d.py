"""Rule slice_figure_3d: the 2 x 2 panel rendered off-screen with pyvista."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import pandas as pd  # noqa: E402

from trivsel.io import load  # noqa: E402
from trivsel.study.figures import slice_figure_3d  # noqa: E402

sm = snakemake  # noqa: F821
data = load(sm.input.data)
errors = pd.read_csv(sm.input.errors)
meshes = dict(zip(sm.params.fractions, sm.input.meshes))
slice_figure_3d(data, meshes, sm.output[0], errors=errors, function=int(sm.wildcards.function))
print(f"wrote {sm.output[0]}")
