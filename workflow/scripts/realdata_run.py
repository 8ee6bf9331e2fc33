"""Rule realdata_run: one volume's rows (trivsel.study.realdata.measure) and curves (curves)."""

import sys
import time

sys.stdout = sys.stderr = open(snakemake.log[0], "w", buffering=1)  # noqa: F821

import trivsel.study.realdata as rd  # noqa: E402

sm = snakemake  # noqa: F821
volume = sm.wildcards.volume
missing = rd.missing_message([volume], "leave it out of `realdata: volumes`")
if missing:
    # one line, in the log and on the terminal that runs snakemake
    print(f"realdata_run: {missing}")
    print(f"realdata_run: {missing}", file=sys.__stderr__)
    sys.exit(1)
methods, repeats = list(sm.params.methods), int(sm.params.repeats)
t0 = time.perf_counter()
rd.warm_up(methods)  # numba kernels loaded before any timing
data = rd.load_volume(volume, quick=bool(sm.params.quick))
print(f"{volume}: {data.shape} points, spacing {tuple(float(s) for s in data.spacing)}, values "
      f"{data.values.min():.4g} .. {data.values.max():.4g}" + (f", {data.meta['frame']}" if "frame" in data.meta else ""))
rows = []
for f in sorted(sm.params.fractions, reverse=True):
    print(f"  kept {100 * f:g} %")
    rows.append(rd.measure(data, f, repeats=repeats, methods=methods, say=print))
rd.write_csv(rows, sm.output.rows)
print(f"  curves at {sorted(sm.params.curve_fractions)}")
curves = rd.curves(data, sm.params.curve_fractions, methods=methods, repeats=repeats, say=print)
curves.to_csv(sm.output.curves, index=False, float_format="%.10g")
print(rd.tables(rows, methods)[0])
print(curves.to_string())
print(f"{len(rows)} rows and {len(curves)} curve points in {time.perf_counter() - t0:.1f} s")
