"""Rule sample: the Table-1 function on the (n+1)^3 grid of eq. (18), saved as .npz."""

import sys

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import trivsel  # noqa: E402
from trivsel.io import save_npz  # noqa: E402

function, n = int(snakemake.wildcards.function), int(snakemake.wildcards.n)  # noqa: F821
data = trivsel.sample_grid(function, n)
save_npz(data, snakemake.output[0])  # noqa: F821
print(f"function {function}, n = {n}: {data.n_points} points, f in [{data.values.min():.6g}, {data.values.max():.6g}]")
