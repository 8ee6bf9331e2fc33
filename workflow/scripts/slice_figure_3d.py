"""Rule slice_figure_3d: the 2 x 2 panel rendered off-screen with pyvista, for every function."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import pandas as pd  # noqa: E402

from trivsel.io import load  # noqa: E402
from trivsel.study.figures import slice_figure_3d  # noqa: E402

sm = snakemake  # noqa: F821
k = len(sm.params.fractions)  # the meshes come function by function, fraction by fraction
for i, function in enumerate(sm.params.functions):
    meshes = dict(zip(sm.params.fractions, sm.input.meshes[i * k:(i + 1) * k]))
    slice_figure_3d(load(sm.input.data[i]), meshes, sm.output[i], errors=pd.read_csv(sm.input.errors[i]),
                    function=int(function))
    print(f"wrote {sm.output[i]}")
