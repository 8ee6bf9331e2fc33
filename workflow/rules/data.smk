# Stage 1, data: sample each Table-1 function on the (n+1)^3 grid of eq. (18).


rule sample:
    output:
        "results/data/f{function}_n{n}.npz",
    params:
        code=CODE_DATA,
    log:
        "results/logs/sample/f{function}_n{n}.log",
    benchmark:
        "results/benchmarks/sample/f{function}_n{n}.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/sample.py"
