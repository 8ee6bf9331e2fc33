"""Rules slice_figure and slice_figure_3d: the 2 x 2 panel of Figs. 4-6 for every function.

``params.draw`` names the function of :mod:`trivsel.study.figures` that draws one figure:
``slice_figure`` (mid-plane slices, matplotlib) or ``slice_figure_3d`` (pyvista, off-screen).
"""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import pandas as pd  # noqa: E402

from trivsel.io import load  # noqa: E402
from trivsel.study import figures  # noqa: E402

sm = snakemake  # noqa: F821
draw = getattr(figures, sm.params.draw)
k = len(sm.params.fractions)  # the meshes come function by function, fraction by fraction
for i, function in enumerate(sm.params.functions):
    meshes = dict(zip(sm.params.fractions, sm.input.meshes[i * k:(i + 1) * k]))
    draw(load(sm.input.data[i]), meshes, sm.output[i], errors=pd.read_csv(sm.input.errors[i]), function=int(function))
    print(f"wrote {sm.output[i]}")
