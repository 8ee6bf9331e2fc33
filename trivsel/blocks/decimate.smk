# `trivsel blocks --method decimate` (trivsel.blocks.decimate): bottom-up decimation in blocks.
#
#   kernels -> costs (x-slabs of blocks) -> cut -> mesh (x-slabs of blocks) ->
#   per pass P: step_P (merge the pass before, plan this one) -> [rcosts (x-slabs of regions)
#   -> quota (and the regions recorded again)] -> apply (x-slabs of regions) ->
#   tiles (the last pass merged, the mesh kept by tile) -> [fit (x-slabs of tiles)] ->
#   pieces (x-slabs of tiles) -> finish
#
# The first bracketed stages run with a count or tol_rms (ST.costed): their cut spends the count
# and the squared-error budget that tau.json and each quota.npz carry on; fit runs with fitted values.
#
# The stages are those of `trivsel reduce --block B` (trivsel.decimation.blocked), so both give the
# same mesh.  Written and run by `trivsel blocks` in the run's folder, which holds blocks.json.
# What one stage hands the next is temporary: Snakemake removes a file once every job that
# reads it has run (a killed run keeps what its unfinished jobs still need).
# Block and region jobs read only their blocks' or regions' samples, the cut job a sample of the
# blocks' costs, fit and pieces jobs each tile's surroundings; step, quota and tiles hold arrays
# over the whole grid (a few bytes a point), never a decimation of it.  The rules run
# in the Python environment that runs Snakemake.
# Each command execs the job's Python in place of the shell, so the job's process is Snakemake's
# child: a cluster that finds a job's processes by their parents (SLURM's proctrack/linuxproc)
# still finds it after a cancellation's SIGTERM, which kills the shell at once, and kills it
# after its grace time; a job busy in a compiled kernel would otherwise run on outside its job.

import os
import sys

from trivsel.blocks import item_name, read_config
from trivsel.blocks.decimate import Stages, job_resources
from trivsel.blocks.slurm import end_with_parent

# the Snakemake of a SLURM job's batch script (a job step's has SLURM_STEP_ID) ends with the script
if workflow.remote_exec and "SLURM_JOB_ID" in os.environ and "SLURM_STEP_ID" not in os.environ:
    end_with_parent()

CFG, PLAN = read_config(".")
ST = Stages(CFG, PLAN)
PY = sys.executable
PASSES = range(len(ST.passes))
TILE_FILES = [f"tiles/{s}.npz" for s in ST.slabs]
FIT_FILES = [f"fit/{s}.npz" for s in ST.slabs] if ST.fit else []
RESULTS = [f"merged/{name}" for name in ["summary.json", "mesh.pvtu"] + (["mesh.vtu"] if CFG["merged"] else [])]


def res(kind):
    mem, minutes = job_resources(CFG, PLAN, kind)
    return {"mem_mb": mem, "runtime": minutes}


def region_files(p, folder):
    return [f"passes/{p}/{folder}/{s}.npz" for s in ST.region_slabs(p)]


def step_inputs(p):
    if p == 0:
        return [f"meshes/{s}.npz" for s in ST.slabs]
    spent = [f"passes/{p - 1}/quota.npz"] if ST.costed and p < len(ST.passes) else []  # the error spent so far
    return [f"passes/{p - 1}/state.npz", f"passes/{p - 1}/plan.npz"] + spent + region_files(p - 1, "out")


wildcard_constraints:
    slab=r"\d+",
    p=r"\d+",


localrules:
    all,


rule all:
    input:
        RESULTS,
    default_target: True


rule kernels:
    output:
        touch("kernels.done"),
    log:
        "logs/kernels.log",
    benchmark:
        "benchmarks/kernels.tsv"
    resources:
        **res("kernels"),
    params:
        py=PY,
    shell:
        "exec '{params.py}' -m trivsel.blocks.decimate kernels . > {log} 2>&1"


rule costs:
    input:
        "kernels.done",
    output:
        temp("costs/{slab}.npz"),
    log:
        "logs/costs/{slab}.log",
    benchmark:
        "benchmarks/costs/{slab}.tsv"
    resources:
        **res("costs"),
    params:
        py=PY,
    shell:
        "exec '{params.py}' -m trivsel.blocks.decimate costs . {wildcards.slab} > {log} 2>&1"


rule cut:
    input:
        [f"costs/{s}.npz" for s in ST.slabs] if ST.costed else "kernels.done",
    output:
        "tau.json",
        temp("costs/whole.npz") if ST.costed else [],
    log:
        "logs/cut.log",
    benchmark:
        "benchmarks/cut.tsv"
    resources:
        **res("cut"),
    params:
        py=PY,
    shell:
        "exec '{params.py}' -m trivsel.blocks.decimate cut . > {log} 2>&1"


rule mesh:
    input:
        "tau.json",
        ["costs/{slab}.npz", "costs/whole.npz"] if ST.costed else [],
    output:
        temp("meshes/{slab}.npz"),
    log:
        "logs/mesh/{slab}.log",
    benchmark:
        "benchmarks/mesh/{slab}.tsv"
    resources:
        **res("mesh"),
    params:
        py=PY,
    shell:
        "exec '{params.py}' -m trivsel.blocks.decimate mesh . {wildcards.slab} > {log} 2>&1"


# one step per pass: its region inputs, one file per x-slab of its region grid (known from the plan)
for _p in PASSES:

    rule:
        name:
            f"step_{_p}"
        input:
            step_inputs(_p),
        output:
            temp(f"passes/{_p}/state.npz"),
            temp(f"passes/{_p}/plan.npz"),
            temp(region_files(_p, "in")),
        log:
            f"logs/step/{_p}.log",
        benchmark:
            f"benchmarks/step/{_p}.tsv"
        resources:
            **res("step"),
        params:
            py=PY,
            p=_p,
        shell:
            "exec '{params.py}' -m trivsel.blocks.decimate step . {params.p} > {log} 2>&1"


rule rcosts:
    input:
        "passes/{p}/plan.npz",
        "passes/{p}/in/{slab}.npz",
    output:
        temp("passes/{p}/costs/{slab}.npz"),
    log:
        "logs/rcosts/{p}_{slab}.log",
    benchmark:
        "benchmarks/rcosts/{p}_{slab}.tsv"
    resources:
        **res("rcosts"),
    params:
        py=PY,
    shell:
        "exec '{params.py}' -m trivsel.blocks.decimate rcosts . {wildcards.p}_{wildcards.slab} > {log} 2>&1"


rule quota:
    input:
        lambda wc: [f"passes/{wc.p}/plan.npz"] + region_files(int(wc.p), "costs") + region_files(int(wc.p), "in"),
    output:
        temp("passes/{p}/quota.npz"),
        temp("passes/{p}/again.npz"),
    log:
        "logs/quota/{p}.log",
    benchmark:
        "benchmarks/quota/{p}.tsv"
    resources:
        **res("quota"),
    params:
        py=PY,
    shell:
        "exec '{params.py}' -m trivsel.blocks.decimate quota . {wildcards.p} > {log} 2>&1"


rule apply:
    input:
        "passes/{p}/plan.npz",
        "passes/{p}/in/{slab}.npz",
        lambda wc: [f"passes/{wc.p}/quota.npz", f"passes/{wc.p}/again.npz", f"passes/{wc.p}/costs/{wc.slab}.npz"]
        if ST.costed else [],
    output:
        temp("passes/{p}/out/{slab}.npz"),
    log:
        "logs/apply/{p}_{slab}.log",
    benchmark:
        "benchmarks/apply/{p}_{slab}.tsv"
    resources:
        **res("apply"),
    params:
        py=PY,
    shell:
        "exec '{params.py}' -m trivsel.blocks.decimate apply . {wildcards.p}_{wildcards.slab} > {log} 2>&1"


# the last pass merged and the mesh kept by tile (a block of the plan), one file per x-slab of tiles
rule tiles:
    input:
        step_inputs(len(ST.passes)),
    output:
        temp(TILE_FILES),
        temp("tiles/mesh.json"),
    log:
        "logs/tiles.log",
    benchmark:
        "benchmarks/tiles.tsv"
    resources:
        **res("tiles"),
    params:
        py=PY,
    shell:
        "exec '{params.py}' -m trivsel.blocks.decimate tiles . > {log} 2>&1"


# the fitted values of a slab's tiles: each from the tiles around it
rule fit:
    input:
        TILE_FILES,
        "tiles/mesh.json",
    output:
        temp("fit/{slab}.npz"),
    log:
        "logs/fit/{slab}.log",
    benchmark:
        "benchmarks/fit/{slab}.tsv"
    resources:
        **res("fit"),
    params:
        py=PY,
    shell:
        "exec '{params.py}' -m trivsel.blocks.decimate fit . {wildcards.slab} > {log} 2>&1"


# a slab's pieces, and the errors at its tiles' points
for _s in ST.slabs:

    rule:
        name:
            f"pieces_{_s}"
        input:
            TILE_FILES,
            "tiles/mesh.json",
            FIT_FILES,
        output:
            temp(f"sums/{_s}.npz"),
            [f"pieces/{item_name(b)}.vtu" for b in PLAN.blocks() if b[0] == _s],
        log:
            f"logs/pieces/{_s}.log",
        benchmark:
            f"benchmarks/pieces/{_s}.tsv"
        resources:
            **res("pieces"),
        params:
            py=PY,
            slab=_s,
        shell:
            "exec '{params.py}' -m trivsel.blocks.decimate pieces . {params.slab} > {log} 2>&1"


rule finish:
    input:
        [f"sums/{s}.npz" for s in ST.slabs],
        "tiles/mesh.json",
        [f"pieces/{item_name(b)}.vtu" for b in PLAN.blocks()],
        (TILE_FILES + FIT_FILES) if CFG["merged"] else [],
    output:
        RESULTS,
    log:
        "logs/finish.log",
    benchmark:
        "benchmarks/finish.tsv"
    resources:
        **res("finish"),
    params:
        py=PY,
    shell:
        "exec '{params.py}' -m trivsel.blocks.decimate finish . > {log} 2>&1"
