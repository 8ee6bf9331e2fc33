# A blocked reduction (trivsel.blocks): lines (one job per axis) -> planes -> blocks -> merge.
#
# The rules run in the Python environment that runs Snakemake (`trivsel blocks` starts it with
# its own interpreter), where trivsel is installed: no conda environment of their own.
# Each command execs the job's Python in place of the shell, so the job's process is Snakemake's
# child: a cluster that finds a job's processes by their parents (SLURM's proctrack/linuxproc)
# still finds it after a cancellation's SIGTERM, which kills the shell at once, and kills it
# after its grace time; a job busy in a compiled kernel would otherwise run on outside its job.
#
# Written and run by `trivsel blocks`, in the run's folder (snakemake --directory OUT), which
# holds blocks.json (the configuration and the plan).  Every job reads the region of the
# volume it needs, never the whole volume.  Memory and runtime requests come from the job's
# size (trivsel.blocks.job_resources), so a cluster executor gets them unchanged:
#   trivsel blocks ... -- --executor slurm --workflow-profile workflow/profiles/slurm
#
# Batches (cluster runs): a cluster spends seconds on each job it schedules, so `trivsel blocks`
# sets `--config planes_per_job=P blocks_per_job=B` from the jobs' sizes
# (trivsel.blocks.group_components) and each cluster job reduces P planes or B blocks, one after
# the other in one process (rules planes_K and blocks_K).  Without them (local runs), one job
# per plane and per block (rules plane and block).  The kernels and the three line jobs form
# one cluster job (group "lines").

import os
import sys

from trivsel.blocks import block_faces, item_name, job_batches, job_resources, parse_item, read_config
from trivsel.blocks.slurm import end_with_parent

# the Snakemake of a SLURM job's batch script (a job step's has SLURM_STEP_ID) ends with the script
if workflow.remote_exec and "SLURM_JOB_ID" in os.environ and "SLURM_STEP_ID" not in os.environ:
    end_with_parent()

CFG, PLAN = read_config(".")
PY = sys.executable
PLANES = [item_name(x) for x in PLAN.planes()]
BLOCKS = [item_name(x) for x in PLAN.blocks()]
PLANES_PER_JOB = int(config.get("planes_per_job", 1))
BLOCKS_PER_JOB = int(config.get("blocks_per_job", 1))


def plane_inputs(plane):
    return [f"lines/{axis}.npz" for axis in range(3) if axis != plane[0]]


def block_inputs(block):
    return [f"planes/{item_name(p)}.npz" for p, _ in block_faces(PLAN, block)]


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
        "exec '{params.py}' -m trivsel.blocks kernels . > {log} 2>&1"


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
        "exec '{params.py}' -m trivsel.blocks lines . {wildcards.axis} > {log} 2>&1"


# one job per plane and per block (a local run, or a cluster run asked for it)
if PLANES_PER_JOB <= 1:

    rule plane:
        input:
            lambda wc: plane_inputs(parse_item(wc.plane)),
        output:
            "planes/{plane}.npz",
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
            "exec '{params.py}' -m trivsel.blocks plane . {wildcards.plane} > {log} 2>&1"


if BLOCKS_PER_JOB <= 1:

    rule block:
        input:
            lambda wc: block_inputs(parse_item(wc.block)),
        output:
            "pieces/{block}.npz",
            "pieces/{block}.vtu",
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
            "exec '{params.py}' -m trivsel.blocks block . {wildcards.block} > {log} 2>&1"


# one cluster job per batch of planes and of blocks, each reduced in one process
for _kind, _items, _per_job, _inputs, _outputs in (
    ("plane", PLAN.planes(), PLANES_PER_JOB, plane_inputs, lambda x: [f"planes/{item_name(x)}.npz"]),
    ("block", PLAN.blocks(), BLOCKS_PER_JOB, block_inputs,
     lambda x: [f"pieces/{item_name(x)}.npz", f"pieces/{item_name(x)}.vtu"]),
):
    if _per_job <= 1:
        continue
    for _k, _batch in enumerate(job_batches(_items, _per_job)):
        _mem, _minutes = zip(*(job_resources(PLAN, _kind, x) for x in _batch))

        rule:
            name:
                f"{_kind}s_{_k}"
            input:
                sorted({f for x in _batch for f in _inputs(x)}),
            output:
                [f for x in _batch for f in _outputs(x)],
            log:
                f"logs/{_kind}/batch_{_k}.log",
            benchmark:
                f"benchmarks/{_kind}/batch_{_k}.tsv"
            resources:
                mem_mb=max(_mem),
                runtime=sum(_minutes),
            params:
                py=PY,
                kind=_kind,
                names=" ".join(item_name(x) for x in _batch),
            shell:
                "exec '{params.py}' -m trivsel.blocks {params.kind} . {params.names} > {log} 2>&1"


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
        "exec '{params.py}' -m trivsel.blocks merge . > {log} 2>&1"
