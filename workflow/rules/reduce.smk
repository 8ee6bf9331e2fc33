# Stage 2, reduce: one `trivsel reduce` per (function, n, option variant), run to the
# largest fraction; the smaller fractions are snapshots written on the way
# (errors.csv has one row per fraction, mesh_<fraction>.vtu one mesh per fraction).
# Before them, for each method of the sweep: kernels (parts 0 and 1, side by side), then
# kernels_driver (part 2: the extension module the reductions load); the reductions wait for
# its marker.
# The variant's flags are trivsel.Options.cli_args() (workflow/rules/common.smk).


rule kernels:
    """Compile the numba kernels of one method into numba's cache in two halves, side by
    side, before the reductions fan out (trivsel compile --part 0: swapping, --part 1:
    insertion: about half the time of one process on a fresh machine, a no-op load once
    they are cached)."""
    output:
        "results/kernels/{method}_part{part}.txt",
    params:
        part=lambda wildcards: int(wildcards.part),
        code=CODE_CORE,
    log:
        "results/logs/kernels/{method}_part{part}.log",
    benchmark:
        "results/benchmarks/kernels/{method}_part{part}.tsv"
    wildcard_constraints:
        method="|".join(KERNEL_METHODS),
        part="[01]",
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/kernels.py"


rule kernels_driver:
    """Build the extension module of the kernels a reduction of one method calls
    (trivsel compile --part 2: the drivers and everything they call, which links the two
    halves from numba's cache; numba's own drivers where no module can be built)."""
    input:
        expand("results/kernels/{{method}}_part{part}.txt", part=[0, 1]),
    output:
        "results/kernels/{method}_part2.txt",
    params:
        part=2,
        code=CODE_CORE,
    log:
        "results/logs/kernels/{method}_part2.log",
    benchmark:
        "results/benchmarks/kernels/{method}_part2.tsv"
    wildcard_constraints:
        method="|".join(KERNEL_METHODS),
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/kernels.py"


rule reduce:
    input:
        kernels=kernel_driver_marker,
    output:
        errors="results/runs/n{n}/{variant}/f{function}/errors.csv",
        result="results/runs/n{n}/{variant}/f{function}/result.json",
        meshes=expand(
            "results/runs/n{{n}}/{{variant}}/f{{function}}/mesh_{fraction}.vtu",
            fraction=FRACTION_LABELS,
        ),
    params:
        fractions=FRACTIONS,
        args=variant_cli_args,
        code=CODE_CORE,
    log:
        "results/logs/reduce/n{n}/{variant}/f{function}.log",
    benchmark:
        "results/benchmarks/reduce/n{n}/{variant}/f{function}.tsv"
    threads: 1
    resources:
        mem_mb=reduce_mem_mb,
        runtime=reduce_runtime,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/reduce.py"
