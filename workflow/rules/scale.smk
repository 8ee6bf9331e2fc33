# Optional stage, scale: wall time and peak memory against the number of points,
# trivsel's paper and greedy methods beside VTK's tetrahedral quadric decimation.
# Off by default (`scale: activate: false`); on with
#   snakemake -c 1 --configfile config/scale.yaml
# (-c 1: one measurement at a time, so jobs do not compete for the cores.)
# One job per (method, n) runs trivsel.study.scaling.measure: a fresh Python process that warms up
# on the 5^3 grid (numba kernels loaded, never compiled inside the timing), then times one
# run.  scale_table and scale_figure collect them.  Helpers live in the package
# (trivsel.study.scaling), so this file has rules only.

import trivsel.study.scaling as scaling_pkg

SCALE_NS = list(config["scale"]["n"])
SCALE_METHODS = list(config["scale"]["methods"])
SCALE_TARGETS = (
    [
        "results/report/scaling.csv",
        "results/report/scaling.md",
        "results/report/figures/scaling.png",
    ]
    if config["scale"]["activate"]
    else []
)


rule scale_run:
    output:
        "results/scale/{scale_method}/n{n}.json",
    params:
        function=config["scale"]["function"],
        fraction=config["scale"]["fraction"],
        code=CODE_SCALE,
    wildcard_constraints:
        scale_method="paper|greedy|vtk",
    log:
        "results/logs/scale_run/{scale_method}/n{n}.log",
    benchmark:
        "results/benchmarks/scale_run/{scale_method}/n{n}.tsv"
    threads: 1
    resources:
        mem_mb=scaling_pkg.scale_mem_mb,
        runtime=scaling_pkg.scale_runtime,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/scale_run.py"


rule scale_table:
    input:
        expand("results/scale/{m}/n{n}.json", m=SCALE_METHODS, n=SCALE_NS),
    output:
        csv=report(
            "results/report/scaling.csv",
            caption="../report/scaling.rst",
            category="Scaling",
            labels={"table": "time and memory per method and n (csv)"},
        ),
        md=report(
            "results/report/scaling.md",
            caption="../report/scaling.rst",
            category="Scaling",
            labels={"table": "fitted slopes, ratios trivsel/VTK, targets (Markdown)"},
        ),
    params:
        function=config["scale"]["function"],
        fraction=config["scale"]["fraction"],
        figure="figures/scaling.png",
        code=CODE_SCALE_REPORT,
    log:
        "results/logs/scale_table.log",
    benchmark:
        "results/benchmarks/scale_table.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/scale_table.py"


rule scale_figure:
    input:
        "results/report/scaling.csv",
    output:
        report(
            "results/report/figures/scaling.png",
            caption="../report/scaling_figure.rst",
            category="Scaling",
            labels={"figure": "time and memory against points (log-log)"},
        ),
    params:
        code=CODE_SCALE_REPORT,
    log:
        "results/logs/scale_figure.log",
    benchmark:
        "results/benchmarks/scale_figure.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/scale_figure.py"
