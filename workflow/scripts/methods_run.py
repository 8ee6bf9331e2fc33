"""Rule methods_run: every method at matched vertex counts for one function and n."""

import sys
import time

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

from trivsel.study.comparison import compare_methods  # noqa: E402

sm = snakemake  # noqa: F821
t0 = time.perf_counter()
print(f"function {sm.wildcards.function}, n = {sm.wildcards.n}, fractions {list(sm.params.fractions)}, "
      f"VTK runs {sm.params.vtk_runs}, random seeds {sm.params.random_seeds}")
table = compare_methods(int(sm.wildcards.function), list(sm.params.fractions), n=int(sm.wildcards.n),
                        vtk_runs=int(sm.params.vtk_runs), random_seeds=int(sm.params.random_seeds),
                        progress=print)
table.to_csv(sm.output[0], index=False, float_format="%.10g")
print(table[["method", "values", "fraction", "n_target", "n_selected", "E_rms", "E_inf", "seconds"]].to_string())
print(f"{len(table)} rows in {time.perf_counter() - t0:.1f} s")
