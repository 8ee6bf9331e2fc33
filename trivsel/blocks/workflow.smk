# A blocked reduction (trivsel.blocks): lines (one job per axis) -> planes -> blocks -> merge.
#
# The rules run in the Python environment that runs Snakemake (`trivsel blocks` starts it with
# its own interpreter), where trivsel is installed: no conda environment of their own.
#
# Written and run by `trivsel blocks`, in the run's folder (snakemake --directory OUT), which
# holds blocks.json (the configuration and the plan).  Every job reads the region of the
# volume it needs, never the whole volume.  Memory and runtime requests come from the job's
# size (trivsel.blocks.job_resources), so a cluster executor gets them unchanged:
#   trivsel blocks ... -- --executor slurm --workflow-profile workflow/profiles/slurm
#
# Groups (used by cluster executors only; a local run ignores them): the kernels and the three
# line jobs form one cluster job, and planes and blocks are batched several to a cluster job by
# `--group-components planes=P blocks=B`, which `trivsel blocks` sets from the jobs' sizes
# (trivsel.blocks.group_components), so that a cluster's scheduling time per job does not
# dominate small jobs.  A group job runs its jobs side by side on the cores Snakemake is given.

import sys

from trivsel.blocks import block_faces, item_name, job_resources, parse_item, read_config

CFG, PLAN = read_config(".")
PY = sys.executable
PLANES = [item_name(x) for x in PLAN.planes()]
BLOCKS = [item_name(x) for x in PLAN.blocks()]


wildcard_constraints:
    axis=r"[012]",
    plane=r"\d+_\d+",
    block=r"\d+_\d+_\d+",


localrules:
    all,


# the merge job's own copies; the job links them to the top of the folder when they are complete
RESULTS = [f"merged/{name}" for name in ["summary.json", "mesh.pvtu"] + (["mesh.vtu"] if CFG["merged"] else [])]


rule all:
    input:
        RESULTS,
    default_target: True


# The kernels compile once, before the jobs that use them run side by side (numba's cache in
# the installed package; a later run loads them).
rule kernels:
    output:
        touch("kernels.done"),
    group:
        "lines"
    log:
        "logs/kernels.log",
    benchmark:
        "benchmarks/kernels.tsv"
    resources:
        mem_mb=job_resources(PLAN, "kernels")[0],
        runtime=job_resources(PLAN, "kernels")[1],
    params:
        py=PY,
    shell:
        "'{params.py}' -m trivsel.blocks kernels . > {log} 2>&1"


rule lines:
    input:
        "kernels.done",
    output:
        "lines/{axis}.npz",
    group:
        "lines"
    log:
        "logs/lines/{axis}.log",
    benchmark:
        "benchmarks/lines/{axis}.tsv"
    resources:
        mem_mb=lambda wc: job_resources(PLAN, "lines", int(wc.axis))[0],
        runtime=lambda wc: job_resources(PLAN, "lines", int(wc.axis))[1],
    params:
        py=PY,
    shell:
        "'{params.py}' -m trivsel.blocks lines . {wildcards.axis} > {log} 2>&1"


rule plane:
    input:
        lambda wc: [f"lines/{axis}.npz" for axis in range(3) if axis != parse_item(wc.plane)[0]],
    output:
        "planes/{plane}.npz",
    group:
        "planes"
    log:
        "logs/plane/{plane}.log",
    benchmark:
        "benchmarks/plane/{plane}.tsv"
    resources:
        mem_mb=lambda wc: job_resources(PLAN, "plane", parse_item(wc.plane))[0],
        runtime=lambda wc: job_resources(PLAN, "plane", parse_item(wc.plane))[1],
    params:
        py=PY,
    shell:
        "'{params.py}' -m trivsel.blocks plane . {wildcards.plane} > {log} 2>&1"


rule block:
    input:
        lambda wc: [f"planes/{item_name(p)}.npz" for p, _ in block_faces(PLAN, parse_item(wc.block))],
    output:
        "pieces/{block}.npz",
        "pieces/{block}.vtu",
    group:
        "blocks"
    log:
        "logs/block/{block}.log",
    benchmark:
        "benchmarks/block/{block}.tsv"
    resources:
        mem_mb=lambda wc: job_resources(PLAN, "block", parse_item(wc.block))[0],
        runtime=lambda wc: job_resources(PLAN, "block", parse_item(wc.block))[1],
    params:
        py=PY,
    shell:
        "'{params.py}' -m trivsel.blocks block . {wildcards.block} > {log} 2>&1"


rule merge:
    input:
        expand("pieces/{block}.npz", block=BLOCKS),
        expand("pieces/{block}.vtu", block=BLOCKS),
    output:
        RESULTS,
    log:
        "logs/merge.log",
    benchmark:
        "benchmarks/merge.tsv"
    resources:
        mem_mb=job_resources(PLAN, "merge", merged=CFG["merged"])[0],
        runtime=job_resources(PLAN, "merge", merged=CFG["merged"])[1],
    params:
        py=PY,
    shell:
        "'{params.py}' -m trivsel.blocks merge . > {log} 2>&1"
