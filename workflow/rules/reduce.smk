# Stage 2, reduce: one `trivsel reduce` per (function, n, option variant), run to the
# largest fraction; the smaller fractions are snapshots written on the way
# (errors.csv has one row per fraction, mesh_<fraction>.vtu one mesh per fraction).


rule kernels:
    """Compile the numba kernels of one method into numba's cache in two halves, side by
    side, before the reductions fan out (trivsel compile --part; about 12 s instead of 21 s
    on a fresh machine, a no-op load once they are cached)."""
    output:
        "results/kernels/{method}_part{part}.txt",
    params:
        code=CODE_CORE,
    log:
        "results/logs/kernels/{method}_part{part}.log",
    benchmark:
        "results/benchmarks/kernels/{method}_part{part}.tsv"
    wildcard_constraints:
        method="paper|greedy",
        part="[01]",
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
        kernels=kernel_markers,
    output:
        errors="results/runs/n{n}/{variant}/f{function}/errors.csv",
        result="results/runs/n{n}/{variant}/f{function}/result.json",
        meshes=expand(
            "results/runs/n{{n}}/{{variant}}/f{{function}}/mesh_{fraction}.vtu",
            fraction=FRACTION_LABELS,
        ),
    params:
        fractions=FRACTIONS,
        args=lambda wildcards: reduce_cli_args(VARIANTS[wildcards.variant]),
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
