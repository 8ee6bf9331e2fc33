# Stage 2, reduce: one `trivsel reduce` per (function, n, option variant), run to the
# largest fraction; the smaller fractions are snapshots written on the way
# (errors.csv has one row per fraction, mesh_<fraction>.vtu one mesh per fraction).


rule reduce:
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
