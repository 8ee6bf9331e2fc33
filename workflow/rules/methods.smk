# Stage "methods" ("how good is it"; on with `methods: activate: true`, e.g.
#   snakemake -c all --configfile config/methods.yaml):
# every method at matched vertex counts - trivsel's greedy and paper methods with data and
# fitted vertex values, VTK's tetrahedral quadric decimation (median of several runs), a random
# subset + Delaunay (mean of several seeds) and the paper's curvature order + plain Delaunay -
# for each function and n, over the Table-1 fractions and the sweep `methods: fractions`.
# The work is trivsel.study.comparison.compare_methods; these rules only call it and collect.


rule methods_run:
    output:
        "results/methods/n{n}/f{function}.csv",
    params:
        fractions=METHODS_FRACTIONS,
        vtk_runs=config["methods"]["vtk_runs"],
        random_seeds=config["methods"]["random_seeds"],
        code=CODE_METHODS,
    log:
        "results/logs/methods_run/n{n}/f{function}.log",
    benchmark:
        "results/benchmarks/methods_run/n{n}/f{function}.tsv"
    threads: 1
    resources:
        mem_mb=methods_mem_mb,
        runtime=methods_runtime,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/methods_run.py"


rule methods_table:
    input:
        [f"results/methods/n{n}/f{f}.csv" for n in NS for f in FUNCTIONS],
    output:
        csv=report(
            "results/report/methods.csv",
            caption="../report/methods.rst",
            category="Methods compared",
            labels={"table": "every method (csv)"},
        ),
        md=report(
            "results/report/methods.md",
            caption="../report/methods.rst",
            category="Methods compared",
            labels={"table": "summary and target check (Markdown)"},
        ),
    params:
        fractions=FRACTIONS,
        figures={(n, f): f"figures/methods_f{f}_n{n}.png" for n in NS for f in FUNCTIONS},
        code=CODE_METHODS_REPORT,
    log:
        "results/logs/methods_table.log",
    benchmark:
        "results/benchmarks/methods_table.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/methods_table.py"


rule methods_figure:
    input:
        "results/methods/n{n}/f{function}.csv",
    output:
        report(
            "results/report/figures/methods_f{function}_n{n}.png",
            caption="../report/methods_figure.rst",
            category="Methods compared",
            subcategory="n = {n}",
            labels={"function": "{function}", "n": "{n}", "figure": "error vs vertex count"},
        ),
    params:
        code=CODE_METHODS_REPORT,
    log:
        "results/logs/methods_figure/n{n}/f{function}.log",
    benchmark:
        "results/benchmarks/methods_figure/n{n}/f{function}.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/methods_figure.py"
